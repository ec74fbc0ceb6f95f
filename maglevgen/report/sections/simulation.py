"""Section: simulation."""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from maglevgen.errors import InputError
from maglevgen.report.format import fnum, tex_breakable, tex_escape, tex_unit

__all__ = ["Simulation", "simulation_section"]

# PNGs written by `maglevgen simulate --out DIR`, with the paper's figures they correspond to.
SIMULATION_FIGURES: tuple[tuple[str, str], ...] = (
    ("levitation_pitch.png", "Levitation height and pitch (the paper's figs 3, 5 and 7)."),
    ("travel_roll.png", "Travel distance and roll (the paper's fig 4): every run travels the "
     "same 200 m to a few decimetres, so the travel is drawn one subplot per controller as its "
     "departure from the reference travel (the reference speed's integral)."),
    ("lateral_yaw.png", "Lateral position and yaw (the paper's figs 6 and 8 plot lateral "
     "position and pitch; pitch is in the first figure)."),
)

Simulation = Path | Mapping[str, bytes | str] | None

# metrics.json's keys (maglevgen.analyses.simulate.ScenarioRun.header, simulate.metrics) as the
# report
# names them: (LaTeX text, unit). A key not listed is shown in words, without its underscores.
METRIC_LABELS: dict[str, tuple[str, str]] = {
    "params_sha256": ("parameters (SHA-256 of the file and overrides)", ""),
    "scenario": ("scenario", ""),
    "speed": ("trim speed $V$", "m/s"),
    "release_speed": ("release speed of a launch", "m/s"),
    "propulsion_force": (r"propulsion force at trim $F_\mathrm{prop}$", "N"),
    "rk4_stability_limit": (r"largest stable RK4 step $\Delta t_\mathrm{max}$", "s"),
    "fastest_closed_loop_growth": ("fastest growing closed-loop pole (speed drift)", "1/s"),
    "growth_rate": ("growth rate of the run", "1/s"),
    "t_end": (r"simulated time $t_\mathrm{end}$", "s"),
    "dt": (r"time step $\Delta t$", "s"),
    "steps": ("time steps", ""),
    "min_gap": (r"smallest gap $\min \delta$", "m"),
    "speed_start": ("speed at the start", "m/s"),
    "speed_end": ("speed at the end", "m/s"),
    "speed_at_contact": ("speed at contact", "m/s"),
    "rms_array_force": ("RMS array control force", "N"),
    "max_abs": ("largest deviation", ""),
    "relative_to_peak": ("relative to its peak", ""),
}


def simulation_section(source: Simulation, params_sha256: str | None = None
                ) -> tuple[dict[str, Any], _Deferred]:
    """Figures and metrics of `maglevgen simulate`: its output folder, or its files in memory.

    A folder must come from the same parameters as the report (``params_sha256``, the digest
    its metrics.json records): a run of another carriage is refused, not shown as this one's.
    """
    empty = {
        "given": False,
        "figures": [],
        "missing": [],
        "metrics": [],
        "runs": [],
        "disturbance": "",
        "growth": None,
        "speed_mode": None,
    }
    if source is None:
        return empty, _Deferred({}, {})
    if isinstance(source, Mapping):
        where = "the simulation results"
        sim = source
    else:
        where = f"--simulation {source}"
        folder = Path(source)
        if not folder.is_dir():
            raise InputError(f"{where}: not a folder")
        names = [n for n, _ in SIMULATION_FIGURES] + ["metrics.json"]
        sim = {n: (folder / n).read_bytes() for n in names if (folder / n).is_file()}
    files: dict[str, str] = {}  # report file -> simulation file, read when the report is done
    figures, missing = [], []
    for name, caption in SIMULATION_FIGURES:
        if name in sim:
            files[f"sim_{name}"] = name
            figures.append({"file": f"sim_{name}", "caption": caption, "name": name})
        else:
            missing.append(name)
    if not figures:
        raise InputError(f"{where}: none of {', '.join(n for n, _ in SIMULATION_FIGURES)} found")
    ctx = {**empty, "given": True, "figures": figures, "missing": missing}
    if "metrics.json" in sim:
        try:
            data = json.loads(_as_bytes(sim["metrics.json"]).decode("utf-8"))
        except (UnicodeDecodeError, ValueError) as exc:
            raise InputError(f"{where}: metrics.json is not readable JSON ({exc})") from None
        made_with = data.get("params_sha256") if isinstance(data, dict) else None
        if params_sha256 is not None and made_with != params_sha256:
            raise InputError(f"{where}: made with other parameters (its metrics.json has "
                             f"params_sha256 {str(made_with)[:16]}..., this report's parameters "
                             f"{params_sha256[:16]}...)")
        ctx.update(_metrics(data))
    elif params_sha256 is not None:
        raise InputError(f"{where}: no metrics.json to tell which parameters it was made with")
    return ctx, _Deferred(sim, files)


@dataclass(frozen=True)
class _Deferred:
    """The simulation files the report includes, read only by ``read``: `maglevgen build` may
    still be rendering them in the background while the report's context is built."""

    sim: Mapping[str, bytes | str]
    names: dict[str, str]  # report file -> simulation file

    def read(self) -> dict[str, bytes]:
        return {out: _as_bytes(self.sim[name]) for out, name in self.names.items()}


def _as_bytes(data: bytes | str) -> bytes:
    return data.encode("utf-8") if isinstance(data, str) else data


