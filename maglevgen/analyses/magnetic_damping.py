"""The track circuits' magnetic damping per axis, read from the generated C's Jacobians.

With ``model.circuit_dynamics = "first-order"`` each array's lift and drag depend on its gap
rates (the circuits' lag, derive/circuit_lag.py), so the Jacobian's velocity columns carry a
magnetic damping. Per axis (lateral, vertical, roll, pitch, yaw: conventions.AXES) it is read
as the per-axis plants read the stiffness, from the diagonal:

    c_i = -m_i dA[rate_i, rate_i],   rate_i = v, w, p, q, r (the axis's body rate)

at the trim, m_i the axis inertia of ``maglev_axis_plants``, so that the axis closes as
m_i a'' + (c_i + K_rate,i) a' + (k_i + K_pos,i) a = 0 beside the controller's rate gain. The
diagonal of the rigid body's Coriolis terms is zero at trim (no body rate), so c_i is the
array forces' own. Positive damps, negative (above v_c = R/(k L)) feeds the motion; the
quasi-static model's c_i is only eq 3's speed dependence (the array speed's body-rate part).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from maglevgen.control.carriage_plant import Plant
from maglevgen.control.operating import OperatingPoint
from maglevgen.derive import conventions as cv

__all__ = ["axis_damping", "damping_across_speed"]

# the body rate of each axis, in conventions.AXES order
AXIS_RATES: tuple[str, ...] = ("v", "w", "p", "q", "r")


def axis_damping(op: OperatingPoint, axis_inertia: np.ndarray) -> np.ndarray:
    """c (5,) at ``op``: -m_i A[rate_i, rate_i] (N s/m, N m s/rad), see the module docstring."""
    idx = [cv.STATE_INDEX[s] for s in AXIS_RATES]
    return -np.asarray(axis_inertia, dtype=float).ravel() * np.diag(op.A)[idx]


def damping_across_speed(plant: Plant, speeds: Sequence[float] | np.ndarray) -> np.ndarray:
    """c (n_speeds, 5) at each speed's trim, from the plant's compiled library."""
    points = plant.points(speeds)
    plants = plant.lib.function("maglev_axis_plants")
    return np.array([axis_damping(op, plants(op.speed, plant.p)[1]) for op in points])
