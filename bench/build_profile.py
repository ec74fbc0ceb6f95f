"""Where the time of one `maglevgen build` goes, stage by stage, around maglevgen.build.run_build.

Run by bench/run.py in a fresh Python process, on an output folder and a cache folder
($MAGLEVGEN_CACHE) that earlier builds filled, with the arguments of the CLI:

    python bench/build_profile.py timers|cprofile OUT_DIR [--set NAME=VALUE ...] [--no-pdf]

It imports the modules `maglevgen build` uses (timed: ``import_s``), then calls run_build as
the CLI does and prints one JSON object on stdout: the wall time of run_build, whether it
rebuilt, and per stage (STAGES: functions run_build reaches) its seconds and calls.

- ``timers``: each stage function is wrapped in a wall-clock timer (the module attribute the
  caller looks up is replaced), nothing else changes: these seconds are unprofiled;
- ``cprofile``: run_build under cProfile; a stage's cumulative time from the profile, plus
  the functions run_build calls directly and the imports run_build still triggers (matplotlib,
  python-control). cProfile slows Python-heavy work (SymPy) more than work in C or in other
  processes (gcc, LaTeX), so these seconds are larger than the timers' and only their
  proportions are comparable.

Stage functions run inside one another (the report context contains its figures), so stage
times overlap; bench/writeup.py shows them as a tree. A stage whose function is not found
(renamed) is left out, not guessed.
"""

from __future__ import annotations

import argparse
import functools
import importlib
import json
import sys
import threading
import time
from pathlib import Path

T_START = time.perf_counter()

import maglevgen.cli  # noqa: E402,F401  (what `python -m maglevgen.cli` imports first)
from maglevgen.build import BuildOptions  # noqa: E402
from maglevgen.params import load_params  # noqa: E402

# what run_build imports when it rebuilds (imported here so the timers can wrap them)
LAZY_MODULES = (
    "maglevgen.infrastructure.cache",
    "maglevgen.carriage",
    "maglevgen.codegen.interface",
    "maglevgen.runtime.library",
    "maglevgen.infrastructure.workers",
    "maglevgen.analyses.queries",
    "maglevgen.analyses.sim_output",
    "maglevgen.analyses.simulate",
    "maglevgen.report",
    "maglevgen.report.render",
    "maglevgen.report.latex",
    "maglevgen.derive.numeric",
)
for _m in LAZY_MODULES:
    importlib.import_module(_m)

T_IMPORTED = time.perf_counter()

# (key, "module:attribute" the caller looks the function up by)
STAGES: tuple[tuple[str, str], ...] = (
    ("run_build", "maglevgen.build:run_build"),
    ("build_key", "maglevgen.build:build_key"),
    ("up_to_date", "maglevgen.build:up_to_date"),
    ("runtime_sources", "maglevgen.runtime.library:runtime_sources"),
    ("simulation_library", "maglevgen.runtime.library:simulation_library"),
    ("model_functions", "maglevgen.derive.numeric:model_functions"),  # timers only (memoised)
    ("carriage_functions", "maglevgen.carriage:DerivedCarriage.functions"),  # cprofile only
    ("render_interface", "maglevgen.codegen.interface:render_interface"),
    ("run_scenarios", "maglevgen.analyses.simulate:run_scenarios"),
    ("c_simulate", "maglevgen.runtime.library:SimulationLibrary.simulate"),
    ("render_metrics", "maglevgen.analyses.sim_output:render_metrics"),
    # trajectories, simulation figures and report figures are drawn in forked children
    # (maglevgen.infrastructure.workers): this process only sees the time it waits for them
    ("background_wait", "maglevgen.infrastructure.workers:Job.result"),
    ("report_files", "maglevgen.build:_report_files"),
    ("build_context", "maglevgen.report.render:build_context"),
    ("trim_report", "maglevgen.report.render:trim_report"),
    ("gains_report", "maglevgen.report.render:gains_report"),
    ("verification", "maglevgen.report.render:verification_section"),
    ("render_tex", "maglevgen.report.render:render_tex"),
    ("run_latex", "maglevgen.report.latex:run_latex"),
    ("summary_text", "maglevgen.build:summary_text"),
    ("write_output", "maglevgen.build:write_output"),
)


