"""Export the carriage as an FMI 2.0 co-simulation FMU and run it in FMPy.

    python examples/fmu_fmpy.py [OUT]

Writes OUT/maglev.fmu and OUT/fmu_heave.png: the heave and roll of the FMU's LQR loop from
its default start (trim plus the simulation's disturbance), beside `Carriage.simulate`.
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from fmpy import read_model_description, simulate_fmu

import maglevgen

out = Path(sys.argv[1] if len(sys.argv) > 1 else "example_output/fmu_fmpy")
carriage = maglevgen.load()
path = carriage.fmu(out, kind="cs", controller="lqr")
md = read_model_description(str(path))
print(f"{out / path.name}: FMI {md.fmiVersion}, {len(md.modelVariables)} variables")

fmu = simulate_fmu(str(path), fmi_type="CoSimulation", stop_time=2.0, output_interval=1e-3,
                   output=["z", "phi"])
# the same controller in maglev_simulate's firmware loop: the loop the FMU runs (its default
# --loop firmware: the tick law, the speed loop, the budget, the actuator lag in the plant)
run = carriage.simulate(controller="lqr", t_end=2.0)

fig, axes = plt.subplots(2, 1, figsize=(6, 5), sharex=True)
for ax, name, scale, unit in ((axes[0], "z", 1e3, "mm"), (axes[1], "phi", 1e3, "mrad")):
    i = carriage.state_names.index(name)
    ax.plot(fmu["time"], fmu[name] * scale, label="FMU in FMPy")
    ax.plot(run.t, run.x[:, i] * scale, "--", label="Carriage.simulate")
    ax.set_ylabel(f"{name} [{unit}]")
    ax.grid(True, lw=0.3)
axes[0].legend()
axes[1].set_xlabel("t [s]")
fig.tight_layout()
fig.savefig(out / "fmu_heave.png", dpi=90)
plt.close(fig)
gap = abs(fmu["z"][-1] - run.x[-1, carriage.state_names.index("z")])
print(f"z at 2 s: FMU and Carriage.simulate differ by {gap:.2e} m; wrote {out / 'fmu_heave.png'}")
