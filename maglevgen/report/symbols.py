"""The symbols the report prints for parameters (vehicle.mass -> m), and the nomenclature."""

from __future__ import annotations

import re
from typing import Any

import sympy as sp

from maglevgen.report.display import ltx
from maglevgen.report.format import tex_escape

__all__ = ["K_SYM", "array_labels", "display_key_symbol", "to_display"]

_VEC = r"(?P<c>[xyz])"


def display_symbol(name: str) -> sp.Symbol:
    """The symbol the report prints for a flattened parameter name (vehicle.mass -> m)."""
    fixed = {
        "vehicle.mass": "m",
        "vehicle.length": r"\ell",
        "vehicle.width": r"w_c",
        "vehicle.height": r"h_c",
        "vehicle.gravity": "g",
        "halbach.remanence": "B_r",
        "halbach.thickness": "d",
        "halbach.magnets_per_wavelength": "M",
        "halbach.wavelength": "lambda",
        "halbach.width": "w",
        "circuit.resistance": "R",
        "circuit.inductance": "L",
        "circuit.pitch": "p_c",  # p is the roll rate
        "operation.speed": "V",
        "control.state_weights.0": "q_1",
        "control.state_weights.1": "q_2",
        "control.input_weight": "r",
        "track.min_gap": r"g_{\min}",
    }
    if name in fixed:
        return sp.Symbol(fixed[name])
    rules = [
        (r"vehicle\.inertia_cg\.(?P<c>xx|yy|zz|xy|xz|yz)", "I_{{{c}}}"),
        (rf"vehicle\.cg_offset\.{_VEC}", "{c}_G"),
        (rf"arrays\.(?P<n>[^.]+)\.position\.{_VEC}", "a_{{{n},{c}}}"),
        (rf"arrays\.(?P<n>[^.]+)\.normal\.{_VEC}", "n_{{{n},{c}}}"),
        (r"arrays\.(?P<n>[^.]+)\.nominal_gap", "G_{{{n}}}"),
        (r"arrays\.(?P<n>[^.]+)\.circuits", "N_{{{n}}}"),
        (rf"operation\.propulsion_point\.{_VEC}", "a_{{p,{c}}}"),
    ]
    for pattern, fmt in rules:
        m = re.fullmatch(pattern, name)
        if m:  # an array's name comes from the parameter file: escaped like all its text
            return sp.Symbol(fmt.format(**{k: tex_escape(v) for k, v in m.groupdict().items()}))
    return sp.Symbol(r"\mathrm{" + name.replace("_", r"\_") + "}")


def display_key_symbol(key: str) -> str:
    """LaTeX of the symbol of a schema leaf (vectors: the vector's name)."""
    vec = {
        "vehicle.cg_offset": r"\mathbf{r}_G",
        "operation.propulsion_point": r"\mathbf{a}_p",
        "control.state_weights": r"(q_1, q_2)",
        "vehicle.inertia_cg": r"\mathbf{I}_G",
    }
    m = re.fullmatch(r"arrays\.([^.]+)\.(position|normal)", key)
    if m:
        return ((r"\mathbf{a}_{" if m.group(2) == "position" else r"\mathbf{n}_{")
                + tex_escape(m.group(1)) + "}")
    if key in vec:
        return vec[key]
    return ltx(display_symbol(key))


K_SYM = sp.Symbol("k")  # the wavenumber 2 pi / lambda


def to_display(model, expr: Any, numbers: dict[str, float] | None = None) -> Any:
    """A model expression in display symbols; ``numbers`` substitutes values for some names.

    lambda is replaced by 2 pi / k, so the model's 2 pi / lambda prints as k.
    """
    rep: dict[sp.Symbol, Any] = {}
    for name, s in zip(model.structure.param_names, model.p, strict=True):
        if name == "halbach.wavelength":
            rep[s] = 2 * sp.pi / K_SYM
        elif numbers is not None and name in numbers:
            rep[s] = sp.Float(numbers[name], 17)
        else:
            rep[s] = display_symbol(name)
    return expr.xreplace(rep)


def array_labels(model) -> list[str]:
    """The arrays' names as LaTeX (names come from the parameter file)."""
    return [tex_escape(a.name) for a in model.arrays]

