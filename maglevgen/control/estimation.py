"""The loop as built: the tick, its delay, the sensors and the estimator, in one place.

The seed of issue 51's `Plant`. What it knows today:

- the sensor set of ``[sensors]`` (`SensorLayout`): each gap sensor's body point, face normal and
  nominal gap, the IMU's point, the track sensor; and each reading's noise at the tick
  (`SensorLayout.noise_covariance`);
- the linear measurement model at an operating point, y = C x + D u (`measurement_model`), from
  the generated C's measurement equations (maglev_gap_reading, maglev_imu_reading: derive/
  sensors.py) and Jacobians (maglev_jacobians);
- the estimator's model at the tick: the 12-state linearisation discretised with ZOH and
  augmented with the delay's commands in flight (`EstimatorModel`), its observability
  (`observability`) and its steady-state Kalman filter (`kalman`).

The estimator's state is the full 12-state deviation from trim (the track position x is the
track sensor's) plus the d commands in flight, known to the controller that computed them
(no process noise on them). The controller needs the loop's states, LOOP_STATES (every state
but x).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from maglevgen.control.lqr import solve_dare
from maglevgen.control.operating import N_AXES, OperatingPoint
from maglevgen.control.sampled import LOOP_STATES, Tick, delay_augmented, zoh
from maglevgen.control.schedule import GainTable
from maglevgen.derive import conventions as cv
from maglevgen.errors import InputError

__all__ = ["ESTIMATION_SHARE", "NEEDED_STATES", "EstimatorPoint", "NoKalmanFilterError",
           "SensorLayout", "continuous_equivalent", "estimation_failures", "estimator_model",
           "estimator_points", "kalman", "kalman_table", "loop_as_built",
           "loop_as_built_speed_states", "measurement_model", "observability", "whole_loop",
           "why_blind"]

#: the states the controller needs (the loop's: every state but the track position x)
NEEDED_STATES: tuple[str, ...] = LOOP_STATES


def face_axes(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(across, along): unit vectors of a face with unit ``normal`` (derive.distributed's
    face_axes: along = body x projected onto the face, across = n x along)."""
    along = np.array([1.0, 0.0, 0.0]) - normal[0] * normal
    along = along / np.linalg.norm(along)
    (n0, n1, n2), (a0, a1, a2) = normal.tolist(), along.tolist()
    # n x along in np.cross's operations (a sample's layout: np.cross's setup cost 40 us)
    return np.array([n1 * a2 - n2 * a1, n2 * a0 - n0 * a2, n0 * a1 - n1 * a0]), along


@dataclass(frozen=True)
class GapSensorGeometry:
    """One gap sensor: its name, body point, its face's unit normal and nominal gap."""

    name: str
    array: str
    point: np.ndarray
    normal: np.ndarray
    nominal_gap: float


