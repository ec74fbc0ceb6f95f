"""The loop as built, as one linear plant at an operating point: what the `spec` design at the
tick is solved on and what every linear verification (eigenvalues, disk and delay margins)
closes. The seed of issue 51's `Plant`: every state of the augmented loop has its place in ONE
layout (`Layout`), and nothing else slices it by hand.

The continuous part, at the trim of an operating point (`loop_model` on LOOP_STATES):

    x' = A x + B_F F + b_p F_prop        (the rigid body and the circuits, linearised)
    tau F' = F_c - F                     (each array's control force lags its command,
                                          [actuators] time_constant; tau = 0: F = F_c)

F the array control forces (the allocation's components, `control.actuators`), F_c their
commands, F_prop the propulsion (no lag: the drive along the track is not an array's). The
controller runs at the tick h = 1/tick_rate with d ticks of computation delay: its command is
held (zero-order hold) and applied d ticks after the state it was computed from was sampled.
The exact ZOH discretisation of (x, F) is one matrix exponential (`zoh`); the d commands in
flight are states of the loop (`Layout` block "in_flight").

The controller (ideal sensing: x measured at each tick) is

    w[k] = -K_x x[k] - K_q (w[k-1], ..., w[k-d]) - K_a w_hat[k]      (5 generalized forces)
    F_prop[k] = F_ff - k_v dV[k] - k_i xi[k],   xi[k+1] = xi[k] + h dV[k]
    F_c = T w                                                         (allocation, eqs 22-23)

with F_ff the trim propulsion at the speed reference (the C tick's feedforward,
`maglev_schedule_f_prop`: an input, so the speed loop keeps the plant's own drag slope),
w_hat its prediction of the lagged generalized forces from its own applied commands,
w_hat[k+1] = a w_hat[k] + (1 - a) w_applied[k], a = exp(-h/tau) (exact for a held command),
and xi the speed error's integral (integral action, `speed_loop_gains`: a drag the
feedforward misses leaves no steady speed error; k_i = 0 leaves xi out of the layout). The C
tick clamps xi so that |k_i xi| stays within control.spec.speed_integral_limit (anti-windup);
the linear loop here is the unclamped one. K_x, K_q, K_a
are the discrete LQR of the design model (`design_model`): the reduced linearisation with the
lag on the generalized forces and the commands in flight, the `spec` weights on the body
states, none on the lag and the queue.

References
----------
G. F. Franklin, J. D. Powell, M. Workman, *Digital Control of Dynamic Systems*, 3rd ed.
(1998), sections 4.3.3 (ZOH), 4.3.4 (delay) and 9.3 (discrete LQR).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from maglevgen.control.lqr import numerical_dlqr, weighted_qr
from maglevgen.control.operating import AXIS_STATES, N_AXES, REDUCED_STATES, OperatingPoint
from maglevgen.control.registry import WeightsFn
from maglevgen.control.sampled import LOOP_INDEX, LOOP_STATES, Tick, loop_model, zoh
from maglevgen.control.spec import spec_weights
from maglevgen.derive import conventions as cv

__all__ = ["LoopDesign", "LoopPlant", "speed_loop_gains"]

# the controller's commands: the five generalized forces, then the propulsion
COMMANDS: tuple[str, ...] = (*(c.name for c in cv.CONTROLS), "F_prop")


@dataclass(frozen=True)
class Block:
    """A named group of consecutive states of a layout."""

    name: str
    states: tuple[str, ...]


@dataclass(frozen=True)
class Layout:
    """The order of a state vector as named blocks: the one place a block's slice comes from."""

    blocks: tuple[Block, ...]

    def __getitem__(self, name: str) -> slice:
        start = 0
        for b in self.blocks:
            if b.name == name:
                return slice(start, start + len(b.states))
            start += len(b.states)
        raise KeyError(f"no block {name!r} in the layout ({', '.join(self.names)})")

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(b.name for b in self.blocks)

    @property
    def states(self) -> tuple[str, ...]:
        return tuple(s for b in self.blocks for s in b.states)

    @property
    def size(self) -> int:
        return len(self.states)

    def has(self, name: str) -> bool:
        return name in self.names and self[name].stop > self[name].start


