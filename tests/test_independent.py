"""Every derived number against a reference written in the tests (independent_reference.py).

The trim against a root solve of eq 3 and the static balance; the full axis stiffness (array
forces, gravity and propulsion moments) against central differences; the axis plants, gains
and damping against the hand-solved Riccati equation in mpmath and a numerical ISE minimum;
the closed-form gains by evaluating the very SymPy expression the C is generated from, in
float64 and float32, on both branches of its stable form.
"""

from __future__ import annotations

from pathlib import Path

import mpmath
import numpy as np
import pytest
import sympy as sp
from independent_reference import (
    array_loads,
    array_state,
    contact_gaps,
    external_wrench,
    generalized_mass,
    ise_optimal_damping,
    lqr_reference_mp,
    reference_trim,
    rotation,
    stiffness_fd,
    symmetric_lift_off_speed,
    zero_attitude_lift_off_bound,
)

from maglevgen.carriage import DerivedCarriage
from maglevgen.control.symbolic_reference import axis_plants, carriage_gains
from maglevgen.derive import conventions as cv
from maglevgen.derive.riccati import lqr_gain_mp, riccati_stable_form
from maglevgen.params import Parameters, default_params_path, load_params

SPEEDS = (20.0, 45.0)


# Both force laws, the point law first: its model derives in seconds, so a mutant of derive/
# that a reference here catches fails fast under `pytest -x` (make mutation).
LAWS = ("point", "distributed")


@pytest.fixture(scope="module", params=LAWS, ids=[f"{law}law" for law in LAWS])
def law_carriage(request: pytest.FixtureRequest) -> DerivedCarriage:
    """The default carriage with each force law (model.array_force)."""
    return DerivedCarriage(load_params(overrides=[f'model.array_force="{request.param}"']))


@pytest.fixture(scope="module")
def heavy(law_carriage: DerivedCarriage) -> DerivedCarriage:
    """A second carriage: heavier, CG further off O (a larger gravity stiffness)."""
    return DerivedCarriage(load_params(overrides=[
        "vehicle.mass=10.5", "vehicle.cg_offset=[0.02, 0.0, 0.03]",
        f'model.array_force="{law_carriage.params.model.array_force}"']))


def _q(trim) -> np.ndarray:
    return np.array([trim.x[cv.STATE_INDEX[s]] for s in cv.Q_STATES])


def _cases(carriage: DerivedCarriage, heavy: DerivedCarriage):
    return [(c, v) for c in (carriage, heavy) for v in SPEEDS]


def _assert_stiffness(K: np.ndarray, K_ref: np.ndarray, rel: float = 1e-6) -> None:
    """Entrywise, relative to the geometric mean of the diagonal scales of row and column."""
    scale = np.abs(np.diag(K_ref))
    for i in range(5):
        for j in range(5):
            tol = rel * np.sqrt(scale[i] * scale[j]) + 1e-9
            assert abs(K[i, j] - K_ref[i, j]) < tol, (i, j, K[i, j], K_ref[i, j])


def test_trim_equals_root_of_eq3_and_static_balance(law_carriage: DerivedCarriage,
                                                    heavy: DerivedCarriage) -> None:
    """Pose, propulsion and every array's gap, lift and drag against the root found here."""
    for c, v in _cases(law_carriage, heavy):
        trim, ref = c.trim(v), reference_trim(c.params, v)
        np.testing.assert_allclose(_q(trim), ref.q, rtol=0, atol=1e-10)
        assert trim.u[0] == pytest.approx(ref.f_prop, rel=1e-9)
        assert ref.f_prop > 0  # the drag opposes the motion: propulsion pushes forward
        np.testing.assert_allclose(trim.gaps, ref.arrays.gaps, rtol=0, atol=1e-10)
        np.testing.assert_allclose(trim.lift, ref.arrays.lift, rtol=1e-9)
        np.testing.assert_allclose(trim.drag, ref.arrays.drag, rtol=1e-9)
        # the trim state moves at the speed along the track (inertial x)
        assert trim.x[0] == 0 and np.linalg.norm(trim.x[6:9]) == pytest.approx(v, rel=1e-12)


ACCELERATIONS = (5.0, -3.0)  # m/s^2: the default launch, and braking


