"""A C run's controller loop: the `loop` string of the API and CLI ("firmware" / "continuous")
to the plant's loop as built (`run_loop`), its gains and speed loop (the loop type itself, its
tick and C settings: `maglevgen.control.built_loop`, re-exported here)."""

from __future__ import annotations

from maglevgen.control.built_loop import FirmwareTick, control_loop, loop_design
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.operating import OperatingPoint, SpeedMode
from maglevgen.control.plant import LoopDesign
from maglevgen.control.sampled import Tick, speed_gain
from maglevgen.errors import InputError

__all__ = ["LOOPS", "FirmwareTick", "control_loop", "firmware_gains", "run_loop",
           "speed_loop_gain"]


# how a run executes its controller: as the firmware does, or the paper's continuous law
LOOPS: tuple[str, ...] = ("firmware", "continuous")


def firmware_gains(op: OperatingPoint, controller: str, tick: FirmwareTick) -> LoopDesign:
    """``controller``'s gains on the loop ``tick`` describes (`loop.loop_design`, a
    `plant.LoopDesign`): its design at the tick on the loop as built where it has one (the
    `spec` controller: K_pos, K_rate, K_lag, K_delay, what the firmware's table holds), else
    its continuous gains (K_lag, K_delay None: fed back with zero gains)."""
    return loop_design(op, controller, tick.setting())


def run_loop(plant: Plant, loop: str) -> tuple[Tick | None, float, float | None]:
    """(tick, speed gain, force budget) of a run ``loop`` (LOOPS): the plant's loop as built
    (`Plant.loop`: its `FirmwareTick`, k_v and budget), or the paper's continuous law (None, 0,
    None)."""
    if loop not in LOOPS:
        raise InputError(f"--loop {loop!r}: expected one of {', '.join(LOOPS)}")
    if loop == "continuous":
        return None, 0.0, None
    built = plant.loop
    return built.firmware_tick(), built.speed_gain, built.force_budget


def speed_loop_gain(mode: SpeedMode, bandwidth: float) -> float:
    """k_v [N s/m] that puts the speed pole at -``bandwidth`` [rad/s] (`sampled.speed_gain`
    with the drag's total slope along the trim curve, ``mode.drag_slope_trim``; negative where
    the drag falls with speed, which makes the open loop unstable)."""
    return speed_gain(mode.mass, mode.drag_slope_trim, bandwidth)
