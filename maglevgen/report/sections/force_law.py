"""Section: force law."""

from __future__ import annotations

from typing import Any

import numpy as np
import sympy as sp

from maglevgen.control.carriage_plant import Plant
from maglevgen.derive import conventions as cv
from maglevgen.derive.inductrack import drag_per_circuit, halbach_surface_field, lift_per_circuit
from maglevgen.derive.memo import memoized
from maglevgen.report.display import REPORT_SOURCE, Display, eq, ltx
from maglevgen.report.symbols import K_SYM

__all__ = ["array_force_curves", "force_curves", "force_law_section"]

# The force law's symbols: eq 4's B_r, d, M and eq 3's w, L, R, B_0, gap delta and speed v.
_FORCE_SYMBOLS = sp.symbols("B_r d M w L R B_0 delta v")


@memoized
def _force_law_forms(_source: str) -> dict[str, Any]:
    """Eqs 3-4 in display symbols and what follows from them (parameter independent, cached
    across processes): B0, F_L, F_D, F_D/F_L, the gap slope and the characteristic speed."""

    Br, d, M, w, L, R, B0, delta, v = _FORCE_SYMBOLS
    k = K_SYM
    FL = lift_per_circuit(B0, w, k, L, R, delta, v)
    FD = drag_per_circuit(B0, w, k, L, R, delta, v)
    ratio = sp.simplify(FD / FL)
    (v_c,) = [s for s in sp.solve(sp.Eq(ratio, 1), v) if s.is_positive is not False]
    return {"B0": halbach_surface_field(Br, d, M, k), "FL": FL, "FD": FD, "ratio": ratio,
            "slope": sp.simplify(sp.diff(FL, delta) / FL), "v_c": v_c}


def _force_numbers(carriage) -> dict[sp.Symbol, float]:
    """The force law's symbols with the carriage's values (B0 from eq 4).

    B0 and v_c (`force_law_section`) are the values of displayed closed forms of the parameters
    (eq 4, and F_D/F_L = 1 of eq 3), printed beside their equations; they are not a model
    result, so they are evaluated here from the same SymPy form that is displayed (xreplace,
    no lambdify). Every force the report prints or draws comes from the compiled library."""
    Br, d, M, w, L, R, B0, _delta, _v = _FORCE_SYMBOLS
    pr = carriage.params
    num = {Br: pr.halbach.remanence, d: pr.halbach.thickness,
           M: pr.halbach.magnets_per_wavelength, K_SYM: pr.wavenumber, w: pr.halbach.width,
           L: pr.circuit.inductance, R: pr.circuit.resistance}
    num[B0] = float(_force_law_forms(REPORT_SOURCE)["B0"].xreplace(num))
    return num


