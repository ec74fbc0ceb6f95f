"""The track circuits' electrical lag: the first-order (slowly modulated gap) Inductrack force.

Eq 3 is the steady state of a track circuit at a constant gap. When the gap moves, each
circuit's current follows the flux through its L/R dynamics (L/R = 1.73 ms for the LLNL
circuit), so the force lags the gap. This module derives the force to first order in the rate
of the flux amplitude, for the point law (eq 3 at the face centre) and the distributed law
(derive/distributed.py: each circuit at its own gap).

Derivation (``circuit_response``, done by SymPy below, not copied):

1. A circuit is a lumped L-R loop driven by the flux of the array through it (Post, ref [5]):
   L I' + R I = Phi'. The flux is Phi = Re(A(t) exp(i omega t)), omega = k v, with the
   amplitude A = (B0 w / k) exp(-k g) of eq 3's model (times sinhc(x) for a face tilted across
   its width, derive/distributed.py), which varies slowly with the pose.
2. The periodic state is I = Re(J(t) exp(i omega t)) with J = H0 A + H1 A' + O(A''): putting
   it into the circuit equation and matching the terms in A and A' gives
   H0 = i omega / (R + i omega L) (eq 3's steady response) and H1 = R / (R + i omega L)^2 (the
   first-order Taylor term of H0 in omega: the sidebands omega +- Omega of a modulation at
   Omega seen to first order).
3. The force on the array along a coordinate q of the array relative to the circuit is
   -<I dPhi/dq> over a period (the sign of L I' + R I = Phi' folded in): along the gap,
   dPhi/dg = -k Phi, and along the track, dPhi/dxi = i k Phi (phasor). With
   <Re(a e^{i w t}) Re(b e^{i w t})> = Re(a conj(b))/2 and rho = A'/A (the log-amplitude
   rate):

       lift = (k/2) A^2 (Re H0 + rho Re H1),   drag = (k/2) A^2 (Re(-i H0) + rho Re(-i H1))

   that is lift = F_eq3 (1 + tau_d rho), drag = D_eq3 (1 + tau_D rho) with

       tau_d = R (R^2 - omega^2 L^2) / ((R^2 + omega^2 L^2) omega^2 L),
       tau_D = -2 L R / (R^2 + omega^2 L^2).

   For the point law rho = -k g' (g' the face-centre gap rate), so the lift carries
   -c g' with c = k F_eq3 tau_d: positive (damping) below v_c = R / (k L) and negative
   (the Inductrack's negative damping) above it.
4. Distributed law: circuit j has rho_j = -k (g_c' + beta' t_j) + L(x) x' (x = k alpha w/2,
   derive/distributed.py's notation). Its force is F0_j (1 + tau_d rho_j) with F0_j the
   quasi-static force of circuit j; summed over the array the lift is
   F_array (1 + tau_d rho_bar) with rho_bar = -k g_c' + L(x) x' + (N L(N y) - L(y)) y'/2
   (= half the rate of ln F_array along the motion at a fixed speed), acting at the
   quasi-static point of action, plus a couple about the across-face axis from the spread of
   rho_j along the array: sum_j (t_j - t_bar) F0_j tau_d rho_j = F_array tau_d sigma with
   sigma = -k beta' var_t, var_t = (p^2/4) (N^2 L'(N y) - L'(y)) (the variance of the
   circuit positions under the load's weights; p^2 (N^2 - 1)/12 untilted). The drag's rate
   part has the same structure with tau_D. The current is one per circuit, so the spread
   across the width (which follows the field, not the lag) keeps its quasi-static centroid.

Assumptions and validity:

- The speed is constant over a modulation period (v'/v << omega); only the pose modulates
  the amplitude.
- Slow modulation: the error of the expansion is its next term. For a modulation at Omega,
  the rate coefficient projected on the gap rate over whole periods (the damping) differs from
  the exact sideband response by at most (Omega L)^2 / (R^2 + omega^2 L^2) of its scale
  |R / (R + i omega L)^2| Omega (the odd Taylor terms cancel in the projection; checked
  against the sideband solution over 0.5-40 m/s). For the LLNL circuit at Omega = 45 rad/s
  (the heave/pitch frequencies) that is under 0.6 % at any speed (the low-speed limit is
  (Omega L/R)^2). Relative to the coefficient itself the error exceeds 1 % only in
  6.6-11.4 m/s, where the coefficient passes through zero at v_c = 9.18 m/s, i.e. near
  lift-off (6.54 m/s); at 60 rad/s the band is up to 12.6 m/s. Below omega = Omega (v below
  Omega/k = 0.7 m/s, never in the envelope) the expansion fails altogether.
- First order in the rate: the model drops terms in (k g' L/|R + i omega L|)^2, below
  1e-4 for gap rates under 0.1 m/s; large transients (a touchdown) are outside its accuracy.
- The couple of the distributed law is exact to first order in the rates (it is linear in
  them); the circuits are at the face centre's speed, as in derive/distributed.py.
- The circuits under a face are taken at their positions t_j on it, as in
  derive/distributed.py. A track circuit is fixed in the track, so as the face slides over it
  with a slope beta along its length it also sees the convective rate k beta v; like the
  face's end effects (which eq 3 and derive/distributed.py neglect) it is left out: at the
  default trim (beta about 1e-3) it would change the lift by |tau_d k beta v| = 3e-4.
At rest (all rates zero) every rate term vanishes identically: trim is eq 3's.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import sympy as sp

from maglevgen.derive.distributed import face_axes, langevin, langevin_slope

__all__ = ["circuit_response", "distributed_lag", "drag_rate_per_circuit", "lift_rate_per_circuit"]



@dataclass(frozen=True)
class CircuitResponse:
    """The first-order periodic state of one circuit, in (R, L, omega) (positive symbols).

    ``H0``, ``H1``: J = H0 A + H1 A' (complex current amplitude); ``lift0``, ``lift1``,
    ``drag0``, ``drag1``: lift = (k/2) A^2 (lift0 + rho lift1), drag likewise, rho = A'/A;
    ``tau_lift`` = lift1/lift0 (tau_d), ``tau_drag`` = drag1/drag0 (tau_D)."""

    R: sp.Symbol
    L: sp.Symbol
    omega: sp.Symbol
    H0: sp.Expr
    H1: sp.Expr
    lift0: sp.Expr
    lift1: sp.Expr
    drag0: sp.Expr
    drag1: sp.Expr
    tau_lift: sp.Expr
    tau_drag: sp.Expr


@lru_cache(maxsize=1)
def circuit_response() -> CircuitResponse:
    """Solve L I' + R I = Phi' for Phi = Re(A(t) e^{i omega t}) to first order in A'.

    Steps 1-3 of the module docstring: the trial J = H0 A + H1 A' is put into the circuit
    equation, A'' (second order) dropped, the coefficients of A and A' set to zero and solved
    for H0, H1; the period-averaged forces are -<I dPhi/dq> along the gap and the track."""
    R, L, w = sp.symbols("R L omega", positive=True)
    t = sp.Symbol("t", real=True)
    A = sp.Function("A", real=True)(t)
    H0, H1 = sp.symbols("H0 H1")
    J = H0 * A + H1 * A.diff(t)
    phase = sp.exp(sp.I * w * t)
    residual = sp.expand((L * (J * phase).diff(t) + R * J * phase - (A * phase).diff(t))
                         / phase)
    residual = residual.subs(A.diff(t, 2), 0)  # second order in the modulation rate
    a, ad = sp.symbols("a a_dot")
    residual = sp.expand(residual.subs(A.diff(t), ad).subs(A, a))
    sol = sp.solve([residual.coeff(a), residual.coeff(ad)], [H0, H1], dict=True)[0]
    h0, h1 = sp.simplify(sol[H0]), sp.simplify(sol[H1])

    def re(z: sp.Expr) -> sp.Expr:
        return sp.factor(sp.simplify(sp.re(sp.expand_complex(z))))

    # lift: -<I dPhi/dg>, dPhi/dg = Re(-k A e^{iwt}) -> (k/2) A^2 Re(H); drag: <I dPhi/dxi>,
    # dPhi/dxi = Re(i k A e^{iwt}) -> (k/2) A^2 Re(H conj(i)) = (k/2) A^2 Re(-i H)
    lift0, lift1 = re(h0), re(h1)
    drag0, drag1 = re(-sp.I * h0), re(-sp.I * h1)
    return CircuitResponse(R, L, w, h0, h1, lift0, lift1, drag0, drag1,
                           sp.factor(sp.simplify(lift1 / lift0)),
                           sp.factor(sp.simplify(drag1 / drag0)))


def _coefficient(expr: sp.Expr, inductance: sp.Expr, resistance: sp.Expr,
                 omega: sp.Expr) -> sp.Expr:
    cr = circuit_response()
    return expr.xreplace({cr.R: resistance, cr.L: inductance, cr.omega: omega})


def lift_rate_per_circuit(B0: sp.Expr, width: sp.Expr, wavenumber: sp.Expr,
                          inductance: sp.Expr, resistance: sp.Expr, gap: sp.Expr,
                          speed: sp.Expr, log_rate: sp.Expr) -> sp.Expr:
    """The lift's first-order term, F_eq3 tau_d rho = (B0^2 w^2 / (2k)) e^{-2kg} Re(H1) rho.

    Written without tau_d's 1/omega^2 (Re H1 = R (R^2 - omega^2 L^2) / (R^2 + omega^2 L^2)^2),
    so it is finite at v = 0; ``log_rate`` is rho = A'/A (1/s)."""
    c = _coefficient(circuit_response().lift1, inductance, resistance, wavenumber * speed)
    return (B0**2 * width**2 / (2 * wavenumber) * c * sp.exp(-2 * wavenumber * gap)
            * log_rate)


