"""The loop as built (maglevgen.control.plant: tick, delay, actuator lag, speed loop), its design
at the tick and its margins (maglevgen.control.margins).

References, each assembled here from the C's Jacobians and the allocation: python-control's
``c2d`` (ZOH) of the plant with the lag written here; ``control.dlqr`` on the design model with
the lag and the delay's states written here; ``control.disk_margins`` on each loop broken at
its actuator, and the multi-loop margin's mu bracketed by a lower bound found here; the delay
margin from the eigenvalues of the loop with extra delay states appended here; the speed
loop's steady error from the final-value theorem on a model written here and from scipy's
solve_ivp.
"""

from __future__ import annotations

import control
import numpy as np
import pytest
import scipy.integrate
import scipy.linalg

from maglevgen.analyses.envelope import loop_setting
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.margins import disk_gain_phase, disk_margins
from maglevgen.control.plant import LoopPlant, speed_loop_gains
from maglevgen.control.sampled import LOOP_STATES, Tick
from maglevgen.control.spec import spec_weights
from maglevgen.derive import conventions as cv

TAU = 2e-3
LOOP_IDX = [cv.STATE_INDEX[s] for s in LOOP_STATES]
REDUCED = ["y", "z", "phi", "theta", "psi", "v", "w", "p", "q", "r"]


def _plant_continuous(op, tau: float) -> tuple[np.ndarray, np.ndarray]:
    """(x, F) with tau F' = F_c - F, inputs (F_c, F_prop): written from op.A, op.B."""
    A = op.A[np.ix_(LOOP_IDX, LOOP_IDX)]
    B_F, b_p = op.B[LOOP_IDX, 1:], op.B[LOOP_IDX, 0]
    n, nf = A.shape[0], B_F.shape[1]
    Ac = np.block([[A, B_F], [np.zeros((nf, n)), -np.eye(nf) / tau]])
    Bc = np.block([[np.zeros((n, nf)), b_p[:, None]],
                   [np.eye(nf) / tau, np.zeros((nf, 1))]])
    return Ac, Bc


@pytest.mark.parametrize("tau", [TAU, 10e-3])
def test_discrete_plant_is_c2d_of_the_lagged_plant(op, tau) -> None:
    tick = Tick(1000.0, 1)
    Ac, Bc = _plant_continuous(op, tau)
    ref = control.c2d(control.ss(Ac, Bc, np.eye(Ac.shape[0]), 0), tick.period, "zoh")
    Phi, Gamma = LoopPlant(op, tick, tau).discrete()
    np.testing.assert_allclose(Phi, ref.A, atol=1e-10 * np.abs(ref.A).max())
    np.testing.assert_allclose(Gamma, ref.B, atol=1e-10 * np.abs(ref.B).max())
    # the lag over one held tick: exp(-h/tau) on the force states (scipy's expm of them alone)
    nf = op.B.shape[1] - 1
    np.testing.assert_allclose(Phi[-nf:, -nf:], scipy.linalg.expm(-np.eye(nf) * tick.period
                                                                  / tau), rtol=1e-12)