def test_accelerating_trim_equals_root_of_static_balances_with_dalembert_load(
        law_carriage: DerivedCarriage, heavy: DerivedCarriage) -> None:
    """The accelerating trim, in C (maglev_trim_accelerating, checked) and by derive/trim.py,
    against the root of the six static balances with the d'Alembert load -m a e_x at the CG
    solved here (independent_reference): pose, propulsion and every array's gap, lift and
    drag; along the track F_prop = drag + m a; accelerating pitches nose down (braking nose
    up) by several mrad from the constant-speed trim: the CG sits above the thrust's line."""
    from maglevgen.control.operating import checked_accelerating_trim
    from maglevgen.derive.trim import solve_trim
    from maglevgen.runtime.library import simulation_library

    lib = simulation_library(law_carriage.structure)  # heavy has the same structure
    for c, v in _cases(law_carriage, heavy):
        min_gap, mass = c.params.track.min_gap, c.params.vehicle.mass
        still = reference_trim(c.params, v)
        for a in ACCELERATIONS:
            ref = reference_trim(c.params, v, a)
            x, f_prop, gaps = checked_accelerating_trim(lib, c.p, v, a, min_gap)
            lift, drag = (f.ravel() for f in lib.function("maglev_array_forces")(x, c.p))
            tr = solve_trim(c.functions, c.p, v, min_gap, acceleration=a)
            for q, fp, fl, fd in ((x[1:6], f_prop, lift, drag),
                                  (_q(tr), tr.u[0], tr.lift, tr.drag)):
                np.testing.assert_allclose(q, ref.q, rtol=0, atol=1e-10)
                assert fp == pytest.approx(ref.f_prop, rel=1e-9)
                np.testing.assert_allclose(fl, ref.arrays.lift, rtol=1e-9)
                np.testing.assert_allclose(fd, ref.arrays.drag, rtol=1e-9)
            np.testing.assert_allclose(gaps, contact_gaps(c.params, ref.q), rtol=0, atol=1e-10)
            assert ref.f_prop == pytest.approx(ref.arrays.drag.sum() + mass * a, rel=1e-9)
            assert np.sign(a) * (ref.q[3] - still.q[3]) < -1e-3  # rad
            # the trim state translates at v along the track, unrotated
            assert np.linalg.norm(x[6:9]) == pytest.approx(v, rel=1e-12)
            assert np.all(x[9:12] == 0) and x[0] == 0


def test_accelerating_trim_at_zero_acceleration_is_the_constant_speed_trim(
        law_carriage: DerivedCarriage) -> None:
    """maglev_trim_accelerating(v, 0) gives maglev_trim(v) (to 1e-12: the same Newton
    iterations on the same residual), both at the test's root of the static balances."""
    from maglevgen.runtime.library import simulation_library

    lib = simulation_library(law_carriage.structure)
    for v in (7.0, *SPEEDS):
        x0, f0 = (a.ravel() for a in lib.function("maglev_trim")(v, law_carriage.p))
        xa, fa = (a.ravel() for a in lib.function("maglev_trim_accelerating")(
            v, 0.0, law_carriage.p))
        np.testing.assert_allclose(xa, x0, rtol=0, atol=1e-12)
        assert fa[0] == pytest.approx(f0[0], rel=1e-12)
        np.testing.assert_allclose(xa[1:6], reference_trim(law_carriage.params, v).q, rtol=0,
                                   atol=1e-10)


def test_trim_of_an_asymmetric_carriage_equals_root_of_eq3_and_static_balance() -> None:
    """CG 1 cm to the side: the equilibrium rolls and yaws (a symmetric carriage's trim has
    zero roll and yaw, where the yaw's terms of the trim state's velocity vanish)."""
    c = DerivedCarriage(load_params(overrides=["vehicle.cg_offset=[0.005, 0.01, 0.015]"]))
    for v in SPEEDS:
        trim, ref = c.trim(v), reference_trim(c.params, v)
        assert min(abs(ref.q[2]), abs(ref.q[4])) > 1e-6  # rolled and yawed
        np.testing.assert_allclose(_q(trim), ref.q, rtol=0, atol=1e-10)
        assert trim.u[0] == pytest.approx(ref.f_prop, rel=1e-9)
        np.testing.assert_allclose(trim.lift, ref.arrays.lift, rtol=1e-9)
        assert np.linalg.norm(trim.x[6:9]) == pytest.approx(v, rel=1e-12)


