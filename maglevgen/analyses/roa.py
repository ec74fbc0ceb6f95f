"""A region of attraction of a controller's closed loop across the envelope: a contact-free
sublevel set of a Lyapunov function on which it decreases, its contact limit computed and its
decrease sampled.

At each speed the Lyapunov candidate is V(x) = dx' P dx on the ten reduced states
dx = x_r - x_r,trim (`operating.REDUCED_STATES`; the forward speed is held by the propulsion,
the along-track position drops out), P the solution of the Lyapunov equation of the linear
closed loop A_cl = A_r - B_g K (eqs 24-33's coupled form)

    A_cl' P + P A_cl = -(Q + K' R K),

with Q, R the weights of the design (`design_weights`): for `spec` those of [control.spec]
(Bryson's rule on the allowed deviations and the force budget), for the paper's designs the
paper's q1, q2, r. For an LQR designed with these weights on the coupled model (`spec`,
`coupled`) P is its Riccati solution (the CARE's P satisfies exactly this equation with its
own gain); for the per-axis LQR and the damping it is the cost-to-go of the paper's cost
under that controller.

The level: the smaller of
1. the contact limit, computed (`contact_level`): the largest c with every array's gap (the
   closest corner, `maglev_gaps`, the nonlinear gaps) at or above track.min_gap on the whole
   of {V <= c}, by minimising V over the states in contact, per gap, from several starts; and
2. the largest c such that, at every sampled state of {V <= c}, dV/dt = 2 dx' P f(x) < 0 on
   the **nonlinear** closed loop (the generated C's `maglev_closed_loop`, the build's
   physics model; evaluated in C, batched: `maglev_lyapunov_batch`).
The set is therefore a contact-free sublevel set of V on which V decreases (where sampled),
not the limit of recovery: the carriage recovers from further out along most directions.
The states of 2: ``directions`` unit directions on the ellipsoid {V = 1} (uniform on the whitened
sphere, plus the ten state axes, the default disturbance and P's eigenvectors, each with both
signs), each at radii doubling from 1/1024 of the default disturbance's to the first shell
with a failure, then on a uniform grid of ``radii`` radii up to that shell, then ``bisections``
bisections between the last passing and the first failing radius. Then, as the firmware runs
the controller (the tick, its delay, the zero-order hold, the speed loop and the force budget
of [control.spec]: `Plant.loop`), closed-loop runs from ``confirm`` states on the
boundary {V = c} must all settle without contact; where one does not, c shrinks
(CONFIRM_SHRINK) until every run settles.

The decrease is a sampled estimate, not a proof: a failure between the sampled directions or
radii can be missed (the report states the counts and the radial bracket); the contact limit
is a local minimisation from several starts (a tested bound: no state of {V <= c} in contact
among 10^5 sampled in tests/test_roa.py). A certificate would
bound dV/dt over the whole set (sum-of-squares on a polynomial model with its remainder).
"""

from __future__ import annotations

import io
import json
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from maglevgen.analyses.roa_contact import CONTACT_STARTS, contact_level
from maglevgen.analyses.simulate import DISTURBANCE, run_loop, simulate_batch
from maglevgen.control.built_loop import Loop
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.lqr import weighted_qr
from maglevgen.control.operating import (
    N_AXES,
    REDUCED_INDEX,
    REDUCED_STATES,
    OperatingPoint,
    coupled_weights,
)
from maglevgen.controllers import controller as registered
from maglevgen.derive import conventions as cv
from maglevgen.errors import InputError

if TYPE_CHECKING:  # the library comes from the Plant; only its type is named here
    from maglevgen.runtime.library import SimulationLibrary

__all__ = ["AXIS_NAMES", "AXIS_UNITS", "BUILD_SAMPLING", "BUILD_SPEEDS", "COMMAND_SAMPLING",
           "CONFIRM_DT", "CONFIRM_T_END", "DEFAULT_SPEEDS", "MAX_BATCH", "MAX_DIRECTIONS",
           "MAX_SPEEDS", "REDUCED_INDEX", "REDUCED_STATES", "Evaluator", "Region", "Sampling",
           "confirmation_run", "contact_level", "default_deviation", "lyapunov_matrix",
           "region_of_attraction", "region_png", "sampled_search", "speed_region", "study",
           "study_files", "study_json", "study_lines", "summary_lines"]

#: the states V is defined on, and their display units (mm, mrad; rates per second)
AXIS_NAMES: tuple[str, ...] = cv.Q_STATES
AXIS_UNITS: dict[str, tuple[str, float]] = {
    "y": ("mm", 1e3), "z": ("mm", 1e3), "phi": ("mrad", 1e3), "theta": ("mrad", 1e3),
    "psi": ("mrad", 1e3)}
