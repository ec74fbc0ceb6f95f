"""`maglevgen montecarlo`: the batch's per-run cost against a single run's C loop, its scaling
on the machine's cores, runs per second, 10^4 runs, and the same sweep as a Python loop over
SciPy (the trim by SciPy's root finding on the lambdified model, the run by solve_ivp) as the
ratio. Every run: 10 s at 1 kHz (10^4 RK4 steps), the coupled LQR, the default [tolerances].

    python bench/montecarlo.py [--quick] [--big N]   (also part of `make bench`)
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import BENCH, log, summary

from maglevgen.analyses.montecarlo import (
    make_study,
    run_local,
    sample_inputs,
    sample_parameters,
)
from maglevgen.analyses.simulate import AXIS_STATES, simulate
from maglevgen.carriage import DerivedCarriage
from maglevgen.control.operating import operating_point
from maglevgen.derive import conventions as cv
from maglevgen.params import load_params
from maglevgen.runtime.library import simulation_library

T_END, DT, CONTROLLER = 10.0, 1e-3, "coupled"


def _python_sample(carriage: DerivedCarriage, study, lib, i: int) -> float:
    """Sample i the way an engineer would without the toolchain's C: SciPy's trim on the
    lambdified model, then solve_ivp (RK45, rtol 1e-6) of the closed loop. The gains are the
    C's (the same op), so only the trim and the integration are replaced. Seconds."""
    from scipy.integrate import solve_ivp

    from maglevgen.derive.trim import solve_trim

    fns = carriage.functions
    draws = sample_inputs(study, i)
    p = sample_parameters(study, draws)
    t0 = time.perf_counter()
    trim = solve_trim(fns, p, float(draws[0]), study.min_gap)
    t_trim = time.perf_counter() - t0
    op = operating_point(lib, p, float(draws[0]), study.min_gap, study.weights)
    K_pos, K_rate = op.gains(CONTROLLER)
    idx = list(AXIS_STATES)
    u = np.zeros(op.allocation.shape[0] + 1)
    u[0] = op.f_prop
    x0 = np.asarray(trim.x, dtype=float).ravel().copy()
    for (s, _), d in zip(study.disturbance, draws[1:1 + len(study.disturbance)], strict=True):
        x0[cv.STATE_INDEX[s]] += d

    def rhs(_t: float, x: np.ndarray) -> np.ndarray:
        rates = fns.kin(x).ravel()[idx]
        u[1:] = op.allocation @ (-(K_pos @ (x[idx] - op.a_trim) + K_rate @ rates))
        return fns.xdot(x, u, p).ravel()

    def contact(_t: float, x: np.ndarray) -> float:  # as the C loop: stop at contact
        return float(np.min(fns.gaps(x, p))) - study.min_gap

    contact.terminal = True
    t0 = time.perf_counter()
    solve_ivp(rhs, (0.0, T_END), x0, method="RK45", rtol=1e-6, atol=1e-9,
              t_eval=np.arange(0.0, T_END + DT / 2, DT), events=contact)
    return t_trim + time.perf_counter() - t0


