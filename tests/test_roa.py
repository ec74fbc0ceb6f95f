"""The sampled region of attraction (maglevgen.analyses.roa, maglev_lyapunov_batch).

References: a two-state system whose region is known in closed form (x1' = -x1 + x1^3,
x2' = -x2: V = x1^2 + x2^2 decreases exactly inside x1^2 < 1 on each level, so the largest
level is c = 1) with scipy's solve_ivp on either side of it; for the carriage, scipy's CARE
for P, the lambdified SymPy model (derive.numeric) for dV/dt at fresh random states, the
test's own gap geometry (independent_reference.contact_gaps) and solve_ivp on the SymPy model
for the runs from inside and outside the set.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
from independent_reference import contact_gaps
from scipy.integrate import solve_ivp

from maglevgen.analyses import roa
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.lqr import weighted_qr
from maglevgen.control.operating import AXIS_STATES, REDUCED_INDEX
from maglevgen.control.spec import spec_weights

SMALL = roa.Sampling(directions=60, radii=8, bisections=4, confirm=0)


def test_two_state_level_brackets_the_known_one() -> None:
    """x1' = -x1 + x1^3, x2' = -x2, V = x1^2 + x2^2: dV/dt = -2 x1^2 (1 - x1^2) - 2 x2^2 is
    negative on {V = c} exactly when c < 1 (the worst point x2 = 0); the search brackets
    c = 1 within its stated radial resolution, and solve_ivp confirms the region: just
    inside along x1 the state returns, just outside it escapes."""
    def failures(dx):
        x1, x2 = dx[:, 0], dx[:, 1]
        vd = 2 * x1 * (-x1 + x1**3) + 2 * x2 * (-x2)
        return ~(vd < 0), np.zeros(len(dx), bool), vd

    theta = np.random.default_rng(3).uniform(0, 2 * np.pi, 200)
    D = np.vstack([[1.0, 0.0], [-1.0, 0.0], np.column_stack([np.cos(theta), np.sin(theta)])])
    s = roa.Sampling(directions=200, radii=16, bisections=8)
    lo, hi, limit, _ = roa.sampled_search(failures, D, 0.1, s)
    assert limit == "dV/dt"
    assert lo**2 <= 1.0 <= hi**2
    assert hi / lo - 1 < 0.01  # 16 radii then 8 bisections: 1/16/2^8 of the top shell
    np.testing.assert_allclose(lo**2, 1.0, rtol=0.02)

    def run(x0):
        sol = solve_ivp(lambda _t, x: [-x[0] + x[0] ** 3, -x[1]], (0, 5), x0, rtol=1e-10,
                        events=lambda _t, x: abs(x[0]) - 10)
        return float(np.hypot(*sol.y[:, -1]))

    assert run([0.95 * lo, 0.0]) < 0.05
    assert run([1.05 * hi, 0.0]) > 5


def test_p_is_the_spec_designs_riccati_solution(op) -> None:
    """For the spec controller the Lyapunov P equals scipy's CARE solution of its weights."""
    P = roa.lyapunov_matrix(op, "spec")
    A_r, B_g = op.reduced
    Q, R = weighted_qr(op.rate_map, *spec_weights(op))
    P_care = scipy.linalg.solve_continuous_are(A_r, B_g, Q, R)
    np.testing.assert_allclose(P, P_care, rtol=1e-6, atol=1e-9 * np.abs(P_care).max())


def _closed_loop_rhs(carriage, op, controller: str):
    """The continuous closed loop on the lambdified SymPy model (not the generated C)."""
    f = carriage.functions
    K_pos, K_rate = op.gains(controller)
    idx = list(AXIS_STATES)
    u = np.zeros(op.allocation.shape[0] + 1)
    u[0] = op.f_prop

    def rhs(_t, x):
        rates = f.kin(x).ravel()[idx]
        u[1:] = op.allocation @ (-(K_pos @ (x[idx] - op.a_trim) + K_rate @ rates))
        return f.xdot(x, u, carriage.p).ravel()

    return rhs


@pytest.fixture(scope="module")
def region(sim_lib, carriage, op):
    return roa.speed_region(sim_lib, carriage.p, op, "spec", carriage.params.track.min_gap,
                            SMALL)


