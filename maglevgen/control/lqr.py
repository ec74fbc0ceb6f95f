"""The LQR solves shared by the controllers: SciPy's CARE (and DARE) on small dense models."""

from __future__ import annotations

import numpy as np

__all__ = ["numerical_dlqr", "numerical_lqr", "quadratic_cost", "weighted_qr"]


def numerical_lqr(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray) -> np.ndarray:
    """The numerical LQR gain K = R^-1 B^T P, P from scipy's Schur-method CARE solver.

    The same solver python-control's ``lqr`` calls without slycot; used here directly so that
    a build does not import python-control (and scipy.signal, ~1 s). The tests check the
    closed forms and the coupled LQR against python-control itself.
    """
    import scipy.linalg  # local: importing the simulation path stays SciPy-free

    P = scipy.linalg.solve_continuous_are(A, B, Q, R)
    return np.linalg.solve(R, B.T @ P)


def numerical_dlqr(Phi: np.ndarray, Gamma: np.ndarray, Q: np.ndarray,
                   R: np.ndarray) -> np.ndarray:
    """The discrete LQR gain K = (R + G^T P G)^-1 G^T P Phi, P from scipy's DARE."""
    import scipy.linalg  # local: see numerical_lqr

    P = scipy.linalg.solve_discrete_are(Phi, Gamma, Q, R)
    return np.linalg.solve(R + Gamma.T @ P @ Gamma, Gamma.T @ P @ Phi)


def weighted_qr(C_rate: np.ndarray, q1: np.ndarray, q2: np.ndarray,
                r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(Q, R) on the reduced state: q1[i] on axis position i, q2[i] on axis rate i (C_rate x_r),
    r[i] on generalized force i."""
    n_axes = C_rate.shape[0]
    S = np.eye(n_axes, C_rate.shape[1])
    Q = S.T @ np.diag(q1) @ S + C_rate.T @ np.diag(q2) @ C_rate
    return Q, np.diag(np.asarray(r, dtype=float))


def quadratic_cost(A_cl: np.ndarray, Q_total: np.ndarray) -> float:
    """J = trace(X), A_cl' X + X A_cl = -Q_total: the integral of x' Q_total x summed over unit
    initial states (inf when A_cl is not Hurwitz)."""
    import scipy.linalg  # local: see numerical_lqr

    if np.max(np.linalg.eigvals(A_cl).real) >= 0:
        return float("inf")
    return float(np.trace(scipy.linalg.solve_continuous_lyapunov(A_cl.T, -Q_total)))
