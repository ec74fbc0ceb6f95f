"""The numbers `maglevgen trim`, `gains` and `envelope` print, as plain data (the report and
SUMMARY.md read the same): no argument parsing, no printing.

Every number printed for the carriage comes from the compiled library generated from the
derivation (`maglev_trim`, `maglev_array_forces`, `maglev_stiffness`, `maglev_axis_plants`,
`maglev_lqr_gains`, `maglev_jacobians`, `maglev_allocation_matrix`; maglevgen.control.operating),
the
same C the firmware embeds; numpy and SciPy only assemble and solve small dense problems from
them (eigenvalues, the coupled LQR's CARE, the designs' costs). The comparison columns are
references, labelled as such: the paper's printed forms (eqs 13-19, 31-32, SymPy), SciPy's
numerical LQR of each axis and the 50-digit closed form (mpmath).
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import sympy as sp

from maglevgen.analyses.envelope import DEFAULT_SPEEDS, compute_envelope
from maglevgen.carriage import DerivedCarriage, stiffness_rows
from maglevgen.control.carriage_plant import Plant, lift_off_speed
from maglevgen.control.operating import (
    N_AXES,
    REDUCED_STATES,
    AxisGains,
    OperatingPoint,
    Weights,
    checked_accelerating_trim,
    checked_trim,
    compare_designs,
    numerical_lqr,
    operating_point,
    speed_mode,
)
from maglevgen.controllers import controller as registered
from maglevgen.controllers import title as controller_title
from maglevgen.derive import conventions as cv
from maglevgen.derive.paper import paper_riccati
from maglevgen.derive.riccati import lqr_gain_mp, riccati_solution_mp
from maglevgen.derive.structure import input_names_of
from maglevgen.errors import InputError, NoTrimError
from maglevgen.infrastructure import progress

__all__ = ["AcceleratingMargin", "accelerating_margins", "displayed_gains", "embedded_gains",
           "gains_report", "pitch_paper_form", "stiffness_table", "trim_point", "trim_report"]


@dataclass(frozen=True)
class TrimPoint:
    """The trim at one speed and the array forces and stiffness there, from the C."""

    speed: float
    x: np.ndarray
    f_prop: float
    gaps: np.ndarray
    lift: np.ndarray
    drag: np.ndarray
    residual: float  # largest |acceleration| of maglev_dynamics at the trim
    K_magnetic: np.ndarray  # K_st0 (5 x 5)
    K_other: np.ndarray  # gravity and propulsion moments (5 x 5)
    acceleration: float = 0.0  # along-track acceleration of the trim [m/s^2]


def _speed(carriage: DerivedCarriage, speed: float | None) -> float:
    return float(carriage.params.operation.speed if speed is None else speed)


def _lift_off(plant: Plant) -> float:
    """The lowest speed with a trim (bisection on the C's trim up to envelope.v_max, or
    further where the carriage has no trim there: 4, 16, ... times it up to the first above
    1e4 m/s); inf when none."""
    return lift_off_speed(plant.lib, plant.p, plant.min_gap,
                          float(plant.params.envelope.v_max), v_limit=4e4)


def trim_point(plant: Plant, speed: float | None, acceleration: float = 0.0) -> TrimPoint:
    """The checked trim at ``speed`` (default operation.speed) and what the trim table shows;
    NoTrimError naming the lift-off speed when there is none. ``acceleration`` [m/s^2]: the
    accelerating trim (`checked_accelerating_trim`: eqs 1-2 with the d'Alembert load at the
    CG); its residual is the accelerations' departure from the translation at a."""
    carriage, lib = plant.carriage, plant.lib
    v = _speed(carriage, speed)
    p = carriage.p
    try:
        if not v > 0:
            raise NoTrimError(f"no trim at speed {v!r} m/s: operation.speed must be > 0")
        min_gap = carriage.params.track.min_gap
        x, f_prop, gaps = (checked_trim(lib, p, v, min_gap) if acceleration == 0 else
                           checked_accelerating_trim(lib, p, v, acceleration, min_gap))
    except NoTrimError as exc:
        # the checked trim's own pointer to `maglevgen trim` is dropped: this is what that
        # command prints, and the lift-off speed below says where a trim starts
        why = re.sub(r"; see `maglevgen trim[^`]*`", "", str(exc).split(": ", 1)[-1])
        v_off = _lift_off(plant) if v > 0 else float("nan")
        hint = f"; lift-off needs {v_off:.4g} m/s" if np.isfinite(v_off) else ""
        moving = f" accelerating at {acceleration:g} m/s^2" if acceleration else ""
        raise NoTrimError(f"no trim at speed {v:g} m/s{moving}: {why}{hint}") from None
    u = np.zeros(lib.function("maglev_dynamics").shapes_in[1][0])
    u[cv.PROPULSION_INPUT] = f_prop
    xdot = lib.function("maglev_dynamics")(x, u, p)[0].ravel()
    # the translation's R^T (a, 0, 0) (derive/trim.py)
    xdot[cv.VELOCITY] -= x[cv.VELOCITY] * (acceleration / v)
    acc = xdot[cv.KINETIC]
    lift, drag = (a.ravel() for a in lib.function("maglev_array_forces")(x, p))
    K_mag, K_oth = lib.function("maglev_stiffness")(x, f_prop, p)
    return TrimPoint(v, x, f_prop, gaps, lift, drag, float(np.max(np.abs(acc))), K_mag, K_oth,
                     float(acceleration))