def test_carriage_region_holds_on_the_sympy_model(region, sim_lib, carriage, op) -> None:
    """At fresh random states in {V <= c} (another seed, uniform in the ellipsoid's volume)
    dV/dt < 0 on the lambdified model and every gap (the test's geometry) is above min_gap;
    the C's V and dV/dt agree with numpy on the same model."""
    assert region.level > 0 and region.limit in ("dV/dt", "contact")
    rhs = _closed_loop_rhs(carriage, op, "spec")
    P, c, n = region.P, region.level, len(REDUCED_INDEX)
    L = np.linalg.cholesky(P)
    rng = np.random.default_rng(12345)
    z = rng.standard_normal((40, n))
    z *= (rng.uniform(size=(40, 1)) ** (1 / n)) / np.linalg.norm(z, axis=1, keepdims=True)
    dx = np.sqrt(c) * np.linalg.solve(L.T, z.T).T
    ev = roa.Evaluator(sim_lib, carriage.p, op, "spec", P, SMALL)
    V_c, Vd_c, _ = ev(dx)
    min_gap = carriage.params.track.min_gap
    for k in range(dx.shape[0]):
        x = op.x_trim.copy()
        x[list(REDUCED_INDEX)] += dx[k]
        vd = 2 * dx[k] @ P @ rhs(0.0, x)[list(REDUCED_INDEX)]
        assert vd < 0
        assert np.min(contact_gaps(carriage.params, x[1:6])) > min_gap
        np.testing.assert_allclose(V_c[k], dx[k] @ P @ dx[k], rtol=1e-10)
        np.testing.assert_allclose(Vd_c[k], vd, rtol=1e-6, atol=1e-9 * abs(vd) + 1e-12)


def _run(carriage, op, x0: np.ndarray, t_end: float) -> tuple[float, bool]:
    """(final deviation norm / initial, contact) of a solve_ivp run on the SymPy model."""
    rhs = _closed_loop_rhs(carriage, op, "spec")
    min_gap = carriage.params.track.min_gap

    def contact(_t, x):
        return np.min(contact_gaps(carriage.params, x[1:6])) - min_gap

    contact.terminal = True
    sol = solve_ivp(rhs, (0, t_end), x0, method="LSODA", rtol=1e-8, atol=1e-11,
                    events=contact)
    hit = sol.status == 1 or np.min(contact_gaps(carriage.params, x0[1:6])) <= min_gap
    idx = list(REDUCED_INDEX)
    d0 = np.linalg.norm(x0[idx] - op.x_trim[idx])
    return float(np.linalg.norm(sol.y[idx, -1] - op.x_trim[idx]) / d0), hit


@pytest.mark.slow
def test_inside_settles_outside_along_the_weakest_direction_fails(region, carriage,
                                                                   op) -> None:
    """From just inside the level (0.95 of the boundary along the default disturbance and
    along the weakest axis alone) the SymPy model returns to trim without contact; at 1.5
    times the boundary along the weakest sampled direction (the first that failed) a gap
    of the test's geometry is below min_gap or dV/dt >= 0 on the SymPy model. ~15 s."""
    idx = list(REDUCED_INDEX)
    d0 = roa.default_deviation()
    e = np.zeros(len(idx))
    e[roa.AXIS_NAMES.index(region.weakest)] = 0.95 * region.extents[region.weakest]
    for dx in (0.95 * d0 / region.multiple_of(d0), e):
        x0 = op.x_trim.copy()
        x0[idx] += dx
        ratio, hit = _run(carriage, op, x0, 0.3)
        assert not hit and ratio < 0.05, (dx, ratio, hit)
    assert region.worst is not None
    x0 = op.x_trim.copy()
    x0[idx] += 1.5 * np.sqrt(region.level) * region.worst
    touches = np.min(contact_gaps(carriage.params, x0[1:6])) <= carriage.params.track.min_gap
    dx = x0[idx] - op.x_trim[idx]
    rising = 2 * dx @ region.P @ _closed_loop_rhs(carriage, op, "spec")(0.0, x0)[idx] >= 0
    assert touches or rising


def test_level_invariant_to_batch_and_workers(sim_lib, carriage, op, region) -> None:
    """The same seed gives the same level whatever the batch size and thread count."""
    other = roa.speed_region(sim_lib, carriage.p, op, "spec", carriage.params.track.min_gap,
                             roa.Sampling(directions=60, radii=8, bisections=4, confirm=0,
                                          batch=37, workers=2))
    assert other.level == region.level and other.failing_level == region.failing_level
    assert other.states == region.states


