"""The lift-off search: the lowest speed with a trim, by bisection on whether one exists.

One definition for both sides of the toolchain: the derivation's Python trim
(`derive.trim.lift_off_speed`) and the compiled C's (`maglevgen.analyses.envelope.lift_off_speed`)
pass their own test of "a trim exists at v". Imports nothing: the simulation path reads it
without SymPy or SciPy.
"""

from __future__ import annotations

from collections.abc import Callable

__all__ = ["lowest_trim_speed"]

#: the bisection stops when the bracket is this fraction of its upper end
LIFT_OFF_RTOL = 1e-6


def lowest_trim_speed(has_trim: Callable[[float], bool], lo: float, hi: float,
                      v_limit: float, grow: float = 2.0) -> float:
    """The lowest speed in (``lo``, ...) where ``has_trim`` holds, to LIFT_OFF_RTOL.

    ``hi`` is multiplied by ``grow`` until it has a trim (inf once it passes ``v_limit``);
    then [lo, hi] is bisected, ``lo`` a speed without a trim (or 0), on the assumption that
    the trims above lift-off form one interval. Returns the bracket's upper end: a speed
    with a trim.
    """
    while not has_trim(hi):
        hi *= grow
        if hi > v_limit:
            return float("inf")
    while hi - lo > LIFT_OFF_RTOL * hi:
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if has_trim(mid) else (mid, hi)
    return hi