def run(quick: bool = False, big: int | None = None) -> dict:
    carriage = DerivedCarriage(load_params())
    lib = simulation_library(carriage.structure)
    study = make_study(carriage, lib, (CONTROLLER,), T_END, DT, seed=1)
    load_start = os.getloadavg()
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    n = 40 if quick else 200
    repeats = 2 if quick else 3
    big = big if big is not None else (0 if quick else 10_000)

    # a single run's C loop: maglev_simulate with sample 0's inputs (what simulate calls)
    draws = sample_inputs(study, 0)
    p = sample_parameters(study, draws)
    op = operating_point(lib, p, float(draws[0]), study.min_gap, study.weights)
    K_pos, K_rate = (k.ravel(order="F") for k in op.gains(CONTROLLER))
    x0 = op.x_trim
    n_u, n_g = op.allocation.shape[0] + 1, op.gaps.size
    c_loop = []
    for _ in range(15):
        t0 = time.perf_counter()
        lib.simulate(x0, DT, round(T_END / DT), op.f_prop, K_pos, K_rate, op.a_trim, p,
                     study.min_gap, n_u, n_g)
        c_loop.append(time.perf_counter() - t0)
    single = []
    for _ in range(15):
        t0 = time.perf_counter()
        simulate(lib, p, op, CONTROLLER, T_END, DT, study.min_gap)
        single.append(time.perf_counter() - t0)
    log(f"montecarlo: {n} samples x {repeats} on 1 and {cores} processes")
    one, many = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        run_local(study, n, workers=1)
        one.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        run_local(study, n, workers=cores)
        many.append(time.perf_counter() - t0)
    per_run = summary(np.array(one) / n)
    out = {
        "loadavg_start": load_start,
        "t_end": T_END, "dt": DT, "controller": CONTROLLER, "cores": cores, "samples": n,
        "c_loop_s": summary(c_loop), "single_simulate_s": summary(single),
        "batch_per_run_1_s": per_run,
        "batch_overhead_vs_c_loop": per_run["median"] / summary(c_loop)["median"] - 1,
        "batch_s_1": summary(one), "batch_s_all": summary(many),
        "scaling": summary(one)["median"] / summary(many)["median"],
        "runs_per_s_all": n / summary(many)["median"],
    }
    if big:
        log(f"montecarlo: {big} runs on {cores} processes")
        t0 = time.perf_counter()
        run_local(study, big, workers=cores)
        out["big_runs"], out["big_s"] = big, time.perf_counter() - t0
    n_py = 2 if quick else 4
    carriage.functions  # noqa: B018  (lambdify once, outside the timing)
    log(f"montecarlo: {n_py} samples by SciPy (trim + solve_ivp RK45) on the lambdified model")
    py = [_python_sample(carriage, study, lib, i) for i in range(n_py)]
    out["python_per_run_s"] = summary(py)
    out["python_ratio"] = summary(py)["median"] / per_run["median"]
    out["loadavg_end"] = os.getloadavg()
    return out


def markdown(r: dict) -> list[str]:
    c, s, b = r["c_loop_s"], r["single_simulate_s"], r["batch_per_run_1_s"]
    lines = [
        "## Monte Carlo (`maglevgen montecarlo`)", "",
        f"Each run: {r['t_end']:g} s at {1 / r['dt']:g} Hz (RK4 in the generated C), the "
        f"{r['controller']} controller, one sample of the default `[tolerances]` (its trim, "
        "gains and coupled-LQR Riccati solve per sample, the status and per-axis metrics). "
        f"Medians [quartiles] on {r['cores']} cores"
        + (f" (load average {r['loadavg_start'][0]:.1f} at the start, "
           f"{r['loadavg_end'][0]:.1f} at the end: the scaling needs idle cores)"
           if "loadavg_start" in r else "") + ".", "",
        "| what | time |", "| --- | --- |",
        f"| a single run's C loop (`maglev_simulate`) | {c['median'] * 1e3:.2f} ms "
        f"[{c['q1'] * 1e3:.2f}, {c['q3'] * 1e3:.2f}] |",
        f"| a single `simulate` (the C loop + the moving-trim grid) | "
        f"{s['median'] * 1e3:.2f} ms [{s['q1'] * 1e3:.2f}, {s['q3'] * 1e3:.2f}] |",
        f"| per run in a batch of {r['samples']}, 1 process | {b['median'] * 1e3:.2f} ms "
        f"[{b['q1'] * 1e3:.2f}, {b['q3'] * 1e3:.2f}]: overhead "
        f"{r['batch_overhead_vs_c_loop'] * 100:.0f} % over the C loop (target < 10 %) |",
        f"| {r['samples']} runs on 1 / {r['cores']} processes | "
        f"{r['batch_s_1']['median']:.2f} s / {r['batch_s_all']['median']:.2f} s: "
        f"{r['scaling']:.2f}x (target >= 1.7x on 2 cores), {r['runs_per_s_all']:.0f} runs/s |",
    ]
    if "big_runs" in r:
        lines.append(f"| {r['big_runs']} runs on {r['cores']} processes | {r['big_s']:.1f} s "
                     "(target < 60 s) |")
    p = r["python_per_run_s"]
    lines += [
        f"| per run by SciPy: root-finding trim + solve_ivp RK45 (rtol 1e-6) on the lambdified "
        f"model | {p['median']:.2f} s: {r['python_ratio']:.0f}x the batch's per-run time |",
        "",
    ]
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--big", type=int, default=None, help="runs of the big batch (0: skip)")
    ap.add_argument("--json", type=Path, default=BENCH / "montecarlo_results.json")
    args = ap.parse_args(argv)
    r = run(args.quick, args.big)
    args.json.write_text(json.dumps(r, indent=1) + "\n")
    print("\n".join(markdown(r)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
