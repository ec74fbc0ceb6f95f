"""Section: the parameter table, with each value's provenance.

Provenance is data of the parameter file (its ``[provenance]`` table, validated by
maglevgen.params): "paper" or "assumed" with the reason, for a key or a whole table. A value
that differs from the schema's paper value is "changed"; one given with --set is "set".
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from maglevgen.params import schema_leaves
from maglevgen.report.symbols import display_key_symbol

__all__ = ["model_choices", "parameter_rows", "provenance_of"]


@dataclass(frozen=True)
class Note:
    """A provenance entry of the parameter file: what it says and the key or table it covers."""

    kind: str  # "paper" or "assumed"
    text: str
    scope: str  # a parameter key or a table ("arrays", "vehicle.inertia_cg")


def provenance_of(key: str, provenance) -> Note | None:
    """The most specific entry for ``key``: its own, else the longest table key above it."""
    best = None
    for scope, entry in provenance.items():
        if (key == scope or key.startswith(scope + ".")) and (
                best is None or len(scope) > len(best[0])):
            best = (scope, entry)
    return Note(best[1].source, best[1].why, best[0]) if best else None


_PAPER_NUMBER = re.compile(
    r"^\s*(?:[A-Za-z]+\s*=\s*)?(?P<num>[-+]?[0-9.]+(?:e[-+]?\d+)?|I)\s*"
    r"(?P<unit>cm|mm|kg|ohm|H|m)?\b",
    re.IGNORECASE,
)
_UNIT_SCALE = {"cm": 1e-2, "mm": 1e-3}


def paper_number(text: str) -> float | None:
    """The number of a schema "paper" value ("65 cm" -> 0.65, "Q = I" -> 1), or None."""
    m = _PAPER_NUMBER.match(text)
    if not m:
        return None
    num = m.group("num")
    value = 1.0 if num == "I" else float(num)
    return value * _UNIT_SCALE.get((m.group("unit") or "").lower(), 1.0)


@dataclass(frozen=True)
class ParamRow:
    """One row of the parameter table."""

    key: str
    symbol: str  # LaTeX
    values: tuple[float, ...]
    unit: str
    description: str
    source: str  # "paper", "assumed", "changed" or "set"
    paper: str  # the paper's value as the schema gives it, or ""
    note: int | None  # index into the notes list (1-based), or None
    override: str  # the --set item that set it, or ""

    @property
    def table(self) -> str:
        """The table the key sits in ("arrays.3"), the group heading of the typeset table."""
        return self.key.rsplit(".", 1)[0] if "." in self.key else ""

    @property
    def leaf(self) -> str:
        """The key's last part ("nominal_gap"): keys never break inside the table."""
        return self.key.rsplit(".", 1)[-1]


def parameter_rows(loaded) -> tuple[list[ParamRow], list[Note]]:
    """The parameter table: each schema leaf's value, unit, source and the reason for it."""
    provenance = loaded.params.provenance
    overrides = {item.split("=", 1)[0].strip(): item for item in loaded.overrides}
    used: list[Note] = []
    rows = []
    for lf in schema_leaves(loaded.params):
        note = provenance_of(lf.key, provenance)
        override = next((item for name, item in overrides.items()
                         if lf.key == name or lf.key.startswith(name + ".")), "")
        ref = paper_number(lf.paper) if lf.paper else None
        if override:
            source = "set"
        elif ref is not None and any(abs(v - ref) > 1e-9 * max(abs(ref), 1e-300)
                                     for v in lf.values):
            source = "changed"
        elif lf.paper or (note is not None and note.kind == "paper"):
            source = "paper"
        else:
            source = "assumed"
        idx = None
        if note is not None:
            if note not in used:
                used.append(note)
            idx = used.index(note) + 1
        rows.append(ParamRow(lf.key, display_key_symbol(lf.key), lf.values, lf.unit,
                             lf.description, source, lf.paper, idx, override))
    return rows, used


def model_choices(params) -> dict[str, Any]:
    """The file's choices that are no number of the parameter vector: where the inertia comes
    from (vehicle.inertia_cg: a table, or "box" with its moments) and control.actuators."""
    v = params.vehicle
    return {"inertia_box": v.box, "inertia_diag": [float(d) for d in np.diag(v.inertia_matrix())],
            "actuators": params.control.actuators}
