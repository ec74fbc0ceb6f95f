"""Controllers of one carriage at a speed: per-axis LQR (eqs 24-33), damping (eqs 20-21),
allocation (eqs 22-23), and their comparison on the full coupled linearisation.

Per axis the plant is m a'' + k a = u with a in (y, z, phi, theta, psi): k is the diagonal of
the total stiffness at trim (magnetic K_st0 plus the gravity and propulsion moments of the CG
offset) and m the diagonal of the generalized mass about O. The gains depend on the speed only
through k (the trim moves with speed), so `gain_schedule` gives them in closed form along a
speed sweep.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import sympy as sp

from .carriage import Carriage
from .derive import conventions as cv
from .derive.allocation import minimum_norm_allocation
from .derive.damping import damping_gain_closed_form
from .derive.geometry import control_effectiveness
from .derive.memo import memoized
from .derive.paper import paper_riccati
from .derive.riccati import lqr_gain_mp, lqr_gain_numeric, riccati_solution_mp
from .derive.trim import Trim
from .operating import (
    REDUCED_STATES,
    Weights,
    coupled_lqr,
    coupled_weights,
    numerical_lqr,
)


@dataclass(frozen=True)
class AxisGains:
    """One axis: its plant, the closed-form LQR, the numerical LQR and the paper's gain."""

    axis: str
    stiffness: float
    inertia: float
    A: np.ndarray
    B: np.ndarray
    P_closed_form: np.ndarray
    K_closed_form: np.ndarray
    K_numerical: np.ndarray
    K_paper: np.ndarray
    K_reference: np.ndarray  # the closed form in 50-digit arithmetic, rounded to double
    damping_gain: float | None

    def relative(self, K: np.ndarray, ref: np.ndarray | None = None) -> float:
        ref = self.K_reference if ref is None else ref
        return float(np.max(np.abs(K - ref) / np.abs(ref)))

    def to_json(self, Q: tuple[float, float], R: float) -> dict:
        err_cf = self.relative(self.K_closed_form)
        err_num = self.relative(self.K_numerical)
        return {
            "stiffness": self.stiffness,
            "inertia": self.inertia,
            "A": self.A.tolist(),
            "B": self.B.tolist(),
            "P_closed_form": self.P_closed_form.tolist(),
            "K_closed_form": self.K_closed_form.tolist(),
            "K_numerical": self.K_numerical.tolist(),
            "K_paper": self.K_paper.tolist(),
            "paper_applies": bool(Q == (1.0, 1.0) and R == 1.0),
            "relative_difference": {
                "numerical_vs_closed_form": self.relative(self.K_numerical, self.K_closed_form),
                "paper_vs_closed_form": self.relative(self.K_paper, self.K_closed_form),
            },
            "accuracy_vs_50_digit_reference": {
                "closed_form": err_cf,
                "numerical": err_num,
                "more_accurate": "closed_form" if err_cf <= err_num else "numerical",
            },
            "closed_loop_poles": [[p.real, p.imag] for p in
                                  np.linalg.eigvals(self.A - self.B @ self.K_closed_form[None])],
            "damping_gain": self.damping_gain,
        }


def axis_plants(carriage: Carriage, trim: Trim) -> list[tuple[str, float, float]]:
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


def carriage_gains(carriage: Carriage, trim: Trim) -> list[AxisGains]:
    """Per-axis gains at a trim, with the weights of the parameter file."""
    (q1, q2), r = carriage.params.control.state_weights, carriage.params.control.input_weight
    return [axis_gains(a, k, m, q1, q2, r) for a, k, m in axis_plants(carriage, trim)]


def gain_schedule(carriage: Carriage, speeds: np.ndarray) -> dict[str, np.ndarray]:
    """K (closed form) per axis along a speed sweep: shape (len(speeds), 2) per axis."""
    (q1, q2), r = carriage.params.control.state_weights, carriage.params.control.input_weight
    out = {a: np.zeros((len(speeds), 2)) for a in cv.AXES}
    for j, v in enumerate(speeds):
        for axis, k, m in axis_plants(carriage, carriage.trim(float(v))):
            out[axis][j] = lqr_gain_numeric(k, m, q1, q2, r)
    return out


# ------------------------------------------------------------------------------ allocation


