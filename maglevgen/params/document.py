"""The whole parameter document: `Parameters`, its provenance, the rules across sections."""

from __future__ import annotations

import math
import re
from typing import Annotated, Any, get_args, get_origin

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from maglevgen.infrastructure.text import check_text
from maglevgen.params.fields import ModelError, Section, short_repr, table_of
from maglevgen.params.sections import (
    ACTUATOR_LAG,
    LOOP_TOLERANCES,
    SENSOR_TOLERANCES,
    Actuators,
    Array,
    Circuit,
    Control,
    ControlSpec,
    Envelope,
    GapSensors,
    Halbach,
    Imu,
    ModelChoices,
    Operation,
    ProcessNoise,
    Sensors,
    Tolerances,
    Track,
    TrackSensor,
    Vehicle,
)
from maglevgen.params.vector import flatten, schema_leaves

__all__ = ["ARRAY_NAME_RULE", "SCHEMA_DEPTH", "Parameters", "entry_limits", "schema_unit",
           "with_sensor_values"]

PROVENANCE_SOURCES = ("paper", "assumed")



class Provenance(BaseModel):
    """Where a value comes from: the paper gives it ("paper", with where), or it does not
    ("assumed", with the reason). The report's parameter table reads it."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)

    source: str = Field(description="paper or assumed", json_schema_extra={
        "unit": "-", "choices": list(PROVENANCE_SOURCES)})
    why: str = Field(min_length=1, description="where in the paper, or why this value")

    @field_validator("source")
    @classmethod
    def _known_source(cls, source: str) -> str:
        if source not in PROVENANCE_SOURCES:
            raise ValueError(f"expected one of {', '.join(PROVENANCE_SOURCES)}")
        return source

    @field_validator("why")
    @classmethod
    def _one_line_text(cls, why: str) -> str:
        """It reaches the report's LaTeX and SUMMARY.md: no control characters, bounded."""
        bad = check_text(why)
        if bad is not None:
            raise ValueError(bad)
        return why


