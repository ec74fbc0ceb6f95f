"""The tilted-array load in closed form (derive/distributed.py) against a numerical quadrature of
the same circuit model written here: each circuit's current from the flux integrated across its
width at the local gaps (scipy.integrate.quad), its force the current times the local field,
circuits summed one by one along the array. And the zero-tilt limit: eq 3 at the face centre."""

from __future__ import annotations

import math

import numpy as np
import pytest
import sympy as sp
from scipy.integrate import quad
from scipy.spatial.transform import Rotation

from maglevgen.derive.distributed import SERIES_BELOW, distributed_load, langevin, sinhc

K = 2 * math.pi / 0.1  # wavenumber of the default carriage's 10 cm wavelength
W, PITCH = 0.12, 0.01


def _rotation(phi: float, theta: float, psi: float) -> np.ndarray:
    """Body-to-inertial rotation, z-y-x Euler angles (scipy, not the project's)."""
    return Rotation.from_euler("ZYX", [psi, theta, phi]).as_matrix()


def _quadrature_load(normal, R, gap_c, n_circuits):
    """(force / (N * B0^2 w^2 e^{-2k g_c} * const), point of action - face centre, body axes)."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    ex = np.array([1.0, 0.0, 0.0])
    e_t = ex - n[0] * n
    e_t /= np.linalg.norm(e_t)
    e_s = np.cross(n, e_t)

    def gap(s, t):  # the track plane is fixed: the point's displacement along the track normal
        return gap_c + n @ ((R - np.eye(3)) @ (s * e_s + t * e_t))

    total, moment = 0.0, np.zeros(3)
    for j in range(n_circuits):
        t = (j - (n_circuits - 1) / 2) * PITCH
        field_sum = quad(lambda s, t=t: math.exp(-K * gap(s, t)), -W / 2, W / 2,
                         epsabs=0, epsrel=1e-13)[0]
        field_moment = quad(lambda s, t=t: s * math.exp(-K * gap(s, t)), -W / 2, W / 2,
                            epsabs=1e-14 * W * field_sum, epsrel=1e-12)[0]
        f = field_sum * field_sum  # current (~ flux) times the integrated field
        total += f
        moment += field_sum * (field_moment * e_s + t * field_sum * e_t)
    norm = n_circuits * W**2 * math.exp(-2 * K * gap_c)
    return total / norm, moment / total


def _closed_form(normal, R, gap_c, n_circuits):
    n = sp.Matrix(normal) / sp.sqrt(sum(c * c for c in normal))
    load = distributed_load(n, sp.Matrix(R), sp.Float(gap_c, 30), sp.Float(K, 30),
                            sp.Float(W, 30), sp.Float(PITCH, 30), sp.Integer(n_circuits))
    return float(load.factor.evalf(30)), np.array([float(c.evalf(30)) for c in load.offset]), load


POSES = [(0.05, 0.0, 0.0), (0.0, 0.03, 0.0), (0.04, -0.02, 0.01), (-0.12, 0.08, -0.05),
         (1e-4, 2e-4, 0.0), (0.002, -0.001, 0.0)]
NORMALS = [(0.0, 0.0, 1.0), (0.0, 1.0, -1.0), (0.0, -1.0, -1.0), (0.1, 0.3, 1.0)]


@pytest.mark.parametrize("pose", POSES)
@pytest.mark.parametrize("normal", NORMALS)
def test_closed_form_matches_quadrature(pose, normal):
    R = _rotation(*pose)
    factor_q, offset_q = _quadrature_load(normal, R, 0.015, 13)
    factor, offset, _ = _closed_form(normal, R, 0.015, 13)
    assert factor == pytest.approx(factor_q, rel=1e-10)
    assert np.allclose(offset, offset_q, rtol=1e-9, atol=1e-13)


def test_zero_tilt_is_eq3_at_the_face_centre():
    for normal in NORMALS:
        factor, offset, load = _closed_form(normal, np.eye(3), 0.015, 13)
        assert factor == pytest.approx(1.0, rel=1e-15)
        assert np.allclose(offset, 0.0, rtol=0, atol=1e-16)
        assert float(load.closest_gap) == pytest.approx(0.015, rel=1e-15)


@pytest.mark.parametrize("u", [0.0, 1e-9, 1e-4, 0.1, SERIES_BELOW * 0.999, SERIES_BELOW,
                               SERIES_BELOW * 1.001, 0.7, -0.2, -3.0])
def test_special_functions_against_mpmath(u):
    import mpmath

    mpmath.mp.dps = 50
    us = sp.Float(u, 30)
    exact_sinhc = mpmath.mpf(1) if u == 0 else mpmath.sinh(u) / u
    exact_lang = mpmath.mpf(0) if u == 0 else mpmath.coth(u) - 1 / mpmath.mpf(u)
    got_s = float(sinhc(us).evalf(30))
    got_l = float(langevin(us).evalf(30))
    assert got_s == pytest.approx(float(exact_sinhc), rel=1e-15)
    assert got_l == pytest.approx(float(exact_lang), rel=1e-15, abs=1e-300)
    # the double-precision evaluation the C sees (lambdify to numpy) stays accurate too
    x = sp.Symbol("x", real=True)
    f_s, f_l = sp.lambdify(x, sinhc(x)), sp.lambdify(x, langevin(x))
    with np.errstate(all="ignore"):
        assert float(f_s(np.float64(u))) == pytest.approx(float(exact_sinhc), rel=1e-14)
        assert float(f_l(np.float64(u))) == pytest.approx(float(exact_lang), rel=1e-13, abs=1e-300)


def test_closest_corner_gap():
    """The closest corner of the face, from the four corners' exact gaps computed here."""
    for pose in POSES:
        R = _rotation(*pose)
        for normal in NORMALS:
            n = np.asarray(normal, float) / np.linalg.norm(normal)
            e_t = np.array([1.0, 0, 0]) - n[0] * n
            e_t /= np.linalg.norm(e_t)
            e_s = np.cross(n, e_t)
            length = 13 * PITCH
            corners = [0.015 + n @ ((R - np.eye(3)) @ (a * W / 2 * e_s + b * length / 2 * e_t))
                       for a in (-1, 1) for b in (-1, 1)]
            _, _, load = _closed_form(normal, R, 0.015, 13)
            assert float(load.closest_gap) == pytest.approx(min(corners), rel=1e-12)


