"""Runs on the sensors (`simulate --loop sensed`): the firmware's own sense tick, compiled for
the host (maglevgen.runtime.sense), flown by maglev_simulate around the run-time-parameter
plant with the lag and the delay, on readings from the generated measurement functions with
the run's noise.

References: output_feedback.noisy_hold (numpy's Kalman filter and the loop's law at the
operating point, written apart from the C) fed the very same noise; the sense table's rows
against the exact rows (estimation.sense_plants, the DARE at each speed) between the nodes;
the noise against the [sensors] file's densities and resolutions; the header's error codes.
"""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from maglevgen.carriage import DerivedCarriage
from maglevgen.control.built_loop import Loop

SPEED, SECONDS, SKIP = 20.0, 3.0, 500  # the compared hold; its first ticks (the start) left out


@pytest.fixture(scope="module")
def held(carriage: DerivedCarriage, sim_lib, sensed_tick):
    """The C hold on the sensors from trim at SPEED, and noisy_hold's with the same noise."""
    from maglevgen.analyses.output_feedback import noisy_hold
    from maglevgen.analyses.simulate import run_scenarios
    from maglevgen.control.carriage_plant import Plant

    run = run_scenarios(Plant(carriage, sim_lib), ("spec",), SECONDS, 1e-3, SPEED,
                        loop=Loop.SENSED, disturbance={})
    traj = run.trajectories[0]
    ref = noisy_hold(sim_lib, carriage.p, carriage.params, traj.op, t_end=SECONDS, seed=0)
    return traj, ref


def _high_pass(s: np.ndarray, width: int = 50) -> np.ndarray:
    return s - np.convolve(s, np.ones(width) / width, mode="same")


def test_sensed_hold_flies_as_the_numpy_output_feedback_loop(held) -> None:
    """Same plant, same noise: tick by tick, each array's gap deviation above 20 Hz (less its
    50-tick moving average) follows the numpy loop's (correlation >= 0.75, RMS within 15 %),
    and the whole deviation has its RMS within 35 %: the firmware's estimator and law do
    what the design's do. The slow part agrees in size, not tick by tick: the firmware starts
    its estimate from the first readings and schedules its tables on the estimated speed,
    the numpy loop starts at the trim at one speed. A table whose readings at trim were
    0.18 mm off (the bound relative to the accelerometer's 9.81 m/s^2) gave 40-95 um of RMS
    against 4-6 um here."""
    traj, ref = held
    assert traj.c_status == 0 and traj.sensing.tick_error == 0
    c = (traj.gaps[1:] - traj.op.gaps)[SKIP:]
    py = (ref.gap_series - traj.op.gaps)[SKIP:]
    rms_c, rms_py = np.sqrt(np.mean(c**2, axis=0)), np.sqrt(np.mean(py**2, axis=0))
    assert np.all(np.abs(rms_c / rms_py - 1) < 0.35), (rms_c, rms_py)
    fast_c = np.array([_high_pass(c[:, j]) for j in range(c.shape[1])])
    fast_py = np.array([_high_pass(py[:, j]) for j in range(c.shape[1])])
    corr = [np.corrcoef(a, b)[0, 1] for a, b in zip(fast_c, fast_py, strict=True)]
    assert min(corr) >= 0.75, corr
    ratio = np.std(fast_c, axis=1) / np.std(fast_py, axis=1)
    assert np.all(np.abs(ratio - 1) < 0.15), ratio


def test_sensed_metrics_say_what_the_run_did(held) -> None:
    """The metrics of a run on the sensors from its own arrays: the prediction error is the
    state less the prediction recorded a tick before (computed here), the array forces the
    plant's inputs."""
    from maglevgen.analyses.simulate import metrics

    traj, _ = held
    m = metrics(traj)["sensing"]
    pred = traj.sensing.predicted
    err = traj.x[1:pred.shape[0]] - pred[:-1]  # 1 ms steps: a tick a step
    assert m["rms_estimation_error"]["z"] == pytest.approx(np.sqrt(np.mean(err[:, 2] ** 2)),
                                                           rel=1e-12)
    assert 0 < m["rms_estimation_error"]["z"] < 20e-6
    arrays = traj.array_forces
    assert set(m["rms_array_force"]) == set(arrays)
    assert m["budget_share"] == 0.0 and m["tick_error"] == 0
    assert metrics(replace(traj, sensing=None))["sensing"] is None


