"""The CPU a parameter-change build cannot avoid, whatever the report does: one fresh
process, each piece timed alone (process CPU seconds, nothing else running in it).

    python bench/build_floor.py    # $MAGLEVGEN_CACHE holds the cached library

Pieces, in the order a build meets them:
- ``startup_to_simulations``: interpreter, maglevgen's light imports (numpy, the parameter
  schema), loading the cached library and the three closed-loop simulations;
- ``matplotlib_import``: what the drawing process pays once;
- ``simulation_figures``: figs 3-8 (three PNGs);
- ``report_figures``: the two force figures (their curves computed beforehand, untimed);
- ``trajectories``: three CSVs and the .npz archive.

Their sum over the machine's cores is a lower bound on the build's wall time with the
outputs it has now (the report's own work, the symbolic imports and LaTeX not counted).
Prints one JSON object.
"""

from __future__ import annotations

import time

CPU0 = time.process_time()

import json  # noqa: E402
import os  # noqa: E402

from maglevgen.analyses.simulate import run_scenarios  # noqa: E402
from maglevgen.carriage import DerivedCarriage  # noqa: E402
from maglevgen.control.carriage_plant import Plant  # noqa: E402
from maglevgen.controllers import names as controller_names  # noqa: E402
from maglevgen.params import load_params  # noqa: E402
from maglevgen.runtime.library import cached_simulation_library  # noqa: E402


def _cpu(fn, *args):
    c0 = time.process_time()
    value = fn(*args)
    return time.process_time() - c0, value


def main() -> None:
    loaded = load_params(None, [])
    carriage = DerivedCarriage(loaded)
    lib = cached_simulation_library(carriage.structure)
    if lib is None:
        raise SystemExit("build_floor.py: no cached library: run a build first")
    run = run_scenarios(Plant(carriage, lib), controller_names(), 10.0, 1e-3, bar=None)
    out = {"startup_to_simulations": time.process_time() - CPU0}

    def import_matplotlib() -> None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot
        from matplotlib.figure import Figure  # noqa: F401

    out["matplotlib_import"], _ = _cpu(import_matplotlib)
    from maglevgen.analyses.sim_output import render_figures, render_trajectories

    out["simulation_figures"], _ = _cpu(render_figures, run.trajectories)
    from maglevgen.analyses.queries import trim_point
    from maglevgen.report import force_curves
    from maglevgen.report.figures import force_figures

    # as the build draws them (maglevgen.build._draw_report_figures): at the library's trim
    plant = Plant(carriage, lib)
    curves = force_curves(plant, trim_point(plant, None))
    out["report_figures"], _ = _cpu(force_figures, curves)
    out["trajectories"], _ = _cpu(render_trajectories, run.trajectories, run.input_names)
    out["total"] = sum(out.values())
    out["cores"] = len(os.sched_getaffinity(0))
    out["wall_lower_bound"] = out["total"] / out["cores"]
    print(json.dumps(out))


if __name__ == "__main__":
    main()
