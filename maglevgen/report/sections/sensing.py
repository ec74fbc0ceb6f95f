"""Section: sensors and estimation (issue 49). The measurement equations (derive/sensors.py),
the sensor set of ``[sensors]``, observability and the Kalman filter across the envelope
(maglevgen.analyses.sensing, the envelope's `SensingCheck`), the embedded loop's disk margins
against frequency (envelope_figures.disk_margins_png), and the noisy holds of the
output-feedback loop (maglevgen.analyses.output_feedback) the build ran."""

from __future__ import annotations

from collections.abc import Sequence
from functools import cache
from typing import Any

import numpy as np
import sympy as sp

from maglevgen.analyses.envelope_figures import disk_margins_png
from maglevgen.control.estimation import SensorLayout
from maglevgen.derive import conventions as cv
from maglevgen.derive.rigid_body import rotation_body_to_inertial
from maglevgen.derive.sensors import GapSensorSymbols, gap_reading
from maglevgen.report.display import ltx, matrix_tex
from maglevgen.report.format import fcolumn, fnum, tex_escape, tex_unit, tex_verdict

__all__ = ["gap_jacobian", "sensing_section"]

DISK_MARGIN_FIGURE = "fig_disk_margins.png"

#: the speeds of the envelope's grid the section's table shows (both ends among them)
TABLE_SPEEDS = 6


@cache
def gap_jacobian() -> tuple[sp.Matrix, sp.Matrix, sp.Matrix]:
    """(J, b, n): dd/d(y, z, phi, theta, psi) of a gap sensor's reading
    (derive.sensors.gap_reading) at the design pose, for a sensor at body point b on a face
    of unit normal n (SymPy; |n| = 1 substituted), and the symbols b, n."""
    b = sp.Matrix(sp.symbols("b_x b_y b_z", real=True))
    n = sp.Matrix(sp.symbols("n_x n_y n_z", real=True))
    x = sp.Matrix(sp.symbols(" ".join(cv.STATE_NAMES), real=True))
    R = rotation_body_to_inertial(*x[cv.ATTITUDE])
    d = gap_reading(GapSensorSymbols(b, n, sp.Symbol("g_0", positive=True)), x[cv.POSITION, 0],
                    R)
    J = sp.Matrix([d]).jacobian(x[cv.AXIS_COORDINATES, 0]).subs({s: 0 for s in x})
    unit = n[0] ** 2 + n[1] ** 2 + n[2] ** 2
    return J.applyfunc(lambda e: sp.factor(sp.simplify(e * unit))), b, n


def gap_jacobian_tex() -> str:
    """`gap_jacobian`'s row as a bmatrix."""
    return matrix_tex(gap_jacobian()[0], ltx)


def _sensor_rows(params, layout: SensorLayout) -> list[dict[str, str]]:
    """One row per reading: name, what it reads, where, its noise (1 sigma at the tick)."""
    sd = np.sqrt(layout.variances)
    rows = []
    n_gap = len(layout.gaps)
    for i, name in enumerate(layout.names):
        if i < n_gap:
            g = layout.gaps[i]
            what = f"gap to the track, array {g.array}'s face"
            where = ", ".join(fnum(v, 4) for v in g.point)
            unit = "m"
        elif name.startswith("gyro"):
            what, where, unit = f"body rate {name[-1]}", "IMU", "rad/s"
        elif name.startswith("accel"):
            what, where, unit = f"specific force along body {name[-1]}", "IMU", "m/s^2"
        else:
            what, where, unit = "position along the track", "--", "m"
        rows.append({"name": tex_escape(name), "what": tex_escape(what),
                     "where": tex_escape(where), "noise": fnum(float(sd[i]), 3),
                     "unit": tex_unit(unit)})
    if layout.imu_point is not None:
        for r in rows:
            if r["where"] == "IMU":
                r["where"] = "IMU at " + ", ".join(fnum(v, 3) for v in layout.imu_point)
    return rows