#: the shells searched first: radii doubling from 2^SHELL_LOW to 2^SHELL_HIGH times the
#: default disturbance's sqrt(V); no failure up to the last: the level is reported as a bound
SHELL_LOW, SHELL_HIGH = -10, 8
#: the factor on c when a confirmation run from the boundary does not settle, and how often
CONFIRM_SHRINK, CONFIRM_ROUNDS = 0.64, 6
#: the confirmation runs: (deviations, P) -> [(status, V(end) / V(start))] (`confirmation_run`)
Confirm = Callable[[list[np.ndarray], np.ndarray], list[tuple[str, float]]]
#: the confirmation runs' length [s] and RK4 step [s]
CONFIRM_T_END, CONFIRM_DT = 6.0, 1e-3


#: the most directions per speed, states per C call and speeds (`maglevgen roa`): the
#: states of a speed are held in memory, ten doubles each
MAX_DIRECTIONS, MAX_BATCH, MAX_SPEEDS = 1_000_000, 1_000_000, 1000


@dataclass(frozen=True)
class Sampling:
    """How densely the set is sampled and how the work is split.

    ``directions`` random directions (plus the fixed ones, see the module docstring),
    ``radii`` uniform radii per direction, ``bisections`` of the bracket, ``confirm``
    boundary runs per speed, ``seed`` of the directions; ``batch`` states per C call and
    ``workers`` threads (neither changes a number: every state is evaluated alone)."""

    directions: int = 3000
    radii: int = 32
    bisections: int = 8
    confirm: int = 8
    seed: int = 0
    batch: int = 8192
    workers: int = 1

    def __post_init__(self) -> None:
        for name, low, high in (("directions", 1, MAX_DIRECTIONS), ("radii", 2, 10_000),
                                ("bisections", 0, 64), ("confirm", 0, 10_000),
                                ("batch", 1, MAX_BATCH), ("workers", 1, 1024),
                                ("seed", 0, 2**128 - 1)):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or isinstance(value, bool) \
                    or not low <= value <= high:
                option = "--samples" if name == "directions" else f"--{name}"
                raise InputError(f"{option} {value!r}: expected a whole number from {low} "
                                 f"to {high}")


#: the command's resolution and the build's (seconds, not minutes)
COMMAND_SAMPLING = Sampling()
BUILD_SAMPLING = Sampling(directions=150, radii=10, bisections=4, confirm=2)


@dataclass(frozen=True)
class Confirmation:
    """One closed-loop run from a boundary state: what it was, how it ended."""

    label: str
    status: str  # simulate.run_status: settled, not settled, diverging, contact
    decay: float = float("nan")  # V at the run's end / V at its start

    @property
    def ok(self) -> bool:
        """Settled, or (a design slower than the run) without contact or divergence and
        with V at the end below a tenth of its start."""
        return self.status == "settled" or (self.status == "not settled" and self.decay < 0.1)


@dataclass(frozen=True)
class Recovery:
    """How far along a direction the firmware loop recovers (`recovery_bracket`): from
    ``lo`` times it, not from ``hi`` times it (multiples of the default disturbance, or of the
    boundary state along the limiting direction)."""

    label: str
    lo: float
    hi: float

    def text(self) -> str:
        top = (f"not from {self.hi:.3g}x" if np.isfinite(self.hi) else
               f"no failure up to {self.lo:.3g}x")
        return f"{self.label}: recovers from {self.lo:.3g}x, {top}"

    def to_json(self) -> dict:
        return {"along": self.label, "recovers_from": self.lo,
                "fails_from": self.hi if np.isfinite(self.hi) else None}


