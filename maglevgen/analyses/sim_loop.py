"""A C run's controller loop: the `loop` string of the API and CLI ("firmware" / "continuous")
to the plant's loop as built (`run_loop`), its gains and speed loop (the loop type itself, its
tick and C settings: `maglevgen.control.built_loop`, re-exported here)."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import TYPE_CHECKING

import numpy as np

from maglevgen.control.built_loop import Loop, LoopSetting, control_loop, loop_design
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.operating import OperatingPoint, SpeedMode
from maglevgen.control.plant import LoopDesign
from maglevgen.control.sampled import Tick, speed_gain
from maglevgen.derive import conventions as cv
from maglevgen.derive.conventions import Q_STATES
from maglevgen.errors import InputError
from maglevgen.runtime.sense import Sensing

if TYPE_CHECKING:
    from collections.abc import Callable

    from maglevgen.analyses.sensed import SensedFirmware
    from maglevgen.control.estimation import SensorLayout

__all__ = ["LoopSetting", "SensedTick", "control_loop", "estimation_error", "firmware_gains",
           "flown_loop", "reading_noise", "reading_spread", "run_loop", "sensed_metrics",
           "sensing", "speed_loop_gain", "white_rms"]


# how a run executes its controller: as the firmware does on the sensors' readings (the
# embedded controller's sense tick), as it does on the exact state (ideal sensing), or the
# paper's continuous law
LOOPS: tuple[str, ...] = ("firmware", "sensed", "continuous")


def flown_loop(plant: Plant) -> Loop:
    """The loop the embedded controller flies on a carriage (the build's judged runs and its
    region's confirmations): SENSED (its sense tick on the readings) where the file has
    [sensors], else FIRMWARE (the exact state: nothing says what is measured)."""
    return Loop.SENSED if plant.params.sensors is not None else Loop.FIRMWARE


def firmware_gains(op: OperatingPoint, controller: str, tick: LoopSetting) -> LoopDesign:
    """``controller``'s gains on the loop ``tick`` (`loop.loop_design`, a
    `plant.LoopDesign`): its design at the tick on the loop as built where it has one (the
    `spec` controller: K_pos, K_rate, K_lag, K_delay, what the firmware's table holds), else
    its continuous gains (K_lag, K_delay None: fed back with zero gains)."""
    return loop_design(op, controller, tick)


def run_loop(plant: Plant, loop: Loop, seed: int = 0,
             noise_scale: float = 1.0) -> tuple[Tick | None, float, float | None]:
    """(tick, speed gain, force budget) of a run ``loop``: the plant's loop as built
    (`Plant.loop`, and its k_v and budget); that loop on the sensors (a
    `SensedTick` of `maglevgen.analyses.sensed.sensed_firmware`, its noise times
    ``noise_scale`` from ``seed``); or the paper's continuous law (None, 0, None)."""
    if loop not in tuple(Loop):
        raise InputError(f"--loop {loop!r}: expected one of {', '.join(LOOPS)}")
    loop = Loop(loop)
    if loop is Loop.CONTINUOUS:
        return None, 0.0, None
    built = tick = plant.loop
    if loop is Loop.SENSED:
        from maglevgen.analyses.sensed import sensed_firmware

        tick = SensedTick(**{f.name: getattr(built, f.name) for f in fields(LoopSetting)},
                          firmware=sensed_firmware(plant), seed=int(seed),
                          noise_scale=float(noise_scale))
    return tick, built.speed_gain, built.force_budget


def speed_loop_gain(mode: SpeedMode, bandwidth: float) -> float:
    """k_v [N s/m] that puts the speed pole at -``bandwidth`` [rad/s] (`sampled.speed_gain`
    with the drag's total slope along the trim curve, ``mode.drag_slope_trim``; negative where
    the drag falls with speed, which makes the open loop unstable)."""
    return speed_gain(mode.mass, mode.drag_slope_trim, bandwidth)


@dataclass(frozen=True)
class SensedTick(LoopSetting):
    """A `LoopSetting` flown on the sensors: the firmware's sense tick (``firmware``) on the
    plant's readings with their noise times ``noise_scale`` drawn from ``seed`` (a run's
    own: `sensing`) in place of the exact state's feedback. ``sensor_values``: (key, value)
    pairs of maglevgen.params.SENSOR_TOLERANCES (a Monte-Carlo sample's draws) the noise is
    drawn with in place of the file's; the firmware's tables stay its design."""

    firmware: SensedFirmware | None = None
    seed: int = 0
    noise_scale: float = 1.0
    sensor_values: tuple[tuple[str, float], ...] = ()

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.firmware is None:
            raise InputError("a run on the sensors needs the firmware's sense tick")
        if not (isinstance(self.noise_scale, (int, float)) and np.isfinite(self.noise_scale)
                and self.noise_scale >= 0):
            raise InputError(f"noise scale {self.noise_scale!r}: must be a finite number >= 0")


def reading_spread(params, layout: SensorLayout) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each reading of ``layout`` (``[sensors]``): (its noise's RMS at the tick, rounding
    included (`SensorLayout.variances`), its in-run bias's magnitude (the IMU's; 0 else),
    its resolution (the gaps' and the track's; 0 else)): what a run's noise is drawn from
    (`reading_noise`, the FMU's `maglevgen.exports.fmu_sense`)."""
    s = params.sensors
    ny = len(layout.names)
    bias = np.zeros(ny)
    if s.imu is not None:
        bias[layout.gyro_readings] = s.imu.gyro_bias
        bias[layout.accel_readings] = s.imu.accel_bias
    step = np.zeros(ny)
    if s.gap is not None:
        step[layout.gap_readings] = s.gap.resolution
    if s.track is not None:
        step[-1] = s.track.resolution
    return np.sqrt(layout.variances), bias, step


def white_rms(sigma: np.ndarray, step: np.ndarray) -> np.ndarray:
    """The white noise's RMS that, with the rounding to ``step`` (variance step^2/12),
    gives a reading's RMS ``sigma``."""
    return np.sqrt(np.clip(sigma**2 - step**2 / 12, 0.0, None))


def reading_noise(params, layout: SensorLayout, n_ticks: int, seed: int = 0,
                  noise_scale: float = 1.0, out: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """What a run adds to the readings of ``layout`` (``[sensors]``) at each of ``n_ticks``
    ticks, and each reading's resolution, every noise, bias and resolution times
    ``noise_scale``: (noise (n_ticks, readings), steps). The noise is each reading's
    in-run bias (the IMU's: each axis's sign drawn once per run, first) plus white noise,
    drawn from numpy's default_rng(``seed``); the white noise leaves out the share of the
    variance the rounding to the resolution adds (the run rounds each noisy reading).
    ``out``: a float64 C-contiguous array of that shape the noise is written into (the same
    numbers: memory kept across runs, `BatchBuffers.noise`), else a new one."""
    sigma, bias, step = reading_spread(params, layout)
    rng = np.random.default_rng(seed)
    sigma = sigma * noise_scale
    if params.sensors.imu is not None:  # each axis's in-run bias, its sign drawn once per run
        bias[layout.gyro_readings] *= rng.choice((-1.0, 1.0), 3)
        bias[layout.accel_readings] *= rng.choice((-1.0, 1.0), 3)
    step = step * noise_scale
    shape = (n_ticks, len(layout.names))
    if out is not None and (out.shape != shape or out.dtype != np.float64
                            or not out.flags.c_contiguous):
        raise ValueError(f"the noise's array is {out.shape} {out.dtype}, not {shape} float64 "
                         "C-contiguous")
    noise = rng.standard_normal(shape) if out is None else rng.standard_normal(out=out)
    noise *= white_rms(sigma, step)  # in place: a run's noise is its largest array
    noise += bias * noise_scale
    return noise, step


def sensing(tick: SensedTick, n_ticks: int, record: bool = True, n_inputs: int = 0,
            noise_memory: Callable[[tuple[int, int]], np.ndarray] | None = None) -> Sensing:
    """A run's `Sensing` of ``tick``: its sensors, ``n_ticks`` ticks of noise
    (`reading_noise` with the tick's seed, scale and sensor values; written into the array
    ``noise_memory`` gives for its shape, `BatchBuffers.noise`, else a new one) and,
    ``record``, each tick's readings and prediction kept (and its command, given the
    plant's ``n_inputs``)."""
    fw = tick.firmware
    assert fw is not None  # SensedTick refuses None
    params, noisy = fw.sampled(tick.sensor_values)  # the sample's sensors' noise
    out = None if noise_memory is None else noise_memory((n_ticks, len(noisy.names)))
    noise, step = reading_noise(params, noisy, n_ticks, tick.seed, tick.noise_scale, out)
    layout = fw.layout
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
