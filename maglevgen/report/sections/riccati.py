"""Section: riccati."""

from __future__ import annotations

from typing import Any

import sympy as sp

from maglevgen.derive.paper import paper_riccati
from maglevgen.derive.riccati import (
    axis_matrices,
    riccati_closed_form,
    riccati_residual,
    riccati_stable_form,
)
from maglevgen.derive.spec_design import damping_ratio_form, rate_weight_form
from maglevgen.report.display import abbreviate_radicals, eqs, ltx

__all__ = ["riccati_section"]


def riccati_section(gains: dict) -> dict[str, Any]:

    k, m = sp.Symbol("k"), sp.Symbol("m")
    q1, q2, r = sp.symbols("q_1 q_2 r")
    A, B = axis_matrices(k, m)
    p11, p12, p22 = sp.symbols("p_11 p_12 p_22")
    P = sp.Matrix([[p11, p12], [p12, p22]])
    res = riccati_residual(A, B, sp.diag(q1, q2), sp.Matrix([[r]]), P)
    are = eqs(
        [(ltx(sp.expand(res[i, j])), sp.Integer(0)) for i, j in ((0, 0), (0, 1), (1, 1))], tag="30"
    )
    g = riccati_closed_form(k, m, q1, q2, r)
    defs, (P11, P12, P22, K1, K2, s1, s2) = abbreviate_radicals(
        [g.P[0, 0], g.P[0, 1], g.P[1, 1], g.K[0], g.K[1], *g.poles], "sigma"
    )
    closed = eqs(
        [(ltx(s), e) for s, e in defs] + [("p_{11}", P11), ("p_{12}", P12), ("p_{22}", P22)],
        tag="31",
    )
    gain = eqs([("K_1", K1), ("K_2", K2)], tag="32")
    poles = eqs([(r"\lambda_{1}", s1), (r"\lambda_{2}", s2)])
    st = riccati_stable_form(k, m, q1, q2, r)
    K1s, K2s = sp.symbols("K_1 K_2")
    Pst = st.P_of_gains(K1s, K2s)
    stable = eqs(
        [
            (r"\sigma", st.sigma),
            (r"K_1\big|_{k \ge 0}", st.K1_nonneg),
            (r"K_1\big|_{k < 0}", st.K1_neg),
            ("K_2", st.K2_of_K1(K1s)),
            ("p_{11}", Pst[0, 0]),
            ("p_{12}", Pst[0, 1]),
            ("p_{22}", Pst[1, 1]),
        ]
    )
    Pp, Kp = paper_riccati(k, m)
    printed = eqs(
        [("p_{11}", Pp[0, 0]), ("p_{12}", Pp[0, 1]), ("p_{22}", Pp[1, 1])], tag="31, paper"
    ) + eqs([("K_1", Kp[0]), ("K_2", Kp[1])], tag="32, paper")
    form = rate_weight_form()
    design = eqs([(r"\zeta", damping_ratio_form()), ("q_2", form.q2),
                  (r"\zeta\big|_{q_2 = 0}", form.zeta_at_zero_rate_weight)])
    axes = []
    for axis, a in gains["axes"].items():
        axes.append(
            {
                "axis": axis,
                "k": a["stiffness"],
                "m": a["inertia"],
                "K_cf": a["K_closed_form"],
                "K_num": a["K_numerical"],
                "K_paper": a["K_paper"],
                "P": a["P_closed_form"],
                "poles": [complex(*p) for p in a["closed_loop_poles"]],
                "rel_num": a["relative_difference"]["numerical_vs_closed_form"],
                "rel_paper": a["relative_difference"]["paper_vs_closed_form"],
            }
        )
    return {
        "A": ltx(A),
        "B": ltx(B),
        "Q": ltx(sp.diag(q1, q2)),
        "R": ltx(r),
        "are": are,
        "closed": closed,
        "gain": gain,
        "poles": poles,
        "stable": stable,
        "design": design,
        "printed": printed,
        "axes": axes,
        "Q_values": gains["Q"],
        "R_value": gains["R"],
        "paper_applies": all(a["paper_applies"] for a in gains["axes"].values()),
    }


