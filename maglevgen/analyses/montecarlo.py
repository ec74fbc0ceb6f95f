"""Monte-Carlo robustness over the carriage's tolerances (`maglevgen montecarlo`).

Each sample draws the parameters listed in the file's ``[tolerances]`` (normal, truncated at
+-4 sigma, or uniform about the file's value; entries of the parameter vector, and beside it
the loop's, maglevgen.params.LOOP_TOLERANCES: the actuators' lag, the sensors' noises and
biases), a hold speed (by default uniform over the
envelope's [v_min, v_max]) and an initial disturbance; then, per controller, one closed-loop
RK4 run (the hold scenario of `maglevgen simulate`) from the sampled carriage's own trim plus
the disturbance, all in the compiled run-time-parameter C (the parameters are arguments of the
C, so nothing is regenerated or recompiled), and the run's status and per-axis metrics
(maglevgen.analyses.simulate.run_summary).

As the firmware flies (the default): the controller is the NOMINAL carriage's design at the
sample's speed, its gains, its reference and its feed-forward propulsion (what the firmware's
table and schedule hold, designed once on the file's values), flying the sampled carriage,
which the firmware does not know. On the sensors (``--loop sensed``) each sample's readings
carry its own noise (seeded per sample) drawn with its sampled sensor entries, the IMU's
bias its sampled magnitude with a sign drawn per axis; the firmware's Kalman gains stay the
design on the file's sensors (a tolerance is what the real sensor does, not what the filter
was designed for). Likewise a drawn actuator lag is the sampled plant's (the C loop's tau):
the firmware's K_lag, K_delay, its prediction of the lagged forces and its sense tick's
tables stay the design on the file's lag (`sample_tick`). A loop on the exact state reads no
sensor: its samples' sensor draws are recorded, not flown (the continuous law's, the lag's
too). ``--redesign`` (`Study.redesign`) instead re-trims and re-designs the controller for each
sample's own parameters (the drawn lag included), as if the firmware knew them: an optimistic
bound, named as such in the output.

Reproducibility: sample i draws from ``SeedSequence(seed, spawn_key=(i,))`` (numpy's i-th
child of the seed), so its result depends on (seed, i) alone, never on the worker count or
the chunking. Chunks of samples run in worker processes (``concurrent.futures``; the C runs
without the GIL but the per-sample Python, trim checks and metrics would serialise threads)
or on a Dask cluster (``--scheduler tcp://host:port`` or ``local`` for a LocalCluster); a
chunk whose worker died is retried once, then reported.

Bad samples: the file is refused (exit 2) when a tolerance can draw a value outside its key's
range (maglevgen.params); a sample that breaks a rule across keys (the inertia tensor's, a
nominal gap not above track.min_gap) is rejected and counted (status ``rejected``), and one
without a trim at its speed is counted as ``no trim``. Neither enters the contact rate.
"""

from __future__ import annotations

import json
import math
import os
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from maglevgen.analyses.montecarlo_report import (
    CONTACT_CAUSES,
    aggregate,
    input_label,
    markdown,
    plots,
    summary_json,
    table,
    table_files,
    wilson,
)
from maglevgen.analyses.montecarlo_report import FAILURES as FAILURES
from maglevgen.analyses.montecarlo_report import SAMPLE_STATUSES as SAMPLE_STATUSES
from maglevgen.analyses.montecarlo_report import STATUSES as STATUSES
from maglevgen.analyses.montecarlo_report import WORST as WORST
from maglevgen.analyses.montecarlo_report import Z95 as Z95
from maglevgen.analyses.montecarlo_study import Columns, Study
from maglevgen.analyses.sim_loop import LoopSetting, SensedTick
from maglevgen.analyses.simulate import (
    control_loop,
    rk4_stability_limit,
    run_summary,
    simulate,
    simulate_batch,
)
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.operating import (
    REDUCED_STATES,
    OperatingPoint,
    Weights,
    checked_trim,
    operating_point,
)
from maglevgen.derive import conventions as cv
from maglevgen.errors import InputError, MaglevError, NoTrimError
from maglevgen.infrastructure.workers import process_pool
from maglevgen.params import ACTUATOR_LAG, LOOP_TOLERANCES, SENSOR_TOLERANCES
from maglevgen.runtime.runs import BatchBuffers

