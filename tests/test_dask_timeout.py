"""A Dask study whose workers are all lost fails (issue 54): exit 1 and one line naming the
samples not run, within the stated timeout (MAGLEVGEN_DASK_WORKER_TIMEOUT), instead of
waiting for ever. The scheduler and its one worker are separate processes, as on a cluster;
the worker is killed (SIGKILL) while the study runs.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

pytest.importorskip("distributed")

TIMEOUT = 10.0  # [s] the study's wait with no worker, set for the test


def _dask(*args: str, **kw) -> subprocess.Popen:
    exe = shutil.which("dask", path=os.path.dirname(sys.executable)) or "dask"
    return subprocess.Popen([exe, *args], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            **kw)


@pytest.mark.slow
def test_a_study_that_loses_its_only_worker_fails_in_time(tmp_path: Path) -> None:
    info = tmp_path / "scheduler.json"
    scheduler = _dask("scheduler", "--scheduler-file", str(info), "--port", "0",
                      "--no-dashboard")
    worker = None
    study = None
    try:
        deadline = time.monotonic() + 120
        while not info.exists():
            assert time.monotonic() < deadline, "no scheduler"
            time.sleep(0.2)
        time.sleep(0.5)
        address = json.loads(info.read_text())["address"]
        worker = _dask("worker", "--no-nanny", "--nthreads", "1", "--scheduler-file",
                       str(info))
        env = {**os.environ, "MAGLEVGEN_DASK_WORKER_TIMEOUT": str(TIMEOUT)}
        study = subprocess.Popen([sys.executable, "-m", "maglevgen.cli", "montecarlo",
                                  "--samples", "20000", "--scheduler", address],
                                 env=env, cwd=tmp_path, stdout=subprocess.PIPE,
                                 stderr=subprocess.PIPE, text=True)
        # the study submitted and running on the worker: the worker busy (its CPU time
        # grows), however long a loaded machine takes to load the carriage and connect
        busy = psutil.Process(worker.pid)
        idle = sum(busy.cpu_times()[:2])
        deadline = time.monotonic() + 600
        while sum(busy.cpu_times()[:2]) < idle + 2.0:
            assert study.poll() is None, study.communicate()
            assert time.monotonic() < deadline, "the worker never ran the study"
            time.sleep(0.2)
        assert study.poll() is None, study.communicate()
        worker.send_signal(signal.SIGKILL)
        worker.wait()
        killed = time.monotonic()
        _, err = study.communicate(timeout=TIMEOUT + 120)
        waited = time.monotonic() - killed
    finally:
        for p in (study, worker, scheduler):
            if p is not None and p.poll() is None:
                p.kill()
                p.wait()
    assert study.returncode == 1, err
    line = err.strip().splitlines()[-1]
    assert line.startswith("maglevgen: error: the Dask cluster has had no worker for 10 s"), err
    assert "not run" in line
    assert TIMEOUT <= waited < TIMEOUT + 120, waited
