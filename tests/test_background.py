"""maglevgen.background: work in a forked child, its failures, and the pending-file view.

The reference for a result is the same function called in this process.
"""

from __future__ import annotations

import multiprocessing
import os
import time
from pathlib import Path

import numpy as np
import pytest

from maglevgen import background
from maglevgen.background import Background, PendingFiles, Shared, Worker
from maglevgen.errors import MaglevError


def _pid_and_sum(values: np.ndarray) -> tuple[int, float]:
    return os.getpid(), float(np.sum(values))


def _fails() -> None:
    raise ValueError("no trim at 1e9 m/s")


def _dies() -> None:
    os._exit(3)


def _slow() -> int:
    time.sleep(60)
    return 1


def test_result_comes_from_a_child_and_equals_the_direct_call() -> None:
    data = np.linspace(0.0, 1.0, 1001)  # seen by the child through fork, never pickled
    job = Background("summing", _pid_and_sum, data)
    spool = Path(job._spool)
    pid, total = job.result()
    assert pid != os.getpid()
    assert not spool.exists()  # a one-job child is cleaned up once its result is read
    assert total == _pid_and_sum(data)[1]
    assert job.result() == (pid, total)  # a second call returns the same result


def test_without_fork_the_work_runs_here(monkeypatch) -> None:
    monkeypatch.setattr(multiprocessing, "get_all_start_methods", lambda: ["spawn"])
    job = Background("summing", _pid_and_sum, np.ones(4))
    assert job.result() == (os.getpid(), 4.0)


def test_a_failure_in_the_child_is_one_line_naming_the_job_and_the_error() -> None:
    with pytest.raises(MaglevError) as err:
        Background("drawing the figures", _fails).result()
    msg = str(err.value)
    assert msg == "drawing the figures failed: ValueError: no trim at 1e9 m/s"
    assert "\n" not in msg


def test_a_child_that_dies_is_reported_with_its_exit_code() -> None:
    with pytest.raises(MaglevError, match=r"drawing failed: .*ended with code 3"):
        Background("drawing", _dies).result()


def test_leaving_the_block_early_stops_the_child() -> None:
    t0 = time.monotonic()
    with pytest.raises(RuntimeError), Background("sleeping", _slow) as job:
        proc = job._proc
        assert proc is not None and proc.is_alive()
        raise RuntimeError("the caller failed meanwhile")
    assert not proc.is_alive()
    assert time.monotonic() - t0 < 30  # did not wait for the 60 s sleep


_LOADED: list[str] = []


def _load(name: str) -> int:
    """A slow import done once: the jobs after it find it in the same process."""
    _LOADED.append(name)
    return os.getpid()


def _loaded_here() -> tuple[int, list[str]]:
    return os.getpid(), list(_LOADED)


def test_a_worker_runs_later_jobs_in_the_same_child_in_order() -> None:
    with Worker("drawing", _load, "matplotlib") as worker:
        second = worker.submit("summing", _pid_and_sum, np.arange(5.0))  # pickled to the child
        third = worker.submit("reading", _loaded_here)
        # asked out of order: the earlier results are kept until they are asked for
        pid, loaded = third.result()
        assert loaded == ["matplotlib"] and _LOADED == []  # the import happened in the child
        assert second.result() == (pid, 10.0)
        assert worker.first.result() == pid != os.getpid()
        proc, spool = worker._proc, Path(worker._spool)
        assert spool.is_dir()  # where the child writes its results
    assert proc is not None and not proc.is_alive()  # every result taken: it ended by itself
    assert not spool.exists()


def _megabytes(n: int) -> bytes:
    return b"x" * (n << 20)


def test_large_jobs_and_results_cross_without_deadlock() -> None:
    """The child sends an 8 MB result while this process sends it an 8 MB job: pipes hold
    far less, so each side must not wait for the other."""
    big = np.ones(1 << 20)  # 8 MB, pickled to the child
    with Worker("writing", _megabytes, 8) as worker:
        second = worker.submit("summing", _pid_and_sum, big)
        assert second.result()[1] == float(big.size)
        assert len(worker.first.result()) == 8 << 20


def test_a_failing_job_names_itself_and_the_worker_goes_on() -> None:
    with Worker("drawing", _load, "matplotlib") as worker:
        bad = worker.submit("drawing the report figures", _fails)
        good = worker.submit("summing", _pid_and_sum, np.ones(3))
        with pytest.raises(MaglevError, match=r"^drawing the report figures failed: ValueError"):
            bad.result()
        assert good.result()[1] == 3.0


