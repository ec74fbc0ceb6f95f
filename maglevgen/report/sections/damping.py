"""Section: damping."""

from __future__ import annotations

from typing import Any

import numpy as np
import sympy as sp

from maglevgen.derive.damping import (
    damping_gain_closed_form,
    optimal_damping_ratio,
    square_error_cost,
)
from maglevgen.derive.memo import memoized
from maglevgen.derive.paper import paper_allocation
from maglevgen.report.display import REPORT_SOURCE, Display, eq, ltx, matrix_tex
from maglevgen.report.format import fnum, tex_escape

__all__ = ["damping_allocation_section"]


def damping_allocation_section(gains: dict) -> dict[str, Any]:
    axes = []
    for axis, a in gains["axes"].items():
        cg = a["damping_gain"]
        if cg is None:
            poles = None
        else:
            poles = sorted(
                np.roots([a["inertia"], cg, a["stiffness"]]), key=lambda z: (z.real, z.imag)
            )
        axes.append({"axis": axis, "k": a["stiffness"], "m": a["inertia"], "c": cg, "poles": poles})
    alloc = gains["allocation"]
    E, T = np.array(alloc["effectiveness"]), np.array(alloc["minimum_norm"])
    return {
        **_damping_allocation_forms(E.shape, REPORT_SOURCE),
        "axes": axes,
        "E": matrix_tex(E, lambda v: fnum(v, 4)),
        "T": matrix_tex(T, lambda v: fnum(v, 4)),
        # E T = I where every u is reachable; else the Penrose condition E T E = E
        "full_rank": bool(np.linalg.matrix_rank(E) == E.shape[0]),
        "E_T_residual": float(np.max(np.abs(E @ T - np.eye(E.shape[0])))
                              if np.linalg.matrix_rank(E) == E.shape[0]
                              else np.max(np.abs(E @ T @ E - E))),
        "T_pinv_residual": float(np.max(np.abs(T - np.linalg.pinv(E)))),
        # F_<axis><array name>: the name escaped, the axis a subscript as sympy prints F_y3
        "forces": [ltx(sp.Symbol(f"F_{{{f[2]}{tex_escape(f[3:])}}}")) for f in alloc["forces"]],
        "controls": [ltx(sp.Symbol(c_)) for c_ in alloc["controls"]],
    }


@memoized
def _damping_allocation_forms(shape: tuple[int, int], _source: str) -> dict[str, Any]:
    """The damping cost and its optimum (eqs 20-21 derived), the allocation's Lagrangian and
    solution for an E of ``shape``, and the paper's printed eqs 22-23: parameter
    independent, cached across processes."""

    c, k, m, x0 = sp.symbols("c k m x0", positive=True)
    J = square_error_cost(c, k, m, x0)
    dJ = sp.factor(sp.diff(J, c))
    c_opt = damping_gain_closed_form(k, m)
    curv = sp.simplify(sp.diff(J, c, 2).subs(c, c_opt))
    F = sp.MatrixSymbol("F", shape[1], 1)
    lam = sp.MatrixSymbol("lambda", shape[0], 1)
    Es, us = sp.MatrixSymbol("E", *shape), sp.MatrixSymbol("u", shape[0], 1)
    printed = paper_allocation()
    order = ("F_z3", "F_z1", "F_z2", "F_z6", "F_z5", "F_z4", "F_y1", "F_y2", "F_y4", "F_y5")
    pl: list[str] = []
    for i in range(0, len(order), 2):
        a_, b_ = order[i], order[i + 1]
        pl.append(
            f"{ltx(sp.Symbol(a_))} &= {ltx(printed[a_])} & "
            f"{ltx(sp.Symbol(b_))} &= {ltx(printed[b_])}"
        )
    pl[2] += r" \tag{22, paper}"
    pl[-1] += r" \tag{23, paper}"
    return {
        "J": eq(r"J(c)", J),
        "dJ": eq(r"\frac{\partial J}{\partial c}", dJ),
        "c_opt": eq(r"c^{*}", c_opt),
        "curvature": eq(r"\left.\frac{\partial^2 J}{\partial c^2}\right|_{c^{*}}", curv),
        "zeta": eq(r"\zeta^{*}", optimal_damping_ratio()),
        "lagrangian": eq(r"\mathcal{L}", F.T * F + lam.T * (Es * F - us)),
        "solution": eq("T", Es.T * (Es * Es.T).I),
        "printed": Display(tuple(pl)),
    }


