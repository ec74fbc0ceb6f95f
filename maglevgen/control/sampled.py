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

from maglevgen.codegen.checks import MAX_DELAY_TICKS
from maglevgen.control.lqr import numerical_dlqr, weighted_qr
from maglevgen.control.operating import AXIS_STATES, N_AXES, REDUCED_STATES, OperatingPoint
from maglevgen.control.registry import WeightsFn
from maglevgen.control.spec import spec_weights
from maglevgen.derive import conventions as cv
from maglevgen.errors import InputError

__all__ = ["LOOP_INDEX", "LOOP_STATES", "Tick", "delay_augmented", "loop_gain", "loop_model",
           "sampled_closed_loop", "sampled_eigenvalues", "speed_gain", "tick_design",
           "tick_design_loop_gains", "zoh"]

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
    return _loop_gain_of(op, *(design or op).gains(controller), k_v)


def _loop_gain_of(op: OperatingPoint, K_pos: np.ndarray, K_rate: np.ndarray,
                  k_v: float) -> np.ndarray:
    """`loop_gain` with the axis gains (K_pos, K_rate) given."""
    A, _ = loop_model(op)
    n = len(LOOP_INDEX)
    S = np.zeros((N_AXES, n))
    S[range(N_AXES), range(N_AXES)] = 1.0
    axis_rows = [LOOP_INDEX.index(i) for i in AXIS_STATES]
    C_rate = A[axis_rows, :]  # a' as a function of the loop state (the Euler kinematics)
    K = np.zeros((N_AXES + 1, n))
    K[:N_AXES] = K_pos @ S + K_rate @ C_rate
    vel = op.x_trim[cv.VELOCITY]
    for name, comp in zip(cv.STATE_NAMES[cv.VELOCITY], vel, strict=True):
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


def delay_augmented(Phi: np.ndarray, Gamma: np.ndarray,
                    delay: int) -> tuple[np.ndarray, np.ndarray]:
    """(Phi_a, Gamma_a): the ZOH model with ``delay`` ticks of computation delay, on
    z[k] = (x[k], w[k-1], ..., w[k-d]) (the commands in flight, newest first): x[k+1] =
    Phi x[k] + Gamma w[k-d], the queue moves on by one tick and the command computed at tick
    k, the input of z[k+1] = Phi_a z[k] + Gamma_a w[k], enters it."""
    n, m, d = Phi.shape[0], Gamma.shape[1], delay
    if d == 0:
        return Phi, Gamma
    N = n + d * m
    Pa, Ga = np.zeros((N, N)), np.zeros((N, m))
    Pa[:n, :n] = Phi
    Pa[:n, n + (d - 1) * m:] = Gamma  # the command computed d ticks ago
    for j in range(1, d):  # the queue moves on by one tick
        Pa[n + j * m:n + (j + 1) * m, n + (j - 1) * m:n + j * m] = np.eye(m)
    Ga[n:n + m] = np.eye(m)  # the command computed now
    return Pa, Ga


def sampled_closed_loop(A: np.ndarray, B: np.ndarray, K: np.ndarray, tick: Tick,
                        K_delay: np.ndarray | None = None) -> np.ndarray:
    """The discrete closed loop on (x, the commands in flight): x[k+1] = Phi x + Gamma w_k,
    the oldest command applied, the newest w[k] = -K x[k] - K_delay (w[k-1], ..., w[k-d])
    entering the queue (``K_delay`` m x d m, None: no feedback of the commands in flight)."""
    Phi, Gamma = zoh(A, B, tick.period)
    Pa, Ga = delay_augmented(Phi, Gamma, tick.delay)
    m, d = B.shape[1], tick.delay
    K_full = np.hstack([K, np.zeros((m, d * m)) if K_delay is None else K_delay])
    return Pa - Ga @ K_full


def sampled_eigenvalues(A: np.ndarray, B: np.ndarray, K: np.ndarray,
                        tick: Tick, K_delay: np.ndarray | None = None) -> np.ndarray:
    """Continuous-equivalent eigenvalues ln(z)/h of the sampled-data closed loop (with
    ``K_delay`` as in `sampled_closed_loop`)."""
    z = np.linalg.eigvals(sampled_closed_loop(A, B, K, tick, K_delay)).astype(complex)
    small = np.abs(z) < 1e-300
    s = np.log(np.where(small, 1.0, z)) / tick.period
    return np.where(small, -np.inf + 0j, s)


@dataclass(frozen=True)
class TickDesign:
    """The `spec` design at the tick: the discrete LQR of the ZOH model augmented with the
    delay (`tick_design`), as gains on the loop's state and on the commands in flight."""

    K_pos: np.ndarray  # 5 x 5 on a - a_ref
    K_rate: np.ndarray  # 5 x 5 on a'
    K_delay: np.ndarray  # 5 x 5 d on the generalized forces in flight (w[k-1], ..., w[k-d])


def tick_design(op: OperatingPoint, tick: Tick, weights: WeightsFn = spec_weights
                ) -> TickDesign:
    """A controller's weights (q1, q2, r per axis, its `Controller.weights`; default the
    `spec` design's, `spec.spec_weights`) on the tick: the
    reduced linearisation (A_r, B_gen) discretised exactly with ZOH over the period h
    (Phi, Gamma), augmented with the delay's commands in flight (`delay_augmented`), and the
    discrete LQR of that model, K = (R + Gamma_a' P Gamma_a)^-1 Gamma_a' P Phi_a with P from
    SciPy's DARE, Q_a = blkdiag(Q, 0) and the same Q, R as the continuous design (the sum
    h sum_k (z' Q_a z + w' R w) approximates the continuous cost; the factor h scales P,
    not K). The commands in flight carry no weight of their own: each is weighed by R when
    it is computed."""
    A_r, B_g = op.reduced
    q1, q2, r = weights(op)
    Q, R = weighted_qr(op.rate_map, q1, q2, r)
    Phi, Gamma = zoh(A_r, B_g, tick.period)
    Pa, Ga = delay_augmented(Phi, Gamma, tick.delay)
    n = A_r.shape[0]
    Qa = np.zeros_like(Pa)
    Qa[:n, :n] = Q
    K = numerical_dlqr(Pa, Ga, Qa, R)
    K_pos, K_rate = op.axis_gains(K[:, :n])
    return TickDesign(K_pos, K_rate, K[:, n:])


def tick_design_loop_gains(op: OperatingPoint, design: TickDesign, k_v: float
                           ) -> tuple[np.ndarray, np.ndarray]:
    """(K, K_delay) of `tick_design` on the loop (LOOP_STATES, six inputs): rows 0-4 as
    `loop_gain`'s with the design's (K_pos, K_rate), row 5 the speed loop; K_delay (6 x 6 d)
    the design's feedback of the generalized forces in flight (the propulsion's in flight
    not fed back)."""
    K = _loop_gain_of(op, design.K_pos, design.K_rate, k_v)
    m = N_AXES + 1
    d = design.K_delay.shape[1] // N_AXES
    K_delay = np.zeros((m, d * m))
    for j in range(d):
        K_delay[:N_AXES, j * m:j * m + N_AXES] = design.K_delay[:, j * N_AXES:(j + 1) * N_AXES]
    return K, K_delay
