"""The track circuits' first-order lag (derive/circuit_lag.py, model.circuit_dynamics) against
references written here: a direct integration of the circuit equation (solve_ivp), the
characteristic speed R/(kL), eq 3 at rest, central differences of a circuit-by-circuit force
sum with the rate term (independent_reference.array_loads) and a numpy assembly of the closed
loop with the coupled LQR.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import scipy.optimize
from independent_reference import (
    array_loads,
    array_state,
    lag_times,
    rigid_body_xdot,
    rotation,
)
from scipy.integrate import solve_ivp

from maglevgen.carriage import DerivedCarriage
from maglevgen.control.operating import REDUCED_STATES, closed_loop_stability
from maglevgen.derive import conventions as cv
from maglevgen.params import load_params
from maglevgen.runtime.library import simulation_library

MODULATION = 45.0  # rad/s: the heave and pitch frequencies of the default carriage
# both sides of v_c = R/(kL) = 9.18 m/s, outside the band where the rate coefficient passes
# through zero (there the slow-modulation error is small against the coefficient's scale, not
# against the coefficient itself: derive/circuit_lag.py)
SLOW_SPEEDS = (5.0, 14.0, 20.0, 40.0)


def _upper_array(carriage: DerivedCarriage) -> int:
    return next(i for i, a in enumerate(carriage.params.arrays.values())
                if abs(a.normal[2]) > 1 - 1e-9)


def _integrated_rate_coefficients(prm, speed: float) -> tuple[float, float]:
    """(c_L / F_L, c_D / F_D): -d(force)/d(gap rate) over the mean force, of one circuit whose
    gap is modulated as a sin(Omega t), from the circuit equation L I' + R I = Phi' integrated
    by solve_ivp (Phi = exp(-k g) cos(omega t), omega = k v), the lift k I Phi and the drag
    I dPhi/dxi = -k exp(-k g) sin(omega t) I projected on the gap rate over two whole periods
    after one period of transient (Omega = omega / n, n integer, so the carrier's periods are
    whole as well)."""
    R, L = prm.circuit.resistance, prm.circuit.inductance
    k = 2 * np.pi / prm.halbach.wavelength
    w = k * speed
    n = max(1, round(w / MODULATION))
    Om = w / n
    amp = 1e-2 / k  # k a = 0.01: the projection's nonlinear error is (k a)^2

    def rhs(t, j):  # j = L I
        g, gd = amp * np.sin(Om * t), amp * Om * np.cos(Om * t)
        dphi = np.exp(-k * g) * (-k * gd * np.cos(w * t) - w * np.sin(w * t))
        return [dphi - j[0] * R / L]

    T = 2 * np.pi / Om
    sol = solve_ivp(rhs, (0.0, 3 * T), [0.0], method="DOP853", rtol=1e-12, atol=1e-15,
                    dense_output=True)
    assert sol.success
    t = np.linspace(T, 3 * T, 64 * 2 * n, endpoint=False)  # uniform over whole periods
    j = sol.sol(t)[0]
    g, gd = amp * np.sin(Om * t), amp * Om * np.cos(Om * t)
    lift = k * j * np.exp(-k * g) * np.cos(w * t)
    drag = -k * np.exp(-k * g) * np.sin(w * t) * j
    proj = np.mean(gd**2)
    return (-np.mean(lift * gd) / proj / np.mean(lift),
            -np.mean(drag * gd) / proj / np.mean(drag))


def _library_rate_coefficients(carriage: DerivedCarriage, lib, speed: float, array: int,
                               dw: float = 1e-4) -> tuple[float, float]:
    """The same from the generated C: -d(force)/d(heave rate) / force of an upper array at
    zero attitude (its gap rate is the heave rate w there), central differences."""
    fn = lib.function("maglev_array_forces")
    x = np.zeros(len(cv.STATES))
    x[cv.STATE_INDEX["u"]] = speed
    out = []
    for sign in (1.0, -1.0, 0.0):
        x[cv.STATE_INDEX["w"]] = sign * dw
        lift, drag = (a.ravel()[array] for a in fn(x, carriage.p))
        out.append((lift, drag))
    (lp, dp), (lm, dm), (l0, d0) = out
    return -(lp - lm) / (2 * dw) / l0, -(dp - dm) / (2 * dw) / d0


@pytest.mark.parametrize("speed", SLOW_SPEEDS)
def test_rate_coefficient_equals_direct_integration_of_the_circuit(carriage: DerivedCarriage,
                                                                   sim_lib,
                                                                     speed: float) -> None:
    """The C's lift and drag rate terms (and the issue's closed form k tau_d) against the
    circuit equation integrated directly, to 1 % where the modulation is slow."""
    assert carriage.params.model.circuit_dynamics == "first-order"
    lift_ref, drag_ref = _integrated_rate_coefficients(carriage.params, speed)
    lift_c, drag_c = _library_rate_coefficients(carriage, sim_lib, speed,
                                                _upper_array(carriage))
    assert lift_c == pytest.approx(lift_ref, rel=1e-2)
    assert drag_c == pytest.approx(drag_ref, rel=1e-2)
    c = carriage.params.circuit
    k = carriage.params.wavenumber
    w = k * speed
    tau_d = c.resistance * (c.resistance**2 - (w * c.inductance) ** 2) / (
        (c.resistance**2 + (w * c.inductance) ** 2) * w**2 * c.inductance)
    assert k * tau_d == pytest.approx(lift_ref, rel=1e-2)
    assert np.sign(lift_ref) == (1.0 if speed < c.resistance / (k * c.inductance) else -1.0)


def test_the_lift_rate_term_changes_sign_at_r_over_k_l(carriage: DerivedCarriage, sim_lib) -> None:
    """Damping below R/(kL), negative damping above: the root of the C's rate coefficient
    (Brent) at the characteristic speed written here."""
    c = carriage.params.circuit
    v_c = c.resistance / (carriage.params.wavenumber * c.inductance)
    i = _upper_array(carriage)

    def coefficient(v: float) -> float:
        return _library_rate_coefficients(carriage, sim_lib, v, i)[0]

    assert coefficient(0.5 * v_c) > 0 > coefficient(2 * v_c)
    root = scipy.optimize.brentq(coefficient, 0.5 * v_c, 2 * v_c, xtol=1e-12, rtol=1e-12)
    assert root == pytest.approx(v_c, rel=1e-7)
    assert v_c == pytest.approx(9.18, abs=0.005)  # the number


def _rest_states(carriage: DerivedCarriage, speed: float, n: int = 5) -> list[np.ndarray]:
    """Poses about the design pose moving along the track at ``speed`` with no body rate:
    every gap's rate is zero."""
    rng = np.random.default_rng(35)
    out = []
    for _ in range(n):
        x = np.zeros(12)
        x[1:6] = [*rng.normal(0, 1e-3, 2), *rng.normal(0, 5e-3, 3)]
        x[6:9] = rotation(*x[3:6]).T @ np.array([speed, 0.0, 0.0])  # along the track
        out.append(x)
    return out


