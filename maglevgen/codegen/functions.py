"""The generated functions, built as CasADi Functions from the SymPy derivation.

Every function that depends on the parameters takes the vector ``p`` as its last input
(``maglev_closed_loop_prepared`` takes the constants ``maglev_closed_loop_prepare`` made from
it instead); `bake_all` folds a parameter file's values in as constants. `FUNCTION_SPECS`
names each function, its inputs and outputs and says what it does; everything downstream (C,
header, manifest) reads the Function objects made to it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np
import sympy as sp

from maglevgen.codegen.casadi_model import CasadiModel, casadi_model
from maglevgen.codegen.sympy_casadi import SympyToCasadi, casadi_rewriting_off
from maglevgen.derive import conventions as cv
from maglevgen.derive.linearize import (
    Q_STATES,
    STIFFNESS_PARTS,
    generalized_mass_expr,
    stiffness_form,
    stiffness_parts,
)
from maglevgen.derive.model import CarriageModel
from maglevgen.derive.riccati import riccati_stable_form
from maglevgen.derive.sensors import GapSensorSymbols, accelerometer_reading, gap_reading
from maglevgen.derive.structure import NORMAL_AXIS
from maglevgen.derive.trim import along_track_acceleration

__all__ = ["DESCRIPTIONS", "PREFIX", "bake_all", "build_functions"]

PREFIX = "maglev_"
N_AXES = len(cv.AXES)


#: functions for the analysis (the report) that the run-time-parameter library has and
#: `maglevgen generate` leaves out: the firmware needs none of them
ANALYSIS_FUNCTIONS = ("maglev_stiffness_parts",)
_ANALYSIS_DESCRIPTIONS = {"stiffness_parts":
    "at state x and propulsion F_prop: maglev_stiffness's K_magnetic + K_other "
    "split by where the pose enters the wrench (5 x 5 each): the gap slope of eq "
    "3, the rotating moment arms, the tilt across the face, gravity's and the "
    "propulsion's moments (the report's parts table; run-time-parameter library "
    "only, not in the baked firmware)"}


@dataclass(frozen=True)
class Built:
    """The generated functions (runtime parameters) and the parameter vector's size;
    ``analysis``: the ANALYSIS_FUNCTIONS, built only when asked for."""

    functions: tuple[ca.Function, ...]
    n_p: int
    analysis: tuple[ca.Function, ...] = ()


def _pairs(syms, sx) -> dict:
    return {s: sx[i] for i, s in enumerate(syms)}


# Newton stopping tolerances of the trim solve per precision: residual (accelerations, m/s^2 and
# rad/s^2) and step (m, rad, N). float32 cannot reach float64's (every call would then run all
# its iterations); 1e-5 is a few times float32's rounding of the accelerations at trim
# (measured 2e-6 to 1e-5 between 8 and 45 m/s), and reached in as many iterations as float64.
NEWTON_TOLERANCES = {"double": (1e-13, 1e-12), "single": (1e-5, 1e-6)}


@dataclass(frozen=True)
class FunctionSpec:
    """One generated function: its name without PREFIX and its inputs and outputs by name
    (the names the C, the header and the manifest show). `build_functions` makes it from its
    symbols and expressions of those names; a ``derived`` one (the RK4 step, the prepared
    closed loop) is made from other functions of the table, and its names are checked
    against these."""

    name: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    description: str  # what it does, for the header and the manifest
    derived: bool = False


#: every generated function, in the order of the C, the header and the manifest
FUNCTION_SPECS: tuple[FunctionSpec, ...] = (
    FunctionSpec("dynamics", ("x", "u", "p"), ("xdot",),
                 "xdot = f(x, u): the nonlinear 12-state model with array forces (eqs 1-4, "
                 "8-12)"),
    FunctionSpec("dynamics_prepare", ("p",), ("d",),
                 "the part of maglev_dynamics that depends only on p: d, once per simulation",
                 derived=True),
    FunctionSpec("dynamics_prepared", ("x", "u", "d"), ("xdot",),
                 "maglev_dynamics' xdot from x, u and the prepared d", derived=True),
    FunctionSpec("jacobians", ("x", "u", "p"), ("A", "B"),
                 "(A, B) = (df/dx, df/du) of maglev_dynamics"),
    FunctionSpec("trim", ("v", "p"), ("x_trim", "F_prop"),
                 "equilibrium at speed v (Newton iterations in C): trim state and propulsion "
                 "force"),
    FunctionSpec("trim_accelerating", ("v", "accel", "p"), ("x_trim", "F_prop"),
                 "equilibrium at speed v accelerating at accel along the track (Newton "
                 "iterations in C): eqs 1-2 with the d'Alembert load -m accel at the CG and "
                 "the propulsion at operation.propulsion_point (derive/trim.py); trim state "
                 "and propulsion force (drag + m accel); accel = 0 gives maglev_trim"),
    FunctionSpec("axis_plants", ("v", "p"), ("k", "m"),
                 "per-axis stiffness k (eqs 13-19 derived) and inertia m at the trim at speed "
                 "v"),
    FunctionSpec("axis_gains", ("k", "m", "p"), ("K", "c_damping"),
                 "per-axis LQR gains K (5 x 2) and damping gains from (k, m): closed form (eqs "
                 "29-33), the small part of the gain schedule"),
    FunctionSpec("lqr_gains", ("v", "p"), ("K", "c_damping"),
                 "per-axis LQR gains K (5 x 2) at speed v, closed form (eqs 29-33) at the trim"),
    FunctionSpec("lqr_control", ("x", "K", "a_ref", "p"), ("u_gen",),
                 "one control tick: u_gen = -K (a - a_ref, a_dot), a = (y, z, phi, theta, psi)"),
    FunctionSpec("damping_control", ("x", "c_damping", "p"), ("u_gen",),
                 "one control tick: u_gen = -c a_dot, optimized damping (eqs 20-21)"),
    FunctionSpec("coupled_control", ("x", "K_pos", "K_rate", "a_ref", "p"), ("u_gen",),
                 "one control tick of a full-matrix feedback (the coupled LQR): u_gen = "
                 "-(K_pos (a - a_ref) + K_rate a_dot), K_pos and K_rate 5 x 5"),
    FunctionSpec("allocate", ("u_gen", "p"), ("F_arrays",),
                 "array forces T u_gen, T the pseudo-inverse of E: the least-norm forces that "
                 "produce u_gen (eqs 22-23 derived), or with normal actuators (E of rank 4) "
                 "its least-squares projection"),
    FunctionSpec("allocation_matrix", ("p",), ("T",),
                 "T (arrays' forces x 5): the minimum-norm allocation as a matrix"),
    FunctionSpec("rk4_step", ("x", "dt", "F_prop", "K_pos", "K_rate", "a_ref", "p"),
                 ("x_next", "u"),
                 "one RK4 step of the closed loop; the axis feedback is evaluated at every "
                 "stage", derived=True),
    FunctionSpec("closed_loop", ("x", "F_prop", "K_pos", "K_rate", "a_ref", "T", "p"),
                 ("xdot", "u", "gaps"),
                 "xdot and u of the closed loop (the right-hand side that maglev_rk4_step "
                 "integrates), the array forces being T u_gen with T an input; and the gaps at "
                 "x (they share the model's geometry)"),
    FunctionSpec("closed_loop_prepare", ("F_prop", "K_pos", "K_rate", "a_ref", "T", "p"),
                 ("c",),
                 "the part of maglev_closed_loop that depends only on the inputs constant over "
                 "a run: c, once per simulation", derived=True),
    FunctionSpec("closed_loop_prepared", ("x", "c"), ("xdot", "u", "gaps"),
                 "maglev_closed_loop's xdot, u and gaps from x and the prepared c", derived=True),
    FunctionSpec("gaps", ("x", "p"), ("gaps",),
                 "the gap of each array face's closest corner (exact pose geometry); contact "
                 "when one reaches track.min_gap"),
    FunctionSpec("array_forces", ("x", "p"), ("lift", "drag"),
                 "lift and drag of each array at state x (eqs 3-4 at the exact gaps, summed "
                 "over the tilted face for model.array_force = distributed)"),
    FunctionSpec("stiffness", ("x", "F_prop", "p"), ("K_magnetic", "K_other"),
                 "at state x and propulsion F_prop: the magnetic stiffness K_st0 = -dW/dq of "
                 "the array forces (5 x 5, eqs 13-19 derived) and that of the gravity and "
                 "propulsion moments (K_other)"),
    FunctionSpec("effectiveness", ("p",), ("E",),
                 "E (5 x arrays' forces): the generalized forces about O that unit array "
                 "control forces produce (eqs 22-23; T is its minimum-norm inverse)"),
    FunctionSpec("gap_reading", ("x", "point", "normal", "nominal_gap"), ("reading", "H"),
                 "what a gap sensor at a body point of a face (its unit normal and nominal "
                 "gap) reads along the turned normal to the face's track plane, and its "
                 "Jacobian dreading/dx (derive/sensors.py)"),
    FunctionSpec("imu_reading", ("x", "xdot", "point", "p"),
                 ("gyro", "specific_force", "H_x", "H_xdot"),
                 "what an IMU at a body point reads: the body rates and the specific force in "
                 "body axes, and the Jacobians of (gyro, accel) in x and in xdot "
                 "(derive/sensors.py)"),
)


#: what each generated function does (the header's and the manifest's text), by name
DESCRIPTIONS: dict[str, str] = {**{s.name: s.description for s in FUNCTION_SPECS},
                                **_ANALYSIS_DESCRIPTIONS}


def build_functions(model: CarriageModel, newton_iterations: int = 30,
                    precision: str = "double", analysis: bool = False) -> Built:
    """All generated functions (`FUNCTION_SPECS`) with the parameters as a run-time input
    (and, with ``analysis``, the ANALYSIS_FUNCTIONS).

    Each part of the model gives its functions' inputs and outputs by name (``io``); the
    table orders and names them. The parts run in this order, and each makes its symbols
    where they are first needed, in the same order every time: CasADi orders the operands of
    its nodes by their creation, so the same order is the same C.
    """
    cm = casadi_model(model)
    x, u, p = cm.x, cm.u, cm.p
    base = {**_pairs(model.x, x), **_pairs(model.u, u), **_pairs(model.p, p)}
    io: dict[str, tuple[dict, dict]] = {}  # function -> (inputs, outputs), each by name

    dynamics = ca.Function("maglev_dynamics", [x, u, p], [cm.xdot])
    io["dynamics"] = {"x": x, "u": u, "p": p}, {"xdot": cm.xdot}
    io["jacobians"] = ({"x": x, "u": u, "p": p},
                       {"A": ca.jacobian(cm.xdot, x), "B": ca.jacobian(cm.xdot, u)})
    trim = _trim_io(model, cm, dynamics, precision, newton_iterations, io)
    K_fn, xs, fprop_s, lift_fn = _plant_io(model, cm, base, trim, io)
    rates_fn = _control_io(cm, K_fn, io)
    E, T_normal = _allocation_io(model, p, io)
    _closed_loop_io(cm, dynamics, rates_fn, E, T_normal, io)
    _sensor_io(model, p, io)
    made = {s.name: _finished(_function(s, *io[s.name]))
            for s in FUNCTION_SPECS if not s.derived}
    # the step calls the finished right-hand side, so the C holds one copy of it
    made["rk4_step"] = _rk4_step(made["closed_loop"], made["allocation_matrix"])
    made["closed_loop_prepare"], made["closed_loop_prepared"] = \
        _prepared(made["closed_loop"], 1, "c")
    made["dynamics_prepare"], made["dynamics_prepared"] = _prepared(made["dynamics"], 2, "d")
    for s in FUNCTION_SPECS:  # the derived functions' names are the table's
        f = made[s.name]
        if (tuple(f.name_in()), tuple(f.name_out())) != (s.inputs, s.outputs):
            raise ValueError(f"{f.name()}: inputs {f.name_in()} and outputs {f.name_out()}, "
                             f"not the table's {s.inputs} and {s.outputs}")
    extra = (_finished(_stiffness_parts(model, base, xs, fprop_s, p, lift_fn)),) \
        if analysis else ()
    return Built(tuple(made[s.name] for s in FUNCTION_SPECS), p.shape[0], extra)


def _trim_io(model: CarriageModel, cm: CasadiModel, dynamics: ca.Function, precision: str,
             newton_iterations: int, io: dict) -> tuple[ca.MX, ca.MX, ca.MX, ca.MX]:
    """maglev_trim and maglev_trim_accelerating into ``io``; (v, p, x_trim, u_trim) of the
    constant-speed trim (MX) for the functions at the trim."""
    u, p = cm.u, cm.p
    n_u = u.shape[0]
    # --- trim: Newton on the six accelerations in (y, z, phi, theta, psi, F_prop), less those
    # of a pure translation at accel along the track (derive.trim.along_track_acceleration:
    # eqs 1-2 with the d'Alembert load at the CG). One solver serves maglev_trim (accel = 0,
    # where the target and its Jacobian are exactly zero: the same iterations as without it)
    # and maglev_trim_accelerating, so the C holds one copy of the Newton solve's model.
    v, accel = ca.SX.sym("v"), ca.SX.sym("accel")
    z6 = ca.SX.sym("z", _F_PROP + 1)
    x_trim = _trim_state(v, z6)
    u_trim = ca.vertcat(z6[_F_PROP], ca.SX.zeros(n_u - 1))
    angles = ("phi", "theta", "psi")
    a_sym = sp.Symbol("a_track", real=True)
    target = SympyToCasadi({**{model.x[cv.STATE_INDEX[s]]: z6[cv.Q_STATES.index(s)]
                               for s in angles}, a_sym: accel})(
        along_track_acceleration(model.R, a_sym))
    residual = dynamics(x_trim, u_trim, p)[cv.KINETIC] - target
    res_fn = ca.Function("maglev_trim_residual", [z6, ca.vertcat(v, accel, p)], [residual])
    abstol, abstol_step = NEWTON_TOLERANCES[precision]
    newton = ca.rootfinder("maglev_trim_newton", "fast_newton", res_fn,
                           {"max_iter": newton_iterations, "abstol": abstol,
                            "abstolStep": abstol_step})
    v_mx, a_mx, p_mx = ca.MX.sym("v"), ca.MX.sym("accel"), ca.MX.sym("p", p.shape[0])
    guess = ca.vertcat(*(0,) * (_F_PROP + 1))
    trim_state_fn = ca.Function("maglev_trim_state", [v, z6], [x_trim, u_trim])
    xt_mx, ut_mx = trim_state_fn(v_mx, newton(guess, ca.vertcat(v_mx, 0, p_mx)))
    io["trim"] = {"v": v_mx, "p": p_mx}, {"x_trim": xt_mx, "F_prop": ut_mx[0]}
    xa_mx, ua_mx = trim_state_fn(v_mx, newton(guess, ca.vertcat(v_mx, a_mx, p_mx)))
    io["trim_accelerating"] = ({"v": v_mx, "accel": a_mx, "p": p_mx},
                               {"x_trim": xa_mx, "F_prop": ua_mx[0]})
    return v_mx, p_mx, xt_mx, ut_mx


def _plant_io(model: CarriageModel, cm: CasadiModel, base: dict, trim: tuple, io: dict
              ) -> tuple[ca.Function, ca.SX, ca.SX, ca.Function]:
    """maglev_array_forces, maglev_stiffness, maglev_lqr_gains and maglev_axis_plants into
    ``io``; the axis gains' function of (k, m) and p, the symbols x and F_prop of the
    stiffness, the array forces' function."""
    x, p = cm.x, cm.p
    n_x = x.shape[0]
    conv = SympyToCasadi(base)
    names = model.structure.param_names
    v_mx, p_mx, xt_mx, ut_mx = trim
    # --- per-axis plants at trim and their closed-form gains
    sf = stiffness_form(model.structure)
    q_sx = ca.SX.sym("q", 5)
    fl, fd, fprop = ca.SX.sym("FL", len(model.arrays)), ca.SX.sym("FD", len(model.arrays)), \
        ca.SX.sym("Fp")
    conv_k = SympyToCasadi({**base, **_pairs(sf.q, q_sx), **_pairs(sf.lift_sym, fl),
                            **_pairs(sf.drag_sym, fd), model.u[0]: fprop})
    k_diag = ca.vertcat(*[conv_k(sf.K[i, i] + sf.K_other[i, i]) for i in range(5)])
    m_diag = conv(generalized_mass_expr(model))
    q1 = p[names.index("control.state_weights.0")]
    q2 = p[names.index("control.state_weights.1")]
    r = p[names.index("control.input_weight")]
    # closed-form gains (riccati_stable_form) and damping of each axis from (k, m)
    km = ca.SX.sym("km", 2 * N_AXES)
    K_sx, c_sx = ca.SX(N_AXES, 2), ca.SX(N_AXES, 1)
    ks, ms = sp.Symbol("k", real=True), sp.Symbol("m", positive=True)
    wsyms = sp.symbols("q1 q2 r", positive=True)
    stable = riccati_stable_form(ks, ms, *wsyms)
    for i in range(N_AXES):
        k_i, m_i = km[i], km[N_AXES + i]
        conv_axis = SympyToCasadi({ks: k_i, ms: m_i, **dict(zip(wsyms, (q1, q2, r),
                                                               strict=True))})
        K_sx[i, 0] = conv_axis(stable.K[0])
        K_sx[i, 1] = conv_axis(stable.K[1])
        # optimized damping c = sqrt(k m) (derive/damping.py); none where k <= 0
        c_sx[i] = ca.if_else(k_i > 0, ca.sqrt(ca.fmax(k_i, 0) * m_i), 0)
    K_fn = ca.Function("maglev_axis_gains", [km, p], [K_sx, c_sx])
    plant_qf = ca.Function("maglev_axis_plant_qf", [q_sx, fl, fd, fprop, p],
                           [ca.vertcat(k_diag, m_diag)])
    xs = ca.SX.sym("x_s", n_x)
    fprop_s = ca.SX.sym("F_prop")
    lift_fn = ca.Function("maglev_array_forces", [x, p], [cm.lift, cm.drag])
    fl_t, fd_t = lift_fn(xs, p)
    q_of_x = ca.vertcat(*[xs[cv.STATE_INDEX[s]] for s in Q_STATES])
    plant = ca.Function("maglev_axis_plant", [xs, fprop_s, p],
                        [plant_qf(q_of_x, fl_t, fd_t, fprop_s, p)])
    io["array_forces"] = {"x": xs, "p": p}, {"lift": fl_t, "drag": fd_t}
    K_mag = ca.SX(5, 5)
    K_oth = ca.SX(5, 5)
    for i in range(5):
        for j in range(5):
            K_mag[i, j] = conv_k(sf.K[i, j])
            K_oth[i, j] = conv_k(sf.K_other[i, j])
    stiff_qf = ca.Function("maglev_stiffness_qf", [q_sx, fl, fd, fprop, p], [K_mag, K_oth])
    io["stiffness"] = ({"x": xs, "F_prop": fprop_s, "p": p},
                       dict(zip(("K_magnetic", "K_other"),
                                stiff_qf(q_of_x, fl_t, fd_t, fprop_s, p), strict=True)))
    km_mx = plant(xt_mx, ut_mx[0], p_mx)
    K_mx, c_mx = K_fn(km_mx, p_mx)
    io["lqr_gains"] = {"v": v_mx, "p": p_mx}, {"K": K_mx, "c_damping": c_mx}
    io["axis_plants"] = {"v": v_mx, "p": p_mx}, {"k": km_mx[:N_AXES], "m": km_mx[N_AXES:]}
    return K_fn, xs, fprop_s, lift_fn