def drag_rate_per_circuit(B0: sp.Expr, width: sp.Expr, wavenumber: sp.Expr,
                          inductance: sp.Expr, resistance: sp.Expr, gap: sp.Expr,
                          speed: sp.Expr, log_rate: sp.Expr) -> sp.Expr:
    """The drag's first-order term, D_eq3 tau_D rho = (B0^2 w^2 / (2k)) e^{-2kg} Re(-i H1) rho
    (Re(-i H1) = -2 omega L R^2 / (R^2 + omega^2 L^2)^2)."""
    c = _coefficient(circuit_response().drag1, inductance, resistance, wavenumber * speed)
    return (B0**2 * width**2 / (2 * wavenumber) * c * sp.exp(-2 * wavenumber * gap)
            * log_rate)


def magnetic_damping_per_circuit(B0: sp.Expr, width: sp.Expr, wavenumber: sp.Expr,
                                 inductance: sp.Expr, resistance: sp.Expr, gap: sp.Expr,
                                 speed: sp.Expr) -> sp.Expr:
    """c = -d(lift)/d(g') of one circuit of the point law (rho = -k g'): k F_eq3 tau_d, in
    N s/m; negative (the lift pushes along the gap's rate) above v_c = R/(k L)."""
    g_rate = sp.Symbol("g_rate", real=True)
    lift = lift_rate_per_circuit(B0, width, wavenumber, inductance, resistance, gap, speed,
                                 -wavenumber * g_rate)
    return -sp.diff(lift, g_rate)