@pytest.mark.parametrize("delay", [0, 1, 2])
def test_design_is_dlqr_of_the_zoh_model_with_the_lag_and_the_delay(op, delay) -> None:
    """The gains on (a - a_ref, a'), on the lagged generalized forces and on the commands in
    flight equal python-control's dlqr on the model assembled here."""
    tick = Tick(1000.0, delay)
    A_r = op.A[np.ix_([cv.STATE_INDEX[s] for s in REDUCED], [cv.STATE_INDEX[s] for s in REDUCED])]
    B_g = op.B[[cv.STATE_INDEX[s] for s in REDUCED], 1:] @ op.allocation
    n, m = A_r.shape[0], B_g.shape[1]
    Ac = np.block([[A_r, B_g], [np.zeros((m, n)), -np.eye(m) / TAU]])
    Bc = np.vstack([np.zeros((n, m)), np.eye(m) / TAU])
    sysd = control.c2d(control.ss(Ac, Bc, np.eye(n + m), 0), tick.period, "zoh")
    nc = n + m
    N = nc + delay * m
    Pa, Ga = np.zeros((N, N)), np.zeros((N, m))
    Pa[:nc, :nc] = sysd.A
    if delay == 0:
        Ga[:nc] = sysd.B
    else:
        Pa[:nc, N - m:] = sysd.B
        for j in range(1, delay):
            Pa[nc + j * m:nc + (j + 1) * m, nc + (j - 1) * m:nc + j * m] = np.eye(m)
        Ga[nc:nc + m] = np.eye(m)
    q1, q2, r = spec_weights(op)
    C = op.rate_map
    Q = np.zeros((N, N))
    Q[:n, :n] = np.diag(np.r_[q1, np.zeros(n - 5)]) + C.T @ np.diag(q2) @ C
    K_ref, _, _ = control.dlqr(Pa, Ga, Q, np.diag(r))
    design = LoopPlant(op, tick, TAU).design()
    K_state = design.K_pos @ np.eye(5, n) + design.K_rate @ op.rate_map
    scale = np.abs(K_ref).max()
    np.testing.assert_allclose(K_state, K_ref[:, :n], atol=1e-6 * scale)
    np.testing.assert_allclose(design.K_lag, K_ref[:, n:nc], atol=1e-6 * scale)
    np.testing.assert_allclose(design.K_delay, K_ref[:, nc:], atol=1e-6 * scale)


@pytest.fixture(scope="module")
def loop(carriage, op):
    setting = loop_setting(carriage, [op])
    plant = LoopPlant(op, setting.tick, TAU, setting.speed_gain)
    return plant, plant.design()


def _mu_lower_bound(M: np.ndarray, rng: np.random.Generator) -> float:
    """max over diagonal unitary Q of the spectral radius of Q M: mu itself for independent
    complex scalars (Doyle 1982), any Q a lower bound; a few random starts and Nelder-Mead on
    the phases, written here."""
    import scipy.optimize

    n = M.shape[0]

    def neg(phases: np.ndarray) -> float:
        q = np.exp(1j * np.r_[0.0, phases])
        return -float(np.max(np.abs(np.linalg.eigvals(q[:, None] * M))))

    best = -neg(np.zeros(n - 1))
    for _ in range(6):
        res = scipy.optimize.minimize(neg, rng.uniform(-np.pi, np.pi, n - 1),
                                      method="Nelder-Mead",
                                      options={"maxiter": 4000, "xatol": 1e-8, "fatol": 1e-12})
        best = max(best, -float(res.fun))
    return best


def test_disk_margins_against_python_control_and_mu_bounds(loop) -> None:
    """Loop at a time: each channel's SISO loop with the others closed (assembled here)
    against control.disk_margins on the same frequencies. Multi-loop: python-control needs
    SLICOT (AB13MD) for a MIMO loop; here its mu is bracketed instead: our D-scaled upper bound
    at least the lower bound max_Q rho(Q M) found here, and within 2 % of it at the worst
    frequency (against AB13MD in a run with slycot: 0.78403577 both at v_min)."""
    plant, design = loop
    M, N, C = plant.open_loop(design)
    h = plant.tick.period
    omega = np.logspace(0, np.log10(np.pi / h), 120)
    ours = disk_margins(M, N, C, h, omega)
    for i in range(N.shape[1]):
        others = [j for j in range(N.shape[1]) if j != i]
        Mi = M + N[:, others] @ C[others]
        L_i = control.ss(Mi, N[:, [i]], -C[[i]], 0, dt=h)
        dm_i, dgm_i, dpm_i = control.disk_margins(L_i, omega, skew=0.0)
        assert ours.per_loop[i] == pytest.approx(dm_i, rel=1e-8)
        gm, pm = disk_gain_phase(ours.per_loop[i])
        assert gm == pytest.approx(dgm_i, rel=1e-8) and pm == pytest.approx(dpm_i, rel=1e-8)
    # S - I/2 at the worst frequency, from python-control's frequency response of L = -G
    k = int(np.argmin(ours.alpha_multi))
    L = control.ss(M, N, -C, 0, dt=h)
    resp = L.frequency_response([omega[k]])
    Lk = (resp.magnitude * np.exp(1j * resp.phase))[:, :, 0]
    eye = np.eye(Lk.shape[0])
    Mk = np.linalg.inv(eye + Lk) - eye / 2
    lower = _mu_lower_bound(Mk, np.random.default_rng(1))
    upper = 1.0 / ours.alpha_multi[k]
    assert lower <= upper * (1 + 1e-9)
    assert upper <= 1.02 * lower
    # and every frequency's bound is at least that frequency's largest diagonal entry
    assert np.all(ours.alpha_multi <= ours.alpha_loops.min(axis=0) * (1 + 1e-9))


