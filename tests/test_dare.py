"""The DARE solve the discrete designs share (maglevgen.control.lqr.solve_dare): SciPy's
solve_discrete_are, and the structure-preserving doubling where SciPy's QZ reordering refuses
the pencil. References: SciPy's own solution of the same problem, python-control's dlqr gain,
and the DARE's residual computed here."""

from __future__ import annotations

import control
import numpy as np
import pytest
import scipy.linalg

from maglevgen.control import lqr


def _problem(seed: int, n: int = 8, m: int = 3, delay: int = 0):
    """A random stabilizable, detectable DARE (A with a few unstable modes), with ``delay``
    ticks of input delay appended (a singular A: the delay's shift)."""
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    A *= 1.2 / np.abs(np.linalg.eigvals(A)).max()  # its largest mode unstable
    B = rng.normal(size=(n, m))
    if delay:
        N = n + delay * m
        Ad, Bd = np.zeros((N, N)), np.zeros((N, m))
        Ad[:n, :n] = A
        Ad[:n, N - m:] = B  # the oldest command acts
        Bd[n:n + m] = np.eye(m)
        for j in range(1, delay):
            Ad[n + j * m:n + (j + 1) * m, n + (j - 1) * m:n + j * m] = np.eye(m)
        A, B = Ad, Bd
    C = rng.normal(size=(A.shape[0], A.shape[0]))
    Q = C @ C.T / A.shape[0] + 1e-3 * np.eye(A.shape[0])
    R = np.diag(rng.uniform(0.1, 10.0, size=m))
    return A, B, Q, R


def _residual(A, B, Q, R, X) -> float:
    AXB = A.T @ X @ B
    res = A.T @ X @ A - X - AXB @ np.linalg.solve(R + B.T @ X @ B, AXB.T) + Q
    return float(np.abs(res).max() / np.abs(X).max())


@pytest.mark.parametrize(("seed", "delay"), [(0, 0), (1, 0), (2, 1), (3, 2)])
def test_the_doubling_finds_scipys_solution(seed: int, delay: int) -> None:
    A, B, Q, R = _problem(seed, delay=delay)
    assert np.abs(np.linalg.eigvals(A)).max() > 1.0  # the problem needs feedback
    X = lqr.dare_doubling(A, B, Q, R)
    ref = scipy.linalg.solve_discrete_are(A, B, Q, R)
    np.testing.assert_allclose(X, ref, rtol=1e-8, atol=1e-10 * np.abs(ref).max())
    assert _residual(A, B, Q, R, X) < 1e-11


def test_the_gain_is_control_dlqr_when_scipy_refuses(monkeypatch) -> None:
    """solve_dare falls back to the doubling when SciPy raises (SciPy made to refuse here, as
    its reordering does on an ill-conditioned pencil): the discrete LQR gain is still
    python-control's, computed before SciPy was made to refuse."""
    A, B, Q, R = _problem(4, delay=1)
    K_ref = np.asarray(control.dlqr(A, B, Q, R)[0])

    def refuse(*_args, **_kwargs):
        raise np.linalg.LinAlgError("Reordering of (A, B) failed")

    monkeypatch.setattr(scipy.linalg, "solve_discrete_are", refuse)
    K = lqr.numerical_dlqr(A, B, Q, R)
    np.testing.assert_allclose(K, K_ref, rtol=1e-7, atol=1e-9 * np.abs(K_ref).max())


def test_no_stabilizing_solution_is_refused(monkeypatch) -> None:
    """An unstable mode the input cannot reach has no stabilizing solution: SciPy's error
    comes through, whatever the doubling does."""
    A = np.diag([1.5, 0.5])
    B = np.array([[0.0], [1.0]])
    Q, R = np.eye(2), np.eye(1)

    def refuse(*_args, **_kwargs):
        raise ValueError("no stabilizing solution")

    monkeypatch.setattr(scipy.linalg, "solve_discrete_are", refuse)
    with pytest.raises((ValueError, np.linalg.LinAlgError)):
        lqr.solve_dare(A, B, Q, R)
