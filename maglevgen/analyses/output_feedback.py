"""The output-feedback loop as built, run: the nonlinear plant (the generated C's dynamics,
RK4) read by noisy sensors (the generated C's measurement equations, derive/sensors.py, with
each reading's noise, quantization and bias of ``[sensors]``, seeded), the steady-state Kalman
filter at the tick (maglevgen.control.estimation) and the embedded controller's gains on its
estimate, the command applied after the tick's delay and saturated at each array's force
budget.

A hold at one speed from trim (the estimate starts at trim too): what the sensors' noise
alone costs. Metrics: each array's control force, RMS and peak, and the share of ticks it
sits at the budget; the gaps' and the attitude's RMS deviation from trim; the estimation
error's RMS per state against the filter's own prediction (sqrt of P after the update).

Not in this loop (yet): the anti-alias filters' lag (their noise bandwidth is in the
readings' variance), the actuators' lag (issue 49's other half), a process disturbance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from maglevgen.carriage import structure_of
from maglevgen.control.estimation import (
    EstimatorPoint,
    SensorLayout,
    estimate_gain,
    estimator_points,
    measurement_model,
)
from maglevgen.control.operating import OperatingPoint
from maglevgen.control.sampled import Tick, loop_gain, speed_gain
from maglevgen.derive import conventions as cv

__all__ = ["NoisyHold", "noisy_hold"]

RK4_STEPS_PER_TICK = 2  # 0.5 ms at 1 kHz: the plant's fastest open-loop mode is about 60 1/s


@dataclass(frozen=True)
class NoisyHold:
    """One noisy hold's metrics (see the module docstring)."""

    speed: float  # [m/s]
    t_end: float  # [s]
    noise_scale: float  # every sensor's noise (and bias) times this
    arrays: tuple[str, ...]
    force_rms: np.ndarray  # [N] per array, the norm of its control components
    force_peak: np.ndarray  # [N]
    at_budget: np.ndarray  # share of ticks at the budget, per array
    budget: float  # [N]
    gap_rms: np.ndarray  # [m] per array, the closest corner's deviation from trim
    min_gap: float  # [m] the smallest gap of the run
    attitude_rms: dict[str, float]  # [rad] phi, theta, psi from trim
    estimation_rms: dict[str, float]  # per estimated state, z - z_hat[k|k]
    estimation_predicted: dict[str, float]  # sqrt(P after the update)'s diagonal

    def lines(self) -> list[str]:
        """Plain-text lines for a terminal or BENCHMARKS.md."""
        share = 100 * self.force_rms / self.budget
        out = [f"noisy hold at {self.speed:g} m/s for {self.t_end:g} s (sensor noise x "
               f"{self.noise_scale:g}): smallest gap {1e3 * self.min_gap:.3f} mm"]
        for i, name in enumerate(self.arrays):
            out.append(f"  array {name}: control force RMS {self.force_rms[i]:.3f} N "
                       f"({share[i]:.1f} % of {self.budget:g} N), peak "
                       f"{self.force_peak[i]:.3f} N, at the budget "
                       f"{100 * self.at_budget[i]:.2f} % of ticks, gap RMS "
                       f"{1e6 * self.gap_rms[i]:.2f} um")
        out.append("  attitude RMS " + ", ".join(f"{k} {1e6 * v:.2f} urad"
                                                 for k, v in self.attitude_rms.items()))
        out.append("  estimation error RMS (predicted by P) " + ", ".join(
            f"{k} {v:.3g} ({self.estimation_predicted[k]:.3g})"
            for k, v in self.estimation_rms.items()))
        return out


