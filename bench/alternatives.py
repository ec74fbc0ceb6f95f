"""What an engineer would otherwise use from Python: casadi.Function, sympy.lambdify, scipy.

Everything here computes the same model as the generated C (the symbolic model of
derive/model.py), from the same parameter vector and the same inputs.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca
import numpy as np
import sympy as sp
from scipy.integrate import solve_ivp

from maglevgen.carriage import DerivedCarriage
from maglevgen.derive import conventions as cv
from maglevgen.derive.linearize import Q_STATES

AXIS_IDX = [cv.STATE_INDEX[s] for s in Q_STATES]

# scipy solve_ivp: the method and tolerances of the closed-loop comparison.
IVP_METHOD = "RK45"
IVP_RTOL = 1e-6
IVP_ATOL = 1e-9


def lambdify_xdot(carriage: DerivedCarriage, cse: bool) -> tuple[Callable, float]:
    """xdot(x, u, p) as one numpy function of the composed expression, and its build time."""
    m = carriage.model
    t0 = time.perf_counter()
    f = sp.lambdify([list(m.x), list(m.u), list(m.p)], m.compose(), modules="numpy", cse=cse)
    return f, time.perf_counter() - t0


def lambdify_kinematics(carriage: DerivedCarriage) -> Callable:
    m = carriage.model
    return sp.lambdify([list(m.x)], m.kinematics, modules="numpy", cse=True)


def function_named(functions, name: str) -> ca.Function:
    return next(f for f in functions if f.name() == name)


def closed_loop_function(functions) -> ca.Function:
    """casadi.Function (x, k_pos, k_rate, a_ref, F_prop, p) -> (xdot, u) of the closed loop,
    built from the generated maglev_dynamics and maglev_allocate Functions."""
    dyn, alloc = (
        function_named(functions, "maglev_dynamics"),
        function_named(functions, "maglev_allocate"),
    )
    n_x, n_u, n_p = (dyn.size1_in(i) for i in range(3))
    x, p = ca.SX.sym("x", n_x), ca.SX.sym("p", n_p)
    k_pos, k_rate, a_ref = (ca.SX.sym(n, 5) for n in ("k_pos", "k_rate", "a_ref"))
    f_prop = ca.SX.sym("F_prop")
    adot = dyn(x, ca.DM.zeros(n_u), p)[AXIS_IDX]  # the kinematics do not depend on u
    a = ca.vertcat(*[x[i] for i in AXIS_IDX])
    u = ca.vertcat(f_prop, alloc(-(k_pos * (a - a_ref) + k_rate * adot), p))
    return ca.Function("closed_loop", [x, k_pos, k_rate, a_ref, f_prop, p], [dyn(x, u, p), u])


@dataclass(frozen=True)
class Loop:
    """The closed-loop run every contender performs."""

    x0: np.ndarray
    F_prop: float
    k_pos: np.ndarray
    k_rate: np.ndarray
    a_ref: np.ndarray
    dt: float
    n_steps: int
    gap_min: float

    def as_dict(self) -> dict:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


def casadi_rk4(
    rhs: ca.Function, gaps: ca.Function | None, loop: Loop, p: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The RK4 loop of maglev_simulate in Python, one casadi.Function call per stage."""
    n, dt = loop.n_steps, loop.dt
    X, U = np.zeros((n + 1, 12)), np.zeros((n + 1, rhs.size1_out(1)))
    # the constant inputs converted to casadi.DM once; the state goes in as numpy at each call
    args = tuple(ca.DM(a) for a in (loop.k_pos, loop.k_rate, loop.a_ref, loop.F_prop, p))
    p_dm = args[-1]

    def f(x):
        xd, u = rhs(x, *args)
        return np.asarray(xd).ravel(), u

    x = loop.x0.copy()
    X[0] = x
    for k in range(n + 1):
        if gaps is not None and np.min(np.asarray(gaps(x, p_dm))) < loop.gap_min:
            return X[: k + 1], U[: k + 1]
        k1, u = f(x)
        U[k] = np.asarray(u).ravel()
        if k == n:
            break
        k2 = f(x + dt / 2 * k1)[0]
        k3 = f(x + dt / 2 * k2)[0]
        k4 = f(x + dt * k3)[0]
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        X[k + 1] = x
    return X, U


def ivp_closed_loop(
    xdot: Callable, kin: Callable, T: np.ndarray, loop: Loop, p: np.ndarray
) -> tuple[np.ndarray, int]:
    """scipy solve_ivp on the lambdified model with the same feedback; samples at 1/dt."""

    def rhs(_t, x):
        adot = np.asarray(kin(x), dtype=float).ravel()[AXIS_IDX]
        u_gen = -(loop.k_pos * (x[AXIS_IDX] - loop.a_ref) + loop.k_rate * adot)
        u = np.concatenate([[loop.F_prop], T @ u_gen])
        return np.asarray(xdot(x, u, p), dtype=float).ravel()

    t_end = loop.dt * loop.n_steps
    t_eval = np.linspace(0.0, t_end, loop.n_steps + 1)
    sol = solve_ivp(
        rhs, (0.0, t_end), loop.x0, method=IVP_METHOD, t_eval=t_eval, rtol=IVP_RTOL, atol=IVP_ATOL
    )
    if not sol.success:
        raise RuntimeError(f"solve_ivp failed: {sol.message}")
    return sol.y.T, int(sol.nfev)
