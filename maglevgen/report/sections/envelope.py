"""Section: envelope."""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any

import numpy as np

from maglevgen.analyses.envelope import (
    compute_envelope,
)
from maglevgen.analyses.envelope_figures import stability_map_png
from maglevgen.analyses.queries import displayed_gains, embedded_gains
from maglevgen.analyses.roa import (
    AXIS_NAMES,
    AXIS_UNITS,
    BUILD_SAMPLING,
    BUILD_SPEEDS,
    region_png,
    study,
)
from maglevgen.analyses.sim_loop import flown_loop
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.operating import STABILITY_MARGIN, closed_loop_stability
from maglevgen.controllers import controller as registered
from maglevgen.controllers import title as controller_title
from maglevgen.report.display import matrix_tex
from maglevgen.report.format import fcolumn, fnum, tex_escape
from maglevgen.report.sections.verification import Check

__all__ = ["ENVELOPE_FIGURE", "ROA_FIGURE", "envelope_checks", "envelope_context",
           "envelope_section", "roa_context", "roa_section"]

# ============================================================================ envelope

ENVELOPE_FIGURE = "envelope_stability_map.png"
ROA_FIGURE = "envelope_region_of_attraction.png"


def envelope_section(plant: Plant, given: tuple[Any, bytes] | None):
    """The envelope (maglevgen.analyses.envelope, through the compiled library) and its stability
    map:
    the caller's (``given``) when it has them (`maglevgen build`), else computed and drawn."""
    if given is not None:
        return given
    env = compute_envelope(plant)
    return env, stability_map_png(env)


def envelope_checks(plant: Plant, env) -> list[Check]:
    """Stability rows: each designed controller at the design speed and across the envelope
    (a row fails when the closed loop has an eigenvalue with real part >= -margin); the
    controllers other than the embedded one are findings about their design (`Check.finding`),
    not the toolchain's checks."""

    carriage = plant.carriage
    speed = carriage.params.operation.speed
    op = plant.point(speed)
    out = []
    embedded = carriage.params.envelope.embedded_controller
    # every controller that applies forces
    for name in [n for n in env.controllers if registered(n).tick_function is not None]:
        title = tex_escape(controller_title(name)) + (" (embedded)" if name == embedded else "")
        out.append(Check(
            f"{title}: closed loop at {speed:.4g} m/s (largest real part, 1/s)",
            "eigenvalues (numpy) of the C Jacobians with the gains and allocation",
            closed_loop_stability(op, name)[0], -STABILITY_MARGIN, unit="1/s",
            finding=name != embedded))
        out.append(Check(
            f"{title}: closed loop across [{env.v_min:.4g}, {env.v_max:.4g}] m/s (largest "
            "real part, 1/s)", f"the same at {env.speeds.size} speeds",
            float(np.max(env.controllers[name].max_real)), -STABILITY_MARGIN, unit="1/s",
            finding=name != embedded))
    return out


def _spec_context(carriage) -> dict[str, Any]:
    """[control.spec] as the report states it."""
    s = carriage.params.control.spec
    d = s.max_deviation
    return {"min_damping_ratio": s.min_damping_ratio, "min_decay_rate": s.min_decay_rate,
            "design_damping_ratio": s.min_damping_ratio + s.damping_margin,
            "force_budget": s.force_budget, "tick_rate": s.tick_rate,
            "delay_ticks": s.delay_ticks, "speed_bandwidth": s.speed_bandwidth,
            "speed_integral_ratio": s.speed_integral_ratio,
            "speed_integral_pole": s.speed_integral_ratio * s.speed_bandwidth,
            "speed_integral_limit": s.speed_integral_limit,
            "min_gap_margin": s.min_gap_margin,
            "deviation": {"y": d.y * 1e3, "z": d.z * 1e3, "phi": d.phi * 1e3,
                          "theta": d.theta * 1e3, "psi": d.psi * 1e3}}


def _gain_matrix(K) -> str:
    """A 5 x 5 gain matrix as a typeset bmatrix, 4 significant digits, the entries that are
    round-off of a zero (`summary.displayed_gains`, as `maglevgen gains` prints them) as 0."""
    return matrix_tex(displayed_gains(K), lambda v: "0" if v == 0 else fnum(v, 4))


def _embedded_context(plant: Plant, env, table: Mapping[str, Any]) -> dict[str, Any]:
    """The embedded controller in full: its weights (and, for `spec`, how they follow from
    ``[control.spec]``), its gains at v_min, the design speed and v_max (`gains --json`'s
    "embedded" entry at each, from the same code), the table schedule's error for its gains
    and its verdicts."""
    carriage = plant.carriage
    name = carriage.params.envelope.embedded_controller
    design = carriage.params.operation.speed
    where = [("v_{\\min}", env.v_min), ("V", design), ("v_{\\max}", env.v_max)]
    if not env.v_min < design < env.v_max:  # the design speed outside: v_min and v_max only
        where = [where[0], where[2]]
    points = plant.points([v for _, v in where])
    at = []
    for (label, v), op in zip(where, points, strict=True):
        e = embedded_gains(carriage, op)
        row = {"label": label, "speed": v, "K_pos": _gain_matrix(e["K_pos"]),
               "K_rate": _gain_matrix(e["K_rate"])}
        if "weights" in e:
            w = e["weights"]
            row["weights"] = [{"axis": a, "q1": q1, "q2": q2, "r": r, "F_max": r ** -0.5}
                              for a, q1, q2, r in zip(e["axes"], w["q1"], w["q2"], w["r"],
                                                      strict=True)]
        at.append(row)
    same_r = all(np.allclose([w["r"] for w in row["weights"]],
                             [w["r"] for w in at[0]["weights"]], rtol=1e-9)
                 for row in at if "weights" in row)
    c = env.controllers[name]
    errors = table.get("relative_error_by_field", {})
    s = carriage.params.control.spec
    return {
        "name": name, "title": controller_title(name), "at": at,
        "spec_design": registered(name).weights is not None, "same_r": same_r,
        "deviation": [float(getattr(s.max_deviation, k)) for k in ("y", "z", "phi", "theta",
                                                                   "psi")],
        "design_damping_ratio": s.min_damping_ratio + s.damping_margin,
        "verdict": c.verdict, "ok": c.ok, "spec_verdict": c.spec_verdict,
        "meets_spec": c.meets_spec, "firmware_design": env.firmware_design(name),
        "table_error": {"K_pos": errors.get("K_pos"), "K_rate": errors.get("K_rate"),
                        "worst": table["worst_relative_error"], "bound": table["bound"]},
    }