def _control_io(cm: CasadiModel, K_fn: ca.Function, io: dict) -> ca.Function:
    """The per-tick controllers and maglev_axis_gains into ``io``; the axis rates' function."""
    x, p = cm.x, cm.p
    n_x = x.shape[0]
    # --- per-tick controllers on the axis coordinates a = (y, z, phi, theta, psi): the gains
    # and the reference come from the schedule (maglev_trim, maglev_lqr_gains or
    # maglev_axis_plants + maglev_axis_gains), computed once per speed, not at every tick.
    rates_fn = ca.Function("maglev_axis_rates", [x], [
        ca.vertcat(*[cm.xdot[cv.STATE_INDEX[s]] for s in Q_STATES])])
    x_c = ca.SX.sym("x", n_x)
    K_in, c_in, a_ref_in = ca.SX.sym("K", N_AXES, 2), ca.SX.sym("c", N_AXES), \
        ca.SX.sym("a_ref", N_AXES)
    a_c = ca.vertcat(*[x_c[cv.STATE_INDEX[s]] for s in Q_STATES])
    adot = rates_fn(x_c)
    io["lqr_control"] = ({"x": x_c, "K": K_in, "a_ref": a_ref_in, "p": p},
                         {"u_gen": -(K_in[:, 0] * (a_c - a_ref_in) + K_in[:, 1] * adot)})
    io["damping_control"] = {"x": x_c, "c_damping": c_in, "p": p}, {"u_gen": -c_in * adot}
    Kp_in, Kr_in = ca.SX.sym("K_pos", N_AXES, N_AXES), ca.SX.sym("K_rate", N_AXES, N_AXES)
    io["coupled_control"] = ({"x": x_c, "K_pos": Kp_in, "K_rate": Kr_in, "a_ref": a_ref_in,
                              "p": p},
                             {"u_gen": -(Kp_in @ (a_c - a_ref_in) + Kr_in @ adot)})
    k_in, m_in = ca.SX.sym("k", N_AXES), ca.SX.sym("m", N_AXES)
    io["axis_gains"] = ({"k": k_in, "m": m_in, "p": p},
                        dict(zip(("K", "c_damping"), K_fn(ca.vertcat(k_in, m_in), p),
                                 strict=True)))
    return rates_fn


