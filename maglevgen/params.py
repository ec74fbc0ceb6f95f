"""The parameter file: schema (names, units, meaning), loading, overrides and validation.

The schema below is the single source of truth for parameter names and units; the C header,
the manifest, the report tables and ``maglevgen params show`` all read it. Values live in the
TOML file (the default one describes the LLNL carriage of the paper, with the reason for each
value the paper does not give written beside it).
"""

from __future__ import annotations

import difflib
import math
import os
import re
import sys
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Annotated, Any, get_args, get_origin

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator
from pydantic.fields import FieldInfo

from maglevgen.control import embeddable
from maglevgen.derive.conventions import (
    DISTURBANCE,  # the initial disturbance of `maglevgen simulate`
)
from maglevgen.derive.structure import CIRCUIT_DYNAMICS, box_principal_moments
from maglevgen.errors import InputError
from maglevgen.infrastructure.cache import DEFAULT_PARAMS_NAME, params_digest
from maglevgen.infrastructure.text import check_text

__all__ = [
    "ACTUATOR_MODELS",
    "ARRAY_FORCE_LAWS",
    "ARRAY_NAME",
    "ARRAY_NAME_RULE",
    "BOX_DIMENSIONS",
    "INERTIA_BOX",
    "NORMAL_TRUNCATION",
    "NOT_IN_MODEL",
    "PAPER_ARRAY_FORCE",
    "PROVENANCE_SOURCES",
    "SCHEMA_DEPTH",
    "Actuators",
    "Array",
    "AxisDeviation",
    "Circuit",
    "Control",
    "ControlSpec",
    "Envelope",
    "GapSensor",
    "GapSensors",
    "Halbach",
    "Imu",
    "Inertia",
    "LoadedParams",
    "ModelChoices",
    "Operation",
    "ParamEntry",
    "Parameters",
    "ProcessNoise",
    "Provenance",
    "SchemaLeaf",
    "Sensors",
    "Tolerance",
    "Tolerances",
    "Track",
    "TrackSensor",
    "Vec3",
    "Vehicle",
    "annotate_with_units",
    "check_count",
    "check_key_option",
    "check_option",
    "check_run_options",
    "default_params_path",
    "default_params_text",
    "did_you_mean",
    "entry_limits",
    "flatten",
    "limits_text",
    "load_params",
    "parse_override",
    "schema_leaves",
    "schema_rows",
    "schema_table",
    "validate",
]

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]

# Ranges shared by several fields: (lo, hi, why), see _f.
_SIZE = "a bench model to a 1 km train"
_ARRAY_SIZE = "a millimetre-scale model to a full-size array"
_OFFSET = (-1e3, 1e3, "a point of the vehicle: within its largest length")
_MOMENT = (1e-9, 1e9, "a gram-scale model to a 1000 t train")
_PRODUCT = (-1e9, 1e9, "no larger than the principal moments")
_WEIGHT = (1e-6, 1e6, "relative LQR weights: a ratio above 1e12 leaves the Riccati "
                      "equation ill-conditioned in double precision")


def _f(unit: str, description: str, *, limits: tuple[float, float, str],
       paper: str | None = None) -> Any:
    """A documented field: its unit and meaning, the paper's value where it gives one, and the
    closed range [lo, hi] of physically meaningful values (each component's, for a vector)
    with the reason for it. The range keeps every value away from the overflow and underflow
    of the model's arithmetic (exp(-k g), k^2 v^2, products of masses and lengths)."""
    extra: dict[str, Any] = {"unit": unit, "limits": list(limits)}
    if paper is not None:
        extra["paper"] = paper
    return Field(description=description, json_schema_extra=extra)


def _short(value: Any, limit: int = 60) -> str:
    """repr of a value for a one-line message, cut at ``limit`` characters (a table or array
    nested too deep for repr's recursion shown by its brackets only)."""
    try:
        text = repr(value)
    except RecursionError:
        text = "{...}" if isinstance(value, dict) else "[...]"
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _number(v: Any) -> bool:
    """A finite TOML number (booleans and non-finite floats are left to the type checks)."""
    return (isinstance(v, int) and not isinstance(v, bool)) or (
        isinstance(v, float) and math.isfinite(v))


def limits_text(lo: float, hi: float, unit: str) -> str:
    return f"[{lo:g}, {hi:g}]" + (f" {unit}" if unit and unit != "1" else "")


def _extra(info: FieldInfo) -> dict[str, Any]:
    """A field's json_schema_extra: its unit, limits (lo, hi, why), choices, paper."""
    extra = info.json_schema_extra
    return dict(extra) if isinstance(extra, dict) else {}


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, allow_inf_nan=False)

    @model_validator(mode="before")
    @classmethod
    def _within_limits(cls, data: Any) -> Any:
        """Every number inside its field's range, checked before anything computes with it."""
        if not isinstance(data, dict):
            return data  # the type check reports it
        for field, info in cls.model_fields.items():
            extra = _extra(info)
            if field not in data or "limits" not in extra:
                continue
            value = data[field]
            lo, hi, why = extra["limits"]
            comps = value if isinstance(value, list) else [value]
            for i, c in enumerate(comps):
                if _number(c) and not lo <= c <= hi:
                    where = f"component {i} " if isinstance(value, list) else ""
                    raise _ModelError(field, _short(value), f"{where}outside the range "
                                      f"{limits_text(lo, hi, extra['unit'])} ({why})")
        return data


class Inertia(_Section):
    """Inertia tensor about the centre of gravity, body axes (tensor entries, not products)."""

    xx: float = _f("kg*m^2", "I_xx about the CG", limits=_MOMENT)
    yy: float = _f("kg*m^2", "I_yy about the CG", limits=_MOMENT)
    zz: float = _f("kg*m^2", "I_zz about the CG", limits=_MOMENT)
    xy: float = _f("kg*m^2", "tensor entry I_xy (= -integral of x*y dm)", limits=_PRODUCT)
    xz: float = _f("kg*m^2", "tensor entry I_xz (= -integral of x*z dm)", limits=_PRODUCT)
    yz: float = _f("kg*m^2", "tensor entry I_yz (= -integral of y*z dm)", limits=_PRODUCT)

    def matrix(self) -> np.ndarray:
        return np.array(
            [[self.xx, self.xy, self.xz], [self.xy, self.yy, self.yz], [self.xz, self.yz, self.zz]]
        )


