"""No work on the discarded branch (issue 53): the per-stage right-hand side with and without
maglevgen.codegen.branches.guard_discarded_branches, side by side.

    .venv/bin/python bench/experiments/branches.py [--reps N] [--calls N] [--out FILE]

Builds the default carriage's `maglev_dynamics_prepare`/`maglev_dynamics_prepared` pair (the
firmware loop's stage function, as maglevgen.codegen.functions builds it), generates its C
through the build's C pass twice (CasADi's both-sided if_else as before, and with the guarded
branches the build now writes), compiles both at the simulation library's flags and times
them per call in one C process, interleaved (bench/c/bench_prepared.c; the state 1 mm above
the trim at operation.speed, where every special function's argument takes the series).
Counts the C statements each evaluates per stage (a third build counts the guarded blocks it
enters) and checks that the two builds agree with CasADi's own evaluation of the SX function.
Then the whole closed loop: the simulation library as the build writes it now and as it wrote
it before (the same sources rendered with the pass off), RUNS firmware-loop holds of 10 s at
1 kHz (the embedded controller at operation.speed, the default disturbance, one thread) per
round, the two libraries alternating, process CPU time per round; the runs' final states
compared. Writes the raw JSON (bench/experiments/branches_results.json).
"""

from __future__ import annotations

import argparse
import ctypes
import json
import re
import shutil
import sys
import tempfile
import time
from pathlib import Path

import casadi as ca
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/: common.py
sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import DRIVER_DIR, EXPERIMENTS, log, paired_ratios, run, summary
from laws import write_input

from maglevgen.analyses.simulate import DISTURBANCE, hold_run, run_loop
from maglevgen.carriage import DerivedCarriage
from maglevgen.codegen import branches, cpass
from maglevgen.codegen.branches import guard_discarded_branches
from maglevgen.codegen.casadi_model import casadi_model
from maglevgen.codegen.cpass import postprocess, static_helpers
from maglevgen.codegen.functions import _prepared
from maglevgen.codegen.generate import render_runtime_sources
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.operating import Weights, operating_point
from maglevgen.derive.model import build_model
from maglevgen.derive.structure import numbered
from maglevgen.params import load_params
from maglevgen.runtime.compile import DEFAULT_FLAGS, compile_shared
from maglevgen.runtime.library import SimulationLibrary, simulation_library

T_END, DT, RUNS = 10.0, 1e-3, 10

_BLOCK = re.compile(r"^  if \(a\d+!=0\) \{$")
_STATEMENT = re.compile(r"^ +a\d+=.*;$")


def pair(carriage: DerivedCarriage) -> tuple[ca.Function, ca.Function]:
    cm = casadi_model(carriage.model)
    f = ca.Function("maglev_dynamics", [cm.x, cm.u, cm.p], [cm.xdot], ["x", "u", "p"],
                    ["xdot"], {"cse": True})
    return _prepared(f, 2, "d")


def sources(prepare: ca.Function, prepared: ca.Function,
            thresholds: tuple[int, ...] = ()) -> dict[str, str]:
    """The pair's C before and now (and, for each of ``thresholds``, with the pass's MIN_RUN
    at that value: "MIN_RUN=k"), and the counting build."""
    gen = ca.CodeGenerator("maglev_bench.c", {"with_header": False})
    gen.add(prepare)
    gen.add(prepared)
    both = static_helpers(postprocess(gen.dump(), "double"))
    guarded = guard_discarded_branches(both)
    out = {"both sides (before)": both, "taken side (now)": guarded}
    for k in thresholds:
        saved, branches.MIN_RUN = branches.MIN_RUN, k
        try:
            out[f"MIN_RUN={k}"] = guard_discarded_branches(both)
        finally:
            branches.MIN_RUN = saved
    return {**out, "counting": counting(guarded)}


