"""Per-axis LQR (derive/riccati.py, eqs 24-33) against independent references.

References: mpmath evaluation at 50+ digits with the residual of eq 28 computed in mpmath,
scipy.linalg.solve_continuous_are, control.lqr, the textbook double-integrator gain, SymPy
simplification. No number here is copied from the program's own output.
"""

from __future__ import annotations

import control
import mpmath
import numpy as np
import pytest
import scipy.linalg
import sympy as sp
from hypothesis import given, settings
from hypothesis import strategies as st

from maglevgen.derive import riccati as rc
from maglevgen.derive.paper import paper_riccati

EPS64 = float(np.finfo(np.float64).eps)
# Extra weightings for the 50-digit checks, on top of the paper's Q = I, R = 1.
WEIGHTS = [(1.0, 1.0, 1.0), (1e4, 1e-2, 1e-3), (1e-3, 1e3, 10.0)]


def _mp_model(k, m, q1, q2, r):
    """A, B, Q, R of one axis as mpmath matrices, built here from the axis equation."""
    k, m = mpmath.mpf(k), mpmath.mpf(m)
    A = mpmath.matrix([[0, 1], [-k / m, 0]])
    B = mpmath.matrix([[0], [1 / m]])
    return A, B, mpmath.diag([q1, q2]), mpmath.matrix([[r]])


def _points_with_weights():
    """The sweep's (k, m) grid, thinned, under each weighting of WEIGHTS."""
    grid = rc.default_sweep()[::3]
    return [(k, m, *w) for (k, m, *_) in grid for w in WEIGHTS]


@pytest.fixture(scope="module")
def sweep() -> rc.LqrSweep:
    """Errors of every method against the 50-digit closed form over the default sweep."""
    return rc.numerical_lqr_error_sweep()


# (a) the closed form solves eq 28 ----------------------------------------------------------

def test_closed_form_residual_is_zero_symbolically():
    g = rc.riccati_closed_form()
    residual = rc.riccati_residual(g.A, g.B, g.Q, g.R, g.P)
    assert residual.applyfunc(sp.simplify) == sp.zeros(2, 2)
    assert (g.K - g.R.inv() * g.B.T * g.P).applyfunc(sp.simplify) == sp.zeros(1, 2)


def test_double_integrator_textbook_gain():
    # k = 0, m = 1, Q = I, R = 1: the textbook LQR gain of 1/s^2 is [1, sqrt(3)].
    g = rc.riccati_closed_form(0, 1, 1, 1, 1)
    assert (g.K - sp.Matrix([[1, sp.sqrt(3)]])).applyfunc(sp.simplify) == sp.zeros(1, 2)


@pytest.mark.parametrize("pt", _points_with_weights())
def test_50_digit_closed_form_solves_are(pt):
    with mpmath.workdps(80):
        A, B, Q, R = _mp_model(*pt)
        P = rc.riccati_solution_mp(*pt)
        K1, K2 = rc.lqr_gain_mp(*pt)
        assert rc.riccati_relative_residual(A, B, Q, R, P) < 1e-40
        assert P[0, 0] > 0 and mpmath.det(P) > 0
        assert abs(P[0, 1] - P[1, 0]) == 0
        poles = mpmath.eig(A - B * mpmath.matrix([[K1, K2]]), left=False, right=False)
        assert all(mpmath.re(p) < 0 for p in poles)


def test_stable_form_equals_closed_form_symbolically():
    g, s = rc.riccati_closed_form(), rc.riccati_stable_form()
    assert sp.simplify(s.K1_nonneg - g.K[0]) == 0
    assert sp.simplify(s.K1_neg - g.K[0]) == 0
    # K2 > 0 in both forms (both are square roots), so equal squares mean equal values.
    assert sp.simplify(s.K2_of_K1(g.K[0]) ** 2 - g.K[1] ** 2) == 0
    assert (s.P_of_gains(g.K[0], g.K[1]) - g.P).applyfunc(sp.simplify) == sp.zeros(2, 2)


# (b) float64 evaluation --------------------------------------------------------------------

def test_float64_matches_50_digit_reference(sweep):
    worst = float(np.max(sweep.stable_float64))
    print(f"float64 stable form, max relative error over the sweep: {worst:.3e}")
    assert worst < 1e-10


# (c) numerical solvers, measured -----------------------------------------------------------

def test_numerical_solvers_accuracy_measured(sweep):
    errors = sweep.max_errors()
    print("max relative gain error vs the 50-digit closed form:", errors)
    # Measured 0.164 for both (scipy 1.17.1, python-control 0.10.2 on its scipy path), at
    # k = 1e7, m = 1e-3 where K1 ~ 5e-8 is tiny next to P's other entries; 0.25 allows for
    # LAPACK variation. On |k| <= 1e3 they reach 4.1e-7 (bound below: 1e-6).
    assert errors["control_lqr"] < 0.25
    assert errors["scipy_care"] < 0.25
    small_k = np.abs(np.array(sweep.points)[:, 0]) <= 1e3
    assert np.max(sweep.control_lqr[small_k]) < 1e-6
    assert np.max(sweep.scipy_care[small_k]) < 1e-6