@dataclass(frozen=True)
class SensorLayout:
    """The sensor set of ``[sensors]`` with each reading's noise at the tick."""

    gaps: tuple[GapSensorGeometry, ...]
    imu_point: np.ndarray | None
    track: bool
    variances: np.ndarray  # per reading, at the tick: the noise's variance
    names: tuple[str, ...]  # per reading

    @classmethod
    def of(cls, params) -> SensorLayout:
        """From a parameter file's ``[sensors]`` (InputError when it has none). Noise at the
        tick: a reading's RMS squared plus its quantization step^2/12; a noise density N
        behind a first-order anti-alias filter at f_c, sampled once per tick, has the
        variance N^2 (pi/2) f_c (the filter's noise-equivalent bandwidth)."""
        s = params.sensors
        if s is None:
            raise InputError("sensors: the parameter file has no [sensors] table (what the "
                             "carriage measures); see `maglevgen params schema`")
        gaps, var, names = [], [], []
        if s.gap is not None:
            for name, g in s.gap_sensors.items():
                arr = params.arrays[g.array]
                n = np.array(arr.normal, dtype=float)
                across, along = face_axes(n)
                point = np.array(arr.position) + g.across * across + g.along * along
                gaps.append(GapSensorGeometry(name, g.array, point, n,
                                              float(arr.nominal_gap)))
                var.append(s.gap.noise**2 + s.gap.resolution**2 / 12)
                names.append(f"gap_{name}")
        imu = None
        if s.imu is not None:
            imu = np.array(s.imu.position, dtype=float)
            bandwidth = np.pi / 2 * s.imu.anti_alias
            var += [s.imu.gyro_noise**2 * bandwidth] * 3 + [s.imu.accel_noise**2 * bandwidth] * 3
            names += ["gyro_p", "gyro_q", "gyro_r", "accel_x", "accel_y", "accel_z"]
        if s.track is not None:
            var.append(s.track.noise**2 + s.track.resolution**2 / 12)
            names.append("track_x")
        return cls(tuple(gaps), imu, s.track is not None, np.array(var), tuple(names))

    # The readings' order (`of`): the gaps, the IMU's three rates and three accelerations,
    # the track position.
    @property
    def gap_readings(self) -> slice:
        return slice(0, len(self.gaps))

    @property
    def gyro_readings(self) -> slice:
        return slice(len(self.gaps), len(self.gaps) + 3)

    @property
    def accel_readings(self) -> slice:
        return slice(len(self.gaps) + 3, len(self.gaps) + 6)

    def describe(self) -> str:
        """The set in a few words, for messages: "8 gap sensors (1 at each face centre ...)"."""
        parts = []
        if self.gaps:
            parts.append(f"{len(self.gaps)} gap sensors")
        if self.imu_point is not None:
            parts.append("an IMU")
        if self.track:
            parts.append("the track sensor")
        return ", ".join(parts) if parts else "no sensor"


@dataclass(frozen=True)
class MeasurementModel:
    """y = y_trim + C dx + D du at an operating point (x the 12 states, u the dynamics' inputs:
    F_prop then the array forces)."""

    y_trim: np.ndarray
    C: np.ndarray
    D: np.ndarray
    names: tuple[str, ...]


def measurement_model(lib, p: np.ndarray, op: OperatingPoint,
                      layout: SensorLayout) -> MeasurementModel:
    """The sensors' readings at trim and their linearisation from the generated C: each gap
    sensor's maglev_gap_reading (reading, dreading/dx), the IMU's maglev_imu_reading (its
    readings and Jacobians in x and xdot) with xdot = A dx + B du at trim (maglev_jacobians:
    the accelerometer reads the dynamics, so D = H_xdot B), the track sensor x."""
    n_x, n_u = op.A.shape[0], op.B.shape[1]
    rows_y, rows_C, rows_D = [], [], []
    gap_fn = lib.function("maglev_gap_reading")
    for g in layout.gaps:
        reading, H = gap_fn(op.x_trim, g.point, g.normal, g.nominal_gap)
        rows_y.append(np.ravel(reading))
        rows_C.append(np.reshape(H, (1, n_x)))
        rows_D.append(np.zeros((1, n_u)))
    if layout.imu_point is not None:
        u = np.zeros(n_u)
        u[cv.PROPULSION_INPUT] = op.f_prop
        xdot = lib.function("maglev_dynamics")(op.x_trim, u, p)[0].ravel()
        gyro, accel, H_x, H_xdot = lib.function("maglev_imu_reading")(
            op.x_trim, xdot, layout.imu_point, p)
        rows_y.append(np.concatenate([np.ravel(gyro), np.ravel(accel)]))
        rows_C.append(H_x + H_xdot @ op.A)
        rows_D.append(H_xdot @ op.B)
    if layout.track:
        rows_y.append(op.x_trim[[cv.STATE_INDEX["x"]]])
        e = np.zeros((1, n_x))
        e[0, cv.STATE_INDEX["x"]] = 1.0
        rows_C.append(e)
        rows_D.append(np.zeros((1, n_u)))
    return MeasurementModel(np.concatenate(rows_y), np.vstack(rows_C), np.vstack(rows_D),
                            layout.names)


