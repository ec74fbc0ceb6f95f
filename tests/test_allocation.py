"""Minimum-norm allocation (derive/allocation.py, eqs 22-23) against pseudoinverses."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import sympy as sp

from maglevgen.derive import allocation


@pytest.fixture(scope="module")
def paper_E() -> sp.Matrix:
    return allocation.paper_effectiveness()


@pytest.fixture(scope="module")
def paper_T(paper_E) -> sp.Matrix:
    return allocation.minimum_norm_allocation(paper_E)


def test_layout_columns_and_rank(paper_E):
    _, components = allocation.paper_array_layout()
    assert allocation.column_names(components) == [
        "F_y1", "F_z1", "F_y2", "F_z2", "F_z3", "F_y4", "F_z4", "F_y5", "F_z5", "F_z6"]
    assert paper_E.shape == (5, 10)
    report = allocation.allocation_rank_report(paper_E)
    assert report.full_row_rank
    assert np.linalg.matrix_rank(np.array(paper_E, dtype=float)) == 5
    # A unit z force on array 1 at (0.26, 0.09, -0.119): moment r x e_z = (0.09, -0.26, 0).
    assert list(paper_E[:, 1]) == [0, 1, sp.Rational("0.09"), sp.Rational("-0.26"), 0]


def test_paper_effectiveness_equals_cross_products(paper_E):
    """Every column of E against (e_y, e_z, r x e) with r the paper's array positions, typed
    here (m): arrays 1, 2 front lower at x = +0.26, y = +/-0.09, z = -0.119; 3 front upper on
    the centre line at z = -0.03; 4, 5 and 6 the same at the rear, x = -0.26 (eqs 8-12)."""
    positions = {1: (0.26, 0.09, -0.119), 2: (0.26, -0.09, -0.119), 3: (0.26, 0.0, -0.03),
                 4: (-0.26, 0.09, -0.119), 5: (-0.26, -0.09, -0.119), 6: (-0.26, 0.0, -0.03)}
    unit = {"y": np.array([0.0, 1.0, 0.0]), "z": np.array([0.0, 0.0, 1.0])}
    columns = []
    for name in ("F_y1", "F_z1", "F_y2", "F_z2", "F_z3", "F_y4", "F_z4", "F_y5", "F_z5", "F_z6"):
        e = unit[name[2]]
        columns.append([e[1], e[2], *np.cross(positions[int(name[3])], e)])
    np.testing.assert_allclose(np.array(paper_E, dtype=float), np.array(columns).T,
                               rtol=0, atol=1e-15)


def test_equals_numpy_pinv(paper_E, paper_T):
    T_np = np.linalg.pinv(np.array(paper_E, dtype=float))
    np.testing.assert_allclose(np.array(paper_T, dtype=float), T_np, rtol=1e-12, atol=1e-12)


def test_equals_exact_pseudoinverse(paper_E, paper_T):
    assert paper_T == paper_E.pinv()
    assert paper_E * paper_T == sp.eye(5)


def test_symbolic_geometry():
    Lx, Ly, zu, zl = sp.symbols("L_x L_y z_u z_l", positive=True)
    E = allocation.paper_effectiveness(x_arm=Lx, y_arm=Ly, z_upper=-zu, z_lower=-zl)
    T = allocation.minimum_norm_allocation(E)
    assert (E * T).applyfunc(sp.simplify) == sp.eye(5)
    # Spot-check the symbolic T against numpy's pinv at a numeric geometry.
    values = {Lx: 0.3, Ly: 0.11, zu: 0.05, zl: 0.2}
    T_num = np.array(T.subs(values), dtype=float)
    E_num = np.array(E.subs(values), dtype=float)
    np.testing.assert_allclose(T_num, np.linalg.pinv(E_num), rtol=1e-10, atol=1e-12)


def test_minimum_norm_property(paper_E, paper_T):
    rng = np.random.default_rng(7)
    E = np.array(paper_E, dtype=float)
    T = np.array(paper_T, dtype=float)
    null = scipy.linalg.null_space(E)
    assert null.shape == (10, 5)
    for _ in range(20):
        u = rng.normal(size=5)
        F = T @ u
        np.testing.assert_allclose(E @ F, u, atol=1e-12)
        other = F + null @ rng.normal(size=5)
        np.testing.assert_allclose(E @ other, u, atol=1e-12)  # also a solution ...
        assert np.linalg.norm(other) > np.linalg.norm(F)  # ... but a longer one


def test_rank_deficient_gives_the_least_squares_minimum_norm_forces():
    """Where E F = u cannot be met for every u, T is still Moore-Penrose's: numpy's pinv, and
    F = T u is the least-norm minimizer of |E F - u| (checked against scipy's lstsq)."""
    E = sp.Matrix([[1, 1, 0], [2, 2, 0]])
    report = allocation.allocation_rank_report(E)
    assert not report.full_row_rank and report.rank == 1
    T = np.array(allocation.minimum_norm_allocation(E), dtype=float)
    E_num = np.array(E, dtype=float)
    np.testing.assert_allclose(T, np.linalg.pinv(E_num), atol=1e-15)
    u = np.array([0.3, -1.7])
    np.testing.assert_allclose(T @ u, scipy.linalg.lstsq(E_num, u)[0], atol=1e-14)