def effectiveness(carriage: Carriage) -> np.ndarray:
    """E (5 x n_array_forces): generalized forces about O from the array control forces."""
    arrays = list(carriage.params.arrays.values())
    comps = [c for _, c in carriage.structure.arrays]
    E = control_effectiveness([sp.Matrix(a.position) for a in arrays], comps)
    return np.array(E.evalf(), dtype=float)


def allocation_matrix(carriage: Carriage) -> np.ndarray:
    """T (n x 5): minimum-norm array forces for (u_y, u_z, u_phi, u_theta, u_psi)."""
    return _minimum_norm(tuple(map(tuple, effectiveness(carriage).tolist())))


@memoized
def _minimum_norm(E: tuple[tuple[float, ...], ...]) -> np.ndarray:
    """The derived minimum-norm allocation (eqs 22-23) for the array geometry E, kept across
    processes: it depends on the array positions only, which few parameter edits change."""
    rational = sp.Matrix(E).applyfunc(sp.nsimplify)
    return np.array(minimum_norm_allocation(rational).evalf(), dtype=float)


# -------------------------------------------------------------------------- coupled model
# The reduced state and the coupled LQR's weights are those of maglevgen.operating (the
# envelope's), here on the lambdified model.


@dataclass(frozen=True)
class CoupledComparison:
    """The per-axis design applied to the full linearisation, beside the coupled LQR."""

    poles_per_axis: np.ndarray
    poles_coupled: np.ndarray
    poles_damping: np.ndarray
    cost_per_axis: float  # J = trace(P_lyap) for unit-covariance initial states
    cost_coupled: float
    K_coupled: np.ndarray  # 5 x 10 on REDUCED_STATES


def reduced_model(carriage: Carriage, trim: Trim) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A, B_gen, C_rate): the 10-state linearisation driven by the five generalized controls.

    B_gen routes (u_y..u_psi) through the minimum-norm allocation; C_rate maps the reduced
    state to the axis rates (y', z', phi', theta', psi') by the linearised kinematics.
    """
    A, B = carriage.linearize(trim)
    idx = [cv.STATE_INDEX[s] for s in REDUCED_STATES]
    Ar = A[np.ix_(idx, idx)]
    Bg = B[idx, 1:] @ allocation_matrix(carriage)
    C_rate = A[np.ix_([cv.STATE_INDEX[s] for s in REDUCED_STATES[:5]], idx)]
    return Ar, Bg, C_rate


def _feedback(gains: list[AxisGains], C_rate: np.ndarray, damping: bool = False) -> np.ndarray:
    K = np.zeros((5, 10))
    for i, g in enumerate(gains):
        if damping:
            K[i] = (g.damping_gain or 0.0) * C_rate[i]
        else:
            K[i, i] = g.K_closed_form[0]
            K[i] += g.K_closed_form[1] * C_rate[i]
    return K


def coupled_comparison(carriage: Carriage, trim: Trim,
                       gains: list[AxisGains]) -> CoupledComparison:
    """Numerical LQR of the coupled model vs the per-axis closed forms applied to it (on the
    lambdified model: the reference for the generated C's, `compare_designs`)."""
    Ar, Bg, C_rate = reduced_model(carriage, trim)
    w = Weights.of(carriage.params)
    K_c = coupled_lqr(Ar, Bg, C_rate, w)
    return compare_designs(Ar, Bg, C_rate, w, _feedback(gains, C_rate), K_c,
                           _feedback(gains, C_rate, damping=True))


def compare_designs(Ar: np.ndarray, Bg: np.ndarray, C_rate: np.ndarray, w: Weights,
                    K_a: np.ndarray, K_c: np.ndarray, K_d: np.ndarray) -> CoupledComparison:
    """Poles and LQR costs of the per-axis (K_a), coupled (K_c) and damping (K_d) feedbacks
    (5 x 10 on REDUCED_STATES) closed around the reduced linearisation (Ar, Bg)."""
    Q, R = coupled_weights(C_rate, w)

    def cost(K: np.ndarray) -> float:
        Acl = Ar - Bg @ K
        if np.max(np.linalg.eigvals(Acl).real) >= 0:
            return float("inf")
        X = scipy.linalg.solve_continuous_lyapunov(Acl.T, -(Q + K.T @ R @ K))
        return float(np.trace(X))

    eig = lambda K: np.linalg.eigvals(Ar - Bg @ K)  # noqa: E731
    return CoupledComparison(eig(K_a), eig(K_c), eig(K_d), cost(K_a), cost(K_c),
                             np.asarray(K_c))
