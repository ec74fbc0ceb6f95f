"""The on-disk cache: where it is, what its keys hash, and the derivation memo store.

Everything cached is parameter independent and keyed by a fingerprint of the source that
produced it and the library versions (read from package metadata, so computing a key imports
nothing heavy). Entries carry a checksum; a corrupted entry reads as absent and is rebuilt.
"""

from __future__ import annotations

import hashlib
import os
import sys
import tempfile
from collections.abc import Callable, Iterable
from functools import cache
from importlib import metadata, util
from pathlib import Path
from typing import Any

from . import __version__

# The derivation and the code generator (what the cached C and the memoised steps depend on).
DERIVATION_PACKAGES = ("maglevgen.derive", "maglevgen.codegen")
DERIVATION_FILES = ("maglevgen/params.py", "templates/maglev_simulate.*.j2")
DERIVATION_LIBS = ("casadi", "sympy", "numpy", "cloudpickle")
# Everything a build's outputs depend on.
ALL_PACKAGES = ("maglevgen", "maglevgen.derive", "maglevgen.codegen", "maglevgen.runtime",
                "maglevgen.templates")
ALL_LIBS = ("casadi", "sympy", "numpy", "scipy", "control", "matplotlib", "jinja2",
            "cloudpickle", "mpmath")


DEFAULT_PARAMS_NAME = "carriage_llnl.toml"  # the default carriage, inside the maglevgen package


def params_digest(text: str, overrides: Iterable[str]) -> str:
    """sha256 of a parameter file's text and the --set overrides applied to it."""
    digest = hashlib.sha256(text.encode("utf-8"))
    for item in overrides:
        digest.update(b"\0" + item.encode("utf-8"))
    return digest.hexdigest()


def default_cache_dir() -> Path:
    base = os.environ.get("MAGLEVGEN_CACHE") or os.environ.get("XDG_CACHE_HOME")
    return Path(base) / "maglevgen" if base else Path.home() / ".cache" / "maglevgen"


def _package_root(pkg: str) -> Path:
    spec = util.find_spec(pkg)
    if spec is None or not spec.submodule_search_locations:
        raise RuntimeError(f"package {pkg} not found")
    return Path(next(iter(spec.submodule_search_locations)))


def _resolve(rel: str) -> list[Path]:
    """'maglevgen/params.py' or 'templates/x.*.j2' (a glob) -> the installed files."""
    head, pattern = rel.split("/", 1)
    pkg = {"maglevgen": "maglevgen", "templates": "maglevgen.templates"}[head]
    found = sorted(_package_root(pkg).glob(pattern))
    if not found:
        raise RuntimeError(f"{rel}: no such file in the installed package")
    return found


def _hash_files(h: Any, files: Iterable[tuple[str, Path]]) -> None:
    for label, path in files:
        h.update(label.encode() + b"\0" + hashlib.sha256(path.read_bytes()).digest())


def _versions(libs: Iterable[str]) -> str:
    out = [f"maglevgen={__version__}", f"python={sys.version_info[:2]}"]
    for lib in libs:
        try:
            out.append(f"{lib}={metadata.version(lib)}")
        except metadata.PackageNotFoundError:
            out.append(f"{lib}=-")
    return ";".join(out)


def fingerprint(packages: Iterable[str], files: Iterable[str], libs: Iterable[str],
                recursive: bool = False) -> str:
    """sha256 of the named packages' .py/.j2/.toml files, extra files and library versions."""
    h = hashlib.sha256(_versions(libs).encode())
    for pkg in packages:
        root = _package_root(pkg)
        found = root.rglob("*") if recursive else root.iterdir()
        _hash_files(h, ((f"{pkg}/{f.relative_to(root)}", f) for f in sorted(found)
                        if f.suffix in (".py", ".j2", ".toml") and "__pycache__" not in f.parts))
    _hash_files(h, ((f"{rel}:{p.name}", p) for rel in files for p in _resolve(rel)))
    return h.hexdigest()


@cache
def derivation_fingerprint() -> str:
    return fingerprint(DERIVATION_PACKAGES, DERIVATION_FILES, DERIVATION_LIBS)


def toolchain_fingerprint() -> str:
    return fingerprint(ALL_PACKAGES, (), ALL_LIBS, recursive=True)


def write_atomic(path: Path, data: bytes) -> bool:
    """Write through a temporary file and rename; False (no exception) when not writable."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
        return True
    except OSError:
        return False


class DiskStore:
    """derive.memo's cross-process store: cloudpickled results under the derivation's key.

    File layout: 64 hex digits of sha256(payload), then the payload; any mismatch or
    unpickling error reads as a miss.
    """

    def __init__(self, progress: Callable[[str], None] | None = None) -> None:
        self.progress = progress

    def _path(self, key: str) -> Path:
        digest = hashlib.sha256((derivation_fingerprint() + key).encode()).hexdigest()[:32]
        return default_cache_dir() / "memo" / f"{digest}.pkl"

    def get(self, key: str) -> Any:
        from .derive.memo import MISSING

        try:
            blob = self._path(key).read_bytes()
            if hashlib.sha256(blob[64:]).hexdigest().encode() == blob[:64]:
                import cloudpickle

                return cloudpickle.loads(blob[64:])
        except Exception:  # absent, truncated or unreadable: derive again
            pass
        if self.progress is not None:
            self.progress(f"deriving {key.split('(')[0].rsplit('.', 1)[-1]} (cached afterwards)")
        return MISSING

    def put(self, key: str, value: Any) -> None:
        import cloudpickle

        data = cloudpickle.dumps(value)
        write_atomic(self._path(key), hashlib.sha256(data).hexdigest().encode() + data)


STORE = DiskStore()
