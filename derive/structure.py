"""What the symbolic derivation depends on besides parameter values, without SymPy.

A carriage's structure (its parameter vector's names, its arrays and their control force
components) keys every cache and orders the inputs; the simulation path reads only this, so
running the compiled model imports no SymPy.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from . import conventions as cv

# Body axes a control force component of an array can act along (paper eqs 22-23: F_y, F_z).
CONTROL_AXES: tuple[str, ...] = ("y", "z")


@dataclass(frozen=True)
class Structure:
    """What the symbolic derivation depends on besides parameter values.

    ``param_names`` is the ordered parameter vector (from the schema, see params.flatten);
    ``arrays`` pairs each array name with its control force components (e.g. ("y", "z"));
    ``array_force`` is the array force law: "distributed" (the circuit model summed over the
    tilted face, derive/distributed.py) or "point" (eq 3 at the face centre, the paper's).
    """

    param_names: tuple[str, ...]
    arrays: tuple[tuple[str, tuple[str, ...]], ...]
    array_force: str = "point"


def control_components(normal_values: Sequence[float], tol: float = 1e-12) -> tuple[str, ...]:
    """Control force components an array has: the body axes (y, z) its normal has a part along.

    Arrays facing up have a z component only; the 45-degree arrays have both, which gives the
    ten array forces of the paper (F_z1..F_z6 and F_y1, F_y2, F_y4, F_y5) for its geometry.
    """
    return tuple(ax for ax in CONTROL_AXES if abs(normal_values["xyz".index(ax)]) > tol)


def input_names_of(structure: Structure) -> tuple[str, ...]:
    """Input order: F_prop, then F_<axis><array> for each array's control components."""
    names = [cv.PROPULSION.name]
    for name, comps in structure.arrays:
        names += [f"F_{ax}{name}" for ax in comps]
    return tuple(names)
