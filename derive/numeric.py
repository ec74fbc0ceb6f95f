"""Numerical evaluation of the symbolic model: lambdified layers and chain-rule Jacobians.

Each layer of ``CarriageModel`` and each of its partial derivatives is a SymPy expression,
lambdified once per structure. xdot and the Jacobians (A, B) are composed from them by the
chain rule, which is exact: the symbolic linearisation is the product of symbolic partials.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import sympy as sp

from maglevgen.derive import conventions as cv
from maglevgen.derive.conventions import Q_STATES
from maglevgen.derive.differentiate import Differentiator, jacobian
from maglevgen.derive.linearize import generalized_mass_expr, stiffness_form, stiffness_parts
from maglevgen.derive.memo import memoized
from maglevgen.derive.model import CarriageModel, Structure, build_model

__all__ = ["ModelFunctions", "generalized_mass", "lambdified_parts", "linearize",
           "magnetic_stiffness", "model_functions", "other_stiffness", "stiffness_split",
           "symbolic_model", "total_stiffness"]


class Equilibrium(Protocol):
    """What the evaluations at trim read of a trim (derive.trim.Trim has it; trim imports this
    module, so the dependency is this protocol, not that class)."""

    x: np.ndarray
    u: np.ndarray
    lift: np.ndarray
    drag: np.ndarray


def _fn(args: list, expr: sp.Matrix) -> Callable[..., np.ndarray]:
    # lambdify(cse=True)'s code, without its two walks of the expression as a tree (shared
    # subexpressions again at every use: most of its time): the implemented functions'
    # (the model has none) and the symbols' (of the reduced expression here)
    cses, reduced = sp.cse(expr, list=False)
    f = sp.lambdify(args, reduced, modules="numpy", cse=lambda _: (cses, reduced),
                    use_imps=False)
    shape = expr.shape

    def call(*a: np.ndarray) -> np.ndarray:
        # numpy's select evaluates every branch: the series' branch of sinhc/L (below
        # derive.distributed.SERIES_BELOW) is taken where the closed one divides by zero
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.asarray(f(*a), dtype=float).reshape(shape)

    return call


@dataclass(frozen=True)
class ModelFunctions:
    """Numerical functions of one structure's model; arguments are 1-D float arrays."""

    model: CarriageModel
    kin: Callable[..., np.ndarray]
    kin_x: Callable[..., np.ndarray]
    speeds: Callable[..., np.ndarray]
    gaps: Callable[..., np.ndarray]  # face-centre gaps (x, p): the force law's
    contact_gaps: Callable[..., np.ndarray]  # each face's closest corner (x, p): contact
    lift: Callable[..., np.ndarray]  # (x, s, p)
    drag: Callable[..., np.ndarray]
    lift_x: Callable[..., np.ndarray]
    lift_s: Callable[..., np.ndarray]
    drag_x: Callable[..., np.ndarray]
    drag_s: Callable[..., np.ndarray]
    speeds_x: Callable[..., np.ndarray]
    spread: Callable[..., np.ndarray]  # the lag's spread forces (x, s, p)
    spread_x: Callable[..., np.ndarray]
    spread_s: Callable[..., np.ndarray]
    arms: Callable[..., np.ndarray]  # each array's point of action, stacked (x, p)
    arms_x: Callable[..., np.ndarray]
    wrench: Callable[..., np.ndarray]  # (x, u, FL, FD, G, A, p)
    wrench_x: Callable[..., np.ndarray]
    wrench_u: Callable[..., np.ndarray]
    wrench_FL: Callable[..., np.ndarray]
    wrench_FD: Callable[..., np.ndarray]
    wrench_G: Callable[..., np.ndarray]
    wrench_A: Callable[..., np.ndarray]
    acc: Callable[..., np.ndarray]  # (x, W, p)
    acc_x: Callable[..., np.ndarray]
    acc_W: Callable[..., np.ndarray]
    stiffness_magnetic: Callable[..., np.ndarray]  # K_st0 (q, F_L, F_D, p), derive.linearize
    stiffness_other: Callable[..., np.ndarray]  # gravity/propulsion stiffness (q, F_prop, p)

    def forces(self, x: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(gaps, lift, drag) of every array at state x."""
        s = self.speeds(x, p).ravel()
        return self.gaps(x, p).ravel(), self.lift(x, s, p).ravel(), self.drag(x, s, p).ravel()

    def body_wrench(self, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        """Total external force and moment about O, body axes."""
        _, fl, fd = self.forces(x, p)
        spread = self.spread(x, self.speeds(x, p).ravel(), p).ravel()
        return self.wrench(x, u, fl, fd, spread, self.arms(x, p).ravel(), p).ravel()

    def xdot(self, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
        w = self.body_wrench(x, u, p)
        return np.concatenate([self.kin(x).ravel(), self.acc(x, w, p).ravel()])

    def jacobians(self, x: np.ndarray, u: np.ndarray, p: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
        """(A, B) = (d xdot/dx, d xdot/du) by the chain rule through the layers."""
        s = self.speeds(x, p).ravel()
        fl, fd = self.lift(x, s, p).ravel(), self.drag(x, s, p).ravel()
        s_x = self.speeds_x(x, p)
        fl_x = self.lift_x(x, s, p) + self.lift_s(x, s, p) @ s_x
        fd_x = self.drag_x(x, s, p) + self.drag_s(x, s, p) @ s_x
        g = self.spread(x, s, p).ravel()
        g_x = self.spread_x(x, s, p) + self.spread_s(x, s, p) @ s_x
        layers = (x, u, fl, fd, g, self.arms(x, p).ravel(), p)
        w = self.wrench(*layers).ravel()
        w_x = (self.wrench_x(*layers) + self.wrench_FL(*layers) @ fl_x
               + self.wrench_FD(*layers) @ fd_x + self.wrench_G(*layers) @ g_x
               + self.wrench_A(*layers) @ self.arms_x(x, p))
        a_W = self.acc_W(x, w, p)
        A = np.vstack([self.kin_x(x), self.acc_x(x, w, p) + a_W @ w_x])
        B = np.vstack([np.zeros((6, len(u))), a_W @ self.wrench_u(*layers)])
        return A, B


@memoized
def symbolic_model(structure: Structure) -> CarriageModel:
    """`build_model`, kept across processes: unpickling it takes a tenth of deriving it (what
    the report displays needs the model, not its lambdified layers)."""
    return build_model(structure)


@memoized
def model_functions(structure: Structure) -> ModelFunctions:
    """Lambdify the layers of the model of ``structure`` and their partial derivatives."""
    m = build_model(structure)
    stiffness_magnetic, stiffness_other = lambdify_stiffness(structure)
    x, u, s = list(m.x), list(m.u), list(m.speed_sym)
    fl, fd, w = list(m.lift_sym), list(m.drag_sym), list(m.wrench_sym)
    xs, xups = [m.x], [m.x, m.u, m.lift_sym, m.drag_sym, m.spread_sym, m.arm_sym, m.p]
    arms = sp.Matrix.vstack(*m.arms)
    xsp = [m.x, m.speed_sym, m.p]
    d = Differentiator()  # one for all: the layers share their gaps, factors and rotation

    def jac(exprs: sp.Matrix, variables: list) -> sp.Matrix:
        return jacobian(exprs, variables, d)

    return ModelFunctions(
        model=m,
        kin=_fn(xs, m.kinematics),
        kin_x=_fn(xs, jac(m.kinematics, x)),
        speeds=_fn([m.x, m.p], m.array_speeds),
        gaps=_fn([m.x, m.p], m.gaps),
        contact_gaps=_fn([m.x, m.p], m.contact_gaps),
        lift=_fn([m.x, m.speed_sym, m.p], m.lift_at_speed),
        drag=_fn([m.x, m.speed_sym, m.p], m.drag_at_speed),
        lift_x=_fn([m.x, m.speed_sym, m.p], jac(m.lift_at_speed, x)),
        lift_s=_fn([m.x, m.speed_sym, m.p], jac(m.lift_at_speed, s)),
        drag_x=_fn([m.x, m.speed_sym, m.p], jac(m.drag_at_speed, x)),
        drag_s=_fn([m.x, m.speed_sym, m.p], jac(m.drag_at_speed, s)),
        speeds_x=_fn([m.x, m.p], jac(m.array_speeds, x)),
        spread=_fn(xsp, m.spread_at_speed),
        spread_x=_fn(xsp, jac(m.spread_at_speed, x)),
        spread_s=_fn(xsp, jac(m.spread_at_speed, s)),
        arms=_fn([m.x, m.p], arms),
        arms_x=_fn([m.x, m.p], jac(arms, x)),
        wrench=_fn(xups, m.wrench),
        wrench_x=_fn(xups, jac(m.wrench, x)),
        wrench_u=_fn(xups, jac(m.wrench, u)),
        wrench_FL=_fn(xups, jac(m.wrench, fl)),
        wrench_FD=_fn(xups, jac(m.wrench, fd)),
        wrench_G=_fn(xups, jac(m.wrench, list(m.spread_sym))),
        wrench_A=_fn(xups, jac(m.wrench, list(m.arm_sym))),
        acc=_fn([m.x, m.wrench_sym, m.p], m.accelerations),
        acc_x=_fn([m.x, m.wrench_sym, m.p], jac(m.accelerations, x)),
        acc_W=_fn([m.x, m.wrench_sym, m.p], jac(m.accelerations, w)),
        stiffness_magnetic=stiffness_magnetic,
        stiffness_other=stiffness_other,
    )


# ------------------------------------------------ the linearisation at trim (eqs 5-19)


def magnetic_stiffness(mf: ModelFunctions, trim: Equilibrium, p: np.ndarray) -> np.ndarray:
    """K_st0 evaluated at the trim pose and array forces."""
    return np.asarray(mf.stiffness_magnetic(_trim_q(trim), trim.lift, trim.drag, p),
                      dtype=float)


def other_stiffness(mf: ModelFunctions, trim: Equilibrium, p: np.ndarray) -> np.ndarray:
    """Stiffness of the gravity and propulsion moments about O at trim (CG offset terms)."""
    return np.asarray(mf.stiffness_other(_trim_q(trim), trim.u[0], p), dtype=float)


def total_stiffness(mf: ModelFunctions, trim: Equilibrium, p: np.ndarray) -> np.ndarray:
    """K_st0 plus the gravity and propulsion terms: -dW/dq of every external force."""
    return magnetic_stiffness(mf, trim, p) + other_stiffness(mf, trim, p)


def _trim_q(trim: Equilibrium) -> np.ndarray:
    return np.array([trim.x[cv.STATE_INDEX[s]] for s in Q_STATES])


def lambdify_stiffness(structure: Structure):
    """(K_st0(q, F_L, F_D, p), K_other(q, F_prop, p)) as numpy functions."""
    sf = stiffness_form(structure)
    m = build_model(structure)
    return (_fn([sf.q, sf.lift_sym, sf.drag_sym, m.p], sf.K),
            _fn([sf.q, m.u[0], m.p], sf.K_other))


@memoized
def lambdified_parts(structure: Structure) -> dict[str, Callable[..., np.ndarray]]:
    """The STIFFNESS_PARTS as numpy functions, kept across processes (lambdifying them takes
    seconds): the tests' reference for the generated maglev_stiffness_parts, which the report
    prints."""
    sp_parts = stiffness_parts(structure)
    m = build_model(structure)
    args = [sp_parts.q, sp_parts.lift_sym, sp_parts.drag_sym, sp_parts.f_prop, m.p]
    return {name: _fn(args, K) for name, K in sp_parts.parts.items()}


def stiffness_split(structure: Structure, trim: Equilibrium, p: np.ndarray
                    ) -> dict[str, np.ndarray]:
    """The derived stiffness K_st0 + K_other at trim split into STIFFNESS_PARTS (5x5 each):
    gap slope, rotating arms, tilt across the face, gravity, propulsion."""
    q = _trim_q(trim)
    return {name: f(q, trim.lift, trim.drag, trim.u[0], p)
            for name, f in lambdified_parts(structure).items()}


def generalized_mass(model: CarriageModel, p: np.ndarray) -> np.ndarray:
    """`generalized_mass_expr` evaluated at the parameter values ``p``."""
    val = dict(zip(model.p, p, strict=True))
    return np.array([float(e) for e in generalized_mass_expr(model).xreplace(val)])


def linearize(mf: ModelFunctions, trim: Equilibrium, p: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """A (12x12) and B (12 x n_inputs) of the full model at trim."""
    return mf.jacobians(trim.x, trim.u, p)