INERTIA_BOX = "box"
# the box's dimensions: in the parameter vector only where inertia_cg = "box" uses them
BOX_DIMENSIONS = ("width", "height")


class Vehicle(_Section):
    mass: float = _f("kg", "carriage mass", paper="9.3 kg",
                     limits=(1e-3, 1e6, "a gram-scale model to a 1000 t train"))
    length: float = _f("m", "carriage (cradle) length", paper="65 cm", limits=(1e-3, 1e3, _SIZE))
    inertia_cg: Inertia | str = Field(
        description="the inertia tensor about the CG: a table (xx, yy, zz, xy, xz, yz) given "
        f"explicitly, or \"{INERTIA_BOX}\": a uniform box of the mass, length, width and "
        "height, I = m/12 diag(w^2 + h^2, l^2 + h^2, l^2 + w^2), which follows the mass",
        json_schema_extra={"unit": "kg*m^2", "choices": ["a table", INERTIA_BOX]})
    width: float | None = Field(default=None, description="carriage width (body y), for "
                                "inertia_cg = \"box\"", json_schema_extra={
                                    "unit": "m", "limits": [1e-3, 1e3, _SIZE]})
    height: float | None = Field(default=None, description="carriage height (body z), for "
                                 "inertia_cg = \"box\"", json_schema_extra={
                                     "unit": "m", "limits": [1e-3, 1e3, _SIZE]})
    cg_offset: Vec3 = _f("m", "r_G: centre of gravity relative to the body origin O, body axes",
                         limits=_OFFSET)
    gravity: float = _f("m/s^2", "gravitational acceleration",
                        limits=(0.1, 100.0, "a small moon's 0.1 to a 10 g test rig"))

    @field_validator("inertia_cg", mode="before")
    @classmethod
    def _inertia_table_or_box(cls, value: Any) -> Any:
        if isinstance(value, str) and value != INERTIA_BOX:
            raise ValueError(f"expected a table (xx, yy, zz, xy, xz, yz) or \"{INERTIA_BOX}\"")
        return value

    @model_validator(mode="after")
    def _box_dimensions(self) -> Vehicle:
        if self.inertia_cg == INERTIA_BOX:
            for dim in BOX_DIMENSIONS:
                if getattr(self, dim) is None:
                    raise _ModelError(dim, "(missing)", f"inertia_cg = \"{INERTIA_BOX}\" "
                                      "computes the inertia from the length, width and height")
        return self

    @property
    def box(self) -> bool:
        """Whether the inertia is the uniform box's (computed from the mass)."""
        return self.inertia_cg == INERTIA_BOX

    def unused_fields(self) -> tuple[str, ...]:
        """Fields outside the parameter vector: the box's dimensions with an explicit tensor,
        the tensor's table with the box."""
        return ("inertia_cg",) if self.box else BOX_DIMENSIONS

    def inertia_matrix(self) -> np.ndarray:
        """I about the CG, body axes: the table's, or the uniform box's (box_inertia)."""
        if isinstance(self.inertia_cg, Inertia):
            return self.inertia_cg.matrix()
        return np.diag(box_principal_moments(self.mass, self.length, float(self.width or 0),
                                   float(self.height or 0)))


class Halbach(_Section):
    remanence: float = _f("T", "B_r of the magnet material (eq 4)",
                          limits=(1e-3, 2.5, "no permanent magnet reaches 2.5 T; NdFeB ~1.4 T"))
    thickness: float = _f("m", "d: array thickness normal to its face (eq 4)",
                          limits=(1e-4, 1.0, _ARRAY_SIZE))
    magnets_per_wavelength: int = _f(
        "1", "M: magnet elements per wavelength (eq 4)",
        limits=(2, 256, "eq 4 needs M >= 2; above 256 its factor sin(pi/M)/(pi/M) is 1 "
                        "within 3e-5"))
    wavelength: float = _f("m", "lambda: Halbach wavelength; k = 2*pi/lambda", paper="0.1 m",
                           limits=(1e-3, 10.0, _ARRAY_SIZE))
    width: float = _f("m", "w: transverse width of each array (eq 3)", paper="0.12 m",
                      limits=(1e-3, 10.0, _ARRAY_SIZE))


class Circuit(_Section):
    resistance: float = _f("ohm", "R: resistance of one track circuit (loop)",
                           paper="1.5e-3 ohm/loop",
                           limits=(1e-9, 1e3, "a near-superconducting loop to a thin wire"))
    inductance: float = _f("H", "L: inductance of one track circuit (loop)",
                           paper="2.6e-6 H/loop",
                           limits=(1e-12, 1.0, "a nanometre-scale loop to a many-turn coil"))
    pitch: float = _f("m", "p: spacing of the track circuits along the track (an array covers "
                           "circuits x pitch of it)",
                      limits=(1e-4, 1.0, "a 0.1 mm litz ladder to 1 m coils"))


class Array(_Section):
    position: Vec3 = _f("m", "centre of the array face, body axes, relative to O",
                        limits=_OFFSET)
    normal: Vec3 = _f("1", "direction of the track's repulsion on the array, body axes "
                           "(normalised on load)",
                      limits=(-1e3, 1e3, "a direction: only its ratios count; bounded so that "
                                         "its norm is finite"))
    nominal_gap: float = _f("m", "gap between array face and track surface at the design pose",
                            limits=(1e-5, 1.0, "the field decays as exp(-2 pi gap/lambda): "
                                               "Inductrack gaps are mm to cm"))
    circuits: float = _f("1", "track circuits under the array at any instant",
                         limits=(0.1, 1e5, "a fraction of one loop to a 100 m array at "
                                           "1 mm pitch"))

    @field_validator("normal")
    @classmethod
    def _unit_normal(cls, n: list[float]) -> list[float]:
        norm = math.sqrt(sum(c * c for c in n))
        if not norm > 0:
            raise ValueError("must be a non-zero vector")
        return [c / norm for c in n]


