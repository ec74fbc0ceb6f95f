"""The estimator's model at the tick, its observability and its Kalman filter
(maglevgen/control/plant.py), against python-control: `control.c2d` (ZOH) of the C's
Jacobians with the sensors' linearisation from the numpy geometry of
tests/independent_reference.py (central differences), `control.obsv`, `control.dlqe`, and a
long noisy run of the filter against the DARE's covariance."""

from __future__ import annotations

import control
import independent_reference as ref
import numpy as np
import pytest

from maglevgen.analyses.simulate import Weights, operating_point
from maglevgen.control.estimation import (
    NEEDED_STATES,
    EstimatorPoint,
    SensorLayout,
    continuous_equivalent,
    estimation_failures,
    estimator_model,
    estimator_points,
    kalman,
    observability,
    whole_loop,
)
from maglevgen.control.sampled import LOOP_STATES, loop_gain, speed_gain
from maglevgen.derive import conventions as cv
from maglevgen.errors import InputError
from maglevgen.params import load_params

SPEEDS = (10.0, 20.0, 40.0)


def _op(sim_lib, carriage, speed: float):
    return operating_point(sim_lib, carriage.p, speed, carriage.params.track.min_gap,
                           Weights.of(carriage.params))


def _reference_model(carriage, op, params):
    """(Phi, C scaled by the noise, the 12-state C) written here: python-control's ZOH of
    (A, B), the readings' Jacobian by central differences of the numpy geometry (the
    accelerometer's xdot = A dx + B du), each reading's noise from the file's numbers."""
    h = 1.0 / params.control.spec.tick_rate
    sysd = control.c2d(control.ss(op.A, op.B, np.eye(12), 0), h, method="zoh")
    # the readings are linear in xdot: their Jacobian in x does not depend on it
    Hx, Hd = ref.sensor_jacobians_fd(params, op.x_trim, np.zeros(12))
    C = Hx + Hd @ op.A
    s = params.sensors
    sig2 = ([s.gap.noise**2 + s.gap.resolution**2 / 12] * len(s.gap_sensors)
            + [s.imu.gyro_noise**2 * np.pi / 2 * s.imu.anti_alias] * 3
            + [s.imu.accel_noise**2 * np.pi / 2 * s.imu.anti_alias] * 3
            + [s.track.noise**2 + s.track.resolution**2 / 12])
    return np.asarray(sysd.A), C / np.sqrt(np.array(sig2))[:, None], C


@pytest.mark.parametrize("speed", SPEEDS)
def test_observability_equals_control_obsv(sim_lib, carriage, speed: float) -> None:
    params = carriage.params
    op = _op(sim_lib, carriage, speed)
    model = estimator_model(sim_lib, carriage.p, op, params)
    obs = observability(model)
    Phi, C_scaled, C = _reference_model(carriage, op, params)
    np.testing.assert_allclose(model.C[:, :12], C, rtol=1e-6, atol=1e-6)
    Ob = control.obsv(Phi, C_scaled)
    s = np.linalg.svd(Ob, compute_uv=False)
    assert obs.rank == np.linalg.matrix_rank(Ob) == 12
    np.testing.assert_allclose(obs.singular_values, s, rtol=1e-5, atol=1e-6 * s[0])
    assert obs.unobservable == ()


def test_face_centre_gaps_alone_leave_roll_and_lateral_apart_only_by_their_dynamics(
        sim_lib, carriage) -> None:
    """Face-centre gap sensors without an IMU: their readings' Jacobian in the pose has rank
    4 (roll and a lateral shift move them alike; numpy's rank of the numpy geometry's
    Jacobian), python-control's observability matrix of the tick model is the package's
    (rank and singular values), and the Kalman filter's roll error (from control.dlqe's P)
    is more than a tenth of the 5 mrad the spec allows: the verdict names roll and why."""
    overrides = [f'sensors.gap_sensors.{n}.across=0.0' for n in ("g3l", "g3r", "g6l", "g6r")]
    loaded = load_params(overrides=overrides)
    params = loaded.params.model_copy(update={"sensors": loaded.params.sensors.model_copy(
        update={"imu": None})})
    op = _op(sim_lib, carriage, 20.0)
    Hx, _ = ref.sensor_jacobians_fd(params, op.x_trim, np.zeros(12))
    pose = [cv.STATE_INDEX[s] for s in ("y", "z", "phi", "theta", "psi")]
    assert np.linalg.matrix_rank(Hx[:-1, pose], tol=1e-9) == 4
    layout = SensorLayout.of(params)
    model = estimator_model(sim_lib, carriage.p, op, params, layout)
    obs = observability(model)
    Phi = np.asarray(control.c2d(control.ss(op.A, op.B, np.eye(12), 0), 1e-3).A)
    Ob = control.obsv(Phi, model.C[:, :12] / np.sqrt(layout.variances)[:, None])
    assert obs.rank == np.linalg.matrix_rank(Ob)
    np.testing.assert_allclose(obs.singular_values, np.linalg.svd(Ob, compute_uv=False),
                               rtol=1e-6, atol=1e-9 * obs.singular_values[0])
    _, P, _ = control.dlqe(model.Phi, np.eye(model.Phi.shape[0]), model.C, model.Q, model.R)
    S = model.C @ P @ model.C.T + model.R
    P_upd = P - P @ model.C.T @ np.linalg.solve(S, model.C @ P)
    i = cv.STATE_INDEX["phi"]
    assert np.sqrt(P_upd[i, i]) > 0.1 * params.control.spec.max_deviation.phi
    point = EstimatorPoint(model, obs, kalman(model))
    assert point.error_std["phi"] == pytest.approx(np.sqrt(P_upd[i, i]), rel=1e-6)
    failures = estimation_failures([point], params)
    assert any(f.startswith("phi: ") and "face centres only" in f and "no gyro" in f
               for f in failures), failures


