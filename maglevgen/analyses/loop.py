"""The loop as the firmware builds it: its tick and speed loop, plant, gains and stability."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from maglevgen.control import controller as registered_controller
from maglevgen.control.operating import OperatingPoint, stability
from maglevgen.control.plant import LoopDesign, LoopPlant, speed_loop_gains
from maglevgen.control.sampled import (
    Tick,
    loop_gain,
    loop_model,
    sampled_eigenvalues,
    tick_design,
    tick_design_loop_gains,
)

__all__ = ["LoopSetting", "loop_design", "loop_plant", "loop_setting", "loop_stability",
           "sampled_stability", "tick_design_stability"]


@dataclass(frozen=True)
class LoopSetting:
    """How the firmware runs every controller: its tick and the speed loop's gain."""

    tick: Tick
    speed_gain: float  # k_v [N s/m], one value over the envelope
    bandwidth: float  # the speed pole it guarantees at least [1/s]
    actuator_lag: float = 0.0  # [s] each array force's first-order lag ([actuators])
    # k_i [N/m] of the speed error's integral (`plant.LoopPlant.k_i`; 0: none), and the
    # largest propulsion |k_i xi| it may add [N] (the C tick's anti-windup clamp; inf: none)
    speed_integral: float = 0.0
    speed_integral_limit: float = float("inf")

    def tick_text(self) -> str:
        """"sampled-data loop at <rate> Hz with <n> tick(s) of delay[ and a <tau> ms actuator
        lag]"."""
        delay = f"{self.tick.delay} tick{'s' if self.tick.delay != 1 else ''} of delay"
        lag = (f" and a {self.actuator_lag * 1e3:.3g} ms actuator lag" if self.actuator_lag > 0
               else ", instant actuators")
        return f"sampled-data loop at {self.tick.rate:g} Hz with {delay}{lag}"

    def text(self) -> str:
        integral = (f", k_i = {self.speed_integral:.4g} N/m (|k_i xi| <= "
                    f"{self.speed_integral_limit:.4g} N)" if self.speed_integral > 0 else "")
        return (f"{self.tick_text()}, zero-order hold, speed loop k_v = "
                f"{self.speed_gain:.4g} N s/m{integral}")


def loop_setting(carriage, points: Sequence[OperatingPoint]) -> LoopSetting:
    """The tick of ``[control.spec]`` and the speed loop's gains (`plant.speed_loop_gains`
    with control.spec.speed_integral_ratio r): one constant (k_v, k_i) over the points, k_v
    the largest over them, so that the loop m s^2 + (slope + k_v) s + k_i has its poles at
    -speed_bandwidth and -r speed_bandwidth where the drag slope is lowest (r = 0: the one
    pole, at least as fast as speed_bandwidth at every speed); the integral clamped at
    control.spec.speed_integral_limit."""
    spec, mass = carriage.params.control.spec, carriage.params.vehicle.mass
    k_v, k_i = max(speed_loop_gains(mass, op.trim_drag_slope, spec.speed_bandwidth,
                                    spec.speed_integral_ratio) for op in points)
    return LoopSetting(Tick.of(carriage.params), k_v, float(spec.speed_bandwidth),
                       float(carriage.params.actuators.time_constant), k_i,
                       float(spec.speed_integral_limit))


def loop_plant(op: OperatingPoint, setting: LoopSetting) -> LoopPlant:
    """The loop as built at ``op`` (`plant.LoopPlant`: tick, delay, actuator lag, speed loop)."""
    return LoopPlant(op, setting.tick, setting.actuator_lag, setting.speed_gain,
                     setting.speed_integral)


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


def loop_stability(op: OperatingPoint, controller: str, setting: LoopSetting,
                   design: OperatingPoint | None = None,
                   continuous: bool = False) -> tuple[float, float, float, float]:
    """(largest real part, smallest damping ratio, largest real part of the levitation modes,
    i.e. all but the speed loop's, largest real part of the speed loop's modes; -inf where it
    has none) of the loop as built at ``op`` with ``controller``'s gains from ``design``
    (default ``op``; ``continuous``: its continuous gains even where it is designed at the
    tick); (inf, nan, inf, inf) where it has none."""
    try:
        gains = loop_design(design or op, controller, setting, continuous)
    except (np.linalg.LinAlgError, ValueError):
        return float("inf"), float("nan"), float("inf"), float("inf")
    if not all(np.all(np.isfinite(k)) for k in (gains.K_pos, gains.K_rate)):
        return float("inf"), float("nan"), float("inf"), float("inf")
    s, speed = loop_plant(op, setting).modes(gains)
    finite = np.isfinite(s)
    max_real, min_damping = stability(s[finite])
    speed_real = float(np.max(s[finite & speed].real)) if np.any(finite & speed) else -np.inf
    return max_real, min_damping, float(np.max(s[finite & ~speed].real)), speed_real


def sampled_stability(op: OperatingPoint, controller: str, setting: LoopSetting,
                      design: OperatingPoint | None = None) -> tuple[float, float]:
    """(largest real part, smallest damping ratio) of the sampled-data loop at ``op`` without
    the actuator lag and with the continuous gains of ``design`` (default ``op``): the loop
    `loop_stability` had before [actuators]."""
    A, B = loop_model(op)
    K = loop_gain(op, controller, setting.speed_gain, design)
    if not np.all(np.isfinite(K)):
        return float("inf"), float("nan")
    s = sampled_eigenvalues(A, B, K, setting.tick)
    return stability(s[np.isfinite(s)])


def tick_design_stability(op: OperatingPoint, setting: LoopSetting) -> tuple[float, float]:
    """(largest real part, smallest damping ratio) of the sampled-data loop at ``op`` with
    the `spec` weights designed at the tick (`sampled.tick_design`, its feedback of the
    commands in flight included); (inf, nan) where the DARE has no stabilizing solution."""
    try:
        design = tick_design(op, setting.tick)
    except (np.linalg.LinAlgError, ValueError):
        return float("inf"), float("nan")
    A, B = loop_model(op)
    K, K_delay = tick_design_loop_gains(op, design, setting.speed_gain)
    s = sampled_eigenvalues(A, B, K, setting.tick, K_delay)
    return stability(s[np.isfinite(s)])