class Operation(_Section):
    speed: float = _f("m/s", "forward speed at which trim and gains are computed",
                      limits=(1e-3, 1e3, "moving, and under 1 km/s; the rail record is "
                                         "168 m/s"))
    propulsion_point: Vec3 = _f("m", "point of the body where the propulsion force acts",
                                limits=_OFFSET)


# the array control forces: eqs 22-23's body y and z components, or one along each normal
ACTUATOR_MODELS = ("paper", "normal")


class AxisDeviation(_Section):
    """The largest deviation from trim allowed on each controlled axis (Bryson's rule)."""

    y: float = _f("m", "lateral", limits=(1e-6, 0.1, "a micrometre to 10 cm"))
    z: float = _f("m", "heave", limits=(1e-6, 0.1, "a micrometre to 10 cm"))
    phi: float = _f("rad", "roll", limits=(1e-6, 0.5, "a microradian to about 30 degrees"))
    theta: float = _f("rad", "pitch", limits=(1e-6, 0.5, "a microradian to about 30 degrees"))
    psi: float = _f("rad", "yaw", limits=(1e-6, 0.5, "a microradian to about 30 degrees"))


_RATE = (1e-3, 1e4, "a 1000 s time constant to 0.1 ms")


class ControlSpec(_Section):
    """What the embedded controller must achieve, and how the firmware runs it: the `spec`
    controller is designed from it and every controller is verified against it. Not part of
    the model's parameter vector (it changes no equation)."""

    max_deviation: AxisDeviation = Field(default_factory=lambda: AxisDeviation(
        y=2e-3, z=2e-3, phi=5e-3, theta=4e-3, psi=5e-3), description="allowed deviation "
        "per axis (Bryson's rule: q1 = 1/a_max^2), the peak a run may reach: at least the "
        "disturbance's own reach (its offset and the motion it starts), else no controller "
        "meets it")
    force_budget: float = Field(
        default=20.0, description="largest control force of one array (the norm of its "
        "control components); Bryson's rule r = 1/F_max^2 with F_max the generalized force "
        "that alone takes one array to this budget; the allocation saturates at it",
        json_schema_extra={"unit": "N", "limits": [1e-6, 1e7, "a micronewton to 1000 t"]})
    min_damping_ratio: float = Field(
        default=0.5, description="smallest damping ratio of any closed-loop mode",
        json_schema_extra={"unit": "1", "limits": [0.0, 0.99, "from undamped to almost "
                                                   "critically damped"]})
    damping_margin: float = Field(
        default=0.1, description="the `spec` design's per-axis damping ratio above "
        "min_damping_ratio (the coupling between axes, the tick and its delay take some)",
        json_schema_extra={"unit": "1", "limits": [0.0, 0.5, "a design ratio below 1"]})
    min_decay_rate: float = Field(
        default=1.0, description="slowest allowed decay: every closed-loop eigenvalue's real "
        "part below minus this", json_schema_extra={"unit": "1/s", "limits": list(_RATE)})
    min_levitation_decay_rate: float = Field(
        default=5.0, description="slowest allowed decay of the levitation modes (every mode "
        "of the loop but the speed loop's): real part below minus this",
        json_schema_extra={"unit": "1/s", "limits": list(_RATE)})
    min_disk_gain_margin: float = Field(
        default=6.0, description="the embedded loop's multi-loop disk margin at the plant "
        "input (broken at the actuators, every array force at once), in gain",
        json_schema_extra={"unit": "dB", "limits": [0.0, 40.0, "none to a factor of 100"]})
    min_disk_phase_margin: float = Field(
        default=40.0, description="the same disk margin in phase",
        json_schema_extra={"unit": "deg", "limits": [0.0, 90.0, "none to the 90 degrees of "
                                                     "an infinite disk"]})
    min_delay_margin: int = Field(
        default=2, description="extra ticks of delay between the controller's array commands "
        "and the actuators that the embedded loop must stay stable with",
        json_schema_extra={"unit": "1", "limits": [0, 20, "none to twenty ticks"]})
    min_gap_margin: float = Field(
        default=3e-3, description="smallest gap of a run above track.min_gap",
        json_schema_extra={"unit": "m", "limits": [0.0, 0.1, "up to 10 cm"]})
    tick_rate: float = Field(
        default=1000.0, description="the controller's sampling rate in the firmware (zero-"
        "order hold between ticks)", json_schema_extra={
            "unit": "Hz", "limits": [1.0, 1e6, "1 Hz to 1 MHz"]})
    delay_ticks: int = Field(
        default=1, description="computation delay: a command computed at one tick is "
        "applied at the next (1) or at once (0)", json_schema_extra={
            "unit": "1", "limits": [0, 4, "at most four ticks late"]})
    speed_bandwidth: float = Field(
        default=5.0, description="the speed loop's closed-loop pole (the propulsion's "
        "feedback on the forward speed, beside the feedforward of the trim drag and m a)",
        json_schema_extra={"unit": "1/s", "limits": list(_RATE)})
    speed_integral_ratio: float = Field(
        default=0.5, description="the speed loop's integral action: the propulsion also "
        "feeds back the speed error's integral, with the gains that put the speed loop's "
        "poles at -speed_bandwidth and at -this x speed_bandwidth where the drag slope is "
        "lowest (`plant.speed_loop_gains`), so that a drag the feedforward misses leaves no "
        "steady speed error; 0: none (a steady error of dF_D / k_v). 0.5: the integral's "
        "pole at half the bandwidth (its zero at a third), at least 1.7/s over the default "
        "envelope against min_decay_rate 1/s",
        json_schema_extra={"unit": "1", "limits": [0.0, 1.0, "none to a double pole at "
                                                   "the bandwidth"]})
    speed_integral_limit: float = Field(
        default=100.0, description="the largest propulsion the speed integral may add or "
        "remove, |k_i xi| (anti-windup: the integral is clamped there at each tick, so "
        "that a speed error the drive cannot remove builds no unbounded correction). 100 N: "
        "twice the largest correction B0 -10 % or R, L +-30 % need over the default "
        "envelope (L -30 %: 47 N at 20 m/s; bench/experiments/speed_integral.py); the trim "
        "drag peaks at 143 N",
        json_schema_extra={"unit": "N", "limits": [0.0, 1e7, "none to 1000 t"]})