def envelope_context(plant: Plant, env, table: Mapping[str, Any] | None = None
                     ) -> dict[str, Any]:
    """The section's numbers; ``table``: the firmware table's manifest entry (c/manifest.json's
    ``gain_table``, which the build passes), else the same entry fitted here."""
    carriage = plant.carriage
    if table is None:
        table = plant.gain_table(env.v_min, env.v_max).manifest()

    embedded = carriage.params.envelope.embedded_controller
    pick = np.unique(np.linspace(0, env.speeds.size - 1, min(9, env.speeds.size)).astype(int))
    names = list(env.controllers)
    return {
        "v_min": env.v_min, "v_max": env.v_max, "n": int(env.speeds.size),
        "figure": ENVELOPE_FIGURE,
        "launch_acceleration": carriage.params.envelope.launch_acceleration,
        "rows": [{"title": controller_title(n), "name": n, "verdict": c.verdict,
                  "ok": c.ok, "embedded": n == embedded, "spec_verdict": c.spec_verdict,
                  "spec_short": ("meets it" if c.meets_spec else "FAILS "
                                 + ", ".join(f.spec for f in c.spec_failures)),
                  "meets_spec": c.meets_spec} for n, c in env.controllers.items()],
        "spec_checked_on": env.checked_on(),
        "robustness": env.robustness_verdict(), "robust": env.robust,
        "spec": _spec_context(carriage),
        "names": [controller_title(n) for n in names],
        "gain_table": {"nodes": table["nodes"], "dense_grid": table["dense_grid"],
                       "bound": table["bound"], "worst": table["worst_relative_error"],
                       "by_field": [{"name": k, "error": float(v)} for k, v in
                                    table["relative_error_by_field"].items()]},
        "embedded": _embedded_context(plant, env, table),
        "table": [{"speed": float(env.speeds[i]),
                   "cells": [float(env.controllers[n].max_real[i]) for n in names]}
                  for i in pick],
    }




def roa_section(plant: Plant, given: tuple[Any, bytes] | None):
    """The embedded controller's sampled region of attraction (maglevgen.analyses.roa, at the
    build's
    resolution) and its figure: the caller's (``given``, `maglevgen build`) when it has them."""
    if given is not None:
        return given
    regions = study(plant, [plant.params.envelope.embedded_controller], BUILD_SPEEDS,
                    BUILD_SAMPLING, flown_loop(plant))
    return regions, region_png(regions)


def roa_context(regions) -> dict[str, Any]:
    """The region's table and statement (the first region: the embedded controller's)."""
    reg = regions[0]
    return {"figure": ROA_FIGURE, "controller": controller_title(reg.controller),
            "loop": ("the firmware's sense tick on noisy readings" if reg.loop == "sensed"
                     else f"the {reg.loop} loop"),
            "statement": roa_statement_tex(reg.statement()),
            "rows": [{"speed": s, "level": c, "extents": list(e), "multiple": m,
                      "limit": r.limit, "confirmed": r.confirmed and r.level > 0,
                      "shrinks": r.shrinks}
                     for r, s, c, m, *e in zip(reg.regions, *_roa_columns(reg.regions),
                                               strict=True)]}


def _roa_columns(regions) -> list[list[str]]:
    """The region table's numbers, each column in one notation (`fcolumn`, 3 or 4 digits)."""
    cols = [fcolumn([r.speed for r in regions], 4), fcolumn([r.level for r in regions], 3)]
    cols += [fcolumn([r.extents[a] * AXIS_UNITS[a][1] for r in regions], 3)
             for a in AXIS_NAMES]
    return [*cols[:2], fcolumn([r.disturbance_multiple for r in regions], 3), *cols[2:]]


def roa_statement_tex(text: str) -> str:
    """The region's statement (plain text, also SUMMARY.md's) as LaTeX: escaped, with its
    mathematics typeset ({V <= c}, {V = c}, dV/dt < 0)."""
    out = tex_escape(text)
    for plain, math in ((r"\{V \textless{}= c\}", r"$\{V \le c\}$"),
                        (r"\{V = c\}", r"$\{V = c\}$"),
                        (r"dV/dt \textless{} 0", r"$\dot V < 0$")):
        out = out.replace(plain, math)
    return re.sub(r"(?<![\w$])c(?= shrank| = 0)", "$c$", out)