def test_the_sense_tables_readings_at_trim_are_within_a_tenth_of_their_noise(
        carriage: DerivedCarriage, sim_lib, sensed_tick) -> None:
    """Between the table's nodes, each reading at trim is within TRIM_READING_SHARE of its
    noise of the exact value, and C's rows within GAIN_TABLE_BOUND of their own largest
    entry: the exact rows from the DARE at each speed (estimation.sense_plants)."""
    from maglevgen.analyses.firmware_sources import sense_schedule
    from maglevgen.control import sense_table as stab
    from maglevgen.control.carriage_plant import Plant
    from maglevgen.control.schedule import GAIN_TABLE_BOUND, field_slices

    fw = sensed_tick[0].firmware
    plant = Plant(carriage, sim_lib)
    table = sense_schedule(plant, fw.v_min, fw.v_max, fw.loop).table
    speeds = np.linspace(fw.v_min, fw.v_max, 9)[1:-1] + 0.37  # off the nodes
    exact = np.array([sp.row() for sp in stab.sense_plants(
        sim_lib, carriage.p, carriage.params, plant.points(speeds),
        fw.loop.actuator_lag, fw.loop.delay_ticks)])
    approx = table(speeds)
    where = dict(zip((n for n, _ in table.fields), field_slices(table.fields), strict=True))
    i, n = where["y_trim"]
    sigma = np.sqrt(fw.layout.variances)
    assert np.all(np.abs(approx[:, i:i + n] - exact[:, i:i + n])
                  <= stab.TRIM_READING_SHARE * sigma * 1.5)
    i, n = where["C"]
    ny = sigma.size
    for j in range(ny):
        rows_exact, rows_approx = exact[:, i + j:i + n:ny], approx[:, i + j:i + n:ny]
        own = np.max(np.abs(rows_exact))
        if own > 0:
            assert np.max(np.abs(rows_approx - rows_exact)) <= 2 * GAIN_TABLE_BOUND * own, j


def test_reading_noise_has_the_files_variance(carriage: DerivedCarriage, sensed_tick) -> None:
    """The noise a run draws: per reading, white noise whose variance plus the rounding's
    (resolution^2 / 12) is the layout's variance at the tick (from the file's densities and
    anti-alias filters, estimation.SensorLayout), around the IMU's bias (the file's, a sign
    per axis); the rows are successive ticks of one generator (a longer run starts alike)."""
    from maglevgen.analyses.sim_loop import reading_noise

    params = carriage.params
    layout = sensed_tick[0].firmware.layout
    noise, step = reading_noise(params, layout, 40000, seed=3)
    centred = noise - np.mean(noise, axis=0)
    expected = np.sqrt(layout.variances - step**2 / 12)
    assert np.allclose(np.std(centred, axis=0), expected, rtol=0.03)
    n_gap = len(layout.gaps)
    bias = np.abs(np.mean(noise[:, n_gap:n_gap + 3], axis=0))
    assert np.allclose(bias, params.sensors.imu.gyro_bias, rtol=0.0,
                       atol=4 * expected[n_gap] / np.sqrt(40000))
    longer, _ = reading_noise(params, layout, 40010, seed=3)
    assert np.array_equal(longer[:40000], noise)


def test_a_tick_without_a_usable_gap_ends_the_run_with_the_sense_ticks_code(
        carriage: DerivedCarriage, sim_lib, sensed_tick) -> None:
    """Every gap reading NaN from the tenth tick: the sense tick answers MAGLEV_ERR_SENSOR
    (the firmware header's code), which ends the host's run there with MAGLEV_SIM_ERROR."""
    from maglevgen.analyses.sim_loop import control_loop, sensing
    from maglevgen.analyses.simulate import initial_state
    from maglevgen.codegen.checks import ERROR_CODES
    from maglevgen.control.operating import Weights, operating_point

    tick, k_v, budget = sensed_tick
    op = operating_point(sim_lib, carriage.p, SPEED, carriage.params.track.min_gap,
                         Weights.of(carriage.params))
    sense = sensing(tick, 101)
    sense.noise[10:, :len(tick.firmware.layout.gaps)] = np.nan
    loop = control_loop(1e-3, tick, k_v, budget, op.speed, sense=sense)
    run = sim_lib.simulate(initial_state(op, {}), 1e-3, 100, op.f_prop,
                           np.zeros(25), np.zeros(25), op.a_trim, carriage.p,
                           carriage.params.track.min_gap, op.allocation.shape[0] + 1,
                           op.gaps.size, loop)
    assert run.status == 3 and run.last == 10  # MAGLEV_SIM_ERROR at the tenth tick
    assert sense.tick_error == ERROR_CODES["MAGLEV_ERR_SENSOR"][0]