def _allocation_io(model: CarriageModel, p: ca.SX, io: dict) -> tuple[ca.SX, ca.SX | None]:
    """maglev_allocate and maglev_effectiveness into ``io``; E and, with normal actuators,
    its pseudo-inverse."""
    # --- allocation: T = E^T (E E^T)^-1 from the array positions in p (E E^T can be singular
    # with forces along the normals: the pseudoinverse by iterated Tikhonov then)
    u_gen = ca.SX.sym("u_gen", N_AXES)
    E = _effectiveness(model, p)
    normal = any(NORMAL_AXIS in comps for _, comps in model.structure.arrays)
    T_normal = _pseudo_inverse(E) if normal else None
    forces = T_normal @ u_gen if T_normal is not None else E.T @ ca.solve(E @ E.T, u_gen)
    io["allocate"] = {"u_gen": u_gen, "p": p}, {"F_arrays": forces}
    io["effectiveness"] = {"p": p}, {"E": E}
    return E, T_normal


def _closed_loop_io(cm: CasadiModel, dynamics: ca.Function, rates_fn: ca.Function, E: ca.SX,
                    T_normal: ca.SX | None, io: dict) -> None:
    """maglev_gaps, maglev_closed_loop and maglev_allocation_matrix into ``io``."""
    x, p = cm.x, cm.p
    n_x = x.shape[0]
    normal = T_normal is not None
    # --- the closed loop's right-hand side, with the allocation matrix T as an input:
    # maglev_simulate computes T once (maglev_allocation_matrix) and calls this four times per
    # RK4 step, so one copy of the model's code stays in the instruction cache and nothing
    # that depends on p alone is recomputed at every stage
    F_prop = ca.SX.sym("F_prop")
    # full 5 x 5 gain matrices: diagonal for the per-axis designs, full for the coupled LQR
    K_pos, K_rate = ca.SX.sym("K_pos", N_AXES, N_AXES), ca.SX.sym("K_rate", N_AXES, N_AXES)
    a_ref = ca.SX.sym("a_ref", N_AXES)
    x0 = ca.SX.sym("x", n_x)
    T_in = ca.SX.sym("T", E.shape[1], N_AXES)
    with casadi_rewriting_off():  # keep the model's shared reciprocals (sympy_casadi)
        a_cl = ca.vertcat(*[x0[cv.STATE_INDEX[s]] for s in Q_STATES])
        u_cl = ca.vertcat(F_prop, T_in @ -(K_pos @ (a_cl - a_ref) + K_rate @ rates_fn(x0)))
        # contact is judged at each face's closest corner, not its centre
        gaps_fn = ca.Function("maglev_gaps", [x, p], [cm.contact_gaps])
        io["gaps"] = {"x": x, "p": p}, {"gaps": cm.contact_gaps}
        io["closed_loop"] = ({"x": x0, "F_prop": F_prop, "K_pos": K_pos, "K_rate": K_rate,
                              "a_ref": a_ref, "T": T_in, "p": p},
                             {"xdot": dynamics(x0, u_cl, p), "u": u_cl, "gaps": gaps_fn(x0, p)})
        io["allocation_matrix"] = ({"p": p}, {
            "T": T_normal if normal else E.T @ ca.solve(E @ E.T, ca.SX.eye(N_AXES))})



