"""Section: the pole map: open loop, the damping control, the per-axis LQR on the coupled
linearisation, the coupled LQR and the embedded controller, from the data of `maglevgen
gains`."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["POLE_FIGURE", "pole_sets"]

POLE_FIGURE = "pole_map.png"


def pole_sets(gains: dict) -> dict[str, Any]:
    """name -> list of (real, imag) poles in 1/s; the open loop per axis from m s^2 + k = 0."""
    open_loop: list[tuple[float, float]] = []
    for a in gains["axes"].values():
        for z in np.roots([a["inertia"], 0.0, a["stiffness"]]):
            open_loop.append((float(z.real), float(z.imag)))
    c = gains["coupled"]
    return {
        "open loop (per axis)": sorted(open_loop),
        "damping control": [tuple(p) for p in c["poles_damping"]],
        "per-axis LQR": [tuple(p) for p in c["poles_per_axis_design"]],
        "coupled LQR": [tuple(p) for p in c["poles_coupled_lqr"]],
        f"{gains['embedded']['title']} (embedded)":
            [tuple(p) for p in gains["embedded"]["closed_loop_poles"]],
    }
