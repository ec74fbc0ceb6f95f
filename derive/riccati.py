"""Per-axis LQR of the paper's section 4 (eqs 24-33), derived in closed form with SymPy.

Each controlled axis (lateral, vertical, roll, pitch, yaw) is a mass-spring system

    x = (position, rate),  A = [[0, 1], [-k/m, 0]],  B = [[0], [1/m]],  u = -K x,

with k the stiffness (negative for an unstable axis), m > 0 the mass or inertia and u the applied
generalized force. The cost is eq 25 with Q = diag(q1, q2) > 0 and R = r > 0; P solves the
algebraic Riccati equation (ARE) of eq 28, written out for this A, B in eq 30, and K = R^-1 B^T P
(eq 27). The paper's eq 20 carries +u with B = [0, -1/m]; with u = -K x the gain K is the same.

Three forms are kept:

- ``riccati_closed_form``: the stabilizing solution as ``sympy.solve`` returns it from the three
  scalar equations of eq 30 (K1 = sqrt(k^2 + q1/r) - k in effect);
- ``riccati_stable_form``: the same P and K without cancellation, for float32 code:
  K1 = (q1/r)/(sigma + k) when k >= 0 and sigma - k when k < 0 (sigma = sqrt(k^2 + q1/r)),
  K2 = sqrt(2 m K1 + q2/r), p11 = r K2 sigma, p12 = m r K1, p22 = m r K2;
- ``lqr_gain_mp``: the closed form evaluated with mpmath, the reference for every numerical test.

References
----------
W. Ko, Q. Han, C. Ham, "Dynamics and Control of a Maglev Vehicle", eqs 24-33.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cache, partial
from typing import Any, TypeAlias

import mpmath
import numpy as np
import scipy.linalg
import sympy as sp

from maglevgen.derive.memo import memoized

__all__ = ["LqrSweep", "axis_matrices", "default_sweep", "lqr_gain_mp", "lqr_gain_numeric",
           "numerical_lqr_error_sweep", "riccati_closed_form", "riccati_relative_residual",
           "riccati_residual", "riccati_solution_mp", "riccati_stable_form"]

# A matrix in any of the three representations riccati_residual accepts.
MatrixLike: TypeAlias = "sp.MatrixBase | mpmath.matrix | np.ndarray | Sequence[Sequence[float]]"
# A real number: a float, an exact string ("9.3"), an mpmath or a SymPy number.
RealLike: TypeAlias = "float | int | str | mpmath.mpf | sp.Expr"
# One axis's (k, m, q1, q2, r).
AxisPoint: TypeAlias = tuple[float, float, float, float, float]

# Generic symbols of the derivation; user values are substituted for them afterwards.
_k = sp.Symbol("k", real=True)
_m, _q1, _q2, _r = sp.symbols("m q1 q2 r", positive=True)
_ARGS = (_k, _m, _q1, _q2, _r)
_p11, _p12, _p22 = sp.symbols("p11 p12 p22")
# Sign-proof parameter: k = sqrt(q1/r) (a - 1/a) / 2 maps a > 0 one-to-one onto the real line.
_a = sp.Symbol("a", positive=True)
_K1, _K2 = sp.symbols("K1 K2", positive=True)


@dataclass(frozen=True)
class AxisLQR:
    """Closed-form LQR of one axis: the model used, the ARE solution P, gain K and poles."""

    A: sp.ImmutableMatrix
    B: sp.ImmutableMatrix
    Q: sp.ImmutableMatrix
    R: sp.ImmutableMatrix
    P: sp.ImmutableMatrix
    K: sp.ImmutableMatrix
    poles: tuple[sp.Expr, sp.Expr]


@dataclass(frozen=True)
class AxisLQRStable:
    """Cancellation-free form of the same P and K (see the module docstring).

    Selection rule: K1 = ``K1_nonneg`` when k >= 0, else ``K1_neg`` (``K1`` is the Piecewise;
    generated code uses casadi.if_else on ``k >= 0``). ``K2_of_K1`` and ``P_of_gains`` are the
    rest of the evaluation, in terms of the selected K1 and then (K1, K2).
    """

    sigma: sp.Expr
    K1_nonneg: sp.Expr
    K1_neg: sp.Expr
    K1: sp.Piecewise
    K2_of_K1: sp.Lambda
    P_of_gains: sp.Lambda
    K2: sp.Expr
    P: sp.ImmutableMatrix
    K: sp.ImmutableMatrix


def axis_matrices(k: sp.Expr, m: sp.Expr) -> tuple[sp.ImmutableMatrix, sp.ImmutableMatrix]:
    """A and B of one axis (eq 29), u being the applied generalized force."""
    A = sp.ImmutableMatrix([[0, 1], [-k / m, 0]])
    B = sp.ImmutableMatrix([[0], [1 / m]])
    return A, B


def riccati_residual(A: MatrixLike, B: MatrixLike, Q: MatrixLike, R: MatrixLike,
                     P: MatrixLike) -> MatrixLike:
    """Left side of the ARE, A^T P + P A - P B R^-1 B^T P + Q (eq 28); zero at a solution.

    Works on SymPy matrices, mpmath matrices or float arrays, returning the same kind.
    """
    a: Any
    b: Any
    q: Any
    r: Any
    p: Any
    if isinstance(P, sp.MatrixBase):
        a, b, q, r, p = (sp.Matrix(X) for X in (A, B, Q, R, P))
        return a.T * p + p * a - p * b * r.inv() * b.T * p + q
    if isinstance(P, mpmath.matrix):
        a, b, q, r = (_to_mp(X) for X in (A, B, Q, R))
        return a.T * P + P * a - P * b * mpmath.inverse(r) * b.T * P + q
    a, b, q, r, p = (np.atleast_2d(np.asarray(X, dtype=float)) for X in (A, B, Q, R, P))
    return a.T @ p + p @ a - p @ b @ np.linalg.solve(r, b.T @ p) + q


def _to_mp(X: MatrixLike) -> mpmath.matrix:
    """An mpmath matrix of X (an mpmath matrix, a nested list or an array; SymPy entries too)."""
    if isinstance(X, mpmath.matrix):
        return X
    rows = np.atleast_2d(np.asarray(X, dtype=object)).tolist()
    return mpmath.matrix([[mpmath.mpf(sp.N(x, mpmath.mp.dps + 5)) if isinstance(x, sp.Basic)
                           else mpmath.mpmathify(x) for x in row] for row in rows])


def riccati_relative_residual(A: MatrixLike, B: MatrixLike, Q: MatrixLike, R: MatrixLike,
                              P: MatrixLike) -> float:
    """Max-norm of the eq 28 residual over the sum of the max-norms of its four terms (mpmath).

    Evaluated at the working precision of the caller's mpmath context.
    """
    a, b, q, r, p = (_to_mp(X) for X in (A, B, Q, R, P))
    terms = (a.T * p, p * a, p * b * mpmath.inverse(r) * b.T * p, q)
    scale = sum(mpmath.mnorm(T, "inf") for T in terms)
    return float(mpmath.mnorm(riccati_residual(a, b, q, r, p), "inf") / scale)


def _factor_radicands(expr: sp.Expr) -> sp.Expr:
    """Factor the base of every square root, so sqrt(c (a^2 + 1)^2) becomes (a^2 + 1) sqrt(c)."""
    def is_sqrt(e: sp.Basic) -> bool:
        return e.is_Pow and e.exp == sp.S.Half

    for _ in range(3):  # nested radicals: inner ones first
        expr = expr.replace(is_sqrt, lambda e: sp.sqrt(sp.factor(e.base)))
    return expr


def _sign_over_all_k(expr: sp.Expr) -> bool | None:
    """Whether expr > 0 for every real k (True), < 0 for every k (False), or undecided (None).

    Substitutes k = sqrt(q1/r)(a - 1/a)/2, a > 0 (a bijection onto the reals, under which
    sqrt(k^2 + q1/r) = sqrt(q1/r)(a + 1/a)/2 and sigma - k = sqrt(q1/r)/a), so SymPy's
    assumptions decide the sign of every radical for all a > 0.
    """
    e = _factor_radicands(sp.sympify(expr).subs(_k, sp.sqrt(_q1 / _r) * (_a - 1 / _a) / 2))
    e = _factor_radicands(sp.factor(e))
    if e.is_positive:
        return True
    if e.is_negative:
        return False
    return None


def _are_equations() -> tuple[sp.Expr, sp.Expr, sp.Expr]:
    """The (1,1), (1,2), (2,2) entries of eq 30 for the generic axis."""
    A, B = axis_matrices(_k, _m)
    P = sp.Matrix([[_p11, _p12], [_p12, _p22]])
    M: Any = riccati_residual(A, B, sp.diag(_q1, _q2), sp.Matrix([[_r]]), P)
    return M[0, 0], M[0, 1], M[1, 1]


def _is_stabilizing(K: sp.Matrix) -> bool:
    """Hurwitz test of lambda^2 + (K2/m) lambda + (k + K1)/m, the closed loop of A - B K.

    A second-order polynomial is Hurwitz iff both lower coefficients are positive; each sign is
    decided for all real k by ``_sign_over_all_k``. A candidate is rejected as soon as one
    coefficient is negative for all k; a sign left undecided otherwise raises.
    """
    signs = [_sign_over_all_k(c) for c in (_k + K[0], K[1])]
    if False in signs:
        return False
    if None in signs:
        raise ArithmeticError(f"cannot decide the closed-loop signs of K = {list(K)}")
    return True


@memoized
def _generic_closed_form() -> AxisLQR:
    """Solve eq 30 with sympy.solve and keep the stabilizing solution.

    sympy.solve returns four solutions: two roots for p12 from the (1,1) entry and, for each,
    two for p22 from the (2,2) entry; p11 follows linearly from the (1,2) entry. The closed loop
    is Hurwitz iff k + K1 > 0 and K2 > 0 (``_is_stabilizing``); this keeps exactly one solution,
    the root with k + K1 = +sqrt(k^2 + q1/r) and p22 > 0. That P is then checked positive
    definite (p11 > 0, det P > 0) for all real k, which makes it the unique stabilizing
    solution of eq 28 (ref. [11] of the paper).
    """
    A, B = axis_matrices(_k, _m)
    Q, R = sp.ImmutableMatrix(sp.diag(_q1, _q2)), sp.ImmutableMatrix([[_r]])
    solutions = sp.solve(_are_equations(), [_p11, _p12, _p22], dict=True)
    chosen = []
    for sol in solutions:
        P = sp.Matrix([[_p11, _p12], [_p12, _p22]]).subs(sol)
        K = (R.inv() * B.T * P).applyfunc(sp.simplify)
        if _is_stabilizing(K):
            chosen.append((P.applyfunc(sp.simplify), K))
    if len(chosen) != 1:
        raise ArithmeticError(f"expected one stabilizing ARE solution, found {len(chosen)}")
    P, K = chosen[0]
    if not (_sign_over_all_k(P[0, 0]) and _sign_over_all_k(P.det())):
        raise ArithmeticError("the stabilizing ARE solution is not positive definite")
    lam = sp.Symbol("lambda")
    poles = sp.solve(((A - B * K) - lam * sp.eye(2)).det(), lam)
    return AxisLQR(A, B, Q, R, sp.ImmutableMatrix(P), sp.ImmutableMatrix(K), tuple(poles))


def _subs_axis(expr: sp.Basic, k: RealLike, m: RealLike, q1: RealLike, q2: RealLike,
               r: RealLike) -> sp.Basic:
    """Substitute the user's (k, m, q1, q2, r) for the generic symbols."""
    values = dict(zip(_ARGS, map(sp.sympify, (k, m, q1, q2, r)), strict=True))
    return expr.xreplace(values) if isinstance(expr, sp.Basic) else expr


