"""Monte Carlo over the actuators' lag (``"actuators.time_constant"`` in
[tolerances.parameters], maglevgen.params.ACTUATOR_LAG): each sample's plant lags by its draw,
the firmware's design stays the file's.

References independent of the sampling code: `simulate` of the sample with the C loop's plant
lag set directly (`ControlLoop.tau`, maglev_simulate called here) and the nominal design
(`firmware_gains` on the file's loop); the lag's closed form F(s) = F_c + (F0 - F_c)
exp(-s / tau) over a held tick, checked with numpy on the forces the run records (not the
C's arithmetic: the ratio of successive steps' force changes is exp(-dt / tau)).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from maglevgen.analyses.montecarlo import make_study, run_local, sample_tick
from maglevgen.analyses.sim_loop import firmware_gains, run_loop
from maglevgen.analyses.simulate import hold_run, metrics, simulate
from maglevgen.carriage import DerivedCarriage
from maglevgen.cli import main
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.operating import Weights, operating_point
from maglevgen.derive import conventions as cv
from maglevgen.params import load_params

SPEEDS = "tolerances.speed=[8.0, 16.0]"
LAG = 'tolerances.parameters={"actuators.time_constant" = {uniform = 1.5e-3}}'  # 0.5-3.5 ms
NOMINAL_LAG = 2e-3
T_END, DT = 0.3, 1e-4  # ten RK4 steps a 1 kHz tick: the lag seen within a held tick


@pytest.fixture(scope="module")
def lag_studies(sim_lib):
    """Per loop, a study of three samples (seed 13) whose only tolerance beside the speed
    and the disturbance is the actuators' lag: (loop, carriage, study, columns)."""
    carriage = DerivedCarriage(load_params(None, [SPEEDS, LAG]))
    plant = Plant(carriage, sim_lib)
    out = {}
    for loop in ("firmware", "sensed"):
        tick, k_v, budget = run_loop(plant, loop)
        study = make_study(plant, ("spec",), t_end=T_END, dt=DT, seed=13, tick=tick,
                           speed_gain=k_v, force_budget=budget)
        out[loop] = (loop, carriage, study, run_local(study, 3, workers=1))
    return out


@pytest.fixture(params=["firmware", "sensed"])
def lag_study(request, lag_studies):
    return lag_studies[request.param]


def _inputs(carriage, cols, i, lib):
    speed, min_gap = float(cols["speed"][i]), carriage.params.track.min_gap
    w = Weights.of(carriage.params)
    op = operating_point(lib, carriage.p, speed, min_gap, w)  # p is the file's: lag alone
    dist = {s: float(cols[f"disturbance.{s}"][i]) for s in ("y", "z", "phi", "theta", "psi")}
    return op, dist, min_gap


def test_a_drawn_lag_is_recorded_and_flown_with_the_nominal_design(lag_study, sim_lib) -> None:
    """Each row records its draw (within 2 +- 1.5 ms), and its run equals (bit for bit) the
    run of the same sample through `simulate` at the file's loop with only the C loop's
    plant lag set to the draw: the ControlLoop built here from the NOMINAL loop (its K_lag
    and K_delay `firmware_gains` of the file's lag, its lag prediction the file's), tau
    replaced, maglev_simulate called here. The draw moves the run (the file's lag flies
    another path)."""
    loop_name, carriage, study, cols = lag_study
    drawn = cols["actuators.time_constant"]
    assert np.all(np.abs(drawn - NOMINAL_LAG) <= 1.5e-3) and np.ptp(drawn) > 1e-4
    assert study.tick.lag == NOMINAL_LAG
    for i in range(3):
        op, dist, min_gap = _inputs(carriage, cols, i, sim_lib)
        tick = sample_tick(study, i)
        assert tick.plant_lag == drawn[i] and tick.lag == NOMINAL_LAG
        run = simulate(sim_lib, carriage.p, op, "spec", T_END, DT, min_gap, dist, tick=tick,
                       speed_gain=study.speed_gain, force_budget=study.force_budget,
                       controller_op=op)
        m = metrics(run)
        assert m["min_gap"] == cols["min_gap"][i]
        for axis in cv.AXES:
            assert m["axes"][axis]["peak_deviation"] == cols[f"peak.{axis}"][i], axis
        assert m["tick"]["actuator_lag"] == drawn[i]
        # the same run with the loop's plant lag set directly, the design the nominal one
        nominal_tick = replace(tick, plant_lag=None)
        n_steps = round(T_END / DT)
        inputs = hold_run(carriage.p, op, "spec", DT, dist, nominal_tick, study.speed_gain,
                          study.force_budget, op, n_steps)
        loop = inputs.loop
        assert loop is not None and loop.tau == NOMINAL_LAG
        if loop_name == "firmware":
            K = firmware_gains(op, "spec", study.tick)  # the design on the file's lag
            assert loop.k_lag == tuple(K.K_lag.ravel(order="F"))
        direct = sim_lib.simulate(inputs.x0, DT, n_steps, inputs.f_prop, inputs.k_pos,
                                  inputs.k_rate, inputs.a_ref, carriage.p, min_gap,
                                  op.allocation.shape[0] + 1, op.gaps.size,
                                  replace(loop, tau=float(drawn[i]), law_tau=NOMINAL_LAG))
        np.testing.assert_array_equal(direct.x, run.x)
        np.testing.assert_array_equal(direct.u, run.u)
        filed = simulate(sim_lib, carriage.p, op, "spec", T_END, DT, min_gap, dist,
                         tick=nominal_tick, speed_gain=study.speed_gain,
                         force_budget=study.force_budget, controller_op=op)
        assert not np.array_equal(filed.x, run.x)


