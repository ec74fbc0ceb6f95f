"""Section: envelope."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ...envelope import (
    compute_envelope,
    envelope_points,
    gain_table,
    stability_map_png,
)
from ...library import simulation_library
from ...operating import CONTROLLER_TITLES, STABILITY_MARGIN, closed_loop_stability
from ...roa import AXIS_NAMES, AXIS_UNITS, BUILD_SAMPLING, BUILD_SPEEDS, region_png, study
from ..format import tex_escape
from .verification import Check

# ============================================================================ envelope

ENVELOPE_FIGURE = "envelope_stability_map.png"
ROA_FIGURE = "envelope_region_of_attraction.png"


def _envelope(carriage, given: tuple[Any, bytes] | None):
    """The envelope (maglevgen.envelope, through the compiled library) and its stability map:
    the caller's (``given``) when it has them (`maglevgen build`), else computed and drawn."""
    if given is not None:
        return given
    env = compute_envelope(carriage, simulation_library(carriage.structure))
    return env, stability_map_png(env)


def _envelope_checks(carriage, env) -> list[Check]:
    """Stability rows: each designed controller at the design speed and across the envelope
    (a row fails when the closed loop has an eigenvalue with real part >= -margin)."""

    speed = carriage.params.operation.speed
    (op,) = envelope_points(carriage, simulation_library(carriage.structure), [speed])
    out = []
    for name in ("coupled", "lqr", "damping"):
        title = tex_escape(CONTROLLER_TITLES[name])
        out.append(Check(
            f"{title}: closed loop at {speed:.4g} m/s (largest real part, 1/s)",
            "eigenvalues (numpy) of the C Jacobians with the gains and allocation",
            closed_loop_stability(op, name)[0], -STABILITY_MARGIN))
        out.append(Check(
            f"{title}: closed loop across [{env.v_min:.4g}, {env.v_max:.4g}] m/s (largest "
            "real part, 1/s)", f"the same at {env.speeds.size} speeds",
            float(np.max(env.controllers[name].max_real)), -STABILITY_MARGIN))
    return out


def _spec_context(carriage) -> dict[str, Any]:
    """[control.spec] as the report states it."""
    s = carriage.params.control.spec
    d = s.max_deviation
    return {"min_damping_ratio": s.min_damping_ratio, "min_decay_rate": s.min_decay_rate,
            "design_damping_ratio": s.min_damping_ratio + s.damping_margin,
            "force_budget": s.force_budget, "tick_rate": s.tick_rate,
            "delay_ticks": s.delay_ticks, "speed_bandwidth": s.speed_bandwidth,
            "min_gap_margin": s.min_gap_margin,
            "deviation": {"y": d.y * 1e3, "z": d.z * 1e3, "phi": d.phi * 1e3,
                          "theta": d.theta * 1e3, "psi": d.psi * 1e3}}


def _envelope_context(carriage, env, table: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The section's numbers; ``table``: the firmware table's manifest entry (c/manifest.json's
    ``gain_table``, which the build passes), else the same entry fitted here."""
    if table is None:
        table = gain_table(carriage, simulation_library(carriage.structure), env.v_min,
                           env.v_max).manifest()

    embedded = carriage.params.envelope.embedded_controller
    pick = np.unique(np.linspace(0, env.speeds.size - 1, min(9, env.speeds.size)).astype(int))
    names = list(env.controllers)
    return {
        "v_min": env.v_min, "v_max": env.v_max, "n": int(env.speeds.size),
        "figure": ENVELOPE_FIGURE,
        "launch_acceleration": carriage.params.envelope.launch_acceleration,
        "rows": [{"title": CONTROLLER_TITLES[n], "name": n, "verdict": c.verdict,
                  "ok": c.ok, "embedded": n == embedded, "spec_verdict": c.spec_verdict,
                  "spec_short": ("meets it" if c.meets_spec else "FAILS "
                                 + ", ".join(f.spec for f in c.spec_failures)),
                  "meets_spec": c.meets_spec} for n, c in env.controllers.items()],
        "spec_checked_on": env.checked_on(),
        "robustness": env.robustness_verdict(), "robust": env.robust,
        "spec": _spec_context(carriage),
        "names": [CONTROLLER_TITLES[n] for n in names],
        "gain_table": {"nodes": table["nodes"], "dense_grid": table["dense_grid"],
                       "bound": table["bound"], "worst": table["worst_relative_error"],
                       "by_field": [{"name": k, "error": float(v)} for k, v in
                                    table["relative_error_by_field"].items()]},
        "table": [{"speed": float(env.speeds[i]),
                   "cells": [float(env.controllers[n].max_real[i]) for n in names]}
                  for i in pick],
    }




def _roa(carriage, given: tuple[Any, bytes] | None):
    """The embedded controller's sampled region of attraction (maglevgen.roa, at the build's
    resolution) and its figure: the caller's (``given``, `maglevgen build`) when it has them."""
    if given is not None:
        return given
    regions = study(carriage, simulation_library(carriage.structure),
                    [carriage.params.envelope.embedded_controller], BUILD_SPEEDS,
                    BUILD_SAMPLING)
    return regions, region_png(regions)


def _roa_context(regions) -> dict[str, Any]:
    """The region's table and statement (the first region: the embedded controller's)."""
    reg = regions[0]
    return {"figure": ROA_FIGURE, "controller": CONTROLLER_TITLES[reg.controller],
            "statement": reg.statement(),
            "rows": [{"speed": r.speed, "level": r.level,
                      "extents": [r.extents[a] * AXIS_UNITS[a][1] for a in AXIS_NAMES],
                      "multiple": r.disturbance_multiple, "limit": r.limit,
                      "confirmed": r.confirmed and r.level > 0, "shrinks": r.shrinks}
                     for r in reg.regions]}
