"""The benchmarks' hand-written C model computes what the generated C computes.

bench/ compares the speed of the generated ``maglev_dynamics`` with a hand-written C model
(bench/reference/maglev_model.c). The comparison is only fair if both compute the same
derivative: this checks the hand-written model against the generated C and the symbolic
model on random states near trim, its allocation against the generated one, and its RK4 loop
against the same loop written in Python around the generated functions.
"""

from __future__ import annotations

import ctypes
from pathlib import Path

import numpy as np
import pytest

from maglevgen.carriage import DerivedCarriage
from maglevgen.codegen.cpass import generate_c
from maglevgen.codegen.functions import build_functions
from maglevgen.control.symbolic_reference import allocation_matrix
from maglevgen.derive import conventions as cv
from maglevgen.derive.linearize import Q_STATES
from maglevgen.params import load_params
from maglevgen.runtime.compile import compile_shared
from maglevgen.runtime.ffi import GeneratedLibrary

pytestmark = [pytest.mark.needs_cc, pytest.mark.slow]

REFERENCE = Path(__file__).resolve().parents[1] / "bench" / "reference" / "maglev_model.c"
FLAGS = ["-std=c99", "-O2", "-fPIC", "-shared", "-Wall", "-Wextra", "-Wpedantic", "-Werror"]
N_SAMPLES = 300
RTOL = 1e-12

_D = ctypes.POINTER(ctypes.c_double)


def _ptr(a: np.ndarray) -> ctypes.POINTER:
    return a.ctypes.data_as(_D)


@pytest.fixture(scope="module")
def carriage() -> DerivedCarriage:
    """The default carriage with the paper's point force law and quasi-static circuits (eq 3):
    the model the hand-written C implements (the distributed law is checked against its own
    quadrature reference, the circuits' lag in test_circuit_lag.py)."""
    return DerivedCarriage(load_params(overrides=['model.array_force="point"',
                                           'model.circuit_dynamics="quasi-static"']))


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> ctypes.CDLL:
    lib = ctypes.CDLL(
        str(compile_shared([REFERENCE], FLAGS, cache_dir=tmp_path_factory.mktemp("ref_cache")))
    )
    lib.ref_dynamics.restype = None
    lib.ref_allocate.restype = None
    lib.ref_simulate.restype = ctypes.c_longlong
    lib.ref_simulate.argtypes = [
        _D,
        ctypes.c_double,
        ctypes.c_longlong,
        ctypes.c_double,
        _D,
        _D,
        _D,
        _D,
        ctypes.c_double,
        _D,
        _D,
        _D,
        ctypes.POINTER(ctypes.c_int),
    ]
    return lib


@pytest.fixture(scope="module")
def generated(carriage: DerivedCarriage, tmp_path_factory) -> GeneratedLibrary:
    """maglev_dynamics and maglev_allocate as `maglevgen generate --parameters runtime` emits
    them (the same Functions and C pass), in a library of their own."""
    wanted = ("maglev_dynamics", "maglev_allocate")
    fns = [f for f in build_functions(carriage.model).functions if f.name() in wanted]
    assert [f.name() for f in fns] == list(wanted)
    out = tmp_path_factory.mktemp("gen")
    for name, text in generate_c(fns, "maglev_functions", "double").items():
        (out / name).write_text(text)
    lib = compile_shared([out / "maglev_functions.c"])
    return GeneratedLibrary(lib, "double")


def _ref_xdot(lib: ctypes.CDLL, x: np.ndarray, u: np.ndarray, p: np.ndarray) -> np.ndarray:
    x, u, p = (np.ascontiguousarray(a, dtype=float) for a in (x, u, p))
    out = np.zeros(12)
    lib.ref_dynamics(_ptr(x), _ptr(u), _ptr(p), _ptr(out))
    return out