def test_closed_form_at_least_as_accurate_as_solvers(sweep):
    # At every point, up to a rounding floor of 4 ulp (a solver can be exact by luck).
    floor = 4 * EPS64
    best_solver = np.minimum(sweep.control_lqr, sweep.scipy_care)
    assert np.all(sweep.stable_float64 <= np.maximum(best_solver, floor))


# (d) float32 evaluation --------------------------------------------------------------------

def test_float32_matches_50_digit_reference(sweep):
    worst = float(np.max(sweep.stable_float32))
    print(f"float32 stable form, max relative error over the sweep: {worst:.3e}")
    assert worst < 1e-5


def test_float32_matches_control_lqr_where_it_is_accurate(sweep):
    checked = 0
    for pt, err in zip(sweep.points, sweep.control_lqr, strict=True):
        if err > 1e-7:  # control.lqr itself is off by more than float32 could show
            continue
        A = np.array([[0.0, 1.0], [-pt[0] / pt[1], 0.0]])
        B = np.array([[0.0], [1.0 / pt[1]]])
        K_ref = np.ravel(control.lqr(A, B, np.diag(pt[2:4]), np.array([[pt[4]]]))[0])
        K32 = rc.lqr_gain_numeric(*pt, dtype=np.float32)
        np.testing.assert_allclose(K32.astype(np.float64), K_ref, rtol=1e-5)
        checked += 1
    print(f"float32 compared with control.lqr at {checked} of {len(sweep.points)} points")
    assert checked > len(sweep.points) // 2


def test_float32_evaluation_stays_float32():
    K = rc.lqr_gain_numeric(-3.0, 2.0, 1.0, 1.0, 1.0, dtype=np.float32)
    assert K.dtype == np.float32
    f_nonneg, f_neg, f_k2 = rc._numpy_functions("stable")
    args = tuple(np.float32(v) for v in (3.0, 2.0, 1.0, 1.0, 1.0))
    for value in (f_nonneg(*args), f_neg(*args), f_k2(np.float32(0.5), *args)):
        assert np.asarray(value).dtype == np.float32


def test_naive_form_loses_accuracy_in_float32():
    pt = (1e4, 1.0, 1.0, 1.0, 1.0)
    with mpmath.workdps(60):
        ref = rc.lqr_gain_mp(*pt)
        naive = rc.lqr_gain_numeric(*pt, dtype=np.float32, form="closed")
        stable = rc.lqr_gain_numeric(*pt, dtype=np.float32)
        err_naive = abs(mpmath.mpf(float(naive[0])) - ref[0]) / ref[0]
        err_stable = abs(mpmath.mpf(float(stable[0])) - ref[0]) / ref[0]
    print(f"K1 at k = 1e4 in float32: naive error {float(err_naive):.3e}, "
          f"stable error {float(err_stable):.3e}")
    assert err_naive > 1e-2
    assert err_stable < 1e-6


# (e) property tests against scipy ----------------------------------------------------------

def _log_uniform(lo: float, hi: float):
    return st.floats(lo, hi).map(lambda e: 10.0**e)


@settings(max_examples=150, deadline=None)
@given(k=_log_uniform(-3, 4), sign=st.sampled_from([1.0, -1.0]), m=_log_uniform(-2, 3),
       q1=_log_uniform(-2, 2), q2=_log_uniform(-2, 2), r=_log_uniform(-2, 2))
def test_matches_scipy_care(k, sign, m, q1, q2, r):
    k *= sign
    A = np.array([[0.0, 1.0], [-k / m, 0.0]])
    B = np.array([[0.0], [1.0 / m]])
    P_scipy = scipy.linalg.solve_continuous_are(A, B, np.diag([q1, q2]), np.array([[r]]))
    K_scipy = np.ravel(B.T @ P_scipy / r)
    with mpmath.workdps(40):
        P = np.array(rc.riccati_solution_mp(k, m, q1, q2, r, dps=30).tolist(), dtype=float)
    K = rc.lqr_gain_numeric(k, m, q1, q2, r)
    # Normwise: scipy resolves small entries only to ||P|| eps; 2000 random draws over these
    # ranges measured 6e-9 (P) and 1.2e-8 (K).
    assert np.linalg.norm(P - P_scipy) <= 1e-7 * np.linalg.norm(P)
    assert np.linalg.norm(K - K_scipy) <= 1e-7 * np.linalg.norm(K)


# (f) the paper's printed eq 31 ------------------------------------------------------------

