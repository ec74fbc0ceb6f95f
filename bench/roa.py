"""Region of attraction (issue 36): states per second of the batched C against Python.

    python bench/roa.py

In one run on the default carriage at operation.speed with the spec controller: V and dV/dt
at the same random states of {V <= c} by `maglev_lyapunov_batch` (one call per 8192 states,
one thread) and by a Python loop over the lambdified SymPy model (derive.numeric, the closed
loop assembled in numpy per state), median of 3 rounds each; then the build's share: the
region at BUILD_SAMPLING over BUILD_SPEEDS speeds (with its boundary runs) and the command's
at COMMAND_SAMPLING, wall time. Writes bench/roa_results.json and the section of
BENCHMARKS.md.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import BENCH, ROOT

from maglevgen.analyses import roa
from maglevgen.analyses.sim_loop import flown_loop
from maglevgen.carriage import DerivedCarriage
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.operating import AXIS_STATES, REDUCED_INDEX
from maglevgen.params import load_params
from maglevgen.runtime.library import simulation_library

RESULTS = BENCH / "roa_results.json"
BEGIN, END = "<!-- roa benchmark: bench/roa.py -->", "<!-- end of roa benchmark -->"
N_C, N_PY = 200_000, 2_000


def _median(fn, rounds: int = 3) -> float:
    times = []
    for _ in range(rounds):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def main() -> None:
    carriage = DerivedCarriage(load_params())
    lib = simulation_library(carriage.structure)
    plant = Plant(carriage, lib)
    (op,) = plant.points([carriage.params.operation.speed])
    P = roa.lyapunov_matrix(op, "spec")
    rng = np.random.default_rng(0)
    L = np.linalg.cholesky(P)
    z = rng.standard_normal((N_C, P.shape[0]))
    z /= np.linalg.norm(z, axis=1, keepdims=True)
    dx = 0.1 * np.linalg.solve(L.T, z.T).T
    ev = roa.Evaluator(lib, carriage.p, op, "spec", P, roa.COMMAND_SAMPLING)
    t_c = _median(lambda: ev(dx))

    f = carriage.functions
    K_pos, K_rate = op.gains("spec")
    idx, red = list(AXIS_STATES), list(REDUCED_INDEX)
    u = np.zeros(op.allocation.shape[0] + 1)
    u[0] = op.f_prop

    def python_loop() -> None:
        for k in range(N_PY):
            x = op.x_trim.copy()
            x[red] += dx[k]
            u[1:] = op.allocation @ (-(K_pos @ (x[idx] - op.a_trim)
                                       + K_rate @ f.kin(x).ravel()[idx]))
            xd = f.xdot(x, u, carriage.p).ravel()
            _ = (dx[k] @ P @ dx[k], 2 * dx[k] @ P @ xd[red])

    t_py = _median(python_loop)
    t0 = time.perf_counter()
    # the build's region and the command's, on the loop the embedded controller flies (its
    # boundary runs on the sensors where the file has [sensors]), as `build` and `roa` run them
    loop = flown_loop(plant)
    roa.study(plant, ["spec"], roa.BUILD_SPEEDS, roa.BUILD_SAMPLING, loop)
    t_build = time.perf_counter() - t0
    t0 = time.perf_counter()
    regions = roa.study(plant, ["spec"], roa.DEFAULT_SPEEDS, roa.COMMAND_SAMPLING, loop)
    t_cmd = time.perf_counter() - t0
    res = {"states_c": N_C, "seconds_c": t_c, "states_per_s_c": N_C / t_c,
           "states_python": N_PY, "seconds_python": t_py, "states_per_s_python": N_PY / t_py,
           "speedup": (N_C / t_c) / (N_PY / t_py),
           "build_region_s": t_build, "build_speeds": roa.BUILD_SPEEDS,
           "command_region_s": t_cmd, "command_speeds": roa.DEFAULT_SPEEDS,
           "command_states": sum(r.states for r in regions[0].regions), "loop": loop.value,
           "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
    RESULTS.write_text(json.dumps(res, indent=1) + "\n")
    text = (f"{BEGIN}\n## Region of attraction (issue 36; bench/roa.py, {res['date']}; raw: "
            "bench/roa_results.json)\n\n"
            "V and dV/dt of the spec controller's nonlinear closed loop at random states, one "
            "thread, median of 3 rounds, in one run:\n\n"
            "| evaluator | states | s | states/s |\n|---|---|---|---|\n"
            f"| maglev_lyapunov_batch (C, batches of 8192) | {N_C} | {t_c:.3f} | "
            f"{res['states_per_s_c']:.3g} |\n"
            f"| Python loop over the lambdified SymPy model | {N_PY} | {t_py:.3f} | "
            f"{res['states_per_s_python']:.3g} |\n\n"
            f"The C evaluates {res['speedup']:.0f} times as many states per second. The "
            f"build's region ({roa.BUILD_SPEEDS} speeds at BUILD_SAMPLING, with its boundary "
            f"runs on the `{loop.value}` loop): {t_build:.2f} s; the command's "
            f"({roa.DEFAULT_SPEEDS} speeds at "
            f"COMMAND_SAMPLING, {res['command_states']} states): {t_cmd:.1f} s.\n{END}\n")
    bm = ROOT / "BENCHMARKS.md"
    old = bm.read_text()
    if BEGIN in old:
        old = old[:old.index(BEGIN)] + old[old.index(END) + len(END) + 1:]
    bm.write_text(old.rstrip("\n") + "\n\n" + text)
    print(text)


if __name__ == "__main__":
    main()
