"""Section: rigid body."""

from __future__ import annotations

import random
from fractions import Fraction
from typing import Any

import sympy as sp

from maglevgen.derive.memo import memoized
from maglevgen.derive.rigid_body import body_accelerations, inertia_about_origin
from maglevgen.report.display import REPORT_SOURCE, eqs, ltx

__all__ = ["rigid_body_section"]


def _vec(names: str) -> sp.Matrix:
    return sp.Matrix(sp.symbols(names))


def _rigid_body_exprs():
    """Eqs 1-2 in components, with I_O's entries named (defined by the parallel-axis theorem)."""

    m = sp.Symbol("m")
    rG = _vec("x_G y_G z_G")
    v, om = _vec("u v w"), _vec("p q r")
    vd = sp.Matrix([sp.Symbol(rf"\dot{{{n}}}") for n in "uvw"])
    omd = sp.Matrix([sp.Symbol(rf"\dot{{{n}}}") for n in "pqr"])
    keys = (("xx", "xy", "xz"), ("xy", "yy", "yz"), ("xz", "yz", "zz"))
    IO = sp.Matrix(3, 3, lambda i, j: sp.Symbol(f"I^O_{keys[i][j]}"))
    IG = sp.Matrix(3, 3, lambda i, j: sp.Symbol(f"I_{keys[i][j]}"))
    f1 = m * (vd + om.cross(v) + omd.cross(rG) + om.cross(om.cross(rG)))
    m2 = IO * omd + om.cross(IO * om) + m * rG.cross(vd + om.cross(v))
    return m, rG, v, om, vd, omd, IO, IG, f1, m2, inertia_about_origin(m, IG, rG)


def _rigid_body_check(samples: int = 3, seed: int = 7) -> int:
    """Eqs 1-2 at the model's solved accelerations, in exact rationals: count of nonzero
    residual components over ``samples`` random bodies and motions (0 when they agree)."""

    m, rG, v, om, vd, omd, IO, IG, f1, m2, IO_expr = _rigid_body_exprs()
    rng = random.Random(seed)

    def q() -> sp.Rational:
        return sp.Rational(Fraction(rng.randint(-99, 99), rng.randint(1, 50)))

    nonzero = 0
    for _ in range(samples):
        off = [q() / 10 for _ in range(3)]
        IGv = sp.Matrix(
            [
                [3 + abs(q()), off[0], off[1]],
                [off[0], 3 + abs(q()), off[2]],
                [off[1], off[2], 3 + abs(q())],
            ]
        )
        vals: dict[sp.Symbol, Any] = {m: 1 + abs(q())}
        vals.update(zip(rG, [q() / 10 for _ in range(3)], strict=True))
        vals.update(zip(v, [q() for _ in range(3)], strict=True))
        vals.update(zip(om, [q() for _ in range(3)], strict=True))
        f = sp.Matrix([q() for _ in range(3)])
        M = sp.Matrix([q() for _ in range(3)])
        vdot, omdot = body_accelerations(
            vals[m], IGv, rG.xreplace(vals), v.xreplace(vals), om.xreplace(vals), f, M
        )
        vals.update(zip(vd, vdot, strict=True))
        vals.update(zip(omd, omdot, strict=True))
        vals.update(zip(IG, IGv, strict=True))
        IOv = IO_expr.xreplace(vals)
        vals.update(zip(IO, IOv, strict=True))
        res = list(f1.xreplace(vals) - f) + list(m2.xreplace(vals) - M)
        nonzero += sum(1 for r in res if sp.simplify(r) != 0)
    return nonzero


def rigid_body_section() -> dict[str, Any]:
    return _rigid_body_section(REPORT_SOURCE)


@memoized
def _rigid_body_section(_source: str) -> dict[str, Any]:
    """Eqs 1-2 and the parallel-axis theorem, and the exact check of the solved equations:
    parameter independent, cached across processes."""
    *_, IO, _IG, f1, m2, IO_expr = _rigid_body_exprs()
    comps = "xyz"
    eq1 = eqs([(f"f_{{O,{c}}}", sp.expand(f1[i])) for i, c in enumerate(comps)], tag="1")
    eq2 = eqs([(f"m_{{O,{c}}}", sp.expand(m2[i])) for i, c in enumerate(comps)], tag="2")
    upper = [(i, j) for i in range(3) for j in range(i, 3)]
    parallel = eqs([(ltx(IO[i, j]), sp.expand(IO_expr[i, j])) for i, j in upper])
    return {
        "eq1": eq1,
        "eq2": eq2,
        "parallel_axis": parallel,
        "exact_residual_nonzero": _rigid_body_check(),
    }