def test_paper_eq31_does_not_solve_eq30():
    k, m = sp.Integer(2000), sp.Rational("9.3")
    P, _ = paper_riccati(k, m)
    A, B = rc.axis_matrices(k, m)
    with mpmath.workdps(50):
        printed = rc.riccati_relative_residual(A, B, sp.eye(2), sp.Matrix([[1]]), P)
        true = rc.riccati_relative_residual(A, B, sp.eye(2), sp.Matrix([[1]]),
                                            rc.riccati_solution_mp(2000, "9.3"))
    print(f"relative eq 30 residual at k = 2000, m = 9.3: printed eq 31 {printed:.3e}, "
          f"closed form {true:.3e}")
    assert printed > 0.5
    assert true < 1e-40


def test_paper_eq31_has_no_degenerate_solution_case():
    k, m = sp.Symbol("k", real=True), sp.Symbol("m", positive=True)
    P, _ = paper_riccati(k, m)
    A, B = rc.axis_matrices(k, m)
    res = rc.riccati_residual(A, B, sp.eye(2), sp.Matrix([[1]]), P)
    # The (1,1) entry vanishes only at k = 1 (checked by solving it) ...
    assert sp.solve(sp.simplify(res[0, 0]), k) == [1]
    # ... where the (1,2) entry is nonzero at any m > 0 (checked numerically at 30 digits).
    r12 = sp.lambdify(m, res[0, 1].subs(k, 1), "mpmath")
    with mpmath.workdps(30):
        assert all(abs(r12(mpmath.mpf(v))) > 1e-6 for v in np.logspace(-3, 4, 15))


def test_defaults_are_the_papers_weights():
    """Weights left out are the paper's Q = I, R = 1 (eq 25), for the mpmath forms and the
    numpy one alike; the accuracy sweep carries those weights over m in [1e-3, 1e4] and |k| in
    [1e-3, 1e7] (a point a decade, 8 masses x 11 stiffnesses), both signs of k."""
    from independent_reference import lqr_reference_mp

    k, m = -37.5, 2.5
    K_ref, P_ref = lqr_reference_mp(k, m, 1.0, 1.0, 1.0, dps=60)
    with mpmath.workdps(60):
        K, P = rc.lqr_gain_mp(k, m), rc.riccati_solution_mp(k, m)
        tol = mpmath.mpf(10) ** -45
        assert all(abs(a - b) < tol * abs(b) for a, b in zip(K, K_ref, strict=True))
        assert mpmath.mnorm(P - P_ref, "inf") < tol * mpmath.mnorm(P_ref, "inf")
    K_num = rc.lqr_gain_numeric(k, m)
    assert K_num.dtype == np.float64
    np.testing.assert_allclose(K_num, [float(x) for x in K_ref], rtol=1e-14)
    sweep = rc.default_sweep()
    assert {pt[2:] for pt in sweep} == {(1.0, 1.0, 1.0)} and len(sweep) == 8 * 11 * 2
    ks, ms = np.array([pt[0] for pt in sweep]), np.array([pt[1] for pt in sweep])
    assert (np.abs(ks).min(), np.abs(ks).max(), ms.min(), ms.max()) == \
        pytest.approx((1e-3, 1e7, 1e-3, 1e4), rel=1e-12)
    assert sorted(ks[ks > 0]) == pytest.approx(sorted(-ks[ks < 0]), rel=0)


def test_residual_of_float_arrays_equals_eq28_written_here():
    """The numpy branch of riccati_residual: zero at scipy's CARE solution, and at any other
    symmetric P the four terms of eq 28 written out here with numpy."""
    rng = np.random.default_rng(5)
    k, m, q1, q2, r = -40.0, 2.0, 3.0, 0.5, 0.2
    A, B = np.array([[0.0, 1.0], [-k / m, 0.0]]), np.array([[0.0], [1.0 / m]])
    Q, R = np.diag([q1, q2]), np.array([[r]])
    P = scipy.linalg.solve_continuous_are(A, B, Q, R)
    scale = np.abs(A.T @ P).max() + np.abs(Q).max()
    assert np.abs(rc.riccati_residual(A, B, Q, R, P)).max() < 1e-12 * scale
    X = rng.normal(size=(2, 2))
    P = X + X.T
    expected = A.T @ P + P @ A - P @ B @ B.T @ P / r + Q
    np.testing.assert_allclose(rc.riccati_residual(A, B, Q, R, P), expected, rtol=1e-13)
    np.testing.assert_allclose(rc.riccati_residual(A.tolist(), B, Q, [[r]], P), expected,
                               rtol=1e-13)  # nested lists are arrays too


