"""`spec`: the coupled LQR with weights chosen from the specification (``[control.spec]``).

Per axis i (lateral, heave, roll, pitch, yaw), Bryson's rule gives q1_i = 1/a_max,i^2 from the
allowed deviation and r_i = 1/F_max,i^2 from the force budget, F_max,i being the generalized
force that alone takes one array to its budget through the allocation T (eqs 22-23):
F_max,i = budget / max_j |T_ji|. The rate weight q2_i is the closed form of
`maglevgen.derive.spec_design` that gives the per-axis closed loop (k_i, m_i of
`maglev_axis_plants`) the design damping ratio min_damping_ratio + damping_margin:

    q2 = 2 m r (k - (1 - 2 zeta^2) sigma),  sigma = sqrt(k^2 + q1/r)

(floored at a tiny positive weight where the position weight alone damps the axis more).
The gains are the full-state LQR of the coupled 10-state linearisation with these weights
(SciPy's CARE), written as 5 x 5 gains on (a - a_ref, a') like the coupled LQR's; the firmware
runs them through the same tick (`maglev_coupled_control`) from the table schedule.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from maglevgen.control.lqr import numerical_lqr, weighted_qr
from maglevgen.control.registry import Controller, register

if TYPE_CHECKING:
    from maglevgen.control.operating import OperatingPoint

__all__ = ["axis_force_limits", "rate_weight", "spec_weights"]

# q2 where the closed form is not positive, relative to q1 m / sigma (the rate weight that
# would weigh the axis' natural-frequency rate like its position): small, not zero, so that R
# and Q stay definite
RATE_WEIGHT_FLOOR = 1e-6


def axis_force_limits(T: np.ndarray, budget: float) -> np.ndarray:
    """F_max,i = budget / max_j |T_ji|: the generalized force i that alone drives the most
    loaded array force component to the budget (T: array forces per generalized force)."""
    return budget / np.max(np.abs(T), axis=0)


def rate_weight(zeta: float, q1: np.ndarray, r: np.ndarray, k: np.ndarray,
                m: np.ndarray) -> np.ndarray:
    """q2 giving the per-axis closed loop the damping ratio ``zeta`` (the module docstring's
    closed form, `maglevgen.derive.spec_design.rate_weight_form`), floored."""
    sigma = np.sqrt(k**2 + q1 / r)
    q2 = 2 * m * r * (k - (1 - 2 * zeta**2) * sigma)
    return np.maximum(q2, RATE_WEIGHT_FLOOR * q1 * m / sigma)


def spec_weights(op: OperatingPoint) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(q1, q2, r) per axis at ``op``."""
    s = op.weights.spec
    if s is None or op.plants is None:
        raise ValueError("the operating point carries no specification (Weights.spec) or no "
                         "axis plants")
    q1 = 1.0 / np.asarray(s.a_max) ** 2
    r = 1.0 / axis_force_limits(op.allocation, s.force_budget) ** 2
    k, m = op.plants[:, 0], op.plants[:, 1]
    return q1, rate_weight(s.zeta, q1, r, k, m), r


def _spec(op: OperatingPoint) -> tuple[np.ndarray, np.ndarray]:
    A_r, B_g = op.reduced
    q1, q2, r = spec_weights(op)
    try:
        K = numerical_lqr(A_r, B_g, *weighted_qr(op.rate_map, q1, q2, r))
    except (np.linalg.LinAlgError, ValueError):
        K = np.full((len(q1), A_r.shape[0]), np.nan)
    return op.axis_gains(K)


register(Controller(
    "spec", "spec LQR", "the coupled LQR with weights from [control.spec]: Bryson's rule on "
    "the allowed deviations and the force budget, the rate weight in closed form for the "
    "damping ratio", _spec, style={"color": "tab:red", "ls": "-", "lw": 1.3}, tick_design=True,
    weights=spec_weights))
