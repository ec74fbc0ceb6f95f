"""The assembled model, its trim and its linearisation against independent references."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from independent_reference import reference_trim

from maglevgen.carriage import DerivedCarriage
from maglevgen.cli import main
from maglevgen.codegen.casadi_model import casadi_model
from maglevgen.control.carriage_plant import Plant
from maglevgen.derive import conventions as cv
from maglevgen.errors import NoTrimError
from maglevgen.params import load_params


def _rot(phi: float, theta: float, psi: float) -> np.ndarray:
    c, s = np.cos, np.sin
    Rz = np.array([[c(psi), -s(psi), 0], [s(psi), c(psi), 0], [0, 0, 1]])
    Ry = np.array([[c(theta), 0, s(theta)], [0, 1, 0], [-s(theta), 0, c(theta)]])
    Rx = np.array([[1, 0, 0], [0, c(phi), -s(phi)], [0, s(phi), c(phi)]])
    return Rz @ Ry @ Rx


def _array_wrench_printed_eq3(carriage: DerivedCarriage, q: np.ndarray, speed: float) -> np.ndarray:
    """(F_y, F_z, M_x, M_y, M_z) of the arrays, written here from eqs 3-4 as printed."""
    prm = carriage.params
    h, c = prm.halbach, prm.circuit
    k = 2 * np.pi / h.wavelength
    M = h.magnets_per_wavelength
    B0 = h.remanence * (1 - np.exp(-k * h.thickness)) * np.sin(np.pi / M) / (np.pi / M)
    omega = k * speed
    R = _rot(*q[2:5])
    X = np.array([0.0, q[0], q[1]])
    total = np.zeros(6)
    for arr in prm.arrays.values():
        a, n = np.array(arr.position), np.array(arr.normal)
        gap = arr.nominal_gap + n @ (X + (R - np.eye(3)) @ a)
        F = (arr.circuits * B0**2 * h.width**2 / (2 * k * c.inductance)
             / (1 + (c.resistance / (omega * c.inductance)) ** 2) * np.exp(-2 * k * gap))
        f = F * n - F * c.resistance / (omega * c.inductance) * np.array([1.0, 0, 0])
        total += np.concatenate([f, np.cross(R @ a, f)])
    return total[1:]


def test_surface_field_matches_paper_value(carriage: DerivedCarriage) -> None:
    """Eq 4 with the assumed Br, d, M gives the paper's B0 = 0.9 T within 0.5 %."""
    val = dict(zip(carriage.model.p, carriage.p, strict=True))
    assert float(carriage.model.B0.xreplace(val)) == pytest.approx(0.9, rel=5e-3)


def test_trim_is_equilibrium_at_nominal_gap(carriage: DerivedCarriage, trim) -> None:
    xdot = carriage.functions.xdot(trim.x, trim.u, carriage.p)
    assert np.max(np.abs(xdot[6:])) < 1e-9
    assert xdot[0] == pytest.approx(carriage.params.operation.speed, rel=1e-12)
    assert np.max(np.abs(xdot[1:6])) < 1e-9
    upper = [i for i, a in enumerate(carriage.params.arrays.values()) if a.normal[2] == 1.0]
    assert np.mean(trim.gaps[upper]) == pytest.approx(0.015, abs=1e-4)
    # propulsion balances the drag: eq 3's drag at the trim gaps, summed here (the gaps are
    # checked against an independent root solve in test_independent.py)
    h, c = carriage.params.halbach, carriage.params.circuit
    ratio = c.resistance / (2 * np.pi / h.wavelength * trim.speed * c.inductance)
    assert trim.u[0] == pytest.approx(ratio * trim.lift.sum(), rel=1e-3)
    assert trim.u[0] == pytest.approx(reference_trim(carriage.params, trim.speed).f_prop,
                                      rel=1e-9)


@pytest.fixture(scope="module")
def point() -> DerivedCarriage:
    """The paper's force law: eq 3 at each face centre (model.array_force = "point")."""
    return DerivedCarriage(load_params(overrides=['model.array_force="point"']))


def test_trim_forces_balance_weight_independently(point: DerivedCarriage) -> None:
    """The printed eq 3 with the point law's trim pose reproduces the weight (independent
    force sum); the distributed law's trim is checked in test_independent.py."""
    carriage, trim = point, point.trim()
    q = np.array([trim.x[cv.STATE_INDEX[s]] for s in ("y", "z", "phi", "theta", "psi")])
    w = _array_wrench_printed_eq3(carriage, q, trim.speed)
    weight = carriage.params.vehicle.mass * carriage.params.vehicle.gravity
    assert w[1] == pytest.approx(weight, rel=1e-9)
    assert abs(w[0]) < 1e-9 * weight


def test_stiffness_equals_central_difference(point: DerivedCarriage) -> None:
    """Each derived stiffness of the point law (closed form in the trim forces) equals -dW/dq
    of printed eq 3 by differences (the distributed law's: test_stiffness_parts.py)."""
    carriage, trim = point, point.trim()
    q0 = np.array([trim.x[cv.STATE_INDEX[s]] for s in ("y", "z", "phi", "theta", "psi")])
    K = carriage.magnetic_stiffness(trim)
    K_fd = np.zeros((5, 5))
    for j in range(5):
        h = 1e-6
        e = np.zeros(5)
        e[j] = h
        K_fd[:, j] = -(_array_wrench_printed_eq3(carriage, q0 + e, trim.speed)
                       - _array_wrench_printed_eq3(carriage, q0 - e, trim.speed)) / (2 * h)
    scale = np.abs(np.diag(K))
    for i in range(5):
        for j in range(5):
            tol = 1e-6 * np.sqrt(scale[i] * scale[j]) + 1e-9
            assert abs(K[i, j] - K_fd[i, j]) < tol, (i, j, K[i, j], K_fd[i, j])