class Control(_Section):
    state_weights: Annotated[list[float], Field(min_length=2, max_length=2)] = _f(
        "1", "diagonal of Q per axis: [position, rate] (paper: Q = I)", paper="Q = I",
        limits=_WEIGHT)
    input_weight: float = _f("1", "R per axis (paper: R = 1)", paper="R = 1", limits=_WEIGHT)
    actuators: str = Field(
        default="paper", description="the array control forces: \"paper\" gives each array a "
        "force along body z and each array whose normal has a y part one along body y too "
        "(eqs 22-23); \"normal\" one force along each array's normal (what an array can push)",
        json_schema_extra={"unit": "-", "choices": list(ACTUATOR_MODELS)})
    spec: ControlSpec = Field(default_factory=ControlSpec, description="the specification "
                              "the controllers are designed to and verified against")

    @field_validator("actuators")
    @classmethod
    def _known_actuators(cls, name: str) -> str:
        if name not in ACTUATOR_MODELS:
            raise ValueError(f"expected one of {', '.join(ACTUATOR_MODELS)}")
        return name

    @field_validator("state_weights")
    @classmethod
    def _positive_weights(cls, q: list[float]) -> list[float]:
        if not all(c > 0 for c in q):
            raise ValueError("both weights must be > 0")
        return q


class Actuators(_Section):
    """What stands between a commanded array force and the force on the carriage: each array's
    control force follows its command through a first-order lag (a drive coil's current, L/R),
    within a force and a rate limit. Not part of the model's parameter vector (it changes no
    equation of the rigid body); the loop the `spec` controller is designed on and every linear
    verification include the lag (`maglevgen.control.plant`)."""

    time_constant: float = Field(
        default=2e-3, description="tau: each array's control force F follows its command F_c "
        "as tau F' = F_c - F (a drive coil's L/R); 0: the force appears at once",
        json_schema_extra={"unit": "s", "limits": [0.0, 1.0, "instant to a 1 s lag, far "
                                                   "slower than any levitation mode"]})
    force_limit: float = Field(
        default=20.0, description="largest control force one array's drive can produce (the "
        "norm of its control components); control.spec.force_budget may not exceed it",
        json_schema_extra={"unit": "N", "limits": [1e-6, 1e7, "a micronewton to 1000 t"]})
    rate_limit: float = Field(
        default=2e4, description="largest rate of change of one array's control force (the "
        "drive's voltage over the coil's inductance)",
        json_schema_extra={"unit": "N/s", "limits": [1e-3, 1e12, "a creeping drive to "
                                                     "an instant one"]})


class Track(_Section):
    min_gap: float = _f("m", "smallest gap before an array touches the track (contact)",
                        limits=(1e-6, 0.1, "a micrometre to 10 cm of mechanical clearance"))


class _Embeddable:
    """The embeddable controllers as the parameter table's choices, read from the registry
    when asked (a controller registered after import is one)."""

    def __iter__(self) -> Iterator[str]:
        return iter(embeddable())


_ENVELOPE_SPEED = "a 1 cm/s crawl to 1 km/s, past any rail launcher"


class Envelope(_Section):
    """The speeds the carriage flies and the launch: not part of the model's parameter vector
    (nothing here changes the equations; the envelope, the schedule and the launch read it)."""

    v_min: float | None = Field(
        default=None, description="lowest speed of the envelope (omitted: "
        "(1 + lift_off_margin) x the lift-off speed, found by the trim in C)",
        json_schema_extra={"unit": "m/s", "limits": [0.01, 1e3, _ENVELOPE_SPEED]})
    lift_off_margin: float = Field(
        default=0.5, description="margin of v_min above the lift-off speed when v_min is "
        "omitted (0.5: 50 % above)", json_schema_extra={
            "unit": "1", "limits": [0.05, 10.0, "at least 5 % above lift-off, where the "
                                    "guide wheels would still touch; at most 11 x lift-off"]})
    v_max: float = Field(description="release speed: the top of the envelope",
                         json_schema_extra={"unit": "m/s",
                                            "limits": [0.01, 1e3, _ENVELOPE_SPEED]})
    launch_acceleration: float = Field(
        description="steady acceleration of the launch run: the propulsion is the trim drag "
        "plus m times this (the paper's 'steady acceleration force')",
        json_schema_extra={"unit": "m/s^2", "limits": [1e-3, 1e3, "a creeping test to 100 g"]})
    schedule_nodes: int = Field(
        default=64, description="speeds of the gain schedule's spline nodes over "
        "[v_min, v_max]", json_schema_extra={
            "unit": "1", "limits": [4, 4096, "a cubic spline needs 4; 4096 x 56 values is "
                                   "past any controller's memory"]})
    embedded_controller: str = Field(
        default="spec", description="the controller the firmware C embeds and `build` "
        "verifies over the envelope", json_schema_extra={
            "unit": "-", "choices": _Embeddable()})  # type: ignore[dict-item]  # read live

    @field_validator("embedded_controller")
    @classmethod
    def _known_controller(cls, name: str) -> str:
        if name not in (known := embeddable()):
            raise ValueError(f"expected one of {', '.join(known)}")
        return name

    @model_validator(mode="after")
    def _ordered(self) -> Envelope:
        if self.v_min is not None and not self.v_min < self.v_max:
            raise _ModelError("v_min", f"{self.v_min:g}",
                              f"is not below envelope.v_max = {self.v_max:g}")
        return self


ARRAY_FORCE_LAWS = ("distributed", "point")
PAPER_ARRAY_FORCE = "point"  # the paper's eq 3 at the face centre