def riccati_closed_form(k: RealLike = _k, m: RealLike = _m, q1: RealLike = _q1,
                        q2: RealLike = _q2, r: RealLike = _r) -> AxisLQR:
    """Closed-form stabilizing P, K and closed-loop poles of one axis (eqs 27-30).

    Derived once with generic symbols (see ``_generic_closed_form`` for the selection argument)
    and then evaluated at the given k, m, q1, q2, r (numbers or SymPy expressions).
    """
    g = _generic_closed_form()
    sub = partial(_subs_axis, k=k, m=m, q1=q1, q2=q2, r=r)
    return AxisLQR(sub(g.A), sub(g.B), sub(g.Q), sub(g.R), sub(g.P), sub(g.K),
                   tuple(sub(p) for p in g.poles))


@memoized
def _generic_stable_form() -> AxisLQRStable:
    """Rewrite the closed form without cancellation, deriving each step from eq 30.

    K1 = sigma - k is multiplied by (sigma + k)/(sigma + k), its numerator expanding to q1/r;
    K2 is the positive root of the (2,2) entry with p12 = m r K1; p11 comes from the (1,2) entry
    with k + K1 replaced by sigma, which has no cancellation when k < 0.
    """
    _, e12, e22 = _are_equations()
    K1_closed = _generic_closed_form().K[0]
    sigma = sp.sqrt(_k**2 + _q1 / _r)
    if sp.simplify(K1_closed - (sigma - _k)) != 0:
        raise ArithmeticError(f"unexpected closed-form K1: {K1_closed}")
    numerator = sp.expand((sigma - _k) * (sigma + _k))
    if numerator.has(sp.sqrt(_k**2 + _q1 / _r)):
        raise ArithmeticError("rationalizing K1 left a radical in the numerator")
    K1_nonneg, K1_neg = numerator / (sigma + _k), sigma - _k
    p22_roots = sp.solve(e22.subs(_p12, _m * _r * _K1), _p22)
    (p22,) = [p for p in p22_roots if p.is_positive]
    K2_of_K1 = sp.Lambda(_K1, sp.simplify(p22 / (_m * _r)))
    (p11,) = sp.solve(e12, _p11)
    p11 = sp.factor(p11.subs({_p12: _m * _r * _K1, _p22: _m * _r * _K2}))
    p11 = sp.factor(p11.subs(_K1, sigma - _k))  # k + K1 -> sigma
    P_of_gains = sp.Lambda((_K1, _K2), sp.ImmutableMatrix(
        [[p11, _m * _r * _K1], [_m * _r * _K1, _m * _r * _K2]]))
    K1 = sp.Piecewise((K1_nonneg, _k >= 0), (K1_neg, True))
    K2 = K2_of_K1(K1)
    P = P_of_gains(K1, K2)
    K = sp.ImmutableMatrix([[K1, K2]])
    return AxisLQRStable(sigma, K1_nonneg, K1_neg, K1, K2_of_K1, P_of_gains, K2, P, K)


