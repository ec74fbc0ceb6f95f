"""The loop as the firmware builds it, in ONE type (`LoopSetting`, a `Tick`): its tick and
delay, the actuator lag, the speed loop's gains and the integral's clamp, the force budget; and
what each consumer reads from it: a host run's tick (the run takes the loop itself), the C
loop's struct (`control_loop`, maglev_control_loop), the controller's gains on that loop
(`loop_design`).
How a run executes its controller is a `Loop` (the API's and CLI's ``loop`` strings are its
values, parsed there; below the API a run takes the member).

`maglevgen.control.plant.LoopPlant` is this loop linearised at one operating point;
`maglevgen.control.carriage_plant.Plant` builds the one `LoopSetting` of a carriage (over the
schedule's nodes) and hands it to every analysis and export.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING

import numpy as np

from maglevgen.control.operating import OperatingPoint
from maglevgen.control.plant import LoopDesign, LoopPlant, speed_loop_gains
from maglevgen.control.registry import controller as registered_controller
from maglevgen.control.sampled import Tick
from maglevgen.errors import InputError
from maglevgen.runtime.runs import ControlLoop
from maglevgen.runtime.sense import Sensing

if TYPE_CHECKING:
    from maglevgen.carriage import DerivedCarriage

__all__ = ["Loop", "LoopSetting", "control_loop", "flown_controllers", "loop_design",
           "loop_plant", "loop_setting"]


class Loop(str, Enum):
    """How a run executes its controller: ``FIRMWARE`` the loop as built on the exact state
    (`Plant.loop`: the tick and delay of [control.spec], the actuator lag, the speed loop, the
    force budget, each controller's gains on that loop); ``SENSED`` that loop on the sensors'
    readings (the embedded controller's sense tick); ``CONTINUOUS`` the paper's law at every
    RK4 stage. The values are the ``--loop`` strings of the API and the CLI, which parse them;
    every function below the API takes the member."""

    FIRMWARE = "firmware"
    SENSED = "sensed"
    CONTINUOUS = "continuous"

    def __str__(self) -> str:  # its string, as a str (enum.StrEnum is Python 3.11's)
        return str(self.value)

    def __format__(self, spec: str) -> str:
        return format(str(self.value), spec)


def flown_controllers(loop: Loop, controllers: Sequence[str], embedded: str,
                      all_asked: bool = False) -> tuple[str, ...]:
    """The controllers a run on ``loop`` flies: ``controllers``, except on the sensors, where
    the firmware's sense tick flies the ``embedded`` controller alone (its tables are that
    one's): asked for all (``all_asked``), that one; asked for another, an InputError."""
    if loop is not Loop.SENSED:
        return tuple(controllers)
    if all_asked:
        return (embedded,)
    others = [c for c in controllers if c != embedded]
    if others:
        raise InputError(f"--loop sensed: the firmware's sense tick flies the embedded "
                         f"controller ({embedded!r}, envelope.embedded_controller), not "
                         f"{', '.join(map(repr, others))}; --loop firmware runs any "
                         "controller on the exact state")
    return tuple(controllers)


@dataclass(frozen=True)
class LoopSetting(Tick):
    """How the firmware runs every controller, in one type: its tick (`Tick`: ``rate`` [Hz]
    and ``delay`` [ticks]), each array force's first-order ``lag`` [s] in the plant
    ([actuators] time_constant; 0: none), the speed error's integral gain ``speed_integral``
    [N/m] with the propulsion's |k_i xi| clamped at ``integral_limit`` [N] (the C tick's
    anti-windup; inf: none), the speed loop's gain ``speed_gain`` [N s/m] (one value over the
    envelope) and the speed pole ``bandwidth`` [1/s] it guarantees at least, the per-array
    ``force_budget`` [N] (control.spec.force_budget; inf: none).

    A run at a LoopSetting runs the firmware tick's law (templates/maglev_tick_law.c.j2) with
    each controller's gains on this loop (`loop_design`: the design at the tick where the
    controller has one); a run at a plain `Tick` runs the controller's continuous gains on the
    plant without the lag (the host loop before issue 50)."""

    lag: float = 0.0  # [s]
    speed_integral: float = 0.0  # [N/m]
    integral_limit: float = float("inf")  # [N]
    speed_gain: float = 0.0  # [N s/m]
    bandwidth: float = 0.0  # [1/s]
    force_budget: float = float("inf")  # [N] per array
    # [s] the plant's lag where it is not the ``lag`` the firmware was designed for (a
    # Monte-Carlo sample's drawn [actuators] time_constant); None: ``lag``
    plant_lag: float | None = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.plant_lag is not None and not (
                isinstance(self.plant_lag, (int, float)) and np.isfinite(self.plant_lag)
                and self.plant_lag > 0):
            raise InputError(f"the plant's actuator lag {self.plant_lag!r} s: must be a "
                             "finite number > 0")
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

    def tick_text(self) -> str:
        """"sampled-data loop at <rate> Hz with <n> tick(s) of delay[ and a <tau> ms actuator
        lag]"."""
        delay = f"{self.delay} tick{'s' if self.delay != 1 else ''} of delay"
        lag = (f" and a {self.lag * 1e3:.3g} ms actuator lag" if self.lag > 0
               else ", instant actuators")
        return f"sampled-data loop at {self.rate:g} Hz with {delay}{lag}"

    def text(self) -> str:
        integral = (f", k_i = {self.speed_integral:.4g} N/m (|k_i xi| <= "
                    f"{self.integral_limit:.4g} N)" if self.speed_integral > 0 else "")
        return (f"{self.tick_text()}, zero-order hold, speed loop k_v = "
                f"{self.speed_gain:.4g} N s/m{integral}")

    # ------------------------------------------------- what the firmware and the FMU read

    @property
    def tick(self) -> Tick:
        """The tick alone (rate and delay)."""
        return Tick(self.rate, self.delay)

    @property
    def flown_lag(self) -> float:
        """[s] the plant's lag: ``plant_lag`` where given, else the design's ``lag``."""
        return float(self.lag if self.plant_lag is None else self.plant_lag)

    @property
    def actuator_lag(self) -> float:
        """[s] ``lag``, by its name in [actuators]."""
        return self.lag

    @property
    def speed_integral_limit(self) -> float:
        """[N] ``integral_limit``, by its name in [control.spec]."""
        return self.integral_limit

    @property
    def tick_rate(self) -> float:
        """[Hz]"""
        return float(self.rate)

    @property
    def delay_ticks(self) -> int:
        """Ticks from computing a command to applying it."""
        return int(self.delay)

    @property
    def c_integral_limit(self) -> float:
        """The limit the C tick clamps |k_i xi| at: the given one, 0 without an integral."""
        return float(self.integral_limit) if self.speed_integral > 0 else 0.0

    @property
    def lag_pole(self) -> float:
        """a = exp(-h/tau): the lag over one held tick (0 without a lag; `plant.LoopPlant`)."""
        return float(np.exp(-1.0 / (self.tick_rate * self.lag))) if self.lag > 0 else 0.0

    def check_embeddable(self) -> None:
        """ValueError where the C tick cannot run it: a speed integral without a finite
        clamp."""
        if self.speed_integral > 0 and not np.isfinite(self.integral_limit):
            raise ValueError("the firmware's speed integral needs a finite limit "
                             f"(speed_integral_limit {self.integral_limit!r} N)")

    def control_loop(self, dt: float, v_ref: float, accel: float = 0.0,
                     design: LoopDesign | None = None) -> ControlLoop | None:
        """The C loop's struct (maglev_control_loop) of this loop at the RK4 step ``dt``
        (`control_loop` with its speed gain and force budget)."""
        return control_loop(dt, self, self.speed_gain, self.force_budget, v_ref, accel, design)


def loop_setting(carriage: DerivedCarriage, points: Sequence[OperatingPoint]) -> LoopSetting:
    """The tick of ``[control.spec]`` and the speed loop's gains (`plant.speed_loop_gains`
    with control.spec.speed_integral_ratio r): one constant (k_v, k_i) over the points, k_v
    the largest over them, so that the loop m s^2 + (slope + k_v) s + k_i has its poles at
    -speed_bandwidth and -r speed_bandwidth where the drag slope is lowest (r = 0: the one
    pole, at least as fast as speed_bandwidth at every speed); the integral clamped at
    control.spec.speed_integral_limit; control.spec.force_budget per array."""
    spec, mass = carriage.params.control.spec, carriage.params.vehicle.mass
    k_v, k_i = max(speed_loop_gains(mass, op.trim_drag_slope, spec.speed_bandwidth,
                                    spec.speed_integral_ratio) for op in points)
    tick = Tick.of(carriage.params)
    return LoopSetting(tick.rate, tick.delay, float(carriage.params.actuators.time_constant),
                       k_i, float(spec.speed_integral_limit), k_v, float(spec.speed_bandwidth),
                       float(spec.force_budget))


def loop_plant(op: OperatingPoint, setting: LoopSetting) -> LoopPlant:
    """The loop as built at ``op`` (`plant.LoopPlant`: tick, delay, actuator lag, speed loop)."""
    return LoopPlant(op, setting.tick, setting.lag, setting.speed_gain, setting.speed_integral)


def loop_design(op: OperatingPoint, controller: str, setting: LoopSetting,
                continuous: bool = False) -> LoopDesign:
    """``controller``'s gains on the loop as built: its design at the tick on `loop_plant`
    (the controller's ``tick_design``, unless ``continuous``), else its continuous gains (no
    feedback of the commands in flight or of the actuators). ValueError / LinAlgError where
    the DARE has no stabilizing solution."""
    c = registered_controller(controller)
    if c.tick_design and c.weights is not None and not continuous:
        return loop_plant(op, setting).design(c.weights)
    return LoopDesign(*op.gains(controller))


def control_loop(dt: float, tick: Tick | None, speed_gain: float, force_budget: float | None,
                 v_ref: float, accel: float = 0.0, design=None,
                 sense: Sensing | None = None) -> ControlLoop | None:
    """The C loop's settings (maglev_control_loop), or None for the continuous loop: the
    controller at every RK4 stage, the propulsion without speed feedback, no budget.
    Validates them. A `LoopSetting` adds the actuator lag (the plant's, `flown_lag`; the tick
    law's prediction the design's ``lag``) and the speed integral;
    ``design`` (a `plant.LoopDesign`): the tick law's K_lag and K_delay of maglev_simulate;
    ``sense`` (at a `LoopSetting`; `maglevgen.analyses.sim_loop.sensing`): the firmware's
    sense tick on the readings."""
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
    if isinstance(tick, LoopSetting):
        law = {"tau": tick.flown_lag, "law_tau": float(tick.lag),
               "k_i": float(tick.speed_integral), "i_max": float(tick.integral_limit)}
    if design is not None:
        for key, K in (("k_lag", design.K_lag), ("k_delay", design.K_delay)):
            if K is not None and K.size:
                law[key] = tuple(float(v) for v in K.ravel(order="F"))
    if sense is not None and not isinstance(tick, LoopSetting):
        raise ValueError("the sensors' loop runs at a firmware tick")
    return ControlLoop(0 if tick is None else tick.steps(dt), 0 if tick is None else tick.delay,
                       float(speed_gain), float(v_ref), float(accel), budget, **law,
                       sense=sense)
