"""The paper's designs and the open loop: no control, optimized damping (eqs 20-21), the
per-axis LQR (eqs 24-33) and the coupled LQR with the paper's weights (Q = I, R = 1).

Kept so that figs 3-8 and the paper's comparison stay reproducible; with the paper's weights
both LQRs damp the heave axis to a damping ratio of about 0.002 (see `spec` for a design to a
specification).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from maglevgen.control.registry import Controller, register

if TYPE_CHECKING:
    from maglevgen.control.operating import OperatingPoint

__all__ = []

N_AXES = 5


def _none(op: OperatingPoint) -> tuple[np.ndarray, np.ndarray]:
    zero = np.zeros((N_AXES, N_AXES))
    return zero, zero.copy()


def _damping(op: OperatingPoint) -> tuple[np.ndarray, np.ndarray]:
    return np.zeros((N_AXES, N_AXES)), np.diag(op.c_damping)


def _per_axis_lqr(op: OperatingPoint) -> tuple[np.ndarray, np.ndarray]:
    return np.diag(op.K[:, 0]), np.diag(op.K[:, 1])


def _coupled(op: OperatingPoint) -> tuple[np.ndarray, np.ndarray]:
    return op.axis_gains(op.K_coupled)


register(Controller(
    "none", "no control", "no control: the array forces are zero", _none, embeddable=False,
    paper=True, tick_function=None, fmu_gains="none",
    style={"color": "0.45", "ls": ":", "lw": 1.2}))
register(Controller(
    "damping", "optimized damping", "optimized damping (eqs 20-21): K_rate = diag(c)",
    _damping, paper=True, tick_function="maglev_damping_control", fmu_gains="damping",
    style={"color": "tab:green", "ls": "-", "lw": 1.0}))
register(Controller(
    "lqr", "per-axis LQR", "the paper's per-axis LQR (eqs 24-33) with control.state_weights "
    "and control.input_weight", _per_axis_lqr, paper=True, tick_function="maglev_lqr_control",
    fmu_gains="axis", style={"color": "tab:blue", "ls": "--", "lw": 1.6}))
register(Controller(
    "coupled", "coupled LQR", "a full-state LQR of the coupled 10-state linearisation with the "
    "per-axis design's weights (control.state_weights, control.input_weight)", _coupled,
    paper=True, style={"color": "tab:orange", "ls": "-", "lw": 0.9}))
