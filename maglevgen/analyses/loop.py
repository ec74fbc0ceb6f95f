"""The loop as the firmware builds it: its stability and that of the designs before it (the loop
itself, its plant and gains: `maglevgen.control.built_loop`, re-exported here)."""

from __future__ import annotations

import numpy as np

from maglevgen.control.built_loop import LoopSetting, loop_design, loop_plant, loop_setting
from maglevgen.control.operating import OperatingPoint, stability
from maglevgen.control.sampled import (
    loop_gain,
    loop_model,
    sampled_eigenvalues,
    tick_design,
    tick_design_loop_gains,
)

__all__ = ["LoopSetting", "loop_design", "loop_plant", "loop_setting", "loop_stability",
           "tick_design_stability"]


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

