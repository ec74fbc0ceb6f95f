"""The derived stiffness of both array force laws and its parts (the lambdified split and the
compiled library's maglev_stiffness_parts, which the report prints) against central differences
of force sums written here (independent_reference.py's array loads: eq 3 at the face centre for
"point", the circuit model integrated by Gauss-Legendre quadrature over the face for
"distributed").

Each part is a difference quotient of a wrench in which only that part's dependence on the
pose is kept: the gap slope (each array's force scaled by exp(-2k (gap(q) - gap*)) at its trim
point of action), the rotating arms (the trim forces at their trim points, turned by R(q)),
gravity and propulsion (their forces at their points, turned by R(q)); the tilt across the face
is what the full magnetic difference quotient leaves over.
"""

from __future__ import annotations

import numpy as np
import pytest
from independent_reference import array_state, rotation, stiffness_fd

from maglevgen.analyses.queries import trim_point
from maglevgen.carriage import DerivedCarriage
from maglevgen.control.carriage_plant import Plant
from maglevgen.derive import conventions as cv
from maglevgen.derive.linearize import STIFFNESS_PARTS
from maglevgen.params import Parameters, load_params
from maglevgen.runtime.library import simulation_library

H = 1e-6


@pytest.fixture(scope="module")
def point() -> DerivedCarriage:
    return DerivedCarriage(load_params(overrides=['model.array_force="point"']))


def _q(trim) -> np.ndarray:
    return np.array([trim.x[cv.STATE_INDEX[s]] for s in cv.Q_STATES])


def _difference(wrench, q0: np.ndarray) -> np.ndarray:
    """K = -d(F_y, F_z, M_x, M_y, M_z)/dq of ``wrench(q)`` (6-vector) by central differences."""
    K = np.zeros((5, 5))
    for j in range(5):
        e = np.zeros(5)
        e[j] = H
        K[:, j] = -(wrench(q0 + e) - wrench(q0 - e))[1:] / (2 * H)
    return K


def _part_references(prm: Parameters, q0: np.ndarray, speed: float, f_prop: float
                     ) -> dict[str, np.ndarray]:
    k = 2 * np.pi / prm.halbach.wavelength
    st0 = array_state(prm, q0, speed)
    R0 = rotation(*q0[2:5])
    normals = [np.array(a.normal) for a in prm.arrays.values()]
    ex = np.array([1.0, 0.0, 0.0])
    forces = [fl * n - fd * ex for fl, fd, n in zip(st0.lift, st0.drag, normals, strict=True)]

    def gap_slope(q: np.ndarray) -> np.ndarray:
        scale = np.exp(-2 * k * (array_state(prm, q, speed).gaps - st0.gaps))
        return sum(np.concatenate([s * f, np.cross(R0 @ arm, s * f)])
                   for s, f, arm in zip(scale, forces, st0.arms, strict=True))

    def rotating_arms(q: np.ndarray) -> np.ndarray:
        R = rotation(*q[2:5])
        return sum(np.concatenate([f, np.cross(R @ arm, f)])
                   for f, arm in zip(forces, st0.arms, strict=True))

    def at_point(point: np.ndarray, force: np.ndarray):
        return lambda q: np.concatenate([force, np.cross(rotation(*q[2:5]) @ point, force)])

    v = prm.vehicle
    refs = {"gap_slope": _difference(gap_slope, q0),
            "rotating_arms": _difference(rotating_arms, q0),
            "gravity": _difference(at_point(np.array(v.cg_offset),
                                            np.array([0.0, 0.0, -v.mass * v.gravity])), q0),
            "propulsion": _difference(at_point(np.array(prm.operation.propulsion_point),
                                               f_prop * ex), q0)}
    magnetic = stiffness_fd(prm, q0, speed, f_prop, other=False, h=H)
    refs["tilt"] = magnetic - refs["gap_slope"] - refs["rotating_arms"]
    return refs


def _assert_close(K: np.ndarray, K_ref: np.ndarray, scale: np.ndarray, rel: float) -> None:
    """Entrywise, relative to the geometric mean of the axis scales of row and column."""
    for i in range(5):
        for j in range(5):
            tol = rel * np.sqrt(scale[i] * scale[j]) + 1e-9
            assert abs(K[i, j] - K_ref[i, j]) < tol, (i, j, K[i, j], K_ref[i, j])


def test_the_default_law_is_distributed(carriage: DerivedCarriage) -> None:
    assert carriage.params.model.array_force == "distributed"