def process_noise(op: OperatingPoint, params) -> tuple[np.ndarray, np.ndarray]:
    """(G, W): where the unmeasured forces enter (12 x 6: the along-track force as the
    propulsion's column of B, then the five generalized forces through the allocation, as the
    controller's act) and their continuous intensity W = diag(density^2 / 2) (a one-sided
    density N is a two-sided N^2/2), [sensors.disturbance]."""
    d = params.sensors.disturbance
    G = np.column_stack([op.B[:, cv.PROPULSION_INPUT], op.B[:, cv.ARRAY_INPUTS] @ op.allocation])
    W = np.diag([d.force**2 / 2] * 3 + [d.moment**2 / 2] * 3)
    return G, W


def discrete_noise(A: np.ndarray, G: np.ndarray, W: np.ndarray, h: float) -> np.ndarray:
    """Q_d = int_0^h e^{A s} G W G' e^{A' s} ds (Van Loan's matrix exponential): the
    covariance one tick of the continuous white noise adds to the state."""
    n = A.shape[0]
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n], M[:n, n:], M[n:, n:] = -A, G @ W @ G.T, A.T
    E = scipy.linalg.expm(M * h)
    Phi_T = E[n:, n:]
    Q = Phi_T.T @ E[:n, n:]
    return (Q + Q.T) / 2


@dataclass(frozen=True)
class EstimatorModel:
    """The estimator's model at the tick: z[k+1] = Phi z[k] + Gamma u[k] + w[k],
    y[k] = C z[k] + D u[k] + v[k] on z = (dx, the d commands in flight u[k-1] .. u[k-d]),
    cov w = Q, cov v = R; u the dynamics' inputs (F_prop, then the array forces) computed at
    tick k. The measurement at tick k reads the command applied then (the oldest in flight;
    with no delay, u[k] itself: D)."""

    speed: float
    Phi: np.ndarray
    Gamma: np.ndarray
    C: np.ndarray
    D: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    states: tuple[str, ...]  # the plant's states it holds; then the lag's, then the queue
    names: tuple[str, ...]  # the readings
    n_lag: int = 0  # the lagged array forces after the plant's states (0: instant actuators)

    @property
    def n_x(self) -> int:
        return len(self.states)

    @property
    def queue(self) -> slice:
        """The commands in flight (newest first, each the dynamics' inputs)."""
        return slice(self.n_x + self.n_lag, self.Phi.shape[0])


