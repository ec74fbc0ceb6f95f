"""Progress on stderr for the steps that take more than a second (stdout stays clean).

Steps are announced as one line each; long loops show a rich progress bar when stderr is a
terminal and nothing more otherwise (logs get the step lines only).
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager


def step(message: str) -> None:
    """Announce a slow step."""
    print(f"maglevgen: {message}", file=sys.stderr, flush=True)


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