class ModelChoices(_Section):
    """Which physics the derivation uses: choices, not numbers of the parameter vector."""

    array_force: str = Field(
        default="distributed", description="force law of an array: 'distributed' sums the "
        "Inductrack circuit model over the tilted face (each circuit at its own gap, acting "
        "at the load's centroid); 'point' is the paper's eq 3 at the face centre with the "
        "centre gap", json_schema_extra={"unit": "-", "choices": list(ARRAY_FORCE_LAWS)})

    circuit_dynamics: str = Field(
        default="first-order", description="current of a track circuit: 'first-order' "
        "follows the moving gap through L I' + R I = Phi' to first order in the gap rates "
        "(the lag's rate term: damping below R/(k L), negative damping above it; "
        "derive/circuit_lag.py); 'quasi-static' is the paper's eq 3, the steady state at "
        "the instantaneous gap (no rate term), kept to reproduce the paper",
        json_schema_extra={"unit": "-", "choices": list(CIRCUIT_DYNAMICS)})

    @field_validator("array_force")
    @classmethod
    def _known_law(cls, name: str) -> str:
        if name not in ARRAY_FORCE_LAWS:
            raise ValueError(f"expected one of {', '.join(ARRAY_FORCE_LAWS)}")
        return name

    @field_validator("circuit_dynamics")
    @classmethod
    def _known_dynamics(cls, name: str) -> str:
        if name not in CIRCUIT_DYNAMICS:
            raise ValueError(f"expected one of {', '.join(CIRCUIT_DYNAMICS)}")
        return name


_SPREAD = (0.0, 1e6, "an absolute spread in the key's unit; the sampled values must also stay "
                    "inside the key's own range (checked against the file's value)")
# a normal tolerance is truncated at this many sigma, so its support is bounded and checked
NORMAL_TRUNCATION = 4.0


class Tolerance(_Section):
    """One parameter's spread about its value in the file, absolute, in the key's unit: a
    normal distribution (sigma, truncated at +-NORMAL_TRUNCATION sigma) or a uniform one
    (+- half-width). Exactly one of the two."""

    normal: float | None = Field(default=None, description="sigma of a normal distribution "
                                 f"truncated at +-{NORMAL_TRUNCATION:g} sigma",
                                 json_schema_extra={"unit": "key's", "limits": list(_SPREAD)})
    uniform: float | None = Field(default=None, description="half-width of a uniform "
                                  "distribution", json_schema_extra={"unit": "key's",
                                                                     "limits": list(_SPREAD)})

    @model_validator(mode="after")
    def _one_kind(self) -> Tolerance:
        if (self.normal is None) == (self.uniform is None):
            raise _ModelError("normal", f"{self.normal}, uniform = {self.uniform}",
                              "give exactly one of normal (sigma) or uniform (half-width)")
        return self

    @property
    def half_width(self) -> float:
        """The support's half-width: every sample lies within value +- this."""
        if self.normal is not None:
            return NORMAL_TRUNCATION * self.normal
        assert self.uniform is not None  # one of the two, validated
        return float(self.uniform)




class Tolerances(_Section):
    """What `maglevgen montecarlo` samples: not part of the model's parameter vector."""

    speed: Annotated[list[float], Field(min_length=2, max_length=2)] | None = Field(
        default=None, description="[lo, hi]: the hold speed drawn uniformly in it (omitted: "
        "the envelope's [v_min, v_max])", json_schema_extra={
            "unit": "m/s", "limits": [0.01, 1e3, _ENVELOPE_SPEED]})
    disturbance: dict[str, float] = Field(
        default_factory=lambda: dict(DISTURBANCE), description="per state (x, y, z, "
        "phi, theta, psi, u, v, w, p, q, r): the initial deviation from trim drawn uniformly "
        "in +- this amplitude", json_schema_extra={
            "unit": "m, rad, m/s or rad/s", "limits": [0.0, 0.1, "a disturbance from trim, "
                                                       "below the gaps' scale"]})
    parameters: dict[str, Tolerance] = Field(
        default_factory=dict, description="per entry of the parameter vector (its dotted name, "
        "as `maglevgen params show` prints it, e.g. \"vehicle.mass\", \"vehicle.cg_offset.z\")")

    @field_validator("disturbance")
    @classmethod
    def _known_states(cls, amps: dict[str, float]) -> dict[str, float]:
        from maglevgen.derive.conventions import STATE_INDEX

        for name, amp in amps.items():
            if name not in STATE_INDEX:
                raise _ModelError(name, _short(amp), "not a state: expected one of "
                                  + ", ".join(STATE_INDEX))
            if not (_number(amp) and 0.0 <= amp <= 0.1):
                raise _ModelError(name, _short(amp), "outside the range [0, 0.1] (a "
                                  "disturbance from trim, below the gaps' scale)")
        return amps

    @model_validator(mode="after")
    def _ordered(self) -> Tolerances:
        if self.speed is not None and not self.speed[0] < self.speed[1]:
            raise _ModelError("speed", _short(self.speed), "expected [lo, hi] with lo < hi")
        return self


_SAMPLE_RATE = (1.0, 1e6, "1 Hz to 1 MHz: at least the controller's tick")
_CUTOFF = (0.1, 5e5, "0.1 Hz to half of a 1 MHz sample rate")


class GapSensor(_Section):
    """One gap sensor: the array face it reads and where on that face. It measures the
    distance from its point along the face's normal (turning with the body) to the track
    plane that face runs over (derive/sensors.py)."""

    array: str = Field(description="the array whose face it sits on (a key of [arrays])",
                       json_schema_extra={"unit": "-"})
    across: float = _f("m", "from the face centre across the face (the face's e_s = n x e_t, "
                            "derive/distributed.py's face_axes; +y for an upward face)",
                       limits=(-10.0, 10.0, "on the face: within half the array's width"))
    along: float = Field(default=0.0, description="from the face centre along the face (e_t, "
                         "body x projected onto it)", json_schema_extra={
                             "unit": "m", "limits": [-100.0, 100.0,
                                                     "on the face: within half its length"]})


class GapSensors(_Section):
    """The gap sensors (eddy-current or laser triangulation) and what each reading carries."""

    noise: float = _f("m", "RMS noise of one reading at the tick (after the anti-alias "
                      "filter)", limits=(0.0, 1e-2, "a perfect sensor to 1 cm"))
    resolution: float = _f("m", "quantization step of a reading (adds step^2/12 to the "
                           "noise's variance)", limits=(0.0, 1e-2, "none to 1 cm"))
    sample_rate: float = _f("Hz", "readings per second", limits=_SAMPLE_RATE)
    anti_alias: float = _f("Hz", "cut-off of the first-order anti-alias filter before the "
                           "sampler (below half the sample rate)", limits=_CUTOFF)


