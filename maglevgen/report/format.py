"""Numbers and text as LaTeX: the one place where the report formats a number or escapes a
string (every user string that reaches LaTeX goes through `tex_escape` or a filter built on it).
"""

from __future__ import annotations

import math
import re
import unicodedata

from maglevgen.infrastructure.columns import plain_column

__all__ = [
    "ROUNDOFF",
    "axis_unit_row",
    "faxis_unit",
    "fcolumn",
    "fcomplex",
    "ferr",
    "ffixed",
    "fnum",
    "fpct",
    "froundoff",
    "tex_breakable",
    "tex_escape",
    "tex_key",
    "tex_prose",
    "tex_unit",
    "tex_verdict",
]

# A value below this fraction of its table's largest is round-off of a structural zero: printed
# as 0, and the bound stated once where the table is.
ROUNDOFF = 1e-12

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
    """A relative difference as a signed percentage (LaTeX text); from 1000 % on, as the
    ratio it stands for (x = 5.7e8 reads "5.7 x 10^8 times", not a 12-digit percentage)."""
    if abs(x) >= 10:
        return f"${fnum(1 + x, 2)}$ times"
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
    "\N{MIDDLE DOT}": r"$\cdot$",
}


#: the Greek small letters LaTeX has a command for (omicron is an o)
_TEX_GREEK = frozenset(("alpha", "beta", "gamma", "delta", "epsilon", "zeta", "eta", "theta",
                        "iota", "kappa", "lamda", "mu", "nu", "xi", "pi", "rho", "sigma", "tau",
                        "upsilon", "phi", "chi", "psi", "omega"))


def tex_escape(text: object) -> str:
    """Text made safe for LaTeX: special characters escaped, other non-ASCII transliterated,
    control characters (which the parameter file's validation refuses) shown as ``?``."""
    out = []
    for ch in str(text):
        name = unicodedata.name(ch, "")
        greek = name[19:].lower() if name.startswith("GREEK SMALL LETTER ") else ""
        if ch in _TEX_ESCAPES:
            out.append(_TEX_ESCAPES[ch])
        elif ch in "\n\t\r":
            out.append(" " if ch != "\n" else ch)  # white space: LaTeX's meaning unchanged
        elif unicodedata.category(ch) in ("Cc", "Cf", "Cs", "Co", "Cn", "Zl", "Zp"):
            out.append("?")
        elif ord(ch) < 128:
            out.append(ch)
        elif greek in _TEX_GREEK:
            out.append(rf"$\{'lambda' if greek == 'lamda' else greek}$")
        else:
            ascii_ = unicodedata.normalize("NFKD", ch).encode("ascii", "ignore").decode()
            out.append(ascii_ or "?")
    return "".join(out)


def tex_verdict(text: str) -> str:
    """A verdict line (`maglevgen.analyses.verdicts`: Markdown, code in backticks) typeset so
    that the PDF's text reads as SUMMARY.md's line without its backticks: code in typewriter,
    no "--" ligature, a straight quote."""
    parts = str(text).split("`")
    out = []
    for i, part in enumerate(parts):
        esc = (re.sub("-(?=-)", "-{}", tex_escape(part)).replace("'", r"\textquotesingle{}")
               .replace(r"\_", r"{\ttfamily\char95}"))  # OT1's \_ is a rule, not a glyph
        out.append(rf"\texttt{{{esc}}}" if i % 2 else esc)
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



# Per-axis units (translation, rotation) of the quantities a table of the five axes shows:
# a stiffness or position gain, a generalized mass, a damping or rate gain, a deviation, a
# generalized force, and the spec design's weights (Bryson's rule: 1/a^2, 1/F^2, s^2/a^2)
_AXIS_UNITS = {"k": (r"N/m", r"N\,m/rad"), "m": (r"kg", r"kg\,m$^2$"),
               "c": (r"N\,s/m", r"N\,m\,s/rad"), "a": ("m", "rad"), "F": ("N", r"N\,m"),
               "q1": (r"1/m$^2$", r"1/rad$^2$"), "r": (r"1/N$^2$", r"1/(N\,m)$^2$"),
               "q2": (r"s$^2$/m$^2$", r"s$^2$/rad$^2$"),
               # the Riccati solution P of one axis: x^T P x the cost in N^2 s or (N m)^2 s
               "p11": (r"N$^2$\,s/m$^2$", r"N$^2$\,m$^2$\,s/rad$^2$"),
               "p12": (r"N$^2$\,s$^2$/m$^2$", r"N$^2$\,m$^2$\,s$^2$/rad$^2$"),
               "p22": (r"N$^2$\,s$^3$/m$^2$", r"N$^2$\,m$^2$\,s$^3$/rad$^2$")}