@dataclass(frozen=True)
class AcceleratingMargin:
    """The accelerating trim beside the constant-speed one at a speed (the launch's reference:
    `trim_point` with and without the acceleration, from the C)."""

    speed: float  # [m/s]
    acceleration: float  # [m/s^2]
    pitch: float  # constant-speed trim pitch [rad]
    pitch_accelerating: float  # [rad]
    heave: float  # [m]
    heave_accelerating: float  # [m]
    gap: float  # smallest closest-corner gap at constant speed [m]
    gap_accelerating: float  # [m]
    gap_array: str  # the array with the smallest gap when accelerating
    f_prop: float  # [N]
    f_prop_accelerating: float  # [N]
    min_gap: float  # track.min_gap [m]

    @property
    def pitch_offset(self) -> float:
        """pitch_accelerating - pitch [rad]: nose down when the CG is above the thrust."""
        return self.pitch_accelerating - self.pitch

    @property
    def gap_margin(self) -> float:
        """gap_accelerating - track.min_gap [m]."""
        return self.gap_accelerating - self.min_gap

    def sentence(self) -> str:
        """One line (plain ASCII) for SUMMARY.md."""
        return (f"Accelerating trim at {self.speed:.4g} m/s and {self.acceleration:g} m/s^2 "
                f"(the launch's reference): pitch {self.pitch_accelerating * 1e3:+.3f} mrad "
                f"({self.pitch_offset * 1e3:+.3f} mrad from the constant-speed trim), smallest "
                f"corner gap {self.gap_accelerating * 1e3:.3f} mm (array {self.gap_array}; "
                f"{self.gap * 1e3:.3f} mm at constant speed; track.min_gap "
                f"{self.min_gap * 1e3:g} mm), F_prop {self.f_prop_accelerating:.4g} N.")


def accelerating_margins(plant: Plant, speeds: Sequence[float],
                         acceleration: float | None = None) -> list[AcceleratingMargin]:
    """`AcceleratingMargin` at each speed, at ``acceleration`` (default
    envelope.launch_acceleration)."""
    carriage = plant.carriage
    a = carriage.params.envelope.launch_acceleration if acceleration is None else acceleration
    names = list(carriage.params.arrays)
    heave, pitch = cv.STATE_INDEX["z"], cv.STATE_INDEX["theta"]
    out = []
    for v in speeds:
        still, moving = (trim_point(plant, v, acc) for acc in (0.0, a))
        i = int(np.argmin(moving.gaps))
        out.append(AcceleratingMargin(
            float(v), float(a), float(still.x[pitch]), float(moving.x[pitch]),
            float(still.x[heave]), float(moving.x[heave]), float(np.min(still.gaps)),
            float(moving.gaps[i]), names[i],
            still.f_prop, moving.f_prop, carriage.params.track.min_gap))
    return out


def stiffness_table(plant: Plant, speed: float | None):
    """Per-axis stiffness at the C's trim: derived K_st0 (and with gravity) beside eqs 13-19."""
    tp = trim_point(plant, speed)
    return stiffness_rows(plant.carriage.paper_stiffness_inputs(tp), tp.K_magnetic,
                          tp.K_magnetic + tp.K_other)