def speed_loop_gains(mass: float, drag_slope: float, bandwidth: float,
                     integral_ratio: float = 1.0) -> tuple[float, float]:
    """(k_v [N s/m], k_i [N/m]) of the speed loop m dV' = -(dF_D,trim/dV) dV + dF_prop with
    dF_prop = -k_v dV - k_i int dV: the characteristic polynomial m s^2 + (slope + k_v) s + k_i
    = m (s + b)(s + r b) has its roots at -``bandwidth`` (b) and -``integral_ratio`` b (r),
    k_v = m b (1 + r) - slope and k_i = m r b^2; r = 1 a double root at -b, r = 0 no integral
    (k_v = m b - slope puts the one pole at -b, `sampled.speed_gain`)."""
    if not (np.isfinite(integral_ratio) and integral_ratio >= 0):
        raise ValueError(f"integral ratio {integral_ratio!r}: must be a finite number >= 0")
    r = float(integral_ratio)
    return float(mass * bandwidth * (1 + r) - drag_slope), float(mass * r * bandwidth**2)


@dataclass(frozen=True)
class LoopDesign:
    """The `spec` weights solved at the tick on the design model (`LoopPlant.design`): gains on
    the reduced body states (as K_pos, K_rate on (a - a_ref, a')), on the predicted lagged
    generalized forces and on the generalized forces in flight (newest first)."""

    K_pos: np.ndarray  # 5 x 5
    K_rate: np.ndarray  # 5 x 5
    K_lag: np.ndarray | None = None  # 5 x 5 (5 x 0 without a lag); None: no feedback
    K_delay: np.ndarray | None = None  # 5 x 5 d; None: no feedback of the commands in flight


