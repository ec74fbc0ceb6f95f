"""The envelope and the launch run, timed against the same work done the way an engineer would
without the compiled library: SciPy's trim and python-control's LQR on the lambdified SymPy
model, and scipy's solve_ivp for the launch. Medians of repeats, ratios taken in one run.

    python bench/envelope.py [--repeats N]   (also part of `make bench`)
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import BENCH, log, summary

from maglevgen.analyses.envelope import compute_envelope
from maglevgen.analyses.simulate import initial_state, launch
from maglevgen.carriage import DerivedCarriage
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.schedule import Schedule
from maglevgen.params import load_params
from maglevgen.runtime.library import simulation_library

N_SPEEDS = 50


def _python_envelope(carriage: DerivedCarriage, speeds: np.ndarray) -> dict[str, np.ndarray]:
    """The same eigenvalue sweep on the lambdified model: SciPy trim, SymPy Jacobians,
    python-control LQR per axis and coupled."""
    import control

    from maglevgen.control.symbolic_reference import effectiveness

    T = np.linalg.pinv(effectiveness(carriage))
    red = [1, 2, 3, 4, 5, 7, 8, 9, 10, 11]
    ax = [1, 2, 3, 4, 5]
    (q1, q2), r = carriage.params.control.state_weights, carriage.params.control.input_weight
    out = {n: np.zeros(len(speeds)) for n in ("none", "damping", "lqr", "coupled")}
    m = carriage.generalized_mass()
    for j, v in enumerate(speeds):
        carriage._trims.clear()
        trim = carriage.trim(float(v))
        A, B = carriage.linearize(trim)
        Ar, Bg = A[np.ix_(red, red)], B[red, 1:] @ T
        S, C = np.eye(5, 10), A[np.ix_(ax, red)]
        k = np.diag(carriage.total_stiffness(trim))
        Kp, Kr = np.zeros(5), np.zeros(5)
        for i in range(5):
            K, _, _ = control.lqr([[0, 1], [-k[i] / m[i], 0]], [[0], [1 / m[i]]],
                                  np.diag([q1, q2]), [[r]])
            Kp[i], Kr[i] = np.asarray(K).ravel()
        c = np.where(k > 0, np.sqrt(np.maximum(k, 0) * m), 0.0)
        Kc, _, _ = control.lqr(Ar, Bg, q1 * S.T @ S + q2 * C.T @ C, r * np.eye(5))
        for name, K in (("none", np.zeros((5, 10))), ("damping", np.diag(c) @ C),
                        ("lqr", np.diag(Kp) @ S + np.diag(Kr) @ C), ("coupled", np.asarray(Kc))):
            out[name][j] = np.max(np.linalg.eigvals(Ar - Bg @ K).real)
    return out


def _python_launch(carriage: DerivedCarriage, sched: Schedule, x0: np.ndarray, f_extra: float,
                   v_end: float) -> float:
    """The launch by solve_ivp (RK45, rtol 1e-6) on the lambdified model; its end time."""
    from scipy.integrate import solve_ivp

    from maglevgen.control.symbolic_reference import effectiveness

    fns = carriage.functions
    T = np.linalg.pinv(effectiveness(carriage))
    n_u = carriage.model.u.shape[0]
    spline = sched.spline
    ax = [1, 2, 3, 4, 5]

    def rhs(_t: float, x: np.ndarray) -> np.ndarray:
        v = np.clip(np.linalg.norm(x[6:9]), sched.speeds[0], sched.speeds[-1])
        f_drag, a_ref, K_pos, K_rate = Schedule.unpack(spline(v))
        rates = fns.xdot(x, np.zeros(n_u), carriage.p).ravel()[ax]
        u = np.concatenate([[f_drag + f_extra], T @ -(K_pos @ (x[ax] - a_ref) + K_rate @ rates)])
        return fns.xdot(x, u, carriage.p).ravel()

    def done(_t: float, x: np.ndarray) -> float:
        return np.linalg.norm(x[6:9]) - v_end

    done.terminal = True
    sol = solve_ivp(rhs, (0.0, 60.0), x0, rtol=1e-6, atol=1e-9, events=done)
    return float(sol.t[-1])


def run(repeats: int = 5) -> dict:
    carriage = DerivedCarriage(load_params())
    lib = simulation_library(carriage.structure)
    compute_envelope(Plant(carriage, lib), N_SPEEDS)  # warm: library loaded, functions resolved
    log(f"envelope: {N_SPEEDS} speeds x 4 controllers, compiled library")
    c_times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        env = compute_envelope(Plant(carriage, lib), N_SPEEDS)
        c_times.append(time.perf_counter() - t0)
    carriage.functions  # noqa: B018  (lambdify once, outside the timing)
    log("envelope: the same with SciPy/python-control on the lambdified model")
    py_times, py = [], None
    for _ in range(max(1, repeats // 2)):
        t0 = time.perf_counter()
        py = _python_envelope(carriage, env.speeds)
        py_times.append(time.perf_counter() - t0)
    agree = max(float(np.max(np.abs(py[n] - env.controllers[n].max_real))) for n in py)

    v_lo, v_hi = Plant(carriage, lib).speed_range
    points = Plant(carriage, lib).points(np.linspace(v_lo, v_hi,
                                                        carriage.params.envelope.schedule_nodes))
    sched = Schedule.from_points(points, "coupled")
    f_extra = carriage.params.vehicle.mass * carriage.params.envelope.launch_acceleration
    log(f"launch {v_lo:.3g} -> {v_hi:.3g} m/s at 1 kHz in C")
    l_times, traj = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        traj = launch(lib, carriage.p, sched, points[0], v_hi, f_extra, 1e-3,
                      carriage.params.track.min_gap, max_time=20.0)
        l_times.append(time.perf_counter() - t0)
    log("launch by solve_ivp (RK45, rtol 1e-6) on the lambdified model")
    t0 = time.perf_counter()
    t_py = _python_launch(carriage, sched, initial_state(points[0], traj.disturbance), f_extra,
                          v_hi)
    py_launch = time.perf_counter() - t0
    return {
        "speeds": N_SPEEDS, "controllers": 4,
        "envelope_c_s": summary(c_times), "envelope_python_s": summary(py_times),
        "envelope_ratio": summary(py_times)["median"] / summary(c_times)["median"],
        "largest_real_part_difference": agree,
        "launch_c_s": summary(l_times), "launch_steps": int(traj.t.size - 1),
        "launch_duration_s": float(traj.t[-1]), "launch_python_s": py_launch,
        "launch_python_duration_s": t_py,
        "launch_ratio": py_launch / summary(l_times)["median"],
    }


def markdown(r: dict) -> list[str]:
    e, lc = r["envelope_c_s"], r["launch_c_s"]
    return [
        "## Envelope and launch", "",
        f"`compute_envelope` for {r['speeds']} speeds x {r['controllers']} controllers (trim, "
        "Jacobians and gains in the generated C; coupled LQR by SciPy's CARE): median "
        f"{e['median'] * 1e3:.0f} ms [{e['q1'] * 1e3:.0f}, {e['q3'] * 1e3:.0f}]; the same sweep "
        "with SciPy's trim, the SymPy Jacobians and python-control's LQR on the lambdified model "
        f"{r['envelope_python_s']['median']:.2f} s: {r['envelope_ratio']:.0f}x "
        f"(largest real parts agree to {r['largest_real_part_difference']:.1e} 1/s).", "",
        f"Launch run v_min -> v_max ({r['launch_duration_s']:.2f} s, {r['launch_steps']} RK4 "
        f"steps at 1 kHz, gains scheduled at every step in C): median {lc['median'] * 1e3:.1f} "
        f"ms [{lc['q1'] * 1e3:.1f}, {lc['q3'] * 1e3:.1f}]; solve_ivp (RK45, rtol 1e-6) on the "
        f"lambdified model with the same schedule: {r['launch_python_s']:.1f} s "
        f"({r['launch_ratio']:.0f}x).", "",
    ]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--json", type=Path, default=BENCH / "envelope_results.json")
    args = ap.parse_args(argv)
    r = run(args.repeats)
    args.json.write_text(json.dumps(r, indent=1) + "\n")
    print("\n".join(markdown(r)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
