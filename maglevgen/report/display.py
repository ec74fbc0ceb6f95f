"""SymPy expressions as LaTeX displays: rounding, line breaking, aligned blocks, matrices."""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import sympy as sp

from maglevgen.infrastructure.hashing import sha256_hex

__all__ = ["EULER_PHI", "EULER_PSI", "EULER_THETA", "LINE_WIDTH", "REPORT_SOURCE", "Display",
           "abbreviate_radicals", "break_sum", "decimal_rationals", "display_filter", "eq", "eqs",
           "ltx", "math_prose", "matrix_tex", "round_floats", "trig_abbrev"]

# Width budget of one display line, in the units of `tex_width` (about one math glyph).
LINE_WIDTH = 62
FLOAT_DIGITS = 4  # significant digits of numbers printed inside symbolic expressions

# Report pieces cached across processes (derive.memo's store, whose key covers the derivation's
# source) take the report package's digest as an argument, so an edit here renders them again.
EULER_PHI, EULER_THETA, EULER_PSI = sp.symbols("phi theta psi")  # the Euler angles as displayed

REPORT_SOURCE = sha256_hex(b"".join(
    p.read_bytes() for p in sorted(Path(__file__).parent.rglob("*.py"))))[:16]

def ltx(expr: Any) -> str:
    """sympy.latex with the report's settings; a float's power of ten as the tables write
    it (a x 10^e, `format.fnum`), not SymPy's a . 10^e."""
    return sp.latex(expr, full_prec=False).replace(r" \cdot 10^{", r" \times 10^{")


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
            m = re.match(r"\\[A-Za-z]+|\\.?", s[i:], re.DOTALL)  # matches at any backslash
            assert m is not None
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
            m = re.match(r"\\([A-Za-z]+|.?)", s[i:], re.DOTALL)  # matches at any backslash
            assert m is not None
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


def display_filter(d: Display) -> str:
    return "\\begin{align*}\n" + " \\\\\n".join(d.lines) + "\n\\end{align*}"





def trig_abbrev() -> dict[sp.Expr, sp.Symbol]:
    """cos(phi) -> c_phi, sin(phi) -> s_phi, ... (named subexpressions of the rotations)."""
    rep: dict[sp.Expr, sp.Symbol] = {}
    for a in (EULER_PHI, EULER_THETA, EULER_PSI):
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



_MATH_SPAN = re.compile(
    r"\[(?:[^\[\]]|\[[^\[\]]*\])*\]"  # a list, nested once ([[a, b], [c, d]])
    r"|[\w.()*/^+-]*(?:sqrt\(|Eq\()[^\]]*?\)(?:\s[+-]\s[\w.()*/^]+)*"  # sqrt(...) - k
    r"|[\w.()*/^]+(?:\s[+-]\s[\w.()*/^]+)*"  # a product or sum of tokens
)
_FUNCTIONS = {"sqrt": sp.sqrt, "Eq": sp.Eq}


def _as_math(span: str) -> str | None:
    """LaTeX text of a span of SymPy's string output (rounded), or None when not math."""
    if not re.search(r"[_*/^\[]|sqrt|Eq|\.\d", span):
        return None  # words, and integers such as equation numbers, stay text
    from sympy.parsing.sympy_parser import parse_expr

    names = {n: sp.Symbol(n) for n in re.findall(r"[A-Za-z_]\w*", span) if n not in _FUNCTIONS}
    try:
        value = parse_expr(span.replace("^", "**"), local_dict={**names, **_FUNCTIONS},
                           evaluate=True)
    except Exception:
        return None
    value = decimal_rationals(value)
    if isinstance(value, list | tuple):
        if value and all(isinstance(v, list | tuple) for v in value):
            return "$" + matrix_tex([[round_floats(x, 6) for x in row] for row in value]) + "$"
        if len(value) == 1:  # SymPy's list of one root or residual: the value itself
            return f"${ltx(round_floats(value[0], 6))}$"
        # each element its own formula, so that a long list breaks between them
        return "[" + ", ".join(f"${ltx(round_floats(v, 6))}$" for v in value) + "]"
    if isinstance(value, sp.Basic):
        return f"${ltx(round_floats(value, 6))}$"
    return None


def decimal_rationals(value: Any) -> Any:
    """Rationals with a terminating decimal (13/50, 119/1000: the paper's printed 0.26 and
    0.119 after SymPy's exact arithmetic) as that decimal; 1/3 stays a fraction."""
    if isinstance(value, list | tuple):
        return type(value)(decimal_rationals(v) for v in value)
    if not isinstance(value, sp.Basic):
        return value

    def terminating(q: sp.Rational) -> bool:
        d = int(q.q)
        for p in (2, 5):
            while d % p == 0:
                d //= p
        return d == 1 and q.q != 1

    powers = {p.exp for p in value.atoms(sp.Pow)}  # a square root stays one, not ^0.5
    rep = {q: sp.Float(f"{float(q):.6g}", 6) for q in value.atoms(sp.Rational)
           if terminating(q) and q not in powers}
    return value.xreplace(rep) if rep else value


def math_prose(text: str) -> str:
    """A finding written with SymPy's string output, as LaTeX text: each list, Eq(...),
    sqrt(...) and formula in it typeset (numbers rounded), the words escaped."""
    from maglevgen.report.format import tex_escape

    out, last = [], 0
    text = text.replace(" * ", " \N{MIDDLE DOT} ")  # a product written out: a centred dot
    for m in _MATH_SPAN.finditer(text):
        span, start, end = m.group(0), m.start(), m.end()
        while span.startswith("(") and span.count("(") > span.count(")"):
            span, start = span[1:], start + 1  # "(F_z3, ...": the list's parenthesis is text
        while span.endswith(")") and span.count(")") > span.count("("):
            span, end = span[:-1], end - 1
        tex = _as_math(span) if span else None
        if tex is None:
            continue
        out.append(tex_escape(text[last:start]))
        out.append(tex)
        last = end
    out.append(tex_escape(text[last:]))
    return "".join(out)
