"""Section part: the two actuator models (control.actuators) side by side, in the damping and
allocation section: each one's E and T from its generated C, and the peak array control
forces of the same closed-loop runs (the hold of `maglevgen simulate`) under each."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import scipy.linalg
import sympy as sp

from maglevgen.analyses.simulate import metrics, run_scenarios
from maglevgen.carriage import DerivedCarriage
from maglevgen.control.carriage_plant import Plant
from maglevgen.controllers import REGISTRY
from maglevgen.derive.structure import input_names_of
from maglevgen.params import ACTUATOR_MODELS, LoadedParams
from maglevgen.report.display import ltx, matrix_tex
from maglevgen.report.format import fnum, tex_escape

__all__ = ["RUN_DT", "RUN_T_END", "actuator_comparison_section", "with_actuators"]

RUN_T_END, RUN_DT = 10.0, 1e-3


def run_controllers() -> tuple[str, ...]:
    """The runs compared: `maglevgen simulate`'s hold (its default length and step) per design
    of the paper that applies forces (read from the registry when the section is made)."""
    return tuple(n for n, c in REGISTRY.items() if c.paper and c.tick_function)

ACTUATOR_TEXT = {
    "paper": "eqs 22--23: a body-$z$ force on every array and an independent body-$y$ force on "
             "each array whose normal has a $y$ part (the lower 45-degree arrays)",
    "normal": "one force along each array's normal, all a real array can push with",
}


def with_actuators(carriage, actuators: str):
    """The same carriage with another actuator model (its parameters otherwise unchanged)."""
    if carriage.params.control.actuators == actuators:
        return carriage
    params = carriage.params.model_copy(update={
        "control": carriage.params.control.model_copy(update={"actuators": actuators})})
    loaded = carriage.loaded
    return DerivedCarriage(LoadedParams(params, loaded.source, loaded.sha256,
                                 (*loaded.overrides, f'control.actuators="{actuators}"')))


def actuator_comparison_section(carriage, progress: Callable[[str], None],
                         hold_runs: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """E, T, rank and peak array forces of every actuator model, from their generated C;
    ``hold_runs``: the selected model's runs (RUN_T_END, RUN_DT) by controller, when the
    caller has made them already."""
    models = []
    peaks: dict[str, dict[str, dict]] = {}
    arrays: list[str] = list(carriage.params.arrays)
    for name in ACTUATOR_MODELS:
        progress(f"report: actuator model {name!r} (its library and runs)")
        c = with_actuators(carriage, name)
        plant = Plant(c, progress=progress)
        lib = plant.lib
        (E,) = lib.function("maglev_effectiveness")(c.p)
        (T,) = lib.function("maglev_allocation_matrix")(c.p)
        E, T = np.asarray(E), np.asarray(T)
        rank = int(np.linalg.matrix_rank(E))
        forces = input_names_of(c.structure)[1:]  # not c.model: no second symbolic model
        models.append({
            "name": name, "text": ACTUATOR_TEXT[name], "selected": c is carriage,
            "forces": [ltx(sp.Symbol(f"F_{{{f[2]}{tex_escape(f[3:])}}}")) for f in forces],
            "n_forces": len(forces), "rank": rank,
            "E": matrix_tex(E, lambda v: fnum(v, 4)), "T": matrix_tex(T, lambda v: fnum(v, 4)),
            "T_pinv_residual": float(np.max(np.abs(T - np.linalg.pinv(E)))),
            "lost": _lost_direction(E) if rank < E.shape[0] else None,
        })
        if c is carriage and hold_runs is not None:
            trajectories = tuple(hold_runs[k] for k in run_controllers())
        else:
            trajectories = run_scenarios(plant, run_controllers(), RUN_T_END,
                                         RUN_DT).trajectories
        for traj in trajectories:
            m = metrics(traj)
            peaks.setdefault(traj.controller, {})[name] = {
                "status": m["status"], "roll": fnum(m["axes"]["roll"]["peak_deviation"], 3),
                "forces": [fnum(m["peak_array_force"][a], 4) for a in arrays]}
    return {"models": models, "arrays": [tex_escape(a) for a in arrays],
            "runs": [{"controller": k, **v} for k, v in peaks.items()],
            "t_end": RUN_T_END, "dt": RUN_DT, "speed": carriage.params.operation.speed}


def _lost_direction(E: np.ndarray) -> dict[str, Any]:
    """The generalized-force combination w^T u no array force makes (w^T E = 0), scaled to a
    unit roll entry; where w involves only u_y and u_phi, the height z0 of the x axis about
    which the roll moment u_phi + z0 u_y is lost (every line of action meets that axis)."""
    w = scipy.linalg.null_space(E.T)[:, 0]
    k = int(np.argmax(np.abs(w)))
    w = w / (w[2] if abs(w[2]) > 1e-9 else w[k])
    only_y_roll = bool(np.all(np.abs(w[[1, 3, 4]]) < 1e-9))
    return {"w": matrix_tex(w[None, :], lambda v: fnum(v, 4)),
            "z0": float(w[0]) if only_y_roll and abs(w[2]) > 0 else None}