def array_force_curves(plant: Plant, array: int, gaps: np.ndarray, speeds: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Lift and drag of array ``array`` from the compiled library (maglev_array_forces) at
    zero attitude, its face-centre gap ``gaps[i]`` (the carriage moved along the array's
    normal) and forward speed ``speeds[i]``: eq 3 times the array's circuits for either force
    law (at zero attitude the distributed face has one gap across it)."""
    carriage = plant.carriage
    arr = list(carriage.params.arrays.values())[array]
    n_z = arr.normal[2]  # gap = nominal gap + n . (0, y, z) at zero attitude
    fn = plant.lib.function("maglev_array_forces")
    x = np.zeros(len(cv.STATES))
    out = np.zeros((2, len(gaps)))
    for i, (g, v) in enumerate(zip(gaps, speeds, strict=True)):
        x[cv.STATE_INDEX["z"]] = (g - arr.nominal_gap) / n_z
        x[cv.STATE_INDEX["u"]] = v
        lift, drag = fn(x, carriage.p)
        out[:, i] = lift.ravel()[array], drag.ravel()[array]
    return out[0], out[1]


def force_curves(plant: Plant, trim) -> dict[str, Any]:
    # ``trim``: summary.TrimPoint (speed, gaps, lift of every array, from the compiled library)
    """What the force figures draw, as plain numbers (they are drawn in another process):
    F_L and F_D (eq 3) of one upper array against the gap at the trim speed and against the
    speed at the nominal gap (`array_force_curves`, the plant's compiled library), and every
    array's point at trim."""
    carriage = plant.carriage
    v_c = float(_force_law_forms(REPORT_SOURCE)["v_c"].xreplace(_force_numbers(carriage)))
    arrays = list(carriage.params.arrays.items())
    upper = [i for i, (_, a) in enumerate(arrays) if abs(a.normal[2]) > 1 - 1e-9]
    i_up = upper[0] if upper else 0
    a_up = arrays[i_up][1]
    n_c, g0 = a_up.circuits, a_up.nominal_gap
    gap = np.linspace(carriage.params.track.min_gap, 0.05, 400)
    speed = np.linspace(0.0, max(3 * trim.speed, 3 * v_c), 400)
    lift_gap, drag_gap = array_force_curves(plant, i_up, gap,
                                            np.full_like(gap, trim.speed))
    lift_v, drag_v = array_force_curves(plant, i_up, np.full_like(speed, g0), speed)
    points: dict[tuple[float, float], list[str]] = {}
    dots = []
    for i, (name, a) in enumerate(arrays):
        xy = (float(trim.gaps[i] * 1e3), float(trim.lift[i] * n_c / a.circuits))
        dots.append(xy)
        points.setdefault((round(xy[0]), round(xy[1], -1)), []).append(name)
    return {"speed": trim.speed, "v_c": v_c, "circuits": n_c, "nominal_gap": g0,
            "gap": gap, "lift_gap": lift_gap, "drag_gap": drag_gap,
            "v": speed, "lift_v": lift_v, "drag_v": drag_v,
            "dots": dots, "labels": [(xy, ", ".join(names)) for xy, names in points.items()]}


def force_law_section(carriage, trim, trep: dict) -> dict[str, Any]:
    forms, num = _force_law_forms(REPORT_SOURCE), _force_numbers(carriage)
    B0_expr, FL, FD = forms["B0"], forms["FL"], forms["FD"]
    ratio, slope, v_c = forms["ratio"], forms["slope"], forms["v_c"]
    pr = carriage.params
    B0_val = num[_FORCE_SYMBOLS[6]]
    v_c_val = float(v_c.xreplace(num))
    FLi, FDi = sp.Function("F_L"), sp.Function("F_D")
    Ni, di, si = sp.symbols("N_i delta_i s_i")
    arrays = []
    for name, a in trep["arrays"].items():
        n_c = pr.arrays[name].circuits
        arrays.append(
            {
                "name": name,
                "gap_mm": a["gap"] * 1e3,
                "lift": a["lift"],
                "drag": a["drag"],
                "circuits": n_c,
                "lift_per_circuit": a["lift"] / n_c,
                "speed": trim.speed,
            }
        )
    return {
        "array_force_law": pr.model.array_force,
        "B0": eq("B_0", B0_expr, tag="4"),
        "lift": eq("F_L", FL, tag="3"),
        "drag": eq("F_D", FD),
        "ratio": eq(r"\frac{F_D}{F_L}", ratio),
        "slope": eq(r"\frac{1}{F_L}\frac{\partial F_L}{\partial \delta}", slope, tag="5--6"),
        "array_force": Display(
            (
                f"{ltx(sp.Symbol('F_{L,i}'))} &= {ltx(Ni * FLi(di, si))}, \\qquad "
                f"{ltx(sp.Symbol('F_{D,i}'))} = {ltx(Ni * FDi(di, si))}",
            )
        ),
        "v_c": eq("v_c", v_c),
        "B0_value": B0_val,
        "B0_paper": 0.9,
        "B0_rel": (0.9 - B0_val) / B0_val,
        "k_value": pr.wavenumber,
        "v_c_value": v_c_val,
        # F_D/F_L of the first array at trim, from the compiled library's forces (trep)
        "ratio_at_trim": arrays[0]["drag"] / arrays[0]["lift"],
        "arrays": arrays,
    }


