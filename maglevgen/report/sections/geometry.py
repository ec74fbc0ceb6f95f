"""Section: geometry."""

from __future__ import annotations

from typing import Any

import sympy as sp

from maglevgen.derive import conventions as cv
from maglevgen.derive.geometry import generalized_wrench_row
from maglevgen.derive.memo import memoized
from maglevgen.derive.model import build_model
from maglevgen.derive.paper import paper_force_sums
from maglevgen.report.display import (
    REPORT_SOURCE,
    Display,
    break_sum,
    eqs,
    round_floats,
    trig_abbrev,
)
from maglevgen.report.format import tex_escape
from maglevgen.report.symbols import to_display

__all__ = ["geometry_section"]


def geometry_section(carriage, gains: dict) -> dict[str, Any]:
    model = carriage.model
    free = model.gaps.free_symbols
    gap_values = tuple((e.name, float(e.value)) for e, s in zip(carriage.entries, model.p,
                                                                  strict=True) if s in free)
    arrays = tuple((name, tuple(map(float, a.position)), tuple(map(float, a.normal)))
                   for name, a in carriage.params.arrays.items())
    gaps, derived, printed = _geometry_displays(model.structure, gap_values, arrays,
                                                REPORT_SOURCE)
    return {
        "gaps": gaps,
        "derived_sums": derived,
        "printed_sums": printed,
        "forces": gains["allocation"]["forces"],
    }


@memoized
def _geometry_displays(structure, gap_values: tuple[tuple[str, float], ...],
                       arrays: tuple[tuple[str, tuple[float, ...], tuple[float, ...]], ...],
                       _source: str) -> tuple[Display, Display, Display]:
    """The gaps with ``gap_values`` substituted, the generalized forces of the arrays' lifts
    and drags at the design pose (eqs 8-12 derived, from ``arrays``: name, position, normal)
    and the paper's printed sums; keyed by what they show (memoised across processes), so that
    editing a parameter they do not show finds them cached."""

    model = build_model(structure)
    ab = trig_abbrev()
    state_sym = dict(zip(model.x, sp.symbols(" ".join(cv.STATE_NAMES)), strict=True))
    gaps = []
    for i, arr in enumerate(model.arrays):
        gexpr = to_display(model, model.gaps[i], dict(gap_values)).xreplace(state_sym)
        gaps += break_sum(rf"\delta_{{{tex_escape(arr.name)}}}",
                          round_floats(sp.expand(gexpr.xreplace(ab))))
    ex = sp.Matrix([-1, 0, 0])
    total = sp.zeros(5, 1)
    for name, position, normal in arrays:
        pos = sp.Matrix([sp.Float(c, 17) for c in position])
        nrm = sp.Matrix([sp.Float(c, 17) for c in normal])
        label = tex_escape(name)
        FL, FD = sp.Symbol(f"F_{{L,{label}}}"), sp.Symbol(f"F_{{D,{label}}}")
        total += generalized_wrench_row(pos, nrm) * FL + generalized_wrench_row(pos, ex) * FD
    labels = ("F_y", "F_z", "M_x", "M_y", "M_z")
    derived = eqs([(rf"\textstyle\sum {lab}", round_floats(sp.expand(total[i])))
                   for i, lab in enumerate(labels)])
    printed_sums = paper_force_sums()
    printed_order = (("F_z", "8"), ("F_y", "9"), ("M_x", "10"), ("M_z", "11"), ("M_y", "12"))
    printed = Display(
        tuple(
            line
            for lab, tag in printed_order
            for line in break_sum(rf"\textstyle\sum {lab}", _as_printed(printed_sums[lab]),
                                 tag=f"{tag}, paper")
        )
    )
    return Display(tuple(gaps)), derived, printed




def _as_printed(expr: sp.Expr) -> sp.Expr:
    """Eqs 10-12 as the paper prints them, the arm times the sum: 0.119 (F_y1 - ...), not
    SymPy's distributed 119 F_y1/1000 - ... (the coefficient as the decimal printed)."""
    coeff, rest = sp.factor_terms(expr).as_coeff_Mul()
    if coeff == 1 or not rest.is_Add:
        return expr
    return sp.Mul(sp.Float(f"{float(coeff):g}", 3), rest, evaluate=False)
