"""Derivation, generation and compile time of the default carriage, phase by phase.

Run by bench/run.py in a fresh Python process (so nothing is cached in memory):

    python bench/derive_phases.py OUT_DIR

It does what the first steps of ``maglevgen build`` do, timing each phase: load the
parameters, derive the model (SymPy), lambdify it (the numeric layer), generate the
run-time-parameter C (runtime/library.py ``runtime_sources``) and compile it
(``simulation_library``). Then, in the same process, it repeats them (the "second call":
results held in memory) and times what ``maglevgen generate --parameters runtime`` does
(``render`` + write: the CasADi functions and their C, built anew each time) and its two parts.
Prints one JSON object of seconds on stdout.

The disk caches are the ones the CLI uses, under $MAGLEVGEN_CACHE (bench/run.py points it at a
fresh folder for a cold run and at the previous run's folder for a cached run):
maglevgen/infrastructure/cache.py's memo store for the derivation steps derive/memo.py memoises
(the derivation, the lambdified model), and runtime/library.py's generated C (``derivation/``)
and compiled library (``lib/``). The phases go through the same entry points as the CLI
(DerivedCarriage, library), so any change to those caches is measured here with no change to
this script.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

T_START = time.perf_counter()

from maglevgen.carriage import DerivedCarriage  # noqa: E402
from maglevgen.codegen.cpass import generate_c  # noqa: E402
from maglevgen.codegen.functions import build_functions  # noqa: E402
from maglevgen.codegen.generate import GenerateOptions, render, write_output  # noqa: E402
from maglevgen.derive.model import build_model  # noqa: E402
from maglevgen.params import load_params  # noqa: E402
from maglevgen.runtime.library import runtime_sources, simulation_library  # noqa: E402


def derive(carriage: DerivedCarriage) -> None:
    """The symbolic derivation of the carriage's structure (SymPy, eqs 1-4, 8-12)."""
    build_model(carriage.structure)


def lambdify(carriage: DerivedCarriage) -> None:
    """The numeric layer (lambdified layers and partials), through the DerivedCarriage as the CLI
    and
    the generator reach it (so through the memo store the package installs)."""
    _ = carriage.functions


def sources(carriage: DerivedCarriage) -> None:
    """The run-time-parameter C of the carriage's structure (cached as derivation/<key>)."""
    runtime_sources(carriage.structure)


def compile_library(carriage: DerivedCarriage) -> None:
    """The simulation library compiled from those sources (cached under lib/)."""
    simulation_library(carriage.structure)


def generate(carriage: DerivedCarriage, out: Path) -> None:
    """`maglevgen generate --parameters runtime`: CasADi functions, C and templates, written."""
    write_output(render(carriage, GenerateOptions("double", "runtime")), out)


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
        carriage = DerivedCarriage(load_params(None, []))

    phase("params", load)
    phase("derive", derive, carriage)
    phase("lambdify", lambdify, carriage)
    phase("sources", sources, carriage)
    phase("compile", compile_library, carriage)
    t["total"] = sum(t.values())
    # the same again in this process
    phase("second_derive", derive, carriage)
    phase("second_sources", sources, carriage)
    phase("second_compile", compile_library, carriage)
    # `maglevgen generate --parameters runtime` and its two parts
    phase("generate", generate, carriage, out)
    built = {}
    phase("casadi_functions", lambda: built.update(f=build_functions(carriage.model)))
    phase("c_code", lambda: generate_c(list(built["f"].functions), "maglev_functions", "double"))
    json.dump(t, sys.stdout)
    print()


if __name__ == "__main__":
    main(sys.argv[1])
