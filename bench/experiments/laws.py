"""The distributed force law's C against the point law's, per function, in one run.

    .venv/bin/python bench/experiments/laws.py [--reps N] [--out FILE] [LABEL=LIBRARY.so ...]

Builds (or reuses) the run-time-parameter library of the default carriage under each force
law (maglevgen.runtime.library.simulation_library: the cache of MAGLEVGEN_CACHE), writes each one's
inputs (the trim at operation.speed, a state 1 mm off it, the LQR hold run of `maglevgen
simulate`: 10 s at 1 kHz), and times maglev_dynamics, maglev_jacobians, maglev_trim,
maglev_stiffness and one maglev_simulate run of every library from one C process
(bench/c/bench_laws.c), the libraries interleaved in every repeat. Extra LABEL=PATH arguments
add libraries built elsewhere (e.g. the same laws before a change: LABEL is
``<law>-<anything>``, the law's inputs are used). Prints the medians and the distributed/point
ratios per function (medians of the per-repeat ratios) and writes the raw JSON.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/: common.py
from common import DRIVER_DIR, EXPERIMENTS, log, paired_ratios, run, summary

from maglevgen.analyses.simulate import DISTURBANCE, initial_state
from maglevgen.carriage import DerivedCarriage
from maglevgen.control.operating import Weights, operating_point
from maglevgen.params import load_params
from maglevgen.runtime.library import simulation_library

LAWS = ("point", "distributed")
FUNCTIONS = ("dynamics", "jacobians", "trim", "stiffness", "closed_loop")


def _fmt(values) -> str:
    return " ".join(repr(float(v)) for v in np.ravel(values))


def write_input(carriage: DerivedCarriage, lib, path: Path) -> Path:
    """The driver's input for ``carriage`` (bench/c/bench_laws.c's INPUT)."""
    pr = carriage.params
    speed = float(pr.operation.speed)
    op = operating_point(lib, carriage.p, speed, pr.track.min_gap, Weights.of(pr))
    x = op.x_trim.copy()
    x[2] += 1e-3
    u = np.zeros(op.allocation.shape[0] + 1)
    u[0] = op.f_prop
    K_pos, K_rate = (k.ravel(order="F") for k in op.gains("lqr"))
    x0 = initial_state(op, DISTURBANCE)
    lines = [str(carriage.p.size), _fmt(carriage.p), _fmt(x), _fmt(u), repr(speed), _fmt(x0),
             repr(float(op.f_prop)), _fmt(K_pos), _fmt(K_rate), _fmt(op.a_trim),
             _fmt([1e-3, 10_000, pr.track.min_gap])]
    path.write_text("\n".join(lines) + "\n")
    return path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--out", type=Path, default=EXPERIMENTS / "laws_results.json")
    ap.add_argument("extra", nargs="*", help="LABEL=LIBRARY.so (LABEL starts with a law)")
    args = ap.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="bench_laws_"))
    exe = work / "bench_laws"
    run(["gcc", "-std=c99", "-O2", "-o", exe, DRIVER_DIR / "bench_laws.c", "-ldl"])
    base = DerivedCarriage(load_params())
    libs, inputs = {}, {}
    for law in LAWS:
        carriage = base.with_array_force(law)
        log(f"library of the {law} law")
        lib = simulation_library(carriage.structure)
        libs[law] = lib.path
        inputs[law] = write_input(carriage, lib, work / f"{law}.txt")
    for item in args.extra:
        label, path = item.split("=", 1)
        libs[label] = Path(path)
        inputs[label] = inputs[label.split("-", 1)[0]]
    labels = list(libs)
    log(f"timing {', '.join(labels)} ({args.reps} repeats)")
    raw = json.loads(run([exe, args.reps, *[a for k in labels for a in (libs[k], inputs[k])]]))
    res = dict(zip(labels, raw, strict=True))
    out = {"reps": args.reps, "libraries": {k: str(v) for k, v in libs.items()},
           "ns": {k: {f: summary(res[k][f"{f}_ns"]) for f in FUNCTIONS} for k in labels},
           "ratios": {}}
    for k in labels:
        if k == "point":
            continue
        out["ratios"][f"{k}/point"] = {
            f: paired_ratios(res[k][f"{f}_ns"], res["point"][f"{f}_ns"]) for f in FUNCTIONS}
    args.out.write_text(json.dumps(out, indent=1) + "\n")
    print("| function | " + " | ".join(f"{k} [us]" for k in labels) + " | "
          + " | ".join(out["ratios"]) + " |")
    for f in FUNCTIONS:
        cells = [f"{out['ns'][k][f]['median'] / 1e3:.4g}" for k in labels]
        ratios = [f"{r[f]['median']:.2f}" for r in out["ratios"].values()]
        print(f"| {f} | " + " | ".join(cells) + " | " + " | ".join(ratios) + " |")
    shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