MAX_SAMPLES = 10_000_000


def sample_inputs(study: Study, index: int) -> np.ndarray:
    """Sample ``index``'s draws (speed, disturbances, parameters) from its own SeedSequence."""
    from maglevgen.params import NORMAL_TRUNCATION

    rng = np.random.default_rng(np.random.SeedSequence(study.seed, spawn_key=(index,)))
    lo, hi = study.speed
    out = [rng.uniform(lo, hi)]
    out += [rng.uniform(-a, a) for _, a in study.disturbance]
    beside = dict(study.loop_values)
    for name, sigma, half in zip(study.keys, study.sigma, study.half, strict=True):
        nominal = beside[name] if name in beside else study.p[study.names.index(name)]
        if math.isnan(sigma):
            out.append(nominal + rng.uniform(-half, half))
            continue
        z = rng.standard_normal()
        while abs(z) > NORMAL_TRUNCATION:  # truncated normal by rejection
            z = rng.standard_normal()
        out.append(nominal + sigma * z)
    return np.array(out)


def _assign(data: dict, entry: str, value: float) -> None:
    """Set a parameter vector entry (``vehicle.cg_offset.z``) in a model_dump dict."""
    node: Any = data
    parts = entry.split(".")
    for i, part in enumerate(parts):
        last = i == len(parts) - 1
        if isinstance(node, list):
            j = "xyz".index(part) if part in ("x", "y", "z") and len(node) == 3 else int(part)
            node[j] = value
            return
        if last:
            node[part] = value
            return
        node = node[part]


# entries that a rule across keys reads (maglevgen.params.Parameters._physical_inertia): a
# sample that draws one of them is validated as a whole file would be; every other entry
# stays in its own range by the check of the file (Parameters._tolerances_within_limits)
CROSS_KEY_RULES = ("vehicle.inertia_cg.", "track.min_gap", ".nominal_gap")


def sample_parameters(study: Study, draws: np.ndarray) -> np.ndarray | str:
    """The sample's parameter vector; the reason when it is rejected (a rule across keys
    broken)."""
    from maglevgen.params import validate

    p = np.array(study.p)
    values = draws[1 + len(study.disturbance):]
    beside = dict(study.loop_values)
    for name, value in zip(study.keys, values, strict=True):
        if name not in beside:
            p[study.names.index(name)] = value
    if any(r in k for k in study.keys for r in CROSS_KEY_RULES):
        data = json.loads(json.dumps(study.data))  # a deep copy
        for name, value in zip(study.keys, values, strict=True):
            _assign(data, name, float(value))
        try:
            validate(data, "sample")
        except InputError as exc:
            return str(exc).removeprefix("sample: ")
    return p


def sample_sensors(study: Study, draws: np.ndarray) -> tuple[tuple[str, float], ...]:
    """The sample's drawn sensor entries (key, value), in file order: what its run's readings
    carry (`SensedTick.sensor_values`)."""
    values = draws[1 + len(study.disturbance):]
    return tuple((k, float(v)) for k, v in zip(study.keys, values, strict=True)
                 if k in SENSOR_TOLERANCES)


def sample_lag(study: Study, draws: np.ndarray) -> float | None:
    """The sample's drawn actuator lag [s] (maglevgen.params.ACTUATOR_LAG), None where the
    file gives it no tolerance: what its run's plant lags by (`sample_tick`)."""
    if ACTUATOR_LAG not in study.keys:
        return None
    return float(draws[1 + len(study.disturbance) + study.keys.index(ACTUATOR_LAG)])