def _resolve(spec: str) -> tuple[object, str] | None:
    """(owner, attribute name) of "module:attr" or "module:Class.attr"; None if absent."""
    mod, _, attr = spec.partition(":")
    owner: object = importlib.import_module(mod)
    *path, name = attr.split(".")
    for part in path:
        owner = getattr(owner, part, None)
        if owner is None:
            return None
    return (owner, name) if hasattr(owner, name) else None


def _quiet(*_args, **_kwargs) -> None:
    pass


def _install_timers() -> dict[str, dict]:
    """Wrap every stage function in a timer; the dict fills as they run."""
    seen: dict[str, dict] = {}
    lock = threading.Lock()
    for key, spec in STAGES:
        found = _resolve(spec)
        if found is None:
            continue
        owner, name = found
        fn = getattr(owner, name)
        if isinstance(fn, functools.cached_property) or not callable(fn):
            continue

        def timed(*args, __fn=fn, __key=key, **kwargs):
            t0 = time.perf_counter()
            try:
                return __fn(*args, **kwargs)
            finally:
                dt = time.perf_counter() - t0
                with lock:
                    s = seen.setdefault(__key, {"seconds": 0.0, "calls": 0})
                    s["seconds"] += dt
                    s["calls"] += 1

        setattr(owner, name, functools.wraps(fn)(timed))
    return seen


def _code_key(fn) -> tuple[str, int, str] | None:
    """pstats' key of a function; None for a memoised one (its wrapper's code is shared)."""
    if isinstance(fn, functools.cached_property):
        fn = fn.func
    if hasattr(fn, "__wrapped__"):
        return None
    code = getattr(fn, "__code__", None)
    return None if code is None else (code.co_filename, code.co_firstlineno, code.co_name)


def _profiled(stats: dict) -> tuple[dict[str, dict], list[dict]]:
    """Cumulative seconds of each stage, imports included, and run_build's direct callees."""
    out: dict[str, dict] = {}
    keys = {}
    for key, spec in STAGES:
        found = _resolve(spec)
        if (
            found is not None
            and (
                ck := _code_key(
                    vars(found[0]).get(found[1]) if isinstance(found[0], type) else getattr(*found)
                )
            )
            in stats
        ):
            keys[key] = ck
            out[key] = {"seconds": stats[ck][3], "calls": stats[ck][1]}
    imports = [
        v for (f, _line, n), v in stats.items() if n == "_find_and_load" and "importlib" in f
    ]
    if imports:  # recursive: cProfile's cumulative counts the outermost calls only
        out["imports"] = {
            "seconds": sum(v[3] for v in imports),
            "calls": sum(v[1] for v in imports),
        }
    callees = []
    if "run_build" in keys:
        for (f, line, n), v in stats.items():
            edge = v[4].get(keys["run_build"])
            if edge is not None:
                callees.append(
                    {
                        "function": f"{Path(f).name}:{line}({n})",
                        "seconds": edge[3],
                        "calls": edge[1],
                    }
                )
    return out, sorted(callees, key=lambda r: -r["seconds"])[:20]


def main(argv: list[str]) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("mode", choices=("timers", "cprofile"))
    ap.add_argument("out", type=Path)
    ap.add_argument("--set", action="append", default=[], dest="overrides")
    ap.add_argument("--no-pdf", action="store_true")
    args = ap.parse_args(argv)
    seen = _install_timers() if args.mode == "timers" else None
    import maglevgen.build as build  # after the timers: run_build looks its stages up here

    loaded = load_params(None, args.overrides)
    opts = BuildOptions(pdf=not args.no_pdf)
    callees: list[dict] = []
    t0 = time.perf_counter()
    if seen is not None:
        res = build.run_build(loaded, args.out, opts, step=_quiet, bar=None)
        wall = time.perf_counter() - t0
        stages = seen
    else:
        import cProfile
        import pstats

        prof = cProfile.Profile()
        prof.enable()
        res = build.run_build(loaded, args.out, opts, step=_quiet, bar=None)
        prof.disable()
        wall = time.perf_counter() - t0
        stages, callees = _profiled(pstats.Stats(prof).stats)  # type: ignore[attr-defined]
    json.dump(
        {
            "mode": args.mode,
            "import_s": T_IMPORTED - T_START,
            "run_build_s": wall,
            "rebuilt": res.rebuilt,
            "stages": stages,
            "run_build_callees": callees,
        },
        sys.stdout,
    )
    print()


if __name__ == "__main__":
    main(sys.argv[1:])