def test_delay_margin_against_eigenvalues_with_extra_delay_states(loop) -> None:
    """The loop with k extra ticks of the array commands, the queue appended here to the
    open loop (M, N, C): the largest k that keeps every eigenvalue inside the unit circle is
    the one `closed_loop(design, k)` gives, and the default carriage's is at least 2."""
    plant, design = loop
    M, N, C = plant.open_loop(design)
    n, nf = M.shape[0], N.shape[1]

    def radius_here(k: int) -> float:
        if k == 0:
            return float(np.max(np.abs(np.linalg.eigvals(M + N @ C))))
        A = np.zeros((n + k * nf, n + k * nf))
        A[:n, :n] = M
        A[:n, n + (k - 1) * nf:] = N  # the actuators receive the oldest
        A[n:n + nf, :n] = C  # the controller's commands enter the queue
        for j in range(1, k):
            A[n + j * nf:n + (j + 1) * nf, n + (j - 1) * nf:n + j * nf] = np.eye(nf)
        return float(np.max(np.abs(np.linalg.eigvals(A))))

    for k in range(7):
        ours = float(np.max(np.abs(np.linalg.eigvals(plant.closed_loop(design, k)))))
        assert ours == pytest.approx(radius_here(k), rel=1e-9)
    stable = [radius_here(k) < 1 for k in range(7)]
    assert all(stable[:3])  # the spec's 2 extra ticks


def test_margin_formulas() -> None:
    """A disk of size alpha: gain (1 + a/2)/(1 - a/2), phase 2 atan(a/2) (Seiler et al.)."""
    gm, pm = disk_gain_phase(0.75)
    assert 10 ** (gm / 20) == pytest.approx(1.375 / 0.625)
    assert pm == pytest.approx(np.degrees(2 * np.arctan(0.375)))


def test_levitation_and_speed_modes_split_by_participation(loop) -> None:
    """The speed loop's modes are the eigenvalues of the closed loop nearest those of its
    scalar model m s + (slope + k_v) with the tick's delay (written here, a 2-state discrete
    loop); everything else decays faster than the spec's 5 1/s."""
    plant, design = loop
    s, speed = plant.modes(design)
    m = 9.3
    a = -(plant.op.trim_drag_slope) / m
    h = plant.tick.period
    # dV[k+1] = e^{a h} dV + (e^{a h} - 1)/a / m * p[k-1],  p[k] = -k_v dV[k]
    ea = np.exp(a * h)
    A = np.array([[ea, (ea - 1) / a / m], [-plant.k_v, 0.0]])
    z = np.linalg.eigvals(A).astype(complex)
    slow_ref = np.log(z[np.argmax(np.abs(z))]) / h
    slow = s[speed & np.isfinite(s) & (np.abs(s) < 100)]
    assert len(slow) == 1 and abs(slow[0] - slow_ref) < 0.05 * abs(slow_ref)
    assert np.max(s[np.isfinite(s) & ~speed].real) < -5.0


