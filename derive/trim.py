"""Trim: the equilibrium of the nonlinear model at a forward speed, steady or accelerating.

Unknowns: lateral offset y, heave z, roll, pitch, yaw and the propulsion force F_prop; the
carriage moves at speed V along the track (inertial velocity (V, 0, 0), no rotation) with no
control force. The equations are the six accelerations of eqs 1-2 set to their value in a pure
translation at the along-track acceleration a (`along_track_acceleration`; zero at constant
speed). With upper and lower arrays both acting, the heave has no closed form, so the root is
found numerically: a bracketed 1-D solve of the vertical balance gives the start, Newton
(MINPACK hybrd) the rest.

The accelerating trim (a != 0): the carriage keeps its pose (w = w' = 0) while O accelerates
at a e_x (inertial). Its body-axis acceleration is then v' = R^T (a, 0, 0) and eqs 1-2 read

    f_O = m R^T a e_x,        m_O = r_G x (m R^T a e_x),                       (1), (2)

the six static balances of the moving frame with the d'Alembert load -m a e_x at the CG:
f_O - m a R^T e_x = 0 and m_O - r_G x m a R^T e_x = 0. The propulsion F_prop (along the track
at operation.propulsion_point, derive.model) balances the drag and m a: along the track
F_prop = sum_i F_D,i + m a (lift acts along the track normals, which have no x component), and
its moment arm below the CG, m a (z_cg - z_prop), pitches the carriage nose down against the
pitch stiffness. Since eqs 1-2 are linear in (v', w') with an invertible mass matrix, setting
the model's accelerations to (R^T a e_x, 0) is the same root as the static balances with the
d'Alembert load; at a = 0 it is the constant-speed trim term by term.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import sympy as sp
from scipy.optimize import brentq, root

from maglevgen.derive import conventions as cv
from maglevgen.derive.numeric import ModelFunctions
from maglevgen.derive.search import lowest_trim_speed

__all__ = ["NoTrimError", "Trim", "along_track_acceleration", "lift_off_speed", "solve_trim"]


class NoTrimError(ValueError):
    """No equilibrium at the requested speed (the application reports it as bad input:
    maglevgen.errors.NoTrimError, exit 2)."""

_TRIM_UNKNOWNS = ("y", "z", "phi", "theta", "psi")


def along_track_acceleration(R: sp.Matrix, accel: sp.Expr) -> sp.Matrix:
    """(v', w') of a pure translation at ``accel`` along the track: the accelerating trim's
    target for the model's six accelerations (eqs 1-2 with w = w' = 0).

    Parameters
    ----------
    R : sympy.Matrix
        Body-to-inertial rotation (3 x 3) at the trim pose (derive.rigid_body, Z-Y-X Euler).
    accel : sympy.Expr
        Along-track (inertial x) acceleration a [m/s^2].

    Returns
    -------
    sympy.Matrix
        (6, 1): R^T (a, 0, 0) (the body-axis acceleration of O), then (0, 0, 0). Eqs 1-2 equal
        to these are the static balances with the d'Alembert load -m a e_x at the CG (module
        docstring); zero at a = 0.
    """
    return sp.Matrix.vstack(R.T * sp.Matrix([accel, 0, 0]), sp.zeros(3, 1))


@dataclass(frozen=True)
class Trim:
    """An equilibrium: the state, the propulsion force, and every array's gap and forces."""

    speed: float
    x: np.ndarray  # 12 states
    u: np.ndarray  # inputs (propulsion, control components = 0)
    gaps: np.ndarray
    lift: np.ndarray
    drag: np.ndarray
    residual: float  # max |acceleration - target| at the root, m/s^2 or rad/s^2
    acceleration: float = 0.0  # along-track acceleration a [m/s^2] (0: constant speed)


def trim_state(speed: float, q: np.ndarray) -> np.ndarray:
    """The 12-state vector at pose q = (y, z, phi, theta, psi) moving at (speed, 0, 0) inertial."""
    x = np.zeros(cv.N_STATES)
    x[cv.AXIS_COORDINATES] = q
    x[cv.VELOCITY] = _rotation(*x[cv.ATTITUDE]).T @ np.array([speed, 0.0, 0.0])
    return x


# The trim's unknowns: the pose q (Q_STATES), then the propulsion force.
_POSE = slice(0, len(cv.Q_STATES))
_F_PROP = len(cv.Q_STATES)


def _level_pose(z: float) -> np.ndarray:
    """The pose q at heave z, level and centred."""
    q = np.zeros(len(cv.Q_STATES))
    q[cv.Q_STATES.index("z")] = z
    return q


def _rotation(phi: float, theta: float, psi: float) -> np.ndarray:
    cf, sf, ct, st, cp, sp_ = (np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta),
                               np.cos(psi), np.sin(psi))
    return (np.array([[cp, -sp_, 0], [sp_, cp, 0], [0, 0, 1]])
            @ np.array([[ct, 0, st], [0, 1, 0], [-st, 0, ct]])
            @ np.array([[1, 0, 0], [0, cf, -sf], [0, sf, cf]]))


def _heave_limits(mf: ModelFunctions, p: np.ndarray, min_gap: float) -> tuple[float, float]:
    """The heave range in which every array keeps at least ``min_gap`` at zero attitude."""
    g0 = mf.gaps(np.zeros(cv.N_STATES), p).ravel()
    # the gap change per metre of heave
    dz = mf.gaps(np.eye(cv.N_STATES)[cv.STATE_INDEX["z"]], p).ravel() - g0
    lo = max((min_gap - g) / d for g, d in zip(g0, dz, strict=True) if d > 0)
    hi = min((min_gap - g) / d for g, d in zip(g0, dz, strict=True) if d < 0)
    return lo, hi


