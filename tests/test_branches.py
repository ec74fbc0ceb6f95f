"""The guarded branches of the generated C (maglevgen.codegen.branches): the same numbers as
CasADi's own evaluation of the same SX function (bit for bit where the compiler keeps
CasADi's order) and as mpmath at 150 digits, on both sides of every switch; the discarded
side's statements inside an ``if``; a value shared with an unconditional use not guarded.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import casadi as ca
import mpmath
import numpy as np
import pytest
import sympy as sp

from maglevgen.codegen.cpass import generate_c
from maglevgen.codegen.sympy_casadi import to_casadi
from maglevgen.derive.distributed import (
    SERIES_BELOW,
    langevin,
    langevin_curvature,
    langevin_slope,
    sinhc,
)

pytestmark = pytest.mark.needs_cc

FLAGS = ["-std=c99", "-O2", "-fPIC", "-shared", "-Wall", "-Wextra", "-Wpedantic", "-Werror",
         "-Wconversion", "-Wdouble-promotion"]
#: both sides of the switch at SERIES_BELOW, 0, tiny, large, and -800 (past a sinh's overflow)
ARGUMENTS = (0.0, 1e-9, -1e-4, 0.1, 0.2499, SERIES_BELOW, -0.2501, 0.7, -3.0, 40.0, -800.0)
FAMILY = (sinhc, langevin, langevin_slope, langevin_curvature)


def _mp(fn: type, v: mpmath.mpf) -> mpmath.mpf:
    if v == 0:
        return mpmath.mpf(fn.at_zero)
    return {sinhc: lambda: mpmath.sinh(v) / v,
            langevin: lambda: mpmath.coth(v) - 1 / v,
            langevin_slope: lambda: 1 / v**2 - 1 / mpmath.sinh(v) ** 2,
            langevin_curvature: lambda: -2 / v**3 + 2 * mpmath.cosh(v) / mpmath.sinh(v) ** 3}[fn]()


@pytest.fixture(scope="module")
def family(tmp_path_factory) -> tuple[ca.Function, Path, str]:
    """f(u, w): the four special functions of u and of w (each argument's closed forms share
    one exp), sinhc(u) L(w), t = sin(u) w, which the closed form of sinhc(t) also reads, and
    a Piecewise whose second side g is an output too (values used outside the branch: they
    must not be guarded); compiled through generate_c."""
    x, y = sp.symbols("x y", real=True)
    u, w = ca.SX.sym("u"), ca.SX.sym("w")
    t = sp.sin(x) * y
    g = sp.cos(x) * y + sp.sin(x * y) * x - y**3 / 3
    exprs = [f(a) for a in (x, y) for f in FAMILY] + [
        sinhc(x) * langevin(y), sinhc(t), t, sp.Piecewise((x**2, x < 0.5), (g, True)), g]
    outs = [to_casadi(e, {x: u, y: w}) for e in exprs]
    fn = ca.Function("br_family", [u, w], [ca.vertcat(*outs)], ["u", "w"], ["out"],
                     {"cse": True})
    folder = tmp_path_factory.mktemp("branches")
    sources = generate_c([fn], "br_family", "double")
    for name, text in sources.items():
        (folder / name).write_text(text)
    lib = folder / "br_family.so"
    subprocess.run(["cc", *FLAGS, "-o", str(lib), str(folder / "br_family.c"), "-lm"],
                   check=True, capture_output=True)
    return fn, lib, sources["br_family.c"]


def test_the_discarded_sides_are_guarded(family) -> None:
    """Each argument's series and closed form sit in an ``if`` on their own condition."""
    _fn, _lib, text = family
    blocks = re.findall(r"\n  if \((a\d+)!=0\) \{\n(.*?)\n  \}", text, re.S)
    assert len(blocks) >= 4, "fewer guarded blocks than the two sides of two arguments"
    assert sum("exp(" in body for _c, body in blocks) >= 2, "no closed form's exp guarded"


@pytest.mark.parametrize("u", ARGUMENTS)
def test_guarded_c_equals_casadi_and_mpmath(family, u: float) -> None:
    fn, lib, _text = family
    ext = ca.external("br_family", str(lib))
    mpmath.mp.dps = 150
    for w in (u, 0.3 - u, -0.05):
        got = np.array(ext(u, w)).ravel()
        want = np.array(fn(u, w)).ravel()  # CasADi's SX virtual machine
        assert np.array_equal(np.isfinite(got), np.isfinite(want))
        ok = np.isfinite(want)
        np.testing.assert_allclose(got[ok], want[ok], rtol=1e-14, atol=0)
        mu, mw = mpmath.mpf(u), mpmath.mpf(w)
        mt = mpmath.sin(mu) * mw
        mg = mpmath.cos(mu) * mw + mpmath.sin(mu * mw) * mu - mw**3 / 3
        refs = [_mp(f, a) for a in (mu, mw) for f in FAMILY] + [
            _mp(sinhc, mu) * _mp(langevin, mw), _mp(sinhc, mt), mt,
            mu**2 if mu < 0.5 else mg, mg]
        for k, ref in enumerate(refs):
            if not np.isfinite(got[k]):
                assert abs(u) > 700 and FAMILY[k % 4] is sinhc, k  # sinh(800) overflows
                continue
            # L'' = -2/u^3 + 2 cosh/sinh^3 cancels about 4000-fold at the switch; g's terms
            # cancel where it passes zero
            rel = 2e-12 if k in (3, 7) else 1e-13
            scale = 1e-15 if k < 11 else 1e-15 * (1 + abs(u) + abs(w)) ** 3
            assert got[k] == pytest.approx(float(ref), rel=rel, abs=scale), (k, u, w)


def test_the_model_stage_equals_casadi(carriage, sim_lib, op, monkeypatch) -> None:
    """The default carriage's per-stage right-hand side as compiled (guarded;
    maglev_dynamics_prepare then maglev_dynamics_prepared, the firmware loop's stage) against
    CasADi's evaluation of the SX function it was generated from, at the trim and at poses
    about it where the special functions' arguments (recorded here as converted) fall on both
    sides of SERIES_BELOW."""
    from maglevgen.codegen import sympy_casadi
    from maglevgen.codegen.casadi_model import casadi_model

    arguments: list = []
    convert = sympy_casadi.SympyToCasadi._removable

    def recorded(self, e):
        arguments.append(self._conv(e.args[0]))
        return convert(self, e)

    monkeypatch.setattr(sympy_casadi.SympyToCasadi, "_removable", recorded)
    cm = casadi_model(carriage.model)
    f = ca.Function("f", [cm.x, cm.u, cm.p], [cm.xdot, ca.vertcat(*arguments)])
    d = np.array(ca.external("maglev_dynamics_prepare", str(sim_lib.path))(carriage.p))
    stage = ca.external("maglev_dynamics_prepared", str(sim_lib.path))
    rng = np.random.default_rng(53)
    sides = set()
    for scale in (0.0, 1e-3, 0.1, 0.3):
        x = op.x_trim + scale * rng.standard_normal(12)
        u = rng.standard_normal(cm.u.shape[0]) * 100
        want, args = (np.array(v).ravel() for v in f(x, u, carriage.p))
        sides |= set(np.abs(args) < SERIES_BELOW)
        got = np.array(stage(x, u, d)).ravel()
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * np.max(np.abs(want)))
    assert sides == {True, False}, "the poses did not reach both sides of the switch"