def counting(guarded: str) -> str:
    """The guarded C with a counter of the statements each evaluation runs."""
    out, block = [], None
    lines = guarded.split("\n")
    for i, line in enumerate(lines):
        if _BLOCK.match(line):
            n = 0
            for t in lines[i + 1:]:
                if t == "  }":
                    break
                n += 1
            out.append(line + f" bench_statements += {n};")
            block = True
            continue
        if line == "  }" and block:
            block = None
        elif _STATEMENT.match(line) and block is None and line.startswith("  a"):
            line += " ++bench_statements;"
        out.append(line)
    return "long long bench_statements;\n" + "\n".join(out)


def statements(text: str, function: str) -> int:
    """Statements in the body of the CasADi function ``function`` calls (all of them run)."""
    callee = re.search(rf"int {function}\(.*?\n.*?return (casadi_f\d+)\(", text, re.S)
    assert callee is not None
    body = re.search(rf"static int {callee.group(1)}\(.*?\n(.*?)\n\}}\n", text, re.S)
    assert body is not None
    return sum(1 for t in body.group(1).split("\n") if _STATEMENT.match(t))


def before_library(carriage: DerivedCarriage, work: Path) -> SimulationLibrary:
    """The simulation library of the build before the pass: its sources rendered with
    guard_discarded_branches off, compiled at the same flags."""
    saved = cpass.guard_discarded_branches
    cpass.guard_discarded_branches = lambda text: text
    try:
        files = render_runtime_sources(build_model(numbered(carriage.structure)), "double")
    finally:
        cpass.guard_discarded_branches = saved
    folder = work / "before"
    folder.mkdir()
    for name, text in files.items():
        (folder / name).write_text(text)
    lib = compile_shared(sorted(folder.glob("*.c")), cache_dir=work / "cache")
    return SimulationLibrary(lib, "double", folder)