def test_batch_refuses_bad_arguments(sim_lib, carriage, op) -> None:
    """maglev_lyapunov_batch refuses a non-finite P (MAGLEV_SIM_ARGUMENT: a RuntimeError
    here, the callers validate first) and gives NaN for a non-finite state row."""
    P = np.eye(12)
    K_pos, K_rate = (k.ravel(order="F") for k in op.gains("spec"))
    X = np.tile(op.x_trim, (2, 1))
    X[1, 2] = np.nan
    V, Vd, g = sim_lib.lyapunov_batch(X, op.f_prop, K_pos, K_rate, op.a_trim, op.x_trim, P,
                                      carriage.p, op.gaps.size)
    assert V[0] == 0 and np.isnan(V[1]) and np.isnan(Vd[1]) and np.all(np.isnan(g[1]))
    np.testing.assert_allclose(g[0], contact_gaps(carriage.params, op.x_trim[1:6]), rtol=1e-9)
    P[0, 0] = np.inf
    with pytest.raises(RuntimeError, match="MAGLEV_SIM_ARGUMENT"):
        sim_lib.lyapunov_batch(X, op.f_prop, K_pos, K_rate, op.a_trim, op.x_trim, P,
                               carriage.p, op.gaps.size)


def test_montecarlo_column_places_each_sample_against_the_region(sim_lib) -> None:
    """Each Monte-Carlo sample carries its initial deviation as a multiple of the nominal
    region at its speed: finite and positive for the spec design, and no sample inside the
    region (multiple < 1) fails its run (the runs are the reference: a failure there would
    contradict the region)."""
    from maglevgen.analyses.montecarlo import FAILURES, make_study, run_local
    from maglevgen.carriage import DerivedCarriage
    from maglevgen.params import load_params

    carriage = DerivedCarriage(load_params(None, ["tolerances.speed=[15.0, 25.0]"]))
    study = make_study(Plant(carriage, sim_lib), ("spec",), t_end=0.4, dt=1e-3, seed=3)
    cols = run_local(study, 6, workers=1)
    m = cols["region_multiple"]
    assert np.all(np.isfinite(m)) and np.all(m > 0)
    inside = m < 1
    assert inside.any()
    assert not np.any(np.isin(cols["status"][inside], FAILURES))


@pytest.mark.parametrize("argv, key", [
    (["roa", "--samples", "0"], "--samples 0"),
    (["roa", "--speeds", "0"], "--speeds 0"),
    (["roa", "--controller", "bogus"], "--controller 'bogus'"),
    (["roa", "--workers", "0"], "--workers 0"),
])
def test_bad_options_are_one_line_exit_2(argv, key, capsys, private_cache) -> None:
    """Bad input: exit 2 and one line on stderr naming the option and its value."""
    from maglevgen.cli import main

    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and key in err[0], err


def _gaps_many(prm, Q: np.ndarray) -> np.ndarray:
    """independent_reference.contact_gaps at every row of Q (y, z, phi, theta, psi),
    vectorised: each face's least corner gap nominal_gap + n . (X + (R - I) b)."""
    from independent_reference import _face_axes

    y, z, phi, th, psi = Q.T
    c, s = np.cos, np.sin
    one, zero = np.ones_like(y), np.zeros_like(y)
    Rz = np.stack([np.stack([c(psi), -s(psi), zero], -1), np.stack([s(psi), c(psi), zero], -1),
                   np.stack([zero, zero, one], -1)], -2)
    Ry = np.stack([np.stack([c(th), zero, s(th)], -1), np.stack([zero, one, zero], -1),
                   np.stack([-s(th), zero, c(th)], -1)], -2)
    Rx = np.stack([np.stack([one, zero, zero], -1), np.stack([zero, c(phi), -s(phi)], -1),
                   np.stack([zero, s(phi), c(phi)], -1)], -2)
    R = Rz @ Ry @ Rx - np.eye(3)
    X = np.stack([zero, y, z], -1)
    out = []
    for arr in prm.arrays.values():
        a, n = np.array(arr.position), np.array(arr.normal)
        across, along = _face_axes(n)
        half_l, half_w = arr.circuits * prm.circuit.pitch / 2, prm.halbach.width / 2
        corners = [a + i * half_w * across + j * half_l * along for i in (-1, 1)
                   for j in (-1, 1)]
        out.append(np.min([arr.nominal_gap + (X + R @ b) @ n for b in corners], axis=0))
    return np.stack(out, -1)