def _lag_in_ticks(u: np.ndarray, steps: int, first: int, ticks: int) -> np.ndarray:
    """tau [s] from the recorded forces within each held tick: F(s) = F_c + (F0 - F_c)
    exp(-s / tau) gives (F_{j+2} - F_{j+1}) / (F_{j+1} - F_j) = exp(-dt / tau) at every
    step j of a tick (F_c held), for each array force with a clear change."""
    out = []
    for k in range(first, first + ticks):
        F = u[k * steps:(k + 1) * steps + 1, 1:]  # the tick's samples, its start to its end
        d = np.diff(F, axis=0)
        big = np.abs(d[0]) > 1e-6 * max(np.max(np.abs(F)), 1e-12)
        ratio = d[1:, big] / d[:-1, big]
        out.append(-DT / np.log(ratio).ravel())
    return np.concatenate(out)


def test_the_plant_lags_by_the_draw_as_the_closed_form_says(lag_study, sim_lib) -> None:
    """Within every held tick each array force follows F(s) = F_c + (F0 - F_c)
    exp(-s / tau) with tau the sample's DRAW (numpy on the recorded forces, to 1e-6), not the
    file's 2 ms; the run with the file's lag gives 2 ms the same way."""
    _, carriage, study, cols = lag_study
    steps = round(1 / (study.tick.rate * DT))
    for i in range(3):
        op, dist, min_gap = _inputs(carriage, cols, i, sim_lib)
        tick = sample_tick(study, i)
        for t, expected in ((tick, cols["actuators.time_constant"][i]),
                            (replace(tick, plant_lag=None), NOMINAL_LAG)):
            run = simulate(sim_lib, carriage.p, op, "spec", 0.02, DT, min_gap, dist, tick=t,
                           speed_gain=study.speed_gain, force_budget=study.force_budget,
                           controller_op=op)
            seen = _lag_in_ticks(run.u, steps, first=2, ticks=10)
            assert seen.size > 20
            np.testing.assert_allclose(seen, expected, rtol=1e-6)


def test_redesign_designs_for_the_drawn_lag(sim_lib) -> None:
    """--redesign (as if the firmware knew the sample): the design's lag is the draw too,
    and its K_lag is the design at the drawn lag, not the file's."""
    carriage = DerivedCarriage(load_params(None, [SPEEDS, LAG]))
    plant = Plant(carriage, sim_lib)
    tick, k_v, budget = run_loop(plant, "firmware")
    study = make_study(plant, ("spec",), t_end=0.05, dt=1e-3, seed=13, tick=tick,
                       speed_gain=k_v, force_budget=budget, redesign=True)
    own = sample_tick(study, 0)
    assert own.plant_lag is None and own.lag != NOMINAL_LAG
    op = operating_point(sim_lib, carriage.p, 12.0, carriage.params.track.min_gap,
                         Weights.of(carriage.params))
    assert not np.allclose(firmware_gains(op, "spec", own).K_lag,
                           firmware_gains(op, "spec", tick).K_lag)


def test_a_drawn_lag_on_the_continuous_law_is_recorded_not_flown(sim_lib) -> None:
    carriage = DerivedCarriage(load_params(None, [SPEEDS, LAG]))
    study = make_study(Plant(carriage, sim_lib), ("spec",), t_end=0.05, dt=1e-3, seed=13)
    assert sample_tick(study, 0) is None
    cols = run_local(study, 2, workers=1)
    assert np.ptp(cols["actuators.time_constant"]) > 0