def run_sample(study: Study, index: int, lib=None) -> list[dict]:
    """One row per controller: the draws, the status and the per-axis metrics."""
    lib = lib or study.library()
    prepared = _prepare(study, index, lib)
    if isinstance(prepared, list):
        return prepared
    p, op, design, disturbance, row = prepared
    return [_run_row(study, lib, p, row, c,
                     simulate(lib, p, op, c, study.t_end, study.dt, study.min_gap, disturbance,
                              tick=sample_tick(study, index), speed_gain=study.speed_gain,
                              force_budget=study.force_budget, controller_op=design),
                     op, disturbance)
            for c in study.controllers]


def run_samples_batch(study: Study, indices: Sequence[int], lib=None,
                      threads: int = 0, buffers: BatchBuffers | None = None) -> list[dict]:
    """`run_sample`'s rows of every sample of ``indices``, in order, with the closed-loop runs
    of all of them in one call of the C batch driver (maglevgen.analyses.simulate.simulate_batch) on
    ``threads`` threads (0: every core): the same rows (each run is the same maglev_simulate
    call). The draws, the trim and the gains of each sample come first, in Python and the
    library's C, as `run_sample` makes them. ``buffers``: the runs' rows written there
    (`BatchBuffers`; every row is reduced before this returns)."""
    lib = lib or study.library()
    out: list[list[dict] | None] = []
    jobs, owners, ticks = [], [], []
    for i in indices:
        prepared = _prepare(study, int(i), lib)
        if isinstance(prepared, list):
            out.append(prepared)
            continue
        p, op, design, disturbance, row = prepared
        out.append(None)
        for c in study.controllers:
            jobs.append((p, op, c, disturbance, design))
            owners.append((len(out) - 1, row))
            ticks.append(sample_tick(study, int(i)))
    trajectories = simulate_batch(lib, jobs, study.t_end, study.dt, study.min_gap,
                                  tick=study.tick, speed_gain=study.speed_gain,
                                  force_budget=study.force_budget, threads=threads,
                                  ticks=ticks, buffers=buffers)
    runs: dict[int, list[dict]] = {}
    for (k, row), (p, op, c, d, _), traj in zip(owners, jobs, trajectories, strict=True):
        runs.setdefault(k, []).append(_run_row(study, lib, p, row, c, traj, op, d))
    return [r for k, rows in enumerate(out) for r in (rows if rows is not None else runs[k])]


def _noise_seed(study: Study, index: int) -> int:
    """Sample ``index``'s sensor noise seed (a run on the sensors): from (seed, index) alone,
    a stream apart from the sample's draws."""
    return int(np.random.SeedSequence(study.seed, spawn_key=(index, 1)).generate_state(1)[0])


def sample_tick(study: Study, index: int):
    """The study's tick for sample ``index``: at a `LoopSetting` with the sample's drawn
    actuator lag as the plant's (``plant_lag``; the firmware's K_lag, K_delay and lag
    prediction stay the design on the file's lag; with ``study.redesign`` the design's lag
    too, re-designed for it); at a `SensedTick` also with the sample's own noise and its
    drawn sensor entries (the firmware's tables stay the design on the file's). The
    continuous loop (no tick) flies no lag: its draws are recorded, not flown."""
    tick = study.tick
    if not isinstance(tick, LoopSetting):
        return tick
    draws = sample_inputs(study, index)
    lag = sample_lag(study, draws)
    if lag is not None:
        tick = replace(tick, lag=lag) if study.redesign else replace(tick, plant_lag=lag)
    if not isinstance(tick, SensedTick):
        return tick
    return replace(tick, seed=_noise_seed(study, index),
                   sensor_values=sample_sensors(study, draws))