def _reduced_gaps(prm, op, dx: np.ndarray) -> np.ndarray:
    """The reference gaps at trim + the rows of dx (10 reduced deviations)."""
    X = np.tile(op.x_trim, (dx.shape[0], 1))
    X[:, list(REDUCED_INDEX)] += dx
    return _gaps_many(prm, X[:, 1:6])


@pytest.fixture(scope="module")
def speeds_ops(sim_lib, carriage):

    v_min, v_max = Plant(carriage, sim_lib).speed_range
    return Plant(carriage, sim_lib).points([v_min, 20.9, v_max])


def test_contact_level_is_the_closed_form_on_linearised_gaps(speeds_ops, carriage) -> None:
    """On the gaps linearised at trim (g0 + A dx, A by central differences of the test's own
    geometry) the contact-limited level is the closed form: min over {V <= c} of a'dx is
    -sqrt(c a'P^-1 a), so gap j reaches min_gap at c_j = (g0_j - min_gap)^2 / (a_j'P^-1 a_j);
    the level is the least c_j and the state returned lies on {V = c} at min_gap."""
    prm, min_gap = carriage.params, carriage.params.track.min_gap
    for op in speeds_ops:
        P = roa.lyapunov_matrix(op, "spec")
        n = P.shape[0]
        g0 = _reduced_gaps(prm, op, np.zeros((1, n)))[0]
        h = 1e-7
        A = np.column_stack([(_reduced_gaps(prm, op, h * e[None, :])[0]
                              - _reduced_gaps(prm, op, -h * e[None, :])[0]) / (2 * h)
                             for e in np.eye(n)])
        Pinv = np.linalg.inv(P)
        expected = min((g0[j] - min_gap) ** 2 / (A[j] @ Pinv @ A[j]) for j in range(g0.size))
        c, touch = roa.contact_level(lambda dx, g0=g0, A=A: g0 + dx @ A.T, P, min_gap)
        assert c == pytest.approx(expected, rel=1e-6), op.speed
        assert touch @ P @ touch == pytest.approx(c, rel=1e-9)
        assert np.min(g0 + A @ touch) == pytest.approx(min_gap, abs=1e-12)


@pytest.mark.slow
def test_no_state_of_the_contact_limited_set_is_in_contact(speeds_ops, sim_lib,
                                                           carriage) -> None:
    """The level from the generated gaps against 10^5 states of {V <= c} per speed (half
    uniform in the volume, half on the boundary, where a gap is least), their gaps from the
    test's own geometry: none in contact; the state the level names is in contact (the
    level is not too small); the region `speed_region` reports is at most this level."""
    prm, min_gap = carriage.params, carriage.params.track.min_gap
    rng = np.random.default_rng(2024)
    for op in speeds_ops[:2]:
        P = roa.lyapunov_matrix(op, "spec")
        n = P.shape[0]
        ev = roa.Evaluator(sim_lib, carriage.p, op, "spec", P, SMALL)
        c, touch = roa.contact_level(lambda dx, ev=ev: ev.all_gaps(dx)[2], P, min_gap)
        L = np.linalg.cholesky(P)
        z = rng.standard_normal((100_000, n))
        z /= np.linalg.norm(z, axis=1, keepdims=True)
        z[:50_000] *= rng.uniform(size=(50_000, 1)) ** (1 / n)
        dx = np.sqrt(c) * np.linalg.solve(L.T, z.T).T * (1 - 1e-9)
        g = _reduced_gaps(prm, op, dx)
        assert np.min(g) > min_gap, op.speed
        assert np.min(_reduced_gaps(prm, op, touch[None, :])) <= min_gap + 1e-11
        assert touch @ P @ touch == pytest.approx(c, rel=1e-9)
        region = roa.speed_region(sim_lib, carriage.p, op, "spec", min_gap, SMALL)
        assert region.level <= c * (1 + 1e-12)
