"""The lock-step batch in SIMD lanes (templates/maglev_lanes.c, issue 53) against the scalar
batch driver (templates/maglev_batch.c, one maglev_simulate per run) on the default study's runs.

    .venv/bin/python bench/simd_batch.py [--samples N] [--reps R] [--loops firmware sensed]
    (also part of `make bench`)

The runs are `maglevgen montecarlo`'s default study's (the embedded controller, 10 s at 1 kHz,
10^4 RK4 steps; seed 0) on each loop: ``--loop firmware`` (its tick, delay, actuator lag, speed
loop and force budget on the exact state) and ``--loop sensed`` (`montecarlo`'s default: the
same loop with the firmware's sense tick on each run's noisy readings), prepared once (a
sensed run's sense state and records are its own: its runs are prepared afresh, untimed,
for every variant). Each repeat runs every variant in turn on one thread, in the chunks of a
10^4-sample study on 2 processes (`default_chunk`: 64 runs a call; a W-lane batch needs at
least W runs a call to fill its lanes): the scalar driver and the lanes at W = 2 (SSE2), 4
(AVX2) and 8 (AVX-512F) where the CPU has them, each with libm's bits (at W = 4 and 8
glibc's exp and small-angle sincos over the lanes, maglevgen.codegen.lanes; libm per lane
else) and with glibc's libmvec (the experiment: not bit for bit). CPU time of this
process (time.process_time: the OpenMP team is one thread); medians, and the ratios to the
scalar driver taken in the same repeat. Every run of every variant is compared with the
scalar driver's: x, u, gaps, status, last sample and saturated steps equal to the last bit,
on the sensors each tick's readings, predictions and commands too (and the largest relative
and absolute differences of the final states where the last samples agree). Speed is
measured here, never asserted in tests; tests/test_simd_batch.py checks the equality.
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
from common import BENCH, log, paired_ratios, replace_section, study_runs, summary

from maglevgen.analyses.montecarlo import default_chunk, make_study
from maglevgen.analyses.simulate import run_loop
from maglevgen.carriage import DerivedCarriage
from maglevgen.codegen.lanes import WIDTHS
from maglevgen.control.carriage_plant import Plant
from maglevgen.params import load_params
from maglevgen.runtime.library import simulation_library
from maglevgen.runtime.runs import BatchBuffers

T_END, DT = 10.0, 1e-3


def _max_rel(a: np.ndarray, b: np.ndarray) -> float:
    scale = np.maximum(np.abs(a), np.abs(b))
    d = np.abs(a - b)
    return float(np.max(np.where(scale > 0, d / np.where(scale > 0, scale, 1), 0)))


BEGIN = "<!-- simd batch benchmark: bench/simd_batch.py -->"
END = "<!-- end of simd batch benchmark -->"
RESULTS = BENCH / "simd_batch_results.json"


LOOPS = ("firmware", "sensed")


def _same_sensing(a, b) -> bool:
    """Two runs' sense ticks recorded the same readings, predictions, commands and error."""
    if a.loop.sense is None:
        return b.loop.sense is None
    sa, sb = a.loop.sense, b.loop.sense
    return (np.array_equal(sa.readings, sb.readings) and np.array_equal(sa.predicted, sb.predicted)
            and np.array_equal(sa.commands, sb.commands) and sa.tick_error == sb.tick_error)


