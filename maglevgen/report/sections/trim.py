"""Section: trim."""

from __future__ import annotations

from typing import Any

import sympy as sp

from ...derive import conventions as cv
from ..display import ltx


def _trim(trep: dict) -> dict[str, Any]:
    return {
        "speed": trep["speed"],
        "lift_off": trep["lift_off_speed"],
        "residual": trep["residual"],
        "F_prop": trep["propulsion_force"],
        "states": [
            (s.name, ltx(sp.Symbol(s.name)), trep["state"][s.name], s.unit, s.description)
            for s in cv.STATES
        ],
    }


