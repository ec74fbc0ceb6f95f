"""The report's own figures (matplotlib, PNG bytes), drawn from plain numbers.

Kept apart from maglevgen.report so that the process that draws them (`maglevgen build`'s
drawing worker, maglevgen.background) imports matplotlib and numpy only, not SymPy.
"""

from __future__ import annotations

import io
from typing import Any

_RC = {
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
    with mpl.rc_context(rc):
        fig = Figure(figsize=(6.0, 3.4))
        ax = fig.add_subplot()
        ax.plot(c["gap"] * 1e3, c["lift_gap"], label=f"lift, {n_c:g} circuits")
        ax.plot(c["gap"] * 1e3, c["drag_gap"], label=f"drag, {n_c:g} circuits")
        for xy in c["dots"]:
            ax.plot(*xy, "k.", ms=6)
        for xy, label in c["labels"]:
            ax.annotate(label, xy, textcoords="offset points", xytext=(6, 6), fontsize=7)
        ax.set_xlabel("gap [mm]")
        ax.set_ylabel("force per array [N]")
        ax.set_title(f"Eq 3 at {speed:g} m/s; dots: arrays at trim")
        ax.legend()
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
        ax.set_xlabel("speed [m/s]")
        ax.set_ylabel("force per array [N]")
        ax.set_title(f"Eq 3 at the nominal gap {c['nominal_gap'] * 1e3:g} mm, {n_c:g} circuits")
        ax.legend()
        fig.tight_layout()
        out["fig_force_speed.png"] = _png(fig)
    return out