def test_heave_range_equals_gap_limits_written_here(law_carriage: DerivedCarriage,
                                                    heavy: DerivedCarriage) -> None:
    """The trim's heave bracket: at zero attitude each gap is linear in z (slope n_z, from the
    reference gaps at z = 0 and 1 mm); the range keeping every gap >= track.min_gap, solved
    here, is the one the solver brackets the vertical balance in."""
    for c in (law_carriage, heavy):
        _assert_heave_range(c)


def test_heave_range_with_tilted_upper_arrays_equals_gap_limits_written_here() -> None:
    """Arrays 3 and 6 tilted 11 degrees about x: the slope of their gaps in heave is 0.98, not
    1, where dividing the gap margin by the slope and multiplying by it would agree."""
    _assert_heave_range(DerivedCarriage(load_params(overrides=[
        'model.array_force="point"', "arrays.3.normal=[0.0, 0.2, 1.0]",
        "arrays.6.normal=[0.0, -0.2, 1.0]"])))


def _reference_heave_range(prm: Parameters, speed: float) -> tuple[float, float]:
    """Heave range keeping every gap >= track.min_gap at zero attitude: each gap is linear in
    z, its slope taken from the reference gaps at z = 0 and 1 mm."""
    g0 = array_state(prm, np.zeros(5), speed).gaps
    slope = (array_state(prm, np.array([0, 1e-3, 0, 0, 0]), speed).gaps - g0) / 1e-3
    bounds = (prm.track.min_gap - g0) / slope
    return bounds[slope > 0].max(), bounds[slope < 0].min()


def _array_lift_at_heave_limit(prm: Parameters, speed: float, limit: str) -> float:
    """The arrays' net vertical force (eq 3's sums) at zero attitude, the heave at its
    "lower" or "upper" limit."""
    z = _reference_heave_range(prm, speed)[("lower", "upper").index(limit)]
    return float(external_wrench(prm, np.array([0.0, z, 0, 0, 0]), speed, 0.0, other=False)[2])


def _assert_heave_range(c: DerivedCarriage) -> None:
    from maglevgen.derive.trim import _heave_limits

    np.testing.assert_allclose(_heave_limits(c.functions, c.p, c.params.track.min_gap),
                               _reference_heave_range(c.params, c.params.operation.speed),
                               rtol=0, atol=1e-12)


LOW_RESISTANCE = Path(__file__).parent / "data" / "carriage_low_resistance.toml"
# pitched nose-up at low speed: the CG far aft and the propulsion well below the arrays' drag
PITCHED = ("vehicle.cg_offset=[-0.22, 0.0, 0.015]", "operation.propulsion_point=[0.0, 0.0, -0.3]")


@pytest.mark.parametrize("overrides", [(), PITCHED], ids=["low-resistance", "pitched"])
def test_lift_off_speed_equals_reference_below_1_m_s_and_after_doubling(
        overrides: tuple[str, ...]) -> None:
    """The lift-off search of derive/trim.py against the continuation and Brent solve written
    here (symmetric_lift_off_speed), on a carriage of a parameter file of its own: a tenth of
    the loop resistance puts the zero-attitude bound below 1 m/s (the search's bracket must
    start below it); pitched, the lift-off is more than twice that bound (the search must
    double its upper end before it bisects)."""
    c = DerivedCarriage(load_params(LOW_RESISTANCE, overrides=list(overrides)))
    bound = zero_attitude_lift_off_bound(c.params)
    ref = symmetric_lift_off_speed(c.params, v_start=8 * bound)
    if overrides:  # the premise: no trim at twice the bound, so the search doubles
        assert ref > 2 * bound
    else:  # the premise: the search's bracket must start below 1 m/s
        assert bound < ref < 1.0
    assert c.lift_off_speed() == pytest.approx(ref, rel=2e-6)


def test_no_lift_off_when_the_lift_at_the_search_limit_is_short_of_the_weight() -> None:
    """A carriage 0.5 N heavier than the arrays' vertical force at the lift-off search's upper
    speed (10^4 m/s, zero attitude, heave at its lower gap limit; eq 3's sums written here):
    no speed up to that limit holds it, so the lowest speed with an equilibrium is inf."""
    law = 'model.array_force="point"'
    prm = load_params(overrides=[law]).params
    lift = _array_lift_at_heave_limit(prm, 1e4, "lower")
    mass = float((lift + 0.5) / prm.vehicle.gravity)
    c = DerivedCarriage(load_params(overrides=[law, f"vehicle.mass={mass!r}"]))
    assert c.lift_off_speed() == float("inf")