def riccati_stable_form(k: RealLike = _k, m: RealLike = _m, q1: RealLike = _q1,
                        q2: RealLike = _q2, r: RealLike = _r) -> AxisLQRStable:
    """Cancellation-free P and K of one axis (eqs 27-32), for float32 evaluation.

    Valid as long as k^2 and q1/r are finite in the target precision (|k| < 1.8e19 in float32).
    """
    g = _generic_stable_form()
    sub = partial(_subs_axis, k=k, m=m, q1=q1, q2=q2, r=r)
    return AxisLQRStable(sub(g.sigma), sub(g.K1_nonneg), sub(g.K1_neg), sub(g.K1),
                         sub(g.K2_of_K1), sub(g.P_of_gains), sub(g.K2), sub(g.P), sub(g.K))


@memoized
def _numpy_functions(form: str) -> tuple[Callable, ...]:
    """Lambdified numpy evaluators of the gain expressions; they add no float64 constants."""
    if form == "closed":
        return (sp.lambdify(_ARGS, list(_generic_closed_form().K), "numpy"),)
    g = _generic_stable_form()
    return (sp.lambdify(_ARGS, g.K1_nonneg, "numpy"), sp.lambdify(_ARGS, g.K1_neg, "numpy"),
            sp.lambdify((_K1, *_ARGS), g.K2_of_K1(_K1), "numpy"))


