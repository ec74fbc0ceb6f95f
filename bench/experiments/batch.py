"""Monte-Carlo runs per second, in one process: the study's path through the C batch
(maglevgen.analyses.montecarlo.run_samples_batch) on 1 and 2 threads, the bare C loop (the same runs
prepared beforehand, maglev_batch_simulate alone) on 1 and 2 threads, and today's per-sample
Python path (run_sample: one maglev_simulate call per run from Python); the study as the
CLI runs it (maglevgen.analyses.montecarlo.run_local: chunks on 1 and on 2 worker processes); and
where
the batch path's time goes, stage by stage (thread CPU time of this process, one pass).

    .venv/bin/python bench/experiments/batch.py [--samples N] [--reps R] [--out FILE] [--no-write]

Writes its section of BENCHMARKS.md (between BEGIN and END) unless --no-write.

The default study of `maglevgen montecarlo` (the default carriage's [tolerances], the
embedded controller, --loop firmware, 10 s at 1 kHz, seed 0). Wall time (perf_counter) and
the process's CPU time (all threads) per variant; the variants alternate in every repeat;
medians. On a shared machine only the CPU time and the ratios within one run mean much.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/: common.py
from common import EXPERIMENTS, log, paired_ratios, replace_section, summary

from maglevgen.analyses.montecarlo import (
    _prepare,
    _run_row,
    make_study,
    run_local,
    run_sample,
    run_samples_batch,
)
from maglevgen.analyses.simulate import hold_run, hold_trajectory, run_loop
from maglevgen.carriage import DerivedCarriage
from maglevgen.control.carriage_plant import Plant
from maglevgen.params import load_params
from maglevgen.runtime.library import simulation_library

BEGIN = "<!-- batch benchmark (bench/experiments/batch.py) -->"
END = "<!-- end of batch benchmark -->"


def section(r: dict) -> list[str]:
    """The BENCHMARKS.md section of a run's results ``r`` (what main writes to --out)."""
    lo, hi = r["load_average_start"], r["load_average_end"]
    lines = [BEGIN, "",
             "### Monte Carlo in C: runs per second (bench/experiments/batch.py, "
             f"{r['date']}; raw: "
             "bench/experiments/batch_results.json)", "",
             f"The default study of `maglevgen montecarlo` ({r['controller']} controller, "
             f"`--loop {r['loop']}`, 10 s at 1 kHz, seed 0), {r['samples']} samples, "
             f"{r['reps']} repeats, the variants alternating, all in one run; load average "
             f"(1 min) {lo[0]:.1f} at the start and {hi[0]:.1f} at the end on the 2 shared "
             "cores (`os.getloadavg`). CPU: this process's threads and its ended worker "
             "processes. Medians.", "",
             "| variant | runs/s (wall) | CPU s per run |", "| --- | --- | --- |"]
    for k, rate in r["runs_per_s"].items():
        lines.append(f"| {k} | {rate:.3g} | {r['cpu_per_run'][k]:.3g} |")
    lines += ["", "| ratio (median of the per-repeat ratios [quartiles]) | value |",
              "| --- | --- |"]
    for k, q in r["ratios"].items():
        lines.append(f"| {k} | {q['median']:.3g} [{q['q1']:.3g}-{q['q3']:.3g}] |")
    stages = r["stages_cpu_s"]
    total = sum(stages.values())
    c_run = stages["the C runs (maglev_batch_simulate)"]
    lines += ["", "Where the batch path's time goes (one pass over the same samples, one "
              "thread, thread CPU time per sample):", "",
              "| stage | CPU ms per sample | share |", "| --- | --- | --- |"]
    for k, v in stages.items():
        lines.append(f"| {k} | {1e3 * v:.3g} | {100 * v / total:.0f} % |")
    lines += ["", f"The Python around the runs: {1e3 * (total - c_run):.3g} ms per sample, "
              f"{100 * (total - c_run) / c_run:.0f} % on top of the C run "
              f"({1e3 * c_run:.3g} ms).", "", END]
    return lines


def cpu_time() -> float:
    """CPU seconds of this process (all threads) and of its ended worker processes."""
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + kids.ru_utime + kids.ru_stime


