"""Section: coordinate conventions, state order, the rotation and the kinematics."""

from __future__ import annotations

from typing import Any

import sympy as sp

from maglevgen.derive import conventions as cv
from maglevgen.derive.memo import memoized
from maglevgen.derive.rigid_body import euler_rates, rotation_body_to_inertial
from maglevgen.report.display import (
    EULER_PHI,
    EULER_PSI,
    EULER_THETA,
    REPORT_SOURCE,
    Display,
    eqs,
    ltx,
    trig_abbrev,
)

__all__ = ["conventions_section"]


def conventions_section(model) -> dict[str, Any]:
    return _conventions_section(model.input_names, REPORT_SOURCE)


@memoized
def _conventions_section(input_names: tuple[str, ...], _source: str) -> dict[str, Any]:
    """States, axes, inputs, R and the kinematics (cached across processes: they depend on
    the input names alone)."""

    ab = trig_abbrev()
    Rm = rotation_body_to_inertial(EULER_PHI, EULER_THETA, EULER_PSI)
    vel = sp.Matrix(sp.symbols("u v w"))
    omega = sp.Matrix(sp.symbols("p q r"))
    pos_rates = (Rm * vel).xreplace(ab)
    rates = (
        euler_rates(EULER_PHI, EULER_THETA, omega)
        .xreplace(ab)
        .xreplace({sp.tan(EULER_THETA): sp.Symbol("t_theta")})
    )
    inputs = [cv.PROPULSION] + [
        cv.Signal(n, "N", f"control force of array {n[3:]} along body {n[2]}")
        for n in input_names[1:]
    ]
    return {
        "states": [(i, ltx(sp.Symbol(st.name)), st) for i, st in enumerate(cv.STATES)],
        "axes": [
            (a, ltx(sp.Symbol(cv.AXIS_POSITION_STATE[a])), c)
            for a, c in zip(cv.AXES, cv.CONTROLS, strict=True)
        ],
        "inputs": inputs,
        "rotation": Display((r"\mathbf{R} &= " + ltx(Rm.xreplace(ab)),)),
        "kinematics": eqs(
            [(ltx(sp.Symbol(rf"\dot{{{s}}}")), pos_rates[i]) for i, s in enumerate("xyz")]
            + [
                (ltx(sp.Symbol(rf"\dot{{\{s}}}")), rates[i])
                for i, s in enumerate(("phi", "theta", "psi"))
            ]
        ),
    }