@dataclass(frozen=True)
class SpeedRegion:
    """The region at one speed."""

    speed: float  # [m/s]
    level: float  # c: confirmed by the boundary runs (0: no region)
    sampled_level: float  # c from dV/dt and the gaps alone
    failing_level: float  # V of the first failing shell (inf: none found)
    limit: str  # what bounds the sampled level: "dV/dt", "contact", "none found" or "unstable"
    states: int  # states evaluated
    P: np.ndarray  # (10, 10) on REDUCED_STATES (NaN when the linear closed loop is unstable)
    default_V: float  # V of the default disturbance (simulate.DISTURBANCE)
    confirmations: tuple[Confirmation, ...] = ()
    shrinks: int = 0  # how often the confirmation runs shrank c
    rejected: tuple[Confirmation, ...] = ()  # the runs that failed at a larger c
    worst: np.ndarray | None = None  # the first failing sampled direction (V = 1)
    recovery: tuple[Recovery, ...] = ()  # firmware-loop runs along chosen directions

    @property
    def confirmed(self) -> bool:
        return all(c.ok for c in self.confirmations)

    @property
    def extents(self) -> dict[str, float]:
        """Per axis, the largest deviation of that axis alone (every other state at trim)
        inside {V <= c}: sqrt(c / P_ii) [m, rad]."""
        return {a: (float(np.sqrt(self.level / self.P[i, i])) if self.level > 0 else 0.0)
                for i, a in enumerate(AXIS_NAMES)}

    @property
    def projections(self) -> dict[str, float]:
        """Per axis, the largest deviation of that axis over the whole set (rates and the
        other axes free): sqrt(c (P^-1)_ii) [m, rad]."""
        if not self.level > 0:
            return {a: 0.0 for a in AXIS_NAMES}
        inv = np.linalg.inv(self.P)
        return {a: float(np.sqrt(self.level * inv[i, i])) for i, a in enumerate(AXIS_NAMES)}

    @property
    def disturbance_multiple(self) -> float:
        """sqrt(c / V(default disturbance)): how many times the README's default disturbance
        (1 mm / 2 mrad on every axis at once) lies inside the set."""
        return float(np.sqrt(self.level / self.default_V)) if self.level > 0 else 0.0

    @property
    def radial_bracket(self) -> float:
        """(sqrt(failing) - sqrt(sampled)) / sqrt(sampled): the radial resolution of the
        sampled level along the sampled directions (inf: no failure found, or no level)."""
        if not (self.sampled_level > 0 and np.isfinite(self.failing_level)):
            return float("inf")
        return float(np.sqrt(self.failing_level / self.sampled_level) - 1)

    @property
    def weakest(self) -> str:
        """The axis with the smallest extent relative to the default disturbance's value on
        it (1 mm, 2 mrad)."""
        e, d = self.extents, default_deviation()
        return min(AXIS_NAMES, key=lambda a: e[a] / d[AXIS_NAMES.index(a)])

    def multiple_of(self, dx: np.ndarray) -> float:
        """sqrt(V(dx) / c): the deviation ``dx`` (10 reduced states) as a multiple of the
        region's boundary along its direction (inf: no region)."""
        if not self.level > 0:
            return float("inf")
        dx = np.asarray(dx, dtype=float)
        return float(np.sqrt(dx @ self.P @ dx / self.level))

    def to_json(self) -> dict:
        return {"speed": self.speed, "level": self.level, "sampled_level": self.sampled_level,
                "failing_level": (self.failing_level if np.isfinite(self.failing_level)
                                  else None),
                "limit": self.limit, "states": self.states, "confirmed": self.confirmed,
                "shrinks": self.shrinks, "radial_bracket": (
                    self.radial_bracket if np.isfinite(self.radial_bracket) else None),
                "extents": self.extents, "projections": self.projections,
                "disturbance_multiple": self.disturbance_multiple,
                "confirmations": [{"state": c.label, "status": c.status,
                                   "V_end_over_start": c.decay, "ok": c.ok}
                                  for c in self.confirmations],
                "rejected": [{"state": c.label, "status": c.status} for c in self.rejected],
                "recovery": [r.to_json() for r in self.recovery],
                "P": self.P.tolist() if np.all(np.isfinite(self.P)) else None}


@dataclass(frozen=True)
class Region:
    """A controller's region of attraction at each speed, and how it was sampled."""

    controller: str
    regions: tuple[SpeedRegion, ...]
    sampling: Sampling
    loop: str  # how the confirmation runs executed the controller
    fixed_directions: int = 0

    @property
    def speeds(self) -> np.ndarray:
        return np.array([r.speed for r in self.regions])

    def statement(self) -> str:
        """How the level was established, and what it is not (one paragraph, ASCII)."""
        s = self.sampling
        brackets = [r.radial_bracket for r in self.regions if np.isfinite(r.radial_bracket)]
        bracket = (f"within {100 * max(brackets):.2g} % in the square root of c along the sampled "
                   "directions" if brackets else "not bracketed (no failure found)")
        states = max((r.states for r in self.regions), default=0)
        return (f"A contact-free sublevel set of V on which V decreases, not the limit of "
                f"recovery. Contact: computed, the largest c with every nonlinear gap at or "
                f"above track.min_gap on all of {{V <= c}} (V minimised over the states in "
                f"contact, per gap, SLSQP from {1 + CONTACT_STARTS} starts). Decrease: a "
                f"sampled estimate, not a proof: dV/dt < 0 on the nonlinear closed loop (the "
                f"generated C) at up to "
                f"{states} states of {{V <= c}} ({s.directions} random directions uniform on "
                f"the ellipsoid plus {self.fixed_directions} fixed ones (the state axes, the "
                f"default disturbance, P's eigenvectors), on shells doubling in radius, "
                f"{s.radii} radii up to the first failing shell and {s.bisections} "
                f"bisections, seed {s.seed}); the level is bracketed {bracket}; a failure "
                f"between the sampled directions can be missed. {s.confirm} closed-loop runs "
                f"per speed ({self.loop} loop, {CONFIRM_T_END:g} s) from states on {{V = c}} "
                f"must settle without contact; where one did not, c shrank by "
                f"{CONFIRM_SHRINK:g} until all did (at most {CONFIRM_ROUNDS} times, else "
                "c = 0: no region confirmed).")

    def to_json(self) -> dict:
        s = self.sampling
        return {"controller": self.controller, "loop": self.loop,
                "states": list(REDUCED_STATES),
                "sampling": {"directions": s.directions, "fixed_directions":
                             self.fixed_directions, "radii": s.radii,
                             "bisections": s.bisections, "confirm": s.confirm,
                             "seed": s.seed},
                "statement": self.statement(),
                "speeds": [r.to_json() for r in self.regions]}


