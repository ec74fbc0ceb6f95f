"""Operating points: trim, gains and the linearised closed loop at one speed, from the
generated C.

Every number here comes from the compiled run-time-parameter library (`maglev_trim`,
`maglev_lqr_gains`, `maglev_jacobians`, `maglev_allocation_matrix`); numpy and SciPy only
assemble and solve small dense problems (eigenvalues, the coupled LQR's Riccati equation).

The controllers act on the axis coordinates a = (y, z, phi, theta, psi) and their rates
a' (the Euler kinematics of the body velocities), with 5 x 5 gain matrices:

    u_gen = -(K_pos (a - a_ref) + K_rate a')

- ``none``: K_pos = K_rate = 0;
- ``damping``: K_pos = 0, K_rate = diag(c) (optimized damping, eqs 20-21);
- ``lqr``: the paper's per-axis LQR (eqs 24-33): K_pos = diag(K[:, 0]), K_rate = diag(K[:, 1]);
- ``coupled``: a full-state LQR of the coupled 10-state linearisation (below), with the same
  weights as the per-axis design (Q = q1 on every axis position and q2 on every axis rate,
  R = r on every generalized force), written in the same (a, a') coordinates.

The coupled linearisation: the 12-state Jacobian at trim restricted to the ten states
(y, z, phi, theta, psi, v, w, p, q, r). The along-track position x is dropped because nothing
depends on it (a pure integrator); the forward speed u is dropped because the propulsion
holds it (it is the scheduling variable, not a state the arrays control; its own slow mode
under a constant force, the drag's slope with speed, is reported beside, not as part of the
controller's stability). The inputs are the five generalized forces through the minimum-norm
allocation T (eqs 22-23).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .derive import conventions as cv
from .derive.conventions import Q_STATES
from .errors import InputError, NoTrimError
from .library import SimulationLibrary
from .runtime.ffi import GeneratedFunctionError

CONTROLLERS: tuple[str, ...] = ("none", "damping", "lqr", "coupled")
CONTROLLER_TITLES: dict[str, str] = {"none": "no control", "damping": "optimized damping",
                                     "lqr": "per-axis LQR", "coupled": "coupled LQR"}
AXIS_STATES: tuple[int, ...] = tuple(cv.STATE_INDEX[s] for s in Q_STATES)
# the coupled model's states (see the module docstring)
REDUCED_STATES: tuple[str, ...] = ("y", "z", "phi", "theta", "psi", "v", "w", "p", "q", "r")
REDUCED_INDEX: tuple[int, ...] = tuple(cv.STATE_INDEX[s] for s in REDUCED_STATES)
N_AXES = len(cv.AXES)


@dataclass(frozen=True)
class Weights:
    """LQR weights per axis: q1 on the position, q2 on the rate, r on the force."""

    q1: float
    q2: float
    r: float

    @classmethod
    def of(cls, params) -> Weights:
        (q1, q2), r = params.control.state_weights, params.control.input_weight
        return cls(float(q1), float(q2), float(r))


@dataclass(frozen=True)
class OperatingPoint:
    """Trim, gains and the linearisation at one speed, all computed by the generated C."""

    speed: float
    x_trim: np.ndarray
    f_prop: float
    gaps: np.ndarray
    K: np.ndarray  # (5, 2) per-axis LQR position and rate gains
    c_damping: np.ndarray  # (5,) optimized damping gains
    allocation: np.ndarray  # T (n_array_forces x 5)
    A: np.ndarray  # (12, 12) df/dx at trim
    B: np.ndarray  # (12, n_u) df/du at trim
    weights: Weights

    @cached_property
    def K_coupled(self) -> np.ndarray:
        """(5, 10) the coupled LQR on REDUCED_STATES; NaN where the Riccati equation has no
        stabilizing solution. Solved when first asked for (the other controllers never do)."""
        A_r, B_g = self.reduced
        try:
            return coupled_lqr(A_r, B_g, self.rate_map, self.weights)
        except (np.linalg.LinAlgError, ValueError):
            return np.full((N_AXES, len(REDUCED_INDEX)), np.nan)

    @property
    def a_trim(self) -> np.ndarray:
        return self.x_trim[list(AXIS_STATES)]

    @property
    def rate_map(self) -> np.ndarray:
        """C_rate (5 x 10): the axis rates a' as a linear function of the reduced state."""
        return self.A[np.ix_(list(AXIS_STATES), list(REDUCED_INDEX))]

    @property
    def reduced(self) -> tuple[np.ndarray, np.ndarray]:
        """(A_r, B_gen): the 10-state linearisation driven by the five generalized forces."""
        idx = list(REDUCED_INDEX)
        return self.A[np.ix_(idx, idx)], self.B[idx, 1:] @ self.allocation

    def gains(self, controller: str) -> tuple[np.ndarray, np.ndarray]:
        """(K_pos, K_rate), each 5 x 5, of a controller (module docstring)."""
        zero = np.zeros((N_AXES, N_AXES))
        if controller == "none":
            return zero, zero.copy()
        if controller == "damping":
            return zero, np.diag(self.c_damping)
        if controller == "lqr":
            return np.diag(self.K[:, 0]), np.diag(self.K[:, 1])
        if controller == "coupled":
            # K_c x_r = K' [a; a'] with [a; a'] = M x_r, M = [S; C_rate] (invertible near trim)
            M = np.vstack([np.eye(N_AXES, len(REDUCED_INDEX)), self.rate_map])
            K_prime = np.linalg.solve(M.T, self.K_coupled.T).T
            return K_prime[:, :N_AXES], K_prime[:, N_AXES:]
        raise InputError(f"controller {controller!r}: expected one of {', '.join(CONTROLLERS)}")

    def reduced_closed_loop(self, controller: str) -> np.ndarray:
        """A_cl (10 x 10) of the coupled linearisation with the controller closed around it."""
        A_r, B_g = self.reduced
        K_pos, K_rate = self.gains(controller)
        S = np.eye(N_AXES, len(REDUCED_INDEX))
        return A_r - B_g @ (K_pos @ S + K_rate @ self.rate_map)

    def full_closed_loop(self, controller: str) -> np.ndarray:
        """A_cl (12 x 12) of the whole linearisation with the controller (propulsion fixed)."""
        K_pos, K_rate = self.gains(controller)
        select = np.zeros((N_AXES, self.A.shape[0]))
        select[range(N_AXES), AXIS_STATES] = 1.0
        d_ugen = -(K_pos @ select + K_rate @ (select @ self.A))
        return self.A + self.B[:, 1:] @ self.allocation @ d_ugen

    @property
    def speed_pole(self) -> float:
        """The forward-speed mode under the constant trim propulsion: d(u')/du at trim [1/s]."""
        iu = cv.STATE_INDEX["u"]
        return float(self.A[iu, iu])


