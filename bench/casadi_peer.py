"""The closed loop as CasADi's own code generation and JAX run it (issue 53): peers in `make bench`.

    python bench/casadi_peer.py [--rounds N] [--samples N]

The job: the default carriage held at operation.speed by the embedded controller's gains,
from the trim plus the default disturbance, the continuous closed loop (the controller at
every RK4 stage, the propulsion's feed-forward), 10^4 RK4 steps at 1 kHz, SAMPLES runs, one
thread. Contenders:

- the project's C: `maglev_simulate` through the batch driver (`simulate_batch`, one thread,
  the continuous loop: no tick), the build's library;
- CasADi's codegen of the same graph: the project's SX closed-loop right-hand side
  (`maglev_closed_loop`, as maglevgen.codegen.functions builds it, T an input) under an MX RK4
  step written as a CasADi user writes it, `mapaccum` over the steps (the gains, T and p as
  accumulators passed through, so no 10^4-column copies) and `map` over the samples, CasADi's
  C as CasADi writes it (no maglevgen pass), gcc -O3 -fPIC -shared, with and without
  -fno-semantic-interposition, evaluated through `casadi.external`;
- JAX (jit + vmap + scan, CPU, float64, one thread): the same SX right-hand side translated
  instruction by instruction into jax.numpy (bench/jax_peer.py), the same RK4 expressions,
  ``lax.scan`` over the steps, ``vmap`` over the runs, compiled once (the compile timed
  apart). JAX is the optional ``bench`` extra (`make bench` installs it); without it the
  contender is skipped with a line saying so.

Rounds alternate the contenders; CPU time (time.process_time) per round; runs per CPU-second;
each contender's final states against the project's (max relative and absolute difference).
Beside them, the limits: the operations of one RK4 stage counted in the SX graphs (both sides
of every if_else; bench/jax_peer.py's `operation_count`), and this machine's peak double
add/multiply rate on one core, scalar and in each vector extension it has, measured by
bench/c/flop_peak.c; each contender's time per run against the operation count's time at the
scalar peak. Writes bench/casadi_peer_results.json and its section of BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import casadi as ca
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import BENCH, DRIVER_DIR, log, paired_ratios, replace_section, run, summary
from jax_peer import available, jax_simulation, operation_count

from maglevgen.analyses.simulate import DISTURBANCE, hold_run
from maglevgen.carriage import DerivedCarriage
from maglevgen.codegen.functions import build_functions
from maglevgen.control.operating import Weights, operating_point
from maglevgen.params import load_params
from maglevgen.runtime.library import simulation_library

T_END, DT = 10.0, 1e-3
RESULTS = BENCH / "casadi_peer_results.json"
BEGIN = "<!-- casadi peer benchmark: bench/casadi_peer.py -->"
END = "<!-- end of casadi peer benchmark -->"
FLAGS = {"CasADi codegen, gcc -O3": ["-O3", "-fPIC", "-shared"],
         "CasADi codegen, gcc -O3 -fno-semantic-interposition":
             ["-O3", "-fPIC", "-shared", "-fno-semantic-interposition"]}
PROJECT = "maglevgen's C (maglev_simulate, -O2)"
JAX = "JAX (jit + vmap + scan, CPU, float64)"
#: the peak-rate kernels' build: no fused multiply-add, the scalar kernel left scalar
FLOP_FLAGS = ["-O2", "-ffp-contract=off", "-fno-tree-vectorize", "-fno-tree-slp-vectorize"]


def flop_peaks(work: Path) -> dict[str, dict[str, float]]:
    """This core's peak double add/multiply rate (bench/c/flop_peak.c): kernel -> lanes and
    Gflop/s, for the scalar kernel and each vector extension the CPU has."""
    exe = work / "flop_peak"
    run(["gcc", *FLOP_FLAGS, "-o", exe, DRIVER_DIR / "flop_peak.c"])
    out = {}
    for line in run([exe]).splitlines():
        name, lanes, rate = line.split()
        out[name] = {"lanes": int(lanes), "gflops": float(rate)}
    return out


def casadi_simulation(closed_loop: ca.Function, n_steps: int, samples: int) -> ca.Function:
    """sim(x0, theta) -> x_N of each sample: RK4 (MX) around ``closed_loop``, mapaccum over
    the steps, map over the samples (columns)."""
    names = [n for n in closed_loop.name_in() if n != "x"]
    x = ca.MX.sym("x", closed_loop.sparsity_in("x"))
    theta = {n: ca.MX.sym(n, closed_loop.sparsity_in(n)) for n in names}

    def f(xx):
        return closed_loop.call({**theta, "x": xx})["xdot"]

    k1 = f(x)
    k2 = f(x + DT / 2 * k1)
    k3 = f(x + DT / 2 * k2)
    k4 = f(x + DT * k3)
    x_next = x + DT / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    flat = ca.vertcat(*[ca.vec(theta[n]) for n in names])
    th = ca.MX.sym("theta", flat.shape[0])
    step = ca.Function("step", [x, *theta.values()], [x_next, *theta.values()])
    unflat, at = [], 0
    for n in names:
        sz = closed_loop.sparsity_in(n)
        unflat.append(ca.reshape(th[at:at + sz.numel()], sz.size1(), sz.size2()))
        at += sz.numel()
    k = len(names) + 1
    steps = step.mapaccum("steps", n_steps, list(range(k)), list(range(k)), {})
    x0 = ca.MX.sym("x0", x.shape[0])
    out = steps(x0, *unflat)
    one = ca.Function("one", [x0, th], [out[0][:, -1]])
    return one.map("sim", "serial", samples, [], [])


def inputs(carriage: DerivedCarriage, lib):
    pr = carriage.params
    op = operating_point(lib, carriage.p, float(pr.operation.speed), pr.track.min_gap,
                         Weights.of(pr))
    # the continuous loop: no tick
    batch_run = hold_run(carriage.p, op, pr.envelope.embedded_controller, DT, DISTURBANCE)
    theta = {"F_prop": np.array([batch_run.f_prop]),
             "K_pos": batch_run.k_pos.reshape(5, 5, order="F"),
             "K_rate": batch_run.k_rate.reshape(5, 5, order="F"),
             "a_ref": batch_run.a_ref, "T": op.allocation, "p": batch_run.p}
    return op, batch_run, theta


def measure(rounds: int, samples: int) -> dict:
    load_start = os.getloadavg()
    carriage = DerivedCarriage(load_params())
    lib = simulation_library(carriage.structure)
    op, batch_run, theta = inputs(carriage, lib)
    n_steps = round(T_END / DT)
    functions = {f.name(): f for f in build_functions(carriage.model).functions}
    closed_loop = functions["maglev_closed_loop"]
    # the operations of one RK4 stage: maglevgen's prepared stage (what maglev_simulate runs,
    # the constants of p, the gains and T taken out) and the whole graph CasADi and JAX run
    stage_ops = {"maglev_closed_loop_prepared": operation_count(
                     functions["maglev_closed_loop_prepared"]),
                 "maglev_closed_loop": operation_count(closed_loop)}
    n_x = closed_loop.nnz_in("x")
    rk4_ops = 13 * n_x  # the step's own: x + h k (3x 2 ops), x + h/6 (k1 + 2 k2 + 2 k3 + k4)
    sim = casadi_simulation(closed_loop, n_steps, samples)
    flat = np.concatenate([np.ravel(theta[n], order="F") for n in closed_loop.name_in()
                           if n != "x"])
    x0s = np.tile(batch_run.x0[:, None], (1, samples))
    thetas = np.tile(flat[:, None], (1, samples))
    work = Path(tempfile.mkdtemp(prefix="bench_casadi_peer_"))
    log("CasADi: generating C")
    gen = ca.CodeGenerator("peer.c", {"with_header": False})
    gen.add(sim)
    source = work / "peer.c"
    source.write_text(gen.dump())
    contenders = {}
    compile_s: dict[str, dict[str, float]] = {}
    for label, flags in FLAGS.items():
        lib_path = work / f"peer{len(contenders)}.so"
        log(f"compiling: {label}")
        t0 = time.perf_counter()
        run(["gcc", *flags, "-o", lib_path, source, "-lm"])
        compile_s[label] = {"wall": time.perf_counter() - t0}  # gcc's, another process
        log(f"  {compile_s[label]['wall']:.0f} s")
        ext = ca.external("sim", str(lib_path))
        contenders[label] = (lambda ext=ext: np.array(ext(x0s, thetas)))
    jax_skipped = available()
    if jax_skipped is None:
        log(f"JAX: translating maglev_closed_loop and compiling {n_steps} steps x {samples} runs")
        run_jax, compile_s[JAX] = jax_simulation(
            closed_loop, n_steps, DT, x0s,
            {n: np.tile(np.ravel(theta[n], order="F")[None, :], (samples, 1))
             for n in closed_loop.name_in() if n != "x"})
        log(f"  {compile_s[JAX]['wall']:.0f} s ({compile_s[JAX]['cpu']:.0f} s CPU)")
        contenders[JAX] = run_jax
    else:
        print(f"casadi_peer: JAX skipped: {jax_skipped}", flush=True)
    log("the peak add/multiply rates (bench/c/flop_peak.c)")
    peaks = flop_peaks(work)
    n_u, n_g = op.allocation.shape[0] + 1, op.gaps.size
    min_gap = carriage.params.track.min_gap

    def project() -> np.ndarray:
        done = lib.simulate_batch([batch_run] * samples, DT, n_steps, min_gap, n_u, n_g, 1)
        return np.array([d.x[-1] for d in done]).T

    contenders = {PROJECT: project, **contenders}
    finals = {k: fn() for k, fn in contenders.items()}  # warm up, and the states compared
    reference = finals[PROJECT]
    agreement = {k: float(np.max(np.abs(v - reference)
                                 / np.maximum(np.abs(reference), 1e-9))) for k, v in
                 finals.items()}
    agreement_abs = {k: float(np.max(np.abs(v - reference))) for k, v in finals.items()}
    seconds: dict[str, list[float]] = {k: [] for k in contenders}
    log(f"{rounds} rounds of {samples} runs per contender")
    for r in range(rounds):
        order = list(contenders) if r % 2 == 0 else list(contenders)[::-1]
        for k in order:
            t0 = time.process_time()
            contenders[k]()
            seconds[k].append((time.process_time() - t0) / samples)
    shutil.rmtree(work, ignore_errors=True)
    ops_stage = sum(stage_ops["maglev_closed_loop_prepared"].values())
    ops_run = n_steps * (4 * ops_stage + rk4_ops)
    widest = max(peaks.values(), key=lambda v: v["gflops"])
    return {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "loadavg_start": load_start, "loadavg_end": os.getloadavg(),
            "rounds": rounds, "samples": samples, "steps": n_steps,
            "operations_per_stage": {k: {"total": sum(v.values()), "by_operation": v}
                                     for k, v in stage_ops.items()},
            "operations_per_rk4_step_outside_the_stages": rk4_ops,
            "operations_per_run": ops_run,
            "peak_gflops": peaks,
            "limit_ms_per_run": {"scalar": ops_run / peaks["scalar"]["gflops"] * 1e-6,
                                 "simd": ops_run / widest["gflops"] * 1e-6},
            "compile_s": compile_s, "jax_skipped": jax_skipped,
            "ms_per_run": {k: summary([1e3 * t for t in v]) for k, v in seconds.items()},
            "project_speedup": {k: paired_ratios(v, seconds[PROJECT])
                                for k, v in seconds.items() if k != PROJECT},
            "final_state_max_relative_difference": agreement,
            "final_state_max_absolute_difference": agreement_abs}


def section(res: dict) -> list[str]:
    ms = {k: v["median"] for k, v in res["ms_per_run"].items()}
    limit = res["limit_ms_per_run"]
    peaks = res["peak_gflops"]
    widest = max(peaks, key=lambda k: peaks[k]["gflops"])
    stage = res["operations_per_stage"]
    comp = res["compile_s"]
    graph_ratio = (stage["maglev_closed_loop"]["total"]
                   / stage["maglev_closed_loop_prepared"]["total"])
    la0, la1 = (", ".join(f"{x:.2f}" for x in res[k]) for k in ("loadavg_start", "loadavg_end"))
    lines = [BEGIN, f"## Peers: the closed loop in CasADi's own codegen and in JAX (issue 53; "
             f"bench/casadi_peer.py, {res['date']}; raw: bench/casadi_peer_results.json)", "",
             f"The default carriage held at operation.speed by the embedded controller, the "
             f"continuous closed loop, {res['steps']} RK4 steps at 1 kHz, {res['samples']} "
             f"runs per round, one thread, {res['rounds']} alternating rounds (CPU time); load "
             f"average {la0} at the start and {la1} at the end on the shared 2 cores:", "",
             "| contender | ms per run (median) | runs per CPU-second | maglevgen's C faster by "
             "(per round, median) | x the scalar limit | final states: max relative / absolute "
             "difference to maglevgen's C |",
             "| --- | --- | --- | --- | --- | --- |"]
    for k, v in ms.items():
        ratio = res["project_speedup"].get(k)
        faster = "" if ratio is None else f"{ratio['median']:.2f}x"
        lines.append(f"| {k} | {v:.2f} | {1e3 / v:.1f} | {faster} | "
                     f"{v / limit['scalar']:.2f} | "
                     f"{res['final_state_max_relative_difference'][k]:.1e} / "
                     f"{res['final_state_max_absolute_difference'][k]:.1e} |")
    if res["jax_skipped"]:
        lines += ["", f"JAX skipped: {res['jax_skipped']}."]
    lines += ["", "The limits (operations counted in the SX graphs, rates measured on this "
              "machine in this run):", "",
              "| | |", "| --- | --- |",
              f"| operations per RK4 stage, maglevgen's prepared stage "
              f"(`maglev_closed_loop_prepared`, both sides of every if_else; counted) | "
              f"{stage['maglev_closed_loop_prepared']['total']} |",
              f"| operations per RK4 stage, the graph CasADi's codegen and JAX run "
              f"(`maglev_closed_loop`: p, the gains and T at every stage; counted) | "
              f"{stage['maglev_closed_loop']['total']} |",
              f"| operations per run ({res['steps']} steps x (4 prepared stages + the step's "
              f"{res['operations_per_rk4_step_outside_the_stages']})) | "
              f"{res['operations_per_run'] / 1e6:.1f} M |"]
    for k, v in peaks.items():
        lines.append(f"| peak add/multiply rate, one core, {k} ({v['lanes']} "
                     f"double{'s' if v['lanes'] > 1 else ''} per instruction, no FMA; "
                     f"measured, bench/c/flop_peak.c) | {v['gflops']:.2f} Gflop/s |")
    lines += [f"| the scalar limit per run (operations per run / scalar peak) | "
              f"{limit['scalar']:.2f} ms |",
              f"| the SIMD limit per run (operations per run / {widest} peak) | "
              f"{limit['simd']:.2f} ms |"]
    lines += ["", "Every row's *x the scalar limit* is its time per run over the scalar limit of "
              "maglevgen's prepared stage's count (the fewest operations the job is known to "
              f"need); CasADi's and JAX's graph has {graph_ratio:.2f}x as many per stage "
              "before their compilers' own eliminations."]
    gcc = ", ".join(f"{comp[k]['wall']:.1f} s" for k in FLAGS if k in comp)
    jax_compile = (f"; JAX's jit compile (once, before the rounds: XLA on the whole "
                   f"vmap-of-scan) {comp[JAX]['wall']:.1f} s wall, {comp[JAX]['cpu']:.1f} s "
                   f"CPU" if JAX in comp else "")
    lines += ["", f"Compile times, outside the timed rounds: gcc on CasADi's C {gcc}"
              f"{jax_compile}.", "",
              "CasADi's C is CasADi's as it writes it (no maglevgen pass): the same SX "
              "right-hand side (`maglev_closed_loop`, T an input) under an MX RK4 step, "
              "`mapaccum` over the steps (the gains, T and p passed through as accumulators), "
              "`map` over the runs, through `casadi.external`. JAX runs the same SX graph "
              "translated instruction by instruction into jax.numpy (bench/jax_peer.py: one "
              "jnp operation per CasADi operation, if_else as jnp.where), the same RK4 "
              "expressions (the four stages one copy of the graph under a `lax.scan` over "
              "their offsets: one copy for XLA to compile), `lax.scan` over the steps and "
              "`vmap` over the runs under one `jit`, "
              "float64, XLA on one thread; its exp, sin and cos are XLA's, not glibc's. "
              "maglevgen's C runs the prepared right-hand side (the constants of p, the gains "
              "and T computed once per run) with the guarded branches. maglevgen's lanes "
              "(templates/maglev_lanes.c) fly the tick-held loop only; this continuous loop "
              "runs one maglev_simulate per run there too, so the lanes' row is the section "
              "*Monte Carlo in SIMD lanes* below, on the firmware loop.", END]
    return lines


def run_section(rounds: int, samples: int = 8) -> dict:
    """Measure, write the JSON and the section of BENCHMARKS.md (what `make bench` runs as
    its stage ``casadi_peer``); the results."""
    res = measure(rounds, samples)
    RESULTS.write_text(json.dumps(res, indent=1) + "\n")
    replace_section(section(res), BEGIN, END)
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rounds", type=int, default=9)
    ap.add_argument("--samples", type=int, default=8)
    args = ap.parse_args(argv)
    print("\n".join(section(run_section(args.rounds, args.samples))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