def sensing_section(carriage, env, holds: Sequence[Any] = ()) -> tuple[dict[str, Any],
                                                                        dict[str, bytes]]:
    """The section's context and its figures ({} where the envelope has no sensing check,
    i.e. the file has no [sensors]: the context says so)."""
    params = carriage.params
    sc = env.sensing
    files: dict[str, bytes] = {}
    embedded = params.envelope.embedded_controller
    margins = env.controllers[embedded].margins if embedded in env.controllers else None
    if margins is not None:
        files[DISK_MARGIN_FIGURE] = disk_margins_png(margins)
    ctx: dict[str, Any] = {
        "present": sc is not None,
        "jacobian": gap_jacobian_tex(),
        "margins": None if margins is None else {
            "figure": DISK_MARGIN_FIGURE, "text": tex_verdict(margins.text())},
    }
    if sc is None:
        return ctx, files
    layout = SensorLayout.of(params)
    pick = np.unique(np.linspace(0, sc.speeds.size - 1, min(TABLE_SPEEDS, sc.speeds.size))
                     .round().astype(int))
    k = {s: sc.states.index(s) for s in cv.Q_STATES}
    cols = {
        "speed": fcolumn(sc.speeds[pick], 4),
        "smallest": fcolumn(sc.smallest[pick], 4),
        "gain": fcolumn(sc.gain_norm[pick], 3),
        "y": fcolumn(1e6 * sc.error_std[pick, k["y"]], 3),
        "z": fcolumn(1e6 * sc.error_std[pick, k["z"]], 3),
        "phi": fcolumn(1e6 * sc.error_std[pick, k["phi"]], 3),
        "theta": fcolumn(1e6 * sc.error_std[pick, k["theta"]], 3),
        "psi": fcolumn(1e6 * sc.error_std[pick, k["psi"]], 3),
        "zeta": fcolumn(sc.min_damping[pick], 3),
        "lev": fcolumn(-sc.levitation_real[pick], 4),
    }
    speed_rows = [{key: v[j] for key, v in cols.items()} | {"rank": int(sc.rank[i])}
                  for j, i in enumerate(pick)]
    ends = [0, sc.speeds.size // 2, sc.speeds.size - 1]
    p_cols = [fcolumn(sc.error_std[i], 3) for i in ends]
    p_rows = [{"state": ltx(sp.Symbol(s)), "cells": [c[j] for c in p_cols]}
              for j, s in enumerate(sc.states)]
    hold_rows = []
    for h in holds:
        ratio = max(h.estimation_rms[s] / h.estimation_predicted[s] for s in cv.Q_STATES
                    if h.estimation_predicted[s] > 0)
        hold_rows.append({
            "speed": fnum(h.speed, 4), "scale": fnum(h.noise_scale, 2),
            "rms": fnum(float(np.max(h.force_rms)), 3),
            "share": fnum(100 * h.worst_share, 2),
            "peak": fnum(float(np.max(h.force_peak)), 3),
            "budget": fnum(100 * float(np.max(h.at_budget)), 2),
            "gap": fnum(1e3 * h.min_gap, 4), "gap_rms": fnum(1e6 * float(np.max(h.gap_rms)), 3),
            "att": fnum(1e6 * max(h.attitude_rms.values()), 3), "ratio": fnum(ratio, 2),
            "settled": "yes" if h.settled else "no"})
    ctx.update({
        "sensors": _sensor_rows(params, layout),
        "described": tex_escape(sc.sensors),
        "n_states": sc.n_states,
        "speeds": speed_rows,
        "p_speeds": [fnum(float(sc.speeds[i]), 4) for i in ends],
        "p_rows": p_rows,
        "observability": tex_verdict(sc.observability_text()),
        "loop_subject": tex_verdict(sc.loop_subject()),
        "loop": tex_verdict(sc.loop_text()),
        "holds": hold_rows,
        "hold_t": fnum(holds[0].t_end, 3) if holds else None,
        "budget": fnum(params.control.spec.force_budget, 4),
        "disturbance": {"force": fnum(params.sensors.disturbance.force, 3),
                        "moment": fnum(params.sensors.disturbance.moment, 3)},
        "tau_ms": fnum(1e3 * params.actuators.time_constant, 3),
    })
    return ctx, files
