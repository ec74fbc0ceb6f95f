"""`maglevgen report`: the LaTeX derivation report, rendered from the derivation itself.

Every equation in the report is a SymPy object from ``derive/`` (or built from its functions)
printed with ``sympy.latex``; every number comes from the same code paths as ``maglevgen trim``
and ``maglevgen gains`` (``cli.trim_report``, ``cli.gains_report``). The jinja2 templates in
``templates/report*`` only place them. Long expressions are broken into lines by
``break_sum`` (terms packed to a width budget) or abbreviated by ``sympy.cse``.

The output is written atomically: everything is rendered into a temporary folder beside the
output folder, LaTeX runs there, and only a successful build replaces the previous output.
The .tex is deterministic: no dates, fixed number formats, seeded random samples.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import random
import re
import shutil
import subprocess
import tempfile
import unicodedata
from collections.abc import Callable, Mapping, Sequence
from contextlib import nullcontext
from dataclasses import dataclass
from fractions import Fraction
from importlib import resources
from pathlib import Path
from typing import Any

import jinja2
import mpmath
import numpy as np
import sympy as sp

from . import __version__
from .derive import conventions as cv
from .derive.memo import memoized
from .errors import InputError, MaglevError
from .report_figures import force_figures
from .texsetup import INSTALL_HINT, TEX_PACKAGES, find_tex  # noqa: F401  (re-exported)
from .workers import Background, PendingResult

__all__ = [
    "SIMULATION_FIGURES",
    "TEX_PACKAGES",
    "LatexBuild",
    "ReportOptions",
    "break_sum",
    "build_context",
    "first_latex_error",
    "fnum",
    "latex_env",
    "overfull_boxes",
    "parameter_rows",
    "render_tex",
    "tex_escape",
    "write_report",
]


# PNGs written by `maglevgen simulate --out DIR`, with the paper's figures they correspond to.
SIMULATION_FIGURES: tuple[tuple[str, str], ...] = (
    ("levitation_pitch.png", "Levitation height and pitch (the paper's figs 3, 5 and 7)."),
    ("travel_roll.png", "Travel distance and roll (the paper's fig 4)."),
    ("lateral_pitch.png", "Lateral position and pitch (the paper's figs 6 and 8)."),
)

# Width budget of one display line, in the units of `_tex_width` (about one math glyph).
LINE_WIDTH = 62
FLOAT_DIGITS = 4  # significant digits of numbers printed inside symbolic expressions


@dataclass(frozen=True)
class ReportOptions:
    """What `write_report` does besides rendering the .tex."""

    simulation: Path | Mapping[str, bytes | str] | None = None  # `maglevgen simulate` output
    verify_c: bool = True  # compile the generated C and compare it with the SymPy model
    build_pdf: bool = True  # run LaTeX when it is installed
    envelope: tuple[Any, bytes] | None = None  # (Envelope, stability map PNG) when computed


# =============================================================================== formatting


def fnum(x: float, digits: int = 6) -> str:
    """A number as LaTeX math (without $): plain for 1e-3 <= |x| < 1e5, else a x 10^e."""
    x = float(x)
    if math.isnan(x):
        return r"\text{nan}"
    if math.isinf(x):
        return r"\infty" if x > 0 else r"-\infty"
    if x == 0:
        return "0"
    e = math.floor(math.log10(abs(x)))
    if -3 <= e < 5:
        s = f"{x:.{digits}g}"
        if "e" not in s:
            return s
    mant, exp = f"{x:.{digits - 1}e}".split("e")
    mant = mant.rstrip("0").rstrip(".") if "." in mant else mant
    return rf"{mant} \times 10^{{{int(exp)}}}"


def ffixed(x: float, digits: int = 6) -> str:
    """A number in plain decimal notation with ``digits`` significant digits (LaTeX math).

    For tables a reader (or pdftotext) takes in at a glance: no exponent, so no superscript.
    """
    x = float(x)
    if not math.isfinite(x) or x == 0 or abs(x) < 1e-12 or abs(x) >= 1e15:
        return fnum(x, digits)
    e = math.floor(math.log10(abs(float(f"{x:.{digits}g}"))))
    text = f"{x:.{max(digits - 1 - e, 0)}f}"
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    return text


def fcomplex(z: complex, digits: int = 4) -> str:
    """A complex number a + b j (LaTeX math); a real one without its zero imaginary part."""
    z = complex(z)
    if z.imag == 0:
        return fnum(z.real, digits)
    sign = "+" if z.imag > 0 else "-"
    return rf"{fnum(z.real, digits)} {sign} {fnum(abs(z.imag), digits)}\,j"


def fpct(x: float) -> str:
    """A relative difference as a signed percentage (LaTeX text)."""
    return f"${x * 100:+.1f}\\,\\%$"


def ferr(x: float) -> str:
    """An error magnitude with two significant digits (LaTeX math)."""
    return fnum(x, 2)


_TEX_ESCAPES = {
    "\\": r"\textbackslash{}",
    "{": r"\{",
    "}": r"\}",
    "$": r"\$",
    "&": r"\&",
    "#": r"\#",
    "^": r"\^{}",
    "_": r"\_",
    "%": r"\%",
    "~": r"\textasciitilde{}",
    "<": r"\textless{}",
    ">": r"\textgreater{}",
    "|": r"\textbar{}",
    "°": r"$^\circ$",
    "±": r"$\pm$",
    "×": r"$\times$",
    "–": "--",
    "—": "---",
    "’": "'",
    "“": "``",
    "”": "''",
    "…": r"\dots{}",
    "µ": r"$\mu$",
}


def tex_escape(text: object) -> str:
    """Text made safe for LaTeX: special characters escaped, other non-ASCII transliterated."""
    out = []
    for ch in str(text):
        if ch in _TEX_ESCAPES:
            out.append(_TEX_ESCAPES[ch])
        elif ord(ch) < 128:
            out.append(ch)
        elif unicodedata.name(ch, "").startswith("GREEK SMALL LETTER "):
            out.append(rf"$\{unicodedata.name(ch)[19:].lower()}$")
        else:
            ascii_ = unicodedata.normalize("NFKD", ch).encode("ascii", "ignore").decode()
            out.append(ascii_ or "?")
    return "".join(out)


def tex_breakable(text: object) -> str:
    """Escaped text with break points after , / * = ( [ so that long tokens can wrap."""
    out = re.sub(r"(,|/|\*|=|\(|\[)", r"\1\\allowbreak{}", tex_escape(text))
    # long words (digests, identifiers): a break point every 16 characters
    return re.sub(
        r"[A-Za-z0-9]{16}(?=[A-Za-z0-9]{4})", lambda m: m.group(0) + r"\allowbreak{}", out
    )


def tex_unit(unit: str) -> str:
    """A unit such as kg*m^2 or m/s^2 in LaTeX text (1 for dimensionless)."""
    text = tex_escape(unit or "1").replace("*", r"\,")
    return re.sub(r"\\\^\{\}(-?\d+)", r"$^{\1}$", text)


def tex_key(key: str) -> str:
    """A dotted parameter key in typewriter, breakable after each dot."""
    return (
        r"\texttt{"
        + tex_escape(key).replace(".", r".\allowbreak{}").replace(r"\_", r"\_\allowbreak{}")
        + "}"
    )


# =========================================================================== sympy → LaTeX


def ltx(expr: Any) -> str:
    """sympy.latex with the report's settings."""
    return sp.latex(expr, full_prec=False)


def round_floats(expr: Any, digits: int = FLOAT_DIGITS) -> Any:
    """Floats in an expression rounded to ``digits`` significant digits (for display)."""
    if isinstance(expr, sp.MatrixBase):
        return expr.applyfunc(lambda e: round_floats(e, digits))
    expr = sp.sympify(expr)
    rep = {}
    for f in expr.atoms(sp.Float):
        v = float(f"{float(f):.{digits}g}")
        if abs(v) < 1e-12 or (v == round(v) and abs(v) < 1e6):
            rep[f] = sp.Integer(round(v))
        else:
            rep[f] = sp.Float(v, digits)
    return expr.xreplace(rep)


def _brace_group(s: str, i: int) -> tuple[str, int]:
    """The content of the {...} group starting at s[i] (or the single token there) and the end."""
    while i < len(s) and s[i] == " ":
        i += 1
    if i >= len(s):
        return "", i
    if s[i] != "{":
        if s[i] == "\\":
            m = re.match(r"\\[A-Za-z]+|\\.", s[i:])
            return m.group(0), i + len(m.group(0))
        return s[i], i + 1
    depth, j = 0, i
    while j < len(s):
        if s[j] == "\\":
            j += 2
            continue
        if s[j] == "{":
            depth += 1
        elif s[j] == "}":
            depth -= 1
            if depth == 0:
                return s[i + 1 : j], j + 1
        j += 1
    return s[i + 1 :], len(s)


_WIDE_COMMANDS = {
    "sin": 2.5,
    "cos": 2.5,
    "tan": 2.5,
    "exp": 2.5,
    "log": 2.5,
    "quad": 2,
    "qquad": 4,
    "cdot": 1.5,
    "times": 2,
    "mapsto": 2,
}
_ZERO_COMMANDS = {
    "left",
    "right",
    "mathrm",
    "mathbf",
    "operatorname",
    "text",
    "dot",
    "ddot",
    "hat",
    "bar",
    "boldsymbol",
    "displaystyle",
    "big",
    "Big",
    "bigg",
    "Bigg",
    "limits",
    "nolimits",
    "allowbreak",
}


def _tex_width(s: str) -> float:
    """A rough width of LaTeX math in glyphs: fractions count their wider part, scripts 0.7."""
    w, i = 0.0, 0
    while i < len(s):
        c = s[i]
        if c == "\\":
            m = re.match(r"\\([A-Za-z]+|.)", s[i:])
            name = m.group(1)
            i += len(m.group(0))
            if name in ("frac", "dfrac", "tfrac"):
                a, i = _brace_group(s, i)
                b, i = _brace_group(s, i)
                w += max(_tex_width(a), _tex_width(b)) + 0.5
            elif name == "sqrt":
                a, i = _brace_group(s, i)
                w += _tex_width(a) + 1.5
            elif name in _ZERO_COMMANDS:
                continue
            elif name in (",", ":", ";", " ", "!"):
                w += 0.3
            else:
                w += _WIDE_COMMANDS.get(name, 1.0)
        elif c in "^_":
            a, i = _brace_group(s, i + 1)
            w += 0.7 * _tex_width(a)
        elif c in "{} &":
            i += 1
        elif c in "+-=<>":
            w += 2.0
            i += 1
        else:
            w += 1.0
            i += 1
    return w


def _terms(expr: sp.Expr) -> list[str]:
    """The LaTeX of each term of a sum, signs included, in the printer's order."""
    expr = sp.sympify(expr)
    terms = expr.as_ordered_terms() if isinstance(expr, sp.Add) else [expr]
    return [ltx(t) for t in terms]


def break_sum(
    lhs: str, expr: Any, width: float = LINE_WIDTH, tag: str | None = None, rel: str = "="
) -> list[str]:
    """Lines of an ``align*`` body for ``lhs = expr``, the sum's terms packed to ``width``.

    The first line is ``lhs &= t1 + t2 ...``; the next ones start with ``&\\quad``. A single
    term wider than the budget gets a line of its own.
    """
    parts = _terms(expr) if not isinstance(expr, str) else [expr]
    lines: list[str] = []
    cur = f"{lhs} &{rel} "
    cur_w = _tex_width(lhs) + 2
    first = True
    for t in parts:
        piece = t if first or t.startswith("-") else f"+ {t}"
        tw = _tex_width(piece)
        if not first and cur_w + tw > width and cur.strip() not in ("", "&"):
            lines.append(cur.rstrip())
            cur, cur_w = r"&\quad ", 2.0
        cur += piece + " "
        cur_w += tw
        first = False
    lines.append(cur.rstrip())
    if tag:
        lines[-1] += rf" \tag{{{tag}}}"
    return lines


@dataclass(frozen=True)
class Display:
    """A displayed equation block: ``align*`` lines (joined with \\\\ by the template filter)."""

    lines: tuple[str, ...]

    def __add__(self, other: Display) -> Display:
        return Display(self.lines + other.lines)


def eq(
    lhs: str, expr: Any, tag: str | None = None, width: float = LINE_WIDTH, rel: str = "="
) -> Display:
    return Display(tuple(break_sum(lhs, expr, width, tag, rel)))


def eqs(pairs: Sequence[tuple[str, Any]], tag: str | None = None) -> Display:
    """Several equations in one aligned block; ``tag`` goes on the last line."""
    out: list[str] = []
    for i, (lhs, expr) in enumerate(pairs):
        out += break_sum(lhs, expr, tag=tag if i == len(pairs) - 1 else None)
    return Display(tuple(out))


def matrix_tex(M: Any, fmt: Callable[[Any], str] | None = None) -> str:
    """A bmatrix of numbers (``fmt``) or expressions (``ltx``)."""
    M = np.atleast_2d(np.asarray(M, dtype=object))
    f = fmt or ltx
    rows = [" & ".join(f(v) for v in row) for row in M]
    return r"\begin{bmatrix}" + r" \\ ".join(rows) + r"\end{bmatrix}"


def _display_filter(d: Display) -> str:
    return "\\begin{align*}\n" + " \\\\\n".join(d.lines) + "\n\\end{align*}"


# ============================================================================= jinja


def latex_env() -> jinja2.Environment:
    """jinja2 with LaTeX-safe delimiters: \\BLOCK{...}, \\VAR{...}, \\#{...}."""
    path = resources.files("maglevgen.templates")
    env = jinja2.Environment(
        loader=jinja2.FileSystemLoader(str(path)),
        block_start_string=r"\BLOCK{",
        block_end_string="}",
        variable_start_string=r"\VAR{",
        variable_end_string="}",
        comment_start_string=r"\#{",
        comment_end_string="}",
        line_statement_prefix=None,
        line_comment_prefix=None,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
        autoescape=False,
        undefined=jinja2.StrictUndefined,
    )
    env.filters.update(
        tex=tex_escape,
        texbreak=tex_breakable,
        key=tex_key,
        unit=tex_unit,
        num=fnum,
        fixed=ffixed,
        complex=fcomplex,
        pct=fpct,
        err=ferr,
        display=_display_filter,
    )
    return env


def render_tex(ctx: dict[str, Any]) -> str:
    """report.tex from a context of `build_context`."""
    return latex_env().get_template("report.tex.j2").render(ctx)


# =========================================================================== symbols


_VEC = r"(?P<c>[xyz])"


def display_symbol(name: str) -> sp.Symbol:
    """The symbol the report prints for a flattened parameter name (vehicle.mass -> m)."""
    fixed = {
        "vehicle.mass": "m",
        "vehicle.length": r"\ell",
        "vehicle.gravity": "g",
        "halbach.remanence": "B_r",
        "halbach.thickness": "d",
        "halbach.magnets_per_wavelength": "M",
        "halbach.wavelength": "lambda",
        "halbach.width": "w",
        "circuit.resistance": "R",
        "circuit.inductance": "L",
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


def _array_labels(model) -> list[str]:
    """The arrays' names as LaTeX (names come from the parameter file)."""
    return [tex_escape(a.name) for a in model.arrays]


# =============================================================== parameters and provenance

_MARK = re.compile(
    r"^(?P<kind>paper|assumed)\b\s*(?:\((?P<scope>[^)]*)\))?\s*:\s*(?P<text>.*)$", re.IGNORECASE
)
_HEADER = re.compile(r"^\s*\[\s*([^\]]+?)\s*\]\s*(#.*)?$")
_KEYLINE = re.compile(r"^\s*([A-Za-z0-9_]+)\s*=\s*(.*)$")


@dataclass(frozen=True)
class Note:
    """A "paper:" or "assumed:" comment of the parameter file and what it applies to."""

    kind: str  # "paper" or "assumed"
    text: str
    scope: str  # a key, a section prefix ending in ".", or "" (the whole file)


def _inline_comment(value_and_comment: str) -> str | None:
    """The comment after a TOML value (outside strings), or None."""
    in_str: str | None = None
    for i, ch in enumerate(value_and_comment):
        if in_str:
            if ch == in_str:
                in_str = None
        elif ch in "\"'":
            in_str = ch
        elif ch == "#":
            return value_and_comment[i + 1 :].strip()
    return None


def parse_notes(text: str) -> list[Note]:
    """The file's "paper:"/"assumed:" comments with their scope (see `note_for`).

    An inline comment belongs to its key. A comment block right below a key belongs to that
    key; one at the top of a section (before its first key) to the section; one with an
    explicit scope such as "assumed (all arrays):" to the keys it names.
    """
    notes: list[Note] = []
    section, last_key, section_has_key = "", None, False
    block: list[str] = []
    block_ctx: tuple[str | None, str, bool] = (None, "", False)

    def flush() -> None:
        nonlocal block
        paragraphs: list[tuple[re.Match, list[str]]] = []
        for line in block:
            m = _MARK.match(line)
            if m:
                paragraphs.append((m, [m.group("text")]))
            elif paragraphs:
                paragraphs[-1][1].append(line)
        after_key, sec, sec_has_key = block_ctx
        for m, lines in paragraphs:
            scope_word = (m.group("scope") or "").strip().lower()
            if scope_word:
                scope = "arrays." if "array" in scope_word else ""
            elif after_key:
                scope = after_key
            elif sec and not sec_has_key:
                scope = sec + "."
            else:
                scope = ""
            notes.append(Note(m.group("kind").lower(), " ".join(lines).strip(), scope))
        block = []

    for raw in text.splitlines():
        line = raw.strip()
        if not line:
            flush()
            last_key = None
            continue
        if line.startswith("#"):
            if not block:
                block_ctx = (last_key, section, section_has_key)
            block.append(line.lstrip("#").strip())
            continue
        flush()
        h = _HEADER.match(line)
        if h:
            section, last_key, section_has_key = h.group(1).strip(), None, False
            continue
        k = _KEYLINE.match(line)
        if k:
            key = f"{section}.{k.group(1)}" if section else k.group(1)
            comment = _inline_comment(k.group(2))
            m = _MARK.match(comment or "")
            if m:
                notes.append(Note(m.group("kind").lower(), m.group("text").strip(), key))
            last_key, section_has_key = key, True
    flush()
    return notes


def note_for(key: str, notes: Sequence[Note]) -> Note | None:
    """The most specific note of a key: its own, then its section's, then a wider scope."""
    best: Note | None = None
    for n in notes:
        if n.scope == key:
            return n
        if (
            n.scope.endswith(".")
            and key.startswith(n.scope)
            and (best is None or len(n.scope) > len(best.scope))
        ):
            best = n
    return best


_PAPER_NUMBER = re.compile(
    r"^\s*(?:[A-Za-z]+\s*=\s*)?(?P<num>[-+]?[0-9.]+(?:e[-+]?\d+)?|I)\s*"
    r"(?P<unit>cm|mm|kg|ohm|H|m)?\b",
    re.IGNORECASE,
)
_UNIT_SCALE = {"cm": 1e-2, "mm": 1e-3}


def paper_number(text: str) -> float | None:
    """The number of a schema "paper" value ("65 cm" -> 0.65, "Q = I" -> 1), or None."""
    m = _PAPER_NUMBER.match(text)
    if not m:
        return None
    num = m.group("num")
    value = 1.0 if num == "I" else float(num)
    return value * _UNIT_SCALE.get((m.group("unit") or "").lower(), 1.0)


@dataclass(frozen=True)
class ParamRow:
    """One row of the parameter table."""

    key: str
    symbol: str  # LaTeX
    values: tuple[float, ...]
    unit: str
    description: str
    source: str  # "paper", "assumed", "changed" or "set"
    paper: str  # the paper's value as the schema gives it, or ""
    note: int | None  # index into the notes list (1-based), or None
    override: str  # the --set item that set it, or ""


def _same_field_paper_note(
    key: str,
    values: tuple[float, ...],
    notes: list[Note],
    rows_by_key: dict[str, tuple[float, ...]],
) -> Note | None:
    """A "paper:" note on the same field of another array with the same value up to sign.

    Up to sign: the file marks one array of each mirror-image pair (1 and 2, 4 and 5).
    """
    m = re.fullmatch(r"arrays\.[^.]+\.([^.]+)", key)
    if not m:
        return None
    for n in notes:
        other = re.fullmatch(r"arrays\.[^.]+\." + re.escape(m.group(1)), n.scope)
        ref = rows_by_key.get(n.scope)
        if (
            other
            and n.kind == "paper"
            and ref is not None
            and all(abs(abs(a) - abs(b)) <= 1e-12 for a, b in zip(ref, values, strict=True))
        ):
            return n
    return None


def parameter_rows(loaded, text: str) -> tuple[list[ParamRow], list[Note]]:
    """The parameter table: each schema leaf's value, unit, source and the reason for it.

    Which values are the paper's: the schema's ``paper`` entries and the file's "paper:"
    comments; the reasons for the others: the file's "assumed:" comments. A value that differs
    from the schema's paper value is "changed"; one given with --set is "set".
    """
    notes = parse_notes(text)
    from .params import schema_leaves

    leaves = [(lf.key, lf.values, lf.unit, lf.description, lf.paper)
              for lf in schema_leaves(loaded.params)]
    rows_by_key = {k: v for k, v, *_ in leaves}
    overrides = {}
    for item in loaded.overrides:
        name = item.split("=", 1)[0].strip()
        overrides[name] = item
    used: list[Note] = []
    rows = []
    for key, values, unit, desc, paper in leaves:
        note = note_for(key, notes)
        if note is None or note.scope != key:
            note = _same_field_paper_note(key, values, notes, rows_by_key) or note
        override = next(
            (item for name, item in overrides.items() if key == name or key.startswith(name + ".")),
            "",
        )
        ref = paper_number(paper) if paper else None
        if override:
            source = "set"
        elif ref is not None and any(abs(v - ref) > 1e-9 * max(abs(ref), 1e-300) for v in values):
            source = "changed"
        elif paper or (note is not None and note.kind == "paper"):
            source = "paper"
        else:
            source = "assumed"
        idx = None
        if note is not None:
            if note not in used:
                used.append(note)
            idx = used.index(note) + 1
        rows.append(
            ParamRow(key, display_key_symbol(key), values, unit, desc, source, paper, idx, override)
        )
    return rows, used


def params_text_of(loaded) -> str:
    """The text of the parameter file a LoadedParams came from (its comments hold the reasons).

    The file named by ``loaded.source`` if loading it again gives the same digest, else the
    default file if that does; so a file in the working folder that happens to carry the
    default file's name is never mistaken for it.
    """
    from .params import DEFAULT_PARAMS_NAME, default_params_text, load_params

    candidates: list[tuple[str | None, Callable[[], str]]] = []
    if loaded.source != DEFAULT_PARAMS_NAME or Path(loaded.source).is_file():
        candidates.append((loaded.source, lambda: Path(loaded.source).read_text("utf-8")))
    candidates.append((None, default_params_text))
    for path, read in candidates:
        try:
            if load_params(path, loaded.overrides).sha256 == loaded.sha256:
                return read()
        except (OSError, UnicodeDecodeError, InputError):
            continue
    raise InputError(f"{loaded.source}: the parameter file changed while the report was made")


# ======================================================================== section builders

_PHI, _THETA, _PSI = sp.symbols("phi theta psi")


def _trig_abbrev() -> dict[sp.Expr, sp.Symbol]:
    """cos(phi) -> c_phi, sin(phi) -> s_phi, ... (named subexpressions of the rotations)."""
    rep: dict[sp.Expr, sp.Symbol] = {}
    for a in (_PHI, _THETA, _PSI):
        rep[sp.cos(a)] = sp.Symbol(f"c_{a.name}")
        rep[sp.sin(a)] = sp.Symbol(f"s_{a.name}")
    return rep


def abbreviate_radicals(
    exprs: Sequence[sp.Expr], prefix: str = "s"
) -> tuple[list[tuple[sp.Symbol, sp.Expr]], list[sp.Expr]]:
    """Name every square root of a compound base, innermost first: (definitions, exprs)."""
    exprs = [sp.sympify(e) for e in exprs]
    defs: list[tuple[sp.Symbol, sp.Expr]] = []
    while True:
        cands = {
            p
            for e in exprs
            for p in e.atoms(sp.Pow)
            if p.exp == sp.S.Half and not p.base.is_Symbol and not p.base.is_Number
        }
        if not cands:
            return defs, exprs
        inner = min(cands, key=lambda p: (sp.count_ops(p), sp.srepr(p)))
        sym = sp.Symbol(f"{prefix}_{len(defs) + 1}")
        defs.append((sym, inner))
        exprs = [e.xreplace({inner: sym}) for e in exprs]


def _conventions(model) -> dict[str, Any]:
    return _conventions_section(model.input_names, _REPORT_SOURCE)


@memoized
def _conventions_section(input_names: tuple[str, ...], _source: str) -> dict[str, Any]:
    """States, axes, inputs, R and the kinematics (cached across processes: they depend on
    the input names alone)."""
    from .derive.rigid_body import euler_rates, rotation_body_to_inertial

    ab = _trig_abbrev()
    Rm = rotation_body_to_inertial(_PHI, _THETA, _PSI)
    vel = sp.Matrix(sp.symbols("u v w"))
    omega = sp.Matrix(sp.symbols("p q r"))
    pos_rates = (Rm * vel).xreplace(ab)
    rates = (
        euler_rates(_PHI, _THETA, omega)
        .xreplace(ab)
        .xreplace({sp.tan(_THETA): sp.Symbol("t_theta")})
    )
    inputs = [cv.PROPULSION] + [
        cv.Signal(n, "N", f"control force of array {n[3:]} along body {n[2]}")
        for n in input_names[1:]
    ]
    return {
        "states": [(i, ltx(sp.Symbol(st.name)), st) for i, st in enumerate(cv.STATES)],
        "axes": [
            (a, ltx(sp.Symbol(cv.AXIS_POSITION_STATE[a])), c)
            for a, c in zip(cv.AXES, cv.CONTROLS, strict=True)
        ],
        "inputs": inputs,
        "rotation": Display((r"\mathbf{R} &= " + ltx(Rm.xreplace(ab)),)),
        "kinematics": eqs(
            [(ltx(sp.Symbol(rf"\dot{{{s}}}")), pos_rates[i]) for i, s in enumerate("xyz")]
            + [
                (ltx(sp.Symbol(rf"\dot{{\{s}}}")), rates[i])
                for i, s in enumerate(("phi", "theta", "psi"))
            ]
        ),
    }


def _vec(names: str) -> sp.Matrix:
    return sp.Matrix(sp.symbols(names))


def _rigid_body_exprs():
    """Eqs 1-2 in components, with I_O's entries named (defined by the parallel-axis theorem)."""
    from .derive.rigid_body import inertia_about_origin

    m = sp.Symbol("m")
    rG = _vec("x_G y_G z_G")
    v, om = _vec("u v w"), _vec("p q r")
    vd = sp.Matrix([sp.Symbol(rf"\dot{{{n}}}") for n in "uvw"])
    omd = sp.Matrix([sp.Symbol(rf"\dot{{{n}}}") for n in "pqr"])
    keys = (("xx", "xy", "xz"), ("xy", "yy", "yz"), ("xz", "yz", "zz"))
    IO = sp.Matrix(3, 3, lambda i, j: sp.Symbol(f"I^O_{keys[i][j]}"))
    IG = sp.Matrix(3, 3, lambda i, j: sp.Symbol(f"I_{keys[i][j]}"))
    f1 = m * (vd + om.cross(v) + omd.cross(rG) + om.cross(om.cross(rG)))
    m2 = IO * omd + om.cross(IO * om) + m * rG.cross(vd + om.cross(v))
    return m, rG, v, om, vd, omd, IO, IG, f1, m2, inertia_about_origin(m, IG, rG)


def _rigid_body_check(samples: int = 3, seed: int = 7) -> int:
    """Eqs 1-2 at the model's solved accelerations, in exact rationals: count of nonzero
    residual components over ``samples`` random bodies and motions (0 when they agree)."""
    from .derive.rigid_body import body_accelerations

    m, rG, v, om, vd, omd, IO, IG, f1, m2, IO_expr = _rigid_body_exprs()
    rng = random.Random(seed)

    def q() -> sp.Rational:
        return sp.Rational(Fraction(rng.randint(-99, 99), rng.randint(1, 50)))

    nonzero = 0
    for _ in range(samples):
        off = [q() / 10 for _ in range(3)]
        IGv = sp.Matrix(
            [
                [3 + abs(q()), off[0], off[1]],
                [off[0], 3 + abs(q()), off[2]],
                [off[1], off[2], 3 + abs(q())],
            ]
        )
        vals: dict[sp.Symbol, Any] = {m: 1 + abs(q())}
        vals.update(zip(rG, [q() / 10 for _ in range(3)], strict=True))
        vals.update(zip(v, [q() for _ in range(3)], strict=True))
        vals.update(zip(om, [q() for _ in range(3)], strict=True))
        f = sp.Matrix([q() for _ in range(3)])
        M = sp.Matrix([q() for _ in range(3)])
        vdot, omdot = body_accelerations(
            vals[m], IGv, rG.xreplace(vals), v.xreplace(vals), om.xreplace(vals), f, M
        )
        vals.update(zip(vd, vdot, strict=True))
        vals.update(zip(omd, omdot, strict=True))
        vals.update(zip(IG, IGv, strict=True))
        IOv = IO_expr.xreplace(vals)
        vals.update(zip(IO, IOv, strict=True))
        res = list(f1.xreplace(vals) - f) + list(m2.xreplace(vals) - M)
        nonzero += sum(1 for r in res if sp.simplify(r) != 0)
    return nonzero


def _rigid_body() -> dict[str, Any]:
    return _rigid_body_section(_REPORT_SOURCE)


@memoized
def _rigid_body_section(_source: str) -> dict[str, Any]:
    """Eqs 1-2 and the parallel-axis theorem, and the exact check of the solved equations:
    parameter independent, cached across processes."""
    *_, IO, _IG, f1, m2, IO_expr = _rigid_body_exprs()
    comps = "xyz"
    eq1 = eqs([(f"f_{{O,{c}}}", sp.expand(f1[i])) for i, c in enumerate(comps)], tag="1")
    eq2 = eqs([(f"m_{{O,{c}}}", sp.expand(m2[i])) for i, c in enumerate(comps)], tag="2")
    upper = [(i, j) for i in range(3) for j in range(i, 3)]
    parallel = eqs([(ltx(IO[i, j]), sp.expand(IO_expr[i, j])) for i, j in upper])
    return {
        "eq1": eq1,
        "eq2": eq2,
        "parallel_axis": parallel,
        "exact_residual_nonzero": _rigid_body_check(),
    }


# Report pieces cached across processes (derive.memo's store, whose key covers the derivation's
# source) take this file's digest as an argument, so an edit here renders them again.
_REPORT_SOURCE = hashlib.sha256(Path(__file__).read_bytes()).hexdigest()[:16]

# The force law's symbols: eq 4's B_r, d, M and eq 3's w, L, R, B_0, gap delta and speed v.
_FORCE_SYMBOLS = sp.symbols("B_r d M w L R B_0 delta v")


@memoized
def _force_law_forms(_source: str) -> dict[str, Any]:
    """Eqs 3-4 in display symbols and what follows from them (parameter independent, cached
    across processes): B0, F_L, F_D, F_D/F_L, the gap slope and the characteristic speed."""
    from .derive.inductrack import drag_per_circuit, halbach_surface_field, lift_per_circuit

    Br, d, M, w, L, R, B0, delta, v = _FORCE_SYMBOLS
    k = K_SYM
    FL = lift_per_circuit(B0, w, k, L, R, delta, v)
    FD = drag_per_circuit(B0, w, k, L, R, delta, v)
    ratio = sp.simplify(FD / FL)
    (v_c,) = [s for s in sp.solve(sp.Eq(ratio, 1), v) if s.is_positive is not False]
    return {"B0": halbach_surface_field(Br, d, M, k), "FL": FL, "FD": FD, "ratio": ratio,
            "slope": sp.simplify(sp.diff(FL, delta) / FL), "v_c": v_c}


def _force_numbers(carriage) -> dict[sp.Symbol, float]:
    """The force law's symbols with the carriage's values (B0 from eq 4)."""
    Br, d, M, w, L, R, B0, _delta, _v = _FORCE_SYMBOLS
    pr = carriage.params
    num = {Br: pr.halbach.remanence, d: pr.halbach.thickness,
           M: pr.halbach.magnets_per_wavelength, K_SYM: pr.wavenumber, w: pr.halbach.width,
           L: pr.circuit.inductance, R: pr.circuit.resistance}
    num[B0] = float(_force_law_forms(_REPORT_SOURCE)["B0"].xreplace(num))
    return num


def force_curves(carriage, trim) -> dict[str, Any]:
    """What the force figures draw, as plain numbers (they are drawn in another process):
    F_L and F_D (eq 3) of one upper array against the gap at the trim speed and against the
    speed at the nominal gap, and every array's point at trim."""
    forms, num = _force_law_forms(_REPORT_SOURCE), _force_numbers(carriage)
    delta, v = _FORCE_SYMBOLS[7:]
    FL = sp.lambdify((delta, v), forms["FL"].xreplace(num), "numpy")
    FD = sp.lambdify((delta, v), forms["FD"].xreplace(num), "numpy")
    v_c = float(forms["v_c"].xreplace(num))
    arrays = list(carriage.params.arrays.items())
    upper = [a for _, a in arrays if abs(a.normal[2]) > 1 - 1e-9] or [a for _, a in arrays]
    n_c, g0 = upper[0].circuits, upper[0].nominal_gap
    gap = np.linspace(carriage.params.track.min_gap, 0.05, 400)
    speed = np.linspace(0.0, max(3 * trim.speed, 3 * v_c), 400)
    points: dict[tuple[float, float], list[str]] = {}
    dots = []
    for i, (name, a) in enumerate(arrays):
        xy = (float(trim.gaps[i] * 1e3), float(trim.lift[i] * n_c / a.circuits))
        dots.append(xy)
        points.setdefault((round(xy[0]), round(xy[1], -1)), []).append(name)
    return {"speed": trim.speed, "v_c": v_c, "circuits": n_c, "nominal_gap": g0,
            "gap": gap, "lift_gap": n_c * FL(gap, trim.speed),
            "drag_gap": n_c * FD(gap, trim.speed),
            "v": speed, "lift_v": n_c * FL(g0, speed), "drag_v": n_c * FD(g0, speed),
            "dots": dots, "labels": [(xy, ", ".join(names)) for xy, names in points.items()]}


def _force_law(carriage, trim, trep: dict) -> dict[str, Any]:
    forms, num = _force_law_forms(_REPORT_SOURCE), _force_numbers(carriage)
    B0_expr, FL, FD = forms["B0"], forms["FL"], forms["FD"]
    ratio, slope, v_c = forms["ratio"], forms["slope"], forms["v_c"]
    v = _FORCE_SYMBOLS[8]
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
        "ratio_at_trim": float(ratio.xreplace({**num, v: trim.speed})),
        "arrays": arrays,
    }


def _geometry(carriage, gains: dict) -> dict[str, Any]:
    model = carriage.model
    free = model.gaps.free_symbols
    gap_values = tuple((e.name, float(e.value)) for e, s in zip(carriage.entries, model.p,
                                                                  strict=True) if s in free)
    arrays = tuple((name, tuple(map(float, a.position)), tuple(map(float, a.normal)))
                   for name, a in carriage.params.arrays.items())
    gaps, derived, printed = _geometry_displays(model.structure, gap_values, arrays,
                                                _REPORT_SOURCE)
    return {
        "gaps": gaps,
        "derived_sums": derived,
        "printed_sums": printed,
        "forces": gains["allocation"]["forces"],
    }


@memoized
def _geometry_displays(structure, gap_values: tuple[tuple[str, float], ...],
                       arrays: tuple[tuple[str, tuple[float, ...], tuple[float, ...]], ...],
                       _source: str) -> tuple[Display, Display, Display]:
    """The gaps with ``gap_values`` substituted, the generalized forces of the arrays' lifts
    and drags at the design pose (eqs 8-12 derived, from ``arrays``: name, position, normal)
    and the paper's printed sums; keyed by what they show (memoised across processes), so that
    editing a parameter they do not show finds them cached."""
    from .derive.geometry import generalized_wrench_row
    from .derive.model import build_model
    from .derive.paper import paper_force_sums

    model = build_model(structure)
    ab = _trig_abbrev()
    state_sym = dict(zip(model.x, sp.symbols(" ".join(cv.STATE_NAMES)), strict=True))
    gaps = []
    for i, arr in enumerate(model.arrays):
        gexpr = to_display(model, model.gaps[i], dict(gap_values)).xreplace(state_sym)
        gaps += break_sum(rf"\delta_{{{tex_escape(arr.name)}}}",
                          round_floats(sp.expand(gexpr.xreplace(ab))))
    ex = sp.Matrix([-1, 0, 0])
    total = sp.zeros(5, 1)
    for name, position, normal in arrays:
        pos = sp.Matrix([sp.Float(c, 17) for c in position])
        nrm = sp.Matrix([sp.Float(c, 17) for c in normal])
        label = tex_escape(name)
        FL, FD = sp.Symbol(f"F_{{L,{label}}}"), sp.Symbol(f"F_{{D,{label}}}")
        total += generalized_wrench_row(pos, nrm) * FL + generalized_wrench_row(pos, ex) * FD
    labels = ("F_y", "F_z", "M_x", "M_y", "M_z")
    derived = eqs([(rf"\textstyle\sum {lab}", round_floats(sp.expand(total[i])))
                   for i, lab in enumerate(labels)])
    printed_sums = paper_force_sums()
    printed_order = (("F_z", "8"), ("F_y", "9"), ("M_x", "10"), ("M_z", "11"), ("M_y", "12"))
    printed = Display(
        tuple(
            line
            for lab, tag in printed_order
            for line in break_sum(rf"\textstyle\sum {lab}", printed_sums[lab], tag=tag)
        )
    )
    return Display(tuple(gaps)), derived, printed


def _trim(trep: dict) -> dict[str, Any]:
    return {
        "speed": trep["speed"],
        "lift_off": trep["lift_off_speed"],
        "residual": trep["residual"],
        "F_prop": trep["propulsion_force"],
        "states": [
            (s.name, ltx(sp.Symbol(s.name)), trep["state"][s.name], s.unit, s.description)
            for s in cv.STATES
        ],
    }


_Q_LABELS = ("y", "z", r"\phi", r"\theta", r"\psi")
_W_LABELS = ("F_y", "F_z", "M_x", "M_y", "M_z")


def _shown_values(carriage) -> tuple[tuple[str, float], ...]:
    """The parameter values the stiffness display substitutes: those of the symbols in K_st0
    (the array geometry), so that editing any other parameter finds the display cached."""
    from .derive.linearize import design_pose_stiffness

    model = carriage.model
    free = design_pose_stiffness(model.structure).free_symbols
    return tuple((e.name, float(e.value)) for e, s in zip(carriage.entries, model.p, strict=True)
                 if s in free and e.name != "halbach.wavelength")


@memoized
def _stiffness_display(structure, values: tuple[tuple[str, float], ...],
                       _source: str) -> tuple[Display, Display]:
    """K_st0 at the design pose (eqs 13-19 derived) with ``values`` substituted, entry by
    entry, and the generalized masses, as LaTeX lines."""
    from .derive.linearize import design_pose_stiffness, generalized_mass_expr
    from .derive.model import build_model

    model = build_model(structure)
    K = design_pose_stiffness(structure)
    names = _array_labels(model)
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


def _stiffness(carriage, trim, trep: dict) -> dict[str, Any]:
    from .derive.paper import paper_stiffness

    model = carriage.model
    lines, mass_lines = _stiffness_display(model.structure, _shown_values(carriage),
                                           _REPORT_SOURCE)
    K_mag = np.array(trep["stiffness_matrix"])
    K_tot = carriage.total_stiffness(trim)
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
                "formula": ltx(printed[axis]),
                "eq": tags[axis],
                "paper": r["paper"],
                "derived": r["derived"],
                "total": r["derived_with_gravity"],
                "rel": r["paper_relative_difference"],
            }
        )
    inputs = [(ltx(syms[n]), v) for n, v in trep["paper_inputs"].items()]
    A, B = carriage.linearize(trim)
    scale = np.max(np.abs(A))
    a_entries = [
        (
            rf"\dot{{{ltx(sp.Symbol(cv.STATE_NAMES[i]))}}}",
            ltx(sp.Symbol(cv.STATE_NAMES[j])),
            float(A[i, j]),
        )
        for i in range(12)
        for j in range(12)
        if abs(A[i, j]) > 1e-13 * scale
    ]
    return {
        "K_symbolic": lines,
        "mass": mass_lines,
        "mass_values": carriage.generalized_mass().tolist(),
        "K_mag": matrix_tex(K_mag, lambda v: fnum(v, 5)),
        "K_tot": matrix_tex(K_tot, lambda v: fnum(v, 5)),
        "rows": rows,
        "paper_inputs": inputs,
        "A_entries": a_entries,
        "B_shape": B.shape,
        "B_nonzero": int(np.count_nonzero(np.abs(B) > 1e-13)),
    }