def stages(study, idx, lib) -> dict[str, float]:
    """Thread CPU seconds of each stage of `run_samples_batch` over the samples ``idx``, one
    thread, the stages run one after another as the batch path runs them."""
    out = dict.fromkeys(("draws, parameters, trim, Jacobians (_prepare)",
                         "gains (hold_run: the controller's design, SciPy's Riccati)",
                         "the C runs (maglev_batch_simulate)",
                         "moving equilibrium (hold_trajectory: 9 trims in C)",
                         "rows (_run_row: metrics, contact cause, region multiple)"), 0.0)
    names = list(out)
    clock = time.thread_time
    t = clock()
    prepared = [_prepare(study, i, lib) for i in idx]
    out[names[0]] = clock() - t
    prepared = [q for q in prepared if not isinstance(q, list)]
    c = study.controllers[0]
    t = clock()
    runs = [hold_run(p, op, c, study.dt, d, study.tick, study.speed_gain, study.force_budget)
            for p, op, d, _row in prepared]
    out[names[1]] = clock() - t
    op0 = prepared[0][1]
    t = clock()
    done = lib.simulate_batch(runs, study.dt, round(study.t_end / study.dt), study.min_gap,
                              op0.allocation.shape[0] + 1, op0.gaps.size, 1)
    out[names[2]] = clock() - t
    t = clock()
    trajs = [hold_trajectory(lib, p, op, c, study.dt, study.min_gap, d, run, study.tick,
                             study.speed_gain, study.force_budget)
             for (p, op, d, _row), run in zip(prepared, done, strict=True)]
    out[names[3]] = clock() - t
    t = clock()
    for (p, op, d, row), traj in zip(prepared, trajs, strict=True):
        _run_row(study, lib, p, row, c, traj, op, d)
    out[names[4]] = clock() - t
    return {k: v / len(prepared) for k, v in out.items()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--samples", type=int, default=8)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--out", type=Path, default=EXPERIMENTS / "batch_results.json")
    ap.add_argument("--no-write", action="store_true", help="leave BENCHMARKS.md alone")
    args = ap.parse_args(argv)
    load_start = os.getloadavg()
    carriage = DerivedCarriage(load_params())
    lib = simulation_library(carriage.structure)
    controller = carriage.params.envelope.embedded_controller
    tick, k_v, budget = run_loop(Plant(carriage, lib), "firmware")
    study = make_study(Plant(carriage, lib), (controller,), 10.0, 1e-3, 0, tick, k_v, budget)
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
        # the study as `maglevgen montecarlo` runs it (chunks of 8 samples)
        "study (run_local), 1 process": lambda: run_local(study, args.samples, 1, 8),
        "study (run_local), 2 processes": lambda: run_local(study, args.samples, 2, 8),
    }
    variants["batch path, 1 thread"]()  # compiles the batch driver once (cached)
    wall: dict[str, list[float]] = {k: [] for k in variants}
    cpu: dict[str, list[float]] = {k: [] for k in variants}
    for r in range(args.reps):
        names = list(variants) if r % 2 == 0 else list(reversed(variants))
        for name in names:
            log(f"repeat {r + 1}: {name}")
            t0, c0 = time.perf_counter(), cpu_time()
            variants[name]()
            wall[name].append(time.perf_counter() - t0)
            cpu[name].append(cpu_time() - c0)
    n_runs = {k: (len(runs) if k.startswith("bare") else args.samples) for k in variants}
    log("stages of the batch path")
    per_stage = stages(study, idx, lib)
    load = os.getloadavg()
    out = {"samples": args.samples, "load_average_start": load_start,
           "load_average_end": load, "stages_cpu_s": per_stage, "runs": len(runs),
           "reps": args.reps,
           "controller": controller, "loop": "firmware",
           "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
           "wall_s": {k: summary(v) for k, v in wall.items()},
           "cpu_s": {k: summary(v) for k, v in cpu.items()}, "runs_per_s": {}}
    print("| variant | runs/s (wall) | CPU s per run |")
    print("| --- | --- | --- |")
    for k in variants:
        rate = n_runs[k] / out["wall_s"][k]["median"]
        out["runs_per_s"][k] = rate
        out.setdefault("cpu_per_run", {})[k] = out["cpu_s"][k]["median"] / n_runs[k]
        print(f"| {k} | {rate:.3g} | {out['cpu_per_run'][k]:.3g} |")
    # per-repeat ratios (the contenders of one repeat ran within seconds of each other)
    pairs = {"batch path / bare C loop, CPU per run, 1 thread":
             ("cpu", "batch path, 1 thread", "bare C loop, 1 thread"),
             "per-sample Python / bare C loop, CPU per run":
             ("cpu", "per-sample Python (run_sample)", "bare C loop, 1 thread"),
             "bare C loop: 2 threads / 1 thread, runs/s":
             ("wall", "bare C loop, 1 thread", "bare C loop, 2 threads"),
             "batch path: 2 threads / 1 thread, runs/s":
             ("wall", "batch path, 1 thread", "batch path, 2 threads"),
             "study: 2 processes / 1 process, runs/s":
             ("wall", "study (run_local), 1 process", "study (run_local), 2 processes")}
    out["ratios"] = {}
    print("\n| ratio (median of the per-repeat ratios [quartiles]) | value |\n| --- | --- |")
    for label, (kind, a, b) in pairs.items():
        src = cpu if kind == "cpu" else wall
        na, nb = n_runs[a], n_runs[b]
        r = paired_ratios([x / na for x in src[a]], [y / nb for y in src[b]])
        out["ratios"][label] = r
        print(f"| {label} | {r['median']:.3g} [{r['q1']:.3g}-{r['q3']:.3g}] |")
    print("\n| stage of the batch path | CPU s per sample |\n| --- | --- |")
    for k, v in per_stage.items():
        print(f"| {k} | {v:.4g} |")
    args.out.write_text(json.dumps(out, indent=1) + "\n")
    if not args.no_write:
        replace_section(section(out), BEGIN, END)
    return 0


if __name__ == "__main__":
    sys.exit(main())