def test_closed_loop_poles_equal_eigenvalues_of_control_lqr():
    """The poles riccati_closed_form returns are those of A - B K (python-control's lqr)."""
    for k, m, q1, q2, r in [(2000.0, 9.3, 1.0, 1.0, 1.0), (-40.0, 2.0, 3.0, 0.5, 0.2)]:
        A, B = np.array([[0.0, 1.0], [-k / m, 0.0]]), np.array([[0.0], [1.0 / m]])
        _, _, eig = control.lqr(A, B, np.diag([q1, q2]), np.array([[r]]))
        g = rc.riccati_closed_form(*(sp.Float(x) for x in (k, m, q1, q2, r)))
        poles = sorted((complex(sp.N(p)) for p in g.poles), key=lambda z: (z.real, z.imag))
        ref = sorted(np.asarray(eig, dtype=complex), key=lambda z: (z.real, z.imag))
        np.testing.assert_allclose(poles, ref, rtol=1e-9)


@pytest.mark.parametrize("pt", [(1e15, 1.0, 1.0, 1.0, 1.0), (1e9, 1.0, 1.0, 1.0, 1e6),
                                (1e5, 1.0, 1e-10, 1.0, 1.0)])
def test_mp_gain_keeps_the_digits_asked_for_under_cancellation(pt):
    """lqr_gain_mp's promise, dps correct digits, where sigma - k cancels log10(k^2 r/q1)
    digits (24 to 30 here), against the hand-solved ARE at 100 digits."""
    from independent_reference import lqr_reference_mp

    K_ref, _ = lqr_reference_mp(*pt, dps=100)
    K = rc.lqr_gain_mp(*pt, dps=20)
    with mpmath.workdps(100):
        for a, b in zip(K, K_ref, strict=True):
            assert abs(a - b) < mpmath.mpf(10) ** -20 * abs(b), (pt, a, b)


def test_relative_residual_keeps_sympy_entries_to_working_precision():
    """SymPy entries (radicals of the exact P) are read at the caller's mpmath precision: at 40
    digits the exact solution's eq 28 residual is at the 40-digit rounding level."""
    k, m = sp.Integer(2000), sp.Rational("9.3")
    s = sp.sqrt(k**2 + 1)  # the hand solution: K1 = s - k, K2 = sqrt(2 m K1 + 1), P = m K ...
    K1, K2 = s - k, sp.sqrt(2 * m * (s - k) + 1)
    P = sp.Matrix([[K2 * s, m * K1], [m * K1, m * K2]])
    A, B = sp.Matrix([[0, 1], [-k / m, 0]]), sp.Matrix([[0], [1 / m]])
    with mpmath.workdps(40):
        assert rc.riccati_relative_residual(A, B, sp.eye(2), sp.Matrix([[1]]), P) < 1e-38


def test_sign_prover_decides_signs_known_by_hand() -> None:
    """The prover behind the stabilizing-root choice and the positive-definite P (for every real
    k): sigma = sqrt(k^2 + q1/r) exceeds |k|, so sigma - k and sigma + k are positive; k, 1 - k
    and k^2 - 1 change sign."""
    k, q1, r = rc._k, rc._q1, rc._r
    sigma = sp.sqrt(k**2 + q1 / r)
    assert rc._sign_over_all_k(k**2 + q1 / r) is True
    assert rc._sign_over_all_k(sigma - k) is True
    assert rc._sign_over_all_k(sigma + k) is True
    assert rc._sign_over_all_k(k - sigma) is False
    assert rc._sign_over_all_k(-(k**2 + q1 / r)) is False
    for changes_sign in (k, 1 - k, k**2 - 1):
        assert rc._sign_over_all_k(changes_sign) is None, changes_sign



@pytest.mark.parametrize("k, q1", [(0.7, 1e-6), (0.3, 1e-8), (1e-3, 1e-12), (40.0, 1e-3),
                                   (-0.7, 1e-6), (-0.3, 1e-8), (-1e-3, 1e-12)])
def test_stable_form_has_no_cancellation_for_either_sign_of_k(k: float, q1: float) -> None:
    """|k| small but q1/r << k^2, so sigma ~ |k|: for k >= 0, sigma - k would cancel and the
    stable form takes K1 = (q1/r)/(sigma + k); for k < 0 the reverse. Each branch keeps float64
    and float32 within a few ulps of the hand-solved ARE (independent_reference's
    lqr_reference_mp, 60 digits), so the branch must switch at k = 0, not at some other k."""
    from independent_reference import lqr_reference_mp

    K_ref, _ = lqr_reference_mp(k, 2.5, q1, 1.0, 1.0)
    for dtype, rtol in ((np.float64, 1e-14), (np.float32, 2e-6)):
        K = rc.lqr_gain_numeric(k, 2.5, q1, 1.0, 1.0, dtype=dtype)
        for got, ref in zip(K, K_ref, strict=True):
            assert abs(float(got) - float(ref)) <= rtol * float(ref), (dtype, k, q1, got, ref)