def _damping_allocation(gains: dict) -> dict[str, Any]:
    axes = []
    for axis, a in gains["axes"].items():
        cg = a["damping_gain"]
        if cg is None:
            poles = None
        else:
            poles = sorted(
                np.roots([a["inertia"], cg, a["stiffness"]]), key=lambda z: (z.real, z.imag)
            )
        axes.append({"axis": axis, "k": a["stiffness"], "m": a["inertia"], "c": cg, "poles": poles})
    alloc = gains["allocation"]
    E, T = np.array(alloc["effectiveness"]), np.array(alloc["minimum_norm"])
    return {
        **_damping_allocation_forms(E.shape, _REPORT_SOURCE),
        "axes": axes,
        "E": matrix_tex(E, lambda v: fnum(v, 4)),
        "T": matrix_tex(T, lambda v: fnum(v, 4)),
        "E_T_residual": float(np.max(np.abs(E @ T - np.eye(E.shape[0])))),
        "T_pinv_residual": float(np.max(np.abs(T - np.linalg.pinv(E)))),
        # F_<axis><array name>: the name escaped, the axis a subscript as sympy prints F_y3
        "forces": [ltx(sp.Symbol(f"F_{{{f[2]}{tex_escape(f[3:])}}}")) for f in alloc["forces"]],
        "controls": [ltx(sp.Symbol(c_)) for c_ in alloc["controls"]],
    }


