"""The schema's building blocks: a section's model and range check, the schema's error."""

from __future__ import annotations

import math
from typing import Annotated, Any, get_args

from pydantic import BaseModel, ConfigDict, Field, model_validator
from pydantic.fields import FieldInfo

__all__ = ["ModelError", "Section", "Vec3", "field_extra", "finite_number", "limits_text",
           "short_repr", "table_of"]

Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]


def short_repr(value: Any, limit: int = 60) -> str:
    """repr of a value for a one-line message, cut at ``limit`` characters (a table or array
    nested too deep for repr's recursion shown by its brackets only)."""
    try:
        text = repr(value)
    except RecursionError:
        text = "{...}" if isinstance(value, dict) else "[...]"
    return text if len(text) <= limit else text[: limit - 3] + "..."


def finite_number(v: Any) -> bool:
    """A finite TOML number (booleans and non-finite floats are left to the type checks)."""
    return (isinstance(v, int) and not isinstance(v, bool)) or (
        isinstance(v, float) and math.isfinite(v))


def limits_text(lo: float, hi: float, unit: str) -> str:
    return f"[{lo:g}, {hi:g}]" + (f" {unit}" if unit and unit != "1" else "")


def field_extra(info: FieldInfo) -> dict[str, Any]:
    """A field's json_schema_extra: its unit, limits (lo, hi, why), choices, paper."""
    extra = info.json_schema_extra
    return dict(extra) if isinstance(extra, dict) else {}


class Section(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, allow_inf_nan=False)

    @model_validator(mode="before")
    @classmethod
    def _within_limits(cls, data: Any) -> Any:
        """Every number inside its field's range, checked before anything computes with it."""
        if not isinstance(data, dict):
            return data  # the type check reports it
        for field, info in cls.model_fields.items():
            extra = field_extra(info)
            if field not in data or "limits" not in extra:
                continue
            value = data[field]
            lo, hi, why = extra["limits"]
            comps = value if isinstance(value, list) else [value]
            for i, c in enumerate(comps):
                if finite_number(c) and not lo <= c <= hi:
                    where = f"component {i} " if isinstance(value, list) else ""
                    raise ModelError(field, short_repr(value), f"{where}outside the range "
                                     f"{limits_text(lo, hi, extra['unit'])} ({why})")
        return data


class ModelError(ValueError):
    """A rule of the schema broken: ``key`` relative to where the validator sits."""

    def __init__(self, key: str, value: str, reason: str) -> None:
        super().__init__(reason)
        self.key, self.value, self.reason = key, value, reason


def table_of(ann: Any) -> type[BaseModel] | None:
    """The table type of a field's annotation (``Inertia`` of ``Inertia | str``), or None."""
    for tp in (ann, *get_args(ann)):
        if isinstance(tp, type) and issubclass(tp, BaseModel):
            return tp
    return None
