"""The firmware estimator's schedule: the sense tick's table over speed
(templates/firmware_maglev_sense.c.j2), its readings' plausible ranges, and the accelerating
trim it flies a launch on.

Each row holds one speed's steady-state Kalman filter (`maglevgen.control.estimation`) in the
form the tick applies it, and the trim's change per unit of commanded acceleration.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from maglevgen.control.estimation import SensorLayout, estimator_points, measurement_model
from maglevgen.control.operating import OperatingPoint, checked_accelerating_trim
from maglevgen.control.schedule import GAIN_TABLE_BOUND, GainTable, field_scales, field_slices
from maglevgen.derive import conventions as cv
from maglevgen.errors import InputError, NoTrimError

__all__ = ["ACCEL_RANGE", "GAP_RANGE", "GYRO_RANGE", "M_DROPPED_SHARE", "TRACK_RANGE",
           "TRIM_READING_SHARE", "reading_ranges", "sense_fields", "sense_plants", "sense_table"]

#: a gap reading is plausible within [0, this x its face's nominal gap] (a gap sensor's
#: measuring range: contact to a few times the gap it flies at)
GAP_RANGE = 4.0
#: [rad/s] a gyro reading's plausible magnitude: 2000 deg/s, a MEMS gyro's widest full scale
GYRO_RANGE = 35.0
#: [m/s^2] an accelerometer reading's plausible magnitude: 16 g, a MEMS accelerometer's
ACCEL_RANGE = 157.0
#: [m] the track position's plausible magnitude: 10 000 km of track
TRACK_RANGE = 1e7


def reading_ranges(layout: SensorLayout) -> np.ndarray:
    """(n_readings, 2) [lo, hi] of each reading the sense tick accepts (GAP_RANGE,
    GYRO_RANGE, ACCEL_RANGE, TRACK_RANGE; the readings' order of `SensorLayout`): a reading
    outside its range is a faulty sensor, not a state, and is left out of the update."""
    rows = [(0.0, GAP_RANGE * g.nominal_gap) for g in layout.gaps]
    if layout.imu_point is not None:
        rows += [(-GYRO_RANGE, GYRO_RANGE)] * 3 + [(-ACCEL_RANGE, ACCEL_RANGE)] * 3
    if layout.track:
        rows.append((-TRACK_RANGE, TRACK_RANGE))
    return np.array(rows, dtype=float).reshape(-1, 2)


def sense_fields(n_states: int, n_lag: int, n_inputs: int,
                 n_readings: int) -> tuple[tuple[str, int], ...]:
    """The sense table's row (each matrix column-major): the trim propulsion F_prop, the trim
    state (all MAGLEV_NX entries), the readings at trim, then on the estimator's plant states
    (``n_states``, `EstimatorModel.states`) and lagged array forces (``n_lag``): Phi - I (the
    plant rows of the ZOH transition less the identity, so that the table's bound is on the
    motion of one tick, not on 1), Gamma (the plant rows' input matrix on the command applied
    during the tick), C and D (the readings on those states and on the applied command) and
    the update's gain M (plant rows); then the accelerating trim's change per m/s^2 of
    commanded acceleration: its state (all MAGLEV_NX entries) and its propulsion
    (`accelerating_change`). Not stored: the lag's rows (exactly a F + (1 - a) F_c,
    a = exp(-h / tau)), the queue of commands in flight (a shift), and M's rows on them (the
    filter knows its commands; measured below 1e-7 of M's largest entry on the default
    carriage)."""
    n, nl, m, ny = n_states, n_lag, n_inputs, n_readings
    return (("F_prop", 1), ("x_trim", len(cv.STATES)), ("y_trim", ny),
            ("Phi_minus_I", n * (n + nl)), ("Gamma", n * m), ("C", ny * (n + nl)),
            ("D", ny * m), ("M", n * ny), ("x_accel", len(cv.STATES)), ("F_accel", 1))


@dataclass(frozen=True)
class SensePlant:
    """The exact matrices of one row of the sense table at a speed (`sense_plant`)."""

    speed: float
    f_prop: float  # [N] the trim propulsion
    x_trim: np.ndarray  # (MAGLEV_NX,) the trim state
    y_trim: np.ndarray  # (n_readings,)
    Phi: np.ndarray  # (n, n + n_lag) the plant rows of the transition
    Gamma: np.ndarray  # (n, m) the plant rows' input matrix (the applied command)
    C: np.ndarray  # (n_readings, n + n_lag)
    D: np.ndarray  # (n_readings, m) on the applied command
    M: np.ndarray  # (n, n_readings) the update's gain, plant rows
    M_dropped: float  # the largest |entry| of M's rows not stored (lag, queue)
    x_accel: np.ndarray  # (MAGLEV_NX,) [per m/s^2] the accelerating trim's state change
    f_accel: float  # [N per m/s^2] its propulsion's change (m and the drag's change)

    def row(self) -> np.ndarray:
        """The table's row (`sense_fields`' order)."""
        n = self.Phi.shape[0]
        x_trim = self.x_trim.copy()
        x_trim[cv.STATE_INDEX["u"]] -= self.speed  # u - v: the tick adds its speed back
        return np.concatenate([
            [self.f_prop], x_trim, self.y_trim,
            (self.Phi - np.eye(*self.Phi.shape)).ravel(order="F"),
            self.Gamma.ravel(order="F"), self.C.ravel(order="F"), self.D.ravel(order="F"),
            self.M[:n].ravel(order="F"), self.x_accel, [self.f_accel]])


#: an entry of the accelerating trim's change below this share of its largest is rounding
#: (the lateral states, zero by symmetry): zero, so that the tick has no term for it
ACCEL_ROUNDING = 1e-9


def accelerating_change(lib, p: np.ndarray, op: OperatingPoint,
                        params) -> tuple[np.ndarray, float]:
    """The trim's change per m/s^2 of along-track acceleration at ``op``'s speed: the state
    (all MAGLEV_NX entries: the pose, and the body velocities that carry the same speed
    along the track at the other pitch) and the propulsion of the accelerating trim at
    envelope.launch_acceleration a_L less the steady trim's, over a_L
    (`checked_accelerating_trim`; the propulsion's is m plus the drag's change). The sense
    tick scales them by the commanded acceleration: the trim of a launch at a_L exactly,
    linear in between; zero when a_L is 0. InputError naming envelope.launch_acceleration
    where there is no accelerating trim."""
    a = params.envelope.launch_acceleration
    if a == 0:
        return np.zeros(len(cv.STATES)), 0.0
    try:
        x_a, f_a, _ = checked_accelerating_trim(lib, p, op.speed, a, params.track.min_gap)
    except NoTrimError as exc:
        raise InputError(f"envelope.launch_acceleration = {a:g}: {exc}") from None
    change = (np.asarray(x_a, dtype=float) - np.asarray(op.x_trim, dtype=float)) / a
    change[np.abs(change) < ACCEL_ROUNDING * np.max(np.abs(change))] = 0.0
    return change, float((f_a - op.f_prop) / a)


def sense_plants(lib, p: np.ndarray, params, points: list[OperatingPoint], tau: float,
                 delay: int) -> list[SensePlant]:
    """`SensePlant` at each operating point: the estimator (`estimator_points`, the lag
    ``tau``) with ``delay`` ticks of delay (the file's tick) and the readings at trim
    (`measurement_model`). The trim state's and the track reading's along-track position
    are the trim's at the start (0): the tick carries the position itself (the moving trim)."""
    layout = SensorLayout.of(params)
    out = []
    for op, point in zip(points, estimator_points(lib, p, params, points, tau), strict=True):
        model, design = point.model, point.design
        n, nl, m = model.n_x, model.n_lag, model.Gamma.shape[1]
        nc = n + nl
        if delay > 0:  # the command applied during the tick: the oldest in flight
            oldest = slice(nc + (delay - 1) * m, nc + delay * m)
            Gamma, D = model.Phi[:n, oldest], model.C[:, oldest]
        else:
            Gamma, D = model.Gamma[:n], model.D
        y_trim = measurement_model(lib, p, op, layout).y_trim
        x_accel, f_accel = accelerating_change(lib, p, op, params)
        out.append(SensePlant(model.speed, float(op.f_prop), np.asarray(op.x_trim, dtype=float),
                              y_trim, model.Phi[:n, :nc], Gamma, model.C[:, :nc], D,
                              design.M[:n], float(np.max(np.abs(design.M[n:]), initial=0.0)),
                              x_accel, f_accel))
    return out


#: M's rows the sense tick does not apply (on the lagged forces and the commands in flight):
#: their largest entry at most this share of M's largest (measured 3e-8 on the default
#: carriage), else the table refuses to leave them out
M_DROPPED_SHARE = 1e-6


def sense_table(lib, p: np.ndarray, params, operating_at, v_min: float, v_max: float,
                tau: float, delay: int) -> GainTable:
    """The sense tick's schedule over [v_min, v_max] (`sense_fields`, `sense_plants`) in the
    controller's table machinery (schedule.GainTable: a Chebyshev series in 1/v, the fewest
    nodes within GAIN_TABLE_BOUND of each field's largest magnitude on a dense grid, each
    value's terms cut to schedule.DROP_SHARE of that bound: most of the filter's values are
    constant over speed to it);
    ``operating_at(v)``: the operating point at a speed. ValueError when M's rows left out
    exceed M_DROPPED_SHARE at some speed (the filter would need them)."""
    layout = SensorLayout.of(params)

    def rows(speeds: np.ndarray) -> np.ndarray:
        plants = sense_plants(lib, p, params, [operating_at(float(v)) for v in speeds], tau,
                              delay)
        for sp in plants:
            if sp.M_dropped > M_DROPPED_SHARE * np.max(np.abs(sp.M)):
                raise ValueError(f"sense table: at {sp.speed:.4g} m/s the update's gain on the "
                                 f"lagged forces or the commands in flight reaches "
                                 f"{sp.M_dropped:.3g} ({sp.M_dropped / np.max(np.abs(sp.M)):.2g}"
                                 f" of M's largest entry; the tick leaves them out)")
        return np.array([sp.row() for sp in plants])

    n_states = len(cv.STATES) - (0 if layout.track else 1)
    n_inputs = operating_at(v_min).B.shape[1]
    n_lag = n_inputs - 1 if tau > 0 else 0
    sigma = np.sqrt(layout.variances)

    def scales(exact: np.ndarray, fields: tuple[tuple[str, int], ...]) -> np.ndarray:
        return sense_scales(exact, fields, sigma)

    return GainTable.fit(rows, v_min, v_max,
                         sense_fields(n_states, n_lag, n_inputs, len(layout.names)),
                         value_scale=scales)


#: a reading's row (column) of C, D or M smaller than this share of its field's largest
#: value everywhere is measured against the field's (its values do not matter below that)
OWN_SCALE_FLOOR = 1e-6


#: the sense table's readings at trim: each within this share of the reading's noise (its
#: standard deviation at the tick), an absolute bound (`sense_scales`)
TRIM_READING_SHARE = 0.1


def sense_scales(exact: np.ndarray, fields: tuple[tuple[str, int], ...],
                 sigma: np.ndarray) -> np.ndarray:
    """Each value's scale in the sense table's bound (schedule.GainTable.fit's
    ``value_scale``; GAIN_TABLE_BOUND x scale is what a value may be off), from the dense
    grid's ``exact`` rows and each reading's noise ``sigma`` at the tick. A field's largest
    value is its values' measure (schedule.field_scales) where they share a unit, not where
    they mix the readings': the readings at trim (gaps of 15 mm beside the accelerometer's
    9.81 m/s^2, which made a gap's trim 0.18 mm off within the bound) are each bound to
    TRIM_READING_SHARE of its noise; C's and D's rows and M's columns, one reading each, to
    their own largest magnitude."""
    scale = field_scales(exact, fields)
    ny = sigma.size
    for (name, n), (i, _) in zip(fields, field_slices(fields), strict=True):
        block = np.max(np.abs(exact[:, i:i + n]), axis=0)
        if name == "y_trim":
            scale[i:i + n] = TRIM_READING_SHARE * sigma / GAIN_TABLE_BOUND
        elif name in ("C", "D"):  # column-major ny x k: reading j's row is j, j + ny, ...
            per = block.reshape(-1, ny).max(axis=0)
            per = np.where(per > OWN_SCALE_FLOOR * scale[i], per, scale[i])
            scale[i:i + n] = np.tile(per, n // ny)
        elif name == "M":  # column-major k x ny: reading j's column is a run of k
            per = block.reshape(ny, -1).max(axis=1)
            per = np.where(per > OWN_SCALE_FLOOR * scale[i], per, scale[i])
            scale[i:i + n] = np.repeat(per, n // ny)
    return scale
