"""`maglevgen montecarlo`'s default study against its C floor: the study's runs per second on
one process against the bare C batch loop of the same runs (issue 37: within 1.1x), on one and
on every core (at least 1.8x on 2), 10^4 samples (under a minute; on the sensors beside the
floor of the C loop and numpy's draw of the runs' noise, and on ``--loop firmware``), and the
same sweep as a Python loop over SciPy (the trim by SciPy's root finding on the lambdified
model, the run by solve_ivp) as the ratio. The study is the CLI's default: the default
[tolerances], the embedded controller, ``--loop sensed`` (its firmware's sense tick on each
run's noisy readings, the tick, delay, lag, speed loop and force budget; ``--loop firmware``:
the same on the exact state), 10 s at 1 kHz (10^4 RK4 steps), seed 0;
bench/experiments/batch.py splits the firmware loop's path into its stages.

    python bench/montecarlo.py [--quick] [--big N] [--loop sensed|firmware]
    (also part of `make bench`)
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
from common import BENCH, log, paired_ratios, study_runs, summary

from maglevgen.analyses.montecarlo import (
    default_chunk,
    make_study,
    run_local,
    sample_inputs,
    sample_parameters,
    sample_tick,
)
from maglevgen.analyses.sim_loop import SensedTick, reading_noise
from maglevgen.analyses.simulate import AXIS_STATES, run_loop
from maglevgen.carriage import DerivedCarriage
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.operating import operating_point
from maglevgen.derive import conventions as cv
from maglevgen.params import load_params
from maglevgen.runtime.library import simulation_library
from maglevgen.runtime.runs import BatchBuffers

T_END, DT = 10.0, 1e-3


def _python_sample(carriage: DerivedCarriage, study, lib, i: int) -> float:
    """Sample i the way an engineer would without the toolchain's C: SciPy's trim on the
    lambdified model, then solve_ivp (RK45, rtol 1e-6) of the closed loop (the controller at
    every stage: the firmware's tick is the C loop's). The gains are the C's (the same op),
    so only the trim and the integration are replaced. Seconds."""
    from scipy.integrate import solve_ivp

    from maglevgen.derive.trim import solve_trim

    fns = carriage.functions
    draws = sample_inputs(study, i)
    p = sample_parameters(study, draws)
    t0 = time.perf_counter()
    trim = solve_trim(fns, p, float(draws[0]), study.min_gap)
    t_trim = time.perf_counter() - t0
    op = operating_point(lib, p, float(draws[0]), study.min_gap, study.weights)
    K_pos, K_rate = op.gains(study.controllers[0])
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


def noise_draw_per_run(study, n: int) -> dict:
    """Seconds a run's noise takes to draw (`sim_loop.reading_noise` of samples 0..n-1's own
    ticks, as `simulate.hold_run` draws it, into one array as `BatchBuffers` keeps it): the
    part of a run on the sensors that numpy's generator makes, whatever the C costs."""
    n_ticks = round(T_END / DT) + 1
    out: np.ndarray | None = None
    times = []
    for i in range(n):
        tick = sample_tick(study, i)
        assert isinstance(tick, SensedTick)
        params, noisy = tick.firmware.sampled(tick.sensor_values)
        if out is None:
            out = np.empty((n_ticks, len(noisy.names)))
        t0 = time.perf_counter()
        reading_noise(params, noisy, n_ticks, tick.seed, tick.noise_scale, out)
        times.append(time.perf_counter() - t0)
    return summary(times)


def run(quick: bool = False, big: int | None = None, loop: str = "sensed") -> dict:
    carriage = DerivedCarriage(load_params())
    lib = simulation_library(carriage.structure)
    controller = carriage.params.envelope.embedded_controller
    tick, k_v, budget = run_loop(Plant(carriage, lib), loop)
    study = make_study(Plant(carriage, lib), (controller,), T_END, DT, 0, tick, k_v, budget)
    load_start = os.getloadavg()
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    n = 40 if quick else 400
    repeats = 2 if quick else 3
    big = big if big is not None else (0 if quick else 10_000)
    runs, n_u, n_g = study_runs(study, lib, n, as_flown=True)
    n_steps = round(T_END / DT)
    lib.simulate_batch(runs[:2], DT, n_steps, study.min_gap, n_u, n_g, 1, lanes=0)  # compiled
    log(f"montecarlo: {n} samples x {repeats}: the bare C loop, the study on 1 and {cores} "
        "processes")
    # the bare loop (the study's runs: each sample's own tick, nothing recorded) in the chunks
    # a 1-process study makes, into the memory of the previous chunk as a worker writes them
    # (BatchBuffers: not pages the kernel maps afresh); a run on the sensors is prepared
    # afresh (untimed) for every repeat, its sense state its own
    size = default_chunk(n, 1)
    bare, one, many = [], [], []
    buffers = BatchBuffers()
    for _ in range(repeats):  # the three alternate in every repeat
        if loop == "sensed":
            runs = study_runs(study, lib, n, as_flown=True)[0]
        t0 = time.perf_counter()
        for i in range(0, len(runs), size):
            lib.simulate_batch(runs[i:i + size], DT, n_steps, study.min_gap, n_u, n_g, 1,
                               lanes=0, buffers=buffers)
        bare.append((time.perf_counter() - t0) / len(runs))
        t0 = time.perf_counter()
        run_local(study, n, workers=1)
        one.append((time.perf_counter() - t0) / n)
        t0 = time.perf_counter()
        run_local(study, n, workers=cores)
        many.append((time.perf_counter() - t0) / n)
    out = {
        "loadavg_start": load_start, "t_end": T_END, "dt": DT, "controller": controller,
        "loop": loop, "cores": cores, "samples": n, "repeats": repeats, "seed": 0,
        "chunk": size,
        "bare_c_per_run_s": summary(bare), "study_per_run_1_s": summary(one),
        "study_per_run_all_s": summary(many),
        "study_vs_bare_c": paired_ratios(one, bare),
        "scaling": paired_ratios(one, many),
        "runs_per_s_all": 1.0 / summary(many)["median"],
    }
    if big:
        log(f"montecarlo: {big} runs on {cores} processes")
        t0 = time.perf_counter()
        run_local(study, big, workers=cores)
        out["big_runs"], out["big_s"] = big, time.perf_counter() - t0
        out["big_floor_s"] = big * summary(bare)["median"] / cores
        if loop == "sensed":
            noise = out["noise_per_run_s"] = noise_draw_per_run(study, 40)
            out["big_floor_noise_s"] = out["big_floor_s"] + big * noise["median"] / cores
            log(f"montecarlo: {big} runs of --loop firmware on {cores} processes")
            fw_study = make_study(Plant(carriage, lib), (controller,), T_END, DT, 0,
                                  *run_loop(Plant(carriage, lib), "firmware"))
            run_local(fw_study, 2 * cores, workers=1)  # its library built, outside the timing
            t0 = time.perf_counter()
            run_local(fw_study, big, workers=cores)
            out["big_firmware_s"] = time.perf_counter() - t0
    n_py = 2 if quick else 4
    carriage.functions  # noqa: B018  (lambdify once, outside the timing)
    log(f"montecarlo: {n_py} samples by SciPy (trim + solve_ivp RK45) on the lambdified model")
    py = [_python_sample(carriage, study, lib, i) for i in range(n_py)]
    out["python_per_run_s"] = summary(py)
    out["python_ratio"] = summary(py)["median"] / summary(one)["median"]
    out["loadavg_end"] = os.getloadavg()
    return out