def _samples(carriage: DerivedCarriage, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """States scattered around trim (mm, mrad, a few m/s) and array forces of a few newtons."""
    trim = carriage.trim()
    rng = np.random.default_rng(seed)
    scale = [0.5, 2e-3, 2e-3, 0.01, 0.01, 0.01, 2.0, 0.05, 0.05, 0.05, 0.05, 0.05]
    X = trim.x + rng.normal(scale=scale, size=(n, 12))
    U = np.tile(trim.u, (n, 1)) + rng.normal(scale=5.0, size=(n, trim.u.size))
    return X, U


def test_same_parameter_vector_and_structure(reference: ctypes.CDLL,
                                             carriage: DerivedCarriage) -> None:
    names = (ctypes.c_char_p * len(carriage.p)).in_dll(reference, "REF_PARAM_NAMES")
    assert [n.decode() for n in names] == [e.name for e in carriage.entries]
    # the reference is written for the default structure: y and z on arrays 1, 2, 4, 5
    assert carriage.structure.arrays == (
        ("1", ("y", "z")),
        ("2", ("y", "z")),
        ("3", ("z",)),
        ("4", ("y", "z")),
        ("5", ("y", "z")),
        ("6", ("z",)),
    )


def test_dynamics_match_generated_c_and_symbolic_model(
    reference: ctypes.CDLL, generated: GeneratedLibrary, carriage: DerivedCarriage
) -> None:
    dyn = generated.function("maglev_dynamics")
    X, U = _samples(carriage, N_SAMPLES, seed=5)
    p = carriage.p
    ref = np.array([_ref_xdot(reference, x, u, p) for x, u in zip(X, U, strict=True)])
    gen = np.array([dyn(x, u, p)[0].ravel() for x, u in zip(X, U, strict=True)])
    sym = np.array([carriage.functions.xdot(x, u, p) for x, u in zip(X, U, strict=True)])
    # relative to each component's typical size (a component that crosses zero has none)
    scale = np.mean(np.abs(gen), axis=0)
    assert np.all(scale > 0)
    assert np.max(np.abs(ref - gen) / scale) < RTOL
    assert np.max(np.abs(ref - sym) / scale) < RTOL


def test_dynamics_away_from_trim(
    reference: ctypes.CDLL, generated: GeneratedLibrary, carriage: DerivedCarriage
) -> None:
    """Large attitudes, rates and a CG offset in every direction: nothing is small-angle."""
    dyn = generated.function("maglev_dynamics")
    rng = np.random.default_rng(9)
    p = carriage.p.copy()
    names = [e.name for e in carriage.entries]
    for key in ("x", "y", "z"):
        p[names.index(f"vehicle.cg_offset.{key}")] = rng.uniform(-0.03, 0.03)
    p[names.index("vehicle.inertia_cg.xy")] = 0.002
    for _ in range(50):
        x = rng.normal(scale=[1, 0.01, 0.01, 0.4, 0.4, 0.4, 10, 1, 1, 2, 2, 2])
        u = rng.normal(scale=20.0, size=11)
        gen = dyn(x, u, p)[0].ravel()
        np.testing.assert_allclose(
            _ref_xdot(reference, x, u, p), gen, rtol=1e-11, atol=1e-12 * np.max(np.abs(gen))
        )


def test_allocation_matches(
    reference: ctypes.CDLL, generated: GeneratedLibrary, carriage: DerivedCarriage
) -> None:
    alloc = generated.function("maglev_allocate")
    T = allocation_matrix(carriage)
    p = np.ascontiguousarray(carriage.p)
    for u in np.random.default_rng(3).normal(scale=10.0, size=(20, 5)):
        F = np.zeros(10)
        reference.ref_allocate(_ptr(np.ascontiguousarray(u)), _ptr(p), _ptr(F))
        np.testing.assert_allclose(F, alloc(u, p)[0].ravel(), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(F, T @ u, rtol=1e-12, atol=1e-12)


def _python_loop(generated: GeneratedLibrary, x0, dt, n, F_prop, k_pos, k_rate, a_ref, p):
    """The closed loop of ref_simulate written out in Python around the generated functions."""
    dyn, alloc = generated.function("maglev_dynamics"), generated.function("maglev_allocate")
    idx = [cv.STATE_INDEX[s] for s in Q_STATES]

    def f(x):
        adot = dyn(x, np.zeros(11), p)[0].ravel()[idx]  # kinematics do not depend on u
        u_gen = -(k_pos * (x[idx] - a_ref) + k_rate * adot)
        u = np.concatenate([[F_prop], alloc(u_gen, p)[0].ravel()])
        return dyn(x, u, p)[0].ravel(), u

    xs, us = [x0], []
    x = x0
    for _ in range(n):
        k1, u = f(x)
        us.append(u)
        k2 = f(x + dt / 2 * k1)[0]
        k3 = f(x + dt / 2 * k2)[0]
        k4 = f(x + dt * k3)[0]
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        xs.append(x)
    us.append(f(x)[1])
    return np.array(xs), np.array(us)


def _ref_simulate(reference: ctypes.CDLL, x0: np.ndarray, dt: float, n: int, f_prop: float,
                  k_pos: np.ndarray, k_rate: np.ndarray, a_ref: np.ndarray, p: np.ndarray,
                  gap_min: float = 0.002) -> tuple[int, int, np.ndarray, np.ndarray, np.ndarray]:
    """ref_simulate over n steps: (last sample, status, states, inputs, gaps)."""
    X, U, G = np.zeros((n + 1, 12)), np.zeros((n + 1, 11)), np.zeros((n + 1, 6))
    status = ctypes.c_int(-1)
    done = reference.ref_simulate(_ptr(x0), dt, n, f_prop, _ptr(k_pos), _ptr(k_rate),
                                  _ptr(a_ref), _ptr(p), gap_min, _ptr(X), _ptr(U), _ptr(G),
                                  ctypes.byref(status))
    return done, status.value, X, U, G


def test_closed_loop_matches_python_loop(
    reference: ctypes.CDLL, generated: GeneratedLibrary, carriage: DerivedCarriage
) -> None:
    trim = carriage.trim()
    idx = [cv.STATE_INDEX[s] for s in Q_STATES]
    k_pos = np.array([30.0, 60.0, 5.0, 8.0, 4.0])
    k_rate = np.array([3.0, 4.0, 0.4, 0.6, 0.5])
    a_ref = trim.x[idx].copy()
    x0 = trim.x.copy()
    x0[idx] += [1e-3, 1e-3, 5e-3, 5e-3, 5e-3]
    dt, n, p = 1e-3, 50, np.ascontiguousarray(carriage.p)
    want_x, want_u = _python_loop(generated, x0, dt, n, trim.u[0], k_pos, k_rate, a_ref, p)
    done, status, X, U, G = _ref_simulate(reference, x0, dt, n, trim.u[0], k_pos, k_rate, a_ref,
                                          p)
    assert (done, status) == (n, 0)
    np.testing.assert_allclose(X, want_x, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(U, want_u, rtol=1e-9, atol=1e-9)
    gaps = np.array([carriage.functions.forces(x, carriage.p)[0] for x in X])
    np.testing.assert_allclose(G, gaps, rtol=1e-12, atol=1e-14)


def test_closed_loop_reports_contact(reference: ctypes.CDLL, carriage: DerivedCarriage) -> None:
    trim = carriage.trim()
    x0 = trim.x.copy()
    x0[cv.STATE_INDEX["w"]] = -1.0  # falling at 1 m/s with no feedback: contact within 15 ms
    zeros = np.zeros(5)
    n, p = 1000, np.ascontiguousarray(carriage.p)
    done, status, _X, _U, G = _ref_simulate(reference, x0, 1e-3, n, trim.u[0], zeros, zeros,
                                            zeros, p)
    assert status == 1 and 0 < done < 30
    assert G[done].min() < 0.002 <= G[done - 1].min()
