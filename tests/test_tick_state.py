"""The firmware tick of the design at the tick (maglev_tick with its caller-owned state):
the controller of maglevgen.control.plant's docstring, in C.

References: the controller's equations written out here in numpy (the table's Chebyshev
series by Clenshaw in the C's order, the prediction of the lagged forces, the commands in
flight, the speed integral), the axis rates from the lambdified SymPy model
(derive.numeric) and the allocation from the SymPy effectiveness (pinv); for the closed
loop, the plant's ZOH discretisation by control.c2d with the actuator lag and the delay
built here, the gains by control.dlqr on the augmented design model built here, and the
trim propulsion's slope from the SymPy/SciPy trim (derive.trim) at neighbouring speeds.
"""

from __future__ import annotations

import ctypes
import subprocess
from pathlib import Path

import numpy as np
import pytest

from maglevgen.carriage import DerivedCarriage
from maglevgen.control.carriage_plant import Plant

AX = [1, 2, 3, 4, 5]  # y, z, phi, theta, psi in the state
REDUCED = [1, 2, 3, 4, 5, 7, 8, 9, 10, 11]  # the design's body states
OK = 0


@pytest.fixture(scope="module")
def tick_lib(carriage: DerivedCarriage, sim_lib, tmp_path_factory) -> dict:
    """The firmware folder in double precision with the default loop (its speed integral and
    clamp, control.spec.speed_integral_ratio and speed_integral_limit), compiled into a host
    library. Its table is the fit without dropped terms (drop_share 0): it interpolates the
    rows at its nodes, which the closed-loop eigenvalue test takes as exact."""
    from maglevgen.codegen.checks import ERROR_CODES
    from maglevgen.codegen.generate import write_output
    from maglevgen.control.schedule import GainTable, tick_table_fields
    from maglevgen.exports.firmware import firmware_loop, render_firmware

    plant = Plant(carriage, sim_lib)
    v_min, v_max = plant.speed_range
    setting = plant.loop
    table = GainTable.fit(lambda vs: plant.tick_table_rows(setting, vs), v_min,
                          v_max, tick_table_fields(setting.tick.delay), drop_share=0.0)
    loop = firmware_loop(plant)
    assert loop.speed_integral > 0 and 0 < loop.c_integral_limit < np.inf
    folder = tmp_path_factory.mktemp("tick_state")
    write_output(render_firmware(carriage, table, loop, "double"), folder)
    so = folder / "tick.so"
    subprocess.run(["cc", "-std=c99", "-O2", "-fPIC", "-shared", "-Wall", "-Werror",
                    "maglev_tick.c", "maglev_gain_table.c", "maglev_functions.c", "-lm", "-o",
                    str(so)], cwd=folder, check=True)
    header = (folder / "maglev_gain_table.h").read_text()
    return {"so": so, "table": table, "loop": loop, "setting": setting, "folder": folder,
            "header": header, "nonfinite": ERROR_CODES["MAGLEV_ERR_NONFINITE"][0]}


def _state_type(delay: int) -> type[ctypes.Structure]:
    class State(ctypes.Structure):
        _fields_ = [("in_flight", ctypes.c_double * (5 * max(delay, 1))),
                    ("w_hat", ctypes.c_double * 5), ("xi", ctypes.c_double)]
    return State