def _ms(q: dict) -> str:
    return f"{q['median'] * 1e3:.2f} ms [{q['q1'] * 1e3:.2f}, {q['q3'] * 1e3:.2f}]"


def markdown(r: dict) -> list[str]:
    ratio, scaling = r["study_vs_bare_c"], r["scaling"]
    lines = [
        "## Monte Carlo (`maglevgen montecarlo`)", "",
        f"The default study: {r['t_end']:g} s at {1 / r['dt']:g} Hz (RK4 in the generated C), "
        f"the {r['controller']} controller with `--loop {r['loop']}`, the default "
        f"`[tolerances]`, seed {r['seed']} (each sample's trim, gains and Riccati solve, its "
        f"status and per-axis metrics). {r['samples']} samples, {r['repeats']} repeats with "
        "the three variants alternating; medians [quartiles], wall time on "
        f"{r['cores']} cores"
        + (f" (load average {r['loadavg_start'][0]:.1f} at the start, "
           f"{r['loadavg_end'][0]:.1f} at the end: the scaling needs idle cores)"
           if "loadavg_start" in r else "") + ".", "",
        "| what | time |", "| --- | --- |",
        f"| per run, the bare C loop (`SimulationLibrary.simulate_batch` of the prepared runs, "
        f"1 thread, in SIMD lanes as the study runs them, "
        f"in the study's chunks of {r.get('chunk', '?')}) "
        f"| {_ms(r['bare_c_per_run_s'])} |",
        f"| per run, the study on 1 process (`run_local`: draws, trims, gains, the C batch, "
        f"metrics) | {_ms(r['study_per_run_1_s'])}: {ratio['median']:.3g}x the bare C loop "
        "(target within 1.1x) |",
        f"| per run, the study on {r['cores']} processes | {_ms(r['study_per_run_all_s'])}: "
        f"{scaling['median']:.3g}x [{scaling['q1']:.3g}-{scaling['q3']:.3g}] the runs per "
        f"second of 1 process (target >= 1.8x on 2 cores), {r['runs_per_s_all']:.0f} runs/s |",
    ]
    if "big_runs" in r:
        lines.append(f"| {r['big_runs']} runs on {r['cores']} processes | {r['big_s']:.1f} s "
                     f"(target < 60 s); the bare C loop alone on {r['cores']} cores would take "
                     f"{r['big_floor_s']:.0f} s"
                     + (f", and with numpy's draw of each run's noise "
                        f"({r['noise_per_run_s']['median'] * 1e3:.2f} ms a run, "
                        "`sim_loop.reading_noise`) "
                        f"{r['big_floor_noise_s']:.0f} s: the floor with no other Python "
                        "at all (the trims, the moving equilibrium's, the metrics)"
                        if "big_floor_noise_s" in r else "") + " |")
    if "big_firmware_s" in r:
        lines.append(f"| {r['big_runs']} runs of `--loop firmware` (the same study on the "
                     f"exact state at the tick: no sensors, no noise, no estimator) on "
                     f"{r['cores']} processes | {r['big_firmware_s']:.1f} s (target < 60 s) |")
    p = r["python_per_run_s"]
    lines += [
        f"| per run by SciPy: root-finding trim + solve_ivp RK45 (rtol 1e-6) on the lambdified "
        f"model | {p['median']:.2f} s: {r['python_ratio']:.0f}x the study's per-run time |",
        "",
    ]
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--big", type=int, default=None, help="runs of the big batch (0: skip)")
    ap.add_argument("--loop", choices=("sensed", "firmware"), default="sensed",
                    help="the study's loop (default: montecarlo's, on the sensors)")
    ap.add_argument("--json", type=Path, default=BENCH / "montecarlo_results.json")
    args = ap.parse_args(argv)
    r = run(args.quick, args.big, args.loop)
    args.json.write_text(json.dumps(r, indent=1) + "\n")
    print("\n".join(markdown(r)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
