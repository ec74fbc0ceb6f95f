"""The report's own figures (matplotlib, PNG bytes), drawn from plain numbers.

Kept apart from maglevgen.report so that the process that draws them (`maglevgen build`'s
drawing worker, or the report's own child process) imports matplotlib and numpy only, not
SymPy. Axis labels are symbol and unit; legends sit outside the data.
"""

from __future__ import annotations

import io
from typing import Any, cast

import numpy as np

__all__ = ["damping_figure", "force_figures", "pole_map"]

def _rc_without_cycle() -> Any:
    """_RC less its colour cycle (typed Any: matplotlib's stub wants Literal keys)."""
    return {k: v for k, v in _RC.items() if k != "axes.prop_cycle"}


_RC: dict[str, Any] = {
    "font.family": "DejaVu Sans",
    "font.size": 9,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "lines.linewidth": 1.4,
    "figure.dpi": 100,
    "savefig.dpi": 150,
    "path.simplify": False,
    "svg.hashsalt": "maglevgen",
    "axes.prop_cycle": None,
}


def _png(fig) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=150, metadata={"Software": None})
    return buf.getvalue()


def force_figures(curves: dict[str, Any]) -> dict[str, bytes]:
    """Force-versus-gap and force-versus-speed curves of the force law (PNG bytes), drawn
    from `force_curves`."""
    import matplotlib as mpl
    from cycler import cycler
    from matplotlib.figure import Figure

    rc = dict(_RC)
    rc["axes.prop_cycle"] = cycler(color=["#1f77b4", "#d62728", "#2ca02c", "#9467bd"])
    c = curves
    n_c, speed, v_c = c["circuits"], c["speed"], c["v_c"]
    out = {}
    with mpl.rc_context(cast(Any, rc)):  # matplotlib's stub: Literal keys
        fig = Figure(figsize=(6.0, 3.4))
        ax = fig.add_subplot()
        ax.plot(c["gap"] * 1e3, c["lift_gap"], label=f"lift, {n_c:g} circuits")
        ax.plot(c["gap"] * 1e3, c["drag_gap"], label=f"drag, {n_c:g} circuits")
        for xy in c["dots"]:
            ax.plot(*xy, "k.", ms=6)
        for xy, label in c["labels"]:
            ax.annotate(label, xy, textcoords="offset points", xytext=(6, 6), fontsize=7)
        ax.set_xlabel(r"gap $\delta$ / mm")
        ax.set_ylabel(r"force per array $F$ / N")
        ax.set_title(f"Eq 3 at {speed:g} m/s; dots: arrays at trim")
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
        fig.tight_layout()
        out["fig_force_gap.png"] = _png(fig)

        fig = Figure(figsize=(6.0, 3.4))
        ax = fig.add_subplot()
        ax.plot(c["v"], c["lift_v"], label="lift")
        ax.plot(c["v"], c["drag_v"], label="drag")
        ax.axvline(v_c, color="0.4", ls=":", lw=1)
        ax.axvline(speed, color="0.4", ls="--", lw=1)
        ax.annotate(r"$v_c$", (v_c, 0), textcoords="offset points", xytext=(3, 3), fontsize=8)
        ax.annotate("V", (speed, 0), textcoords="offset points", xytext=(3, 3), fontsize=8)
        ax.set_xlabel(r"speed $v$ / (m/s)")
        ax.set_ylabel(r"force per array $F$ / N")
        ax.set_title(f"Eq 3 at the nominal gap {c['nominal_gap'] * 1e3:g} mm, {n_c:g} circuits")
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
        fig.tight_layout()
        out["fig_force_speed.png"] = _png(fig)
    return out


_POLE_STYLE = {"open loop (per axis)": ("x", "#7f7f7f"), "damping control": ("s", "#2ca02c"),
               "per-axis LQR": ("o", "#1f77b4"), "coupled LQR": ("^", "#d62728")}


