"""runtime/ffi.py's calls of the generated functions: what each call returns is its own, from
any thread, whatever array-like form its inputs take; against CasADi's own loader."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import casadi as ca
import numpy as np
import pytest

from maglevgen.carriage import DerivedCarriage
from maglevgen.runtime.ffi import GeneratedFunctionError


@pytest.fixture(scope="module")
def states(carriage: DerivedCarriage, sim_lib) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """200 states about the trim at 20 m/s, the trim input and p."""
    p = carriage.p
    x_trim, f_prop = sim_lib.function("maglev_trim")(20.0, p)
    rng = np.random.default_rng(7)
    X = x_trim.ravel() + rng.normal(scale=1e-3, size=(200, x_trim.size))
    u = np.zeros(sim_lib.function("maglev_dynamics").shapes_in[1][0])
    u[0] = float(f_prop.ravel()[0])
    return X, u, p


def test_dynamics_agree_with_casadi_external(sim_lib, states) -> None:
    X, u, p = states
    ours = sim_lib.function("maglev_dynamics")
    theirs = ca.external("maglev_dynamics", str(sim_lib.path))
    for x in X[:20]:
        np.testing.assert_array_equal(ours(x, u, p)[0].ravel(),
                                      np.asarray(theirs(x, u, p)).ravel())


def test_a_result_is_not_overwritten_by_the_next_call(sim_lib, states) -> None:
    X, u, p = states
    f = sim_lib.function("maglev_dynamics")
    first = f(X[0], u, p)[0]
    kept = first.copy()
    second = f(X[1], u, p)[0]
    assert not np.array_equal(first, second)
    np.testing.assert_array_equal(first, kept)


def test_calls_from_many_threads_match_one_thread(sim_lib, states) -> None:
    """ctypes releases the GIL during the C call, so the threads' calls overlap: each needs
    its own input, output and work arrays."""
    X, u, p = states
    f = sim_lib.function("maglev_dynamics")
    trim = sim_lib.function("maglev_trim")
    alone = [f(x, u, p)[0] for x in X]
    trims_alone = [trim(v, p)[0] for v in np.linspace(15.0, 40.0, 24)]
    with ThreadPoolExecutor(max_workers=4) as pool:
        together = list(pool.map(lambda x: f(x, u, p)[0], X))
        trims_together = list(pool.map(lambda v: trim(v, p)[0], np.linspace(15.0, 40.0, 24)))
    for a, b in zip(alone + trims_alone, together + trims_together, strict=True):
        np.testing.assert_array_equal(a, b)


def test_input_forms_give_the_same_call(sim_lib, carriage: DerivedCarriage, states) -> None:
    """A matrix input as a 2-D array or as its column-major vector, a scalar as a float, an int
    or a 1-element array, a vector as a list: the same numbers reach the C."""
    X, _u, p = states
    ctl = sim_lib.function("maglev_coupled_control")
    rng = np.random.default_rng(3)
    K_pos, K_rate = rng.normal(size=(5, 5)), rng.normal(size=(5, 5))
    a_ref = rng.normal(scale=1e-3, size=5)
    as_matrices = ctl(X[0], K_pos, K_rate, a_ref, p)[0]
    as_vectors = ctl(list(X[0]), K_pos.ravel(order="F"), K_rate.ravel(order="F"), a_ref, p)[0]
    np.testing.assert_array_equal(as_matrices, as_vectors)
    # u_gen = -(K_pos (a - a_ref) + K_rate a_dot): the matrix is read column-major
    assert not np.array_equal(as_matrices, ctl(X[0], K_pos.T, K_rate, a_ref, p)[0])
    trim = sim_lib.function("maglev_trim")
    for speed in (20, 20.0, np.array([20.0]), [20.0]):
        np.testing.assert_array_equal(trim(speed, p)[0], trim(20.0, p)[0])


def test_wrong_sizes_and_error_codes_are_refused(sim_lib, states) -> None:
    X, u, p = states
    f = sim_lib.function("maglev_dynamics")
    with pytest.raises(ValueError, match="input of size 11"):
        f(X[0][:11], u, p)
    with pytest.raises(TypeError, match="takes 3 inputs"):
        f(X[0], u)
    bad = p.copy()
    bad[0] = -1.0  # a negative mass: out of the parameter's range
    with pytest.raises(GeneratedFunctionError):
        f(X[0], u, bad)
    np.testing.assert_array_equal(f(X[0], u, p)[0], f(X[0].copy(), u, p)[0])
