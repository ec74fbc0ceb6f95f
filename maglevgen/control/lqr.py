"""The LQR solves shared by the controllers: SciPy's CARE (and DARE) on small dense models, and
the structure-preserving doubling algorithm for a DARE whose pencil SciPy's QZ reordering
refuses (`solve_dare`).

References
----------
E. K.-W. Chu, H.-Y. Fan, W.-W. Lin, C.-S. Wang, "Structure-preserving algorithms for periodic
discrete-time algebraic Riccati equations", Int. J. Control 77 (2004) 767-788 (SDA-1).
"""

from __future__ import annotations

import numpy as np

__all__ = ["dare_doubling", "numerical_dlqr", "numerical_lqr", "quadratic_cost", "solve_dare",
           "weighted_qr"]

#: the doubling's stop: the change of X relative to its size; and its iterations (it converges
#: quadratically: a handful where a stabilizing solution exists)
DOUBLING_TOL, DOUBLING_ITERATIONS = 1e-13, 100
#: a solution is accepted when the DARE's residual is at most this share of |X| (1-norm)
DARE_RESIDUAL = 1e-9


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
    """The discrete LQR gain K = (R + G^T P G)^-1 G^T P Phi, P from `solve_dare`."""
    P = solve_dare(Phi, Gamma, Q, R)
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


def dare_residual(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray,
                  X: np.ndarray) -> float:
    """|A'XA - X - A'XB (R + B'XB)^-1 B'XA + Q| / max(1, |X|) (1-norms)."""
    AXB = A.T @ X @ B
    res = A.T @ X @ A - X - AXB @ np.linalg.solve(R + B.T @ X @ B, AXB.T) + Q
    return float(np.linalg.norm(res, 1) / max(1.0, np.linalg.norm(X, 1)))


def dare_doubling(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray) -> np.ndarray:
    """X of the DARE X = A'XA - A'XB (R + B'XB)^-1 B'XA + Q by structure-preserving doubling
    (SDA-1, module references): A_0 = A, G_0 = B R^-1 B', H_0 = Q, W = I + G_k H_k,
    A_k+1 = A_k W^-1 A_k, G_k+1 = G_k + A_k W^-1 G_k A_k', H_k+1 = H_k + A_k' H_k W^-1 A_k;
    H_k -> X quadratically where the stabilizing solution exists. A singular A (a delay's
    shift, a lag) is no obstacle. ValueError when it does not converge or the result does
    not solve the DARE to DARE_RESIDUAL."""
    n = A.shape[0]
    eye = np.eye(n)
    G = B @ np.linalg.solve(R, B.T)
    G, H, Ak = (G + G.T) / 2, (Q + Q.T) / 2, np.array(A, dtype=float)
    with np.errstate(over="ignore", invalid="ignore"):  # a divergence is refused below
        H = _doubling(Ak, G, H, eye)
    if (res := dare_residual(A, B, Q, R, H)) > DARE_RESIDUAL:
        raise ValueError(f"the doubling's X leaves a residual of {res:.3g}")
    return H


def _doubling(Ak: np.ndarray, G: np.ndarray, H: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """`dare_doubling`'s iteration from (A_0, G_0, H_0): H at convergence."""
    for _ in range(DOUBLING_ITERATIONS):
        W = eye + G @ H
        WA, WG = np.linalg.solve(W, Ak), np.linalg.solve(W, G)
        G_next = G + Ak @ WG @ Ak.T
        H_next = H + WA.T @ H @ Ak
        Ak = Ak @ WA
        if not (np.all(np.isfinite(H_next)) and np.all(np.isfinite(G_next))):
            raise ValueError("the doubling diverged")
        step = np.linalg.norm(H_next - H, 1) / max(1.0, np.linalg.norm(H_next, 1))
        G, H = (G_next + G_next.T) / 2, (H_next + H_next.T) / 2
        if step < DOUBLING_TOL:
            return H
    raise ValueError(f"the doubling did not converge in {DOUBLING_ITERATIONS} iterations")


def solve_dare(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray) -> np.ndarray:
    """The DARE's stabilizing X: SciPy's solve_discrete_are, and where its QZ reordering
    refuses the pencil (ill-conditioned: a slow tick over fast modes, a delay's zero
    eigenvalues) `dare_doubling`, kept only if A - B K is stable. ValueError /
    LinAlgError (SciPy's message) where neither finds it."""
    import scipy.linalg  # local: see numerical_lqr

    try:
        return scipy.linalg.solve_discrete_are(A, B, Q, R)
    except (ValueError, np.linalg.LinAlgError) as exc:
        try:
            X = dare_doubling(A, B, Q, R)
        except (ValueError, np.linalg.LinAlgError):
            raise exc from None
        K = np.linalg.solve(R + B.T @ X @ B, B.T @ X @ A)
        if np.max(np.abs(np.linalg.eigvals(A - B @ K))) >= 1.0:
            raise exc from None
        return X
