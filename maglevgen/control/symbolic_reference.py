"""The tests' reference controllers, on the lambdified SymPy model: per-axis LQR (eqs 24-33),
damping (eqs 20-21), allocation (eqs 22-23), and their comparison on the full coupled
linearisation.

Per axis the plant is m a'' + k a = u with a in (y, z, phi, theta, psi): k is the diagonal of
the total stiffness at trim (magnetic K_st0 plus the gravity and propulsion moments of the CG
offset) and m the diagonal of the generalized mass about O. The gains depend on the speed only
through k (the trim moves with speed), so `gain_schedule` gives them in closed form along a
speed sweep.

Nothing the toolchain prints comes from here: the CLI, SUMMARY.md and the report read the
compiled library (maglevgen.analyses.queries, maglevgen.control.operating). These functions of
a `DerivedCarriage` and a `Trim` (axis_plants, carriage_gains, gain_schedule, reduced_model,
coupled_comparison) are the independent references the tests and bench/ hold the library
against.
"""

from __future__ import annotations

import numpy as np
import sympy as sp

from maglevgen.carriage import DerivedCarriage
from maglevgen.control.operating import (
    N_AXES,
    REDUCED_STATES,
    AxisGains,
    CoupledComparison,
    Weights,
    compare_designs,
    coupled_lqr,
    numerical_lqr,
)
from maglevgen.derive import conventions as cv
from maglevgen.derive.allocation import minimum_norm_allocation
from maglevgen.derive.damping import damping_gain_closed_form
from maglevgen.derive.geometry import control_effectiveness
from maglevgen.derive.memo import memoized
from maglevgen.derive.paper import paper_riccati
from maglevgen.derive.riccati import lqr_gain_mp, lqr_gain_numeric, riccati_solution_mp
from maglevgen.derive.trim import Trim

__all__ = ["allocation_matrix", "axis_plants", "carriage_gains", "coupled_comparison",
           "effectiveness", "gain_schedule", "reduced_model"]


def axis_plants(carriage: DerivedCarriage, trim: Trim) -> list[tuple[str, float, float]]:
    """(axis, stiffness, inertia) of each axis at trim."""
    K = carriage.total_stiffness(trim)
    M = carriage.generalized_mass()
    return [(axis, float(K[i, i]), float(M[i])) for i, axis in enumerate(cv.AXES)]


def axis_gains(axis: str, k: float, m: float, q1: float, q2: float, r: float) -> AxisGains:
    A = np.array([[0.0, 1.0], [-k / m, 0.0]])
    B = np.array([[0.0], [1.0 / m]])
    K_cf = lqr_gain_numeric(k, m, q1, q2, r)
    P = np.array(riccati_solution_mp(k, m, q1, q2, r).tolist(), dtype=float)
    K_num = numerical_lqr(A, B, np.diag([q1, q2]), np.array([[r]]))
    _, Kp = paper_riccati(sp.Float(k, 30), sp.Float(m, 30))
    K_ref = np.array([float(v) for v in lqr_gain_mp(k, m, q1, q2, r)])
    c = float(damping_gain_closed_form(sp.Float(k), sp.Float(m))) if k > 0 else None
    return AxisGains(axis, k, m, A, B, P, np.asarray(K_cf, dtype=float),
                     np.asarray(K_num, dtype=float).ravel(),
                     np.array([float(v) for v in Kp], dtype=float), K_ref, c)


def carriage_gains(carriage: DerivedCarriage, trim: Trim) -> list[AxisGains]:
    """Per-axis gains at a trim, with the weights of the parameter file."""
    (q1, q2), r = carriage.params.control.state_weights, carriage.params.control.input_weight
    return [axis_gains(a, k, m, q1, q2, r) for a, k, m in axis_plants(carriage, trim)]


def gain_schedule(carriage: DerivedCarriage, speeds: np.ndarray) -> dict[str, np.ndarray]:
    """K (closed form) per axis along a speed sweep: shape (len(speeds), 2) per axis."""
    (q1, q2), r = carriage.params.control.state_weights, carriage.params.control.input_weight
    out = {a: np.zeros((len(speeds), 2)) for a in cv.AXES}
    for j, v in enumerate(speeds):
        for axis, k, m in axis_plants(carriage, carriage.trim(float(v))):
            out[axis][j] = lqr_gain_numeric(k, m, q1, q2, r)
    return out


# ------------------------------------------------------------------------------ allocation


def effectiveness(carriage: DerivedCarriage) -> np.ndarray:
    """E (5 x n_array_forces): generalized forces about O from the array control forces."""
    arrays = list(carriage.params.arrays.values())
    comps = [c for _, c in carriage.structure.arrays]
    E = control_effectiveness([sp.Matrix(a.position) for a in arrays], comps,
                              [sp.Matrix(a.normal) for a in arrays])
    return np.array(E.evalf(), dtype=float)


def allocation_matrix(carriage: DerivedCarriage) -> np.ndarray:
    """T (n x 5): minimum-norm array forces for (u_y, u_z, u_phi, u_theta, u_psi)."""
    return _minimum_norm(tuple(map(tuple, effectiveness(carriage).tolist())))


@memoized
def _minimum_norm(E: tuple[tuple[float, ...], ...]) -> np.ndarray:
    """The derived minimum-norm allocation (eqs 22-23) for the array geometry E, kept across
    processes: it depends on the array positions only, which few parameter edits change."""
    rational = sp.Matrix(E).applyfunc(sp.nsimplify)
    return np.array(minimum_norm_allocation(rational).evalf(), dtype=float)


# -------------------------------------------------------------------------- coupled model
# The reduced state and the coupled LQR's weights are those of maglevgen.control.operating (the
# envelope's), here on the lambdified model.


def reduced_model(carriage: DerivedCarriage, trim: Trim) -> tuple[np.ndarray, np.ndarray,
                  np.ndarray]:
    """(A, B_gen, C_rate): the 10-state linearisation driven by the five generalized controls.

    B_gen routes (u_y..u_psi) through the minimum-norm allocation; C_rate maps the reduced
    state to the axis rates (y', z', phi', theta', psi') by the linearised kinematics.
    """
    A, B = carriage.linearize(trim)
    idx = [cv.STATE_INDEX[s] for s in REDUCED_STATES]
    Ar = A[np.ix_(idx, idx)]
    Bg = B[idx, 1:] @ allocation_matrix(carriage)
    C_rate = A[np.ix_([cv.STATE_INDEX[s] for s in cv.Q_STATES], idx)]
    return Ar, Bg, C_rate


def _feedback(gains: list[AxisGains], C_rate: np.ndarray, damping: bool = False) -> np.ndarray:
    K = np.zeros((N_AXES, len(REDUCED_STATES)))
    for i, g in enumerate(gains):
        if damping:
            K[i] = (g.damping_gain or 0.0) * C_rate[i]
        else:
            K[i, i] = g.K_closed_form[0]
            K[i] += g.K_closed_form[1] * C_rate[i]
    return K


def coupled_comparison(carriage: DerivedCarriage, trim: Trim,
                       gains: list[AxisGains]) -> CoupledComparison:
    """Numerical LQR of the coupled model vs the per-axis closed forms applied to it (on the
    lambdified model: the reference for the generated C's, `compare_designs`)."""
    Ar, Bg, C_rate = reduced_model(carriage, trim)
    w = Weights.of(carriage.params)
    K_c = coupled_lqr(Ar, Bg, C_rate, w)
    return compare_designs(Ar, Bg, C_rate, w, _feedback(gains, C_rate), K_c,
                           _feedback(gains, C_rate, damping=True))