class CTick:
    """maglev_tick_init / maglev_tick of the compiled folder through ctypes."""

    def __init__(self, so: Path, delay: int, nu: int) -> None:
        lib = ctypes.CDLL(str(so))
        self.State = _state_type(delay)
        self.nu = nu
        P = ctypes.POINTER(ctypes.c_double)
        self._init = lib.maglev_tick_init
        self._init.argtypes = [ctypes.POINTER(self.State)]
        self._tick = lib.maglev_tick
        self._tick.argtypes = [ctypes.POINTER(self.State), P, ctypes.c_double, P]
        self.s = self.State()
        assert self._init(ctypes.byref(self.s)) == 0

    def __call__(self, x: np.ndarray, v_ref: float) -> tuple[int, np.ndarray]:
        P = ctypes.POINTER(ctypes.c_double)
        xs = np.ascontiguousarray(x, dtype=float)
        u = np.full(self.nu, 7.0)
        rc = self._tick(ctypes.byref(self.s), xs.ctypes.data_as(P), float(v_ref),
                        u.ctypes.data_as(P))
        return rc, u

    def state(self) -> tuple[np.ndarray, np.ndarray, float]:
        return (np.array(self.s.in_flight[:]), np.array(self.s.w_hat[:]), float(self.s.xi))

    def set_state(self, in_flight: np.ndarray, w_hat: np.ndarray, xi: float) -> None:
        for i, v in enumerate(in_flight):
            self.s.in_flight[i] = float(v)
        for i, v in enumerate(w_hat):
            self.s.w_hat[i] = float(v)
        self.s.xi = float(xi)


def _clenshaw(table, v: float) -> np.ndarray:
    """The table's row at v, as maglev_gain_table.c evaluates it (same operations, same
    order, IEEE doubles): clamped to the range, t = T_SCALE / v - T_OFFSET."""
    a, b = 1.0 / table.v_max, 1.0 / table.v_min
    t_scale, t_offset = 2.0 / (b - a), (a + b) / (b - a)
    vc = min(max(v, table.v_min), table.v_max)
    t = t_scale / vc - t_offset
    t2 = t + t
    out = np.zeros(table.coeffs.shape[1])
    for i in table.stored:
        b1 = b2 = 0.0
        for k in range(len(table.coeffs) - 1, 0, -1):
            b1, b2 = (t2 * b1 - b2) + float(table.coeffs[k, i]), b1
        out[i] = (t * b1 - b2) + float(table.coeffs[0, i])
    return out


def _fields(table) -> dict[str, slice]:
    out, i = {}, 0
    for name, n in table.fields:
        out[name] = slice(i, i + n)
        i += n
    return out


