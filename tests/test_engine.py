"""One numeric engine: what `maglevgen trim` and `gains` print comes from the generated C,
and agrees with independent references computed here on the lambdified SymPy model (SciPy's
trim and CARE, the Python closed form, the SymPy allocation, python-control).
"""

from __future__ import annotations

import json

import control
import numpy as np
import pytest
from independent_reference import contact_gaps

from maglevgen.analyses import queries
from maglevgen.carriage import DerivedCarriage
from maglevgen.cli import main
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.symbolic_reference import allocation_matrix, carriage_gains, effectiveness
from maglevgen.derive import conventions as cv
from maglevgen.derive.numeric import magnetic_stiffness, other_stiffness


class _At:
    """A Trim-like pose for derive.numeric's stiffness at an arbitrary state."""

    def __init__(self, x: np.ndarray, f_prop: float, lift: np.ndarray, drag: np.ndarray):
        self.x, self.u, self.lift, self.drag = x, np.array([f_prop]), lift, drag


def _states(trim, n: int = 5) -> list[np.ndarray]:
    rng = np.random.default_rng(20)
    scale = np.array([0, 2e-3, 1e-3, 0.01, 0.01, 0.01, 0.5, 0.05, 0.05, 0.1, 0.1, 0.1])
    return [trim.x + scale * rng.uniform(-1, 1, 12) for _ in range(n)]


def test_array_forces_and_stiffness_in_c_equal_the_lambdified_model(sim_lib,
                                                                    carriage: DerivedCarriage,
                                                                    trim) -> None:
    """maglev_array_forces and maglev_stiffness (new generated functions) against the SymPy
    model lambdified, at the trim and at states around it."""
    p = carriage.p
    for x in [trim.x, *_states(trim)]:
        _, lift_ref, drag_ref = carriage.functions.forces(x, p)
        lift, drag = (a.ravel() for a in sim_lib.function("maglev_array_forces")(x, p))
        np.testing.assert_allclose(lift, lift_ref, rtol=1e-12)
        np.testing.assert_allclose(drag, drag_ref, rtol=1e-12)
        f_prop = 1.7 * trim.u[0]
        at = _At(x, f_prop, lift_ref, drag_ref)
        K_mag, K_oth = sim_lib.function("maglev_stiffness")(x, f_prop, p)
        ref_mag = magnetic_stiffness(carriage.functions, at, p)
        ref_oth = other_stiffness(carriage.functions, at, p)
        np.testing.assert_allclose(K_mag, ref_mag, rtol=1e-10, atol=1e-10 * np.abs(ref_mag).max())
        np.testing.assert_allclose(K_oth, ref_oth, rtol=1e-10, atol=1e-10 * np.abs(ref_oth).max())


