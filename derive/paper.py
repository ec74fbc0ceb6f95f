"""The paper's PRINTED forms of eqs 8-33, kept only to compare with the derived ones.

Nothing here is used to build a model or a controller. Each function returns what the paper
prints, typos included; the ``paper_discrepancies_*`` functions find, by computation, where the
printed forms contradict themselves or the derivations of ``riccati``, ``damping`` and
``allocation``.

Symbols follow the paper: k is the Halbach wavenumber 2 pi / lambda in the stiffnesses of
eqs 13-19, but the axis stiffness K_st0 in the Riccati forms of eqs 30-33.
"""

from __future__ import annotations

from collections.abc import Sequence

import sympy as sp

from maglevgen.derive.allocation import minimum_norm_allocation
from maglevgen.derive.memo import memoized
from maglevgen.derive.riccati import axis_matrices, riccati_closed_form, riccati_residual

__all__ = ["PAPER_FORCES", "paper_allocation", "paper_allocation_constraints",
           "paper_discrepancies_allocation", "paper_discrepancies_riccati", "paper_force_sums",
           "paper_riccati", "paper_stiffness"]

# The ten array control forces of eqs 22-23, by their printed names.
PAPER_FORCES: dict[str, sp.Symbol] = {
    name: sp.Symbol(name)
    for name in ("F_z1", "F_z2", "F_z3", "F_z4", "F_z5", "F_z6", "F_y1", "F_y2", "F_y4", "F_y5")
}
_Z_FORCES = ("F_z3", "F_z1", "F_z2", "F_z6", "F_z5", "F_z4")  # eq 22's order
_Y_FORCES = ("F_y1", "F_y2", "F_y4", "F_y5")  # eq 23's order
_u = sp.symbols("u_y u_z u_phi u_theta u_psi")
_Lx, _Ly, _Lxla = sp.symbols("L_x L_y L_xlat", positive=True)


def paper_stiffness(F_lat: sp.Expr, F_upper: sp.Expr, m: sp.Expr, g: sp.Expr, k: sp.Expr,
                    Lz: sp.Expr, Lx: sp.Expr, Lxla: sp.Expr) -> dict[str, sp.Expr]:
    """PRINTED axis stiffnesses of eqs 13-19 (not the truth; compare with ``linearize``).

    Lateral 8 F k (eq 13), vertical 2 m g k (eq 7), roll 8 F k Lz^2 (eq 14), pitch
    0.12 F_upper k Lx^2 (eq 15), yaw 8 F k Lxla^2 (eq 16), F = F_bncd_y the equilibrium force of
    one lateral array. Eq 18 and eq 33 write F_bncd_y in the pitch entry instead of eq 15's
    F_bncd_upper, and eq 33 writes L_y^2 in the roll entry instead of eq 14's L_z^2.
    """
    return {
        "lateral": 8 * F_lat * k,
        "vertical": 2 * m * g * k,
        "roll": 8 * F_lat * k * Lz**2,
        "pitch": sp.Rational("0.12") * F_upper * k * Lx**2,
        "yaw": 8 * F_lat * k * Lxla**2,
    }


def paper_riccati(k: sp.Expr, m: sp.Expr) -> tuple[sp.Matrix, sp.Matrix]:
    """PRINTED P (eq 31) and K (eq 32) for Q = I, R = 1; k = K_st0 of the axis. Not the truth.

    With u = -K x and B = [0, 1/m] the printed K maps directly onto this module's convention
    (the paper's eq 20 carries +u with B = [0, -1/m]).
    """
    s = sp.sqrt(k**2 + 1)
    w = sp.sqrt(1 + 2 * m * (s - 1))
    P = sp.Matrix([[w * (s - 1) + k, m * (s - 1)], [m * (s - 1), m * w]])
    K = sp.Matrix([[s - 1, w]])
    return P, K


def paper_riccati_residual(k: sp.Expr, m: sp.Expr) -> sp.Matrix:
    """Eq 30 (the ARE for Q = I, R = 1) at the printed P of eq 31; zero if eq 31 solved it."""
    A, B = axis_matrices(k, m)
    return riccati_residual(A, B, sp.eye(2), sp.Matrix([[1]]), paper_riccati(k, m)[0])


def paper_force_sums(F: dict[str, sp.Expr] | None = None) -> dict[str, sp.Expr]:
    """PRINTED force and moment sums of eqs 8-12 (eq 11 labels pitch M_z, eq 12 yaw M_y)."""
    F = PAPER_FORCES if F is None else F
    heave = F["F_z3"] - F["F_z1"] - F["F_z2"] + F["F_z6"] - F["F_z4"] - F["F_z5"]
    lateral = F["F_y1"] - F["F_y2"] + F["F_y4"] - F["F_y5"]
    return {
        "F_z": heave,
        "F_y": lateral,
        "M_x": sp.Rational("0.119") * lateral,
        "M_z": sp.Rational("0.26") * heave,
        "M_y": sp.Rational("0.26") * (F["F_y1"] - F["F_y2"] - F["F_y4"] + F["F_y5"]),
    }