@dataclass(frozen=True)
class LoopPlant:
    """The loop at one operating point: the tick, the actuator lag ``tau`` [s] and the speed
    loop (k_v, k_i), with its layouts, its discrete models and its closed loops."""

    op: OperatingPoint
    tick: Tick
    tau: float  # [s] actuator lag, 0: none
    k_v: float = 0.0  # [N s/m]
    k_i: float = 0.0  # [N/m]

    # ---------------------------------------------------------------- layouts

    @property
    def n_forces(self) -> int:
        """Array control force components (the allocation's rows)."""
        return int(self.op.allocation.shape[0])

    @cached_property
    def plant_layout(self) -> Layout:
        """The plant's continuous state: the body (LOOP_STATES) and the lagged array forces."""
        lag = tuple(f"F{i}" for i in range(self.n_forces)) if self.tau > 0 else ()
        return Layout((Block("body", LOOP_STATES), Block("actuators", lag)))

    @cached_property
    def loop_layout(self) -> Layout:
        """The closed loop's discrete state: the plant's, the commands in flight (newest
        first), the controller's prediction of the lagged generalized forces, the speed
        error's integral."""
        d = self.tick.delay
        flight = tuple(f"{c}[k-{j + 1}]" for j in range(d) for c in COMMANDS)
        pred = tuple(f"{c.name}_hat" for c in cv.CONTROLS) if self.tau > 0 else ()
        return Layout((*self.plant_layout.blocks, Block("in_flight", flight),
                       Block("prediction", pred),
                       Block("speed_integral", ("xi_v",) if self.k_i else ())))

    @cached_property
    def design_layout(self) -> Layout:
        """The design model's state: the reduced body states, the lagged generalized forces,
        the generalized forces in flight (newest first)."""
        d = self.tick.delay
        lag = tuple(c.name for c in cv.CONTROLS) if self.tau > 0 else ()
        flight = tuple(f"{c.name}[k-{j + 1}]" for j in range(d) for c in cv.CONTROLS)
        return Layout((Block("body", REDUCED_STATES), Block("actuators", lag),
                       Block("in_flight", flight)))

    # ---------------------------------------------------------------- models

    @cached_property
    def lag_pole(self) -> float:
        """a = exp(-h/tau): the lag over one held tick (0 without a lag)."""
        return float(np.exp(-self.tick.period / self.tau)) if self.tau > 0 else 0.0

    def continuous(self) -> tuple[np.ndarray, np.ndarray]:
        """(A, B) on `plant_layout`; inputs the array force commands F_c, then F_prop."""
        A_x, B_x = loop_model(self.op)  # inputs: 5 generalized forces, propulsion
        idx = list(LOOP_INDEX)
        B_F = self.op.B[idx, 1:]
        b_p = B_x[:, -1]
        L = self.plant_layout
        nf = self.n_forces
        A = np.zeros((L.size, L.size))
        B = np.zeros((L.size, nf + 1))
        body, act = L["body"], L["actuators"]
        A[body, body] = A_x
        if self.tau > 0:
            A[body, act] = B_F
            A[act, act] = -np.eye(nf) / self.tau
            B[act, :nf] = np.eye(nf) / self.tau
        else:
            B[body, :nf] = B_F
        B[body, nf] = b_p
        return A, B

    def discrete(self) -> tuple[np.ndarray, np.ndarray]:
        """(Phi, Gamma): `continuous` held over one tick (exact ZOH)."""
        return zoh(*self.continuous(), self.tick.period)

    def design_model(self) -> tuple[np.ndarray, np.ndarray]:
        """(Phi_d, Gamma_d) on `design_layout`, input the five generalized forces computed at
        this tick: the reduced body driven by the lagged generalized forces, held over the
        tick, the oldest in flight applied."""
        A_r, B_g = self.op.reduced
        L = self.design_layout
        n_c = L["in_flight"].start  # body and lag: the continuous part
        Ac, Bc = np.zeros((n_c, n_c)), np.zeros((n_c, N_AXES))
        body, act = L["body"], L["actuators"]
        Ac[body, body] = A_r
        if self.tau > 0:
            Ac[body, act] = B_g
            Ac[act, act] = -np.eye(N_AXES) / self.tau
            Bc[act] = np.eye(N_AXES) / self.tau
        else:
            Bc[body] = B_g
        Phi_c, Gam_c = zoh(Ac, Bc, self.tick.period)
        d = self.tick.delay
        Phi, Gam = np.zeros((L.size, L.size)), np.zeros((L.size, N_AXES))
        Phi[:n_c, :n_c] = Phi_c
        if d == 0:
            Gam[:n_c] = Gam_c
            return Phi, Gam
        fl = L["in_flight"]
        oldest = slice(fl.stop - N_AXES, fl.stop)
        Phi[:n_c, oldest] = Gam_c
        for j in range(1, d):  # the queue moves on by one tick
            Phi[fl.start + j * N_AXES:fl.start + (j + 1) * N_AXES,
                fl.start + (j - 1) * N_AXES:fl.start + j * N_AXES] = np.eye(N_AXES)
        Gam[fl.start:fl.start + N_AXES] = np.eye(N_AXES)
        return Phi, Gam

    def design(self, weights: WeightsFn = spec_weights) -> LoopDesign:
        """A controller's weights (q1, q2, r per axis, its `Controller.weights`; default the
        `spec` design's, `spec.spec_weights`) on `design_model`:
        K = (R + G' P G)^-1 G' P Phi, P from SciPy's DARE, Q_a = blkdiag(Q, 0, 0) (the lag
        and the commands in flight carry no weight of their own: each command is weighed by R
        when it is computed). ValueError / LinAlgError where the DARE has no solution."""
        Phi, Gam = self.design_model()
        q1, q2, r = weights(self.op)
        Q, R = weighted_qr(self.op.rate_map, q1, q2, r)
        L = self.design_layout
        Qa = np.zeros_like(Phi)
        Qa[L["body"], L["body"]] = Q
        K = numerical_dlqr(Phi, Gam, Qa, R)
        K_pos, K_rate = self.op.axis_gains(K[:, L["body"]])
        return LoopDesign(K_pos, K_rate, K[:, L["actuators"]], K[:, L["in_flight"]])

    # ---------------------------------------------------------------- the loop

    def controller_gains(self, design: LoopDesign) -> np.ndarray:
        """K_c (6 x loop_layout.size): the commands computed at a tick, u[k] = -K_c z[k],
        z on `loop_layout`; rows the generalized forces, then the propulsion's deviation.
        A ``design`` with K_lag or K_delay None (a controller's continuous gains,
        `OperatingPoint.gains`) feeds back neither the prediction nor the commands in flight."""
        L = self.loop_layout
        A_x, _ = loop_model(self.op)
        S = np.zeros((N_AXES, len(LOOP_INDEX)))
        S[range(N_AXES), range(N_AXES)] = 1.0
        C_rate = A_x[[LOOP_INDEX.index(i) for i in AXIS_STATES], :]
        K = np.zeros((N_AXES + 1, L.size))
        K[:N_AXES, L["body"]] = design.K_pos @ S + design.K_rate @ C_rate
        if design.K_delay is not None:
            m, fl = N_AXES + 1, L["in_flight"]
            for j in range(self.tick.delay):
                K[:N_AXES, fl.start + j * m:fl.start + j * m + N_AXES] = \
                    design.K_delay[:, j * N_AXES:(j + 1) * N_AXES]
        if design.K_lag is not None and self.tau > 0:
            K[:N_AXES, L["prediction"]] = design.K_lag
        vel = self.op.x_trim[cv.VELOCITY]
        body = L["body"].start
        for name, comp in zip(cv.STATE_NAMES[cv.VELOCITY], vel, strict=True):
            K[N_AXES, body + LOOP_STATES.index(name)] = self.k_v * comp / np.linalg.norm(vel)
        if self.k_i:
            K[N_AXES, L["speed_integral"]] = self.k_i
        return K

    def speed_row(self) -> np.ndarray:
        """dV as a row on `loop_layout` (dV = (u du + v dv + w dw)/V at trim)."""
        L = self.loop_layout
        c = np.zeros(L.size)
        vel = self.op.x_trim[cv.VELOCITY]
        for name, comp in zip(cv.STATE_NAMES[cv.VELOCITY], vel, strict=True):
            c[L["body"].start + LOOP_STATES.index(name)] = comp / np.linalg.norm(vel)
        return c

    def open_loop(self, design: LoopDesign, extra_delay: int = 0
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(M, N, C): the loop broken at the actuators' inputs, z[k+1] = M z[k] + N e[k],
        y[k] = C z[k], on `loop_layout` (and ``extra_delay`` ticks of the array commands
        between the controller and the actuators, states after it); e the array force commands
        the actuators receive, y those the controller sends. e = y closes the loop; the
        propulsion's loop stays closed."""
        L = self.loop_layout
        Phi, Gam = self.discrete()
        nf, m, d = self.n_forces, N_AXES + 1, self.tick.delay
        K = self.controller_gains(design)
        n = L.size + extra_delay * nf
        M, N, C = np.zeros((n, n)), np.zeros((n, nf)), np.zeros((nf, n))
        # the applied command u_app = U z: the oldest in flight, or the one computed now
        U = np.zeros((m, n))
        if d == 0:
            U[:, :L.size] = -K
        else:
            fl = L["in_flight"]
            U[:, fl.stop - m:fl.stop] = np.eye(m)
        plant = slice(0, L["in_flight"].start)
        M[plant, plant] = Phi
        M[plant] += np.outer(Gam[:, nf], U[N_AXES])  # the propulsion, applied
        N[plant] = Gam[:, :nf]
        if d > 0:
            fl = L["in_flight"]
            M[fl.start:fl.start + m, :L.size] = -K
            for j in range(1, d):
                M[fl.start + j * m:fl.start + (j + 1) * m,
                  fl.start + (j - 1) * m:fl.start + j * m] = np.eye(m)
        if self.tau > 0:
            pr = L["prediction"]
            M[pr, pr] = self.lag_pole * np.eye(N_AXES)
            M[pr] += (1 - self.lag_pole) * U[:N_AXES]
        if self.k_i:
            M[L["speed_integral"], :L.size] = self.tick.period * self.speed_row()
            M[L["speed_integral"], L["speed_integral"]] += 1.0
        y = self.op.allocation @ U[:N_AXES]  # the array commands sent
        if extra_delay == 0:
            C[:] = y
            return M, N, C
        e0 = L.size  # a queue of array commands: sent -> ... -> received
        M[e0:e0 + nf] = y
        for j in range(1, extra_delay):
            M[e0 + j * nf:e0 + (j + 1) * nf, e0 + (j - 1) * nf:e0 + j * nf] = np.eye(nf)
        C[:, n - nf:] = np.eye(nf)
        return M, N, C

    def closed_loop(self, design: LoopDesign, extra_delay: int = 0) -> np.ndarray:
        """The discrete closed loop's matrix (`open_loop` with e = y)."""
        M, N, C = self.open_loop(design, extra_delay)
        return M + N @ C

    def eigenvalues(self, design: LoopDesign, extra_delay: int = 0) -> np.ndarray:
        """Continuous-equivalent eigenvalues ln(z)/h of `closed_loop` (z = 0: -inf)."""
        z = np.linalg.eigvals(self.closed_loop(design, extra_delay)).astype(complex)
        small = np.abs(z) < 1e-300
        s = np.log(np.where(small, 1.0, z)) / self.tick.period
        return np.where(small, -np.inf + 0j, s)

    def speed_states(self, extra_delay: int = 0) -> np.ndarray:
        """Mask of the speed loop's states on `loop_layout` (and the extra delay's): the
        forward speed u, its integral and the propulsion commands in flight."""
        L = self.loop_layout
        mask = np.zeros(L.size + extra_delay * self.n_forces, dtype=bool)
        mask[L["body"].start + LOOP_STATES.index("u")] = True
        mask[L["speed_integral"]] = True
        fl, m = L["in_flight"], N_AXES + 1
        for j in range(self.tick.delay):
            mask[fl.start + j * m + N_AXES] = True
        return mask

    def modes(self, design: LoopDesign, extra_delay: int = 0
              ) -> tuple[np.ndarray, np.ndarray]:
        """(s, speed): the continuous-equivalent eigenvalues ln(z)/h of `closed_loop` and
        whether each is a mode of the speed loop, i.e. the speed states' participation
        factors |l_i r_i| (left and right eigenvectors, l' r = 1; independent of the states'
        units) sum to more than half (Verghese, Perez-Arriaga, Schweppe, 1982)."""
        import scipy.linalg  # local: see lqr.numerical_lqr

        Acl = self.closed_loop(design, extra_delay)
        z, left, right = scipy.linalg.eig(Acl, left=True, right=True)
        scale = np.einsum("ij,ij->j", left.conj(), right)
        part = np.abs(left.conj() * right / np.where(np.abs(scale) > 0, scale, 1.0))
        total = part.sum(axis=0)
        speed = part[self.speed_states(extra_delay)].sum(axis=0) > 0.5 * total
        small = np.abs(z) < 1e-300
        s = np.log(np.where(small, 1.0, z.astype(complex))) / self.tick.period
        return np.where(small, -np.inf + 0j, s), speed
