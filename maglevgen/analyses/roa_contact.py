"""The contact limit of a region of attraction: the largest Lyapunov level free of contact."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["CONTACT_STARTS", "contact_level"]


#: the optimiser's starts per gap besides the linearised optimum, and their spread
CONTACT_STARTS, CONTACT_SPREAD = 6, 0.5
#: [m] a gap this close above track.min_gap counts as the contact the level is limited by
CONTACT_TOLERANCE = 1e-12


def contact_level(gaps: Callable[[np.ndarray], np.ndarray], P: np.ndarray, min_gap: float,
                  seed: int = 0) -> tuple[float, np.ndarray | None]:
    """(c, dx*): the largest c with every gap at or above ``min_gap`` on {V <= c}, computed,
    not sampled: per gap g_j the smallest V(dx) = dx' P dx with g_j(trim + dx) <= min_gap
    (SciPy's SLSQP in the whitened coordinates z = L' dx, V = |z|^2, the gaps' gradients by
    central differences), from the linearised optimum (on g_j ~ g_j0 + a'dx:
    dx = (min_gap - g_j0) P^-1 a / (a' P^-1 a), c_j = (g_j0 - min_gap)^2 / (a' P^-1 a))
    and CONTACT_STARTS starts spread about it; the smallest over the gaps and starts, each
    kept only where the gap there is at min_gap (a state in contact: every c above it holds
    one). ``gaps(dx)``: every gap at the rows of dx (n x 10 reduced deviations). dx*: the
    contact state on {V = c} (None: no gap reaches min_gap, c = inf)."""
    from scipy.optimize import minimize

    L = np.linalg.cholesky(P)
    n = P.shape[0]
    raw_gaps = gaps

    def finite_gaps(dx: np.ndarray) -> np.ndarray:
        # the optimiser may step far outside the model's range (the closed loop not finite
        # there): such rows are NaN, which SLSQP backs off from and the contact test drops
        try:
            return raw_gaps(dx)
        except RuntimeError:
            if dx.shape[0] == 1:
                return np.full((1, g_size), np.nan)
            return np.vstack([finite_gaps(row[None, :]) for row in dx])

    def dx_of(z: np.ndarray) -> np.ndarray:
        return np.linalg.solve(L.T, z)

    g0 = raw_gaps(np.zeros((1, n)))[0]
    g_size = g0.size
    rng = np.random.default_rng(seed)
    best, best_dx = np.inf, None
    for j in range(g0.size):
        if not g0[j] > min_gap:
            return 0.0, np.zeros(n)

        def g(z: np.ndarray, j: int = j) -> float:
            return float(finite_gaps(dx_of(z)[None, :])[0, j])

        def grad(z: np.ndarray, j: int = j) -> np.ndarray:
            h = 1e-7 * max(1.0, float(np.linalg.norm(z)))
            Z = np.vstack([z + h * e for e in np.eye(n)] + [z - h * e for e in np.eye(n)])
            G = finite_gaps(np.linalg.solve(L.T, Z.T).T)[:, j]
            return (G[:n] - G[n:]) / (2 * h)

        b = grad(np.zeros(n))  # the gap's gradient in z: a' dx = b' z
        if not np.linalg.norm(b) > 0:
            continue
        z_lin = (min_gap - g0[j]) * b / (b @ b)
        starts = [z_lin] + [z_lin + CONTACT_SPREAD * np.linalg.norm(z_lin)
                            * rng.standard_normal(n) / np.sqrt(n)
                            for _ in range(CONTACT_STARTS)]
        for z0 in starts:
            res = minimize(lambda z: float(z @ z), z0, jac=lambda z: 2 * z, method="SLSQP",
                           constraints=[{"type": "ineq", "fun": lambda z, g=g: min_gap - g(z),
                                         "jac": lambda z, grad=grad: -grad(z)}],
                           options={"maxiter": 200, "ftol": 1e-14})
            z = res.x
            for _ in range(4):  # onto the contact along the ray (Newton in the ray's scale)
                slope = float(grad(z) @ z)
                if not (np.all(np.isfinite(z)) and slope < 0):
                    break
                z = z * (1.0 - (g(z) - min_gap) / slope)
            # kept where the state is in contact, to CONTACT_TOLERANCE
            if np.all(np.isfinite(z)) and g(z) <= min_gap + CONTACT_TOLERANCE and z @ z < best:
                best, best_dx = float(z @ z), dx_of(z)
    return best, best_dx

