"""Array geometry: exact gaps from the pose, array forces and moments, the sums of eqs 8-12.

Each array i has a body-frame face centre a_i and unit normal n_i (the direction in which the
track pushes it). The track surface it faces is a plane fixed in the inertial frame through the
point a_i - g0_i n_i of the design pose, with the same normal; so the exact gap at pose (X, R) is

    gap_i = g0_i + n_i . (X + (R - 1) a_i)

with no small-angle approximation. The lift acts along n_i (inertial, the track's normal) and
the drag along -x; their moments are taken about O with the rotated arm R a_i.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import sympy as sp

from maglevgen.derive.structure import NORMAL_AXIS

__all__ = ["ArraySymbols", "array_gap", "array_gap_rate", "array_speed", "array_wrench",
           "control_direction", "control_effectiveness", "generalized_wrench_row"]

_AXIS_VECTOR = {"x": (1, 0, 0), "y": (0, 1, 0), "z": (0, 0, 1)}


@dataclass(frozen=True)
class ArraySymbols:
    """The symbols of one array's geometry and circuit count."""

    name: str
    position: sp.Matrix  # a_i, body frame
    normal: sp.Matrix  # n_i, body frame, unit
    nominal_gap: sp.Symbol
    circuits: sp.Symbol


def array_gap(arr: ArraySymbols, position_O: sp.Matrix, R: sp.Matrix) -> sp.Expr:
    """Exact gap of an array at pose (X, R) (see the module docstring)."""
    return arr.nominal_gap + (arr.normal.T * (position_O + (R - sp.eye(3)) * arr.position))[0]


def array_gap_rate(arr: ArraySymbols, R: sp.Matrix, velocity: sp.Matrix, omega: sp.Matrix
                   ) -> sp.Expr:
    """Rate of the exact gap along the motion: n_i . R (v + omega x a_i) (X' = R v and
    R' = R [omega]x with body velocities; zero at trim, which moves along the track)."""
    return (arr.normal.T * R * (velocity + omega.cross(arr.position)))[0]


def array_speed(arr: ArraySymbols, R: sp.Matrix, velocity: sp.Matrix, omega: sp.Matrix
                ) -> sp.Expr:
    """Along-track (inertial x) speed of an array's face centre: (R (v + w x a_i))_x."""
    return (R[0, :] * (velocity + omega.cross(arr.position)))[0]


def array_wrench(arr: ArraySymbols, lift: sp.Expr, drag: sp.Expr, R: sp.Matrix,
                 arm: sp.Matrix | None = None) -> tuple[sp.Matrix, sp.Matrix]:
    """An array's force (lift along n_i, drag along -x) and its moment about O, inertial axes.

    The force acts at ``arm`` (body axes; default the face centre a_i, the paper's model)."""
    force = lift * arr.normal - drag * sp.Matrix([1, 0, 0])
    return force, (R * (arr.position if arm is None else arm)).cross(force)


def generalized_wrench_row(position: sp.Matrix, direction: sp.Matrix) -> sp.Matrix:
    """(F_y, F_z, M_x, M_y, M_z) about O of a unit force along ``direction`` at ``position``."""
    m = position.cross(direction)
    return sp.Matrix([direction[1], direction[2], m[0], m[1], m[2]])


def control_direction(component: str, normal: sp.Matrix | None = None) -> sp.Matrix:
    """Body-frame unit direction of a control force component: a body axis (y, z) of eqs
    22-23, or the array's unit normal for NORMAL_AXIS (control.actuators = "normal")."""
    if component == NORMAL_AXIS:
        if normal is None:
            raise ValueError("a force along the normal needs the array's normal")
        return sp.Matrix(normal)
    return sp.Matrix(_AXIS_VECTOR[component])


def control_effectiveness(positions: Sequence[sp.Matrix], components: Sequence[Sequence[str]],
                          normals: Sequence[sp.Matrix] | None = None) -> sp.Matrix:
    """E (5 x n): generalized forces (u_y, u_z, u_phi, u_theta, u_psi) from array forces.

    Column j is the wrench about O of a unit control force component of one array at its
    face centre, at the design pose; columns are ordered array by array, y before z. A
    component along the normal (NORMAL_AXIS) needs ``normals`` (unit, body frame).
    """
    cols = []
    for i, (pos, comps) in enumerate(zip(positions, components, strict=True)):
        for ax in comps:
            d = control_direction(ax, normals[i] if normals is not None else None)
            cols.append(generalized_wrench_row(pos, d))
    return sp.Matrix.hstack(*cols)
