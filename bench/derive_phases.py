"""Derivation, generation and compile time of the default carriage, phase by phase.

Run by bench/run.py in a fresh Python process (so nothing is cached in memory):

    python bench/derive_phases.py OUT_DIR

It does what ``maglevgen generate --parameters runtime`` and a first compile do, timing each
phase, then repeats the work in the same process (the "in-process second call": SymPy results
are held by lru_cache, the compiled library by runtime/compile.py's content-hash cache). Disk
caches go to $MAGLEVGEN_CACHE, which bench/run.py points at a fresh folder for a cold run and
at the previous run's folder for a cached run. Prints one JSON object of seconds on stdout.

The phases go through the same entry points as the CLI (Carriage, render), so an on-disk
derivation cache they use is measured by bench/run.py's cached runs with no change here; if
a cache needs an explicit call, ``derive`` / ``lambdify`` below are the functions to adapt.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

T_START = time.perf_counter()

from maglevgen.carriage import Carriage  # noqa: E402
from maglevgen.codegen.cpass import generate_c  # noqa: E402
from maglevgen.codegen.functions import build_functions  # noqa: E402
from maglevgen.codegen.generate import GenerateOptions, render, write_output  # noqa: E402
from maglevgen.derive.model import build_model  # noqa: E402
from maglevgen.params import load_params  # noqa: E402
from maglevgen.runtime.compile import compile_shared, default_cache_dir  # noqa: E402

COMPILE_FLAGS = ("-std=c99", "-O2", "-fPIC", "-shared")


def derive(carriage: Carriage) -> None:
    """The symbolic derivation of the carriage's structure (SymPy, eqs 1-4, 8-12)."""
    build_model(carriage.structure)


def lambdify(carriage: Carriage) -> None:
    """The numeric layer (lambdified layers and partials), through the Carriage as the CLI and
    the generator reach it (so through whatever cache the Carriage installs)."""
    _ = carriage.functions


def generate(carriage: Carriage, out: Path) -> None:
    """CasADi functions, C code and templates of the runtime-parameter build, written out."""
    write_output(render(carriage, GenerateOptions("double", "runtime")), out)


def compile_o2(out: Path) -> None:
    sources = [out / "maglev_functions.c"]
    if (out / "maglev_simulate.c").exists():
        sources.append(out / "maglev_simulate.c")
    compile_shared(sources, COMPILE_FLAGS, cache_dir=default_cache_dir() / "bench_lib")


def main(out_dir: str) -> None:
    out = Path(out_dir)
    t: dict[str, float] = {"import": time.perf_counter() - T_START}

    def phase(name: str, fn, *args) -> None:
        t0 = time.perf_counter()
        fn(*args)
        t[name] = time.perf_counter() - t0

    carriage = None

    def load() -> None:
        nonlocal carriage
        carriage = Carriage(load_params(None, []))

    phase("params", load)
    phase("derive", derive, carriage)
    phase("lambdify", lambdify, carriage)
    phase("generate", generate, carriage, out)
    phase("compile", compile_o2, out)
    t["total"] = sum(t.values())
    # the same again in this process
    phase("second_derive", derive, carriage)
    phase("second_generate", generate, carriage, out)
    phase("second_compile", compile_o2, out)
    # what generate spends in its two parts
    built = {}
    phase("casadi_functions", lambda: built.update(f=build_functions(carriage.model)))
    phase("c_code", lambda: generate_c(list(built["f"].functions), "maglev_functions", "double"))
    json.dump(t, sys.stdout)
    print()


if __name__ == "__main__":
    main(sys.argv[1])
