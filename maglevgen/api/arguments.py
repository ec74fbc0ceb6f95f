"""The API's argument checks: a bad value refused with its option's one-line message."""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from maglevgen.controllers import names as controller_names
from maglevgen.derive import conventions as cv
from maglevgen.errors import InputError

if TYPE_CHECKING:
    from maglevgen.control.built_loop import Loop
    from maglevgen.params import Parameters

__all__ = ["MAX_ACCELERATION", "MAX_SEED", "MAX_WORKERS", "as_path", "check_choice_text",
           "check_controller", "check_run_arguments", "chosen_loop", "commands",
           "controller_choice", "flag", "initial_disturbance", "loop_of", "quiet", "shown"]


def commands() -> ModuleType:
    """The module holding the functions behind the commands (trim_report, gains_report,
    envelope_of, envelope_verdicts, verdict_lines, plant_of): the one place this API
    names it."""
    from maglevgen.analyses import queries

    return queries


def quiet(_message: str) -> None:
    """No progress (the methods' default: a script's stderr stays its own)."""


def check_run_arguments(t_end: float, dt: float) -> None:
    from maglevgen.params import check_run_options

    check_run_options(t_end, dt)


#: the most worker processes or threads a study starts (more is a typo, not a machine)
MAX_WORKERS = 1024
#: the largest |acceleration| of an accelerating trim (envelope.launch_acceleration's bound)
MAX_ACCELERATION = 1e3
_MAX_PATH = 4096  # PATH_MAX
MAX_SEED = 2**128 - 1  # numpy's SeedSequence's entropy: any non-negative int; bounded here


def check_controller(controller: str) -> None:
    if not isinstance(controller, str) or controller not in (known := controller_names()):
        raise InputError(f"--controller {shown(controller)}: expected one of "
                         f"{', '.join(known)}")


def controller_choice(controller: str | None, embedded: str) -> str:
    """``--controller`` of a study: a registered name or "all"; None: the embedded one."""
    choice = embedded if controller is None else controller
    if choice != "all":
        check_controller(choice)
    return choice


def loop_of(loop: object, choices: Sequence[str] | None = None) -> Loop:
    """``--loop``: the `Loop` the string names (``choices``: the command's loops, default
    every one), or an InputError naming them. The one place a loop string becomes a loop."""
    from maglevgen.control.built_loop import Loop

    names = tuple(Loop) if choices is None else tuple(choices)
    if not isinstance(loop, str) or loop not in names:
        raise InputError(f"--loop {shown(loop)}: expected one of {', '.join(names)}")
    return Loop(loop)


def chosen_loop(loop: object, controllers: Sequence[str], params: Parameters) -> Loop:
    """``--loop`` as `loop_of` parses it; None (the default): as a carriage flies, SENSED
    (the firmware's sense tick on the readings of [sensors]) when the embedded controller is
    the one asked and the file has [sensors], else FIRMWARE (the exact state: other
    controllers have no sense tick, and without [sensors] nothing says what is measured)."""
    from maglevgen.control.built_loop import Loop

    if loop is None:
        alone = tuple(controllers) == (params.envelope.embedded_controller,)
        return Loop.SENSED if alone and params.sensors is not None else Loop.FIRMWARE
    return loop_of(loop)


def as_path(option: str, value: object) -> Path:
    """A folder or file argument (``--out``, ``--simulation``) as a Path: a non-empty str or
    path-like without NUL, at most PATH_MAX long, or an InputError naming the option (a
    number or None gave a TypeError from pathlib, a NUL a ValueError)."""
    from maglevgen.infrastructure.text import check_text

    text = os.fspath(value) if isinstance(value, (str, os.PathLike)) else None
    if not isinstance(text, str) or not text:
        raise InputError(f"{option} {shown(value)}: expected a folder's path (a non-empty "
                         "str or pathlib.Path)")
    # a NUL no file name can hold (the OS's ValueError); other characters are the user's to
    # choose: a folder's name is shown escaped (shown_name), not refused
    bad = check_text(text, _MAX_PATH) if "\0" in text or len(text) > _MAX_PATH else None
    if bad is not None:
        raise InputError(f"{option} {shown(value)}: the path {bad}")
    return Path(text)


def check_choice_text(option: str, value: object) -> None:
    """A choice argument is a string (its own check then names the choices): a list or a
    dict gave "unhashable type" from the table it is looked up in."""
    if not isinstance(value, str):
        raise InputError(f"{option} {shown(value)}: expected a string naming one of its "
                         "choices")


def flag(option: str, value: object) -> bool:
    """A yes/no argument: True or False (a number or a string is a mistake: 'no' is true)."""
    if not isinstance(value, (bool, np.bool_)):
        raise InputError(f"{option} {shown(value)}: expected True or False")
    return bool(value)


def shown(value: object) -> str:
    """A bad argument's value in a one-line message: its repr, cut short."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def initial_disturbance(given: Mapping[str, float] | Sequence[str] | None
                        ) -> dict[str, float] | None:
    """The initial deviation from trim of ``--disturbance STATE=VALUE`` items, or of a
    mapping state -> value, checked (None: the default disturbance)."""
    if not given:
        return None
    if isinstance(given, str):  # one "STATE=VALUE" would iterate by character
        given = (given,)
    if not isinstance(given, Mapping) and not (
            isinstance(given, Sequence) and all(isinstance(i, str) for i in given)):
        raise InputError(f"--disturbance {shown(given)}: expected STATE=VALUE strings or a "
                         "mapping state -> value")
    items = ([(f"{k}={v}", k, v) for k, v in given.items()] if isinstance(given, Mapping)
             else [(item, *item.partition("=")[::2]) for item in given])
    out = {}
    for item, name, raw in items:
        try:
            value = float(raw)
        except (TypeError, ValueError):
            value = math.nan
        if str(name).strip() not in cv.STATE_INDEX or not (math.isfinite(value)
                                                            and abs(value) <= 0.1):
            raise InputError(f"--disturbance {item!r}: expected STATE=VALUE with a state of "
                             f"{', '.join(cv.STATE_INDEX)} and |VALUE| <= 0.1")
        out[str(name).strip()] = value
    return out