def test_speed_integral_removes_the_steady_error(op, carriage) -> None:
    """A drag the feed-forward misses (dF): the speed error of m V' = -(slope + k_v) dV - k_i xi
    - dF, xi' = dV tends to -dF/(slope + k_v) without the integral (ratio r = 0) and to 0 with
    it (r = 0.5, 1; solve_ivp on the model written here, and the final-value theorem); the
    characteristic polynomial's roots are -b and -r b (numpy.roots); the loop's own closed
    loop with the integral has its speed modes where that polynomial says."""
    m, b = carriage.params.vehicle.mass, carriage.params.control.spec.speed_bandwidth
    slope = op.trim_drag_slope
    dF = 5.0  # [N]
    for ratio in (0.0, 0.5, 1.0):
        k_v, k_i = speed_loop_gains(m, slope, b, ratio)
        if ratio:
            assert np.allclose(np.sort(np.roots([m, slope + k_v, k_i]).real), [-b, -ratio * b],
                               rtol=1e-6)
        else:
            assert k_i == 0 and (slope + k_v) / m == pytest.approx(b, rel=1e-12)

        def rhs(t, y, k_v=k_v, k_i=k_i):
            dV, xi = y
            return [(-(slope + k_v) * dV - k_i * xi - dF) / m, dV]

        sol = scipy.integrate.solve_ivp(rhs, (0, 20.0), [0.0, 0.0], rtol=1e-10, atol=1e-12)
        final = sol.y[0, -1]
        if ratio:
            assert abs(final) < 1e-6  # FVT: s dV(s) -> 0 with the integrator
        else:
            assert final == pytest.approx(-dF / (slope + k_v), rel=1e-6)
    for ratio in (1.0, carriage.params.control.spec.speed_integral_ratio):
        k_v, k_i = speed_loop_gains(m, slope, b, ratio)
        plant = LoopPlant(op, Tick(1000.0, 1), TAU, k_v, k_i)
        s, speed = plant.modes(plant.design())
        # two modes of the speed loop near -b and -r b (the roots move under the coupling and
        # the tick), the pair's sum and product within 10 % of the polynomial's
        pair = np.sort_complex(s[speed & (np.abs(s) < 50)])
        assert len(pair) == 2, pair
        assert abs(np.sum(pair).real / (-(1 + ratio) * b) - 1) < 0.1, (ratio, pair)
        assert abs(np.prod(pair) / (ratio * b**2) - 1) < 0.1, (ratio, pair)