def test_a_set_that_sees_no_pose_is_refused_naming_the_states(sim_lib, carriage) -> None:
    """The track sensor alone: the antisymmetric states (lateral, roll, yaw and their rates)
    are in the null space of python-control's observability matrix (the heave and pitch show
    in the drag, hence in the track position); InputError (exit 2) names exactly the needed
    ones."""
    params = carriage.params
    params = params.model_copy(update={"sensors": params.sensors.model_copy(
        update={"gap": None, "gap_sensors": {}, "imu": None})})
    op = _op(sim_lib, carriage, 20.0)
    model = estimator_model(sim_lib, carriage.p, op, params)
    Ob = control.obsv(model.Phi[:12, :12], model.C[:, :12])
    Vt = np.linalg.svd(Ob)[2]
    rank = np.linalg.matrix_rank(Ob)
    blind = {cv.STATE_NAMES[i] for i in range(12)
             if np.linalg.norm(Vt[rank:, i]) > 1e-6} & set(NEEDED_STATES)
    assert {"y", "phi", "psi", "v", "p", "r"} <= blind
    with pytest.raises(InputError) as exc:
        estimator_points(sim_lib, carriage.p, params, [op])
    msg = str(exc.value)
    assert "\n" not in msg and "20 m/s" in msg and f"rank {rank} of 12" in msg
    named = {part.split(":")[0].strip() for part in msg.split("): ", 1)[1].split(";")}
    assert named == blind, msg
    assert all(f"{b}: not seen by the track sensor" in msg for b in blind)


@pytest.mark.parametrize("speed", SPEEDS)
def test_kalman_gains_equal_control_dlqe(sim_lib, carriage, speed: float) -> None:
    op = _op(sim_lib, carriage, speed)
    model = estimator_model(sim_lib, carriage.p, op, carriage.params)
    design = kalman(model)
    L, P, _ = control.dlqe(model.Phi, np.eye(model.Phi.shape[0]), model.C, model.Q, model.R)
    np.testing.assert_allclose(design.L, L, rtol=1e-6, atol=1e-9 * np.max(np.abs(L)))
    np.testing.assert_allclose(design.P, P, rtol=1e-6, atol=1e-9 * np.max(np.abs(P)))
    # the error dynamics are stable: the predictor's eigenvalues inside the unit circle
    assert np.max(np.abs(np.linalg.eigvals(model.Phi - design.L @ model.C))) < 1.0


