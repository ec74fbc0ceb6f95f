"""Axis and angle conventions, state and input order: the one place everything else reads.

Frames (right-handed):
- inertial (track) frame: x along the track in the direction of travel, y lateral (to the
  left when looking along +x), z vertically up. Gravity is -g along z.
- body (carriage) frame: origin O at the carriage's geometric reference point; axes coincide
  with the inertial ones at the design pose (all states zero).
- attitude: Z-Y-X Euler angles (yaw psi about z, then pitch theta about y, then roll phi
  about x); R = Rz(psi) Ry(theta) Rx(phi) maps body components to inertial components.

The paper's axis labels differ (its eq 11 calls pitch a moment about z and eq 12 yaw a moment
about y); this toolchain keeps one convention: roll about x, pitch about y, yaw about z.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["ARRAY_INPUTS", "ATTITUDE", "AXES", "AXIS_COORDINATES", "AXIS_POSITION_STATE",
           "CONTROLS", "DISTURBANCE", "KINETIC", "N_STATES", "POSITION", "PROPULSION",
           "PROPULSION_INPUT", "Q_STATES", "RATES", "STATES", "STATE_INDEX", "STATE_NAMES",
           "VELOCITY", "Signal"]


@dataclass(frozen=True)
class Signal:
    """A named scalar signal with its unit and a one-line description."""

    name: str
    unit: str
    description: str


STATES: tuple[Signal, ...] = (
    Signal("x", "m", "inertial position of O along the track"),
    Signal("y", "m", "inertial lateral position of O"),
    Signal("z", "m", "inertial vertical position of O (heave from the design pose)"),
    Signal("phi", "rad", "roll angle (Z-Y-X Euler)"),
    Signal("theta", "rad", "pitch angle (Z-Y-X Euler)"),
    Signal("psi", "rad", "yaw angle (Z-Y-X Euler)"),
    Signal("u", "m/s", "velocity of O along body x"),
    Signal("v", "m/s", "velocity of O along body y"),
    Signal("w", "m/s", "velocity of O along body z"),
    Signal("p", "rad/s", "body roll rate"),
    Signal("q", "rad/s", "body pitch rate"),
    Signal("r", "rad/s", "body yaw rate"),
)

STATE_NAMES: tuple[str, ...] = tuple(s.name for s in STATES)
STATE_INDEX: dict[str, int] = {n: i for i, n in enumerate(STATE_NAMES)}
N_STATES = len(STATES)


def state_span(first: str, last: str) -> slice:
    """The slice of STATES from ``first`` to ``last`` (both included): the state vector's
    named blocks are read from here, never written as numbers."""
    return slice(STATE_INDEX[first], STATE_INDEX[last] + 1)


# The blocks of the state vector (eqs 1-2): the inertial position of O, the Z-Y-X Euler
# angles, the body velocity and the body rates; KINETIC the velocity and rates together (the
# states whose derivatives are the accelerations, the trim's residual).
POSITION = state_span("x", "z")
ATTITUDE = state_span("phi", "psi")
VELOCITY = state_span("u", "w")
RATES = state_span("p", "r")
KINETIC = state_span("u", "r")

# The five controlled degrees of freedom of the paper's eqs 17-21, in its order
# a0 = [dy, dz, phi, theta, psi]; each axis pairs a position state with its rate state.
AXES: tuple[str, ...] = ("lateral", "vertical", "roll", "pitch", "yaw")
AXIS_POSITION_STATE: dict[str, str] = {
    "lateral": "y",
    "vertical": "z",
    "roll": "phi",
    "pitch": "theta",
    "yaw": "psi",
}
# The axis coordinates a = (y, z, phi, theta, psi): the states the per-axis design works on.
Q_STATES: tuple[str, ...] = tuple(AXIS_POSITION_STATE[a] for a in AXES)
# ... which are one block of the state vector: the pose without the along-track position.
AXIS_COORDINATES = state_span(Q_STATES[0], Q_STATES[-1])
assert STATE_NAMES[AXIS_COORDINATES] == Q_STATES
# Generalized control force of each axis (the paper's u_y, u_z, u_phi, u_theta, u_psi).
CONTROLS: tuple[Signal, ...] = (
    Signal("u_y", "N", "lateral control force (inertial y)"),
    Signal("u_z", "N", "vertical control force (inertial z)"),
    Signal("u_phi", "N*m", "roll control moment about O"),
    Signal("u_theta", "N*m", "pitch control moment about O"),
    Signal("u_psi", "N*m", "yaw control moment about O"),
)

# Inputs of the dynamics: the propulsion force and each array's control force components.
PROPULSION = Signal("F_prop", "N", "propulsion force along the track (inertial x)")
#: where they stand in the input vector u (`derive.structure.input_names_of`): the propulsion
#: first, then each array's control force components, array by array
PROPULSION_INPUT = 0
ARRAY_INPUTS = slice(1, None)

#: The initial disturbance from trim per state (m, rad) of `maglevgen simulate`, and the
#: parameter file's default tolerances.disturbance: small against the gaps (15 mm upper,
#: 30 mm lower) so the response stays in the linear range the controllers were designed for.
DISTURBANCE: dict[str, float] = {"y": 1e-3, "z": 1e-3, "phi": 2e-3, "theta": 2e-3, "psi": 2e-3}
