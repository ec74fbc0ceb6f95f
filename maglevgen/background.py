"""Work done in a forked child process while this one goes on (the machine has 2+ cores).

`maglevgen build` renders its trajectories and figures (matplotlib: import and drawing, about
a second) in children while it builds the report's context; `maglevgen simulate` draws its
figures in a child while it writes the trajectories. The child is forked,
so it sees this process's data without pickling; only its result travels back, over a pipe.
Where fork is not available the work runs in this process when its result is asked for.
"""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Iterator, Mapping
from typing import Any, Generic, TypeVar

from .errors import MaglevError

T = TypeVar("T")


class Background(Generic[T]):
    """``fn(*args)`` running in a forked child; ``result()`` waits for it.

    Use it as a context manager: leaving the block before ``result()`` (an error elsewhere)
    stops the child. A failure in the child raises MaglevError naming ``what`` and the error.
    """

    def __init__(self, what: str, fn: Callable[..., T], *args: Any) -> None:
        self._what, self._fn, self._args = what, fn, args
        self._done = False
        self._value: T | None = None
        self._proc = self._conn = None
        if "fork" in multiprocessing.get_all_start_methods():
            ctx = multiprocessing.get_context("fork")
            self._conn, child = ctx.Pipe(duplex=False)
            self._proc = ctx.Process(target=_child, args=(fn, args, child), daemon=True,
                                     name=f"maglevgen {what}")
            self._proc.start()
            child.close()

    def __enter__(self) -> Background[T]:
        return self

    def __exit__(self, *exc: object) -> None:
        self.cancel()

    def cancel(self) -> None:
        """Stop the child if its result was not taken (the caller failed meanwhile)."""
        if self._proc is not None and not self._done:
            self._proc.terminate()
            self._proc.join()
            self._conn.close()
            self._proc = None
            self._done = True

    def result(self) -> T:
        if self._done:
            return self._value  # type: ignore[return-value]
        if self._proc is None:
            self._value = self._fn(*self._args)
        else:
            try:
                ok, value = self._conn.recv()
            except EOFError:
                ok, value = False, f"the child process ended with code {self._proc.exitcode}"
            finally:
                self._proc.join()
                self._conn.close()
            if not ok:
                raise MaglevError(f"{self._what} failed: {value}")
            self._value = value
        self._done = True
        return self._value  # type: ignore[return-value]


def _child(fn: Callable[..., Any], args: tuple, conn: Any) -> None:
    try:
        value = (True, fn(*args))
    except BaseException as exc:  # reported to the parent in one line
        value = (False, f"{type(exc).__name__}: {exc}")
    conn.send(value)
    conn.close()


class PendingFiles(Mapping[str, bytes]):
    """Files in memory, some of which a `Background` job is still producing: reading one of
    those waits for the job; listing and testing names does not."""

    def __init__(self, ready: Mapping[str, bytes], pending: tuple[str, ...],
                 job: Background[Mapping[str, bytes]]) -> None:
        self._ready, self._pending, self._job = ready, pending, job

    def __getitem__(self, name: str) -> bytes:
        if name in self._ready:
            return self._ready[name]
        if name in self._pending:
            return self._job.result()[name]
        raise KeyError(name)

    def __contains__(self, name: object) -> bool:  # Mapping's would read the file
        return name in self._ready or name in self._pending

    def __iter__(self) -> Iterator[str]:
        yield from self._ready
        yield from (n for n in self._pending if n not in self._ready)

    def __len__(self) -> int:
        return len(set(self._ready) | set(self._pending))
