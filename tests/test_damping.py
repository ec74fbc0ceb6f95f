"""Optimized damping (derive/damping.py, eqs 20-21) against numerical minimization.

J(c) is computed here independently, by scipy's Lyapunov solver and by integrating the free
response with solve_ivp, and minimized with scipy.optimize.minimize_scalar.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.integrate
import scipy.linalg
import scipy.optimize
import sympy as sp

from maglevgen.derive import damping

CASES = [(2000.0, 9.3), (1.0, 1.0), (1e-2, 1e3), (1e6, 1e-2), (50.0, 0.2)]


def _cost_lyapunov(c: float, k: float, m: float) -> float:
    """J = integral x^2 from (1, 0): x0^T P x0 with A^T P + P A = -diag(1, 0)."""
    A = np.array([[0.0, 1.0], [-k / m, -c / m]])
    P = scipy.linalg.solve_continuous_lyapunov(A.T, -np.diag([1.0, 0.0]))
    return float(P[0, 0])


def _cost_integrated(c: float, k: float, m: float, x0: float) -> float:
    """J by integrating the free response from (x0, 0) and the running cost x^2."""
    def rhs(_t, s):
        x, v, _ = s
        return [v, -(c * v + k * x) / m, x * x]

    t_end = 40.0 * max(m / c, c / k)  # many times the slowest time constant
    sol = scipy.integrate.solve_ivp(rhs, (0.0, t_end), [x0, 0.0, 0.0], method="LSODA",
                                    rtol=1e-10, atol=1e-14)
    return float(sol.y[2, -1])


@pytest.mark.parametrize(("k", "m"), CASES)
def test_gain_minimizes_lyapunov_cost(k, m):
    # Search c over 1e-8..1e8 on a log scale; J is unimodal in c > 0.
    res = scipy.optimize.minimize_scalar(
        lambda logc: _cost_lyapunov(np.exp(logc), k, m),
        bounds=(np.log(1e-8), np.log(1e8)), method="bounded", options={"xatol": 1e-10})
    c_num = float(np.exp(res.x))
    c_sym = float(damping.damping_gain_closed_form(sp.Float(k), sp.Float(m)))
    assert c_sym == pytest.approx(c_num, rel=1e-5)


@pytest.mark.parametrize(("k", "m"), CASES[:3])
def test_cost_formula_matches_integration(k, m):
    for factor in (0.3, 1.0, 3.0):
        c = factor * np.sqrt(k * m)
        x0 = 0.3  # not 1: the cost's x0^2 factor is checked too
        J_sym = float(damping.square_error_cost(sp.Float(c), sp.Float(k), sp.Float(m),
                                                sp.Float(x0)))
        assert J_sym == pytest.approx(_cost_integrated(c, k, m, x0), rel=1e-6)
        assert J_sym == pytest.approx(x0**2 * _cost_lyapunov(c, k, m), rel=1e-10)


def test_optimal_damping_ratio_is_one_half():
    assert damping.optimal_damping_ratio() == sp.Rational(1, 2)
    k, m = sp.symbols("k m", positive=True)
    c = damping.damping_gain_closed_form(k, m)
    # zeta from the closed-loop poles: s^2 + (c/m) s + k/m = s^2 + 2 zeta w s + w^2.
    zeta = sp.simplify((c / m) / (2 * sp.sqrt(k / m)))
    assert zeta == sp.Rational(1, 2)


@pytest.mark.parametrize("k", [-5.0, 0.0])
def test_unstable_axis_is_rejected(k):
    with pytest.raises(ValueError, match="cannot stabilize"):
        damping.damping_gain_closed_form(sp.Float(k), sp.Integer(2))
    # Independent check of the reason: some pole has Re >= 0 for every c tried.
    for c in np.logspace(-3, 3, 13):
        poles = np.roots([2.0, c, k])
        assert np.max(poles.real) >= -1e-12
