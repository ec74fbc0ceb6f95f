"""Checks of derive/rigid_body.py (eqs 1-2 and Z-Y-X Euler kinematics) against independent
references: sympy.physics.mechanics (Kane's method), direct differentiation of R, point-mass
inertia sums, and conservation laws / the intermediate-axis instability of torque-free motion.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
import sympy as sp
import sympy.physics.mechanics as me
from scipy.integrate import solve_ivp

from maglevgen.derive.rigid_body import (
    body_accelerations,
    euler_rates,
    inertia_about_origin,
    rotation_body_to_inertial,
    skew,
)

N_SAMPLES = 25
REL_TOL = 1e-10


def _skew_np(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _random_inertia(rng: np.random.Generator) -> np.ndarray:
    """A physical (triangle-inequality) inertia about the CG in randomly rotated body axes."""
    a, b = rng.uniform(1.0, 5.0, 2)
    c = rng.uniform(abs(a - b) + 0.2, a + b - 0.2)
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    J = Q @ np.diag([a, b, c]) @ Q.T
    assert abs(J[0, 1]) > 1e-3 and abs(J[1, 2]) > 1e-3 and abs(J[0, 2]) > 1e-3
    return 0.5 * (J + J.T)


# ----------------------------------------------------------------------------------------
# Symbols shared by the symbolic reference and the function under test
# ----------------------------------------------------------------------------------------
_m, _g = sp.symbols("m g", positive=True)
_Ixx, _Iyy, _Izz, _Ixy, _Iyz, _Ixz = sp.symbols("I_xx I_yy I_zz I_xy I_yz I_xz")
_IG = sp.Matrix([[_Ixx, _Ixy, _Ixz], [_Ixy, _Iyy, _Iyz], [_Ixz, _Iyz, _Izz]])
_rG = sp.Matrix(sp.symbols("rG1:4"))
_F = sp.Matrix(sp.symbols("F1:4"))
_T = sp.Matrix(sp.symbols("T1:4"))
_PARAMS = [_m, _g, _Ixx, _Iyy, _Izz, _Ixy, _Iyz, _Ixz, *_rG, *_F, *_T]


def _param_values(rng: np.random.Generator) -> list[float]:
    J = _random_inertia(rng)
    return [rng.uniform(0.5, 20.0), 9.81, J[0, 0], J[1, 1], J[2, 2], J[0, 1], J[1, 2],
            J[0, 2], *rng.uniform(-1.0, 1.0, 3), *rng.uniform(-10.0, 10.0, 3),
            *rng.uniform(-10.0, 10.0, 3)]


@functools.lru_cache(maxsize=1)
def _kane_reference():
    """Kane's equations for a free rigid body; q = (x, y, z, phi, theta, psi) of O,
    u = body-axis velocity of O and body rates. Returns lambdified (M, f, qdot) and symbols."""
    x, y, z, phi, theta, psi = me.dynamicsymbols("x y z phi theta psi")
    u1, u2, u3, u4, u5, u6 = me.dynamicsymbols("u1:7")
    q = [x, y, z, phi, theta, psi]
    u = [u1, u2, u3, u4, u5, u6]

    N = me.ReferenceFrame("N")
    A = N.orientnew("A", "Axis", (psi, N.z))      # yaw about inertial z
    C = A.orientnew("C", "Axis", (theta, A.y))    # pitch about the once-rotated y
    B = C.orientnew("B", "Axis", (phi, C.x))      # roll about the body x
    No = me.Point("No")
    No.set_vel(N, 0)
    Opt = No.locatenew("O", x * N.x + y * N.y + z * N.z)

    kd = [Opt.pos_from(No).dt(N).dot(B.x) - u1,
          Opt.pos_from(No).dt(N).dot(B.y) - u2,
          Opt.pos_from(No).dt(N).dot(B.z) - u3,
          B.ang_vel_in(N).dot(B.x) - u4,
          B.ang_vel_in(N).dot(B.y) - u5,
          B.ang_vel_in(N).dot(B.z) - u6]
    Opt.set_vel(N, u1 * B.x + u2 * B.y + u3 * B.z)
    B.set_ang_vel(N, u4 * B.x + u5 * B.y + u6 * B.z)

    G = Opt.locatenew("G", _rG[0] * B.x + _rG[1] * B.y + _rG[2] * B.z)
    G.v2pt_theory(Opt, N, B)
    bx = [B.x, B.y, B.z]
    inertia_dyadic = sum((_IG[i, j] * (bx[i] | bx[j]) for i in range(3) for j in range(3)),
                         start=me.Dyadic(0))
    body = me.RigidBody("body", G, B, _m, (inertia_dyadic, G))

    loads = [(Opt, _F[0] * B.x + _F[1] * B.y + _F[2] * B.z),   # general force at O
             (G, -_m * _g * N.z),                              # gravity at the CG
             (B, _T[0] * B.x + _T[1] * B.y + _T[2] * B.z)]     # torque (free vector)
    kane = me.KanesMethod(N, q_ind=q, u_ind=u, kd_eqs=kd)
    kane.kanes_equations([body], loads)

    qs = sp.symbols("x y z phi theta psi")
    us = sp.symbols("u1:7")
    sub = dict(zip(q + u, qs + us, strict=True))
    M = me.msubs(kane.mass_matrix, sub)
    f = me.msubs(kane.forcing, sub)
    kdd = kane.kindiffdict()
    qdot = me.msubs(sp.Matrix([kdd[qi.diff()] for qi in q]), sub)
    args = [*qs, *us, *_PARAMS]
    return (sp.lambdify(args, M, "numpy"), sp.lambdify(args, f, "numpy"),
            sp.lambdify(args, qdot, "numpy"), me.msubs(N.dcm(B), sub), qs)


@functools.lru_cache(maxsize=1)
def _module_accelerations():
    """body_accelerations with the same loads as the Kane model (gravity moved to O)."""
    qs = sp.symbols("x y z phi theta psi")
    us = sp.symbols("u1:7")
    phi, theta, psi = qs[3:]
    R = rotation_body_to_inertial(phi, theta, psi)
    grav_body = R.T * sp.Matrix([0, 0, -_m * _g])
    force = _F + grav_body
    moment_O = _T + _rG.cross(grav_body)
    v_dot, w_dot = body_accelerations(_m, _IG, _rG, sp.Matrix(us[:3]), sp.Matrix(us[3:]),
                                      force, moment_O)
    pos_dot = R * sp.Matrix(us[:3])
    ang_dot = euler_rates(phi, theta, sp.Matrix(us[3:]))
    args = [*qs, *us, *_PARAMS]
    return (sp.lambdify(args, sp.Matrix.vstack(v_dot, w_dot), "numpy"),
            sp.lambdify(args, sp.Matrix.vstack(pos_dot, ang_dot), "numpy"))


def _random_state(rng: np.random.Generator) -> list[float]:
    q = [*rng.uniform(-5, 5, 3), rng.uniform(-np.pi, np.pi), rng.uniform(-1.3, 1.3),
         rng.uniform(-np.pi, np.pi)]
    u = [*rng.uniform(-20, 20, 3), *rng.uniform(-3, 3, 3)]
    return q + u


def test_body_accelerations_match_kanes_method():
    M_fn, f_fn, _, _, _ = _kane_reference()
    acc_fn, _ = _module_accelerations()
    rng = np.random.default_rng(20240611)
    worst = 0.0
    for _ in range(N_SAMPLES):
        args = _random_state(rng) + _param_values(rng)
        ref = np.linalg.solve(np.asarray(M_fn(*args), float), np.asarray(f_fn(*args), float))
        got = np.asarray(acc_fn(*args), float)
        err = np.max(np.abs(got - ref)) / np.max(np.abs(ref))
        worst = max(worst, err)
    assert worst < REL_TOL, f"max relative error vs Kane: {worst:.3e}"


def test_kinematics_match_kanes_method():
    """R of the module equals sympy's Z-Y-X chain; Euler rates and position rates match."""
    _, _, qdot_fn, dcm_NB, qs = _kane_reference()
    _, kin_fn = _module_accelerations()
    R_mod = rotation_body_to_inertial(*qs[3:])
    R_diff = sp.lambdify(qs[3:], R_mod - dcm_NB, "numpy")
    rng = np.random.default_rng(7)
    worst_R = worst_kin = 0.0
    for _ in range(N_SAMPLES):
        args = _random_state(rng) + _param_values(rng)
        worst_R = max(worst_R, np.max(np.abs(np.asarray(R_diff(*args[3:6]), float))))
        ref = np.asarray(qdot_fn(*args), float).ravel()
        got = np.asarray(kin_fn(*args), float).ravel()
        worst_kin = max(worst_kin, np.max(np.abs(got - ref)) / np.max(np.abs(ref)))
    assert worst_R < 1e-14
    assert worst_kin < REL_TOL