def _prepare(study: Study, index: int, lib):
    """Sample ``index``'s (p, its operating point, the controller's operating point (the
    nominal carriage's at the sample's speed, or the sample's own with ``study.redesign``),
    disturbance, row maker), or its rows when it has no run (rejected, no trim)."""
    draws = sample_inputs(study, index)
    base = {"sample": index, **dict(zip(study.columns, draws.tolist(), strict=True))}
    disturbance = {s: float(d) for (s, _), d in
                   zip(study.disturbance, draws[1:1 + len(study.disturbance)], strict=True)}
    p = sample_parameters(study, draws)

    def row(controller: str, status: str, reason: str = "", m: dict | None = None) -> dict:
        r = {**base, "controller": controller, "status": status, "reason": reason,
             "contact_cause": "",
             "min_gap": math.nan, "speed_at_contact": math.nan, "speed_error": math.nan,
             "saturated_time": math.nan, "region_multiple": math.nan}
        for axis in cv.AXES:
            ax = (m or {}).get("axes", {}).get(axis, {})
            st = ax.get("settling_time")
            r[f"settling_time.{axis}"] = math.nan if st is None else float(st)
            r[f"peak.{axis}"] = float(ax.get("peak_deviation", math.nan))
            r[f"final.{axis}"] = float(ax.get("final_deviation", math.nan))
        if m is not None:
            r["min_gap"] = m["min_gap"]
            r["speed_at_contact"] = (math.nan if m["speed_at_contact"] is None
                                     else m["speed_at_contact"])
            r["speed_error"] = math.nan if m["speed_error"] is None else m["speed_error"]
            r["saturated_time"] = m["saturated_time"]
        return r

    if isinstance(p, str):
        return [row(c, "rejected", p) for c in study.controllers]
    try:
        op = operating_point(lib, p, float(draws[0]), study.min_gap, study.weights)
    except NoTrimError as exc:
        return [row(c, "no trim", str(exc)) for c in study.controllers]
    design = op if study.redesign else nominal_design(study, lib, float(draws[0]))
    return p, op, design, disturbance, row


def nominal_design(study: Study, lib, speed: float) -> OperatingPoint:
    """The nominal carriage's operating point at ``speed``: the design the firmware flies
    every sampled carriage with (its gains, reference and feed-forward)."""
    return operating_point(lib, np.array(study.p), speed, study.min_gap, study.weights)


def _run_row(study: Study, lib, p, row, controller: str, traj, op,
             disturbance: dict[str, float]) -> dict:
    """The row of one controller's run: its status and `run_summary`, the cause of a contact,
    the initial deviation as a multiple of the region at its speed."""
    m = run_summary(traj)
    r = row(controller, m["status"], m["event"] or "", m)
    r["contact_cause"] = contact_cause(lib, p, study.min_gap, m)
    r["region_multiple"] = region_multiple(study, controller, op.speed, disturbance)
    return r


def region_multiple(study: Study, controller: str, speed: float,
                    disturbance: dict[str, float]) -> float:
    """The sample's initial deviation as a multiple of the nominal region at its speed:
    sqrt(dx' (P / c) dx) with P / c interpolated linearly in speed between the region's
    speeds (clamped at the ends); below 1 the deviation lies inside the region, so a failure
    there contradicts it. NaN without regions, inf where the region is empty."""
    if not study.regions or controller not in study.regions:
        return math.nan
    speeds, M = study.regions[controller]
    dx = np.array([disturbance.get(s, 0.0) for s in REDUCED_STATES])
    Mv = interp_rows(speed, speeds, M.reshape(M.shape[0], -1))
    if not np.all(np.isfinite(Mv)):
        return math.inf
    return float(np.sqrt(max(dx @ Mv.reshape(M.shape[1:]) @ dx, 0.0)))


