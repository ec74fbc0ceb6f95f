"""A C run's controller loop: the firmware tick, its gains, the speed loop, its C settings."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from maglevgen.control.operating import OperatingPoint, SpeedMode
from maglevgen.control.sampled import Tick, speed_gain
from maglevgen.derive import conventions as cv
from maglevgen.derive.conventions import Q_STATES
from maglevgen.errors import InputError
from maglevgen.runtime.library import ControlLoop, SimulationLibrary
from maglevgen.runtime.sense import Sensing

if TYPE_CHECKING:
    from maglevgen.analyses.sensed import SensedFirmware
    from maglevgen.control.estimation import SensorLayout

__all__ = ["LOOPS", "FirmwareTick", "SensedTick", "control_loop", "estimation_error",
           "firmware_gains", "firmware_loop", "reading_noise", "run_loop", "sensed_metrics",
           "sensing", "speed_loop_gain"]


# how a run executes its controller: as the firmware does on the sensors' readings (the
# embedded controller's sense tick), as it does on the exact state (ideal sensing), or the
# paper's continuous law
LOOPS: tuple[str, ...] = ("firmware", "sensed", "continuous")


@dataclass(frozen=True)
class FirmwareTick(Tick):
    """The firmware's tick (`Tick`: rate and delay) with the rest of the loop as built: each
    array force's first-order ``lag`` [s] in the plant ([actuators] time_constant) and the
    speed error's integral gain ``speed_integral`` [N/m], its propulsion |k_i xi| clamped at
    ``integral_limit`` [N] (anti-windup; inf: none). A run at a FirmwareTick runs the
    firmware tick's law (templates/maglev_tick_law.c.j2) with each controller's gains on this
    loop (`firmware_gains`: the design at the tick where the controller has one); a run at a
    plain `Tick` runs the controller's continuous gains on the plant without the lag (the host
    loop before issue 50)."""

    lag: float = 0.0  # [s]
    speed_integral: float = 0.0  # [N/m]
    integral_limit: float = float("inf")  # [N]

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (isinstance(self.lag, (int, float)) and np.isfinite(self.lag) and self.lag >= 0):
            raise InputError(f"actuator lag {self.lag!r} s: must be a finite number >= 0")
        if not (isinstance(self.speed_integral, (int, float))
                and np.isfinite(self.speed_integral) and self.speed_integral >= 0):
            raise InputError(f"speed integral gain {self.speed_integral!r} N/m: must be a "
                             "finite number >= 0")
        if not (isinstance(self.integral_limit, (int, float))
                and self.integral_limit >= 0):
            raise InputError(f"speed integral limit {self.integral_limit!r} N: must be a "
                             "number >= 0 (inf: none)")

    def setting(self, speed_gain: float = 0.0):
        """The `loop.LoopSetting` of this loop (``speed_gain``: its k_v)."""
        from maglevgen.analyses.loop import LoopSetting

        return LoopSetting(Tick(self.rate, self.delay), float(speed_gain), 0.0, self.lag,
                           self.speed_integral, float(self.integral_limit))


def firmware_gains(op: OperatingPoint, controller: str, tick: FirmwareTick):
    """``controller``'s gains on the loop ``tick`` describes (`loop.loop_design`, a
    `plant.LoopDesign`): its design at the tick on the loop as built where it has one (the
    `spec` controller: K_pos, K_rate, K_lag, K_delay, what the firmware's table holds), else
    its continuous gains (K_lag, K_delay None: fed back with zero gains)."""
    from maglevgen.analyses.loop import loop_design

    return loop_design(op, controller, tick.setting())


def firmware_loop(carriage, lib: SimulationLibrary) -> tuple[FirmwareTick, float, float]:
    """(tick, k_v, force budget) of [control.spec]: the tick and its delay with the actuator
    lag and the speed integral and its clamp (`FirmwareTick`), the speed loop's one gain over
    the envelope (`loop.loop_setting`, the gains the envelope's verdicts used) and the
    per-array force budget."""
    from maglevgen.analyses.envelope import envelope_points, resolve_range
    from maglevgen.analyses.loop import loop_setting

    v_lo, v_hi = resolve_range(carriage, lib)
    points = envelope_points(carriage, lib, np.linspace(v_lo, v_hi, carriage.params
                                                        .envelope.schedule_nodes))
    setting = loop_setting(carriage, points)
    tick = FirmwareTick(setting.tick.rate, setting.tick.delay, float(setting.actuator_lag),
                        float(setting.speed_integral), float(setting.speed_integral_limit))
    return tick, setting.speed_gain, float(carriage.params.control.spec.force_budget)


def run_loop(carriage, lib: SimulationLibrary, loop: str, seed: int = 0,
             noise_scale: float = 1.0) -> tuple[Tick | None, float, float | None]:
    """(tick, speed gain, force budget) of a run ``loop`` (LOOPS): `firmware_loop`; that loop
    on the sensors (a `SensedTick` of `maglevgen.analyses.sensed.sensed_firmware`, its noise
    times ``noise_scale`` from ``seed``); or the paper's continuous law (None, 0, None)."""
    if loop not in LOOPS:
        raise InputError(f"--loop {loop!r}: expected one of {', '.join(LOOPS)}")
    if loop == "continuous":
        return None, 0.0, None
    tick, k_v, budget = firmware_loop(carriage, lib)
    if loop == "sensed":
        from maglevgen.analyses.sensed import sensed_firmware

        tick = SensedTick(tick.rate, tick.delay, tick.lag, tick.speed_integral,
                          tick.integral_limit, sensed_firmware(carriage, lib), int(seed),
                          float(noise_scale))
    return tick, k_v, budget


def speed_loop_gain(mode: SpeedMode, bandwidth: float) -> float:
    """k_v [N s/m] that puts the speed pole at -``bandwidth`` [rad/s] (`sampled.speed_gain`
    with the drag's total slope along the trim curve, ``mode.drag_slope_trim``; negative where
    the drag falls with speed, which makes the open loop unstable)."""
    return speed_gain(mode.mass, mode.drag_slope_trim, bandwidth)


def control_loop(dt: float, tick: Tick | None, speed_gain: float, force_budget: float | None,
                 v_ref: float, accel: float = 0.0, design=None,
                 sense: Sensing | None = None) -> ControlLoop | None:
    """The C loop's settings (maglev_control_loop), or None for the continuous loop: the
    controller at every RK4 stage, the propulsion without speed feedback, no budget.
    Validates them. A `FirmwareTick` adds the actuator lag and the speed integral;
    ``design`` (a `plant.LoopDesign`): the tick law's K_lag and K_delay of maglev_simulate;
    ``sense`` (a `SensedTick`'s run: `sensing`): the firmware's sense tick on the readings."""
    if not (isinstance(speed_gain, (int, float)) and np.isfinite(speed_gain)
            and speed_gain >= 0):
        raise InputError(f"speed gain {speed_gain!r} N s/m: must be a finite number >= 0")
    if force_budget is not None and not (isinstance(force_budget, (int, float))
                                         and force_budget > 0):
        raise InputError(f"force budget {force_budget!r} N: must be positive (None or inf: "
                         "no limit)")
    if tick is None and speed_gain == 0 and force_budget is None:
        return None
    budget = 0.0 if force_budget is None or np.isinf(force_budget) else float(force_budget)
    law: dict = {}
    if isinstance(tick, FirmwareTick):
        law = {"tau": float(tick.lag), "k_i": float(tick.speed_integral),
               "i_max": float(tick.integral_limit)}
    if design is not None:
        for key, K in (("k_lag", design.K_lag), ("k_delay", design.K_delay)):
            if K is not None and K.size:
                law[key] = tuple(float(v) for v in K.ravel(order="F"))
    if sense is not None and not isinstance(tick, SensedTick):
        raise ValueError("the sensors' loop runs at a SensedTick")
    return ControlLoop(0 if tick is None else tick.steps(dt), 0 if tick is None else tick.delay,
                       float(speed_gain), float(v_ref), float(accel), budget, **law,
                       sense=sense)


@dataclass(frozen=True)
class SensedTick(FirmwareTick):
    """A `FirmwareTick` flown on the sensors: the firmware's sense tick (``firmware``) on the
    plant's readings with their noise times ``noise_scale`` drawn from ``seed`` (a run's
    own: `sensing`) in place of the exact state's feedback."""

    firmware: SensedFirmware | None = None
    seed: int = 0
    noise_scale: float = 1.0

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.firmware is None:
            raise InputError("a run on the sensors needs the firmware's sense tick")
        if not (isinstance(self.noise_scale, (int, float)) and np.isfinite(self.noise_scale)
                and self.noise_scale >= 0):
            raise InputError(f"noise scale {self.noise_scale!r}: must be a finite number >= 0")


def reading_noise(params, layout: SensorLayout, n_ticks: int, seed: int = 0,
                  noise_scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """What a run adds to the readings of ``layout`` (``[sensors]``) at each of ``n_ticks``
    ticks, and each reading's resolution, every noise, bias and resolution times
    ``noise_scale``: (noise (n_ticks, readings), steps). The noise is each reading's
    in-run bias (the IMU's: each axis's sign drawn once per run, first) plus white noise,
    drawn from numpy's default_rng(``seed``); the white noise leaves out the share of the
    variance the rounding to the resolution adds (the run rounds each noisy reading)."""
    s = params.sensors
    rng = np.random.default_rng(seed)
    ny, n_gap = len(layout.names), len(layout.gaps)
    sigma = np.sqrt(layout.variances) * noise_scale
    bias = np.zeros(ny)
    if s.imu is not None:  # each axis's in-run bias, its sign drawn once per run
        bias[n_gap:n_gap + 3] = s.imu.gyro_bias * rng.choice((-1.0, 1.0), 3)
        bias[n_gap + 3:n_gap + 6] = s.imu.accel_bias * rng.choice((-1.0, 1.0), 3)
    step = np.zeros(ny)
    if s.gap is not None:
        step[:n_gap] = s.gap.resolution
    if s.track is not None:
        step[-1] = s.track.resolution
    step *= noise_scale
    white = np.sqrt(np.clip(sigma**2 - step**2 / 12, 0.0, None))
    return bias * noise_scale + white * rng.standard_normal((n_ticks, ny)), step


def sensing(tick: SensedTick, n_ticks: int, record: bool = True, n_inputs: int = 0
            ) -> Sensing:
    """A run's `Sensing` of ``tick``: its sensors, ``n_ticks`` ticks of noise
    (`reading_noise` with the tick's seed and scale) and, ``record``, each tick's readings
    and prediction kept (and its command, given the plant's ``n_inputs``)."""
    fw = tick.firmware
    assert fw is not None  # SensedTick refuses None
    layout = fw.layout
    noise, step = reading_noise(fw.params, layout, n_ticks, tick.seed, tick.noise_scale)
    return Sensing(fw.library, np.array([g.point for g in layout.gaps]).reshape(-1, 3),
                   np.array([g.normal for g in layout.gaps]).reshape(-1, 3),
                   np.array([g.nominal_gap for g in layout.gaps]), layout.imu_point,
                   layout.track, step, noise, n_ticks if record else 0,
                   n_inputs if record else 0)


def estimation_error(sense: Sensing, x: np.ndarray, tick_steps: int) -> np.ndarray:
    """The sense tick's prediction error at each tick after the first: the state at tick
    k + 1 (the row k (k + 1) tick_steps of ``x``, a run's states) less the prediction made at
    tick k, (ticks - 1, 12); the ticks the run reached and recorded."""
    ticks = min(sense.rows, (x.shape[0] - 1) // tick_steps + 1)
    if ticks < 2:
        return np.zeros((0, x.shape[1]))
    return x[tick_steps:ticks * tick_steps:tick_steps] - sense.predicted[:ticks - 1]


def sensed_metrics(traj) -> dict | None:
    """A `simulate.Trajectory` on the sensors (None otherwise): its noise's seed and scale,
    each array's control force RMS [N] (the plant's, after the lag), the share of the run
    with an array at the budget, the gaps' and the attitude's RMS deviation from the trim
    (the moving equilibrium's for the attitude), and the sense tick's prediction error, RMS
    per state (`estimation_error`)."""
    sense, tick = traj.sensing, traj.tick
    if sense is None or not isinstance(tick, SensedTick):
        return None
    err = estimation_error(sense, traj.x, tick.steps(traj.dt))
    dev = traj.axis_deviation
    return {
        "seed": tick.seed, "noise_scale": tick.noise_scale, "tick_error": sense.tick_error,
        "rms_array_force": {a: float(np.sqrt(np.mean(f**2)))
                            for a, f in traj.array_forces.items()},
        "budget_share": traj.saturated_time / max(float(traj.t[-1]), traj.dt),
        "rms_gap_deviation": [float(v) for v in
                              np.sqrt(np.mean((traj.gaps - traj.op.gaps) ** 2, axis=0))],
        "rms_attitude": {s: float(np.sqrt(np.mean(dev[:, i] ** 2)))
                         for i, s in enumerate(Q_STATES) if s in ("phi", "theta", "psi")},
        "rms_estimation_error": {s.name: float(np.sqrt(np.mean(err[:, i] ** 2)))
                                 for i, s in enumerate(cv.STATES)} if err.size else {},
    }
