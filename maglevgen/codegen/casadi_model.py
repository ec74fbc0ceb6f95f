"""The symbolic model as CasADi SX: the SymPy layers converted and joined, not re-derived."""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import sympy as sp

from maglevgen.codegen.sympy_casadi import SympyToCasadi
from maglevgen.derive.model import CarriageModel

__all__ = ["CasadiModel", "casadi_model"]


@dataclass(frozen=True)
class CasadiModel:
    x: ca.SX
    u: ca.SX
    p: ca.SX
    xdot: ca.SX
    gaps: ca.SX  # face-centre gaps (the force law's)
    contact_gaps: ca.SX  # each face's closest corner (contact)
    lift: ca.SX
    drag: ca.SX


def casadi_model(model: CarriageModel) -> CasadiModel:
    """xdot(x, u, p) as SX, built layer by layer from the SymPy model."""
    x = ca.SX.sym("x", model.x.shape[0])
    u = ca.SX.sym("u", model.u.shape[0])
    p = ca.SX.sym("p", model.p.shape[0])
    mapping = {**_pairs(model.x, x), **_pairs(model.u, u), **_pairs(model.p, p)}
    conv = SympyToCasadi(mapping)
    speeds = conv(model.array_speeds)
    gaps, contact_gaps = conv(model.gaps), conv(model.contact_gaps)
    conv = SympyToCasadi({**mapping, **_pairs(model.speed_sym, speeds)})
    lift, drag = conv(model.lift_at_speed), conv(model.drag_at_speed)
    spread, arms = conv(model.spread_at_speed), conv(sp.Matrix.vstack(*model.arms))
    conv = SympyToCasadi({**mapping, **_pairs(model.lift_sym, lift),
                          **_pairs(model.drag_sym, drag), **_pairs(model.spread_sym, spread),
                          **_pairs(model.arm_sym, arms)})
    wrench = conv(model.wrench)
    conv = SympyToCasadi({**mapping, **_pairs(model.wrench_sym, wrench)})
    xdot = ca.vertcat(conv(model.kinematics), conv(model.accelerations))
    return CasadiModel(x, u, p, xdot, gaps, contact_gaps, lift, drag)


def _pairs(syms, sx: ca.SX) -> dict:
    return {s: sx[i] for i, s in enumerate(syms)}
