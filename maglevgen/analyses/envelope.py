"""The operating envelope: where across [v_min, v_max] each controller keeps the carriage's
linearisation stable, and a verdict that never calls an unstable design good.

At each speed the trim, the Jacobians, the per-axis gains and the allocation come from the
generated C (maglevgen.control.operating); the coupled LQR is solved there by SciPy's CARE. The
eigenvalues are those of the ten-state closed loop (y, z, phi, theta, psi, v, w, p, q, r) with
the controller and the allocation closed around it: x drops out (nothing depends on it) and
the forward speed u is the scheduling variable held by the propulsion (its own mode under a
constant force is reported apart, as ``speed_pole``: `operating.SpeedMode`). See
maglevgen/control/operating.py.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import partial

import numpy as np

from maglevgen.analyses.loop import (
    LoopSetting,
    loop_design,
    loop_plant,
    loop_setting,
    loop_stability,
    tick_design_stability,
)
from maglevgen.analyses.sensing import SensingCheck, sensing_check
from maglevgen.carriage import DerivedCarriage
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.margins import DiskMargins, delay_margin, disk_gain_phase, disk_margins
from maglevgen.control.operating import (
    STABILITY_MARGIN,
    OperatingPoint,
    closed_loop_stability,
    speed_mode,
)
from maglevgen.control.plant import LoopDesign, LoopPlant
from maglevgen.control.sampled import Tick
from maglevgen.controllers import controller as registered_controller
from maglevgen.controllers import names as controller_names
from maglevgen.controllers import title as controller_title
from maglevgen.derive.structure import input_names_of
from maglevgen.errors import InputError
from maglevgen.params import ARRAY_FORCE_LAWS, CIRCUIT_DYNAMICS, LoadedParams

__all__ = ["DEFAULT_SPEEDS", "MAX_SPEEDS", "STABILITY_MARGIN", "Envelope", "LoopMargins",
           "alternate_models", "compute_envelope", "envelope_markdown", "loop_design",
           "loop_plant", "loop_setting", "speed_range"]

DEFAULT_SPEEDS = 50
MARGIN_SPEEDS = 5  # speeds of the grid (both ends among them) where the margins are computed
_EDGE_STEPS = 20  # bisections that locate the edge of a stable range between two grid speeds


def speed_range(carriage: DerivedCarriage) -> tuple[float, float]:
    """The speed range of ``carriage``'s plant (`Plant.speed_range`, through its compiled
    simulation library, cached on disk): what `maglevgen generate` bakes into the trim's
    checks and the firmware table spans."""
    return Plant(carriage).speed_range


@dataclass(frozen=True)
class SpecFailure:
    """One specification a controller misses: where (speed ranges of the grid) and how badly."""

    spec: str  # e.g. "damping ratio >= 0.5"
    ranges: tuple[tuple[float, float], ...]
    worst: float  # the measured value at the worst speed
    worst_speed: float
    unit: str = ""

    def text(self) -> str:
        spans = " and ".join(f"[{lo:.4g}, {hi:.4g}]" for lo, hi in self.ranges)
        unit = f" {self.unit}" if self.unit else ""
        return (f"FAILS {self.spec} for v in {spans} m/s ({self.worst:.4g}{unit} at "
                f"{self.worst_speed:.4g} m/s)")


@dataclass(frozen=True)
class ControllerEnvelope:
    """One controller across the speeds: the continuous linearisation's largest real part,
    smallest damping ratio, stability, unstable speed ranges and verdict; and the sampled-data
    loop's (`maglevgen.control.sampled`: the tick, its delay, the speed loop) against the
    specification, with the specification's verdict."""

    controller: str
    max_real: np.ndarray
    min_damping: np.ndarray
    stable: np.ndarray
    unstable_ranges: tuple[tuple[float, float], ...]
    verdict: str
    sampled_max_real: np.ndarray
    sampled_min_damping: np.ndarray
    spec_failures: tuple[SpecFailure, ...]
    spec_verdict: str
    # where the continuous `spec` design fails on the sampled loop: the design at the tick
    tick_design: TickDesignCheck | None = None
    # the levitation modes' largest real part on the loop as built (all but the speed loop's)
    levitation_real: np.ndarray | None = None
    # a controller designed at the tick: its continuous gains on the same loop (what the
    # host simulation's firmware loop ran before issue 50, and a plain `Tick` still runs)
    continuous_gains: TickDesignCheck | None = None
    margins: LoopMargins | None = None  # the embedded controller's, at MARGIN_SPEEDS speeds

    @property
    def ok(self) -> bool:
        """Stable on the continuous linearisation across the envelope."""
        return not self.unstable_ranges

    @property
    def meets_spec(self) -> bool:
        """Every specification met on the sampled-data loop across the envelope."""
        return not self.spec_failures

    def to_json(self) -> dict:
        return {"max_real": self.max_real.tolist(), "min_damping": self.min_damping.tolist(),
                "stable": self.stable.tolist(), "verdict": self.verdict,
                "unstable_ranges": [list(r) for r in self.unstable_ranges],
                "sampled_max_real": self.sampled_max_real.tolist(),
                "sampled_min_damping": self.sampled_min_damping.tolist(),
                "meets_spec": self.meets_spec, "spec_verdict": self.spec_verdict,
                "spec_failures": [{"spec": f.spec, "ranges": [list(r) for r in f.ranges],
                                   "worst": f.worst, "worst_speed": f.worst_speed}
                                  for f in self.spec_failures],
                # the gains the firmware's table would carry for this controller
                # (`Plant.tick_table_rows`: its design at the tick where it has one)
                "firmware_design": "tick" if registered_controller(self.controller).tick_design
                else "continuous",
                "tick_design": None if self.tick_design is None else self.tick_design.to_json(),
                "levitation_max_real": None if self.levitation_real is None
                else self.levitation_real.tolist(),
                "continuous_gains": None if self.continuous_gains is None
                else self.continuous_gains.to_json(),
                "margins": None if self.margins is None else self.margins.to_json()}