def test_zero_gap_rates_give_eq_3(carriage: DerivedCarriage, sim_lib) -> None:
    """With every rate zero the first-order model's array forces are eq 3's circuit sum."""
    fn = sim_lib.function("maglev_array_forces")
    for speed in (7.0, 20.0, 40.0):
        for x in _rest_states(carriage, speed):
            ref = array_state(carriage.params, x[1:6], speed)
            lift, drag = (a.ravel() for a in fn(x, carriage.p))
            np.testing.assert_allclose(lift, ref.lift, rtol=1e-12)
            np.testing.assert_allclose(drag, ref.drag, rtol=1e-12)


@pytest.fixture(scope="module")
def point_quasi_static():
    """The paper's model: eq 3 at the face centres, quasi-static circuits."""
    c = DerivedCarriage(load_params(overrides=['model.array_force="point"',
                                        'model.circuit_dynamics="quasi-static"']))
    return c, simulation_library(c.structure)


def _moving_states(carriage: DerivedCarriage) -> list[np.ndarray]:
    """Trim at 20 m/s with body velocities and rates added: the gaps move."""
    x0 = carriage.trim(20.0).x
    rng = np.random.default_rng(7)
    return [x0 + np.concatenate([np.zeros(6), rng.normal(0, 0.05, 6)]) for _ in range(4)]


def test_quasi_static_has_no_rate_term(point_quasi_static) -> None:
    """model.circuit_dynamics = "quasi-static": the C's array forces at moving states are
    eq 3's (the reference without the rate term), and its Jacobian's velocity columns are the
    central differences of that reference."""
    carriage, lib = point_quasi_static
    fn = lib.function("maglev_array_forces")
    for x in _moving_states(carriage):
        lift, drag = (a.ravel() for a in fn(x, carriage.p))
        ref_lift, ref_drag, _ = array_loads(carriage.params, x, lag=False)
        np.testing.assert_allclose(lift, ref_lift, rtol=1e-12)
        np.testing.assert_allclose(drag, ref_drag, rtol=1e-12)
        lag_lift = array_loads(carriage.params, x, lag=True)[0]
        assert np.max(np.abs(lag_lift / ref_lift - 1)) > 1e-5  # the term is not negligible
    _assert_velocity_columns(carriage, lib, lag=False)