def estimator_model(lib, p: np.ndarray, op: OperatingPoint, params,
                    layout: SensorLayout | None = None, tau: float = 0.0) -> EstimatorModel:
    """`EstimatorModel` at ``op``: the C's Jacobians (A, B) discretised with ZOH over the tick
    (sampled.zoh), the delay's commands in flight (sampled.delay_augmented), the sensors'
    linearisation (`measurement_model`), the process noise of `process_noise` over one tick
    (`discrete_noise`) and each reading's variance (`SensorLayout.variances`). Without a track
    sensor the track position x (an integrator nothing else depends on, which nothing then
    reads) is left out: no filter could hold its error bounded.

    ``tau`` > 0 [s]: each array force lags its command, tau F' = F_c - F ([actuators]
    time_constant, as control.plant.LoopPlant), and the lagged forces F are states of the
    model after the plant's: the accelerometer reads them (its D on the array forces moves to
    F's columns), the propulsion stays instant. No process noise enters F: the filter knows
    it from its own commands."""
    layout = layout or SensorLayout.of(params)
    tick = Tick.of(params)
    meas = measurement_model(lib, p, op, layout)
    keep = [i for i, s in enumerate(cv.STATE_NAMES) if layout.track or s != "x"]
    A, B, C = op.A[np.ix_(keep, keep)], op.B[keep], meas.C[:, keep]
    n, m, d = A.shape[0], B.shape[1], tick.delay
    nf = m - 1 if tau > 0 else 0
    G, W = process_noise(op, params)
    Ac, Bc, Gc = A, B, G[keep]
    Cc, D = C, meas.D.copy()
    if nf:  # (dx, F): the array columns of B through the lag
        Ac = np.zeros((n + nf, n + nf))
        Ac[:n, :n], Ac[:n, n:] = A, B[:, cv.ARRAY_INPUTS]
        Ac[n:, n:] = -np.eye(nf) / tau
        Bc = np.zeros((n + nf, m))
        Bc[:n, cv.PROPULSION_INPUT] = B[:, cv.PROPULSION_INPUT]
        Bc[n:, cv.ARRAY_INPUTS] = np.eye(nf) / tau
        Gc = np.vstack([G[keep], np.zeros((nf, G.shape[1]))])
        Cc = np.hstack([C, D[:, cv.ARRAY_INPUTS]])
        D[:, cv.ARRAY_INPUTS] = 0.0
    Phi, Gamma = zoh(Ac, Bc, tick.period)
    Pa, Ga = delay_augmented(Phi, Gamma, d)
    nc = n + nf
    Ca = np.zeros((C.shape[0], Pa.shape[0]))
    Ca[:, :nc] = Cc
    Da = D
    if d > 0:  # the command applied at tick k is the oldest in flight
        Ca[:, nc + (d - 1) * m:] = D
        Da = np.zeros_like(D)
    Qa = np.zeros_like(Pa)
    Qa[:nc, :nc] = discrete_noise(Ac, Gc, W, tick.period)
    return EstimatorModel(op.speed, Pa, Ga, Ca, Da, Qa, np.diag(layout.variances),
                          tuple(cv.STATE_NAMES[i] for i in keep), meas.names, nf)


@dataclass(frozen=True)
class Observability:
    """The plant's observability from the sensors at the tick: the discrete observability
    matrix O = [C; C Phi; ...; C Phi^(n-1)] of the plant's states (the commands in flight are
    known), its readings scaled by their noise (each row in noise standard deviations), its
    rank and singular values, and the needed states with a part in its null space."""

    speed: float
    rank: int
    n: int
    singular_values: np.ndarray
    unobservable: tuple[str, ...]  # needed states (NEEDED_STATES) O cannot see
    unneeded: tuple[str, ...]  # states O cannot see that the controller does not need

    @property
    def smallest(self) -> float:
        return float(self.singular_values[-1])


#: a state is unobservable when its unit vector has more than this part in O's null space
NULL_SPACE_SHARE = 1e-6


def observability(model: EstimatorModel) -> Observability:
    """`Observability` of an `EstimatorModel`. Rank as numpy's matrix_rank (singular values
    above s_max max(rows, cols) eps), the noise-scaled O (a reading of variance r weighs
    1/sqrt(r))."""
    n = model.n_x
    Phi = model.Phi[:n, :n]
    scale = 1.0 / np.sqrt(np.diag(model.R))
    C = scale[:, None] * model.C[:, :n]
    rows, block = [], C
    for _ in range(n):
        rows.append(block)
        block = block @ Phi
    obs = np.vstack(rows)
    _, s, Vt = np.linalg.svd(obs)
    tol = s[0] * max(obs.shape) * np.finfo(float).eps
    rank = int(np.sum(s > tol))
    null = Vt[rank:].T  # (n, n - rank)
    share = np.linalg.norm(null, axis=1) if null.size else np.zeros(n)
    blind = [model.states[i] for i in range(n) if share[i] > NULL_SPACE_SHARE]
    return Observability(model.speed, rank, n, s,
                         tuple(b for b in blind if b in NEEDED_STATES),
                         tuple(b for b in blind if b not in NEEDED_STATES))