@dataclass(frozen=True)
class LoopMargins:
    """The embedded loop's margins broken at the actuators (`maglevgen.control.margins`) at a
    few speeds of the envelope: the balanced disk margin of every array force at once
    (multi-loop) and of each alone (loop at a time), and the delay margin in extra ticks."""

    speeds: np.ndarray
    multi: np.ndarray  # disk size alpha per speed
    per_loop: np.ndarray  # (n_speeds, n_channels) alpha
    delay: np.ndarray  # extra ticks the loop stays stable with, per speed
    channels: tuple[str, ...]  # the array force components (F_<axis><array>)
    curves: tuple[DiskMargins, ...]  # against frequency, per speed
    min_phase: float = 0.0  # [deg] control.spec.min_disk_phase_margin, for the figure

    def failures(self, spec) -> tuple[SpecFailure, ...]:
        """The margin specifications of ``spec`` (`ControlSpec`) missed, with their speeds."""
        gp = np.array([disk_gain_phase(a) for a in self.multi])
        out = []
        for text, unit, values, limit in (
                (f"multi-loop disk gain margin >= {spec.min_disk_gain_margin:g} dB", "dB",
                 gp[:, 0], spec.min_disk_gain_margin),
                (f"multi-loop disk phase margin >= {spec.min_disk_phase_margin:g} deg", "deg",
                 gp[:, 1], spec.min_disk_phase_margin),
                (f"delay margin >= {spec.min_delay_margin} extra ticks", "extra ticks",
                 self.delay.astype(float), spec.min_delay_margin)):
            bad = ~(values >= limit)
            if np.any(bad):
                worst = int(np.argmin(values))
                out.append(SpecFailure(text, grid_ranges(self.speeds, bad), float(values[worst]),
                                       float(self.speeds[worst]), unit))
        return tuple(out)

    def text(self) -> str:
        """The margins in one sentence: the worst speed of each."""
        i = int(np.argmin(self.multi))
        gm, pm = disk_gain_phase(float(self.multi[i]))
        worst = np.unravel_index(int(np.argmin(self.per_loop)), self.per_loop.shape)
        lgm, lpm = disk_gain_phase(float(self.per_loop[worst]))
        spans = f"{self.speeds[0]:.4g} to {self.speeds[-1]:.4g} m/s"
        return (f"disk margins at the actuators ({len(self.speeds)} speeds, {spans}): "
                f"multi-loop +-{gm:.3g} dB / {pm:.3g} deg at {self.speeds[i]:.4g} m/s, loop at "
                f"a time at least +-{lgm:.3g} dB / {lpm:.3g} deg ({self.channels[worst[1]]} at "
                f"{self.speeds[worst[0]]:.4g} m/s); delay margin {int(np.min(self.delay))} "
                "extra ticks")

    def to_json(self) -> dict:
        gp = [disk_gain_phase(a) for a in self.multi]
        return {"speeds": self.speeds.tolist(), "channels": list(self.channels),
                "multi_loop_alpha": self.multi.tolist(),
                "multi_loop_gain_db": [g for g, _ in gp],
                "multi_loop_phase_deg": [p for _, p in gp],
                "loop_at_a_time_alpha": self.per_loop.tolist(),
                "delay_margin_ticks": self.delay.tolist(), "text": self.text()}