@memoized
def _damping_allocation_forms(shape: tuple[int, int], _source: str) -> dict[str, Any]:
    """The damping cost and its optimum (eqs 20-21 derived), the allocation's Lagrangian and
    solution for an E of ``shape``, and the paper's printed eqs 22-23: parameter
    independent, cached across processes."""
    from .derive.damping import (
        damping_gain_closed_form,
        optimal_damping_ratio,
        square_error_cost,
    )
    from .derive.paper import paper_allocation

    c, k, m, x0 = sp.symbols("c k m x0", positive=True)
    J = square_error_cost(c, k, m, x0)
    dJ = sp.factor(sp.diff(J, c))
    c_opt = damping_gain_closed_form(k, m)
    curv = sp.simplify(sp.diff(J, c, 2).subs(c, c_opt))
    F = sp.MatrixSymbol("F", shape[1], 1)
    lam = sp.MatrixSymbol("lambda", shape[0], 1)
    Es, us = sp.MatrixSymbol("E", *shape), sp.MatrixSymbol("u", shape[0], 1)
    printed = paper_allocation()
    order = ("F_z3", "F_z1", "F_z2", "F_z6", "F_z5", "F_z4", "F_y1", "F_y2", "F_y4", "F_y5")
    pl: list[str] = []
    for i in range(0, len(order), 2):
        a_, b_ = order[i], order[i + 1]
        pl.append(
            f"{ltx(sp.Symbol(a_))} &= {ltx(printed[a_])} & "
            f"{ltx(sp.Symbol(b_))} &= {ltx(printed[b_])}"
        )
    pl[2] += r" \tag{22}"
    pl[-1] += r" \tag{23}"
    return {
        "J": eq(r"J(c)", J),
        "dJ": eq(r"\frac{\partial J}{\partial c}", dJ),
        "c_opt": eq(r"c^{*}", c_opt),
        "curvature": eq(r"\left.\frac{\partial^2 J}{\partial c^2}\right|_{c^{*}}", curv),
        "zeta": eq(r"\zeta^{*}", optimal_damping_ratio()),
        "lagrangian": eq(r"\mathcal{L}", F.T * F + lam.T * (Es * F - us)),
        "solution": eq("T", Es.T * (Es * Es.T).I),
        "printed": Display(tuple(pl)),
    }