def interp_rows(x: float, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """np.interp(x, xp, fp[:, j]) of every column j of ``fp`` at once (xp increasing, x
    clamped to its ends), in numpy's operations: fp[i] at a grid point, else
    slope (x - xp[i]) + fp[i] with slope (fp[i+1] - fp[i]) / (xp[i+1] - xp[i]) and, where that
    is NaN, from the right end, then fp[i] where the ends are equal."""
    if x <= xp[0]:
        return fp[0].copy()
    if x >= xp[-1]:
        return fp[-1].copy()
    i = int(np.searchsorted(xp, x, side="right")) - 1
    if xp[i] == x:
        return fp[i].copy()
    with np.errstate(invalid="ignore"):  # NaN or inf entries, as np.interp: no warning
        slope = (fp[i + 1] - fp[i]) / (xp[i + 1] - xp[i])
        out = slope * (x - xp[i]) + fp[i]
        nan = np.isnan(out)
        if nan.any():
            out[nan] = (slope * (x - xp[i + 1]) + fp[i + 1])[nan]
            flat = nan & (fp[i] == fp[i + 1])
            out[flat] = fp[i][flat]
    return out


def study_regions(plant: Plant, controllers: Sequence[str],
                  speed: tuple[float, float]) -> dict:
    """`Study.regions`: each controller's sampled region (maglevgen.analyses.roa, BUILD_SAMPLING, no
    boundary runs: the study's own runs are the test of it) at BUILD_SPEEDS speeds."""
    from maglevgen.analyses import roa

    speeds = np.linspace(speed[0], speed[1], roa.BUILD_SPEEDS)
    out = {}
    for c in controllers:
        reg = roa.region_of_attraction(plant, c, speeds, roa.BUILD_SAMPLING,
                                       loop=None)
        M = np.array([r.P / r.level if r.level > 0 else np.full(r.P.shape, np.nan)
                      for r in reg.regions])
        out[c] = (speeds, M)
    return out


# why a run touched the track: its disturbed start was already in contact (no controller
# acted: a finding about the sampled start, not the loop), its speed fell below the sample's
# lift-off (no trim there: the carriage slowed down and landed), or the levitation loop lost
# it at a flying speed


def contact_cause(lib, p, min_gap: float, m: dict) -> str:
    """"" for a run without contact, else one of CONTACT_CAUSES: "starts in contact" when the
    run stopped at its first sample (the start's gap at or below min_gap), else whether the
    sample has a trim at its speed at contact (the Newton trim in C,
    `operating.checked_trim`)."""
    if m["status"] != "contact" or m["speed_at_contact"] is None:
        return ""
    if m["steps"] == 0:
        return CONTACT_CAUSES[0]
    try:
        checked_trim(lib, p, float(m["speed_at_contact"]), min_gap)
    except NoTrimError:
        return CONTACT_CAUSES[0]
    return CONTACT_CAUSES[1]


def run_chunk(study: Study, indices: Sequence[int]) -> Columns:
    """The table of a chunk of samples (what a worker process or a Dask task runs): columns,
    so that what travels back and what a large study holds stay small."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # overflow in a diverging sample: its status says so
        # the chunk's runs in one call of the C batch driver, on one thread: the workers (or
        # Dask) spread the chunks over the cores; each chunk's rows into the memory of the
        # process's (thread's) previous chunk
        return table(run_samples_batch(study, indices, threads=1, buffers=_worker_buffers()))


_WORKER = threading.local()


def _worker_buffers() -> BatchBuffers:
    """This thread's `BatchBuffers`, kept across the chunks it runs."""
    if not hasattr(_WORKER, "buffers"):
        _WORKER.buffers = BatchBuffers()
    return _WORKER.buffers


# ------------------------------------------------------------------------------ execution

Tick = Callable[[int], None]
def concat(tables: list[Columns]) -> Columns:
    """Tables of consecutive chunks as one."""
    return {k: np.concatenate([t[k] for t in tables]) for k in tables[0]}


def _chunks(n: int, size: int) -> list[range]:
    return [range(i, min(n, i + size)) for i in range(0, n, size)]


#: the runs the C batch flies at once at most (templates/maglev_lanes.c's LANES_MAX: 8 lanes
#: of AVX-512; the 4 and 2 lanes of other CPUs divide it)
LANE_BATCH = 8


def default_chunk(n: int, workers: int) -> int:
    """Enough chunks to balance the workers (about 8 per worker), few enough that the
    per-call overhead stays small (at most 64 samples a chunk), and a multiple of the lanes'
    width where it reaches it (of the largest power of 2 up to LANE_BATCH it reaches): the
    lanes fly a chunk's runs W at a time, and a chunk of 25 would fly its last run alone in
    8 lanes (at the cost of 8)."""
    size = max(1, min(64, math.ceil(n / (8 * max(1, workers)))))
    step = 1 << (min(size, LANE_BATCH).bit_length() - 1)
    return size // step * step


class ChunkFailedError(MaglevError):
    """A chunk failed on its retry too (a worker that keeps dying): exit 1."""


def run_local(study: Study, n: int, workers: int, chunk: int | None = None,
              tick: Tick | None = None) -> Columns:
    """Samples 0..n-1 on ``workers`` processes of this machine (1: in this process)."""
    size = chunk or default_chunk(n, workers)
    chunks = _chunks(n, size)
    results: dict[int, Columns] = {}
    if workers <= 1:
        lib, buffers = study.library(), BatchBuffers()
        for k, c in enumerate(chunks):
            results[k] = table(run_samples_batch(study, c, lib, threads=1, buffers=buffers))
            if tick:
                tick(len(c))
        return concat([results[k] for k in range(len(chunks))])
    tries = dict.fromkeys(range(len(chunks)), 0)
    pending = list(range(len(chunks)))
    while pending:
        failed: list[int] = []
        with process_pool(workers) as pool:
            futures = {pool.submit(run_chunk, study, list(chunks[k])): k for k in pending}
            for fut, k in futures.items():
                try:
                    results[k] = fut.result()
                    if tick:
                        tick(len(chunks[k]))
                except BrokenProcessPool:
                    failed.append(k)  # a worker died: every unfinished chunk of the pool
        for k in failed:
            tries[k] += 1
            if tries[k] > 1:
                c = chunks[k]
                raise ChunkFailedError(f"samples {c.start} to {c.stop - 1}: the worker running "
                                       "them died twice (out of memory? a crash in the C?)")
        pending = failed
    return concat([results[k] for k in range(len(chunks))])


def dask_client(scheduler: str, workers: int):
    """A dask.distributed Client: a LocalCluster for ``local``, else the scheduler at the
    address; an InputError (exit 2) when it cannot be reached or Dask is missing."""
    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise InputError("--scheduler: needs dask.distributed (pip install "
                         "'maglevgen[montecarlo]')") from None
    if scheduler == "local":
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None)
        return Client(cluster)
    check_scheduler(scheduler)
    try:
        return Client(scheduler, timeout="5s")
    except (OSError, TimeoutError) as exc:
        raise InputError(f"--scheduler {scheduler}: unreachable ({' '.join(str(exc).split())})"
                         ) from None


