"""Closed-loop simulations of the paper's figs 3-8, integrated by the generated C.

The carriage starts at its trim with a small disturbance on every controlled axis and runs
under the steady propulsion force that balances the drag at trim, with no control, the
optimized damping or the LQR. Trim, gains and the integration loop all run in the compiled
run-time-parameter library (maglevgen.library): Python only prepares the call and reads the
result. ``reference_trajectory`` integrates the same closed loop with scipy's adaptive DOP853
on the lambdified SymPy model, as an independent check.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .derive import conventions as cv
from .derive.conventions import Q_STATES
from .derive.structure import input_names_of
from .errors import InputError, NoTrimError
from .library import SimulationLibrary

CONTROLLERS: tuple[str, ...] = ("none", "damping", "lqr")
CONTROLLER_TITLES: dict[str, str] = {"none": "no control", "damping": "optimized damping",
                                     "lqr": "LQR"}
AXIS_STATES: tuple[int, ...] = tuple(cv.STATE_INDEX[s] for s in Q_STATES)

# The initial disturbance from trim (per axis): small against the gaps (15 mm upper, 30 mm
# lower) so the response stays in the linear range the controllers were designed for.
DISTURBANCE: dict[str, float] = {"y": 1e-3, "z": 1e-3, "phi": 2e-3, "theta": 2e-3,
                                 "psi": 2e-3}
DISTURBANCE_DOC = ("1 mm lateral (y), 1 mm heave up (z), 2 mrad roll, 2 mrad pitch, "
                   "2 mrad yaw from trim; body velocities at trim")

STATUS = {0: "completed", 1: "contact", 2: "non-finite state", 3: "generated code error"}
CHUNK_STEPS = 20_000  # steps per C call: the progress display updates between calls

Progress = Callable[[float], None]


@dataclass(frozen=True)
class OperatingPoint:
    """Trim and gains at one speed, all computed by the generated C."""

    speed: float
    x_trim: np.ndarray
    f_prop: float
    gaps: np.ndarray
    K: np.ndarray  # (5, 2) LQR position and rate gains per axis
    c_damping: np.ndarray  # (5,) optimized damping gains
    allocation: np.ndarray  # T (n_arrays_forces x 5)

    @property
    def a_trim(self) -> np.ndarray:
        return self.x_trim[list(AXIS_STATES)]

    def gains(self, controller: str) -> tuple[np.ndarray, np.ndarray]:
        """(k_pos, k_rate) of a controller."""
        zero = np.zeros(len(cv.AXES))
        if controller == "none":
            return zero, zero
        if controller == "damping":
            return zero, self.c_damping
        if controller == "lqr":
            return self.K[:, 0].copy(), self.K[:, 1].copy()
        raise InputError(f"controller {controller!r}: expected one of {CONTROLLERS}")


def checked_trim(lib: SimulationLibrary, p: np.ndarray, speed: float,
                 min_gap: float) -> tuple[np.ndarray, float, np.ndarray]:
    """(x_trim, F_prop, gaps): the Newton trim in C, checked against the dynamics and the
    track; NoTrimError when there is none."""
    x_trim, f_prop = lib.function("maglev_trim")(speed, p)
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


def operating_point(lib: SimulationLibrary, p: np.ndarray, speed: float,
                    min_gap: float) -> OperatingPoint:
    """Checked trim, gains and allocation matrix at ``speed``, all from the generated C."""
    x_trim, f_prop, gaps = checked_trim(lib, p, speed, min_gap)
    K, c = lib.function("maglev_lqr_gains")(speed, p)
    (T,) = lib.function("maglev_allocation_matrix")(p)
    return OperatingPoint(speed, x_trim, f_prop, gaps, K, c.ravel(), T)


def closed_loop_matrix(lib: SimulationLibrary, p: np.ndarray, op: OperatingPoint,
                       controller: str) -> np.ndarray:
    """A_cl of the closed loop linearised at trim (from the generated Jacobians)."""
    u = np.zeros(op.allocation.shape[0] + 1)
    u[0] = op.f_prop
    A, B = lib.function("maglev_jacobians")(op.x_trim, u, p)
    k_pos, k_rate = op.gains(controller)
    select = np.zeros((len(AXIS_STATES), A.shape[0]))
    select[range(len(AXIS_STATES)), AXIS_STATES] = 1.0
    d_ugen = -(np.diag(k_pos) @ select + np.diag(k_rate) @ (select @ A))
    return A + B[:, 1:] @ op.allocation @ d_ugen


def rk4_stability_limit(eigenvalues: np.ndarray) -> float:
    """Largest step for which RK4 keeps every mode with Re(lambda) <= 0 bounded.

    |R(h lambda)| <= 1 with R(z) = 1 + z + z^2/2 + z^3/6 + z^4/24; modes with a positive real
    part grow in the true solution too, so their real part is set to 0 (the oscillation is
    what limits the step). Bisection along each ray from the origin.
    """
    def amp(z: complex) -> float:
        return abs(1 + z + z**2 / 2 + z**3 / 6 + z**4 / 24)

    limit = np.inf
    for lam in eigenvalues:
        lam = complex(min(lam.real, 0.0), lam.imag)
        if abs(lam) < 1e-12:
            continue
        lo, hi = 0.0, 3.0 / abs(lam)  # the RK4 region lies within |z| < 2.8
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if amp(mid * lam) <= 1 + 1e-12 else (lo, mid)
        limit = min(limit, lo)
    return float(limit)


@dataclass
class Trajectory:
    """A closed-loop run: samples t, states x, inputs u and gaps, and how it ended."""

    controller: str
    op: OperatingPoint
    dt: float
    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    gaps: np.ndarray
    status: str
    event: str | None = None
    disturbance: dict[str, float] = field(default_factory=dict)

    equilibrium: np.ndarray | None = None  # (n, 5) trim axis positions at each sample's speed

    @property
    def axis_deviation(self) -> np.ndarray:
        """(n, 5) deviation of y, z, phi, theta, psi from the trim at the current speed.

        Under a steady propulsion force the speed drifts (the drag falls with speed above the
        Inductrack's characteristic speed, so the speed equilibrium is unstable), and the
        trim moves with it; deviations are measured from that moving equilibrium.
        """
        ref = self.op.a_trim if self.equilibrium is None else self.equilibrium
        return self.x[:, list(AXIS_STATES)] - ref

    @property
    def generalized_forces(self) -> np.ndarray:
        """(n, 5) u_gen produced by the array control forces: E F with E = (T^T T)^-1 T^T."""
        T = self.op.allocation
        E = np.linalg.solve(T.T @ T, T.T)
        return self.u[:, 1:] @ E.T


def initial_state(op: OperatingPoint, disturbance: dict[str, float]) -> np.ndarray:
    x0 = op.x_trim.copy()
    for name, value in disturbance.items():
        if name not in cv.STATE_INDEX:
            raise InputError(f"disturbance on unknown state {name!r}")
        x0[cv.STATE_INDEX[name]] += value
    return x0


def simulate(lib: SimulationLibrary, p: np.ndarray, op: OperatingPoint, controller: str,
             t_end: float, dt: float, min_gap: float,
             disturbance: dict[str, float] | None = None,
             progress: Progress | None = None) -> Trajectory:
    """Run one scenario in C: RK4 from the disturbed trim to ``t_end`` or contact."""
    if not (dt > 0 and t_end > 0 and np.isfinite(dt) and np.isfinite(t_end)):
        raise InputError(f"--dt {dt:g} and --t-end {t_end:g} must be positive")
    disturbance = DISTURBANCE if disturbance is None else disturbance
    n_steps = round(t_end / dt)
    if n_steps < 1:
        raise InputError(f"--t-end {t_end:g} s is shorter than one step of {dt:g} s")
    k_pos, k_rate = op.gains(controller)
    x0 = initial_state(op, disturbance)
    n_u, n_g = op.allocation.shape[0] + 1, op.gaps.size
    xs, us, gs = [], [], []
    done, status = 0, 0
    while True:
        chunk = min(CHUNK_STEPS, n_steps - done)
        last, status, x, u, g = lib.simulate(x0, dt, chunk, op.f_prop, k_pos, k_rate,
                                             op.a_trim, p, min_gap, n_u, n_g)
        final = status != 0 or done + chunk == n_steps
        keep = slice(None) if final else slice(None, -1)  # chunks share their end sample
        xs.append(x[keep]), us.append(u[keep]), gs.append(g[keep])
        done += last
        if progress is not None:
            progress(done / n_steps)
        if final:
            break
        x0 = x[-1]
    x, u, g = np.concatenate(xs), np.concatenate(us), np.concatenate(gs)
    t = np.arange(x.shape[0]) * dt
    event = None
    if status == 1:
        arrays = np.flatnonzero(g[-1] < min_gap) + 1
        event = (f"contact at t = {t[-1]:.4f} s: gap of array(s) "
                 f"{', '.join(map(str, arrays))} below track.min_gap = {min_gap:g} m")
    elif status != 0:
        event = f"{STATUS[status]} at t = {t[-1]:.4f} s"
    traj = Trajectory(controller, op, dt, t, x, u, g, STATUS[status], event, dict(disturbance))
    traj.equilibrium = moving_equilibrium(lib, p, op, x[:, cv.STATE_INDEX["u"]], min_gap)
    return traj


def moving_equilibrium(lib: SimulationLibrary, p: np.ndarray, op: OperatingPoint,
                       speeds: np.ndarray, min_gap: float, n_grid: int = 9) -> np.ndarray | None:
    """Trim axis positions at each speed, interpolated from trims on a grid over the range.

    None when the range reaches a speed without trim (then deviations use the initial trim).
    """
    lo, hi = float(np.min(speeds)), float(np.max(speeds))
    if not np.isfinite(lo + hi):
        return None
    if hi - lo < 1e-9 * max(1.0, abs(hi)):
        return np.tile(op.a_trim, (speeds.size, 1))
    grid = np.linspace(lo, hi, n_grid)
    try:
        trims = np.array([checked_trim(lib, p, v, min_gap)[0][list(AXIS_STATES)]
                          for v in grid])
    except NoTrimError:
        return None
    return np.column_stack([np.interp(speeds, grid, trims[:, i]) for i in range(trims.shape[1])])


def reference_trajectory(functions, p: np.ndarray, op: OperatingPoint, controller: str,
                         t_eval: np.ndarray, disturbance: dict[str, float] | None = None,
                         rtol: float = 1e-12, atol: float = 1e-13) -> np.ndarray:
    """The same closed loop by scipy DOP853 on the lambdified model (derive.numeric)."""
    from scipy.integrate import solve_ivp

    disturbance = DISTURBANCE if disturbance is None else disturbance
    k_pos, k_rate = op.gains(controller)
    idx = list(AXIS_STATES)
    u = np.zeros(op.allocation.shape[0] + 1)
    u[0] = op.f_prop

    def rhs(_t: float, x: np.ndarray) -> np.ndarray:
        rates = functions.kin(x).ravel()[idx]  # position rates do not depend on u
        u[1:] = op.allocation @ (-(k_pos * (x[idx] - op.a_trim) + k_rate * rates))
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


# ------------------------------------------------------------------------------- metrics

# Settled: within 5 % of the peak deviation for the rest of the run. (Not 2 %: under the steady
# propulsion force the carriage slowly accelerates, which tilts it quasi-statically by a few
# percent of the disturbance; that offset is not an oscillation left unsettled.)
SETTLING_BAND = 0.05


def settling_time(t: np.ndarray, dev: np.ndarray, band: float = SETTLING_BAND) -> float | None:
    """First time after which |dev| stays within ``band`` x its peak; None if it never does."""
    mag = np.abs(dev)
    peak = mag.max()
    if peak == 0:
        return 0.0
    outside = np.flatnonzero(mag > band * peak)
    if outside.size == 0:
        return 0.0
    if outside[-1] >= len(t) - 1:
        return None
    return float(t[outside[-1] + 1])


def metrics(traj: Trajectory) -> dict:
    """Per axis: settling time, peak deviation and RMS generalized control force."""
    dev = traj.axis_deviation
    ugen = traj.generalized_forces
    axes = {}
    for i, (axis, state, ctrl) in enumerate(zip(cv.AXES, Q_STATES, cv.CONTROLS, strict=True)):
        unit = cv.STATES[cv.STATE_INDEX[state]].unit
        axes[axis] = {
            "state": state, "unit": unit, "force_unit": ctrl.unit,
            "settling_time": settling_time(traj.t, dev[:, i]),
            "peak_deviation": float(np.max(np.abs(dev[:, i]))),
            "final_deviation": float(abs(dev[-1, i])),
            "rms_control": float(np.sqrt(np.mean(ugen[:, i] ** 2))),
        }
    return {
        "controller": traj.controller, "status": traj.status, "event": traj.event,
        "t_end": float(traj.t[-1]), "dt": traj.dt, "steps": int(traj.t.size - 1),
        "min_gap": float(np.min(traj.gaps)),
        "speed_start": float(traj.x[0, cv.STATE_INDEX["u"]]),
        "speed_end": float(traj.x[-1, cv.STATE_INDEX["u"]]),
        "rms_array_force": float(np.sqrt(np.mean(traj.u[:, 1:] ** 2))),
        "axes": axes,
    }


# ------------------------------------------------------------------------------- the job


@dataclass(frozen=True)
class SimulationRun:
    """The runs of `maglevgen simulate` and what they were computed with."""

    op: OperatingPoint
    trajectories: tuple[Trajectory, ...]
    dt_limit: float
    input_names: tuple[str, ...]
    fastest_growth: float  # largest real part of the closed-loop poles [1/s] (the speed mode)

    def header(self, params_sha256: str) -> dict:
        """What metrics.json states about the runs besides the per-run metrics."""
        return {"params_sha256": params_sha256, "speed": self.op.speed,
                "propulsion_force": self.op.f_prop, "rk4_stability_limit": self.dt_limit,
                "fastest_closed_loop_growth": self.fastest_growth}


def run_scenarios(carriage, controllers: tuple[str, ...], t_end: float, dt: float,
                  speed: float | None = None, lib: SimulationLibrary | None = None,
                  announce: Callable[[str], None] | None = None,
                  bar: Callable[[str], object] | None = None) -> SimulationRun:
    """Trim, gains and one closed-loop run per controller, all in the generated C.

    Refuses a step above RK4's stability limit for the stiffest closed-loop mode.
    """
    from .library import simulation_library

    for c in controllers:
        if c not in CONTROLLERS:
            raise InputError(f"controller {c!r}: expected one of {CONTROLLERS}")
    lib = lib or simulation_library(carriage.structure, progress=announce or (lambda _: None))
    v = carriage.params.operation.speed if speed is None else speed
    min_gap = carriage.params.track.min_gap
    op = operating_point(lib, carriage.p, v, min_gap)
    eig = {c: np.linalg.eigvals(closed_loop_matrix(lib, carriage.p, op, c))
           for c in controllers}
    limits = {c: rk4_stability_limit(e) for c, e in eig.items()}
    worst = min(limits, key=limits.get)
    if dt > limits[worst]:
        raise InputError(f"--dt {dt:g} s exceeds the RK4 stability limit {limits[worst]:.4g} s "
                         f"of the stiffest closed-loop mode ({worst} controller)")
    trajs = []
    for c in controllers:
        if bar is None:
            trajs.append(simulate(lib, carriage.p, op, c, t_end, dt, min_gap))
            continue
        with bar(f"simulating {CONTROLLER_TITLES[c]}") as update:
            trajs.append(simulate(lib, carriage.p, op, c, t_end, dt, min_gap, progress=update))
    growth = max(float(np.max(e.real)) for e in eig.values())
    return SimulationRun(op, tuple(trajs), limits[worst], input_names_of(carriage.structure),
                         growth)
