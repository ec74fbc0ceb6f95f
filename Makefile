# The two commands of the README: `make run` (set up, TeX where it can, then the main job on
# the default carriage: `maglevgen build`) and `make test` (set up, then the test suite). Both create .venv on first use.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin

.PHONY: setup run test test-slow lint docs example-outputs bench clean mutation planted-faults

# pip's own lines (Collecting ..., Installing ...) say what it fetches: a first install takes
# 1-3 minutes, and a silent one looks hung
$(BIN)/maglevgen: pyproject.toml
	@echo "make: creating $(VENV) with $(PYTHON) and installing maglevgen (editable) and its dependencies (SymPy, CasADi, NumPy, SciPy, python-control, Matplotlib; the test and docs extras: pytest, FMPy, Sphinx ...), 1-3 min the first time"
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --progress-bar off -e '.[test,docs]'
	@echo "make: installed maglevgen $$($(BIN)/python -c 'import maglevgen; print(maglevgen.__version__)') into $(VENV)"
	touch $@

setup: $(BIN)/maglevgen

# TeX for report.pdf: installed with apt-get where TeX is missing and this user may (root, or
# sudo without a password), else one line says what to install (maglevgen/infrastructure/texsetup.py).
run: setup
	$(BIN)/python -m maglevgen.infrastructure.texsetup
	$(BIN)/maglevgen build

# The suite in TEST_WORKERS processes (pytest-xdist, one file per worker at a time: the
# module fixtures are built once; the workers share one derivation/compile cache).
# TEST_WORKERS=2 matches CI's 2 cores; `make test TEST_WORKERS=0` runs in one process.
TEST_WORKERS ?= 2

# `make test` leaves out the tests marked `slow` (each over about 10 s alone: the full-length
# runs, the cold and concurrent builds, the QEMU and MISRA passes) so that it stays under 15
# minutes on 2 cores; `make test-slow` runs those. CI (.ci/run) runs both.
test: setup
	$(BIN)/ruff check .
	$(BIN)/mypy
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile -m "not slow"

test-slow: setup
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile -m slow

lint: setup
	$(BIN)/ruff check .

# The documentation site (Sphinx, warnings as errors) into docs/_build/html; tests/test_docs.py
# builds the same in the suite.
docs: setup
	$(BIN)/python -m sphinx -W --keep-going -b html docs docs/_build/html

# The example scripts' outputs the site shows (docs/_examples/): each script of examples/ run
# as a user runs it (a few minutes); tests/test_examples.py fails when they are not current.
example-outputs: setup
	$(BIN)/python docs/_ext/example_outputs.py

# Benchmarks against the usual alternatives: writes BENCHMARKS.md and bench/results.json.
# A full run is long (71 min on 2026-12-05, of which firmware.py's
# MISRA pass 25 min); `$(BIN)/python bench/run.py --quick` is the short one. The bench extra (JAX, a peer of bench/casadi_peer.py) first; where it
# does not install, the bench runs without JAX and says so.
bench: setup
	$(BIN)/pip install --quiet -e '.[bench]' || echo "make: the bench extra (JAX) did not install: bench/casadi_peer.py skips its JAX peer"
	MAGLEV_BENCH_COMMAND="make bench" $(BIN)/python bench/run.py

# Mutation testing of the paper's equations (cosmic-ray; 30-60 min on 2 cores, not part of
# `make test`): mutation/report.txt, summarised in TESTING.md.
mutation: setup
	$(BIN)/pip install --quiet -e '.[test,mutation]'
	PYTHON=$(abspath $(BIN))/python bash mutation/run.sh

# The three faults of issue 23, planted one at a time: each must fail a numeric test.
planted-faults: setup
	$(BIN)/python mutation/planted_faults.py

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache docs/_build
