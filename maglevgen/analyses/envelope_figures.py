"""The envelope's figures: the stability map across speed and the disk margins' curves."""

from __future__ import annotations

import io

import numpy as np

from maglevgen.analyses.envelope import Envelope, LoopMargins
from maglevgen.controllers import controller as registered_controller
from maglevgen.controllers import title as controller_title

__all__ = ["disk_margins_png", "stability_map_png"]


def stability_map_png(env: Envelope) -> bytes:
    """Largest real part against speed, one line per controller, zero marked (PNG bytes)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with plt.rc_context({"font.size": 9}):
        fig, ax = plt.subplots(figsize=(7, 4))
        ax.axhspan(0, 1e9, color="#f6d5d5", lw=0, label="unstable (real part > 0)")
        ax.axhline(0.0, color="k", lw=0.8)
        for n, c in env.controllers.items():  # the registry's styles: coinciding lines show
            ax.plot(env.speeds, c.max_real, marker=".", ms=3, label=f"{controller_title(n)}",
                    **registered_controller(n).style)
        ax.set_yscale("symlog", linthresh=1e-2)
        top = max(1.0, max(float(np.nanmax(c.max_real[np.isfinite(c.max_real)], initial=0))
                           for c in env.controllers.values()) * 2)
        # most damped line (the embedded controller's, far left of zero) half a decade
        # inside the frame, not on it
        bottom = min(-1.0, min(float(np.nanmin(c.max_real[np.isfinite(c.max_real)], initial=0))
                               for c in env.controllers.values()) * 5)
        ax.set_ylim(bottom, top)
        ax.set_xlim(env.speeds[0], env.speeds[-1])
        ax.set_xlabel(r"speed $v$ / (m/s)")
        ax.set_ylabel(r"largest $\mathrm{Re}\,s$ of the closed loop / s$^{-1}$")
        ax.grid(True, lw=0.3)
        ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=8)
        ax.set_title("Stability across the envelope (symmetric log scale)")
        fig.subplots_adjust(left=0.11, right=0.7, bottom=0.12, top=0.92)
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=110, metadata={"Software": None})
        plt.close(fig)
    return buf.getvalue()


def disk_margins_png(margins: LoopMargins) -> bytes:
    """The embedded loop's balanced disk margin against frequency at each margin speed, in
    phase (2 atan(alpha/2)): every array force at once (multi-loop, solid) and the weakest
    channel alone (dashed), the spec's min_disk_phase_margin marked (PNG bytes)."""
    limit = margins.min_phase
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def phase(alpha: np.ndarray) -> np.ndarray:
        return np.degrees(2 * np.arctan(np.minimum(alpha, 1e6) / 2))

    with plt.rc_context({"font.size": 9}):
        fig, ax = plt.subplots(figsize=(7, 4))
        colours = plt.cm.viridis(np.linspace(0, 0.9, len(margins.speeds)))
        for v, c, col in zip(margins.speeds, margins.curves, colours, strict=True):
            ax.semilogx(c.omega, phase(c.alpha_multi), color=col, lw=1.2,
                        label=f"{v:.4g} m/s, multi-loop")
            i = c.worst_loop()
            ax.semilogx(c.omega, phase(c.alpha_loops[i]), color=col, lw=0.8, ls="--",
                        label=f"{v:.4g} m/s, {margins.channels[i]} alone")
        ax.axhline(limit, color="tab:red", lw=0.8, label=f"spec: {limit:g} deg")
        ax.set_ylim(0, 90)
        ax.set_xlabel(r"frequency $\omega$ / (rad/s)")
        ax.set_ylabel("disk margin in phase / deg")
        ax.grid(True, lw=0.3, which="both")
        ax.legend(loc="center left", bbox_to_anchor=(1.01, 0.5), fontsize=7)
        ax.set_title("Disk margins at the actuators (balanced, broken at each array force)")
        fig.subplots_adjust(left=0.09, right=0.68, bottom=0.12, top=0.92)
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=110, metadata={"Software": None})
        plt.close(fig)
    return buf.getvalue()