#: how long a Dask study waits with no worker in the cluster before it fails [s]
#: (MAGLEVGEN_DASK_WORKER_TIMEOUT overrides it): a worker that comes back within it resumes
#: the study (the scheduler runs the lost chunks again, each chunk's result counted once)
DASK_WORKER_TIMEOUT = 120.0


def _worker_timeout() -> float:
    try:
        return max(1.0, float(os.environ.get("MAGLEVGEN_DASK_WORKER_TIMEOUT",
                                             DASK_WORKER_TIMEOUT)))
    except ValueError:
        return DASK_WORKER_TIMEOUT


def run_dask(study: Study, n: int, client, chunk: int | None = None,
             tick: Tick | None = None) -> Columns:
    """Samples 0..n-1 as chunk tasks on a Dask cluster; each task is retried once. A cluster
    left with no worker for `DASK_WORKER_TIMEOUT` seconds fails the study (ChunkFailedError,
    exit 1) naming the samples not run, instead of waiting for ever."""
    from distributed import wait

    workers = max(1, len(client.scheduler_info().get("workers", {})))
    chunks = _chunks(n, chunk or default_chunk(n, workers))
    futures = [client.submit(run_chunk, study, list(c), retries=1, pure=False) for c in chunks]
    where = {f.key: k for k, f in enumerate(futures)}
    results: dict[int, Columns] = {}
    pending = set(futures)
    limit, poll = _worker_timeout(), 1.0
    alone_since: float | None = None
    while pending:
        try:
            done, pending = wait(pending, timeout=poll, return_when="FIRST_COMPLETED")
        except TimeoutError:
            done = set()
        for fut in done:
            k = where[fut.key]
            if k in results:
                continue  # counted once, whatever the scheduler did
            try:
                results[k] = fut.result()
            except Exception as exc:
                c = chunks[k]
                raise ChunkFailedError(f"samples {c.start} to {c.stop - 1} failed twice on "
                                       f"the Dask cluster: {type(exc).__name__}: {exc}"
                                       ) from None
            if tick:
                tick(len(chunks[k]))
        if done or not pending:
            alone_since = None
            continue
        try:
            n_workers = len(client.nthreads())
        except Exception:  # the scheduler itself gone: as good as no worker
            n_workers = 0
        if n_workers:
            alone_since = None
        elif alone_since is None:
            alone_since = time.monotonic()
        elif time.monotonic() - alone_since > limit:
            left = sorted(where[f.key] for f in pending)
            raise ChunkFailedError(
                f"the Dask cluster has had no worker for {limit:.0f} s: samples "
                f"{chunks[left[0]].start} to {chunks[left[-1]].stop - 1} not run "
                f"({len(left)} of {len(chunks)} chunks; start workers and run again)")
    return concat([results[k] for k in range(len(chunks))])


