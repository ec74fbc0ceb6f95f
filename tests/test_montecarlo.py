"""Monte-Carlo robustness (maglevgen.analyses.montecarlo): reproducibility, agreement with
`maglevgen
simulate`, and the contact probability's confidence interval.

References independent of the code under test: numpy's ``SeedSequence.spawn`` for the
per-sample streams; the `maglevgen simulate` command for one sample; a loop written here over
independently drawn samples, straight through the runtime (``maglev_trim``,
``maglev_lqr_gains`` and ``maglev_simulate`` via ctypes) for the contact rate; SciPy's
``binomtest(...).proportion_ci(method="wilson")`` for the interval.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import binomtest

from maglevgen.analyses.montecarlo import (
    default_chunk,
    input_label,
    interp_rows,
    make_study,
    run_dask,
    run_local,
    run_study,
    wilson,
)
from maglevgen.carriage import DerivedCarriage
from maglevgen.cli import main
from maglevgen.control.carriage_plant import Plant
from maglevgen.controllers import names
from maglevgen.derive import conventions as cv
from maglevgen.params import load_params

SPEEDS = "tolerances.speed=[8.0, 16.0]"  # across the per-axis designs' unstable range


def _same(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> None:
    assert list(a) == list(b)
    for k in a:
        if a[k].dtype.kind == "f":
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)  # NaN == NaN here
        else:
            assert a[k].tolist() == b[k].tolist(), k


@pytest.fixture(scope="module")
def small(sim_lib):
    carriage = DerivedCarriage(load_params(None, [SPEEDS]))
    study = make_study(Plant(carriage, sim_lib), ("damping", "coupled"), t_end=0.4, dt=1e-3, seed=7)
    return carriage, study, run_local(study, 6, workers=1)


def test_per_sample_streams_are_the_seed_sequences_children(small) -> None:
    """Sample i's first draw (the speed) comes from SeedSequence(seed).spawn(n)[i]."""
    _, _, cols = small
    children = np.random.SeedSequence(7).spawn(6)
    expected = [np.random.default_rng(c).uniform(8.0, 16.0) for c in children]
    speeds = cols["speed"][cols["controller"] == "coupled"]
    np.testing.assert_array_equal(speeds, expected)
    assert cols["sample"].tolist() == [i for i in range(6) for _ in range(2)]


def test_results_do_not_depend_on_workers_or_chunks(small) -> None:
    _, study, one = small
    _same(one, run_local(study, 6, workers=2, chunk=2))
    _same(one, run_local(study, 6, workers=2, chunk=5))


