"""A full benchmark run rewrites BENCHMARKS.md above the kept-part marker and carries the
sections other scripts recorded (the marker line to the end) over byte for byte."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import pytest

WRITEUP = Path(__file__).resolve().parents[1] / "bench" / "writeup.py"
MARKER = "<!-- recorded separately: kept by make bench -->"  # the line BENCHMARKS.md carries


@pytest.fixture(scope="module")
def writeup() -> ModuleType:
    spec = importlib.util.spec_from_file_location("bench_writeup", WRITEUP)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_marker_is_the_one_benchmarks_md_carries(writeup: ModuleType) -> None:
    assert writeup.KEPT_MARKER == MARKER
    text = (WRITEUP.parents[1] / "BENCHMARKS.md").read_text()
    assert text.count(MARKER) == 1
    # the run's own sections are above it, the separately recorded ones below
    head, tail = text.split(MARKER)
    assert "## 3. `maglev_dynamics`: time per call" in head
    assert "## Issue 20 (part A)" in tail and "## Issue 20 (part A)" not in head


def test_rewrite_keeps_the_marked_part_byte_for_byte(writeup: ModuleType, tmp_path: Path) -> None:
    kept = (f"{MARKER}\n## Issue 99: recorded by hand\n\nodd   spacing \t\n\n"
            "<!-- a: begin -->\n| x |\n<!-- a: end -->\n\n\n")
    old = "# Benchmarks\n\n## 3. stale timing 492 ns\n\n" + kept
    path = tmp_path / "BENCHMARKS.md"
    path.write_bytes(old.encode())
    generated = "# Benchmarks\n\n## 3. fresh timing 300 ns\n"
    new = writeup.document(generated, path.read_text())
    assert new == generated + "\n" + kept
    assert "stale" not in new
    assert new.encode().endswith(kept.encode())
    # the marker quoted inside a line is not the marker line
    quoted = f"# Benchmarks\n\nsee `{MARKER}` below\n\n" + kept
    assert writeup.document(generated, quoted) == generated + "\n" + kept


def test_rewrite_without_marker_is_the_generated_text(writeup: ModuleType) -> None:
    generated = "# Benchmarks\n\nnew\n"
    assert writeup.document(generated, "# Benchmarks\n\nold, no marker\n") == generated
    assert writeup.document(generated, None) == generated


def test_a_section_not_measured_is_carried_over(writeup: ModuleType) -> None:
    old = ("# Benchmarks\n\n## Envelope and launch (2026-11-27)\n\n98 ms\n\n"
           "## Monte Carlo (`maglevgen montecarlo`; old)\n\n220 s\n\n" + MARKER + "\n## Later\n")
    assert writeup._old_section(old, "## Envelope and launch") == [
        "## Envelope and launch (2026-11-27)", "", "98 ms", ""]
    assert writeup._old_section(old, "## Peers for the generated C") == []


def test_issue_53s_lanes_target_needs_the_ratio_and_every_runs_bits(writeup: ModuleType) -> None:
    """The batch at 8 lanes meets its target at 3x the scalar loop only where every run is
    the scalar run's bits; the operation-count row is the firmware loop's alone."""
    def loop(ratio: float, same: bool) -> dict:
        return {"speedup_vs_scalar": {"W=8": {"median": ratio}},
                "bitwise_same_as_scalar": {"W=8": same},
                "ms_per_run": {"W=8": {"median": 10.0}, "scalar": {"median": 10.0 * ratio}}}

    peer = {"limit_ms_per_run": {"scalar": 8.0}, "operations_per_run": 1.4e8,
            "project_speedup": {"CasADi": {"median": 1.5}, "JAX": {"median": 0.9}},
            "jax_skipped": None}
    rows = writeup._lanes_targets({"firmware": loop(3.2, True), "sensed": loop(4.0, False)},
                                  peer)
    met = {r["name"]: r["met"] for r in rows}
    lanes = [n for n in met if n.startswith("the batch at 8 lanes")]
    assert [met[n] for n in lanes] == [True, False]  # the sensed lanes' runs differ
    limit = [n for n in met if "operation-count" in n]
    assert len(limit) == 1 and "--loop firmware" in limit[0]
    assert met[limit[0]] is True  # 10 ms within 1.5 x 8 ms
    assert met["ahead of every peer per CPU-second (the same closed loop and inputs)"] is False
    assert writeup._lanes_targets(None, None) == []