@pytest.mark.parametrize("u", [0.0, 1e-3, 0.2, SERIES_BELOW * 1.01, 0.9, -2.0])
def test_derivatives_against_mpmath_differentiation(u):
    """The opaque functions' fdiff (sinhc' = sinhc L, L' = langevin_slope, and its own), first
    and second derivatives, against mpmath's numerical differentiation of the closed forms."""
    import mpmath

    from maglevgen.derive.distributed import langevin_slope

    mpmath.mp.dps = 40
    closed = {sinhc: lambda v: mpmath.sinh(v) / v if v != 0 else mpmath.mpf(1),
              langevin: lambda v: mpmath.coth(v) - 1 / v if v != 0 else mpmath.mpf(0),
              langevin_slope: lambda v: 1 / v**2 - 1 / mpmath.sinh(v) ** 2 if v != 0
              else mpmath.mpf(1) / 3}
    x = sp.Symbol("x", real=True)
    at = mpmath.mpf(u) if u != 0 else mpmath.mpf("1e-20")  # the closed forms' limit at 0
    for fn, ref in closed.items():
        for order in (1, 2):
            got = sp.diff(fn(x), x, order).subs(x, sp.Float(u, 40))
            got = float(got.rewrite(sp.Piecewise).evalf(30))
            want = float(mpmath.diff(ref, at, order))
            assert got == pytest.approx(want, rel=1e-12, abs=1e-14), (fn, order)
