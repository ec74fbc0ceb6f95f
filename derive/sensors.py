"""Measurement equations y = h(x, xdot): what the carriage's sensors read, from the geometry
of the gaps (derive/geometry.py) and the rigid body's kinematics (derive/rigid_body.py).

- A gap sensor at body point b on the face of an array with unit normal n (body axes) and
  nominal gap g0 looks along the face's normal as it turns with the body, -R n, at the track
  plane that face runs over (the plane through a - g0 n of the design pose, normal n, as in
  derive/geometry.py). The perpendicular gap of its point is array_gap's at b,
  g = g0 + n . (X + (R - 1) b) (b on the face: n . b = n . a), and the ray from X + R b along
  -R n meets the plane after

      d = g / (n . R n),

  its reading (equal to g to first order: n . R n = 1 - O(angle^2)).
- The gyro reads the body rates omega = (p, q, r) (body axes).
- The accelerometer at body point r reads the specific force in body axes: the inertial
  acceleration of its point less gravity's,

      f = v' + omega x v + omega' x r + omega x (omega x r) + R^T (0, 0, g),

  with (v', omega') the body-velocity rates of xdot (eqs 1-2), so that it depends on the
  inputs through the dynamics: dy/du = (dh/dxdot) (df/du).
- The track sensor reads the position of O along the track, x.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import sympy as sp

from maglevgen.derive import conventions as cv
from maglevgen.derive.geometry import ArraySymbols, array_gap
from maglevgen.derive.rigid_body import rotation_body_to_inertial

__all__ = ["GapSensorSymbols", "accelerometer_reading", "gap_reading", "measurement_model"]


@dataclass(frozen=True)
class GapSensorSymbols:
    """One gap sensor's geometry: its body point b, its face's unit normal n (body axes) and
    that face's nominal gap g0 (symbols or numbers)."""

    point: sp.Matrix
    normal: sp.Matrix
    nominal_gap: sp.Expr


def gap_reading(sensor: GapSensorSymbols, position_O: sp.Matrix, R: sp.Matrix) -> sp.Expr:
    """The distance a gap sensor reads along -R n to its face's track plane: the exact
    perpendicular gap of its point (derive.geometry.array_gap at b) over n . R n."""
    face = ArraySymbols("sensor", sensor.point, sensor.normal, sensor.nominal_gap, sp.S.One)
    perpendicular = array_gap(face, position_O, R)
    return perpendicular / (sensor.normal.T * R * sensor.normal)[0]


def gyro_reading(omega: sp.Matrix) -> sp.Matrix:
    """The body rates (p, q, r)."""
    return sp.Matrix(omega)


def accelerometer_reading(point: sp.Matrix, R: sp.Matrix, velocity: sp.Matrix,
                          omega: sp.Matrix, velocity_rate: sp.Matrix, omega_rate: sp.Matrix,
                          gravity: sp.Expr) -> sp.Matrix:
    """The specific force at body point r, body axes (the module docstring)."""
    accel = (velocity_rate + omega.cross(velocity) + omega_rate.cross(point)
             + omega.cross(omega.cross(point)))
    return accel + R.T * sp.Matrix([0, 0, gravity])


def track_reading(position_O: sp.Matrix) -> sp.Expr:
    """The position of O along the track (inertial x)."""
    return position_O[0]


@dataclass(frozen=True)
class MeasurementModel:
    """y = h(x, xdot) of a sensor set, stacked gaps, gyro (3), accelerometer (3), track
    (each group present or not), with its Jacobians H_x = dh/dx and H_xdot = dh/dxdot."""

    x: sp.Matrix  # the 12 states, conventions.STATES order
    xdot: sp.Matrix  # their rates (the accelerometer reads v' and omega')
    y: sp.Matrix
    names: tuple[str, ...]  # one per row of y
    H_x: sp.Matrix
    H_xdot: sp.Matrix


def measurement_model(gaps: Sequence[tuple[str, GapSensorSymbols]],
                      imu_point: sp.Matrix | None, gravity: sp.Expr | None,
                      track: bool) -> MeasurementModel:
    """The stacked measurement equations of named gap sensors, an IMU at ``imu_point`` (None:
    none) and the track sensor (``track``), and their Jacobians."""
    x = sp.Matrix(sp.symbols(" ".join(cv.STATE_NAMES), real=True))
    xdot = sp.Matrix(sp.symbols(" ".join(f"{n}_dot" for n in cv.STATE_NAMES), real=True))
    pos, (phi, theta, psi) = x[cv.POSITION, 0], x[cv.ATTITUDE]
    vel, omega = x[cv.VELOCITY, 0], x[cv.RATES, 0]
    R = rotation_body_to_inertial(phi, theta, psi)
    rows: list[sp.Expr] = []
    names: list[str] = []
    for name, sensor in gaps:
        rows.append(gap_reading(sensor, pos, R))
        names.append(f"gap_{name}")
    if imu_point is not None:
        if gravity is None:
            raise ValueError("an accelerometer's reading needs gravity")
        rows += list(gyro_reading(omega))
        names += ["gyro_p", "gyro_q", "gyro_r"]
        rows += list(accelerometer_reading(imu_point, R, vel, omega, xdot[cv.VELOCITY, 0],
                                           xdot[cv.RATES, 0], gravity))
        names += ["accel_x", "accel_y", "accel_z"]
    if track:
        rows.append(track_reading(pos))
        names.append("track_x")
    y = sp.Matrix(rows)
    return MeasurementModel(x, xdot, y, tuple(names), y.jacobian(x), y.jacobian(xdot))