def test_a_shared_argument_is_the_data_the_child_was_forked_with(monkeypatch) -> None:
    """A `Shared` argument travels as its name: the 8 MB array is not pickled again."""
    from multiprocessing.reduction import ForkingPickler

    sent: list[int] = []
    dumps = ForkingPickler.dumps
    monkeypatch.setattr(ForkingPickler, "dumps",
                        classmethod(lambda cls, obj, *a: sent.append(len(dumps(obj, *a)))
                                    or dumps(obj, *a)))
    data = np.arange(float(1 << 20))
    with Worker("summing", _pid_and_sum, data, shared={"samples": data}) as worker:
        again = worker.submit("summing again", _pid_and_sum, Shared("samples"))
        assert again.result() == worker.first.result()
        assert again.result()[1] == float(np.sum(data))
    assert sent and max(sent) < 10_000, sent


def test_without_fork_a_shared_argument_is_the_data_itself(monkeypatch) -> None:
    monkeypatch.setattr(multiprocessing, "get_all_start_methods", lambda: ["spawn"])
    with Worker("summing", _pid_and_sum, np.ones(2), shared={"ones": np.ones(5)}) as worker:
        assert worker.submit("summing", _pid_and_sum, Shared("ones")).result()[1] == 5.0


def test_a_job_that_cannot_be_sent_fails_its_caller_at_once() -> None:
    with Worker("drawing", _load, "matplotlib") as worker:
        with pytest.raises(MaglevError, match=r"^drawing the report figures failed: cannot send "
                                              r"it to the child process \(.*lambda"):
            worker.submit("drawing the report figures", lambda: 1)  # a lambda does not pickle
        assert worker.submit("reading", _loaded_here).result()[1] == ["matplotlib"]


def test_a_worker_that_dies_fails_its_pending_jobs_with_the_exit_code() -> None:
    with Worker("drawing", _dies) as worker:
        later = worker.submit("summing", _pid_and_sum, np.ones(3))
        with pytest.raises(MaglevError, match=r"summing failed: .*ended with code 3"):
            later.result()
        with pytest.raises(MaglevError, match=r"drawing failed: .*ended with code 3"):
            worker.first.result()


def test_leaving_a_worker_early_stops_it() -> None:
    t0 = time.monotonic()
    with pytest.raises(RuntimeError), Worker("sleeping", _slow) as worker:
        worker.submit("summing", _pid_and_sum, np.ones(3))
        proc = worker._proc
        raise RuntimeError("the caller failed meanwhile")
    assert not proc.is_alive()
    assert time.monotonic() - t0 < 30


def test_without_fork_a_worker_runs_its_jobs_here(monkeypatch) -> None:
    monkeypatch.setattr(multiprocessing, "get_all_start_methods", lambda: ["spawn"])
    with Worker("summing", _pid_and_sum, np.ones(2)) as worker:
        second = worker.submit("summing", _pid_and_sum, np.ones(3))
        assert second.result() == (os.getpid(), 3.0)
        assert worker.first.result() == (os.getpid(), 2.0)


def test_pending_files_wait_for_the_job_only_when_a_pending_file_is_read(monkeypatch) -> None:
    calls = []

    def produce() -> dict[str, bytes]:
        calls.append(1)
        return {"fig.png": b"png", "traj.csv": b"csv"}

    monkeypatch.setattr(multiprocessing, "get_all_start_methods", lambda: [])  # run lazily here
    job = background.Background("rendering", produce)
    files = PendingFiles({"metrics.json": b"{}"}, {"fig.png": job, "traj.csv": job})
    assert "fig.png" in files and "metrics.json" in files and "other" not in files
    assert sorted(files) == ["fig.png", "metrics.json", "traj.csv"] and len(files) == 3
    assert files["metrics.json"] == b"{}" and calls == []
    assert files["fig.png"] == b"png" and files["traj.csv"] == b"csv" and calls == [1]
    with pytest.raises(KeyError):
        files["other"]


def test_render_results_in_a_child_equals_rendering_in_this_process(sim_lib, carriage, op
                                                                     ) -> None:
    """`render_results` draws the figures in a forked child: byte for byte what the same
    functions give in this process."""
    from maglevgen.derive.model import input_names_of
    from maglevgen.sim_output import (
        render_figures,
        render_metrics,
        render_results,
        render_trajectories,
    )
    from maglevgen.simulate import simulate

    trajs = [simulate(sim_lib, carriage.p, op, c, 0.5, 1e-3, carriage.params.track.min_gap)
             for c in ("damping", "lqr")]
    names = input_names_of(carriage.structure)
    header = {"test": True}
    here = {**render_metrics(trajs, header), **render_trajectories(trajs, names),
            **render_figures(trajs)}
    assert render_results(trajs, names, header) == here
    assert any(n.endswith(".png") for n in here) and any(n.endswith(".csv") for n in here)