def closed_loop(carriage: DerivedCarriage, libs: dict[str, SimulationLibrary],
                rounds: int) -> dict:
    """CPU seconds per 10 s firmware-loop run of each library, rounds alternating."""
    now = libs["taken side (now)"]
    pr = carriage.params
    op = operating_point(now, carriage.p, float(pr.operation.speed), pr.track.min_gap,
                         Weights.of(pr))
    tick, k_v, budget = run_loop(Plant(carriage, now), "firmware")
    run = hold_run(carriage.p, op, pr.envelope.embedded_controller, DT, DISTURBANCE, tick,
                   k_v, budget)
    n_steps, n_u = round(T_END / DT), op.allocation.shape[0] + 1
    finals, seconds = {}, {k: [] for k in libs}
    for r in range(rounds):
        for label in (list(libs) if r % 2 == 0 else list(libs)[::-1]):
            t0 = time.process_time()
            done = libs[label].simulate_batch([run] * RUNS, DT, n_steps, pr.track.min_gap,
                                              n_u, op.gaps.size, 1)
            seconds[label].append((time.process_time() - t0) / RUNS)
            finals[label] = (done[0].x[-1], done[0].status)
    (x_now, s_now), (x_before, s_before) = (finals[k] for k in libs)
    return {"runs_per_round": RUNS, "steps": n_steps,
            "ms_per_run": {k: summary([1e3 * t for t in v]) for k, v in seconds.items()},
            "ratio_now_to_before": paired_ratios(seconds["taken side (now)"],
                                                 seconds["both sides (before)"]),
            "final_state_max_relative_difference": float(np.max(
                np.abs(x_now - x_before) / np.maximum(np.abs(x_before), 1e-300))),
            "statuses": [int(s_now), int(s_before)]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--reps", type=int, default=15)
    ap.add_argument("--calls", type=int, default=20_000)
    ap.add_argument("--rounds", type=int, default=9)
    ap.add_argument("--thresholds", type=int, nargs="*", default=[],
                    help="also time the pass with MIN_RUN at each of these values")
    ap.add_argument("--out", type=Path, default=EXPERIMENTS / "branches_results.json")
    args = ap.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="bench_branches_"))
    carriage = DerivedCarriage(load_params())
    log("functions and C")
    prepare, prepared = pair(carriage)
    libs = {}
    for k, (label, text) in enumerate(sources(prepare, prepared,
                                              tuple(args.thresholds)).items()):
        libs[label] = work / f"lib{k}.so"
        libs[label].with_suffix(".c").write_text(text)
        run(["gcc", *DEFAULT_FLAGS, "-o", libs[label], libs[label].with_suffix(".c"), "-lm"])
    input_file = write_input(carriage, simulation_library(carriage.structure), work / "in.txt")
    p, x, u = (np.array(line.split(), float)
               for line in input_file.read_text().split("\n")[1:4])
    d = prepare(p)
    reference = np.array(prepared(x, u, d)).ravel()  # CasADi's own evaluation (the SX VM)
    agreement = {}
    for label, lib in libs.items():
        got = np.array(ca.external("maglev_dynamics_prepared", str(lib))(x, u, d)).ravel()
        agreement[label] = float(np.max(np.abs(got - reference) / np.maximum(
            np.abs(reference), 1e-300)))
    counter = ctypes.CDLL(str(libs["counting"]))
    taken = ctypes.c_longlong.in_dll(counter, "bench_statements")
    taken.value = 0
    ca.external("maglev_dynamics_prepared", str(libs["counting"]))(x, u, d)
    before_text = libs["both sides (before)"].with_suffix(".c").read_text()
    counts = {"both sides (before)": statements(before_text, "maglev_dynamics_prepared"),
              "taken side (now)": taken.value,
              "casadi instructions": prepared.n_instructions()}
    exe = work / "bench_prepared"
    run(["gcc", "-std=c99", "-O2", "-o", exe, DRIVER_DIR / "bench_prepared.c", "-ldl"])
    timed = [label for label in libs if label != "counting"]
    log(f"timing {len(timed)} builds ({args.reps} repeats of {args.calls} calls)")
    raw = json.loads(run([exe, args.reps, args.calls, input_file,
                          *(libs[k] for k in timed)]))
    ns = dict(zip(timed, raw, strict=True))
    out = {"reps": args.reps, "calls": args.calls, "statements_per_stage": counts,
           "max_relative_difference_to_casadi": agreement,
           "ns_per_stage": {k: summary(v) for k, v in ns.items()},
           "ratio_to_before": {k: paired_ratios(v, ns["both sides (before)"])
                               for k, v in ns.items()},
           "ratio_now_to_before": paired_ratios(ns["taken side (now)"],
                                                ns["both sides (before)"])}
    log(f"closed loop: {args.rounds} rounds of {RUNS} runs per library")
    sims = {"taken side (now)": simulation_library(carriage.structure),
            "both sides (before)": before_library(carriage, work)}
    out["closed_loop"] = closed_loop(carriage, sims, args.rounds)
    args.out.write_text(json.dumps(out, indent=1) + "\n")
    print("| build | C statements per stage | ns per stage (median) | max rel. diff. to CasADi |")
    print("| --- | --- | --- | --- |")
    for label in timed:
        ratio = out["ratio_to_before"][label]["median"]
        print(f"| {label} | {counts.get(label, '')} | "
              f"{out['ns_per_stage'][label]['median']:.0f} (x{ratio:.3f}) | "
              f"{agreement[label]:.1e} |")
    print(f"ratio now/before per repeat: median {out['ratio_now_to_before']['median']:.3f}")
    cl = out["closed_loop"]
    print("| closed loop, 10 s at 1 kHz | " + " | ".join(
        f"{k}: {v['median']:.2f} ms" for k, v in cl["ms_per_run"].items())
        + f" | ratio {cl['ratio_now_to_before']['median']:.3f} | final states differ by "
        f"{cl['final_state_max_relative_difference']:.1e} |")
    shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