def _riccati(gains: dict) -> dict[str, Any]:
    from .derive.paper import paper_riccati
    from .derive.riccati import (
        axis_matrices,
        riccati_closed_form,
        riccati_residual,
        riccati_stable_form,
    )

    k, m = sp.Symbol("k"), sp.Symbol("m")
    q1, q2, r = sp.symbols("q_1 q_2 r")
    A, B = axis_matrices(k, m)
    p11, p12, p22 = sp.symbols("p_11 p_12 p_22")
    P = sp.Matrix([[p11, p12], [p12, p22]])
    res = riccati_residual(A, B, sp.diag(q1, q2), sp.Matrix([[r]]), P)
    are = eqs(
        [(ltx(sp.expand(res[i, j])), sp.Integer(0)) for i, j in ((0, 0), (0, 1), (1, 1))], tag="30"
    )
    g = riccati_closed_form(k, m, q1, q2, r)
    defs, (P11, P12, P22, K1, K2, s1, s2) = abbreviate_radicals(
        [g.P[0, 0], g.P[0, 1], g.P[1, 1], g.K[0], g.K[1], *g.poles], "sigma"
    )
    closed = eqs(
        [(ltx(s), e) for s, e in defs] + [("p_{11}", P11), ("p_{12}", P12), ("p_{22}", P22)],
        tag="31",
    )
    gain = eqs([("K_1", K1), ("K_2", K2)], tag="32")
    poles = eqs([(r"\lambda_{1}", s1), (r"\lambda_{2}", s2)])
    st = riccati_stable_form(k, m, q1, q2, r)
    K1s, K2s = sp.symbols("K_1 K_2")
    Pst = st.P_of_gains(K1s, K2s)
    stable = eqs(
        [
            (r"\sigma", st.sigma),
            (r"K_1\big|_{k \ge 0}", st.K1_nonneg),
            (r"K_1\big|_{k < 0}", st.K1_neg),
            ("K_2", st.K2_of_K1(K1s)),
            ("p_{11}", Pst[0, 0]),
            ("p_{12}", Pst[0, 1]),
            ("p_{22}", Pst[1, 1]),
        ]
    )
    Pp, Kp = paper_riccati(k, m)
    printed = eqs(
        [("p_{11}", Pp[0, 0]), ("p_{12}", Pp[0, 1]), ("p_{22}", Pp[1, 1])], tag="31"
    ) + eqs([("K_1", Kp[0]), ("K_2", Kp[1])], tag="32")
    axes = []
    for axis, a in gains["axes"].items():
        axes.append(
            {
                "axis": axis,
                "k": a["stiffness"],
                "m": a["inertia"],
                "K_cf": a["K_closed_form"],
                "K_num": a["K_numerical"],
                "K_paper": a["K_paper"],
                "P": a["P_closed_form"],
                "poles": [complex(*p) for p in a["closed_loop_poles"]],
                "rel_num": a["relative_difference"]["numerical_vs_closed_form"],
                "rel_paper": a["relative_difference"]["paper_vs_closed_form"],
            }
        )
    return {
        "A": ltx(A),
        "B": ltx(B),
        "Q": ltx(sp.diag(q1, q2)),
        "R": ltx(r),
        "are": are,
        "closed": closed,
        "gain": gain,
        "poles": poles,
        "stable": stable,
        "printed": printed,
        "axes": axes,
        "Q_values": gains["Q"],
        "R_value": gains["R"],
        "paper_applies": all(a["paper_applies"] for a in gains["axes"].values()),
    }


