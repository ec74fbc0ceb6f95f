"""The paper's printed forms (derive/paper.py) and their inconsistencies, shown numerically.

Each constraint set is re-typed here from the paper's text as a numpy matrix (order given in
each test), so the checks do not go through the module's own constraint builder; references
are numpy rank and least squares, python-control's lqr and SymPy derivatives.
"""

from __future__ import annotations

import re

import control
import numpy as np
import pytest
import sympy as sp
from sympy.physics import units
from sympy.physics.units.systems.si import dimsys_SI

from maglevgen.derive import allocation, paper

LX, LY, LXLA = 0.26, 0.09, 0.26
RNG = np.random.default_rng(3)
# Eq 22, forces in the order (F_z3, F_z1, F_z2, F_z6, F_z5, F_z4).
EQ22 = np.array([[1, -1, -1, 1, -1, -1], [1, -1, -1, -1, 1, 1]], dtype=float)
Z_ORDER = ("F_z3", "F_z1", "F_z2", "F_z6", "F_z5", "F_z4")
# Eq 23, forces in the order (F_y1, F_y2, F_y4, F_y5).
EQ23 = np.array([[1, -1, 1, -1]] * 3, dtype=float)
Y_ORDER = ("F_y1", "F_y2", "F_y4", "F_y5")


def _printed(u: np.ndarray) -> dict[str, float]:
    """The printed eqs 22-23 solutions at numeric u and the paper's arms."""
    sym = paper.paper_allocation([sp.Float(x) for x in u], sp.Float(LX), sp.Float(LY),
                                 sp.Float(LXLA))
    return {name: float(v) for name, v in sym.items()}


def _rhs22(u):
    return np.array([u[1], u[3] / LX])


def _rhs23(u):
    return np.array([u[0], u[2] / LY, u[2] / LXLA])  # third entry prints u_phi, not u_psi


def test_eq22_printed_solution_violates_its_constraints():
    for _ in range(5):
        u = RNG.normal(size=5)
        F = np.array([_printed(u)[n] for n in Z_ORDER])
        residual = EQ22 @ F - _rhs22(u)
        assert np.linalg.norm(residual) > 0.1 * np.linalg.norm(_rhs22(u))


def test_eq22_minimum_norm_solution_differs_from_printed():
    u = RNG.normal(size=5)
    F_ls = np.linalg.lstsq(EQ22, _rhs22(u), rcond=None)[0]  # minimum-norm solution
    np.testing.assert_allclose(EQ22 @ F_ls, _rhs22(u), atol=1e-12)
    F_printed = np.array([_printed(u)[n] for n in Z_ORDER])
    assert np.linalg.norm(F_ls - F_printed) > 0.1 * np.linalg.norm(F_ls)
    # The module's Lagrange solution of the same constraints agrees with lstsq.
    T = np.array(allocation.minimum_norm_allocation(sp.Matrix(EQ22.astype(int))), dtype=float)
    np.testing.assert_allclose(T @ _rhs22(u), F_ls, atol=1e-12)


def _coefficient_rows(exprs, names) -> np.ndarray:
    """d expr / d F of paper.py's printed expressions, as floats (the arms set to numbers)."""
    arms = dict(zip(sp.symbols("L_x L_y L_xlat", positive=True), (LX, LY, LXLA), strict=True))
    F = [paper.PAPER_FORCES[n] for n in names]
    return np.array(sp.Matrix(exprs).jacobian(F).xreplace(arms), dtype=float)


def test_printed_constraints_are_the_transcribed_rows():
    """paper.py's constraint builder against the rows typed above from the paper's text."""
    eq22, eq23 = paper.paper_allocation_constraints()
    np.testing.assert_array_equal(_coefficient_rows(eq22, Z_ORDER), EQ22)
    np.testing.assert_array_equal(_coefficient_rows(eq23, Y_ORDER), EQ23)


def test_eq23_constraints_have_rank_one():
    _, eq23 = paper.paper_allocation_constraints()
    assert np.linalg.matrix_rank(_coefficient_rows(eq23, Y_ORDER)) == 1

    def misfit(u):
        F_ls = np.linalg.lstsq(EQ23, _rhs23(u), rcond=None)[0]
        return np.linalg.norm(EQ23 @ F_ls - _rhs23(u))

    # Solvable only if u_y = u_phi/L_y = u_phi/L_xlat; with L_y != L_xlat that is u_y = u_phi = 0.
    assert misfit(RNG.normal(size=5)) > 1e-3
    assert misfit(np.array([1.0, 0.0, LY, 0.0, 0.0])) > 1e-3  # u_y = u_phi/L_y only
    assert misfit(np.array([0.0, 2.0, 0.0, 3.0, 4.0])) < 1e-12