class Imu(_Section):
    """The inertial measurement unit: a three-axis gyro and accelerometer at one point of the
    body, body axes."""

    position: Vec3 = _f("m", "the IMU's point, body axes, relative to O (what its "
                        "accelerometer's reading depends on)", limits=_OFFSET)
    gyro_noise: float = _f("rad/s/sqrt(Hz)", "gyro angle random walk (white rate noise "
                           "density, each axis)", limits=(0.0, 1.0, "a perfect gyro to 1 rad/s "
                                                              "in 1 Hz"))
    gyro_bias: float = _f("rad/s", "gyro in-run bias (each axis; in the simulated sensor, not "
                          "estimated)", limits=(0.0, 1.0, "none to 1 rad/s"))
    accel_noise: float = _f("m/s^2/sqrt(Hz)", "accelerometer velocity random walk (white "
                            "noise density, each axis)", limits=(0.0, 10.0, "a perfect "
                                                                  "accelerometer to 1 g"))
    accel_bias: float = _f("m/s^2", "accelerometer in-run bias (each axis; in the simulated "
                           "sensor, not estimated)", limits=(0.0, 10.0, "none to 1 g"))
    sample_rate: float = _f("Hz", "readings per second", limits=_SAMPLE_RATE)
    anti_alias: float = _f("Hz", "cut-off of the first-order anti-alias (digital low-pass) "
                           "filter (below half the sample rate)", limits=_CUTOFF)


class TrackSensor(_Section):
    """The position along the track (an encoder or track markers read on the carriage)."""

    noise: float = _f("m", "RMS noise of one reading", limits=(0.0, 10.0, "none to 10 m"))
    resolution: float = _f("m", "quantization step (adds step^2/12 to the noise's variance)",
                           limits=(0.0, 10.0, "none to 10 m"))
    sample_rate: float = _f("Hz", "readings per second", limits=_SAMPLE_RATE)


class ProcessNoise(_Section):
    """The forces no sensor measures, as the estimator's model takes them: white force and
    moment densities on the body (track irregularity, the arrays' field ripple above the
    Nyquist frequency), the Kalman filter's process noise."""

    force: float = _f("N/sqrt(Hz)", "one-sided density of an unmeasured force along each "
                      "axis (continuous intensity force^2/2)",
                      limits=(1e-9, 1e6, "any force a carriage meets, and not zero: a "
                                         "filter that trusts its model alone never corrects"))
    moment: float = _f("N*m/sqrt(Hz)", "one-sided density of an unmeasured moment about each "
                       "axis (continuous intensity moment^2/2)",
                       limits=(1e-9, 1e6, "as the force's"))


class Sensors(_Section):
    """What the carriage measures: the estimator's measurement equations (derive/sensors.py)
    and noise. Not part of the model's parameter vector (it changes no equation of motion).
    A group left out is not fitted."""

    gap: GapSensors | None = Field(default=None, description="what every gap sensor's "
                                   "reading carries (with gap_sensors)")
    gap_sensors: dict[str, GapSensor] = Field(default_factory=dict, description="the gap "
                                              "sensors by name: where each sits")
    imu: Imu | None = Field(default=None, description="the inertial measurement unit")
    track: TrackSensor | None = Field(default=None, description="the position along the "
                                      "track")
    disturbance: ProcessNoise = Field(default_factory=lambda: ProcessNoise(
        force=0.2, moment=0.05), description="the unmeasured forces the estimator assumes")

    @model_validator(mode="after")
    def _below_nyquist(self) -> Sensors:
        for name, group in (("gap", self.gap), ("imu", self.imu)):
            if group is not None and not group.anti_alias < group.sample_rate / 2:
                raise _ModelError(f"{name}.anti_alias", f"{group.anti_alias:g}",
                                  f"not below half the sample rate {group.sample_rate:g} Hz "
                                  "(the Nyquist frequency): it would not stop aliasing")
        if self.gap is None and self.imu is None and self.track is None:
            raise _ModelError("(sensors)", "{}", "no sensor: give gap, imu or track")
        if (self.gap is None) != (not self.gap_sensors):
            raise _ModelError("gap_sensors" if self.gap is None else "gap", "(missing)",
                              "gap sensors need both [sensors.gap] (their noise) and "
                              "[sensors.gap_sensors] (where they sit)")
        return self

    def groups(self) -> dict[str, GapSensors | Imu | TrackSensor]:
        """The fitted groups by name (gap, imu, track)."""
        return {k: v for k, v in (("gap", self.gap), ("imu", self.imu), ("track", self.track))
                if v is not None}