def _zeta(pole: complex) -> float:
    """Damping ratio of a pole: -Re / |pole|."""
    return float(-pole.real / abs(pole)) if pole != 0 else 1.0


def _paper_comparison(gains: dict, trep: dict) -> dict[str, Any]:
    from .derive.paper import (
        paper_discrepancies_allocation,
        paper_discrepancies_riccati,
        paper_riccati,
    )
    from .derive.riccati import (
        axis_matrices,
        lqr_gain_mp,
        lqr_gain_numeric,
        riccati_relative_residual,
    )

    (q1, _), (_, q2) = gains["Q"]
    r = gains["R"]
    axes = []
    for axis, a in gains["axes"].items():
        k, m = a["stiffness"], a["inertia"]
        with mpmath.workdps(50):
            P, _K = paper_riccati(sp.Float(k, 50), sp.Float(m, 50))
            A, B = axis_matrices(sp.Float(k, 50), sp.Float(m, 50))
            paper_res = riccati_relative_residual(A, B, [[1, 0], [0, 1]], [[1]], P)
            ref = [mpmath.mpf(v) for v in lqr_gain_mp(k, m, q1, q2, r)]

            def rel(K: np.ndarray, ref: list = ref) -> float:
                return float(
                    max(
                        abs(mpmath.mpf(float(x)) - y) / abs(y)
                        for x, y in zip(np.ravel(K), ref, strict=True)
                    )
                )

            with np.errstate(all="ignore"):
                naive32 = rel(lqr_gain_numeric(k, m, q1, q2, r, np.float32, "closed"))
                stable32 = rel(lqr_gain_numeric(k, m, q1, q2, r, np.float32, "stable"))
                naive64 = rel(lqr_gain_numeric(k, m, q1, q2, r, np.float64, "closed"))
        lqr_poles = [complex(*p) for p in a["closed_loop_poles"]]
        c = a["damping_gain"]
        damp_poles = list(np.roots([m, c, k])) if c is not None else []
        axes.append(
            {
                "axis": axis,
                "paper_residual": paper_res,
                "paper_gain_rel": a["relative_difference"]["paper_vs_closed_form"],
                "naive32": naive32,
                "stable32": stable32,
                "naive64": naive64,
                "zeta_lqr": min(_zeta(p) for p in lqr_poles),
                "decay_lqr": -max(p.real for p in lqr_poles),
                "zeta_damping": min(_zeta(p) for p in damp_poles) if damp_poles else None,
                "decay_damping": -max(p.real for p in damp_poles) if damp_poles else None,
            }
        )
    coupled = gains["coupled"]
    slowest = {
        name: -max(p[0] for p in coupled[key])
        for name, key in (
            ("per_axis", "poles_per_axis_design"),
            ("coupled", "poles_coupled_lqr"),
            ("damping", "poles_damping"),
        )
    }
    lat = gains["axes"]["lateral"]
    riccati_notes = paper_discrepancies_riccati(
        sp.Float(lat["stiffness"], 6), sp.Float(lat["inertia"], 6)
    )
    return {
        "stiffness": [
            (axis, r_["paper_relative_difference"]) for axis, r_ in trep["stiffness"].items()
        ],
        "axes": axes,
        "slowest": slowest,
        "cost_per_axis": coupled["cost_per_axis_design"],
        "cost_coupled": coupled["cost_coupled_lqr"],
        "riccati_notes": riccati_notes,
        "allocation_notes": paper_discrepancies_allocation(),
    }


