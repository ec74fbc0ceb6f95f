"""The carriage's plant: ONE object per carriage and model choice that every analysis, export
and report section takes instead of (carriage, library, ...).

A `Plant` holds the carriage, its compiled simulation library (loaded once, on first use), the
envelope's speed range (resolved once), the operating points at the speeds asked for (each
solved once), the loop as the firmware builds it (`built_loop.LoopSetting`: tick, delay,
actuator lag, speed loop, budget; built once over the schedule's nodes), the firmware's gain
table and the launch schedule; `with_model` gives the same plant with another force law or
circuit model (its own library).

Not to be confused with `maglevgen.control.plant.LoopPlant`: the linear loop as built at ONE
operating point (what the tick design is solved on and the eigenvalues close); a `Plant` makes
one of those per point (`loop_plant`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import cached_property, partial
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from maglevgen.control.built_loop import LoopSetting, loop_design, loop_plant, loop_setting
from maglevgen.control.operating import OperatingPoint, Weights, checked_trim, operating_point
from maglevgen.control.plant import LoopPlant
from maglevgen.control.schedule import (
    GainTable,
    Reference,
    Schedule,
    accelerating_references,
    gain_table_row,
    tick_table_fields,
)
from maglevgen.derive.search import lowest_trim_speed
from maglevgen.errors import InputError, NoTrimError
from maglevgen.runtime.library import (
    SimulationLibrary,
    loaded_library,
    runtime_sources,
    simulation_library,
)

if TYPE_CHECKING:
    from maglevgen.carriage import DerivedCarriage
    from maglevgen.params import Parameters

__all__ = ["Plant", "lift_off_speed"]

#: the most operating points a plant keeps (an envelope of up to 100 000 speeds holds its own
#: list while it runs; the plant of a long-lived `maglevgen.Carriage` keeps no more than this)
MAX_CACHED_POINTS = 4096


def _quiet(_: str) -> None:
    pass


def lift_off_speed(lib: SimulationLibrary, p: np.ndarray, min_gap: float,
                   v_hi: float, v_limit: float | None = None) -> float:
    """The lowest speed with a trim (the Newton solve in C converges and every gap is above
    track.min_gap), by bisection between 0 and ``v_hi`` (derive.search). ``v_limit``: when
    ``v_hi`` has no trim, the search goes on at 4, 16, ... times ``v_hi`` up to it (inf when
    none has one); None: an InputError naming envelope.v_max instead."""
    def has_trim(v: float) -> bool:
        try:
            checked_trim(lib, p, v, min_gap)
        except NoTrimError:
            return False
        return True

    v = lowest_trim_speed(has_trim, 0.0, v_hi, v_hi if v_limit is None else v_limit, grow=4.0)
    if v == float("inf") and v_limit is None:
        raise InputError(f"envelope.v_max = {v_hi:g}: the carriage has no trim at this speed "
                         "(see `maglevgen trim --speed`)")
    return v


class Plant:
    """One carriage and model choice with its library, speed range, operating points, loop as
    built, gain table and launch schedule, each built once.

    Parameters
    ----------
    carriage : DerivedCarriage
        The carriage (its parameters and model choice).
    lib : SimulationLibrary, optional
        Its compiled simulation library; default: `simulation_library` of its structure,
        generated or reused (cached on disk) on first use.
    progress : callable, optional
        Where the library's generation and compilation report their steps.
    cache_dir, cc : optional
        The cache folder and C compiler the library is built with (defaults: the usual).
    """

    def __init__(self, carriage: DerivedCarriage, lib: SimulationLibrary | None = None,
                 progress: Callable[[str], None] = _quiet, cache_dir: Path | None = None,
                 cc: str | None = None) -> None:
        self.carriage = carriage
        self._lib = lib
        self._progress, self._cache_dir, self._cc = progress, cache_dir, cc
        self._points: dict[float, OperatingPoint] = {}
        self._models: dict[tuple[str, str], Plant] = {}

    def __repr__(self) -> str:
        m = self.params.model
        return f"Plant({self.carriage.loaded.source!r}, {m.array_force}, {m.circuit_dynamics})"

    # ------------------------------------------------------------------ what it holds

    @property
    def lib(self) -> SimulationLibrary:
        """The compiled simulation library (loaded on first use, then kept)."""
        if self._lib is None:
            self._lib = simulation_library(self.carriage.structure, cache_dir=self._cache_dir,
                                           cc=self._cc, progress=self._progress)
        return self._lib

    @property
    def worker_library(self) -> Callable[[], SimulationLibrary]:
        """How another process gets this library: a picklable call that loads it there once
        (from the same cache, with the same compiler) and then reuses it."""
        return partial(loaded_library, self.carriage.structure, self._cache_dir, self._cc)

    def runtime_sources(self, precision: str = "double", cache_dir: Path | None = None,
                        progress: Callable[[str], None] | None = None) -> Path:
        """The folder of the library's run-time-parameter C at ``precision`` (generated or
        reused; ``cache_dir`` and ``progress`` default to this plant's)."""
        return runtime_sources(self.carriage.structure, precision,
                               self._cache_dir if cache_dir is None else cache_dir,
                               self._progress if progress is None else progress)

    @property
    def loaded(self) -> bool:
        """Whether the library is loaded yet."""
        return self._lib is not None

    @property
    def params(self) -> Parameters:
        return self.carriage.params

    @property
    def p(self) -> np.ndarray:
        """The parameter vector the generated functions take."""
        return self.carriage.p

    @property
    def min_gap(self) -> float:
        return float(self.params.track.min_gap)

    @cached_property
    def speed_range(self) -> tuple[float, float]:
        """(v_min, v_max) of the parameter file's envelope, v_min from the lift-off speed when
        the file omits it ((1 + lift_off_margin) x lift-off); an InputError naming the key
        when the range has no trim."""
        env = self.params.envelope
        if env.v_min is not None:
            for key, v in (("envelope.v_min", env.v_min), ("envelope.v_max", env.v_max)):
                try:
                    checked_trim(self.lib, self.p, v, self.min_gap)
                except NoTrimError:
                    raise InputError(f"{key} = {v:g}: the carriage has no trim at this speed "
                                     "(below lift-off?); see `maglevgen trim --speed`") from None
            return float(env.v_min), float(env.v_max)
        v_lift = lift_off_speed(self.lib, self.p, self.min_gap, env.v_max)
        v_min = (1 + env.lift_off_margin) * v_lift
        if not v_min < env.v_max:
            raise InputError(f"envelope.v_max = {env.v_max:g}: not above the default v_min "
                             f"{v_min:.4g} m/s ((1 + lift_off_margin) x lift-off {v_lift:.4g} "
                             "m/s)")
        return v_min, float(env.v_max)

    # ------------------------------------------------------------- operating points

    def points(self, speeds: Sequence[float] | np.ndarray) -> list[OperatingPoint]:
        """Operating points at ``speeds`` (trim, gains, Jacobians: the generated C), each
        solved once per plant (up to MAX_CACHED_POINTS kept); an InputError where one has no
        trim."""
        out = []
        for v in speeds:
            key = float(v)
            op = self._points.get(key)
            if op is None:
                try:
                    op = operating_point(self.lib, self.p, key, self.min_gap,
                                         Weights.of(self.params))
                except NoTrimError as exc:
                    raise InputError(f"envelope: {exc}") from None
                if len(self._points) < MAX_CACHED_POINTS:
                    self._points[key] = op
            out.append(op)
        return out

    def point(self, speed: float) -> OperatingPoint:
        """The operating point at ``speed`` (`points`)."""
        (op,) = self.points([speed])
        return op

    def schedule_speeds(self) -> np.ndarray:
        """The schedule's nodes: envelope.schedule_nodes speeds spanning the speed range."""
        v_min, v_max = self.speed_range
        return np.linspace(v_min, v_max, self.params.envelope.schedule_nodes)

    # ------------------------------------------------------------------ the loop

    def setting(self, points: Sequence[OperatingPoint]) -> LoopSetting:
        """The loop as built with its speed loop's gains over ``points`` (`loop_setting`)."""
        return loop_setting(self.carriage, points)

    @cached_property
    def loop(self) -> LoopSetting:
        """The loop the firmware runs (`loop_setting` over the schedule's nodes: its tick,
        delay, actuator lag, speed loop and its clamp, force budget): what the firmware
        folder, the FMU's "firmware" start values and `simulate --loop firmware` fly."""
        return self.setting(self.points(self.schedule_speeds()))

    def loop_plant(self, op: OperatingPoint, setting: LoopSetting | None = None) -> LoopPlant:
        """The linear loop as built at ``op`` (default ``setting``: `loop`)."""
        return loop_plant(op, setting or self.loop)

    # ------------------------------------------------- the gain table and the launch

    def tick_table_rows(self, setting: LoopSetting,
                        speeds: Sequence[float] | np.ndarray) -> np.ndarray:
        """The firmware table's exact rows at ``speeds`` (`schedule.tick_table_fields`): the
        trim and the embedded controller's design at the tick on the loop as built
        (`loop_design`)."""
        embedded = self.params.envelope.embedded_controller
        return np.array([gain_table_row(op, embedded, loop_design(op, embedded, setting),
                                        setting.tick.delay)
                         for op in self.points(speeds)])

    def gain_table(self, v_min: float | None = None, v_max: float | None = None,
                   setting: LoopSetting | None = None) -> GainTable:
        """The firmware's table schedule over [v_min, v_max] (default: the speed range)
        fitted to the exact schedule (`tick_table_rows` on ``setting``'s loop, default
        `loop`); its manifest() is what c/manifest.json and the report show."""
        if v_min is None or v_max is None:
            v_min, v_max = self.speed_range
        chosen = setting or self.loop
        return GainTable.fit(lambda vs: self.tick_table_rows(chosen, vs), v_min, v_max,
                             tick_table_fields(chosen.tick.delay))

    def launch_references(self, points: Sequence[OperatingPoint]) -> list[Reference]:
        """`accelerating_references` at envelope.launch_acceleration for ``points``;
        InputError (naming the key) where the carriage has no accelerating trim."""
        prm = self.params
        a = prm.envelope.launch_acceleration
        try:
            return accelerating_references(self.lib, self.p, list(points), a,
                                           prm.vehicle.mass, prm.track.min_gap)
        except NoTrimError as exc:
            raise InputError(f"envelope.launch_acceleration = {a:g}: {exc}") from None

    def launch_schedule(self, points: Sequence[OperatingPoint], controller: str,
                        references: list[Reference] | None = None,
                        setting: LoopSetting | None = None) -> Schedule:
        """The launch's schedule of ``controller`` at ``points``: the reference and the
        propulsion feedforward of the accelerating trim at envelope.launch_acceleration
        (`launch_references`), the gains of the constant-speed linearisation (the points'):
        the controller's continuous gains, or with ``setting`` its gains on that loop as
        built (`loop_design`: the design at the tick with K_lag and K_delay)."""
        a = self.params.envelope.launch_acceleration
        refs = self.launch_references(points) if references is None else references
        designs = None if setting is None else [loop_design(op, controller, setting)
                                                for op in points]
        return Schedule.from_points(list(points), controller, refs, a, designs)

    # ------------------------------------------------------------- model choices

    def with_model(self, array_force: str | None = None, circuit_dynamics: str | None = None,
                   progress: Callable[[str], None] | None = None) -> Plant:
        """The same plant with model.array_force and/or model.circuit_dynamics changed (its
        own derivation and library, built once per plant); itself when nothing changes.
        ``progress``: where that library's steps are announced (default: this plant's), when
        this call first makes it."""
        m = self.params.model
        key = (array_force or m.array_force, circuit_dynamics or m.circuit_dynamics)
        if key == (m.array_force, m.circuit_dynamics):
            return self
        if key not in self._models:
            other = self.carriage.with_array_force(key[0]).with_circuit_dynamics(key[1])
            self._models[key] = Plant(other, progress=progress or self._progress,
                                      cache_dir=self._cache_dir, cc=self._cc)
        return self._models[key]

    def with_carriage(self, carriage: DerivedCarriage) -> Plant:
        """A plant of another carriage (another model choice built elsewhere, e.g.
        `envelope.alternate_models`) with this one's library settings."""
        return Plant(carriage, progress=self._progress, cache_dir=self._cache_dir, cc=self._cc)