def _sensor_io(model: CarriageModel, p: ca.SX, io: dict) -> None:
    """maglev_gap_reading and maglev_imu_reading into ``io``: derive/sensors.py's measurement
    equations of one sensor, its geometry an input (the sensor set is the caller's)."""
    n_x = len(cv.STATES)
    xs = sp.Matrix(sp.symbols(" ".join(cv.STATE_NAMES), real=True))
    ds = sp.Matrix(sp.symbols(" ".join(f"{n}_dot" for n in cv.STATE_NAMES), real=True))
    bs, ns = sp.Matrix(sp.symbols("b0:3", real=True)), sp.Matrix(sp.symbols("n0:3", real=True))
    g0, g = sp.Symbol("g0", real=True), sp.Symbol("g", real=True)
    x, xdot = ca.SX.sym("x", n_x), ca.SX.sym("xdot", n_x)
    point, normal, nominal = ca.SX.sym("point", 3), ca.SX.sym("normal", 3), ca.SX.sym("g0")
    R = model.R.xreplace(dict(zip(model.x, xs, strict=True)))
    conv = SympyToCasadi({**_pairs(xs, x), **_pairs(ds, xdot), **_pairs(bs, point),
                          **_pairs(ns, normal), g0: nominal,
                          g: p[model.structure.param_names.index("vehicle.gravity")]})
    reading = conv(gap_reading(GapSensorSymbols(bs, ns, g0), xs[cv.POSITION, 0], R))
    io["gap_reading"] = ({"x": x, "point": point, "normal": normal, "nominal_gap": nominal},
                         {"reading": reading, "H": ca.jacobian(reading, x)})
    gyro = x[cv.RATES]
    accel = conv(accelerometer_reading(bs, R, xs[cv.VELOCITY, 0], xs[cv.RATES, 0],
                                       ds[cv.VELOCITY, 0], ds[cv.RATES, 0], g))
    both = ca.vertcat(gyro, accel)
    io["imu_reading"] = ({"x": x, "xdot": xdot, "point": point, "p": p},
                         {"gyro": gyro, "specific_force": accel, "H_x": ca.jacobian(both, x),
                          "H_xdot": ca.jacobian(both, xdot)})