@pytest.mark.parametrize("speed", [0.0, -0.5, -1e-9, float("nan")])
def test_trim_refuses_a_speed_that_is_not_positive(speed: float) -> None:
    """The trim is asked for a speed along +x only: zero, a negative or a NaN speed is refused
    before any solve, saying so (a slow negative speed would otherwise reach the lift-off
    search, whose error names a cause that is not the input's)."""
    from maglevgen.derive.trim import NoTrimError, solve_trim

    c = DerivedCarriage(load_params(overrides=['model.array_force="point"']))
    with pytest.raises(NoTrimError, match=r"^operation\.speed = .*: must be > 0$"):
        solve_trim(c.functions, c.p, speed, c.params.track.min_gap)


def test_no_trim_below_the_zero_attitude_bound_names_the_lift_off_speed() -> None:
    """Below the zero-attitude bound (eq 3's vertical balance, written here) the arrays cannot
    lift the carriage, also a hair below it (the net force short of the weight by less than
    1 N); the error names the lift-off speed, equal to the continuation and Brent solve
    written here to the 4 digits printed. A hair above the bound they do lift it."""
    from maglevgen.derive.trim import NoTrimError, solve_trim

    c = DerivedCarriage(load_params(overrides=['model.array_force="point"']))
    prm = c.params
    bound = zero_attitude_lift_off_bound(prm)
    ref = symmetric_lift_off_speed(prm, v_start=8 * bound)

    def net_up(speed: float) -> float:
        weight = prm.vehicle.mass * prm.vehicle.gravity
        return _array_lift_at_heave_limit(prm, speed, "lower") - weight

    for speed in (0.5 * bound, (1 - 1e-4) * bound):
        assert net_up(speed) < 0  # the premise
        with pytest.raises(NoTrimError, match="cannot lift the carriage off the track") as err:
            solve_trim(c.functions, c.p, speed, prm.track.min_gap)
        named = float(str(err.value).rsplit("lift-off needs ", 1)[1].split()[0])
        assert named == pytest.approx(ref, rel=1e-3)
    assert net_up((1 - 1e-4) * bound) > -1  # a hair below: short of the weight by < 1 N
    # a hair above, the arrays lift it (by < 1 N): pitched, the corners may still touch, but
    # the error must not say the arrays cannot lift it
    assert 0 < net_up((1 + 1e-4) * bound) < 1
    with pytest.raises(NoTrimError) as err:
        solve_trim(c.functions, c.p, (1 + 1e-4) * bound, prm.track.min_gap)
    assert "cannot lift" not in str(err.value)


def test_upper_contact_is_blamed_only_when_the_arrays_push_up_there(tmp_path: Path) -> None:
    """A 10 g carriage at 0.2 m/s: at the top of the heave range (the lower arrays at
    track.min_gap) the net vertical force, eq 3's sums and the weight written here, is
    downward by less than 1 N. The lift does not push the lower arrays into the track, so
    whatever the solver concludes, it must not give that as the reason; and an equilibrium it
    returns must balance (here the solver stalls, residual 0.5 m/s^2: it must say so)."""
    from maglevgen.derive.trim import NoTrimError, solve_trim

    text = default_params_path().read_text()
    text = text.replace("\nmass = 9.3\n", "\nmass = 0.01\n").replace(
        '"vehicle.mass" = { normal = 0.3 }', '"vehicle.mass" = { normal = 0.001 }')
    light = tmp_path / "carriage_light.toml"
    light.write_text(text)
    c = DerivedCarriage(load_params(light, overrides=['model.array_force="point"']))
    prm, speed = c.params, 0.2
    assert prm.vehicle.mass == 0.01
    net = (_array_lift_at_heave_limit(prm, speed, "upper")
           - prm.vehicle.mass * prm.vehicle.gravity)
    assert -1.0 < net < 0.0  # the premise: downward, within 1 N of balance
    try:
        trim = solve_trim(c.functions, c.p, speed, prm.track.min_gap)
    except NoTrimError as err:
        assert "into the track" not in str(err)
    else:  # an equilibrium returned must be one: eqs 1-3's static balance, written here
        weight = prm.vehicle.mass * prm.vehicle.gravity
        balance = external_wrench(prm, _q(trim), speed, float(trim.u[0]))
        assert np.abs(balance).max() < 1e-6 * weight


