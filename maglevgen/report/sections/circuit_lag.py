"""Section: the track circuits' lag (derive/circuit_lag.py): the derivation, the magnetic
damping per axis against speed (the generated C's Jacobians) and the envelope with and
without it."""

from __future__ import annotations

from typing import Any

import numpy as np
import sympy as sp

from maglevgen.analyses.envelope import compute_envelope
from maglevgen.analyses.magnetic_damping import damping_across_speed
from maglevgen.control.carriage_plant import Plant
from maglevgen.controllers import controller as registered_controller
from maglevgen.controllers import title as controller_title
from maglevgen.derive import conventions as cv
from maglevgen.derive.circuit_lag import circuit_response
from maglevgen.report.display import eq
from maglevgen.report.figures import damping_figure

__all__ = ["CIRCUIT_LAG_FIGURE", "circuit_lag"]

CIRCUIT_LAG_FIGURE = "circuit_lag_damping.png"  # not fig_*: the force section takes those
_N_SPEEDS = 40
_UNITS = {"lateral": "N s/m", "vertical": "N s/m", "roll": "N m s/rad", "pitch": "N m s/rad",
          "yaw": "N m s/rad"}
MODELS = ("first-order", "quasi-static")


def _forms() -> dict[str, Any]:
    """The circuit equation's first-order solution in display symbols."""
    cr = circuit_response()
    R, L, w = sp.symbols("R L omega", positive=True)
    to = {cr.R: R, cr.L: L, cr.omega: w}
    v, k = sp.symbols("v k", positive=True)
    (v_c,) = sp.solve(sp.Eq(sp.numer(sp.together(cr.lift1)).xreplace(to).xreplace(
        {w: k * v}), 0), v)
    return {
        "H0": eq("H_0", cr.H0.xreplace(to)),
        "H1": eq("H_1", cr.H1.xreplace(to)),
        "tau_d": eq(r"\tau_d", cr.tau_lift.xreplace(to)),
        "tau_D": eq(r"\tau_D", cr.tau_drag.xreplace(to)),
        "v_c": eq("v_c", v_c),
    }


def _other(carriage):
    """The same carriage with the other circuit model."""
    now = carriage.params.model.circuit_dynamics
    return carriage.with_circuit_dynamics(MODELS[1 - MODELS.index(now)])


def circuit_lag(plant: Plant, env, gains: dict) -> tuple[dict[str, Any], bytes]:
    """The section's context and its figure (PNG bytes).

    ``env``: this carriage's envelope; the other circuit model's library and envelope are
    built here (one more derivation and compile when not cached); ``gains``:
    `summary.gains_report` (the controllers' rate gains at the design speed)."""
    carriage = plant.carriage
    other_plant = plant.with_model(circuit_dynamics=_other(carriage).params.model
                                   .circuit_dynamics)
    other = other_plant.carriage
    other_env = compute_envelope(other_plant, other_models=False)
    speeds = np.linspace(env.v_min, env.v_max, _N_SPEEDS)
    mine = damping_across_speed(plant, speeds)
    theirs = damping_across_speed(other_plant, speeds)
    now = carriage.params.model.circuit_dynamics
    curves = {now: mine, other.params.model.circuit_dynamics: theirs}
    V = carriage.params.operation.speed
    at_v = {n: damping_across_speed(pl, [V])[0]
            for n, pl in ((now, plant), (other.params.model.circuit_dynamics, other_plant))}
    # entries below 1e-12 of the largest are round-off of a structural zero (the quasi-static
    # lateral: eq 3 has no lateral rate term at zero roll)
    scale = max(float(np.max(np.abs(c))) for c in at_v.values())
    at_v = {n: np.where(np.abs(c) < 1e-12 * scale, 0.0, c) for n, c in at_v.items()}
    axes = []
    for i, axis in enumerate(cv.AXES):
        g = gains["axes"][axis]
        axes.append({"axis": axis, "unit": _UNITS[axis],
                     "first_order": float(at_v["first-order"][i]),
                     "quasi_static": float(at_v["quasi-static"][i]),
                     "lqr_rate": float(g["K_closed_form"][1]),
                     "damping": float(g["damping_gain"])})
    envs = {now: env, other.params.model.circuit_dynamics: other_env}
    rows = [{"title": controller_title(n),
             "first_order": envs["first-order"].controllers[n].verdict,
             "quasi_static": envs["quasi-static"].controllers[n].verdict,
             "ok_first_order": envs["first-order"].controllers[n].ok,
             "ok_quasi_static": envs["quasi-static"].controllers[n].ok}
            for n in env.controllers]
    c = carriage.params.circuit
    k = carriage.params.wavenumber
    ctx = {"model": now, "figure": CIRCUIT_LAG_FIGURE, "speed": V, "axes": axes,
           "envelope": rows, "v_c_value": c.resistance / (k * c.inductance),
           "time_constant_ms": c.inductance / c.resistance * 1e3, **_forms()}
    figure = damping_figure({
        "speeds": speeds, "speed": V, "v_c": ctx["v_c_value"], "models": list(MODELS),
        "axes": [f"{axis} ({_UNITS[axis]})" for axis in cv.AXES],
        "damping": {n: curves[n] for n in MODELS},
        "controllers": [controller_title(n) for n in env.controllers],
        "colors": [registered_controller(n).style.get("color", "k") for n in env.controllers],
        "envelope_speeds": {n: envs[n].speeds for n in MODELS},
        "max_real": {n: [envs[n].controllers[c].max_real for c in env.controllers]
                     for n in MODELS}})
    return ctx, figure
