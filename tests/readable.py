"""A scanner for raw Python/SymPy output in text a person reads (the PDF's text through
pdftotext, SUMMARY.md, the CLI's text output).

What it flags, each a form a program prints and a person does not write: ``**`` (a power),
``[[`` (a nested list), ``Eq(`` and ``sqrt(`` (SymPy's repr), `` * `` (a product with spaces),
a list bracket around a single number (``[1]``, ``[1.0]``), a number with more than 7
significant digits (``1.999999e+01`` is 7, ``19.99999943`` is 10), and round-off noise: a
number below 1e-12 in magnitude where the line is not reporting an error, a residual or a
bound, on the line before it or in the few lines above (a table's caption and header):
``y = 1.2e-19 m`` is noise, ``max|ET - I| = 2.2e-16`` a measurement.

The scanner reads text, never LaTeX source: LaTeX writes ``x^{2}`` and ``\\cdot``, and what it
shows is what pdftotext returns.
"""

from __future__ import annotations

import re

RAW_TOKENS = ("**", "[[", "Eq(", "sqrt(", " * ")

# a number as printed: 1, -2.5, 3.1e-07, 4.2 x 10-19 (pdftotext of a x 10^{-19})
_NUMBER = re.compile(
    r"(?<![\w.])(?P<mant>[-+]?(?:\d+\.\d*|\.\d+|\d+))"
    r"(?:(?P<e>[eE][-+]?\d+)|\s*[x×]\s*10(?P<pow>[-−]?\d+))?(?![\w.])")
# a list of one number; not a note marker ("paper [3]", or "[3]" opening a line of notes)
_SINGLE = re.compile(r"\[\s*[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?\s*\]")
_NOTE_BEFORE = re.compile(r"(?:^\s*|\b(?:paper|assumed)\s+)$")
# words that make a tiny number a measurement (an error, a residual, a bound), not noise
_MEASURES = re.compile(r"\b(?:resid\w*|errors?|err|diff\w*|max|bounds?|toleran\w*|accura\w*|"
                       r"round-?off|eps|vs|precision|largest|root|zero)\b", re.IGNORECASE)
CONTEXT_LINES = 12  # at most this many lines above a number are its context


def _context(lines: list[str], i: int, start: int) -> str:
    """What says whether the number at ``lines[i][start:]`` is a measurement: in a Markdown
    table its column's header; elsewhere the line before it, the block of lines it is in
    (back to a blank line: a table's header) and the paragraph above that block (its
    caption, also where a page break falls between them), at most CONTEXT_LINES lines."""
    line = lines[i]
    if line.lstrip().startswith("|"):
        top = i
        while top > 0 and lines[top - 1].lstrip().startswith("|"):
            top -= 1
        column = line[:start].count("|") - 1
        head = lines[top].strip().strip("|").split("|")
        return head[column] if 0 <= column < len(head) else ""
    above, blanks, j = [], 0, i - 1
    while j >= 0 and len(above) < CONTEXT_LINES:
        if lines[j + 1].startswith("\f"):  # a page break (pdftotext's form feed) is layout:
            # the page before ends in its number and the blank lines of its bottom margin
            while j >= 0 and (not lines[j].strip() or lines[j].strip().isdigit()):
                j -= 1
            if j < 0:
                break
        if not lines[j].strip():
            blanks += 1
            if blanks == 2:
                break
        above.append(lines[j])
        j -= 1
    return "\n".join([*reversed(above), line[:start]])


# identifiers and digests are not numbers: hex runs of 12+ characters, and dotted versions
_SKIP = re.compile(r"\b[0-9a-f]{12,}\b|\b\d+\.\d+\.\d+\b")


def significant_digits(mantissa: str) -> int:
    """The significant digits of a printed mantissa (leading zeros not counted; an integer's
    trailing zeros not counted either: 1000 has one)."""
    m = mantissa.lstrip("+-")
    if "." in m:
        return len(m.replace(".", "").lstrip("0")) or 1
    return len(m.lstrip("0").rstrip("0")) or 1


def raw_findings(text: str, where: str = "") -> list[str]:
    """Every raw form in ``text``, each as "where, line N: what: the line"."""
    out = []
    lines = text.replace("\r\n", "\n").split("\n")  # not splitlines(): a form feed (a page
    # break in pdftotext's output) stays at the start of its page's first line
    for n, line in enumerate(lines, 1):
        def hit(what: str, n: int = n, line: str = line) -> None:
            out.append(f"{where} line {n}: {what}: {line.strip()[:160]}")

        for tok in RAW_TOKENS:
            if tok in line:
                hit(repr(tok))
        if any(not _NOTE_BEFORE.search(line[:m.start()]) for m in _SINGLE.finditer(line)):
            hit("a list bracket around one number")
        scan = _SKIP.sub(" ", line)
        for m in _NUMBER.finditer(scan):
            mant = m.group("mant")
            if significant_digits(mant) > 7:
                hit(f"{m.group(0).strip()} has more than 7 significant digits")
            exp = m.group("e") or (("e" + m.group("pow").replace("−", "-")) if m.group("pow")
                                   else "")
            try:
                value = float(mant + exp)
            except ValueError:
                continue
            if 0 < abs(value) < 1e-12 and not _MEASURES.search(_context(lines, n - 1,
                                                                           m.start())):
                hit(f"{m.group(0).strip()} is round-off noise")
    return out