def checked_trim(lib: SimulationLibrary, p: np.ndarray, speed: float,
                 min_gap: float) -> tuple[np.ndarray, float, np.ndarray]:
    """(x_trim, F_prop, gaps): the Newton trim in C, checked against the dynamics and the
    track; NoTrimError when there is none."""
    try:
        x_trim, f_prop = lib.function("maglev_trim")(speed, p)
    except GeneratedFunctionError as exc:
        raise NoTrimError(f"no trim at {speed:g} m/s: the Newton trim in C returned "
                          f"{exc.code_name} (below lift-off speed?); see `maglevgen trim`"
                          ) from None
    x_trim, f_prop = x_trim.ravel(), float(f_prop.ravel()[0])
    n_u = lib.function("maglev_dynamics").shapes_in[1][0]
    u = np.zeros(n_u)
    u[0] = f_prop
    acc = lib.function("maglev_dynamics")(x_trim, u, p)[0].ravel()[6:]
    gaps = lib.function("maglev_gaps")(x_trim, p)[0].ravel()
    if not (np.all(np.isfinite(acc)) and np.max(np.abs(acc)) < 1e-8):
        raise NoTrimError(f"no trim at {speed:g} m/s: the Newton solve in C did not converge "
                          "(below lift-off speed?); see `maglevgen trim`")
    if np.min(gaps) < min_gap:
        raise NoTrimError(f"no trim at {speed:g} m/s with every gap above track.min_gap = "
                          f"{min_gap:g} m (smallest {np.min(gaps):.4g} m)")
    return x_trim, f_prop, gaps


def coupled_weights(C_rate: np.ndarray, w: Weights) -> tuple[np.ndarray, np.ndarray]:
    """(Q, R) of the coupled LQR on the reduced state: the per-axis design's weights, q1 on
    every axis position, q2 on every axis rate (C_rate x_r), r on every generalized force."""
    S = np.eye(N_AXES, C_rate.shape[1])
    return w.q1 * S.T @ S + w.q2 * C_rate.T @ C_rate, w.r * np.eye(N_AXES)


def numerical_lqr(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray) -> np.ndarray:
    """The numerical LQR gain K = R^-1 B^T P, P from scipy's Schur-method CARE solver.

    The same solver python-control's ``lqr`` calls without slycot; used here directly so that
    a build does not import python-control (and scipy.signal, ~1 s). The tests check the
    closed forms and the coupled LQR against python-control itself.
    """
    import scipy.linalg  # local: importing the simulation path stays SciPy-free

    P = scipy.linalg.solve_continuous_are(A, B, Q, R)
    return np.linalg.solve(R, B.T @ P)


def coupled_lqr(A_r: np.ndarray, B_g: np.ndarray, C_rate: np.ndarray,
                w: Weights) -> np.ndarray:
    """K (5 x 10) of the coupled LQR with `coupled_weights`."""
    return numerical_lqr(A_r, B_g, *coupled_weights(C_rate, w))


def operating_point(lib: SimulationLibrary, p: np.ndarray, speed: float, min_gap: float,
                    weights: Weights) -> OperatingPoint:
    """Checked trim, gains, allocation and linearisation at ``speed``, from the generated C."""
    x_trim, f_prop, gaps = checked_trim(lib, p, speed, min_gap)
    K, c = lib.function("maglev_lqr_gains")(speed, p)
    (T,) = lib.function("maglev_allocation_matrix")(p)
    u = np.zeros(T.shape[0] + 1)
    u[0] = f_prop
    A, B = lib.function("maglev_jacobians")(x_trim, u, p)
    return OperatingPoint(float(speed), x_trim, f_prop, gaps, K, c.ravel(), T, A, B, weights)


def stability(eigenvalues: np.ndarray) -> tuple[float, float]:
    """(largest real part [1/s], smallest damping ratio) of a set of eigenvalues."""
    ev = np.asarray(eigenvalues)
    mag = np.abs(ev)
    zeta = np.where(mag > 1e-12, -ev.real / np.where(mag > 1e-12, mag, 1.0), 1.0)
    return float(np.max(ev.real)), float(np.min(zeta))
