"""What `maglevgen simulate` writes: trajectories (CSV, .npz), figs 3-8 (PNG) and the metrics.

Every writer returns bytes keyed by file name; the caller writes them at once (atomically).
Column names and units come from derive/conventions.py and the model's input names.
"""

from __future__ import annotations

import io
import json
import zipfile
from collections.abc import Sequence

import numpy as np

from maglevgen.analyses.simulate import (
    DISTURBANCE_DOC,
    FINAL_SHARE,
    SETTLING_BAND,
    Trajectory,
    disturbance_doc,
    metrics,
)
from maglevgen.controllers import controller as registered_controller
from maglevgen.controllers import title as controller_title
from maglevgen.derive import conventions as cv
from maglevgen.infrastructure.columns import fcolumn_plain
from maglevgen.infrastructure.workers import Shared, child, submit

__all__ = ["FIGURES", "FIGURE_NAMES", "PEAK_WINDOW", "ZOOM_SECONDS", "columns", "figure_png",
           "render_figures", "render_metrics", "render_results", "render_trajectories",
           "speed_figure_png", "trajectory_names", "travel_departure"]

# The paper's figures: (file, title, [(state, scale, axis label)], figures reproduced)
FIGURES: tuple[tuple[str, str, tuple[tuple[str, float, str], ...], str], ...] = (
    ("levitation_pitch.png", "Levitation height and pitch",
     (("z", 1e3, r"heave $z - z_0$ / mm"), ("theta", 1e3, r"pitch $\theta - \theta_0$ / mrad")),
     "figs 3, 5, 7"),
    ("travel_roll.png", "Travel distance and roll",
     # the travel: each run's departure from the reference travel (`travel_departure`)
     (("x", 1e3, r"travel $x - x_\mathrm{ref}$ / mm"),
      ("phi", 1e3, r"roll $\phi - \phi_0$ / mrad")), "fig 4"),
    # the paper's figs 6 and 8 plot lateral position and pitch; pitch is drawn once, in the
    # first figure, and this one carries the remaining axis, yaw
    ("lateral_yaw.png", "Lateral position and yaw",
     (("y", 1e3, r"lateral $y - y_0$ / mm"), ("psi", 1e3, r"yaw $\psi - \psi_0$ / mrad")),
     "figs 6, 8 (their pitch: the first figure)"),
)
PLOT_POINTS = 4000  # samples per line at most (decimated evenly; the run keeps every step)
ZOOM_SECONDS = 1.5  # the left column: the raw response over the first seconds
PEAK_WINDOW = 0.05  # [s] the right column: the largest |deviation| in windows this long
PEAK_FLOOR = 1e-6  # the envelope's log axis reaches down to this fraction of its largest


def _style(controller: str) -> dict:
    """The registry's line style of a controller (maglevgen.control), so that coinciding
    responses stay distinguishable (dashes, widths), drawn in registration order."""
    return dict(registered_controller(controller).style)


def _label(traj: Trajectory) -> str:
    name = controller_title(traj.controller)
    if traj.event:
        name += " (contact)" if traj.status == "contact" else f" ({traj.status})"
    return name


def _series(traj: Trajectory, state: str) -> np.ndarray:
    if state in _AXIS_OF_STATE:
        return traj.axis_deviation[:, _AXIS_OF_STATE[state]]
    return traj.x[:, cv.STATE_INDEX[state]]


def peak_envelope(t: np.ndarray, y: np.ndarray, window: float) -> tuple[np.ndarray, np.ndarray]:
    """(window centres, largest |y| in each window of ``window`` seconds): the envelope of an
    oscillating response, readable where the raw trace over many periods is a solid band."""
    dt = float(t[1] - t[0]) if t.size > 1 else window
    n = max(1, round(window / dt))
    k = t.size // n
    if k == 0:
        return t[:1], np.abs(y[:1])
    peaks = np.max(np.abs(y[: k * n]).reshape(k, n), axis=1)
    centres = t[: k * n].reshape(k, n).mean(axis=1)
    return centres, peaks
_AXIS_OF_STATE = {s: i for i, s in enumerate(("y", "z", "phi", "theta", "psi"))}


def columns(input_names: Sequence[str], n_gaps: int) -> list[tuple[str, str]]:
    """(name, unit) of every trajectory column."""
    cols = [("t", "s")] + [(s.name, s.unit) for s in cv.STATES]
    cols += [(n, "N") for n in input_names]
    cols += [(f"gap_{i + 1}", "m") for i in range(n_gaps)]
    return cols


