"""Command-line numbers and counts checked against the schema's ranges."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from maglevgen.errors import InputError
from maglevgen.params.document import Parameters
from maglevgen.params.fields import limits_text, short_repr, table_of
from maglevgen.params.reference import schema_table

__all__ = ["check_count", "check_key_option", "check_option", "check_run_options"]


def check_option(option: str, value: Any, lo: float, hi: float, unit: str, why: str) -> None:
    """A command-line number inside [lo, hi], or a one-line InputError naming it (a value
    that is no real number, from the Python API, too)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InputError(f"{option} {short_repr(value)}: expected a number in "
                         f"{limits_text(lo, hi, unit)}")
    try:
        inside = math.isfinite(value) and lo <= value <= hi
    except OverflowError:  # an int past a float's range
        inside = False
    if not inside:
        shown = f"{value:g}" if isinstance(value, (float, np.floating)) else short_repr(value)
        raise InputError(f"{option} {shown}: outside the range {limits_text(lo, hi, unit)} "
                         f"({why})")


def check_count(option: str, value: Any, lo: int, hi: int, why: str) -> int:
    """A command-line count (``--samples``, ``--speeds``, ``--workers``, ``--seed``...) that is
    a whole number in [lo, hi], or a one-line InputError naming it: a bool, a float, a string
    or None from the Python API included (each gave a TypeError or ValueError deep in the
    work, or an allocation of terabytes)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not (
            lo <= value <= hi):
        raise InputError(f"{option} {short_repr(value)}: expected a whole number from {lo} to "
                         f"{hi} ({why})")
    return int(value)


def check_run_options(t_end: float, dt: float) -> None:
    """--t-end and --dt inside ranges the simulation can hold (its trajectories in memory)."""
    check_option("--t-end", t_end, 1e-3, 1e4, "s", "a millisecond to nearly three hours")
    check_option("--dt", dt, 1e-7, 1.0, "s", "RK4 steps; the stability limit is checked too")
    if t_end / dt > 1e7:
        raise InputError(f"--t-end {t_end:g} s / --dt {dt:g} s = {t_end / dt:.3g} "
                         "steps: more than 1e7 (the trajectories are held in memory)")


def check_key_option(option: str, value: float, key: str) -> None:
    """A command-line number that stands for the schema's ``key``: inside its range."""
    row = next(r for r in schema_table() if r[0] == key)
    info = _model_field(key)
    lo, hi, why = info.json_schema_extra["limits"]  # type: ignore[index]
    check_option(option, value, lo, hi, row[1], why)


def _model_field(key: str) -> Any:
    model: Any = Parameters
    *path, last = key.split(".")
    for part in path:
        model = table_of(model.model_fields[part].annotation)
    return model.model_fields[last]