def _stable_with_delay(plant: LoopPlant, gains: LoopDesign, extra: int) -> bool:
    """Whether ``plant``'s closed loop with ``gains`` and ``extra`` ticks of delay is stable."""
    return bool(np.max(np.abs(np.linalg.eigvals(plant.closed_loop(gains, extra)))) < 1)


def loop_margins(carriage, points: Sequence[OperatingPoint], controller: str,
                 setting: LoopSetting) -> LoopMargins:
    """`LoopMargins` of ``controller`` (its gains as `loop_design`) at ``points``."""
    curves, delays = [], []
    for op in points:
        plant, gains = loop_plant(op, setting), loop_design(op, controller, setting)
        curves.append(disk_margins(*plant.open_loop(gains), setting.tick.period))
        delays.append(delay_margin(partial(_stable_with_delay, plant, gains)))
    return LoopMargins(np.array([op.speed for op in points]),
                       np.array([c.multi for c in curves]),
                       np.array([c.per_loop for c in curves]), np.array(delays),
                       tuple(input_names_of(carriage.structure)[1:]), tuple(curves),
                       float(carriage.params.control.spec.min_disk_phase_margin))


@dataclass(frozen=True)
class TickDesignCheck:
    """The `spec` weights designed at the tick (`sampled.tick_design`: DARE on the ZOH model
    with the delay) on the same sampled-data loop, where the continuous design fails it."""

    max_real: np.ndarray
    min_damping: np.ndarray
    failures: tuple[SpecFailure, ...]
    verdict: str  # `spec_verdict_text` of this design

    @property
    def meets_spec(self) -> bool:
        return not self.failures

    def text(self, tick: Tick) -> str:
        """What the design at the tick achieves, and which design the firmware gets."""
        how = (f"designed at the tick (DARE on the ZOH model with {tick.delay} tick(s) of "
               "delay, the same weights)")
        said = (f"{how} it {self.verdict}" if self.meets_spec
                else f"{how} it also {self.verdict}")
        return (f"{said}; that design feeds back the commands in flight, which the generated "
                "loop (maglev_control_loop) does not: the firmware gets the continuous design")

    def to_json(self) -> dict:
        return {"method": "DARE on the ZOH model augmented with the delay, the spec weights",
                "max_real": self.max_real.tolist(), "min_damping": self.min_damping.tolist(),
                "meets_spec": self.meets_spec, "verdict": self.verdict,
                "spec_failures": [{"spec": f.spec, "ranges": [list(r) for r in f.ranges],
                                   "worst": f.worst, "worst_speed": f.worst_speed}
                                  for f in self.failures]}


