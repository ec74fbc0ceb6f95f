"""Reference computations written for the tests, from the paper's equations and the geometry.

Nothing here imports the derivation (maglevgen.derive) or the code generator: the force law is
eq 3 as printed (with 1/(1 + (R/(omega L))^2) and the drag ratio R/(omega L) of ref [5]) at the
face centre for ``model.array_force = "point"``, and for "distributed" the same circuit law summed
circuit by circuit along the array with each circuit's flux and force integrated across the
width at the local gaps by Gauss-Legendre quadrature (no closed form), acting where they act; the
rigid body is the static balance of eqs 1-2 (no motion but the steady speed: force and moment
about O both zero; accelerating along the track, with the d'Alembert load -m a at the CG), the
stiffness is a central difference, and the LQR gains come from the
Riccati equation of eq 30 solved by hand in mpmath at 60 digits. The tests compare every derived
number the toolchain prints or generates with these.
"""

from __future__ import annotations

from dataclasses import dataclass

import control
import mpmath
import numpy as np
import scipy.linalg
import scipy.optimize

from maglevgen.params import Parameters


def rotation(phi: float, theta: float, psi: float) -> np.ndarray:
    """Z-Y-X Euler rotation, body to inertial."""
    c, s = np.cos, np.sin
    Rz = np.array([[c(psi), -s(psi), 0], [s(psi), c(psi), 0], [0, 0, 1]])
    Ry = np.array([[c(theta), 0, s(theta)], [0, 1, 0], [-s(theta), 0, c(theta)]])
    Rx = np.array([[1, 0, 0], [0, c(phi), -s(phi)], [0, s(phi), c(phi)]])
    return Rz @ Ry @ Rx


@dataclass(frozen=True)
class ArrayState:
    """Gap, lift and drag of every array at a pose, and where they act (body axes)."""

    gaps: np.ndarray
    lift: np.ndarray
    drag: np.ndarray
    arms: np.ndarray  # point of action of each array's force, body axes (n_arrays x 3)


_GL_S, _GL_W = np.polynomial.legendre.leggauss(24)  # exact for the smooth exp across a width