def _metrics(data: Any) -> dict[str, Any]:
    """The tables of `maglevgen simulate`'s metrics.json: scalars, and per run and axis."""
    if not isinstance(data, dict):
        return {"metrics": _flatten_metrics(data)[:40]}
    runs = []
    for run in data.get("runs", []) if isinstance(data.get("runs"), list) else []:
        axes = run.get("axes", {}) if isinstance(run, dict) else {}
        if not isinstance(axes, dict):
            continue
        rows = []
        for axis, a in axes.items():
            if not isinstance(a, dict):
                continue
            rows.append(
                {
                    "axis": axis,
                    "state": a.get("state", ""),
                    "settling": a.get("settling_time"),
                    "peak": a.get("peak_deviation"),
                    "final": a.get("final_deviation"),
                    # a deviation decayed below 1e-12 prints as that bound (its column's
                    # notation is chosen from the others)
                    "final_shown": (None if not isinstance(a.get("final_deviation"), int | float)
                                    or abs(a["final_deviation"]) < 1e-12
                                    else a["final_deviation"]),
                    "unit": a.get("unit", ""),
                    "rms": a.get("rms_control"),
                    "force_unit": a.get("force_unit", ""),
                }
            )
        runs.append(
            {
                "controller": str(run.get("controller", "")),
                "status": str(run.get("status", "")),
                "event": str(run.get("event") or ""),
                "speeds": _speeds(run),
                "min_gap": _number(run.get("min_gap")),
                "rms_force": _number(run.get("rms_array_force")),
                "axes": rows,
            }
        )
    scalars = {k: v for k, v in data.items() if k not in ("runs", "disturbance", "speed_mode")}
    disturbance = data.get("disturbance")
    growth = data.get("fastest_closed_loop_growth")
    raw = data.get("runs")
    first = raw[0] if isinstance(raw, list) and raw and isinstance(raw[0], dict) else {}
    tick = first.get("tick") if isinstance(first.get("tick"), dict) else None
    return {
        "speed_gain": _number(first.get("speed_gain")) or None,
        "tick_rate": _number(tick.get("rate")) if tick else None,
        "delay_ticks": _number(tick.get("delay")) if tick else None,
        "actuator_lag": _number(tick.get("actuator_lag")) if tick else None,
        "speed_integral": _number(tick.get("speed_integral")) if tick else None,
        "integral_limit": _number(tick.get("integral_limit")) if tick else None,
        "force_budget": _number(first.get("force_budget")),
        "speed_mode": _speed_mode(data.get("speed_mode")),
        "metrics": _flatten_metrics(scalars)[:40],
        "runs": runs,
        "disturbance": disturbance if isinstance(disturbance, str) else "",
        "growth": float(growth) if isinstance(growth, int | float) else None,
    }


def _number(v: Any) -> float | None:
    return float(v) if isinstance(v, int | float) and not isinstance(v, bool) else None


_SPEED_MODE_NUMBERS = ("speed", "eigenvalue", "pole_trim", "pole_fixed_gaps", "pole_retrim")


def _speed_mode(mode: Any) -> dict[str, Any] | None:
    """The speed mode of metrics.json (`SpeedMode.to_json`), when it has every number shown."""
    if not (isinstance(mode, dict) and all(isinstance(mode.get(k), int | float)
                                           and not isinstance(mode.get(k), bool)
                                           for k in _SPEED_MODE_NUMBERS)):
        return None
    return {**{k: float(mode[k]) for k in _SPEED_MODE_NUMBERS},
            "controller": str(mode.get("controller", "")),
            "dominant": str(mode.get("dominant", ""))}


def _speeds(run: Any) -> tuple[float, float] | None:
    """(speed at the start, at the end) of a run, when metrics.json gives them."""
    a, b = run.get("speed_start"), run.get("speed_end")
    return (float(a), float(b)) if isinstance(a, int | float) and isinstance(b, int | float) \
        else None


def metric_label(key: str) -> str:
    """The LaTeX name of a dotted metrics.json key: each part by METRIC_LABELS (or in words),
    the unit of the last one in brackets."""
    parts = [p for p in key.split(".") if p]
    names = [METRIC_LABELS.get(p, (tex_escape(p.replace("_", " ")), ""))[0] for p in parts]
    unit = METRIC_LABELS.get(parts[-1], ("", ""))[1] if parts else ""
    return ", ".join(names) + (f" [{tex_unit(unit)}]" if unit else "")


def _flatten_metrics(data: Any, prefix: str = "") -> list[tuple[str, str]]:
    """(LaTeX name with unit, LaTeX value) of the scalar leaves of a JSON document, in its
    order (`metric_label` names them)."""
    if isinstance(data, dict):
        return [row for k, v in data.items() for row in _flatten_metrics(v, f"{prefix}{k}.")]
    key = metric_label(prefix.rstrip("."))
    if isinstance(data, list):
        if (
            all(isinstance(v, int | float) and not isinstance(v, bool) for v in data)
            and len(data) <= 6
        ):
            return [(key, "$(" + ",\\ ".join(fnum(v, 4) for v in data) + ")$")]
        return [row for i, v in enumerate(data) for row in _flatten_metrics(v, f"{prefix}{i}.")]
    if data is None:
        return [(key, "---")]
    if isinstance(data, bool):
        return [(key, "yes" if data else "no")]
    if isinstance(data, int | float):
        return [(key, f"${fnum(data, 6)}$")]
    return [(key, tex_breakable(data))]