def _function(spec: FunctionSpec, inputs: dict, outputs: dict) -> ca.Function:
    """The CasADi Function of ``spec``: its inputs the symbols ``inputs`` holds of their
    names, its outputs the expressions ``outputs`` holds of theirs (every one, no other)."""
    if (set(inputs), set(outputs)) != (set(spec.inputs), set(spec.outputs)):
        raise ValueError(f"{spec.name}: inputs {sorted(inputs)} and outputs {sorted(outputs)}, "
                         f"the table has {sorted(spec.inputs)} and {sorted(spec.outputs)}")
    return ca.Function(PREFIX + spec.name, [inputs[n] for n in spec.inputs],
                       [outputs[n] for n in spec.outputs], list(spec.inputs),
                       list(spec.outputs))


def _stiffness_parts(model: CarriageModel, base: dict, xs: ca.SX, fprop: ca.SX, p: ca.SX,
                     array_forces: ca.Function) -> ca.Function:
    """maglev_stiffness_parts(x, F_prop, p): derive.linearize.stiffness_parts (the product
    rule's exact split of K_st0 + K_other) at the pose of x, with the array forces at x."""
    split = stiffness_parts(model.structure)
    q_sx = ca.SX.sym("q", 5)
    fl, fd = ca.SX.sym("FL", len(model.arrays)), ca.SX.sym("FD", len(model.arrays))
    fp = ca.SX.sym("Fp")
    conv = SympyToCasadi({**base, **_pairs(split.q, q_sx), **_pairs(split.lift_sym, fl),
                          **_pairs(split.drag_sym, fd), split.f_prop: fp})
    mats = []
    for name in STIFFNESS_PARTS:
        K = ca.SX(5, 5)
        for i in range(5):
            for j in range(5):
                K[i, j] = conv(split.parts[name][i, j])
        mats.append(K)
    parts_qf = ca.Function("maglev_stiffness_parts_qf", [q_sx, fl, fd, fp, p], mats)
    fl_x, fd_x = array_forces(xs, p)
    q_of_x = ca.vertcat(*[xs[cv.STATE_INDEX[s]] for s in Q_STATES])
    return ca.Function("maglev_stiffness_parts", [xs, fprop, p],
                       list(parts_qf(q_of_x, fl_x, fd_x, fprop, p)),
                       ["x", "F_prop", "p"], list(STIFFNESS_PARTS))


