"""Section: the summary of findings, the report's first page: the verdict of each controller
across the envelope, the trim, the gains and closed-loop poles, the paper's discrepancies
ranked by size, and the count of verification checks passed and failed."""

from __future__ import annotations

from typing import Any

from maglevgen.report.format import faxis_unit, tex_verdict
from maglevgen.report.latex import latex_env

__all__ = ["summary", "verdict_tex"]


def _discrepancies(trep: dict, gains: dict) -> list[dict[str, Any]]:
    """The paper's printed values against the derivation, largest relative difference first."""
    rows = []
    for axis, r in trep["stiffness"].items():
        rows.append({"what": f"{axis} stiffness (printed eq)", "unit": faxis_unit(axis, "k"),
                     "paper": r["paper"],
                     "derived": r["derived"], "rel": r["paper_relative_difference"]})
    for axis, a in gains["axes"].items():
        if a["relative_difference"]["paper_vs_closed_form"] is None:
            continue
        # the gain component the printed form misses most (K1: position, K2: rate)
        i = max((0, 1), key=lambda j: abs(a["K_paper"][j] / a["K_closed_form"][j] - 1))
        paper, derived = a["K_paper"][i], a["K_closed_form"][i]
        rows.append({"what": f"{axis} LQR gain K{i + 1} (eqs 31-32 as printed)",
                     "unit": faxis_unit(axis, "k" if i == 0 else "c"),
                     "paper": paper, "derived": derived, "rel": paper / derived - 1})
    for r in rows:  # the gains' table's quantity: the printed value over the derived beside it
        r["ratio"] = 1 + r["rel"]
    return sorted(rows, key=lambda r: -abs(r["rel"]))


def _by_kind(rows: list[dict[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    """The discrepancies in two tables, each of one quantity per column: the printed
    stiffnesses (their difference from the derived one in percent) and the printed LQR gains
    (their ratio to the derived one: orders of magnitude, which no percentage reads)."""
    return {"stiffness": [r for r in rows if "stiffness" in r["what"]],
            "gains": [r for r in rows if "stiffness" not in r["what"]]}


def verdict_tex(verdict) -> str:
    """The first page's verdict block (templates/report/verdict.tex.j2): the lines of
    `maglevgen.analyses.verdicts.EmbeddedVerdict.lines`, which SUMMARY.md and stdout print,
    typeset (`tex_verdict`)."""
    return latex_env().get_template("report/verdict.tex.j2").render(vd=verdict_context(verdict))


def verdict_context(verdict) -> dict[str, Any]:
    """The verdict block (`maglevgen.analyses.verdicts.EmbeddedVerdict.lines`, as SUMMARY.md
    prints it) typeset: the head, the checks deciding the exit code, the findings."""
    return {"head": tex_verdict(verdict.head()), "verified": verdict.verified,
            "complete": verdict.complete,
            "checks": [{"text": tex_verdict(c.line()), "ok": c.ok} for c in verdict.checks],
            "findings_head": tex_verdict(verdict.findings_head()),
            "findings": [tex_verdict(c.line()) for c in verdict.findings]}


def summary(trep: dict, gains: dict, paper: dict, checks: list, envelope: dict,
            stiffness: dict, lag: dict, verdict) -> dict[str, Any]:
    """What the first page shows (plain data; the template formats it); ``lag``: the circuit
    lag section's context (each axis's magnetic damping at the design speed); ``verdict``:
    the embedded controller's (`maglevgen.analyses.verdicts.EmbeddedVerdict`), the block
    SUMMARY.md and stdout print."""
    own = [c for c in checks if not c.finding]
    status = [c.status for c in own]
    magnetic = {a["axis"]: a[lag["model"].replace("-", "_")] for a in lag["axes"]}
    return {
        "verdict_tex": verdict_tex(verdict),
        "verdicts": envelope["rows"],
        "embedded": envelope["embedded"],
        "spec_checked_on": envelope["spec_checked_on"],
        "v_min": envelope["v_min"], "v_max": envelope["v_max"],
        "trim": {"speed": trep["speed"], "lift_off": trep["lift_off_speed"],
                 "F_prop": trep["propulsion_force"], "residual": trep["residual"]},
        "gains": [{"axis": axis, "K": a["K_closed_form"], "magnetic": magnetic[axis],
                   "poles": [complex(*p) for p in a["closed_loop_poles"]]}
                  for axis, a in gains["axes"].items()],
        "discrepancies": _discrepancies(trep, gains),
        "discrepancy_tables": _by_kind(_discrepancies(trep, gains)),
        "speed_mode": gains["speed_mode"],
        "circuit_dynamics": lag["model"],
        "passed": status.count("pass"), "failed": status.count("FAIL"),
        "not_run": status.count("not run"),
        "failed_checks": [c.what for c in own if c.status == "FAIL"],  # LaTeX text
        # the other designs' failed rows: findings about them (the paper's), apart
        "design_findings": [c.what for c in checks if c.finding and c.status == "FAIL"],
    }
