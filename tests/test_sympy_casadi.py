"""The SymPy -> CasADi conversion (codegen/sympy_casadi.py) node by node, against SymPy's own
numeric evaluation at 30 digits (evalf), on expressions that reach every branch of the
converter: sums whose terms are all subtracted, negations, integer powers from -6 to 6, square
roots and their reciprocals, other exponents, every unary function, Piecewise with several
branches and each comparison on both sides and at equality, Max and Min of three arguments,
pi and E, the removable-singularity functions of derive/distributed.py, and matrices.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
import sympy as sp

from maglevgen.codegen.sympy_casadi import _UNARY, to_casadi
from maglevgen.derive.distributed import sinhc

x, y, z = sp.symbols("x y z", real=True)
# (x, y, z) points: x = y (comparisons at equality), x < y, x > y; all inside every function's
# domain below (asin/acos: |x| < 1; log, sqrt: positive arguments)
POINTS = [(0.3, 0.3, 1.7), (0.2, 0.7, 2.5), (0.9, -0.4, 0.6)]

EXPRESSIONS = [
    -x - y, -x - 2 * y - z, x - y, 3 - x, x - sp.Rational(1, 2), -2 * x * y, -x * y * z,
    -(x + y) * z, x * y * z - 1, sp.pi * x + sp.E, -sp.pi - x,
    *[z**n for n in range(-6, 7)], *[(x + z) ** n for n in (-4, -1, 2, 3)],
    sp.sqrt(z), 1 / sp.sqrt(z), z ** sp.Rational(3, 2), z ** sp.Rational(-3, 2),
    z ** sp.Rational(1, 3), z ** sp.Rational(-1, 3), z**sp.Float(0.7), sp.Abs(y),
    *[f(x) if f in (sp.asin, sp.acos, sp.sign, sp.Abs) else f(z) for f in _UNARY],
    sp.Piecewise((x, x < y), (y, True)), sp.Piecewise((x, x <= y), (y, True)),
    sp.Piecewise((x, x > y), (y, True)), sp.Piecewise((x, x >= y), (y, True)),
    sp.Piecewise((1, x < y), (2, x <= y), (3 + z, True)),
    sp.Max(x, y, z - 1), sp.Min(x, y, z - 1), sp.Max(x, y), sp.Min(-x, y), sp.Max(x, -1),
    sp.Min(-1, y),  # a node whose first argument is -1 but not a product
    sinhc(x - y), sinhc(z),
]


def _evaluate(expr: sp.Expr, point: tuple[float, float, float]) -> float:
    sx = ca.SX.sym("s", 3)
    f = ca.Function("f", [sx], [to_casadi(expr, {x: sx[0], y: sx[1], z: sx[2]})])
    return float(f(point))


@pytest.mark.parametrize("expr", EXPRESSIONS, ids=str)
def test_conversion_equals_sympy_evalf(expr: sp.Expr) -> None:
    for point in POINTS:
        ref = complex(expr.evalf(30, subs=dict(zip((x, y, z), point, strict=True))))
        assert ref.imag == 0, (expr, point)
        assert _evaluate(expr, point) == pytest.approx(ref.real, rel=1e-13, abs=1e-14), point


def test_matrix_conversion_keeps_every_entry_in_place() -> None:
    M = sp.Matrix([[x + y, -x - y, x**-2], [sp.Integer(0), y * z, -z]])
    sx = ca.SX.sym("s", 3)
    out = to_casadi(M, {x: sx[0], y: sx[1], z: sx[2]})
    assert out.shape == (2, 3)
    got = np.array(ca.Function("f", [sx], [out])(POINTS[1]))
    ref = np.array(M.subs(dict(zip((x, y, z), POINTS[1], strict=True))).evalf(30), dtype=float)
    np.testing.assert_allclose(got, ref, rtol=1e-14, atol=0)


def test_unknown_symbol_and_function_raise() -> None:
    with pytest.raises(KeyError, match="symbol y"):
        to_casadi(x + y, {x: ca.SX.sym("x")})
    with pytest.raises(NotImplementedError, match="gamma"):
        to_casadi(sp.gamma(x), {x: ca.SX.sym("x")})


@pytest.mark.parametrize("u", [0.0, -1e-7, 0.1, 0.2499, 0.25, -0.2501, 0.7, -3.0, 40.0, -800.0])
def test_removable_singularities_and_their_casadi_derivatives_against_mpmath(u: float) -> None:
    """sinhc, L, L', L'' as converted (Horner series, closed forms in one exp(-|u|)) and
    CasADi's derivative of each, against mpmath's closed forms at 150 digits (their
    derivative by mpmath's numerical differentiation); at -800 a sinh would overflow, L and L'
    stay finite."""
    import mpmath

    from maglevgen.derive.distributed import langevin, langevin_curvature, langevin_slope

    mpmath.mp.dps = 150  # the closed forms at 1e-30 cancel about 90 digits
    refs = {sinhc: lambda v: mpmath.sinh(v) / v if v != 0 else mpmath.mpf(1),
            langevin: lambda v: mpmath.coth(v) - 1 / v if v != 0 else mpmath.mpf(0),
            langevin_slope: lambda v: (1 / v**2 - 1 / mpmath.sinh(v) ** 2 if v != 0
                                       else mpmath.mpf(1) / 3),
            langevin_curvature: lambda v: (-2 / v**3 + 2 * mpmath.cosh(v) / mpmath.sinh(v) ** 3
                                           if v != 0 else mpmath.mpf(0))}
    s = ca.SX.sym("s")
    at = mpmath.mpf(u) if u != 0 else mpmath.mpf("1e-30")
    for fn, ref in refs.items():
        if fn is sinhc and abs(u) > 700:
            continue  # sinh(800) is past float64
        value = to_casadi(fn(x), {x: s})
        f = ca.Function("f", [s], [value, ca.jacobian(value, s)])
        got, slope = (float(v) for v in f(u))
        want = float(ref(at))
        # L'' = -2/u^3 + 2 cosh/sinh^3 cancels about 4000-fold at the switch (both forms)
        rel = 2e-12 if fn is langevin_curvature else 1e-13
        assert got == pytest.approx(want, rel=rel, abs=1e-15), fn
        want_slope = float(mpmath.diff(ref, at))
        # the derivative of a series truncated after u^12 (L') errs by about 2e-12 relative
        # at the switch, as the expanded series did
        assert slope == pytest.approx(want_slope, rel=1e-11, abs=1e-14), fn