def lyapunov_matrix(op: OperatingPoint, controller: str) -> np.ndarray | None:
    """P (10 x 10) of A_cl' P + P A_cl = -(Q + K' R K) on REDUCED_STATES (module docstring),
    None when the linear closed loop is not stable (no quadratic region)."""
    import scipy.linalg  # local: the simulation path stays SciPy-free

    A_cl = op.reduced_closed_loop(controller)
    if not (np.all(np.isfinite(A_cl)) and np.max(np.linalg.eigvals(A_cl).real) < 0):
        return None
    Q, R = design_weights(op, controller)
    K_pos, K_rate = op.gains(controller)
    K = K_pos @ np.eye(N_AXES, len(REDUCED_INDEX)) + K_rate @ op.rate_map
    P = scipy.linalg.solve_continuous_lyapunov(A_cl.T, -(Q + K.T @ R @ K))
    P = 0.5 * (P + P.T)
    if np.min(np.linalg.eigvalsh(P)) <= 0:
        return None
    return P


def design_weights(op: OperatingPoint, controller: str) -> tuple[np.ndarray, np.ndarray]:
    """(Q, R) of V's Lyapunov equation: the controller's own weights (`Controller.weights`:
    the spec's Bryson weights for `spec`), else the paper's (q1, q2, r of [control],
    `operating.coupled_weights`)."""
    if (weights := registered(controller).weights) is not None:
        return weighted_qr(op.rate_map, *weights(op))
    return coupled_weights(op.rate_map, op.weights)


def default_deviation() -> np.ndarray:
    """The README's default disturbance (simulate.DISTURBANCE) on REDUCED_STATES."""
    return np.array([DISTURBANCE.get(s, 0.0) for s in REDUCED_STATES])


def _embed(P: np.ndarray) -> np.ndarray:
    """P on the twelve states: zero rows and columns for x and u."""
    full = np.zeros((len(cv.STATES), len(cv.STATES)))
    full[np.ix_(REDUCED_INDEX, REDUCED_INDEX)] = P
    return full


