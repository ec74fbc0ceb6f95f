"""Numbers and text as LaTeX: the one place where the report formats a number or escapes a
string (every user string that reaches LaTeX goes through `tex_escape` or a filter built on it).
"""

from __future__ import annotations

import math
import re
import unicodedata

__all__ = [
    "ROUNDOFF",
    "faxis_unit",
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



# Per-axis units of a stiffness (and position gain), a generalized mass and a damping (and
# rate gain): the translations in N and m, the rotations in N m and rad
_AXIS_UNITS = {"k": (r"N/m", r"N\,m/rad"), "m": (r"kg", r"kg\,m$^2$"),
               "c": (r"N\,s/m", r"N\,m\,s/rad")}
_ROTATIONS = ("roll", "pitch", "yaw")


def faxis_unit(axis: str, quantity: str) -> str:
    """The unit (LaTeX text) of ``quantity`` ("k", "m" or "c") on ``axis``: a table whose
    rows are the five axes gives each row's units in a column of their own."""
    return _AXIS_UNITS[quantity][axis in _ROTATIONS]


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
