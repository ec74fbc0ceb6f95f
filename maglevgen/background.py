"""Work done in a forked child process while this one goes on (the machine has 2+ cores).

`maglevgen build` has one child (`Worker`) draw every figure, the simulation's and the
report's (matplotlib costs about half a second to import), and write the trajectories while
it builds the report's context; `maglevgen simulate` draws its figures in a child
(`Background`) while it writes the trajectories. A child is forked, so its first job sees this
process's data without pickling; results travel back through files in a spool folder. Where
fork is not available the work runs in this process when its result is asked for.
"""

from __future__ import annotations

import itertools
import multiprocessing
import os
import pickle
import queue
import shutil
import tempfile
import threading
from collections.abc import Callable, Iterator, Mapping
from contextlib import suppress
from dataclasses import dataclass
from multiprocessing.reduction import ForkingPickler
from typing import Any, Generic, Protocol, TypeVar

from .errors import MaglevError

T = TypeVar("T")


class Worker:
    """A forked child that runs jobs in order while this process goes on.

    ``Worker(what, fn, *args, shared=...)`` forks the child with a first job (it sees this
    process's data through fork, nothing is pickled); ``submit(what, fn, *args)`` sends it
    another over a pipe, pickled except for `Shared` arguments, which name an entry of
    ``shared``. So a child that imported something slow for one job reuses it for the
    next. A thread of this process writes the jobs to the pipe and the child writes its
    results to files, so neither side ever waits for the other to read. Each job's
    ``result()`` waits for it. Use the worker as a context manager: leaving the block before
    every result was taken (an error elsewhere) stops the child. A failure in a job raises
    MaglevError naming the job and the error. Without fork every job runs in this process
    when its result is asked for.
    """

    _serves = True  # after its first job, the child waits for more until stopped

    def __init__(self, what: str, fn: Callable[..., Any], *args: Any,
                 shared: Mapping[str, Any] | None = None) -> None:
        self._what = what
        self._shared = dict(shared or {})
        self._jobs: list[Job] = []
        self._proc = self._conn = self._send = None
        self._outbox: queue.SimpleQueue | None = None
        self._sender: threading.Thread | None = None
        if "fork" in multiprocessing.get_all_start_methods():
            ctx = multiprocessing.get_context("fork")
            self._conn, results = ctx.Pipe(duplex=False)
            jobs, self._send = ctx.Pipe(duplex=False)
            # results travel through files: a child never waits for this process to read
            self._spool = tempfile.mkdtemp(prefix="maglevgen-worker-")
            self._proc = ctx.Process(target=_serve,
                                     args=(fn, args, jobs if self._serves else None, results,
                                           self._shared, self._spool),
                                     daemon=True, name=f"maglevgen {what}")
            self._proc.start()
            results.close()
            jobs.close()
        self.first: Job = self._add(what, fn, args)

    def _add(self, what: str, fn: Callable[..., Any], args: tuple) -> Job:
        job = Job(self, len(self._jobs), what, fn, args)
        self._jobs.append(job)
        return job

    def submit(self, what: str, fn: Callable[..., Any], *args: Any) -> Job:
        """Run ``fn(*args)`` in the child after the jobs before it."""
        if self._proc is not None:
            if self._send is None:
                raise RuntimeError(f"{self._what}: the worker was stopped")
            try:  # here, so that a job that cannot be sent fails its caller
                payload = ForkingPickler.dumps((fn, args))
            except Exception as exc:
                raise MaglevError(f"{what} failed: cannot send it to the child process "
                                  f"({type(exc).__name__}: {exc})") from None
            if self._sender is None:
                self._outbox = queue.SimpleQueue()
                self._sender = threading.Thread(target=_send_all, daemon=True,
                                                args=(self._outbox, self._send))
                self._sender.start()
            self._outbox.put(payload)
        return self._add(what, fn, args)

    def __enter__(self) -> Worker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.cancel()

    def cancel(self) -> None:
        """Stop the child unless every result was taken (then it ends by itself)."""
        if self._proc is None:
            return
        finished = all(job.done for job in self._jobs)
        if not finished:
            self._proc.terminate()
        if self._serves:  # other children may hold the pipe: no EOF to wait for, a None ends
            if self._sender is None:
                with suppress(OSError):
                    self._send.send(None)
            else:
                self._outbox.put(None)
                self._sender.join()
        self._proc.join()
        self._send.close()
        self._conn.close()
        shutil.rmtree(self._spool, ignore_errors=True)
        self._proc = self._send = None
        for job in self._jobs:
            job.done = True

    def _receive(self, index: int) -> None:
        """Read results until job ``index`` has its own (they arrive in order)."""
        while not self._jobs[index].done:
            job = next(j for j in self._jobs if not j.done)
            try:
                ok, value = self._conn.recv()
                if ok:
                    value = _read_spooled(value)
            except EOFError:
                self._proc.join()
                ok, value = False, f"the child process ended with code {self._proc.exitcode}"
            job.settle(ok, value)