def tilt_rates(normal: sp.Matrix, R: sp.Matrix, omega: sp.Matrix) -> tuple[sp.Expr, sp.Expr]:
    """(alpha', beta'): rates of the gap's slopes across and along a face, alpha = n . R e_s,
    beta = n . R e_t (derive/distributed.py), with R' = R [omega]x (omega in body axes)."""
    e_s, e_t = face_axes(normal)
    return ((normal.T * R * omega.cross(e_s))[0], (normal.T * R * omega.cross(e_t))[0])


@dataclass(frozen=True)
class DistributedLag:
    """The rates of the distributed law (step 4 of the module docstring).

    ``log_rate``: rho_bar, the load-weighted mean of the circuits' log-amplitude rates (1/s);
    ``spread``: sigma = -k beta' var_t (m^2/s): the couple of the rate part about the face's
    across axis is (rate force at rho = sigma) along e_t x (force direction)."""

    log_rate: sp.Expr
    spread: sp.Expr


def distributed_lag(normal: sp.Matrix, R: sp.Matrix, omega: sp.Matrix, alpha: sp.Expr,
                    beta: sp.Expr, centre_gap_rate: sp.Expr, wavenumber: sp.Expr,
                    width: sp.Expr, pitch: sp.Expr, circuits: sp.Expr) -> DistributedLag:
    """rho_bar and sigma of a tilted face (``alpha``, ``beta``: its gap slopes, from
    derive.distributed.distributed_load) moving with ``centre_gap_rate`` and body rates
    ``omega``."""
    alpha_rate, beta_rate = tilt_rates(normal, R, omega)
    x = wavenumber * alpha * width / 2
    y = wavenumber * beta * pitch
    log_rate = (-wavenumber * centre_gap_rate + langevin(x) * wavenumber * width / 2 * alpha_rate
                + (circuits * langevin(circuits * y) - langevin(y)) * wavenumber * pitch
                * beta_rate / 2)
    var_t = pitch**2 / 4 * (circuits**2 * langevin_slope(circuits * y) - langevin_slope(y))
    return DistributedLag(log_rate, -wavenumber * beta_rate * var_t)
