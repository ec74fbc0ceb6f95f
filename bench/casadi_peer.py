"""The closed loop as CasADi's own code generation runs it (issue 53): a peer in `make bench`.

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
  -fno-semantic-interposition, evaluated through `casadi.external`.

Rounds alternate the contenders; CPU time (time.process_time) per round; runs per CPU-second;
each contender's final states against the project's (max relative difference). Writes
bench/casadi_peer_results.json and its section of BENCHMARKS.md. JAX (jit + vmap + scan) is
left out: see that section.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import casadi as ca
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import BENCH, log, paired_ratios, replace_section, run, summary

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
    carriage = DerivedCarriage(load_params())
    lib = simulation_library(carriage.structure)
    op, batch_run, theta = inputs(carriage, lib)
    n_steps = round(T_END / DT)
    closed_loop = next(f for f in build_functions(carriage.model).functions
                       if f.name() == "maglev_closed_loop")
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
    for label, flags in FLAGS.items():
        lib_path = work / f"peer{len(contenders)}.so"
        log(f"compiling: {label}")
        t0 = time.perf_counter()
        run(["gcc", *flags, "-o", lib_path, source, "-lm"])
        log(f"  {time.perf_counter() - t0:.0f} s")
        ext = ca.external("sim", str(lib_path))
        contenders[label] = (lambda ext=ext: np.array(ext(x0s, thetas)))
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
    seconds: dict[str, list[float]] = {k: [] for k in contenders}
    log(f"{rounds} rounds of {samples} runs per contender")
    for r in range(rounds):
        order = list(contenders) if r % 2 == 0 else list(contenders)[::-1]
        for k in order:
            t0 = time.process_time()
            contenders[k]()
            seconds[k].append((time.process_time() - t0) / samples)
    shutil.rmtree(work, ignore_errors=True)
    return {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "rounds": rounds, "samples": samples, "steps": n_steps,
            "ms_per_run": {k: summary([1e3 * t for t in v]) for k, v in seconds.items()},
            "project_speedup": {k: paired_ratios(v, seconds[PROJECT])
                                for k, v in seconds.items() if k != PROJECT},
            "final_state_max_relative_difference": agreement}


def section(res: dict) -> list[str]:
    lines = [BEGIN, f"## Peers: the closed loop in CasADi's own codegen (issue 53; "
             f"bench/casadi_peer.py, {res['date']}; raw: bench/casadi_peer_results.json)", "",
             f"The default carriage held at operation.speed by the embedded controller, the "
             f"continuous closed loop, {res['steps']} RK4 steps at 1 kHz, {res['samples']} "
             f"runs per round, one thread, {res['rounds']} alternating rounds (CPU time):", "",
             "| contender | ms per run (median) | runs per CPU-second | maglevgen's C faster by "
             "(per round, median) | final states: max relative difference to maglevgen's C |",
             "| --- | --- | --- | --- | --- |"]
    for k, v in res["ms_per_run"].items():
        ratio = res["project_speedup"].get(k)
        faster = "" if ratio is None else f"{ratio['median']:.2f}x"
        lines.append(f"| {k} | {v['median']:.2f} | {1e3 / v['median']:.1f} | {faster} | "
                     f"{res['final_state_max_relative_difference'][k]:.1e} |")
    lines += ["", "CasADi's C is CasADi's as it writes it (no maglevgen pass): the same SX "
              "right-hand side (`maglev_closed_loop`, T an input) under an MX RK4 step, "
              "`mapaccum` over the steps (the gains, T and p passed through as accumulators), "
              "`map` over the runs, through `casadi.external`. maglevgen's C runs the prepared "
              "right-hand side (the constants of p, the gains and T computed once per run) "
              "with the guarded branches. JAX (jit + vmap + scan) is not in the run: not among "
              "the project's dependencies, and the 4-minute compile issue 53 measured is more "
              "than `make bench` should pay.", END]
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
