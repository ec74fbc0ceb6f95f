"""Memoisation of the expensive, parameter-independent derivation steps.

The derivation depends on the carriage's structure, never on parameter values, so its slow
steps (differentiating the wrench, solving the Riccati equation, lambdifying) are pure
functions of hashable arguments. ``memoized`` keeps their results in the process and, when a
store is installed, across processes. derive/ does no I/O itself: the application installs
the store (maglevgen.infrastructure.cache.DiskStore), which must key an entry by the source of
everything
the computing module (passed with the key) depends on.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, Protocol, TypeVar

__all__ = ["MISSING", "memoized", "set_store"]

F = TypeVar("F", bound=Callable[..., Any])
MISSING = object()


class Store(Protocol):
    def get(self, module: str, key: str) -> Any: ...  # MISSING when absent or unreadable

    def put(self, module: str, key: str, value: Any) -> None: ...


_store: Store | None = None


def set_store(store: Store | None) -> None:
    """Install (or remove, with None) the cross-process store."""
    global _store
    _store = store


def memoized(fn: F) -> F:
    """Like functools.cache, and shared through the installed store (key: name and args)."""
    results: dict[tuple, Any] = {}

    @functools.wraps(fn)
    def wrapper(*args: Any) -> Any:
        if args in results:
            return results[args]
        key = f"{fn.__module__}.{fn.__qualname__}{args!r}"
        store = _store
        value = store.get(fn.__module__, key) if store is not None else MISSING
        if value is MISSING:
            value = fn(*args)
            if store is not None:
                store.put(fn.__module__, key, value)
        results[args] = value
        return value

    wrapper.cache_clear = results.clear  # type: ignore[attr-defined]
    return wrapper  # type: ignore[return-value]
