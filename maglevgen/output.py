"""Atomic output folders: every command's files appear at once or not at all.

Files are written into a temporary sibling folder, then swapped in under an advisory lock, so
an interrupted run leaves the previous output untouched and two concurrent runs into one
folder end with one complete set (the last to finish), never a mix.
"""

from __future__ import annotations

import fcntl
import os
import shutil
import tempfile
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path

from .errors import InputError


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def check_writable(out_dir: Path) -> Path:
    """Fail early (before slow work) when the output folder cannot be created or replaced."""
    out_dir = Path(out_dir).resolve()
    parent = out_dir.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        probe = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.probe.", dir=parent))
        probe.rmdir()
    except OSError as exc:
        raise InputError(f"cannot write to {parent}: {exc.strerror}") from None
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"cannot write to {out_dir}: it is a file, not a folder")
    return out_dir


@contextmanager
def _locked(parent: Path) -> Iterator[None]:
    """An exclusive advisory lock on the parent folder itself (no lock file left behind)."""
    fd = os.open(parent, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # releases the lock


def write_output(files: Mapping[str, str | bytes], out_dir: Path) -> list[Path]:
    """Write ``files`` (relative names, '/' for subfolders) as the whole content of ``out_dir``."""
    out_dir = check_writable(out_dir)
    parent = out_dir.parent
    try:
        tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", dir=parent))
        tmp.chmod(0o777 & ~_umask())  # mkdtemp makes it private; outputs get the usual mode
    except OSError as exc:
        raise InputError(f"cannot write to {parent}: {exc.strerror}") from None
    try:
        for name, data in sorted(files.items()):
            path = tmp / name
            if path.resolve().parent != tmp and tmp not in path.resolve().parents:
                raise ValueError(f"output name {name!r} leaves the output folder")
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data.encode("utf-8") if isinstance(data, str) else data)
        with _locked(parent):
            old = None
            if out_dir.exists():
                old = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.old.", dir=parent))
                os.replace(out_dir, old / "d")
            os.replace(tmp, out_dir)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        raise InputError(f"cannot write to {out_dir}: {exc.strerror}") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return [out_dir / n for n in sorted(files)]
