"""The closed loop as the firmware runs it: the controller sampled at its tick, its command
held (zero-order hold) and applied after its computation delay, with the speed loop.

The loop's linearisation keeps eleven states, LOOP_STATES = (y, z, phi, theta, psi, v, w, p,
q, r, u): the along-track position x drops out (nothing depends on it) and the forward speed
u stays, because the propulsion now holds it by feedback: F_prop = F_ff + k_v (v_ref - V),
V = |(u, v, w)|, F_ff the trim drag (plus m a in a launch). The inputs are the five
generalized forces (through the minimum-norm allocation T of eqs 22-23) and the propulsion.

With the tick period h and a delay of d ticks, the exact ZOH discretisation of x' = A x + B w
is x[k+1] = Phi x[k] + Gamma w[k], Phi = e^{A h}, Gamma = int_0^h e^{A s} ds B (one matrix
exponential of [[A, B], [0, 0]] h), and the command computed at tick k is applied over
[k + d, k + d + 1): w[k] = -K x[k - d]. The delay's d commands in flight are states of the
augmented loop. Its eigenvalues z are reported as continuous-equivalent s = ln(z)/h, so that
damping ratios and decay rates read as those of the continuous design (a delay state's z = 0
is s = -inf: it decays in one tick).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .codegen.checks import MAX_DELAY_TICKS
from .derive import conventions as cv
from .errors import InputError
from .operating import AXIS_STATES, N_AXES, REDUCED_STATES, OperatingPoint

__all__ = ["LOOP_STATES", "Tick", "loop_gain", "loop_model", "sampled_eigenvalues",
           "speed_gain"]

LOOP_STATES: tuple[str, ...] = (*REDUCED_STATES, "u")
LOOP_INDEX: tuple[int, ...] = tuple(cv.STATE_INDEX[s] for s in LOOP_STATES)


@dataclass(frozen=True)
class Tick:
    """The controller's tick as the firmware runs it: ``rate`` [Hz] (in a simulation the
    control period 1/rate a whole number of RK4 steps) and the computation ``delay`` [ticks]
    from sampling the state to applying the command (0 to MAX_DELAY_TICKS), the command held
    in between."""

    rate: float  # [Hz]
    delay: int = 1  # [ticks]

    def __post_init__(self) -> None:
        if not (isinstance(self.rate, (int, float)) and np.isfinite(self.rate)
                and self.rate > 0):
            raise InputError(f"tick rate {self.rate!r} Hz: must be a positive number")
        if not (isinstance(self.delay, (int, np.integer)) and not isinstance(self.delay, bool)
                and 0 <= self.delay <= MAX_DELAY_TICKS):
            raise InputError(f"tick delay {self.delay!r}: must be a whole number of ticks "
                             f"from 0 to {MAX_DELAY_TICKS}")

    @property
    def period(self) -> float:
        return 1.0 / self.rate

    def steps(self, dt: float) -> int:
        """RK4 steps of ``dt`` per tick: the period 1/rate must be a whole multiple of dt
        (within 1e-9 of a step)."""
        ratio = 1.0 / (self.rate * dt)
        n = round(ratio)
        if n < 1 or abs(ratio - n) > 1e-9:
            raise InputError(f"tick rate {self.rate!r} Hz: its period {1.0 / self.rate:.9g} s "
                             f"is not a whole multiple of the step dt = {dt:g} s")
        return n

    @classmethod
    def of(cls, params) -> Tick:
        """control.spec.tick_rate and delay_ticks."""
        s = params.control.spec
        return cls(float(s.tick_rate), int(s.delay_ticks))


def loop_model(op: OperatingPoint) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) on LOOP_STATES: inputs the five generalized forces, then the propulsion."""
    idx = list(LOOP_INDEX)
    A = op.A[np.ix_(idx, idx)]
    B = np.column_stack([op.B[idx, 1:] @ op.allocation, op.B[idx, 0]])
    return A, B


def speed_gain(mass: float, drag_slope: float, bandwidth: float) -> float:
    """k_v [N s/m] that puts the speed pole at -``bandwidth`` [1/s]: along the trim curve
    m V' = F_prop - F_D,trim(V), so with F_prop = F_ff - k_v (V - v_ref) the pole is
    -(dF_D,trim/dV + k_v)/m, and k_v = m bandwidth - dF_D,trim/dV (``drag_slope``,
    `OperatingPoint.trim_drag_slope`)."""
    if not (np.isfinite(bandwidth) and bandwidth > 0):
        raise InputError(f"speed-loop bandwidth {bandwidth!r} 1/s: must be positive")
    return float(mass * bandwidth - drag_slope)


def loop_gain(op: OperatingPoint, controller: str, k_v: float,
              design: OperatingPoint | None = None) -> np.ndarray:
    """K (6 x 11): w = -K x on LOOP_STATES; rows 0-4 the controller's generalized forces,
    row 5 the propulsion's speed feedback k_v dV (dV = (u du + v dv + w dw)/V at trim).
    ``design``: the operating point whose gains the controller uses (another model's, to
    check them on this one); default ``op``."""
    A, _ = loop_model(op)
    n = len(LOOP_INDEX)
    K_pos, K_rate = (design or op).gains(controller)
    S = np.zeros((N_AXES, n))
    S[range(N_AXES), range(N_AXES)] = 1.0
    axis_rows = [LOOP_INDEX.index(i) for i in AXIS_STATES]
    C_rate = A[axis_rows, :]  # a' as a function of the loop state (the Euler kinematics)
    K = np.zeros((N_AXES + 1, n))
    K[:N_AXES] = K_pos @ S + K_rate @ C_rate
    vel = op.x_trim[6:9]
    for name, comp in zip(("u", "v", "w"), vel, strict=True):
        K[N_AXES, LOOP_STATES.index(name)] = k_v * comp / np.linalg.norm(vel)
    return K


def zoh(A: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """(Phi, Gamma): the exact zero-order-hold discretisation over one period ``h``."""
    import scipy.linalg  # local: the simulation path stays SciPy-free

    n, m = B.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = A, B
    E = scipy.linalg.expm(M * h)
    return E[:n, :n], E[:n, n:]


def sampled_closed_loop(A: np.ndarray, B: np.ndarray, K: np.ndarray,
                        tick: Tick) -> np.ndarray:
    """The discrete closed loop on (x, the commands in flight): x[k+1] = Phi x + Gamma w_k,
    the oldest command applied, the newest -K x[k] entering the queue."""
    Phi, Gamma = zoh(A, B, tick.period)
    n, m, d = A.shape[0], B.shape[1], tick.delay
    if d == 0:
        return Phi - Gamma @ K
    N = n + d * m
    M = np.zeros((N, N))
    M[:n, :n] = Phi
    M[:n, n + (d - 1) * m:] = Gamma  # the command computed d ticks ago
    M[n:n + m, :n] = -K  # the command computed now
    for j in range(1, d):  # the queue moves on by one tick
        M[n + j * m:n + (j + 1) * m, n + (j - 1) * m:n + j * m] = np.eye(m)
    return M


def sampled_eigenvalues(A: np.ndarray, B: np.ndarray, K: np.ndarray,
                        tick: Tick) -> np.ndarray:
    """Continuous-equivalent eigenvalues ln(z)/h of the sampled-data closed loop."""
    z = np.linalg.eigvals(sampled_closed_loop(A, B, K, tick)).astype(complex)
    small = np.abs(z) < 1e-300
    s = np.log(np.where(small, 1.0, z)) / tick.period
    return np.where(small, -np.inf + 0j, s)