def table(traj: Trajectory) -> np.ndarray:
    return np.column_stack([traj.t, traj.x, traj.u, traj.gaps])


def trajectory_csv(traj: Trajectory, input_names: Sequence[str]) -> bytes:
    cols = columns(input_names, traj.gaps.shape[1])
    buf = io.StringIO()
    buf.write(f"# maglevgen simulate: controller {traj.controller} "
              f"({controller_title(traj.controller)}), dt {traj.dt:g} s, status {traj.status}"
              f"{'; ' + traj.event if traj.event else ''}\n")
    buf.write(f"# initial disturbance: {disturbance_doc(traj.disturbance)}\n")
    buf.write(",".join(f"{n} [{u}]" for n, u in cols) + "\n")
    buf.write(csv_rows(table(traj)))
    return buf.getvalue().encode()


def csv_rows(data: np.ndarray, fmt: str = "%.10e") -> str:
    """The rows of ``data`` as np.savetxt(delimiter=",", fmt=fmt) writes them, formatted in
    one call (savetxt formats row by row in Python: this takes about a tenth less time)."""
    row = ",".join([fmt] * data.shape[1]) + "\n"
    return (row * data.shape[0]) % tuple(data.ravel().tolist())


NPZ_LEVEL = 1


def trajectories_npz(trajs: Sequence[Trajectory], input_names: Sequence[str]) -> bytes:
    """One archive: ``<controller>`` (n x columns) per run, plus the column names and units."""
    cols = columns(input_names, trajs[0].gaps.shape[1])
    arrays = {t.controller: table(t) for t in trajs}
    arrays["columns"] = np.array([n for n, _ in cols])
    arrays["units"] = np.array([u for _, u in cols])
    buf = io.BytesIO()
    # np.savez stamps the current time into the zip entries; fixed stamps keep it reproducible.
    # Level 1: floating-point samples deflate to 82% at any level, and level 1 takes a quarter
    # less time than the default 6 for 0.7% more bytes.
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, arr in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            npy = io.BytesIO()
            np.lib.format.write_array(npy, np.asanyarray(arr), allow_pickle=False)
            zf.writestr(info, npy.getvalue(), zipfile.ZIP_DEFLATED, NPZ_LEVEL)
    return buf.getvalue()


def travel_departure(traj: Trajectory) -> np.ndarray:
    """x - x_ref [m]: the travel's departure from the reference travel, x_ref the run's first
    x plus the integral of the reference speed (the speed loop's v_ref, else the trim speed):
    every run travels 200 m in 10 s within a few decimetres, so x itself draws one line."""
    ref = traj.speed_reference
    v = np.full(traj.t.size, traj.op.speed) if ref is None else np.asarray(ref, dtype=float)
    along = traj.x[:, cv.STATE_INDEX["x"]]
    x_ref = along[0] + np.concatenate(([0.0], np.cumsum(0.5 * (v[1:] + v[:-1])
                                                        * np.diff(traj.t))))
    return along - x_ref