def noisy_hold(lib, p: np.ndarray, params, op: OperatingPoint, controller: str | None = None,
               t_end: float = 20.0, seed: int = 0, noise_scale: float = 1.0,
               point: EstimatorPoint | None = None) -> NoisyHold:
    """The output-feedback loop held at ``op``'s speed for ``t_end`` seconds (module
    docstring); the noise drawn from numpy's default_rng(seed). ``controller``: default the
    embedded one (``envelope.embedded_controller``)."""
    controller = controller or params.envelope.embedded_controller
    layout = SensorLayout.of(params)
    tick = Tick.of(params)
    point = point or estimator_points(lib, p, params, [op])[0]
    model, design = point.model, point.design
    k_v = speed_gain(params.vehicle.mass, op.trim_drag_slope, params.control.spec.speed_bandwidth)
    K_u = estimate_gain(model, op, loop_gain(op, controller, k_v))
    meas = measurement_model(lib, p, op, layout)
    s = params.sensors
    rng = np.random.default_rng(seed)
    sigma = np.sqrt(layout.variances) * noise_scale
    n_gap = len(layout.gaps)
    bias = np.zeros(len(layout.names))
    if s.imu is not None:  # each axis's in-run bias, its sign drawn once per run
        bias[n_gap:n_gap + 3] = s.imu.gyro_bias * rng.choice((-1.0, 1.0), 3)
        bias[n_gap + 3:n_gap + 6] = s.imu.accel_bias * rng.choice((-1.0, 1.0), 3)
    bias *= noise_scale
    step = np.zeros(len(layout.names))
    if s.gap is not None:
        step[:n_gap] = s.gap.resolution
    if s.track is not None:
        step[-1] = s.track.resolution
    # the readings' white noise: the quantization is applied to the reading, so leave its
    # share out of the drawn noise
    white = np.sqrt(np.clip(sigma**2 - (step * noise_scale) ** 2 / 12, 0.0, None))

    dynamics = lib.function("maglev_dynamics")
    gap_fn, imu_fn = lib.function("maglev_gap_reading"), lib.function("maglev_imu_reading")
    gaps_fn = lib.function("maglev_gaps")
    arrays = tuple(name for name in params.arrays)
    comps = [len(c) for _, c in _structure_arrays(params)]
    first = np.cumsum([0, *comps])[:-1]
    budget = params.control.spec.force_budget

    n_u, n_x = op.B.shape[1], model.n_x
    u_trim = np.zeros(n_u)
    u_trim[0] = op.f_prop
    keep = [cv.STATE_INDEX[st] for st in model.states]
    queue = [np.zeros(n_u) for _ in range(tick.delay)]  # commands in flight, newest first
    z_pred = np.zeros(model.Phi.shape[0])
    x = op.x_trim.copy()
    h = tick.period / RK4_STEPS_PER_TICK
    n_ticks = round(t_end * tick.rate)
    forces = np.zeros((n_ticks, len(arrays)))
    gaps = np.zeros((n_ticks, len(arrays)))
    att = np.zeros((n_ticks, 3))
    est_err = np.zeros((n_ticks, n_x))
    gaps_trim = np.ravel(gaps_fn(op.x_trim, p)[0])
    V = op.speed
    du_applied = queue[-1] if queue else np.zeros(n_u)
    for k in range(n_ticks):
        t = k * tick.period
        u_applied = u_trim + du_applied
        xdot = np.ravel(dynamics(x, u_applied, p)[0])
        y = np.empty(len(layout.names))
        for j, g in enumerate(layout.gaps):
            y[j] = float(np.ravel(gap_fn(x, g.point, g.normal, g.nominal_gap)[0])[0])
        if layout.imu_point is not None:
            gyro, acc, _, _ = imu_fn(x, xdot, layout.imu_point, p)
            y[n_gap:n_gap + 6] = np.concatenate([np.ravel(gyro), np.ravel(acc)])
        if layout.track:
            y[-1] = x[0]
        y = y + bias + white * rng.standard_normal(len(y))
        q = step * noise_scale
        y = np.where(q > 0, np.round(y / np.where(q > 0, q, 1.0)) * q, y)
        y_ref = meas.y_trim.copy()
        if layout.track:
            y_ref[-1] += V * t  # the trim moves along the track
        dz_true = x - op.x_trim
        dz_true[0] -= V * t
        # the update, the control on the updated estimate, the prediction
        innov = (y - y_ref) - model.C @ z_pred - (model.D @ du_applied if tick.delay == 0
                                                  else 0.0)
        z_post = z_pred + design.M @ innov
        du = -K_u @ z_post
        for i in range(len(arrays)):  # each array's control force saturated at the budget
            sl = slice(1 + first[i], 1 + first[i] + comps[i])
            norm = np.linalg.norm(du[sl])
            if norm > budget:
                du[sl] *= budget / norm
        est_err[k] = dz_true[keep] - z_post[:n_x]
        z_pred = model.Phi @ z_post + model.Gamma @ du
        if tick.delay == 0:
            du_applied = du
        else:
            queue.insert(0, du)
            du_applied = queue.pop()
        # the plant over the tick with the command applied now (held)
        u_hold = u_trim + du_applied
        for _ in range(RK4_STEPS_PER_TICK):
            x = _rk4(dynamics, x, u_hold, p, h)
        forces[k] = [np.linalg.norm(du_applied[1 + first[i]:1 + first[i] + comps[i]])
                     for i in range(len(arrays))]
        gaps[k] = np.ravel(gaps_fn(x, p)[0])
        att[k] = x[3:6] - op.x_trim[3:6]
    predicted = np.sqrt(np.clip(np.diag(design.P_updated)[:n_x], 0.0, None))
    return NoisyHold(
        op.speed, t_end, noise_scale, arrays, np.sqrt(np.mean(forces**2, axis=0)),
        np.max(forces, axis=0), np.mean(forces >= budget * (1 - 1e-9), axis=0), budget,
        np.sqrt(np.mean((gaps - gaps_trim) ** 2, axis=0)), float(np.min(gaps)),
        dict(zip(("phi", "theta", "psi"), np.sqrt(np.mean(att**2, axis=0)).tolist(),
                 strict=True)),
        dict(zip(model.states, np.sqrt(np.mean(est_err**2, axis=0)).tolist(), strict=True)),
        dict(zip(model.states, predicted.tolist(), strict=True)))


def _structure_arrays(params) -> list[tuple[str, tuple[str, ...]]]:
    """(array, its control force components) in the input order (derive.structure)."""
    return list(structure_of(params).arrays)


def _rk4(f, x: np.ndarray, u: np.ndarray, p: np.ndarray, h: float) -> np.ndarray:
    def rhs(xx: np.ndarray) -> np.ndarray:
        return np.ravel(f(xx, u, p)[0])

    k1 = rhs(x)
    k2 = rhs(x + h / 2 * k1)
    k3 = rhs(x + h / 2 * k2)
    k4 = rhs(x + h * k3)
    return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