# ------------------------------------------------------------------------------ the study


def make_study(plant: Plant, controllers: Sequence[str], t_end: float, dt: float,
               seed: int, tick=None, speed_gain: float = 0.0,
               force_budget: float | None = None, redesign: bool = False) -> Study:
    """The study of a carriage's [tolerances]; the speed range defaults to the envelope's.
    Refuses a step above RK4's stability limit at the range's ends (nominal parameters).
    ``tick`` (maglevgen.analyses.simulate.Tick), ``speed_gain``, ``force_budget``: how the
    controller
    runs in every sample, as in maglevgen.analyses.simulate.simulate (the defaults: at every RK4
    stage, no speed loop, no budget); ``redesign``: `Study.redesign`."""
    control_loop(dt, tick, speed_gain, force_budget, 1.0)  # refused before any sample

    carriage, lib = plant.carriage, plant.lib
    params = carriage.params
    tol = params.tolerances
    if tol.speed is not None:
        speed = (float(tol.speed[0]), float(tol.speed[1]))
    else:
        speed = plant.speed_range
    w = Weights.of(params)
    for v in speed:
        try:
            op = operating_point(lib, carriage.p, v, params.track.min_gap, w)
        except NoTrimError as exc:
            raise InputError(f"tolerances.speed: {exc}") from None
        for c in controllers:
            limit = rk4_stability_limit(np.linalg.eigvals(op.full_closed_loop(c)))
            if dt > limit:
                raise InputError(f"--dt {dt:g} s exceeds the RK4 stability limit {limit:.4g} s "
                                 f"of the {c} controller at {v:g} m/s")
    keys = tuple(tol.parameters)
    own = params.loop_values()
    return Study(
        origin=carriage.loaded.source,
        # the samples are validated without the tolerances (drawn about the file's values)
        data={k: v for k, v in params.model_dump().items() if k != "tolerances"},
        library=plant.worker_library,
        names=tuple(e.name for e in carriage.entries), p=tuple(map(float, carriage.p)),
        keys=keys,
        sigma=tuple(math.nan if t.normal is None else float(t.normal)
                    for t in tol.parameters.values()),
        half=tuple(t.half_width for t in tol.parameters.values()),
        speed=speed, disturbance=tuple((s, float(a)) for s, a in tol.disturbance.items()),
        controllers=tuple(controllers), t_end=float(t_end), dt=float(dt),
        min_gap=float(params.track.min_gap), weights=w, seed=int(seed), tick=tick,
        speed_gain=float(speed_gain), force_budget=force_budget, redesign=bool(redesign),
        regions=study_regions(plant, controllers, speed),
        loop_values=tuple((k, own[k]) for k in keys if k in LOOP_TOLERANCES))