def figure_png(trajs: Sequence[Trajectory], title: str,
               panels: tuple[tuple[str, float, str], ...], figs: str) -> bytes:
    """One row per state: the raw response over the first ZOOM_SECONDS (left) and the peak
    envelope over the whole run on a log axis (right), every controller in its registry
    style; the travel (a state whose runs coincide to a few parts in a thousand) one subplot
    per controller of its departure from the reference travel (`travel_departure`), so that
    no line hides another (deterministic PNG bytes)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t_end = max((float(t.t[-1]) for t in trajs), default=0.0)
    zoom = min(ZOOM_SECONDS, t_end) or ZOOM_SECONDS
    with plt.rc_context({"svg.hashsalt": "maglevgen", "font.size": 9}):
        fig = plt.figure(figsize=(9, 2.6 * len(panels)))
        grid = fig.add_gridspec(len(panels), 2, left=0.08, right=0.8, bottom=0.1, top=0.88,
                                hspace=0.45, wspace=0.3)
        legend_from = None
        bottom = []
        for row, (state, scale, label) in enumerate(panels):
            if state not in _AXIS_OF_STATE:  # the travel: one subplot per controller
                sub = grid[row, :].subgridspec(1, max(len(trajs), 1), wspace=0.55)
                for k, traj in enumerate(trajs):
                    cx = fig.add_subplot(sub[0, k])
                    every = max(1, traj.t.size // PLOT_POINTS)
                    cx.plot(traj.t[::every], travel_departure(traj)[::every] * scale,
                            label=_label(traj), **_style(traj.controller))
                    cx.set_title(_label(traj), fontsize=7)
                    cx.set_xlim(0, t_end or 1.0)
                    cx.tick_params(labelsize=7)
                    cx.grid(True, lw=0.3)
                    cx.set_xlabel(r"$t$ / s", fontsize=7)
                    if k == 0:
                        cx.set_ylabel(label)
                continue
            ax, bx = fig.add_subplot(grid[row, 0]), fig.add_subplot(grid[row, 1])
            legend_from = legend_from or (ax, bx)
            top = 0.0
            for traj in trajs:
                y = _series(traj, state) * scale
                near = traj.t <= zoom
                every = max(1, int(np.count_nonzero(near)) // PLOT_POINTS)
                ax.plot(traj.t[near][::every], y[near][::every], label=_label(traj),
                        **_style(traj.controller))
                tc, peak = peak_envelope(traj.t, y, PEAK_WINDOW)
                top = max(top, float(np.max(peak, initial=0.0)))
                bx.plot(tc, np.maximum(peak, 1e-300), **_style(traj.controller))
            ax.set_ylabel(label)
            ax.set_xlim(0, zoom)
            bx.set_xlim(0, t_end or 1.0)
            symbol, _, unit = label.partition(" / ")
            bx.set_yscale("log")
            if top > 0:
                bx.set_ylim(top * PEAK_FLOOR, top * 2)
            bx.set_ylabel(f"peak |{symbol.split(' ', 1)[-1]}| / {unit}")
            bx.set_title(f"peak over {PEAK_WINDOW * 1e3:g} ms windows, whole run", fontsize=9)
            ax.set_title(f"first {zoom:g} s", fontsize=9)
            for a in (ax, bx):
                a.grid(True, lw=0.3)
            if row == len(panels) - 1:
                bottom += [ax, bx]
        for a in bottom:
            a.set_xlabel(r"time $t$ / s")
        if legend_from is not None:  # beside the axes, not over the responses
            legend_from[1].legend(*legend_from[0].get_legend_handles_labels(),
                                  loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8)
        fig.suptitle(f"{title} (paper {figs})")
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=110, metadata={"Software": None})
        plt.close(fig)
    return buf.getvalue()


def _loop_figures(m: dict) -> str:
    """The speed error and the time at the force budget, where the run had them."""
    out = ""
    if m.get("speed_gain") and m.get("speed_error") is not None:
        out += f"; largest speed error after 1 s {m['speed_error']:.3%}"
    if m.get("force_budget"):
        out += f"; {m.get('saturated_time', 0.0):.3g} s at the force budget"
    return out


def metrics_markdown(all_metrics: Sequence[dict], disturbance: str = DISTURBANCE_DOC,
                     speed_mode: dict | None = None) -> str:
    """One table per controller: settling time, peak deviation, RMS control per axis;
    ``speed_mode``: `SpeedMode.to_json` at the run's speed, whose sentence says why the speed
    drifts under the held propulsion."""
    launch = bool(all_metrics) and all_metrics[0].get("scenario") == "launch"
    first = all_metrics[0] if all_metrics else {}
    speed_loop = bool(first.get("speed_gain"))
    tick = first.get("tick")
    how = (f"The controller runs at a {tick['rate']:g} Hz tick, its command applied "
           f"{tick['delay']} tick(s) after sampling and held in between"
           if tick else "The controller is evaluated at every RK4 stage (continuous)")
    if tick and tick.get("actuator_lag"):
        how += (" (the firmware tick's law, each controller's gains on the loop as built); "
                "each array's control force follows its command through a "
                f"{tick['actuator_lag'] * 1e3:g} ms first-order lag")
    if first.get("force_budget"):
        how += f"; each array's control force is limited to {first['force_budget']:g} N"
    how += ". "
    k_i = (tick or {}).get("speed_integral") or 0.0
    integral = (f", k_i = {k_i:.4g} N/m on the speed error's integral, clamped at "
                f"{tick['integral_limit']:g} N" if tick and k_i > 0 else "")
    scenario = how + (
        "Launch: from the accelerating trim at the envelope's v_min the carriage accelerates "
        "to v_max under that trim's propulsion (its drag plus m a); the gains, the reference "
        "(the accelerating trim at the current speed) and the drag follow the gain schedule "
        "at the measured speed"
        + (f", and a speed loop (k_v = {first['speed_gain']:.4g} N s/m{integral}) tracks the "
           "commanded speed ramp." if speed_loop else ".")
        if launch else
        (f"The propulsion holds the speed: the trim drag as feedforward and a speed loop "
         f"(k_v = {first['speed_gain']:.4g} N s/m{integral}) on the forward speed."
         if speed_loop else
         "The propulsion force is held at its trim value; the along-track speed is not "
         "controlled and drifts" + (f": {speed_mode['explanation']}." if speed_mode else ".")))
    lines = ["# Closed-loop simulation metrics", "",
             f"Initial disturbance: {disturbance}. {scenario} Deviations are measured "
             "from the trim at the current speed. Status: 'contact' (a gap reached "
             "track.min_gap), 'diverging' (non-finite, or the peak deviation grows from the "
             "first quarter of the run to the last, beyond 5 % of the default disturbance, "
             "where the linearised closed loop is not stable: a stable one's growth over a "
             "short run is its transient, and a noise floor is not growth), 'settled' "
             "(every axis settles) or 'not settled'. Settling time: the first time after "
             "which the deviation stays about its final value (its mean over the run's last "
             f"{FINAL_SHARE:.0%}) within {SETTLING_BAND:.0%} of its largest excursion from "
             f"it, or within {SETTLING_BAND:.0%} of the default disturbance where that is "
             "larger (the sensors' noise keeps a run jittering: a small disturbance's 5 % is "
             "below that jitter); 'not settled' when it never does or does only within those "
             f"last {FINAL_SHARE:.0%}. A steady offset from the "
             "trim is the final deviation, not a failure to settle.", ""]
    for m in all_metrics:
        lines += [f"## {controller_title(m['controller'])} (`{m['controller']}`)", "",
                  f"Status: {m['status']}" + (f" ({m['event']})" if m["event"] else "")
                  + f"; {m['steps']} steps of {m['dt']:g} s to t = {m['t_end']:g} s; smallest "
                  f"gap {m['min_gap'] * 1e3:.3f} mm; speed {m['speed_start']:.4f} -> "
                  f"{m['speed_end']:.4f} m/s; RMS array control force "
                  f"{m['rms_array_force']:.4g} N" + _peak_forces(m) + _loop_figures(m)
                  + ".", ""]
        if m.get("spec"):
            lines += [f"Against [control.spec]: {m['spec']['verdict']}.", ""]
        lines += ["| axis | settling time [s] | peak deviation | final deviation | "
                  "RMS control force/moment |", "| --- | --- | --- | --- | --- |"]
        axes = list(m["axes"].items())
        # each column in one notation (no 0.00158 above 4.89e-04); a deviation decayed below
        # 1e-12 is printed as that bound, not as its digits
        peaks = fcolumn_plain([a["peak_deviation"] for _, a in axes])
        shown = [a["final_deviation"] for _, a in axes if abs(a["final_deviation"]) >= 1e-12]
        finals = iter(fcolumn_plain(shown, 3))
        rms = fcolumn_plain([a["rms_control"] for _, a in axes])
        for j, (axis, a) in enumerate(axes):
            ts = "not settled" if a["settling_time"] is None else f"{a['settling_time']:.3f}"
            final = "< 1e-12" if abs(a["final_deviation"]) < 1e-12 else next(finals)
            unit = a["force_unit"].replace("*", " ")  # N m: a '*' would start emphasis
            lines.append(f"| {axis} ({a['state']}) | {ts} | {peaks[j]} {a['unit']} | "
                         f"{final} {a['unit']} | {rms[j]} {unit} |")
        lines.append("")
    return "\n".join(lines)


FIGURE_NAMES: tuple[str, ...] = tuple(f[0] for f in FIGURES)


def render_figures(trajs: Sequence[Trajectory]) -> dict[str, bytes]:
    """The PNG figures of a simulation run (figs 3-8; a launch also against speed)."""
    out = {name: figure_png(trajs, title, panels, figs) for name, title, panels, figs in FIGURES}
    if trajs and trajs[0].scenario == "launch":
        out[SPEED_FIGURE] = speed_figure_png(trajs)
    return out


SPEED_FIGURE = "against_speed.png"


def speed_figure_png(trajs: Sequence[Trajectory]) -> bytes:
    """Heave, pitch and roll deviations against the speed of a launch (PNG bytes): the raw
    response over the first ZOOM_SECONDS (left) and the peak envelope over the whole launch on
    a log axis (right, as `figure_png`), so that runs which settle to zero, and runs ringing
    for seconds, stay apart."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = (("z", 1e3, r"$z - z_0$ / mm"),
              ("theta", 1e3, r"$\theta - \theta_0$ / mrad"),
              ("phi", 1e3, r"$\phi - \phi_0$ / mrad"))
    with plt.rc_context({"font.size": 9}):
        fig, axes = plt.subplots(len(panels), 2, figsize=(9, 6.4), squeeze=False)
        for (ax, bx), (state, scale, label) in zip(axes, panels, strict=True):
            top = 0.0
            for traj in trajs:
                y = traj.axis_deviation[:, _AXIS_OF_STATE[state]] * scale
                near = traj.t <= ZOOM_SECONDS
                every = max(1, int(np.count_nonzero(near)) // PLOT_POINTS)
                ax.plot(traj.speed[near][::every], y[near][::every],
                        label=controller_title(traj.controller)
                        + (f" ({traj.status})" if traj.status == "contact" else ""),
                        **_style(traj.controller))
                tc, peak = peak_envelope(traj.t, y, PEAK_WINDOW)
                top = max(top, float(np.max(peak, initial=0.0)))
                bx.plot(np.interp(tc, traj.t, traj.speed), np.maximum(peak, 1e-300),
                        **_style(traj.controller))
            ax.set_ylabel(label)
            bx.set_yscale("log")
            if top > 0:
                bx.set_ylim(top * PEAK_FLOOR, top * 2)
            symbol, _, unit = label.partition(" / ")
            bx.set_ylabel(f"peak |{symbol}| / {unit}")
            for a in (ax, bx):
                a.grid(True, lw=0.3)
        axes[0, 0].set_title(f"first {ZOOM_SECONDS:g} s of the launch", fontsize=9)
        axes[0, 1].set_title(f"peak over {PEAK_WINDOW * 1e3:g} ms windows, whole launch",
                             fontsize=9)
        axes[0, 1].legend(*axes[0, 0].get_legend_handles_labels(), loc="upper left",
                          bbox_to_anchor=(1.02, 1.0), fontsize=8)
        for a in axes[-1]:
            a.set_xlabel("speed $v$ / (m/s)")
        fig.suptitle("Launch: deviations from the scheduled trim against speed")
        fig.subplots_adjust(left=0.08, right=0.8, bottom=0.08, top=0.9, hspace=0.3,
                            wspace=0.3)
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=110, metadata={"Software": None})
        plt.close(fig)
    return buf.getvalue()