# sections and tables that are not part of the model's parameter vector (dotted keys)
NOT_IN_MODEL: tuple[str, ...] = ("envelope", "model", "provenance", "tolerances", "control.spec",
                                 "actuators", "sensors")
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
                raise _ModelError("<name>", _short(name), ARRAY_NAME_RULE)
            if name.upper() in seen:
                raise _ModelError("<name>", _short(name), f"same as array "
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
        if self.control.spec.force_budget > self.actuators.force_limit:
            raise _ModelError("control.spec.force_budget", f"{self.control.spec.force_budget:g}",
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
                raise _ModelError("provenance", _short(key), "names no parameter or table")
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
                raise _ModelError(f"sensors.{group}.sample_rate", f"{sensor.sample_rate:g}",
                                  f"below control.spec.tick_rate = {tick:g} Hz (a tick "
                                  "without a reading; multi-rate estimation is not modelled)")
        for name, g in self.sensors.gap_sensors.items():
            where = f"sensors.gap_sensors.{name}"
            arr = self.arrays.get(g.array)
            if arr is None:
                raise _ModelError(f"{where}.array", _short(g.array), "not an array: expected "
                                  "one of " + ", ".join(self.arrays))
            half_w = self.halbach.width / 2
            half_l = arr.circuits * self.circuit.pitch / 2
            if abs(g.across) > half_w * (1 + 1e-12):
                raise _ModelError(f"{where}.across", f"{g.across:g}", f"off the face: its "
                                  f"half-width is halbach.width / 2 = {half_w:g} m")
            if abs(g.along) > half_l * (1 + 1e-12):
                raise _ModelError(f"{where}.along", f"{g.along:g}", f"off the face: its "
                                  f"half-length is circuits x pitch / 2 = {half_l:g} m")

    def _tolerances_within_limits(self) -> None:
        """The file is refused when a tolerance can draw a value outside its key's range:
        every sample then passes the key checks (the cross-key rules are checked per sample,
        maglevgen.analyses.montecarlo)."""
        values = {e.name: e.value for e in flatten(self)}
        for key, tol in self.tolerances.parameters.items():
            where = f"tolerances.parameters.{key}"
            if key not in values:
                raise _ModelError(where, _short(tol.model_dump(exclude_none=True)),
                                  "not an entry of the parameter vector (see `maglevgen "
                                  "params show`)")
            if key.startswith("arrays.") and ".normal." in key:
                raise _ModelError(where, _short(tol.model_dump(exclude_none=True)),
                                  "an array's normal is a direction (normalised on load); "
                                  "tolerance its position instead")
            lo, hi, why = _leaf_limits(key)
            a, b = values[key] - tol.half_width, values[key] + tol.half_width
            if not lo <= a <= b <= hi:
                raise _ModelError(where, _short(tol.model_dump(exclude_none=True)),
                                  f"draws values in [{a:.6g}, {b:.6g}], outside the key's range "
                                  f"[{lo:g}, {hi:g}] ({why})")

    @property
    def wavenumber(self) -> float:
        return 2 * math.pi / self.halbach.wavelength


class _ModelError(ValueError):
    """A rule of the schema broken: ``key`` relative to where the validator sits."""

    def __init__(self, key: str, value: str, reason: str) -> None:
        super().__init__(reason)
        self.key, self.value, self.reason = key, value, reason


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


def _too_deep(data: Any, limit: int) -> tuple[str, Any] | None:
    """The first (dotted key, value) nested deeper than ``limit`` levels, or None."""
    stack: list[tuple[Any, tuple[str, ...], int]] = [(data, (), 1)]
    while stack:
        node, path, depth = stack.pop()
        if not isinstance(node, (dict, list)):
            continue
        if depth > limit:
            return ".".join(path), node
        items = node.items() if isinstance(node, dict) else enumerate(node)
        stack.extend((v, (*path, str(k)), depth + 1) for k, v in reversed(list(items)))
    return None


def _deepest_line(text: str) -> str:
    """The line with the most brackets: where a nesting too deep for the parser sits."""
    lines = text.splitlines() or [""]
    i = max(range(len(lines)), key=lambda j: lines[j].count("[") + lines[j].count("{"))
    key = re.match(r"\s*([^=\s]+)\s*=", lines[i])
    return f"line {i + 1}" + (f" (key {_short(key.group(1), 40)})" if key else "")


SCHEMA_DEPTH = _schema_depth(Parameters)  # 4: the document, arrays, one array, its position


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
            bad = ".".join(keys[: depth + 1])
            raise InputError(f"--set {dotted}: unknown key {bad!r}{did_you_mean(bad)}")
        node = node[key]
    # a key of the schema the file may omit (<name>: a table's key, any name)
    optional = any(re.fullmatch(re.escape(k).replace(re.escape("<name>"), r"[^.]+"), dotted)
                   for k, *_ in schema_rows())
    if not isinstance(node, dict) or (keys[-1] not in node and not optional):
        raise InputError(f"--set {dotted}: unknown key {dotted!r}{did_you_mean(dotted)}")
    node[keys[-1]] = value


#: the longest --set value (a vector or a small table; a parameter file holds more)
MAX_SET = 4000


def did_you_mean(key: str) -> str:
    """`` (did you mean 'vehicle.mass'?)`` for a misspelt key: the closest of the schema's keys
    and tables (difflib, an array's name read as ``<name>``), or "" when none is close."""
    known: set[str] = set()
    for row in schema_rows():
        parts = row[0].split(".")
        known.update(".".join(parts[:i]) for i in range(1, len(parts) + 1))
    parts = key.split(".")
    generic = ".".join(["arrays", "<name>", *parts[2:]]) if parts[0] == "arrays" and len(
        parts) > 1 else key
    parent, _, last = generic.rpartition(".")
    siblings = sorted(k.rpartition(".")[2] for k in known if k.rpartition(".")[0] == parent)
    close = [f"{parent}.{c}" if parent else c
             for c in difflib.get_close_matches(last, siblings, n=1, cutoff=0.6)]
    # a misspelt table further up: the closest whole key
    depth = generic.count(".")
    close = close or difflib.get_close_matches(
        generic, sorted(k for k in known if k.count(".") == depth), n=1, cutoff=0.8)
    if not close or close[0] == generic:
        return ""
    suggestion = close[0]
    if generic != key and suggestion.startswith("arrays.<name>"):
        suggestion = suggestion.replace("<name>", parts[1], 1)
    return f" (did you mean {suggestion!r}?)"


def parse_override(item: str) -> tuple[str, Any]:
    """Parse ``NAME=VALUE`` where VALUE is a TOML value (``9.3``, ``[0, 0, 0.01]``, ``"x"``)."""
    if "=" not in item:
        raise InputError(f"--set {item!r}: expected NAME=VALUE")
    name, raw = (s.strip() for s in item.split("=", 1))
    if not re.fullmatch(r"[A-Za-z0-9_]+(\.[A-Za-z0-9_]+)*", name):
        raise InputError(f"--set {_short(item)}: {_short(name)} is not a dotted parameter name")
    bad = check_text(item.split("=", 1)[1], MAX_SET)  # before strip(): a trailing newline too
    if bad is not None:  # a newline would let the value add keys of its own to the TOML
        one_line = " (one TOML value on one line)" if "control" in bad else ""
        raise InputError(f"--set {name}: the value {bad}{one_line}")
    try:
        doc = tomllib.loads(f"v = {raw}")
        if list(doc) != ["v"]:
            raise InputError(f"--set {name}: the value {_short(raw)} is more than one TOML "
                             "value")
        value = doc["v"]
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"--set {_short(item)}: not a TOML value ({exc})") from None
    except RecursionError:
        raise InputError(f"--set {name}: arrays or inline tables nested deeper than the "
                         f"schema's {SCHEMA_DEPTH} levels") from None
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
    deep = _too_deep(data, SCHEMA_DEPTH)
    if deep is not None:
        raise InputError(f"{origin}: {deep[0]} = {_short(deep[1])}: nested deeper than the "
                         f"schema's {SCHEMA_DEPTH} levels of tables and arrays")
    try:
        return Parameters.model_validate(data)
    except ValidationError as exc:
        err = exc.errors(include_url=False)[0]
        ctx_err = (err.get("ctx") or {}).get("error")
        if isinstance(ctx_err, _ModelError):
            key = _format_loc([p for p in [*err["loc"], ctx_err.key] if p != "Inertia"])
            raise InputError(f"{origin}: {key} = {ctx_err.value}: {ctx_err.reason}") from None
        loc = [p for p in err["loc"] if not (isinstance(p, str) and p.startswith("function-"))]
        if loc[:2] == ["vehicle", "inertia_cg"] and loc[2:3] in (["Inertia"], ["str"]):
            del loc[2]  # the member of ``Inertia | str`` pydantic names
        key = _format_loc(loc) or "(top level)"
        msg = err["msg"]
        if err["type"] == "missing":
            raise InputError(f"{origin}: missing key {key}") from None
        if err["type"] == "extra_forbidden":
            raise InputError(f"{origin}: unknown key {key}{did_you_mean(key)}") from None
        value = _lookup(data, loc)
        msg = msg.removeprefix("Value error, ")
        raise InputError(f"{origin}: {key} = {_short(value)}: {msg}") from None


def load_params(path: str | Path | None = None, overrides: Sequence[str] = ()) -> LoadedParams:
    """Load a parameter file (the default carriage when ``path`` is None) and apply overrides."""
    if isinstance(overrides, str):  # one "NAME=VALUE" would iterate by character
        overrides = (overrides,)
    if not isinstance(overrides, Sequence) or not all(isinstance(o, str) for o in overrides):
        raise InputError(f"--set {_short(overrides)}: expected NAME=VALUE strings (a list "
                         "of them)")
    if path is None:
        text, origin = default_params_text(), DEFAULT_PARAMS_NAME
    else:
        if not isinstance(path, (str, os.PathLike)) or isinstance(os.fspath(path), bytes) \
                or not os.fspath(path):
            raise InputError(f"--params {_short(path)}: expected a parameter file's path (a "
                             "non-empty str or pathlib.Path)")
        bad = check_text(os.fspath(path), 4096)
        if bad is not None:
            raise InputError(f"--params {_short(path)}: the path {bad}")
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
    except RecursionError:  # the parser recurses once per level of nesting
        raise InputError(f"{origin}: {_deepest_line(text)}: arrays or inline tables nested "
                         f"deeper than the schema's {SCHEMA_DEPTH} levels") from None
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
    extra = _extra(info)
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
            extra = _extra(info)
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
                    table := _table_of(ann)) is not None:
                walk(table, name + ".")  # an optional table (sensors, its groups)
            elif model is GapSensor and field == "array":
                rows.append((name, "-", info.description or "", "", "a key of [arrays]"))
            elif model is Vehicle and field == "inertia_cg":
                rows.append((name, "", info.description or "", "",
                             f"a table, or \"{INERTIA_BOX}\""))
                walk(Inertia, name + ".")
            elif model is Tolerances and field in ("parameters", "disturbance"):
                extra = _extra(info)
                if field == "disturbance":
                    lo, hi, why = extra["limits"]
                    rows.append((name, str(extra["unit"]), info.description or "",
                                 "", f"in {limits_text(lo, hi, '')}: {why}"))
                    continue
                rows.append((f"{name}.<key>", "", info.description or "", "",
                             "an entry of the parameter vector; its values +- the spread "
                             "inside the key's range"))
                walk(Tolerance, name + ".<key>.")
            elif field == "arrays":
                rows.append((f"{name}.<name>", "", "the name of an array (a table key)", "",
                             ARRAY_NAME_RULE.removeprefix("an array name must be ")))
                walk(Array, name + ".<name>.")
            else:
                extra = _extra(info)
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