class Evaluator:
    """V, dV/dt and the smallest gap at deviations from trim, in the generated C."""

    def __init__(self, lib: SimulationLibrary, p: np.ndarray, op: OperatingPoint,
                 controller: str, P: np.ndarray, sampling: Sampling) -> None:
        self.lib, self.p, self.op, self.sampling = lib, p, op, sampling
        self.P12 = _embed(P)
        self.K_pos, self.K_rate = (k.ravel(order="F") for k in op.gains(controller))
        self.count = 0

    def __call__(self, dx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(V, dV/dt, smallest gap) at the rows of ``dx`` (n x 10 reduced deviations)."""
        V, Vd, g = self.all_gaps(dx)
        return V, Vd, (g.min(axis=1) if g.size else np.zeros(0))

    def all_gaps(self, dx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(V, dV/dt, every gap (n x n_gaps)) at the rows of ``dx``."""
        X = np.tile(self.op.x_trim, (dx.shape[0], 1))
        X[:, list(REDUCED_INDEX)] += dx
        b = self.sampling.batch
        chunks = [X[i:i + b] for i in range(0, X.shape[0], b)]
        n_g = self.op.gaps.size

        def one(chunk: np.ndarray):
            return self.lib.lyapunov_batch(chunk, self.op.f_prop, self.K_pos, self.K_rate,
                                           self.op.a_trim, self.op.x_trim, self.P12, self.p,
                                           n_g)

        if self.sampling.workers > 1 and len(chunks) > 1:
            with ThreadPoolExecutor(self.sampling.workers) as pool:
                parts = list(pool.map(one, chunks))
        else:
            parts = [one(c) for c in chunks]
        self.count += X.shape[0]
        if not parts:
            return np.zeros(0), np.zeros(0), np.zeros((0, n_g))
        V = np.concatenate([q[0] for q in parts])
        Vd = np.concatenate([q[1] for q in parts])
        return V, Vd, np.concatenate([q[2] for q in parts])


def _directions(P: np.ndarray, sampling: Sampling) -> tuple[np.ndarray, int]:
    """(D, n_fixed): rows of deviations with V = 1, the fixed ones first (the ten state axes,
    the default disturbance, P's eigenvectors, both signs), then the random ones (uniform on
    the whitened sphere z = L' dx, P = L L')."""
    L = np.linalg.cholesky(P)
    _, vecs = np.linalg.eigh(P)
    fixed = np.vstack([np.eye(P.shape[0]), default_deviation()[None, :], vecs.T])
    fixed = np.vstack([fixed, -fixed])
    fixed /= np.sqrt(np.einsum("ij,jk,ik->i", fixed, P, fixed))[:, None]
    rng = np.random.default_rng(sampling.seed)
    z = rng.standard_normal((sampling.directions, P.shape[0]))
    z /= np.linalg.norm(z, axis=1, keepdims=True)
    random = np.linalg.solve(L.T, z.T).T  # dx = L^-T z: V = |z|^2 = 1
    return np.vstack([fixed, random]), fixed.shape[0]


def sampled_search(failures: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]],
                   D: np.ndarray, scale: float, sampling: Sampling
                   ) -> tuple[float, float, str, list[int]]:
    """(lo, hi, limit, worst): the largest sampled radius lo with no failure at any sampled
    state r D_j, r <= lo (V = r^2 for rows D_j with V = 1), the smallest failing radius hi
    found (inf: none), what failed there ("dV/dt", "contact", "none found") and the index of
    the worst failing direction. ``failures(dx)``: (dV/dt not below 0, a gap not above the
    minimum, dV/dt) at the rows of dx. Shells doubling from 2^SHELL_LOW ``scale`` until one
    fails, a uniform grid of ``sampling.radii`` radii up to it, then bisections."""
    worst: list[int] = []

    def shell_fails(r: float) -> tuple[bool, str]:
        f_v, f_g, Vd = failures(r * D)
        bad = f_v | f_g
        if bad.any():
            # the failing direction with the largest dV/dt (contact first)
            score = np.where(f_g, np.inf, np.nan_to_num(Vd, nan=np.inf))
            worst[:] = [int(np.argmax(np.where(bad, score, -np.inf)))]
            return True, "contact" if f_g.any() and not f_v.any() else "dV/dt"
        return False, ""

    lo, hi, limit = 0.0, float("inf"), "none found"
    for k in range(SHELL_LOW, SHELL_HIGH + 1):
        r = scale * 2.0 ** k
        bad, why = shell_fails(r)
        if bad:
            hi, limit = r, why
            break
        lo = r
    if not np.isfinite(hi):
        return lo, hi, limit, worst
    top = hi
    for _ in range(3):  # a dense grid below the failing shell (below its first radius again
        grid = top * np.arange(1, sampling.radii + 1) / sampling.radii  # when that failed)
        lo, hit = 0.0, None
        for r in grid:
            bad, why = shell_fails(float(r))
            if bad:
                hit = (float(r), why)
                break
            lo = float(r)
        if hit is not None:
            hi, limit = hit
        if lo > 0:
            break
        top = float(grid[0])
    for _ in range(sampling.bisections):
        mid = 0.5 * (lo + hi)
        bad, why = shell_fails(mid)
        if bad:
            hi, limit = mid, why
        else:
            lo = mid
    return lo, hi, limit, worst