def measure(samples: int, reps: int, loop: str = "firmware") -> dict:
    """The variants' times and agreement on ``loop`` (module docstring)."""
    carriage = DerivedCarriage(load_params())
    lib = simulation_library(carriage.structure)
    plant = Plant(carriage, lib)
    controller = carriage.params.envelope.embedded_controller
    tick, k_v, budget = run_loop(plant, loop)
    study = make_study(plant, (controller,), T_END, DT, 0, tick, k_v, budget)
    runs, n_u, n_g = study_runs(study, lib, samples)
    sensed = loop == "sensed"
    n_steps = round(T_END / DT)
    size = default_chunk(10_000, 2)  # the chunk of `maglevgen montecarlo --samples 10000`
    widths = [w for w in WIDTHS if lib.lane_width(w) == w]
    variants: dict[str, tuple[int | None, str]] = {
        "scalar": (None, "libm"), **{f"W={w}": (w, "libm") for w in widths},
        **{f"W={w}, libmvec": (w, "libmvec") for w in widths}}

    # each variant's chunks into memory of its own kept across repeats, as a Monte-Carlo
    # worker writes them (BatchBuffers: no fresh pages for the kernel to map)
    buffers: dict[tuple, BatchBuffers] = {}

    def batch(lanes: int | None, math: str) -> tuple[float, list, list]:
        fresh = study_runs(study, lib, samples)[0] if sensed else runs  # untimed
        out = []
        t0 = time.process_time()
        for i in range(0, len(fresh), size):
            out += lib.simulate_batch(fresh[i:i + size], DT, n_steps, study.min_gap, n_u, n_g,
                                      1, lanes=lanes, lane_math=math,
                                      buffers=buffers.setdefault((lanes, math, i),
                                                                 BatchBuffers()))
        return (time.process_time() - t0) / len(fresh), out, fresh

    for lanes, math in variants.values():  # each driver compiled and loaded once, untimed
        lib.simulate_batch(runs[:1], DT, 10, study.min_gap, n_u, n_g, 1, lanes=lanes,
                           lane_math=math)
    load_start = os.getloadavg()
    log(f"simd_batch: --loop {loop}, {len(runs)} runs x {reps} repeats, "
        f"variants {list(variants)}")
    times: dict[str, list[float]] = {k: [] for k in variants}
    same: dict[str, bool] = dict.fromkeys(variants, True)
    rel: dict[str, float] = dict.fromkeys(variants, 0.0)
    absd: dict[str, float] = dict.fromkeys(variants, 0.0)
    reference: list | None = None
    for _ in range(reps):
        reference = reference_runs = None
        for name, (lanes, math) in variants.items():
            t, got, flown = batch(lanes, math)
            times[name].append(t)
            if reference is None:
                reference, reference_runs = got, flown
                continue
            for a, b in zip(reference, got, strict=True):
                same[name] &= (a.status == b.status and a.last == b.last
                               and a.saturated_steps == b.saturated_steps
                               and np.array_equal(a.x, b.x) and np.array_equal(a.u, b.u)
                               and np.array_equal(a.gaps, b.gaps))
                if a.last == b.last:
                    rel[name] = max(rel[name], _max_rel(a.x[-1], b.x[-1]))
                    absd[name] = max(absd[name], float(np.max(np.abs(a.x[-1] - b.x[-1]))))
            for a, b in zip(reference_runs, flown, strict=True):
                same[name] &= _same_sensing(a, b)
    statuses: dict[str, int] = {}
    for r in reference or []:
        statuses[str(r.status)] = statuses.get(str(r.status), 0) + 1
    return {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "loadavg_start": load_start, "loadavg_end": os.getloadavg(), "t_end": T_END, "dt": DT,
        "controller": controller, "loop": loop, "runs": len(runs), "chunk": size,
        "reps": reps, "threads": 1, "widths_this_cpu": widths,
        "ms_per_run": {k: summary([1e3 * t for t in v]) for k, v in times.items()},
        "speedup_vs_scalar": {k: paired_ratios(times["scalar"], v)
                              for k, v in times.items() if k != "scalar"},
        "bitwise_same_as_scalar": {k: v for k, v in same.items() if k != "scalar"},
        "max_rel_diff_final_state": {k: v for k, v in rel.items() if k != "scalar"},
        "max_abs_diff_final_state": {k: v for k, v in absd.items() if k != "scalar"},
        "statuses_of_runs": statuses,
    }