@dataclass(frozen=True)
class Envelope:
    """Every controller's stability across the envelope's speeds."""

    speeds: np.ndarray
    v_min: float
    v_max: float
    controllers: dict[str, ControllerEnvelope]
    # the forward-speed mode under the trim propulsion [1/s], per speed: the speed eigenvalue
    # of the embedded controller's 12-state closed loop (`operating.SpeedMode`)
    speed_pole: np.ndarray
    loop: LoopSetting | None = None  # how the sampled-data verdicts ran the controllers
    model: str = ""  # the linearisation's model choices, in words
    # the embedded controller's gains on the alternate models (`model_checks`)
    other_models: tuple[ModelCheck, ...] = ()
    # the embedded controller's sensors, Kalman filter and whole loop with the estimator
    # (maglevgen.analyses.sensing; None: no [sensors], or the embedded controller not run)
    sensing: SensingCheck | None = None

    def checked_on(self) -> str:
        """The model and loop the specification verdicts were computed on, in words."""
        loop = "" if self.loop is None else f"; {self.loop.text()}"
        others = ", ".join(c.model for c in self.other_models)
        also = (f"; the embedded controller's gains also on the same loop with {others}"
                if others else "")
        return f"on the linearisation with {self.model}{loop}{also}"

    def firmware_design(self, name: str) -> str:
        """Which design of controller ``name`` (the embedded one) the firmware gets and why,
        in one sentence: the gains designed on the continuous linearisation, checked on the
        sampled-data loop; for a controller designed at the tick (`spec`), that design, which
        the firmware's ticks and the host's runs fly."""
        c = self.controllers.get(name)
        if c is None or self.loop is None:
            return (f"The firmware gets the {controller_title(name)} gains designed on the "
                    "continuous linearisation (not checked here on the sampled-data loop).")
        on = f"on the {self.loop.tick_text()}"
        if not registered_controller(name).tick_design:
            return (f"The firmware gets the {controller_title(name)} gains designed on the "
                    f"continuous linearisation, which {on} "
                    f"{'meet' if c.meets_spec else 'fail'} [control.spec].")
        cont = c.continuous_gains
        cont_said = "" if cont is None else (f"; the continuous {controller_title(name)} gains "
                                             f"on the same loop: {cont.verdict}")
        return (f"The {controller_title(name)} design is solved at the tick on the loop as "
                "built (DARE on the ZOH model with the delay and the actuator lag; gains on "
                "the state, the commands in flight and the actuator forces the controller "
                "predicts from its own commands), which "
                f"{'meets' if c.meets_spec else 'fails'} [control.spec] {on}. The firmware "
                "runs this design from its table, the commands in flight, the predicted "
                "actuator forces and the speed integral in a caller-owned state: its sense "
                "tick (maglev_sense_tick) on a Kalman filter's estimate from the readings, "
                "maglev_tick on the full state (ideal sensing, a reference); the host's runs "
                "(the judged holds and launch, the region's confirmations, Monte Carlo) fly "
                "the sense tick itself on the plant's noisy readings where the file has "
                "[sensors], else the same law (one C source) on the exact state, on the plant "
                f"with the actuator lag{cont_said}.")

    def robustness_verdict(self) -> str:
        """The embedded controller's gains on the other models, in one sentence."""
        return "; ".join(c.text() for c in self.other_models)

    @property
    def robust(self) -> bool:
        return all(c.ok for c in self.other_models)

    def to_json(self) -> dict:
        return {"speeds": self.speeds.tolist(), "v_min": self.v_min, "v_max": self.v_max,
                "stability_margin": STABILITY_MARGIN,
                "states": "y z phi theta psi v w p q r (x dropped; u held by the propulsion)",
                "controllers": {n: c.to_json() for n, c in self.controllers.items()},
                "speed_pole": self.speed_pole.tolist(),
                "spec_checked_on": self.checked_on(),
                "speed_loop_gain": None if self.loop is None else self.loop.speed_gain,
                "tick_rate": None if self.loop is None else self.loop.tick.rate,
                "delay_ticks": None if self.loop is None else self.loop.tick.delay,
                "actuator_lag": None if self.loop is None else self.loop.actuator_lag,
                "other_models": [{"model": c.model, "ok": c.ok, "verdict": c.text()}
                                 for c in self.other_models],
                "sensing": None if self.sensing is None else self.sensing.to_json()}


def _edge(plant: Plant, controller: str, v_stable: float, v_unstable: float) -> float:
    """The speed between a stable and an unstable grid speed where stability is lost."""
    a, b = v_stable, v_unstable
    for _ in range(_EDGE_STEPS):
        mid = 0.5 * (a + b)
        op = plant.point(mid)
        if closed_loop_stability(op, controller)[0] < -STABILITY_MARGIN:
            a = mid
        else:
            b = mid
    return b


def unstable_ranges(plant: Plant, controller: str, speeds: np.ndarray,
                    stable: np.ndarray) -> tuple[tuple[float, float], ...]:
    """The speed intervals where the closed loop is unstable, edges located by bisection."""
    ranges = []
    i, n = 0, len(speeds)
    while i < n:
        if stable[i]:
            i += 1
            continue
        j = i
        while j + 1 < n and not stable[j + 1]:
            j += 1
        lo = speeds[i] if i == 0 else _edge(plant, controller, speeds[i - 1], speeds[i])
        hi = speeds[j] if j == n - 1 else _edge(plant, controller, speeds[j + 1], speeds[j])
        ranges.append((float(lo), float(hi)))
        i = j + 1
    return tuple(ranges)