def speed_region(lib: SimulationLibrary, p: np.ndarray, op: OperatingPoint, controller: str,
                 min_gap: float, sampling: Sampling,
                 confirm: Confirm | None = None) -> SpeedRegion:
    """The region at ``op`` (module docstring); ``confirm(dxs, P)``: the status of a
    closed-loop run from each deviation (10 reduced states) and V's ratio end / start, None:
    no confirmation runs."""
    d0 = default_deviation()
    P = lyapunov_matrix(op, controller)
    if P is None:
        nan = np.full((len(REDUCED_INDEX),) * 2, np.nan)
        return SpeedRegion(op.speed, 0.0, 0.0, 0.0, "unstable", 0, nan, float("nan"))
    default_V = float(d0 @ P @ d0)
    D, _ = _directions(P, sampling)
    ev = Evaluator(lib, p, op, controller, P, sampling)

    # contact: computed (contact_level); dV/dt < 0: sampled, inside the contact-free set
    c_contact, touch = contact_level(lambda dx: ev.all_gaps(dx)[2], P, min_gap, sampling.seed)

    def failures(dx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        _, Vd, _ = ev(dx)
        f_v = ~(Vd < 0)
        return f_v, np.zeros_like(f_v), Vd

    lo, hi, limit, worst = sampled_search(failures, D, float(np.sqrt(default_V)), sampling)
    if c_contact <= lo**2:
        lo, hi, limit = float(np.sqrt(c_contact)), float(np.sqrt(c_contact)), "contact"
        if touch is not None and c_contact > 0:  # the contact state leads the boundary runs
            D = np.vstack([D, touch / np.sqrt(c_contact)])
            worst = [D.shape[0] - 1]
    sampled = lo**2
    level, confirmations, shrinks = sampled, [], 0
    rejected: list[Confirmation] = []
    if confirm is not None and sampled > 0 and sampling.confirm > 0:
        boundary = _boundary_directions(D, P, worst, sampling.confirm)
        for shrinks in range(CONFIRM_ROUNDS + 1):
            r = np.sqrt(level)
            done = confirm([r * d for _, d in boundary], P)  # one batch
            confirmations = [Confirmation(lbl, *c)
                             for (lbl, _), c in zip(boundary, done, strict=True)]
            if all(c.ok for c in confirmations) or shrinks == CONFIRM_ROUNDS:
                break
            rejected += [c for c in confirmations if not c.ok]
            level *= CONFIRM_SHRINK
        if not all(c.ok for c in confirmations):
            level = 0.0
    recovery: list[Recovery] = []
    if confirm is not None and sampling.confirm > 0:
        along = [("the default disturbance", d0, 1.0), ("the default disturbance reversed",
                                                        -d0, 1.0)]
        if worst and level > 0:
            w = np.sqrt(level) * D[worst[0]]  # on the boundary: multiples of the boundary
            along += [(f"the {limit}-limiting direction", w, 1.0),
                      (f"the {limit}-limiting direction reversed", -w, 1.0)]
        recovery = [Recovery(lbl, *recovery_bracket(confirm, d, P)) for lbl, d, _ in along]
    return SpeedRegion(op.speed, float(level), float(sampled),
                       float(hi**2), limit, ev.count, P, default_V, tuple(confirmations),
                       shrinks, tuple(rejected), D[worst[0]] if worst else None,
                       tuple(recovery))


#: recovery along a direction: multiples doubling from 1 up to RECOVERY_TOP, then bisections
RECOVERY_TOP, RECOVERY_BISECTIONS = 32.0, 5


def recovery_bracket(confirm: Confirm, d: np.ndarray, P: np.ndarray) -> tuple[float, float]:
    """(lo, hi): the runs of ``confirm`` (the firmware loop) recover from lo d and not from
    hi d (hi inf: recovered up to RECOVERY_TOP d; lo 0: not even from d), multiples doubling
    from 1, then RECOVERY_BISECTIONS bisections. A bracket of the first failure found along
    the ray, not a proof that every smaller multiple recovers."""
    def ok(m: float) -> bool:
        return Confirmation("", *confirm([m * d], P)[0]).ok

    lo, hi, m = 0.0, float("inf"), 1.0
    while m <= RECOVERY_TOP:
        if not ok(m):
            hi = m
            break
        lo, m = m, 2 * m
    if not np.isfinite(hi):
        return lo, hi
    for _ in range(RECOVERY_BISECTIONS):
        mid = 0.5 * (lo + hi)
        if ok(mid):
            lo = mid
        else:
            hi = mid
    return lo, hi


def _boundary_directions(D: np.ndarray, P: np.ndarray, worst: list[int],
                         n: int) -> list[tuple[str, np.ndarray]]:
    """The boundary runs' directions (V = 1), in order: the first failing sampled direction,
    the default disturbance, each axis alone (the weakest first), the default reversed, then
    random directions."""
    d0 = default_deviation()
    out = []
    if worst:
        out.append(("the first failing sampled direction", D[worst[0]]))
    out.append(("the default disturbance", d0 / np.sqrt(d0 @ P @ d0)))
    order = sorted(range(N_AXES), key=lambda i: 1.0 / (np.sqrt(P[i, i]) * d0[i]))
    for i in order:
        e = np.zeros(P.shape[0])
        e[i] = 1.0 / np.sqrt(P[i, i])
        out.append((f"{AXIS_NAMES[i]} alone", e))
    out.append(("the default disturbance reversed", -d0 / np.sqrt(d0 @ P @ d0)))
    n_fixed = 2 * (P.shape[0] + 1 + P.shape[0])
    for j in range(n_fixed, D.shape[0]):
        out.append((f"random direction {j - n_fixed}", D[j]))
    return out[:n]


def confirmation_run(lib: SimulationLibrary, p: np.ndarray, op: OperatingPoint,
                     controller: str, min_gap: float, loop: tuple) -> Confirm:
    """[(status, V(end) / V(start))] of hold runs from trim + each deviation (10 reduced
    states), the controller run as ``loop`` = (tick, speed gain, force budget) says
    (`simulate.run_loop`): the runs in one batch (`simulate.simulate_batch`: the firmware
    loop's runs, on the state or on the sensors, side by side in SIMD lanes, each the run
    `simulate` makes)."""
    tick, k_v, budget = loop

    def run(dxs: list[np.ndarray], P: np.ndarray) -> list[tuple[str, float]]:
        jobs = [(p, op, controller, {s: float(v) for s, v in zip(REDUCED_STATES, dx,
                                                                   strict=True)})
                for dx in dxs]
        trajs = simulate_batch(lib, jobs, CONFIRM_T_END, CONFIRM_DT, min_gap, tick=tick,
                               speed_gain=k_v, force_budget=budget, threads=1)
        out = []
        for dx, traj in zip(dxs, trajs, strict=True):
            end = traj.x[-1, list(REDUCED_INDEX)] - op.x_trim[list(REDUCED_INDEX)]
            out.append((traj.status, float(end @ P @ end / (dx @ P @ dx))))
        return out

    return run


def region_of_attraction(plant: Plant, controller: str,
                         speeds: Sequence[float] | np.ndarray,
                         sampling: Sampling = COMMAND_SAMPLING,
                         loop: Loop | None = Loop.FIRMWARE,
                         progress: Callable[[float], None] | None = None) -> Region:
    """The region of ``controller`` at ``speeds`` (module docstring), the boundary confirmed
    by runs of ``loop`` (a `Loop`; ``FIRMWARE``: the tick-held loop of [control.spec]; None:
    no runs)."""
    carriage, lib = plant.carriage, plant.lib
    min_gap = carriage.params.track.min_gap
    settings = None if loop is None else run_loop(plant, loop)
    out = []
    for i, op in enumerate(plant.points(speeds)):
        confirm = (None if settings is None else
                   confirmation_run(lib, carriage.p, op, controller, min_gap, settings))
        out.append(speed_region(lib, carriage.p, op, controller, min_gap, sampling, confirm))
        if progress is not None:
            progress((i + 1) / len(speeds))
    n_fixed = 2 * (2 * len(REDUCED_STATES) + 1)
    return Region(controller, tuple(out), sampling, "none" if loop is None else loop.value,
                  n_fixed)


def recovery_lines(region: Region) -> list[str]:
    """Per speed, how far the firmware loop recovers along the default disturbance (both
    signs, multiples of it) and along the limiting direction (both signs, multiples of the
    boundary): beside the set, which is not the limit of recovery."""
    out = [f"- {r.speed:.4g} m/s: " + "; ".join(x.text() for x in r.recovery)
           for r in region.regions if r.recovery]
    if not out:
        return []
    return [f"Recovery beyond the set ({region.loop} loop runs of {CONFIRM_T_END:g} s, "
            f"multiples doubling to {RECOVERY_TOP:g}, {RECOVERY_BISECTIONS} bisections; the "
            "default disturbance in multiples of itself, the limiting direction in multiples "
            "of the boundary):", *out]


def axis_rows(region: Region) -> list[list[str]]:
    """The markdown table's rows: speed, c, the extents (mm, mrad), the default multiple,
    what limits the level, the confirmation."""
    rows = []
    for r in region.regions:
        ext = r.extents
        rows.append([f"{r.speed:.4g}", f"{r.level:.4g}",
                     *(f"{ext[a] * AXIS_UNITS[a][1]:.3g}" for a in AXIS_NAMES),
                     f"{r.disturbance_multiple:.3g}", r.limit,
                     ("yes" if r.confirmed else "no") + (f" (c x {CONFIRM_SHRINK}^{r.shrinks})"
                                                         if r.shrinks else "")])
    return rows


def region_markdown(regions: Sequence[Region]) -> str:
    """roa.md: per controller the table of `axis_rows` and the statement."""
    head = ["speed [m/s]", "c", *(f"{a} [{AXIS_UNITS[a][0]}]" for a in AXIS_NAMES),
            "x default", "limited by", "boundary runs settle"]
    out = ["# Region of attraction (maglevgen roa)", "",
           "V = dx' P dx on the reduced states (y, z, phi, theta, psi, v, w, p, q, r); per "
           "speed the level c, each axis' largest deviation alone inside {V <= c}, and how "
           "many times the default disturbance (1 mm / 2 mrad on every axis) fits.", ""]
    for reg in regions:
        out += [f"## {reg.controller}", "", "| " + " | ".join(head) + " |",
                "|" + "---|" * len(head)]
        out += ["| " + " | ".join(row) + " |" for row in axis_rows(reg)]
        out += ["", reg.statement(), ""]
        rec = recovery_lines(reg)
        out += [*rec, ""] if rec else []
    return "\n".join(out)


def region_png(regions: Sequence[Region]) -> bytes:
    """roa_extent.png: each axis' extent against speed, one line per controller."""
    import matplotlib  # local: only when the figure is drawn

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(10, 5.6), sharex=True)
    for reg in regions:
        style = dict(registered(reg.controller).style)
        style.setdefault("marker", ".")
        v = reg.speeds
        for ax, a in zip(axes.flat, AXIS_NAMES, strict=False):
            unit, scale = AXIS_UNITS[a]
            ax.plot(v, [r.extents[a] * scale for r in reg.regions], label=reg.controller,
                    **style)
            ax.set_ylabel(f"extent of {a} / {unit}")
        axes.flat[5].plot(v, [r.disturbance_multiple for r in reg.regions],
                          label=reg.controller, **style)
    axes.flat[5].set_ylabel("multiple of the\ndefault disturbance")
    for ax in axes.flat:
        ax.grid(True, alpha=0.3)
        ax.set_ylim(bottom=0)
    for ax in axes[1]:
        ax.set_xlabel("speed $v$ / (m/s)")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle("Region of attraction: largest recoverable deviation per axis (sampled)",
                 fontsize=10)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, metadata={"Software": None})
    plt.close(fig)
    return buf.getvalue()


