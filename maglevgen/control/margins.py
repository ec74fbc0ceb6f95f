"""Stability margins of the loop as built, broken at the actuators (`plant.LoopPlant`).

Disk margins (balanced, skew 0): with the loop transfer L(z) at the plant input (the array
force commands, negative feedback) and S = (I + L)^-1, the loop tolerates every simultaneous
gain and phase change of each channel, u_i -> f_i u_i, with f_i inside the disk

    D(alpha) = { (1 + d/2) / (1 - d/2) : |d| < alpha },   alpha = 1 / sup_w mu(S - I/2),

mu the structured singular value for independent complex scalars per channel ("multi-loop"),
computed as its upper bound inf_D sigma_max(D M D^-1) over positive diagonal D (what SLICOT's
AB13MD, under python-control's `disk_margins`, computes); loop at a time: each channel alone,
the others closed, alpha_i = 1 / sup_w |(S - I/2)_ii|. The disk in gain and phase:

    gain margin 20 log10((1 + alpha/2) / (1 - alpha/2)) dB,  phase margin 2 atan(alpha/2).

The delay margin: the largest number of extra ticks between the controller's array commands
and the actuators (the controller unaware of them) for which the loop stays stable.

References
----------
P. Seiler, A. Packard, P. Gahinet, "An introduction to disk margins", IEEE Control Systems
Magazine 40(5), 2020. J. C. Doyle, "Analysis of feedback systems with structured
uncertainties", IEE Proc. D 129(6), 1982 (the D-scaled upper bound of mu).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["DiskMargins", "delay_margin", "disk_gain_phase", "disk_margins"]

MAX_EXTRA_TICKS = 20  # the delay margin is searched up to this many extra ticks


def disk_gain_phase(alpha: float) -> tuple[float, float]:
    """(gain margin [dB], phase margin [deg]) of a balanced disk of size ``alpha``."""
    if not alpha < 2:
        return float("inf"), 90.0 if alpha == 2 else float("inf")
    g = (1 + alpha / 2) / (1 - alpha / 2)
    return float(20 * np.log10(g)), float(np.degrees(2 * np.arctan(alpha / 2)))


def _osborne(M: np.ndarray) -> np.ndarray:
    """Osborne's balancing of |M| for a stack of matrices (..., n, n): the diagonals d that
    equalise each row's and column's off-diagonal 2-norms of D |M| D^-1 (a start for the
    D-scaling, and itself an upper bound), all frequencies at once."""
    n = M.shape[-1]
    off2 = np.abs(M) ** 2 * (1.0 - np.eye(n))
    d = np.ones(M.shape[:-1])
    for _ in range(50):
        S2 = off2 * (d[..., :, None] / d[..., None, :]) ** 2
        col, row = np.sqrt(np.sum(S2, axis=-2)), np.sqrt(np.sum(S2, axis=-1))
        ok = (col > 0) & (row > 0)
        step = np.where(ok, np.sqrt(np.sqrt(np.where(ok, col, 1) / np.where(ok, row, 1))), 1.0)
        d *= step
        if np.max(np.abs(np.log(step))) < 1e-6:
            break
    return d


def _sigma_max(M: np.ndarray) -> np.ndarray:
    """The largest singular value of each matrix of a stack (..., n, n)."""
    return np.linalg.svd(M, compute_uv=False)[..., 0]


def _scaled_norm(M: np.ndarray, d: np.ndarray) -> float:
    return float(_sigma_max(M * d[:, None] / d[None, :]))


def _scaled_norm_grad(M: np.ndarray, x: np.ndarray) -> tuple[float, np.ndarray]:
    """sigma_max(D M D^-1) with D = diag(exp([0, x])), and its gradient in x: with A v =
    sigma u and u^H A = sigma v^H, d sigma / d log d_i = sigma (|u_i|^2 - |v_i|^2)."""
    d = np.exp(np.r_[0.0, x])
    U, s, Vh = np.linalg.svd(M * d[:, None] / d[None, :])
    grad = s[0] * (np.abs(U[:, 0]) ** 2 - np.abs(Vh[0]) ** 2)
    return float(s[0]), grad[1:]


def mu_upper_bound(M: np.ndarray, refine: bool = True) -> float:
    """inf_D sigma_max(D M D^-1), D positive diagonal: mu's upper bound for a structure of
    complex scalars; Osborne's balancing (`_osborne`) as the start, then (``refine``) BFGS on
    log D with sigma_max's analytic gradient and a short Nelder-Mead search from there (where
    the largest singular value is repeated it has no gradient), the first entry fixed at 1.
    Without ``refine``: the bound at Osborne's D, never below the refined one."""
    if M.shape[0] == 1:
        return float(abs(M[0, 0]))
    start = float(_osborne_bounds(M[None])[0])
    return _refined(M, start) if refine else start