def _reference_loop(op, k_v: float, tau: float, gains: tuple | None = None,
                    k_i: float = 0.0) -> np.ndarray:
    """Eigenvalues (continuous-equivalent) of the loop as built at 1 kHz with one tick of
    delay, assembled here: c2d of the lagged plant (`_plant_continuous`); the controller
    w = -(K_x x + K_q w[k-1] + K_a w_hat) with K from control.dlqr on the design model
    (`_reference_gains`) or ``gains`` = (K_pos, K_rate) alone; w_hat[k+1] = a w_hat +
    (1 - a) w[k-1]; the propulsion -k_v dV - k_i xi, applied a tick late like w, with the
    speed error's integral xi[k+1] = xi[k] + h dV[k] (k_i = 0: no integral)."""
    h = 1e-3
    Ac, Bc = _plant_continuous(op, tau)
    sysd = control.c2d(control.ss(Ac, Bc, np.eye(Ac.shape[0]), 0), h, "zoh")
    Phi, Gam = np.asarray(sysd.A), np.asarray(sysd.B)
    n, nf = 11, Bc.shape[1] - 1
    T = op.allocation
    A = op.A[np.ix_(LOOP_IDX, LOOP_IDX)]
    S, C_rate = np.eye(5, 11), A[:5, :]
    if gains is None:
        Kr, Ka, Kq = _reference_gains(op, tau)
        # the reduced gain on the loop state: through (a, a'), as the firmware writes it
        Mr = np.vstack([np.eye(5, 10), op.rate_map])
        Kp_all = np.linalg.solve(Mr.T, Kr.T).T
        Kx = Kp_all[:, :5] @ S + Kp_all[:, 5:] @ C_rate
    else:
        Kx, Ka, Kq = gains[0] @ S + gains[1] @ C_rate, np.zeros((5, 5)), np.zeros((5, 5))
    vel = op.x_trim[6:9] / np.linalg.norm(op.x_trim[6:9])
    cV = np.zeros(11)
    cV[[10, 5, 6]] = vel
    a = np.exp(-h / tau)
    N = n + nf + 6 + 5 + 1  # plant, (w, p) in flight, w_hat, xi
    X = np.zeros((N, N))
    pl, fw, fp, wh, xi = slice(0, n + nf), slice(n + nf, n + nf + 5), n + nf + 5, slice(
        n + nf + 6, N - 1), N - 1
    X[pl, pl] = Phi
    X[pl, fw] = Gam[:, :nf] @ T
    X[pl, fp] = Gam[:, nf]
    X[fw, :n] = -Kx
    X[fw, fw] = -Kq
    X[fw, wh] = -Ka
    X[fp, :n] = -k_v * cV
    X[wh, wh] = a * np.eye(5)
    X[wh, fw] = (1 - a) * np.eye(5)
    X[fp, xi] = -k_i
    X[xi, :n] = h * cV
    X[xi, xi] = 1.0
    if k_i == 0:  # xi then feeds nothing: leave its unit eigenvalue out
        X = X[:-1, :-1]
    z = np.linalg.eigvals(X).astype(complex)
    z = z[np.abs(z) > 1e-12]
    return np.log(z) / h


