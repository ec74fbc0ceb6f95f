"""The parameter file: schema (names, units, meaning), loading, overrides and validation.

The schema below is the single source of truth for parameter names and units; the C header,
the manifest, the report tables and ``maglevgen params show`` all read it. Values live in the
TOML file (the default one describes the LLNL carriage of the paper, with the reason for each
value the paper does not give written beside it).
"""

from __future__ import annotations

import math
import re
import sys
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from .cache import DEFAULT_PARAMS_NAME, params_digest
from .errors import InputError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]


def _f(unit: str, description: str, *, gt: float | None = None, ge: float | None = None,
       paper: str | None = None) -> Any:
    """A documented field: its unit and meaning, and the paper's value where it gives one."""
    extra: dict[str, Any] = {"unit": unit}
    if paper is not None:
        extra["paper"] = paper
    return Field(description=description, gt=gt, ge=ge, json_schema_extra=extra)


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, allow_inf_nan=False)


class Inertia(_Section):
    """Inertia tensor about the centre of gravity, body axes (tensor entries, not products)."""

    xx: float = _f("kg*m^2", "I_xx about the CG", gt=0)
    yy: float = _f("kg*m^2", "I_yy about the CG", gt=0)
    zz: float = _f("kg*m^2", "I_zz about the CG", gt=0)
    xy: float = _f("kg*m^2", "tensor entry I_xy (= -integral of x*y dm)")
    xz: float = _f("kg*m^2", "tensor entry I_xz (= -integral of x*z dm)")
    yz: float = _f("kg*m^2", "tensor entry I_yz (= -integral of y*z dm)")

    def matrix(self) -> np.ndarray:
        return np.array(
            [[self.xx, self.xy, self.xz], [self.xy, self.yy, self.yz], [self.xz, self.yz, self.zz]]
        )


class Vehicle(_Section):
    mass: float = _f("kg", "carriage mass", gt=0, paper="9.3 kg")
    length: float = _f("m", "carriage (cradle) length", gt=0, paper="65 cm")
    inertia_cg: Inertia
    cg_offset: Vec3 = _f("m", "r_G: centre of gravity relative to the body origin O, body axes")
    gravity: float = _f("m/s^2", "gravitational acceleration", gt=0)


class Halbach(_Section):
    remanence: float = _f("T", "B_r of the magnet material (eq 4)", gt=0)
    thickness: float = _f("m", "d: array thickness normal to its face (eq 4)", gt=0)
    magnets_per_wavelength: int = _f("1", "M: magnet elements per wavelength (eq 4)", ge=2)
    wavelength: float = _f("m", "lambda: Halbach wavelength; k = 2*pi/lambda", gt=0, paper="0.1 m")
    width: float = _f("m", "w: transverse width of each array (eq 3)", gt=0, paper="0.12 m")


class Circuit(_Section):
    resistance: float = _f("ohm", "R: resistance of one track circuit (loop)", gt=0,
                           paper="1.5e-3 ohm/loop")
    inductance: float = _f("H", "L: inductance of one track circuit (loop)", gt=0,
                           paper="2.6e-6 H/loop")


class Array(_Section):
    position: Vec3 = _f("m", "centre of the array face, body axes, relative to O")
    normal: Vec3 = _f("1", "direction of the track's repulsion on the array, body axes "
                           "(normalised on load)")
    nominal_gap: float = _f("m", "gap between array face and track surface at the design pose",
                            gt=0)
    circuits: float = _f("1", "track circuits under the array at any instant", gt=0)

    @field_validator("normal")
    @classmethod
    def _unit_normal(cls, n: list[float]) -> list[float]:
        norm = math.sqrt(sum(c * c for c in n))
        if not norm > 0:
            raise ValueError("must be a non-zero vector")
        return [c / norm for c in n]


class Operation(_Section):
    speed: float = _f("m/s", "forward speed at which trim and gains are computed", gt=0)
    propulsion_point: Vec3 = _f("m", "point of the body where the propulsion force acts")


