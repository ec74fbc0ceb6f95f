"""The carriage's `Plant` (maglevgen.control.carriage_plant): built once per carriage and model
choice, it loads its library once, solves each operating point once, and what it caches is
what the direct computation gives; its loop as built is the speed loop [control.spec] asks for
and what the C loop, the host run and the FMU read from it.

References that are not the Plant: `operating_point` called directly on the library, the
lift-off speed from the lambdified model (SymPy/SciPy), the roots of the speed loop's
characteristic polynomial (numpy), the parameter file's values.
"""

from __future__ import annotations

import numpy as np
import pytest

from maglevgen.carriage import DerivedCarriage
from maglevgen.control import carriage_plant as cp
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.operating import Weights, operating_point
from maglevgen.controllers import REGISTRY, Controller, register
from maglevgen.params import ARRAY_FORCE_LAWS


@pytest.fixture(scope="module")
def plant(carriage: DerivedCarriage, sim_lib) -> Plant:
    return Plant(carriage, sim_lib)


def test_cached_points_equal_the_direct_ones(plant: Plant, carriage: DerivedCarriage,
                                             sim_lib) -> None:
    """Each point equals `operating_point` on the library at the same speed (trim, Jacobian,
    gains, bit for bit), and asking again returns the same object (solved once)."""
    speeds = np.linspace(*plant.speed_range, 4)
    got = plant.points(speeds)
    for v, op in zip(speeds, got, strict=True):
        ref = operating_point(sim_lib, carriage.p, float(v), carriage.params.track.min_gap,
                              Weights.of(carriage.params))
        assert op.speed == ref.speed
        np.testing.assert_array_equal(op.x_trim, ref.x_trim)
        np.testing.assert_array_equal(op.A, ref.A)
        for name in ("lqr", "spec"):
            for a, b in zip(op.gains(name), ref.gains(name), strict=True):
                np.testing.assert_array_equal(a, b)
    again = plant.points(speeds[::-1])
    assert all(a is b for a, b in zip(again, got[::-1], strict=True))
    assert plant.point(float(speeds[1])) is got[1]


def test_the_cache_keeps_at_most_its_bound(carriage: DerivedCarriage, sim_lib,
                                           monkeypatch: pytest.MonkeyPatch) -> None:
    """Past MAX_CACHED_POINTS a point is solved again when asked again (the same numbers),
    so that a long-lived plant's memory stays bounded."""
    monkeypatch.setattr(cp, "MAX_CACHED_POINTS", 2)
    plant = Plant(carriage, sim_lib)
    first = plant.points([18.0, 19.0, 20.0])
    again = plant.points([18.0, 19.0, 20.0])
    assert again[0] is first[0] and again[1] is first[1] and again[2] is not first[2]
    np.testing.assert_array_equal(again[2].A, first[2].A)