@dataclass(frozen=True)
class KalmanDesign:
    """The steady-state Kalman filter at the tick of an `EstimatorModel`: with P the a-priori
    error covariance (the DARE's, SciPy), the update z[k|k] = z[k|k-1] + M (y[k] - C z[k|k-1]
    - D u[k]) with M = P C' (C P C' + R)^-1, then z[k+1|k] = Phi z[k|k] + Gamma u[k]; the
    predictor's gain L = Phi M (python-control's dlqe form)."""

    speed: float
    P: np.ndarray  # a priori: cov(z[k] - z[k|k-1])
    M: np.ndarray  # the measurement update's gain
    L: np.ndarray  # the predictor's gain, Phi M
    P_updated: np.ndarray  # cov(z[k] - z[k|k]) = (I - M C) P: what the controller's uses


class NoKalmanFilterError(ArithmeticError):
    """SciPy's DARE found no steady-state filter for an `EstimatorModel` (its Phi is singular
    with the delay and Q singular; at a slow tick, e.g. 50 Hz at 39 m/s on the default
    carriage, the pencil is too ill-conditioned to order): a failed design, which the sensing
    check reports, not an internal error."""

    def __init__(self, speed: float, why: str) -> None:
        super().__init__(f"no steady-state Kalman filter at {speed:.4g} m/s (SciPy's "
                         f"solve_discrete_are: {why.split(';')[0].rstrip('.')})")
        self.speed = speed


def kalman(model: EstimatorModel) -> KalmanDesign:
    """`KalmanDesign` of ``model``: P from `lqr.solve_dare` (SciPy's solve_discrete_are, or
    the doubling where SciPy's reordering refuses) on the dual problem (Phi', C', Q, R);
    `NoKalmanFilterError` when it has none."""
    try:
        P = solve_dare(model.Phi.T, model.C.T, model.Q, model.R)
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise NoKalmanFilterError(model.speed, str(exc)) from exc
    if not np.all(np.isfinite(P)):
        raise NoKalmanFilterError(model.speed, "a covariance that is not finite")
    P = (P + P.T) / 2
    S = model.C @ P @ model.C.T + model.R
    M = np.linalg.solve(S, model.C @ P).T
    updated = (np.eye(P.shape[0]) - M @ model.C) @ P
    return KalmanDesign(model.speed, P, M, model.Phi @ M, (updated + updated.T) / 2)


#: the estimate's error (its standard deviation, after the measurement update) on an axis
#: allowed as a share of that axis's control.spec.max_deviation: a tenth, so that the
#: estimate's noise takes little of the room the spec gives the motion
ESTIMATION_SHARE = 0.1


@dataclass(frozen=True)
class EstimatorPoint:
    """The estimator at one speed: its model, observability and Kalman filter."""

    model: EstimatorModel
    observability: Observability
    design: KalmanDesign

    @property
    def error_std(self) -> dict[str, float]:
        """Each plant state's estimation error, standard deviation after the update."""
        d = np.sqrt(np.clip(np.diag(self.design.P_updated)[:self.model.n_x], 0.0, None))
        return dict(zip(self.model.states, d.tolist(), strict=True))


def estimator_points(lib, p: np.ndarray, params, points: list[OperatingPoint],
                     tau: float = 0.0) -> list[EstimatorPoint]:
    """`EstimatorPoint` at each operating point (e.g. the envelope's speeds; ``tau``: the
    actuator lag in the model, `estimator_model`). InputError (exit 2) when the sensor set
    cannot observe a state the controller needs at some speed (`check_observable`): no
    filter exists then."""
    layout = SensorLayout.of(params)
    out = []
    for op in points:
        model = estimator_model(lib, p, op, params, layout, tau)
        obs = observability(model)
        check_observable(obs, layout, params)
        out.append(EstimatorPoint(model, obs, kalman(model)))
    return out