@dataclass(frozen=True)
class Check:
    """One row of the verification table."""

    what: str  # LaTeX text
    reference: str  # LaTeX text
    error: float | None  # measured error (None: not run)
    bound: float
    note: str = ""  # why it was not run

    @property
    def status(self) -> str:
        if self.error is None:
            return "not run"
        return "pass" if self.error <= self.bound else "FAIL"


def _generated_c_checks(
    carriage,
    trim,
    gains: dict,
    progress: Callable[[str], None],
    samples: int = 300,
    seed: int = 20240607,
) -> list[Check]:
    """Generated C (double, run-time parameters) against the SymPy model and the gains."""
    from .library import simulation_library

    what = (
        f"Generated C \\texttt{{maglev\\_dynamics}} vs SymPy model, {samples} states near trim",
        "Generated C \\texttt{maglev\\_jacobians} vs chain-rule Jacobians, 20 states",
        "Generated C \\texttt{maglev\\_trim} vs Python trim",
        "Generated C \\texttt{maglev\\_lqr\\_gains} vs closed form",
    )
    refs = (
        "lambdified model layers",
        "lambdified partials",
        "SciPy root (hybrd)",
        "\\texttt{gains} closed form",
    )
    bounds = (1e-12, 1e-10, 1e-9, 1e-10)
    try:
        lib = simulation_library(carriage.structure, progress=progress)
    except MaglevError as exc:
        return [
            Check(w, r_, None, b, f"not run: {exc}")
            for w, r_, b in zip(what, refs, bounds, strict=True)
        ]
    mf, p = carriage.functions, carriage.p
    rng = np.random.default_rng(seed)
    n_u = carriage.model.u.shape[0]
    X = trim.x + rng.normal(
        scale=[0.5, 1e-3, 1e-3, 5e-3, 5e-3, 5e-3, 1.0, 0.02, 0.02, 0.05, 0.05, 0.05],
        size=(samples, 12),
    )
    U = trim.u + rng.normal(scale=2.0, size=(samples, n_u))
    dyn = lib.function("maglev_dynamics")
    ref = np.array([mf.xdot(x, u, p) for x, u in zip(X, U, strict=True)])
    got = np.array([dyn(x, u, p)[0].ravel() for x, u in zip(X, U, strict=True)])
    scale = np.maximum(np.max(np.abs(ref), axis=0), 1e-300)
    e_dyn = float(np.max(np.abs(got - ref) / scale))
    jac = lib.function("maglev_jacobians")
    e_jac = 0.0
    for x, u in zip(X[:20], U[:20], strict=True):
        A, B = mf.jacobians(x, u, p)
        Ac, Bc = jac(x, u, p)
        e_jac = max(
            e_jac,
            float(np.max(np.abs(Ac - A)) / np.max(np.abs(A))),
            float(np.max(np.abs(Bc - B)) / np.max(np.abs(B))),
        )
    xt, fp = lib.function("maglev_trim")([trim.speed], p)
    e_trim = max(
        float(np.max(np.abs(xt.ravel() - trim.x))),
        abs(float(fp.ravel()[0]) - trim.u[0]) / abs(trim.u[0]),
    )
    Kc, _c = lib.function("maglev_lqr_gains")([trim.speed], p)
    K_ref = np.array([a["K_closed_form"] for a in gains["axes"].values()])
    e_gain = float(np.max(np.abs(Kc - K_ref) / np.abs(K_ref)))
    return [
        Check(w, r_, e, b)
        for w, r_, e, b in zip(what, refs, (e_dyn, e_jac, e_trim, e_gain), bounds, strict=True)
    ]


