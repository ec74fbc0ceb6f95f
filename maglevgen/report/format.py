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


#: the Greek letters LaTeX has a command for (the capitals not drawn as Latin letters)
_TEX_GREEK = frozenset(("alpha", "beta", "gamma", "delta", "epsilon", "zeta", "eta", "theta",
                        "iota", "kappa", "lamda", "mu", "nu", "xi", "pi", "rho", "sigma", "tau",
                        "upsilon", "phi", "chi", "psi", "omega", "final sigma", "Gamma", "Delta",
                        "Theta", "Lamda", "Xi", "Pi", "Sigma", "Upsilon", "Phi", "Psi",
                        "Omega"))
_GREEK_COMMAND = {"lamda": "lambda", "Lamda": "Lambda", "final sigma": "varsigma"}
#: Greek capitals drawn as Latin ones (LaTeX has no command for them), and omicron
_GREEK_AS_LATIN = {"Alpha": "A", "Beta": "B", "Epsilon": "E", "Zeta": "Z", "Eta": "H",
                   "Iota": "I", "Kappa": "K", "Mu": "M", "Nu": "N", "Omicron": "O", "Rho": "P",
                   "Tau": "T", "Chi": "X", "omicron": "o"}
#: letters of Latin alphabets with a LaTeX command (OT1, the report's font encoding)
_TEX_LETTERS = {"ß": r"\ss{}", "æ": r"\ae{}", "Æ": r"\AE{}", "œ": r"\oe{}", "Œ": r"\OE{}",
                "ø": r"\o{}", "Ø": r"\O{}", "ł": r"\l{}", "Ł": r"\L{}", "ı": r"\i{}",
                "ȷ": r"\j{}", "¿": "?`", "¡": "!`", "§": r"\S{}", "¶": r"\P{}",
                "©": r"\copyright{}", "£": r"\pounds{}", "‘": "`", "\u00a0": "~",
                "≤": r"$\le$", "≥": r"$\ge$", "≈": r"$\approx$", "≠": r"$\neq$",
                "→": r"$\to$", "∞": r"$\infty$", "²": r"$^2$", "³": r"$^3$", "¹": r"$^1$",
                "√": r"$\surd$", "∂": r"$\partial$", "−": "$-$", "′": r"$'$"}
#: combining marks that are LaTeX text accents in OT1 (an ogonek, say, is not: escaped)
_TEX_ACCENTS = {"\u0300": "`", "\u0301": "'", "\u0302": "^", "\u0303": "~", "\u0304": "=",
                "\u0306": "u", "\u0307": ".", "\u0308": '"', "\u030a": "r", "\u030b": "H",
                "\u030c": "v", "\u0323": "d", "\u0327": "c", "\u0331": "b"}
_UNSAFE = ("Cc", "Cf", "Cs", "Co", "Cn", "Zl", "Zp")


def _tex_char(ch: str) -> str | None:
    """One character without combining marks as LaTeX, or None where LaTeX has none."""
    if ch in _TEX_ESCAPES:
        return _TEX_ESCAPES[ch]
    if ch in "\n\t\r":
        return " " if ch != "\n" else ch  # white space: LaTeX's meaning unchanged
    if unicodedata.category(ch) in _UNSAFE:
        return "?"
    if ord(ch) < 128:
        return ch
    if ch in _TEX_LETTERS:
        return _TEX_LETTERS[ch]
    name = unicodedata.name(ch, "")
    if name.startswith(("GREEK SMALL LETTER ", "GREEK CAPITAL LETTER ")):
        letter = name.split(" LETTER ", 1)[1].lower()
        if name.startswith("GREEK CAPITAL"):
            letter = letter.capitalize()
        if letter in _GREEK_AS_LATIN:
            return _GREEK_AS_LATIN[letter]
        if letter in _TEX_GREEK:
            return f"$\\{_GREEK_COMMAND.get(letter, letter)}$"
    compat = unicodedata.normalize("NFKD", ch)  # a ligature, a full-width letter: its letters
    if compat != ch and all(32 <= ord(c) < 127 for c in compat):
        return "".join(_TEX_ESCAPES.get(c, c) for c in compat)
    return None


def _escaped_code_points(text: str) -> str:
    """What LaTeX cannot typeset, shown as its code points: [U+4E2D] (a break point after)."""
    return "".join(f"[U+{ord(c):04X}]\\allowbreak{{}}" for c in text)


def tex_escape(text: object) -> str:
    """Text made safe for LaTeX, in ASCII: special characters escaped; accented Latin letters
    as LaTeX accents on their letter (e acute as \\'{e}), Greek letters as math symbols, other
    letters and signs with a LaTeX command as that command (all in the report's OT1 fonts,
    which pdftotext reads back as the characters); anything else (CJK, emoji, Cyrillic...)
    shown as its code points, [U+4E2D]; control characters (which the parameter file's
    validation refuses) as ``?``."""
    out = []
    # a base character and the combining marks on it, from the decomposed text
    for group in re.findall(r".[\u0300-\u036f]*|[\u0300-\u036f]+", unicodedata.normalize(
            "NFD", str(text)), flags=re.DOTALL):
        base, marks = group[0], group[1:]
        if unicodedata.combining(base):
            out.append(_escaped_code_points(group))
            continue
        if not marks:
            tex = _tex_char(base)
            out.append(tex if tex is not None else _escaped_code_points(base))
            continue
        if base.isascii() and base.isalpha() and all(m in _TEX_ACCENTS for m in marks):
            tex = {"i": r"\i{}", "j": r"\j{}"}.get(base, base)  # dotless under an accent
            for m in marks:
                tex = f"\\{_TEX_ACCENTS[m]}{{{tex}}}"
            out.append(tex)
        elif base.isalpha():  # a mark OT1 has no accent for, or a letter it cannot accent
            out.append(_escaped_code_points(unicodedata.normalize("NFC", group)))
        else:  # marks on a space or a sign: the sign, and the marks shown
            tex = _tex_char(base)
            out.append((tex if tex is not None else _escaped_code_points(base))
                       + _escaped_code_points(marks))
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
