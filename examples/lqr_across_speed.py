"""Compare the paper's per-axis LQR with the coupled LQR across the speed envelope.

    python examples/lqr_across_speed.py [OUT]

At evenly spaced speeds in [v_min, v_max]: each controller's slowest closed-loop pole on the
coupled ten-state linearisation and its heave gains. Writes OUT/lqr_across_speed.csv and
OUT/lqr_across_speed.png.
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

import maglevgen

out = Path(sys.argv[1] if len(sys.argv) > 1 else "example_output/lqr_across_speed")
out.mkdir(parents=True, exist_ok=True)
carriage = maglevgen.load()
env = carriage.envelope(n_speeds=12)  # the speeds and the verdicts
controllers = ("lqr", "coupled")

rows = []
for v in env.speeds:
    row = [float(v)]
    for c in controllers:
        g = carriage.gains(float(v), controller=c)
        row += [float(np.max(g.poles.real)), float(g.K_pos[1, 1]), float(g.K_rate[1, 1])]
    rows.append(row)
table = np.array(rows)
header = "speed," + ",".join(f"{c}_slowest_pole,{c}_K_z,{c}_K_zdot" for c in controllers)
np.savetxt(out / "lqr_across_speed.csv", table, delimiter=",", header=header, comments="")

fig, ax = plt.subplots(figsize=(6, 3.5))
for i, c in enumerate(controllers):
    ax.plot(table[:, 0], table[:, 1 + 3 * i], marker=".", label=c)
ax.axhline(0.0, color="k", lw=0.8)
ax.set_xlabel("speed [m/s]")
ax.set_ylabel("largest real part [1/s]")
ax.set_title("slowest closed-loop pole, coupled linearisation")
ax.legend()
ax.grid(True, lw=0.3)
fig.tight_layout()
fig.savefig(out / "lqr_across_speed.png", dpi=90)
plt.close(fig)
for c in controllers:
    print(f"{c:>8}: {env.verdicts[c]}")
print(f"wrote {out / 'lqr_across_speed.csv'} and {out / 'lqr_across_speed.png'}")
