"""Section: simulation."""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ...errors import InputError
from ..format import fnum, tex_breakable, tex_escape

# PNGs written by `maglevgen simulate --out DIR`, with the paper's figures they correspond to.
SIMULATION_FIGURES: tuple[tuple[str, str], ...] = (
    ("levitation_pitch.png", "Levitation height and pitch (the paper's figs 3, 5 and 7)."),
    ("travel_roll.png", "Travel distance and roll (the paper's fig 4)."),
    ("lateral_pitch.png", "Lateral position and pitch (the paper's figs 6 and 8)."),
)

Simulation = Path | Mapping[str, bytes | str] | None


def _simulation(source: Simulation, params_sha256: str | None = None
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
                "axes": rows,
            }
        )
    scalars = {k: v for k, v in data.items() if k not in ("runs", "disturbance")}
    disturbance = data.get("disturbance")
    growth = data.get("fastest_closed_loop_growth")
    return {
        "metrics": _flatten_metrics(scalars)[:40],
        "runs": runs,
        "disturbance": disturbance if isinstance(disturbance, str) else "",
        "growth": float(growth) if isinstance(growth, int | float) else None,
    }


def _speeds(run: Any) -> tuple[float, float] | None:
    """(speed at the start, at the end) of a run, when metrics.json gives them."""
    a, b = run.get("speed_start"), run.get("speed_end")
    return (float(a), float(b)) if isinstance(a, int | float) and isinstance(b, int | float) \
        else None


def _flatten_metrics(data: Any, prefix: str = "") -> list[tuple[str, str]]:
    """(dotted key, LaTeX value) of the scalar leaves of a JSON document, in its order."""
    if isinstance(data, dict):
        return [row for k, v in data.items() for row in _flatten_metrics(v, f"{prefix}{k}.")]
    if isinstance(data, list):
        if (
            all(isinstance(v, int | float) and not isinstance(v, bool) for v in data)
            and len(data) <= 6
        ):
            return [(prefix.rstrip("."), "$(" + ",\\ ".join(fnum(v, 4) for v in data) + ")$")]
        return [row for i, v in enumerate(data) for row in _flatten_metrics(v, f"{prefix}{i}.")]
    if isinstance(data, bool) or data is None:
        return [(prefix.rstrip("."), tex_escape(json.dumps(data)))]
    if isinstance(data, int | float):
        return [(prefix.rstrip("."), f"${fnum(data, 6)}$")]
    return [(prefix.rstrip("."), tex_breakable(data))]


