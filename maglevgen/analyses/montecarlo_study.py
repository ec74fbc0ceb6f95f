"""A Monte-Carlo study's definition (`Study`: what every worker needs to run any sample)
and its result table's type (`Columns`): what `maglevgen.analyses.montecarlo` runs and
`maglevgen.analyses.montecarlo_report` reports."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from maglevgen.control.operating import Weights
from maglevgen.params import SENSOR_TOLERANCES

__all__ = ["Columns", "Study"]

Columns = dict[str, np.ndarray]  # a table: one array per column, one row per run


@dataclass(frozen=True)
class Study:
    """Everything a worker needs to run any sample: small and picklable."""

    origin: str
    data: dict  # the validated parameter set (model_dump) the samples are drawn about
    # how a worker process gets the compiled library (`Plant.worker_library`: loaded once there)
    library: Callable[[], Any]
    names: tuple[str, ...]  # parameter vector entries
    p: tuple[float, ...]  # nominal parameter vector
    keys: tuple[str, ...]  # toleranced entries, in file order (parameters and sensors)
    sigma: tuple[float, ...]  # normal sigma, or NaN for a uniform one
    half: tuple[float, ...]  # uniform half-width (or the truncation for a normal)
    speed: tuple[float, float]
    disturbance: tuple[tuple[str, float], ...]
    controllers: tuple[str, ...]
    t_end: float
    dt: float
    min_gap: float
    weights: Weights
    seed: int
    # how the controller runs in every sample (maglevgen.analyses.simulate.simulate): its tick
    # (maglevgen.analyses.simulate.Tick; None: at every RK4 stage), the speed loop's k_v [N s/m],
    # the
    # per-array force budget [N] (None: no limit)
    tick: Any = None
    speed_gain: float = 0.0
    force_budget: float | None = None
    # True: each sample's controller re-designed for its own parameters (``--redesign``);
    # False: the nominal design at the sample's speed, as the firmware flies
    # (maglevgen.analyses.montecarlo's docstring)
    redesign: bool = False
    # per controller the nominal carriage's sampled region of attraction over the speed range
    # (maglevgen.analyses.roa at BUILD_SAMPLING, without boundary runs): (speeds, P / c per speed,
    # NaN where there is none), for each sample's ``region_multiple``
    regions: dict | None = None
    # the file's values of the toleranced entries beside p (maglevgen.params.LOOP_TOLERANCES:
    # the actuators' lag, the sensors' noises and biases): (key, value) pairs; a sample's
    # draws of them set its run's plant lag and readings (`sample_tick`)
    loop_values: tuple[tuple[str, float], ...] = ()

    @property
    def sensors(self) -> tuple[tuple[str, float], ...]:
        """The toleranced sensor entries of `loop_values` (SENSOR_TOLERANCES)."""
        return tuple((k, v) for k, v in self.loop_values if k in SENSOR_TOLERANCES)

    @property
    def columns(self) -> tuple[str, ...]:
        """The sampled inputs, in draw order: speed, disturbances, parameters."""
        return ("speed", *(f"disturbance.{s}" for s, _ in self.disturbance), *self.keys)