def test_eq23_printed_solution_violates_even_consistent_constraints():
    # Choose u on the consistent set (L_y = L_xlat here): u_phi / L_y = u_y.
    u = np.array([1.5, 0.0, 1.5 * LY, 0.0, 0.0])
    arms = (sp.Float(LX), sp.Float(LY), sp.Float(LY))
    sym = paper.paper_allocation([sp.Float(x) for x in u], *arms)
    F = np.array([float(sym[n]) for n in Y_ORDER])
    rhs = np.array([u[0], u[2] / LY, u[2] / LY])
    assert np.linalg.norm(EQ23 @ F - rhs) > 1.0


def test_printed_allocation_ignores_yaw_command():
    u = RNG.normal(size=5)
    u2 = u.copy()
    u2[4] += 10.0
    assert _printed(u) == _printed(u2)


def test_eq10_eq11_are_multiples_of_eq9_eq8():
    """paper.py's printed sums: eq 11 = 0.26 x eq 8 and eq 10 = 0.119 x eq 9 (transcribed)."""
    sums = paper.paper_force_sums()
    heave = np.array([1, -1, -1, 1, -1, -1])  # eq 8 over Z_ORDER
    lateral = np.array([1, -1, 1, -1])  # eq 9 over Y_ORDER
    np.testing.assert_array_equal(_coefficient_rows([sums["F_z"]], Z_ORDER)[0], heave)
    np.testing.assert_allclose(_coefficient_rows([sums["M_z"]], Z_ORDER)[0], 0.26 * heave)
    np.testing.assert_array_equal(_coefficient_rows([sums["F_y"]], Y_ORDER)[0], lateral)
    np.testing.assert_allclose(_coefficient_rows([sums["M_x"]], Y_ORDER)[0], 0.119 * lateral)
    rows = _coefficient_rows([sums["F_z"], sums["M_z"]], Z_ORDER)
    assert np.linalg.matrix_rank(rows) == 1
    # The geometry's E makes heave and pitch independent (rows u_z, u_theta of E on F_z).
    E = np.array(allocation.paper_effectiveness(), dtype=float)
    z_cols = [1, 3, 4, 6, 8, 9]
    assert np.linalg.matrix_rank(E[[1, 3]][:, z_cols]) == 2


def test_eq22_pitch_and_eq11_pitch_disagree():
    """Eq 22's pitch constraint and eq 11's pitch moment, both from paper.py, are not parallel:
    the finding names the coefficient rows, which must be those rows."""
    eq22, _ = paper.paper_allocation_constraints()
    rows = _coefficient_rows([eq22[1], paper.paper_force_sums()["M_z"]], Z_ORDER)
    assert np.linalg.matrix_rank(rows) == 2
    (found,) = [s for s in paper.paper_discrepancies_allocation() if s.startswith("eq 22's")]
    printed = [[float(sp.Rational(x)) for x in part.split(", ")]
               for part in re.findall(r"\[([^\]]*)\]", found)]
    np.testing.assert_allclose(printed, rows)


# The printed solutions of eqs 22-23, typed from the paper: F = S22 @ (u_z, u_theta/L_x) over
# Z_ORDER, and F_y = (u_y/4 + u_phi/(4 L_y) + u_phi/(4 L_xlat)) (-1, 1, -1, 1) over Y_ORDER.
S22 = np.array([[-1, -1], [1, 1], [1, 1], [-1, 1], [1, -1], [1, -1]]) / 4
S23 = np.array([-1.0, 1.0, -1.0, 1.0])
EQ12 = 0.26 * np.array([1, -1, -1, 1])  # eq 12's yaw moment over Y_ORDER


def _finding(start: str) -> str:
    (found,) = [s for s in paper.paper_discrepancies_allocation() if s.startswith(start)]
    return found


