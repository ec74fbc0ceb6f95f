"""Atomic output folders: every command's files appear at once or not at all.

Files are written into a temporary sibling folder, then swapped in under an advisory lock, so
an interrupted run leaves the previous output untouched and two concurrent runs into one
folder end with one complete set (the last to finish), never a mix.

Every sibling folder a run creates (``.NAME.XXXXXXXX`` for the new files, ``.NAME.old.XXXXXXXX``
for the replaced output, ``.NAME.probe.XXXXXXXX`` for the write check) is created under the
parent's lock and holds its own advisory lock for as long as its run lives, so a later run
tells the folders of a killed run (no lock) from those of a live one and removes them.
"""

from __future__ import annotations

import errno
import fcntl
import os
import re
import shutil
import tempfile
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path

from maglevgen.errors import InputError

__all__ = ["check_writable", "clean_stale_siblings", "remove_stale_siblings", "write_output"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _cannot_write(where: Path, exc: OSError) -> InputError:
    return InputError(f"cannot write to {where}: {exc.strerror or exc}")


@contextmanager
def _locked(parent: Path) -> Iterator[None]:
    """An exclusive advisory lock on the parent folder itself (no lock file left behind)."""
    try:
        fd = os.open(parent, os.O_RDONLY)
    except OSError as exc:
        raise _cannot_write(parent, exc) from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # releases the lock


class _Sibling:
    """A temporary folder beside the output, locked by this process while it exists."""

    def __init__(self, out_dir: Path, kind: str = "") -> None:
        self.path = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.{kind}", dir=out_dir.parent))
        self._fd: int | None = os.open(self.path, os.O_RDONLY)
        fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)

    def remove(self) -> None:
        shutil.rmtree(self.path, ignore_errors=True)
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


def _sibling_pattern(name: str) -> re.Pattern[str]:
    # tempfile.mkdtemp's names: the prefix, then 8 of [a-z0-9_]
    return re.compile(rf"\.{re.escape(name)}\.(?:old\.|probe\.)?[a-z0-9_]{{8}}")


def remove_stale_siblings(out_dir: Path) -> list[Path]:
    """Remove the temporary folders of killed runs into ``out_dir`` (call under the lock):
    those of its naming pattern that no live run holds locked."""
    pattern, removed = _sibling_pattern(out_dir.name), []
    for entry in sorted(out_dir.parent.iterdir()):
        if not pattern.fullmatch(entry.name) or entry.is_symlink() or not entry.is_dir():
            continue
        try:
            fd = os.open(entry, os.O_RDONLY)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            continue  # a live run's folder
        else:
            if not out_dir.exists() and (entry / "d").is_dir():
                # killed between moving the output aside and swapping the new one in
                os.replace(entry / "d", out_dir)
            shutil.rmtree(entry, ignore_errors=True)
            removed.append(entry)
        finally:
            os.close(fd)
    return removed


def clean_stale_siblings(out_dir: Path) -> None:
    """`remove_stale_siblings` under the lock, for a run that writes nothing (an up-to-date
    build); a folder it cannot lock or read is left for the next run that writes."""
    try:
        with _locked(out_dir.parent):
            remove_stale_siblings(out_dir)
    except (OSError, InputError):
        pass


def _mount_points() -> set[str]:
    """Every mount point of this process's namespace (bind mounts included, which
    os.path.ismount does not see when they share the parent's file system)."""
    try:
        text = Path("/proc/self/mountinfo").read_text()
    except OSError:
        return set()
    # field 5 is the mount point, with space, tab, newline and backslash as octal escapes
    return {re.sub(r"\\([0-7]{3})", lambda m: chr(int(m.group(1), 8)), line.split()[4])
            for line in text.splitlines() if len(line.split()) > 4}


def _check_replaceable(out_dir: Path) -> None:
    """Refuse, before any work, an existing output folder that cannot be moved aside."""
    if os.path.ismount(out_dir) or str(out_dir) in _mount_points():
        raise InputError(f"cannot replace {out_dir}: it is a mount point (choose a folder "
                         "inside it, e.g. --out " + str(out_dir / "build") + ")")
    # moving a folder to another parent rewrites its '..' entry: it must be writable
    if not os.access(out_dir, os.W_OK | os.X_OK):
        raise InputError(f"cannot replace {out_dir}: {os.strerror(errno.EACCES)}")


def check_writable(out_dir: Path) -> Path:
    """Fail early (before slow work) when the output folder cannot be created or replaced;
    remove what killed runs into the same folder left beside it."""
    out_dir = Path(out_dir).resolve()
    parent = out_dir.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise _cannot_write(parent, exc) from None
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"cannot write to {out_dir}: it is a file, not a folder")
    with _locked(parent):
        remove_stale_siblings(out_dir)
        try:
            _Sibling(out_dir, "probe.").remove()
        except OSError as exc:
            raise _cannot_write(parent, exc) from None
        if out_dir.is_dir():
            _check_replaceable(out_dir)
    return out_dir


def write_output(files: Mapping[str, str | bytes], out_dir: Path) -> list[Path]:
    """Write ``files`` (relative names, '/' for subfolders) as the whole content of ``out_dir``."""
    out_dir = check_writable(out_dir)
    parent = out_dir.parent
    try:
        with _locked(parent):  # a cleaner under the lock sees it locked from the start
            tmp = _Sibling(out_dir)
        tmp.path.chmod(0o777 & ~_umask())  # mkdtemp makes it private; outputs get the usual mode
    except OSError as exc:
        raise _cannot_write(parent, exc) from None
    old: _Sibling | None = None
    try:
        for name, data in sorted(files.items()):
            path = tmp.path / name
            if path.resolve().parent != tmp.path and tmp.path not in path.resolve().parents:
                raise ValueError(f"output name {name!r} leaves the output folder")
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data.encode("utf-8") if isinstance(data, str) else data)
        with _locked(parent):
            if out_dir.exists():
                old = _Sibling(out_dir, "old.")
                os.replace(out_dir, old.path / "d")
            try:
                os.replace(tmp.path, out_dir)
            except OSError:
                if old is not None:  # the previous output goes back where it was
                    os.replace(old.path / "d", out_dir)
                raise
    except OSError as exc:
        raise _cannot_write(out_dir, exc) from None
    finally:
        tmp.remove()  # gone already when it was swapped in
        if old is not None:
            old.remove()
    return [out_dir / n for n in sorted(files)]
