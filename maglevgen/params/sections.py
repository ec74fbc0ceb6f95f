"""The parameter file's sections: one model per table, each field with its unit and range."""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Annotated, Any

import numpy as np
from pydantic import Field, field_validator, model_validator

from maglevgen.controllers import embeddable
from maglevgen.derive.conventions import (
    DISTURBANCE,  # the initial disturbance of `maglevgen simulate`
)
from maglevgen.derive.structure import CIRCUIT_DYNAMICS, box_principal_moments
from maglevgen.params.fields import ModelError, Section, Vec3, finite_number, short_repr

__all__ = ["ACTUATOR_LAG", "ACTUATOR_MODELS", "ARRAY_FORCE_LAWS", "INERTIA_BOX",
           "LOOP_TOLERANCES", "NORMAL_TRUNCATION", "PAPER_ARRAY_FORCE", "SENSOR_TOLERANCES",
           "Actuators", "Array", "Circuit",
           "Control", "ControlSpec", "Envelope", "GapSensor", "GapSensors", "Halbach", "Imu",
           "Inertia", "ModelChoices", "Operation", "ProcessNoise", "Sensors", "Tolerance",
           "Tolerances", "Track", "TrackSensor", "Vehicle"]


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


class Inertia(Section):
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


class Vehicle(Section):
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
                    raise ModelError(dim, "(missing)", f"inertia_cg = \"{INERTIA_BOX}\" "
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


class Halbach(Section):
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


class Circuit(Section):
    resistance: float = _f("ohm", "R: resistance of one track circuit (loop)",
                           paper="1.5e-3 ohm/loop",
                           limits=(1e-9, 1e3, "a near-superconducting loop to a thin wire"))
    inductance: float = _f("H", "L: inductance of one track circuit (loop)",
                           paper="2.6e-6 H/loop",
                           limits=(1e-12, 1.0, "a nanometre-scale loop to a many-turn coil"))
    pitch: float = _f("m", "p: spacing of the track circuits along the track (an array covers "
                           "circuits x pitch of it)",
                      limits=(1e-4, 1.0, "a 0.1 mm litz ladder to 1 m coils"))


class Array(Section):
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


class Operation(Section):
    speed: float = _f("m/s", "forward speed at which trim and gains are computed",
                      limits=(1e-3, 1e3, "moving, and under 1 km/s; the rail record is "
                                         "168 m/s"))
    propulsion_point: Vec3 = _f("m", "point of the body where the propulsion force acts",
                                limits=_OFFSET)


# the array control forces: eqs 22-23's body y and z components, or one along each normal
ACTUATOR_MODELS = ("paper", "normal")


class AxisDeviation(Section):
    """The largest deviation from trim allowed on each controlled axis (Bryson's rule)."""

    y: float = _f("m", "lateral", limits=(1e-6, 0.1, "a micrometre to 10 cm"))
    z: float = _f("m", "heave", limits=(1e-6, 0.1, "a micrometre to 10 cm"))
    phi: float = _f("rad", "roll", limits=(1e-6, 0.5, "a microradian to about 30 degrees"))
    theta: float = _f("rad", "pitch", limits=(1e-6, 0.5, "a microradian to about 30 degrees"))
    psi: float = _f("rad", "yaw", limits=(1e-6, 0.5, "a microradian to about 30 degrees"))


_RATE = (1e-3, 1e4, "a 1000 s time constant to 0.1 ms")


class ControlSpec(Section):
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


class Control(Section):
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


class Actuators(Section):
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


class Track(Section):
    min_gap: float = _f("m", "smallest gap before an array touches the track (contact)",
                        limits=(1e-6, 0.1, "a micrometre to 10 cm of mechanical clearance"))


class _Embeddable:
    """The embeddable controllers as the parameter table's choices, read from the registry
    when asked (a controller registered after import is one)."""

    def __iter__(self) -> Iterator[str]:
        return iter(embeddable())


_ENVELOPE_SPEED = "a 1 cm/s crawl to 1 km/s, past any rail launcher"


class Envelope(Section):
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
            raise ModelError("v_min", f"{self.v_min:g}",
                             f"is not below envelope.v_max = {self.v_max:g}")
        return self


ARRAY_FORCE_LAWS = ("distributed", "point")
PAPER_ARRAY_FORCE = "point"  # the paper's eq 3 at the face centre


class ModelChoices(Section):
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


class Tolerance(Section):
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
            raise ModelError("normal", f"{self.normal}, uniform = {self.uniform}",
                             "give exactly one of normal (sigma) or uniform (half-width)")
        return self

    @property
    def half_width(self) -> float:
        """The support's half-width: every sample lies within value +- this."""
        if self.normal is not None:
            return NORMAL_TRUNCATION * self.normal
        assert self.uniform is not None  # one of the two, validated
        return float(self.uniform)


#: the [sensors] entries a tolerance may spread besides the parameter vector: what a real
#: sensor does apart from its datasheet (each reading's noise, each IMU axis's in-run bias).
#: A Monte-Carlo sample's readings carry its drawn values; the firmware's Kalman gains stay
#: the design on the file's values. Resolutions, rates and filters are the converter's design,
#: not spreads; the disturbance is the filter's assumption, not a sensor's.
SENSOR_TOLERANCES = ("sensors.gap.noise", "sensors.imu.gyro_noise", "sensors.imu.gyro_bias",
                     "sensors.imu.accel_noise", "sensors.imu.accel_bias", "sensors.track.noise")

#: the actuators' lag (each array force's L/R) a tolerance may spread: what the real drive
#: does apart from its nominal L/R. A sample's plant lags by its drawn value; the firmware's
#: design (K_lag, K_delay, its prediction's lag pole, the sense tick's tables) stays the
#: file's. A draw must stay > 0 (0 is a plant without the lag the design feeds back).
ACTUATOR_LAG = "actuators.time_constant"

#: every entry a tolerance may spread besides the parameter vector: the loop's (the actuators'
#: lag, the sensors' noises and biases), flown by each Monte-Carlo sample's run while the
#: firmware's design stays the one on the file's values
LOOP_TOLERANCES = (ACTUATOR_LAG, *SENSOR_TOLERANCES)


class Tolerances(Section):
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
        "as `maglevgen params show` prints it, e.g. \"vehicle.mass\", \"vehicle.cg_offset.z\"), "
        "or per sensor noise or bias (" + ", ".join(f'"{k}"' for k in SENSOR_TOLERANCES)
        + "): each sample's readings carry its drawn value, the Kalman gains stay the design "
        f"on the file's; or \"{ACTUATOR_LAG}\" (each array force's lag, > 0 in every "
        "draw): each sample's plant lags by its drawn value, the firmware's gains, lag "
        "prediction and Kalman filter stay the design on the file's")

    @field_validator("disturbance")
    @classmethod
    def _known_states(cls, amps: dict[str, float]) -> dict[str, float]:
        from maglevgen.derive.conventions import STATE_INDEX

        for name, amp in amps.items():
            if name not in STATE_INDEX:
                raise ModelError(name, short_repr(amp), "not a state: expected one of "
                                 + ", ".join(STATE_INDEX))
            if not (finite_number(amp) and 0.0 <= amp <= 0.1):
                raise ModelError(name, short_repr(amp), "outside the range [0, 0.1] (a "
                                 "disturbance from trim, below the gaps' scale)")
        return amps

    @model_validator(mode="after")
    def _ordered(self) -> Tolerances:
        if self.speed is not None and not self.speed[0] < self.speed[1]:
            raise ModelError("speed", short_repr(self.speed), "expected [lo, hi] with lo < hi")
        return self