def _verification(
    carriage,
    trim,
    gains: dict,
    trep: dict,
    rigid: dict,
    alloc: dict,
    paper: dict,
    c_progress: Callable[[str], None] | None,
) -> list[Check]:
    """The verification table; the generated-C rows only when ``c_progress`` is given."""
    from .derive.riccati import riccati_relative_residual

    axes = gains["axes"]
    (q1, _), (_, q2) = gains["Q"]
    r = gains["R"]
    with mpmath.workdps(50):
        are = max(
            riccati_relative_residual(a["A"], a["B"], [[q1, 0], [0, q2]], [[r]], a["P_closed_form"])
            for a in axes.values()
        )
    checks = [
        Check(
            "Closed-form $K$ (eq 32, stable form) vs numerical LQR, all axes",
            "scipy CARE (Schur)",
            max(a["relative_difference"]["numerical_vs_closed_form"] for a in axes.values()),
            1e-6,
        ),
        Check(
            "Closed-form $K$ in double precision",
            "closed form in 50-digit mpmath",
            max(a["accuracy_vs_50_digit_reference"]["closed_form"] for a in axes.values()),
            1e-14,
        ),
        Check(
            "Numerical LQR $K$ (scipy CARE)",
            "closed form in 50-digit mpmath",
            max(a["accuracy_vs_50_digit_reference"]["numerical"] for a in axes.values()),
            1e-6,
        ),
        Check(
            "Stable closed form in single precision",
            "closed form in 50-digit mpmath",
            max(a["stable32"] for a in paper["axes"]),
            1e-5,
        ),
        Check("Closed-form $P$ in eq 28 (relative residual)", "zero", are, 1e-14),
        Check(
            "Trim: largest acceleration at the equilibrium",
            "zero [m/s$^2$, rad/s$^2$]",
            trep["residual"],
            1e-8,
        ),
        Check(
            "Eqs 1--2 at the model's accelerations (exact rationals, 3 bodies)",
            "zero (count of nonzero residuals)",
            float(rigid["exact_residual_nonzero"]),
            0.0,
        ),
        Check("Allocation: $E\\,T - I$", "zero", alloc["E_T_residual"], 1e-12),
        Check(
            "Allocation: $T$ from the Lagrangian vs $E^{+}$",
            "numpy pinv",
            alloc["T_pinv_residual"],
            1e-12,
        ),
    ]
    if c_progress is not None:
        checks += _generated_c_checks(carriage, trim, gains, c_progress)
    return checks


Simulation = Path | Mapping[str, bytes | str] | None


def _simulation(source: Simulation) -> tuple[dict[str, Any], _Deferred]:
    """Figures and metrics of `maglevgen simulate`: its output folder, or its files in memory."""
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
        ctx.update(_metrics(data))
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


# ============================================================================= context

SECTION_TITLES: dict[str, str] = {
    "parameters": "Parameters",
    "conventions": "Coordinate conventions and state order",
    "rigid_body": "Rigid-body equations (eqs 1-2)",
    "force_law": "Halbach field and force law (eqs 3-4)",
    "geometry": "Geometry and force and moment sums (eqs 8-12)",
    "trim": "Trim",
    "stiffness": "Linearisation and stiffness (eqs 5-19)",
    "damping": "Damping control and allocation (eqs 20-23)",
    "riccati": "Riccati equations and LQR gains (eqs 24-33)",
    "paper": "Paper versus derivation",
    "verification": "Verification",
    "envelope": "Operating envelope",
    "simulation": "Simulation",
}


def _quiet(_msg: str) -> None:
    pass


def build_context(
    carriage,
    params_text: str,
    options: ReportOptions = ReportOptions(),
    progress: Callable[[str], None] = _quiet,
    figures: PendingResult | None = None,
) -> tuple[dict[str, Any], dict[str, bytes]]:
    """Everything the templates show, and the binary files (figures) the report includes.

    ``progress`` is called with a short message before each slow step. The force figures are
    drawn in a child process while this one builds the context: ``figures`` when the caller
    has them drawn already (`maglevgen build`: `force_figures` of `force_curves`, by the
    worker that drew the simulation's), else by a child of their own.
    """
    from .summary import gains_report, trim_report

    sim, sim_files = _simulation(options.simulation)  # bad input fails before the slow steps
    progress("report: envelope (stability across speed, in the compiled library)")
    env, env_png = _envelope(carriage, options)
    progress("report: trim and stiffness")
    trim = carriage.trim()
    with (nullcontext() if figures is not None else
          Background("drawing the report figures", force_figures, force_curves(carriage, trim))
          ) as own:
        figures = figures if own is None else own
        trep = trim_report(carriage, None)
        progress("report: LQR gains, coupled comparison and allocation")
        gains = gains_report(carriage, None)
        progress("report: symbolic forms")
        force = _force_law(carriage, trim, trep)
        rigid = _rigid_body()
        alloc = _damping_allocation(gains)
        sections = {
            "conventions": _conventions(carriage.model),
            "rigid_body": rigid,
            "force_law": force,
            "geometry": _geometry(carriage, gains),
            "trim": _trim(trep),
            "stiffness": _stiffness(carriage, trim, trep),
            "damping": alloc,
            "riccati": _riccati(gains),
        }
        progress("report: comparison with the paper")
        paper = _paper_comparison(gains, trep)
        progress("report: verification")
        checks = _verification(
            carriage, trim, gains, trep, rigid, alloc, paper, progress if options.verify_c else None
        ) + _envelope_checks(carriage, env)
        progress("report: figures")
        files = dict(figures.result())
    files.update(sim_files.read())
    files[ENVELOPE_FIGURE] = env_png
    rows, notes = parameter_rows(carriage.loaded, params_text)
    loaded = carriage.loaded
    ctx: dict[str, Any] = {
        "version": __version__,
        "titles": SECTION_TITLES,
        "source": Path(loaded.source).name,
        "sha256": loaded.sha256,
        "overrides": list(loaded.overrides),
        "speed": trep["speed"],
        "parameters": {
            "rows": rows,
            "notes": notes,
            "B0": force["B0_value"],
            "B0_paper": force["B0_paper"],
            "B0_rel": force["B0_rel"],
        },
        **sections,
        "paper": paper,
        "checks": checks,
        "envelope": _envelope_context(carriage, env),
        "simulation": sim,
        "figures": sorted(f for f in files if f.startswith("fig_")),
    }
    return ctx, files


