"""Section: trim."""

from __future__ import annotations

from typing import Any

import sympy as sp

from maglevgen.analyses.queries import AcceleratingMargin
from maglevgen.derive import conventions as cv
from maglevgen.report.display import ltx
from maglevgen.report.format import ROUNDOFF, fcolumn

__all__ = ["trim_section"]


def trim_section(trep: dict,
                 accelerating: list[AcceleratingMargin] | None = None) -> dict[str, Any]:
    """The trim table's context; ``accelerating``: the accelerating trim beside the
    constant-speed one at v_min, the design speed and v_max (`accelerating_margins`)."""
    rows = [{"speed": r.speed, "pitch": r.pitch * 1e3, "pitch_acc": r.pitch_accelerating * 1e3,
             "offset": r.pitch_offset * 1e3, "heave_shift": (r.heave_accelerating - r.heave) * 1e3,
             "gap": r.gap * 1e3, "gap_acc": r.gap_accelerating * 1e3, "array": r.gap_array,
             "margin": r.gap_margin * 1e3, "F_prop": r.f_prop, "F_prop_acc": r.f_prop_accelerating}
            for r in accelerating or []]
    return {
        "accelerating": rows,
        "acceleration": accelerating[0].acceleration if accelerating else 0.0,
        "min_gap": accelerating[0].min_gap * 1e3 if accelerating else 0.0,
        "speed": trep["speed"],
        "lift_off": trep["lift_off_speed"],
        "residual": trep["residual"],
        "F_prop": trep["propulsion_force"],
        # the library's numbers as they are (the table prints `states`, one notation)
        "values": [trep["state"][s.name] for s in cv.STATES],
        "states": [
            (s.name, ltx(sp.Symbol(s.name)), value, s.unit, s.description)
            for s, value in zip(cv.STATES, _state_column(trep["state"]), strict=True)
        ],
    }


def _state_column(state: dict[str, float]) -> list[str]:
    """The trim state's values as one table column (`fcolumn`: one notation, no raw
    0.0000344784 beside 20), round-off of a structural zero printed as 0."""
    return fcolumn([0.0 if abs(v) < ROUNDOFF else v for v in (state[s.name] for s in cv.STATES)])
