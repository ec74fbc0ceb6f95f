"""Monte-Carlo runs per second, in one process: the study's path through the C batch
(maglevgen.montecarlo.run_samples_batch) on 1 and 2 threads, the bare C loop (the same runs
prepared beforehand, maglev_batch_simulate alone) on 1 and 2 threads, and today's per-sample
Python path (run_sample: one maglev_simulate call per run from Python).

    .venv/bin/python bench/batch.py [--samples N] [--reps R] [--out FILE]

The default study of `maglevgen montecarlo` (the default carriage's [tolerances], the
embedded controller, --loop firmware, 10 s at 1 kHz, seed 0). Wall time (perf_counter) and
the process's CPU time (all threads) per variant; the variants alternate in every repeat;
medians. On a shared machine only the CPU time and the ratios within one run mean much.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from common import BENCH, log, summary

from maglevgen.carriage import Carriage
from maglevgen.library import simulation_library
from maglevgen.montecarlo import _prepare, make_study, run_sample, run_samples_batch
from maglevgen.params import load_params
from maglevgen.simulate import hold_run, run_loop


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--samples", type=int, default=8)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--out", type=Path, default=BENCH / "batch_results.json")
    args = ap.parse_args(argv)
    carriage = Carriage(load_params())
    lib = simulation_library(carriage.structure)
    controller = carriage.params.envelope.embedded_controller
    tick, k_v, budget = run_loop(carriage, lib, "firmware")
    study = make_study(carriage, lib, (controller,), 10.0, 1e-3, 0, tick, k_v, budget)
    idx = range(args.samples)
    runs, n_u, n_g = [], 0, 0
    for i in idx:  # the bare loop's inputs: the study's runs, prepared once
        prepared = _prepare(study, i, lib)
        if isinstance(prepared, list):
            continue
        p, op, dist, _row = prepared
        runs.append(hold_run(p, op, controller, study.dt, dist, tick, k_v, budget))
        n_u, n_g = op.allocation.shape[0] + 1, op.gaps.size
    n_steps = round(study.t_end / study.dt)
    variants = {
        "per-sample Python (run_sample)": lambda: [run_sample(study, i, lib) for i in idx],
        "batch path, 1 thread": lambda: run_samples_batch(study, idx, lib, threads=1),
        "batch path, 2 threads": lambda: run_samples_batch(study, idx, lib, threads=2),
        "bare C loop, 1 thread": lambda: lib.simulate_batch(runs, study.dt, n_steps,
                                                            study.min_gap, n_u, n_g, 1),
        "bare C loop, 2 threads": lambda: lib.simulate_batch(runs, study.dt, n_steps,
                                                             study.min_gap, n_u, n_g, 2),
    }
    variants["batch path, 1 thread"]()  # compiles the batch driver once (cached)
    wall: dict[str, list[float]] = {k: [] for k in variants}
    cpu: dict[str, list[float]] = {k: [] for k in variants}
    for r in range(args.reps):
        names = list(variants) if r % 2 == 0 else list(reversed(variants))
        for name in names:
            log(f"repeat {r + 1}: {name}")
            t0, c0 = time.perf_counter(), time.process_time()
            variants[name]()
            wall[name].append(time.perf_counter() - t0)
            cpu[name].append(time.process_time() - c0)
    n_runs = {k: (len(runs) if k.startswith("bare") else args.samples) for k in variants}
    out = {"samples": args.samples, "runs": len(runs), "reps": args.reps,
           "controller": controller, "loop": "firmware",
           "wall_s": {k: summary(v) for k, v in wall.items()},
           "cpu_s": {k: summary(v) for k, v in cpu.items()}, "runs_per_s": {}}
    print("| variant | runs/s (wall) | CPU s per run |")
    print("| --- | --- | --- |")
    for k in variants:
        rate = n_runs[k] / out["wall_s"][k]["median"]
        out["runs_per_s"][k] = rate
        print(f"| {k} | {rate:.3g} | {out['cpu_s'][k]['median'] / n_runs[k]:.3g} |")
    args.out.write_text(json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