def pitch_paper_form(carriage: DerivedCarriage, tp: TrimPoint,
                     printed: float) -> dict[str, float | None]:
    """Eq 15's pitch stiffness as printed, with its net front force replaced by the sum of the
    arrays' stiffness contributions, and derived (K_st0's pitch entry from the C) [N m/rad].

    Eq 15 expands the front net force F_z3 - F_z1 - F_z2 as 0.06 F_z3 (1 + 2 k L_x theta): the
    printed K = 0.12 F_upper k L_x^2 = 2 k L_x^2 (0.06 F_upper) takes the net force's slope as
    2k times the net force. But each array's force F_i exp(-2 k gap_i) (eq 3) changes by
    -2k F_i per metre of its own gap, and pitch moves array i's gap by -n_z,i x_i theta, so its
    moment -x_i n_z,i F_i changes by 2k F_i n_z,i^2 x_i^2 theta whatever the sign of n_z,i:
    the lower arrays' stiffness adds to the upper arrays' instead of subtracting. With the sum
    K = 2k sum_i F_i n_z,i^2 x_i^2 (the arm L_x = |x_i| is right); what the derived value has
    beyond it are the moment arms turning with the carriage, the drag's gap slope at the
    arrays' heights and, with the distributed array force, the tilt across each face (eq 15
    is a point-force argument). ``printed``: eq 15 at this trim (`stiffness_rows`).
    """
    k = carriage.params.wavenumber
    arrays = list(carriage.params.arrays.values())
    x = np.array([a.position[0] for a in arrays])
    n_z = np.array([a.normal[2] for a in arrays])
    front = x > 0
    upper = float(np.sum((tp.lift * np.maximum(n_z, 0))[front]))
    return {
        "printed": float(printed),
        "sum_of_contributions": float(2 * k * np.sum(tp.lift * n_z**2 * x**2)),
        "derived": float(tp.K_magnetic[3, 3]),
        # eq 15's ratio (F_z3 - F_z1 - F_z2)/F_z3, printed 0.06, at this trim; None: no array
        # lifts from above in front of the centre of mass (eq 15's F_z3 does not exist)
        "net_front_ratio": (float(np.sum((tp.lift * n_z)[front])) / upper if upper > 0
                            else None),
    }


def trim_report(plant: Plant, speed: float | None, acceleration: float = 0.0) -> dict:
    """Everything `maglevgen trim` prints, as plain data; ``acceleration`` [m/s^2]: of the
    accelerating trim (`trim_point`)."""
    carriage = plant.carriage
    tp = trim_point(plant, speed, acceleration)
    kin = carriage.paper_stiffness_inputs(tp)
    rows = stiffness_rows(kin, tp.K_magnetic, tp.K_magnetic + tp.K_other)
    names = list(carriage.params.arrays)
    return {
        "speed": tp.speed,
        "acceleration": tp.acceleration,
        "params_sha256": carriage.loaded.sha256,
        "state": {s.name: float(v) for s, v in zip(cv.STATES, tp.x, strict=True)},
        "state_units": {s.name: s.unit for s in cv.STATES},
        "propulsion_force": tp.f_prop,
        "residual": tp.residual,
        "lift_off_speed": _lift_off(plant),
        "arrays": {n: {"gap": float(g), "lift": float(fl), "drag": float(fd)}
                   for n, g, fl, fd in zip(names, tp.gaps, tp.lift, tp.drag, strict=True)},
        "stiffness": {
            r.axis: {"unit": r.unit, "derived": r.derived_magnetic,
                     "derived_with_gravity": r.derived_total,
                     "paper_formula": plain_formula(sp.sympify(r.paper_formula)),
                     "paper": r.paper_value, "paper_relative_difference": r.relative_difference}
            for r in rows
        },
        "stiffness_matrix": tp.K_magnetic.tolist(),
        "paper_inputs": kin,
        "pitch_paper_form": pitch_paper_form(
            carriage, tp, next(r.paper_value for r in rows if r.axis == "pitch")),
    }


def plain_formula(expr: sp.Expr) -> str:
    """A SymPy product as a person writes it in plain text: the coefficient as a decimal, the
    factors separated by spaces, powers with ^ (eq 15's 0.12 F_upper k Lx^2, not SymPy's
    3*F_upper*Lx**2*k/25)."""
    coeff, rest = sp.sympify(expr).as_coeff_Mul()
    factors = []
    for f in sp.Mul.make_args(rest):
        base, exp = f.as_base_exp()
        factors.append(sp.sstr(base) + ("" if exp == 1 else f"^{sp.sstr(exp)}"))
    head = [] if coeff == 1 else [f"{float(coeff):g}"]
    return " ".join(head + factors)


