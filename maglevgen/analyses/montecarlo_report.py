"""The Monte-Carlo study's statistics and report: aggregate, summary, Markdown, plots, tables."""

from __future__ import annotations

import io
import math
from typing import Any

import numpy as np

from maglevgen.analyses.montecarlo_study import Columns, Study
from maglevgen.analyses.sim_loop import LoopSetting, SensedTick
from maglevgen.analyses.simulate import RUN_STATUSES
from maglevgen.controllers import controller as registered_controller
from maglevgen.controllers import title as controller_title
from maglevgen.derive import conventions as cv
from maglevgen.params import ACTUATOR_LAG, LOOP_TOLERANCES

__all__ = ["CONTACT_CAUSES", "FAILURES", "SAMPLE_STATUSES", "STATUSES", "WORST", "Z95",
           "aggregate", "input_label", "markdown", "plots", "summary_json", "table", "table_files",
           "wilson"]

# statuses of a sample's run: the simulation's (RUN_STATUSES) and two of the sample itself
SAMPLE_STATUSES = ("rejected", "no trim")
STATUSES = RUN_STATUSES + SAMPLE_STATUSES
FAILURES = ("contact", "diverging", "generated code error")
Z95 = 1.959963984540054  # the 0.975 quantile of the standard normal
WORST = 5
CONTACT_CAUSES = ("starts in contact", "below lift-off", "levitation")


def table(rows: list[dict]) -> Columns:
    """Rows as columns (numbers as float64, the rest as str), in sample then controller order."""
    if not rows:
        return {}
    cols = {}
    for name in rows[0]:
        values = [r[name] for r in rows]
        if isinstance(values[0], str):
            cols[name] = np.array(values, dtype=str)
        elif name == "sample":
            cols[name] = np.array(values, dtype=np.int64)
        else:
            cols[name] = np.array(values, dtype=np.float64)
    return cols


