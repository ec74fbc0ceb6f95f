"""The sensing checks of the embedded controller's verdict (maglevgen.analyses.sensing): the
observability and the Kalman filter across the envelope, the whole loop with the estimator,
and the verdict's exit-3 reason for a sensor set that cannot see what the controller needs.

References written here: python-control's ``obsv`` of the noise-scaled model; ``control.dlqe``
on the ZOH model with the lag and the delay assembled here with ``control.c2d`` and the
readings' Jacobian from the numpy geometry of tests/independent_reference.py; the ideal loop
of tests/test_loop_plant.py (``control.c2d`` and ``control.dlqr``); the whole loop's
eigenvalues are those of that loop and of the filter's error (the separation principle).
"""

from __future__ import annotations

import control
import independent_reference as ref
import numpy as np
import pytest
from test_loop_plant import TAU, _reference_loop

from maglevgen.analyses.envelope import compute_envelope
from maglevgen.analyses.verdicts import embedded_verdict
from maglevgen.carriage import DerivedCarriage
from maglevgen.control.carriage_plant import Plant
from maglevgen.derive import conventions as cv
from maglevgen.params import LoadedParams, load_params

SPEEDS = 3  # the envelope's grid in these tests: both ends and the middle


@pytest.fixture(scope="module")
def sensing_envelope(carriage, sim_lib):
    return compute_envelope(Plant(carriage, sim_lib), SPEEDS, controllers=("spec",),
                            other_models=False)


def _reference_filter(params, op, tau: float, h: float = 1e-3, imu: bool = True):
    """(Phi, C, L, R) of the Kalman predictor assembled here (``imu`` False: without the
    IMU's six readings): control.c2d of (dx, F) with
    tau F' = F_c - F, the delay's queue of the dynamics' inputs (one tick), the readings'
    Jacobian by central differences of the numpy geometry (the accelerometer reads
    xdot = A dx + B_F F + b_p F_prop), each reading's variance from the file's numbers, the
    process noise (forces and moments through B and the allocation) by Van Loan's integral
    in scipy; L from control.dlqe."""
    import scipy.linalg

    A, B = op.A, op.B
    n, m = 12, B.shape[1]
    nf = m - 1
    Ac = np.block([[A, B[:, 1:]], [np.zeros((nf, n)), -np.eye(nf) / tau]])
    Bc = np.block([[B[:, :1], np.zeros((n, nf))], [np.zeros((nf, 1)), np.eye(nf) / tau]])
    sysd = control.c2d(control.ss(Ac, Bc, np.eye(n + nf), 0), h, "zoh")
    N = n + nf + m
    Phi = np.zeros((N, N))
    Phi[:n + nf, :n + nf] = sysd.A
    Phi[:n + nf, n + nf:] = sysd.B
    Hx, Hd = ref.sensor_jacobians_fd(params, op.x_trim, np.zeros(12))
    C = np.zeros((Hx.shape[0], N))
    C[:, :n] = Hx + Hd @ A
    C[:, n:n + nf] = Hd @ B[:, 1:]
    C[:, n + nf] = Hd @ B[:, 0]  # the propulsion applied: the queue's oldest
    s = params.sensors
    R = np.diag([s.gap.noise**2 + s.gap.resolution**2 / 12] * len(s.gap_sensors)
                + [s.imu.gyro_noise**2 * np.pi / 2 * s.imu.anti_alias] * 3
                + [s.imu.accel_noise**2 * np.pi / 2 * s.imu.anti_alias] * 3
                + [s.track.noise**2 + s.track.resolution**2 / 12])
    d = s.disturbance
    G = np.vstack([np.column_stack([B[:, 0], B[:, 1:] @ op.allocation]), np.zeros((nf, 6))])
    W = np.diag([d.force**2 / 2] * 3 + [d.moment**2 / 2] * 3)
    nc = n + nf
    Mv = np.zeros((2 * nc, 2 * nc))
    Mv[:nc, :nc], Mv[:nc, nc:], Mv[nc:, nc:] = -Ac, G @ W @ G.T, Ac.T
    E = scipy.linalg.expm(Mv * h)
    Q = np.zeros((N, N))
    Q[:nc, :nc] = E[nc:, nc:].T @ E[:nc, nc:]
    Q = (Q + Q.T) / 2
    if not imu:
        keep = [i for i in range(C.shape[0])
                if not len(s.gap_sensors) <= i < len(s.gap_sensors) + 6]
        C, R = C[keep], R[np.ix_(keep, keep)]
    L, P, _ = control.dlqe(Phi, np.eye(N), C, Q, R)
    return Phi, C, np.asarray(L), R, np.asarray(P)