class Parameters(Section):
    """A carriage description. Arrays are keyed by their number in the paper's Fig. 2."""

    vehicle: Vehicle
    halbach: Halbach
    circuit: Circuit
    arrays: dict[str, Array] = Field(min_length=1)
    operation: Operation
    control: Control
    track: Track
    envelope: Envelope
    model: ModelChoices = Field(default_factory=ModelChoices)
    actuators: Actuators = Field(default_factory=Actuators)
    # parameter key or table ("arrays.3", "vehicle.inertia_cg") -> where its value comes from
    provenance: dict[str, Provenance] = Field(default_factory=dict)
    tolerances: Tolerances = Field(default_factory=Tolerances)
    sensors: Sensors | None = Field(default=None, description="what the carriage measures "
                                    "(the estimator's); omitted: no output-feedback design")

    @field_validator("arrays", mode="before")
    @classmethod
    def _array_names(cls, arrays: Any) -> Any:
        """Array names become parts of C identifiers (MAGLEV_U_F_Z3, MAGLEV_P_ARRAYS_3_...),
        CasADi and SymPy symbol names and LaTeX subscripts: letters, digits and underscores
        only, and distinct regardless of case (the C macros are upper case)."""
        if not isinstance(arrays, dict):
            return arrays
        seen: dict[str, str] = {}
        for name in arrays:
            if not ARRAY_NAME.fullmatch(name):
                raise ModelError("<name>", short_repr(name), ARRAY_NAME_RULE)
            if name.upper() in seen:
                raise ModelError("<name>", short_repr(name), f"same as array "
                                 f"{seen[name.upper()]!r} in upper case (the C macros)")
            seen[name.upper()] = name
        return arrays

    @model_validator(mode="after")
    def _physical_inertia(self) -> Parameters:
        i = self.vehicle.inertia_cg
        eig = np.linalg.eigvalsh(self.vehicle.inertia_matrix())
        value = ("" if isinstance(i, str) else  # a box's moments are physical by construction
                 f"[xx={i.xx:g}, yy={i.yy:g}, zz={i.zz:g}, xy={i.xy:g}, xz={i.xz:g}, yz={i.yz:g}]")
        if eig[0] <= 0:
            raise ModelError("vehicle.inertia_cg", value, "is not positive definite "
                             f"(principal moments {', '.join(f'{e:.4g}' for e in eig)})")
        # Principal moments of a real body satisfy I1 + I2 >= I3 for every ordering.
        if eig[0] + eig[1] < eig[2] * (1 - 1e-12):
            raise ModelError("vehicle.inertia_cg", value, "violates the triangle inequality "
                             f"of principal moments ({eig[0]:.4g} + {eig[1]:.4g} < {eig[2]:.4g})")
        for name, arr in self.arrays.items():
            if arr.nominal_gap <= self.track.min_gap:
                raise ModelError(f"arrays.{name}.nominal_gap", f"{arr.nominal_gap:g}",
                                 f"is not above track.min_gap = {self.track.min_gap:g}")
        if self.control.spec.force_budget > self.actuators.force_limit:
            raise ModelError("control.spec.force_budget", f"{self.control.spec.force_budget:g}",
                             "above actuators.force_limit = "
                             f"{self.actuators.force_limit:g} (what a drive can produce)")
        self._tolerances_within_limits()
        self._sensors_on_the_carriage()
        keys = [lf.key for lf in schema_leaves(self)] + [
            f"{t}.{f}" for t, m in (("envelope", Envelope), ("vehicle", Vehicle),
                                    ("control", Control), ("control.spec", ControlSpec),
                                    ("actuators", Actuators),
                                    ("sensors", Sensors), ("sensors.gap", GapSensors),
                                    ("sensors.imu", Imu), ("sensors.track", TrackSensor),
                                    ("sensors.disturbance", ProcessNoise))
            for f in m.model_fields]
        for key in self.provenance:
            if not any(k == key or k.startswith(key + ".") for k in keys):
                raise ModelError("provenance", short_repr(key), "names no parameter or table")
        return self

    def _sensors_on_the_carriage(self) -> None:
        """Each gap sensor on an array's face (a key of [arrays], within its width and
        length); each sensor at least as fast as the controller's tick (a slower one would
        leave ticks without a reading: multi-rate estimation is not modelled)."""
        if self.sensors is None:
            return
        tick = self.control.spec.tick_rate
        for group, sensor in self.sensors.groups().items():
            if sensor.sample_rate < tick * (1 - 1e-12):
                raise ModelError(f"sensors.{group}.sample_rate", f"{sensor.sample_rate:g}",
                                 f"below control.spec.tick_rate = {tick:g} Hz (a tick "
                                 "without a reading; multi-rate estimation is not modelled)")
        for name, g in self.sensors.gap_sensors.items():
            where = f"sensors.gap_sensors.{name}"
            arr = self.arrays.get(g.array)
            if arr is None:
                raise ModelError(f"{where}.array", short_repr(g.array), "not an array: expected "
                                 "one of " + ", ".join(self.arrays))
            half_w = self.halbach.width / 2
            half_l = arr.circuits * self.circuit.pitch / 2
            if abs(g.across) > half_w * (1 + 1e-12):
                raise ModelError(f"{where}.across", f"{g.across:g}", f"off the face: its "
                                 f"half-width is halbach.width / 2 = {half_w:g} m")
            if abs(g.along) > half_l * (1 + 1e-12):
                raise ModelError(f"{where}.along", f"{g.along:g}", f"off the face: its "
                                 f"half-length is circuits x pitch / 2 = {half_l:g} m")

    def _tolerances_within_limits(self) -> None:
        """The file is refused when a tolerance can draw a value outside its key's range:
        every sample then passes the key checks (the cross-key rules are checked per sample,
        maglevgen.analyses.montecarlo)."""
        values = {e.name: e.value for e in flatten(self)}
        values.update(self.loop_values())
        for key, tol in self.tolerances.parameters.items():
            where = f"tolerances.parameters.{key}"
            if key in SENSOR_TOLERANCES and key not in values:
                raise ModelError(where, short_repr(tol.model_dump(exclude_none=True)),
                                 f"the file has no [{key.rpartition('.')[0]}]: no such "
                                 "sensor to spread")
            if key not in values:
                raise ModelError(where, short_repr(tol.model_dump(exclude_none=True)),
                                 "not an entry of the parameter vector (see `maglevgen "
                                 "params show`) nor the loop's (the actuators' lag, a "
                                 "sensor's noise or bias: " + ", ".join(LOOP_TOLERANCES) + ")")
            if key.startswith("arrays.") and ".normal." in key:
                raise ModelError(where, short_repr(tol.model_dump(exclude_none=True)),
                                 "an array's normal is a direction (normalised on load); "
                                 "tolerance its position instead")
            lo, hi, why = _leaf_limits(key)
            a, b = values[key] - tol.half_width, values[key] + tol.half_width
            if key == ACTUATOR_LAG and not a > 0:
                raise ModelError(where, short_repr(tol.model_dump(exclude_none=True)),
                                 f"draws values in [{a:.6g}, {b:.6g}]: a sample's lag must "
                                 "stay > 0 (the firmware's design feeds the lagged forces "
                                 "back)")
            if not lo <= a <= b <= hi:
                raise ModelError(where, short_repr(tol.model_dump(exclude_none=True)),
                                 f"draws values in [{a:.6g}, {b:.6g}], outside the key's range "
                                 f"[{lo:g}, {hi:g}] ({why})")

    def loop_values(self) -> dict[str, float]:
        """The `LOOP_TOLERANCES` entries the file has (the actuators' lag, its sensors'
        groups' noises and biases), by key."""
        return {ACTUATOR_LAG: float(self.actuators.time_constant), **self.sensor_values()}

    def sensor_values(self) -> dict[str, float]:
        """The `SENSOR_TOLERANCES` entries the file has (its sensors' groups), by key."""
        out: dict[str, float] = {}
        groups = self.sensors.groups() if self.sensors is not None else {}
        for key in SENSOR_TOLERANCES:
            _, group, field = key.split(".")
            if group in groups:
                out[key] = float(getattr(groups[group], field))
        return out

    @property
    def wavenumber(self) -> float:
        return 2 * math.pi / self.halbach.wavelength