def _finished(fn: ca.Function) -> ca.Function:
    """The same function with dense outputs (firmware indexes them with the header's macros)
    and, for SX, CasADi's common subexpression elimination: SymPy's expanded expressions
    repeat products that SymPyToCasadi's memo cannot see as shared (about 13% of the
    dynamics' operations)."""
    sx = fn.is_a("SXFunction")
    if not sx and all(fn.sparsity_out(i).is_dense() for i in range(fn.n_out())):
        return fn
    sym = ca.SX.sym if sx else ca.MX.sym
    ins: list[Any] = [sym(fn.name_in(i), fn.sparsity_in(i)) for i in range(fn.n_in())]
    with casadi_rewriting_off():  # rebuilding the nodes must not undo the shared reciprocals
        outs = [ca.densify(o) for o in fn.call(ins)]
        return ca.Function(fn.name(), ins, outs, fn.name_in(), fn.name_out(), {"cse": sx})


def _prepared(fn: ca.Function, n_state: int, name: str) -> tuple[ca.Function, ca.Function]:
    """``fn`` split in two by CasADi's extract_parametric: what depends only on its inputs
    after the first ``n_state`` (those constant over a simulation: for maglev_closed_loop F_prop,
    the gains, the reference, T and p; for maglev_dynamics p), computed once
    (``NAME_prepare``, output ``name``), and the rest at every stage (``NAME_prepared``): the
    field B0's exp and sin and the inverse inertia's divisions, among others, leave the stage."""
    ins = fn.sx_in()
    states, run = ins[:n_state], ins[n_state:]
    with casadi_rewriting_off():
        outs = fn.call(ins)
        rest, syms, values = ca.extract_parametric(outs, run, {"extract_trivial": True})
        c = ca.vertcat(*syms)
        prepare = ca.Function(f"{fn.name()}_prepare", run, [ca.vertcat(*values)],
                              fn.name_in()[n_state:], [name], {"cse": True})
        prepared = ca.Function(f"{fn.name()}_prepared", [*states, c], rest,
                               [*fn.name_in()[:n_state], name], fn.name_out(), {"cse": True})
    return prepare, prepared