def _reference_xdot(carriage: DerivedCarriage, x: np.ndarray, f_prop: float, lag: bool,
                    body_wrench: np.ndarray | None = None) -> np.ndarray:
    return rigid_body_xdot(carriage.params, x, array_loads(carriage.params, x, lag)[2], f_prop,
                           body_wrench)


def _reference_jacobian(carriage: DerivedCarriage, x: np.ndarray, f_prop: float, lag: bool,
                        h: float = 1e-6) -> np.ndarray:
    J = np.zeros((12, 12))
    for j in range(12):
        e = np.zeros(12)
        e[j] = h
        J[:, j] = (_reference_xdot(carriage, x + e, f_prop, lag)
                   - _reference_xdot(carriage, x - e, f_prop, lag)) / (2 * h)
    return J


def _assert_velocity_columns(carriage: DerivedCarriage, lib, lag: bool) -> np.ndarray:
    from maglevgen.control.operating import checked_trim

    x, f_prop, _ = checked_trim(lib, carriage.p, 20.0, carriage.params.track.min_gap)
    u = np.zeros(len(carriage.model.u))
    u[0] = f_prop
    A, _ = lib.function("maglev_jacobians")(x, u, carriage.p)
    J = _reference_jacobian(carriage, x, f_prop, lag)
    np.testing.assert_allclose(A[6:, 6:], J[6:, 6:], rtol=1e-5, atol=1e-6)
    return A


def test_velocity_columns_equal_central_differences_of_the_lagged_force_sum(
        carriage: DerivedCarriage, sim_lib) -> None:
    """The default model's Jacobian (generated C) in its velocity columns: the rate term of
    every circuit (each at its own gap; its couple along the face included) against central
    differences of the circuit-by-circuit sum written in independent_reference."""
    A = _assert_velocity_columns(carriage, sim_lib, lag=True)
    # the heave rate's own column carries the negative damping above v_c: about -2 N s/m
    c_heave = -carriage.params.vehicle.mass * A[cv.STATE_INDEX["w"], cv.STATE_INDEX["w"]]
    assert -3.0 < c_heave < -1.0


def test_point_law_velocity_columns_equal_central_differences() -> None:
    """The point law (eq 3 at the face centres with the centre gap's rate), lambdified."""
    c = DerivedCarriage(load_params(overrides=['model.array_force="point"']))
    assert c.params.model.circuit_dynamics == "first-order"
    trim = c.trim(20.0)
    A, _ = c.linearize(trim)
    J = _reference_jacobian(c, trim.x, trim.u[0], lag=True)
    np.testing.assert_allclose(A[6:, 6:], J[6:, 6:], rtol=1e-5, atol=1e-6)


def _reference_plant(carriage: DerivedCarriage, x: np.ndarray, f_prop: float, lag: bool
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A_r, B_r, C_rate) of the ten-state linearisation, assembled here: A_r by central
    differences of the reference, the generalized forces (F_y, F_z, M_x, M_y, M_z, body axes
    about O: what the minimum-norm allocation delivers) as inputs, C_rate the axis rates."""
    idx = [cv.STATE_INDEX[s] for s in REDUCED_STATES]
    J = _reference_jacobian(carriage, x, f_prop, lag)
    x0 = _reference_xdot(carriage, x, f_prop, lag)
    B = np.zeros((12, 5))
    for j, row in enumerate((1, 2, 3, 4, 5)):  # F_y, F_z, M_x, M_y, M_z
        w = np.zeros(6)
        w[row] = 1.0
        B[:, j] = _reference_xdot(carriage, x, f_prop, lag, body_wrench=w) - x0
    axes = [cv.STATE_INDEX[s] for s in cv.Q_STATES]
    return J[np.ix_(idx, idx)], B[idx], J[np.ix_(axes, idx)]


def _coupled_lqr(carriage: DerivedCarriage, A_r: np.ndarray, B_r: np.ndarray, C_rate: np.ndarray
                 ) -> np.ndarray:
    """The LQR of Q = q1 on the axis positions + q2 on the axis rates, R = r I (the paper's
    weights), by SciPy's CARE."""
    (q1, q2), r = carriage.params.control.state_weights, carriage.params.control.input_weight
    S = np.eye(5, 10)
    Q = q1 * S.T @ S + q2 * C_rate.T @ C_rate
    P = scipy.linalg.solve_continuous_are(A_r, B_r, Q, r * np.eye(5))
    return B_r.T @ P / r


