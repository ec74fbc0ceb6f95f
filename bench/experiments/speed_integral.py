"""The speed loop with and without integral action on a carriage whose drag the feed-forward
misses (issue 49: B0 -10 %, R and L +-30 %): a 6 s hold at v_min, 20 m/s and v_max in the
host's firmware loop (maglev_simulate with the loop as built, a LoopSetting: the tick law of
the firmware, the `spec` design at the tick, one tick of delay, the 2 ms actuator lag, the
force budget), the plant the perturbed carriage, the controller the nominal one (its design,
reference and feed-forward: `simulate(..., controller_op=...)`, as `maglevgen montecarlo`
flies its samples), from the undisturbed perturbed trim. Three speed loops: P (k_v of
`sampled.speed_gain`, no integral: the loop before the integral), PI at the default
control.spec.speed_integral_ratio, and PI with r = 1 (a double pole at the bandwidth).

Not a timed benchmark: it records the speed errors the issue's target names.
Usage: .venv/bin/python bench/experiments/speed_integral.py
"""

from __future__ import annotations

import dataclasses

import numpy as np

from maglevgen.analyses.simulate import run_loop, simulate
from maglevgen.carriage import DerivedCarriage
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.plant import speed_loop_gains
from maglevgen.params import load_params
from maglevgen.runtime.library import simulation_library

CASES = (("B0 -10 %", "halbach.remanence=1.26"), ("R +30 %", "circuit.resistance=1.95e-3"),
         ("R -30 %", "circuit.resistance=1.05e-3"), ("L +30 %", "circuit.inductance=3.38e-6"),
         ("L -30 %", "circuit.inductance=1.82e-6"))
T_END, DT = 6.0, 1e-3  # [s]
STILL = {k: 0.0 for k in ("y", "z", "phi", "theta", "psi")}


if __name__ == "__main__":
    nominal = DerivedCarriage(load_params())
    lib = simulation_library(nominal.structure)
    tick, k_v, budget = run_loop(Plant(nominal, lib), "firmware")
    spec, m = nominal.params.control.spec, nominal.params.vehicle.mass
    b, r = spec.speed_bandwidth, spec.speed_integral_ratio
    v_lo, v_hi = Plant(nominal, lib).speed_range
    slope = min(op.trim_drag_slope for op in Plant(nominal, lib).points(
        np.linspace(v_lo, v_hi, nominal.params.envelope.schedule_nodes)))
    k_v1, k_i1 = speed_loop_gains(m, slope, b, 1.0)
    loops = (("P", dataclasses.replace(tick, speed_integral=0.0), k_v - m * b * r),
             (f"PI r={r:g}", tick, k_v),
             ("PI r=1", dataclasses.replace(tick, speed_integral=k_i1), k_v1))
    for name, t, kv in loops:
        print(f"{name}: k_v = {kv:.4g} N s/m, k_i = {t.speed_integral:.4g} N/m, "
              f"|k_i xi| <= {t.integral_limit:g} N")
    print("| carriage | speed [m/s] | loop | error at 6 s [%] | largest after 1 s [%] | "
          "largest after 3 s [%] | propulsion - feed-forward at 6 s [N] |")
    print("| --- | --- | --- | --- | --- | --- | --- |")
    for label, override in CASES:
        plant = DerivedCarriage(load_params(overrides=[override]))
        for v in (v_lo, 20.0, v_hi):
            (op_n,) = Plant(nominal, lib).points([v])
            (op_p,) = Plant(plant, lib).points([v])
            for name, t, kv in loops:
                tr = simulate(lib, plant.p, op_p, "spec", T_END, DT,
                              plant.params.track.min_gap, STILL, tick=t, speed_gain=kv,
                              force_budget=budget, controller_op=op_n)
                assert tr.c_status == 0
                err = 100 * (tr.speed - v) / v
                extra = tr.u[-1, 0] - op_n.f_prop  # the drag the feed-forward misses
                print(f"| {label} | {v:.4g} | {name} | {err[-1]:+.4f} | "
                      f"{np.max(np.abs(err[tr.t > 1])):.4f} | "
                      f"{np.max(np.abs(err[tr.t > 3])):.4f} | "
                      f"{extra:+.2f} |", flush=True)
