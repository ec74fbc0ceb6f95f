"""Jacobians and substitutions by SymPy's own rules, each shared subexpression done once.

SymPy's ``diff`` recomputes the free symbols of every subexpression it descends into (to skip
the constant ones) and differentiates a subexpression shared by several entries (a gap, a load
factor, the rotation) once per entry: quadratic in the depth of the model's expressions, and
most of the derivation's time. `Differentiator` applies the very rules of SymPy's Add, Mul,
Pow and Function (``_eval_derivative``, Leibniz's rule for Mul) and hands any other node to
SymPy, with the free symbols and the derivatives kept per (subexpression, variable); so its
results are SymPy's expressions, node for node (what the generated C is printed from), only
made once. `xreplace` is SymPy's xreplace likewise: SymPy's walks the expression as a tree,
a shared subexpression again at every use.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import sympy as sp
from sympy.core.basic import Basic
from sympy.core.function import ArgumentIndexError

__all__ = ["Differentiator", "jacobian", "xreplace"]


def _generic_function(cls: Any) -> bool:
    """Whether SymPy differentiates ``cls`` by Function's chain rule (its fdiff per argument)."""
    return (issubclass(cls, sp.Function)
            and cls._eval_derivative is sp.Function._eval_derivative
            and cls._eval_derivative_n_times is Basic._eval_derivative_n_times)


class Differentiator:
    """d(expr)/d(symbol), memoised per subexpression: share one across the Jacobians of
    expressions with common parts."""

    def __init__(self) -> None:
        self._free: dict[Basic, frozenset] = {}
        self._done: dict[tuple[Basic, sp.Symbol], sp.Expr] = {}
        self._generic: dict[type, bool] = {}

    def free_symbols(self, expr: Basic) -> frozenset:
        try:
            return self._free[expr]
        except KeyError:
            pass
        if expr.is_Symbol or not expr.args:
            found = frozenset(expr.free_symbols)
        elif type(expr) in (sp.Add, sp.Mul, sp.Pow) or self._is_generic(type(expr)):
            found = frozenset().union(*(self.free_symbols(a) for a in expr.args))
        else:  # bound variables (Piecewise has none, but Subs, Integral ... would)
            found = frozenset(expr.free_symbols)
        self._free[expr] = found
        return found

    def _is_generic(self, cls: type) -> bool:
        if cls not in self._generic:
            self._generic[cls] = _generic_function(cls)
        return self._generic[cls]

    def __call__(self, expr: sp.Expr, v: sp.Symbol) -> sp.Expr:
        if v not in self.free_symbols(expr):
            return sp.S.Zero
        key = (expr, v)
        done = self._done.get(key)
        if done is None:
            done = self._derivative(expr, v)
            self._done[key] = done
        return done

    def _derivative(self, expr: sp.Expr, v: sp.Symbol) -> sp.Expr:
        # each branch is the named class's SymPy rule, its arguments' derivatives from self
        cls = type(expr)
        if expr == v:
            return sp.S.One
        if cls is sp.Add:  # Add._eval_derivative
            return sp.Add(*[self(a, v) for a in expr.args])
        if cls is sp.Mul:  # Mul._eval_derivative_n_times, n = 1: Leibniz over the factors
            args = expr.args
            terms = [sp.Mul(*[self(a, v) if j == i else a for j, a in enumerate(args)])
                     for i in range(len(args))]
            return sp.Add(*terms)
        if cls is sp.Pow:  # Pow._eval_derivative
            dbase, dexp = self(expr.base, v), self(expr.exp, v)
            return expr * (dexp * sp.log(expr.base) + dbase * expr.exp / expr.base)
        if self._is_generic(cls):  # Function._eval_derivative
            terms = []
            for i, a in enumerate(expr.args, start=1):
                da = self(a, v)
                if da.is_zero:
                    continue
                try:
                    df = expr.fdiff(i)
                except ArgumentIndexError:
                    df = sp.Function.fdiff(expr, i)
                terms.append(df * da)
            return sp.Add(*terms)
        return expr.diff(v)  # Piecewise, Abs, sign, ...: SymPy's own


def jacobian(exprs: sp.Matrix, variables: Sequence[sp.Symbol],
             d: Differentiator | None = None) -> sp.Matrix:
    """``exprs.jacobian(variables)`` (a column of expressions), with `Differentiator` ``d``
    (a new one by default)."""
    d = Differentiator() if d is None else d
    col = list(exprs)
    return sp.Matrix(len(col), len(variables), lambda i, j: d(col[i], variables[j]))


def xreplace(exprs: sp.Matrix, rule: dict) -> sp.Matrix:
    """``exprs.xreplace(rule)``: Basic._xreplace's rule (a node is rebuilt when one of its
    arguments changed), each distinct subexpression replaced once."""
    done: dict[Basic, tuple[Basic, bool]] = {}

    def rep(expr: Basic) -> tuple[Basic, bool]:
        if expr in rule:
            return rule[expr], True
        hit = done.get(expr)
        if hit is None:
            args, changed = [], False
            for a in expr.args:
                if isinstance(a, Basic):
                    a, c = rep(a)
                    changed |= c
                elif hasattr(a, "_xreplace"):
                    a, c = a._xreplace(rule)
                    changed |= c
                args.append(a)
            hit = (expr.func(*args), True) if changed else (expr, False)
            done[expr] = hit
        return hit

    return sp.Matrix(exprs.rows, exprs.cols, [rep(e)[0] for e in exprs])
