"""The closed loop on the lambdified model by SciPy's DOP853 (`maglevgen.derive.numeric`):
a reference for the generated C's runs (`maglevgen.analyses.simulate`) that shares none of
its code, only the model's equations."""

from __future__ import annotations

import numpy as np

from maglevgen.analyses.simulate import AXIS_STATES, DISTURBANCE, Trajectory, initial_state
from maglevgen.control.operating import OperatingPoint
from maglevgen.derive import conventions as cv

__all__ = ["reference_check", "reference_trajectory"]


def reference_trajectory(functions, p: np.ndarray, op: OperatingPoint, controller: str,
                         t_eval: np.ndarray, disturbance: dict[str, float] | None = None,
                         rtol: float = 1e-12, atol: float = 1e-13) -> np.ndarray:
    """The same closed loop by scipy DOP853 on the lambdified model (derive.numeric)."""
    from scipy.integrate import solve_ivp

    disturbance = DISTURBANCE if disturbance is None else disturbance
    K_pos, K_rate = op.gains(controller)
    idx = list(AXIS_STATES)
    u = np.zeros(op.allocation.shape[0] + 1)
    u[cv.PROPULSION_INPUT] = op.f_prop

    def rhs(_t: float, x: np.ndarray) -> np.ndarray:
        rates = functions.kin(x).ravel()[idx]  # position rates do not depend on u
        u[cv.ARRAY_INPUTS] = op.allocation @ (-(K_pos @ (x[idx] - op.a_trim) + K_rate @ rates))
        return functions.xdot(x, u, p).ravel()

    sol = solve_ivp(rhs, (t_eval[0], t_eval[-1]), initial_state(op, disturbance),
                    method="DOP853", t_eval=t_eval, rtol=rtol, atol=atol)
    if not sol.success:
        raise RuntimeError(f"reference integration failed: {sol.message}")
    return sol.y.T


def reference_check(functions, p: np.ndarray, traj: Trajectory) -> dict:
    """The C run against DOP853 on the lambdified model at the same samples: the largest
    deviation of each controlled axis, absolute and relative to the axis' peak excursion."""
    ref = reference_trajectory(functions, p, traj.op, traj.controller, traj.t,
                               traj.disturbance)
    idx = list(AXIS_STATES)
    dev = np.abs(traj.x[:, idx] - ref[:, idx]).max(axis=0)
    peak = np.abs(ref[:, idx] - traj.op.a_trim).max(axis=0)
    return {axis: {"max_abs": float(d), "relative_to_peak": float(d / pk) if pk > 0 else 0.0}
            for axis, d, pk in zip(cv.AXES, dev, peak, strict=True)}
