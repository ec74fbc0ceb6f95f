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
  R = r on every generalized force), written in the same (a, a') coordinates;
- ``spec``: the same coupled LQR with weights from the specification (maglevgen/control/spec.py).

The controllers themselves are defined once, in the registry of maglevgen/control (registry.py).

The coupled linearisation: the 12-state Jacobian at trim restricted to the ten states
(y, z, phi, theta, psi, v, w, p, q, r). The along-track position x is dropped because nothing
depends on it (a pure integrator); the forward speed u is dropped because the propulsion
holds it (it is the scheduling variable, not a state the arrays control; its own slow mode
under a constant force, the trim drag's slope with speed, is reported beside as `SpeedMode`,
not as part of the controller's stability). The inputs are the five generalized forces
through the minimum-norm allocation T (eqs 22-23).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from maglevgen.control.lqr import numerical_lqr, quadratic_cost
from maglevgen.control.registry import controller as registered_controller
from maglevgen.derive import conventions as cv
from maglevgen.derive.conventions import Q_STATES
from maglevgen.errors import InputError, NoTrimError
from maglevgen.runtime.ffi import GeneratedFunctionError
from maglevgen.runtime.library import SimulationLibrary

__all__ = ["AXIS_STATES", "N_AXES", "REDUCED_INDEX", "REDUCED_STATES", "STABILITY_MARGIN",
           "AxisGains", "CoupledComparison", "OperatingPoint", "SpeedMode", "Weights",
           "checked_accelerating_trim", "checked_trim", "closed_loop_stability", "compare_designs",
           "coupled_lqr", "coupled_weights", "numerical_lqr", "operating_point", "speed_mode",
           "stability"]

AXIS_STATES: tuple[int, ...] = tuple(cv.STATE_INDEX[s] for s in Q_STATES)
# the coupled model's states (see the module docstring)
REDUCED_STATES: tuple[str, ...] = ("y", "z", "phi", "theta", "psi", "v", "w", "p", "q", "r")
REDUCED_INDEX: tuple[int, ...] = tuple(cv.STATE_INDEX[s] for s in REDUCED_STATES)
N_AXES = len(cv.AXES)


@dataclass(frozen=True)
class SpecWeights:
    """The specification's numbers the `spec` design uses (``[control.spec]``,
    `maglevgen.control.spec`): here, beside the paper's `Weights` that carry them, so that
    the design's module imports nothing of the operating point at run time."""

    a_max: tuple[float, ...]  # allowed deviation per axis [m, m, rad, rad, rad]
    force_budget: float  # [N] per array
    zeta: float  # the per-axis design damping ratio

    @classmethod
    def of(cls, spec) -> SpecWeights:
        """From a `maglevgen.params.ControlSpec`."""
        dev = spec.max_deviation
        return cls(tuple(float(getattr(dev, k)) for k in Q_STATES), float(spec.force_budget),
                   float(spec.min_damping_ratio + spec.damping_margin))


@dataclass(frozen=True)
class Weights:
    """LQR weights per axis: q1 on the position, q2 on the rate, r on the force (the paper's
    designs), and the specification the `spec` design derives its own from."""

    q1: float
    q2: float
    r: float
    spec: SpecWeights | None = None

    @classmethod
    def of(cls, params) -> Weights:
        (q1, q2), r = params.control.state_weights, params.control.input_weight
        return cls(float(q1), float(q2), float(r), SpecWeights.of(params.control.spec))


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
    plants: np.ndarray | None = None  # (5, 2) per-axis (k, m) of maglev_axis_plants
    _gains: dict = field(default_factory=dict, compare=False, repr=False)  # by controller

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
        """(K_pos, K_rate), each 5 x 5, of a registered controller (maglevgen.control), computed
        once per operating point."""
        if controller not in self._gains:
            try:
                law = registered_controller(controller)
            except KeyError as exc:
                raise InputError(exc.args[0]) from None
            self._gains[controller] = law.gains(self)
        K_pos, K_rate = self._gains[controller]
        return K_pos.copy(), K_rate.copy()

    @property
    def trim_drag_slope(self) -> float:
        """dF_prop,trim/dV [N s/m]: the trim propulsion's slope along the trim curve.

        Trim: acc(x(V, q), F_prop) = 0 in the six unknowns (q, F_prop). The body velocity at
        trim is R^T (V, 0, 0); turning it with q leaves every array's along-track speed at V
        and its gaps still (the trim flies along the track), so d acc/dq at fixed V is A's
        position columns plus its velocity columns along d(R^T (V, 0, 0))/dq (zero but for
        the circuits' lag, which sees the gap rates n . R v), and d acc/dV is A's velocity
        columns along the trim's velocity direction (the implicit-function theorem).
        """
        acc, q, vel = cv.KINETIC, cv.AXIS_COORDINATES, cv.VELOCITY
        V = self.speed
        dv_dq = V * _track_direction_slopes(*self.x_trim[cv.ATTITUDE])
        J = np.column_stack([self.A[acc, q] + self.A[acc, vel] @ dv_dq, self.B[acc, 0]])
        dacc_dV = self.A[acc, vel] @ (self.x_trim[vel] / V)
        return float(-np.linalg.solve(J, dacc_dV)[len(Q_STATES)])  # F_prop's, after q's

    def axis_gains(self, K_reduced: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(K_pos, K_rate) of a full-state gain K_reduced (5 x 10) on REDUCED_STATES:
        K_reduced x_r = K' [a; a'] with [a; a'] = M x_r, M = [S; C_rate] (invertible near
        trim)."""
        M = np.vstack([np.eye(N_AXES, len(REDUCED_INDEX)), self.rate_map])
        K_prime = np.linalg.solve(M.T, K_reduced.T).T
        return K_prime[:, :N_AXES], K_prime[:, N_AXES:]

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
        return self.A + self.B[:, cv.ARRAY_INPUTS] @ self.allocation @ d_ugen


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
    return _checked(lib, p, speed, 0.0, min_gap, x_trim, f_prop)


def checked_accelerating_trim(lib: SimulationLibrary, p: np.ndarray, speed: float,
                              acceleration: float, min_gap: float
                              ) -> tuple[np.ndarray, float, np.ndarray]:
    """(x_trim, F_prop, gaps) of the carriage at ``speed`` accelerating at ``acceleration``
    [m/s^2] along the track: `maglev_trim_accelerating` in C (eqs 1-2 with the d'Alembert
    load -m a at the CG, derive/trim.py), checked like `checked_trim` with the model's
    accelerations less the translation's, R^T (a, 0, 0) = (a / V) (u, v, w); F_prop is the
    drag plus m a. NoTrimError when there is none; zero acceleration gives `checked_trim`."""
    if not np.isfinite(acceleration):
        raise InputError(f"--acceleration {acceleration!r}: must be a finite number in m/s^2")
    try:
        x_trim, f_prop = lib.function("maglev_trim_accelerating")(speed, acceleration, p)
    except GeneratedFunctionError as exc:
        raise NoTrimError(f"no trim at {speed:g} m/s accelerating at {acceleration:g} m/s^2: "
                          f"the Newton trim in C returned {exc.code_name} (below lift-off "
                          "speed?); see `maglevgen trim --acceleration`") from None
    return _checked(lib, p, speed, float(acceleration), min_gap, x_trim, f_prop)


def _checked(lib: SimulationLibrary, p: np.ndarray, speed: float, acceleration: float,
             min_gap: float, x_trim: np.ndarray, f_prop: np.ndarray
             ) -> tuple[np.ndarray, float, np.ndarray]:
    """The C's trim checked here as well: the accelerations of maglev_dynamics at it less those
    of the translation at ``acceleration`` below 1e-8, every gap above ``min_gap``."""
    x_trim, f_trim = x_trim.ravel(), float(f_prop.ravel()[0])
    n_u = lib.function("maglev_dynamics").shapes_in[1][0]
    u = np.zeros(n_u)
    u[cv.PROPULSION_INPUT] = f_trim
    xdot = lib.function("maglev_dynamics")(x_trim, u, p)[0].ravel()
    xdot[cv.VELOCITY] -= x_trim[cv.VELOCITY] * (acceleration / speed)
    acc = xdot[cv.KINETIC]
    gaps = lib.function("maglev_gaps")(x_trim, p)[0].ravel()
    moving = f" accelerating at {acceleration:g} m/s^2" if acceleration else ""
    if not (np.all(np.isfinite(acc)) and np.max(np.abs(acc)) < 1e-8):
        raise NoTrimError(f"no trim at {speed:g} m/s{moving}: the Newton solve in C did not "
                          "converge (below lift-off speed?); see `maglevgen trim`")
    if np.min(gaps) < min_gap:
        raise NoTrimError(f"no trim at {speed:g} m/s{moving} with every gap above "
                          f"track.min_gap = {min_gap:g} m (smallest {np.min(gaps):.4g} m)")
    return x_trim, f_trim, gaps


def coupled_weights(C_rate: np.ndarray, w: Weights) -> tuple[np.ndarray, np.ndarray]:
    """(Q, R) of the coupled LQR on the reduced state: the per-axis design's weights, q1 on
    every axis position, q2 on every axis rate (C_rate x_r), r on every generalized force."""
    S = np.eye(N_AXES, C_rate.shape[1])
    return w.q1 * S.T @ S + w.q2 * C_rate.T @ C_rate, w.r * np.eye(N_AXES)


def coupled_lqr(A_r: np.ndarray, B_g: np.ndarray, C_rate: np.ndarray,
                w: Weights) -> np.ndarray:
    """K (5 x 10) of the coupled LQR with `coupled_weights`."""
    return numerical_lqr(A_r, B_g, *coupled_weights(C_rate, w))


@dataclass(frozen=True)
class AxisGains:
    """One axis: its plant, the closed-form LQR, the numerical LQR and the paper's gain."""

    axis: str
    stiffness: float
    inertia: float
    A: np.ndarray
    B: np.ndarray
    P_closed_form: np.ndarray
    K_closed_form: np.ndarray
    K_numerical: np.ndarray
    K_paper: np.ndarray
    K_reference: np.ndarray  # the closed form in 50-digit arithmetic, rounded to double
    damping_gain: float | None

    def relative(self, K: np.ndarray, ref: np.ndarray | None = None) -> float:
        ref = self.K_reference if ref is None else ref
        return float(np.max(np.abs(K - ref) / np.abs(ref)))

    def to_json(self, Q: tuple[float, float], R: float) -> dict:
        err_cf = self.relative(self.K_closed_form)
        err_num = self.relative(self.K_numerical)
        return {
            "stiffness": self.stiffness,
            "inertia": self.inertia,
            "A": self.A.tolist(),
            "B": self.B.tolist(),
            "P_closed_form": self.P_closed_form.tolist(),
            "K_closed_form": self.K_closed_form.tolist(),
            "K_numerical": self.K_numerical.tolist(),
            "K_paper": self.K_paper.tolist(),
            "paper_applies": bool(Q == (1.0, 1.0) and R == 1.0),
            "relative_difference": {
                "numerical_vs_closed_form": self.relative(self.K_numerical, self.K_closed_form),
                "paper_vs_closed_form": self.relative(self.K_paper, self.K_closed_form),
            },
            "accuracy_vs_50_digit_reference": {
                "closed_form": err_cf,
                "numerical": err_num,
                "more_accurate": "closed_form" if err_cf <= err_num else "numerical",
            },
            "closed_loop_poles": [[p.real, p.imag] for p in
                                  np.linalg.eigvals(self.A - self.B @ self.K_closed_form[None])],
            "damping_gain": self.damping_gain,
        }


@dataclass(frozen=True)
class CoupledComparison:
    """The per-axis design applied to the full linearisation, beside the coupled LQR."""

    poles_per_axis: np.ndarray
    poles_coupled: np.ndarray
    poles_damping: np.ndarray
    cost_per_axis: float  # J = trace(P_lyap) for unit-covariance initial states
    cost_coupled: float
    K_coupled: np.ndarray  # 5 x 10 on REDUCED_STATES


def compare_designs(Ar: np.ndarray, Bg: np.ndarray, C_rate: np.ndarray, w: Weights,
                    K_a: np.ndarray, K_c: np.ndarray, K_d: np.ndarray) -> CoupledComparison:
    """Poles and LQR costs of the per-axis (K_a), coupled (K_c) and damping (K_d) feedbacks
    (5 x 10 on REDUCED_STATES) closed around the reduced linearisation (Ar, Bg)."""
    Q, R = coupled_weights(C_rate, w)

    def cost(K: np.ndarray) -> float:
        return quadratic_cost(Ar - Bg @ K, Q + K.T @ R @ K)

    eig = lambda K: np.linalg.eigvals(Ar - Bg @ K)  # noqa: E731
    return CoupledComparison(eig(K_a), eig(K_c), eig(K_d), cost(K_a), cost(K_c),
                             np.asarray(K_c))


def operating_point(lib: SimulationLibrary, p: np.ndarray, speed: float, min_gap: float,
                    weights: Weights) -> OperatingPoint:
    """Checked trim, gains, allocation and linearisation at ``speed``, from the generated C."""
    x_trim, f_prop, gaps = checked_trim(lib, p, speed, min_gap)
    K, c = lib.function("maglev_lqr_gains")(speed, p)
    (T,) = lib.function("maglev_allocation_matrix")(p)
    u = np.zeros(T.shape[0] + 1)
    u[cv.PROPULSION_INPUT] = f_prop
    A, B = lib.function("maglev_jacobians")(x_trim, u, p)
    k, m = (a.ravel() for a in lib.function("maglev_axis_plants")(speed, p))
    return OperatingPoint(float(speed), x_trim, f_prop, gaps, K, c.ravel(), T, A, B, weights,
                          np.column_stack([k, m]))


# a closed loop is called stable when every eigenvalue's real part is below -STABILITY_MARGIN
# (1/s): a mode closer to the axis than this neither decays nor grows visibly in a launch
STABILITY_MARGIN = 1e-6


def stability(eigenvalues: np.ndarray) -> tuple[float, float]:
    """(largest real part [1/s], smallest damping ratio) of a set of eigenvalues."""
    ev = np.asarray(eigenvalues)
    mag = np.abs(ev)
    zeta = np.where(mag > 1e-12, -ev.real / np.where(mag > 1e-12, mag, 1.0), 1.0)
    return float(np.max(ev.real)), float(np.min(zeta))


def closed_loop_stability(op: OperatingPoint, controller: str) -> tuple[float, float]:
    """(largest real part, smallest damping ratio) of the ten-state closed loop at ``op``."""
    A_cl = op.reduced_closed_loop(controller)
    if not np.all(np.isfinite(A_cl)):
        return float("inf"), float("nan")
    return stability(np.linalg.eigvals(A_cl))


@dataclass(frozen=True)
class SpeedMode:
    """The forward-speed mode under the constant trim propulsion, and the two parts of it.

    Along the track m V' = F_prop - F_D(V) (eqs 1-2 along x; lift acts along the track normal
    and drag along -x). With the propulsion held at its trim value and every other axis
    following the trim as the speed changes (they are orders of magnitude faster), the pole is

        lambda = -(1/m) dF_D,trim/dV
               = -(1/m) sum_i (dF_D,i/dV|_gaps + dF_D,i/d(gap_i) d(gap_i)/dV),

    the trim drag's total slope along the trim curve: the drag law's slope at fixed gaps (eq 3;
    negative above the characteristic speed v_c = R/(kL), where the drag falls with speed,
    positive below it) plus the re-trim (lift rises with speed, the carriage rises: the upper
    arrays' gaps open, the lower arrays' close, and as the upper arrays carry most of the drag,
    exp(-2 k gap), the trim drag falls, below v_c as well). Numbers from the generated C: the
    trim drag's slope by the implicit-function theorem on the trim's six balances with
    maglev_jacobians, the fixed-gap slope from eq 3 at the C's array forces, the eigenvalue of
    `full_closed_loop`.
    """

    speed: float  # V [m/s]
    mass: float  # m [kg]
    drag_slope_trim: float  # dF_D,trim/dV along the trim curve (re-trim included) [N s/m]
    drag_slope_fixed_gaps: float  # sum_i dF_D,i/dV at the trim's gaps (eq 3) [N s/m]
    characteristic_speed: float  # v_c = R/(k L), where eq 3's drag equals its lift [m/s]
    eigenvalue: float  # the speed mode's eigenvalue of the 12-state closed loop [1/s]
    controller: str  # whose closed loop gave ``eigenvalue``

    @property
    def pole_trim(self) -> float:
        """-(dF_D,trim/dV)/m: the speed pole from the trim drag's total slope [1/s]."""
        return -self.drag_slope_trim / self.mass

    @property
    def pole_fixed_gaps(self) -> float:
        """-(sum_i dF_D,i/dV|_gaps)/m: the drag law's part of the pole [1/s]."""
        return -self.drag_slope_fixed_gaps / self.mass

    @property
    def pole_retrim(self) -> float:
        """pole_trim - pole_fixed_gaps: the part from the gaps following the trim [1/s]."""
        return self.pole_trim - self.pole_fixed_gaps

    @property
    def dominant(self) -> str:
        """"drag law" or "re-trim": the part with the larger magnitude."""
        return "drag law" if abs(self.pole_fixed_gaps) >= abs(self.pole_retrim) else "re-trim"

    def to_json(self) -> dict:
        """As plain data: the slopes, the two parts of the pole, the eigenvalue, the sentence."""
        return {"speed": self.speed, "mass": self.mass, "controller": self.controller,
                "drag_slope_trim": self.drag_slope_trim,
                "drag_slope_fixed_gaps": self.drag_slope_fixed_gaps,
                "characteristic_speed": self.characteristic_speed,
                "pole_trim": self.pole_trim, "pole_fixed_gaps": self.pole_fixed_gaps,
                "pole_retrim": self.pole_retrim, "eigenvalue": self.eigenvalue,
                "dominant": self.dominant, "explanation": self.explanation()}

    def explanation(self) -> str:
        """One sentence (plain ASCII) for SUMMARY.md, metrics.md and the messages."""
        side = "above" if self.speed > self.characteristic_speed else "below"
        law = "falls" if self.drag_slope_fixed_gaps < 0 else "rises"
        state = ("unstable" if self.eigenvalue > 0 else "stable" if self.eigenvalue <= 0
                 else "of unknown stability")  # NaN: no closed loop for the controller
        retrim = ("lift rises with speed, the upper gaps open and the trim drag falls"
                  if self.pole_retrim > 0 else "the gaps follow the trim and the drag rises")
        return (f"under the constant trim propulsion the speed is {state} (12-state pole "
                f"{self.eigenvalue:+.4f} 1/s); the trim drag's total slope with speed gives "
                f"-(dF_D,trim/dV)/m = {self.pole_trim:+.4f} 1/s: {self.pole_fixed_gaps:+.4f} "
                f"1/s from the drag law at fixed gaps ({side} the characteristic speed "
                f"{self.characteristic_speed:.4g} m/s the drag {law} with speed) and "
                f"{self.pole_retrim:+.4f} 1/s from the re-trim ({retrim}); the "
                f"{self.dominant} dominates")


def _track_direction_slopes(phi: float, theta: float, psi: float) -> np.ndarray:
    """d(R^T e_x)/d(y, z, phi, theta, psi) (3 x 5): how the track direction in body axes
    turns with the attitude (R = Rz(psi) Ry(theta) Rx(phi); R^T e_x is R's first row)."""
    cf, sf, ct, st, cp, sp_ = (np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta),
                               np.cos(psi), np.sin(psi))
    d_phi = [0.0, cf * st * cp + sf * sp_, -sf * st * cp + cf * sp_]
    d_theta = [-st * cp, sf * ct * cp, cf * ct * cp]
    d_psi = [-ct * sp_, -sf * st * sp_ - cf * cp, -cf * st * sp_ + sf * cp]
    return np.column_stack([np.zeros(3), np.zeros(3), d_phi, d_theta, d_psi])


def speed_mode(lib: SimulationLibrary, p: np.ndarray, op: OperatingPoint, mass: float,
               controller: str = "lqr") -> SpeedMode:
    """`SpeedMode` at ``op`` from the generated C, the eigenvalue that of ``controller``'s
    12-state closed loop (`OperatingPoint.full_closed_loop`)."""
    V = op.speed
    # eq 3 at a fixed gap: F_D = F_L r, r = R/(omega L) = v_c/V, F_D ~ r/(1 + r^2), so
    # dF_D/dV = -F_D (1 - r^2) / ((1 + r^2) V); r from the C's drag/lift of each array.
    lift, drag = (a.ravel() for a in lib.function("maglev_array_forces")(op.x_trim, p))
    # an array out of the track's reach (its gap metres wide) has no lift and no drag: it adds
    # nothing to the slope (0/0 made the slope NaN, printed by `gains --json`)
    r = np.divide(drag, lift, out=np.zeros_like(drag), where=lift != 0)
    fixed = float(-np.sum(drag * (1 - r**2) / ((1 + r**2) * V)))
    # the speed mode: the eigenvector with the largest share in u (x, a pure integrator, aside)
    kept = [i for i in range(cv.N_STATES) if i != cv.STATE_INDEX["x"]]
    A_cl = op.full_closed_loop(controller)[np.ix_(kept, kept)]
    eigenvalue = float("nan")  # the coupled LQR where its Riccati equation has no solution
    if np.all(np.isfinite(A_cl)):
        ev, vec = np.linalg.eig(A_cl)
        share = np.abs(vec[kept.index(cv.STATE_INDEX["u"])]) / np.linalg.norm(vec, axis=0)
        eigenvalue = float(ev[np.argmax(share)].real)
    return SpeedMode(V, float(mass), op.trim_drag_slope, fixed, float(np.median(r)) * V,
                     eigenvalue, controller)
