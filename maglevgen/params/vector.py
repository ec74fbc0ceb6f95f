"""The parameter vector: the schema flattened into the scalar entries the model and C take."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

from pydantic import BaseModel

from maglevgen.params.fields import field_extra
from maglevgen.params.sections import Vehicle

__all__ = ["flatten", "schema_leaves"]


# sections and tables that are not part of the model's parameter vector (dotted keys)
NOT_IN_MODEL: tuple[str, ...] = ("envelope", "model", "provenance", "tolerances", "control.spec",
                                 "actuators", "sensors")


@dataclass(frozen=True)
class ParamEntry:
    name: str
    value: float
    unit: str
    description: str


def _field_meta(model: type[BaseModel], field: str) -> tuple[str, str]:
    info = model.model_fields[field]
    extra = field_extra(info)
    return str(extra.get("unit", "")), info.description or ""


_VEC_SUFFIX = ("x", "y", "z")


@dataclass(frozen=True)
class SchemaLeaf:
    """One leaf field of a parameter set: its dotted key, value(s) and schema metadata."""

    key: str
    values: tuple[float, ...]
    unit: str
    description: str
    paper: str
    vector: bool  # a list field (one parameter entry per component)


def schema_leaves(obj: BaseModel, prefix: str = "") -> Iterator[SchemaLeaf]:
    """Every leaf field in file order (vectors as one leaf); the one walk over the schema."""
    unused = obj.unused_fields() if isinstance(obj, Vehicle) else ()
    for field, info in type(obj).model_fields.items():
        if f"{prefix}{field}" in NOT_IN_MODEL or field in unused:
            continue
        value = getattr(obj, field)
        if isinstance(value, str):
            continue  # a choice (control.actuators): it selects the model, no number of it
        key = f"{prefix}{field}"
        if isinstance(value, BaseModel):
            yield from schema_leaves(value, key + ".")
        elif isinstance(value, dict):
            for name, item in value.items():
                yield from schema_leaves(item, f"{key}.{name}.")
        else:
            extra = field_extra(info)
            vals = tuple(float(v) for v in value) if isinstance(value, list) else (float(value),)
            yield SchemaLeaf(key, vals, str(extra.get("unit", "")), info.description or "",
                             str(extra.get("paper", "")), isinstance(value, list))


def _walk(obj: BaseModel) -> Iterator[ParamEntry]:
    for leaf in schema_leaves(obj):
        if not leaf.vector:
            yield ParamEntry(leaf.key, leaf.values[0], leaf.unit, leaf.description)
            continue
        n = len(leaf.values)
        suffixes = _VEC_SUFFIX if n == 3 else tuple(map(str, range(n)))
        for sfx, c in zip(suffixes, leaf.values, strict=True):
            yield ParamEntry(f"{leaf.key}.{sfx}", c, leaf.unit, leaf.description)


def flatten(params: BaseModel) -> list[ParamEntry]:
    """The parameter vector of ``params`` (a parameter document,
    `maglevgen.params.document.Parameters`) in file order, one scalar per entry, with units
    from the schema."""
    return list(_walk(params))
