"""maglevgen.infrastructure.workers: jobs in a forked child through concurrent.futures, their
failures, and
the pending-file view (replaces tests/test_background.py, test for test).

The reference for a result is the same function called in this process.
"""

from __future__ import annotations

import multiprocessing
import os
import threading
import time

import numpy as np
import pytest

from maglevgen.errors import MaglevError
from maglevgen.infrastructure.workers import PendingFiles, Shared, child, submit


def _pid_and_sum(values: np.ndarray) -> tuple[int, float]:
    return os.getpid(), float(np.sum(values))


def _fails() -> None:
    raise ValueError("no trim at 1e9 m/s")


def _dies() -> None:
    os._exit(3)


def _sleep_then(value: int, seconds: float) -> int:
    time.sleep(seconds)
    return value


def _apply(fn, *args):
    return fn(*args)


def _double(a: np.ndarray) -> np.ndarray:
    return 2 * a


def _no_fork(monkeypatch) -> None:
    monkeypatch.setattr(multiprocessing, "get_all_start_methods", lambda: ["spawn"])


def test_result_comes_from_a_child_and_equals_the_direct_call() -> None:
    data = np.linspace(0.0, 1.0, 1001)
    with child() as pool:
        job = submit(pool, "summing", _pid_and_sum, data)
        pid, total = job.result()
        assert job.result() == (pid, total)  # a second call returns the same result
    assert pid != os.getpid()
    assert total == _pid_and_sum(data)[1]


def test_without_fork_the_work_runs_here(monkeypatch) -> None:
    _no_fork(monkeypatch)
    with child() as pool:
        assert submit(pool, "summing", _pid_and_sum, np.ones(4)).result() == (os.getpid(), 4.0)


def test_a_failure_in_the_child_is_one_line_naming_the_job_and_the_error() -> None:
    with child() as pool, pytest.raises(MaglevError) as err:
        submit(pool, "drawing the figures", _fails).result()
    msg = str(err.value)
    assert msg == "drawing the figures failed: ValueError: no trim at 1e9 m/s"
    assert "\n" not in msg and err.value.exit_code == 1


def test_a_child_that_dies_is_reported() -> None:
    with child() as pool, pytest.raises(MaglevError, match="dying failed: the child process "
                                                           "ended"):
        submit(pool, "dying", _dies).result()


def test_leaving_the_block_by_an_error_stops_the_child() -> None:
    start = time.monotonic()
    with pytest.raises(KeyError), child() as pool:
        jobs = [submit(pool, "sleeping", _sleep_then, i, 600.0) for i in range(3)]
        time.sleep(0.2)  # the first job has started
        raise KeyError("an error elsewhere")
    # not the 600 s of the first job; a loaded machine's slack for the stop (idle: under 1 s)
    assert time.monotonic() - start < 300.0
    for job in jobs:
        assert job.future.cancelled() or job.future.exception() is not None


def test_later_jobs_run_in_the_same_child_in_order() -> None:
    with child() as pool:
        jobs = [submit(pool, f"job {i}", _pid_and_sum, np.full(3, float(i))) for i in range(4)]
        results = [j.result() for j in jobs]
    assert len({pid for pid, _ in results}) == 1 and results[0][0] != os.getpid()
    assert [s for _, s in results] == [0.0, 3.0, 6.0, 9.0]


def test_large_jobs_and_results_cross_without_deadlock() -> None:
    big = np.random.default_rng(1).standard_normal(2_000_000)  # 16 MB each way
    with child() as pool:
        jobs = [submit(pool, "doubling", _double, big) for _ in range(3)]
        for job in jobs:
            np.testing.assert_array_equal(job.result(), 2 * big)


def test_a_failing_job_names_itself_and_the_worker_goes_on() -> None:
    with child() as pool:
        bad = submit(pool, "the bad one", _fails)
        good = submit(pool, "the good one", _pid_and_sum, np.ones(2))
        with pytest.raises(MaglevError, match=r"^the bad one failed: ValueError"):
            bad.result()
        assert good.result()[1] == 2.0


def test_a_shared_argument_is_the_data_the_child_was_forked_with() -> None:
    """A lambda and a lock cannot be pickled: the child holds them because it was forked
    with them."""
    lock = threading.Lock()
    with child(shared={"f": lambda: 42, "lock": lock}) as pool:
        assert submit(pool, "calling", _apply, Shared("f")).result() == 42
        pid = submit(pool, "locking", _apply, lambda_free_pid, Shared("lock")).result()
    assert pid != os.getpid()


def lambda_free_pid(lock) -> int:
    with lock:
        return os.getpid()


def test_without_fork_a_shared_argument_is_the_data_itself(monkeypatch) -> None:
    _no_fork(monkeypatch)
    data = object()
    with child(shared={"d": data}) as pool:
        assert submit(pool, "identity", _apply, lambda x: x, Shared("d")).result() is data


def test_a_job_that_cannot_be_sent_fails_naming_itself() -> None:
    with child() as pool, pytest.raises(MaglevError, match=r"^sending a lambda failed: "):
        submit(pool, "sending a lambda", _apply, lambda: 1).result()


def test_pending_files_wait_for_the_job_only_when_a_pending_file_is_read(monkeypatch) -> None:
    calls = []

    class Lazy:  # a job that runs when its result is first asked for
        def result(self) -> dict[str, bytes]:
            calls.append(1)
            return {"fig.png": b"png", "traj.csv": b"csv"}

    job = Lazy()
    files = PendingFiles({"metrics.json": b"{}"}, {"fig.png": job, "traj.csv": job})
    assert "fig.png" in files and "metrics.json" in files and "other" not in files
    assert sorted(files) == ["fig.png", "metrics.json", "traj.csv"] and len(files) == 3
    assert files["metrics.json"] == b"{}" and calls == []
    assert files["fig.png"] == b"png" and calls == [1]
    with pytest.raises(KeyError):
        files["other"]


def test_render_results_in_a_child_equals_rendering_in_this_process(sim_lib, carriage, op
                                                                     ) -> None:
    """`render_results` draws the figures in a forked child: byte for byte what the same
    functions give in this process."""
    from maglevgen.analyses.sim_output import (
        render_figures,
        render_metrics,
        render_results,
        render_trajectories,
    )
    from maglevgen.analyses.simulate import simulate
    from maglevgen.derive.model import input_names_of

    trajs = [simulate(sim_lib, carriage.p, op, c, 0.5, 1e-3, carriage.params.track.min_gap)
             for c in ("damping", "lqr")]
    names = input_names_of(carriage.structure)
    header = {"test": True}
    here = {**render_metrics(trajs, header), **render_trajectories(trajs, names),
            **render_figures(trajs)}
    assert render_results(trajs, names, header) == here
    assert any(n.endswith(".png") for n in here) and any(n.endswith(".csv") for n in here)
