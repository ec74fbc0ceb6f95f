"""Atomic output folders: every command's files appear at once or not at all.

Files are written into a temporary sibling folder, then swapped in under an advisory lock, so
an interrupted run leaves the previous output untouched and two concurrent runs into one
folder end with one complete set (the last to finish), never a mix.

Every sibling folder a run creates (``.NAME.XXXXXXXX`` for the new files, ``.NAME.old.XXXXXXXX``
for the replaced output, ``.NAME.probe.XXXXXXXX`` for the write check) is created under the
parent's lock and holds its own advisory lock for as long as its run lives, so a later run
tells the folders of a killed run (no lock) from those of a live one and removes them.

A folder is written only when it is new, empty, or holds nothing but what maglevgen wrote
there before: the names its `MARKER` lists (every output folder gets one), and a build's
BUILD.json with the names it lists. Anything else (the user's thesis beside a parameter
file, a file added to a build) is refused with exit 2 before any work, checked again under
the lock just before the swap, and the replaced output is removed name by name from that list,
so a file maglevgen did not write is never deleted.
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import re
import shutil
import tempfile
from collections.abc import Iterator, Mapping
from contextlib import contextmanager, suppress
from pathlib import Path

from maglevgen.errors import InputError
from maglevgen.infrastructure.text import shown_name

__all__ = ["MARKER", "InputError", "Path", "check_writable", "clean_stale_siblings",
           "foreign_entry", "owned_names", "remove_stale_siblings", "write_output"]

#: the file every output folder gets: the names maglevgen wrote there (the folder's own list)
MARKER = ".maglevgen-output.json"
_BUILD_STAMP = "BUILD.json"  # maglevgen.build.STAMP (output sits below build: named here)


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
        self.release()

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


def _listed(folder: Path, name: str, key: str) -> set[str] | None:
    """The relative names a maglevgen list file in ``folder`` holds under ``key`` (None: no
    such file, or not a list of relative names inside the folder)."""
    path = folder / name
    if path.is_symlink() or not path.is_file():
        return None
    try:
        names = json.loads(path.read_text(encoding="utf-8"))[key]
    except (OSError, ValueError, KeyError, TypeError, UnicodeDecodeError):
        return None
    if not isinstance(names, list | dict):
        return None
    out = set()
    for n in names:
        if not isinstance(n, str) or not n or n.startswith("/") or "\0" in n \
                or any(part in ("", ".", "..") for part in n.split("/")):
            return None  # an entry outside the folder: not a list maglevgen wrote
        out.add(n)
    return out | {name}


def owned_names(folder: Path) -> set[str] | None:
    """The relative file names maglevgen wrote into ``folder`` (its `MARKER`'s list, a
    build's BUILD.json list, each with the list file itself); None when it holds neither."""
    lists = [n for n in (_listed(folder, MARKER, "files"), _listed(folder, _BUILD_STAMP, "files"))
             if n is not None]
    return set().union(*lists) if lists else None


def foreign_entry(folder: Path, owned: set[str]) -> str | None:
    """The first path under ``folder`` (relative, sorted walk) that is not one of ``owned``
    nor a folder holding only owned names; None when there is none. Symbolic links are
    entries of their own, never followed."""
    for root, dirs, files in os.walk(folder):
        rel_root = Path(root).relative_to(folder)
        entries = sorted(files + [d for d in dirs if (Path(root) / d).is_symlink()])
        dirs[:] = sorted(d for d in dirs if not (Path(root) / d).is_symlink())
        for name in entries:
            rel = (rel_root / name).as_posix()
            if rel not in owned:
                return rel
        for d in dirs:
            rel = (rel_root / d).as_posix()
            if not any(o.startswith(rel + "/") for o in owned):
                return rel + "/"
    return None


def check_owned(out_dir: Path) -> None:
    """Refuse (InputError, exit 2) an existing ``out_dir`` that holds anything maglevgen did
    not write there: writing would replace it."""
    if not out_dir.is_dir():
        return
    try:
        if not any(out_dir.iterdir()):
            return
        owned = owned_names(out_dir)
        extra = "" if owned is None else foreign_entry(out_dir, owned)
    except OSError as exc:
        raise _cannot_write(out_dir, exc) from None
    if extra is not None:
        what = f" ({shown_name(extra)})" if extra else ""
        raise InputError(f"{shown_name(out_dir)} holds files maglevgen did not write{what}; "
                         "pick another "
                         "--out or empty it")


def _remove_owned(folder: Path, owned: set[str] | None) -> bool:
    """Remove from ``folder`` the names maglevgen wrote (``owned``; None: read its lists),
    then the folders left empty; True when the folder itself is gone. A file not listed
    stays where it is, and so do the lists (a later cleaner then still knows the folder)."""
    if owned is None:
        owned = owned_names(folder) or set()
    lists = {MARKER, _BUILD_STAMP}
    for rel in sorted(owned - lists):
        with suppress(OSError):  # absent, or a folder now: left
            (folder / rel).unlink()
    _remove_empty_folders(folder)
    if foreign_entry(folder, owned & lists) is not None:
        return False
    for rel in sorted(owned & lists):
        with suppress(OSError):
            (folder / rel).unlink()
    _remove_empty_folders(folder)
    return not folder.exists()


def _remove_empty_folders(folder: Path) -> None:
    for root, _dirs, _files in os.walk(folder, topdown=False):  # deepest first
        with suppress(OSError):  # not empty
            os.rmdir(root)


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
            old = entry / "d"
            if not out_dir.exists() and old.is_dir():
                # killed between moving the output aside and swapping the new one in
                os.replace(old, out_dir)
            # an output folder moved aside holds its list (no other folder is ever moved
            # aside but the tool's cache entries): removed name by name
            if (old.is_dir() and not old.is_symlink() and owned_names(old) is not None
                    and not _remove_owned(old, None)):
                continue  # a file maglevgen did not write (added during a swap): kept
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


def check_writable(out_dir: Path, ours: bool = False) -> Path:
    """Fail early (before slow work) when the output folder cannot be created or replaced
    (`check_owned`, unless ``ours``: a folder of the tool's own cache); remove what killed
    runs into the same folder left beside it."""
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
            if not ours:
                check_owned(out_dir)
            _check_replaceable(out_dir)
    return out_dir


def write_output(files: Mapping[str, str | bytes], out_dir: Path,
                 ours: bool = False) -> list[Path]:
    """Write ``files`` (relative names, '/' for subfolders) as the whole content of ``out_dir``,
    with the `MARKER` listing them. ``ours``: a folder inside the tool's own cache, replaced
    whole whatever it holds."""
    if MARKER in files:
        raise ValueError(f"output name {MARKER!r} is the marker's")
    out_dir = check_writable(out_dir, ours)
    parent = out_dir.parent
    try:
        with _locked(parent):  # a cleaner under the lock sees it locked from the start
            tmp = _Sibling(out_dir)
        tmp.path.chmod(0o777 & ~_umask())  # mkdtemp makes it private; outputs get the usual mode
    except OSError as exc:
        raise _cannot_write(parent, exc) from None
    old: _Sibling | None = None
    owned_before: set[str] | None = None
    marker = json.dumps({"written_by": "maglevgen", "files": sorted(files)}, indent=0) + "\n"
    try:
        for name, data in sorted({**files, MARKER: marker}.items()):
            path = tmp.path / name
            if path.resolve().parent != tmp.path and tmp.path not in path.resolve().parents:
                raise ValueError(f"output name {name!r} leaves the output folder")
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data.encode("utf-8") if isinstance(data, str) else data)
        with _locked(parent):
            if out_dir.exists() and not ours:
                check_owned(out_dir)  # again: files may have been added since the start
                owned_before = owned_names(out_dir)
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
            # the replaced output, name by name: a file added since the check stays there
            if not ours and old.path.joinpath("d").is_dir() and not _remove_owned(
                    old.path / "d", owned_before):
                old.release()  # kept beside the output with what it still holds
            else:
                old.remove()
    return [out_dir / n for n in sorted(files)]
