"""The on-disk cache: where it is, what its keys hash, and the derivation memo store.

Every key is a `maglevgen.infrastructure.hashing.ContentHash` of everything the cached value
depends on: the
source closure of the module that computes it (`hashing.source_closure`: its file and every
maglevgen module it imports, followed through the package), the library versions and the
arguments. An edit to any of those files is therefore a miss, whatever module it is in.
Entries carry a checksum; a corrupted entry reads as absent and is rebuilt.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Iterable
from functools import cache
from pathlib import Path
from typing import Any

from maglevgen.derive import memo
from maglevgen.infrastructure.hashing import ContentHash, closure_hash, package_root, sha256_hex
from maglevgen.version import __version__

__all__ = [
    "ALL_LIBS",
    "ALL_PACKAGES",
    "DEFAULT_PARAMS_NAME",
    "DERIVATION_LIBS",
    "DERIVATION_TEMPLATES",
    "MEMO_LIBS",
    "STORE",
    "DiskStore",
    "cache_root",
    "default_cache_dir",
    "derivation_fingerprint",
    "install_store",
    "params_digest",
    "toolchain_fingerprint",
    "write_atomic",
]

# What the cached C of the derivation depends on besides the generator's source closure.
# (every template render_runtime_sources renders or imports)
DERIVATION_TEMPLATES = ("maglev_simulate.*.j2", "maglev_checks.c.j2", "maglev_errors.h.j2",
                        "c_prototype.h.j2", "casadi_output.j2", "generated_file.j2")
DERIVATION_LIBS = ("casadi", "sympy", "numpy", "cloudpickle")
# Everything a build's outputs depend on.
ALL_PACKAGES = ("maglevgen", "maglevgen.derive", "maglevgen.codegen", "maglevgen.runtime",
                "maglevgen.templates")
ALL_LIBS = ("casadi", "sympy", "numpy", "scipy", "control", "matplotlib", "jinja2",
            "cloudpickle", "mpmath")
MEMO_LIBS = ("sympy", "numpy", "scipy", "mpmath", "cloudpickle")


DEFAULT_PARAMS_NAME = "carriage_llnl.toml"  # the default carriage, inside the maglevgen package


def params_digest(text: str, overrides: Iterable[str]) -> str:
    """sha256 of a parameter file's text (what `sha256sum` prints for it) and of the --set
    overrides applied to it, each after a NUL."""
    h = ContentHash().raw(text.encode("utf-8"))
    for item in overrides:
        h.raw(b"\0" + item.encode("utf-8"))
    return h.hexdigest()


def default_cache_dir() -> Path:
    base = os.environ.get("MAGLEVGEN_CACHE") or os.environ.get("XDG_CACHE_HOME")
    return Path(base) / "maglevgen" if base else Path.home() / ".cache" / "maglevgen"


def cache_root(cache_dir: Path | None) -> Path:
    """The cache folder: ``cache_dir`` when given, else `default_cache_dir`."""
    return Path(cache_dir) if cache_dir else default_cache_dir()


@cache
def derivation_fingerprint() -> str:
    """The key of the generated run-time-parameter C: the generator's source closure, its
    templates and the libraries' versions."""
    templates = package_root("maglevgen.templates")
    h = closure_hash("maglevgen.codegen.generate").versions(DERIVATION_LIBS)
    h.text("maglevgen", __version__)
    h.files((f"templates/{p.name}", p) for pattern in DERIVATION_TEMPLATES
            for p in sorted(templates.glob(pattern)))
    return h.hexdigest()


def toolchain_fingerprint() -> str:
    """Every source, template and data file of the installed toolchain, and the libraries."""
    h = ContentHash().versions(ALL_LIBS).text("maglevgen", __version__)
    for pkg in ALL_PACKAGES:
        root = package_root(pkg)
        h.files((f"{pkg}/{f.relative_to(root)}", f) for f in sorted(root.rglob("*"))
                if f.suffix in (".py", ".j2", ".toml") and "__pycache__" not in f.parts)
    return h.hexdigest()


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


@cache
def _memo_versions() -> str:
    return ContentHash().versions(MEMO_LIBS).text("maglevgen", __version__).hexdigest()


@cache
def _module_key(module: str) -> str:
    """The part of a memo key that covers the computing module's source closure."""
    return closure_hash(module).text("versions", _memo_versions()).hexdigest()


class DiskStore:
    """derive.memo's cross-process store: cloudpickled results, keyed by the computing
    module's source closure (`_module_key`) and the call.

    File layout: 64 hex digits of sha256(payload), then the payload; any mismatch or
    unpickling error reads as a miss.
    """

    def __init__(self, progress: Callable[[str], None] | None = None) -> None:
        self.progress = progress
        self.misses = 0  # entries derived afresh by this process (what the tests observe)

    def path(self, module: str, key: str) -> Path:
        digest = ContentHash(_module_key(module), key).hexdigest(32)
        return default_cache_dir() / "memo" / f"{digest}.pkl"

    def get(self, module: str, key: str) -> Any:
        try:
            blob = self.path(module, key).read_bytes()
            if sha256_hex(blob[64:]).encode() == blob[:64]:
                import cloudpickle  # local: only when an entry is read (light path: hashing)

                return cloudpickle.loads(blob[64:])
        except Exception:  # absent, truncated or unreadable: derive again
            pass
        self.misses += 1
        if self.progress is not None:
            self.progress(f"deriving {key.split('(')[0].rsplit('.', 1)[-1]} (cached afterwards)")
        return memo.MISSING

    def put(self, module: str, key: str, value: Any) -> None:
        import cloudpickle  # local: only when an entry is written

        data = cloudpickle.dumps(value)
        write_atomic(self.path(module, key), sha256_hex(data).encode() + data)


STORE = DiskStore()


def install_store() -> DiskStore:
    """Share derive.memo's results across processes through `STORE` (derive/ does no I/O
    itself; the application installs the store when it builds a carriage)."""
    memo.set_store(STORE)
    return STORE