def _rk4_step(closed_loop: ca.Function, allocation_matrix: ca.Function) -> ca.Function:
    """One RK4 step of the closed loop (MX): T once, then ``closed_loop`` at the four stages.

    The linear axis feedback is evaluated at every stage, so the step integrates the
    continuous closed loop x' = f(x, u(x)) to fourth order. Calling the SX right-hand side
    (instead of inlining it four times) keeps the step's code a quarter of the size. The
    step's inputs are x, dt and the closed loop's other inputs but T (p when it has one), so
    the same construction serves the run-time-parameter and the baked functions.
    """
    run_names = [n for n in closed_loop.name_in() if n not in ("x", "T")]
    x, dt = ca.MX.sym("x", closed_loop.sparsity_in("x")), ca.MX.sym("dt")
    run = {n: ca.MX.sym(n, closed_loop.sparsity_in(n)) for n in run_names}
    T = ca.MX(allocation_matrix.call([run[n] for n in allocation_matrix.name_in()])[0])

    def stage(xx: ca.MX) -> dict[str, ca.MX]:
        return closed_loop.call({**run, "x": xx, "T": T})

    s1 = stage(x)
    k1 = s1["xdot"]
    k2 = stage(x + dt / 2 * k1)["xdot"]
    k3 = stage(x + dt / 2 * k2)["xdot"]
    k4 = stage(x + dt * k3)["xdot"]
    return ca.Function("maglev_rk4_step", [x, dt, *run.values()],
                       [x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4), s1["u"]],
                       ["x", "dt", *run_names], ["x_next", "u"])


