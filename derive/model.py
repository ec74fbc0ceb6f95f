"""The nonlinear 12-state carriage model, symbolic in every parameter.

Assembles the rigid-body equations (eqs 1-2), the Inductrack force law (eqs 3-4, with the
circuits' first-order lag of derive/circuit_lag.py for model.circuit_dynamics = "first-order")
and the array geometry (eqs 8-12) into xdot = f(x, u, p). The model depends on the parameter
values only through the symbols of ``p``; it depends on the *structure* of the carriage (which
arrays exist, which control force components each has, the force law and the circuit
dynamics), so a structure is its cache key.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import lru_cache

import sympy as sp

from maglevgen.derive import conventions as cv
from maglevgen.derive.circuit_lag import (
    distributed_lag,
    drag_rate_per_circuit,
    lift_rate_per_circuit,
)
from maglevgen.derive.distributed import distributed_load, face_axes
from maglevgen.derive.geometry import (
    ArraySymbols,
    array_gap,
    array_gap_rate,
    array_speed,
    array_wrench,
    control_direction,
)
from maglevgen.derive.inductrack import drag_per_circuit, halbach_surface_field, lift_per_circuit
from maglevgen.derive.rigid_body import body_accelerations, euler_rates, rotation_body_to_inertial
from maglevgen.derive.structure import (
    Structure,
    box_principal_moments,
    explicit_inertia,
    input_names_of,
)

__all__ = ["CarriageModel", "Structure", "build_model", "inertia_cg_matrix", "input_names_of"]


def symbol_name(param_name: str) -> str:
    """A valid identifier for a dotted parameter name: vehicle.mass -> vehicle_mass."""
    return re.sub(r"[^A-Za-z0-9_]", "_", param_name)


@dataclass(frozen=True)
class CarriageModel:
    """The symbolic model, kept in layers joined by intermediate symbols.

    xdot = [kinematics(x); accelerations(x, W, p)], W = wrench(x, u, F_L, F_D, p),
    F_L = lift(x, p), F_D = drag(x, p). Keeping the layers apart (instead of one expanded
    expression) keeps every expression small, so differentiating, lambdifying and converting to
    CasADi stay fast; ``compose`` gives the single expression when one is wanted.
    """

    structure: Structure
    p: sp.Matrix  # parameter symbols, in Structure.param_names order
    x: sp.Matrix  # 12 states, conventions.STATES order
    u: sp.Matrix  # inputs: propulsion, then the array control force components
    input_names: tuple[str, ...]
    arrays: tuple[ArraySymbols, ...]
    wavenumber: sp.Expr
    B0: sp.Expr
    R: sp.Matrix
    gaps: sp.Matrix  # exact face-centre gap of each array, in (x, p)
    contact_gaps: sp.Matrix  # gap of each face's closest corner, in (x, p): contact
    load_factor: sp.Matrix  # array force / (N eq 3 at the centre gap): 1 for "point"
    arms: tuple[sp.Matrix, ...]  # point of action of each array's force, body axes, in (x, p)
    gap_rates: sp.Matrix  # rate of each face-centre gap along the motion, in (x, p)
    array_speeds: sp.Matrix  # along-track speed of each array face centre, in (x, p)
    lift: sp.Matrix  # total lift of each array (all its circuits), in (x, p)
    drag: sp.Matrix  # total drag of each array, in (x, p)
    # (first-order circuit dynamics: both include the rate terms, zero at rest)
    speed_sym: sp.Matrix  # s_i standing for array_speeds[i] in lift_at_speed / drag_at_speed
    lift_at_speed: sp.Matrix  # lift in (x, s, p)
    drag_at_speed: sp.Matrix  # drag in (x, s, p)
    # the lag's spread lift and drag of each array (G_L_0.., G_D_0..; zero without the lag),
    # whose couple about the face's across axis enters ``wrench`` through spread_sym: a layer
    # of its own, like lift and drag, so that the wrench's derivatives stay small
    spread: sp.Matrix  # in (x, p)
    spread_at_speed: sp.Matrix  # in (x, s, p)
    spread_sym: sp.Matrix  # G standing for spread[i] in ``wrench``
    arm_sym: sp.Matrix  # A standing for the stacked ``arms`` in ``wrench`` (a layer too)
    lift_sym: sp.Matrix  # F_L_i standing for lift[i] in ``wrench``
    drag_sym: sp.Matrix  # F_D_i standing for drag[i] in ``wrench``
    wrench: sp.Matrix  # (force, moment about O), body axes, in (x, u, F_L, F_D, G, A, p)
    wrench_sym: sp.Matrix  # W standing for ``wrench`` in ``accelerations``
    kinematics: sp.Matrix  # (R v, Euler rates), in x
    accelerations: sp.Matrix  # (v_dot, omega_dot), eqs 1-2, in (x, W, p)

    def param(self, name: str) -> sp.Symbol:
        return self.p[self.structure.param_names.index(name)]

    def vec(self, name: str) -> sp.Matrix:
        return sp.Matrix([self.param(f"{name}.{c}") for c in "xyz"])

    def compose(self) -> sp.Matrix:
        """xdot as one expression in (x, u, p) (large: prefer the layers)."""
        sub = dict(zip(self.lift_sym, self.lift, strict=True))
        sub.update(zip(self.drag_sym, self.drag, strict=True))
        sub.update(zip(self.spread_sym, self.spread, strict=True))
        sub.update(zip(self.arm_sym, sp.Matrix.vstack(*self.arms), strict=True))
        wrench = self.wrench.xreplace(sub)
        acc = self.accelerations.xreplace(dict(zip(self.wrench_sym, wrench, strict=True)))
        return sp.Matrix.vstack(self.kinematics, acc)


@lru_cache(maxsize=8)
def build_model(structure: Structure) -> CarriageModel:
    """Derive xdot = f(x, u, p) for a structure (eqs 1-4, 8-12)."""
    p = sp.Matrix([sp.Symbol(symbol_name(n), real=True) for n in structure.param_names])
    sym = dict(zip(structure.param_names, p, strict=True))

    def vec(prefix: str) -> sp.Matrix:
        return sp.Matrix([sym[f"{prefix}.{c}"] for c in "xyz"])

    x = sp.Matrix(sp.symbols(" ".join(cv.STATE_NAMES), real=True))
    pos, (phi, theta, psi) = x[cv.POSITION, 0], x[cv.ATTITUDE]
    vel, omega = x[cv.VELOCITY, 0], x[cv.RATES, 0]
    input_names = input_names_of(structure)
    u = sp.Matrix(sp.symbols(" ".join(input_names), real=True))

    m, g = sym["vehicle.mass"], sym["vehicle.gravity"]
    inertia = inertia_cg_matrix(sym.__getitem__, structure.param_names)
    r_G = vec("vehicle.cg_offset")
    k = 2 * sp.pi / sym["halbach.wavelength"]
    B0 = halbach_surface_field(sym["halbach.remanence"], sym["halbach.thickness"],
                               sym["halbach.magnets_per_wavelength"], k)
    w, L, Rc = sym["halbach.width"], sym["circuit.inductance"], sym["circuit.resistance"]
    R = rotation_body_to_inertial(phi, theta, psi)

    arrays, gaps, contact, factors, arms, speeds, lifts, drags = [], [], [], [], [], [], [], []
    gap_rates, spread_lifts, spread_drags, across = [], [], [], []
    lagging = structure.circuit_dynamics == "first-order"
    distributed = structure.array_force == "distributed"
    ex = sp.Matrix([1, 0, 0])
    speed_sym = sp.Matrix(sp.symbols(f"s0:{len(structure.arrays)}", real=True))
    for (name, _comps), s in zip(structure.arrays, speed_sym, strict=True):
        a = ArraySymbols(name, vec(f"arrays.{name}.position"), vec(f"arrays.{name}.normal"),
                         sym[f"arrays.{name}.nominal_gap"], sym[f"arrays.{name}.circuits"])
        gap = array_gap(a, pos, R)
        gap_rate = array_gap_rate(a, R, vel, omega)
        load = distributed_load(a.normal, R, gap, k, w, sym["circuit.pitch"], a.circuits)
        if distributed:
            factor, arm = load.factor, a.position + load.offset
        else:  # the paper's: eq 3 with the centre gap, at the face centre
            factor, arm = sp.S.One, a.position
        arrays.append(a)
        gaps.append(gap)
        gap_rates.append(gap_rate)
        contact.append(load.closest_gap)
        factors.append(factor)
        arms.append(arm)
        speeds.append(array_speed(a, R, vel, omega))
        lift = a.circuits * factor * lift_per_circuit(B0, w, k, L, Rc, gap, s)
        drag = a.circuits * factor * drag_per_circuit(B0, w, k, L, Rc, gap, s)
        spread = [sp.S.Zero, sp.S.Zero]
        if lagging:  # eq 3's term unchanged, plus the rate term (zero at rest): trim is eq 3's
            if distributed:
                lag = distributed_lag(a.normal, R, omega, load.alpha, load.beta, gap_rate, k, w,
                                      sym["circuit.pitch"], a.circuits)
                rho = lag.log_rate
                spread = [a.circuits * factor * f(B0, w, k, L, Rc, gap, s, lag.spread)
                          for f in (lift_rate_per_circuit, drag_rate_per_circuit)]
            else:
                rho = -k * gap_rate
            lift = lift + a.circuits * factor * lift_rate_per_circuit(B0, w, k, L, Rc, gap, s,
                                                                      rho)
            drag = drag + a.circuits * factor * drag_rate_per_circuit(B0, w, k, L, Rc, gap, s,
                                                                      rho)
        lifts.append(lift)
        drags.append(drag)
        spread_lifts.append(spread[0])
        spread_drags.append(spread[1])
        across.append(face_axes(a.normal)[1])

    n = len(arrays)
    at_speed = dict(zip(speed_sym, speeds, strict=True))
    lift_s, drag_s = sp.Matrix(lifts), sp.Matrix(drags)
    spread_s = sp.Matrix([*spread_lifts, *spread_drags])
    lift_sym = sp.Matrix(sp.symbols(f"F_L0:{n}", real=True))
    drag_sym = sp.Matrix(sp.symbols(f"F_D0:{n}", real=True))
    spread_sym = sp.Matrix(sp.symbols(f"G_L0:{n} G_D0:{n}", real=True))
    # the circuits' rate forces spread along the face: a couple about its across axis,
    # (R e_t) x (spread lift n - spread drag x), inertial
    couples = [(R * e_t).cross(gl * a.normal - gd * ex) if lagging and distributed
               else sp.zeros(3, 1)
               for a, e_t, gl, gd in zip(arrays, across, spread_sym[:n], spread_sym[n:],
                                         strict=True)]
    arm_sym = sp.Matrix(sp.symbols(" ".join(f"A{i}_{c}" for i in range(n) for c in "xyz"),
                                   real=True))
    arm_of = [arm_sym[3 * i:3 * i + 3, 0] for i in range(n)]
    wrench = _wrench(structure, arrays, arm_of, u, lift_sym, drag_sym, R, m, g, r_G,
                     vec("operation.propulsion_point"), couples)
    wrench_sym = sp.Matrix(sp.symbols("W_Fx W_Fy W_Fz W_Mx W_My W_Mz", real=True))
    v_dot, omega_dot = body_accelerations(m, inertia, r_G, vel, omega,
                                          wrench_sym[0:3, 0], wrench_sym[3:6, 0])
    kinematics = sp.Matrix.vstack(R * vel, euler_rates(phi, theta, omega))
    return CarriageModel(structure, p, x, u, input_names, tuple(arrays), k, B0, R,
                         sp.Matrix(gaps), sp.Matrix(contact), sp.Matrix(factors), tuple(arms),
                         sp.Matrix(gap_rates), sp.Matrix(speeds),
                         lift_s.xreplace(at_speed), drag_s.xreplace(at_speed), speed_sym,
                         lift_s, drag_s, spread_s.xreplace(at_speed), spread_s, spread_sym,
                         arm_sym,
                         lift_sym, drag_sym, wrench, wrench_sym, kinematics,
                         sp.Matrix.vstack(v_dot, omega_dot))


def _wrench(structure: Structure, arrays: list[ArraySymbols], arms: list[sp.Matrix],
            u: sp.Matrix, lift: sp.Matrix, drag: sp.Matrix, R: sp.Matrix, m: sp.Expr,
            g: sp.Expr, r_G: sp.Matrix, a_prop: sp.Matrix, couples: list[sp.Matrix]
            ) -> sp.Matrix:
    """Total external force and moment about O, body axes (eqs 8-12 come out of this sum).

    Lift acts along the track normal n_i and drag along -x (inertial), plus each array's
    couple (inertial; the circuit lag's spread along the face, zero otherwise); gravity at the
    CG; propulsion along the track at ``a_prop``; control components along body axes at a_i
    (eqs 22-23), or along the array's normal n_i (control.actuators = "normal").
    """
    ex = sp.Matrix([1, 0, 0])
    force_in, moment_in = sp.zeros(3, 1), sp.zeros(3, 1)
    for a, arm, fl, fd, couple in zip(arrays, arms, lift, drag, couples, strict=True):
        f, mo = array_wrench(a, fl, fd, R, arm)
        force_in += f
        moment_in += mo + couple
    f_prop = u[0] * ex
    force_in += f_prop
    moment_in += (R * a_prop).cross(f_prop)
    f_grav = sp.Matrix([0, 0, -m * g])
    force_in += f_grav
    moment_in += (R * r_G).cross(f_grav)
    force_b, moment_b = R.T * force_in, R.T * moment_in
    j = 1
    for a, (_name, comps) in zip(arrays, structure.arrays, strict=True):
        for ax in comps:
            fc = u[j] * control_direction(ax, a.normal)
            force_b += fc
            moment_b += a.position.cross(fc)
            j += 1
    return sp.Matrix.vstack(force_b, moment_b)


_INERTIA_KEYS = (("xx", "xy", "xz"), ("xy", "yy", "yz"), ("xz", "yz", "zz"))


def inertia_cg_matrix(param: Callable[[str], sp.Expr], param_names: Sequence[str]
                      ) -> sp.Matrix:
    """I about the CG, body axes: the tensor's entries where the parameter vector holds them,
    else the uniform box of the mass, length, width and height (vehicle.inertia_cg = "box"),
    so that the inertia follows the mass."""
    if explicit_inertia(param_names):
        return sp.Matrix(3, 3, lambda i, j: param("vehicle.inertia_cg." + _INERTIA_KEYS[i][j]))
    return sp.diag(*box_principal_moments(*(param(f"vehicle.{k}") for k in
                                            ("mass", "length", "width", "height"))))