@pytest.mark.parametrize("speed", [20.0, 35.0])
def test_each_laws_stiffness_equals_central_differences(carriage: DerivedCarriage,
                                                        point: DerivedCarriage,
                                                        speed: float) -> None:
    """K_st0 + K_other of both laws against -dW/dq of the reference force sums."""
    for c in (carriage, point):
        trim = c.trim(speed)
        K_fd = stiffness_fd(c.params, _q(trim), speed, float(trim.u[0]), h=H)
        _assert_close(c.total_stiffness(trim), K_fd, np.abs(np.diag(K_fd)), 1e-6)


def test_parts_sum_to_the_derived_stiffness_and_equal_their_differences(
        carriage: DerivedCarriage, point: DerivedCarriage) -> None:
    for c in (carriage, point):
        trim = c.trim()
        parts = c.stiffness_parts(trim)
        total = c.total_stiffness(trim)
        scale = np.abs(np.diag(total))
        _assert_close(sum(parts.values()), total, scale, 1e-12)
        refs = _part_references(c.params, _q(trim), trim.speed, float(trim.u[0]))
        assert set(parts) == set(refs)
        for name, K in parts.items():
            _assert_close(K, refs[name], scale, 1e-6)
        if c.params.model.array_force == "point":
            assert np.all(parts["tilt"] == 0)  # the point force has no tilt term
        else:  # the face's tilt restores in roll and pitch: the term the point force drops
            roll, pitch = cv.AXES.index("roll"), cv.AXES.index("pitch")
            assert refs["tilt"][roll, roll] > 0.5 * total[roll, roll]
            assert refs["tilt"][pitch, pitch] > 0


def test_contact_gaps_are_the_closest_corners(carriage: DerivedCarriage,
                                              point: DerivedCarriage) -> None:
    """The model's contact gap of each face equals the smallest of its four corners' gaps,
    each computed here from the pose (corner = face centre +- w/2 across +- N p/2 along)."""
    rng = np.random.default_rng(17)
    prm = carriage.params
    w, pitch = prm.halbach.width, prm.circuit.pitch
    for c in (carriage, point):
        for _ in range(5):
            x = np.zeros(12)
            x[[1, 2, 3, 4, 5]] = rng.uniform(-1, 1, 5) * [2e-3, 2e-3, 0.03, 0.03, 0.03]
            R = rotation(*x[3:6])
            X = x[0:3]
            got = c.functions.contact_gaps(x, c.p).ravel()
            centre = c.functions.gaps(x, c.p).ravel()
            for i, arr in enumerate(prm.arrays.values()):
                a, n = np.array(arr.position), np.array(arr.normal)
                along = np.array([1.0, 0.0, 0.0])  # the paper's normals lie in the y-z plane
                across = np.cross(n, along)
                length = arr.circuits * pitch
                corners = [a + sw * w / 2 * across + sl * length / 2 * along
                           for sw in (-1, 1) for sl in (-1, 1)]
                gaps = [arr.nominal_gap + n @ (X + R @ b - b) for b in corners]
                assert got[i] == pytest.approx(min(gaps), abs=1e-15)
                assert got[i] < centre[i]


def test_library_parts_are_the_derivations_split(carriage: DerivedCarriage, point: DerivedCarriage,
                                                 private_cache) -> None:
    """maglev_stiffness_parts (generated C, the report's parts table) at the C's trim equals
    each part's central difference of the force sums written here, sums to maglev_stiffness's
    K_st0 + K_other, and agrees with the lambdified split (the SymPy it is generated from)."""
    for c in (carriage, point):
        lib = simulation_library(c.structure)
        tp = trim_point(Plant(c, lib), None)
        got = dict(zip(STIFFNESS_PARTS, lib.function("maglev_stiffness_parts")(
            tp.x, tp.f_prop, c.p), strict=True))
        total = tp.K_magnetic + tp.K_other
        scale = np.abs(np.diag(total))
        _assert_close(sum(got.values()), total, scale, 1e-12)
        q = np.array([tp.x[cv.STATE_INDEX[s]] for s in cv.Q_STATES])
        refs = _part_references(c.params, q, tp.speed, tp.f_prop)
        u = np.zeros(len(c.trim().u))
        u[0] = tp.f_prop
        at = type("At", (), {"x": tp.x, "u": u, "lift": tp.lift, "drag": tp.drag})
        lambdified = c.stiffness_parts(at)
        for name, K in got.items():
            _assert_close(K, refs[name], scale, 1e-6)
            _assert_close(K, lambdified[name], scale, 1e-12)
        # the tilt part is what separates the laws: nonzero in roll only for the distributed
        roll = cv.AXES.index("roll")
        assert (got["tilt"][roll, roll] > 0.5 * total[roll, roll]) == (c is carriage)
