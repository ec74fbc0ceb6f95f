"""Closed-loop simulations of the paper's figs 3-8, integrated by the generated C.

The carriage starts at its trim with a small disturbance on every controlled axis and runs
under the steady propulsion force that balances the drag at trim, with no control, the
optimized damping or the LQR. Trim, gains and the integration loop all run in the compiled
run-time-parameter library (the `Plant`'s): Python only prepares the call and reads the
result. `maglevgen.analyses.reference` integrates the same closed loop with scipy's adaptive
DOP853 on the lambdified SymPy model, as an independent check.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass, field, replace
from functools import cached_property, partial
from typing import TYPE_CHECKING, Any

import numpy as np

from maglevgen.analyses.run_spec import RunSpec, RunVerdict, judge_run
from maglevgen.analyses.sim_loop import (
    LoopSetting,
    SensedTick,
    control_loop,
    firmware_gains,
    run_loop,
    sensed_metrics,
    sensing,
    speed_loop_gain,
)
from maglevgen.control.built_loop import Loop, flown_controllers
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.operating import (
    AXIS_STATES,
    STABILITY_MARGIN,
    OperatingPoint,
    SpeedMode,
    Weights,
    checked_accelerating_trim,
    checked_trim,
    closed_loop_stability,
    operating_point,
    speed_mode,
)
from maglevgen.control.sampled import Tick
from maglevgen.control.schedule import A_REF, K_POS, Schedule
from maglevgen.controllers import names as controller_names
from maglevgen.controllers import title as controller_title
from maglevgen.derive import conventions as cv
from maglevgen.derive.conventions import DISTURBANCE, Q_STATES
from maglevgen.derive.structure import input_names_of
from maglevgen.errors import InputError, NoTrimError
from maglevgen.runtime.runs import BatchBuffers, BatchRun, Run
from maglevgen.runtime.sense import Sensing

if TYPE_CHECKING:  # the library comes from the Plant; only its type is named here
    from maglevgen.runtime.library import SimulationLibrary

__all__ = ["AXIS_STATES", "DISTURBANCE", "DISTURBANCE_DOC", "FINAL_SHARE", "RUN_STATUSES",
           "SETTLING_BAND", "LoopSetting", "SimulationRun", "Tick", "Trajectory", "Weights",
           "control_loop", "disturbance_doc", "firmware_gains", "hold_run", "hold_trajectory",
           "initial_state", "launch", "metrics", "operating_point", "rk4_stability_limit",
           "run_loop", "run_scenarios", "run_summary", "settling_time", "simulate",
           "simulate_batch", "spec_verdict", "speed_loop_gain"]

# DISTURBANCE (derive.conventions) in words
DISTURBANCE_DOC = ("1 mm lateral (y), 1 mm heave up (z), 2 mrad roll, 2 mrad pitch, "
                   "2 mrad yaw from trim; body velocities at trim")



def disturbance_doc(disturbance: dict[str, float]) -> str:
    """DISTURBANCE_DOC for the default disturbance, else the values (--disturbance)."""
    if disturbance == DISTURBANCE:
        return DISTURBANCE_DOC
    return ", ".join(f"{k} {v:+.6g}" for k, v in disturbance.items()) + " from trim"


SCENARIOS: tuple[str, ...] = ("hold", "launch")
# what maglev_simulate / maglev_launch report (MAGLEV_SIM_*); a run that took every step gets
# its status from its trajectory (run_status)
C_STATUS = {1: "contact", 2: "diverging", 3: "generated code error"}
# every status of a run (maglevgen.analyses.montecarlo's samples add theirs)
RUN_STATUSES: tuple[str, ...] = ("settled", "not settled", "diverging", "contact",
                                 "generated code error")
# the axis states' columns of x: a slice (a view, no gather)
_AXIS_COLUMNS = cv.AXIS_COORDINATES
CHUNK_STEPS = 20_000  # steps per C call: the progress display updates between calls

Progress = Callable[[int], None]


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
    c_status: int  # MAGLEV_SIM_* of the C loop
    event: str | None = None
    disturbance: dict[str, float] = field(default_factory=dict)
    scenario: str = "hold"
    equilibrium: np.ndarray | None = None  # (n, 5) trim axis positions at each sample's speed
    input_names: tuple[str, ...] = ()  # F_prop, F_<axis><array>...: groups u by array
    speed_reference: np.ndarray | None = None  # (n,) v_ref of the speed loop [m/s]
    saturated_time: float = 0.0  # [s] steps run with an array's control force at its budget
    tick: Tick | None = None  # None: the controller at every RK4 stage
    speed_gain: float = 0.0  # k_v of the speed loop [N s/m]
    force_budget: float | None = None  # [N] per array, None: no limit
    run_spec: RunSpec | None = None  # the limits the run is judged against (`spec_verdict`)
    sensing: Sensing | None = None  # a run on the sensors: its readings and predictions

    @property
    def speed_error(self) -> float | None:
        """max |V - v_ref| / v_ref after the first second (None for a run not longer)."""
        return _speed_error(self, self.speed)

    @cached_property
    def speed(self) -> np.ndarray:
        """|(u, v, w)| at each sample: the speed the schedule is evaluated at [m/s].

        Computed once (x is not reassigned), as sqrt((u^2 + v^2) + w^2): np.linalg.norm's
        operations in its order, without its passes over a strided (n, 3) view."""
        u, v, w = (self.x[:, cv.STATE_INDEX[s]] for s in cv.STATE_NAMES[cv.VELOCITY])
        return np.sqrt(u * u + v * v + w * w)

    @property
    def axis_deviation(self) -> np.ndarray:
        """(n, 5) deviation of y, z, phi, theta, psi from the trim at the current speed.

        The speed changes during a run (the launch accelerates; under the trim propulsion of
        the hold scenario the speed mode drifts slowly, see `SpeedMode`) and
        the trim moves with it; deviations are measured from that moving equilibrium.
        """
        ref = self.op.a_trim if self.equilibrium is None else self.equilibrium
        return self.x[:, _AXIS_COLUMNS] - ref

    @property
    def generalized_forces(self) -> np.ndarray:
        """(n, 5) u_gen produced by the array control forces: E F with E = pinv(T) (T = E's
        pseudoinverse, of rank 4 with the paper's geometry's normal actuators)."""
        return self.u[:, cv.ARRAY_INPUTS] @ np.linalg.pinv(self.op.allocation).T

    @property
    def array_forces(self) -> dict[str, np.ndarray]:
        """(n,) magnitude of each array's control force [N]: |(F_y, F_z)| of eqs 22-23's
        components, |F_n| along the normal; by array name (empty without input_names)."""
        groups: dict[str, list[int]] = {}
        for j, name in enumerate(self.input_names[1:], start=1):
            groups.setdefault(name[3:], []).append(j)  # F_<axis><array>
        return {a: np.linalg.norm(self.u[:, cols], axis=1) for a, cols in groups.items()}

    @property
    def growth_rate(self) -> float | None:
        """ln(peak |deviation| of the last quarter / of the first quarter) per second, over the
        axis that grows most (each axis relative to its own peak); None for a short run."""
        return _growth_rate(self.t, self.axis_deviation)

    @property
    def status(self) -> str:
        """settled, not settled, diverging, contact (or generated code error): `run_status`."""
        return run_status(self)


def spec_verdict(traj: Trajectory) -> RunVerdict | None:
    """The run against its ``run_spec`` (`maglevgen.analyses.run_spec`); None without one."""
    if traj.run_spec is None:
        return None
    dev = traj.axis_deviation
    return judge_run(traj.run_spec, settling_times(traj.t, dev),
                     np.max(np.abs(dev), axis=0), float(np.min(traj.gaps)), traj.speed_error,
                     bool(traj.speed_gain), traj.saturated_time, traj.force_budget,
                     np.abs(dev[0]), float(np.min(traj.gaps[0])))


def run_status(traj: Trajectory) -> str:
    """What a run did: ``contact`` (a gap reached track.min_gap), ``diverging`` (a state
    became non-finite, or the deviation's peak grew from the first quarter of the run to the
    last, beyond GROWTH_FLOOR, where the linearised closed loop is not stable), ``settled``
    (every axis within SETTLING_BAND of its largest excursion from its final value, or within
    its GROWTH_FLOOR of it where that is larger, for the rest of the run: `settling_time`) or
    ``not settled``.

    A hold run whose linearised closed loop at its trim is stable is not called diverging for
    a growing peak: over a run short against the slowest mode (about 15 s for the LQRs), the
    axes the disturbance excites through the coupling peak after the first quarter, a
    transient that decays (it is ``not settled``). A launch crosses speeds with other gains,
    so its growth counts as is."""
    if traj.c_status in C_STATUS:
        return C_STATUS[traj.c_status]
    dev = traj.axis_deviation
    return _status(traj, _growth_rate(traj.t, dev),
                   lambda: settling_times(traj.t, dev))


def _status(traj: Trajectory, growth: float | None,
            settling: Callable[[], list[float | None]]) -> str:
    """`run_status` of a run the C finished, from its growth rate and (only asked for when
    the run is not diverging) its axes' settling times: `metrics` passes what it computes
    anyway, so each is computed once per run."""
    if growth is not None and growth > 0 and not linearly_stable_hold(traj):
        return "diverging"
    if all(st is not None for st in settling()):
        return "settled"
    return "not settled"


def _growth_rate(t: np.ndarray, deviation: np.ndarray) -> float | None:
    """`Trajectory.growth_rate` of the axis deviations ``deviation`` sampled at ``t``: the
    fastest growth of an axis's peak from the first quarter to the last, over the axes whose
    last peak is above GROWTH_FLOOR (0 when none is: a run that stays that close to its trim
    does not diverge, whatever its noise floor does; an undisturbed run on the sensors starts
    at zero and ends at the noise's peak)."""
    n = t.size // 4
    if n < 2:
        return None
    dev = np.abs(deviation)
    first, last = dev[:n].max(axis=0), dev[-n:].max(axis=0)
    ok = (first > 0) & (last > GROWTH_FLOOR)
    if not np.any(ok):
        return 0.0
    span = t[-n:].mean() - t[:n].mean()
    with np.errstate(divide="ignore"):
        return float(np.max(np.log(np.maximum(last[ok], 1e-300) / first[ok])) / span)


def _speed_error(traj: Trajectory, speed: np.ndarray) -> float | None:
    """`Trajectory.speed_error` with the run's ``speed`` (`Trajectory.speed`) given."""
    ref = traj.speed_reference
    if ref is None:
        ref = np.full(traj.t.size, traj.op.speed)
    late = traj.t > 1.0
    if not np.any(late):
        return None
    return float(np.max(np.abs(speed[late] - ref[late]) / ref[late]))


def linearly_stable_hold(traj: Trajectory) -> bool:
    """Whether ``traj`` holds one speed with gains whose linearised closed loop is stable,
    as the envelope calls it (`closed_loop_stability` below -STABILITY_MARGIN)."""
    return (traj.scenario == "hold"
            and closed_loop_stability(traj.op, traj.controller)[0] < -STABILITY_MARGIN)


def initial_state(op: OperatingPoint, disturbance: dict[str, float],
                  x_start: np.ndarray | None = None) -> np.ndarray:
    """``x_start`` (default the trim of ``op``) plus the disturbance."""
    x0 = (op.x_trim if x_start is None else np.asarray(x_start, dtype=float)).copy()
    for name, value in disturbance.items():
        if name not in cv.STATE_INDEX:
            raise InputError(f"disturbance on unknown state {name!r}")
        x0[cv.STATE_INDEX[name]] += value
    return x0


def _check_steps(t_end: float, dt: float) -> int:
    if not (dt > 0 and t_end > 0 and np.isfinite(dt) and np.isfinite(t_end)):
        raise InputError(f"--dt {dt:g} and --t-end {t_end:g} must be positive")
    n_steps = round(t_end / dt)
    if n_steps < 1:
        raise InputError(f"--t-end {t_end:g} s is shorter than one step of {dt:g} s")
    return n_steps


def _contact_event(t: np.ndarray, g: np.ndarray, speed: float, min_gap: float,
                   c_status: int) -> str | None:
    if c_status == 1:
        arrays = np.flatnonzero(g[-1] < min_gap) + 1
        return (f"contact at t = {t[-1]:.4f} s, {speed:.3f} m/s: gap of array(s) "
                f"{', '.join(map(str, arrays))} below track.min_gap = {min_gap:g} m")
    if c_status == 2:
        return f"non-finite state at t = {t[-1]:.4f} s"
    if c_status != 0:
        return f"{C_STATUS.get(c_status, 'error')} at t = {t[-1]:.4f} s"
    return None


def simulate(lib: SimulationLibrary, p: np.ndarray, op: OperatingPoint, controller: str,
             t_end: float, dt: float, min_gap: float,
             disturbance: dict[str, float] | None = None,
             progress: Progress | None = None, tick: Tick | None = None,
             speed_gain: float = 0.0, force_budget: float | None = None,
             controller_op: OperatingPoint | None = None) -> Trajectory:
    """The hold scenario in C: RK4 from the disturbed trim to ``t_end`` or contact, the
    propulsion at the trim drag and the gains fixed at the trim speed's.

    ``controller_op``: the operating point the controller was designed at, when it is not
    the plant's ``op`` (the firmware's nominal design flying a carriage whose parameters
    ``p`` differ from the nominal: `maglevgen montecarlo`): its gains, its reference and its
    feed-forward propulsion; the run still starts from ``op``'s trim plus the disturbance,
    and is measured against ``p``'s own trim.

    ``tick``: the controller runs at the tick with its delay, the command held between ticks
    (None: at every RK4 stage); ``speed_gain``: k_v of the speed loop F_prop = F_trim +
    k_v (v_trim - V) (`speed_loop_gain`; 0: the propulsion held at the trim drag);
    ``force_budget``: each array's control force limited to it [N] (None: no limit). The
    defaults give the loop of maglev_simulate without a maglev_control_loop.
    """
    n_steps = _check_steps(t_end, dt)
    disturbance = DISTURBANCE if disturbance is None else disturbance
    first = hold_run(p, op, controller, dt, disturbance, tick, speed_gain, force_budget,
                     controller_op, n_steps)
    n_u, n_g = op.allocation.shape[0] + 1, op.gaps.size
    xs, us, gs = [], [], []
    done, status, saturated = 0, 0, 0
    # a ticked run in one call: its command pipeline does not survive a chunk's end
    loop = first.loop
    chunk_steps = CHUNK_STEPS if loop is None or loop.tick_steps == 0 else n_steps
    x0 = first.x0
    while True:
        chunk = min(chunk_steps, n_steps - done)
        run = lib.simulate(x0, dt, chunk, first.f_prop, first.k_pos, first.k_rate, first.a_ref,
                           p, min_gap, n_u, n_g, loop)
        status, x, u, g = run.status, run.x, run.u, run.gaps
        saturated += run.saturated_steps
        final = status != 0 or done + chunk == n_steps
        keep = slice(None) if final else slice(None, -1)  # chunks share their end sample
        xs.append(x[keep])
        us.append(u[keep])
        gs.append(g[keep])
        done += run.last
        if progress is not None:
            progress(done / n_steps)
        if final:
            break
        x0 = x[-1]
    whole = Run(done, status, np.concatenate(xs), np.concatenate(us), np.concatenate(gs),
                saturated)
    traj = hold_trajectory(lib, p, op, controller, dt, min_gap, disturbance, whole, tick,
                           speed_gain, force_budget)
    traj.sensing = None if loop is None else loop.sense
    return traj


def hold_run(p: np.ndarray, op: OperatingPoint, controller: str, dt: float,
             disturbance: dict[str, float], tick: Tick | None = None, speed_gain: float = 0.0,
             force_budget: float | None = None, controller_op: OperatingPoint | None = None,
             n_steps: int = 0, record: bool = True,
             noise_memory: Callable[[tuple[int, int]], np.ndarray] | None = None) -> BatchRun:
    """maglev_simulate's inputs for `simulate`'s run of ``n_steps`` steps (the disturbed trim
    of ``op``, the trim drag, the gains and the reference of ``controller_op`` (default
    ``op``), p and the loop; at a `SensedTick` its sensors and noise (readings, predictions
    kept when ``record``; the noise in ``noise_memory``'s array: `sim_loop.sensing`) and zero
    gains (the firmware's tables fly): `simulate_batch`'s."""
    design = op if controller_op is None else controller_op
    if isinstance(tick, SensedTick):  # no gain designed: maglev_simulate reads none here
        sense = sensing(tick, n_steps // tick.steps(dt) + 1, record, op.B.shape[1],
                        noise_memory)
        loop = control_loop(dt, tick, speed_gain, force_budget, design.speed, sense=sense)
        K_pos = K_rate = np.zeros(25)
    elif isinstance(tick, LoopSetting):
        gains = firmware_gains(design, controller, tick)
        loop = control_loop(dt, tick, speed_gain, force_budget, design.speed, design=gains)
        K_pos, K_rate = (k.ravel(order="F") for k in (gains.K_pos, gains.K_rate))
    else:
        loop = control_loop(dt, tick, speed_gain, force_budget, design.speed)
        K_pos, K_rate = (k.ravel(order="F") for k in design.gains(controller))
    return BatchRun(initial_state(op, disturbance), float(design.f_prop), K_pos, K_rate,
                    design.a_trim, p, loop)


def hold_trajectory(lib: SimulationLibrary, p: np.ndarray, op: OperatingPoint,
                    controller: str, dt: float, min_gap: float,
                    disturbance: dict[str, float], run: Run, tick: Tick | None = None,
                    speed_gain: float = 0.0, force_budget: float | None = None) -> Trajectory:
    """`simulate`'s Trajectory of the hold run ``run`` (its x, u and gap rows from sample 0):
    its event and the moving equilibrium it is measured against."""
    x, u, g = run.x, run.u, run.gaps
    t = np.arange(x.shape[0]) * dt
    traj = Trajectory(controller, op, dt, t, x, u, g, run.status, None, dict(disturbance),
                      speed_reference=np.full(t.size, op.speed),
                      saturated_time=run.saturated_steps * dt,
                      tick=tick, speed_gain=float(speed_gain), force_budget=force_budget)
    speed = traj.speed  # once: a norm over every sample
    traj.event = _contact_event(t, g, float(speed[-1]), min_gap, run.status)
    traj.equilibrium = moving_equilibrium(lib, p, op, speed, min_gap)
    return traj


def simulate_batch(lib: SimulationLibrary, jobs: list[tuple],
                   t_end: float, dt: float, min_gap: float, tick: Tick | None = None,
                   speed_gain: float = 0.0, force_budget: float | None = None,
                   threads: int = 0, seeds: Sequence[int] | None = None,
                   lanes: int | None = 0, ticks: Sequence[Tick | None] | None = None,
                   buffers: BatchBuffers | None = None) -> list[Trajectory]:
    """`simulate` of each job (p, op, controller, disturbance[, controller_op]), the runs in
    one call of the C batch driver on ``threads`` threads (0: every core): the same
    trajectories, in order. At a `SensedTick` each run draws its own noise: from ``seeds``
    (one per job), else the tick's seed plus the job's place; ``ticks`` (one per job, the
    same loop each: a Monte-Carlo sample's own noise and sensors) in place of both. ``lanes``:
    `SimulationLibrary.simulate_batch`'s (default 0: the tick-held runs W at a time in SIMD
    lanes where the CPU and the batch allow, the same numbers; None: one maglev_simulate
    per run). ``buffers`` (`BatchBuffers`): the trajectories' rows written into them, good
    until the next call with the same buffers, and so are the runs' noise arrays
    (`BatchBuffers.noise`)."""
    n_steps = _check_steps(t_end, dt)
    if not jobs:
        return []
    seeds = seeds if seeds is not None else [
        (tick.seed if isinstance(tick, SensedTick) else 0) + i for i in range(len(jobs))]
    ticks = ticks if ticks is not None else [
        replace(tick, seed=int(s)) if isinstance(tick, SensedTick) else tick for s in seeds]
    runs = [hold_run(p, op, c, dt, d, tk, speed_gain, force_budget,
                     design[0] if design else None, n_steps=n_steps, record=False,
                     noise_memory=None if buffers is None else partial(buffers.noise, j))
            for j, ((p, op, c, d, *design), tk) in enumerate(zip(jobs, ticks, strict=True))]
    op0 = jobs[0][1]
    done = lib.simulate_batch(runs, dt, n_steps, min_gap, op0.allocation.shape[0] + 1,
                              op0.gaps.size, threads, lanes, buffers=buffers)
    out = [hold_trajectory(lib, p, op, c, dt, min_gap, d, run, tk, speed_gain, force_budget)
           for (p, op, c, d, *_), run, tk in zip(jobs, done, ticks, strict=True)]
    for traj, r in zip(out, runs, strict=True):
        traj.sensing = None if r.loop is None else r.loop.sense
    return out


def launch(lib: SimulationLibrary, p: np.ndarray, schedule: Schedule, op: OperatingPoint,
           v_end: float, accel_force: float, dt: float, min_gap: float,
           max_time: float, hold_steps: int = 1,
           disturbance: dict[str, float] | None = None,
           x_start: np.ndarray | None = None, tick: Tick | None = None,
           speed_gain: float = 0.0, force_budget: float | None = None,
           accel: float = 0.0) -> Trajectory:
    """The launch run in C (`maglev_launch`): from the disturbed trim at the schedule's first
    speed the carriage accelerates under F_drag(v) + ``accel_force`` until ``v_end``, the
    controller's gains, reference and the drag following ``schedule`` at the measured speed
    (every ``hold_steps`` steps, held between; 0: at every RK4 stage); ``max_time`` bounds
    the run. ``x_start``: the state the disturbance is added to (default op's trim; the
    accelerating trim for a schedule at an acceleration, `run_scenarios`).

    ``tick``, ``speed_gain``, ``force_budget`` as in `simulate` (with a tick the schedule is
    evaluated at each tick, ``hold_steps`` unused); the speed loop tracks v_ref(t) =
    v0 + ``accel`` t up to ``v_end`` (v0 the schedule's first speed, ``accel`` [m/s^2] the
    commanded acceleration, of which ``accel_force`` = m ``accel`` is the feedforward).
    """
    disturbance = DISTURBANCE if disturbance is None else disturbance
    if not accel_force >= 0:  # 0: the propulsion follows the trim drag (the speed is held)
        raise InputError(f"launch thrust {accel_force:g} N must not be negative")
    if not (np.isfinite(accel) and accel >= 0):
        raise InputError(f"launch acceleration {accel!r} m/s^2: must be a finite number >= 0")
    if speed_gain and accel_force > 0 and accel == 0:
        raise InputError("launch with a speed loop: the commanded acceleration (the speed "
                         "reference's slope) is 0 while the thrust accelerates")
    n_steps = _check_steps(max_time, dt)
    sense = (sensing(tick, n_steps // tick.steps(dt) + 1, True, op.B.shape[1])
             if isinstance(tick, SensedTick) else None)
    loop = control_loop(dt, tick, speed_gain, force_budget, op.speed, accel, sense=sense)
    x0 = initial_state(op, disturbance, x_start)
    # on the sensors the firmware's tick adds the acceleration's feedforward itself (a_ref)
    f_extra = 0.0 if sense is not None else accel_force
    run = lib.launch(x0, dt, n_steps, v_end, f_extra, hold_steps, schedule, p, min_gap,
                     op.allocation.shape[0] + 1, op.gaps.size, loop)
    status, x, u, g = run.status, run.x, run.u, run.gaps
    t = np.arange(x.shape[0]) * dt
    traj = Trajectory(schedule.controller, op, dt, t, x, u, g, status, None,
                      dict(disturbance), scenario="launch",
                      speed_reference=np.minimum(op.speed + accel * t, v_end),
                      saturated_time=run.saturated_steps * dt, tick=tick,
                      speed_gain=float(speed_gain), force_budget=force_budget, sensing=sense)
    traj.event = _contact_event(t, g, float(traj.speed[-1]), min_gap, status)
    # deviations from the scheduled reference (the trim at each sample's speed; the
    # accelerating trim for a schedule at the launch's acceleration)
    traj.equilibrium = schedule.at(traj.speed)[:, A_REF:K_POS]  # Schedule.unpack's a_ref
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


# ------------------------------------------------------------------------------- metrics

# Settled: within 5 % of the largest excursion from the final value for the rest of the run.
# (Not 2 %: under the steady propulsion force the carriage slowly accelerates, which tilts it
# quasi-statically by a few percent of the disturbance; that drift is not an oscillation left
# unsettled.)
SETTLING_BAND = 0.05
#: the share of a run at its end whose mean is a deviation's final value (`settling_time`)
FINAL_SHARE = 0.1
#: each axis's deviation floor: SETTLING_BAND of the default disturbance (50 um, 0.1 mrad).
#: Within it of its final value a deviation is settled whatever its excursion (on the sensors
#: the noise keeps every axis jittering, 4-7 um and 40-85 urad with the default [sensors],
#: more than 5 % of a small disturbance); one whose peak stays below it is not growth.
GROWTH_FLOOR = SETTLING_BAND * np.array([DISTURBANCE[k] for k in Q_STATES])


def settling_time(t: np.ndarray, dev: np.ndarray, band: float = SETTLING_BAND,
                  floor: float = 0.0) -> float | None:
    """The settling time about the final value: the first time after which ``dev`` stays
    within ``band`` x its largest excursion from its final value (`final_value`), or within
    ``floor`` of it where that is larger; None if it never does, or does only within the
    window its final value is the mean of (too late to tell). A steady offset from the trim
    (a sampled carriage flying the nominal design) is the final deviation, not unsettled."""
    tail = _final_window(len(dev))
    mag = np.abs(dev - np.mean(dev[-tail:]))
    peak = mag.max()
    if peak == 0:
        return 0.0
    outside = np.flatnonzero(mag > max(band * peak, floor))
    if outside.size == 0:
        return 0.0
    if outside[-1] >= len(t) - tail:
        return None
    return float(t[outside[-1] + 1])


def _final_window(n: int) -> int:
    """The samples of a run of ``n`` whose mean is its final value: its last FINAL_SHARE."""
    return max(1, round(FINAL_SHARE * n))


def final_value(dev: np.ndarray) -> np.ndarray:
    """A deviation's final value (per column): its mean over the run's last FINAL_SHARE."""
    return np.mean(dev[-_final_window(len(dev)):], axis=0)


def settling_times(t: np.ndarray, dev: np.ndarray) -> list[float | None]:
    """`settling_time` of each axis of ``dev`` ((n, 5): y, z, phi, theta, psi from the trim),
    about its final value within SETTLING_BAND of its largest excursion or its GROWTH_FLOOR,
    whichever is larger."""
    return [settling_time(t, dev[:, i], floor=float(GROWTH_FLOOR[i]))
            for i in range(dev.shape[1])]


def run_summary(traj: Trajectory) -> dict:
    """What a run did, for a table of many runs (a Monte-Carlo sample's row): its status and
    event, growth rate, gaps and speeds, the speed error after the first second
    (`Trajectory.speed_error`), the time with an array at its force budget, and per axis
    its settling time, peak and final deviation. `metrics` is this and the rest."""
    # each derived series computed once (the properties would recompute them per use)
    dev = traj.axis_deviation
    speed = traj.speed
    growth = _growth_rate(traj.t, dev)
    settling, finals = settling_times(traj.t, dev), final_value(dev)
    status = (C_STATUS[traj.c_status] if traj.c_status in C_STATUS
              else _status(traj, growth, lambda: settling))
    axes = {}
    for i, (axis, state, ctrl) in enumerate(zip(cv.AXES, Q_STATES, cv.CONTROLS, strict=True)):
        axes[axis] = {
            "state": state, "unit": cv.STATES[cv.STATE_INDEX[state]].unit,
            "force_unit": ctrl.unit, "settling_time": settling[i],
            "peak_deviation": float(np.max(np.abs(dev[:, i]))),
            "final_deviation": float(abs(finals[i])),
        }
    return {
        "controller": traj.controller, "scenario": traj.scenario, "status": status,
        "event": traj.event, "growth_rate": growth,
        "t_end": float(traj.t[-1]), "dt": traj.dt, "steps": int(traj.t.size - 1),
        "min_gap": float(np.min(traj.gaps)),
        "speed_start": float(speed[0]), "speed_end": float(speed[-1]),
        "speed_at_contact": float(speed[-1]) if status == "contact" else None,
        "speed_error": _speed_error(traj, speed), "saturated_time": traj.saturated_time,
        "axes": axes,
    }


def metrics(traj: Trajectory) -> dict:
    """`run_summary` and, per axis, the RMS generalized control force; for the run, the
    array forces' RMS and peaks, how the controller ran, the run against its spec and, on
    the sensors, `sensed_metrics` (the keys in that order among the summary's)."""
    m = run_summary(traj)
    ugen = traj.generalized_forces
    for i, ax in enumerate(m["axes"].values()):
        ax["rms_control"] = float(np.sqrt(np.mean(ugen[:, i] ** 2)))
    tick = traj.tick
    later = ("speed_error", "saturated_time", "axes")  # metrics.json: after the forces
    return {**{k: v for k, v in m.items() if k not in later},
            "rms_array_force": float(np.sqrt(np.mean(traj.u[:, cv.ARRAY_INPUTS] ** 2))),
            "peak_array_force": {a: float(np.max(f)) for a, f in traj.array_forces.items()},
            "speed_error": m["speed_error"], "saturated_time": m["saturated_time"],
            # how the controller ran: its tick (None: at every RK4 stage), the speed loop,
            # the budget; the plant's lag, k_i [N/m] and the clamp of |k_i xi| [N] (None: no
            # integral)
            "tick": None if tick is None else {
                "rate": tick.rate, "delay": tick.delay,
                "actuator_lag": getattr(tick, "flown_lag", 0.0),
                "speed_integral": getattr(tick, "speed_integral", 0.0),
                "integral_limit": (float(tick.integral_limit) if isinstance(tick, LoopSetting)
                                   and tick.speed_integral > 0 else None)},
            "speed_gain": traj.speed_gain, "force_budget": traj.force_budget,
            "axes": m["axes"],
            # the run against [control.spec] (`spec_verdict`; None for a run without limits)
            "spec": None if (verdict := spec_verdict(traj)) is None else verdict.to_json(),
            "sensing": sensed_metrics(traj)}


# ------------------------------------------------------------------------------- the job


@dataclass(frozen=True)
class SimulationRun:
    """The runs of `maglevgen simulate` and what they were computed with."""

    op: OperatingPoint
    trajectories: tuple[Trajectory, ...]
    dt_limit: float
    input_names: tuple[str, ...]
    fastest_growth: float  # largest real part of the closed-loop poles [1/s]
    scenario: str = "hold"
    v_end: float | None = None  # the launch's release speed
    speed_mode: SpeedMode | None = None  # the forward-speed mode at the start speed, explained
    warning: str | None = None  # one line when the hold speed lies outside the envelope

    def header(self, params_sha256: str) -> dict:
        """What metrics.json states about the runs besides the per-run metrics."""
        return {"params_sha256": params_sha256, "scenario": self.scenario,
                "speed": self.op.speed, "release_speed": self.v_end,
                "propulsion_force": self.op.f_prop, "rk4_stability_limit": self.dt_limit,
                "fastest_closed_loop_growth": self.fastest_growth,
                "speed_mode": None if self.speed_mode is None else self.speed_mode.to_json()}


def run_scenarios(plant: Plant, controllers: tuple[str, ...], t_end: float, dt: float,
                  speed: float | None = None,
                  bar: Callable[[str], AbstractContextManager[Callable[[int], None]]]
                  | None = None,
                  scenario: str = "hold",
                  disturbance: dict[str, float] | None = None, tick: Tick | None = None,
                  speed_gain: float = 0.0,
                  force_budget: float | None = None,
                  loop: Loop = Loop.CONTINUOUS,
                  disturbances: tuple[dict[str, float], ...] = ()) -> SimulationRun:
    """Trim, gains and one closed-loop run per controller, all in the generated C.

    ``loop`` (a `Loop`): ``FIRMWARE`` runs every controller as the firmware does
    (`Plant.loop`: the tick and delay of [control.spec], the speed loop at speed_bandwidth,
    the force budget); ``SENSED`` the embedded controller as the firmware flies it on the
    sensors' readings; ``CONTINUOUS`` (the paper's) evaluates it at every RK4 stage under the
    trim propulsion, unless ``tick``, ``speed_gain`` or ``force_budget`` say otherwise.

    ``hold``: from the disturbed trim at ``speed`` (default operation.speed) for ``t_end``
    with the propulsion at the trim drag and the gains of that speed. ``launch``: from the
    disturbed accelerating trim at the envelope's v_min to v_max under the propulsion of the
    accelerating trim at envelope.launch_acceleration (its drag plus m a), the reference that
    trim's pose and the gains those of the constant-speed linearisation, scheduled
    (`launch`, `Plant.launch_schedule`): the runs are judged against the accelerating
    trim; the speed loop then tracks v_min + envelope.launch_acceleration t. ``tick``,
    ``speed_gain`` and ``force_budget`` as in `simulate` (the defaults: the controller at
    every RK4 stage, no speed loop, no budget). Refuses a step above RK4's stability limit
    for the stiffest closed-loop mode at the start speed. ``disturbances``: when given, one
    run per controller and disturbance (in that order) instead of one from ``disturbance``,
    the trim and schedule computed once (`worst_case.judged_signs`).
    """
    for c in controllers:
        if c not in controller_names():
            raise InputError(f"controller {c!r}: expected one of {', '.join(controller_names())}")
    if scenario not in SCENARIOS:
        raise InputError(f"--scenario {scenario!r}: expected one of {', '.join(SCENARIOS)}")
    if not isinstance(loop, Loop):
        raise TypeError(f"loop {loop!r}: a Loop (the API parses the --loop string)")
    carriage, lib = plant.carriage, plant.lib
    min_gap = carriage.params.track.min_gap
    weights = Weights.of(carriage.params)
    v_end, warning = None, None
    if scenario == "launch":
        if speed is not None:
            raise InputError("--speed: the launch starts at envelope.v_min; set that instead")
        v_end = plant.speed_range[1]
        points = plant.points(plant.schedule_speeds())
        op = points[0]
        refs = plant.launch_references(points)
        a = carriage.params.envelope.launch_acceleration
        # the start: the accelerating trim at v_min (the pose of refs[0], the speed along x)
        x_start = checked_accelerating_trim(lib, carriage.p, op.speed, a, min_gap)[0]
    else:
        v = carriage.params.operation.speed if speed is None else speed
        if not (np.isfinite(v) and v > 0):
            raise InputError(f"--speed {v!r}: must be a positive speed in m/s")
        op = operating_point(lib, carriage.p, v, min_gap, weights)
        warning = outside_envelope(plant, v, "operation.speed" if speed is None
                                   else "--speed")
    eig = {c: np.linalg.eigvals(op.full_closed_loop(c)) for c in controllers}
    limits = {c: rk4_stability_limit(e) for c, e in eig.items()}
    worst = min(limits, key=lambda c: limits[c])
    if dt > limits[worst]:
        raise InputError(f"--dt {dt:g} s exceeds the RK4 stability limit {limits[worst]:.4g} s "
                         f"of the stiffest closed-loop mode ({worst} controller)")
    flown_controllers(loop, controllers, carriage.params.envelope.embedded_controller)
    if loop is not Loop.CONTINUOUS:
        tick, speed_gain, force_budget = run_loop(plant, loop)
    control_loop(dt, tick, speed_gain, force_budget, op.speed)  # refused before any run
    loop_kw: dict[str, Any] = {"tick": tick, "speed_gain": speed_gain,
                               "force_budget": force_budget}
    trajs = []
    setting = tick if isinstance(tick, LoopSetting) else None
    for c in controllers:
        sched = (plant.launch_schedule(points, c, refs, setting)
                 if scenario == "launch" else None)
        for dist in disturbances or (disturbance,):
            if scenario == "launch":
                assert sched is not None and v_end is not None  # the launch's, set above
                trajs.append(launch(lib, carriage.p, sched, op, v_end,
                                    carriage.params.vehicle.mass * a, dt, min_gap,
                                    max_time=1.5 * (v_end - op.speed) / a + 1.0,
                                    disturbance=dist, x_start=x_start, accel=a, **loop_kw))
                continue
            if bar is None:
                trajs.append(simulate(lib, carriage.p, op, c, t_end, dt, min_gap, dist,
                                      **loop_kw))
                continue
            with bar(f"simulating {controller_title(c)}") as update:
                trajs.append(simulate(lib, carriage.p, op, c, t_end, dt, min_gap, dist,
                                      progress=update, **loop_kw))
    growth = max(float(np.max(e.real)) for e in eig.values())
    embedded = carriage.params.envelope.embedded_controller
    mode = speed_mode(lib, carriage.p, op, carriage.params.vehicle.mass,
                      embedded if embedded in controllers else controllers[0])
    names = input_names_of(carriage.structure)
    run_limits = RunSpec.of(carriage.params, SETTLING_BAND)
    for traj in trajs:
        traj.input_names = names
        traj.run_spec = run_limits
    return SimulationRun(op, tuple(trajs), limits[worst], names, growth, scenario, v_end, mode,
                         warning)


def outside_envelope(plant: Plant, speed: float, key: str) -> str | None:
    """One line when ``speed`` lies outside the envelope [v_min, v_max] (where the embedded
    controller is verified and the firmware's table holds), else None; None also when the
    envelope itself has no trim (the commands that need it say so)."""
    try:
        v_lo, v_hi = plant.speed_range
    except InputError:
        return None
    if v_lo <= speed <= v_hi:
        return None
    named = f"{key} {speed:g}" if key.startswith("--") else f"{key} = {speed:g}"
    return (f"{named} m/s is outside the envelope [{v_lo:.4g}, {v_hi:.4g}] m/s "
            "(envelope.v_min, envelope.v_max): the controllers are verified inside it only")