def test_default_chunks_fill_the_lanes(sim_lib) -> None:
    """The default chunk keeps the SIMD lanes full: from the widest lane count this CPU runs
    (the library's) on, a multiple of it, so that no chunk flies its last runs in lanes left
    idle; at most 64, and at least 4 chunks a worker for the studies the bench and the guide
    time (400 and 10^4 samples)."""
    width = sim_lib.lane_width(0)
    for n in (1, 7, 30, 100, 400, 799, 1000, 10_000, 123_457):
        for workers in (1, 2, 3, 8):
            size = default_chunk(n, workers)
            assert 1 <= size <= 64, (n, workers, size)
            if size >= width:
                assert size % width == 0, (n, workers, size, width)
    for n in (400, 10_000):
        for workers in (1, 2):
            assert -(-n // default_chunk(n, workers)) >= 4 * workers, (n, workers)


def test_dask_local_cluster_gives_the_same_results(small) -> None:
    distributed = pytest.importorskip("distributed")  # in the test extra: fails loudly in CI
    _, study, one = small
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        _same(one, run_dask(study, 6, client, chunk=2))


def _sample_p(carriage: DerivedCarriage, cols: dict[str, np.ndarray], i: int) -> np.ndarray:
    """Row ``i``'s parameter vector: the file's values with the row's sampled keys."""
    names = [e.name for e in carriage.entries]
    p = carriage.p.copy()
    for key in carriage.params.tolerances.parameters:
        if key in names:  # not a sensor's (they set the readings, not p)
            p[names.index(key)] = cols[key][i]
    return p


def _sample_run_inputs(carriage: DerivedCarriage, cols: dict[str, np.ndarray], i: int, sim_lib):
    """Row ``i``'s carriage rebuilt here: (p, its own operating point, the nominal carriage's
    at the row's speed, the row's disturbance, track.min_gap)."""
    from maglevgen.control.operating import Weights, operating_point

    p = _sample_p(carriage, cols, i)
    speed, min_gap = float(cols["speed"][i]), carriage.params.track.min_gap
    weights = Weights.of(carriage.params)
    own = operating_point(sim_lib, p, speed, min_gap, weights)
    nominal = operating_point(sim_lib, carriage.p, speed, min_gap, weights)
    dist = {s: float(cols[f"disturbance.{s}"][i]) for s in ("y", "z", "phi", "theta", "psi")}
    return p, own, nominal, dist, min_gap


def test_a_sample_flies_the_nominal_design(small, sim_lib) -> None:
    """As the firmware flies (the default): one sample's run equals, bit for bit (the same C
    call, maglev_simulate, in the batch driver and alone), `simulate` of the sampled carriage
    (its parameters rebuilt here from the row) from its own trim plus the row's disturbance,
    with the controller designed on the NOMINAL carriage at the row's speed (operating_point
    of the file's parameters: gains, reference, feed-forward); and it differs from the same
    run with the controller re-designed for the sample (what --redesign does)."""
    from maglevgen.analyses.simulate import metrics, simulate

    carriage, study, cols = small
    assert not study.redesign
    rows = np.flatnonzero((cols["controller"] == "coupled") & (cols["status"] != "no trim")
                          & (cols["status"] != "rejected"))
    i = int(rows[0])
    p, own, nominal, dist, min_gap = _sample_run_inputs(carriage, cols, i, sim_lib)
    flown = metrics(simulate(sim_lib, p, own, "coupled", 0.4, 1e-3, min_gap, dist,
                             controller_op=nominal))
    assert flown["status"] == cols["status"][i]
    assert flown["min_gap"] == cols["min_gap"][i]
    for axis in cv.AXES:
        assert flown["axes"][axis]["peak_deviation"] == cols[f"peak.{axis}"][i], axis
        assert flown["axes"][axis]["final_deviation"] == cols[f"final.{axis}"][i], axis
    redesigned = metrics(simulate(sim_lib, p, own, "coupled", 0.4, 1e-3, min_gap, dist))
    assert redesigned["min_gap"] != flown["min_gap"]


def test_a_redesigned_sample_equals_maglevgen_simulate(small, tmp_path: Path) -> None:
    """--redesign: the sample's parameters, speed and disturbance given to `maglevgen
    simulate`, which designs the controller for the parameters it is given."""
    import dataclasses

    carriage, study, _ = small
    cols = run_local(dataclasses.replace(study, redesign=True), 3, workers=1)
    rows = np.flatnonzero((cols["controller"] == "coupled")
                          & np.isin(cols["status"], ["settled", "not settled", "diverging",
                                                     "contact"]))
    assert rows.size
    i = int(rows[0])

    def v(name: str) -> str:  # the exact double as text
        return repr(float(cols[name][i]))

    cg = [repr(float(c)) for c in carriage.params.vehicle.cg_offset]
    cg[0], cg[2] = v("vehicle.cg_offset.x"), v("vehicle.cg_offset.z")
    sets = [f"vehicle.mass={v('vehicle.mass')}", f"vehicle.cg_offset=[{', '.join(cg)}]",
            f"halbach.remanence={v('halbach.remanence')}",
            f"circuit.resistance={v('circuit.resistance')}"]
    dist = [f"{s}={v(f'disturbance.{s}')}" for s in ("y", "z", "phi", "theta", "psi")]
    argv = ["simulate", "--controller", "coupled", "--loop", "continuous", "--speed",
            v("speed"),
            "--t-end", "0.4", "--dt", "1e-3", "--out", str(tmp_path / "sim")]
    argv += [a for s in sets for a in ("--set", s)] + [a for d in dist
                                                       for a in ("--disturbance", d)]
    assert main(argv) == 0
    run = json.loads((tmp_path / "sim" / "metrics.json").read_text())["runs"][0]
    assert run["status"] == cols["status"][i]
    assert run["min_gap"] == pytest.approx(cols["min_gap"][i], rel=1e-12)
    for axis in cv.AXES:
        ax = run["axes"][axis]
        assert ax["peak_deviation"] == pytest.approx(cols[f"peak.{axis}"][i], rel=1e-12)
        assert ax["final_deviation"] == pytest.approx(cols[f"final.{axis}"][i], rel=1e-12)
        st = cols[f"settling_time.{axis}"][i]
        assert (ax["settling_time"] is None) == bool(np.isnan(st))
        if ax["settling_time"] is not None:
            assert ax["settling_time"] == pytest.approx(st, rel=1e-12)


def _direct_contact_rate(carriage: DerivedCarriage, lib, n: int, t_end: float, dt: float) -> float:
    """Contacts over runs for the optimized damping, samples drawn here from the file's
    tolerances and run through the runtime's ctypes functions alone."""
    tol = carriage.params.tolerances
    names = [e.name for e in carriage.entries]
    rng = np.random.default_rng(2024)
    trim_fn, gains_fn = lib.function("maglev_trim"), lib.function("maglev_lqr_gains")
    dyn, gaps_fn = lib.function("maglev_dynamics"), lib.function("maglev_gaps")
    n_u, n_g = dyn.shapes_in[1][0], gaps_fn.shapes_out[0][0]
    axes = [cv.STATE_INDEX[s] for s in ("y", "z", "phi", "theta", "psi")]
    min_gap = carriage.params.track.min_gap
    runs = contacts = 0
    for _ in range(n):
        v = rng.uniform(*tol.speed)
        x_dist = np.zeros(12)
        for s, a in tol.disturbance.items():
            x_dist[cv.STATE_INDEX[s]] = rng.uniform(-a, a)
        p = carriage.p.copy()
        for key, t in tol.parameters.items():
            if key not in names:
                continue  # a sensor's: this loop reads the exact state
            if t.normal is not None:
                z = rng.standard_normal()
                while abs(z) > 4:
                    z = rng.standard_normal()
                step = t.normal * z
            else:
                step = rng.uniform(-t.uniform, t.uniform)
            p[names.index(key)] += step
        x_trim, f_prop = (a.ravel() for a in trim_fn(v, p))
        u = np.zeros(n_u)
        u[0] = f_prop[0]
        acc = dyn(x_trim, u, p)[0].ravel()[6:]
        if not (np.all(np.isfinite(acc)) and np.max(np.abs(acc)) < 1e-8
                and gaps_fn(x_trim, p)[0].min() >= min_gap):
            continue  # no trim at this speed: not a run
        _K, c = gains_fn(v, p)
        K_pos, K_rate = np.zeros((5, 5)), np.diag(c.ravel())
        x0 = x_trim + x_dist
        _, status, *_ = lib.simulate(x0, dt, round(t_end / dt), f_prop[0], K_pos.ravel("F"),
                                     K_rate.ravel("F"), x_trim[axes], p, min_gap, n_u, n_g)
        runs += 1
        contacts += status == 1  # MAGLEV_SIM_CONTACT
    return contacts / runs


def test_contact_interval_covers_an_independent_estimate(private_cache) -> None:
    """The point force law with quasi-static circuits (the paper's model), whose optimized
    damping loses roll stiffness at low speed: a contact rate worth an interval (with the
    distributed law it holds)."""
    from maglevgen.runtime.library import simulation_library

    carriage = DerivedCarriage(load_params(None, [SPEEDS, 'model.array_force="point"',
                                           'model.circuit_dynamics="quasi-static"']))
    sim_lib = simulation_library(carriage.structure)
    # --redesign: the reference below designs each sample's damping for its own parameters
    study = make_study(Plant(carriage, sim_lib), ("damping",), t_end=3.0, dt=1e-3, seed=11,
                       redesign=True)
    result = run_study(study, 80, workers=2)
    agg = result.summary["controllers"]["damping"]
    k = agg["status_counts"]["contact"]
    lo, hi = agg["contact_ci95"]
    ref = binomtest(k, agg["runs"]).proportion_ci(0.95, method="wilson")
    assert (lo, hi) == pytest.approx((ref.low, ref.high), rel=1e-12)
    assert 0.1 < agg["contact_probability"] < 0.9  # a rate worth an interval
    rate = _direct_contact_rate(carriage, sim_lib, 300, 3.0, 1e-3)
    print(f"direct {rate:.4f} in [{lo:.4f}, {hi:.4f}]")
    assert lo <= rate <= hi, (rate, lo, hi)


def test_wilson_interval_matches_scipy() -> None:
    for k, n in ((0, 10), (3, 10), (10, 10), (517, 1000)):
        ref = binomtest(k, n).proportion_ci(0.95, method="wilson")
        assert wilson(k, n) == pytest.approx((ref.low, ref.high), rel=1e-12, abs=1e-15)


def test_samples_breaking_a_cross_key_rule_are_rejected_and_counted(sim_lib) -> None:
    """A nominal gap drawn at or below track.min_gap (2 mm) is rejected, not run."""
    carriage = DerivedCarriage(load_params(None, [
        'tolerances.parameters={"arrays.3.nominal_gap" = {uniform = 0.0135}}', SPEEDS]))
    study = make_study(Plant(carriage, sim_lib), ("coupled",), t_end=0.02, dt=1e-3, seed=3)
    cols = run_local(study, 40, workers=1)
    below = cols["arrays.3.nominal_gap"] <= carriage.params.track.min_gap
    assert below.any() and not below.all()
    assert (cols["status"] == "rejected").tolist() == below.tolist()
    assert all("nominal_gap" in r for r in cols["reason"][below])


@pytest.mark.parametrize(("argv", "expected"), [
    (["--samples", "0"], "--samples 0"),
    (["--workers", "0"], "--workers 0"),
    (["--scheduler", "nowhere"], "--scheduler 'nowhere'"),
    (["--scheduler", "tcp://127.0.0.1:9"], "unreachable"),
    (["--set", 'tolerances.parameters={"vehicle.mass" = {normal = 5.0}}'],
     "tolerances.parameters.vehicle.mass"),
    (["--set", 'tolerances.parameters={"sensors.gap.resolution" = {uniform = 1e-7}}'],
     "tolerances.parameters.sensors.gap.resolution = {'uniform': 1e-07}: not an entry"),
    (["--set", 'tolerances.parameters={"sensors.imu.gyro_bias" = {normal = 5e-5}}'],
     "tolerances.parameters.sensors.imu.gyro_bias = {'normal': 5e-05}: draws values in"),
])
def test_bad_input_is_one_line_exit_2(argv, expected, capsys, tmp_path: Path) -> None:
    rc = main(["montecarlo", "--samples", "2", "--t-end", "0.01", "--out",
               str(tmp_path / "mc"), *argv])
    err = capsys.readouterr().err
    assert rc == 2, err
    lines = err.strip().splitlines()
    line = lines[-1]
    # an unreachable scheduler is found by trying it (seconds): the command's announced line
    # may come first; every other bad input is the only line
    assert len(lines) == 1 or (expected == "unreachable" and not any(
        ln.startswith("maglevgen: error") for ln in lines[:-1])), err
    assert line.startswith("maglevgen: error:") and expected in line, line
    assert not (tmp_path / "mc").exists()


def test_command_writes_table_report_and_plots(tmp_path: Path, capsys) -> None:
    out = tmp_path / "mc"
    assert main(["montecarlo", "--samples", "4", "--t-end", "0.05", "--workers", "1",
                 "--controller", "all", "--out", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert set(summary["controllers"]) == {"none", "damping", "lqr", "coupled", "spec"}
    assert sorted(p.name for p in out.iterdir()) == [
        ".maglevgen-output.json", "failures.png", "histograms.png", "montecarlo.json",
        "montecarlo.md", "samples.parquet"]
    import pyarrow.parquet as pq

    t = pq.read_table(out / "samples.parquet")
    assert t.num_rows == 4 * len(names())  # every registered controller
    assert (out / "histograms.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_chunk_whose_worker_dies_is_retried_once(small, tmp_path: Path, monkeypatch) -> None:
    """The first worker to run sample 3 dies (os._exit); the retry gives the same table. A
    worker that always dies is reported after the retry. (Worker processes are forked, so
    they see the patched function.)"""
    import multiprocessing
    import os

    from maglevgen.analyses import montecarlo

    if multiprocessing.get_start_method() != "fork":
        pytest.skip("needs forked workers to patch _prepare")  # Linux default
    _, study, one = small
    original = montecarlo._prepare  # every sample's first step, in either path
    marker = tmp_path / "died"

    def dies_once(study, index, lib=None):
        if index == 3 and not marker.exists():
            marker.write_text("x")
            os._exit(1)
        return original(study, index, lib)

    monkeypatch.setattr(montecarlo, "_prepare", dies_once)
    _same(one, run_local(study, 6, workers=2, chunk=2))
    assert marker.exists()

    def always_dies(study, index, lib=None):
        os._exit(1)

    monkeypatch.setattr(montecarlo, "_prepare", always_dies)
    with pytest.raises(montecarlo.ChunkFailedError, match="died twice"):
        run_local(study, 4, workers=2, chunk=2)


def test_scatter_axes_name_symbol_and_unit(small) -> None:
    """failures.png's axes: every sampled input labelled with a symbol or its key and the
    unit the schema gives it (vehicle.mass in kg, the resistance in ohm, a roll deviation in
    rad), never the bare column name."""
    _carriage, study, _ = small
    labels = {name: input_label(study, name) for name in study.columns}
    assert labels["speed"] == r"hold speed $v$ / (m/s)"
    assert labels["disturbance.phi"] == r"initial deviation $\Delta \phi$ / rad"
    assert labels["disturbance.y"] == r"initial deviation $\Delta y$ / m"
    expected = {"vehicle.mass": "kg", "circuit.resistance": r"$\Omega$",
                "vehicle.cg_offset.z": "m", "halbach.remanence": "T"}
    for key, unit in expected.items():  # the default file's [tolerances.parameters]
        assert labels[key] == f"{key} / {unit}"
    assert all(label != name for name, label in labels.items())


@pytest.mark.parametrize("failures", [0, 3])
def test_failure_correlation_is_reported_only_when_runs_failed(failures: int) -> None:
    """A correlation with a constant (no run failed) is undefined: montecarlo.md says there
    is none to report instead of printing +0.000 for every input."""
    from maglevgen.analyses.montecarlo import markdown

    stat = {"median": 0.1, "p95": 0.2, "max": 0.3}
    summary = {"samples": 10, "seed": 0, "t_end": 1.0, "dt": 1e-3, "speed_range": [10, 40],
               "controller_design": "as the firmware flies",
               "timing": {"runs": 10, "seconds": 1.0, "runs_per_s": 10.0, "workers": "1"},
               "controllers": {"spec": {
                   "title": "spec LQR", "runs": 10, "contact_probability": failures / 10,
                   "contact_ci95": [0.0, 0.3], "contact_causes": {},
                   "status_counts": {"settled": 10 - failures, "contact": failures},
                   "failure_probability": failures / 10,
                   "axes": {"lateral": {"settling_time": stat, "peak_deviation": stat,
                                        "final_deviation": stat}},
                   "failure_correlation": {"speed": 0.5 if failures else 0.0,
                                           "vehicle.mass": -0.25 if failures else 0.0},
                   "failures_inside_region": 0, "failures_inside_region_samples": [],
                   "worst": []}}}
    md = markdown(summary)
    if failures:
        assert "- `speed`: +0.500" in md and "- `vehicle.mass`: -0.250" in md
    else:
        assert "`speed`" not in md and "none to report (no run made contact or diverged)" in md


def test_a_start_in_contact_is_counted_apart(carriage, sim_lib, op) -> None:
    """Planted: a run from 20 mm of heave down (the start's gap below track.min_gap by the
    test's own geometry) stops at its first sample and is "starts in contact"; the default
    disturbance's run has no contact cause. In the aggregate the starts in contact leave the
    in-flight contact probability, whose interval is scipy's Wilson interval of the rest."""
    from independent_reference import contact_gaps

    from maglevgen.analyses.montecarlo import CONTACT_CAUSES, contact_cause
    from maglevgen.analyses.montecarlo_report import _in_flight
    from maglevgen.analyses.simulate import initial_state, metrics, simulate

    min_gap = carriage.params.track.min_gap
    down = {"z": -0.02}
    assert np.min(contact_gaps(carriage.params, initial_state(op, down)[1:6])) <= min_gap
    m = metrics(simulate(sim_lib, carriage.p, op, "spec", 0.05, 1e-3, min_gap, down))
    assert m["status"] == "contact"
    assert contact_cause(sim_lib, carriage.p, min_gap, m) == "starts in contact"
    m = metrics(simulate(sim_lib, carriage.p, op, "spec", 0.05, 1e-3, min_gap))
    assert contact_cause(sim_lib, carriage.p, min_gap, m) == ""

    status = np.array(["contact"] * 5 + ["settled"] * 95)
    cause = np.array([CONTACT_CAUSES[0]] * 3 + [CONTACT_CAUSES[2]] * 2 + [""] * 95)
    got = _in_flight(status, cause, 100)
    ref = binomtest(2, 97).proportion_ci(0.95, method="wilson")
    assert (got["starts_in_contact"], got["runs"], got["contacts"]) == (3, 97, 2)
    assert got["ci95"] == pytest.approx([ref.low, ref.high], rel=1e-9)


@pytest.fixture(scope="module")
def sensed_study(sim_lib):
    """A small study on the sensors: the embedded controller's sense tick on each sample."""
    from maglevgen.analyses.sim_loop import run_loop

    carriage = DerivedCarriage(load_params(None, [SPEEDS]))
    plant = Plant(carriage, sim_lib)
    tick, k_v, budget = run_loop(plant, "sensed")
    study = make_study(plant, ("spec",), t_end=0.3, dt=1e-3, seed=5, tick=tick,
                       speed_gain=k_v, force_budget=budget)
    return carriage, study, run_local(study, 4, workers=1)


def test_a_sample_on_the_sensors_has_its_own_noise_whatever_the_chunks(sensed_study,
                                                                        sim_lib) -> None:
    """Each sample's sensor noise comes from (seed, sample) alone: the rows do not depend on
    the workers or the chunks (bit for bit), and sample i's run equals `simulate` of its
    carriage at a SensedTick seeded with SeedSequence(seed, spawn_key=(i, 1))'s first word
    reading with the row's sensor draws, its plant lagging by the row's drawn actuator lag."""
    from dataclasses import replace

    from maglevgen.analyses.simulate import metrics, simulate

    carriage, study, one = sensed_study
    _same(one, run_local(study, 4, workers=2, chunk=1))
    i = int(np.flatnonzero(one["status"] != "no trim")[0])
    p, own, nominal, dist, min_gap = _sample_run_inputs(carriage, one, i, sim_lib)
    seed = int(np.random.SeedSequence(5, spawn_key=(i, 1)).generate_state(1)[0])
    drawn = tuple((k, float(one[k][i])) for k in carriage.params.tolerances.parameters
                  if k.startswith("sensors."))  # the row's sensor draws: its readings'
    tick = replace(study.tick, seed=seed, sensor_values=drawn,
                   plant_lag=float(one["actuators.time_constant"][i]))
    run = simulate(sim_lib, p, own, "spec", 0.3, 1e-3, min_gap, dist, tick=tick,
                   speed_gain=study.speed_gain, force_budget=study.force_budget,
                   controller_op=nominal)
    flown = metrics(run)
    assert flown["min_gap"] == one["min_gap"][i]
    for axis in cv.AXES:
        assert flown["axes"][axis]["peak_deviation"] == one[f"peak.{axis}"][i], axis
    other = simulate(sim_lib, p, own, "spec", 0.3, 1e-3, min_gap, dist,
                     tick=replace(tick, seed=seed + 1), speed_gain=study.speed_gain,
                     force_budget=study.force_budget, controller_op=nominal)
    assert not np.array_equal(other.x[-1], run.x[-1])  # another seed's noise, another run


GAP_NOISE = 'tolerances.parameters={"sensors.gap.noise" = {uniform = 9e-6}}'


def test_a_sensor_tolerance_sets_each_samples_readings(sim_lib) -> None:
    """A tolerance on the gap sensors' noise (10 um +- 9 um): each sample's row records its
    draw, and its run's gap readings carry that noise: the spread of successive readings'
    differences (std / sqrt(2), numpy on the recorded readings; the gaps move far less in a
    tick) is sqrt(draw^2 + resolution^2 / 12) within 6 %, whatever the other samples drew.
    The row is that run's (bit for bit), and the same sample read with the file's noise flies
    another path; the firmware's tables are the file's design either way."""
    from dataclasses import replace

    from maglevgen.analyses.montecarlo import sample_tick
    from maglevgen.analyses.sim_loop import run_loop
    from maglevgen.analyses.simulate import metrics, simulate

    carriage = DerivedCarriage(load_params(None, [SPEEDS, GAP_NOISE]))
    plant = Plant(carriage, sim_lib)
    tick, k_v, budget = run_loop(plant, "sensed")
    seconds = 1.0
    study = make_study(plant, ("spec",), t_end=seconds, dt=1e-3, seed=11, tick=tick,
                       speed_gain=k_v, force_budget=budget)
    cols = run_local(study, 3, workers=1)
    drawn = cols["sensors.gap.noise"]
    assert np.all(np.abs(drawn - 10e-6) <= 9e-6) and np.ptp(drawn) > 2e-6
    resolution = carriage.params.sensors.gap.resolution
    n_gap = len(carriage.params.sensors.gap_sensors)
    seen = []
    for i in np.flatnonzero(cols["status"] != "no trim"):
        p, own, nominal, dist, min_gap = _sample_run_inputs(carriage, cols, int(i), sim_lib)
        own_tick = sample_tick(study, int(i))
        assert own_tick.sensor_values == (("sensors.gap.noise", drawn[i]),)
        run = simulate(sim_lib, p, own, "spec", seconds, 1e-3, min_gap, dist, tick=own_tick,
                       speed_gain=k_v, force_budget=budget, controller_op=nominal)
        flown = metrics(run)
        assert flown["min_gap"] == cols["min_gap"][i]
        for axis in cv.AXES:
            assert flown["axes"][axis]["peak_deviation"] == cols[f"peak.{axis}"][i], axis
        gaps = run.sensing.readings[100:, :n_gap]
        spread = np.std(np.diff(gaps, axis=0)) / np.sqrt(2)
        expected = np.sqrt(drawn[i] ** 2 + resolution**2 / 12)
        assert spread == pytest.approx(expected, rel=0.06), (i, spread, expected)
        seen.append(spread)
        filed = simulate(sim_lib, p, own, "spec", seconds, 1e-3, min_gap, dist,
                         tick=replace(own_tick, sensor_values=()), speed_gain=k_v,
                         force_budget=budget, controller_op=nominal)
        assert not np.array_equal(filed.x, run.x)
    assert len(seen) >= 2


def test_interp_rows_is_numpys_interp_of_each_column() -> None:
    """A region's P/c at a sample's speed (`region_multiple`) interpolated over every entry
    at once: np.interp's numbers, column by column, to the last bit, at the grid's speeds,
    between them, outside the range (clamped) and with NaN entries (an empty region)."""
    rng = np.random.default_rng(5)
    xp = np.sort(rng.uniform(6.0, 40.0, 9))
    fp = rng.normal(size=(9, 100)) * 10.0 ** rng.uniform(-6, 6, (9, 100))
    fp[3, 7] = fp[6, 2] = np.nan
    fp[4:6, 9] = np.inf  # inf - inf: numpy's second formula, then the equal ends
    for x in [*rng.uniform(0.0, 50.0, 3000), *xp]:
        got = interp_rows(float(x), xp, fp)
        ref = np.array([np.interp(x, xp, fp[:, j]) for j in range(fp.shape[1])])
        assert np.array_equal(got, ref, equal_nan=True), x