#: speeds of `maglevgen roa` and of the build's region (the build's at BUILD_SAMPLING)
DEFAULT_SPEEDS, BUILD_SPEEDS = 8, 4


def study(plant: Plant, controllers: Sequence[str],
          n_speeds: int = DEFAULT_SPEEDS, sampling: Sampling = COMMAND_SAMPLING,
          loop: Loop | None = Loop.FIRMWARE,
          progress: Callable[[float], None] | None = None) -> list[Region]:
    """The region of each of ``controllers`` at ``n_speeds`` speeds spanning the envelope."""
    if not isinstance(n_speeds, (int, np.integer)) or not 1 <= n_speeds <= MAX_SPEEDS:
        raise InputError(f"--speeds {n_speeds!r}: expected 1 to {MAX_SPEEDS} speeds")
    v_min, v_max = plant.speed_range
    speeds = np.linspace(v_min, v_max, n_speeds) if n_speeds > 1 else np.array([v_min])
    out = []
    for i, c in enumerate(controllers):
        def step(f: float, i: int = i) -> None:
            if progress is not None:
                progress((i + f) / len(controllers))

        out.append(region_of_attraction(plant, c, speeds, sampling, loop, step))
    return out


def study_json(regions: Sequence[Region]) -> dict:
    """What `maglevgen roa --json` prints and roa.json holds."""
    return {"lyapunov": "V = dx' P dx, A_cl' P + P A_cl = -(Q + K' R K) (the design's weights)",
            "units": {"extents": "m, rad", "level": "V"},
            "controllers": {r.controller: r.to_json() for r in regions}}