def _face_axes(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(across, along): the face's unit vectors, along = body x projected onto the face."""
    along = np.array([1.0, 0.0, 0.0]) - n[0] * n
    along /= np.linalg.norm(along)
    return np.cross(n, along), along


def array_state(prm: Parameters, q: np.ndarray, speed: float) -> ArrayState:
    """Each array's gap (plane of the track through its design-pose face) and its forces.

    "point": eq 3 with N circuits at the face-centre gap, at the face centre. "distributed":
    circuit j (of N, pitch p, centred on the face) links the flux of the field across its width
    at the local gaps, Phi_j = int exp(-k g(s, t_j)) ds, and carries the force Phi_j times the
    field along it, so eq 3's (w exp(-k g))^2 becomes Phi_j^2, acting at the field-weighted
    point of the circuit; the array's force is the sum over its circuits."""
    h, c = prm.halbach, prm.circuit
    k = 2 * np.pi / h.wavelength
    M = h.magnets_per_wavelength
    B0 = h.remanence * (1 - np.exp(-k * h.thickness)) * np.sin(np.pi / M) / (np.pi / M)  # eq 4
    omega = k * speed
    per_flux2 = B0**2 / (2 * k * c.inductance) / (1 + (c.resistance / (omega * c.inductance)) ** 2)
    R = rotation(*q[2:5])
    X = np.array([0.0, q[0], q[1]])
    distributed = prm.model.array_force == "distributed"
    gaps, lift, arms = [], [], []
    for arr in prm.arrays.values():
        a, n = np.array(arr.position), np.array(arr.normal)
        gap = arr.nominal_gap + n @ (X + (R - np.eye(3)) @ a)
        gaps.append(gap)
        if not distributed:
            lift.append(arr.circuits * per_flux2 * h.width**2 * np.exp(-2 * k * gap))
            arms.append(a)
            continue
        across, along = _face_axes(n)
        n_c = round(arr.circuits)
        total, moment = 0.0, np.zeros(3)
        for j in range(n_c):
            t = (j - (n_c - 1) / 2) * c.pitch
            s = _GL_S * h.width / 2
            points = a + np.outer(s, across) + t * along  # body points across the circuit
            # each point's own gap to the track plane (n . b = n . a on the face)
            density = np.exp(-k * (arr.nominal_gap + (X + points @ R.T - points) @ n))
            flux = (h.width / 2) * _GL_W @ density
            f = flux * (h.width / 2) * (_GL_W * density)  # force per quadrature node
            total += f.sum()
            moment += f @ points
        lift.append(per_flux2 * total)
        arms.append(moment / total)
    lift_a = np.array(lift)
    return ArrayState(np.array(gaps), lift_a, lift_a * c.resistance / (omega * c.inductance),
                      np.array(arms))


def contact_gaps(prm: Parameters, q: np.ndarray) -> np.ndarray:
    """Each face's smallest gap: the least of its four corners' (face centre +- w/2 across,
    +- circuits x pitch / 2 along), each corner's gap from the pose like the centre's."""
    R = rotation(*q[2:5])
    X = np.array([0.0, q[0], q[1]])
    half_w, out = prm.halbach.width / 2, []
    for arr in prm.arrays.values():
        a, n = np.array(arr.position), np.array(arr.normal)
        across, along = _face_axes(n)
        half_l = arr.circuits * prm.circuit.pitch / 2
        corners = [a + i * half_w * across + j * half_l * along for i in (-1, 1) for j in (-1, 1)]
        out.append(min(arr.nominal_gap + n @ (X + (R - np.eye(3)) @ b) for b in corners))
    return np.array(out)


def external_wrench(prm: Parameters, q: np.ndarray, speed: float, f_prop: float,
                    magnetic: bool = True, other: bool = True) -> np.ndarray:
    """(F_x, F_y, F_z, M_x, M_y, M_z), inertial axes, moments about O, of the external forces.

    Lift along each array's normal, drag along -x at its point of action; gravity -m g z at the
    CG; propulsion +x at the propulsion point. ``magnetic`` / ``other`` select the parts.
    """
    R = rotation(*q[2:5])
    total = np.zeros(6)
    if magnetic:
        st = array_state(prm, q, speed)
        for arr, fl, fd, arm in zip(prm.arrays.values(), st.lift, st.drag, st.arms,
                                    strict=True):
            f = fl * np.array(arr.normal) - fd * np.array([1.0, 0.0, 0.0])
            total += np.concatenate([f, np.cross(R @ arm, f)])
    if other:
        v = prm.vehicle
        f_g = np.array([0.0, 0.0, -v.mass * v.gravity])
        f_p = np.array([f_prop, 0.0, 0.0])
        total += np.concatenate([f_g, np.cross(R @ np.array(v.cg_offset), f_g)])
        total += np.concatenate([f_p, np.cross(R @ np.array(prm.operation.propulsion_point),
                                               f_p)])
    return total


@dataclass(frozen=True)
class ReferenceTrim:
    """The equilibrium found here: pose q = (y, z, phi, theta, psi), propulsion, array forces."""

    q: np.ndarray
    f_prop: float
    arrays: ArrayState


def dalembert_wrench(prm: Parameters, q: np.ndarray, acceleration: float) -> np.ndarray:
    """(F_x, F_y, F_z, M_x, M_y, M_z), inertial axes, moments about O, of the d'Alembert
    load of a carriage translating at ``acceleration`` along the track: -m a e_x at the CG."""
    v = prm.vehicle
    f = np.array([-v.mass * acceleration, 0.0, 0.0])
    return np.concatenate([f, np.cross(rotation(*q[2:5]) @ np.array(v.cg_offset), f)])


def reference_trim(prm: Parameters, speed: float, acceleration: float = 0.0) -> ReferenceTrim:
    """Root of the six static balances (eqs 1-2 at rest in the moving frame) with eq 3; with
    ``acceleration`` a != 0 the frame accelerates at a along the track and the balances hold
    the d'Alembert load -m a e_x at the CG as well (`dalembert_wrench`).

    Starts from the design pose with the propulsion equal to the drag there (plus m a);
    MINPACK's hybrid Powell method, the scaled residual (N and N m) below 1e-9 of the weight.
    """
    weight = prm.vehicle.mass * prm.vehicle.gravity

    def residual(unknowns: np.ndarray) -> np.ndarray:
        return (external_wrench(prm, unknowns[:5], speed, unknowns[5])
                + dalembert_wrench(prm, unknowns[:5], acceleration)) / weight

    start = np.zeros(6)
    start[5] = array_state(prm, np.zeros(5), speed).drag.sum() + prm.vehicle.mass * acceleration
    sol = scipy.optimize.root(residual, start, method="hybr", tol=1e-15)
    assert np.max(np.abs(residual(sol.x))) < 1e-11, sol.message
    return ReferenceTrim(sol.x[:5], float(sol.x[5]), array_state(prm, sol.x[:5], speed))


def stiffness_fd(prm: Parameters, q0: np.ndarray, speed: float, f_prop: float,
                 magnetic: bool = True, other: bool = True, h: float = 1e-6) -> np.ndarray:
    """K = -d(F_y, F_z, M_x, M_y, M_z)/dq by central differences (speed and F_prop held)."""
    K = np.zeros((5, 5))
    for j in range(5):
        e = np.zeros(5)
        e[j] = h
        plus = external_wrench(prm, q0 + e, speed, f_prop, magnetic, other)
        minus = external_wrench(prm, q0 - e, speed, f_prop, magnetic, other)
        K[:, j] = -(plus - minus)[1:] / (2 * h)
    return K


def generalized_mass(prm: Parameters) -> np.ndarray:
    """(m, m, I_O,xx, I_O,yy, I_O,zz): parallel-axis theorem about O from the CG inertia."""
    v, i = prm.vehicle, prm.vehicle.inertia_cg
    I_G = np.array([[i.xx, i.xy, i.xz], [i.xy, i.yy, i.yz], [i.xz, i.yz, i.zz]])
    r = np.array(v.cg_offset)
    I_O = I_G + v.mass * (r @ r * np.eye(3) - np.outer(r, r))
    return np.array([v.mass, v.mass, *np.diag(I_O)])


def lqr_reference_mp(k: float, m: float, q1: float = 1.0, q2: float = 1.0, r: float = 1.0,
                     dps: int = 60) -> tuple[list[mpmath.mpf], mpmath.matrix]:
    """(K, P) of the axis LQR (eqs 27-30) at ``dps`` digits, solved here by hand.

    With A = [[0, 1], [-k/m, 0]], B = [0, 1/m], K = (p12, p22)/(m r): the (1,1) entry of eq 30
    is K1^2 + 2 k K1 - q1/r = 0, whose root with k + K1 > 0 stabilizes; the (2,2) entry gives
    K2^2 = 2 m K1 + q2/r; the (1,2) entry gives p11 = p22 (k + K1)/m. The ARE residual of the
    result is asserted to vanish at the working precision.
    """
    with mpmath.workdps(dps):
        k, m, q1, q2, r = (mpmath.mpf(v) for v in (k, m, q1, q2, r))
        K1 = mpmath.sqrt(k**2 + q1 / r) - k
        K2 = mpmath.sqrt(2 * m * K1 + q2 / r)
        p12, p22 = m * r * K1, m * r * K2
        P = mpmath.matrix([[p22 * (k + K1) / m, p12], [p12, p22]])
        A = mpmath.matrix([[0, 1], [-k / m, 0]])
        B = mpmath.matrix([[0], [1 / m]])
        res = A.T * P + P * A - P * B * B.T * P / r + mpmath.diag([q1, q2])
        scale = mpmath.mnorm(P, "inf") * (1 + abs(k) / m) + q1 + q2
        assert mpmath.mnorm(res, "inf") <= scale * mpmath.mpf(10) ** (10 - dps)
        assert k + K1 > 0 and K2 > 0  # Hurwitz: s^2 + (K2/m) s + (k + K1)/m
        return [K1, K2], P


def ise_optimal_damping(k: float, m: float) -> float:
    """c minimizing integral x^2 dt of m x'' + c x' + k x = 0 from (1, 0) (eqs 20-21), found
    numerically: the cost from a Lyapunov solve, minimized by bounded Brent."""
    def cost(c: float) -> float:
        A = np.array([[0.0, 1.0], [-k / m, -c / m]])
        return float(scipy.linalg.solve_continuous_lyapunov(A.T, -np.diag([1.0, 0.0]))[0, 0])

    c0 = np.sqrt(k * m)
    res = scipy.optimize.minimize_scalar(cost, bounds=(1e-3 * c0, 1e3 * c0), method="bounded",
                                         options={"xatol": 1e-10 * c0})
    return float(res.x)


def zero_attitude_lift_off_bound(prm: Parameters) -> float:
    """The speed at which the arrays' net vertical force balances the weight at zero attitude
    with the heave at its lowest (each gap linear in z there; the first to reach
    track.min_gap): a lower bound of the lift-off speed, the balance of the speed alone."""
    g0 = array_state(prm, np.zeros(5), 1.0).gaps
    slope = (array_state(prm, np.array([0, 1e-3, 0, 0, 0]), 1.0).gaps - g0) / 1e-3
    z_lo = ((prm.track.min_gap - g0) / slope)[slope > 0].max()
    q = np.array([0.0, z_lo, 0.0, 0.0, 0.0])
    return float(scipy.optimize.brentq(lambda v: external_wrench(prm, q, v, 0.0)[2], 1e-3, 1e3,
                                       xtol=1e-14, rtol=1e-14))


def symmetric_lift_off_speed(prm: Parameters, v_start: float) -> float:
    """The lowest speed whose equilibrium keeps every face's closest corner at track.min_gap,
    for a carriage symmetric about its x-z plane (y = roll = yaw = 0 at the equilibrium).

    The equilibrium: root of the x, z and pitch balances in (z, theta, F_prop), continued down
    in speed from ``v_start`` (which must lift off) by steps of 10 % until the smallest corner
    gap falls below min_gap, each solve starting from the last; then Brent's method on the
    smallest corner gap in that last step. All six balances are asserted at every root.
    """
    weight = prm.vehicle.mass * prm.vehicle.gravity
    pose = lambda u: np.array([0.0, u[0], 0.0, u[1], 0.0])  # noqa: E731
    solved = {}

    def clearance(v: float) -> float:
        if solved:
            start = solved[min(solved, key=lambda s: abs(s - v))]
        else:  # design pose, propulsion equal to the drag there
            start = np.array([0.0, 0.0, array_state(prm, np.zeros(5), v).drag.sum()])
        sol = scipy.optimize.root(
            lambda u: external_wrench(prm, pose(u), v, u[2])[[0, 2, 4]] / weight, start,
            method="hybr", tol=1e-15)
        assert np.max(np.abs(external_wrench(prm, pose(sol.x), v, sol.x[2]))) < 1e-11 * weight
        solved[v] = sol.x
        return float(contact_gaps(prm, pose(sol.x)).min() - prm.track.min_gap)

    hi = v_start
    assert clearance(hi) > 0, "v_start must lift off"
    while clearance(0.9 * hi) > 0:
        hi *= 0.9
    return float(scipy.optimize.brentq(clearance, 0.9 * hi, hi, xtol=1e-14, rtol=1e-12))


# ------------------------------------------------- the circuits' lag and the rigid body


def euler_rates(phi: float, theta: float, omega: np.ndarray) -> np.ndarray:
    """Z-Y-X Euler angle rates from the body rates (p, q, r)."""
    p, q, r = omega
    return np.array([p + (q * np.sin(phi) + r * np.cos(phi)) * np.tan(theta),
                     q * np.cos(phi) - r * np.sin(phi),
                     (q * np.sin(phi) + r * np.cos(phi)) / np.cos(theta)])


def lag_times(prm: Parameters, speed: float) -> tuple[float, float]:
    """(tau_d, tau_D) of L I' + R I = Phi' driven by Phi = Re(A(t) e^{i omega t}), omega = k v:
    to first order in A' the current amplitude is J = H0 A + H1 A', H0 = i omega/(R + i omega
    L), H1 = dH0/domega = R/(R + i omega L)^2, so lift and drag are eq 3's times
    (1 + tau A'/A) with tau_d = Re H1/Re H0 and tau_D = Re(-i H1)/Re(-i H0); written out:"""
    R, L = prm.circuit.resistance, prm.circuit.inductance
    w = 2 * np.pi / prm.halbach.wavelength * speed
    D = R**2 + (w * L) ** 2
    return R * (R**2 - (w * L) ** 2) / (D * w**2 * L), -2 * L * R / D


def _log_flux_gradient(fn, pose: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """d ln(fn)/d pose (pose = X (3), phi, theta, psi) by central differences; fn returns an
    array of fluxes (one per circuit)."""
    grad = []
    for j in range(6):
        e = np.zeros(6)
        e[j] = h
        grad.append((np.log(fn(pose + e)) - np.log(fn(pose - e))) / (2 * h))
    return np.array(grad)


def array_loads(prm: Parameters, x: np.ndarray, lag: bool
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(lift, drag, wrench): each array's lift and drag and the arrays' total (F, M about O),
    inertial axes, at the 12-state ``x`` (body velocities), each array at its face centre's
    along-track speed (R (v + w x a))_x.

    The quasi-static force is `array_state`'s circuit sum (eq 3 at each circuit's flux, the
    point law's face centre). With ``lag`` each circuit's force is that times (1 + tau rho_j),
    `lag_times`, rho_j = d ln Phi_j / dt its flux amplitude's log rate along the motion: the
    gradient of ln Phi_j in the pose (central differences) times the pose's rate from the body
    velocities (X' = R v, Euler rates). Every quadrature node of a circuit shares its current,
    so the circuit's factor applies to its whole force, where it acts."""
    h, c = prm.halbach, prm.circuit
    k = 2 * np.pi / h.wavelength
    M = h.magnets_per_wavelength
    B0 = h.remanence * (1 - np.exp(-k * h.thickness)) * np.sin(np.pi / M) / (np.pi / M)
    pose, v, omega = x[0:6], x[6:9], x[9:12]
    R = rotation(*pose[3:6])
    pose_rate = np.concatenate([R @ v, euler_rates(pose[3], pose[4], omega)])
    distributed = prm.model.array_force == "distributed"
    s_nodes = _GL_S * h.width / 2
    lifts, drags, wrench = [], [], np.zeros(6)
    for arr in prm.arrays.values():
        a, n = np.array(arr.position), np.array(arr.normal)
        speed = (R @ (v + np.cross(omega, a)))[0]
        omega_e = k * speed
        ratio = c.resistance / (omega_e * c.inductance)
        per_flux2 = B0**2 / (2 * k * c.inductance) / (1 + ratio**2)
        tau_l, tau_d = lag_times(prm, speed) if lag else (0.0, 0.0)
        n_c = round(arr.circuits)
        across, along = _face_axes(n)
        if distributed:
            ts = (np.arange(n_c) - (n_c - 1) / 2) * c.pitch
            points = a + s_nodes[None, :, None] * across + ts[:, None, None] * along
        else:  # the point law: N circuits at the face centre, the field at the centre gap
            points = np.broadcast_to(a, (1, 1, 3))

        def density(ps: np.ndarray, ps_pose: np.ndarray, n: np.ndarray = n,
                    g0: float = arr.nominal_gap) -> np.ndarray:
            Rp = rotation(*ps_pose[3:6])
            return np.exp(-k * (g0 + (ps_pose[0:3] + ps @ Rp.T - ps) @ n))

        def fluxes(ps_pose: np.ndarray, points: np.ndarray = points, density=density
                   ) -> np.ndarray:
            if distributed:
                return (h.width / 2) * density(points, ps_pose) @ _GL_W
            return h.width * density(points, ps_pose)[:, 0]

        rho = _log_flux_gradient(fluxes, pose).T @ pose_rate if lag else np.zeros(len(points))
        dens = density(points, pose)
        flux = fluxes(pose)
        if distributed:
            f_qs = per_flux2 * flux[:, None] * (h.width / 2) * (_GL_W[None, :] * dens)
        else:
            f_qs = per_flux2 * np.array([[arr.circuits * flux[0] ** 2]])
        f_lift = f_qs * (1 + tau_l * rho)[:, None]
        f_drag = f_qs * ratio * (1 + tau_d * rho)[:, None]
        lifts.append(f_lift.sum())
        drags.append(f_drag.sum())
        forces = f_lift[..., None] * n - f_drag[..., None] * np.array([1.0, 0.0, 0.0])
        arms = points @ R.T
        wrench += np.concatenate([forces.sum(axis=(0, 1)),
                                  np.cross(arms, forces).sum(axis=(0, 1))])
    return np.array(lifts), np.array(drags), wrench


def rigid_body_xdot(prm: Parameters, x: np.ndarray, wrench_inertial: np.ndarray,
                    f_prop: float, body_wrench: np.ndarray | None = None) -> np.ndarray:
    """xdot of the 12 states: X' = R v, Euler rates, and eqs 1-2 at O with the CG at r_G,

        m (v' + w x v + w' x r_G + w x (w x r_G)) = F,
        I_O w' + w x I_O w + m r_G x (v' + w x v) = M

    solved as one 6 x 6 linear system, with gravity at the CG and the propulsion along the
    track at its point added to ``wrench_inertial`` (moments about O), and ``body_wrench``
    (F, M about O, body axes) added after the rotation to body axes."""
    veh = prm.vehicle
    R = rotation(*x[3:6])
    v, omega = x[6:9], x[9:12]
    f_g = np.array([0.0, 0.0, -veh.mass * veh.gravity])
    f_p = np.array([f_prop, 0.0, 0.0])
    r_G, r_p = np.array(veh.cg_offset), np.array(prm.operation.propulsion_point)
    w_in = wrench_inertial + np.concatenate([f_g + f_p, np.cross(R @ r_G, f_g)
                                             + np.cross(R @ r_p, f_p)])
    F, Mo = R.T @ w_in[:3], R.T @ w_in[3:]
    if body_wrench is not None:
        F, Mo = F + body_wrench[:3], Mo + body_wrench[3:]
    I_G = np.asarray(veh.inertia_matrix(), dtype=float)
    I_O = I_G + veh.mass * (r_G @ r_G * np.eye(3) - np.outer(r_G, r_G))
    m = veh.mass

    def sk(r: np.ndarray) -> np.ndarray:
        return np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])

    lhs = np.block([[m * np.eye(3), -m * sk(r_G)], [m * sk(r_G), I_O]])
    rhs = np.concatenate([
        F - m * np.cross(omega, v) - m * np.cross(omega, np.cross(omega, r_G)),
        Mo - np.cross(omega, I_O @ omega) - m * np.cross(r_G, np.cross(omega, v))])
    acc = np.linalg.solve(lhs, rhs)
    return np.concatenate([R @ v, euler_rates(x[3], x[4], omega), acc])


def axis_damping_ratio(k: float, m: float, q1: float, q2: float, r: float) -> float:
    """The smallest damping ratio of one axis m a'' + k a = u under python-control's LQR."""
    _, _, E = control.lqr([[0, 1], [-k / m, 0]], [[0], [1 / m]], np.diag([q1, q2]), [[r]])
    E = np.asarray(E)
    return float(np.min(-E.real / np.abs(E)))


def spec_weights_reference(spec, k, m, T):
    """The spec design's weights from [control.spec] (``spec``): Bryson's q1 and r (the
    budget over the largest allocation entry of each axis), q2 by a root search on
    python-control's damping ratio (where the position weight alone already damps more, the
    design's stated floor 1e-6 q1 m / sigma)."""
    from scipy.optimize import brentq

    a_max = np.array([getattr(spec.max_deviation, a) for a in ("y", "z", "phi", "theta",
                                                                 "psi")])
    q1, r = 1 / a_max**2, (np.max(np.abs(T), axis=0) / spec.force_budget) ** 2
    zeta = spec.min_damping_ratio + spec.damping_margin
    q2 = np.empty(5)
    for i in range(5):
        sigma = np.sqrt(k[i] ** 2 + q1[i] / r[i])
        floor = 1e-6 * q1[i] * m[i] / sigma
        f = lambda w, i=i: axis_damping_ratio(k[i], m[i], q1[i], w, r[i]) - zeta  # noqa: E731
        q2[i] = floor if f(floor) >= 0 else brentq(f, floor, 1e6 * q1[i] * m[i] / sigma,
                                                   rtol=1e-13)
    return q1, q2, r


def lateral_drift_overshoot(prm: Parameters, q_trim: np.ndarray, speed: float, f_prop: float,
                            v0: float, limits: np.ndarray) -> float:
    """The least distance beyond its starting offset that O drifts sideways from a lateral
    velocity ``v0`` (outward) under any control within the force budget: the kinetic energy
    m v0^2 / 2 taken by at most the budget of every array whose normal has a lateral part
    plus the largest external lateral force (`external_wrench` linearised by `stiffness_fd`
    at ``q_trim``) over poses within ``limits`` (y, z, phi, theta, psi) of the trim."""
    n_lateral = sum(abs(a.normal[1]) > 1e-12 for a in prm.arrays.values())
    K = stiffness_fd(prm, q_trim, speed, f_prop)
    force = n_lateral * prm.control.spec.force_budget + float(np.abs(K[0]) @ limits)
    return prm.vehicle.mass * v0**2 / (2 * force)


# ------------------------------------------------- the sensors' readings


def gap_sensor_points(prm: Parameters) -> list[tuple[str, np.ndarray, np.ndarray, float]]:
    """(name, body point, face normal, the face's nominal gap) of each gap sensor: the face
    centre moved across and along the face (its axes as `contact_gaps` takes them)."""
    out = []
    for name, s in prm.sensors.gap_sensors.items():
        arr = prm.arrays[s.array]
        a, n = np.array(arr.position), np.array(arr.normal)
        across, along = _face_axes(n)
        out.append((name, a + s.across * across + s.along * along, n, arr.nominal_gap))
    return out


def sensor_readings(prm: Parameters, x: np.ndarray, xdot: np.ndarray) -> np.ndarray:
    """The sensors' readings at state x with rates xdot, order gaps, gyro, accelerometer,
    track: each gap sensor's ray from its point along the turned face normal -R n intersected
    with the face's track plane (a point and normal fixed at the design pose) by a linear
    solve; the gyro the body rates; the accelerometer the inertial acceleration of its point,
    d/dt (R (v + omega x r)) = R' (v + omega x r) + R (v' + omega' x r) with R' a five-point
    difference of the rotation along the Euler rates, less gravity, in body axes; the track
    sensor X_x."""
    X, ang, v, w = x[0:3], x[3:6], x[6:9], x[9:12]
    R = rotation(*ang)
    out = []
    for _, b, n, g0 in gap_sensor_points(prm):
        origin, direction = X + R @ b, -(R @ n)
        plane_point = b - g0 * n  # on the plane at the design pose (n . b = n . a on the face)
        # origin + t direction - plane_point orthogonal to n: [n . direction] t = n . (pp - o)
        t = np.linalg.solve(np.array([[n @ direction]]), np.array([n @ (plane_point - origin)]))
        out.append(float(t[0]))
    if prm.sensors.imu is not None:
        r = np.array(prm.sensors.imu.position)
        out += list(w)
        h = 1e-3  # the five-point stencil: truncation O(h^4), rounding 1e-13
        rates = euler_rates(ang[0], ang[1], w)
        Rh = [rotation(*(ang + j * h * rates)) for j in (-2, -1, 1, 2)]
        R_dot = (Rh[0] - 8 * Rh[1] + 8 * Rh[2] - Rh[3]) / (12 * h)
        acc = R_dot @ (v + np.cross(w, r)) + R @ (xdot[6:9] + np.cross(xdot[9:12], r))
        out += list(R.T @ (acc - np.array([0.0, 0.0, -prm.vehicle.gravity])))
    if prm.sensors.track is not None:
        out.append(X[0])
    return np.array(out)


def sensor_jacobians_fd(prm: Parameters, x: np.ndarray, xdot: np.ndarray,
                        h: float = 1e-4) -> tuple[np.ndarray, np.ndarray]:
    """(dy/dx, dy/dxdot) of `sensor_readings` by central differences (a step of 1e-4: the
    accelerometer's R' v carries the rotation's difference rounding, 1e-13 times 20 m/s)."""
    def column(f, i: int, z: np.ndarray) -> np.ndarray:
        e = np.zeros_like(z)
        e[i] = h
        return (f(z + e) - f(z - e)) / (2 * h)

    Hx = np.column_stack([column(lambda z: sensor_readings(prm, z, xdot), i, x)
                          for i in range(len(x))])
    Hd = np.column_stack([column(lambda z: sensor_readings(prm, x, z), i, xdot)
                          for i in range(len(xdot))])
    return Hx, Hd