def lqr_gain_numeric(k: float, m: float, q1: float = 1.0, q2: float = 1.0, r: float = 1.0,
                     dtype: type = np.float64, form: str = "stable") -> np.ndarray:
    """Gain K = (K1, K2) of eq 32 evaluated in ``dtype`` (every operation in that precision).

    ``form="stable"`` evaluates the ``riccati_stable_form`` expressions (branch on k >= 0);
    ``form="closed"`` evaluates the naive closed form, kept to show its cancellation.
    """
    args = tuple(dtype(v) for v in (k, m, q1, q2, r))
    if form == "closed":
        (f,) = _numpy_functions("closed")
        return np.array(f(*args), dtype=dtype)
    if form != "stable":
        raise ValueError(f"form must be 'stable' or 'closed', not {form!r}")
    k1_nonneg, k1_neg, k2_of_k1 = _numpy_functions("stable")
    K1 = k1_nonneg(*args) if args[0] >= 0 else k1_neg(*args)
    return np.array([K1, k2_of_k1(K1, *args)], dtype=dtype)


@cache  # in-process only: mpmath's rationals in these functions do not survive pickling
def _mpmath_functions() -> tuple[Callable, Callable]:
    """Lambdified mpmath evaluators of the closed-form K and P."""
    g = _generic_closed_form()
    return sp.lambdify(_ARGS, list(g.K), "mpmath"), sp.lambdify(_ARGS, g.P.tolist(), "mpmath")