def study_files(regions: Sequence[Region]) -> dict[str, str | bytes]:
    """roa.json, roa.md and roa_extent.png."""
    return {"roa.json": json.dumps(study_json(regions), indent=1) + "\n",
            "roa.md": region_markdown(regions), "roa_extent.png": region_png(regions)}


def study_lines(regions: Sequence[Region], embedded: str) -> list[str]:
    """The command's text: per controller one line per speed, then the statement."""
    out = []
    for reg in regions:
        mark = " [embedded]" if reg.controller == embedded else ""
        out.append(f"Region of attraction of {reg.controller}{mark} (V = dx' P dx; extent of "
                   "each axis alone inside {V <= c}):")
        out.append(f"  {'speed':>8} {'c':>10} " + " ".join(
            f"{a + ' [' + AXIS_UNITS[a][0] + ']':>12}" for a in AXIS_NAMES)
            + f" {'x default':>10}  limited by / boundary runs")
        for r in reg.regions:
            ext = r.extents
            runs = sum(c.ok for c in r.confirmations)
            shrunk = f", c x {CONFIRM_SHRINK}^{r.shrinks}" if r.shrinks else ""
            out.append(f"  {r.speed:8.4g} {r.level:10.4g} " + " ".join(
                f"{ext[a] * AXIS_UNITS[a][1]:12.4g}" for a in AXIS_NAMES)
                + f" {r.disturbance_multiple:10.3g}  {r.limit}; {runs}/"
                f"{len(r.confirmations)} settle{shrunk}")
        out.append("  " + reg.statement())
        out += ["  " + x for x in recovery_lines(reg)]
    return out


def summary_lines(region: Region) -> list[str]:
    """SUMMARY.md's paragraph: per speed the level's extents and the default's multiple."""
    out = [f"Region of attraction of the embedded controller ({region.controller}; "
           "envelope/roa.md, envelope/roa_extent.png; `maglevgen roa` at full resolution), "
           "each axis' largest deviation alone inside {V <= c}:", "",
           "| speed [m/s] | " + " | ".join(f"{a} [{AXIS_UNITS[a][0]}]" for a in AXIS_NAMES)
           + " | multiple of the default disturbance | limited by | boundary runs settle |",
           "|" + " --- |" * (len(AXIS_NAMES) + 4)]
    for r in region.regions:
        ext = r.extents
        out.append(f"| {r.speed:.4g} | " + " | ".join(f"{ext[a] * AXIS_UNITS[a][1]:.3g}"
                                                      for a in AXIS_NAMES)
                   + f" | {r.disturbance_multiple:.3g} | {r.limit} | "
                   + ("yes" if r.confirmed and r.level > 0 else "NO")
                   + (f" (c shrunk {r.shrinks}x)" if r.shrinks else "") + " |")
    out += ["", region.statement()]
    rec = recovery_lines(region)
    return out + (["", *rec] if rec else [])