def _osborne_bounds(Ms: np.ndarray) -> np.ndarray:
    """min(sigma_max at Osborne's D, sigma_max) of each matrix of a stack (F, n, n)."""
    d = _osborne(Ms)
    return np.minimum(_sigma_max(Ms * d[:, :, None] / d[:, None, :]), _sigma_max(Ms))


def _refined(M: np.ndarray, start: float) -> float:
    """`mu_upper_bound`'s search from Osborne's D; never above ``start``."""
    import scipy.optimize  # local: see lqr.numerical_lqr

    d = _osborne(M)
    res = scipy.optimize.minimize(lambda x: _scaled_norm_grad(M, x), np.log(d[1:] / d[0]),
                                  jac=True, method="BFGS", options={"gtol": 1e-10})
    res2 = scipy.optimize.minimize(lambda x: _scaled_norm(M, np.exp(np.r_[0.0, x])), res.x,
                                   method="Nelder-Mead",
                                   options={"xatol": 1e-6, "fatol": 1e-10, "maxiter": 1500})
    return min(float(res.fun), float(res2.fun), start)


def frequency_grid(period: float, n: int = 300) -> np.ndarray:
    """Frequencies [rad/s] from 0.01 rad/s to the Nyquist frequency pi/h, log-spaced."""
    return np.logspace(-2, np.log10(np.pi / period), n)


@dataclass(frozen=True)
class DiskMargins:
    """The disk margins of a loop at one operating point, and against frequency."""

    omega: np.ndarray  # [rad/s]
    alpha_multi: np.ndarray  # multi-loop disk size at each frequency
    alpha_loops: np.ndarray  # (n_channels, n_freq): each channel alone

    @property
    def multi(self) -> float:
        return float(np.min(self.alpha_multi))

    @property
    def per_loop(self) -> np.ndarray:
        return np.min(self.alpha_loops, axis=1)

    def gain_phase(self) -> tuple[float, float]:
        """(dB, deg) of the multi-loop margin."""
        return disk_gain_phase(self.multi)

    def worst_loop(self) -> int:
        return int(np.argmin(self.per_loop))


def _frequency_response(M: np.ndarray, N: np.ndarray, C: np.ndarray, period: float,
                        omega: np.ndarray) -> np.ndarray:
    """G(e^{j w h}) = C (zI - M)^-1 N at each w, (n_freq, p, m), by one eigendecomposition
    where M is diagonalisable (checked by its condition), else by solves."""
    n = M.shape[0]
    z = np.exp(1j * omega * period)
    w, V = np.linalg.eig(M)
    if np.linalg.cond(V) < 1e8:
        CV, ViN = C @ V, np.linalg.solve(V, N)
        return np.einsum("pi,fi,im->fpm", CV, 1.0 / (z[:, None] - w[None, :]), ViN)
    return np.array([C @ np.linalg.solve(zk * np.eye(n) - M, N) for zk in z])


def disk_margins(M: np.ndarray, N: np.ndarray, C: np.ndarray, period: float,
                 omega: np.ndarray | None = None) -> DiskMargins:
    """The balanced disk margins of the loop z[k+1] = M z + N e, y = C z closed by e = y
    (`plant.LoopPlant.open_loop`): L = -G, S = (I + L)^-1 = (I - G)^-1."""
    omega = frequency_grid(period) if omega is None else np.asarray(omega, dtype=float)
    G = _frequency_response(M, N, C, period, omega)
    m = G.shape[1]
    eye = np.eye(m)
    Ms = np.array([np.linalg.solve(eye - Gk, eye) - eye / 2 for Gk in G])
    loops = 1.0 / np.maximum(np.abs(np.diagonal(Ms, axis1=1, axis2=2)).T, 1e-300)
    # Osborne's bound at every frequency (a disk no larger than the refined one), refined
    # where it is smallest until no unrefined frequency can hold a smaller disk
    multi = 1.0 / (np.abs(Ms[:, 0, 0]) if m == 1 else _osborne_bounds(Ms))
    refined = np.zeros(omega.size, dtype=bool)
    while True:
        open_ = np.where(refined, np.inf, multi)
        k = int(np.argmin(open_))
        if refined.any() and open_[k] >= np.min(multi[refined]):
            break
        multi[k] = max(multi[k], 1.0 / mu_upper_bound(Ms[k]))
        refined[k] = True
        if refined.all():
            break
    return DiskMargins(omega, multi, loops)


def delay_margin(stable_with: Callable[[int], bool], limit: int = MAX_EXTRA_TICKS) -> int:
    """The largest n <= ``limit`` such that ``stable_with(k)`` for every k <= n (-1: not
    stable without extra delay)."""
    n = -1
    for k in range(limit + 1):
        if not stable_with(k):
            break
        n = k
    return n