def test_lift_off_found_when_the_lift_at_the_search_limit_exceeds_the_weight_by_half_a_newton(
        ) -> None:
    """The search limit's other edge: at v_max the arrays' vertical force (zero attitude,
    heave at its lower gap limit; eq 3's sums written here) exceeds the weight by 0.5 N. The
    carriage has its CG on O and its propulsion at the height of the drag there (written
    here), so its equilibrium at v_max has no pitch and clears every gap: the search must
    return the lift-off speed, equal to the continuation and Brent solve written here."""
    import scipy.optimize

    from maglevgen.derive.trim import lift_off_speed

    level = ['model.array_force="point"', "vehicle.cg_offset=[0.0, 0.0, 0.0]"]
    prm = load_params(overrides=level).params
    weight = prm.vehicle.mass * prm.vehicle.gravity
    v_max = scipy.optimize.brentq(
        lambda v: _array_lift_at_heave_limit(prm, v, "lower") - weight - 0.5, 1e-3, 1e3,
        xtol=1e-14, rtol=1e-14)
    st = array_state(prm, np.array([0.0, _reference_heave_range(prm, v_max)[0], 0, 0, 0]),
                     v_max)
    z_prop = float(st.drag @ st.arms[:, 2] / st.drag.sum())  # no drag pitch moment
    c = DerivedCarriage(load_params(overrides=[
        *level, f"operation.propulsion_point=[0.0, 0.0, {z_prop!r}]"]))
    ref = symmetric_lift_off_speed(c.params, v_start=v_max)  # asserts a lift-off at v_max
    assert lift_off_speed(c.functions, c.p, c.params.track.min_gap, v_max=v_max) == (
        pytest.approx(ref, rel=2e-6))


def test_lift_at_the_top_of_the_heave_range_pushes_the_lower_arrays_into_the_track(
        tmp_path: Path) -> None:
    """A carriage with weak lower arrays (1 circuit each, 4 mm from the track) at 10 m/s whose
    weight is 0.5 N short of the arrays' vertical force at the top of the heave range (the
    lower arrays at track.min_gap; eq 3's sums written here): nothing holds it down, so there
    is no equilibrium, and the trim gives that reason with that net force, not a solver
    error."""
    from maglevgen.derive.trim import NoTrimError, solve_trim

    weak = ['model.array_force="point"', *(f"arrays.{i}.{key}"
                                            for i in (1, 2, 4, 5)
                                            for key in ("circuits=1", "nominal_gap=0.004"))]
    prm, speed = load_params(overrides=weak).params, 10.0
    mass = (_array_lift_at_heave_limit(prm, speed, "upper") - 0.5) / prm.vehicle.gravity
    assert 0 < mass < prm.vehicle.mass  # the premise: a lighter carriage, still a carriage
    light = tmp_path / "carriage_light.toml"  # the mass tolerance scaled to the mass
    light.write_text(default_params_path().read_text().replace(
        '"vehicle.mass" = { normal = 0.3 }', '"vehicle.mass" = { normal = 0.03 }'))
    c = DerivedCarriage(load_params(light, overrides=[*weak, f"vehicle.mass={mass!r}"]))
    assert c.params.tolerances != prm.tolerances
    with pytest.raises(NoTrimError, match=r"into the track \(net vertical force 0\.5 N at"):
        solve_trim(c.functions, c.p, speed, c.params.track.min_gap)


def test_full_axis_stiffness_equals_central_difference(law_carriage: DerivedCarriage,
                                                       heavy: DerivedCarriage) -> None:
    """K_st0 + gravity and propulsion terms = -dW/dq of every external force (5x5)."""
    for c, v in _cases(law_carriage, heavy):
        trim = c.trim(v)
        q0, fp = _q(trim), float(trim.u[0])
        _assert_stiffness(c.total_stiffness(trim), stiffness_fd(c.params, q0, v, fp))
        _assert_stiffness(c.magnetic_stiffness(trim),
                          stiffness_fd(c.params, q0, v, fp, other=False))


def test_gravity_and_propulsion_stiffness_equals_central_difference(
        law_carriage: DerivedCarriage, heavy: DerivedCarriage) -> None:
    """The K_other part alone: its own scale, so a sign error cannot hide in the magnetic one."""
    from maglevgen.derive.numeric import other_stiffness

    for c, v in _cases(law_carriage, heavy):
        trim = c.trim(v)
        K = other_stiffness(c.functions, trim, c.p)
        K_fd = stiffness_fd(c.params, _q(trim), v, float(trim.u[0]), magnetic=False)
        weight_arm = c.params.vehicle.mass * c.params.vehicle.gravity * 0.01
        assert np.max(np.abs(K_fd)) > weight_arm  # not a vacuous comparison of zeros
        np.testing.assert_allclose(K, K_fd, rtol=0, atol=1e-7 * np.max(np.abs(K_fd)))


