"""The Monte-Carlo batch in C (templates/maglev_batch.c, maglevgen.analyses.simulate.simulate_batch)
against today's per-sample path: every run is maglev_simulate called once per run by the
batch driver on several threads, against `simulate` calling it from Python (chunked, one
sample after another). Same inputs, so the trajectories and the study's rows must be equal
to the last bit, whatever the threads."""

from __future__ import annotations

import math

import numpy as np
import pytest

from maglevgen.analyses.montecarlo import make_study, run_sample, run_samples_batch
from maglevgen.analyses.simulate import (
    LoopSetting,
    Weights,
    operating_point,
    simulate,
    simulate_batch,
)
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.sampled import Tick
from maglevgen.runtime.runs import BatchBuffers


@pytest.mark.needs_cc
@pytest.mark.parametrize("tick", [None, Tick(250.0, 1), LoopSetting(250.0, 1, 2e-3)],
                         ids=["continuous", "ticked", "firmware"])
def test_batch_runs_equal_the_per_sample_runs(carriage, sim_lib, op, tick) -> None:
    """Three runs (two controllers at the nominal parameters, one of them again on a 4 %
    heavier carriage with its own trim and gains), with the speed loop and a force budget on
    the ticked loop, on two threads: x, u, gaps, status and saturated time equal. On the
    firmware loop (the actuator lag, the tick's law) the second controller is `spec`, its
    design at the tick (K_lag and K_delay through the loop's pointers, per run)."""
    p2 = carriage.p.copy()
    p2[carriage.structure.param_names.index("vehicle.mass")] *= 1.04
    op2 = operating_point(sim_lib, p2, op.speed, carriage.params.track.min_gap,
                          Weights.of(carriage.params))
    dist = {"z": 2e-3, "phi": 4e-3}
    second = "spec" if isinstance(tick, LoopSetting) else "coupled"
    jobs = [(carriage.p, op, "lqr", dist), (carriage.p, op, second, dist),
            (p2, op2, "lqr", {"y": -1e-3})]
    kw = {"tick": tick, "speed_gain": 500.0 if tick else 0.0,
          "force_budget": 2e3 if tick else None}
    min_gap = carriage.params.track.min_gap
    got = simulate_batch(sim_lib, jobs, 0.3, 1e-3, min_gap, threads=2, **kw)
    for (p, o, c, d), b in zip(jobs, got, strict=True):
        a = simulate(sim_lib, p, o, c, 0.3, 1e-3, min_gap, d, **kw)
        assert a.status == b.status
        assert a.saturated_time == b.saturated_time
        for name in ("x", "u", "gaps"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), (c, name)


@pytest.mark.needs_cc
def test_batch_study_rows_equal_the_per_sample_rows(carriage, sim_lib) -> None:
    """Five samples of a study (seed 5, two controllers) through run_samples_batch on two
    threads and through run_sample one by one: the same rows, NaN where NaN."""
    study = make_study(Plant(carriage, sim_lib), ("damping", "lqr"), t_end=0.2, dt=1e-3, seed=5)
    want = [r for i in range(5) for r in run_sample(study, i, sim_lib)]
    got = run_samples_batch(study, range(5), sim_lib, threads=2)
    assert len(got) == len(want) == 10
    for a, b in zip(want, got, strict=True):
        assert a.keys() == b.keys()
        for k in a:
            same = (a[k] == b[k] or (isinstance(a[k], float) and math.isnan(a[k])
                                     and math.isnan(b[k])))
            assert same, (k, a[k], b[k])


@pytest.mark.needs_cc
def test_runs_into_kept_buffers_equal_the_per_sample_runs(carriage, sim_lib, op) -> None:
    """`BatchBuffers` kept across calls (a Monte-Carlo worker's): a batch of three firmware-
    loop runs, then one of two others into the same memory (filled with NaN at first, so a
    row the C left unwritten would show): every run equal to `simulate`'s own, the second
    batch's untouched by the first's values, and the first's runs views that the second
    call overwrote (the contract: good until the next call)."""
    tick = LoopSetting(250.0, 1, 2e-3)
    kw = {"tick": tick, "speed_gain": 500.0, "force_budget": 2e3}
    min_gap = carriage.params.track.min_gap
    buffers = BatchBuffers()
    batches = [[(carriage.p, op, "spec", {"z": 2e-3}), (carriage.p, op, "lqr", {"phi": 4e-3}),
                (carriage.p, op, "spec", {"y": -1e-3})],
               [(carriage.p, op, "lqr", {"z": -1e-3}), (carriage.p, op, "spec", {"psi": 3e-3})]]
    first = None
    for jobs in batches:
        got = simulate_batch(sim_lib, jobs, 0.3, 1e-3, min_gap, threads=1, buffers=buffers,
                             **kw)
        for (p, o, c, d), b in zip(jobs, got, strict=True):
            a = simulate(sim_lib, p, o, c, 0.3, 1e-3, min_gap, d, **kw)
            assert a.status == b.status
            for name in ("x", "u", "gaps"):
                assert np.array_equal(getattr(a, name), getattr(b, name)), (c, name)
        if first is None:
            first = got[0].x.copy(), got[0].x
    assert first is not None
    assert not np.array_equal(first[0], first[1])  # the first batch's view: overwritten


def test_sensed_runs_into_kept_buffers_equal_the_per_sample_runs(carriage, sim_lib, op,
                                                                 sensed_tick) -> None:
    """On the sensors, the runs' noise kept too (`BatchBuffers.noise`, reused by the next
    call): two batches of sensed runs with their own seeds into the same buffers, every run's
    noise, states, inputs and gaps equal to `simulate`'s own run with a fresh noise array of
    the same seed, and the first batch's noise overwritten by the second's (the contract)."""
    from dataclasses import replace

    tick, k_v, budget = sensed_tick
    kw = {"speed_gain": k_v, "force_budget": budget}
    min_gap = carriage.params.track.min_gap
    buffers = BatchBuffers()
    batches = [([(carriage.p, op, "spec", {"z": 2e-3}), (carriage.p, op, "spec", {"y": -1e-3})],
                [11, 12]),
               ([(carriage.p, op, "spec", {"psi": 3e-3})], [13])]
    first = None
    for jobs, seeds in batches:
        got = simulate_batch(sim_lib, jobs, 0.2, 1e-3, min_gap, tick=tick, threads=1,
                             seeds=seeds, buffers=buffers, **kw)
        for (p, o, c, d), s, b in zip(jobs, seeds, got, strict=True):
            a = simulate(sim_lib, p, o, c, 0.2, 1e-3, min_gap, d,
                         tick=replace(tick, seed=s), **kw)
            assert a.status == b.status
            assert np.array_equal(a.sensing.noise, b.sensing.noise)
            for name in ("x", "u", "gaps"):
                assert np.array_equal(getattr(a, name), getattr(b, name)), (s, name)
        if first is None:
            first = got[0].sensing.noise.copy(), got[0].sensing.noise
    assert first is not None
    assert np.shares_memory(first[1], buffers.noise(0, first[1].shape))
    assert not np.array_equal(first[0], first[1])  # the first batch's noise: overwritten
