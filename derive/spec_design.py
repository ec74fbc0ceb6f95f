"""Weights from specifications: Bryson's rule and the rate weight that gives a damping ratio.

The per-axis LQR of eqs 24-33 closes each axis as

    m a'' + K2 a' + (k + K1) a = 0,   K1 = sqrt(k^2 + q1/r) - k,   K2 = sqrt(q2/r + 2 m K1)

(eq 32's gains, `riccati.riccati_stable_form`), so the closed loop's damping ratio is analytic
in the weights:

    zeta(q1, q2, r; k, m) = K2 / (2 sqrt(m (k + K1))).

Bryson's rule fixes the position and force weights from the allowed deviation a_max and the
force budget F_max of the axis, q1 = 1/a_max^2 and r = 1/F_max^2 (a deviation of a_max costs
as much as a force of F_max). Solving zeta = zeta_min for q2 then gives the rate weight in
closed form,

    q2 = 2 m r (2 zeta^2 sigma - K1) = 2 m r (k - (1 - 2 zeta^2) sigma),  sigma = sqrt(k^2 + q1/r),

the unique root (zeta grows monotonically with q2). Where it is not positive, the position
weight alone already damps the axis to at least zeta (q2 -> 0 gives zeta_0 = sqrt(K1/(2 sigma)),
which exceeds zeta when sigma > k / (1 - 2 zeta^2)); any small positive q2 then keeps the
spec, and `rate_weight_floor` is used.

References
----------
A. E. Bryson, Y.-C. Ho, *Applied Optimal Control* (1975), section 5.4 (weights from maximum
values). W. Ko, Q. Han, C. Ham, "Dynamics and Control of a Maglev Vehicle", eqs 24-33.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import sympy as sp

from maglevgen.derive.riccati import riccati_stable_form

__all__ = ["damping_ratio_form", "rate_weight_form"]

_k = sp.Symbol("k", real=True)
_m, _q1, _q2, _r, _zeta = sp.symbols("m q_1 q_2 r zeta", positive=True)
_a_max, _F_max = sp.symbols("a_max F_max", positive=True)


def bryson_weights(a_max: sp.Expr = _a_max, F_max: sp.Expr = _F_max) -> tuple[sp.Expr, sp.Expr]:
    """(q1, r) = (1/a_max^2, 1/F_max^2): Bryson's rule for one axis."""
    return 1 / a_max**2, 1 / F_max**2


@cache
def damping_ratio_form() -> sp.Expr:
    """zeta(q1, q2, r; k, m) of the per-axis closed loop under eq 32's gains (k >= 0 branch of
    the stable form's K2(K1) with K1 = sqrt(k^2 + q1/r) - k, the value of either branch)."""
    form = riccati_stable_form(_k, _m, _q1, _q2, _r)
    K1 = sp.sqrt(_k**2 + _q1 / _r) - _k  # either branch of form.K1
    return form.K2_of_K1(K1) / (2 * sp.sqrt(_m * (_k + K1)))


@dataclass(frozen=True)
class RateWeightForm:
    """The rate weight q2 that gives damping ratio zeta, and the damping ratio at q2 = 0."""

    q2: sp.Expr  # q2(zeta; q1, r, k, m)
    zeta_at_zero_rate_weight: sp.Expr  # zeta_0(q1, r, k, m)
    symbols: dict[str, sp.Symbol]


@cache
def rate_weight_form() -> RateWeightForm:
    """Solve zeta(q1, q2, r; k, m) = zeta for q2 with SymPy (the module docstring's form)."""
    zeta = damping_ratio_form()
    roots = sp.solve(sp.Eq(zeta**2, _zeta**2), _q2)
    if len(roots) != 1:
        raise ArithmeticError(f"expected one root for q2, got {roots}")
    q2 = sp.simplify(roots[0])
    zeta0 = sp.simplify(zeta.subs(_q2, 0))
    names = {"k": _k, "m": _m, "q1": _q1, "q2": _q2, "r": _r, "zeta": _zeta}
    return RateWeightForm(q2, zeta0, names)