class NumpyTick:
    """plant.py's controller (its module docstring), written out here:
    w = -(K_pos (a - a_ref) + K_rate a') - K_lag w_hat - K_delay (in flight, newest first),
    F = T w scaled per array to the budget, F_prop = F_ff(v_ref) + k_v (v_ref - V) - k_i xi; then
    w_hat = a w_hat + (1 - a) w_applied (the oldest in flight), w joins the queue,
    xi += h (V - v_ref), clamped to |k_i xi| <= i_max (anti-windup)."""

    def __init__(self, carriage: DerivedCarriage, table, loop, T: np.ndarray) -> None:
        self.c, self.table, self.loop, self.T = carriage, table, loop, T
        self.f = _fields(table)
        self.d = loop.delay_ticks
        self.a = float(np.exp(-1.0 / (loop.tick_rate * loop.actuator_lag)))
        self.groups = np.array([i for i, (_, comps) in enumerate(carriage.structure.arrays)
                                for _ in comps])
        self.in_flight = np.zeros(5 * max(self.d, 1))
        self.w_hat = np.zeros(5)
        self.xi = 0.0

    def w(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """(w, the table's row, V) at state x."""
        V = float(np.sqrt((x[6] * x[6] + x[7] * x[7]) + x[8] * x[8]))
        g = _clenshaw(self.table, V)
        f = self.f
        K_pos = g[f["K_pos"]].reshape(5, 5, order="F")
        K_rate = g[f["K_rate"]].reshape(5, 5, order="F")
        K_lag = g[f["K_lag"]].reshape(5, 5, order="F")
        rates = self.c.functions.xdot(x, np.zeros(self.c.model.u.shape[0]),
                                      self.c.p).ravel()[AX]
        w = -(K_pos @ (x[AX] - g[f["a_ref"]]) + K_rate @ rates) - K_lag @ self.w_hat
        if self.d > 0:
            w = w - g[f["K_delay"]].reshape(5, 5 * self.d, order="F") @ self.in_flight
        return w, g, V

    def __call__(self, x: np.ndarray, v_ref: float) -> np.ndarray:
        w, _, V = self.w(x)
        F = self.T @ w
        norms = np.sqrt(np.bincount(self.groups, F**2))
        budget = self.loop.force_budget
        F = F * np.where(norms > budget, budget / np.maximum(norms, 1e-300), 1.0)[self.groups]
        k_v, k_i = self.loop.speed_gain, self.loop.speed_integral
        f_ff = _clenshaw(self.table, v_ref)[self.f["F_prop"]][0]  # at the reference
        f_prop = (f_ff + k_v * (v_ref - V)) - k_i * self.xi
        self.advance(w)
        k_i, i_max = self.loop.speed_integral, self.loop.c_integral_limit
        xi = self.xi + (1.0 / self.loop.tick_rate) * (V - v_ref)
        if k_i * xi > i_max:
            xi = i_max / k_i
        if k_i * xi < -i_max:
            xi = -i_max / k_i
        self.xi = xi
        return np.concatenate([[f_prop], F])

    def advance(self, w: np.ndarray) -> None:
        applied = self.in_flight[-5:] if self.d > 0 else w
        self.w_hat = self.a * self.w_hat + (1.0 - self.a) * applied
        if self.d > 0:
            self.in_flight = np.concatenate([w, self.in_flight[:-5]])


def _allocation(carriage: DerivedCarriage) -> np.ndarray:
    from maglevgen.control.symbolic_reference import effectiveness

    return np.linalg.pinv(effectiveness(carriage))


@pytest.mark.needs_cc
def test_tick_follows_the_designed_controller_tick_by_tick(tick_lib, carriage, sim_lib) -> None:
    """15 ticks at three speeds (ends and middle of the table) from states off the trim, the
    speed reference off the speed: the C tick's command and state against NumpyTick. What
    does not pass through a CasADi function (the speed integral, the propulsion with the
    table's F_prop, the shift of the commands in flight, the prediction's update from the C's
    own previous state) bit for bit; the generalized forces and array forces (CasADi's rates
    and allocation against SymPy's and pinv: another order of operations) to 1e-12 of their
    scale."""

    table, loop = tick_lib["table"], tick_lib["loop"]
    nu = carriage.model.u.shape[0]
    d = loop.delay_ticks
    T = _allocation(carriage)
    rng = np.random.default_rng(49)
    speeds = [table.v_min, 0.5 * (table.v_min + table.v_max), table.v_max]
    for op in Plant(carriage, sim_lib).points(speeds):
        c, ref = CTick(tick_lib["so"], d, nu), NumpyTick(carriage, table, loop, T)
        v_ref = op.speed * 1.01
        worst = 0.0
        for k in range(15):
            x = op.x_trim.astype(float).copy()
            x[1:6] += rng.normal(scale=[5e-4, 5e-4, 2e-3, 2e-3, 2e-3])
            x[6:12] += rng.normal(scale=[0.05, 1e-2, 1e-2, 1e-2, 1e-2, 1e-2])
            q_old, w_hat_old, xi_old = c.state()
            rc, u = c(x, v_ref)
            u_ref = ref(x, v_ref)
            assert rc == OK, (op.speed, k, rc)
            q, w_hat, xi = c.state()
            # bit for bit: the integral, the propulsion (the C's xi before the tick), the
            # queue's shift and the prediction from the C's own previous state
            V = float(np.sqrt((x[6] * x[6] + x[7] * x[7]) + x[8] * x[8]))
            g = _clenshaw(table, v_ref)
            f_prop = (g[ref.f["F_prop"]][0] + loop.speed_gain * (v_ref - V)) \
                - loop.speed_integral * xi_old
            assert u[0] == f_prop, (op.speed, k, u[0] - f_prop)
            assert xi == xi_old + (1.0 / loop.tick_rate) * (V - v_ref)
            applied = q_old[-5:] if d > 0 else q[:5]
            np.testing.assert_array_equal(w_hat, ref.a * w_hat_old + (1.0 - ref.a) * applied)
            if d > 1:
                np.testing.assert_array_equal(q[5:], q_old[:-5])
            # the numpy controller's own run (its own state all along)
            assert xi == ref.xi and u[0] == pytest.approx(u_ref[0], rel=1e-13)
            scale_w = max(np.max(np.abs(ref.in_flight[:5])), 1e-9)
            if d > 0:
                assert np.max(np.abs(q - ref.in_flight)) <= 1e-12 * scale_w, (op.speed, k)
            assert np.max(np.abs(w_hat - ref.w_hat)) <= 1e-12 * scale_w
            scale_f = max(np.max(np.abs(u_ref[1:])), 1e-9)
            err = np.max(np.abs(u[1:] - u_ref[1:])) / scale_f
            worst = max(worst, err)
            assert err <= 1e-12, (op.speed, k, err)
        assert np.any(np.abs(c.state()[1]) > 1e-3)  # the prediction is exercised


@pytest.mark.needs_cc
def test_tick_error_codes_and_state(tick_lib, carriage, op) -> None:
    """A NaN in the state: MAGLEV_ERR_NONFINITE, the command all zeros, the state moved on
    with a zero command (the queue shifted, the prediction from the oldest in flight) and xi
    unchanged; a NaN planted in the state: MAGLEV_ERR_NONFINITE and the state reset (then
    moved on with the zero command: all zeros); NULL state: MAGLEV_ERR_ARGUMENT."""
    loop = tick_lib["loop"]
    nu = carriage.model.u.shape[0]
    d = loop.delay_ticks
    c = CTick(tick_lib["so"], d, nu)
    x = op.x_trim.astype(float).copy()
    x[2] += 1e-3
    for _ in range(3):
        assert c(x, op.speed * 1.01)[0] == OK
    q0, w0, xi0 = c.state()
    assert np.any(q0 != 0) and xi0 != 0
    bad = x.copy()
    bad[2] = np.nan
    rc, u = c(bad, op.speed)
    assert rc == tick_lib["nonfinite"] and np.all(u == 0)
    q1, w1, xi1 = c.state()
    a = float(np.exp(-1.0 / (loop.tick_rate * loop.actuator_lag)))
    applied = q0[-5:] if d > 0 else np.zeros(5)
    np.testing.assert_array_equal(w1, a * w0 + (1.0 - a) * applied)
    if d > 0:
        np.testing.assert_array_equal(q1[:5], np.zeros(5))
    assert xi1 == xi0
    c.set_state(q1, np.array([np.nan, 0, 0, 0, 0]), xi1)
    rc, u = c(x, op.speed)
    assert rc == tick_lib["nonfinite"] and np.all(u == 0)
    q2, w2, xi2 = c.state()
    assert np.all(q2 == 0) and np.all(w2 == 0) and xi2 == 0
    P = ctypes.POINTER(ctypes.c_double)
    u = np.full(nu, 7.0)
    rc = c._tick(None, x.ctypes.data_as(P), 20.0, u.ctypes.data_as(P))
    assert rc == ERR_ARGUMENT() and np.all(u == 0)


@pytest.mark.needs_cc
def test_tick_speed_integral_is_clamped(tick_lib, carriage, op) -> None:
    """Anti-windup: a speed error the loop does not remove (v_ref 5 m/s above the speed, tick
    after tick) grows xi by h (V - v_ref) until k_i xi reaches -i_max
    (control.spec.speed_integral_limit), then xi stays at -i_max / k_i exactly and the
    propulsion's integral part at +i_max; the first tick with the error reversed moves xi
    back from the bound at once (no stored excess to unwind)."""
    loop = tick_lib["loop"]
    k_i, i_max, h = loop.speed_integral, loop.c_integral_limit, 1.0 / loop.tick_rate
    c = CTick(tick_lib["so"], loop.delay_ticks, carriage.model.u.shape[0])
    x = op.x_trim.astype(float).copy()
    V = float(np.sqrt((x[6] * x[6] + x[7] * x[7]) + x[8] * x[8]))
    v_ref = V + 5.0
    g = _clenshaw(tick_lib["table"], v_ref)
    f_ff = g[_fields(tick_lib["table"])["F_prop"]][0]  # the feedforward at the reference
    n_free = int(np.floor(i_max / k_i / (5.0 * h)))  # ticks before the bound
    assert 10 < n_free < 1000
    xi = 0.0
    for k in range(n_free + 20):
        rc, u = c(x, v_ref)
        assert rc == OK
        assert u[0] == (f_ff + loop.speed_gain * (v_ref - V)) - k_i * xi, k
        xi = c.state()[2]
        if k < n_free - 1:
            assert k_i * xi > -i_max
    assert xi == -i_max / k_i
    rc, _ = c(x, V - 5.0)
    assert rc == OK and c.state()[2] == xi + h * (V - (V - 5.0))


def ERR_ARGUMENT() -> int:
    from maglevgen.codegen.checks import ERROR_CODES

    return ERROR_CODES["MAGLEV_ERR_ARGUMENT"][0]


@pytest.mark.needs_cc
def test_tick_closed_loop_on_the_linearised_plant_has_the_dlqr_loop_eigenvalues(
        tick_lib, carriage, sim_lib) -> None:
    """At a node of the table (where the Chebyshev fit interpolates), the C tick linearised
    by central differences (command and next state against the state and its own state)
    closed around the plant as built here (the 12-state Jacobians with each array force
    through its lag, control.c2d's ZOH over the tick, the command applied after the delay)
    against the same plant closed by the controller built here from control.dlqr's gains on
    the augmented design model (the reduced body, the lag on the generalized forces, the
    commands in flight; control.c2d), the exact prediction, the reference a_ref's slope
    (derive.trim) and the speed loop (its feedforward at the reference: no slope of the trim
    propulsion): the eigenvalues agree to 1e-6 of |z| (1 + its size)."""
    import control

    from maglevgen.control.lqr import weighted_qr
    from maglevgen.control.schedule import GainTable
    from maglevgen.control.spec import spec_weights
    from maglevgen.derive.trim import solve_trim

    table, loop = tick_lib["table"], tick_lib["loop"]
    nu = carriage.model.u.shape[0]
    nf, d, h = nu - 1, loop.delay_ticks, 1.0 / loop.tick_rate
    tau = loop.actuator_lag
    nodes = GainTable.nodes(len(table.coeffs), table.v_min, table.v_max)
    (op,) = Plant(carriage, sim_lib).points([nodes[len(nodes) // 2]])
    x0, v0 = op.x_trim.astype(float), op.speed
    p = carriage.p
    u0 = np.concatenate([[op.f_prop], np.zeros(nf)])
    A, B = (np.asarray(m) for m in sim_lib.function("maglev_jacobians")(x0, u0, p))
    T = _allocation(carriage)

    # --- the C tick as a linear map z = (x - x0, in_flight, w_hat, xi) -> (u - u0, state')
    c = CTick(tick_lib["so"], d, nu)
    nq = 5 * max(d, 1)

    def tick(z: np.ndarray) -> np.ndarray:
        c.set_state(z[12:12 + nq], z[12 + nq:12 + nq + 5], z[-1])
        rc, u = c(x0 + z[:12], v0)
        assert rc == OK
        q, w_hat, xi = c.state()
        return np.concatenate([u - u0, q, w_hat, [xi]])

    step = np.concatenate([np.full(12, 1e-6), np.full(nq + 5, 1e-2), [1e-6]])
    J = np.column_stack([(tick(s) - tick(-s)) / (2 * s[j]) for j, s in
                         enumerate(np.diag(step))])
    K_u, K_s = J[:nu], J[nu:]

    # --- the plant as built: x, the lagged array forces; inputs the array commands, F_prop
    n_p = 12 + nf
    Ac = np.zeros((n_p, n_p))
    Bc = np.zeros((n_p, nu))
    Ac[:12, :12] = A
    Ac[:12, 12:] = B[:, 1:]
    Ac[12:, 12:] = -np.eye(nf) / tau
    Bc[12:, 1:] = np.eye(nf) / tau
    Bc[:12, 0] = B[:, 0]
    plant = control.c2d(control.ss(Ac, Bc, np.eye(n_p), 0), h, method="zoh")
    Phi, Gam = np.asarray(plant.A), np.asarray(plant.B)

    def closed(ctrl_u: np.ndarray, ctrl_s: np.ndarray, n_c: int) -> np.ndarray:
        """z = (plant, commands computed not yet applied (newest first), controller state);
        ctrl_u, ctrl_s: the controller's command and next state on (x, controller state)."""
        n = n_p + d * nu + n_c
        M = np.zeros((n, n))
        cs = slice(n_p + d * nu, n)
        Kx = np.zeros((nu, n))
        Kx[:, :12] = ctrl_u[:, :12]
        Kx[:, cs] = ctrl_u[:, 12:]
        if d == 0:
            M[:n_p] = Phi @ np.eye(n_p, n) + Gam @ Kx
        else:
            M[:n_p, :n_p] = Phi
            M[:n_p, n_p + (d - 1) * nu:n_p + d * nu] = Gam
            M[n_p:n_p + nu] = Kx
            for j in range(1, d):
                M[n_p + j * nu:n_p + (j + 1) * nu, n_p + (j - 1) * nu:n_p + j * nu] = \
                    np.eye(nu)
        M[cs, :12] = ctrl_s[:, :12]
        M[cs, cs] = ctrl_s[:, 12:]
        return M

    z_c = np.linalg.eigvals(closed(K_u, K_s, nq + 5 + 1))

    # --- the reference controller: control.dlqr on the design model built here
    A_r = A[np.ix_(REDUCED, REDUCED)]
    B_g = B[REDUCED, 1:] @ T
    n_d = 10 + 5
    Ad = np.zeros((n_d, n_d))
    Bd = np.zeros((n_d, 5))
    Ad[:10, :10] = A_r
    Ad[:10, 10:] = B_g
    Ad[10:, 10:] = -np.eye(5) / tau
    Bd[10:] = np.eye(5) / tau
    des = control.c2d(control.ss(Ad, Bd, np.eye(n_d), 0), h, method="zoh")
    Pd, Gd = np.asarray(des.A), np.asarray(des.B)
    n_a = n_d + 5 * d
    Pa, Ga = np.zeros((n_a, n_a)), np.zeros((n_a, 5))
    Pa[:n_d, :n_d] = Pd
    if d == 0:
        Ga[:n_d] = Gd
    else:
        Pa[:n_d, n_a - 5:] = Gd
        Ga[n_d:n_d + 5] = np.eye(5)
        for j in range(1, d):
            Pa[n_d + 5 * j:n_d + 5 * (j + 1), n_d + 5 * (j - 1):n_d + 5 * j] = np.eye(5)
    q1, q2, r = spec_weights(op)
    Q, R = weighted_qr(op.rate_map, q1, q2, r)
    Qa = np.zeros((n_a, n_a))
    Qa[:10, :10] = Q
    K, _, _ = control.dlqr(Pa, Ga, Qa, R)
    K = np.asarray(K)
    K_body, K_lag, K_delay = K[:, :10], K[:, 10:15], K[:, 15:]
    # on the body as the tick measures it: K_pos (a - a_ref) + K_rate a', a' linearised
    M_ax = np.vstack([np.eye(5, 10), A[np.ix_(AX, REDUCED)]])
    Kp = np.linalg.solve(M_ax.T, K_body.T).T
    K_pos, K_rate = Kp[:, :5], Kp[:, 5:]
    Kw_x = K_pos @ np.eye(12)[AX] + K_rate @ A[AX]
    # the slope of the trim's pose along the trim curve, the scheduled reference a_ref at the
    # measured speed (derive.trim at v0 +- dv); the feedforward is at the reference v_ref, so
    # the propulsion's row has no slope of the trim propulsion
    dv = 1e-3 * v0
    hi, lo = (solve_trim(carriage.functions, p, v, carriage.params.track.min_gap)
              for v in (v0 + dv, v0 - dv))
    a_ref_slope = (np.asarray(hi.x)[AX] - np.asarray(lo.x)[AX]) / (2 * dv)
    dV = np.zeros(12)
    dV[6:9] = x0[6:9] / np.linalg.norm(x0[6:9])
    a = float(np.exp(-h / tau))
    ref_u = np.zeros((nu, 12 + nq + 6))
    ref_s = np.zeros((nq + 6, 12 + nq + 6))
    # w = -Kw_x x + K_pos a_ref' dV - K_delay q - K_lag w_hat; F = T w;
    # F_prop = -k_v dV - k_i xi
    W = np.zeros((5, 12 + nq + 6))
    W[:, :12] = -Kw_x + np.outer(K_pos @ a_ref_slope, dV)
    if d > 0:
        W[:, 12:12 + nq] = -K_delay
    W[:, 12 + nq:12 + nq + 5] = -K_lag
    ref_u[1:] = T @ W
    ref_u[0, :12] = -loop.speed_gain * dV
    ref_u[0, -1] = -loop.speed_integral
    # next state: the queue (w newest), w_hat = a w_hat + (1 - a) oldest, xi += h dV
    if d > 0:
        ref_s[:5] = W
        for j in range(1, d):
            ref_s[5 * j:5 * (j + 1), 12 + 5 * (j - 1):12 + 5 * j] = np.eye(5)
        ref_s[nq:nq + 5, 12 + nq - 5:12 + nq] = (1 - a) * np.eye(5)
    else:
        ref_s[nq:nq + 5] = (1 - a) * W
    ref_s[nq:nq + 5, 12 + nq:12 + nq + 5] += a * np.eye(5)
    ref_s[-1, :12] = h * dV
    ref_s[-1, -1] = 1.0
    z_r = np.linalg.eigvals(closed(ref_u, ref_s, nq + 6))

    assert z_c.size == z_r.size
    assert np.max(np.abs(z_r)) < 1 + 1e-9  # stable, the along-track position's z = 1 aside
    for z in z_r:  # each reference eigenvalue has a C-loop one next to it, and back
        assert np.min(np.abs(z_c - z)) <= 1e-6 * (1 + abs(z)), (z, z_c)
    for z in z_c:
        assert np.min(np.abs(z_r - z)) <= 1e-6 * (1 + abs(z)), z


_HOSTILE_HARNESS = r"""
#include <math.h>
#include <stdio.h>
#include <string.h>
#include "maglev_tick.h"

static const double hostile[] = {NAN, INFINITY, -INFINITY, 1e30, -1e30, 1e300, 4.9e-324,
                                 -4.9e-324, 2.2e-308, 0.0, -0.0, -1.0};
#define NH ((int)(sizeof hostile / sizeof hostile[0]))
#define NS ((int)(sizeof(maglev_tick_state) / sizeof(double)))

/* after any call: a known code; on an error the command all zeros; the state finite */
static int check(int rc, const double* u, const maglev_tick_state* s, long* bad) {
    const double* v = (const double*)s;
    int i;
    if (rc != MAGLEV_OK && rc != MAGLEV_ERR_NONFINITE && rc != MAGLEV_ERR_NONFINITE_OUTPUT
        && rc != MAGLEV_ERR_ARGUMENT) ++*bad;
    for (i = 0; i < MAGLEV_NU; ++i) {
        if (rc != MAGLEV_OK && u[i] != 0.0) ++*bad;
        if (!isfinite(u[i])) ++*bad;
    }
    for (i = 0; i < NS; ++i) {
        if (!isfinite(v[i])) ++*bad;
    }
    return rc;
}

int main(void) {
    double x0[MAGLEV_NX] = {X0}, x[MAGLEV_NX], u[MAGLEV_NU];
    maglev_tick_state s;
    long calls = 0, bad = 0, errors = 0;
    int h, i, k, rc;
    /* a hostile value in each state entry, then in all, for a few ticks each */
    for (h = 0; h < NH; ++h) {
        for (i = -1; i < MAGLEV_NX; ++i) {
            memcpy(x, x0, sizeof x);
            if (i < 0) { for (k = 0; k < MAGLEV_NX; ++k) x[k] = hostile[h]; }
            else x[i] = hostile[h];
            maglev_tick_init(&s);
            for (k = 0; k < 3; ++k) {
                rc = check(maglev_tick(&s, k == 1 ? x : x0, V_REF, u), u, &s, &bad);
                errors += rc != MAGLEV_OK;
                ++calls;
            }
        }
        /* the speed reference */
        maglev_tick_init(&s);
        rc = check(maglev_tick(&s, x0, hostile[h], u), u, &s, &bad);
        errors += rc != MAGLEV_OK;
        ++calls;
        /* the controller's own state, one entry then all */
        for (i = -1; i < NS; ++i) {
            double* v = (double*)&s;
            maglev_tick_init(&s);
            if (i < 0) { for (k = 0; k < NS; ++k) v[k] = hostile[h]; } else v[i] = hostile[h];
            for (k = 0; k < 3; ++k) {
                rc = check(maglev_tick(&s, x0, V_REF, u), u, &s, &bad);
                errors += rc != MAGLEV_OK;
                ++calls;
            }
        }
    }
    /* NULL pointers */
    maglev_tick_init(&s);
    if (maglev_tick(NULL, x0, V_REF, u) != MAGLEV_ERR_ARGUMENT) ++bad;
    if (maglev_tick(&s, NULL, V_REF, u) != MAGLEV_ERR_ARGUMENT) ++bad;
    if (maglev_tick(&s, x0, V_REF, NULL) != MAGLEV_ERR_ARGUMENT) ++bad;
    if (maglev_tick_init(NULL) != MAGLEV_ERR_ARGUMENT) ++bad;
    printf("calls %ld errors %ld bad %ld\n", calls, errors, bad);
    return bad != 0;
}
"""


@pytest.mark.needs_cc
def test_tick_under_sanitizers_with_hostile_values(tick_lib, op) -> None:
    """maglev_tick under ASan and UBSan (no recovery) with hostile values (NaN, +-inf,
    +-1e30, 1e300, denormals, +-0, -1; the set of test_failsafe.py) in each entry of the
    state x and in all of them, in the speed reference, and in each entry of the
    controller's state and in all of them, then NULL pointers: no sanitizer report, every
    code one the header documents, the command zero on an error and finite always, the
    controller's state finite after every call (a non-finite one reset); and an error for
    at least each call with a NaN or infinity in x, v_ref or the controller's state."""
    from test_failsafe import SANITIZE

    folder = tick_lib["folder"]
    (folder / "hostile.c").write_text(_HOSTILE_HARNESS)
    x0 = ",".join(repr(float(v)) for v in op.x_trim)
    run = subprocess.run(["cc", "-std=c99", "-g", "-O1", *SANITIZE, f"-DX0={x0}",
                          f"-DV_REF={float(op.speed)!r}", "hostile.c", "maglev_tick.c",
                          "maglev_gain_table.c", "maglev_functions.c", "-lm", "-o", "hostile"],
                         cwd=folder, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    out = subprocess.run([str(folder / "hostile")], cwd=folder, capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0 and not out.stderr, out.stdout + out.stderr
    calls, errors, bad = (int(v) for v in out.stdout.split()[1::2])
    n_state = 5 * max(tick_lib["loop"].delay_ticks, 1) + 6
    assert bad == 0 and calls > 500, out.stdout
    assert errors >= 3 * (12 + 1) + 3 + 3 * (n_state + 1), out.stdout


def test_the_firmware_integral_needs_a_finite_clamp() -> None:
    """The loop as built (`LoopSetting`): a speed integral without a finite
    speed_integral_limit is refused by the firmware (the C clamp needs a number); without an
    integral the header's MAGLEV_TICK_I_MAX is 0."""
    from maglevgen.control.built_loop import LoopSetting

    def loop(*rest: float) -> LoopSetting:  # (lag, speed_integral, integral_limit)
        return LoopSetting(1000.0, 1, *rest, speed_gain=60.0)

    with pytest.raises(ValueError, match="finite limit"):
        loop(2e-3, 116.0).check_embeddable()
    loop(2e-3, 116.0, 100.0).check_embeddable()
    assert loop(2e-3, 116.0, 100.0).c_integral_limit == 100.0
    assert loop(2e-3).c_integral_limit == 0.0