def verdict_text(controller: str, speeds: np.ndarray, max_real: np.ndarray,
                 ranges: tuple[tuple[float, float], ...]) -> str:
    """"stable across [a, b] m/s ..." or "UNSTABLE for v in [a, b] m/s ..."."""
    worst = int(np.argmax(max_real))
    where = f"largest real part {max_real[worst]:+.4g} 1/s at {speeds[worst]:.4g} m/s"
    if not ranges:
        return f"stable across [{speeds[0]:.4g}, {speeds[-1]:.4g}] m/s ({where})"
    spans = " and ".join(f"[{lo:.4g}, {hi:.4g}]" for lo, hi in ranges)
    return f"UNSTABLE for v in {spans} m/s ({where})"


def grid_ranges(speeds: np.ndarray, bad: np.ndarray) -> tuple[tuple[float, float], ...]:
    """The runs of consecutive grid speeds where ``bad`` holds, as (first, last) speeds."""
    out, i, n = [], 0, len(speeds)
    while i < n:
        if not bad[i]:
            i += 1
            continue
        j = i
        while j + 1 < n and bad[j + 1]:
            j += 1
        out.append((float(speeds[i]), float(speeds[j])))
        i = j + 1
    return tuple(out)


def tick_design_check(carriage, speeds: np.ndarray, points: Sequence[OperatingPoint],
                      setting: LoopSetting) -> TickDesignCheck:
    """`tick_design_stability` at ``points`` against ``[control.spec]``."""
    sd = np.array([tick_design_stability(op, setting) for op in points])
    failures = spec_failures(carriage, speeds, sd[:, 0], sd[:, 1])
    return TickDesignCheck(sd[:, 0], sd[:, 1], failures,
                           spec_verdict_text(speeds, failures, sd[:, 0], sd[:, 1]))


def spec_failures(carriage, speeds: np.ndarray, max_real: np.ndarray,
                  min_damping: np.ndarray, levitation_real: np.ndarray | None = None
                  ) -> tuple[SpecFailure, ...]:
    """The specifications of ``[control.spec]`` that the loop misses, with their ranges
    (``levitation_real``: the levitation modes' largest real part, checked against
    min_levitation_decay_rate)."""
    spec = carriage.params.control.spec
    lev = () if levitation_real is None else (
        (f"levitation decay rate >= {spec.min_levitation_decay_rate:g} 1/s", "", "1/s",
         -levitation_real, ~(-levitation_real >= spec.min_levitation_decay_rate),
         np.nanargmin),)
    checks = (
        ("stability", "largest real part", "1/s", max_real, ~(max_real < -STABILITY_MARGIN),
         np.nanargmax),
        (f"damping ratio >= {spec.min_damping_ratio:g}", "", "", min_damping,
         ~(min_damping >= spec.min_damping_ratio), np.nanargmin),
        (f"decay rate >= {spec.min_decay_rate:g} 1/s", "", "1/s", -max_real,
         ~(-max_real >= spec.min_decay_rate), np.nanargmin), *lev)
    out = []
    for text, what, unit, values, bad, pick in checks:
        if np.any(bad):
            finite = np.where(np.isfinite(values), values, np.nan)
            worst = int(pick(finite)) if np.any(np.isfinite(finite)) else int(np.argmax(bad))
            out.append(SpecFailure(text, grid_ranges(speeds, bad), float(values[worst]),
                                   float(speeds[worst]), f"{unit} {what}".strip()
                                   if what else unit))
    return tuple(out)


def spec_verdict_text(speeds: np.ndarray, failures: tuple[SpecFailure, ...],
                      max_real: np.ndarray, min_damping: np.ndarray,
                      levitation_real: np.ndarray | None = None,
                      speed_real: np.ndarray | None = None) -> str:
    """"meets the specification across [a, b] m/s (...)" or the failures, "; "-separated;
    the slowest decay per loop (levitation, speed loop) where ``levitation_real`` and
    ``speed_real`` give each loop's largest real part."""
    if failures:
        return "; ".join(f.text() for f in failures)
    decay = f"slowest decay {-np.max(max_real):.4g} 1/s"
    if levitation_real is not None:
        decay = f"slowest decay per loop: levitation {-np.max(levitation_real):.4g} 1/s"
        if speed_real is not None and np.all(np.isfinite(speed_real)):
            decay += f", speed loop {-np.max(speed_real):.4g} 1/s"
    return (f"meets the specification across [{speeds[0]:.4g}, {speeds[-1]:.4g}] m/s "
            f"(smallest damping ratio {np.nanmin(min_damping):.3g}, {decay})")


