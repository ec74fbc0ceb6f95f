"""Progress on stderr for the steps that take more than a second (stdout stays clean).

Each step is announced by one line when it starts (`step`). Long loops show a rich progress
bar when stderr is a terminal; without one they feed the heartbeat's figure instead. Inside
`heartbeat` (the CLI's commands run in one), a step still going after `PULSE` seconds says so:
a line ``... still <step> (<elapsed> s[, <figure>])`` every `PULSE` seconds in a log, one line
rewritten in place on a terminal; so a first build, whose derivation and compiles take
minutes, is never silent for longer than that.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

__all__ = ["PULSE", "announce", "bar", "heartbeat", "held", "rate_bar", "step"]

#: seconds without a line after which the heartbeat says the step is still going
PULSE = 3.0
#: seconds after which an `announce`d command's line is printed (an input error found sooner
#: is then the only line on stderr): the pulse, so the silence is no longer than elsewhere
GRACE = PULSE

#: the lines announced inside `held` (None: print them as they come)
_held: list[str] | None = None


class _State:
    """What the heartbeat reports: the current step, when it (or the last line) started,
    the figure a bar without a terminal feeds, and whether a rich bar owns the terminal."""

    message: str | None = None
    started = 0.0
    last_line = 0.0
    figure = ""
    bar_active = False
    pending_cr = False  # a heartbeat line on a terminal waits to be overwritten
    pending: str | None = None  # an `announce`d line not printed yet


_state = _State()


def step(message: str) -> None:
    """Announce a slow step (held back inside `held`)."""
    line = f"maglevgen: {message}"
    if _held is not None:
        _held.append(line)
        return
    _flush_pending()
    now = time.monotonic()
    _state.message, _state.started, _state.last_line, _state.figure = message, now, now, ""
    _emit(line)


def announce(message: str) -> None:
    """A command's first line: printed `GRACE` seconds after this call (by the heartbeat) or
    before the next `step`, dropped when the command ends or fails sooner; so a command whose
    options are checked after this call still fails with one line."""
    now = time.monotonic()
    _state.message, _state.started, _state.last_line, _state.figure = message, now, now, ""
    _state.pending = message


def _flush_pending() -> None:
    message, _state.pending = _state.pending, None
    if message is not None:
        _state.last_line = time.monotonic()
        _emit(f"maglevgen: {message}")


def _emit(line: str) -> None:
    if _state.pending_cr:  # clear the heartbeat's line on a terminal first
        line = "\r\x1b[K" + line
        _state.pending_cr = False
    print(line, file=sys.stderr, flush=True)


@contextmanager
def held() -> Iterator[None]:
    """Hold back the steps announced inside the block while a command validates its input
    (cheap checks only: a slow block would leave the terminal silent): printed when the
    block ends normally, dropped when it raises, so that a one-line error for bad input is
    the only line on stderr (the CLI's contract)."""
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
        step(line.removeprefix("maglevgen: "))


@contextmanager
def heartbeat(pulse: float = PULSE) -> Iterator[None]:
    """While the block runs, a step announced more than ``pulse`` seconds ago with no line
    since gets a ``still ...`` line (see the module's docstring). The thread writes with
    os.write (no lock of sys.stderr's that a fork of this process could inherit held)."""
    stop = threading.Event()
    tty = sys.stderr.isatty()

    def beat() -> None:
        while not stop.wait(min(0.25, pulse / 4)):
            now = time.monotonic()
            if _state.pending is not None and _held is None and now - _state.started >= GRACE:
                message, _state.pending = _state.pending, None
                if message is not None:
                    _state.last_line = now
                    _write(f"maglevgen: {message}", tty)
                continue
            if (_state.message is None or _held is not None or _state.bar_active
                    or now - _state.last_line < pulse):
                continue
            figure = f", {_state.figure}" if _state.figure else ""
            what = _state.message.split(" (")[0]  # without the step's parenthesis
            text = f"maglevgen: ... still {what} ({now - _state.started:.0f} s{figure})"
            _state.last_line = now
            if not _write(text, tty, in_place=tty):
                return

    def _write(text: str, tty: bool, in_place: bool = False) -> bool:
        try:
            clear = "\r\x1b[K" if tty and _state.pending_cr else ""
            os.write(sys.stderr.fileno(), (clear + text + ("" if in_place else "\n")).encode())
            _state.pending_cr = in_place
        except (OSError, ValueError):  # stderr closed or replaced: nothing to say to
            return False
        return True

    thread = threading.Thread(target=beat, name="maglevgen-heartbeat", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()
        if _state.pending_cr:
            _emit("")
        _state.message = _state.pending = None


@contextmanager
def bar(description: str) -> Iterator[Callable[[float], None]]:
    """A progress bar fed with the completed fraction (0..1); without a terminal, the
    heartbeat's figure (the percentage)."""
    if not sys.stderr.isatty():
        yield lambda fraction: setattr(_state, "figure", f"{fraction:.0%} of {description}")
        _state.figure = ""
        return
    from rich.progress import BarColumn, Progress, TaskProgressColumn, TimeRemainingColumn

    with _owning_terminal(), Progress("[progress.description]{task.description}", BarColumn(),
                                      TaskProgressColumn(), TimeRemainingColumn(),
                                      transient=True, console=_console()) as prog:
        task = prog.add_task(description, total=1.0)
        yield lambda fraction: prog.update(task, completed=fraction)


@contextmanager
def _owning_terminal() -> Iterator[None]:
    """A rich bar draws on the terminal: the heartbeat waits meanwhile."""
    if _state.pending_cr:
        _emit("")
    _state.bar_active = True
    try:
        yield
    finally:
        _state.bar_active = False
        _state.last_line = time.monotonic()


def _console():
    from rich.console import Console

    return Console(stderr=True)


@contextmanager
def rate_bar(description: str, total: int, unit: str = "runs") -> Iterator[Callable[[int], None]]:
    """A progress bar fed with completed counts, showing the rate (``unit``/s); without a
    terminal, the count as the heartbeat's figure and one line at the end with the count and
    the rate."""
    t0 = time.perf_counter()
    if not sys.stderr.isatty():
        done = [0]

        def count(k: int) -> None:
            done[0] += k
            _state.figure = f"{done[0]} of {total} {unit}"

        step(f"{description}: {total} {unit}")
        yield count
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

    with _owning_terminal(), Progress("[progress.description]{task.description}", BarColumn(),
                                      MofNCompleteColumn(), TextColumn("{task.fields[rate]}"),
                                      TimeRemainingColumn(), transient=True,
                                      console=_console()) as prog:
        task = prog.add_task(description, total=total, rate="")
        advanced = [0]

        def advance(k: int) -> None:
            advanced[0] += k
            dt = time.perf_counter() - t0
            prog.update(task, advance=k,
                        rate=f"{advanced[0] / dt:.4g} {unit}/s" if dt > 0 else "")

        yield advance