def test_default_sensors_observe_and_the_whole_loop_meets_the_spec(carriage, sim_lib,
                                                                   sensing_envelope) -> None:
    """At each speed: the rank and smallest singular value of python-control's obsv of the
    noise-scaled (Phi, C) assembled here; the whole loop's eigenvalues those of the ideal loop
    (c2d, dlqr) and of the filter's error (control.dlqe's predictor), its smallest damping
    ratio and largest real part the check's; the verdict's lines say it, both passing."""
    env = sensing_envelope
    sc = env.sensing
    params = carriage.params
    h = 1.0 / params.control.spec.tick_rate
    zetas = []
    for i, op in enumerate(Plant(carriage, sim_lib).points(env.speeds)):
        Phi, C, L, R, _ = _reference_filter(params, op, TAU, h)
        Ob = control.obsv(Phi[:12, :12], C[:, :12] / np.sqrt(np.diag(R))[:, None])
        sv = np.linalg.svd(Ob, compute_uv=False)
        assert sc.rank[i] == np.linalg.matrix_rank(Ob) == 12
        assert sc.smallest[i] == pytest.approx(sv[-1], rel=1e-3)
        z_f = np.linalg.eigvals(Phi - L @ C)
        s_ref = np.concatenate([_reference_loop(op, env.loop.speed_gain, TAU,
                                                k_i=env.loop.speed_integral),
                                np.log(z_f[np.abs(z_f) > 1e-9].astype(complex)) / h])
        zeta = np.min(-s_ref.real / np.abs(s_ref))
        zetas.append(zeta)
        assert sc.min_damping[i] == pytest.approx(zeta, rel=1e-4)
        assert sc.max_real[i] == pytest.approx(np.max(s_ref.real), rel=1e-4)
        assert np.min(np.abs(s_ref.real - sc.levitation_real[i])) < 1e-3 * abs(
            sc.levitation_real[i]) + 1e-6
    spec = params.control.spec
    assert np.all(sc.min_damping >= spec.min_damping_ratio)
    assert np.all(-sc.levitation_real >= spec.min_levitation_decay_rate)
    verdict = embedded_verdict(carriage, env, complete=False)
    (line,) = [c for c in verdict.checks if c.subject.startswith("sensing")]
    assert line.ok and "rank 12 of 12" in line.text, line
    assert f"damping ratio >= {min(zetas):.3g}" in line.text
    assert "2 ms lag" in line.subject and "`spec` at the tick" in line.subject


def test_face_centre_gap_sensors_without_an_imu_fail_the_verdict_naming_why(
        carriage, sim_lib) -> None:
    """The issue's target: gap sensors at the face centres only, no IMU. The roll's 1-sigma
    error of control.dlqe's filter assembled here exceeds a tenth of the spec's phi; the
    verdict fails (build exits 3) with a reason naming phi, the face centres and the missing
    gyro, and the observability line says so."""
    overrides = [f"sensors.gap_sensors.{n}.across=0.0" for n in ("g3l", "g3r", "g6l", "g6r")]
    loaded = load_params(overrides=overrides)
    params = loaded.params.model_copy(update={"sensors": loaded.params.sensors.model_copy(
        update={"imu": None})})
    blind = DerivedCarriage(LoadedParams(params, loaded.source, loaded.sha256,
                                         (*loaded.overrides, "sensors.imu removed")))
    env = compute_envelope(Plant(blind, sim_lib), 2, controllers=("spec",), other_models=False)
    (op,) = Plant(blind, sim_lib).points([env.speeds[-1]])
    # the reference filter without the IMU's rows (the file's IMU numbers go unused)
    _, C, _, R, P = _reference_filter(loaded.params, op, TAU, imu=False)
    S = C @ P @ C.T + R
    P_upd = P - P @ C.T @ np.linalg.solve(S, C @ P)
    i = cv.STATE_INDEX["phi"]
    limit = 0.1 * params.control.spec.max_deviation.phi
    assert np.sqrt(P_upd[i, i]) > limit
    k = env.sensing.states.index("phi")
    assert env.sensing.error_std[-1, k] == pytest.approx(np.sqrt(P_upd[i, i]), rel=1e-3)
    verdict = embedded_verdict(blind, env, complete=False)
    assert verdict.reason is not None
    assert "phi: estimated to" in verdict.reason
    assert "face centres only" in verdict.reason and "no gyro" in verdict.reason
    (line,) = [c for c in verdict.checks if c.subject.startswith("sensing")]
    assert not line.ok and line.text.startswith("FAILS") and "phi:" in line.text


def test_the_reports_gap_jacobian_equals_the_geometrys_differences(carriage) -> None:
    """The sensing section's symbolic row dd/d(y, z, phi, theta, psi) at the design pose,
    evaluated at each default gap sensor's point and face normal, equals the central
    differences of the numpy geometry's readings (tests/independent_reference.py)."""
    import sympy as sp

    from maglevgen.control.estimation import SensorLayout
    from maglevgen.report.sections.sensing import gap_jacobian

    J, b, n = gap_jacobian()
    params = carriage.params
    layout = SensorLayout.of(params)
    Hx, _ = ref.sensor_jacobians_fd(params, np.zeros(12), np.zeros(12))
    pose = [cv.STATE_INDEX[s] for s in ("y", "z", "phi", "theta", "psi")]
    for i, g in enumerate(layout.gaps):
        subs = dict(zip([*b, *n], [*g.point, *g.normal], strict=True))
        row = np.array(J.subs(subs).evalf(), dtype=float).ravel()
        np.testing.assert_allclose(row, Hx[i, pose], atol=1e-7)
    assert sp.simplify(J[2].subs({b[1]: 0, n[0]: 0, n[1]: 0, n[2]: 1})) == 0  # roll unseen


