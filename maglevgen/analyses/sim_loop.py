"""A C run's controller loop: the firmware tick, its gains, the speed loop, its C settings."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from maglevgen.control.operating import OperatingPoint, SpeedMode
from maglevgen.control.sampled import Tick, speed_gain
from maglevgen.errors import InputError
from maglevgen.runtime.library import ControlLoop, SimulationLibrary

__all__ = ["LOOPS", "FirmwareTick", "control_loop", "firmware_gains", "firmware_loop",
           "run_loop", "speed_loop_gain"]


# how a run executes its controller: as the firmware does, or the paper's continuous law
LOOPS: tuple[str, ...] = ("firmware", "continuous")


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


def run_loop(carriage, lib: SimulationLibrary,
             loop: str) -> tuple[Tick | None, float, float | None]:
    """(tick, speed gain, force budget) of a run ``loop`` (LOOPS): `firmware_loop`, or the
    paper's continuous law (None, 0, None)."""
    if loop not in LOOPS:
        raise InputError(f"--loop {loop!r}: expected one of {', '.join(LOOPS)}")
    return firmware_loop(carriage, lib) if loop == "firmware" else (None, 0.0, None)


def speed_loop_gain(mode: SpeedMode, bandwidth: float) -> float:
    """k_v [N s/m] that puts the speed pole at -``bandwidth`` [rad/s] (`sampled.speed_gain`
    with the drag's total slope along the trim curve, ``mode.drag_slope_trim``; negative where
    the drag falls with speed, which makes the open loop unstable)."""
    return speed_gain(mode.mass, mode.drag_slope_trim, bandwidth)


def control_loop(dt: float, tick: Tick | None, speed_gain: float, force_budget: float | None,
                 v_ref: float, accel: float = 0.0, design=None) -> ControlLoop | None:
    """The C loop's settings (maglev_control_loop), or None for the continuous loop: the
    controller at every RK4 stage, the propulsion without speed feedback, no budget.
    Validates them. A `FirmwareTick` adds the actuator lag and the speed integral;
    ``design`` (a `plant.LoopDesign`): the tick law's K_lag and K_delay of maglev_simulate."""
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
    return ControlLoop(0 if tick is None else tick.steps(dt), 0 if tick is None else tick.delay,
                       float(speed_gain), float(v_ref), float(accel), budget, **law)