def test_design_pose_stiffness_equals_central_difference(law_carriage: DerivedCarriage) -> None:
    """The closed form the report prints beside eqs 13-19 (K_st0 at zero attitude, in the
    arrays' lift and drag symbols) with eq 3's lift and drag at the design pose (written here)
    against central differences of the arrays' force sum there."""
    from maglevgen.derive.linearize import design_pose_stiffness

    c, speed = law_carriage, SPEEDS[0]
    m, st = c.model, array_state(c.params, np.zeros(5), speed)
    values = {**dict(zip(m.p, c.p, strict=True)), **dict(zip(m.lift_sym, st.lift, strict=True)),
              **dict(zip(m.drag_sym, st.drag, strict=True))}
    K = design_pose_stiffness(m.structure).xreplace(
        {s: sp.Float(float(v)) for s, v in values.items()})
    _assert_stiffness(np.array(K.evalf(), dtype=float),
                      stiffness_fd(c.params, np.zeros(5), speed, 0.0, other=False))


def test_axis_plants_and_gains_equal_references(law_carriage: DerivedCarriage,
                                                heavy: DerivedCarriage) -> None:
    """(k, m) of each axis, its LQR gain (mpmath, by hand) and damping (numerical ISE minimum)."""
    for c in (law_carriage, heavy):
        trim = c.trim()
        K_fd = stiffness_fd(c.params, _q(trim), trim.speed, float(trim.u[0]))
        M = generalized_mass(c.params)
        plants = axis_plants(c, trim)
        gains = carriage_gains(c, trim)
        w = c.params.control
        for i, ((axis, k, m), g) in enumerate(zip(plants, gains, strict=True)):
            assert axis == g.axis == cv.AXES[i]
            assert k == pytest.approx(K_fd[i, i], rel=1e-6)
            assert g.stiffness == pytest.approx(K_fd[i, i], rel=1e-6)
            assert m == pytest.approx(M[i], rel=1e-13)
            assert g.inertia == pytest.approx(M[i], rel=1e-13)
            K_ref, P_ref = lqr_reference_mp(k, m, *w.state_weights, w.input_weight)
            np.testing.assert_allclose(np.ravel(g.K_closed_form), [float(x) for x in K_ref],
                                       rtol=1e-13)
            np.testing.assert_allclose(g.P_closed_form, np.array(P_ref.tolist(), dtype=float),
                                       rtol=1e-13)
            if k > 0:
                assert g.damping_gain == pytest.approx(ise_optimal_damping(k, m), rel=1e-5)
            else:
                assert g.damping_gain is None


@pytest.mark.needs_cc
def test_generated_c_operating_point_equals_references(carriage: DerivedCarriage, op,
                                                       sim_lib) -> None:
    """The compiled C's trim, axis plants, gains and damping against the references here."""
    v = carriage.params.operation.speed
    ref = reference_trim(carriage.params, v)
    np.testing.assert_allclose(op.x_trim[[cv.STATE_INDEX[s] for s in cv.Q_STATES]], ref.q,
                               rtol=0, atol=1e-10)
    assert op.f_prop == pytest.approx(ref.f_prop, rel=1e-9)
    # the C's gaps are each face's closest corner (contact)
    np.testing.assert_allclose(np.ravel(op.gaps), contact_gaps(carriage.params, ref.q), rtol=0,
                               atol=1e-10)
    k, m = (np.ravel(a) for a in sim_lib.function("maglev_axis_plants")(v, carriage.p))
    K_fd = np.diag(stiffness_fd(carriage.params, ref.q, v, ref.f_prop))
    M = generalized_mass(carriage.params)
    np.testing.assert_allclose(k, K_fd, rtol=1e-6)
    np.testing.assert_allclose(m, M, rtol=1e-13)
    w = carriage.params.control
    for i in range(5):
        K_ref, _ = lqr_reference_mp(k[i], m[i], *w.state_weights, w.input_weight)
        np.testing.assert_allclose(op.K[i], [float(x) for x in K_ref], rtol=1e-12)
        if k[i] > 0:
            assert op.c_damping[i] == pytest.approx(ise_optimal_damping(k[i], m[i]), rel=1e-5)
        else:
            assert op.c_damping[i] == 0


