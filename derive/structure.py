"""What the symbolic derivation depends on besides parameter values, without SymPy.

A carriage's structure (its parameter vector's names, its arrays and their control force
components) keys every cache and orders the inputs; the simulation path reads only this, so
running the compiled model imports no SymPy.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from maglevgen.derive import conventions as cv

__all__ = ["CIRCUIT_DYNAMICS", "NORMAL_AXIS", "Structure", "box_principal_moments",
           "control_components", "explicit_inertia", "input_names_of", "numbered"]

# Body axes a control force component of an array can act along (paper eqs 22-23: F_y, F_z).
CONTROL_AXES: tuple[str, ...] = ("y", "z")
# model.circuit_dynamics: the circuits' first-order lag (derive/circuit_lag.py) or eq 3's
# steady state (the paper's)
CIRCUIT_DYNAMICS: tuple[str, ...] = ("first-order", "quasi-static")
# The component of an array's one actuator along its own normal (control.actuators = "normal").
NORMAL_AXIS = "n"


@dataclass(frozen=True)
class Structure:
    """What the symbolic derivation depends on besides parameter values.

    ``param_names`` is the ordered parameter vector (from the schema, see params.flatten);
    ``arrays`` pairs each array name with its control force components (e.g. ("y", "z"));
    ``array_force`` is the array force law: "distributed" (the circuit model summed over the
    tilted face, derive/distributed.py) or "point" (eq 3 at the face centre, the paper's);
    ``circuit_dynamics`` is "first-order" (the circuits' electrical lag to first order in the
    gap rates, derive/circuit_lag.py) or "quasi-static" (eq 3's steady state, the paper's).
    """

    param_names: tuple[str, ...]
    arrays: tuple[tuple[str, tuple[str, ...]], ...]
    array_force: str = "point"
    circuit_dynamics: str = "quasi-static"

    @property
    def array_names(self) -> tuple[str, ...]:
        """The arrays in the parameter file's order (that of the generated gaps)."""
        return tuple(name for name, _ in self.arrays)

    @property
    def array_of_force(self) -> tuple[int, ...]:
        """The array (0-based) of each control force, in the input order after F_prop
        (`input_names_of`): what a per-array force budget sums over."""
        return tuple(i for i, (_, comps) in enumerate(self.arrays) for _ in comps)


def numbered(structure: Structure) -> Structure:
    """``structure`` with its arrays named by their place ("1", "2", ...), in the parameter
    names too. An array's name is a label: the derivation reads a parameter by its name and
    orders nothing by it, so the C generated from this structure (which holds p's indices,
    never a name) serves every structure that differs from it only in array names, and a
    renamed array derives and compiles nothing new. (SymPy orders a sum's terms by symbol
    name, so deriving under the other names would give the same functions in another order
    of operations.) The LLNL carriage's arrays are named 1 to 6 in order: its own structure."""
    place = {name: str(i) for i, (name, _) in enumerate(structure.arrays, 1)}

    def param(name: str) -> str:
        head, sep, rest = name.partition(".")
        if head != "arrays" or not sep:
            return name
        array, dot, key = rest.partition(".")
        return f"arrays.{place[array]}{dot}{key}"

    return Structure(tuple(param(n) for n in structure.param_names),
                     tuple((place[name], comps) for name, comps in structure.arrays),
                     structure.array_force, structure.circuit_dynamics)


def control_components(normal_values: Sequence[float], actuators: str = "paper",
                       tol: float = 1e-12) -> tuple[str, ...]:
    """Control force components an array has.

    "paper" (eqs 22-23): the body axes (y, z) its normal has a part along. Arrays facing up
    have a z component only; the 45-degree arrays have both, which gives the ten array forces
    of the paper (F_z1..F_z6 and F_y1, F_y2, F_y4, F_y5) for its geometry. "normal": one
    force along the array's normal, F_n<array> (six for the paper's six arrays).
    """
    if actuators == "normal":
        return (NORMAL_AXIS,)
    return tuple(ax for ax in CONTROL_AXES if abs(normal_values["xyz".index(ax)]) > tol)


def input_names_of(structure: Structure) -> tuple[str, ...]:
    """Input order: F_prop, then F_<axis><array> for each array's control components."""
    names = [cv.PROPULSION.name]
    for name, comps in structure.arrays:
        names += [f"F_{ax}{name}" for ax in comps]
    return tuple(names)


def box_principal_moments(mass: Any, length: Any, width: Any, height: Any
                          ) -> tuple[Any, Any, Any]:
    """Principal moments about the centre of a uniform box (numbers or SymPy expressions),
    vehicle.inertia_cg = "box": m/12 (w^2 + h^2), m/12 (l^2 + h^2), m/12 (l^2 + w^2) about x
    (the length), y (the width) and z (the height)."""
    return (mass * (width**2 + height**2) / 12, mass * (length**2 + height**2) / 12,
            mass * (length**2 + width**2) / 12)


def explicit_inertia(param_names: Sequence[str]) -> bool:
    """Whether the parameter vector holds the inertia tensor (else the box's dimensions)."""
    return "vehicle.inertia_cg.xx" in param_names