def why_blind(state: str, layout: SensorLayout, params) -> str:
    """What in the sensor set leaves ``state`` unseen, in a few words."""
    gs = params.sensors.gap_sensors.values()
    centred = bool(gs) and all(g.across == 0 and g.along == 0 for g in gs)
    if state in ("phi", "p", "y", "v") and centred and layout.imu_point is None:
        return ("gap sensors at the face centres only (roll and a lateral shift move them "
                "alike) and no gyro")
    if state in ("x", "u") and not layout.track:
        return "no track sensor"
    return f"not seen by {layout.describe()}"


def check_observable(obs: Observability, layout: SensorLayout, params) -> None:
    """InputError naming each state the controller needs that the sensors cannot observe at
    ``obs``'s speed, and why (`why_blind`)."""
    if obs.unobservable:
        what = "; ".join(f"{s}: {why_blind(s, layout, params)}" for s in obs.unobservable)
        raise InputError(f"sensors: cannot observe what the controller needs at "
                         f"{obs.speed:g} m/s (rank {obs.rank} of {obs.n}): {what}")


def estimation_failures(points: list[EstimatorPoint], params) -> list[str]:
    """The axes whose estimate's error exceeds ESTIMATION_SHARE of control.spec.max_deviation
    somewhere in ``points``, one sentence each naming the worst speed and why (empty: every
    axis estimated well enough across them)."""
    spec = params.control.spec.max_deviation
    layout = SensorLayout.of(params)
    out = []
    for state in cv.Q_STATES:
        limit = ESTIMATION_SHARE * getattr(spec, state)
        worst = max(points, key=lambda e: e.error_std[state])
        err = worst.error_std[state]
        if err > limit:
            out.append(f"{state}: estimated to {err:.3g} (1 sigma) at "
                       f"{worst.model.speed:.4g} m/s, "
                       f"more than {ESTIMATION_SHARE:g} x control.spec.max_deviation.{state} = "
                       f"{limit:.3g} ({why_blind(state, layout, params)})")
    return out


def kalman_fields(n_states: int, n_readings: int) -> tuple[tuple[str, int], ...]:
    """The Kalman table's fields: M, the update's gain on the plant's states (column-major)."""
    return (("M", n_states * n_readings),)


def kalman_row(point: EstimatorPoint) -> np.ndarray:
    """One row of the Kalman table: M's plant rows, column-major."""
    return point.design.M[:point.model.n_x].ravel(order="F")


def kalman_table(lib, p: np.ndarray, params, operating_at, v_min: float, v_max: float):
    """The update's gain M scheduled over [v_min, v_max] in the controller's table machinery
    (maglevgen.control.schedule.GainTable: a Chebyshev series in 1/v, the fewest nodes within
    its bound); ``operating_at(v)`` gives the operating point at a speed."""
    def rows(speeds: np.ndarray) -> np.ndarray:
        pts = estimator_points(lib, p, params, [operating_at(float(v)) for v in speeds])
        return np.array([kalman_row(e) for e in pts])

    layout = SensorLayout.of(params)
    n_states = len(cv.STATES) - (0 if layout.track else 1)
    return GainTable.fit(rows, v_min, v_max, kalman_fields(n_states, len(layout.names)))


def estimate_gain(model: EstimatorModel, op: OperatingPoint, K_loop: np.ndarray) -> np.ndarray:
    """K_u (inputs x estimator states): u - u_trim = -K_u z_hat, the loop's gain K_loop
    (sampled.loop_gain: 6 x LOOP_STATES, five generalized forces then the propulsion's speed
    feedback) on the estimate, the generalized forces through the allocation T to the array
    forces (the dynamics' inputs: F_prop, then the array forces)."""
    K_u = np.zeros((op.B.shape[1], model.Phi.shape[0]))
    cols = [model.states.index(s) for s in LOOP_STATES]
    K_u[0, cols] = K_loop[N_AXES]
    K_u[1:, cols] = op.allocation @ K_loop[:N_AXES]
    return K_u


