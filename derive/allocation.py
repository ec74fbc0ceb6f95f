"""Minimum-norm control allocation of the paper's eqs 22-23 (Lagrange multipliers, SymPy).

The five generalized control forces u = (u_y, u_z, u_phi, u_theta, u_psi) (eq 21) are made by
the array force components F (F_y, F_z of each array) through the control-effectiveness matrix
E of ``geometry.control_effectiveness``: E F = u. Of all F that do so, the allocation takes the
one minimizing sum F^2 (eqs 22-23), from the stationarity of

    L(F, lambda) = F^T F + lambda^T (E F - u).

The paper writes eqs 22-23 for a subset of the constraints; here all five are used with the
geometry's E. When E has full row rank the answer is T = E^T (E E^T)^-1, the pseudoinverse.

Two actuator models (``control.actuators``) give E its columns. "paper" (eqs 22-23): each
array has a body-z force and, where its normal has a y part (the lower 45-degree arrays), an
independent body-y force: ten forces for the paper's six arrays. "normal": an array pushes
along its normal only, one force F_n per array: six forces for the five generalized forces,
so E is 5 x 6 and its column j is the wrench of the unit normal n_j at the face centre a_j,
(n_y, n_z, a x n). The same Lagrangian gives the minimum-norm forces for either.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import sympy as sp

from maglevgen.derive.geometry import control_effectiveness

__all__ = ["allocation_rank_report", "column_names", "minimum_norm_allocation",
           "paper_array_layout", "paper_effectiveness", "paper_normal_effectiveness"]


@dataclass(frozen=True)
class RankReport:
    """Rank of E against its row count: full row rank means every u is reachable."""

    rows: int
    columns: int
    rank: int

    @property
    def full_row_rank(self) -> bool:
        """Whether rank(E) equals its number of rows."""
        return self.rank == self.rows

    def __str__(self) -> str:
        verdict = "full row rank" if self.full_row_rank else "rank deficient"
        return f"E is {self.rows} x {self.columns} with rank {self.rank}: {verdict}"


def allocation_rank_report(E: sp.Matrix) -> RankReport:
    """Rank of the control-effectiveness matrix E (exact for rational or symbolic entries)."""
    E = sp.Matrix(E)
    return RankReport(E.rows, E.cols, E.rank(simplify=True))


def minimum_norm_allocation(E: sp.Matrix) -> sp.Matrix:
    """T (n x rows) with F = T u minimizing sum F^2 subject to E F = u (eqs 22-23).

    Solves the stationarity equations dL/dF = 0, dL/dlambda = 0 of the Lagrangian in the module
    docstring, a linear system, with ``sympy.linsolve``. When E is rank deficient (the normal
    actuators of the paper's geometry: every line of action meets the x axis at the lower
    normals' crossing, so u_phi and u_y are tied) E F = u has no solution for some u; T then
    gives the forces of least |E F - u| and, among them, least sum F^2, from a rank
    factorization E = C R (C full column rank, R full row rank): E F - u is least where
    R F = C^+ u = (C^T C)^-1 C^T u, a full-row-rank constraint for the same Lagrangian. Either
    way T is the Moore-Penrose pseudoinverse of E.
    """
    E = sp.Matrix(E)
    report = allocation_rank_report(E)
    if not report.full_row_rank:
        C, R = E.rank_decomposition(simplify=True)
        return (_lagrange_allocation(R) * (C.T * C).inv() * C.T).applyfunc(sp.simplify)
    return _lagrange_allocation(E)


def _lagrange_allocation(E: sp.Matrix) -> sp.Matrix:
    """T of least sum F^2 subject to E F = u, E of full row rank (the module's Lagrangian)."""
    F = sp.Matrix(sp.symbols(f"F_1:{E.cols + 1}"))
    lam = sp.Matrix(sp.symbols(f"lambda_1:{E.rows + 1}"))
    u = sp.Matrix(sp.symbols(f"u_1:{E.rows + 1}"))
    L = (F.T * F)[0] + (lam.T * (E * F - u))[0]
    unknowns = [*F, *lam]
    stationarity = [sp.diff(L, v) for v in unknowns]
    (solution,) = sp.linsolve(stationarity, unknowns)
    F_of_u = sp.Matrix(solution[: E.cols])
    return F_of_u.jacobian(u).applyfunc(sp.simplify)


# Paper geometry (m): x arm of every array, y arm of the lower arrays, z of upper and lower.
_X_ARM, _Y_ARM = sp.Rational("0.26"), sp.Rational("0.09")
_Z_UPPER, _Z_LOWER = sp.Rational("-0.03"), sp.Rational("-0.119")


def paper_array_layout(x_arm: sp.Expr = _X_ARM, y_arm: sp.Expr = _Y_ARM,
                       z_upper: sp.Expr = _Z_UPPER, z_lower: sp.Expr = _Z_LOWER,
                       ) -> tuple[list[sp.Matrix], list[tuple[str, ...]]]:
    """Body-frame positions and control components of arrays 1-6 of the paper (eqs 8-12).

    Arrays 3 and 6 (upper, front and rear) push along z; arrays 1, 2 (front lower) and 4, 5
    (rear lower) push along y and z, arrays 1 and 4 on the +y side. Defaults are exact
    rationals, so E and T come out exact.
    """
    yz, z = ("y", "z"), ("z",)
    layout = [
        ((x_arm, y_arm, z_lower), yz),
        ((x_arm, -y_arm, z_lower), yz),
        ((x_arm, 0, z_upper), z),
        ((-x_arm, y_arm, z_lower), yz),
        ((-x_arm, -y_arm, z_lower), yz),
        ((-x_arm, 0, z_upper), z),
    ]
    return [sp.Matrix(p) for p, _ in layout], [c for _, c in layout]


def paper_effectiveness(**layout: sp.Expr) -> sp.Matrix:
    """E (5 x 10) of the paper's geometry, columns F_y1, F_z1, F_y2, F_z2, F_z3, F_y4, ..."""
    return control_effectiveness(*paper_array_layout(**layout))


def paper_normals() -> list[sp.Matrix]:
    """Unit normals of arrays 1-6 of the paper (exact): the lower arrays at 45 degrees pushed
    down and outward, (0, +-1, -1)/sqrt(2); the upper ones up, (0, 0, 1)."""
    s2 = 1 / sp.sqrt(2)
    lower_p, lower_m, up = (sp.Matrix([0, s2, -s2]), sp.Matrix([0, -s2, -s2]),
                            sp.Matrix([0, 0, 1]))
    return [lower_p, lower_m, up, lower_p, lower_m, up]


def paper_normal_effectiveness(**layout: sp.Expr) -> sp.Matrix:
    """E (5 x 6) of the paper's geometry with one force along each array's normal
    (control.actuators = "normal"), columns F_n1..F_n6."""
    positions, _ = paper_array_layout(**layout)
    return control_effectiveness(positions, [("n",)] * 6, paper_normals())


def column_names(components: Sequence[Sequence[str]]) -> list[str]:
    """Names F_<axis><array> of the columns of E, in its order."""
    return [f"F_{ax}{i}" for i, comps in enumerate(components, start=1) for ax in comps]