def test_the_sensors_loop_needs_a_tick(carriage: DerivedCarriage, sim_lib, sensed_tick) -> None:
    """A sense on the continuous loop (tick_steps 0) is refused at entry (MAGLEV_SIM_ARGUMENT:
    the library's internal error), nothing run."""
    from maglevgen.analyses.sim_loop import sensing
    from maglevgen.runtime.runs import ControlLoop

    tick = sensed_tick[0]
    loop = ControlLoop(0, 0, sense=sensing(tick, 10))
    with pytest.raises(RuntimeError, match="refused"):
        sim_lib.simulate(np.zeros(12), 1e-3, 5, 0.0, np.zeros(25), np.zeros(25), np.zeros(5),
                         carriage.p, 0.0, 7, 6, loop)


@pytest.mark.parametrize("command", ["simulate", "montecarlo"])
def test_cli_sensed_loop_flies_only_the_embedded_controller(sim_lib, tmp_path,
                                                            command: str) -> None:
    """`simulate|montecarlo --loop sensed --controller lqr`: exit 2, one line naming the
    option and why, checked before the output folder (here a file, which is refused too: the
    option is what the user has to change first); sim_lib: the derivation cached, so that no
    progress line joins the error."""
    taken = tmp_path / "taken"
    taken.write_text("a user's file\n")
    proc = subprocess.run([sys.executable, "-m", "maglevgen.cli", command, "--loop",
                           "sensed", "--controller", "lqr", "--t-end", "0.1", "--out",
                           str(taken)], capture_output=True, text=True, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "--loop sensed" in lines[0] and "'lqr'" in lines[0], lines
    assert taken.read_text() == "a user's file\n"


def test_sensed_launch_flies_the_accelerating_trim(carriage: DerivedCarriage, sim_lib) -> None:
    """The launch on the sensors (the sense tick with the reference's slope, `a_ref`): from the
    accelerating trim at v_min with no disturbance to v_max, the carriage stays on the
    accelerating trim, solved apart at each of five speeds it passes (maglev_trim_accelerating,
    Newton in C): heave within 50 um, pitch within 50 urad of it once past the first second
    (the estimate's start), and the speed within [control.spec]'s error of the ramp. Flying
    the pose change alone, not the body velocities' (w = V sin(theta) at the other pitch), put
    the heave 1.4-2.2 mm off; no feedforward, the speed 0.9 % off. Its status is not
    "diverging": its deviations stay at the noise's size (below simulate.GROWTH_FLOOR)."""
    from maglevgen.analyses.run_spec import RunSpec
    from maglevgen.analyses.simulate import run_scenarios
    from maglevgen.control.built_loop import Loop
    from maglevgen.control.carriage_plant import Plant
    from maglevgen.control.operating import checked_accelerating_trim

    run = run_scenarios(Plant(carriage, sim_lib), ("spec",), 10.0, 1e-3, scenario="launch",
                        loop=Loop.SENSED, disturbance={})
    traj = run.trajectories[0]
    prm = carriage.params
    a = prm.envelope.launch_acceleration
    # from no disturbance the noise floor's peak at the end exceeds the start's: not growth
    # (simulate.GROWTH_FLOOR), so not "diverging"
    assert traj.c_status == 0 and float(np.min(traj.gaps)) > prm.track.min_gap
    assert traj.status in ("settled", "not settled")
    speed = np.linalg.norm(traj.x[:, 6:9], axis=1)
    assert speed[-1] >= run.v_end * (1 - 1e-3)
    ramp = np.minimum(traj.op.speed + a * traj.t, run.v_end)
    after = traj.t >= 1.0
    assert np.max(np.abs(speed[after] - ramp[after]) / ramp[after]) \
        <= RunSpec.of(prm, 0.05).speed_tolerance
    picks = np.flatnonzero(after)[np.linspace(0, np.count_nonzero(after) - 1, 5).astype(int)]
    for k in picks:
        x_a = checked_accelerating_trim(sim_lib, carriage.p, float(speed[k]), a,
                                        prm.track.min_gap)[0]
        assert abs(traj.x[k, 2] - x_a[2]) <= 50e-6, (traj.t[k], traj.x[k, 2] - x_a[2])
        assert abs(traj.x[k, 4] - x_a[4]) <= 50e-6, (traj.t[k], traj.x[k, 4] - x_a[4])


#: the track encoder's 1 mm quantization as white noise of the same variance (1 mm / sqrt(12)
#: RMS, no rounding): the same [sensors] variance, so the same Kalman filter and tables
WHITE_ENCODER = ("sensors.track.noise=2.886751345948129e-4", "sensors.track.resolution=0.0")


def test_one_step_prediction_error_within_the_dares_covariance(sim_lib) -> None:
    """A 6 s hold on the sensors at 20 m/s: every state's one-step prediction error (the state
    at tick k + 1 less the sense tick's prediction at k, past the first second), RMS, within
    1.15 x the square root of the DARE's a-priori covariance's diagonal (SciPy's
    solve_discrete_are on the estimator's model): the filter is not overconfident. The plant
    has none of the process noise the filter assumes, so most states sit below it (y 0.84,
    u 0.49, p 0.28 measured); heave, set by the gap sensors' noise, at 1.00. The encoder reads
    white noise of its rounding's variance here (WHITE_ENCODER): the default 1 mm encoder's
    rounding is not white at a whole number of millimetres a tick, and x and u then sit at
    6.6x and 3.7x (docs/_guides/firmware.md, "What the filter assumes")."""
    from scipy.linalg import solve_discrete_are

    from maglevgen.analyses.sim_loop import estimation_error
    from maglevgen.analyses.simulate import run_scenarios
    from maglevgen.control.carriage_plant import Plant
    from maglevgen.control.estimation import SensorLayout, estimator_model
    from maglevgen.derive import conventions as cv
    from maglevgen.params import load_params

    carriage = DerivedCarriage(load_params(None, list(WHITE_ENCODER)))
    plant = Plant(carriage, sim_lib)
    run = run_scenarios(plant, ("spec",), 6.0, 1e-3, SPEED, loop=Loop.SENSED, disturbance={})
    traj = run.trajectories[0]
    assert traj.c_status == 0
    err = estimation_error(traj.sensing, traj.x, traj.tick.steps(traj.dt))[1000:]
    model = estimator_model(sim_lib, carriage.p, traj.op, carriage.params,
                            SensorLayout.of(carriage.params), plant.loop.actuator_lag)
    P = solve_discrete_are(model.Phi.T, model.C.T, model.Q, model.R)
    sd = np.sqrt(np.diag(P)[:model.n_x])
    rms = np.array([np.sqrt(np.mean(err[:, cv.STATE_INDEX[s]] ** 2)) for s in model.states])
    ratio = dict(zip(model.states, np.round(rms / sd, 3).tolist(), strict=True))
    assert np.all(rms <= 1.15 * sd), ratio


@pytest.mark.needs_cc
def test_the_host_tuned_libraries_hold_no_fused_multiply_add(sensed_tick, sim_lib) -> None:
    """The sense tick's host build (its lanes too) and the lanes' driver are tuned to this
    CPU (`HOST_TUNED_FLAGS`) yet must be the same IEEE operations as the firmware's and the
    scalar loop's: the disassembler finds no fused multiply-add (x86's vfmadd/vfmsub/vfnmadd/
    vfnmsub, add-sub forms included) but in the functions that compute glibc's exp and sincos
    as its FMA build does (their own fused operations, written out: maglevgen.codegen.lanes),
    none in the sense tick, its lanes, the kernels or the loop."""
    import re
    import shutil
    import subprocess

    objdump = shutil.which("objdump")
    if objdump is None:
        pytest.fail("objdump (binutils) is needed to read the compiled code")
    lanes = sim_lib._lanes_functions()[2]._name
    glibc_math = ("vexp4", "vexp8", "exp_check", "exp_lanes", "vsincos4_core",
                  "vsincos8_core", "sincos_check", "sincos_lanes", "sc_all4", "sc_all8",
                  "libm_bits", "maglev_lanes_exp_w", "maglev_lanes_sincos_w",
                  "maglev_fw_lanes_exp_w", "maglev_fw_lanes_sincos_w")
    for lib in (sensed_tick[0].firmware.library.path, lanes):
        text = subprocess.run([objdump, "-d", str(lib)], capture_output=True, text=True,
                              check=True).stdout
        fused = {}
        for name, body in re.findall(r"^[0-9a-f]+ <([^>]+)>:\n(.*?)(?=^[0-9a-f]+ <|\Z)",
                                     text, flags=re.S | re.M):
            found = re.findall(r"\tv?fn?m(?:add|sub)\S*", body)
            if found and not name.startswith(glibc_math):
                fused[name] = sorted(set(found))[:5]
        assert not fused, (lib, fused)
