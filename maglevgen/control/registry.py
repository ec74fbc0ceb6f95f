"""The registry of controllers: `Controller` and `register` (public as `maglevgen.controllers`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["REGISTRY", "Controller", "WeightsFn", "controller", "embeddable", "names", "register",
           "title"]

# A law's functions of an operating point (`maglevgen.control.operating.OperatingPoint`, which
# looks its gains up here: named only in words, so the registry stays below operating.py).
# (K_pos, K_rate) at an operating point
GainsFn = Callable[[Any], tuple[np.ndarray, np.ndarray]]
# (q1, q2, r) per axis at an operating point: the position, rate and force weights
WeightsFn = Callable[[Any], tuple[np.ndarray, np.ndarray, np.ndarray]]


@dataclass(frozen=True)
class Controller:
    """One controller: what every layer needs to know about it.

    ``fmu_gains``: how the FMU's wrapper sets its gains: "none" (zero), "damping" (c of
    maglev_lqr_gains on the rate diagonal), "axis" (the per-axis K of maglev_lqr_gains) or
    "matrix" (K_pos and K_rate solved at export, carried as constants).
    ``tick_function``: the generated C function the firmware calls every tick (None: none).
    ``tick_design``: the loop's verdicts use its design at the tick on the loop as built
    (`maglevgen.control.plant`), else its continuous gains on that loop.
    ``weights``: its own per-axis design weights (q1, q2, r) at an operating point, the ones
    its tick design solves with, the region of attraction's Lyapunov function weighs by and the
    report tabulates (as Bryson's rule on ``[control.spec]``); None: the paper's ``[control]``
    weights (`operating.coupled_weights`).

    Nothing outside maglevgen/control/ compares a controller's name: what a layer branches on
    is a field here, and the registry is read when needed (a controller registered after
    `maglevgen.load()` is a choice of every command).
    """

    name: str
    title: str
    description: str
    gains: GainsFn
    embeddable: bool = True
    paper: bool = False
    tick_function: str | None = "maglev_coupled_control"
    fmu_gains: str = "matrix"
    # designed at the tick on the loop as built (`plant.LoopPlant.design`: the delay, the
    # actuator lag) from its weights; False: its continuous gains are checked on that loop
    tick_design: bool = False
    weights: WeightsFn | None = None
    style: dict = field(default_factory=dict)  # matplotlib line style

    def __post_init__(self) -> None:
        if self.tick_design and self.weights is None:
            raise ValueError(f"controller {self.name!r}: a design at the tick needs its weights")


REGISTRY: dict[str, Controller] = {}


def register(c: Controller) -> Controller:
    """Add ``c`` to the registry (in the order the modules register them)."""
    if c.name in REGISTRY:
        raise ValueError(f"controller {c.name!r} registered twice")
    if not c.name.isidentifier() or not c.name.islower():
        raise ValueError(f"controller name {c.name!r}: a lower-case identifier (it becomes "
                         "part of C and file names)")
    REGISTRY[c.name] = c
    return c


def names() -> tuple[str, ...]:
    """Every controller, in registration order."""
    return tuple(REGISTRY)


def embeddable() -> tuple[str, ...]:
    """The controllers the firmware may embed (and `build` may verify)."""
    return tuple(n for n, c in REGISTRY.items() if c.embeddable)


def titles() -> dict[str, str]:
    """Name -> title, for tables and legends."""
    return {n: c.title for n, c in REGISTRY.items()}


def title(name: str) -> str:
    """The registered controller's title (KeyError as `controller`)."""
    return controller(name).title


def controller(name: str) -> Controller:
    """The registered controller ``name``; KeyError naming the known ones otherwise."""
    try:
        return REGISTRY[name]
    except KeyError:
        raise KeyError(f"controller {name!r}: expected one of {', '.join(REGISTRY)}") from None