def _reference_gains(op, tau: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """control.dlqr on the design model with one tick of delay: (K_body, K_lag, K_delay)."""
    idx = [cv.STATE_INDEX[s] for s in REDUCED]
    A_r = op.A[np.ix_(idx, idx)]
    B_g = op.B[idx, 1:] @ op.allocation
    n, m = 10, 5
    Ac = np.block([[A_r, B_g], [np.zeros((m, n)), -np.eye(m) / tau]])
    Bc = np.vstack([np.zeros((n, m)), np.eye(m) / tau])
    sysd = control.c2d(control.ss(Ac, Bc, np.eye(n + m), 0), 1e-3, "zoh")
    N = n + 2 * m
    Pa, Ga = np.zeros((N, N)), np.zeros((N, m))
    Pa[:n + m, :n + m] = sysd.A
    Pa[:n + m, n + m:] = sysd.B
    Ga[n + m:] = np.eye(m)
    q1, q2, r = spec_weights(op)
    Q = np.zeros((N, N))
    Q[:n, :n] = np.diag(np.r_[q1, np.zeros(5)]) + op.rate_map.T @ np.diag(q2) @ op.rate_map
    K, _, _ = control.dlqr(Pa, Ga, Q, np.diag(r))
    K = np.asarray(K)
    return K[:, :n], K[:, n:n + m], K[:, n + m:]


@pytest.fixture(scope="module")
def default_envelope(carriage, sim_lib):
    from maglevgen.analyses.envelope import compute_envelope

    return compute_envelope(Plant(carriage, sim_lib), 3, controllers=("spec",), other_models=False)


def test_spec_verdict_is_its_design_at_the_tick_on_the_lagged_loop(carriage, sim_lib,
                                                                   default_envelope) -> None:
    """The envelope's loop numbers for `spec` are those of the loop assembled here with the
    2 ms lag and dlqr's gains (smallest damping ratio, largest real part at each speed): it
    meets [control.spec]; its continuous gains lose the damping ratio on the same loop, and
    the sentence on the firmware says both and that the host's firmware loop runs the
    design on the plant with the lag."""

    env = default_envelope
    spec = carriage.params.control.spec
    e = env.controllers["spec"]
    for i, op in enumerate(Plant(carriage, sim_lib).points(env.speeds)):
        s = _reference_loop(op, env.loop.speed_gain, TAU, k_i=env.loop.speed_integral)
        zeta = np.min(-s.real / np.abs(s))
        assert e.sampled_min_damping[i] == pytest.approx(zeta, rel=1e-6)
        assert e.sampled_max_real[i] == pytest.approx(np.max(s.real), rel=1e-6)
        assert zeta >= spec.min_damping_ratio
        s_c = _reference_loop(op, env.loop.speed_gain, TAU, op.gains("spec"),
                              env.loop.speed_integral)
        zeta_c = np.min(-s_c.real / np.abs(s_c))
        assert e.continuous_gains.min_damping[i] == pytest.approx(zeta_c, rel=1e-6)
        assert zeta_c < spec.min_damping_ratio
    assert e.meets_spec and not e.continuous_gains.meets_spec
    said = env.firmware_design("spec")
    assert "2 ms actuator lag" in said and "meets [control.spec]" in said
    assert "the same law (one C source)" in said and "sense tick" in said
    assert "on the plant with the actuator lag" in said
    assert "continuous spec LQR gains on the same loop: FAILS damping ratio >= 0.5" in said
    assert e.margins is not None and "disk margins at the actuators" in e.spec_verdict


@pytest.mark.slow  # a whole build of its own
def test_build_exits_3_naming_a_10_ms_actuator_lag(tmp_path, carriage, sim_lib) -> None:
    """A 10 ms actuator lag: at v_min the multi-loop disk is below the spec's 40 degrees (mu
    at the worst frequency at least the lower bound found here, the disk at most 1/mu); the
    build writes its outputs, exits 3 with one error line naming the controller, the lag and
    the failed margin."""
    import subprocess
    import sys


    v_min, _ = Plant(carriage, sim_lib).speed_range
    (op,) = Plant(carriage, sim_lib).points([v_min])
    setting = loop_setting(carriage, [op])
    plant = LoopPlant(op, setting.tick, 10e-3, setting.speed_gain)
    M, N, C = plant.open_loop(plant.design())
    h = plant.tick.period
    w = disk_margins(M, N, C, h).omega[np.argmin(disk_margins(M, N, C, h).alpha_multi)]
    resp = control.ss(M, N, -C, 0, dt=h).frequency_response([w])
    Lk = (resp.magnitude * np.exp(1j * resp.phase))[:, :, 0]
    eye = np.eye(Lk.shape[0])
    mu = _mu_lower_bound(np.linalg.inv(eye + Lk) - eye / 2, np.random.default_rng(2))
    # mu at least this: the multi-loop disk at most 1/mu, in phase 2 atan(1/(2 mu))
    assert disk_gain_phase(1.0 / mu)[1] < carriage.params.control.spec.min_disk_phase_margin
    out = tmp_path / "b"
    proc = subprocess.run([sys.executable, "-m", "maglevgen.cli", "build", "--no-pdf",
                           "--t-end", "0.5", "--out", str(out), "--set",
                           "actuators.time_constant=0.01"], capture_output=True, text=True)
    assert proc.returncode == 3, proc.stderr
    err = [line for line in proc.stderr.splitlines() if "error" in line]
    assert len(err) == 1, proc.stderr
    assert "'spec'" in err[0] and "SUMMARY.md" in err[0]  # one short line; the whole reason:
    (line,) = [t for t in (out / "SUMMARY.md").read_text().splitlines()
               if t.startswith("Verification failed")]
    assert "'spec'" in line and "10 ms actuator lag" in line
    assert line.lower().count("verification failed") == 1, line  # said once, not twice
    assert "FAILS multi-loop disk phase margin >= 40 deg" in line