def _at(text: str, u: np.ndarray) -> float:
    """A SymPy expression printed in a finding, evaluated at u and the arms above."""
    names = dict(zip(("u_y", "u_z", "u_phi", "u_theta", "u_psi"), u, strict=True))
    names.update(L_x=LX, L_y=LY, L_xlat=LXLA)
    return float(sp.sympify(text).subs({sp.Symbol(n): v for n, v in names.items()}))


def _row(text: str) -> np.ndarray:
    return np.array([float(sp.Rational(x)) for x in text.split(", ")])


def test_discrepancy_findings_state_the_numbers_computed_here():
    """Every number of the allocation findings, parsed back, against numpy on the rows and the
    printed solutions typed above: residuals, minimum-norm solution, rank, the consistency
    conditions, the eq 10/11 ratios and the coefficient rows."""
    u = RNG.normal(size=5)
    F22 = S22 @ np.array([u[1], u[3] / LX])
    F23 = S23 * (u[0] / 4 + u[2] / (4 * LY) + u[2] / (4 * LXLA))
    for start, residual in (("eq 22: the printed", EQ22 @ F22 - _rhs22(u)),
                            ("eq 23: the printed", EQ23 @ F23 - _rhs23(u))):
        printed = re.search(r"residuals \[(.*)\]$", _finding(start))[1].split(", ")
        np.testing.assert_allclose([_at(e, u) for e in printed], residual, rtol=1e-12)
    mn = re.fullmatch(r"eq 22: the minimum-norm solution of the printed constraints is "
                      r"F_z3 = (.*), F_z6 = (.*); printed F_z3 = (.*), F_z6 = (.*)",
                      _finding("eq 22: the minimum-norm"))
    F_ls = np.linalg.lstsq(EQ22, _rhs22(u), rcond=None)[0]
    np.testing.assert_allclose([_at(mn[1], u), _at(mn[2], u)], F_ls[[0, 3]], rtol=1e-12)
    np.testing.assert_allclose([_at(mn[3], u), _at(mn[4], u)], F22[[0, 3]], rtol=1e-12)
    rank = re.fullmatch(r"eq 23: the (\d+) constraint rows have rank (\d+) .*if \[Eq\((.*), "
                        r"(.*)\), Eq\((.*), (.*)\)\]", _finding("eq 23: the 3"))
    assert (int(rank[1]), int(rank[2])) == (len(EQ23), np.linalg.matrix_rank(EQ23))
    rhs = _rhs23(u)  # the conditions: first right side equals each other one
    np.testing.assert_allclose([_at(rank[3], u) - _at(rank[4], u),
                                _at(rank[5], u) - _at(rank[6], u)],
                               [rhs[0] - rhs[1], rhs[0] - rhs[2]], rtol=1e-12)
    for eq, ratio in (("eq 11", 0.26), ("eq 10", 0.119)):  # eqs 10-11 as printed
        assert float(sp.Rational(re.search(r" is (\S+) times", _finding(eq))[1])) == ratio
    yaw = [_row(x) for x in re.findall(r"\[([^\]]*)\]", _finding("eq 23's yaw"))]
    np.testing.assert_allclose(yaw, [EQ23[0], EQ12])
    assert np.linalg.matrix_rank(np.vstack(yaw)) == 2  # not in proportion, as it says
    # the control the finding names as never allocated is the one eqs 22-23 (paper.py's
    # constraints, checked against the typed rows above) leave out
    missing = re.match(r"eqs 22-23: (\w+) appears in no constraint", _finding("eqs 22-23"))[1]
    eq22, eq23 = paper.paper_allocation_constraints()
    read = set().union(*(e.free_symbols for e in (*eq22, *eq23)))
    assert [n for n in ("u_y", "u_z", "u_phi", "u_theta", "u_psi")
            if sp.Symbol(n) not in read] == [missing]


def test_eq21_units():
    """The module's finding names the unit ratio of eq 21 to eq 20; the dimensional analysis
    here: u_phi = L_y * sum M_x is length * force * length, eq 20's I_xx phi'' is
    mass length^2 / time^2, so the ratio is a length (meter)."""
    eq21 = dimsys_SI.get_dimensional_dependencies(
        units.length * units.force * units.length)
    eq20 = dimsys_SI.get_dimensional_dependencies(
        units.mass * units.length**2 / units.time**2)
    ratio = {d: eq21.get(d, 0) - eq20.get(d, 0) for d in set(eq21) | set(eq20)}
    assert {d: e for d, e in ratio.items() if e} == \
        dimsys_SI.get_dimensional_dependencies(units.length)
    (found,) = [s for s in paper.paper_discrepancies_allocation() if s.startswith("eq 21")]
    assert re.search(r"units of (\S+) times", found)[1] == "meter"


