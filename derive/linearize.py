"""Linearisation at trim: the stiffness matrix K_st0 (eqs 5-19) and the full A, B.

The generalized coordinates of eqs 17-19 are q = (y, z, phi, theta, psi) and the generalized
forces (F_y, F_z, M_x, M_y, M_z): inertial components, moments about O. The magnetic stiffness
is K_st0 = -dW/dq of the array forces alone, holding the speed (V, 0, 0) fixed. Because every
array's lift and drag scale as exp(-2 k gap) (eq 3), d(lift_i)/d(gap_i) = -2 k lift_i exactly,
which gives K_st0 in closed form in the trim array forces (the derivation the paper's eqs 13-16
sketch with small-angle arguments); it is derived here from the geometry for any pose.
"""

from __future__ import annotations

from dataclasses import dataclass

import sympy as sp

from maglevgen.derive import conventions as cv
from maglevgen.derive.differentiate import Differentiator, jacobian, xreplace
from maglevgen.derive.geometry import array_wrench
from maglevgen.derive.memo import memoized
from maglevgen.derive.model import CarriageModel, Structure, build_model, inertia_cg_matrix
from maglevgen.derive.rigid_body import inertia_about_origin

__all__ = ["Q_STATES", "STIFFNESS_PARTS", "design_pose_stiffness", "generalized_mass_expr",
           "stiffness_form", "stiffness_parts"]

GENERALIZED_FORCES: tuple[str, ...] = ("F_y", "F_z", "M_x", "M_y", "M_z")
Q_STATES = cv.Q_STATES  # re-exported: the axis coordinates live in conventions


@dataclass(frozen=True)
class StiffnessForm:
    """Symbolic K_st0 (5x5) in the trim array forces and the pose (eqs 13-19 derived)."""

    K: sp.Matrix  # magnetic K_st0, in (q, F_L, F_D, p)
    K_other: sp.Matrix  # gravity (CG offset) and propulsion moments, in (q, F_prop, p)
    q: sp.Matrix
    lift_sym: sp.Matrix
    drag_sym: sp.Matrix


@memoized
def stiffness_form(structure: Structure) -> StiffnessForm:
    """K_st0 = -dW/dq of the array wrench with lift_i = F_L_i exp(-2k (gap_i(q) - gap_i*)),
    times f_i(q) / f_i* for the distributed model (its load factor, derive/distributed.py),
    acting at the array's point of action."""
    m = build_model(structure)
    q = sp.Matrix([m.x[cv.STATE_INDEX[s]] for s in Q_STATES])
    trim_gap = sp.Matrix(sp.symbols(f"G0:{len(m.arrays)}", real=True))
    trim_factor = sp.Matrix(sp.symbols(f"LF0:{len(m.arrays)}", real=True))
    ex = sp.Matrix([1, 0, 0])
    W = sp.zeros(6, 1)
    for i, a in enumerate(m.arrays):
        scale = sp.exp(-2 * m.wavenumber * (m.gaps[i] - trim_gap[i]))
        if m.load_factor[i] != 1:
            scale = scale * m.load_factor[i] / trim_factor[i]
        f, moment = array_wrench(a, scale * m.lift_sym[i], scale * m.drag_sym[i], m.R,
                                 m.arms[i])
        W[0:3, 0] += f
        W[3:6, 0] += moment
    rows = W[1:6, 0]  # F_y, F_z, M_x, M_y, M_z
    d = Differentiator()
    K = -jacobian(rows, q, d)
    K = xreplace(K, {g: gap for g, gap in zip(trim_gap, m.gaps, strict=True)})
    K = xreplace(K, {f: lf for f, lf in zip(trim_factor, m.load_factor, strict=True)})
    mass, grav = m.param("vehicle.mass"), m.param("vehicle.gravity")
    f_prop = m.u[0] * ex
    other = ((m.R * m.vec("vehicle.cg_offset")).cross(sp.Matrix([0, 0, -mass * grav]))
             + (m.R * m.vec("operation.propulsion_point")).cross(f_prop))
    K_other = -jacobian(sp.Matrix.vstack(sp.zeros(2, 1), other), q, d)
    return StiffnessForm(K, K_other, q, m.lift_sym, m.drag_sym)