def _guard_digits(k: RealLike, q1: RealLike, r: RealLike) -> int:
    """Digits lost to cancellation in sigma - k: about 2 log10(k^2 r / q1) at most."""
    ratio = abs(mpmath.mpf(k)) ** 2 * mpmath.mpf(r) / mpmath.mpf(q1)
    return 10 + max(0, int(mpmath.log10(ratio + 1)))


def lqr_gain_mp(k: RealLike, m: RealLike, q1: RealLike = 1, q2: RealLike = 1, r: RealLike = 1,
                dps: int = 50) -> tuple[mpmath.mpf, mpmath.mpf]:
    """Closed-form (K1, K2) of eq 32 correct to ``dps`` digits (mpmath, with guard digits).

    Float arguments are taken as the exact binary numbers they hold.
    """
    with mpmath.workdps(dps + _guard_digits(k, q1, r)):
        K = _mpmath_functions()[0](*(mpmath.mpf(v) for v in (k, m, q1, q2, r)))
    return K[0], K[1]


def riccati_solution_mp(k: RealLike, m: RealLike, q1: RealLike = 1, q2: RealLike = 1,
                        r: RealLike = 1, dps: int = 50) -> mpmath.matrix:
    """Closed-form P of eq 30 correct to ``dps`` digits (mpmath, with guard digits)."""
    with mpmath.workdps(dps + _guard_digits(k, q1, r)):
        return mpmath.matrix(_mpmath_functions()[1](*(mpmath.mpf(v) for v in (k, m, q1, q2, r))))


def default_sweep() -> list[AxisPoint]:
    """(k, m, q1, q2, r) points: log sweeps m in [1e-3, 1e4], |k| in [1e-3, 1e7], both signs."""
    masses = np.logspace(-3, 4, 8)
    stiffness = np.logspace(-3, 7, 11)
    return [(sign * k, m, 1.0, 1.0, 1.0) for m in masses for k in stiffness for sign in (1, -1)]


@dataclass(frozen=True)
class LqrSweep:
    """Per-point max componentwise relative gain errors against the 50-digit closed form."""

    points: tuple[AxisPoint, ...]
    control_lqr: np.ndarray
    scipy_care: np.ndarray
    stable_float64: np.ndarray
    stable_float32: np.ndarray

    def max_errors(self) -> dict[str, float]:
        """The worst error of each method over the sweep."""
        return {name: float(np.max(getattr(self, name)))
                for name in ("control_lqr", "scipy_care", "stable_float64", "stable_float32")}


def _relative_error(K: np.ndarray, K_ref: Sequence[mpmath.mpf]) -> float:
    """max_i |K_i - K_ref_i| / |K_ref_i|, computed in mpmath."""
    with mpmath.workdps(30):
        return float(max(abs(mpmath.mpf(float(a)) - b) / abs(b)
                         for a, b in zip(np.ravel(K), K_ref, strict=True)))


def _numerical_gains(k: float, m: float, q1: float, q2: float, r: float
                     ) -> tuple[np.ndarray, np.ndarray]:
    """K from control.lqr and from scipy.linalg.solve_continuous_are (K = R^-1 B^T P)."""
    import control  # only the tests and the accuracy sweep need python-control

    A = np.array([[0.0, 1.0], [-k / m, 0.0]])
    B = np.array([[0.0], [1.0 / m]])
    Q, R = np.diag([q1, q2]), np.array([[r]])
    K_control = control.lqr(A, B, Q, R)[0]
    P = scipy.linalg.solve_continuous_are(A, B, Q, R)
    return np.ravel(K_control), np.ravel(np.linalg.solve(R, B.T @ P))


def numerical_lqr_error_sweep(points: Sequence[AxisPoint] | None = None) -> LqrSweep:
    """Measure the gain errors of control.lqr, scipy CARE and both closed-form evaluations.

    Each is compared with ``lqr_gain_mp`` at 50 digits over ``points`` (``default_sweep()``).
    """
    points = tuple(default_sweep() if points is None else points)
    errors: dict[str, list[float]] = {"c": [], "s": [], "f64": [], "f32": []}
    for pt in points:
        ref = lqr_gain_mp(*pt)
        K_control, K_scipy = _numerical_gains(*pt)
        errors["c"].append(_relative_error(K_control, ref))
        errors["s"].append(_relative_error(K_scipy, ref))
        errors["f64"].append(_relative_error(lqr_gain_numeric(*pt), ref))
        errors["f32"].append(_relative_error(lqr_gain_numeric(*pt, dtype=np.float32), ref))
    return LqrSweep(points, *(np.array(errors[key]) for key in ("c", "s", "f64", "f32")))