def test_printed_K_follows_from_printed_P_but_is_not_the_lqr_gain():
    k, m = 2000.0, 9.3
    P, K = (np.array(X.evalf(), dtype=float) for X in paper.paper_riccati(sp.Float(k), sp.Float(m)))
    np.testing.assert_allclose(np.array([[0.0, 1.0 / m]]) @ P, K, rtol=1e-12)
    A = np.array([[0.0, 1.0], [-k / m, 0.0]])
    B = np.array([[0.0], [1.0 / m]])
    K_lqr = control.lqr(A, B, np.eye(2), np.eye(1))[0]
    assert abs(K[0, 0] - K_lqr[0, 0]) > 1e3 * abs(K_lqr[0, 0])


@pytest.mark.parametrize("m", [0.5, 9.3])
def test_printed_K_is_the_lqr_gain_only_at_unit_stiffness(m):
    # At k = 1 eq 32's K coincides with control.lqr's; eq 31's P still does not.
    A = np.array([[0.0, 1.0], [-1.0 / m, 0.0]])
    B = np.array([[0.0], [1.0 / m]])
    K_lqr, P_lqr, _ = control.lqr(A, B, np.eye(2), np.eye(1))
    P, K = (np.array(X.evalf(), dtype=float) for X in paper.paper_riccati(sp.Integer(1),
                                                                           sp.Float(m)))
    np.testing.assert_allclose(K, K_lqr, rtol=1e-10)
    assert abs(P[0, 0] - P_lqr[0, 0]) > 1e-3 * abs(P_lqr[0, 0])


def test_printed_lateral_and_vertical_stiffness_follow_from_the_exponential_law():
    F, m, g, k, dy, dz = sp.symbols("F m g k Delta_y Delta_z", positive=True)
    printed = paper.paper_stiffness(F, sp.Symbol("F_u"), m, g, k, *sp.symbols("L_z L_x L_xla"))
    # Eq 13 with F = F(y1) the per-array force: 2 F [e^{2 k dy} - e^{-2 k dy}].
    lateral = 2 * F * (sp.exp(2 * k * dy) - sp.exp(-2 * k * dy))
    assert sp.simplify(sp.diff(lateral, dy).subs(dy, 0) - printed["lateral"]) == 0
    # Eq 6: F_L = m g e^{-2 k dz}; the restoring stiffness is -dF/d(dz).
    lift = m * g * sp.exp(-2 * k * dz)
    assert sp.simplify(-sp.diff(lift, dz).subs(dz, 0) - printed["vertical"]) == 0


def test_riccati_discrepancy_report():
    """The residual the report prints equals eq 30 at eq 31's P, both typed here (numpy)."""
    found = paper.paper_discrepancies_riccati()
    (first,) = [s for s in found if s.startswith("eq 31 does not satisfy eq 30")]
    k, m = 2000.0, 9.3
    s_, w = np.sqrt(k**2 + 1), np.sqrt(1 + 2 * m * (np.sqrt(k**2 + 1) - 1))
    P = np.array([[w * (s_ - 1) + k, m * (s_ - 1)], [m * (s_ - 1), m * w]])  # eq 31 as printed
    A, B = np.array([[0.0, 1.0], [-k / m, 0.0]]), np.array([[0.0], [1.0 / m]])
    res = A.T @ P + P @ A - P @ B @ B.T @ P + np.eye(2)
    printed = np.array([float(x) for x in re.findall(r"-?\d+\.?\d*(?:e-?\d+)?",
                                                     first.split(" is ")[1])]).reshape(2, 2)
    np.testing.assert_allclose(printed, res, rtol=1e-9, atol=1e-6)
    # eq 32's K1 = sqrt(k^2+1) - 1 meets the LQR K1 = sqrt(k^2+1) - k where 1 = k only
    (last,) = [s for s in found if s.startswith("eq 32's K1")]
    assert last.endswith("only at k = [1]")
    assert any("no degenerate case" in s for s in found)
