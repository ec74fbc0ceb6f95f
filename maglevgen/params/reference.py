"""The schema as rows for people (`params schema`, the docs), and units annotated in TOML."""

from __future__ import annotations

import re
from typing import get_origin

from pydantic import BaseModel

from maglevgen.params.document import ARRAY_NAME_RULE, Parameters
from maglevgen.params.fields import field_extra, limits_text, table_of
from maglevgen.params.sections import (
    INERTIA_BOX,
    Array,
    GapSensor,
    Inertia,
    Sensors,
    Tolerance,
    Tolerances,
    Vehicle,
)

__all__ = ["annotate_with_units", "schema_rows", "schema_table"]


def schema_rows() -> list[tuple[str, str, str, str]]:
    """(dotted key, unit, description, paper value) for every leaf of the schema."""
    return [row[:4] for row in schema_table()]


def schema_table() -> list[tuple[str, str, str, str, str]]:
    """(dotted key, unit, description, paper value, allowed values and why) for every leaf of
    the schema, and the rule for array names (``arrays.<name>``)."""
    rows: list[tuple[str, str, str, str, str]] = []

    def walk(model: type[BaseModel], prefix: str) -> None:
        for field, info in model.model_fields.items():
            ann = info.annotation
            name = prefix + field
            if field == "provenance":
                rows.append(("provenance.<key>", "", "where the value of <key> (a parameter "
                             "or table) comes from", "", "source = paper or assumed, and why"))
            elif isinstance(ann, type) and issubclass(ann, BaseModel):
                walk(ann, name + ".")
            elif model is Sensors and field == "gap_sensors":
                rows.append((f"{name}.<name>", "-", "a gap sensor, by its name (a table "
                             "key)", "", "any TOML key"))
                walk(GapSensor, name + ".<name>.")
            elif ((model is Parameters and field == "sensors") or model is Sensors) and (
                    table := table_of(ann)) is not None:
                walk(table, name + ".")  # an optional table (sensors, its groups)
            elif model is GapSensor and field == "array":
                rows.append((name, "-", info.description or "", "", "a key of [arrays]"))
            elif model is Vehicle and field == "inertia_cg":
                rows.append((name, "", info.description or "", "",
                             f"a table, or \"{INERTIA_BOX}\""))
                walk(Inertia, name + ".")
            elif model is Tolerances and field in ("parameters", "disturbance"):
                extra = field_extra(info)
                if field == "disturbance":
                    lo, hi, why = extra["limits"]
                    rows.append((name, str(extra["unit"]), info.description or "",
                                 "", f"in {limits_text(lo, hi, '')}: {why}"))
                    continue
                rows.append((f"{name}.<key>", "", info.description or "", "",
                             "an entry of the parameter vector or a sensor's noise or "
                             "bias; its values +- the spread inside the key's range"))
                walk(Tolerance, name + ".<key>.")
            elif field == "arrays":
                rows.append((f"{name}.<name>", "", "the name of an array (a table key)", "",
                             ARRAY_NAME_RULE.removeprefix("an array name must be ")))
                walk(Array, name + ".<name>.")
            else:
                extra = field_extra(info)
                unit = str(extra.get("unit", ""))
                if "choices" in extra:
                    rows.append((name, unit, info.description or "",
                                 str(extra.get("paper", "")),
                                 "one of " + ", ".join(extra["choices"])))
                    continue
                lo, hi, why = extra["limits"]
                each = "each component in " if get_origin(ann) is list else "in "
                rows.append((name, unit, info.description or "", str(extra.get("paper", "")),
                             f"{each}{limits_text(lo, hi, unit)}: {why}"))

    walk(Parameters, "")
    return rows


def annotate_with_units(text: str) -> str:
    """The TOML text with each key's unit (from the schema) appended as a comment."""
    units = {re.sub(r"\.<name>(\.|$)", r".*\1", k): u for k, u, _, _ in schema_rows()}
    section = ""
    out = []
    for line in text.splitlines():
        m = re.match(r"^\s*\[([^\]]+)\]\s*(#.*)?$", line)
        if m:
            section = m.group(1).strip()
        km = re.match(r"^\s*([A-Za-z0-9_]+)\s*=", line)
        if km:
            key = f"{section}.{km.group(1)}" if section else km.group(1)
            generic = re.sub(r"^(arrays|sensors\.gap_sensors)\.[^.]+(\.|$)", r"\1.*\2", key)
            unit = units.get(key) or units.get(generic)
            if unit is None and section.startswith("vehicle.inertia_cg"):
                unit = "kg*m^2"
            if unit:
                code, hash_, comment = line.partition("#")
                line = (f"{code}# [{unit}]{comment}" if hash_
                        else f"{line}  # [{unit}]")
        out.append(line)
    return "\n".join(out) + "\n"