# --- the closed-form gains: the very expressions the C is generated from --------------------

# (k, m, q1, q2, r) on both sides of k = 0, with |k| up to 1e7 so that the wrong branch of the
# stable form cancels catastrophically (sigma - k for k >> 0, sigma + k for k << 0).
GAIN_POINTS = [(s * k, m, q1, 1.0, r) for s in (1, -1) for k in (1e-3, 0.7, 40.0, 3e3, 1e7)
               for m in (1e-3, 9.3, 1e4) for q1, r in ((1.0, 1.0), (4.0, 0.01))]
# |k| < 1 with a small q1/r: the wrong branch cancels there too (the switch is at k = 0, not 1).
GAIN_POINTS += [(s * k, 9.3, 1e-6, 1.0, 1.0) for s in (1, -1) for k in (0.3, 0.7)]


@pytest.fixture(scope="module")
def stable_gain_functions():
    """K = (K1, K2) of riccati_stable_form (a Piecewise on k >= 0), lambdified as generated."""
    k, m = sp.Symbol("k", real=True), sp.Symbol("m", positive=True)
    w = sp.symbols("q1 q2 r", positive=True)
    stable = riccati_stable_form(k, m, *w)  # codegen/functions.py converts exactly this K
    return (sp.lambdify((k, m, *w), list(stable.K), "numpy"),
            sp.lambdify((k, m, *w), stable.P.tolist(), "mpmath"))


@pytest.mark.parametrize("dtype, rtol", [(np.float64, 8e-15), (np.float32, 4e-6)])
def test_stable_form_gains_equal_mpmath_reference(stable_gain_functions, dtype, rtol) -> None:
    f_K, _ = stable_gain_functions
    worst = 0.0
    for pt in GAIN_POINTS:
        with np.errstate(divide="ignore"):  # numpy.select evaluates the unused branch too
            K = np.array(f_K(*(dtype(x) for x in pt)))
        assert K.dtype == dtype, pt  # evaluated in that precision, no float64 constant
        K_ref, _ = lqr_reference_mp(*pt)
        with mpmath.workdps(30):
            err = max(float(abs(mpmath.mpf(float(a)) - b) / b)
                      for a, b in zip(K, K_ref, strict=True))
        assert err < rtol, (pt, K, [float(x) for x in K_ref])
        worst = max(worst, err)
    assert worst > 0 or dtype is np.float64  # float32 rounding shows: the check is live


def test_stable_form_riccati_solution_equals_mpmath_reference(stable_gain_functions) -> None:
    _, f_P = stable_gain_functions
    with mpmath.workdps(60):
        for pt in GAIN_POINTS:
            P = mpmath.matrix(f_P(*(mpmath.mpf(x) for x in pt)))
            _, P_ref = lqr_reference_mp(*pt)
            assert mpmath.mnorm(P - P_ref, "inf") <= mpmath.mpf(10) ** -40 * \
                mpmath.mnorm(P_ref, "inf"), pt


def test_closed_form_mpmath_gain_equals_hand_solution() -> None:
    """lqr_gain_mp (the reference the accuracy sweep uses) against the hand-solved ARE; also
    at k = 0 exactly (a neutral axis: no cancellation, and no digits to guard)."""
    for pt in [*GAIN_POINTS[::3], (0.0, 9.3, 1.0, 1.0, 1.0), (0.0, 0.4, 3e3, 2.0, 1e-2)]:
        K = lqr_gain_mp(*pt, dps=40)
        K_ref, _ = lqr_reference_mp(*pt)
        for a, b in zip(K, K_ref, strict=True):
            assert abs(a - b) <= mpmath.mpf(10) ** -38 * abs(b), pt


def test_reference_wrench_balances_at_the_reference_trim(law_carriage: DerivedCarriage) -> None:
    """The reference's own root really is an equilibrium, and not the trivial one."""
    prm = law_carriage.params
    ref = reference_trim(prm, 20.0)
    w = external_wrench(prm, ref.q, 20.0, ref.f_prop)
    assert np.max(np.abs(w)) < 1e-9 * prm.vehicle.mass * prm.vehicle.gravity
    assert ref.arrays.lift.sum() > prm.vehicle.mass * prm.vehicle.gravity  # lower arrays pull