def test_trim_json_is_the_c_trim_and_agrees_with_scipy(capsys, carriage: DerivedCarriage,
                                                       trim) -> None:
    assert main(["trim", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    x = np.array([rep["state"][s.name] for s in cv.STATES])
    np.testing.assert_allclose(x, trim.x, rtol=1e-9, atol=1e-12)  # SciPy hybr on SymPy
    assert rep["propulsion_force"] == pytest.approx(trim.u[0], rel=1e-9)
    corners = contact_gaps(carriage.params, trim.x[[1, 2, 3, 4, 5]])
    for i, a in enumerate(rep["arrays"].values()):
        assert a["gap"] == pytest.approx(corners[i], rel=1e-9)  # contact: closest corner
        assert a["lift"] == pytest.approx(trim.lift[i], rel=1e-9)
        assert a["drag"] == pytest.approx(trim.drag[i], rel=1e-9)
    assert rep["residual"] < 1e-8
    K_ref = carriage.magnetic_stiffness(trim)
    np.testing.assert_allclose(rep["stiffness_matrix"], K_ref, rtol=1e-9,
                               atol=1e-9 * np.abs(K_ref).max())
    assert rep["lift_off_speed"] == pytest.approx(carriage.lift_off_speed(), rel=1e-5)


def test_gains_json_is_the_c_and_agrees_with_the_references(capsys, carriage: DerivedCarriage,
                                                            trim) -> None:
    assert main(["gains", "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    (q1, q2), r = carriage.params.control.state_weights, carriage.params.control.input_weight
    for g in carriage_gains(carriage, trim):  # Python closed form on the lambdified plant
        a = rep["axes"][g.axis]
        assert a["stiffness"] == pytest.approx(g.stiffness, rel=1e-9)
        assert a["inertia"] == pytest.approx(g.inertia, rel=1e-12)
        np.testing.assert_allclose(a["K_closed_form"], g.K_closed_form, rtol=1e-8)
        A, B = np.array(a["A"]), np.array(a["B"])
        K_ctl, _, _ = control.lqr(A, B, np.diag([q1, q2]), [[r]])  # python-control
        np.testing.assert_allclose(a["K_closed_form"], np.ravel(K_ctl), rtol=1e-6)
    alloc = rep["allocation"]
    np.testing.assert_allclose(alloc["minimum_norm"], allocation_matrix(carriage), atol=1e-12)
    np.testing.assert_allclose(alloc["effectiveness"], effectiveness(carriage), atol=1e-12)
    from maglevgen.control.symbolic_reference import coupled_comparison

    cc = coupled_comparison(carriage, trim, carriage_gains(carriage, trim))
    for key, ref in (("poles_per_axis_design", cc.poles_per_axis),
                     ("poles_coupled_lqr", cc.poles_coupled), ("poles_damping", cc.poles_damping)):
        got = np.array([complex(*z) for z in rep["coupled"][key]])
        np.testing.assert_allclose(np.sort_complex(got), np.sort_complex(ref), rtol=1e-6,
                                   atol=1e-9)
    assert rep["coupled"]["cost_coupled_lqr"] == pytest.approx(cc.cost_coupled, rel=1e-7)
    if np.isfinite(cc.cost_per_axis):
        assert rep["coupled"]["cost_per_axis_design"] == pytest.approx(cc.cost_per_axis,
                                                                       rel=1e-7)
    else:  # unbounded (the per-axis design does not stabilise the coupled model): JSON null
        assert rep["coupled"]["cost_per_axis_design"] is None


def test_trim_and_gains_never_use_the_lambdified_model(monkeypatch, sim_lib) -> None:
    """The data `trim` and `gains` print is computed without DerivedCarriage.functions (the
    lambdified SymPy model, now a reference only)."""
    from maglevgen.params import load_params

    fresh = DerivedCarriage(load_params(overrides=["vehicle.mass=9.7"]))

    def forbidden(self):
        raise AssertionError("the lambdified model was used")

    monkeypatch.setattr(DerivedCarriage, "functions", property(forbidden))
    monkeypatch.setattr(DerivedCarriage, "trim", forbidden)
    t = queries.trim_report(Plant(fresh, sim_lib), None)
    g = queries.gains_report(Plant(fresh, sim_lib), None)
    assert t["speed"] == g["speed"] == fresh.params.operation.speed
    assert set(g["axes"]) == set(cv.AXES)


def test_no_trim_names_the_lift_off_speed(sim_lib, carriage: DerivedCarriage) -> None:
    from maglevgen.errors import NoTrimError

    v_off = carriage.lift_off_speed()  # SciPy on the lambdified model: the reference
    with pytest.raises(NoTrimError, match=r"^no trim at speed 1 m/s: .*lift-off needs ") as err:
        queries.trim_point(Plant(carriage, sim_lib), 1.0)
    assert float(str(err.value).rsplit("needs ", 1)[1].split()[0]) == pytest.approx(v_off,
                                                                                    rel=1e-3)


def test_report_stiffness_and_trim_are_the_librarys(monkeypatch, sim_lib) -> None:
    """The report's trim, stiffness, A matrix and generalized masses are the compiled
    library's numbers (bit for bit: the lambdified model and SciPy's trim differ from them in
    the last digits) and agree with those references, computed here first; building the
    report's context (the verification's reference rows off) never touches the lambdified
    model."""
    from maglevgen import report as rp
    from maglevgen.derive.numeric import total_stiffness
    from maglevgen.params import load_params

    fresh = DerivedCarriage(load_params(overrides=["vehicle.mass=9.7"]))
    ref_trim = fresh.trim()  # SciPy on the lambdified model: the references
    K_ref = total_stiffness(fresh.functions, ref_trim, fresh.p)
    A_ref, _ = fresh.linearize(ref_trim)
    M_ref = fresh.generalized_mass()

    def forbidden(self, *_a):
        raise AssertionError("the report used the lambdified model")

    monkeypatch.setattr(DerivedCarriage, "functions", property(forbidden))
    for name in ("trim", "linearize", "magnetic_stiffness", "total_stiffness",
                 "generalized_mass", "lift_off_speed"):
        monkeypatch.setattr(DerivedCarriage, name, forbidden)
    ctx, _ = rp.build_context(fresh, rp.ReportOptions(verify_c=False, build_pdf=False))

    tp = queries.trim_point(Plant(fresh, sim_lib), None)
    assert ctx["trim"]["values"] == tp.x.tolist()
    assert ctx["trim"]["F_prop"] == tp.f_prop
    np.testing.assert_allclose(tp.x, ref_trim.x, rtol=1e-9, atol=1e-12)
    K_tot = tp.K_magnetic + tp.K_other
    for i, row in enumerate(ctx["stiffness"]["rows"]):
        assert (row["derived"], row["total"]) == (tp.K_magnetic[i, i], K_tot[i, i]), row["axis"]
    np.testing.assert_allclose(np.diag(K_tot), np.diag(K_ref), rtol=1e-8)
    _, m = (a.ravel() for a in sim_lib.function("maglev_axis_plants")(tp.speed, fresh.p))
    assert ctx["stiffness"]["mass_values"] == m.tolist()
    np.testing.assert_allclose(m, M_ref, rtol=1e-12)
    jac = sim_lib.function("maglev_jacobians")
    u = np.zeros(jac.shapes_in[1][0])
    u[0] = tp.f_prop
    A, _ = jac(tp.x, u, fresh.p)
    shown = [float(A[i, j]) for i in range(12) for j in range(12)
             if abs(A[i, j]) > 1e-13 * np.abs(A).max()]  # the section's nonzero entries
    # each entry: (row, column, value, unit)
    assert [entry[2] for entry in ctx["stiffness"]["A_entries"]] == shown
    np.testing.assert_allclose(A, A_ref, rtol=1e-7, atol=1e-7 * np.abs(A_ref).max())