def check_option(option: str, value: Any, lo: float, hi: float, unit: str, why: str) -> None:
    """A command-line number inside [lo, hi], or a one-line InputError naming it (a value
    that is no real number, from the Python API, too)."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InputError(f"{option} {_short(value)}: expected a number in "
                         f"{limits_text(lo, hi, unit)}")
    try:
        inside = math.isfinite(value) and lo <= value <= hi
    except OverflowError:  # an int past a float's range
        inside = False
    if not inside:
        shown = f"{value:g}" if isinstance(value, (float, np.floating)) else _short(value)
        raise InputError(f"{option} {shown}: outside the range {limits_text(lo, hi, unit)} "
                         f"({why})")


def check_count(option: str, value: Any, lo: int, hi: int, why: str) -> int:
    """A command-line count (``--samples``, ``--speeds``, ``--workers``, ``--seed``...) that is
    a whole number in [lo, hi], or a one-line InputError naming it: a bool, a float, a string
    or None from the Python API included (each gave a TypeError or ValueError deep in the
    work, or an allocation of terabytes)."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not (
            lo <= value <= hi):
        raise InputError(f"{option} {_short(value)}: expected a whole number from {lo} to "
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


def entry_limits(entry: str) -> tuple[float, float]:
    """(lo, hi) of an entry of the parameter vector: the range the run-time-parameter C
    checks p against (MAGLEV_ERR_PARAMETER), the same as a parameter file's."""
    lo, hi, _ = _leaf_limits(entry)
    return lo, hi


def _leaf_limits(entry: str) -> tuple[float, float, str]:
    """(lo, hi, why) of an entry of the parameter vector (``arrays.3.position.z``)."""
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
        table = _table_of(info.annotation)
        if table is not None:
            model, info = table, None
    lo, hi, why = info.json_schema_extra["limits"]
    return float(lo), float(hi), str(why)


def _table_of(ann: Any) -> type[BaseModel] | None:
    """The table type of a field's annotation (``Inertia`` of ``Inertia | str``), or None."""
    for tp in (ann, *get_args(ann)):
        if isinstance(tp, type) and issubclass(tp, BaseModel):
            return tp
    return None


def _model_field(key: str) -> Any:
    model: Any = Parameters
    *path, last = key.split(".")
    for part in path:
        model = _table_of(model.model_fields[part].annotation)
    return model.model_fields[last]


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