def test_each_control_input_pushes_along_its_axis_at_its_array(
        law_carriage: DerivedCarriage) -> None:
    """The model's wrench (eqs 8-12 with eqs 22-23's inputs): setting one control input to 1 N
    adds, in body axes, a unit force along that input's body axis at its array's face centre
    and its moment about O, built here by numpy cross products (at the trim pose)."""
    _assert_unit_inputs(law_carriage)


def test_each_normal_actuator_pushes_along_its_arrays_unit_normal() -> None:
    """control.actuators = "normal": one input per array, a force along its unit normal."""
    _assert_unit_inputs(DerivedCarriage(load_params(overrides=[
        'model.array_force="point"', 'control.actuators="normal"'])))


def _assert_unit_inputs(c: DerivedCarriage) -> None:
    x = c.trim().x
    u0 = np.zeros(c.functions.model.u.shape[0])
    base = np.ravel(c.functions.body_wrench(x, u0, c.p))
    j = 1
    for arr, (_, comps) in zip(c.params.arrays.values(), c.structure.arrays, strict=True):
        for ax in comps:
            u = u0.copy()
            u[j] = 1.0
            n = np.asarray(arr.normal, dtype=float)
            d = n / np.linalg.norm(n) if ax == "n" else np.eye(3)["xyz".index(ax)]
            expected = np.concatenate([d, np.cross(arr.position, d)])
            np.testing.assert_allclose(np.ravel(c.functions.body_wrench(x, u, c.p)) - base,
                                       expected, rtol=0, atol=1e-9)
            j += 1
    assert j == u0.size  # every input checked


def test_array_speed_includes_the_body_rates(law_carriage: DerivedCarriage) -> None:
    """Each array's along-track speed is (R (v + w x a_i))_x: at the trim pose with body rates
    and a sideways body velocity, every array's gap equals the reference's, and its lift and
    drag equal eq 3's at that speed (array_state, one array at a time, the speed built here
    with numpy) times the circuits' lag of the moving gaps (array_loads: the same circuit sum
    with each circuit's rate term, model.circuit_dynamics = "first-order")."""
    c = law_carriage
    assert c.params.model.circuit_dynamics == "first-order"
    x = c.trim().x.copy()
    x[7:9] += (0.4, -0.1)  # body velocity
    omega = np.array([0.6, -0.9, 1.2])  # rad/s: moves the arrays by up to about 0.3 m/s
    x[9:12] = omega
    q = x[1:6]
    R = rotation(*q[2:5])
    gaps, lift, drag = (np.ravel(a) for a in c.functions.forces(x, c.p))
    quasi_static, lagged = (array_loads(c.params, x, lag) for lag in (False, True))
    for i, arr in enumerate(c.params.arrays.values()):
        speed = float((R @ (x[6:9] + np.cross(omega, arr.position)))[0])
        ref = array_state(c.params, q, speed)
        assert gaps[i] == pytest.approx(ref.gaps[i], abs=1e-12)
        assert quasi_static[0][i] == pytest.approx(ref.lift[i], rel=1e-12)
        assert quasi_static[1][i] == pytest.approx(ref.drag[i], rel=1e-12)
        assert lift[i] == pytest.approx(lagged[0][i], rel=1e-9)
        assert drag[i] == pytest.approx(lagged[1][i], rel=1e-9)
        assert abs(lift[i] / ref.lift[i] - 1) > 1e-6  # the lag is there


def test_control_effectiveness_equals_cross_products(law_carriage: DerivedCarriage) -> None:
    """E (eqs 8-12 / 22-23): each column the wrench about O of a unit body-axis force at an
    array's face centre, built here by numpy cross products."""
    from maglevgen.control.symbolic_reference import allocation_matrix

    cols = []
    for arr, (_, comps) in zip(law_carriage.params.arrays.values(), law_carriage.structure.arrays,
                               strict=True):
        for ax in comps:
            n = np.asarray(arr.normal, dtype=float)
            d = n / np.linalg.norm(n) if ax == "n" else np.eye(3)["xyz".index(ax)]
            cols.append([d[1], d[2], *np.cross(arr.position, d)])
    E = np.array(cols).T
    assert E.shape == (5, 10) and np.linalg.matrix_rank(E) == 5
    np.testing.assert_allclose(allocation_matrix(law_carriage), np.linalg.pinv(E), atol=1e-12)
