"""Issue 49 (sensing and estimation): the default carriage's sensors, estimator and the
output-feedback loop, measured.

- observability at the tick (maglevgen.control.estimation.observability) across [v_min, v_max]:
  rank and smallest singular value of the noise-scaled discrete observability matrix;
- the steady-state Kalman filter: each state's estimation error (1 sigma after the update);
- the whole loop (plant at the tick with its delay, sensors, Kalman filter, the embedded
  controller's gains on the estimate; no actuator lag): smallest damping ratio and slowest
  decay, and the filter's own modes;
- 20 s noisy holds (maglevgen.analyses.output_feedback.noisy_hold) at v_min, 20 m/s and v_max
  with the default sensor noise and five times it.

    python bench/output_feedback.py [--section]

Writes bench/output_feedback_results.json and its section of BENCHMARKS.md. Not timings: the
numbers are the loop's, the same on any machine.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
from common import ROOT, log, replace_section

from maglevgen.analyses.envelope import speed_range
from maglevgen.analyses.output_feedback import noisy_hold
from maglevgen.analyses.simulate import Weights, operating_point
from maglevgen.carriage import DerivedCarriage
from maglevgen.control import estimation as pl
from maglevgen.control.operating import stability
from maglevgen.control.sampled import Tick, loop_gain, speed_gain
from maglevgen.params import load_params
from maglevgen.runtime.library import simulation_library

RESULTS = ROOT / "bench" / "output_feedback_results.json"
BEGIN = "<!-- output_feedback: begin -->"
END = "<!-- output_feedback: end -->"
N_SPEEDS = 17
T_HOLD = 20.0


def measure() -> dict:
    c = DerivedCarriage(load_params())
    lib = simulation_library(c.structure)
    params = c.params
    v_min, v_max = speed_range(c)
    w = Weights.of(params)
    ops = [operating_point(lib, c.p, v, params.track.min_gap, w)
           for v in np.linspace(v_min, v_max, N_SPEEDS)]
    points = pl.estimator_points(lib, c.p, params, ops)
    h = Tick.of(params).period
    rows = []
    for op, e in zip(ops, points, strict=True):
        k_v = speed_gain(params.vehicle.mass, op.trim_drag_slope,
                         params.control.spec.speed_bandwidth)
        K_u = pl.estimate_gain(e.model, op,
                               loop_gain(op, params.envelope.embedded_controller, k_v))
        s = pl.continuous_equivalent(pl.whole_loop(e.model, e.design, K_u), h)
        n = e.model.Phi.shape[0]
        f = pl.continuous_equivalent(e.model.Phi @ (np.eye(n) - e.design.M @ e.model.C), h)
        loop_re, loop_zeta = stability(s[np.isfinite(s.real)])
        filt_re, filt_zeta = stability(f[np.isfinite(f.real)])
        rows.append({"speed": op.speed, "rank": e.observability.rank,
                     "n": e.observability.n, "smallest_singular_value": e.observability.smallest,
                     "error_std": e.error_std, "loop_decay": -loop_re, "loop_damping": loop_zeta,
                     "filter_decay": -filt_re, "filter_damping": filt_zeta})
    holds = []
    for v in (v_min, 20.0, v_max):
        op = operating_point(lib, c.p, v, params.track.min_gap, w)
        for scale in (1.0, 5.0):
            log(f"noisy hold at {v:g} m/s, noise x {scale:g}")
            r = noisy_hold(lib, c.p, params, op, t_end=T_HOLD, seed=1, noise_scale=scale)
            holds.append({"speed": v, "noise_scale": scale, "lines": r.lines(),
                          "force_rms_max": float(np.max(r.force_rms)),
                          "force_peak_max": float(np.max(r.force_peak)),
                          "at_budget_max": float(np.max(r.at_budget)),
                          "min_gap": r.min_gap, "budget": r.budget})
    return {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "v_min": v_min,
            "v_max": v_max, "failures": pl.estimation_failures(points, params),
            "speeds": rows, "holds": holds}


def section(r: dict) -> list[str]:
    sp = r["speeds"]
    err = {k: max(row["error_std"][k] for row in sp) for k in sp[0]["error_std"]}
    out = [BEGIN, f"## Issue 49 (sensing and estimation): the default sensors, the Kalman filter "
           f"and the output-feedback loop (bench/output_feedback.py, {r['date']}; raw: "
           "bench/output_feedback_results.json)", "",
           "Default carriage and [sensors] (8 gap sensors, an IMU, the track sensor), 1 kHz tick "
           "with one tick of delay, the embedded `spec` gains on the Kalman filter's updated "
           f"estimate, {N_SPEEDS} speeds over [{r['v_min']:.4g}, {r['v_max']:.4g}] m/s. No "
           "actuator lag and no anti-alias filter lag in these loops (issue 49's other half).",
           "", "| measure | across the envelope |", "| --- | --- |",
           f"| observability rank (of {sp[0]['n']}) | "
           f"{min(row['rank'] for row in sp)} to {max(row['rank'] for row in sp)} |",
           "| smallest singular value of the noise-scaled observability matrix | "
           f"{min(row['smallest_singular_value'] for row in sp):.4g} to "
           f"{max(row['smallest_singular_value'] for row in sp):.4g} |",
           "| whole loop (plant, sensors, filter, controller, delay): smallest damping ratio | "
           f"{min(row['loop_damping'] for row in sp):.4f} |",
           "| whole loop: slowest decay | "
           f"{min(row['loop_decay'] for row in sp):.4g} 1/s |",
           "| the filter's modes: smallest damping ratio, slowest decay | "
           f"{min(row['filter_damping'] for row in sp):.4f}, "
           f"{min(row['filter_decay'] for row in sp):.4g} 1/s |",
           "| estimation error (1 sigma, worst speed) | " + ", ".join(
               f"{k} {v:.3g}" for k, v in err.items()) + " (m, rad, m/s, rad/s) |",
           "| estimation verdict (1 sigma within 0.1 x control.spec.max_deviation) | "
           + ("; ".join(r["failures"]) or "met on every axis") + " |", "",
           f"Noisy holds, {T_HOLD:g} s each (seed 1), from trim:", "", "```"]
    for hold in r["holds"]:
        out += hold["lines"]
    out += ["```", "",
            "The track position's and forward speed's errors exceed the filter's prediction "
            "3-7x at 20 and 40 m/s, not at v_min: there the tick advances a whole number of "
            "the encoder's 1 mm steps (20 and 40), so its quantization error hardly changes "
            "from tick to tick, a bias rather than the white noise of step^2/12 the filter "
            "assumes (a 5 s hold at 20.3 m/s, seed 0: x 3.5e-5 m, u 6.6e-4 m/s, both below "
            "the prediction). The levitation axes' errors stay within the prediction (the "
            "prediction includes the process noise these runs leave out). With noise x 5 "
            "no tick is at the budget and the RMS force stays under 10 % of it.", END]
    return out


def main() -> None:
    if "--section" in sys.argv:  # the section again from the recorded results
        replace_section(section(json.loads(Path(RESULTS).read_text())), BEGIN, END)
        return
    r = measure()
    Path(RESULTS).write_text(json.dumps(r, indent=1) + "\n")
    replace_section(section(r), BEGIN, END)


if __name__ == "__main__":
    main()