class Job:
    """One job of a `Worker`."""

    def __init__(self, worker: Worker, index: int, what: str, fn: Callable[..., Any],
                 args: tuple) -> None:
        self._worker, self._index, self._what = worker, index, what
        self._fn, self._args = fn, args
        self.done = False
        self._ok, self._value = True, None

    def settle(self, ok: bool, value: Any) -> None:
        self._ok, self._value, self.done = ok, value, True
        self._fn = self._args = None  # type: ignore[assignment]

    def result(self) -> Any:
        if not self.done:
            if self._worker._proc is None:
                self.settle(True, self._fn(*_resolve(self._args, self._worker._shared)))
            else:
                self._worker._receive(self._index)
        if not self._ok:
            raise MaglevError(f"{self._what} failed: {self._value}")
        return self._value


class Background(Worker, Generic[T]):
    """``fn(*args)`` running in a forked child; ``result()`` waits for it (a one-job Worker)."""

    _serves = False

    def result(self) -> T:
        try:
            return self.first.result()
        finally:
            self.cancel()  # the child has ended: join it and remove its spool


def _send_all(outbox: queue.SimpleQueue, send: Any) -> None:
    """The sender thread: the pickled jobs in order, then the None that ends the child."""
    while True:
        payload = outbox.get()
        try:
            if payload is None:
                send.send(None)
                return
            send.send_bytes(payload)
        except OSError:  # the child has ended: the jobs' result() say how
            return


@dataclass(frozen=True)
class Shared:
    """A job argument the child already holds: an entry of the ``shared`` data a `Worker`
    was forked with, sent by its name instead of pickled."""

    name: str


def _resolve(args: tuple, shared: Mapping[str, Any]) -> tuple:
    return tuple(shared[a.name] if isinstance(a, Shared) else a for a in args)


def _read_spooled(path: str) -> Any:
    with open(path, "rb") as f:
        value = pickle.load(f)
    os.unlink(path)
    return value


def _serve(fn: Callable[..., Any], args: tuple, jobs: Any, results: Any,
           shared: Mapping[str, Any], spool: str) -> None:
    """The child: the first job, then (with a ``jobs`` pipe) each job that arrives until a
    None or the pipe's end. A result is written to a file in ``spool`` and only its path
    is sent: the pipe holds 64 KB, and a larger result would block this process until the
    parent reads it, with the parent's next job waiting behind it."""
    for index in itertools.count():
        try:
            value = fn(*_resolve(args, shared))
            path = os.path.join(spool, f"{index}.pkl")
            with open(path, "wb") as f:
                pickle.dump(value, f, pickle.HIGHEST_PROTOCOL)
            message = (True, path)
        except BaseException as exc:  # reported to the parent in one line
            message = (False, f"{type(exc).__name__}: {exc}")
        value = None  # not held while waiting for the next job
        results.send(message)
        try:
            job = jobs.recv() if jobs is not None else None
        except EOFError:
            job = None
        if job is None:
            break
        fn, args = job
    results.close()


class PendingResult(Protocol):
    """Files some job is producing (a `Job`, a `Background`): ``result()`` waits for them."""

    def result(self) -> Mapping[str, bytes]: ...


class PendingFiles(Mapping[str, bytes]):
    """Files in memory, some of which jobs (`Worker`, `Background`) are still producing:
    reading one of those waits for its job; listing and testing names does not."""

    def __init__(self, ready: Mapping[str, bytes], pending: Mapping[str, PendingResult]) -> None:
        self._ready, self._pending = ready, pending

    def __getitem__(self, name: str) -> bytes:
        if name in self._ready:
            return self._ready[name]
        if name in self._pending:
            return self._pending[name].result()[name]
        raise KeyError(name)

    def __contains__(self, name: object) -> bool:  # Mapping's would read the file
        return name in self._ready or name in self._pending

    def __iter__(self) -> Iterator[str]:
        yield from self._ready
        yield from (n for n in self._pending if n not in self._ready)

    def __len__(self) -> int:
        return len(set(self._ready) | set(self._pending))