def test_rotation_convention_elementary():
    """Yaw alone turns body x toward inertial +y; pitch alone turns body x toward -z
    (nose down for positive theta about y); roll alone turns body y toward +z."""
    a = sp.Rational(1, 3)
    R = rotation_body_to_inertial(0, 0, a)
    assert sp.simplify(R[:, 0] - sp.Matrix([sp.cos(a), sp.sin(a), 0])) == sp.zeros(3, 1)
    R = rotation_body_to_inertial(0, a, 0)
    assert sp.simplify(R[:, 0] - sp.Matrix([sp.cos(a), 0, -sp.sin(a)])) == sp.zeros(3, 1)
    R = rotation_body_to_inertial(a, 0, 0)
    assert sp.simplify(R[:, 1] - sp.Matrix([0, sp.cos(a), sp.sin(a)])) == sp.zeros(3, 1)


def test_euler_rates_reproduce_rotation_derivative():
    """d/dt R(phi, theta, psi) along euler_rates equals R [omega]x (body rates)."""
    phi, theta, psi = sp.symbols("phi theta psi")
    w = sp.Matrix(sp.symbols("p q r"))
    R = rotation_body_to_inertial(phi, theta, psi)
    rates = euler_rates(phi, theta, w)
    R_dot = sum((R.diff(a) * rates[i] for i, a in enumerate((phi, theta, psi))),
                start=sp.zeros(3, 3))
    fn = sp.lambdify([phi, theta, psi, *w], (R_dot, R * skew(w), R.T * R, R.det()), "numpy")
    rng = np.random.default_rng(3)
    worst = 0.0
    for _ in range(N_SAMPLES):
        ang = [rng.uniform(-np.pi, np.pi), rng.uniform(-1.5, 1.5), rng.uniform(-np.pi, np.pi)]
        lhs, rhs, RtR, det = (np.asarray(t, float) for t in fn(*ang, *rng.uniform(-5, 5, 3)))
        worst = max(worst, np.max(np.abs(lhs - rhs)) / np.max(np.abs(rhs)))
        np.testing.assert_allclose(RtR, np.eye(3), atol=1e-14)
        assert abs(det - 1.0) < 1e-14
    assert worst < REL_TOL