def _table(res: dict) -> list[str]:
    """One loop's table: the variants' times, ratios and agreement."""
    lines = ["| variant | ms per run (median) | runs per CPU-second | speed-up vs the scalar "
             "driver (paired, median) | every run bit for bit the scalar's | final states: max "
             "relative / absolute difference |", "| --- | --- | --- | --- | --- | --- |"]
    for k, v in res["ms_per_run"].items():
        r = res["speedup_vs_scalar"].get(k)
        ratio = "" if r is None else f"{r['median']:.2f}x"
        equal = "" if r is None else ("yes" if res["bitwise_same_as_scalar"][k] else "**no**")
        diff = "" if r is None else (f"{res['max_rel_diff_final_state'][k]:.1e} / "
                                     f"{res['max_abs_diff_final_state'][k]:.1e}")
        lines.append(f"| {k} | {v['median']:.2f} | {1e3 / v['median']:.1f} | {ratio} | "
                     f"{equal} | {diff} |")
    return lines


_LOOP_TEXT = {
    "firmware": "`--loop firmware`: the tick, delay, lag, speed loop and budget on the exact "
                "state",
    "sensed": "`--loop sensed`, `montecarlo`'s default: the firmware's sense tick on each "
              "run's noisy readings; every run's readings, predictions and commands compared "
              "too"}


def section(results: dict) -> list[str]:
    """The section of BENCHMARKS.md: one table per loop measured."""
    measured = list(results.values())
    first, last = measured[0], measured[-1]
    la, lb = first["loadavg_start"][0], last["loadavg_end"][0]
    lines = [BEGIN, f"## Monte Carlo in SIMD lanes (issue 53; bench/simd_batch.py, "
             f"{last['date']}; raw: bench/simd_batch_results.json)", "",
             f"The default study's runs ({first['controller']}, {first['t_end']:g} s at 1 kHz, "
             f"seed 0), {first['runs']} runs in calls of {first['chunk']}, one thread, "
             f"{first['reps']} repeats with the variants in turn; load average {la:.1f} at the "
             f"start and {lb:.1f} at the end on the shared 2 cores: CPU times, the ratios "
             "paired within a repeat."]
    for loop, res in results.items():
        lines += ["", f"{_LOOP_TEXT.get(loop, loop)}:", "", *_table(res)]
    lines += ["", "scalar: templates/maglev_batch.c, one maglev_simulate per run. W=N: "
              "templates/maglev_lanes.c, N runs in lock step, the RK4 stages' "
              "maglev_dynamics_prepared in N lanes (maglevgen.codegen.lanes), the tick, delay, "
              "lag, speed loop, saturation, gaps and statuses per lane as maglev_simulate's own "
              "code; on the sensors the plant's rates at the tick and the readings in lanes too, "
              "each run's noise and rounding per lane, its sense tick (the firmware's) over "
              "the lanes (maglev_sense_lanes.c: a lane on an error branch by "
              "maglev_sense_tick); libm's bits: at W = 4 and 8 glibc's exp and, below "
              "3/256, its sincos in FMA vectors (checked at load and by "
              "tests/test_simd_batch.py), else libm per lane; the last sincos argument vectors "
              "kept. libmvec: the same with glibc's vector "
              "exp, sin and cos (within 4 ulp; tests/test_simd_batch.py against mpmath): "
              "not the scalar run's bits, and a state that is rounding noise "
              "about zero then differs by more than itself, so not within 1e-12 relative on "
              "every state: montecarlo and roa run the bit-for-bit lanes (W = the widest the "
              "CPU has that a call's runs fill).", END]
    return lines


def run_section(samples: int = 64, reps: int = 3, loops: tuple[str, ...] = LOOPS) -> dict:
    """Measure each loop, write the JSON (loop -> results) and the section of BENCHMARKS.md
    (`make bench`'s stage ``simd_batch``); the results."""
    res = {loop: measure(samples, reps, loop) for loop in loops}
    RESULTS.write_text(json.dumps(res, indent=1) + "\n")
    replace_section(section(res), BEGIN, END)
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--loops", nargs="+", default=list(LOOPS), choices=LOOPS)
    args = ap.parse_args(argv)
    print("\n".join(section(run_section(args.samples, args.reps, tuple(args.loops)))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