def axis_gains(axis: str, k: float, m: float, K: np.ndarray, c: float,
               w: Weights) -> AxisGains:
    """One axis: the C's plant (k, m), closed-form gain K and damping c, beside SciPy's
    numerical LQR, the paper's eq 32 and the 50-digit closed form (references)."""
    A = np.array([[0.0, 1.0], [-k / m, 0.0]])
    B = np.array([[0.0], [1.0 / m]])
    K_num = numerical_lqr(A, B, np.diag([w.q1, w.q2]), np.array([[w.r]])).ravel()
    P = np.array(riccati_solution_mp(k, m, w.q1, w.q2, w.r).tolist(), dtype=float)
    _, Kp = paper_riccati(sp.Float(k, 30), sp.Float(m, 30))
    K_ref = np.array([float(v) for v in lqr_gain_mp(k, m, w.q1, w.q2, w.r)])
    return AxisGains(axis, k, m, A, B, P, np.asarray(K, dtype=float), K_num,
                     np.array([float(v) for v in Kp], dtype=float), K_ref,
                     float(c) if k > 0 else None)


def gains_report(plant: Plant, speed: float | None) -> dict:
    """Everything `maglevgen gains` prints, as plain data."""
    v = trim_point(plant, speed).speed  # the trim, or why there is none
    carriage, lib = plant.carriage, plant.lib
    w = Weights.of(carriage.params)
    op = operating_point(lib, carriage.p, v, carriage.params.track.min_gap, w)
    k, m = (a.ravel() for a in lib.function("maglev_axis_plants")(v, carriage.p))
    gains = [axis_gains(axis, float(k[i]), float(m[i]), op.K[i], op.c_damping[i], w)
             for i, axis in enumerate(cv.AXES)]
    Q, R = (w.q1, w.q2), w.r
    cc = coupled_comparison(op)
    mode = speed_mode(lib, carriage.p, op, carriage.params.vehicle.mass,
                      carriage.params.envelope.embedded_controller)
    poles = lambda ev: [[float(e.real), float(e.imag)] for e in sorted(ev, key=_pole_key)]  # noqa: E731
    return {
        "speed": v,
        "Q": [[Q[0], 0.0], [0.0, Q[1]]],
        "R": R,
        "params_sha256": carriage.loaded.sha256,
        "convention": "u = -K x, x = (position, rate), A = [[0, 1], [-k/m, 0]], B = [0, 1/m]",
        "axes": {g.axis: g.to_json(Q, R) for g in gains},
        "coupled": {
            "states": list(REDUCED_STATES),
            # null where the design is unstable on the coupled model (an unbounded cost):
            # JSON has no infinity, and no command prints a non-finite number
            "cost_per_axis_design": _finite_or_none(cc.cost_per_axis),
            "cost_coupled_lqr": _finite_or_none(cc.cost_coupled),
            "poles_per_axis_design": poles(cc.poles_per_axis),
            "poles_coupled_lqr": poles(cc.poles_coupled),
            "poles_damping": poles(cc.poles_damping),
        },
        "allocation": {
            "forces": list(input_names_of(carriage.structure)[1:]),
            "controls": [c.name for c in cv.CONTROLS],
            "effectiveness": lib.function("maglev_effectiveness")(carriage.p)[0].tolist(),
            "minimum_norm": op.allocation.tolist(),
        },
        "speed_mode": mode.to_json(),
        "embedded": embedded_gains(carriage, op),
    }


#: entries of a gain matrix below this fraction of its largest are round-off of the LQR solve
#: of a zero (the carriage's symmetry): `gains` and the report print them as 0
GAIN_ROUNDOFF = 1e-9


def displayed_gains(K) -> np.ndarray:
    """A gain matrix as `maglevgen gains` and the report print it: the entries below
    GAIN_ROUNDOFF of its largest set to 0."""
    K = np.asarray(K, dtype=float)
    scale = float(np.max(np.abs(K))) if K.size else 0.0
    return np.where(np.abs(K) > GAIN_ROUNDOFF * scale, K, 0.0)