_ROTATIONS = ("roll", "pitch", "yaw")
_BLOCK_START = {"lateral": "translations", "roll": "rotations"}


def faxis_unit(axis: str, quantity: str) -> str:
    """The unit (LaTeX text) of ``quantity`` (a key of _AXIS_UNITS) on ``axis``."""
    return _AXIS_UNITS[quantity][axis in _ROTATIONS]


def axis_unit_row(axis: str, *quantities: str, lead: int = 1) -> str:
    """The unit row that opens a block of a table whose rows are the axes (LaTeX), or "" for
    an axis inside a block: every table of the axes gives its quantities in the header and
    their units in a row at the start of each block, translations (lateral, vertical) and
    rotations (roll, pitch, yaw), one unit per column. ``quantities``: a key of _AXIS_UNITS
    per column (the unit follows the block), or the unit itself (LaTeX text; "" for a column
    without one); ``lead``: the columns before them, the first holding the block's name."""
    block = _BLOCK_START.get(axis)
    if block is None:
        return ""
    units = [f"[{faxis_unit(axis, q)}]" if q in _AXIS_UNITS else (f"[{q}]" if q else "")
             for q in quantities]
    cells = [rf"\textit{{{block}}}"] + [""] * (lead - 1) + units
    return (r"\midrule" + "\n" if block == "rotations" else "") + " & ".join(cells) + r" \\" + "\n"


def fcolumn(values, digits: int = 6) -> list[str]:
    """The numbers of one table column (LaTeX math, without $) in one notation: plain
    decimals (`ffixed`) where `maglevgen.infrastructure.columns.plain_column` says so, else
    every entry as a x 10^e (`fnum`'s mantissa and exponent, also for the ones that would read
    plainly), so that a column never mixes 0.000223 with 2.96 x 10^-5. None stays None (the
    template's dash); zeros print as 0."""
    plain = plain_column(values)
    out: list[str] = []
    for v in values:
        if v is None:
            out.append(None)  # type: ignore[arg-type]
        elif plain or not math.isfinite(float(v)) or float(v) == 0:
            out.append(ffixed(v, digits))
        else:
            x = float(v)
            mant, exp = f"{x:.{digits - 1}e}".split("e")
            mant = mant.rstrip("0").rstrip(".") if "." in mant else mant
            out.append(rf"{mant} \times 10^{{{int(exp)}}}")
    return out


def froundoff(x: float, scale: float = 1.0, digits: int = 6) -> str:
    """`ffixed` of ``x``, or 0 when ``|x|`` is below ROUNDOFF x ``scale`` (round-off of a
    structural zero; the template states the bound once)."""
    return "0" if abs(float(x)) < ROUNDOFF * scale else ffixed(x, digits)


_GREEK = ("lambda", "pi", "phi", "theta", "psi", "delta", "zeta", "sigma", "omega", "mu")
_PROSE_MATH = re.compile(
    rf"(?P<greek>\b(?:{'|'.join(_GREEK)})\b)|(?P<sub>\b[A-Za-z]_[A-Za-z0-9]+\b)"
    r"|(?P<mul>(?<=\w)\*(?=\w))|(?P<pow>(?<=\w)\^(?P<exp>-?\d+))"
)
_SYMBOL_PREFIX = re.compile(r"^[A-Za-z_]{1,8}: ")


def tex_prose(text: object) -> str:
    """A schema description as LaTeX text: the leading "symbol: " (the table shows the symbol)
    dropped, the ASCII math in it (lambda, I_xx, 2*pi, m^2) typeset, the rest escaped."""
    s = _SYMBOL_PREFIX.sub("", str(text))
    out, last = [], 0
    for m in _PROSE_MATH.finditer(s):
        out.append(tex_escape(s[last:m.start()]))
        if m.group("greek"):
            out.append(rf"$\{m.group('greek')}$")
        elif m.group("sub"):
            base, sub = m.group("sub").split("_", 1)
            out.append(f"${base}_{{{sub}}}$")
        elif m.group("mul"):
            out.append(r"$\,$")
        else:
            out.append(f"$^{{{m.group('exp')}}}$")
        last = m.end()
    out.append(tex_escape(s[last:]))
    return "".join(out)
