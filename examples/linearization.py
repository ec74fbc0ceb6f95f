"""Inspect the linearisation with python-control: poles, a Bode plot of the heave axis and the
step response of the heave loop under the per-axis LQR.

    python examples/linearization.py [OUT]

Writes OUT/bode_heave.png and OUT/step_heave.png (matplotlib's Agg backend: no display).
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import control
import matplotlib.pyplot as plt
import numpy as np

import maglevgen

out = Path(sys.argv[1] if len(sys.argv) > 1 else "example_output/linearization")
out.mkdir(parents=True, exist_ok=True)
carriage = maglevgen.load()
speed = 20.0

# the whole carriage: 12 states, F_prop and the array forces as inputs
plant = carriage.linearize(speed)
print(plant.state_labels, plant.input_labels, sep="\n")
print("open-loop poles [1/s]:", np.array2string(np.sort_complex(plant.poles()), precision=3))

# the reduced plant (generalized forces in) with the coupled LQR closed around it
reduced = carriage.linearize(speed, model="reduced")
coupled = carriage.gains(speed, controller="coupled")
loop = control.feedback(reduced, coupled.K)  # u_gen = -K x
print("coupled LQR closed-loop poles [1/s]:",
      np.array2string(np.sort_complex(loop.poles()), precision=3))

# one axis: heave, m z'' + k z = u_z (eqs 24-27), and its per-axis LQR
heave = carriage.axis_plant("vertical", speed)
(q1, q2), r = carriage.params.control.state_weights, carriage.params.control.input_weight
K, _, _ = control.lqr(heave, np.diag([q1, q2]), r)
print(f"heave: natural frequency {np.sqrt(-heave.A[1, 0]):.2f} rad/s, LQR K = {K.ravel()}")

fig = plt.figure(figsize=(6, 5))
control.bode_plot(heave, omega=np.logspace(-1, 3, 400), dB=True, title="heave: u_z to z")
fig.savefig(out / "bode_heave.png", dpi=90)
plt.close("all")

# the heave loop closed by its LQR; a 1 N reference step (as a force added to -K x)
closed = control.ss(heave.A - heave.B @ K, heave.B, heave.C, heave.D,
                    states=heave.state_labels, inputs=["u_ref"], outputs=["z"])
resp = control.step_response(closed, T=np.linspace(0, 10, 4000))
fig, ax = plt.subplots(figsize=(6, 3.5))
ax.plot(resp.time, np.squeeze(resp.outputs) * 1e3)
ax.set_xlabel("t [s]")
ax.set_ylabel("z [mm]")
ax.set_title("heave step response, per-axis LQR, 1 N step")
ax.grid(True, lw=0.3)
fig.tight_layout()
fig.savefig(out / "step_heave.png", dpi=90)
plt.close(fig)
print(f"wrote {out / 'bode_heave.png'} and {out / 'step_heave.png'}")
