"""A second process for the figures, through concurrent.futures.

`maglevgen build` and `maglevgen simulate` draw their figures (matplotlib costs about half a
second to import) and write the trajectories in one worker process while this one goes on.
`child` is a ProcessPoolExecutor with one worker started by fork, so data passed as ``shared``
is inherited by the child, not pickled (`Shared` names it in a job's arguments); where fork is
not available it is a one-thread ThreadPoolExecutor. `Job` turns a job's failure into one line
naming the job (MaglevError, exit 1).

Every worker process the tool starts (`process_pool`: these, the Monte-Carlo pool, the
report's figure process) dies with the process that started it: a killed build (SIGKILL, where
nothing of the parent runs any more) leaves no worker behind. On Linux the worker asks the
kernel for SIGKILL at its parent's death (prctl PR_SET_PDEATHSIG, through ctypes, first thing
in the worker), and ends at once when the parent is already gone.
"""

from __future__ import annotations

import ctypes
import errno
import multiprocessing
import os
import signal
import sys
from collections.abc import Callable, Iterator, Mapping
from concurrent.futures import Executor, Future, ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Protocol

from maglevgen.errors import InputError, MaglevError

__all__ = ["Job", "PendingFiles", "Shared", "child", "process_pool", "submit"]

_PR_SET_PDEATHSIG = 1  # linux/prctl.h

_shared: dict[str, Any] = {}  # in the child: the data it was started with


@dataclass(frozen=True)
class Shared:
    """A job argument the child already holds: an entry of `child`'s ``shared`` data."""

    name: str


def die_with_parent(parent: int) -> None:
    """In a worker process: be killed when the process ``parent`` (the one that started
    this worker) dies, and end now if it already has (it died before this call)."""
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent:
        os._exit(1)


def _init(parent: int, then: Callable[..., Any] | None, args: tuple) -> None:
    die_with_parent(parent)
    if then is not None:
        then(*args)


def process_pool(max_workers: int, mp_context=None, initializer: Callable[..., Any] | None = None,
                 initargs: tuple = ()) -> ProcessPoolExecutor:
    """A ProcessPoolExecutor whose workers die with this process (`die_with_parent`), then
    run ``initializer(*initargs)``."""
    return ProcessPoolExecutor(max_workers, mp_context=mp_context, initializer=_init,
                               initargs=(os.getpid(), initializer, tuple(initargs)))


def _hold(shared: dict[str, Any]) -> None:
    _shared.clear()
    _shared.update(shared)


def _call(fn: Callable[..., Any], args: tuple) -> Any:
    return fn(*(_shared[a.name] if isinstance(a, Shared) else a for a in args))


@contextmanager
def child(shared: Mapping[str, Any] | None = None) -> Iterator[Executor]:
    """One worker that runs jobs in order; ``shared`` reaches it by fork, not by pickle.
    Leaving the block by an exception stops the worker (its jobs fail or are cancelled)."""
    initargs = (dict(shared or {}),)
    if "fork" in multiprocessing.get_all_start_methods():
        pool: Executor = process_pool(1, mp_context=multiprocessing.get_context("fork"),
                                      initializer=_hold, initargs=initargs)
    else:
        pool = ThreadPoolExecutor(1, initializer=_hold, initargs=initargs)
    try:
        yield pool
    except BaseException:
        _stop(pool)
        raise
    pool.shutdown(wait=True)


def _stop(pool: Executor) -> None:
    """Cancel the jobs not started and end the worker process (the executor queues a job
    ahead, so cancelling alone would wait for it)."""
    terminate = getattr(pool, "terminate_workers", None)  # Python 3.14
    if terminate is not None:
        terminate()
    else:
        procs = list((getattr(pool, "_processes", None) or {}).values())
        for proc in procs:
            proc.terminate()
        for proc in procs:
            proc.join()
        # A worker killed while it sends a result leaves half a message in the result pipe,
        # and the executor's thread would wait for the rest for ever (shutdown, and the
        # interpreter's exit, join that thread). With the parent's own copy of the pipe's
        # writing end closed, that thread reads end-of-file instead and marks the pool broken.
        results = getattr(pool, "_result_queue", None)
        if results is not None:
            results._writer.close()
    pool.shutdown(wait=True, cancel_futures=True)


class Job:
    """A submitted job; ``result()`` waits for it, a failure is one line naming the job."""

    def __init__(self, what: str, future: Future) -> None:
        self.what, self.future = what, future

    def result(self) -> Any:
        try:
            return self.future.result()
        except BrokenProcessPool:
            raise MaglevError(f"{self.what} failed: the child process ended") from None
        except OSError as exc:
            if exc.errno in (errno.ENOSPC, errno.EDQUOT):  # a full disk: exit 2, as --out's
                where = f" to {exc.filename}" if exc.filename else ""
                raise InputError(f"{self.what} failed: cannot write{where}: {exc.strerror}"
                                 ) from None
            raise MaglevError(f"{self.what} failed: {type(exc).__name__}: "
                              f"{' '.join(str(exc).split())}") from None
        except Exception as exc:
            raise MaglevError(f"{self.what} failed: {type(exc).__name__}: "
                              f"{' '.join(str(exc).split())}") from None


def submit(pool: Executor, what: str, fn: Callable[..., Any], *args: Any) -> Job:
    """Run ``fn(*args)`` in ``pool`` after its earlier jobs (`Shared` arguments resolved
    there)."""
    return Job(what, pool.submit(_call, fn, args))


class PendingResult(Protocol):
    """Files a job is producing: ``result()`` waits for them."""

    def result(self) -> Mapping[str, bytes]: ...


class PendingFiles(Mapping[str, bytes]):
    """Files in memory, some of which jobs are still producing: reading one of those waits
    for its job; listing and testing names does not."""

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