def test_noisy_holds_decide_the_verdict_by_the_issues_targets(carriage,
                                                              sensing_envelope) -> None:
    """Holds made up here (no run): 2.2 N RMS of a 20 N budget with the file's noise misses
    the 10 % target, 2 % of the ticks at the budget with five times the noise misses the 1 %
    one, a gap at track.min_gap is contact; the verdict's lines and its exit-3 reason say
    which; holds within the targets pass."""
    from maglevgen.analyses.output_feedback import NoisyHold

    budget = carriage.params.control.spec.force_budget
    min_gap = carriage.params.track.min_gap

    def hold(speed, scale, rms, at_budget, gap, settled=True):
        return NoisyHold(speed, 1.0, scale, ("1", "2"), np.array([rms, 0.1]),
                         np.array([3 * rms, 0.3]), np.array([at_budget, 0.0]), budget,
                         np.array([1e-6, 1e-6]), gap,
                         {"phi": 1e-5, "theta": 1e-5, "psi": 1e-5},
                         dict.fromkeys(cv.Q_STATES, 1e-6), dict.fromkeys(cv.Q_STATES, 1e-6),
                         settled)

    good = (hold(7.0, 1.0, 0.4, 0.0, 8e-3), hold(7.0, 5.0, 2.0, 0.0, 8e-3))
    verdict = embedded_verdict(carriage, sensing_envelope, holds=good, complete=False)
    (line,) = [c for c in verdict.checks if c.subject.startswith("noisy holds")]
    assert line.ok and verdict.reason is None and "the firmware's sense tick" in line.subject
    assert "force RMS <= 2 % (x 1), 10 % (x 5) of the budget, no tick at it" in line.text
    bad = (hold(7.0, 1.0, 0.11 * budget, 0.0, 8e-3), hold(40.0, 1.0, 0.4, 0.0, 8e-3, False),
           hold(7.0, 5.0, 2.0, 0.02, min_gap))
    verdict = embedded_verdict(carriage, sensing_envelope, holds=bad, complete=False)
    (line,) = [c for c in verdict.checks if c.subject.startswith("noisy holds")]
    assert not line.ok
    assert "x 1 at 7 m/s: force RMS 11 % of the budget" in line.text
    assert "x 1 at 40 m/s: not settled" in line.text
    assert "x 5 at 7 m/s: contact" in line.text and "2 % of the ticks at the budget" in line.text
    assert verdict.reason is not None and "noisy holds with the sensor noise x 5" in verdict.reason


def test_a_set_blind_to_the_pose_fails_the_verdict_naming_the_states(carriage, sim_lib) -> None:
    """The track sensor alone: the needed states in the null space of python-control's obsv
    of the model assembled here (its track row) are exactly those the verdict names, each
    "not seen by the track sensor"; the verdict fails (exit 3), its sensing line says so."""
    from maglevgen.control.estimation import NEEDED_STATES

    params = carriage.params.model_copy(update={"sensors": carriage.params.sensors.model_copy(
        update={"gap": None, "gap_sensors": {}, "imu": None})})
    loaded = carriage.loaded
    blind = DerivedCarriage(LoadedParams(params, loaded.source, loaded.sha256,
                                         (*loaded.overrides, "track sensor alone")))
    env = compute_envelope(Plant(blind, sim_lib), 2, controllers=("spec",), other_models=False)
    (op,) = Plant(blind, sim_lib).points([env.speeds[0]])
    Phi, C, _, _, _ = _reference_filter(carriage.params, op, TAU)
    Ob = control.obsv(Phi[:12, :12], C[-1:, :12])
    rank = np.linalg.matrix_rank(Ob)
    Vt = np.linalg.svd(Ob)[2]
    expected = {cv.STATE_NAMES[i] for i in range(12)
                if np.linalg.norm(Vt[rank:, i]) > 1e-6} & set(NEEDED_STATES)
    sc = env.sensing
    assert not sc.observable and int(sc.rank[0]) == rank
    named = {b.split(":")[0] for b in sc.blind}
    assert named == expected and all("not seen by the track sensor" in b for b in sc.blind)
    verdict = embedded_verdict(blind, env, complete=False)
    assert verdict.reason is not None and "cannot observe what it needs" in verdict.reason
    (line,) = [c for c in verdict.checks if c.subject.startswith("sensing")]
    assert not line.ok and line.text.startswith("FAILS: cannot observe")