def whole_loop(model: EstimatorModel, design: KalmanDesign, K_u: np.ndarray) -> np.ndarray:
    """The discrete output-feedback loop (plant at the tick with its delay, sensors, the
    Kalman filter's update and prediction, the controller on the updated estimate) in the
    coordinates (z, e), e = z - z_hat[k|k-1]: z_hat[k|k] = z - (I - M C) e, u = -K_u z_hat[k|k],
    so z+ = (Phi - Gamma K_u) z + Gamma K_u (I - M C) e and e+ = Phi (I - M C) e (the
    separation principle: its eigenvalues are the controller's and the filter's). The track
    position, which feeds nothing and which nothing holds (its column of Phi - Gamma K_u is
    its own unit vector: eigenvalue 1), is left out of z."""
    n = model.Phi.shape[0]
    IMC = np.eye(n) - design.M @ model.C
    top = np.hstack([model.Phi - model.Gamma @ K_u, model.Gamma @ K_u @ IMC])
    bottom = np.hstack([np.zeros((n, n)), model.Phi @ IMC])
    loop = np.vstack([top, bottom])
    if "x" in model.states:
        i = model.states.index("x")
        keep = [j for j in range(2 * n) if j != i]
        loop = loop[np.ix_(keep, keep)]
    return loop


def continuous_equivalent(loop: np.ndarray, period: float) -> np.ndarray:
    """ln(z)/h of a discrete loop's eigenvalues (z = 0: -inf, it decays in one tick)."""
    z = np.linalg.eigvals(loop).astype(complex)
    small = np.abs(z) < 1e-300
    return np.where(small, -np.inf + 0j, np.log(np.where(small, 1.0, z)) / period)


