"""Section: stiffness."""

from __future__ import annotations

from typing import Any

import numpy as np
import sympy as sp

from maglevgen.analyses.queries import trim_point
from maglevgen.control.carriage_plant import Plant
from maglevgen.derive import conventions as cv
from maglevgen.derive.linearize import STIFFNESS_PARTS, design_pose_stiffness, generalized_mass_expr
from maglevgen.derive.memo import memoized
from maglevgen.derive.model import build_model
from maglevgen.derive.paper import paper_stiffness
from maglevgen.errors import NoTrimError
from maglevgen.infrastructure import progress
from maglevgen.params import ARRAY_FORCE_LAWS, PAPER_ARRAY_FORCE
from maglevgen.report.display import (
    REPORT_SOURCE,
    Display,
    break_sum,
    decimal_rationals,
    eqs,
    ltx,
    matrix_tex,
    round_floats,
)
from maglevgen.report.format import fnum
from maglevgen.report.symbols import K_SYM, array_labels, to_display

__all__ = ["stiffness_section"]

_Q_LABELS = ("y", "z", r"\phi", r"\theta", r"\psi")
_W_LABELS = ("F_y", "F_z", "M_x", "M_y", "M_z")
ROLL = cv.AXES.index("roll")


def _shown_values(carriage) -> tuple[tuple[str, float], ...]:
    """The parameter values the stiffness display substitutes: those of the symbols in K_st0
    (the array geometry), so that editing any other parameter finds the display cached."""

    model = carriage.model
    free = design_pose_stiffness(model.structure).free_symbols
    return tuple((e.name, float(e.value)) for e, s in zip(carriage.entries, model.p, strict=True)
                 if s in free and e.name != "halbach.wavelength")


@memoized
def _stiffness_display(structure, values: tuple[tuple[str, float], ...],
                       _source: str) -> tuple[Display, Display]:
    """K_st0 at the design pose (eqs 13-19 derived) with ``values`` substituted, entry by
    entry, and the generalized masses, as LaTeX lines."""

    model = build_model(structure)
    K = design_pose_stiffness(structure)
    names = array_labels(model)
    rep = {s: sp.Symbol(f"F_{{L,{n}}}") for s, n in zip(model.lift_sym, names, strict=True)}
    rep.update({s: sp.Symbol(f"F_{{D,{n}}}") for s, n in zip(model.drag_sym, names, strict=True)})
    Kd = to_display(model, K, dict(values)).xreplace(rep)
    lines: list[str] = []
    for i in range(5):
        for j in range(5):
            e = round_floats(sp.expand(Kd[i, j]))
            if e != 0:
                lines += break_sum(f"K_{{{_Q_LABELS[i]} {_Q_LABELS[j]}}}", e)
    mass = generalized_mass_expr(model)
    mass_lines = eqs(
        [(f"M_{{{_Q_LABELS[i]} {_Q_LABELS[i]}}}", to_display(model, mass[i])) for i in range(5)]
    )
    return Display(tuple(lines)), mass_lines