# The parts of the derived stiffness, by where q enters the wrench (the product rule splits
# -dW/dq exactly): the array's centre gap (eq 3's slope -2k), the rotation of the moment arms
# R (a_i + offset_i), the tilt across the face (the distributed load's factor and point of
# action; zero for the point model), gravity's moment of the CG offset and the propulsion's.
STIFFNESS_PARTS: tuple[str, ...] = ("gap_slope", "rotating_arms", "tilt", "gravity",
                                    "propulsion")


@dataclass(frozen=True)
class StiffnessParts:
    """K_st0 + K_other split by the product rule: one 5x5 matrix per STIFFNESS_PARTS entry, in
    (q, F_L, F_D, F_prop, p); their sum is K + K_other of ``stiffness_form``."""

    parts: dict[str, sp.Matrix]
    q: sp.Matrix
    lift_sym: sp.Matrix
    drag_sym: sp.Matrix
    f_prop: sp.Symbol


@memoized
def stiffness_parts(structure: Structure) -> StiffnessParts:
    """-dW/dq with each occurrence of q in the wrench differentiated on its own (a copy of q
    for the gaps, for the rotation of the arms and for the tilt factors), then the copies set
    back to q: the exact split of ``stiffness_form``'s K and K_other into STIFFNESS_PARTS."""
    m = build_model(structure)
    q = sp.Matrix([m.x[cv.STATE_INDEX[s]] for s in Q_STATES])
    copies = {name: sp.Matrix(sp.symbols(f"{name}_q0:5", real=True))
              for name in ("gap_slope", "rotating_arms", "tilt")}

    def at(expr, name: str):
        return expr.xreplace(dict(zip(q, copies[name], strict=True)))

    trim_gap = sp.Matrix(sp.symbols(f"G0:{len(m.arrays)}", real=True))
    trim_factor = sp.Matrix(sp.symbols(f"LF0:{len(m.arrays)}", real=True))
    R_rot = at(m.R, "rotating_arms")
    ex = sp.Matrix([1, 0, 0])
    W = sp.zeros(5, 1)
    for i, a in enumerate(m.arrays):
        scale = sp.exp(-2 * m.wavenumber * (at(m.gaps[i], "gap_slope") - trim_gap[i]))
        scale = scale * at(m.load_factor[i], "tilt") / trim_factor[i]
        f = scale * m.lift_sym[i] * a.normal - scale * m.drag_sym[i] * ex
        moment = (R_rot * at(m.arms[i], "tilt")).cross(f)
        W += sp.Matrix([f[1], f[2], *moment])
    back = {c: v for cs in copies.values() for c, v in zip(cs, q, strict=True)}
    back.update(dict(zip(trim_gap, m.gaps, strict=True)))
    back.update(dict(zip(trim_factor, m.load_factor, strict=True)))
    d = Differentiator()
    parts = {name: xreplace(-jacobian(W, cs, d), back) for name, cs in copies.items()}
    mass, grav = m.param("vehicle.mass"), m.param("vehicle.gravity")
    f_prop = sp.Symbol("F_prop", real=True)
    gravity = (m.R * m.vec("vehicle.cg_offset")).cross(sp.Matrix([0, 0, -mass * grav]))
    propulsion = (m.R * m.vec("operation.propulsion_point")).cross(f_prop * ex)
    parts["gravity"] = -jacobian(sp.Matrix.vstack(sp.zeros(2, 1), gravity), q, d)
    parts["propulsion"] = -jacobian(sp.Matrix.vstack(sp.zeros(2, 1), propulsion), q, d)
    return StiffnessParts({n: parts[n] for n in STIFFNESS_PARTS}, q, m.lift_sym, m.drag_sym,
                          f_prop)


@memoized
def design_pose_stiffness(structure: Structure) -> sp.Matrix:
    """K_st0 at zero attitude: the closed form to set beside the paper's eqs 13-19."""
    sf = stiffness_form(structure)
    zero = {s: 0 for s in sf.q}
    return sf.K.xreplace(zero)


def generalized_mass_expr(model: CarriageModel) -> sp.Matrix:
    """Diagonal of M_RB (eq 17) at O: (m, m, I_O,xx, I_O,yy, I_O,zz), symbolic."""
    m = model.param("vehicle.mass")
    inertia = inertia_cg_matrix(model.param, model.structure.param_names)
    I_O = inertia_about_origin(m, inertia, model.vec("vehicle.cg_offset"))
    return sp.Matrix([m, m, I_O[0, 0], I_O[1, 1], I_O[2, 2]])