@dataclass(frozen=True)
class ModelCheck:
    """The embedded controller's gains (designed on the carriage's model) on another model
    of the same carriage: the specification's failures there."""

    model: str  # e.g. "model.array_force = point"
    failures: tuple[SpecFailure, ...]

    @property
    def ok(self) -> bool:
        return not self.failures

    def text(self) -> str:
        if self.ok:
            return f"meets it with {self.model}"
        return f"with {self.model}: " + "; ".join(f.text() for f in self.failures)


# the model choices the embedded controller's gains are also checked on (model.<key>)
MODEL_CHOICES: tuple[tuple[str, tuple[str, ...]], ...] = (("array_force", ARRAY_FORCE_LAWS),
                                                          ("circuit_dynamics", CIRCUIT_DYNAMICS))


def alternate_models(carriage) -> list[tuple[str, DerivedCarriage]]:
    """(label, carriage) for each other value of each model choice, one change at a time."""
    params, out = carriage.params, []
    for key, choices in MODEL_CHOICES:
        for value in choices:
            if value == getattr(params.model, key):
                continue
            changed = params.model_copy(update={"model": params.model.model_copy(
                update={key: value})})
            loaded = carriage.loaded
            out.append((f"model.{key} = {value}", DerivedCarriage(LoadedParams(
                changed, loaded.source, loaded.sha256,
                (*loaded.overrides, f'model.{key}="{value}"')))))
    return out


def model_checks(plant: Plant, controller: str, points: Sequence[OperatingPoint],
                 setting: LoopSetting) -> tuple[ModelCheck, ...]:
    """``controller``'s gains at ``points`` on each alternate model's sampled-data loop at the
    same speeds (each model's own trim and Jacobians, from its own compiled library: the
    plant's `Plant.with_model`)."""
    carriage = plant.carriage
    speeds = np.array([op.speed for op in points])
    out = []
    for label, alt in alternate_models(carriage):
        try:
            alt_points = plant.with_model(alt.params.model.array_force,
                                          alt.params.model.circuit_dynamics).points(speeds)
        except InputError as exc:
            out.append(ModelCheck(label, (SpecFailure(f"a trim ({exc})", ((speeds[0],
                                                                          speeds[-1]),),
                                                      float("nan"), float(speeds[0])),)))
            continue
        sd = np.array([loop_stability(a, controller, setting, design=op)
                       for a, op in zip(alt_points, points, strict=True)])
        out.append(ModelCheck(label, spec_failures(carriage, speeds, sd[:, 0], sd[:, 1],
                                                   sd[:, 2])))
    return tuple(out)


#: the most speeds of an envelope (`maglevgen envelope --speeds`)
MAX_SPEEDS = 100_000