def pole_map(sets: dict[str, list[tuple[float, float]]]) -> bytes:
    """The poles of each set in the complex plane (PNG bytes), with lines of constant damping
    ratio; the legend outside the axes."""
    import math

    import matplotlib as mpl
    from matplotlib.figure import Figure

    with mpl.rc_context(_rc_without_cycle()):
        fig = Figure(figsize=(6.4, 3.8))
        ax = fig.add_subplot()
        reach = max((math.hypot(*p) for ps in sets.values() for p in ps), default=1.0) * 1.1
        for zeta in (0.2, 0.5, 0.707, 0.9):
            ang = math.acos(zeta)
            for sgn in (1, -1):
                ax.plot([0, -reach * zeta], [0, sgn * reach * math.sin(ang)], color="0.8",
                        lw=0.8, ls="--", zorder=0)
            ax.annotate(f"$\\zeta$={zeta:g}", (-reach * zeta, reach * math.sin(ang)),
                        fontsize=6, color="0.5")
        for name, ps in sets.items():  # the embedded controller (any other set): diamonds
            marker, color = _POLE_STYLE.get(name, ("D", "#9467bd"))
            ax.plot([p[0] for p in ps], [p[1] for p in ps], marker, color=color, ms=5,
                    ls="none", label=name, mfc="none" if marker in "os^" else color)
        ax.axhline(0, color="0.5", lw=0.6)
        ax.axvline(0, color="0.5", lw=0.6)
        ax.set_xlabel(r"real part $\mathrm{Re}\,s$ / s$^{-1}$")
        ax.set_ylabel(r"imaginary part $\mathrm{Im}\,s$ / s$^{-1}$")
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
        fig.tight_layout()
        return _png(fig)


def damping_figure(d: dict[str, Any]) -> bytes:
    """Two panels (PNG bytes): the magnetic damping of each axis against speed, one line style
    per circuit model (solid the first, dashed the second of ``d["models"]``), and each
    controller's largest closed-loop real part with either model; drawn from the circuit lag
    section's plain numbers."""
    import matplotlib as mpl
    from matplotlib.figure import Figure

    colors = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e"]
    controller_colors = d.get("colors") or colors  # the registry's, where the caller gives them
    styles = dict(zip(d["models"], ("-", "--"), strict=True))
    with mpl.rc_context(_rc_without_cycle()):
        fig = Figure(figsize=(7.0, 6.4))
        ax, bx = fig.subplots(2, 1)
        for i, label in enumerate(d["axes"]):
            for name, ls in styles.items():
                ax.plot(d["speeds"], d["damping"][name][:, i], ls=ls, color=colors[i],
                        label=f"{label}, {name}")
        ax.axhline(0, color="k", lw=0.7)
        for x, lab in ((d["v_c"], "$v_c$"), (d["speed"], "V")):
            if d["speeds"][0] <= x <= d["speeds"][-1]:
                ax.axvline(x, color="0.4", ls=":", lw=1)
                ax.annotate(lab, (x, 0), textcoords="offset points", xytext=(3, 3))
        ax.set_yscale("symlog", linthresh=1e-2)
        ax.set_xlabel(r"speed $v$ / (m/s)")
        ax.set_ylabel(r"magnetic damping $c_i = -m_i A_{ii}$")
        ax.set_title("Magnetic damping per axis (generated C, Jacobian at trim)")
        _colour_and_style_legend(ax, list(d["axes"]), colors, styles)
        for j, title in enumerate(d["controllers"]):
            for name, ls in styles.items():
                bx.plot(d["envelope_speeds"][name], d["max_real"][name][j], ls=ls,
                        color=controller_colors[j], label=f"{title}, {name}")
        bx.axhline(0, color="k", lw=0.7)
        bx.set_yscale("symlog", linthresh=1e-2)
        bx.set_xlabel(r"speed $v$ / (m/s)")
        bx.set_ylabel(r"largest $\mathrm{Re}\,s$ / s$^{-1}$")
        bx.set_title("Envelope with (solid) and without (dashed) the circuits' lag")
        lows = [float(np.nanmin(np.asarray(v, dtype=float))) for v in d["max_real"].values()]
        bx.set_ylim(bottom=min(-1.0, 5 * min(lows)))  # the most damped line inside the frame
        _colour_and_style_legend(bx, list(d["controllers"]), controller_colors, styles)
        fig.subplots_adjust(left=0.1, right=0.66, hspace=0.35, top=0.95, bottom=0.08)
        return _png(fig)


def _colour_and_style_legend(ax, names: list[str], colors: list[str],
                             styles: dict[str, str]) -> None:
    """One legend entry per colour (the axis or controller) and one per line style (the
    model), at a size readable in print, instead of one per combination."""
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color=colors[i], label=n) for i, n in enumerate(names)]
    handles += [Line2D([], [], color="0.3", ls=ls, label=m) for m, ls in styles.items()]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0,
              fontsize=8)
