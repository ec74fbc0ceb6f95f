"""The controller as the firmware runs it in the generated C loop: the tick, the delay, the
zero-order hold, the speed loop and the force budget (maglev_control_loop).

References: scipy's DOP853 on the lambdified SymPy model (derive.numeric) with the tick-held
controller, its delay, the speed loop and the budget written out here in numpy (integrated
piecewise between ticks with the input held); the allocation from the SymPy effectiveness
(pinv); the gain schedule by scipy's natural CubicSpline; maglev_rk4_step (CasADi's own RK4
step of the continuous closed loop) for the loop without a tick; the trim drag's slope from
the SymPy trim (derive.trim) at neighbouring speeds for the speed loop's gain rule.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from maglevgen.analyses.simulate import (
    AXIS_STATES,
    DISTURBANCE,
    Tick,
    initial_state,
    launch,
    metrics,
    simulate,
    speed_loop_gain,
)
from maglevgen.carriage import DerivedCarriage
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.operating import speed_mode
from maglevgen.control.schedule import Schedule
from maglevgen.control.symbolic_reference import effectiveness
from maglevgen.errors import InputError
from maglevgen.runtime.runs import ControlLoop

AX = list(AXIS_STATES)
DT = 1e-3


_ALLOCATION: dict[int, np.ndarray] = {}


def _allocation(carriage: DerivedCarriage) -> np.ndarray:
    """T = pinv(E), E from the SymPy geometry (evaluated once per carriage)."""
    if id(carriage) not in _ALLOCATION:
        _ALLOCATION[id(carriage)] = np.linalg.pinv(effectiveness(carriage))
    return _ALLOCATION[id(carriage)]


def _groups(carriage: DerivedCarriage) -> np.ndarray:
    """The array of each control force, from the structure (input order)."""
    return np.array([i for i, (_, comps) in enumerate(carriage.structure.arrays)
                     for _ in comps])


def _command(carriage: DerivedCarriage, x: np.ndarray, t: float, gains_at, k_v: float, v_ref_at,
             budget: float | None = None) -> np.ndarray:
    """The command from the state x sampled at t: F_prop = F_ff(v_ref(t)) + k_v (v_ref(t) - V)
    (the firmware's feedforward at the reference) and the minimum-norm array forces of
    u_gen = -(K_pos (a - a_ref) + K_rate a'), each array's scaled down to ``budget``;
    ``gains_at(V)`` -> F_ff, a_ref, K_pos, K_rate."""
    V = float(np.linalg.norm(x[6:9]))
    _, a_ref, K_pos, K_rate = gains_at(V)
    f_ff = gains_at(v_ref_at(t))[0]
    n_u = carriage.model.u.shape[0]
    rates = carriage.functions.xdot(x, np.zeros(n_u), carriage.p).ravel()[AX]  # kinematics
    F = _allocation(carriage) @ -(K_pos @ (x[AX] - a_ref) + K_rate @ rates)
    if budget is not None:
        groups = _groups(carriage)
        norms = np.sqrt(np.bincount(groups, F**2))
        F = F * np.minimum(1.0, budget / np.maximum(norms, 1e-300))[groups]
    return np.concatenate([[f_ff + k_v * (v_ref_at(t) - V)], F])


def _safe(carriage: DerivedCarriage, x0: np.ndarray, gains_at) -> np.ndarray:
    """The command applied before the first computed one arrives: no array force, the
    propulsion's feedforward at the speed of x0 (no speed feedback)."""
    n_u = carriage.model.u.shape[0]
    return np.concatenate([[gains_at(float(np.linalg.norm(x0[6:9])))[0]], np.zeros(n_u - 1)])


def _tick_reference(carriage: DerivedCarriage, x0: np.ndarray, t_end: float, tick_steps: int,
                    delay: int, gains_at, k_v: float, v_ref_at, budget: float | None = None
                    ) -> np.ndarray:
    """The firmware's loop by DOP853: at each tick (every tick_steps * DT) the state is
    sampled and the command computed (`_command`), the command of ``delay`` ticks before
    applied (the safe command until then, `_safe`) and held while the SymPy model is
    integrated to the next tick. The states at every DT."""
    fns, p = carriage.functions, carriage.p
    period = tick_steps * DT
    x, out, queue = np.array(x0, float), [np.array(x0, float)], []
    for j in range(round(t_end / period)):
        t = j * period
        cmd = _command(carriage, x, t, gains_at, k_v, v_ref_at, budget)
        if j == 0:
            queue = [_safe(carriage, x, gains_at)] * delay
        queue.append(cmd)
        held = queue.pop(0)
        sol = solve_ivp(lambda _t, xx, u=held: fns.xdot(xx, u, p).ravel(), (t, t + period), x,
                        method="DOP853", rtol=1e-10, atol=1e-12,
                        t_eval=t + DT * np.arange(1, tick_steps + 1))
        assert sol.success
        out.extend(sol.y.T)
        x = sol.y[:, -1]
    return np.array(out)


def _scaled_error(x: np.ndarray, ref: np.ndarray) -> float:
    """max |x - ref| with each state scaled by its excursion in the reference."""
    scale = np.maximum(np.abs(ref - ref[0]).max(axis=0), 1e-9)
    return float(np.max(np.abs(x - ref) / scale))


def _held_commands(carriage: DerivedCarriage, traj, tick_steps: int, delay: int, gains_at,
                   k_v: float, v_ref_at, budget: float | None = None) -> np.ndarray:
    """The inputs the C run should hold at each of its samples, from its own states at the
    ticks: the command of the tick ``delay`` ticks before (the safe command until then)."""
    ticks = range(0, traj.t.size, tick_steps)
    cmds = [_command(carriage, traj.x[k], traj.t[k], gains_at, k_v, v_ref_at, budget)
            for k in ticks]
    safe = _safe(carriage, traj.x[0], gains_at)
    return np.array([cmds[k // tick_steps - delay] if k // tick_steps >= delay else safe
                     for k in range(traj.t.size)])


# RK4 at DT = 1 ms against DOP853 at rtol 1e-10, each state relative to its excursion: measured
# 3.0e-7 (the launch below) and 2.7e-7 (the hold); the bound leaves a factor of 6.6. A loop
# off by a tick is far outside it: the launch's reference without its delay is 0.79 off,
# without its speed loop 0.028; the hold's with one tick of delay instead of two, 0.21.
BOUND = 2e-6


@pytest.mark.slow
def test_launch_with_tick_delay_and_speed_loop_matches_solve_ivp(carriage, sim_lib) -> None:
    """maglev_launch at a 100 Hz tick (10 RK4 steps) with one tick of delay and the speed
    loop tracking v0 + a t, the gains scheduled at the tick, against the same loop by DOP853;
    the held inputs against the commands computed here from the run's own tick samples."""
    points = Plant(carriage, sim_lib).points(np.linspace(7.0, 12.0, 11))
    sched = Schedule.from_points(points, "damping")
    op, mass, accel = points[0], carriage.params.vehicle.mass, 5.0
    k_v = speed_loop_gain(speed_mode(sim_lib, carriage.p, op, mass, "damping"),
                          carriage.params.control.spec.speed_bandwidth)
    t_end, steps = 0.3, 10
    traj = launch(sim_lib, carriage.p, sched, op, 40.0, mass * accel, DT,
                  carriage.params.track.min_gap, max_time=t_end, tick=Tick(100.0, 1),
                  speed_gain=k_v, accel=accel)
    assert traj.c_status == 0 and traj.t[-1] == pytest.approx(t_end)
    spline, lo, hi = sched.spline, sched.speeds[0], sched.speeds[-1]

    def gains(V: float):
        f_drag, a_ref, K_pos, K_rate = Schedule.unpack(spline(np.clip(V, lo, hi)))
        return f_drag + mass * accel, a_ref, K_pos, K_rate

    def v_ref(t: float) -> float:
        return min(op.speed + accel * t, 40.0)

    np.testing.assert_allclose(traj.speed_reference, [v_ref(t) for t in traj.t], rtol=1e-14)
    held = _held_commands(carriage, traj, steps, 1, gains, k_v, v_ref)
    np.testing.assert_allclose(traj.u, held, rtol=1e-9, atol=1e-9 * np.abs(held).max())
    # the speed loop acts: F_prop differs from its feedforward by more than rounding
    ff = np.array([gains(v_ref(traj.t[max(0, k // steps - 1) * steps]))[0]
                   for k in range(traj.t.size)])
    assert np.max(np.abs(traj.u[:, 0] - ff)) > 1e-3
    x0 = initial_state(op, DISTURBANCE)
    ref = _tick_reference(carriage, x0, t_end, steps, 1, gains, k_v, v_ref)
    assert _scaled_error(traj.x, ref) < BOUND
    wrong = _tick_reference(carriage, x0, t_end, steps, 0, gains, k_v, v_ref)
    assert _scaled_error(traj.x, wrong) > 100 * BOUND


@pytest.mark.slow
def test_hold_with_tick_and_speed_loop_matches_solve_ivp(carriage, sim_lib, op) -> None:
    """maglev_simulate at a 250 Hz tick (4 RK4 steps), two ticks of delay, the speed loop
    and a force budget that the first ticks reach, against the same loop by DOP853 (and the
    held inputs against the commands from the run's own tick samples)."""
    mode = speed_mode(sim_lib, carriage.p, op, carriage.params.vehicle.mass, "damping")
    k_v = speed_loop_gain(mode, carriage.params.control.spec.speed_bandwidth)
    budget, t_end, steps = 2.0, 0.2, 4
    traj = simulate(sim_lib, carriage.p, op, "damping", t_end, DT,
                    carriage.params.track.min_gap, tick=Tick(250.0, 2), speed_gain=k_v,
                    force_budget=budget)
    assert traj.c_status == 0 and 0 < traj.saturated_time < t_end
    K_pos, K_rate = op.gains("damping")

    def gains(_v: float):
        return op.f_prop, op.a_trim, K_pos, K_rate

    def v_ref(_t: float) -> float:
        return op.speed

    held = _held_commands(carriage, traj, steps, 2, gains, k_v, v_ref, budget)
    np.testing.assert_allclose(traj.u, held, rtol=1e-9, atol=1e-9 * np.abs(held).max())
    ref = _tick_reference(carriage, initial_state(op, DISTURBANCE), t_end, steps, 2, gains,
                          k_v, v_ref, budget)
    assert _scaled_error(traj.x, ref) < BOUND


@pytest.mark.parametrize("delay", [0, 1, 3])
def test_a_step_in_the_measurement_reaches_the_command_after_the_delay(carriage, sim_lib, op,
                                                                      delay) -> None:
    """The delay line starts honest. The run starts at the default disturbance: the
    measurement steps from the trim at the first tick (tick 1, counted from 1). Its command is
    applied at tick delay + 1, not before: ticks 1 .. delay hold the safe command (no array
    force, the feedforward propulsion, no speed feedback), as a numpy queue of the loop says;
    from tick delay + 1 the held inputs are the numpy commands of the run's own samples."""
    mode = speed_mode(sim_lib, carriage.p, op, carriage.params.vehicle.mass, "damping")
    k_v = speed_loop_gain(mode, carriage.params.control.spec.speed_bandwidth)
    steps, t_end = 4, 0.06
    traj = simulate(sim_lib, carriage.p, op, "damping", t_end, DT,
                    carriage.params.track.min_gap, tick=Tick(250.0, delay), speed_gain=k_v)
    assert traj.c_status == 0
    K_pos, K_rate = op.gains("damping")

    def gains(_v: float):
        return op.f_prop, op.a_trim, K_pos, K_rate

    def v_ref(_t: float) -> float:
        return op.speed

    # the numpy loop: a queue of `delay` safe commands, one in and one out at every tick
    n_u = traj.u.shape[1]
    queue = [np.concatenate([[op.f_prop], np.zeros(n_u - 1)])] * delay
    applied = []
    for j in range(0, traj.t.size, steps):
        queue.append(_command(carriage, traj.x[j], traj.t[j], gains, k_v, v_ref))
        applied.extend([queue.pop(0)] * min(steps, traj.t.size - j))
    applied = np.array(applied)
    np.testing.assert_allclose(traj.u, applied, rtol=1e-9, atol=1e-9 * np.abs(applied).max())
    # ticks 1 .. delay: exactly no array force; tick delay + 1: the disturbance's response
    first = delay * steps
    assert np.all(traj.u[:first, 1:] == 0.0)
    assert np.all(traj.u[:first, 0] == op.f_prop)
    assert np.abs(traj.u[first, 1:]).max() > 1.0  # [N]: the step's command has arrived


def test_without_a_tick_the_loop_is_maglev_rk4_step(carriage, sim_lib, op) -> None:
    """tick=None (no maglev_control_loop) and a maglev_control_loop of zeros give, bit for
    bit, CasADi's maglev_rk4_step iterated (the feedback at every RK4 stage); a tick at every
    step does not (the command held over the stages)."""
    step = sim_lib.function("maglev_rk4_step")
    min_gap, n = carriage.params.track.min_gap, 300
    for controller in ("damping", "coupled"):
        K_pos, K_rate = op.gains(controller)
        x = initial_state(op, DISTURBANCE)
        xs = [x]
        for _ in range(n):
            x = step(x, DT, op.f_prop, K_pos, K_rate, op.a_trim, carriage.p)[0].ravel()
            xs.append(x)
        expected = np.array(xs)
        plain = simulate(sim_lib, carriage.p, op, controller, n * DT, DT, min_gap)
        assert np.array_equal(plain.x, expected)
        assert plain.saturated_time == 0.0
        Kp, Kr = (k.ravel(order="F") for k in (K_pos, K_rate))
        run = sim_lib.simulate(initial_state(op, DISTURBANCE), DT, n, op.f_prop, Kp, Kr,
                               op.a_trim, carriage.p, min_gap, op.allocation.shape[0] + 1,
                               op.gaps.size,
                               ControlLoop(0, 0, 0.0, op.speed, 0.0, 0.0))
        assert run.status == 0 and np.array_equal(run.x, expected)
        ticked = simulate(sim_lib, carriage.p, op, controller, n * DT, DT, min_gap,
                          tick=Tick(1.0 / DT, 0))
        assert not np.array_equal(ticked.x, expected)
    # the launch: a loop of zeros is the loop without one
    points = Plant(carriage, sim_lib).points(np.linspace(7.0, 12.0, 6))
    sched = Schedule.from_points(points, "coupled")
    x0 = initial_state(points[0], DISTURBANCE)
    runs = [sim_lib.launch(x0, DT, 200, 40.0, 40.0, 1, sched, carriage.p, min_gap,
                           op.allocation.shape[0] + 1, op.gaps.size, loop)
            for loop in (None, ControlLoop(0, 0, 0.0, 7.0, 0.0, -1.0))]
    assert runs[0].status == 0 and np.array_equal(runs[0].x, runs[1].x)


def test_the_speed_loop_holds_the_speed_where_the_trim_propulsion_drifts(carriage, sim_lib,
                                                                           op) -> None:
    """k_v = m omega_v - dF_D,trim/dV, the slope from the SymPy trim at neighbouring speeds;
    from a speed offset the nonlinear run's speed error decays at omega_v (tick 1 kHz, one
    tick of delay) and grows at -(dF_D,trim/dV)/m (about +0.3 1/s at 20 m/s) with k_v = 0.
    The disturbed hold run keeps its speed within 0.1 % after 1 s."""
    mass, v0, h = carriage.params.vehicle.mass, op.speed, 0.05
    slope = (carriage.trim(v0 + h).u[0] - carriage.trim(v0 - h).u[0]) / (2 * h)
    omega = 5.0
    k_v = speed_loop_gain(speed_mode(sim_lib, carriage.p, op, mass, "damping"), omega)
    assert k_v == pytest.approx(mass * omega - slope, rel=1e-4)
    assert -slope / mass == pytest.approx(0.297, abs=0.005)  # the issue's +0.297 1/s
    tick, min_gap = Tick(1000.0, 1), carriage.params.track.min_gap

    def rate(traj, t0: float, t1: float) -> float:
        err = np.abs(traj.speed - v0)
        i0, i1 = (round(t / DT) for t in (t0, t1))
        return float(np.log(err[i1] / err[i0]) / (t1 - t0))

    offset = {"u": 0.02}  # 2 cm/s faster than the trim, nothing else disturbed
    held = simulate(sim_lib, carriage.p, op, "damping", 1.0, DT, min_gap, offset, tick=tick,
                    speed_gain=k_v)
    assert rate(held, 0.3, 0.8) == pytest.approx(-omega, rel=0.05)
    drift = simulate(sim_lib, carriage.p, op, "damping", 4.0, DT, min_gap, offset, tick=tick)
    assert rate(drift, 1.0, 4.0) == pytest.approx(-slope / mass, rel=0.1)
    # the default disturbance: held within 0.1 % after 1 s; the trim propulsion drifts away
    m_held = metrics(simulate(sim_lib, carriage.p, op, "damping", 10.0, DT, min_gap,
                              tick=tick, speed_gain=k_v))
    m_drift = metrics(simulate(sim_lib, carriage.p, op, "damping", 10.0, DT, min_gap,
                               tick=tick))
    assert m_held["speed_error"] < 1e-3 < m_drift["speed_error"]


def test_a_tiny_budget_saturates_and_bounds_every_array_force(carriage, sim_lib, op) -> None:
    """Each array's control force (the norm of its components in u, grouped by the
    structure) never exceeds the budget; a tiny one saturates throughout, a generous one
    never; the same with the command at every stage (no tick)."""
    groups, min_gap = _groups(carriage), carriage.params.track.min_gap
    for tick in (Tick(1000.0, 1), None):
        free = simulate(sim_lib, carriage.p, op, "damping", 1.0, DT, min_gap, tick=tick)
        per_array = np.sqrt(np.array([np.bincount(groups, row**2) for row in free.u[:, 1:]]))
        peak = float(per_array.max())
        for budget, expect in ((0.01 * peak, "always"), (0.5 * peak, "some"),
                               (2.0 * peak, "never")):
            traj = simulate(sim_lib, carriage.p, op, "damping", 1.0, DT, min_gap, tick=tick,
                            force_budget=budget)
            norms = np.sqrt(np.array([np.bincount(groups, row**2) for row in traj.u[:, 1:]]))
            assert np.all(norms <= budget * (1 + 1e-12))
            sat = metrics(traj)["saturated_time"]
            if expect == "always":
                # the tick's first interval holds the safe command (no array force)
                first = 0 if tick is None else round(tick.delay / tick.rate / DT)
                assert sat == pytest.approx(traj.t[-1] - first * DT)
                assert np.allclose(norms[first:].max(axis=1), budget, rtol=1e-12)
                assert np.all(norms[:first] == 0.0)
            elif expect == "some":
                assert 0 < sat < traj.t[-1]
            else:
                assert sat == 0.0
                np.testing.assert_allclose(traj.x, free.x, rtol=1e-10, atol=1e-13)


@pytest.mark.parametrize(("kwargs", "key"), [
    ({"tick": Tick(300.0, 1)}, "tick rate 300.0"),  # 3.33 steps of 1 ms
    ({"speed_gain": -1.0}, "speed gain -1.0"),
    ({"speed_gain": float("nan")}, "speed gain nan"),
    ({"force_budget": 0.0}, "force budget 0.0"),
    ({"force_budget": -3.0}, "force budget -3.0"),
])
def test_bad_loop_settings_are_input_errors(carriage, sim_lib, op, kwargs, key) -> None:
    with pytest.raises(InputError, match=re.escape(key)):
        simulate(sim_lib, carriage.p, op, "damping", 0.01, DT, carriage.params.track.min_gap,
                 **kwargs)


@pytest.mark.parametrize(("rate", "delay", "key"), [
    (0.0, 1, "tick rate 0.0"), (float("inf"), 1, "tick rate inf"), (1000.0, -1, "tick delay -1"),
    (1000.0, 99, "tick delay 99"), (1000.0, 1.5, "tick delay 1.5")])
def test_bad_tick_is_an_input_error(rate, delay, key) -> None:
    with pytest.raises(InputError, match=re.escape(key)):
        Tick(rate, delay)


def test_tick_steps_is_the_period_in_steps() -> None:
    assert Tick(1000.0, 1).steps(1e-4) == 10
    assert Tick(250.0, 0).steps(1e-3) == 4
    with pytest.raises(InputError, match=r"tick rate 1000\.0 Hz.*dt = 0\.0003"):
        Tick(1000.0, 1).steps(3e-4)
    with pytest.raises(InputError, match=re.escape("tick rate 2000.0")):
        Tick(2000.0, 1).steps(1e-3)  # a period shorter than a step


def test_montecarlo_samples_run_the_loop_they_are_given(carriage, sim_lib) -> None:
    """A study's tick, speed gain and budget reach every sample's run: a budget far below
    the forces saturates the whole run, none leaves it unsaturated; a bad tick is refused
    when the study is made (before any sample)."""
    from maglevgen.analyses.montecarlo import make_study, run_sample

    rows = {}
    for budget in (1e-6, None):
        study = make_study(Plant(carriage, sim_lib), ("damping",), 0.2, DT, seed=3,
                           tick=Tick(1000.0, 1), speed_gain=10.0, force_budget=budget)
        assert (study.tick, study.speed_gain, study.force_budget) == (Tick(1000.0, 1), 10.0,
                                                                      budget)
        (rows[budget],) = run_sample(study, 0, sim_lib)
    # saturated but for the first tick's safe command (no array force)
    assert rows[1e-6]["saturated_time"] == pytest.approx(0.2 - 1e-3)
    assert rows[None]["saturated_time"] == 0.0
    with pytest.raises(InputError, match=re.escape("tick rate 300.0")):
        make_study(Plant(carriage, sim_lib), ("damping",), 0.2, DT, seed=3, tick=Tick(300.0, 1))
