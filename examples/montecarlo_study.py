"""A Monte-Carlo robustness study: how often does each controller hit the track?

    python examples/montecarlo_study.py [OUT]

Draws carriages from the parameter file's [tolerances] (mass, CG, remanence, circuit
resistance, speed, initial disturbance), runs the per-axis and the coupled LQR on each in the
compiled C on every core, and prints each controller's contact probability with its 95 %
interval. Writes OUT/montecarlo.md, OUT/montecarlo.json, OUT/samples.parquet and the plots.
"""

from __future__ import annotations

import sys
from pathlib import Path

import maglevgen

out = Path(sys.argv[1] if len(sys.argv) > 1 else "example_output/montecarlo")
carriage = maglevgen.load()
summary = {}
for controller in ("lqr", "coupled"):
    s = carriage.montecarlo(samples=40, seed=1, controller=controller, t_end=2.0,
                            out=out / controller)
    summary[controller] = s["controllers"][controller]

for controller, agg in summary.items():
    lo, hi = agg["contact_ci95"]
    print(f"{controller:8s} contact probability {agg['contact_probability']:.3f} "
          f"(95 % CI [{lo:.3f}, {hi:.3f}])")