def wilson(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion k/n (95 % by default)."""
    if n == 0:
        return (0.0, 1.0)
    p = k / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return (max(0.0, centre - half), min(1.0, centre + half))


def _quantiles(values: np.ndarray) -> dict[str, float | None]:
    v = values[np.isfinite(values)]
    if v.size == 0:
        return {"n": 0, "p5": None, "median": None, "p95": None, "max": None}
    q = np.percentile(v, [5, 50, 95])
    return {"n": int(v.size), "p5": float(q[0]), "median": float(q[1]), "p95": float(q[2]),
            "max": float(v.max())}


def _in_flight(status: np.ndarray, cause: np.ndarray, n_run: int) -> dict:
    """The contact probability (95 % Wilson interval) of the runs that did not start in
    contact: the loop's own failures, the starts in contact counted apart."""
    starts = int(np.sum((status == "contact") & (cause == CONTACT_CAUSES[0])))
    n = n_run - starts
    k = int(np.sum(status == "contact")) - starts
    lo, hi = wilson(k, n)
    return {"starts_in_contact": starts, "runs": n, "contacts": k,
            "probability": k / n if n else None, "ci95": [lo, hi]}


def aggregate(study: Study, cols: dict[str, np.ndarray]) -> dict:
    """Per controller: the status counts, the contact probability with its 95 % Wilson
    interval, settling time and peak deviation per axis, the worst samples and the
    correlation of failures with each sampled input."""
    out: dict[str, Any] = {}
    for c in study.controllers:
        sel = cols["controller"] == c
        status = cols["status"][sel]
        ran = np.isin(status, RUN_STATUSES)
        n_run = int(ran.sum())
        contact = int(np.sum(status == "contact"))
        fail = np.isin(status, FAILURES)
        lo, hi = wilson(contact, n_run)
        axes = {}
        for axis in cv.AXES:
            axes[axis] = {"settling_time": _quantiles(cols[f"settling_time.{axis}"][sel][ran]),
                          "peak_deviation": _quantiles(cols[f"peak.{axis}"][sel][ran]),
                          "final_deviation": _quantiles(cols[f"final.{axis}"][sel][ran])}
        corr = {}
        for name in study.columns:
            x = cols[name][sel][ran]
            y = fail[ran].astype(float)
            r = (float(np.corrcoef(x, y)[0, 1]) if x.size > 2 and np.std(x) > 0
                 and np.std(y) > 0 else 0.0)
            corr[name] = r
        ranked = sorted(corr, key=lambda k: -abs(corr[k]))
        # worst: failures first, then by the smallest gap the run reached
        gap = cols["min_gap"][sel]
        order = np.lexsort((np.where(np.isfinite(gap), gap, np.inf), ~fail))
        worst = []
        idx = np.flatnonzero(sel)
        for j in order[:WORST]:
            if not ran[j]:
                continue
            i = idx[j]
            worst.append({"sample": int(cols["sample"][i]), "status": str(cols["status"][i]),
                          "reason": str(cols["reason"][i]),
                          "min_gap": float(cols["min_gap"][i]),
                          "inputs": {k: float(cols[k][i]) for k in study.columns}})
        mult = cols["region_multiple"][sel] if "region_multiple" in cols else np.array([])
        inside = (fail & (mult < 1)) if mult.size else np.zeros(0, bool)
        out[c] = {
            "title": controller_title(c), "samples": int(sel.sum()), "runs": n_run,
            # failures from inside the sampled region of attraction: contradictions of it
            "failures_inside_region": int(inside.sum()),
            "failures_inside_region_samples": [int(i) for i in
                                               cols["sample"][sel][inside][:WORST]],
            "status_counts": {s: int(np.sum(status == s)) for s in STATUSES},
            "contact_causes": {k: int(np.sum((status == "contact")
                                             & (cols["contact_cause"][sel] == k)))
                               for k in CONTACT_CAUSES},
            "contact_probability": contact / n_run if n_run else None,
            "contact_ci95": [lo, hi],
            # counted apart: the runs whose disturbed start was already in contact
            "contact_in_flight": _in_flight(status, cols["contact_cause"][sel], n_run),
            "failure_probability": int(fail.sum()) / n_run if n_run else None,
            "axes": axes,
            "failure_correlation": {k: corr[k] for k in ranked},
            "worst": worst,
        }
    return out


def _json_safe(o: Any) -> Any:
    """NaN and infinities (a diverged run's gap) as null: strict JSON."""
    if isinstance(o, dict):
        return {k: _json_safe(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_json_safe(v) for v in o]
    if isinstance(o, float) and not math.isfinite(o):
        return None
    return o


def summary_json(study: Study, n: int, agg: dict, timing: dict) -> dict:
    return _json_safe({
        "parameter_file": study.origin, "samples": n, "seed": study.seed,
        "t_end": study.t_end, "dt": study.dt, "speed_range": list(study.speed),
        "disturbance_amplitudes": dict(study.disturbance),
        "tolerances": {k: ({"normal": s} if not math.isnan(s) else {"uniform": h})
                       for k, s, h in zip(study.keys, study.sigma, study.half, strict=True)},
        "per_sample_seed": "numpy SeedSequence(seed, spawn_key=(sample,))",
        "controller_design": design_text(study),
        "confidence": "95 % Wilson score interval",
        "controllers": agg, "timing": timing,
    })


def design_text(study: Study) -> str:
    """How each sample's controller was designed and flown, in words (the module
    docstring)."""
    if isinstance(study.tick, SensedTick):
        loop = ("; flown by the firmware's sense tick on the sampled carriage's noisy "
                "readings, each sample's noise its own (--loop sensed)")
    elif isinstance(study.tick, LoopSetting):
        loop = "; flown by the firmware loop on the exact state (--loop firmware)"
    else:
        loop = "; the paper's law at every RK4 stage (--loop continuous)"
    if study.sensors:
        said = ", ".join(k for k, _ in study.sensors)
        loop += (f"; the sensors' tolerances ({said}) drawn per sample and read with, the "
                 "Kalman gains the design on the file's sensors"
                 if isinstance(study.tick, SensedTick) else
                 f"; the sensors' tolerances ({said}) drawn and recorded, not flown (the loop "
                 "reads the exact state)")
    lag = dict(study.loop_values).get(ACTUATOR_LAG)
    if lag is not None:
        loop += ((f"; the actuators' lag drawn per sample about {lag * 1e3:.3g} ms and flown "
                  "by the sampled plant, "
                  + ("the controller re-designed for it" if study.redesign else
                     "the firmware's K_lag, K_delay and lag prediction the design on the "
                     "file's"))
                 if isinstance(study.tick, LoopSetting) else
                 "; the actuators' lag drawn and recorded, not flown (the continuous law has "
                 "no lag)")
    if study.redesign:
        return ("redesigned per sample (--redesign): each sampled carriage re-trimmed and its "
                "controller re-designed for its own parameters, as if the firmware knew them"
                + loop)
    return ("as the firmware flies: the nominal carriage's design at each sample's speed (its "
            "gains, reference and feed-forward propulsion) on the sampled carriage" + loop)


def markdown(summary: dict) -> str:
    lines = ["# Monte-Carlo robustness", "",
             f"Controller: {summary['controller_design']}.", "",
             f"{summary['samples']} samples (seed {summary['seed']}) of {summary['t_end']:g} s "
             f"at dt = {summary['dt']:g} s, speed uniform in [{summary['speed_range'][0]:.4g}, "
             f"{summary['speed_range'][1]:.4g}] m/s; {summary['timing']['runs']} runs in "
             f"{summary['timing']['seconds']:.3g} s ({summary['timing']['runs_per_s']:.4g} "
             f"runs/s on {summary['timing']['workers']}).", "",
             "| controller | runs | contact probability (95 % CI) | failures | statuses |",
             "| --- | --- | --- | --- | --- |"]
    for c, a in summary["controllers"].items():
        p = a["contact_probability"]
        lo, hi = a["contact_ci95"]
        causes = ", ".join(f"{c} {k}" for c, k in a["contact_causes"].items() if k)
        counts = ", ".join(f"{s} {k}" + (f" ({causes})" if s == "contact" and causes else "")
                           for s, k in a["status_counts"].items() if k)
        pf = a["failure_probability"]
        rate = "-" if p is None else f"{p:.4f} [{lo:.4f}, {hi:.4f}]"
        fails = "-" if pf is None else f"{pf:.4f}"
        lines.append(f"| {a['title']} (`{c}`) | {a['runs']} | {rate} | {fails} | {counts} |")
    for c, a in summary["controllers"].items():
        lines += ["", f"## {a['title']} (`{c}`)", "",
                  "| axis | settling time p50 / p95 / max [s] | peak deviation p50 / p95 / max "
                  "| final deviation p50 / p95 / max |", "| --- | --- | --- | --- |"]
        for axis, q in a["axes"].items():
            def f(d: dict) -> str:
                return " / ".join("-" if d[k] is None else f"{d[k]:.4g}"
                                  for k in ("median", "p95", "max"))
            lines.append(f"| {axis} | {f(q['settling_time'])} | {f(q['peak_deviation'])} "
                         f"| {f(q['final_deviation'])} |")
        if a["failure_probability"]:
            lines += ["", "Correlation of failure (contact, diverging) with each sampled input "
                      "(Pearson, over the runs):", ""]
            lines += [f"- `{k}`: {r:+.3f}" for k, r in a["failure_correlation"].items()]
        else:  # a correlation with a constant is undefined, not zero
            lines += ["", "Correlation of failure with the sampled inputs: none to report (no "
                      "run made contact or diverged)."]
        inside = a.get("failures_inside_region", 0)
        lines += ["", f"Failures from inside the nominal carriage's sampled region of "
                  f"attraction (`region_multiple` < 1, maglevgen roa): {inside}"
                  + (" (samples " + ", ".join(map(str, a["failures_inside_region_samples"]))
                     + "): the region's contradictions" if inside else "") + "."]
        if a["worst"]:
            lines += ["", "Worst samples (failures first, then the smallest gap):", "",
                      "| sample | status | min gap [m] | inputs |", "| --- | --- | --- | --- |"]
            for w in a["worst"]:
                inputs = ", ".join(f"{k} = {v:.5g}" for k, v in w["inputs"].items())
                gap = "-" if w["min_gap"] is None else f"{w['min_gap']:.4g}"
                lines.append(f"| {w['sample']} | {w['status']} | {gap} | "
                             f"{inputs} |")
    return "\n".join(lines) + "\n"


def _png(fig) -> bytes:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, metadata={"Software": None})
    plt.close(fig)
    return buf.getvalue()


_ANGLES = ("phi", "theta", "psi")


def input_label(study: Study, name: str) -> str:
    """A sampled input's axis label, symbol and unit as the other figures have them: the hold
    speed, a state's initial deviation, or a parameter by its key (as the file's
    [tolerances.parameters] names it) and the key's unit."""
    if name == "speed":
        return r"hold speed $v$ / (m/s)"
    if name.startswith("disturbance."):
        state = name.removeprefix("disturbance.")
        sym = f"\\{state}" if state in _ANGLES else state
        unit = cv.STATES[cv.STATE_INDEX[state]].unit
        return rf"initial deviation $\Delta {sym}$ / {_unit_text(unit)}"
    from maglevgen.params import flatten, schema_unit, validate

    units = {e.name: e.unit for e in flatten(validate(study.data, study.origin))}
    if name in LOOP_TOLERANCES:  # the actuators' lag, a sensor's noise or bias: its schema's
        units[name] = schema_unit(name)
    unit = units.get(name, "")
    return f"{name} / {_unit_text(unit)}" if unit and unit != "1" else name


def _unit_text(unit: str) -> str:
    """A unit for an axis label: a compound one in parentheses (m/s -> (m/s)), * as a
    centred dot, ^2 as a superscript."""
    text = unit.replace("ohm", r"$\Omega$").replace("*", r"$\cdot$").replace("^2", r"$^2$")
    return f"({text})" if "/" in unit else text


def _registry_color(controller: str) -> str | None:
    """The controller's colour in the registry's line style (maglevgen.control)."""
    return registered_controller(controller).style.get("color")


def plots(study: Study, cols: dict[str, np.ndarray], agg: dict) -> dict[str, bytes]:
    """histograms.png (settling time and peak deviation per axis, one colour per
    controller) and failures.png (each controller's runs against its two inputs most
    correlated with failure, failures marked)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = {}
    with plt.rc_context({"font.size": 8}):
        fig, axs = plt.subplots(2, len(cv.AXES), figsize=(13, 5))
        for j, axis in enumerate(cv.AXES):
            unit = "m" if j < 2 else "rad"  # cv.AXES: lateral, vertical, then the angles
            for row, (key, label) in enumerate((("settling_time", r"settling time $t_s$ / s"),
                                                ("peak", f"peak deviation / {unit}"))):
                ax = axs[row, j]
                counts = []
                for c in study.controllers:
                    v = cols[f"{key}.{axis}"][cols["controller"] == c]
                    n_runs = v.size
                    v = v[np.isfinite(v)]  # a run that never settled has no settling time
                    if v.size:
                        ax.hist(v, bins=30, alpha=0.5, label=controller_title(c),
                                color=_registry_color(c))
                    counts.append(f"{controller_title(c)}: {v.size} of {n_runs}")
                # how many runs each histogram holds (the settling times: the settled runs)
                ax.text(0.98, 0.97, "\n".join(counts), transform=ax.transAxes, ha="right",
                        va="top", fontsize=6, bbox={"fc": "white", "alpha": 0.7, "lw": 0})
                ax.set_xlabel(label)
                ax.set_ylabel("runs")
                ax.set_title(axis)
        handles, labels = axs[0, 0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="upper center", ncol=max(1, len(labels)), fontsize=7,
                   bbox_to_anchor=(0.5, 1.0))  # above the panels, not over the bars
        fig.tight_layout(rect=(0, 0, 1, 0.93))
        files["histograms.png"] = _png(fig)
        n = len(study.controllers)
        fig, axs = plt.subplots(1, n, figsize=(4.5 * n, 4), squeeze=False)
        for ax, c in zip(axs[0], study.controllers, strict=True):
            sel = cols["controller"] == c
            ranked = list(agg[c]["failure_correlation"])
            kx, ky = [*ranked, "speed", "speed"][:2]
            fail = np.isin(cols["status"][sel], FAILURES)
            ax.scatter(cols[kx][sel][~fail], cols[ky][sel][~fail], s=6, c="tab:blue",
                       label="settled / not settled")
            ax.scatter(cols[kx][sel][fail], cols[ky][sel][fail], s=10, c="tab:red", marker="x",
                       label="contact / diverging")
            ax.set_xlabel(input_label(study, kx))
            ax.set_ylabel(input_label(study, ky))
            ax.set_title(controller_title(c))
        handles, labels = axs[0, 0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="upper center", ncol=2, fontsize=7,
                   bbox_to_anchor=(0.5, 1.0))  # above the panels, not over the points
        fig.tight_layout(rect=(0, 0, 1, 0.9))
        files["failures.png"] = _png(fig)
    return files


def table_files(cols: dict[str, np.ndarray]) -> dict[str, bytes]:
    """samples.parquet where pyarrow is installed, else samples.npz and samples.csv."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        buf = io.BytesIO()
        np.savez(buf, **cols)  # type: ignore[arg-type]  # numpy's stub types allow_pickle here
        names = list(cols)
        lines = [",".join(names)]
        for i in range(len(cols[names[0]])):
            lines.append(",".join(
                f'"{cols[k][i]}"' if cols[k].dtype.kind == "U" else repr(cols[k][i].item())
                for k in names))
        return {"samples.npz": buf.getvalue(), "samples.csv": ("\n".join(lines) + "\n").encode()}
    buf = io.BytesIO()
    pq.write_table(pa.table(cols), buf)
    return {"samples.parquet": buf.getvalue()}

