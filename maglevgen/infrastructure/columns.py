"""A table column's numbers in one notation: the rule every table of the report, SUMMARY.md and
metrics.md follows (the report's LaTeX form is `maglevgen.report.format.fcolumn`), and its
plain-text form. Imports nothing heavy: `simulate` writes metrics.md without SymPy."""

from __future__ import annotations

import math
from collections.abc import Sequence

__all__ = ["fcolumn_plain", "plain_column"]

#: a column prints plain decimals when every nonzero magnitude lies in [low, high); else every
#: entry carries an exponent, so that 0.000223 never stands above 2.96 x 10^-5
PLAIN_RANGE = (1e-4, 1e5)


def plain_column(values: Sequence[float | None]) -> bool:
    """Whether a column's numbers all read as plain decimals (None, zero and non-finite
    entries do not count)."""
    low, high = PLAIN_RANGE
    finite = [abs(float(v)) for v in values
              if v is not None and math.isfinite(float(v)) and float(v) != 0]
    return all(low <= v < high for v in finite)


def fcolumn_plain(values: Sequence[float], digits: int = 4) -> list[str]:
    """A column as plain text with ``digits`` significant digits: plain decimals for the whole
    column, or an exponent (2.965e-05) for the whole column."""
    plain = plain_column(values)
    out = []
    for v in values:
        x = float(v)
        if not plain and x != 0 and math.isfinite(x):
            out.append(f"{x:.{digits - 1}e}")
        elif math.isfinite(x) and abs(x) >= 10**digits:
            out.append(f"{x:.0f}")  # 16865, not 1.686e+04, in a plain column
        else:
            out.append(f"{x:.{digits}g}")
    return out