def embedded_gains(carriage: DerivedCarriage, op: OperatingPoint) -> dict:
    """The embedded controller's gains at ``op``: u_gen = -(K_pos (a - a_ref) + K_rate a'),
    rows the generalized forces (F_y, F_z, M_x, M_y, M_z), columns the axes; and for the
    `spec` design its per-axis weights."""
    name = carriage.params.envelope.embedded_controller
    K_pos, K_rate = op.gains(name)
    out = {"controller": name, "title": controller_title(name), "speed": op.speed,
           "axes": list(cv.AXES), "forces": [c.name for c in cv.CONTROLS],
           "a_ref": op.a_trim.tolist(), "K_pos": K_pos.tolist(), "K_rate": K_rate.tolist(),
           # on the coupled 10-state linearisation, as "coupled" gives the paper's designs'
           "closed_loop_poles": [[float(e.real), float(e.imag)] for e in
                                 sorted(np.linalg.eigvals(op.reduced_closed_loop(name)),
                                        key=_pole_key)]}
    if (weights := registered(name).weights) is not None:
        q1, q2, r = weights(op)
        out["weights"] = {"q1": q1.tolist(), "q2": q2.tolist(), "r": r.tolist(),
                          "design_damping_ratio": None if op.weights.spec is None
                          else op.weights.spec.zeta}
    return out



def coupled_comparison(op: OperatingPoint):
    """The per-axis LQR and the damping applied to the C's coupled linearisation, beside the
    coupled LQR (operating.compare_designs)."""
    S = np.eye(N_AXES, len(REDUCED_STATES))

    def feedback(name: str) -> np.ndarray:
        K_pos, K_rate = op.gains(name)
        return K_pos @ S + K_rate @ op.rate_map

    A_r, B_g = op.reduced
    return compare_designs(A_r, B_g, op.rate_map, op.weights, feedback("lqr"), op.K_coupled,
                           feedback("damping"))


def _finite_or_none(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _pole_key(e: complex) -> tuple[float, float]:
    return (float(e.real), float(e.imag))


def plant_of(carriage: DerivedCarriage) -> Plant:
    """The carriage's plant, its compiled run-time-parameter library loaded on first use
    (cached; built with the steps announced on stderr): what every query here, the API and
    the commands run."""
    return Plant(carriage, progress=progress.step)


def envelope_of(plant: Plant, n_speeds: int | None = None, other_models: bool = True):
    """The envelope of a plant through its compiled library (maglevgen.analyses.envelope)."""
    return compute_envelope(plant, n_speeds or DEFAULT_SPEEDS,
                            other_models=other_models)


def verdict_lines(env, embedded: str) -> list[str]:
    """One line per controller, the embedded one marked."""
    out = [f"Envelope {env.v_min:.4g} to {env.v_max:.4g} m/s (maglevgen envelope):"]
    for name, c in env.controllers.items():
        mark = " [embedded]" if name == embedded else ""
        out.append(f"  {controller_title(name) + mark:<28} {c.verdict}")
        out.append(f"  {'':<28} specification: {c.spec_verdict}")
        if name == embedded and env.other_models:
            out.append(f"  {'':<28} its gains on the other models: "
                       f"{env.robustness_verdict()}")
    if env.sensing is not None:
        sc = env.sensing
        out.append(f"  sensing [embedded]: {sc.observability_subject()}: "
                   f"{sc.observability_text()}")
        out.append(f"  {'':<28} {sc.loop_subject()}: {sc.loop_text()}")
    out.append(f"  (specification checked {env.checked_on()})")
    out.append(f"  {env.firmware_design(embedded)}")
    return out


def envelope_verdicts(plant: Plant) -> tuple[dict, list[str]]:
    """The envelope's verdicts `maglevgen trim` and `gains` print first: the entry their
    ``--json`` report holds under "envelope" and the lines. A carriage whose envelope has no
    trim still gets its trim and gains: the entry is then the reason, ``{"error": ...}``."""
    try:
        env = envelope_of(plant, other_models=False)  # `envelope` and `build` do
    except InputError as exc:
        return {"error": str(exc)}, [f"Envelope not computed: {exc}"]
    embedded = plant.params.envelope.embedded_controller
    entry = {"v_min": env.v_min, "v_max": env.v_max, "embedded": embedded,
             "verdicts": {n: c.verdict for n, c in env.controllers.items()},
             "stable": {n: c.ok for n, c in env.controllers.items()},
             "firmware_design": env.firmware_design(embedded)}
    return entry, verdict_lines(env, embedded)
