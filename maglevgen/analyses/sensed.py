"""Runs on the sensors, as the firmware flies: the embedded controller's firmware folder
(`firmware_sources.render_firmware`: its gain table, its estimator's table, maglev_sense_tick)
compiled for the host in double precision (`maglevgen.runtime.sense`), flown by
maglev_simulate's tick-held loop around the run-time-parameter plant with the actuator lag
and the delay: at each tick the plant is read by the generated measurement functions of the
sensors of ``[sensors]`` (control.estimation.SensorLayout), the run's noise is added
(`output_feedback.reading_noise`: white noise and the IMU's bias, seeded; each reading rounded
to its resolution), and the firmware's sense tick (maglev_sense_init at the first tick from the
first readings, then maglev_sense_tick) computes the command, as it does on the board.

This is the loop the verdicts of the output-feedback loop are about: the same C, its tables
interpolated over speed, its estimator started from the readings, not from the trim.
`output_feedback.noisy_hold` (numpy's estimator at one speed around the same plant) is the
independent reference the tests hold it against.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

from maglevgen.analyses.firmware_sources import host_sense_sources, sense_schedule
from maglevgen.control.built_loop import LoopSetting
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.estimation import SensorLayout
from maglevgen.params import Parameters, with_sensor_values
from maglevgen.runtime.sense import SenseLibrary, sense_library

__all__ = ["SensedFirmware", "sensed_firmware"]


@dataclass(frozen=True, eq=False)
class SensedFirmware:
    """The embedded controller's firmware for the host: its loop (tick, delay, speed loop,
    budget, lag), its speed range, its sensors, its compiled sense tick and the parameters
    it was built from."""

    loop: LoopSetting
    v_min: float  # [m/s] the tables' range
    v_max: float
    layout: SensorLayout
    library: SenseLibrary
    params: Parameters  # the carriage's parameters (its [sensors]: the runs' noise)
    files: dict[str, str]  # the double-precision folder it was compiled from (the FMU's too)
    lanes: str = ""  # and its sense tick over SIMD lanes, compiled beside it (host only)

    def sampled(self, values: tuple[tuple[str, float], ...] = ()
                ) -> tuple[Parameters, SensorLayout]:
        """The parameters and sensor layout a run's readings' noise is drawn with: the
        carriage's, with ``values`` (maglevgen.params.SENSOR_TOLERANCES entries, a
        Monte-Carlo sample's draws) in place of its own; the tables stay the design on
        the carriage's."""
        if not values:
            return self.params, self.layout
        params = with_sensor_values(self.params, dict(values))
        return params, SensorLayout.of(params)


#: each plant's firmware for the host, kept while the plant lives: rendering its tables
#: takes seconds, and a build flies it in its noisy holds and its launch
_BUILT: weakref.WeakKeyDictionary[Plant, SensedFirmware] = weakref.WeakKeyDictionary()


def sensed_firmware(plant: Plant) -> SensedFirmware:
    """The firmware `maglevgen firmware` writes for ``plant``'s carriage, in double precision
    with its sense tick, compiled for the host (cached by its content on disk, and per plant
    in memory); InputError without ``[sensors]`` (nothing to fly on)."""
    if (built := _BUILT.get(plant)) is None:
        built = _BUILT[plant] = _render(plant)
    return built


def _render(plant: Plant) -> SensedFirmware:
    carriage = plant.carriage
    params = carriage.params
    layout = SensorLayout.of(params)  # InputError without [sensors]
    v_min, v_max = plant.speed_range
    loop = plant.loop
    loop.check_embeddable()
    sense = sense_schedule(plant, v_min, v_max, loop)
    assert sense is not None  # [sensors] is there: SensorLayout.of refused otherwise
    files, lanes = host_sense_sources(carriage, plant.gain_table(v_min, v_max), loop, sense)
    return SensedFirmware(loop, float(v_min), float(v_max), layout,
                          sense_library(files, lanes=lanes), params, files, lanes)
