"""Section: the track circuits' lag (derive/circuit_lag.py): the derivation, the magnetic
damping per axis against speed (the generated C's Jacobians) and the envelope with and
without it."""

from __future__ import annotations

import io
from typing import Any

import numpy as np
import sympy as sp

from ...derive import conventions as cv
from ...derive.circuit_lag import circuit_response
from ...envelope import compute_envelope
from ...library import simulation_library
from ...magnetic_damping import damping_across_speed
from ...operating import CONTROLLER_TITLES
from ..display import eq

__all__ = ["CIRCUIT_LAG_FIGURE", "circuit_lag", "damping_figure"]

CIRCUIT_LAG_FIGURE = "circuit_lag_damping.png"  # not fig_*: the force section takes those
_N_SPEEDS = 40
_UNITS = {"lateral": "N s/m", "vertical": "N s/m", "roll": "N m s/rad", "pitch": "N m s/rad",
          "yaw": "N m s/rad"}
MODELS = ("first-order", "quasi-static")


def _forms() -> dict[str, Any]:
    """The circuit equation's first-order solution in display symbols."""
    cr = circuit_response()
    R, L, w = sp.symbols("R L omega", positive=True)
    to = {cr.R: R, cr.L: L, cr.omega: w}
    v, k = sp.symbols("v k", positive=True)
    (v_c,) = sp.solve(sp.Eq(sp.numer(sp.together(cr.lift1)).xreplace(to).xreplace(
        {w: k * v}), 0), v)
    return {
        "H0": eq("H_0", cr.H0.xreplace(to)),
        "H1": eq("H_1", cr.H1.xreplace(to)),
        "tau_d": eq(r"\tau_d", cr.tau_lift.xreplace(to)),
        "tau_D": eq(r"\tau_D", cr.tau_drag.xreplace(to)),
        "v_c": eq("v_c", v_c),
    }


def _other(carriage):
    """The same carriage with the other circuit model."""
    now = carriage.params.model.circuit_dynamics
    return carriage.with_circuit_dynamics(MODELS[1 - MODELS.index(now)])


def circuit_lag(carriage, lib, env, gains: dict) -> tuple[dict[str, Any], bytes]:
    """The section's context and its figure (PNG bytes).

    ``env``: this carriage's envelope; the other circuit model's library and envelope are
    built here (one more derivation and compile when not cached); ``gains``:
    `summary.gains_report` (the controllers' rate gains at the design speed)."""
    other = _other(carriage)
    other_lib = simulation_library(other.structure)
    other_env = compute_envelope(other, other_lib)
    speeds = np.linspace(env.v_min, env.v_max, _N_SPEEDS)
    mine = damping_across_speed(carriage, lib, speeds)
    theirs = damping_across_speed(other, other_lib, speeds)
    now = carriage.params.model.circuit_dynamics
    curves = {now: mine, other.params.model.circuit_dynamics: theirs}
    V = carriage.params.operation.speed
    at_v = {n: damping_across_speed(c, lb, [V])[0]
            for n, c, lb in ((now, carriage, lib),
                             (other.params.model.circuit_dynamics, other, other_lib))}
    # entries below 1e-12 of the largest are round-off of a structural zero (the quasi-static
    # lateral: eq 3 has no lateral rate term at zero roll)
    scale = max(float(np.max(np.abs(c))) for c in at_v.values())
    at_v = {n: np.where(np.abs(c) < 1e-12 * scale, 0.0, c) for n, c in at_v.items()}
    axes = []
    for i, axis in enumerate(cv.AXES):
        g = gains["axes"][axis]
        axes.append({"axis": axis, "unit": _UNITS[axis],
                     "first_order": float(at_v["first-order"][i]),
                     "quasi_static": float(at_v["quasi-static"][i]),
                     "lqr_rate": float(g["K_closed_form"][1]),
                     "damping": float(g["damping_gain"])})
    envs = {now: env, other.params.model.circuit_dynamics: other_env}
    rows = [{"title": CONTROLLER_TITLES[n],
             "first_order": envs["first-order"].controllers[n].verdict,
             "quasi_static": envs["quasi-static"].controllers[n].verdict,
             "ok_first_order": envs["first-order"].controllers[n].ok,
             "ok_quasi_static": envs["quasi-static"].controllers[n].ok}
            for n in env.controllers]
    c = carriage.params.circuit
    k = carriage.params.wavenumber
    ctx = {"model": now, "figure": CIRCUIT_LAG_FIGURE, "speed": V, "axes": axes,
           "envelope": rows, "v_c_value": c.resistance / (k * c.inductance),
           "time_constant_ms": c.inductance / c.resistance * 1e3, **_forms()}
    figure = damping_figure(speeds, curves, V, ctx["v_c_value"],
                            {"first-order": envs["first-order"],
                             "quasi-static": envs["quasi-static"]})
    return ctx, figure


def damping_figure(speeds: np.ndarray, curves: dict[str, np.ndarray], speed: float,
                   v_c: float, envs: dict) -> bytes:
    """Two panels: the magnetic damping of each axis against speed (solid first-order, dashed
    quasi-static), and each controller's largest real part with and without the lag."""
    import matplotlib as mpl
    from matplotlib.figure import Figure

    colors = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e"]
    with mpl.rc_context({"font.size": 8, "axes.grid": True, "grid.alpha": 0.3}):
        fig = Figure(figsize=(7.0, 6.4))
        ax, bx = fig.subplots(2, 1)
        for i, axis in enumerate(cv.AXES):
            for name, ls in (("first-order", "-"), ("quasi-static", "--")):
                ax.plot(speeds, curves[name][:, i], ls=ls, color=colors[i],
                        label=f"{axis} ({_UNITS[axis]}), {name}")
        ax.axhline(0, color="k", lw=0.7)
        for x, lab in ((v_c, "$v_c$"), (speed, "V")):
            if speeds[0] <= x <= speeds[-1]:
                ax.axvline(x, color="0.4", ls=":", lw=1)
                ax.annotate(lab, (x, 0), textcoords="offset points", xytext=(3, 3))
        ax.set_yscale("symlog", linthresh=1e-2)
        ax.set_xlabel(r"speed $v$ / (m/s)")
        ax.set_ylabel(r"magnetic damping $c_i = -m_i A_{ii}$")
        ax.set_title("Magnetic damping per axis (generated C, Jacobian at trim)")
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0, fontsize=6)
        for j, n in enumerate(envs["first-order"].controllers):
            for name, ls in (("first-order", "-"), ("quasi-static", "--")):
                e = envs[name]
                bx.plot(e.speeds, e.controllers[n].max_real, ls=ls, color=colors[j],
                        label=f"{CONTROLLER_TITLES[n]}, {name}")
        bx.axhline(0, color="k", lw=0.7)
        bx.set_yscale("symlog", linthresh=1e-2)
        bx.set_xlabel(r"speed $v$ / (m/s)")
        bx.set_ylabel(r"largest $\mathrm{Re}\,s$ / s$^{-1}$")
        bx.set_title("Envelope with (solid) and without (dashed) the circuits' lag")
        bx.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0, fontsize=6)
        fig.subplots_adjust(left=0.1, right=0.62, hspace=0.35, top=0.95, bottom=0.08)
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=150, metadata={"Software": None})
    return buf.getvalue()
