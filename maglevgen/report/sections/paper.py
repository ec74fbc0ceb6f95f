"""Section: paper."""

from __future__ import annotations

from typing import Any

import mpmath
import numpy as np
import sympy as sp

from maglevgen.derive.paper import (
    paper_discrepancies_allocation,
    paper_discrepancies_riccati,
    paper_riccati,
)
from maglevgen.derive.riccati import (
    axis_matrices,
    lqr_gain_mp,
    lqr_gain_numeric,
    riccati_relative_residual,
)

__all__ = ["paper_comparison_section"]


def _zeta(pole: complex) -> float:
    """Damping ratio of a pole: -Re / |pole|."""
    return float(-pole.real / abs(pole)) if pole != 0 else 1.0


def paper_comparison_section(gains: dict, trep: dict) -> dict[str, Any]:

    (q1, _), (_, q2) = gains["Q"]
    r = gains["R"]
    axes = []
    for axis, a in gains["axes"].items():
        k, m = a["stiffness"], a["inertia"]
        with mpmath.workdps(50):
            P, _K = paper_riccati(sp.Float(k, 50), sp.Float(m, 50))
            A, B = axis_matrices(sp.Float(k, 50), sp.Float(m, 50))
            paper_res = riccati_relative_residual(A, B, [[1, 0], [0, 1]], [[1]], P)
            ref = [mpmath.mpf(v) for v in lqr_gain_mp(k, m, q1, q2, r)]

            def rel(K: np.ndarray, ref: list = ref) -> float:
                return float(
                    max(
                        abs(mpmath.mpf(float(x)) - y) / abs(y)
                        for x, y in zip(np.ravel(K), ref, strict=True)
                    )
                )

            # a study of the printed and the stable closed forms' rounding, not a model
            # result: both forms (the naive one is not in the C) in numpy's float32 and
            # float64 (derive.riccati.lqr_gain_numeric, lambdified once and memoized across
            # processes) against the 50-digit reference; the firmware's float32 gains are
            # checked against it in tests/test_codegen.py's single-precision build
            with np.errstate(all="ignore"):
                naive32 = rel(lqr_gain_numeric(k, m, q1, q2, r, np.float32, "closed"))
                stable32 = rel(lqr_gain_numeric(k, m, q1, q2, r, np.float32, "stable"))
                naive64 = rel(lqr_gain_numeric(k, m, q1, q2, r, np.float64, "closed"))
        lqr_poles = [complex(*p) for p in a["closed_loop_poles"]]
        c = a["damping_gain"]
        damp_poles = list(np.roots([m, c, k])) if c is not None else []
        axes.append(
            {
                "axis": axis,
                "paper_residual": paper_res,
                "paper_gain_rel": a["relative_difference"]["paper_vs_closed_form"],
                "naive32": naive32,
                "stable32": stable32,
                "naive64": naive64,
                "zeta_lqr": min(_zeta(p) for p in lqr_poles),
                "decay_lqr": -max(p.real for p in lqr_poles),
                "zeta_damping": min(_zeta(p) for p in damp_poles) if damp_poles else None,
                "decay_damping": -max(p.real for p in damp_poles) if damp_poles else None,
            }
        )
    coupled = gains["coupled"]
    slowest = {
        name: -max(p[0] for p in coupled[key])
        for name, key in (
            ("per_axis", "poles_per_axis_design"),
            ("coupled", "poles_coupled_lqr"),
            ("damping", "poles_damping"),
        )
    }
    lat = gains["axes"]["lateral"]
    riccati_notes = paper_discrepancies_riccati(
        sp.Float(lat["stiffness"], 6), sp.Float(lat["inertia"], 6)
    )
    return {
        "stiffness": [
            (axis, r_["paper_relative_difference"]) for axis, r_ in trep["stiffness"].items()
        ],
        "axes": axes,
        "slowest": slowest,
        # an unbounded cost (a loop unstable on the coupled model) is null in the JSON
        "cost_per_axis": _cost(coupled["cost_per_axis_design"]),
        "cost_coupled": _cost(coupled["cost_coupled_lqr"]),
        "riccati_notes": riccati_notes,
        "allocation_notes": paper_discrepancies_allocation(),
        "pitch": trep["pitch_paper_form"],
    }


def _cost(value: float | None) -> float:
    """A design's LQR cost as the report prints it: infinity where the JSON has null."""
    return float("inf") if value is None else value
