"""Optimized damping control of the paper's section 3 (eqs 20-21), derived with SymPy.

Each axis obeys m x'' + c x' + k x = 0 under velocity feedback u = c x' (eq 21, u_i = K_i x_i'
entering eq 20 as + u). The paper calls its gains "optimized" without naming the criterion;
this module states one and derives c from it:

    c minimizes J(c) = integral_0^inf x(t)^2 dt, the integral square error of the displacement
    in the free response from x(0) = x0, x'(0) = 0.

J = x0^2 P[0, 0] with P solving the Lyapunov equation A_cl^T P + P A_cl = -diag(1, 0) of the
closed loop A_cl = [[0, 1], [-k/m, -c/m]]. Solving dJ/dc = 0 gives c = sqrt(k m), a damping
ratio of 1/2; ``damping_gain_closed_form`` derives this and checks d2J/dc2 > 0.

For k <= 0 no velocity feedback stabilizes the axis: the characteristic polynomial
m s^2 + c s + k has root product k/m <= 0, so one root is >= 0 for every c; the functions here
raise ``ValueError`` for such k.
"""

from __future__ import annotations

from dataclasses import dataclass

import sympy as sp

from maglevgen.derive.memo import memoized

__all__ = ["damping_gain_closed_form", "optimal_damping_ratio", "square_error_cost"]

_k, _m, _c, _x0 = sp.symbols("k m c x0", positive=True)


@dataclass(frozen=True)
class DampingDerivation:
    """The derivation's steps for generic k, m > 0: J(c), dJ/dc, c*, d2J/dc2 at c*."""

    cost: sp.Expr
    gradient: sp.Expr
    gain: sp.Expr
    curvature: sp.Expr


def closed_loop_matrix(c: sp.Expr, k: sp.Expr, m: sp.Expr) -> sp.Matrix:
    """A_cl of m x'' + c x' + k x = 0 with state (x, x') (eqs 20-21)."""
    return sp.Matrix([[0, 1], [-k / m, -c / m]])


def square_error_cost(c: sp.Expr = _c, k: sp.Expr = _k, m: sp.Expr = _m,
                      x0: sp.Expr = _x0) -> sp.Expr:
    """J = integral of x^2 from x(0) = x0, x'(0) = 0, by the Lyapunov equation (eqs 20-21)."""
    p11, p12, p22 = sp.symbols("p11 p12 p22")
    P = sp.Matrix([[p11, p12], [p12, p22]])
    A = closed_loop_matrix(c, k, m)
    lyap = A.T * P + P * A + sp.diag(1, 0)
    sol = sp.solve([lyap[0, 0], lyap[0, 1], lyap[1, 1]], [p11, p12, p22], dict=True)
    if len(sol) != 1:
        raise ArithmeticError("the Lyapunov equation has no unique solution")
    return sp.simplify(x0**2 * P[0, 0].subs(sol[0]))


@memoized
def _derive() -> DampingDerivation:
    """Minimize J over c > 0 for generic k, m > 0: dJ/dc = 0 has one positive root."""
    J = square_error_cost()
    dJ = sp.simplify(sp.diff(J, _c))
    roots = [c for c in sp.solve(dJ, _c) if c.is_positive]
    if len(roots) != 1:
        raise ArithmeticError(f"expected one positive stationary point, found {roots}")
    curvature = sp.simplify(sp.diff(J, _c, 2).subs(_c, roots[0]))
    if not curvature.is_positive:
        raise ArithmeticError("the stationary point is not a minimum")
    return DampingDerivation(J, dJ, roots[0], curvature)


def _check_stabilizable(k: sp.Expr) -> None:
    """Raise for k <= 0, which no velocity feedback stabilizes (module docstring)."""
    if sp.sympify(k).is_nonpositive:
        raise ValueError(f"stiffness k = {k} <= 0: pure velocity feedback cannot stabilize this "
                         "axis (m s^2 + c s + k has a root >= 0); use the LQR of riccati.py")


def damping_gain_closed_form(k: sp.Expr = _k, m: sp.Expr = _m) -> sp.Expr:
    """The ISE-optimal velocity-feedback gain c of eq 21 (c = sqrt(k m) by derivation).

    Raises ``ValueError`` when k is known to be <= 0.
    """
    _check_stabilizable(k)
    return _derive().gain.xreplace({_k: sp.sympify(k), _m: sp.sympify(m)})


def damping_ratio(c: sp.Expr, k: sp.Expr = _k, m: sp.Expr = _m) -> sp.Expr:
    """zeta = c / (2 sqrt(k m)) of m x'' + c x' + k x = 0 (k > 0)."""
    _check_stabilizable(k)
    return c / (2 * sp.sqrt(k * m))


def optimal_damping_ratio() -> sp.Expr:
    """The damping ratio of ``damping_gain_closed_form``, simplified (1/2 by derivation)."""
    return sp.simplify(damping_ratio(_derive().gain))