def _vertical_force(mf: ModelFunctions, p: np.ndarray, speed: float, z: float) -> float:
    x = trim_state(speed, _level_pose(z))
    u = np.zeros(mf.model.u.shape[0])
    return float(mf.body_wrench(x, u, p)[2])


def lift_off_speed(mf: ModelFunctions, p: np.ndarray, min_gap: float,
                   v_max: float = 1e4) -> float:
    """The lowest speed with an equilibrium that keeps every gap above ``min_gap``.

    A necessary bound comes first (the vertical balance at zero attitude with the upper gap at
    its limit); the equilibrium's own pitch and roll then move it up, found by bisection on
    whether a trim exists.
    """
    z_lo, _ = _heave_limits(mf, p, min_gap)
    f = lambda v: _vertical_force(mf, p, v, z_lo)  # noqa: E731
    if f(v_max) <= 0:
        return float("inf")
    lo = float(brentq(f, 1e-6, v_max, xtol=1e-9))
    return lowest_trim_speed(lambda v: _has_trim(mf, p, v, min_gap), lo, max(2 * lo, 1e-3),
                             v_max)


def _has_trim(mf: ModelFunctions, p: np.ndarray, speed: float, min_gap: float) -> bool:
    try:
        solve_trim(mf, p, speed, min_gap, _explain=False)
    except NoTrimError:
        return False
    return True


def solve_trim(mf: ModelFunctions, p: np.ndarray, speed: float, min_gap: float,
               _explain: bool = True, acceleration: float = 0.0) -> Trim:
    """The equilibrium at ``speed``, or NoTrimError saying why there is none.

    ``acceleration``: the along-track acceleration a [m/s^2] of the accelerating trim (module
    docstring): the six accelerations equal `along_track_acceleration` instead of zero.
    """
    if not speed > 0:
        raise NoTrimError(f"operation.speed = {speed!r}: must be > 0")
    if not np.isfinite(acceleration):
        raise NoTrimError(f"acceleration = {acceleration!r}: must be finite")
    n_u = mf.model.u.shape[0]
    z_lo, z_hi = _heave_limits(mf, p, min_gap)
    if not z_lo < z_hi:
        raise NoTrimError(f"track geometry leaves no heave range with every gap above "
                          f"track.min_gap = {min_gap:g} m")
    f_lo, f_hi = (_vertical_force(mf, p, speed, z) for z in (z_lo, z_hi))
    if f_lo <= 0:
        v_off = lift_off_speed(mf, p, min_gap) if _explain else float("nan")
        raise NoTrimError(
            f"no trim at speed {speed:g} m/s: the arrays cannot lift the carriage off the track "
            f"(net vertical force {f_lo:.4g} N at the contact gap); "
            + (f"lift-off needs {v_off:.4g} m/s" if math.isfinite(v_off)
               else "no speed lifts it off"))
    if f_hi >= 0:
        raise NoTrimError(f"no trim at speed {speed:g} m/s: the lift pushes the lower arrays "
                          f"into the track (net vertical force {f_hi:.4g} N at their contact gap)")
    z0 = brentq(lambda z: _vertical_force(mf, p, speed, z), z_lo, z_hi, xtol=1e-15)

    def residual(unknowns: np.ndarray) -> np.ndarray:
        x = trim_state(speed, unknowns[_POSE])
        u = np.zeros(n_u)
        u[0] = unknowns[_F_PROP]
        # along_track_acceleration: R^T e_x a is the trim state's velocity direction times a
        return mf.xdot(x, u, p)[cv.KINETIC] - np.concatenate(
            [x[cv.VELOCITY] * (acceleration / speed), np.zeros(3)])

    drag0 = mf.forces(trim_state(speed, _level_pose(z0)), p)[2].sum()
    drag0 += _mass(mf, p) * acceleration
    sol = root(residual, np.append(_level_pose(z0), drag0), method="hybr", tol=1e-14)
    res = float(np.max(np.abs(residual(sol.x))))
    if not sol.success and res > 1e-8:
        raise NoTrimError(f"no trim at speed {speed:g} m/s: the equilibrium solver did not "
                          f"converge ({' '.join(sol.message.split())}; residual {res:.3g})")
    x = trim_state(speed, sol.x[_POSE])
    u = np.zeros(n_u)
    u[0] = sol.x[_F_PROP]
    gaps, lift, drag = mf.forces(x, p)
    corners = mf.contact_gaps(x, p).ravel()  # contact: each face's closest corner
    if corners.min() < min_gap:
        i = int(np.argmin(corners))
        name = mf.model.arrays[i].name
        hint = f"; lift-off needs {lift_off_speed(mf, p, min_gap):.4g} m/s" if _explain else ""
        raise NoTrimError(f"no trim at speed {speed:g} m/s: array {name} would sit at gap "
                          f"{corners[i]:.4g} m, below track.min_gap = {min_gap:g} m{hint}")
    return Trim(speed, x, u, gaps, lift, drag, res, float(acceleration))


def _mass(mf: ModelFunctions, p: np.ndarray) -> float:
    """vehicle.mass from the parameter vector (the start of the accelerating trim's F_prop)."""
    return float(p[mf.model.structure.param_names.index("vehicle.mass")])
