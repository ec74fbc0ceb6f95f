"""derive.differentiate against SymPy's own differentiation and xreplace: the same expressions,
node for node (srepr), since the generated C is printed from them."""

from __future__ import annotations

import sympy as sp

from maglevgen.carriage import structure_of
from maglevgen.derive.differentiate import Differentiator, jacobian, xreplace
from maglevgen.derive.distributed import langevin, sinhc
from maglevgen.derive.model import build_model
from maglevgen.params import load_params


def _same(a: sp.Matrix, b: sp.Matrix) -> bool:
    return a.shape == b.shape and all(sp.srepr(x) == sp.srepr(y)
                                      for x, y in zip(a, b, strict=True))


def test_every_rule_gives_sympys_expression() -> None:
    x, y, z = sp.symbols("x y z", real=True)
    exprs = sp.Matrix([
        x**y + sp.sqrt(x**2 + z) / (1 + y),  # Pow: symbolic and rational exponents
        sp.exp(-2 * x * (y - z)) * sp.sin(x * y) * sp.tanh(z),  # Function's chain rule
        sinhc(x * y) ** 2 * langevin(z * x),  # the model's opaque functions (their fdiff)
        sp.Abs(x - y) + sp.Piecewise((x**2, sp.Abs(y) < 1), (y * x, True)),  # SymPy's own
        sp.sign(z) * x + 3,
        sp.Integer(7),
    ])
    assert _same(jacobian(exprs, [x, y, z]), exprs.jacobian([x, y, z]))


def test_the_models_jacobians_are_sympys() -> None:
    m = build_model(structure_of(load_params().params))  # distributed, first-order lag
    d = Differentiator()  # shared, as model_functions shares it
    for exprs, variables in ((m.lift_at_speed, list(m.x)), (m.wrench, list(m.arm_sym)),
                             (m.lift_at_speed, list(m.speed_sym))):
        assert _same(jacobian(exprs, variables, d), exprs.jacobian(variables))


def test_xreplace_is_sympys() -> None:
    x, y, g, G, f = sp.symbols("x y g G f", real=True)
    shared = sp.exp(-2 * x * (g - G)) * sinhc(x * y) / f
    exprs = sp.Matrix([shared * (1 + shared), sp.Abs(G - y) + f, sp.Integer(2), x])
    rule = {G: g, f: sinhc(x * y)}  # cancels: exp(0) = 1, sinhc / sinhc = 1
    assert _same(xreplace(exprs, rule), exprs.xreplace(rule))
    assert xreplace(exprs, rule)[0] == 2
