"""Progress on stderr for the steps that take more than a second (stdout stays clean).

Steps are announced as one line each; long loops show a rich progress bar when stderr is a
terminal and nothing more otherwise (logs get the step lines only).
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager

__all__ = ["bar", "held", "rate_bar", "step"]

#: the lines announced inside `held` (None: print them as they come)
_held: list[str] | None = None


def step(message: str) -> None:
    """Announce a slow step (held back inside `held`)."""
    line = f"maglevgen: {message}"
    if _held is not None:
        _held.append(line)
        return
    print(line, file=sys.stderr, flush=True)


@contextmanager
def held() -> Iterator[None]:
    """Hold back the steps announced inside the block while a command validates its input:
    printed when the block ends normally, dropped when it raises, so that a one-line error
    for bad input is the only line on stderr (the CLI's contract)."""
    global _held
    if _held is not None:  # nested: the outer block decides
        yield
        return
    _held = []
    try:
        yield
    except BaseException:
        _held = None
        raise
    lines, _held = _held, None
    for line in lines:
        print(line, file=sys.stderr, flush=True)


@contextmanager
def bar(description: str) -> Iterator[Callable[[float], None]]:
    """A progress bar fed with the completed fraction (0..1)."""
    if not sys.stderr.isatty():
        yield lambda _fraction: None
        return
    from rich.progress import BarColumn, Progress, TaskProgressColumn, TimeRemainingColumn

    with Progress("[progress.description]{task.description}", BarColumn(),
                  TaskProgressColumn(), TimeRemainingColumn(), transient=True,
                  console=_console()) as prog:
        task = prog.add_task(description, total=1.0)
        yield lambda fraction: prog.update(task, completed=fraction)


def _console():
    from rich.console import Console

    return Console(stderr=True)


@contextmanager
def rate_bar(description: str, total: int, unit: str = "runs") -> Iterator[Callable[[int], None]]:
    """A progress bar fed with completed counts, showing the rate (``unit``/s); without a
    terminal, one line at the end with the count and the rate."""
    import time

    if not sys.stderr.isatty():
        done = [0]
        t0 = time.perf_counter()
        yield lambda k: done.__setitem__(0, done[0] + k)
        dt = time.perf_counter() - t0
        step(f"{description}: {done[0]} of {total} in {dt:.3g} s "
             f"({done[0] / dt if dt > 0 else 0:.4g} {unit}/s)")
        return
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeRemainingColumn,
    )

    with Progress("[progress.description]{task.description}", BarColumn(),
                  MofNCompleteColumn(), TextColumn("{task.fields[rate]}"),
                  TimeRemainingColumn(), transient=True, console=_console()) as prog:
        task = prog.add_task(description, total=total, rate="")
        t0 = time.perf_counter()
        count = [0]

        def advance(k: int) -> None:
            count[0] += k
            dt = time.perf_counter() - t0
            prog.update(task, advance=k,
                        rate=f"{count[0] / dt:.4g} {unit}/s" if dt > 0 else "")

        yield advance
