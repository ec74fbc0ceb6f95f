"""Compile generated C into a shared library, cached by the content hash of sources and flags."""

from __future__ import annotations

import errno
import functools
import os
import shlex
import shutil
import subprocess
import tempfile
from collections.abc import Callable, Sequence
from contextlib import suppress
from pathlib import Path

from maglevgen.errors import InputError, MaglevError
from maglevgen.infrastructure.cache import cache_root, sign_file, signature_ok, write_atomic
from maglevgen.infrastructure.hashing import ContentHash

__all__ = ["DEFAULT_FLAGS", "HOST_TUNED_FLAGS", "CompileError", "cached_shared",
           "compile_object", "compile_shared", "compiler_name", "trusted"]

DEFAULT_FLAGS: tuple[str, ...] = ("-std=c99", "-O2", "-fPIC", "-shared")
#: DEFAULT_FLAGS at -O3 (one -O level on the line) for the libraries that only ever run on the
#: machine that compiled them, where the time goes (the Monte-Carlo lanes' driver, the
#: firmware's sense tick for the host): tuned for this CPU, with no fused multiply-add formed,
#: so every operation is the same IEEE operation as at -O2 and every result the same bits:
#: -ffp-contract=off (-std=c99 implies it for gcc, not for clang), and no SLP vectorisation,
#: whose add-sub patterns GCC 12 fuses into vfmaddsub/vfmsubadd even so (the firmware's
#: written-out gain schedule lost bits that way). tests/test_sensed.py disassembles both
#: libraries for fused instructions. The cache key of a library built with them holds what
#: -march=native means on this machine (`_native_target`): a cache folder shared by different
#: CPUs keeps one library per CPU.
HOST_TUNED_FLAGS: tuple[str, ...] = (*("-O3" if f == "-O2" else f for f in DEFAULT_FLAGS),
                                     "-march=native", "-ffp-contract=off",
                                     "-fno-tree-slp-vectorize")


class CompileError(MaglevError):
    """The compiler rejected the generated code (an internal failure: exit 1)."""


def compiler_name(cc: str | None = None) -> str:
    """The C compiler asked for: ``cc``, else $CC, else gcc."""
    return cc or os.environ.get("CC") or "gcc"


def find_compiler(cc: str | None = None) -> str:
    """The C compiler's path (`compiler_name`); a clear error when there is none."""
    name = compiler_name(cc)
    path = shutil.which(name)
    if path is None:
        raise InputError(f"C compiler {name!r} not found (install gcc or set CC)")
    return path


def compile_shared(sources: Sequence[Path], flags: Sequence[str] = DEFAULT_FLAGS,
                   cc: str | None = None, cache_dir: Path | None = None,
                   progress: Callable[[str], None] | None = None) -> Path:
    """Build (or reuse) a shared library from C sources; returns its path.

    The cache key hashes the compiler path, flags and every source's and header's bytes, so a
    stale entry can never be returned; a cached library whose bytes do not match the
    signature recorded beside it (`maglevgen.infrastructure.cache.sign`: corrupted, or not
    compiled by this user's runs) is never loaded and is compiled again. The library and its
    signature are written to temporary names and renamed.
    """
    compiler = find_compiler(cc)
    sources = [Path(s).resolve() for s in sources]
    lib = _library_path(compiler, sources, flags, cache_dir)
    if _intact(lib):
        return lib
    cache, key = lib.parent, lib.name.removeprefix("lib").removesuffix(".so")
    _refused(lib, progress)
    if progress is not None:
        progress(f"compiling {sources[0].name} ({' '.join(flags)}; cached afterwards)")
    try:
        cache.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create the cache folder {cache}: {exc.strerror}") from None
    tmp = _temporary(cache, f".lib{key}.", ".so")
    cmd = [compiler, *flags, *map(str, sources), "-o", tmp, "-lm"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    _check_compiled(proc, tmp, sources[0], cache)
    _store(tmp, lib)
    return lib


def compile_object(source: Path, flags: Sequence[str] = ("-std=c99", "-O2", "-fPIC"),
                   cc: str | None = None, cache_dir: Path | None = None,
                   progress: Callable[[str], None] | None = None) -> Path:
    """Compile one C file to an object file (``-c``), or reuse it; returns its path.

    For the large generated functions that several shared libraries link (the FMUs: one
    wrapper each around the same carriage functions), so they are compiled once. Cached as
    `compile_shared` caches: the key hashes the compiler path, the flags and the bytes of the
    source and of every C file and header beside it; written to a temporary name, checked
    against its recorded checksum when reused.
    """
    compiler = find_compiler(cc)
    source = Path(source).resolve()
    key = _library_path(compiler, [source], (*flags, "-c"), cache_dir)
    obj = key.with_name(key.name.removeprefix("lib").removesuffix(".so") + ".o")
    if _intact(obj):
        return obj
    _refused(obj, progress)
    if progress is not None:
        progress(f"compiling {source.name} ({' '.join(flags)}; cached afterwards)")
    try:
        obj.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create the cache folder {obj.parent}: {exc.strerror}"
                         ) from None
    tmp = _temporary(obj.parent, f".{obj.stem}.", ".o")
    proc = subprocess.run([compiler, *flags, "-c", str(source), "-o", tmp],
                          capture_output=True, text=True)
    _check_compiled(proc, tmp, source, obj.parent)
    _store(tmp, obj)
    return obj


