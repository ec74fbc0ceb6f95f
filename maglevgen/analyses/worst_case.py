"""The judged runs against the worst disturbance, not one sign of it.

The default disturbance (`derive.conventions.DISTURBANCE`: 1 mm lateral, 1 mm heave, 2 mrad
roll, pitch and yaw) is a size per axis, not a direction: a run judged from the all-positive
start alone can pass where a start with other signs fails (the launch's gap margin: 4.39 mm
all positive, 2.49 mm at the worst signs). `build` therefore runs each judged hold and the
launch from every sign combination of the disturbance's non-zero entries (2^5 = 32 for the
default) and judges the worst: each check's worst value over the combinations, named with the
combination where it occurs (`worst_verdict`). A worst case over the box of the disturbance's
magnitudes would need a search inside it; the vertices are what is checked here, and the
verdict says so.
"""

from __future__ import annotations

import itertools
import math

from maglevgen.analyses.run_spec import RunCheck, RunVerdict

__all__ = ["sign_combinations", "signs_text", "worst_verdict"]

# the checks whose smallest value is the worst; for every other judged check the largest is
_SMALLER_IS_WORSE = ("smallest gap margin",)


def sign_combinations(disturbance: dict[str, float]) -> tuple[dict[str, float], ...]:
    """Every sign combination of ``disturbance``'s non-zero entries (2^n, the given signs
    first), the zero entries kept."""
    keys = [k for k, v in disturbance.items() if v != 0.0]
    out = []
    for signs in itertools.product((1.0, -1.0), repeat=len(keys)):
        d = dict(disturbance)
        for k, s in zip(keys, signs, strict=True):
            d[k] = s * disturbance[k]
        out.append(d)
    return tuple(out)


def signs_text(disturbance: dict[str, float]) -> str:
    """The signs of a combination in one token per state, e.g. "y+ z- phi+ theta- psi+"."""
    return " ".join(f"{k}{'+' if v > 0 else '-'}" for k, v in disturbance.items() if v != 0.0)


def _badness(check: RunCheck) -> float:
    """How bad a check's value is, larger worse (a missing value, e.g. not settled, worst)."""
    if check.value is None:
        return math.inf if check.ok is False else -math.inf
    return -check.value if check.name in _SMALLER_IS_WORSE else check.value


def worst_verdict(runs: list[tuple[dict[str, float], RunVerdict]]) -> RunVerdict:
    """One verdict from the runs of every sign combination (each with its disturbance): per
    judged check the worst value over the runs (the smallest gap margin, the largest of the
    others; a failed check before a passed one), noted with the combination where it occurs;
    the reported-only checks from the first run. Every run has the same checks in the same
    order (one scenario, one loop)."""
    first = runs[0][1]
    checks = []
    for i, c0 in enumerate(first.checks):
        if c0.ok is None:
            checks.append(c0)
            continue
        dist, worst = max(((d, v.checks[i]) for d, v in runs),
                          key=lambda dv: (dv[1].ok is False, _badness(dv[1])))
        at = f"worst at {signs_text(dist)}"
        note = f"{worst.note}, {at}" if worst.note else at
        if worst.value is None:
            note = f"{worst.note} {at}".strip()
        checks.append(RunCheck(worst.name, worst.value, worst.limit, worst.unit, worst.ok, note))
    return RunVerdict(tuple(checks))
