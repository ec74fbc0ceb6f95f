"""Convert SymPy expressions to CasADi SX, node by node (no re-derivation, no string eval).

Shared subexpressions are converted once (memo on the SymPy node), so CasADi sees the same
DAG that SymPy built; CasADi's own CSE then works on it during code generation.

derive/distributed.py's functions with a removable singularity (sinhc, L, L', L'') become their
two branches, the Horner series below SERIES_BELOW and above it the closed form in
m = exp(-|u|) (``closed_exp``): one exponential per argument, which CasADi's CSE shares
among the functions of that argument and their derivatives.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from typing import Any

import casadi as ca
import sympy as sp

from maglevgen.derive.distributed import SERIES_BELOW

__all__ = ["SympyToCasadi", "casadi_rewriting_off", "to_casadi"]

_UNARY = {
    sp.sin: ca.sin, sp.cos: ca.cos, sp.tan: ca.tan, sp.exp: ca.exp, sp.log: ca.log,
    sp.sqrt: ca.sqrt, sp.Abs: ca.fabs, sp.tanh: ca.tanh, sp.asin: ca.asin, sp.acos: ca.acos,
    sp.atan: ca.atan, sp.sinh: ca.sinh, sp.cosh: ca.cosh, sp.sign: ca.sign,
}


@contextmanager
def casadi_rewriting_off() -> Iterator[None]:
    """CasADi's on-the-fly rewriting off for the block.

    CasADi rewrites x * (1/d) as x / d when it builds a node, which turns each reciprocal that
    SymPy shares (d**-1) back into one division per use. SymPy has already simplified the
    expressions, so the rewriting is off while converting them, and while calling the
    resulting SX functions on new symbols (which rebuilds their nodes).
    """
    previous = ca.GlobalOptions.getSimplificationOnTheFly()
    ca.GlobalOptions.setSimplificationOnTheFly(False)
    try:
        yield
    finally:
        ca.GlobalOptions.setSimplificationOnTheFly(previous)


class SympyToCasadi:
    """A converter bound to a mapping from SymPy symbols to CasADi expressions."""

    def __init__(self, mapping: Mapping[sp.Symbol, Any]) -> None:
        self._memo: dict[sp.Basic, Any] = dict(mapping)

    def __call__(self, expr: sp.Basic | sp.MatrixBase) -> Any:
        with casadi_rewriting_off():
            return self._convert(expr)

    def _convert(self, expr: sp.Basic | sp.MatrixBase) -> Any:
        if isinstance(expr, sp.MatrixBase):
            rows, cols = expr.shape
            out = ca.SX(rows, cols)
            for i in range(rows):
                for j in range(cols):
                    out[i, j] = self._conv(expr[i, j])
            return out
        return self._conv(expr)

    def _conv(self, e: sp.Basic) -> Any:
        hit = self._memo.get(e)
        if hit is not None:
            return hit
        out = self._convert_node(e)
        self._memo[e] = out
        return out

    def _sum(self, terms: tuple[sp.Basic, ...]) -> Any:
        """a + b - c: terms with a negative coefficient are subtracted, not multiplied by -1."""
        plus = [t for t in terms if _negated(t) is None]
        minus = [_negated(t) for t in terms if _negated(t) is not None]
        out = self._conv(plus[0]) if plus else -self._conv(minus.pop(0))
        for t in plus[1:]:
            out = out + self._conv(t)
        for t in minus:
            out = out - self._conv(t)
        return out

    def _removable(self, e: sp.Function) -> Any:
        """if_else(|u| < SERIES_BELOW, series(u), closed_exp(s, exp(-|s|))), s = u where the
        closed form is taken and 1 where the series is (CasADi's if_else evaluates both
        branches: nothing may divide by zero)."""
        u = e.args[0]
        cu = self._conv(u)
        small = ca.fabs(cu) < SERIES_BELOW
        safe = ca.if_else(small, 1, cu)
        s, m = sp.Dummy("s", real=True), sp.Dummy("m", positive=True)
        closed = SympyToCasadi({s: safe, m: ca.exp(-ca.fabs(safe))})._convert(e.closed_exp(s, m))
        return ca.if_else(small, self._conv(e.series(u)), closed)

    def _convert_node(self, e: sp.Basic) -> Any:
        if isinstance(e, sp.Symbol):
            raise KeyError(f"symbol {e} has no CasADi counterpart")
        if e.is_Number or e in (sp.pi, sp.E):
            return ca.SX(float(e))
        if getattr(e, "removable_singularity", False):  # derive/distributed.py's functions
            return self._removable(e)
        if isinstance(e, sp.Piecewise):
            *branches, (last, _true) = e.args
            out = self._conv(last)
            for val, cond in reversed(branches):
                out = ca.if_else(self._conv(cond), self._conv(val), out)
            return out
        if isinstance(e, sp.Add):
            return self._sum(e.args)
        if isinstance(e, sp.Mul) and e.args[0] == -1:
            return -self._conv(-e)  # a negation, not a product with -1
        args = [self._conv(a) for a in e.args]
        if isinstance(e, sp.Mul):
            out = args[0]
            for a in args[1:]:
                out = out * a
            return out
        if isinstance(e, sp.Pow):
            return _power(args[0], e.exp)
        fn = _UNARY.get(e.func)
        if fn is not None:
            return fn(args[0])
        if isinstance(e, sp.StrictLessThan | sp.LessThan | sp.StrictGreaterThan
                      | sp.GreaterThan):
            a, b = args
            return {sp.StrictLessThan: a < b, sp.LessThan: a <= b,
                    sp.StrictGreaterThan: a > b, sp.GreaterThan: a >= b}[e.func]
        if isinstance(e, sp.Max):
            return _fold(ca.fmax, args)
        if isinstance(e, sp.Min):
            return _fold(ca.fmin, args)
        raise NotImplementedError(f"no CasADi conversion for {e.func.__name__}")


def _negated(term: sp.Basic) -> sp.Basic | None:
    """-term when ``term`` carries a negative numeric coefficient (so a sum can subtract it)."""
    if term.is_Number and term < 0:
        return -term
    if isinstance(term, sp.Mul) and term.args[0].is_Number and term.args[0] < 0:
        return -term
    return None


def _fold(fn: Any, args: list[Any]) -> Any:
    out = args[0]
    for a in args[1:]:
        out = fn(out, a)
    return out


def _power(base: Any, exponent: sp.Expr) -> Any:
    """Integer powers as products (exact, and what C compilers like); x^(1/2) as sqrt."""
    if exponent.is_Integer:
        n = int(exponent)
        if n == 0:
            return ca.SX(1.0)
        if 0 < abs(n) <= 4:
            out = base
            for _ in range(abs(n) - 1):
                out = out * base
            return out if n > 0 else 1 / out
        return ca.constpow(base, float(n))
    if exponent == sp.Rational(1, 2):
        return ca.sqrt(base)
    if exponent == sp.Rational(-1, 2):
        return 1 / ca.sqrt(base)
    return ca.power(base, float(exponent))


def to_casadi(expr: sp.Basic | sp.MatrixBase, mapping: Mapping[sp.Symbol, Any]) -> Any:
    """Convert ``expr`` with ``mapping`` giving the CasADi expression of each free symbol."""
    return SympyToCasadi(mapping)(expr)