def test_one_library_load_for_every_use(carriage: DerivedCarriage, sim_lib,
                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """A plant built without a library loads it on first use, once: the speed range, the
    points, the loop and the gain table all read the same one."""
    calls = []

    def counted(structure, **kw):
        calls.append(structure)
        return sim_lib

    monkeypatch.setattr(cp, "simulation_library", counted)
    plant = Plant(carriage)
    assert not plant.loaded and calls == []
    v_min, v_max = plant.speed_range
    plant.points([v_min, v_max])
    assert plant.loop is plant.loop
    assert plant.lib is sim_lib and plant.loaded
    assert calls == [carriage.structure]


def test_the_speed_range_is_the_lift_off_of_the_model(plant: Plant,
                                                      carriage: DerivedCarriage) -> None:
    """v_min (the file omits it): (1 + lift_off_margin) x the lift-off speed the lambdified
    model finds (SciPy); v_max the file's."""
    env = carriage.params.envelope
    assert env.v_min is None
    v_min, v_max = plant.speed_range
    assert v_min == pytest.approx((1 + env.lift_off_margin) * carriage.lift_off_speed(),
                                  rel=1e-5)
    assert v_max == env.v_max


def test_the_loop_puts_the_speed_poles_where_the_spec_asks(plant: Plant,
                                                           carriage: DerivedCarriage) -> None:
    """The loop as built over the schedule's nodes: at the node with the lowest drag slope,
    m s^2 + (slope + k_v) s + k_i has its roots at -speed_bandwidth and -r speed_bandwidth;
    the tick, the lag, the clamp and the budget are the file's."""
    prm = carriage.params
    spec = prm.control.spec
    loop = plant.loop
    nodes = np.linspace(*plant.speed_range, prm.envelope.schedule_nodes)
    slopes = [op.trim_drag_slope for op in plant.points(nodes)]
    roots = np.sort(np.roots([prm.vehicle.mass, min(slopes) + loop.speed_gain,
                              loop.speed_integral]).real)
    b, r = spec.speed_bandwidth, spec.speed_integral_ratio
    want = np.sort([-b, -r * b]) if r > 0 else np.array([-b])
    np.testing.assert_allclose(roots[-want.size:], want, rtol=1e-9)
    assert (loop.tick.rate, loop.tick.delay) == (spec.tick_rate, spec.delay_ticks)
    assert loop.actuator_lag == prm.actuators.time_constant
    assert loop.force_budget == spec.force_budget
    assert loop.speed_integral_limit == spec.speed_integral_limit


def test_what_the_c_loop_and_the_host_read_from_the_loop(plant: Plant) -> None:
    """The C loop's struct and the host run's tick carry the loop's numbers: RK4 steps per
    tick from the rate, the delay, k_v, the budget, the lag, k_i and its clamp."""
    loop = plant.loop
    dt = 1e-4
    c = loop.control_loop(dt, 20.0, 0.5)
    assert c is not None
    assert c.tick_steps == round(1.0 / (loop.tick.rate * dt))
    assert (c.delay_ticks, c.k_v, c.force_budget) == (loop.tick.delay, loop.speed_gain,
                                                      loop.force_budget)
    assert (c.tau, c.k_i, c.i_max) == (loop.actuator_lag, loop.speed_integral,
                                       loop.speed_integral_limit)
    assert (c.v_ref, c.accel) == (20.0, 0.5)
    assert (loop.rate, loop.delay, loop.lag) == (loop.tick.rate, loop.tick.delay,
                                                 loop.actuator_lag)


def test_a_controller_registered_after_the_points_are_solved_is_seen(plant: Plant) -> None:
    """The registry is read where it is needed: a controller registered after the plant has
    solved its points gets its gains at those very points (here the damping law as a
    matrix: its gains are the registered damping controller's)."""
    op = plant.point(plant.speed_range[0])
    name = "late_damping"
    register(Controller(name, "late", "damping registered late",
                        lambda o: (np.zeros((5, 5)), np.diag(o.c_damping)),
                        embeddable=False))
    try:
        K_pos, K_rate = plant.point(plant.speed_range[0]).gains(name)
        ref_pos, ref_rate = op.gains("damping")
        np.testing.assert_array_equal(K_pos, ref_pos)
        np.testing.assert_array_equal(K_rate, ref_rate)
    finally:
        REGISTRY.pop(name)


def test_with_model_gives_the_same_plant_with_another_force_law(plant: Plant) -> None:
    """`with_model`: itself when nothing changes; another model choice once per plant, its
    own structure and library, the other choices kept."""
    assert plant.with_model() is plant
    assert plant.with_model(plant.params.model.array_force) is plant
    law = next(a for a in ARRAY_FORCE_LAWS if a != plant.params.model.array_force)
    other = plant.with_model(array_force=law)
    assert other is plant.with_model(array_force=law)
    assert other.params.model.array_force == law
    assert other.params.model.circuit_dynamics == plant.params.model.circuit_dynamics
    assert other.carriage.structure != plant.carriage.structure
    np.testing.assert_array_equal(other.p, plant.p)