def test_skew_is_cross_product():
    a = sp.Matrix(sp.symbols("a1:4"))
    b = sp.Matrix(sp.symbols("b1:4"))
    assert sp.expand(skew(a) * b - a.cross(b)) == sp.zeros(3, 1)


def test_inertia_about_origin_matches_point_mass_sums():
    """Parallel axis theorem against a direct sum over a cloud of point masses."""
    rng = np.random.default_rng(11)
    pts = rng.normal(size=(40, 3)) + np.array([0.3, -0.7, 0.5])
    ms = rng.uniform(0.1, 2.0, 40)

    def inertia(points):
        return sum(mi * (pi @ pi * np.eye(3) - np.outer(pi, pi))
                   for mi, pi in zip(ms, points, strict=True))

    m = ms.sum()
    r_G = (ms[:, None] * pts).sum(axis=0) / m
    I_G = inertia(pts - r_G)
    I_O = inertia(pts)
    got = np.array(inertia_about_origin(sp.Float(m), sp.Matrix(I_G), sp.Matrix(r_G)), float)
    np.testing.assert_allclose(got, I_O, rtol=1e-12, atol=1e-12)


# ----------------------------------------------------------------------------------------
# Torque-free motion
# ----------------------------------------------------------------------------------------
def _numeric_accelerations(m: float, I_G: np.ndarray, r_G: np.ndarray):
    """Force- and moment-free (v_dot, w_dot) of body_accelerations as a numpy function."""
    vs = sp.Matrix(sp.symbols("v1:4"))
    ws = sp.Matrix(sp.symbols("w1:4"))
    v_dot, w_dot = body_accelerations(sp.Float(m), sp.Matrix(I_G), sp.Matrix(r_G), vs, ws,
                                      sp.zeros(3, 1), sp.zeros(3, 1))
    fn = sp.lambdify([*vs, *ws], sp.Matrix.vstack(v_dot, w_dot), "numpy")
    return lambda v, w: np.asarray(fn(*v, *w), float).ravel()


def _integrate_rotation_matrix(acc, v0, w0, t_end, t_eval=None):
    """State: inertial position of O (3), R row-major (9), v (3), omega (3)."""

    def rhs(_t, s):
        R = s[3:12].reshape(3, 3)
        v, w = s[12:15], s[15:18]
        return np.concatenate([R @ v, (R @ _skew_np(w)).ravel(), acc(v, w)])

    s0 = np.concatenate([np.zeros(3), np.eye(3).ravel(), v0, w0])
    sol = solve_ivp(rhs, (0.0, t_end), s0, method="DOP853", rtol=1e-12, atol=1e-12,
                    t_eval=t_eval)
    assert sol.success
    return sol


