"""`maglevgen firmware`: the folder a user builds for the board.

What the folder holds and how it is rendered: maglevgen.analyses.firmware_sources. Here: the
loop and tables the build's verification used, computed from the compiled simulation library,
and the tick's measured cost quoted in the README. The host/HIL files (Newton trim, spline
schedule, maglev_simulate) stay with `maglevgen generate`.

Writers return (file name, text) pairs; `maglevgen.infrastructure.output.write_output` alone
touches the disk.
"""

from __future__ import annotations

from maglevgen.analyses.firmware_sources import (
    FIRMWARE_FLAGS,
    QEMU_TICKS,
    SENSE_REFRESH_TICKS,
    TICK_INPUTS,
    SenseSchedule,
    refresh_slices,
    render_firmware,
    sense_refresh_bound,
    sense_schedule,
)
from maglevgen.codegen.interface import GenerateOptions
from maglevgen.control.built_loop import LoopSetting
from maglevgen.control.carriage_plant import Plant

__all__ = ["FIRMWARE_FLAGS", "MEASURED", "QEMU_TICKS", "SENSE_REFRESH_TICKS", "TICK_INPUTS",
           "SenseSchedule", "firmware_files", "firmware_loop", "refresh_slices", "render_firmware",
           "sense_refresh_bound", "sense_schedule"]

#: the tick's cost on the Cortex-M4F at the default carriage, as bench/firmware_tick.py
#: measured it (BENCHMARKS.md, "Firmware tick on the Cortex-M4F"); quoted by the README
MEASURED: dict = {
    "instructions": 3203, "cycles": 5662, "share_percent": 3.37, "clock_mhz": 168,
    "stack_bytes": 800,
    # maglev_sense_tick: the estimator's products over its table's nonzero values, a slice of
    # its cache's refresh, the law (52696 instructions, 51 % with the table every tick)
    "sense": {"instructions": 6652, "cycles": 11892, "share_percent": 7.08,
              "stack_bytes": 1232},
    # maglev_sense_init: the whole table at once (the start, and a tick that starts again)
    "sense_init": {"instructions": 14887, "cycles": 24409, "share_percent": 14.53,
                   "stack_bytes": 384},
    "method": "every instruction QEMU mps2-an386 executes, newlib's sinf/cosf included",
    "cycle_model": "Cortex-M4/FPv4-SP instruction timings, zero wait states",
}


def firmware_loop(plant: Plant) -> LoopSetting:
    """The tick, delay, speed-loop gain and budget the build's firmware runs verify
    (`Plant.loop`: `loop_setting` over the schedule's nodes, ``[control.spec]``), checked
    embeddable (a speed integral needs a finite clamp: ValueError)."""
    plant.loop.check_embeddable()
    return plant.loop


def firmware_files(plant: Plant, precision: str = "single",
                   with_plant: bool = False, verdict: dict | None = None) -> dict[str, str]:
    """The firmware folder of ``plant``'s carriage (`render_firmware`): the table schedule over
    the envelope and the loop as built (`Plant.loop`); ``verdict``:
    the embedded controller's verification (`maglevgen.build.EmbeddedVerdict.to_json`)."""
    GenerateOptions(precision, "baked")  # an unknown precision: InputError before slow work
    carriage = plant.carriage
    v_min, v_max = plant.speed_range
    loop = firmware_loop(plant)
    return render_firmware(carriage, plant.gain_table(v_min, v_max), loop, precision,
                           with_plant, MEASURED, verdict,
                           sense_schedule(plant, v_min, v_max, loop))
