"""Workers die with their parent (issue 54): a build or a Monte-Carlo study killed with
SIGKILL (nothing of it runs any more) leaves no worker process behind.

The reference is the process table (psutil): the killed command's worker processes, found
while it runs, must all be gone a few seconds after the kill.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

from maglevgen.infrastructure.workers import process_pool

GRACE = 10.0  # [s] after the kill: "a few seconds", generous on a loaded machine


def _workers_of(pid: int) -> list[psutil.Process]:
    """The Python processes below ``pid`` (its pool's and children's workers; gcc is left
    out: it ends on its own when its compile does)."""
    try:
        kids = psutil.Process(pid).children(recursive=True)
    except psutil.NoSuchProcess:
        return []
    out = []
    for k in kids:
        try:
            if "python" in k.name().lower() or "python" in " ".join(k.cmdline()[:1]).lower():
                out.append(k)
        except psutil.Error:
            pass
    return out


def _kill_when_workers_run(argv: list[str], cwd: Path, n: int, timeout: float) -> list[int]:
    """Start ``maglevgen ARGV``, wait until it has ``n`` worker processes, SIGKILL it; the
    workers' pids."""
    proc = subprocess.Popen([sys.executable, "-m", "maglevgen.cli", *argv], cwd=cwd,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + timeout
        while True:
            workers = _workers_of(proc.pid)
            if len(workers) >= n:
                break
            if proc.poll() is not None:
                pytest.fail(f"the command ended (exit {proc.returncode}) before it started "
                            f"{n} workers: {proc.stderr.read().decode()[-500:]}")
            assert time.monotonic() < deadline, "no worker started in time"
            time.sleep(0.05)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    return [w.pid for w in workers]


def _alive(pids: list[int]) -> list[int]:
    left = []
    for pid in pids:
        try:
            p = psutil.Process(pid)
            if p.status() != psutil.STATUS_ZOMBIE:
                left.append(pid)
        except psutil.NoSuchProcess:
            pass
    return left


def _wait_gone(pids: list[int]) -> list[int]:
    deadline = time.monotonic() + GRACE
    while _alive(pids) and time.monotonic() < deadline:
        time.sleep(0.1)
    left = _alive(pids)
    for pid in left:  # do not leave them to the next test
        os.kill(pid, signal.SIGKILL)
    return left


def _sleeper(seconds: float) -> int:
    time.sleep(seconds)
    return os.getpid()


_PARENT = """
import sys, time
from maglevgen.infrastructure.workers import process_pool
from tests.test_orphans import _sleeper
pool = process_pool(2)
futures = [pool.submit(_sleeper, 600) for _ in range(2)]
print("ready", flush=True)
time.sleep(600)
"""


def test_a_pools_workers_die_with_a_killed_parent(tmp_path: Path) -> None:
    """`process_pool` itself, with workers busy for 600 s when their parent is killed."""
    root = Path(__file__).resolve().parents[1]
    proc = subprocess.Popen([sys.executable, "-c", _PARENT], cwd=root,
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "ready"
        deadline = time.monotonic() + 120
        while len(_workers_of(proc.pid)) < 2:
            assert time.monotonic() < deadline and proc.poll() is None
            time.sleep(0.05)
        pids = [w.pid for w in _workers_of(proc.pid)]
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    assert _wait_gone(pids) == []


def test_a_pool_in_a_live_parent_works() -> None:
    with process_pool(1) as pool:
        assert pool.submit(_sleeper, 0).result() != os.getpid()


@pytest.mark.slow
def test_a_killed_build_leaves_no_worker(tmp_path: Path) -> None:
    # a parameter edit: the build runs its simulations and draws in a forked worker
    pids = _kill_when_workers_run(["build", "--out", "out", "--t-end", "1", "--no-pdf",
                                   "--set", "vehicle.mass=9.41"], tmp_path, 1, 900)
    assert pids
    assert _wait_gone(pids) == []


@pytest.mark.slow
def test_a_killed_montecarlo_leaves_no_worker(tmp_path: Path) -> None:
    pids = _kill_when_workers_run(["montecarlo", "--samples", "4000", "--workers", "2",
                                   "--t-end", "1"], tmp_path, 2, 900)
    assert _wait_gone(pids) == []


def _descendants(pid: int) -> list[psutil.Process]:
    try:
        return psutil.Process(pid).children(recursive=True)
    except psutil.NoSuchProcess:
        return []


def _cmdline(p: psutil.Process) -> str:
    try:
        return " ".join(p.cmdline())
    except psutil.Error:
        return ""


@pytest.mark.slow
def test_a_killed_montecarlo_on_a_local_dask_cluster_leaves_no_process(tmp_path: Path) -> None:
    """`montecarlo --scheduler local`: the LocalCluster's worker processes (started by
    multiprocessing's spawn, `spawn_main` in their command line) and every other process
    below the command (the resource tracker...) are gone `GRACE` seconds after a SIGKILL of
    the command, found in the process table while it ran."""
    pytest.importorskip("distributed")
    proc = subprocess.Popen([sys.executable, "-m", "maglevgen.cli", "montecarlo", "--samples",
                             "100000", "--workers", "2", "--t-end", "1", "--scheduler",
                             "local"], cwd=tmp_path, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 900
        while len([p for p in _descendants(proc.pid) if "spawn_main" in _cmdline(p)]) < 2:
            if proc.poll() is not None:
                pytest.fail(f"the command ended (exit {proc.returncode}) before its cluster "
                            f"started: {proc.stderr.read().decode()[-500:]}")
            assert time.monotonic() < deadline, "no Dask worker started in time"
            time.sleep(0.1)
        time.sleep(2.0)  # the workers registered with the scheduler and running chunks
        pids = [p.pid for p in _descendants(proc.pid)]
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    assert len(pids) >= 2
    assert _wait_gone(pids) == []