def paper_allocation_constraints(u: Sequence[sp.Expr] = _u, Lx: sp.Expr = _Lx,
                                 Ly: sp.Expr = _Ly, Lxla: sp.Expr = _Lxla
                                 ) -> tuple[list[sp.Expr], list[sp.Expr]]:
    """PRINTED constraints (each = 0) multiplying lambda_i in eq 22 and in eq 23.

    u = (u_y, u_z, u_phi, u_theta, u_psi); eq 23's third constraint prints u_phi, not u_psi.
    """
    u_y, u_z, u_phi, u_theta, _ = u
    F = PAPER_FORCES
    front_z = F["F_z3"] - F["F_z1"] - F["F_z2"]
    rear_z = F["F_z6"] - F["F_z5"] - F["F_z4"]
    lateral = F["F_y1"] - F["F_y2"] + F["F_y4"] - F["F_y5"]
    eq22 = [front_z + rear_z - u_z, front_z - rear_z - u_theta / Lx]
    eq23 = [lateral - u_y, lateral - u_phi / Ly, lateral - u_phi / Lxla]
    return eq22, eq23


def paper_allocation(u: Sequence[sp.Expr] = _u, Lx: sp.Expr = _Lx, Ly: sp.Expr = _Ly,
                     Lxla: sp.Expr = _Lxla) -> dict[str, sp.Expr]:
    """PRINTED solutions of eqs 22-23 (the ten array forces). Not the truth.

    u = (u_y, u_z, u_phi, u_theta, u_psi); u_psi appears nowhere in the printed solutions.
    """
    u_y, u_z, u_phi, u_theta, _ = u
    a, b = u_z / 4, u_theta / (4 * Lx)
    c = u_y / 4 + u_phi / (4 * Ly) + u_phi / (4 * Lxla)
    return {
        "F_z3": -a - b, "F_z1": a + b, "F_z2": a + b,
        "F_z6": -a + b, "F_z5": a - b, "F_z4": a - b,
        "F_y1": -c, "F_y2": c, "F_y4": -c, "F_y5": c,
    }


def _coefficients(exprs: Sequence[sp.Expr], names: Sequence[str]) -> sp.Matrix:
    """Rows of d expr / d F for the named forces."""
    return sp.Matrix(exprs).jacobian([PAPER_FORCES[n] for n in names])


def _solution_residuals() -> list[str]:
    """Residuals of the printed constraints at the printed solutions (zero if they solved them)."""
    found = []
    printed = {PAPER_FORCES[n]: v for n, v in paper_allocation().items()}
    for eq, cons in zip((22, 23), paper_allocation_constraints(), strict=True):
        res = [sp.simplify(c.subs(printed)) for c in cons]
        if any(r != 0 for r in res):
            found.append(f"eq {eq}: the printed solutions do not satisfy the printed constraints; "
                         f"residuals {res}")
    return found


def _eq22_minimum_norm() -> list[str]:
    """Compare eq 22's printed solution with the minimum-norm solution of its constraints."""
    eq22, _ = paper_allocation_constraints()
    E = _coefficients(eq22, _Z_FORCES)
    rhs = sp.Matrix([_u[1], _u[3] / _Lx])
    true = minimum_norm_allocation(E) * rhs
    printed = paper_allocation()
    diff = {n: sp.simplify(printed[n] - t) for n, t in zip(_Z_FORCES, true, strict=True)}
    if all(d == 0 for d in diff.values()):
        return []
    return [f"eq 22: the minimum-norm solution of the printed constraints is F_z3 = {true[0]}, "
            f"F_z6 = {true[3]}; printed F_z3 = {printed['F_z3']}, F_z6 = {printed['F_z6']}"]


def _eq23_rank() -> list[str]:
    """Eq 23's three constraints share one left side: rank 1, so u must satisfy two conditions."""
    _, eq23 = paper_allocation_constraints()
    C = _coefficients(eq23, _Y_FORCES)
    if C.rank() == len(eq23):
        return []
    lateral = paper_force_sums()["F_y"]
    rhs = [sp.expand(lateral - c) for c in eq23]
    conditions = [sp.Eq(rhs[0], r) for r in rhs[1:]]
    return [f"eq 23: the {len(eq23)} constraint rows have rank {C.rank()} (identical left sides),"
            f" so they are consistent only if {conditions}"]


def _missing_yaw() -> list[str]:
    """u_psi appears in no printed constraint or solution of eqs 22-23."""
    eq22, eq23 = paper_allocation_constraints()
    used = set().union(*(e.free_symbols for e in [*eq22, *eq23, *paper_allocation().values()]))
    return [] if _u[4] in used else [
        "eqs 22-23: u_psi appears in no constraint and no solution (eq 23's third constraint "
        "prints u_phi/L_xlat), so the yaw control of eq 21 is never allocated"]