def _peak_forces(m: dict) -> str:
    """'; peak array force 3: 1.2 N, ...' of a run's metrics ('' without them)."""
    peaks = m.get("peak_array_force") or {}
    return ("; peak array control force " + ", ".join(f"{a}: {f:.4g} N" for a, f in
                                                      peaks.items())) if peaks else ""


def render_results(trajs: Sequence[Trajectory], input_names: Sequence[str],
                   header: dict) -> dict[str, bytes]:
    """Every output file of a simulation run; the figures are drawn in a child process
    (maglevgen.infrastructure.workers) while this one writes the trajectories and metrics."""
    with child(shared={"trajectories": trajs}) as drawing:
        figures = submit(drawing, "drawing the figures", render_figures, Shared("trajectories"))
        files = {**render_metrics(trajs, header), **render_trajectories(trajs, input_names)}
        return {**files, **figures.result()}


NPZ_FILE = "trajectories.npz"


def trajectory_file(traj: Trajectory) -> str:
    """The CSV file of one run."""
    return f"trajectory_{traj.controller}.csv"


def render_trajectories(trajs: Sequence[Trajectory], input_names: Sequence[str]
                        ) -> dict[str, bytes]:
    """The trajectories: one CSV per run and one .npz archive of all."""
    files = {trajectory_file(t): trajectory_csv(t, input_names) for t in trajs}
    files[NPZ_FILE] = trajectories_npz(trajs, input_names)
    return files


def render_metrics(trajs: Sequence[Trajectory], header: dict) -> dict[str, bytes]:
    """metrics.json and metrics.md: settling time, peak deviation and RMS control per axis."""
    all_metrics = [metrics(t) for t in trajs]
    doc = disturbance_doc(trajs[0].disturbance) if trajs else DISTURBANCE_DOC
    return {"metrics.json": (json.dumps({**header, "disturbance": doc, "runs": all_metrics},
                                        indent=2) + "\n").encode(),
            "metrics.md": (metrics_markdown(all_metrics, doc, header.get("speed_mode"))
                           + "\n").encode()}


def trajectory_names(trajs: Sequence[Trajectory]) -> tuple[str, ...]:
    """The names `render_trajectories` produces."""
    return (*map(trajectory_file, trajs), NPZ_FILE)
