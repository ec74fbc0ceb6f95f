"""Two texts compared as a reader compares them: every character between the numbers exactly,
each number to a relative tolerance. For outputs that hold the last digits of a Riccati or
least-squares solution, which differ between LAPACK builds (NumPy's and SciPy's wheels of
different releases) while the program and its inputs are the same."""

from __future__ import annotations

import re

__all__ = ["NUMBER", "differences"]

#: a number as C, JSON, numpy's repr and f-strings print it
NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")


def differences(text: str, stored: str, rtol: float) -> list[str]:
    """Where ``text`` differs from ``stored``: the text between the numbers exactly, each
    number within ``rtol`` of the stored one's magnitude. An empty list: the same."""
    if NUMBER.split(text) != NUMBER.split(stored):
        return ["the text between the numbers differs"]
    return [f"{a} != {b}" for a, b in zip(NUMBER.findall(text), NUMBER.findall(stored),
                                          strict=True)
            if abs(float(a) - float(b)) > rtol * abs(float(b))]