# The trim's unknowns z6 (as derive.trim): the pose q (Q_STATES), then the propulsion force.
_F_PROP = len(cv.Q_STATES)


def _trim_state(v: ca.SX, z6: ca.SX) -> ca.SX:
    """The 12-state vector at the pose q of z6 moving at (v, 0, 0) inertial (as derive.trim)."""
    at = {s: z6[i] for i, s in enumerate(cv.Q_STATES)}
    phi, theta, psi = at["phi"], at["theta"], at["psi"]
    cf, sf, ct, st, cp, sp_ = (ca.cos(phi), ca.sin(phi), ca.cos(theta), ca.sin(theta),
                               ca.cos(psi), ca.sin(psi))
    # body velocity R^T (v, 0, 0): v times the first row of R = Rz Ry Rx
    vel = v * ca.vertcat(cp * ct, cp * st * sf - sp_ * cf, cp * st * cf + sp_ * sf)
    at.update(zip(cv.STATE_NAMES[cv.VELOCITY], ca.vertsplit(vel), strict=True))
    return ca.vertcat(*(at.get(s, 0) for s in cv.STATE_NAMES))


# Iterated Tikhonov for the pseudoinverse, in its residual form: K = E^T (E E^T + d I)^-1,
# T_1 = K, T_k+1 = T_k + K (I - E T_k), with d = PINV_REGULARIZATION trace(E E^T). A singular
# value s of E is recovered to a fraction 1 - (d / (s^2 + d))^k and a zero one (a direction no
# array force reaches) keeps T's range that of pinv. With the paper's normal actuators
# (s_min^2 = 0.135, trace 6.41) each step gains a factor 4.7e-3: 8 steps reach 5e-15 of
# numpy's pinv; a geometry with s^2 under about d / 8 loses that direction (no 1/s forces).
PINV_REGULARIZATION, PINV_STEPS = 1e-4, 8


def _pseudo_inverse(E: ca.SX) -> ca.SX:
    """The Moore-Penrose pseudoinverse of E (5 x n) by PINV_STEPS steps of iterated Tikhonov:
    derive.allocation.minimum_norm_allocation's T, E rank deficient or not."""
    eye = ca.SX.eye(E.shape[0])
    K = E.T @ ca.solve(E @ E.T + PINV_REGULARIZATION * ca.trace(E @ E.T) * eye, eye)
    T = K
    for _ in range(PINV_STEPS - 1):
        T = T + K @ (eye - E @ T)
    return T


def _effectiveness(model: CarriageModel, p: ca.SX) -> ca.SX:
    """E (5 x arrays' forces) from the array positions (and normals, for forces along them)
    in p: the columns of derive.geometry.control_effectiveness."""
    cols = []
    names = model.structure.param_names
    for name, comps in model.structure.arrays:
        pos, normal = (ca.vertcat(*[p[names.index(f"arrays.{name}.{key}.{c}")] for c in "xyz"])
                       for key in ("position", "normal"))
        for ax in comps:
            d = normal if ax == NORMAL_AXIS else ca.DM(np.eye(3)["xyz".index(ax)])
            mom = ca.cross(pos, d)
            cols.append(ca.vertcat(d[1], d[2], mom))
    return ca.horzcat(*cols)


def bake_all(fns: tuple[ca.Function, ...], p_value: np.ndarray) -> list[ca.Function]:
    """Every function with a p input baked (`bake`); the RK4 step is rebuilt around the baked
    right-hand side so that it calls the baked model rather than carrying p as a constant
    argument."""
    baked = {f.name(): bake(f, p_value) if "p" in f.name_in() else f
             for f in fns if f.name() != "maglev_rk4_step"}
    baked["maglev_rk4_step"] = _rk4_step(baked["maglev_closed_loop"],
                                         baked["maglev_allocation_matrix"])
    return [baked[f.name()] for f in fns]


def bake(fn: ca.Function, p_value: np.ndarray) -> ca.Function:
    """The same function with its last input (p) replaced by constants.

    SX functions are re-expanded so that CasADi folds the constants into the expressions; MX
    functions (those calling the trim Newton solver) get p as a constant argument.
    """
    sx = fn.is_a("SXFunction")
    sym = ca.SX.sym if sx else ca.MX.sym
    ins: list[Any] = [sym(fn.name_in(i), fn.sparsity_in(i)) for i in range(fn.n_in() - 1)]
    outs = fn.call([*ins, ca.DM(p_value)])
    return ca.Function(fn.name(), ins, outs, fn.name_in()[:-1], fn.name_out(), {"cse": sx})