class Control(_Section):
    state_weights: Annotated[list[float], Field(min_length=2, max_length=2)] = _f(
        "1", "diagonal of Q per axis: [position, rate] (paper: Q = I)", paper="Q = I")
    input_weight: float = _f("1", "R per axis (paper: R = 1)", gt=0, paper="R = 1")

    @field_validator("state_weights")
    @classmethod
    def _positive_weights(cls, q: list[float]) -> list[float]:
        if not all(c > 0 for c in q):
            raise ValueError("both weights must be > 0")
        return q


class Track(_Section):
    min_gap: float = _f("m", "smallest gap before an array touches the track (contact)", gt=0)


EMBEDDABLE_CONTROLLERS = ("damping", "lqr", "coupled")


class Envelope(_Section):
    """The speeds the carriage flies and the launch: not part of the model's parameter vector
    (nothing here changes the equations; the envelope, the schedule and the launch read it)."""

    v_min: float | None = Field(
        default=None, gt=0, description="lowest speed of the envelope (omitted: "
        "(1 + lift_off_margin) x the lift-off speed, found by the trim in C)",
        json_schema_extra={"unit": "m/s"})
    lift_off_margin: float = Field(
        default=0.5, ge=0.05, le=10, description="margin of v_min above the lift-off speed "
        "when v_min is omitted (0.5: 50 % above)", json_schema_extra={"unit": "1"})
    v_max: float = Field(gt=0, description="release speed: the top of the envelope",
                         json_schema_extra={"unit": "m/s"})
    launch_acceleration: float = Field(
        gt=0, description="steady acceleration of the launch run: the propulsion is the trim "
        "drag plus m times this (the paper's 'steady acceleration force')",
        json_schema_extra={"unit": "m/s^2"})
    schedule_nodes: int = Field(
        default=64, ge=4, le=4096, description="speeds of the gain schedule's spline nodes "
        "over [v_min, v_max]", json_schema_extra={"unit": "1"})
    embedded_controller: str = Field(
        default="coupled", description="the controller the firmware C embeds and `build` "
        f"verifies over the envelope: one of {', '.join(EMBEDDABLE_CONTROLLERS)}",
        json_schema_extra={"unit": "-"})

    @field_validator("embedded_controller")
    @classmethod
    def _known_controller(cls, name: str) -> str:
        if name not in EMBEDDABLE_CONTROLLERS:
            raise ValueError(f"expected one of {', '.join(EMBEDDABLE_CONTROLLERS)}")
        return name

    @model_validator(mode="after")
    def _ordered(self) -> Envelope:
        if self.v_min is not None and not self.v_min < self.v_max:
            raise _ModelError("envelope.v_min", f"{self.v_min:g}",
                              f"is not below envelope.v_max = {self.v_max:g}")
        return self


# sections of the file that are not model parameters (not in the parameter vector p)
NOT_IN_MODEL: tuple[str, ...] = ("envelope",)


class Parameters(_Section):
    """A carriage description. Arrays are keyed by their number in the paper's Fig. 2."""

    vehicle: Vehicle
    halbach: Halbach
    circuit: Circuit
    arrays: dict[str, Array] = Field(min_length=1)
    operation: Operation
    control: Control
    track: Track
    envelope: Envelope

    @model_validator(mode="after")
    def _physical_inertia(self) -> Parameters:
        eig = np.linalg.eigvalsh(self.vehicle.inertia_cg.matrix())
        i = self.vehicle.inertia_cg
        value = f"[xx={i.xx:g}, yy={i.yy:g}, zz={i.zz:g}, xy={i.xy:g}, xz={i.xz:g}, yz={i.yz:g}]"
        if eig[0] <= 0:
            raise _ModelError("vehicle.inertia_cg", value, "is not positive definite "
                              f"(principal moments {', '.join(f'{e:.4g}' for e in eig)})")
        # Principal moments of a real body satisfy I1 + I2 >= I3 for every ordering.
        if eig[0] + eig[1] < eig[2] * (1 - 1e-12):
            raise _ModelError("vehicle.inertia_cg", value, "violates the triangle inequality "
                              f"of principal moments ({eig[0]:.4g} + {eig[1]:.4g} < {eig[2]:.4g})")
        for name, arr in self.arrays.items():
            if arr.nominal_gap <= self.track.min_gap:
                raise _ModelError(f"arrays.{name}.nominal_gap", f"{arr.nominal_gap:g}",
                                  f"is not above track.min_gap = {self.track.min_gap:g}")
        return self

    @property
    def wavenumber(self) -> float:
        return 2 * math.pi / self.halbach.wavelength