_SAMPLE_RATE = (1.0, 1e6, "1 Hz to 1 MHz: at least the controller's tick")
_CUTOFF = (0.1, 5e5, "0.1 Hz to half of a 1 MHz sample rate")


class GapSensor(Section):
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


class GapSensors(Section):
    """The gap sensors (eddy-current or laser triangulation) and what each reading carries."""

    noise: float = _f("m", "RMS noise of one reading at the tick (after the anti-alias "
                      "filter)", limits=(0.0, 1e-2, "a perfect sensor to 1 cm"))
    resolution: float = _f("m", "quantization step of a reading (adds step^2/12 to the "
                           "noise's variance)", limits=(0.0, 1e-2, "none to 1 cm"))
    sample_rate: float = _f("Hz", "readings per second", limits=_SAMPLE_RATE)
    anti_alias: float = _f("Hz", "cut-off of the first-order anti-alias filter before the "
                           "sampler (below half the sample rate)", limits=_CUTOFF)


class Imu(Section):
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


class TrackSensor(Section):
    """The position along the track (an encoder or track markers read on the carriage)."""

    noise: float = _f("m", "RMS noise of one reading", limits=(0.0, 10.0, "none to 10 m"))
    resolution: float = _f("m", "quantization step (adds step^2/12 to the noise's variance)",
                           limits=(0.0, 10.0, "none to 10 m"))
    sample_rate: float = _f("Hz", "readings per second", limits=_SAMPLE_RATE)


class ProcessNoise(Section):
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


class Sensors(Section):
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
                raise ModelError(f"{name}.anti_alias", f"{group.anti_alias:g}",
                                 f"not below half the sample rate {group.sample_rate:g} Hz "
                                 "(the Nyquist frequency): it would not stop aliasing")
        if self.gap is None and self.imu is None and self.track is None:
            raise ModelError("(sensors)", "{}", "no sensor: give gap, imu or track")
        if (self.gap is None) != (not self.gap_sensors):
            raise ModelError("gap_sensors" if self.gap is None else "gap", "(missing)",
                             "gap sensors need both [sensors.gap] (their noise) and "
                             "[sensors.gap_sensors] (where they sit)")
        return self

    def groups(self) -> dict[str, GapSensors | Imu | TrackSensor]:
        """The fitted groups by name (gap, imu, track)."""
        return {k: v for k, v in (("gap", self.gap), ("imu", self.imu), ("track", self.track))
                if v is not None}