def _disk_full(where: Path, exc: OSError | None = None) -> InputError:
    """A full disk (or quota) in the cache: bad input as --out's is (exit 2, one line)."""
    why = exc.strerror if exc is not None and exc.strerror else os.strerror(errno.ENOSPC)
    return InputError(f"cannot write to the cache folder {where}: {why}")


def _temporary(folder: Path, prefix: str, suffix: str) -> str:
    try:
        fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=suffix, dir=folder)
    except OSError as exc:
        raise _disk_full(folder, exc) from None
    os.close(fd)
    return tmp


def _check_compiled(proc: subprocess.CompletedProcess, tmp: str, source: Path,
                    folder: Path) -> None:
    """A failed compile: its temporary removed (gcc may have removed it already), a full
    disk as exit 2, anything else as the compiler's first line (exit 1)."""
    if proc.returncode == 0:
        return
    with suppress(FileNotFoundError):
        os.unlink(tmp)
    if "No space left on device" in proc.stderr or "Disk quota exceeded" in proc.stderr:
        raise _disk_full(folder)
    first = (proc.stderr.strip().splitlines() or ["(no output)"])[0]
    raise CompileError(f"compiling {source.name} failed: {first}")


def _store(tmp: str, entry: Path) -> None:
    """The compiled file signed and renamed into place; a signature that cannot be written
    (a full disk) leaves no entry."""
    try:
        signature = sign_file(Path(tmp))
    except OSError as exc:
        raise _disk_full(entry.parent, exc) from None
    if not write_atomic(_checksum_path(entry), (signature + "\n").encode()):
        with suppress(FileNotFoundError):
            os.unlink(tmp)
        raise _disk_full(entry.parent)
    os.replace(tmp, entry)


def cached_shared(sources: Sequence[Path], flags: Sequence[str] = DEFAULT_FLAGS,
                  cc: str | None = None, cache_dir: Path | None = None) -> Path | None:
    """The library `compile_shared` would return, when it is cached and intact; else None
    (nothing is compiled, and a missing compiler is not an error here)."""
    compiler = shutil.which(compiler_name(cc))
    if compiler is None:
        return None
    lib = _library_path(compiler, [Path(s).resolve() for s in sources], flags, cache_dir)
    return lib if _intact(lib) else None


def _library_path(compiler: str, sources: Sequence[Path], flags: Sequence[str],
                  cache_dir: Path | None) -> Path:
    """Where the library of these sources, flags and compiler is cached: its key hashes the
    compiler path, the flags and every source's and header's bytes."""
    h = ContentHash(compiler, *flags, *(_native_target(compiler) if "-march=native" in flags
                                        else ()))
    for src in sources:
        h.files((f.name, f) for f in (sorted(src.parent.glob("*.[ch]")) if src.suffix == ".c"
                                      else [src]))
    return cache_root(cache_dir) / f"lib{h.hexdigest(24)}.so"


@functools.cache
def _native_target(compiler: str) -> tuple[str, ...]:
    """What ``-march=native`` stands for with this compiler on this CPU: the options its driver
    passes the compiler proper (gcc's cc1 ``-march=... -m...``; clang's ``-target-cpu ...
    -target-feature ...``), paths left out; empty when the driver does not say."""
    try:
        proc = subprocess.run([compiler, "-march=native", "-###", "-x", "c", "-c", os.devnull,
                               "-o", os.devnull], capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.SubprocessError):
        return ()
    lines = [ln for ln in proc.stderr.splitlines() if "cc1" in ln]
    return tuple(t for ln in lines for t in shlex.split(ln) if "/" not in t)


def _checksum_path(lib: Path) -> Path:
    return lib.with_name(lib.name + ".hmac")


def _intact(lib: Path) -> bool:
    """A cached library that is a regular ELF file (no link) and matches its recorded
    signature (`maglevgen.infrastructure.cache.sign`)."""
    if lib.is_symlink() or not _looks_like_elf(lib):
        return False
    try:
        recorded = _checksum_path(lib).read_text()
        return signature_ok(recorded, sign_file(lib))
    except (OSError, UnicodeDecodeError):
        return False


def trusted(lib: Path) -> bool:
    """``lib`` is one this user's runs compiled into a cache (its signature verifies): the
    only libraries the tool loads."""
    return _intact(Path(lib))


def _refused(entry: Path, progress: Callable[[str], None] | None) -> None:
    """Say so when an entry is there but its signature does not verify (planted, corrupted,
    or from another user's key): it is not loaded, and compiled again over it."""
    if progress is not None and (entry.exists() or entry.is_symlink()):
        progress(f"cache entry {entry.name} is not signed by this user's cache key "
                 "(corrupted or not made by maglevgen here): not loaded, compiled again")


def _looks_like_elf(path: Path) -> bool:
    try:
        with path.open("rb") as f:
            head = f.read(4)
        return head == b"\x7fELF" and path.stat().st_size > 1024
    except OSError:
        return False
