"""The numbers `maglevgen trim`, `gains` and `envelope` print, as plain data (the report and
SUMMARY.md read the same): no argument parsing, no printing."""

from __future__ import annotations

from . import progress
from .controllers import allocation_matrix, carriage_gains, coupled_comparison, effectiveness
from .derive import conventions as cv
from .envelope import DEFAULT_SPEEDS, compute_envelope
from .library import simulation_library
from .operating import CONTROLLER_TITLES


def trim_report(carriage, speed: float | None) -> dict:
    """Everything `maglevgen trim` prints, as plain data."""
    trim = carriage.trim(speed)
    rows = carriage.stiffness_table(trim)
    names = list(carriage.params.arrays)
    return {
        "speed": trim.speed,
        "params_sha256": carriage.loaded.sha256,
        "state": {s.name: float(v) for s, v in zip(cv.STATES, trim.x, strict=True)},
        "state_units": {s.name: s.unit for s in cv.STATES},
        "propulsion_force": float(trim.u[0]),
        "residual": trim.residual,
        "lift_off_speed": carriage.lift_off_speed(),
        "arrays": {n: {"gap": float(g), "lift": float(fl), "drag": float(fd)}
                   for n, g, fl, fd in zip(names, trim.gaps, trim.lift, trim.drag, strict=True)},
        "stiffness": {
            r.axis: {"unit": r.unit, "derived": r.derived_magnetic,
                     "derived_with_gravity": r.derived_total, "paper_formula": r.paper_formula,
                     "paper": r.paper_value, "paper_relative_difference": r.relative_difference}
            for r in rows
        },
        "stiffness_matrix": carriage.magnetic_stiffness(trim).tolist(),
        "paper_inputs": carriage.paper_stiffness_inputs(trim),
    }


def gains_report(carriage, speed: float | None) -> dict:
    """Everything `maglevgen gains` prints, as plain data."""
    trim = carriage.trim(speed)
    gains = carriage_gains(carriage, trim)
    ctl = carriage.params.control
    Q, R = tuple(ctl.state_weights), ctl.input_weight
    cc = coupled_comparison(carriage, trim, gains)
    poles = lambda ev: [[float(e.real), float(e.imag)] for e in sorted(ev, key=_pole_key)]  # noqa: E731
    return {
        "speed": trim.speed,
        "Q": [[Q[0], 0.0], [0.0, Q[1]]],
        "R": R,
        "params_sha256": carriage.loaded.sha256,
        "convention": "u = -K x, x = (position, rate), A = [[0, 1], [-k/m, 0]], B = [0, 1/m]",
        "axes": {g.axis: g.to_json(Q, R) for g in gains},
        "coupled": {
            "states": ["y", "z", "phi", "theta", "psi", "v", "w", "p", "q", "r"],
            "cost_per_axis_design": cc.cost_per_axis,
            "cost_coupled_lqr": cc.cost_coupled,
            "poles_per_axis_design": poles(cc.poles_per_axis),
            "poles_coupled_lqr": poles(cc.poles_coupled),
            "poles_damping": poles(cc.poles_damping),
        },
        "allocation": {
            "forces": list(carriage.model.input_names[1:]),
            "controls": [c.name for c in cv.CONTROLS],
            "effectiveness": effectiveness(carriage).tolist(),
            "minimum_norm": allocation_matrix(carriage).tolist(),
        },
    }


def _pole_key(e: complex) -> tuple[float, float]:
    return (float(e.real), float(e.imag))


def _library(carriage):
    return simulation_library(carriage.structure, progress=progress.step)


def envelope_of(carriage, n_speeds: int | None = None):
    """The envelope of a carriage through its compiled library (maglevgen.envelope)."""
    return compute_envelope(carriage, _library(carriage), n_speeds or DEFAULT_SPEEDS)


def verdict_lines(env, embedded: str) -> list[str]:
    """One line per controller, the embedded one marked."""
    out = [f"Envelope {env.v_min:.4g} to {env.v_max:.4g} m/s (maglevgen envelope):"]
    for name, c in env.controllers.items():
        mark = " [embedded]" if name == embedded else ""
        out.append(f"  {CONTROLLER_TITLES[name] + mark:<28} {c.verdict}")
    return out