def compute_envelope(plant: Plant, n_speeds: int = DEFAULT_SPEEDS,
                     controllers: Sequence[str] | None = None,
                     other_models: bool = True) -> Envelope:
    """Each controller's stability at ``n_speeds`` speeds spanning [v_min, v_max], on the
    continuous linearisation and, against ``[control.spec]``, on the sampled-data loop;
    ``other_models``: the embedded controller's gains also on each alternate model
    (`model_checks`). ``controllers``: default every registered one."""
    if not 2 <= n_speeds <= MAX_SPEEDS:
        raise InputError(f"--speeds {n_speeds}: expected 2 to {MAX_SPEEDS} speeds")
    carriage, lib = plant.carriage, plant.lib
    v_min, v_max = plant.speed_range
    speeds = np.linspace(v_min, v_max, n_speeds)
    points = plant.points(speeds)
    setting = plant.setting(points)
    out = {}
    embedded = carriage.params.envelope.embedded_controller
    chosen = controller_names() if controllers is None else tuple(controllers)
    for c in chosen:
        rows = np.array([closed_loop_stability(op, c) for op in points])
        max_real, min_damping = rows[:, 0], rows[:, 1]
        stable = max_real < -STABILITY_MARGIN
        ranges = unstable_ranges(plant, c, speeds, stable)
        # the loop as built: the tick, its delay, the actuator lag, the speed loop
        sd = np.array([loop_stability(op, c, setting) for op in points])
        failures = spec_failures(carriage, speeds, sd[:, 0], sd[:, 1], sd[:, 2])
        margins = None
        if c == embedded:
            pick = np.unique(np.linspace(0, len(points) - 1, MARGIN_SPEEDS).round().astype(int))
            margins = loop_margins(carriage, [points[i] for i in pick], c, setting)
            failures += margins.failures(carriage.params.control.spec)
        said = spec_verdict_text(speeds, failures, sd[:, 0], sd[:, 1], sd[:, 2], sd[:, 3])
        if margins is not None and not failures:
            said += f"; {margins.text()}"
        continuous = None
        if registered_controller(c).tick_design:
            cd = np.array([loop_stability(op, c, setting, continuous=True) for op in points])
            cf = spec_failures(carriage, speeds, cd[:, 0], cd[:, 1], cd[:, 2])
            continuous = TickDesignCheck(cd[:, 0], cd[:, 1], cf, spec_verdict_text(
                speeds, cf, cd[:, 0], cd[:, 1], cd[:, 2], cd[:, 3]))
        out[c] = ControllerEnvelope(c, max_real, min_damping, stable, ranges,
                                    verdict_text(c, speeds, max_real, ranges), sd[:, 0],
                                    sd[:, 1], failures, said, None, sd[:, 2], continuous,
                                    margins)
    mass = carriage.params.vehicle.mass
    speed_poles = [speed_mode(lib, carriage.p, op, mass, embedded).eigenvalue for op in points]
    checks = (model_checks(plant, embedded, points, setting)
              if other_models and embedded in chosen else ())
    sensing = None
    if carriage.params.sensors is not None and embedded in chosen:
        def design_or_none(op: OperatingPoint) -> LoopDesign | None:
            try:
                return loop_design(op, embedded, setting)
            except (np.linalg.LinAlgError, ValueError):
                return None

        def judge(sd: np.ndarray) -> tuple[tuple[SpecFailure, ...], str]:
            f = spec_failures(carriage, speeds, sd[:, 0], sd[:, 1], sd[:, 2])
            return f, spec_verdict_text(speeds, f, sd[:, 0], sd[:, 1], sd[:, 2], sd[:, 3])

        sensing = sensing_check(plant, points, setting, embedded,
                                [(loop_plant(op, setting), design_or_none(op))
                                 for op in points], judge)
    m = carriage.params.model
    model = f"the {m.array_force} force law and {m.circuit_dynamics} circuits"
    return Envelope(speeds, v_min, v_max, out, np.array(speed_poles), setting, model, checks,
                    sensing)


def envelope_markdown(env: Envelope) -> str:
    """The verdicts and a table of the largest real part per controller at a few speeds."""
    lines = ["# Operating envelope", "",
             f"Speeds {env.v_min:.4g} to {env.v_max:.4g} m/s ({env.speeds.size} speeds). "
             "Eigenvalues of the ten-state linearisation (y, z, phi, theta, psi, v, w, p, q, r) "
             "at the trim at each speed with the controller and the allocation closed around "
             "it; x drops out, the forward speed is held by the propulsion. Stable: every real "
             f"part below -{STABILITY_MARGIN:g} 1/s.", "",
             "| controller | verdict |", "| --- | --- |"]
    lines += [f"| {controller_title(n)} (`{n}`) | {c.verdict} |"
              for n, c in env.controllers.items()]
    pick = np.unique(np.linspace(0, env.speeds.size - 1, min(11, env.speeds.size)).astype(int))
    names = list(env.controllers)
    lines += ["", "Largest real part [1/s] (smallest damping ratio):", "",
              "| speed [m/s] | " + " | ".join(f"`{n}`" for n in names) + " |",
              "| --- |" + " --- |" * len(names)]
    for i in pick:
        cells = [f"{env.controllers[n].max_real[i]:+.4f} ({env.controllers[n].min_damping[i]:.3f})"
                 for n in names]
        lines.append(f"| {env.speeds[i]:.3f} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"