# ============================================================================ envelope

ENVELOPE_FIGURE = "envelope_stability_map.png"


def _envelope(carriage, options: ReportOptions):
    """The envelope (maglevgen.envelope, through the compiled library) and its stability map:
    the caller's when it has them (`maglevgen build`), else computed and drawn here."""
    from .envelope import compute_envelope, stability_map_png
    from .library import simulation_library

    if options.envelope is not None:
        env, png = options.envelope
        return env, png
    env = compute_envelope(carriage, simulation_library(carriage.structure))
    return env, stability_map_png(env)


def _envelope_checks(carriage, env) -> list[Check]:
    """Stability rows: each designed controller at the design speed and across the envelope
    (a row fails when the closed loop has an eigenvalue with real part >= -margin)."""
    from .envelope import STABILITY_MARGIN, closed_loop_stability, envelope_points
    from .library import simulation_library
    from .operating import CONTROLLER_TITLES

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


def _envelope_context(carriage, env) -> dict[str, Any]:
    from .operating import CONTROLLER_TITLES

    embedded = carriage.params.envelope.embedded_controller
    pick = np.unique(np.linspace(0, env.speeds.size - 1, min(9, env.speeds.size)).astype(int))
    names = list(env.controllers)
    return {
        "v_min": env.v_min, "v_max": env.v_max, "n": int(env.speeds.size),
        "figure": ENVELOPE_FIGURE,
        "launch_acceleration": carriage.params.envelope.launch_acceleration,
        "rows": [{"title": CONTROLLER_TITLES[n], "name": n, "verdict": c.verdict,
                  "ok": c.ok, "embedded": n == embedded} for n, c in env.controllers.items()],
        "names": [CONTROLLER_TITLES[n] for n in names],
        "table": [{"speed": float(env.speeds[i]),
                   "cells": [float(env.controllers[n].max_real[i]) for n in names]}
                  for i in pick],
    }


# ============================================================================ LaTeX build


@dataclass(frozen=True)
class LatexBuild:
    """The outcome of running LaTeX on report.tex."""

    tool: str | None  # "latexmk", "pdflatex" or None (no TeX installed)
    ok: bool
    seconds: float
    error: str = ""  # the first LaTeX error line when not ok


_LATEX_FLAGS = ("-interaction=nonstopmode", "-halt-on-error", "-file-line-error")


def first_latex_error(log: str) -> str:
    """The first error line of a LaTeX log (file:line: message, or ! message)."""
    for line in log.splitlines():
        if re.match(r"^(\./)?[^:\s]+\.tex:\d+: ", line) or line.startswith("! "):
            return line.strip()
    return "unknown LaTeX error"


_OVERFULL = re.compile(r"^Overfull \\[hv]box \(([\d.]+)pt too (?:wide|high)\)", re.MULTILINE)


def overfull_boxes(log: str) -> list[float]:
    """The excess, in pt, of every overfull box reported in a LaTeX log."""
    return [float(m.group(1)) for m in _OVERFULL.finditer(log)]


def run_latex(folder: Path, timeout: float = 600.0) -> LatexBuild:
    """Build report.pdf from report.tex in ``folder`` with latexmk (or pdflatex, 3 passes)."""
    import time

    tool = find_tex()
    if tool is None:
        return LatexBuild(None, False, 0.0, "")
    start = time.monotonic()
    if tool == "latexmk":
        cmds = [["latexmk", "-pdf", *_LATEX_FLAGS, "report.tex"]]
    else:
        cmds = [["pdflatex", *_LATEX_FLAGS, "report.tex"]] * 3
    env = dict(os.environ, SOURCE_DATE_EPOCH="0", FORCE_SOURCE_DATE="1")
    for cmd in cmds:
        try:
            proc = subprocess.run(
                cmd,
                cwd=folder,
                capture_output=True,
                text=True,
                errors="replace",
                timeout=timeout,
                env=env,
                stdin=subprocess.DEVNULL,
            )
        except subprocess.TimeoutExpired:
            return LatexBuild(
                tool, False, time.monotonic() - start, f"{tool} did not finish within {timeout:g} s"
            )
        if proc.returncode != 0:
            log = folder / "report.log"
            text = log.read_text(errors="replace") if log.exists() else proc.stdout
            return LatexBuild(tool, False, time.monotonic() - start, first_latex_error(text))
    for ext in (".aux", ".fls", ".fdb_latexmk", ".out", ".toc"):
        (folder / f"report{ext}").unlink(missing_ok=True)
    return LatexBuild(tool, True, time.monotonic() - start)


@dataclass(frozen=True)
class ReportResult:
    """What `write_report` wrote."""

    out_dir: Path
    paths: list[Path]
    latex: LatexBuild
    failed_checks: list[str]  # verification rows whose error exceeds their bound


@dataclass(frozen=True)
class ReportFiles:
    """The report's files in memory, how LaTeX went and which checks failed."""

    files: dict[str, bytes]
    latex: LatexBuild
    failed_checks: list[str]


_KEEP = (".tex", ".pdf", ".log", ".png")


def render_report(
    carriage,
    params_text: str,
    options: ReportOptions = ReportOptions(),
    progress: Callable[[str], None] = _quiet,
    failed_dir: Path | None = None,
    figures: PendingResult | None = None,
) -> ReportFiles:
    """report.tex, its figures and, when ``options.build_pdf`` and TeX is installed,
    report.pdf and report.log: every file in memory.

    A LaTeX failure raises MaglevError naming the first error line and the log, kept with the
    failed build in ``failed_dir`` (default: a new temporary folder). ``figures``: see
    `build_context`.
    """
    ctx, files = build_context(carriage, params_text, options, progress, figures)
    progress("report: rendering report.tex")
    files["report.tex"] = render_tex(ctx).encode("utf-8")
    failed = [
        re.sub(r"\\texttt\{([^}]*)\}|\\", r"\1", c.what).replace("\\_", "_")
        for c in ctx["checks"]
        if c.status == "FAIL"
    ]
    latex = LatexBuild(None, False, 0.0)
    if not (options.build_pdf and find_tex() is not None):
        return ReportFiles(files, latex, failed)
    with tempfile.TemporaryDirectory(prefix="maglevgen-report.") as scratch:
        build = Path(scratch)
        for name, data in sorted(files.items()):
            (build / name).write_bytes(data)
        progress("report: LaTeX, building report.pdf")
        latex = run_latex(build)
        if not latex.ok:
            where = _keep_failed(build, failed_dir)
            raise MaglevError(f"LaTeX failed: {latex.error} (log: {where})")
        files = {
            p.name: p.read_bytes()
            for p in sorted(build.iterdir())
            if p.is_file() and p.suffix in _KEEP
        }
    return ReportFiles(files, latex, failed)


def _keep_failed(build: Path, failed_dir: Path | None) -> Path | str:
    """Copy a failed LaTeX build where the user can read its log; the log's path."""
    try:
        if failed_dir is None:
            failed_dir = Path(tempfile.mkdtemp(prefix="maglevgen-report-failed."))
        shutil.rmtree(failed_dir, ignore_errors=True)
        shutil.copytree(build, failed_dir)
        return failed_dir / "report.log"
    except OSError:
        return "not kept: the failed build could not be copied"


def report_files(
    carriage,
    simulation: Mapping[str, bytes | str] | None = None,
    pdf: bool = True,
    progress: Callable[[str], None] = _quiet,
    figures: PendingResult | None = None,
    envelope: tuple[Any, bytes] | None = None,
) -> dict[str, bytes]:
    """The report's files in memory, for a caller that writes them itself (`maglevgen build`).

    ``simulation``: the files of a `maglevgen simulate` run (name -> content), or None;
    ``figures``: the report's figures being drawn already (see `build_context`).
    """
    options = ReportOptions(simulation=simulation, build_pdf=pdf, envelope=envelope)
    return render_report(carriage, params_text_of(carriage.loaded), options, progress,
                         figures=figures).files


def write_report(
    carriage,
    params_text: str,
    out_dir: Path,
    options: ReportOptions = ReportOptions(),
    progress: Callable[[str], None] = _quiet,
) -> ReportResult:
    """Render the report (`render_report`) and write it to ``out_dir`` at once
    (codegen.generate.write_output swaps the folder in).

    On a LaTeX failure ``out_dir`` is left as it was and the failed build is kept in
    ``.<name>.failed`` beside it.
    """
    from .codegen.generate import write_output

    out_dir = Path(out_dir).resolve()
    res = render_report(
        carriage,
        params_text,
        options,
        progress,
        failed_dir=out_dir.parent / f".{out_dir.name}.failed",
    )
    paths = write_output(res.files, out_dir)
    return ReportResult(out_dir, paths, res.latex, res.failed_checks)
