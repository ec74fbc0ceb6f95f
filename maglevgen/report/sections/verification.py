"""Section: verification."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import mpmath
import numpy as np

from maglevgen.control.carriage_plant import Plant
from maglevgen.derive import conventions as cv
from maglevgen.derive.riccati import riccati_relative_residual
from maglevgen.errors import MaglevError

__all__ = ["Check", "verification_section"]

# The spread of the states about the trim that the C is compared with SymPy at (m, rad, m/s,
# rad/s).
_SPREAD: dict[str, float] = {"x": 0.5, "y": 1e-3, "z": 1e-3, "phi": 5e-3, "theta": 5e-3,
                             "psi": 5e-3, "u": 1.0, "v": 0.02, "w": 0.02, "p": 0.05, "q": 0.05,
                             "r": 0.05}


@dataclass(frozen=True)
class Check:
    """One row of the verification table."""

    what: str  # LaTeX text
    reference: str  # LaTeX text
    error: float | None  # measured error (None: not run)
    bound: float
    note: str = ""  # why it was not run
    unit: str = "1"  # of the error and the bound (LaTeX text): "1" for a relative error
    # a finding about a design other than the embedded one (the paper's): listed apart from
    # the toolchain's own checks, not counted as a failed verification
    finding: bool = False

    @property
    def status(self) -> str:
        if self.error is None:
            return "not run"
        return "pass" if self.error <= self.bound else "FAIL"


def _generated_c_checks(
    plant: Plant,
    gains: dict,
    samples: int = 100,
    seed: int = 20240607,
) -> list[Check]:
    """Generated C (double, run-time parameters) against the SymPy model and the gains.

    The references are independent of the library: the lambdified SymPy layers composed by
    the chain rule, and SciPy's root of them for the trim (`Carriage.trim`)."""

    what = (
        f"Generated C \\texttt{{maglev\\_dynamics}} vs SymPy model, {samples} states near trim",
        "Generated C \\texttt{maglev\\_jacobians} vs chain-rule Jacobians, 20 states",
        "Generated C \\texttt{maglev\\_trim} vs Python trim",
        "Generated C \\texttt{maglev\\_lqr\\_gains} vs closed form",
    )
    refs = (
        "lambdified model layers",
        "lambdified partials",
        "SciPy root (hybrd)",
        "\\texttt{gains} closed form",
    )
    bounds = (1e-12, 1e-10, 1e-9, 1e-10)
    try:
        lib = plant.lib
    except MaglevError as exc:
        return [
            Check(w, r_, None, b, f"not run: {exc}")
            for w, r_, b in zip(what, refs, bounds, strict=True)
        ]
    carriage = plant.carriage
    mf, p = carriage.functions, carriage.p
    trim = carriage.trim()  # the reference trim: SciPy on the lambdified model
    rng = np.random.default_rng(seed)
    n_u = carriage.model.u.shape[0]
    X = trim.x + rng.normal(scale=[_SPREAD[s] for s in cv.STATE_NAMES],
                            size=(samples, cv.N_STATES))
    U = trim.u + rng.normal(scale=2.0, size=(samples, n_u))
    dyn = lib.function("maglev_dynamics")
    ref = np.array([mf.xdot(x, u, p) for x, u in zip(X, U, strict=True)])
    got = np.array([dyn(x, u, p)[0].ravel() for x, u in zip(X, U, strict=True)])
    scale = np.maximum(np.max(np.abs(ref), axis=0), 1e-300)
    e_dyn = float(np.max(np.abs(got - ref) / scale))
    jac = lib.function("maglev_jacobians")
    e_jac = 0.0
    for x, u in zip(X[:20], U[:20], strict=True):
        A, B = mf.jacobians(x, u, p)
        Ac, Bc = jac(x, u, p)
        e_jac = max(
            e_jac,
            float(np.max(np.abs(Ac - A)) / np.max(np.abs(A))),
            float(np.max(np.abs(Bc - B)) / np.max(np.abs(B))),
        )
    xt, fp = lib.function("maglev_trim")([trim.speed], p)
    e_trim = max(
        float(np.max(np.abs(xt.ravel() - trim.x))),
        abs(float(fp.ravel()[0]) - trim.u[cv.PROPULSION_INPUT])
        / abs(trim.u[cv.PROPULSION_INPUT]),
    )
    Kc, _c = lib.function("maglev_lqr_gains")([trim.speed], p)
    K_ref = np.array([a["K_closed_form"] for a in gains["axes"].values()])
    e_gain = float(np.max(np.abs(Kc - K_ref) / np.abs(K_ref)))
    return [
        Check(w, r_, e, b)
        for w, r_, e, b in zip(what, refs, (e_dyn, e_jac, e_trim, e_gain), bounds, strict=True)
    ]


def verification_section(
    plant: Plant,
    gains: dict,
    trep: dict,
    rigid: dict,
    alloc: dict,
    paper: dict,
    c_progress: Callable[[str], None] | None,
) -> list[Check]:
    """The verification table; the generated-C rows only when ``c_progress`` is given."""

    axes = gains["axes"]
    (q1, _), (_, q2) = gains["Q"]
    r = gains["R"]
    with mpmath.workdps(50):
        are = max(
            riccati_relative_residual(a["A"], a["B"], [[q1, 0], [0, q2]], [[r]], a["P_closed_form"])
            for a in axes.values()
        )
    checks = [
        Check(
            "Closed-form $K$ (eq 32, stable form) vs numerical LQR, all axes",
            "scipy CARE (Schur)",
            max(a["relative_difference"]["numerical_vs_closed_form"] for a in axes.values()),
            1e-6,
        ),
        Check(
            "Closed-form $K$ in double precision",
            "closed form in 50-digit mpmath",
            max(a["accuracy_vs_50_digit_reference"]["closed_form"] for a in axes.values()),
            1e-14,
        ),
        Check(
            "Numerical LQR $K$ (scipy CARE)",
            "closed form in 50-digit mpmath",
            max(a["accuracy_vs_50_digit_reference"]["numerical"] for a in axes.values()),
            1e-6,
        ),
        Check(
            "Stable closed form in single precision",
            "closed form in 50-digit mpmath",
            max(a["stable32"] for a in paper["axes"]),
            1e-5,
        ),
        Check("Closed-form $P$ in eq 28 (relative residual)", "zero", are, 1e-14),
        Check(
            "Trim: largest acceleration at the equilibrium",
            "zero",
            trep["residual"],
            1e-8,
            unit="m/s$^2$, rad/s$^2$",
        ),
        Check(
            "Eqs 1--2 at the model's accelerations (exact rationals, 3 bodies)",
            "zero",
            float(rigid["exact_residual_nonzero"]),
            0.0,
            unit="count",
        ),
        Check("Allocation: $E\\,T - I$" if alloc["full_rank"] else
              "Allocation: $E\\,T\\,E - E$ ($E$ rank deficient)", "zero",
              alloc["E_T_residual"], 1e-12),
        Check(
            "Allocation: $T$ from the Lagrangian vs $E^{+}$",
            "numpy pinv",
            alloc["T_pinv_residual"],
            1e-12,
        ),
    ]
    if c_progress is not None:
        checks += _generated_c_checks(plant, gains)
    return checks


Simulation = Path | Mapping[str, bytes | str] | None