def stiffness_section(plant: Plant, trim, trep: dict, gains: dict) -> dict[str, Any]:
    """The section's numbers, all from the compiled library (as `maglevgen trim` and `gains`
    print them): K_st0 and the gravity terms of ``trim`` (summary.TrimPoint, maglev_stiffness),
    A and B (maglev_jacobians at the trim), the generalized masses (maglev_axis_plants)."""

    carriage = plant.carriage
    model = carriage.model
    lines, mass_lines = _stiffness_display(model.structure, _shown_values(carriage),
                                           REPORT_SOURCE)
    K_mag = np.array(trep["stiffness_matrix"])
    K_tot = trim.K_magnetic + trim.K_other
    # entries below 1e-12 of the largest are rounding noise of a structural zero
    K_mag = np.where(np.abs(K_mag) < 1e-12 * np.max(np.abs(K_mag)), 0.0, K_mag)
    K_tot = np.where(np.abs(K_tot) < 1e-12 * np.max(np.abs(K_tot)), 0.0, K_tot)
    syms = {
        "F_lat": sp.Symbol("F_{bncd,y}"),
        "F_upper": sp.Symbol("F_{bncd,upper}"),
        "m": sp.Symbol("m"),
        "g": sp.Symbol("g"),
        "k": K_SYM,
        "Lz": sp.Symbol("L_z"),
        "Lx": sp.Symbol("L_x"),
        "Lxla": sp.Symbol("L_{xla}"),
    }
    printed = paper_stiffness(**syms)
    tags = {"lateral": "13", "vertical": "7", "roll": "14", "pitch": "15", "yaw": "16"}
    rows = []
    for axis, r in trep["stiffness"].items():
        rows.append(
            {
                "axis": axis,
                "unit": r["unit"],
                # as printed: eq 15's 0.12 F_upper k L_x^2, not SymPy's 3 F k L_x^2/25
                "formula": ltx(decimal_rationals(printed[axis])),
                "eq": tags[axis],
                "paper": r["paper"],
                "derived": r["derived"],
                "total": r["derived_with_gravity"],
                "rel": r["paper_relative_difference"],
            }
        )
    laws = _by_law(plant, trim)
    for i, row in enumerate(rows):
        for law, d in laws.items():
            row[law] = None if d is None else float(d["magnetic"][i])
    inputs = [(ltx(syms[n]), v) for n, v in trep["paper_inputs"].items()]
    jacobians = plant.lib.function("maglev_jacobians")
    u = np.zeros(jacobians.shapes_in[1][0])
    u[cv.PROPULSION_INPUT] = trim.f_prop
    A, B = jacobians(trim.x, u, carriage.p)
    scale = np.max(np.abs(A))
    a_entries = [
        (
            rf"\dot{{{ltx(sp.Symbol(cv.STATE_NAMES[i]))}}}",
            ltx(sp.Symbol(cv.STATE_NAMES[j])),
            float(A[i, j]),
            jacobian_unit(cv.STATES[i].unit, cv.STATES[j].unit),
        )
        for i in range(cv.N_STATES)
        for j in range(cv.N_STATES)
        if abs(A[i, j]) > 1e-13 * scale
    ]
    return {
        "K_symbolic": lines,
        "mass": mass_lines,
        "mass_values": [a["inertia"] for a in gains["axes"].values()],
        "K_mag": matrix_tex(K_mag, lambda v: fnum(v, 5)),
        "K_tot": matrix_tex(K_tot, lambda v: fnum(v, 5)),
        "rows": rows,
        "model": carriage.params.model.array_force,
        "cg_height": float(carriage.params.vehicle.cg_offset[2]),
        "width": float(carriage.params.halbach.width),
        "parts": _parts_rows(laws),
        "roll": {law: None if d is None else {n: float(v[ROLL]) for n, v in d["parts"].items()}
                 | {"total": float(d["total"][ROLL])} for law, d in laws.items()},
        "paper_inputs": inputs,
        "A_entries": a_entries,
        "B_shape": B.shape,
        "B_nonzero": int(np.count_nonzero(np.abs(B) > 1e-13)),
    }


def jacobian_unit(row_unit: str, column_unit: str) -> str:
    """The unit (LaTeX text) of the entry of A = d(x')/dx in row ``row_unit``'s derivative and
    column ``column_unit`` (the states' units: m, rad, m/s, rad/s): row unit / (s column unit),
    with m, rad and s each to one power ("1/s$^2$", "m/(s\\,rad)")."""
    power: dict[str, int] = {"m": 0, "rad": 0, "s": -1}
    for unit, sign in ((row_unit, 1), (column_unit, -1)):
        num, _, den = unit.partition("/")
        power[num] += sign
        if den:
            power[den] -= sign

    def part(names: list[str]) -> str:
        return r"\,".join(n + (f"$^{{{abs(power[n])}}}$" if abs(power[n]) > 1 else "")
                          for n in names)

    up = [n for n in ("m", "rad", "s") if power[n] > 0]
    down = [n for n in ("m", "rad", "s") if power[n] < 0]
    text = part(up) or "1"
    if down:
        text += "/" + (f"({part(down)})" if len(down) > 1 else part(down))
    return text


# the table's columns: every choice of params.ARRAY_FORCE_LAWS, the paper's first
LAW_COLUMNS = (PAPER_ARRAY_FORCE,
               *(law for law in ARRAY_FORCE_LAWS if law != PAPER_ARRAY_FORCE))


def _by_law(plant: Plant, trim) -> dict[str, dict[str, Any] | None]:
    """Per array force law: the diagonal of K_st0 and of K_st0 + K_other from that law's
    compiled library at its trim, and of each part (maglev_stiffness_parts: the derivation's
    split, derive.linearize.STIFFNESS_PARTS, generated into that library); None where it has
    no trim (each law's plant: `Plant.with_model`)."""
    out: dict[str, dict[str, Any] | None] = {}
    for law in LAW_COLUMNS:
        law_plant = plant.with_model(array_force=law, progress=progress.step)
        other, law_lib = law_plant.carriage, law_plant.lib
        try:
            t = trim if law_plant is plant else trim_point(law_plant, None)
        except NoTrimError:
            out[law] = None
            continue
        split = law_lib.function("maglev_stiffness_parts")(t.x, t.f_prop, other.p)
        parts = {n: np.diag(K) for n, K in zip(STIFFNESS_PARTS, split, strict=True)}
        out[law] = {"magnetic": np.diag(t.K_magnetic), "total": np.diag(t.K_magnetic + t.K_other),
                    "parts": parts}
    return out


def _parts_rows(laws: dict[str, dict[str, Any] | None]) -> list[dict[str, Any]]:
    """One row per axis and law: each part of the derived stiffness and their sum."""
    rows = []
    for i, axis in enumerate(cv.AXES):
        for law, d in laws.items():
            if d is None:
                continue
            rows.append({"axis": axis, "law": law,
                         "parts": [float(d["parts"][n][i]) for n in STIFFNESS_PARTS],
                         "total": float(d["total"][i])})
    return rows
