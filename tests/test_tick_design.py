"""The `spec` design at the tick without the actuator lag (maglevgen.control.sampled.tick_design).
The envelope's verdict of `spec` is its design at the tick on the loop as built, lag included:
tests/test_loop_plant.py.

References: python-control's ``c2d`` (ZOH) of the reduced linearisation, the delay's states
assembled here, and ``control.dlqr`` on that model with the weights built here from the
per-axis (q1, q2, r); the sampled closed loop's eigenvalues from that model and those gains.
"""

from __future__ import annotations

import control
import numpy as np
import pytest

from maglevgen.analyses.envelope import loop_setting
from maglevgen.control.sampled import (
    Tick,
    loop_model,
    sampled_closed_loop,
    tick_design,
    tick_design_loop_gains,
)
from maglevgen.control.spec import spec_weights

LOW_TICK = 200.0  # [Hz] where the continuous design goes unstable, the one at the tick not


def _reference_dlqr(op, tick: Tick) -> np.ndarray:
    """control.dlqr on the ZOH model (control.c2d) with the delay's states assembled here."""
    A_r, B_g = op.reduced
    n, m, d = A_r.shape[0], B_g.shape[1], tick.delay
    sysd = control.c2d(control.ss(A_r, B_g, np.eye(n), 0), tick.period, "zoh")
    Phi, Gamma = np.asarray(sysd.A), np.asarray(sysd.B)
    N = n + d * m
    if d == 0:
        Pa, Ga = Phi, Gamma
    else:
        Pa, Ga = np.zeros((N, N)), np.zeros((N, m))
        Pa[:n, :n] = Phi
        Pa[:n, N - m:] = Gamma  # the oldest command in flight acts over this tick
        for j in range(1, d):
            Pa[n + j * m:n + (j + 1) * m, n + (j - 1) * m:n + j * m] = np.eye(m)
        Ga[n:n + m] = np.eye(m)
    q1, q2, r = spec_weights(op)
    C = op.rate_map
    Q = np.zeros((N, N))
    Q[:n, :n] = np.diag(np.r_[q1, np.zeros(n - 5)]) + C.T @ np.diag(q2) @ C
    K, _, _ = control.dlqr(Pa, Ga, Q, np.diag(r))
    return np.asarray(K)


@pytest.mark.parametrize("delay", [0, 1, 2])
def test_tick_design_is_dlqr_of_the_zoh_model_with_the_delay(op, delay) -> None:
    """The design's gains on (a - a_ref, a') and on the commands in flight, mapped back onto
    the reduced state, equal python-control's dlqr on the model assembled here."""
    tick = Tick(LOW_TICK, delay)
    design = tick_design(op, tick)
    K_ref = _reference_dlqr(op, tick)
    n = op.reduced[0].shape[0]
    S = np.eye(5, n)
    K_state = design.K_pos @ S + design.K_rate @ op.rate_map
    scale = np.abs(K_ref).max()
    np.testing.assert_allclose(K_state, K_ref[:, :n], atol=1e-8 * scale)
    np.testing.assert_allclose(design.K_delay, K_ref[:, n:], atol=1e-8 * scale)


def test_tick_design_on_the_loop_gives_the_reference_closed_loop(carriage, sim_lib, op) -> None:
    """With the speed loop: the loop's eigenvalues from the design's (K, K_delay) equal the
    eigenvalues of the closed loop assembled here from c2d and dlqr's gains."""
    tick = Tick(LOW_TICK, 1)
    setting = loop_setting(carriage, [op])
    K, K_delay = tick_design_loop_gains(op, tick_design(op, tick), setting.speed_gain)
    A, B = loop_model(op)
    n, m = A.shape[0], B.shape[1]
    sysd = control.c2d(control.ss(A, B, np.eye(n), 0), tick.period, "zoh")
    K_ref = _reference_dlqr(op, tick)
    nr = op.reduced[0].shape[0]
    # dlqr's gain as gains on (a, a') (the reduced state's positions and rates, M_r), then
    # on the loop's state, whose rates a' also see u through the kinematics (A's rows)
    M_r = np.vstack([np.eye(5, nr), op.rate_map])
    K_axes = K_ref[:, :nr] @ np.linalg.inv(M_r)
    # y, z, phi, theta, psi lead the loop's state; their rows of A: a' on the loop's state
    M_loop = np.vstack([np.eye(5, n), A[:5]])
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = np.asarray(sysd.A), np.asarray(sysd.B)
    M[n:n + 5, :n] = -K_axes @ M_loop
    M[n:n + 5, n:n + 5] = -K_ref[:, nr:]
    M[n + 5, :n] = -K[5]
    ref = np.sort_complex(np.linalg.eigvals(M))
    got = np.sort_complex(np.linalg.eigvals(sampled_closed_loop(A, B, K, tick, K_delay)))
    np.testing.assert_allclose(got, ref, atol=1e-9)
    assert K_delay.shape == (6, 6) and np.all(K_delay[5] == 0) and np.all(K_delay[:, 5] == 0)