def test_torque_free_conservation():
    rng = np.random.default_rng(5)
    m = 3.7
    I_G = _random_inertia(rng)
    r_G = np.array([0.4, -0.25, 0.6])
    v0 = np.array([1.2, -0.8, 0.5])
    w0 = np.array([0.9, -1.6, 1.1])
    acc = _numeric_accelerations(m, I_G, r_G)
    t = np.linspace(0.0, 10.0, 401)
    sol = _integrate_rotation_matrix(acc, v0, w0, 10.0, t_eval=t)

    ke, L, P, pG = [], [], [], []
    for s in sol.y.T:
        R = s[3:12].reshape(3, 3)
        v, w = s[12:15], s[15:18]
        vG_body = v + np.cross(w, r_G)
        ke.append(0.5 * m * vG_body @ vG_body + 0.5 * w @ I_G @ w)
        L.append(R @ I_G @ w)                    # inertial angular momentum about the CG
        P.append(m * R @ vG_body)                # inertial linear momentum
        pG.append(s[0:3] + R @ r_G)              # inertial CG position
    ke, L, P, pG = map(np.array, (ke, L, P, pG))

    err_ke = np.max(np.abs(ke - ke[0])) / abs(ke[0])
    err_L = np.max(np.linalg.norm(L - L[0], axis=1)) / np.linalg.norm(L[0])
    err_P = np.max(np.linalg.norm(P - P[0], axis=1)) / np.linalg.norm(P[0])
    # the CG moves on a straight line at constant speed
    pG_ref = pG[0] + np.outer(t, P[0] / m)
    err_pG = np.max(np.linalg.norm(pG - pG_ref, axis=1)) / np.max(np.linalg.norm(pG_ref, axis=1))
    # the body really tumbles (not a trivial steady spin)
    w_hist = sol.y[15:18].T
    assert np.ptp(w_hist, axis=0).max() > 0.1
    # R stays orthonormal (integration sanity)
    R_end = sol.y[3:12, -1].reshape(3, 3)
    np.testing.assert_allclose(R_end.T @ R_end, np.eye(3), atol=1e-9)
    assert err_ke < 1e-9, err_ke
    assert err_L < 1e-9, err_L
    assert err_P < 1e-9, err_P
    assert err_pG < 1e-9, err_pG


def test_euler_angle_state_agrees_with_rotation_matrix_state():
    """The 12-state Euler-angle model (no gimbal lock over the run) tracks the R-matrix one."""
    m = 2.0
    I_G = np.array([[1.0, 0.1, -0.05], [0.1, 1.5, 0.08], [-0.05, 0.08, 2.2]])
    r_G = np.array([0.2, 0.1, -0.3])
    v0 = np.array([0.5, 0.2, -0.1])
    w0 = np.array([0.3, 0.2, 0.6])
    acc = _numeric_accelerations(m, I_G, r_G)
    ph, th, ps = sp.symbols("phi theta psi")
    ws = sp.Matrix(sp.symbols("w1:4"))
    vs = sp.Matrix(sp.symbols("v1:4"))
    R_sym = rotation_body_to_inertial(ph, th, ps)
    kin = sp.lambdify([ph, th, ps, *vs, *ws],
                      sp.Matrix.vstack(R_sym * vs, euler_rates(ph, th, ws)), "numpy")
    R_fn = sp.lambdify([ph, th, ps], R_sym, "numpy")

    def rhs(_t, s):
        return np.concatenate([np.asarray(kin(*s[3:12]), float).ravel(), acc(s[6:9], s[9:12])])

    t_end = 4.0
    sol_e = solve_ivp(rhs, (0.0, t_end), np.concatenate([np.zeros(6), v0, w0]),
                      method="DOP853", rtol=1e-12, atol=1e-12)
    sol_r = _integrate_rotation_matrix(acc, v0, w0, t_end)
    se, sr = sol_e.y[:, -1], sol_r.y[:, -1]
    assert np.max(np.abs(sol_e.y[4])) < 1.2          # stayed clear of theta = +-90 deg
    np.testing.assert_allclose(se[0:3], sr[0:3], atol=1e-9)
    np.testing.assert_allclose(np.asarray(R_fn(*se[3:6]), float), sr[3:12].reshape(3, 3),
                               atol=1e-9)
    np.testing.assert_allclose(se[6:12], sr[12:18], atol=1e-9)


@pytest.mark.parametrize(("axis", "flips"), [(1, True), (0, False), (2, False)])
def test_intermediate_axis_flip(axis, flips):
    """Spin about the intermediate principal axis (y, I = 2) flips; about x (smallest) or
    z (largest) it stays stable. CG offset is non-zero (translation couples in eq 1-2)."""
    m = 1.5
    I_G = np.diag([1.0, 2.0, 3.0])
    r_G = np.array([0.3, -0.2, 0.1])
    w0 = np.full(3, 1e-3)
    w0[axis] = 5.0
    acc = _numeric_accelerations(m, I_G, r_G)
    t = np.linspace(0.0, 10.0, 2001)
    sol = _integrate_rotation_matrix(acc, np.array([0.1, 0.0, 0.0]), w0, 10.0, t_eval=t)
    w_axis = sol.y[15 + axis]
    if flips:
        assert w_axis.min() < -4.0, "no flip of the intermediate-axis spin"
    else:
        assert w_axis.min() > 4.9, "spin about a major/minor axis should stay put"
