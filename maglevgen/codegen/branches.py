"""No work on the discarded branch: CasADi's if_else as a C ``if`` in the generated code.

CasADi's SX if_else is ``if_else_zero(c, a) + if_else_zero(!c, b)``: its generated C computes
both sides and keeps one, ``X=(N!=0?Y:0);``. For the distributed force law's special functions
(derive/distributed.py: sinhc, L, L', L'' as a Horner series below SERIES_BELOW and a closed
form in one exp(-|u|) above) that is the closed form, its exponential and its divisions, at
every stage of every step, for a result thrown away (and the series where the closed form is
taken). CasADi 3.8's ``if_else(c, a, b, True)`` short-circuits only MX (a Switch of called
functions); SX ignores the flag. :func:`guard_discarded_branches` makes the branch in the C:
a statement whose value is read only where a condition N is nonzero (as the ``Y`` of
``X=(N!=0?Y:0);``, or by statements that are themselves so guarded) runs under
``if (N!=0) { ... }``, where it stands.

Nothing moves and nothing is rewritten: runs of CasADi's own statements, in CasADi's order, are
wrapped, so the taken branch computes the same operations in the same order (the same bits)
and the discarded one computes nothing. The analysis is that of straight-line code, on the
reaching definitions of CasADi's reused work variables: a statement is guarded by the
definition of N that the marker reads (N's variable is not assigned again between that
definition and the statement), every read of its value is a marker's ``Y`` under that same
definition or a statement guarded by it, and a skipped statement's stale variable is therefore
never read. Any other line (an output, a call) reads its variables unguarded. Runs of fewer than
MIN_RUN statements are left as CasADi wrote them (a branch costs more than they do). The
sinhc/L/L'/L'' of one argument share their closed form's exponential: the analysis follows the
value to every marker that reads it, so the shared part is guarded too.
"""

from __future__ import annotations

import re
from bisect import bisect_left
from dataclasses import dataclass

__all__ = ["MIN_RUN", "guard_discarded_branches"]

#: the fewest consecutive statements worth a branch
MIN_RUN = 4

_BODY_START = re.compile(r"^static int casadi_f\d+\(.*\) \{$")
_STATEMENT = re.compile(r"^  (a\d+)=(.*);$")
_LOAD = re.compile(r"^  (a\d+)=arg\[\d+\]\? arg\[\d+\]\[\d+\] : 0;$")
_MARKER = re.compile(r"^  (a\d+)=\((a\d+)!=0\?(a\d+):[^;:?]+\);$")
_DECLARATION = re.compile(r"^  casadi_real a\d+[,;]")
_VAR = re.compile(r"\ba\d+\b")


@dataclass(frozen=True)
class _Line:
    writes: str | None  # the variable a statement assigns; None for any other line
    reads: tuple[str, ...]
    marker: tuple[str, str] | None  # (N, Y) of X=(N!=0?Y:0)


def _parse(text: str) -> _Line:
    m = _LOAD.match(text)
    if m is not None:  # an input's element: a statement that reads no variable
        return _Line(m.group(1), (), None)
    m = _STATEMENT.match(text)
    if m is None or "arg[" in text or "res[" in text:
        return _Line(None, tuple(sorted(set(_VAR.findall(text)))), None)
    k = _MARKER.match(text)
    marker = (k.group(2), k.group(3)) if k is not None and k.group(2) != k.group(3) else None
    return _Line(m.group(1), tuple(sorted(set(_VAR.findall(m.group(2))))), marker)


def _guards(lines: list[_Line]) -> list[int | None]:
    """For each line, the index of the statement defining the condition it runs under, or
    None: it runs always."""
    last: dict[str, int] = {}  # the reaching definition of each variable
    writes: dict[str, list[int]] = {}
    uses: dict[int, list[tuple[int, bool]]] = {}  # definition -> (reader, read as a marker's Y)
    instance: dict[int, int] = {}  # marker -> the definition of N it reads
    for i, line in enumerate(lines):
        for v in line.reads:
            d = last.get(v, -1)
            if d >= 0:
                uses.setdefault(d, []).append(
                    (i, line.marker is not None and v == line.marker[1]))
        if line.marker is not None and last.get(line.marker[0], -1) >= 0:
            instance[i] = last[line.marker[0]]
        if line.writes is not None:
            last[line.writes] = i
            writes.setdefault(line.writes, []).append(i)
    guard: list[int | None] = [None] * len(lines)
    for i in range(len(lines) - 1, -1, -1):
        if lines[i].writes is None or i not in uses:
            continue
        found = {instance.get(r) if as_y else guard[r] for r, as_y in uses[i]}
        if len(found) != 1:
            continue
        g = found.pop()
        if g is None or g >= i:
            continue
        n_var = lines[g].writes
        assert n_var is not None
        later = writes[n_var]
        k = bisect_left(later, g + 1)
        # N assigned again before this statement (implied by the markers reading g after i;
        # checked all the same)
        if k < len(later) and later[k] < i:
            continue
        guard[i] = g
    return guard


def _guard_body(body: list[str]) -> list[str]:
    lines = [_parse(t) for t in body]
    guard = _guards(lines)
    out: list[str] = []
    first_written: dict[str, bool] = {}  # variable -> whether its first assignment is guarded
    i = 0
    while i < len(body):
        g = guard[i]
        j = i + 1
        while j < len(body) and g is not None and guard[j] == g:
            j += 1
        wrapped = g is not None and j - i >= MIN_RUN
        for line in lines[i:j]:
            if line.writes is not None:
                first_written.setdefault(line.writes, wrapped)
        if wrapped and g is not None:
            out.append(f"  if ({lines[g].writes}!=0) {{")
            out.extend("  " + t for t in body[i:j])
            out.append("  }")
        else:
            out.extend(body[i:j])
        i = j
    return _initialised(out, {v for v, guarded in first_written.items() if guarded})


def _initialised(body: list[str], names: set[str]) -> list[str]:
    """The declarations with ``name=0`` for each of ``names``: a variable first assigned
    under a guard is read only under the same guard, which compilers cannot always see
    (gcc's -Wmaybe-uninitialized)."""
    if not names:
        return body

    def init(m: re.Match) -> str:
        return m.group(0) + "=0" if m.group(0) in names else m.group(0)

    return [_VAR.sub(init, t) if _DECLARATION.match(t) else t for t in body]


def guard_discarded_branches(source: str) -> str:
    """``source`` (CasADi's C after the C pass) with each if_else's discarded side computed
    only where it is taken (see the module docstring). Deterministic: the same text in, the
    same text out."""
    lines = source.split("\n")
    out: list[str] = []
    i = 0
    while i < len(lines):
        out.append(lines[i])
        if not _BODY_START.match(lines[i]):
            i += 1
            continue
        end = lines.index("}", i + 1)
        out.extend(_guard_body(lines[i + 1:end]))
        i = end
    return "\n".join(out)