@pytest.mark.slow
def test_a_long_noisy_run_has_the_dare_covariance(sim_lib, carriage) -> None:
    """The filter's a-priori error in a run driven by noise of covariances Q and R drawn here
    (the plant open loop grows without bound at some speeds, so the run follows the error,
    e+ = Phi e + w - L (C e + v), which no input enters): the variance of every needed state
    equals the DARE's P within four standard errors of 40 batch means (the errors are
    correlated over ticks), each standard error under 5 % of P."""
    op = _op(sim_lib, carriage, 20.0)
    model = estimator_model(sim_lib, carriage.p, op, carriage.params)
    design = kalman(model)
    n_z, n_y = model.Phi.shape[0], model.C.shape[0]
    rng = np.random.default_rng(2026)
    lam, V = np.linalg.eigh(model.Q[:12, :12])
    Lq = V * np.sqrt(np.clip(lam, 0.0, None))  # Q = Lq Lq' (Q is near singular)
    Lr = np.sqrt(np.diag(model.R))
    steps, batches = 200_000, 40
    e = np.zeros(n_z)
    err2 = np.zeros((steps, 12))
    F = model.Phi - design.L @ model.C
    for k in range(steps):
        err2[k] = e[:12] ** 2
        w = np.zeros(n_z)
        w[:12] = Lq @ rng.standard_normal(12)
        e = F @ e + w - design.L @ (Lr * rng.standard_normal(n_y))
    means = err2[steps // 10:].reshape(batches, -1, 12).mean(axis=1)
    est, se = means.mean(axis=0), means.std(axis=0, ddof=1) / np.sqrt(batches)
    for name in NEEDED_STATES:
        i = cv.STATE_INDEX[name]
        assert se[i] < 0.05 * design.P[i, i], (name, se[i], design.P[i, i])
        assert abs(est[i] - design.P[i, i]) < 4 * se[i], (name, est[i], design.P[i, i], se[i])


@pytest.mark.parametrize("speed", (10.0, 40.0))
def test_whole_loop_equals_the_loop_assembled_on_the_estimate(sim_lib, carriage,
                                                              speed: float) -> None:
    """The output-feedback loop assembled here on (z, z_hat[k|k-1]) with control.dlqe's P
    (M = P C' (C P C' + R)^-1) and the loop's gain on the estimate written here: its
    eigenvalues are the package's whole loop's and the track position's 1."""
    params = carriage.params
    op = _op(sim_lib, carriage, speed)
    model = estimator_model(sim_lib, carriage.p, op, params)
    k_v = speed_gain(params.vehicle.mass, op.trim_drag_slope,
                     params.control.spec.speed_bandwidth)
    K = loop_gain(op, "spec", k_v)
    n = model.Phi.shape[0]
    K_u = np.zeros((op.B.shape[1], n))
    cols = [cv.STATE_INDEX[s] for s in LOOP_STATES]  # the estimator holds all 12, x first
    K_u[0, cols], K_u[1:, cols] = K[5], op.allocation @ K[:5]
    _, P, _ = control.dlqe(model.Phi, np.eye(n), model.C, model.Q, model.R)
    M = P @ model.C.T @ np.linalg.inv(model.C @ P @ model.C.T + model.R)
    post_z, post_hat = M @ model.C, np.eye(n) - M @ model.C  # z_hat[k|k] from z, z_hat
    loop = np.block([
        [model.Phi - model.Gamma @ K_u @ post_z, -model.Gamma @ K_u @ post_hat],
        [(model.Phi - model.Gamma @ K_u) @ post_z, (model.Phi - model.Gamma @ K_u) @ post_hat]])
    ref_z = np.linalg.eigvals(loop)
    ref_z = np.delete(ref_z, np.argmin(np.abs(ref_z - 1.0)))
    got = np.linalg.eigvals(whole_loop(model, kalman(model), K_u))
    key = lambda z: (round(z.real, 6), round(abs(z.imag), 6))  # noqa: E731
    np.testing.assert_allclose(sorted(got, key=key), sorted(ref_z, key=key), atol=1e-7)
    s = continuous_equivalent(whole_loop(model, kalman(model), K_u),
                              1.0 / params.control.spec.tick_rate)
    s = s[np.isfinite(s.real)]
    assert np.max(s.real) < -params.control.spec.min_decay_rate


def test_loop_as_built_with_the_speed_integral_separates(sim_lib, carriage) -> None:
    """The output-feedback loop as built with the speed integral (`loop_as_built`, the default
    loop's k_v and k_i, the `spec` design at the tick, 2 ms lag, one tick of delay) has the
    separation principle's eigenvalues: the full-state loop's (control.plant.LoopPlant's
    closed loop) and the filter's, Phi (I - M C), within 1e-7; and the speed-loop modes its
    mask picks include the integral's slow real pole."""
    from maglevgen.analyses.envelope import loop_setting
    from maglevgen.control.estimation import loop_as_built, loop_as_built_speed_states
    from maglevgen.control.plant import LoopPlant
    from maglevgen.control.sampled import Tick

    params = carriage.params
    op = _op(sim_lib, carriage, 20.0)
    setting = loop_setting(carriage, [op])
    assert setting.speed_integral > 0
    tau = float(params.actuators.time_constant)
    plant = LoopPlant(op, Tick.of(params), tau, setting.speed_gain, setting.speed_integral)
    gains = plant.design()
    model = estimator_model(sim_lib, carriage.p, op, params, tau=tau)
    design = kalman(model)
    loop = loop_as_built(model, design, plant, gains)
    full = np.linalg.eigvals(plant.closed_loop(gains))
    filt = np.linalg.eigvals(model.Phi @ (np.eye(model.Phi.shape[0]) - design.M @ model.C))
    # the two layouts hold the commands in flight differently (the generalized forces, or
    # the array forces): they differ by eigenvalues at 0 only, left out on both sides
    ref_z = np.concatenate([full, filt])
    ref_z = ref_z[np.abs(ref_z) > 1e-4]
    got = np.linalg.eigvals(loop)
    got = got[np.abs(got) > 1e-4]
    key = lambda z: (round(z.real, 6), round(abs(z.imag), 6))  # noqa: E731
    assert got.size == ref_z.size
    np.testing.assert_allclose(sorted(got, key=key), sorted(ref_z, key=key), atol=1e-7)
    slow = ref_z[np.argmax(np.abs(ref_z))]  # the integral's pole, the loop's slowest
    assert abs(slow.imag) < 1e-12 and np.log(slow.real) * params.control.spec.tick_rate < -1
    mask = loop_as_built_speed_states(model, 5, 1)
    assert mask.size == loop.shape[0] and mask[-1]


@pytest.mark.slow
def test_a_noisy_hold_estimates_the_pose_as_the_filter_predicts(sim_lib, carriage) -> None:
    """The output-feedback loop on the nonlinear C plant with the sensors' noise (no process
    noise: the filter's P, from SciPy's DARE on the linear model with it, bounds the error
    from above): each axis position's estimation error RMS over 3 s lies between 0.6 and 1.1
    times sqrt of the updated P (the DARE's own prediction for the error the noise makes)."""
    from maglevgen.analyses.output_feedback import noisy_hold

    params = carriage.params
    op = _op(sim_lib, carriage, 15.7)  # a speed whose tick advance is no whole encoder step
    hold = noisy_hold(sim_lib, carriage.p, params, op, t_end=3.0, seed=5)
    model = estimator_model(sim_lib, carriage.p, op, params)
    design = kalman(model)
    S = model.C @ design.P @ model.C.T + model.R
    P_upd = design.P - design.P @ model.C.T @ np.linalg.solve(S, model.C @ design.P)
    for state in cv.Q_STATES:
        i = model.states.index(state)
        ratio = hold.estimation_rms[state] / np.sqrt(P_upd[i, i])
        assert 0.6 < ratio < 1.1, (state, ratio)
    assert hold.min_gap > params.track.min_gap


@pytest.mark.slow
def test_the_kalman_table_holds_dlqe_gains_across_the_envelope(sim_lib, carriage) -> None:
    """The update's gain scheduled over speed in the controller's table machinery (a Chebyshev
    series in 1/v): at speeds between its nodes it equals M from control.dlqe's P within the
    table's bound, relative to M's largest entry."""
    from maglevgen.analyses.envelope import speed_range
    from maglevgen.control.estimation import kalman_table
    from maglevgen.control.schedule import GAIN_TABLE_BOUND

    params = carriage.params
    v_min, v_max = speed_range(carriage)
    table = kalman_table(sim_lib, carriage.p, params, lambda v: _op(sim_lib, carriage, v),
                         v_min, v_max)
    rng = np.random.default_rng(49)
    for v in rng.uniform(v_min, v_max, 3):
        model = estimator_model(sim_lib, carriage.p, _op(sim_lib, carriage, float(v)), params)
        n = model.Phi.shape[0]
        _, P, _ = control.dlqe(model.Phi, np.eye(n), model.C, model.Q, model.R)
        M = P @ model.C.T @ np.linalg.inv(model.C @ P @ model.C.T + model.R)
        got = table(float(v)).reshape(12, -1, order="F")
        assert np.max(np.abs(got - M[:12])) <= GAIN_TABLE_BOUND * np.max(np.abs(M[:12])), v


def test_a_noisy_hold_that_reaches_the_track_stops_there(sim_lib, carriage) -> None:
    """Positive position feedback far above the arrays' stiffness (2e6 N/m, N m/rad on every
    axis, with a budget that lets it act): the carriage hits the track within a few ticks. The
    hold stops at the tick a gap reaches zero instead of integrating through the rail, and
    says so: diverged at that time, contact, not settled, its metrics those of the ticks
    before (finite)."""
    from maglevgen.analyses.output_feedback import noisy_hold
    from maglevgen.control.plant import LoopDesign

    params = carriage.params.model_copy(update={
        "actuators": carriage.params.actuators.model_copy(update={"force_limit": 1e5}),
        "control": carriage.params.control.model_copy(update={
            "spec": carriage.params.control.spec.model_copy(update={"force_budget": 1e5})})})
    op = _op(sim_lib, carriage, 20.0)
    zero = np.zeros((5, 5))
    hold = noisy_hold(sim_lib, carriage.p, params, op, t_end=1.0, seed=3,
                      gains=LoopDesign(-2e6 * np.eye(5), zero, zero, zero))
    assert hold.diverged is not None and 0 < hold.diverged < 0.1
    assert hold.min_gap <= 0 and not hold.settled
    failures = hold.failures(params.track.min_gap)
    assert failures[0] == f"diverged at {hold.diverged:.3g} s" and "contact" in failures[1]
    assert np.all(np.isfinite(hold.force_rms)) and np.all(np.isfinite(hold.gap_rms))
    assert "DIVERGED" in hold.summary()