def test_linearisation_equals_casadi_ad(carriage: DerivedCarriage, trim) -> None:
    """The chain-rule symbolic Jacobians equal CasADi's AD of the converted model at trim."""
    cm = casadi_model(carriage.model)
    jac = ca.Function("jacobians", [cm.x, cm.u, cm.p],
                      [ca.jacobian(cm.xdot, cm.x), ca.jacobian(cm.xdot, cm.u)])
    A_ad, B_ad = (np.array(m) for m in jac(trim.x, trim.u, carriage.p))
    A, B = carriage.linearize(trim)
    for ours, ref in ((A, A_ad), (B, B_ad)):
        assert np.max(np.abs(ours - ref)) <= 1e-9 * np.max(np.abs(ref))
        nz = np.abs(ref) > 1e-6 * np.max(np.abs(ref))
        assert np.max(np.abs(ours[nz] - ref[nz]) / np.abs(ref[nz])) < 1e-9


def test_casadi_dynamics_equals_lambdified_model(carriage: DerivedCarriage) -> None:
    cm = casadi_model(carriage.model)
    f = ca.Function("f", [cm.x, cm.u, cm.p], [cm.xdot])
    rng = np.random.default_rng(3)
    for _ in range(20):
        x = rng.normal(scale=[1, .003, .003, .02, .02, .02, 5, .1, .1, .1, .1, .1])
        x[6] += 20
        u = rng.normal(scale=10, size=carriage.model.u.shape[0])
        ours = carriage.functions.xdot(x, u, carriage.p)
        ref = np.array(f(x, u, carriage.p)).ravel()
        np.testing.assert_allclose(ours, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())


def test_no_trim_below_lift_off(carriage: DerivedCarriage) -> None:
    v_off = carriage.lift_off_speed()
    assert 0 < v_off < carriage.params.operation.speed
    carriage.trim(1.01 * v_off)  # just above: exists
    with pytest.raises(NoTrimError, match="lift-off needs"):
        carriage.trim(0.99 * v_off)


def test_trim_cli_no_equilibrium_is_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["trim", "--speed", "1.0"]) == 2
    lines = capsys.readouterr().err.splitlines()
    # a cold cache adds "maglevgen: <step>" progress lines before it: one error line, the last
    errors = [ln for ln in lines if ln.startswith("maglevgen: error:")]
    assert errors == lines[-1:] and "no trim at speed 1 m/s" in errors[0]


def test_trim_cli_json_stiffness(capsys: pytest.CaptureFixture[str], carriage: DerivedCarriage,
                                 trim) -> None:
    import json

    assert main(["trim", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    K = carriage.magnetic_stiffness(trim)
    for i, axis in enumerate(cv.AXES):
        assert rep["stiffness"][axis]["derived"] == pytest.approx(K[i, i], rel=1e-12)
    # the printed vertical stiffness 2 m g k, evaluated independently
    prm = carriage.params
    k = 2 * np.pi / prm.halbach.wavelength
    assert rep["stiffness"]["vertical"]["paper"] == pytest.approx(
        2 * prm.vehicle.mass * prm.vehicle.gravity * k, rel=1e-12)


def test_override_changes_trim() -> None:
    heavy = DerivedCarriage(load_params(overrides=["vehicle.mass=10.5"]))
    light = DerivedCarriage(load_params())
    assert heavy.trim().x[2] < light.trim().x[2]  # a heavier carriage rides lower


def test_force_figure_curves_are_eq3_from_the_library(carriage: DerivedCarriage, sim_lib) -> None:
    """The force figure's curves (report.force_curves: the compiled library's array forces at
    zero attitude) against eq 3-4 as printed, written here: lift and drag of one upper array
    per circuit count, against the gap at a speed and against the speed at a gap."""
    from maglevgen.report.sections.force_law import array_force_curves

    prm = carriage.params
    h, c = prm.halbach, prm.circuit
    k = 2 * np.pi / h.wavelength
    M = h.magnets_per_wavelength
    B0 = h.remanence * (1 - np.exp(-k * h.thickness)) * np.sin(np.pi / M) / (np.pi / M)
    upper = next(i for i, a in enumerate(prm.arrays.values()) if a.normal[2] > 0.99)
    arr = list(prm.arrays.values())[upper]
    gaps = np.array([prm.track.min_gap, 0.01, 0.02, 0.05, 0.02, 0.02])
    speeds = np.array([20.0, 20.0, 20.0, 20.0, 0.5, 80.0])
    lift, drag = array_force_curves(Plant(carriage, sim_lib), upper, gaps, speeds)
    ratio = c.resistance / (k * speeds * c.inductance)
    F = (arr.circuits * B0**2 * h.width**2 / (2 * k * c.inductance) / (1 + ratio**2)
         * np.exp(-2 * k * gaps))
    np.testing.assert_allclose(lift, F, rtol=1e-12)
    np.testing.assert_allclose(drag, F * ratio, rtol=1e-12)
