"""The speed loop with and without integral action on a carriage whose drag the feedforward
misses (issue 49: B0 -10 %, R +30 %): a 10 s hold at each speed, the nonlinear generated
dynamics (maglev_dynamics) of the perturbed carriage, the controller of the nominal one
(its continuous spec gains through maglev_coupled_control, its trim propulsion as the
feedforward, k_v of the envelope's loop; with the integral, the gains of
`plant.speed_loop_gains`), at the 1 kHz tick with one tick of delay and no actuator lag (the
C loop's today), RK4 at 0.1 ms in a Python loop over the compiled functions.

Not a timed benchmark: it records the speed error the issue's target names, since the C loop
(maglev_simulate) does not run the integral yet.
Usage: .venv/bin/python bench/experiments/speed_integral.py
"""

from __future__ import annotations

import numpy as np

from maglevgen.analyses.envelope import envelope_points, loop_setting, resolve_range
from maglevgen.carriage import DerivedCarriage
from maglevgen.control.operating import checked_trim
from maglevgen.control.plant import speed_loop_gains
from maglevgen.params import load_params
from maglevgen.runtime.library import simulation_library

CASES = (("B0 -10 %", "halbach.remanence=1.26"), ("R +30 %", "circuit.resistance=1.95e-3"))
T_END, TICK, STEPS = 10.0, 1e-3, 10  # [s], [s], RK4 steps per tick


def hold(lib, p_plant, p_nominal, op, k_v: float, k_i: float, x0: np.ndarray) -> np.ndarray:
    """The speed V(t) at each tick of a hold at op.speed (the plant's parameters p_plant, the
    controller's p_nominal)."""
    dyn, ctl = lib.function("maglev_dynamics"), lib.function("maglev_coupled_control")
    K_pos, K_rate = op.gains("spec")
    a_ref = op.a_trim
    T = op.allocation
    x, xi, v_ref, dt = x0.copy(), 0.0, op.speed, TICK / STEPS
    applied = None
    out = []
    for _ in range(round(T_END / TICK)):
        V = float(np.linalg.norm(x[6:9]))
        out.append(V)
        (u_gen,) = ctl(x, K_pos, K_rate, a_ref, p_nominal)
        u = np.r_[op.f_prop + k_v * (v_ref - V) + k_i * xi, T @ u_gen.ravel()]
        xi += TICK * (v_ref - V)
        u_now, applied = (applied if applied is not None else u), u  # one tick of delay
        def f(y: np.ndarray, u_now: np.ndarray = u_now) -> np.ndarray:
            return dyn(y, u_now, p_plant)[0].ravel()

        for _ in range(STEPS):
            k1 = f(x)
            k2 = f(x + dt / 2 * k1)
            k3 = f(x + dt / 2 * k2)
            k4 = f(x + dt * k3)
            x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return np.array(out)


if __name__ == "__main__":
    nominal = DerivedCarriage(load_params())
    lib = simulation_library(nominal.structure)
    p_nominal = nominal.p
    v_lo, v_hi = resolve_range(nominal, lib)
    nodes = envelope_points(nominal, lib, np.linspace(v_lo, v_hi, 64))
    setting = loop_setting(nominal, nodes)
    m, b = nominal.params.vehicle.mass, nominal.params.control.spec.speed_bandwidth
    k_v_pi, k_i = max(speed_loop_gains(m, op.trim_drag_slope, b) for op in nodes)
    print(f"P: k_v = {setting.speed_gain:.4g} N s/m; PI: k_v = {k_v_pi:.4g} N s/m, "
          f"k_i = {k_i:.4g} N/m")
    print("| carriage | speed [m/s] | loop | speed error after 10 s [%] | largest in the "
          "last second [%] |")
    print("| --- | --- | --- | --- | --- |")
    for label, override in CASES:
        plant = DerivedCarriage(load_params(overrides=[override]))
        for v in (v_lo, 20.0, v_hi):
            (op,) = envelope_points(nominal, lib, [v])
            x0, _, _ = checked_trim(lib, plant.p, v, plant.params.track.min_gap)
            for name, kv, ki in (("P", setting.speed_gain, 0.0), ("PI", k_v_pi, k_i)):
                V = hold(lib, plant.p, p_nominal, op, kv, ki, x0)
                err = 100 * (V - v) / v
                last = err[-round(1.0 / TICK):]
                print(f"| {label} | {v:.4g} | {name} | {err[-1]:+.4f} | "
                      f"{last[np.argmax(np.abs(last))]:+.4f} |", flush=True)
