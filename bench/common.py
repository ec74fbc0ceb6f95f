"""Shared pieces of the benchmark suite: paths, summary statistics, running tools."""

from __future__ import annotations

import re
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "bench"
# one-off experiments (their results recorded in BENCHMARKS.md), not run by `make bench`
EXPERIMENTS = BENCH / "experiments"
REFERENCE_DIR = BENCH / "reference"
DRIVER_DIR = BENCH / "c"
BENCHMARKS = ROOT / "BENCHMARKS.md"


def replace_section(lines: Sequence[str], begin: str, end: str,
                    path: Path = BENCHMARKS) -> None:
    """Put ``lines`` (a section from its ``begin`` marker to its ``end`` marker) in place of
    the file's section between the same markers, or append it where the file has none."""
    block = "\n".join(lines) + "\n"
    text = path.read_text()
    if begin in text and end in text:
        head, rest = text.split(begin, 1)
        tail = rest.split(end, 1)[1].lstrip("\n")
        text = head + block + ("\n" + tail if tail else "")
    else:
        text = text.rstrip("\n") + "\n\n" + block
    path.write_text(text)


def log(msg: str) -> None:
    """Progress on stderr (stdout stays clean)."""
    print(f"[bench {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def summary(values: Sequence[float]) -> dict[str, float]:
    """Median, quartiles, min and max of repeated measurements."""
    v = sorted(float(x) for x in values)
    if not v:
        raise ValueError("no measurements")
    if len(v) >= 2:
        q1, _, q3 = statistics.quantiles(v, n=4, method="inclusive")
    else:
        q1 = q3 = v[0]
    return {
        "median": statistics.median(v),
        "q1": q1,
        "q3": q3,
        "min": v[0],
        "max": v[-1],
        "n": len(v),
    }


def paired_ratios(a: Sequence[float], b: Sequence[float]) -> dict[str, float]:
    """a[i] / b[i] for figures taken in the same repeat, summarised."""
    if len(a) != len(b):
        raise ValueError("paired measurements of different lengths")
    return summary([x / y for x, y in zip(a, b, strict=True)])


def run(cmd: Sequence[str], cwd: Path | None = None, env: dict | None = None) -> str:
    """Run a command, return its stdout; raise with its stderr when it fails."""
    proc = subprocess.run(list(map(str, cmd)), cwd=cwd, env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(
            f"{' '.join(map(str, cmd))} failed ({proc.returncode}):\n{proc.stderr.strip()[-4000:]}"
        )
    return proc.stdout


def time_calls(fn: Callable[[int], object], calls: int) -> float:
    """Nanoseconds per call of fn(i) over ``calls`` calls (perf_counter_ns around the loop)."""
    t0 = time.perf_counter_ns()
    for i in range(calls):
        fn(i)
    return (time.perf_counter_ns() - t0) / calls


def worst_stack(ci: str, root: str) -> int:
    """The deepest static stack from ``root`` in gcc's -fcallgraph-info output (``ci``): each
    function's own frame plus its deepest callee's (recursion cut where a call repeats)."""
    own = {m.group(1): int(m.group(2)) for m in re.finditer(
        r'node: \{ title: "([^"]+)" label: "[^"]*?(\d+) bytes \(static\)', ci)}
    calls: dict[str, list[str]] = {}
    for m in re.finditer(r'edge: \{ sourcename: "([^"]+)" targetname: "([^"]+)"', ci):
        calls.setdefault(m.group(1), []).append(m.group(2))

    def worst(f: str, seen: frozenset) -> int:
        return own.get(f, 0) + max((worst(g, seen | {f}) for g in calls.get(f, ())
                                    if g not in seen), default=0)

    return worst(root, frozenset())


def study_runs(study, lib, n: int, as_flown: bool = False) -> tuple[list, int, int]:
    """The C batch driver's inputs (`simulate.hold_run`) for a Monte-Carlo study's first n
    samples, every controller, prepared once as the study prepares them (its `_prepare`: the
    sample's carriage, the nominal design, the disturbance): (runs, inputs, gaps). On the
    study's tick, each run's readings and predictions recorded; ``as_flown``: on each
    sample's own tick (its noise seed, sensors and lag: `montecarlo.sample_tick`) with
    nothing recorded, the runs `montecarlo.run_samples_batch` flies."""
    from maglevgen.analyses.montecarlo import _prepare, sample_tick
    from maglevgen.analyses.simulate import hold_run

    runs, n_u, n_g = [], 0, 0
    n_steps = round(study.t_end / study.dt)
    for i in range(n):
        prepared = _prepare(study, i, lib)
        if isinstance(prepared, list):  # rejected, or no trim: no run
            continue
        p, op, design, dist, _row = prepared
        for c in study.controllers:
            tick = sample_tick(study, i) if as_flown else study.tick
            runs.append(hold_run(p, op, c, study.dt, dist, tick, study.speed_gain,
                                 study.force_budget, controller_op=design, n_steps=n_steps,
                                 record=not as_flown))
        n_u, n_g = op.allocation.shape[0] + 1, op.gaps.size
    return runs, n_u, n_g
