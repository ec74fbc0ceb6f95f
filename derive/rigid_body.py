"""Rigid-body equations of the carriage (eqs 1-2) and Z-Y-X Euler kinematics.

The paper's eqs 1-2 are written at the body origin O with the CG at r_G:

    f_O = m (v_dot + w x v + w_dot x r_G + w x (w x r_G))                    (1)
    m_O = I_O w_dot + w x (I_O w) + m r_G x (v_dot + w x v)                   (2)

with v_dot the rate of change of the body-axis components of v (the paper's (dv/dt)_rel). They
are linear in (v_dot, w_dot); eliminating v_dot gives I_G w_dot = b - r_G x a, where
a = f_O - m (w x v + w x (w x r_G)) and b = m_O - w x (I_O w) - m r_G x (w x v), because
I_O + m [r_G]x [r_G]x = I_G (parallel axis theorem). So only the 3x3 inertia about the CG is
inverted, and it is positive definite for any physical body.
"""

from __future__ import annotations

import sympy as sp

__all__ = ["body_accelerations", "euler_rates", "inertia_about_origin", "rotation_body_to_inertial",
           "skew"]


def skew(r: sp.Matrix) -> sp.Matrix:
    """[r]x, the matrix with [r]x s = r x s."""
    return sp.Matrix([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])


def inertia_about_origin(mass: sp.Expr, inertia_cg: sp.Matrix, r_G: sp.Matrix) -> sp.Matrix:
    """Parallel axis theorem: I_O = I_G + m (|r_G|^2 1 - r_G r_G^T)."""
    return inertia_cg + mass * ((r_G.T * r_G)[0] * sp.eye(3) - r_G * r_G.T)


def body_accelerations(mass: sp.Expr, inertia_cg: sp.Matrix, r_G: sp.Matrix, v: sp.Matrix,
                       omega: sp.Matrix, force: sp.Matrix, moment_O: sp.Matrix
                       ) -> tuple[sp.Matrix, sp.Matrix]:
    """Eqs 1-2 solved for (v_dot, w_dot): body-axis accelerations of O and of the attitude.

    ``force`` is the total external force and ``moment_O`` its moment about O, body axes.
    """
    I_O = inertia_about_origin(mass, inertia_cg, r_G)
    a = force - mass * (omega.cross(v) + omega.cross(omega.cross(r_G)))
    b = moment_O - omega.cross(I_O * omega) - mass * r_G.cross(omega.cross(v))
    omega_dot = _solve_sym3(inertia_cg, b - r_G.cross(a))
    v_dot = a / mass - omega_dot.cross(r_G)
    return v_dot, omega_dot


def _solve_sym3(M: sp.Matrix, rhs: sp.Matrix) -> sp.Matrix:
    """M^-1 rhs for a symmetric 3x3 M by its adjugate (no pivoting: M is positive definite)."""
    return M.adjugate() * rhs / M.det(method="berkowitz")


def rotation_body_to_inertial(phi: sp.Expr, theta: sp.Expr, psi: sp.Expr) -> sp.Matrix:
    """R = Rz(psi) Ry(theta) Rx(phi): body components to inertial components (Z-Y-X Euler)."""
    cf, sf = sp.cos(phi), sp.sin(phi)
    ct, st = sp.cos(theta), sp.sin(theta)
    cp, s_p = sp.cos(psi), sp.sin(psi)
    Rx = sp.Matrix([[1, 0, 0], [0, cf, -sf], [0, sf, cf]])
    Ry = sp.Matrix([[ct, 0, st], [0, 1, 0], [-st, 0, ct]])
    Rz = sp.Matrix([[cp, -s_p, 0], [s_p, cp, 0], [0, 0, 1]])
    return Rz * Ry * Rx


def euler_rates(phi: sp.Expr, theta: sp.Expr, omega: sp.Matrix) -> sp.Matrix:
    """Z-Y-X Euler angle rates from body rates (p, q, r); singular at theta = +-90 deg.

    tan(theta) is written sin(theta)/cos(theta): the model needs both anyway, and generated
    code then calls no tan (one library call fewer per evaluation)."""
    p, q, r = omega
    s = (q * sp.sin(phi) + r * sp.cos(phi)) / sp.cos(theta)
    return sp.Matrix([p + s * sp.sin(theta), q * sp.cos(phi) - r * sp.sin(phi), s])
