"""Progress from the first second: a cold build says what it does, and is never silent for
longer than `SILENCE` seconds (the heartbeat of maglevgen.infrastructure.progress).

Reference: the times at which this test's own process reads each line of the command's
stderr from a pipe (time.monotonic), not the command's account of itself.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from itertools import pairwise
from pathlib import Path

import pytest
from conftest import _COLD_LOG, BUILD_FAST, timed_run

from maglevgen.infrastructure.progress import PULSE

#: the longest silence allowed on stderr: the heartbeat's pulse and 2.5 s for a loaded machine
#: to schedule its thread (measured: up to 2.1 s late at a load of 2 cores shared by 5 suites)
SILENCE = PULSE + 2.5

#: the stages a cold build announces as each starts (the words of their first lines)
STAGES = ("deriving", "compiling", "simulations:", "envelope:", "region of attraction",
          "report:", "writing the folder")


def _gaps(lines: list[tuple[float, str]]) -> list[tuple[float, str]]:
    """(silence, the line that ended it), the start of the process counted as a line."""
    times = [0.0, *(t for t, _ in lines)]
    return [(b - a, text) for a, b, (_, text) in zip(times, times[1:], lines, strict=False)]


@pytest.fixture(scope="module")
def cold_log(tmp_path_factory) -> dict:
    """The suite's cold build's timestamped stderr (conftest's `_cold_build`, before the
    workers start), or a cold build of its own into an empty cache (a run in one process)."""
    ready = os.environ.get(_COLD_LOG)
    if ready and Path(ready).is_file():
        return json.loads(Path(ready).read_text())
    tmp = tmp_path_factory.mktemp("cold")
    code, lines = timed_run([sys.executable, "-m", "maglevgen.cli", "build", "--out",
                             str(tmp / "out"), *BUILD_FAST],
                            {**os.environ, "MAGLEVGEN_CACHE": str(tmp / "cache")})
    return {"exit": code, "lines": lines}


@pytest.mark.slow  # a cold build (minutes) unless the suite's shared one is there
def test_a_cold_build_is_never_silent(cold_log: dict) -> None:
    lines = [(t, text) for t, text in cold_log["lines"]]
    assert cold_log["exit"] == 0, lines[-3:]
    worst = max(_gaps(lines))
    assert worst[0] <= SILENCE, f"{worst[0]:.1f} s without a line, ended by {worst[1]!r}"
    said = " ".join(text for _, text in lines)
    missing = [s for s in STAGES if s not in said]
    assert not missing, missing
    # the first line within the first seconds: the parameters' import and validation
    assert lines[0][0] <= SILENCE and lines[0][1].startswith("maglevgen: ")


def test_heartbeat_fills_a_long_step(tmp_path: Path) -> None:
    """A step of 2.2 s inside `heartbeat(pulse=0.5)`: `still` lines with the elapsed seconds
    while it runs, none once the block has ended (a line the script writes right after the
    block comes after every `still` line: stream order, not time, so a loaded machine that
    wakes the heartbeat late cannot fail it); at most one line per pulse, and no silence
    longer than a pulse and the 2.5 s a loaded machine may take to schedule the thread."""
    script = ("import sys, time\n"
              "from maglevgen.infrastructure import progress\n"
              "with progress.heartbeat(pulse=0.5):\n"
              "    progress.step('deriving the model (cached afterwards)')\n"
              "    time.sleep(2.2)\n"
              "print('block ended', file=sys.stderr, flush=True)\n"
              "time.sleep(1.5)\n")
    code, lines = timed_run([sys.executable, "-c", script], dict(os.environ))
    assert code == 0
    texts = [text for _, text in lines if text]
    assert texts[0] == "maglevgen: deriving the model (cached afterwards)"
    assert texts[-1] == "block ended", texts  # no `still` line after the block
    still = [text for text in texts if "still" in text]
    assert 1 <= len(still) <= 5, texts  # ideally 4 (at 0.5, 1, 1.5, 2 s); never more
    assert all(text.startswith("maglevgen: ... still deriving the model (") for text in still)
    started = next(t for t, text in lines if text == texts[0])
    heard = [t for t, text in lines if text and t >= started]
    assert max(b - a for a, b in pairwise(heard)) < 0.5 + 2.5


def test_an_announced_command_failing_at_once_prints_one_line() -> None:
    """`montecarlo` announces itself before the API checks --samples: the announcement waits
    `GRACE`, so the bad option's error is still the only line (exit 2)."""
    proc = subprocess.run([sys.executable, "-m", "maglevgen.cli", "montecarlo", "--samples",
                           "0"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("\n") == 1 and "--samples 0" in proc.stderr, proc.stderr