@pytest.mark.parametrize(("spread", "expected"), [
    ("{uniform = 2e-3}", "tolerances.parameters.actuators.time_constant = {'uniform': 0.002}: "
                         "draws values in [0, 0.004]: a sample's lag must stay > 0"),
    ("{normal = 6e-4}", "tolerances.parameters.actuators.time_constant = {'normal': 0.0006}: "
                        "draws values in [-0.0004, 0.0044]: a sample's lag must stay > 0"),
])
def test_a_lag_spread_reaching_zero_is_one_line_exit_2(spread, expected, capsys,
                                                       tmp_path) -> None:
    rc = main(["montecarlo", "--samples", "2", "--t-end", "0.01", "--out",
               str(tmp_path / "mc"), "--set",
               f'tolerances.parameters={{"actuators.time_constant" = {spread}}}'])
    err = capsys.readouterr().err
    assert rc == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("maglevgen: error:"), err
    assert expected in lines[0], lines[0]
    assert not (tmp_path / "mc").exists()


def test_a_lag_spread_outside_the_schema_range_is_one_line_exit_2(capsys, tmp_path) -> None:
    rc = main(["montecarlo", "--samples", "2", "--t-end", "0.01", "--out",
               str(tmp_path / "mc"), "--set", "actuators.time_constant=0.9", "--set",
               'tolerances.parameters={"actuators.time_constant" = {uniform = 0.2}}'])
    err = capsys.readouterr().err
    assert rc == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert ("tolerances.parameters.actuators.time_constant = {'uniform': 0.2}: draws values "
            "in [0.7, 1.1], outside the key's range [0, 1]") in lines[0], lines[0]


@pytest.mark.slow  # runs against solve_ivp
def test_a_held_tick_with_the_drawn_lag_matches_dop853(lag_studies, sim_lib) -> None:
    """scipy's DOP853 on the lambdified model (derive.numeric, not the C), from the run's
    state at the start of a held tick with the tick's inputs: the propulsion as held and each
    array force F(s) = F_c + (F0 - F_c) exp(-s / tau) with F0 the run's at the tick's start
    and F_c the held command (from the run's first step in the tick), tau the sample's draw.
    The run's state at the tick's end agrees to 1e-7 of the tick's motion (RK4's error);
    with the file's 2 ms in the same reference it misses by 1e4 times more: the draw, not the
    design, is flown."""
    from scipy.integrate import solve_ivp

    _, carriage, study, cols = lag_studies["firmware"]  # the plant between ticks: any loop's
    f = carriage.functions
    steps = round(1 / (study.tick.rate * DT))
    i = int(np.argmax(np.abs(cols["actuators.time_constant"] - NOMINAL_LAG)))
    drawn = float(cols["actuators.time_constant"][i])
    op, dist, min_gap = _inputs(carriage, cols, i, sim_lib)
    run = simulate(sim_lib, carriage.p, op, "spec", 0.02, DT, min_gap, dist,
                   tick=sample_tick(study, i), speed_gain=study.speed_gain,
                   force_budget=study.force_budget, controller_op=op)
    k = 5
    j0, j1 = k * steps, (k + 1) * steps
    F0, F1 = run.u[j0, 1:], run.u[j0 + 1, 1:]
    a = np.exp(-DT / drawn)
    Fc = (F1 - a * F0) / (1 - a)
    assert np.ptp(run.u[j0:j1, 0]) == 0.0  # the propulsion held over the tick

    def end_state(tau: float) -> np.ndarray:
        def rhs(s: float, x: np.ndarray) -> np.ndarray:
            u = np.concatenate(([run.u[j0, 0]], Fc + (F0 - Fc) * np.exp(-s / tau)))
            return np.asarray(f.xdot(x, u, carriage.p)).ravel()

        sol = solve_ivp(rhs, (0.0, steps * DT), run.x[j0], method="DOP853", rtol=1e-12,
                        atol=1e-14)
        assert sol.success
        return sol.y[:, -1]

    motion = np.max(np.abs(run.x[j1] - run.x[j0]))
    miss = np.max(np.abs(end_state(drawn) - run.x[j1]))
    filed = np.max(np.abs(end_state(NOMINAL_LAG) - run.x[j1]))
    # RK4 at 0.1 ms against DOP853 at 1e-12 (the circuits' fast modes): 5e-10 here
    assert miss < 1e-7 * motion, (miss, motion)
    assert filed > 1e4 * miss, (filed, miss)  # 2.6e-3 here