def _parallel_sums() -> list[str]:
    """Eqs 10-11 are multiples of eqs 9 and 8, unlike the moments eqs 22-23 constrain."""
    found = []
    sums = paper_force_sums()
    eq22, eq23 = paper_allocation_constraints()
    pairs = [("eq 11 pitch moment", "M_z", "eq 8", "F_z", _Z_FORCES, eq22[1], "eq 22's pitch"),
             ("eq 10 roll moment", "M_x", "eq 9", "F_y", _Y_FORCES, None, ""),
             ("eq 12 yaw moment", "M_y", "eq 9", "F_y", _Y_FORCES, eq23[2], "eq 23's yaw")]
    for label, moment, eq, force, names, constraint, cname in pairs:
        if _coefficients([sums[moment], sums[force]], names).rank() == 1:
            found.append(f"{label} is {sp.simplify(sums[moment] / sums[force])} times {eq}'s "
                         f"{force} sum (rank 1): the two cannot be commanded independently")
        if constraint is None:
            continue
        if _coefficients([sums[moment], constraint], names).rank() == 2:
            c_row, m_row = (list(_coefficients([e], names)) for e in (constraint, sums[moment]))
            found.append(f"{cname} constraint weighs ({', '.join(names)}) as {c_row}, not in "
                         f"proportion to the {label}'s {m_row}")
    return found


def _eq21_units() -> list[str]:
    """u_phi = L_y * sum M_x (eq 21) is N m^2, but eq 20 adds u_phi to I_xx phi'' (N m)."""
    from sympy.physics import units  # 0.15 s to import; only this check needs it

    moment = units.newton * units.meter
    eq21 = units.meter * moment
    eq20 = units.kilogram * units.meter**2 / units.second**2
    ratio = units.convert_to(eq21 / eq20, [units.kilogram, units.meter, units.second])
    if ratio == 1:
        return []
    return [f"eq 21: u_phi = L_y * sum M_x (also u_theta, u_psi) has the units of {ratio} times "
            f"eq 20's moment I_xx phi''; eq 22's u_theta/L_x is a force only if u_theta is a "
            "moment"]


def paper_discrepancies_allocation() -> list[str]:
    """Inconsistencies of eqs 8-12 and 21-23 as printed, each found by computation."""
    return list(_allocation_findings())


@memoized
def _allocation_findings() -> tuple[str, ...]:
    return (*_solution_residuals(), *_eq22_minimum_norm(), *_eq23_rank(), *_missing_yaw(),
            *_parallel_sums(), *_eq21_units())


_DEFAULT_K, _DEFAULT_M = sp.Integer(2000), sp.Rational("9.3")  # a stiffness and the cradle mass


def paper_discrepancies_riccati(k: sp.Expr = _DEFAULT_K, m: sp.Expr = _DEFAULT_M) -> list[str]:
    """Inconsistencies of eqs 29-33 as printed, each found by computation (at k, m for numbers)."""
    res = paper_riccati_residual(k, m).evalf(20)
    return [f"eq 31 does not satisfy eq 30: residual at k = {k}, m = {m} is {res.tolist()}",
            *_riccati_symbolic_findings()]


@memoized
def _riccati_symbolic_findings() -> tuple[str, ...]:
    """The findings that hold for every k and m (symbolic solves: memoised)."""
    ks, ms = sp.Symbol("k", real=True), sp.Symbol("m", positive=True)
    found = []
    r11 = paper_riccati_residual(ks, ms)[0, 0]
    roots = sp.solve(sp.simplify(r11), ks)
    r12 = [sp.simplify(paper_riccati_residual(k0, ms)[0, 1]) for k0 in roots]
    if all(sp.solve(r, ms) == [] for r in r12):  # ms is a positive symbol
        found.append(f"eq 31's (1,1) residual vanishes only at k = {roots}, where the (1,2) "
                     f"residual is {r12}, nonzero for every m > 0: no degenerate case")
    P, K = paper_riccati(ks, ms)
    if sp.simplify(sp.Matrix([[0, 1 / ms]]) * P - K) == sp.zeros(1, 2):
        found.append("eq 32's K equals [0, 1/m] P of eq 31 (so eq 32 follows from eq 31), but "
                     "eq 29's B is [0, -1/m]: the sign is absorbed by eq 33's u = +K x")
    true_K1 = riccati_closed_form(ks, ms, 1, 1, 1).K[0]
    same = sp.solve(sp.Eq(K[0], true_K1), ks)
    found.append(f"eq 32's K1 = sqrt(k^2+1) - 1 equals the LQR gain sqrt(k^2+1) - k only at "
                 f"k = {same}")
    return tuple(found)