def with_sensor_values(params: Parameters, values: dict[str, float]) -> Parameters:
    """``params`` with the `SENSOR_TOLERANCES` entries of ``values`` in place of its own (a
    Monte-Carlo sample's sensors; every value within its key's range, as the file's check of
    its tolerances makes them): a copy, the rest shared."""
    if not values:
        return params
    assert params.sensors is not None  # a sensor's tolerance needs the sensor (validated)
    groups: dict[str, dict[str, float]] = {}
    for key, value in values.items():
        if key not in SENSOR_TOLERANCES:
            raise KeyError(f"{key}: not one of SENSOR_TOLERANCES")
        _, group, field = key.split(".")
        groups.setdefault(group, {})[field] = float(value)
    sensors = params.sensors.model_copy(update={
        g: getattr(params.sensors, g).model_copy(update=f) for g, f in groups.items()})
    return params.model_copy(update={"sensors": sensors})


ARRAY_NAME = re.compile(r"[A-Za-z0-9_]{1,16}")
ARRAY_NAME_RULE = ("an array name must be 1 to 16 ASCII letters, digits or underscores "
                   "(it becomes part of C identifiers and LaTeX)")


def _schema_depth(tp: Any) -> int:
    """How many tables and arrays deep a value of type ``tp`` goes (the document is 1)."""
    if isinstance(tp, type) and issubclass(tp, BaseModel):
        return 1 + max((_schema_depth(f.annotation) for f in tp.model_fields.values()),
                       default=0)
    origin = get_origin(tp)
    if origin is Annotated:
        return _schema_depth(get_args(tp)[0])
    if origin in (list, tuple, dict):
        return 1 + max((_schema_depth(a) for a in get_args(tp)[-1:]), default=0)
    return max((_schema_depth(a) for a in get_args(tp)), default=0)


SCHEMA_DEPTH = _schema_depth(Parameters)  # 4: the document, arrays, one array, its position


def entry_limits(entry: str) -> tuple[float, float]:
    """(lo, hi) of an entry of the parameter vector: the range the run-time-parameter C
    checks p against (MAGLEV_ERR_PARAMETER), the same as a parameter file's."""
    lo, hi, _ = _leaf_limits(entry)
    return lo, hi


def schema_unit(entry: str) -> str:
    """The unit of an entry of the parameter vector or of `LOOP_TOLERANCES`, as the
    schema gives it."""
    return str(_leaf_field(entry).json_schema_extra.get("unit", ""))


def _leaf_limits(entry: str) -> tuple[float, float, str]:
    """(lo, hi, why) of an entry of the parameter vector (``arrays.3.position.z``)."""
    lo, hi, why = _leaf_field(entry).json_schema_extra["limits"]
    return float(lo), float(hi), str(why)


def _leaf_field(entry: str) -> Any:
    """The schema's FieldInfo of an entry (``arrays.3.position.z``, ``sensors.imu.gyro_bias``)."""
    parts = entry.split(".")
    model: Any = Parameters
    info: Any = None
    for part in parts:
        if info is not None and get_origin(info.annotation) is list:
            break  # a vector's component suffix
        if model is Parameters and part == "arrays":
            model, info = Array, None
            continue
        if model is Array and info is None and part not in Array.model_fields:
            continue  # the array's name
        info = model.model_fields[part]
        table = table_of(info.annotation)
        if table is not None:
            model, info = table, None
    return info