def loop_as_built(model: EstimatorModel, design: KalmanDesign, plant, gains) -> np.ndarray:
    """The discrete output-feedback loop as built: the plant at the tick with its delay and
    actuator lag (``model``, `estimator_model` with the lag of ``plant``), the sensors, the
    Kalman filter ``design``, and the controller of ``plant`` (control.plant.LoopPlant) with
    ``gains`` (its `LoopDesign`, e.g. the `spec` design at the tick): its gains on the body
    states act on the updated estimate, those on the commands in flight and on its own
    prediction of the lagged generalized forces on what it knows exactly (its commands).

    State (z, e, w_hat, xi): z the model's (plant, lagged forces, commands in flight), e = z -
    z_hat[k|k-1] the filter's error, w_hat the controller's prediction (LoopPlant's
    "prediction" block), xi the speed error's integral where the plant has k_i > 0 (its
    "speed_integral" block). With z_hat[k|k] = z - (I - M C) e and the command c = -K_c (body
    of z_hat[k|k], the generalized forces and propulsion in flight, w_hat, xi):
    z+ = Phi z + Gamma E c, e+ = Phi (I - M C) e, w_hat+ = a w_hat + (1 - a) w_applied,
    xi+ = xi + h dV(z_hat[k|k]) (the speed on the estimate); E maps the six commands to the
    dynamics' inputs (F_prop, then T w: the allocation). The track position (its column in
    z is its own unit vector: eigenvalue 1) is left out."""
    op, L = plant.op, plant.loop_layout
    K_c = plant.controller_gains(gains)  # 6 x L.size
    n_cmd, N = K_c.shape[0], model.Phi.shape[0]
    T = op.allocation  # nf x 5
    n5 = T.shape[1]
    T_pinv = np.linalg.pinv(T)
    m, d = model.Gamma.shape[1], plant.tick.delay
    E = np.zeros((m, n_cmd))  # commands (5 generalized forces, F_prop) -> dynamics' inputs
    E[0, n5] = 1.0
    E[1:, :n5] = T
    Kb = np.zeros((n_cmd, N))  # on z_hat[k|k]: the body states
    for j, name in enumerate(LOOP_STATES):
        Kb[:, model.states.index(name)] = K_c[:, L["body"].start + j]
    Kq = np.zeros((n_cmd, N))  # on z: the commands in flight (exactly known)
    q0 = model.queue.start
    if d:
        fl = L["in_flight"]
        for j in range(d):
            cmd_cols = K_c[:, fl.start + j * n_cmd:fl.start + (j + 1) * n_cmd]
            Kq[:, q0 + j * m] += cmd_cols[:, n5]  # F_prop in flight
            Kq[:, q0 + j * m + 1:q0 + (j + 1) * m] += cmd_cols[:, :n5] @ T_pinv
    n_w = L["prediction"].stop - L["prediction"].start
    n_xi = L["speed_integral"].stop - L["speed_integral"].start
    Kw = K_c[:, L["prediction"]]
    IMC = np.eye(N) - design.M @ model.C
    GE = model.Gamma @ E
    # c = Cz z + Ce e + Cw (w_hat, xi)
    Cz, Ce = -(Kb + Kq), Kb @ IMC
    Cw = -np.hstack([Kw, K_c[:, L["speed_integral"]]])
    n = 2 * N + n_w + n_xi
    w, xi = slice(2 * N, 2 * N + n_w), slice(2 * N + n_w, n)
    loop = np.zeros((n, n))
    loop[:N, :N] = model.Phi + GE @ Cz
    loop[:N, N:2 * N] = GE @ Ce
    loop[:N, 2 * N:] = GE @ Cw
    loop[N:2 * N, N:2 * N] = model.Phi @ IMC
    if n_w:
        a = plant.lag_pole
        loop[w, w] = a * np.eye(n_w)
        if d:  # the oldest in flight is applied: its generalized forces
            oldest = slice(q0 + (d - 1) * m + 1, q0 + d * m)
            loop[w, oldest] += (1 - a) * T_pinv
        else:
            loop[w, :N] += (1 - a) * Cz[:n5]
            loop[w, N:2 * N] += (1 - a) * Ce[:n5]
            loop[w, 2 * N:] += (1 - a) * Cw[:n5]
    if n_xi:  # xi+ = xi + h dV on the updated estimate z - (I - M C) e
        row = plant.speed_row()
        Sv = np.zeros(N)
        for j, name in enumerate(LOOP_STATES):
            Sv[model.states.index(name)] = row[L["body"].start + j]
        h = plant.tick.period
        loop[xi, :N] = h * Sv
        loop[xi, N:2 * N] = -h * Sv @ IMC
        loop[xi, xi] = 1.0
    if "x" in model.states:
        i = model.states.index("x")
        keep = [j for j in range(n) if j != i]
        loop = loop[np.ix_(keep, keep)]
    return loop


def loop_as_built_speed_states(model: EstimatorModel, n_prediction: int,
                               n_integral: int = 0) -> np.ndarray:
    """Mask of the speed loop's states in `loop_as_built`'s order: the forward speed u, the
    propulsion commands in flight, the filter's errors on x and u (the along-track
    estimate) and the speed error's integral (``n_integral``: 1 where the loop has one)."""
    N = model.Phi.shape[0]
    mask = np.zeros(2 * N + n_prediction + n_integral, dtype=bool)
    mask[2 * N + n_prediction:] = True
    m, q0 = model.Gamma.shape[1], model.queue.start
    mask[model.states.index("u")] = True
    mask[N + model.states.index("u")] = True
    if "x" in model.states:
        mask[N + model.states.index("x")] = True
    for j in range((N - q0) // m):
        mask[q0 + j * m] = True
    if "x" in model.states:
        mask = np.delete(mask, model.states.index("x"))
    return mask