class _ModelError(ValueError):
    def __init__(self, key: str, value: str, reason: str) -> None:
        super().__init__(reason)
        self.key, self.value, self.reason = key, value, reason


# --------------------------------------------------------------------------------------------
# Loading


def default_params_path() -> Path:
    return Path(str(resources.files("maglevgen") / DEFAULT_PARAMS_NAME))


def default_params_text() -> str:
    return (resources.files("maglevgen") / DEFAULT_PARAMS_NAME).read_text(encoding="utf-8")


@dataclass(frozen=True)
class LoadedParams:
    """Validated parameters with the text they came from (for hashing and provenance)."""

    params: Parameters
    source: str
    sha256: str
    overrides: tuple[str, ...]


def _set_dotted(data: dict[str, Any], dotted: str, value: Any) -> None:
    keys = dotted.split(".")
    node: Any = data
    for depth, key in enumerate(keys[:-1]):
        if not isinstance(node, dict) or key not in node:
            raise InputError(f"--set {dotted}: unknown key {'.'.join(keys[: depth + 1])!r}")
        node = node[key]
    optional = {k for k, *_ in schema_rows()}  # a key of the schema the file may omit
    if not isinstance(node, dict) or (keys[-1] not in node and dotted not in optional):
        raise InputError(f"--set {dotted}: unknown key {dotted!r}")
    node[keys[-1]] = value


def parse_override(item: str) -> tuple[str, Any]:
    """Parse ``NAME=VALUE`` where VALUE is a TOML value (``9.3``, ``[0, 0, 0.01]``, ``"x"``)."""
    if "=" not in item:
        raise InputError(f"--set {item!r}: expected NAME=VALUE")
    name, raw = (s.strip() for s in item.split("=", 1))
    if not re.fullmatch(r"[A-Za-z0-9_]+(\.[A-Za-z0-9_]+)*", name):
        raise InputError(f"--set {item!r}: {name!r} is not a dotted parameter name")
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"--set {item!r}: not a TOML value ({exc})") from None
    return name, value


def _format_loc(loc: Sequence[int | str]) -> str:
    return ".".join(str(p) for p in loc)


def _lookup(data: Any, loc: Sequence[int | str]) -> Any:
    for p in loc:
        try:
            data = data[p]
        except (KeyError, IndexError, TypeError):
            return None
    return data


def validate(data: dict[str, Any], origin: str) -> Parameters:
    """Validate raw TOML data; raise a one-line InputError naming the key and the value."""
    try:
        return Parameters.model_validate(data)
    except ValidationError as exc:
        err = exc.errors(include_url=False)[0]
        ctx_err = (err.get("ctx") or {}).get("error")
        if isinstance(ctx_err, _ModelError):
            raise InputError(
                f"{origin}: {ctx_err.key} = {ctx_err.value}: {ctx_err.reason}") from None
        loc = [p for p in err["loc"] if not (isinstance(p, str) and p.startswith("function-"))]
        key = _format_loc(loc) or "(top level)"
        msg = err["msg"]
        if err["type"] == "missing":
            raise InputError(f"{origin}: missing key {key}") from None
        if err["type"] == "extra_forbidden":
            raise InputError(f"{origin}: unknown key {key}") from None
        value = _lookup(data, loc)
        msg = msg.removeprefix("Value error, ")
        raise InputError(f"{origin}: {key} = {value!r}: {msg}") from None