@dataclass
class Result:
    study: Study
    n: int
    columns: dict[str, np.ndarray]
    summary: dict


def run_study(study: Study, n: int, workers: int, scheduler: str | None = None,
              chunk: int | None = None, tick: Tick | None = None) -> Result:
    """Run the n samples locally or on Dask and aggregate them."""
    if not 1 <= n <= MAX_SAMPLES:
        raise InputError(f"--samples {n}: expected 1 to {MAX_SAMPLES}")
    if workers < 1:
        raise InputError(f"--workers {workers}: expected at least 1")
    t0 = time.perf_counter()
    if scheduler is None:
        cols = run_local(study, n, workers, chunk, tick)
        where = f"{workers} local process{'es' if workers > 1 else ''}"
    else:
        client = dask_client(scheduler, workers)
        try:
            n_workers = len(client.scheduler_info().get("workers", {}))
            cols = run_dask(study, n, client, chunk, tick)
        finally:
            cluster = client.cluster if scheduler == "local" else None
            client.close()
            if cluster is not None:
                cluster.close()
        where = f"{n_workers} Dask workers ({scheduler})"
    seconds = time.perf_counter() - t0
    runs = len(cols["sample"])
    timing = {"seconds": seconds, "runs": runs, "runs_per_s": runs / seconds if seconds else 0,
              "workers": where}
    agg = aggregate(study, cols)
    return Result(study, n, cols, summary_json(study, n, agg, timing))


def output_files(result: Result) -> dict[str, str | bytes]:
    files: dict[str, str | bytes] = {
        "montecarlo.json": json.dumps(result.summary, indent=1) + "\n",
        "montecarlo.md": markdown(result.summary)}
    files.update(table_files(result.columns))
    files.update(plots(result.study, result.columns, result.summary["controllers"]))
    return files


def default_workers() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (
        os.cpu_count() or 1)


__all__ = ["CONTACT_CAUSES", "FAILURES", "MAX_SAMPLES", "ChunkFailedError",
           "check_scheduler", "contact_cause", "default_chunk", "default_workers",
           "input_label", "interp_rows", "make_study", "markdown", "output_files",
           "run_dask", "run_local", "run_sample", "run_samples_batch", "run_study",
           "sample_inputs", "sample_parameters", "sample_tick", "wilson"]


def check_scheduler(scheduler: str | None) -> None:
    """``--scheduler``'s form: None, "local" or a Dask address (checked before any work, so
    that a misspelt one is the only line on stderr)."""
    import re

    if scheduler is None or scheduler == "local":
        return
    m = (re.fullmatch(r"(tcp|tls)://[A-Za-z0-9_.\-\[\]:]+:(\d{1,5})", scheduler)
         if isinstance(scheduler, str) else None)
    if m is None or not 1 <= int(m.group(2)) <= 65535:
        raise InputError(f"--scheduler {scheduler!r}: expected 'local' or tcp://HOST:PORT "
                         "(a port from 1 to 65535)")
