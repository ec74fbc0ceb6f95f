"""User strings: the one place that checks them and escapes them for a terminal or Markdown.

Provenance texts, names and ``--set`` values come from the user; `check_text` refuses control
characters and bounds the length before any of them reaches C, LaTeX, XML, TOML or a file
name (the escapes of each language are then `maglevgen.report.format.tex_escape`, the FMU's
XML escape and the C identifiers' pattern of the schema). `shown_name` is how a path or a name
the user chose is shown on the terminal and in SUMMARY.md: control characters (an ANSI escape
would drive the terminal) and Markdown/HTML syntax escaped, so it reads as the text it is.
"""

from __future__ import annotations

import re
import unicodedata

__all__ = ["c_string", "check_text", "markdown_code", "shown_name"]

#: the longest user text kept (a provenance note, a name): longer is a mistake, not a note
MAX_TEXT = 2000

# Markdown/HTML syntax characters in a file name shown in SUMMARY.md
_MARKDOWN = re.compile(r"([\\`*_{}\[\]()<>#+!|~&])")


def control_character(text: str) -> str | None:
    """The first control or format character of ``text`` (C0, DEL, C1, bidirectional
    controls...) as ``U+XXXX``, or None. Tab is a control character too: one line, one value."""
    for ch in text:
        if unicodedata.category(ch) in ("Cc", "Cf", "Cs", "Co", "Cn", "Zl", "Zp"):
            return f"U+{ord(ch):04X}"
    return None


def check_text(text: str, max_len: int = MAX_TEXT) -> str | None:
    """Why ``text`` cannot be a user text (a control character, too long), or None."""
    bad = control_character(text)
    if bad is not None:
        return f"holds the control character {bad}"
    if len(text) > max_len:
        return f"is {len(text)} characters long (at most {max_len})"
    return None


def shown_name(text: object, markdown: bool = False) -> str:
    """``text`` as it is safe to print: control characters as ``\\xNN``/``\\uNNNN`` escapes
    (nothing reaches the terminal as a command), and with ``markdown`` Markdown and HTML
    syntax backslash-escaped."""
    out = []
    for ch in str(text):
        if unicodedata.category(ch) in ("Cc", "Cf", "Cs", "Co", "Cn", "Zl", "Zp"):
            out.append(f"\\x{ord(ch):02x}" if ord(ch) < 256 else f"\\u{ord(ch):04x}")
        else:
            out.append(ch)
    shown = "".join(out)
    return _MARKDOWN.sub(r"\\\1", shown) if markdown else shown


def markdown_code(text: object) -> str:
    """``text`` as a Markdown code span (shown as it is, no markup): control characters
    escaped (`shown_name`), the fence longer than any run of backticks in it."""
    shown = shown_name(text)
    run = max((len(m) for m in re.findall(r"`+", shown)), default=0)
    pad = " " if shown.startswith("`") or shown.endswith("`") else ""
    return f"{'`' * (run + 1)}{pad}{shown}{pad}{'`' * (run + 1)}"


def c_string(text: object, width: int = 80) -> str:
    """``text`` as a C string literal (ASCII; backslash, quote and anything outside the
    printable ASCII escaped as octal), split into adjacent literals of at most ``width``
    characters of text at spaces, one per line, for a generated source's line length."""
    out = []
    for ch in str(text):
        if ch in '\\"':
            out.append("\\" + ch)
        elif " " <= ch <= "~" and ch != "?":  # "?" escaped: no trigraph can form
            out.append(ch)
        else:
            out.extend(f"\\{b:03o}" for b in ch.encode("utf-8"))
    words, lines, line = "".join(out).split(" "), [], ""
    for w in words:
        if line and len(line) + 1 + len(w) > width:
            lines.append(line + " ")
            line = w
        else:
            line = f"{line} {w}" if line else w
    lines.append(line)
    return "\n".join(f'"{ln}"' for ln in lines)