def load_params(path: str | Path | None = None, overrides: Sequence[str] = ()) -> LoadedParams:
    """Load a parameter file (the default carriage when ``path`` is None) and apply overrides."""
    if path is None:
        text, origin = default_params_text(), DEFAULT_PARAMS_NAME
    else:
        p = Path(path)
        origin = str(p)
        try:
            text = p.read_text(encoding="utf-8")
        except OSError as exc:
            raise InputError(f"{origin}: cannot read parameter file ({exc.strerror})") from None
        except UnicodeDecodeError as exc:
            raise InputError(f"{origin}: cannot read parameter file (not UTF-8: byte "
                             f"{exc.object[exc.start]:#04x} at offset {exc.start})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{origin}: malformed TOML: {exc}") from None
    for item in overrides:
        name, value = parse_override(item)
        _set_dotted(data, name, value)
    params = validate(data, origin)
    return LoadedParams(params, origin, params_digest(text, overrides), tuple(overrides))


# --------------------------------------------------------------------------------------------
# Flattening: the ordered parameter vector used by the symbolic model and generated C.


@dataclass(frozen=True)
class ParamEntry:
    name: str
    value: float
    unit: str
    description: str


def _field_meta(model: type[BaseModel], field: str) -> tuple[str, str]:
    info = model.model_fields[field]
    extra = info.json_schema_extra if isinstance(info.json_schema_extra, dict) else {}
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
    for field, info in type(obj).model_fields.items():
        if not prefix and field in NOT_IN_MODEL:
            continue
        value = getattr(obj, field)
        key = f"{prefix}{field}"
        if isinstance(value, BaseModel):
            yield from schema_leaves(value, key + ".")
        elif isinstance(value, dict):
            for name, item in value.items():
                yield from schema_leaves(item, f"{key}.{name}.")
        else:
            extra = info.json_schema_extra if isinstance(info.json_schema_extra, dict) else {}
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


def flatten(params: Parameters) -> list[ParamEntry]:
    """The parameter vector in file order, one scalar per entry, with units from the schema."""
    return list(_walk(params))


def schema_rows() -> list[tuple[str, str, str, str]]:
    """(dotted key, unit, description, paper value) for every leaf of the schema."""
    rows: list[tuple[str, str, str, str]] = []

    def walk(model: type[BaseModel], prefix: str) -> None:
        for field, info in model.model_fields.items():
            ann = info.annotation
            name = prefix + field
            if isinstance(ann, type) and issubclass(ann, BaseModel):
                walk(ann, name + ".")
            elif field == "arrays":
                walk(Array, name + ".<name>.")
            else:
                extra = info.json_schema_extra if isinstance(info.json_schema_extra, dict) else {}
                rows.append((name, str(extra.get("unit", "")), info.description or "",
                             str(extra.get("paper", ""))))

    walk(Parameters, "")
    return rows


def annotate_with_units(text: str) -> str:
    """The TOML text with each key's unit (from the schema) appended as a comment."""
    units = {re.sub(r"\.<name>\.", ".*.", k): u for k, u, _, _ in schema_rows()}
    section = ""
    out = []
    for line in text.splitlines():
        m = re.match(r"^\s*\[([^\]]+)\]\s*(#.*)?$", line)
        if m:
            section = m.group(1).strip()
        km = re.match(r"^\s*([A-Za-z0-9_]+)\s*=", line)
        if km:
            key = f"{section}.{km.group(1)}" if section else km.group(1)
            generic = re.sub(r"^arrays\.[^.]+\.", "arrays.*.", key)
            unit = units.get(key) or units.get(generic)
            if unit is None and section.startswith("vehicle.inertia_cg"):
                unit = "kg*m^2"
            if unit:
                code, hash_, comment = line.partition("#")
                line = (f"{code}# [{unit}]{comment}" if hash_
                        else f"{line}  # [{unit}]")
        out.append(line)
    return "\n".join(out) + "\n"
