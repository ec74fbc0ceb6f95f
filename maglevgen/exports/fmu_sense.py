"""The FMU on the sensors (`maglevgen fmu --loop sensed`): the embedded controller's own sense
tick, the C of the firmware folder in double precision (`maglevgen.analyses.sensed`), inside
the FMU's binary, flown on the plant's readings with noise the FMU draws itself.

At each tick the FMU reads the plant through the generated measurement functions of
``[sensors]`` (maglev_gap_reading, maglev_imu_reading; the track position is x), adds each
reading's noise (its in-run bias, whose sign is drawn once per run, plus white noise), rounds
it to the reading's resolution and calls the firmware's maglev_sense_init (first tick) and
maglev_sense_tick, as `maglevgen simulate --loop sensed` does on the host. The noise comes
from a generator written out here so that anyone can reproduce it (`NOISE_GENERATOR`):
splitmix64 from ``noise_seed``, uniforms in (-1, 1) from its 53 high bits, Marsaglia's polar
method for each standard normal, drawn reading by reading, tick by tick.

The firmware's names (maglev_coupled_control, maglev.h, ...) are also the FMU's carriage
functions' names: its files enter the FMU with every ``maglev_`` renamed ``maglev_fw_``
(`renamed_firmware`), the same code under names of its own.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from importlib import resources
from typing import TYPE_CHECKING

import numpy as np

from maglevgen.analyses.sensed import sensed_firmware
from maglevgen.analyses.sim_loop import reading_spread, white_rms
from maglevgen.errors import InputError

if TYPE_CHECKING:
    from maglevgen.control.carriage_plant import Plant

__all__ = ["NOISE_GENERATOR", "FmuSense", "fmu_sense"]

FW_PREFIX = "maglev_fw_"
#: the generator's description (the FMU's documentation, its variables' and the C's)
NOISE_GENERATOR = ("splitmix64 seeded with noise_seed; u = 2 (z >> 11) 2^-53 - 1; Marsaglia's "
                   "polar method, the first normal of each accepted pair")
#: the firmware folder's C the sense tick needs, and the glue that exposes it untyped
_SOURCES = ("maglev_tick.c", "maglev_gain_table.c", "maglev_sense_table.c",
            "maglev_functions.c", "maglev_host_sense.c")
_UNITS = {"gap": "m", "gyro": "rad/s", "accel": "m/s^2", "track": "m"}


@dataclass(frozen=True)
class FmuSense:
    """What the FMU's sensed tick needs: each reading's name, unit, white noise RMS at the
    tick (the reading's noise without the share its rounding adds), in-run bias magnitude and
    resolution (the start values of its parameters); the gap sensors' body points, face
    normals and nominal gaps, the IMU's point (empty: none), whether x is read; the firmware
    state's size in 8-byte words and its loop (tick rate, delay); ``sources``: the renamed
    firmware files (name, text)."""

    names: tuple[str, ...]
    units: tuple[str, ...]
    noise: tuple[float, ...]
    bias: tuple[float, ...]
    resolution: tuple[float, ...]
    gap_point: tuple[float, ...]
    gap_normal: tuple[float, ...]
    gap_nominal: tuple[float, ...]
    imu_point: tuple[float, ...]
    track: bool
    state_words: int
    rate: float
    delay: int
    sources: tuple[tuple[str, str], ...]

    @property
    def n_gap(self) -> int:
        return len(self.gap_nominal)

    @property
    def c_sources(self) -> tuple[str, ...]:
        return tuple(n for n, _ in self.sources if n.endswith(".c"))


def renamed_firmware(files: dict[str, str]) -> dict[str, str]:
    """The sense tick's files of a double-precision firmware folder (its C, every header,
    the host glue) with each ``maglev_`` identifier, and the file names, renamed
    ``maglev_fw_`` and maglev.h renamed maglev_fw.h."""
    glue = (resources.files("maglevgen.templates") / "maglev_host_sense.c").read_text()
    picked = {n: t for n, t in files.items()
              if n in _SOURCES or (n.endswith(".h") and not n.startswith("qemu_"))}
    picked["maglev_host_sense.c"] = glue

    def rename(text: str) -> str:
        return re.sub(r"\bmaglev_", FW_PREFIX, text).replace('"maglev.h"', '"maglev_fw.h"')

    return {("maglev_fw.h" if n == "maglev.h" else rename(n)): rename(t)
            for n, t in sorted(picked.items())}


def fmu_sense(plant: Plant) -> FmuSense:
    """The sensed tick of ``plant``'s embedded controller for its FMU (the firmware compiled
    for the host, `maglevgen.analyses.sensed.sensed_firmware`); InputError without
    ``[sensors]``."""
    fw = sensed_firmware(plant)
    layout = fw.layout
    sigma, bias, step = reading_spread(plant.params, layout)
    white = white_rms(sigma, step)
    units = []
    for name in layout.names:
        kind = name.split("_", 1)[0]
        if kind not in _UNITS:
            raise InputError(f"sensors: reading {name!r} has no unit the FMU knows")
        units.append(_UNITS[kind])

    def flat(rows) -> tuple[float, ...]:
        return tuple(float(v) for v in np.ravel(rows))

    return FmuSense(
        tuple(layout.names), tuple(units), flat(white), flat(bias), flat(step),
        flat([g.point for g in layout.gaps]), flat([g.normal for g in layout.gaps]),
        flat([g.nominal_gap for g in layout.gaps]),
        () if layout.imu_point is None else flat(layout.imu_point), bool(layout.track),
        -(-fw.library.state_size // 8), float(fw.loop.tick.rate), int(fw.loop.tick.delay),
        tuple(sorted(renamed_firmware(fw.files).items())))