def _max_real(A: np.ndarray) -> float:
    return float(np.linalg.eigvals(A).real.max())


def test_closed_loop_with_the_rate_term_equals_a_numpy_assembly(carriage: DerivedCarriage, sim_lib,
                                                                 op) -> None:
    """At 20 m/s, the ten-state closed loops assembled here with and without the rate term:
    the open loop grows about 16 times faster (+0.013 -> +0.21 1/s); the coupled LQR with the
    paper's weights designed on the quasi-static model, applied to the lagged plant, goes
    from -0.066 to +0.041 1/s (unstable); the per-axis LQR (the C's gains) becomes unstable
    (+0.042 1/s); the coupled LQR designed on the lagged model (what the toolchain designs
    for model.circuit_dynamics = "first-order") stays stable. The envelope's eigenvalues
    (generated C) equal the assembly here."""
    assert op.speed == 20.0
    A_qs, B_qs, C_qs = _reference_plant(carriage, op.x_trim, op.f_prop, lag=False)
    A_fo, B_fo, C_fo = _reference_plant(carriage, op.x_trim, op.f_prop, lag=True)
    assert 0.005 < _max_real(A_qs) < 0.03
    assert _max_real(A_fo) > 0.15
    assert closed_loop_stability(op, "none")[0] == pytest.approx(_max_real(A_fo), abs=1e-5)

    K_qs = _coupled_lqr(carriage, A_qs, B_qs, C_qs)
    assert _max_real(A_qs - B_qs @ K_qs) < -0.03  # stable on the model it was designed on
    assert _max_real(A_fo - B_fo @ K_qs) > 0.02  # unstable once the circuits lag

    S = np.eye(5, 10)
    K_axis = np.diag(op.K[:, 0]) @ S + np.diag(op.K[:, 1]) @ C_fo
    assert _max_real(A_qs - B_qs @ K_axis) < -0.03
    lqr = _max_real(A_fo - B_fo @ K_axis)
    assert lqr > 0.02
    assert closed_loop_stability(op, "lqr")[0] == pytest.approx(lqr, abs=1e-5)

    K_fo = _coupled_lqr(carriage, A_fo, B_fo, C_fo)
    coupled = _max_real(A_fo - B_fo @ K_fo)
    assert coupled < -0.03
    assert closed_loop_stability(op, "coupled")[0] == pytest.approx(coupled, abs=1e-5)


def test_lag_times_written_here_equal_the_derived_closed_forms(carriage: DerivedCarriage) -> None:
    """derive.circuit_lag's SymPy solution of the circuit equation: tau_d and tau_D evaluated
    against `lag_times`, and its steady response against eq 3's 1/(1 + (R/(omega L))^2)."""
    from maglevgen.derive.circuit_lag import circuit_response

    cr = circuit_response()
    c = carriage.params.circuit
    for v in (2.0, 9.0, 20.0, 40.0):
        w = carriage.params.wavenumber * v
        val = {cr.R: c.resistance, cr.L: c.inductance, cr.omega: w}
        tau_d, tau_D = lag_times(carriage.params, v)
        assert float(cr.tau_lift.xreplace(val)) == pytest.approx(tau_d, rel=1e-13)
        assert float(cr.tau_drag.xreplace(val)) == pytest.approx(tau_D, rel=1e-13)
        eq3 = 1 / (c.inductance * (1 + (c.resistance / (w * c.inductance)) ** 2))
        assert float(cr.lift0.xreplace(val)) == pytest.approx(eq3, rel=1e-13)


def test_the_report_states_h1_as_minus_i_dh0_domega() -> None:
    """The report's circuit-lag section writes H1 = -i dH0/domega: the identity holds for
    the steady response written here, H0 = i w / (R + i w L) (eq 3's), and the derived H1;
    the plain dH0/domega it said before does not."""
    from pathlib import Path

    import sympy as sp

    from maglevgen.derive.circuit_lag import circuit_response

    cr = circuit_response()
    R, L, w = cr.R, cr.L, cr.omega
    h0 = sp.I * w / (R + sp.I * w * L)
    assert sp.simplify(cr.H0 - h0) == 0
    assert sp.simplify(cr.H1 - (-sp.I) * sp.diff(h0, w)) == 0
    assert sp.simplify(cr.H1 - sp.diff(h0, w)) != 0
    tex = (Path(__file__).resolve().parents[1] / "templates" / "report"
           / "circuit_lag.tex.j2").read_text()
    assert r"$H_1 = -i\,\mathrm{d}H_0/\mathrm{d}\omega$" in tex
