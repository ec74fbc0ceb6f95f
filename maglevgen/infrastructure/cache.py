"""The on-disk cache: where it is, what its keys hash, and the derivation memo store.

Every key is a `maglevgen.infrastructure.hashing.ContentHash` of everything the cached value
depends on: the
source closure of the module that computes it (`hashing.source_closure`: its file and every
maglevgen module it imports, followed through the package), the library versions and the
arguments. An edit to any of those files is therefore a miss, whatever module it is in.

Nothing executable is trusted from disk on its checksum alone (a checksum beside an entry
detects corruption, not tampering: whoever can write the entry can write the checksum). Every
entry the tool writes (a memo's pickle, a library, an object file, a derivation folder's list
of checksums) is signed with an HMAC-SHA256 under a key kept outside the cache (`key_file`:
the user's config folder, 0600, made on first use); an entry whose signature does not verify
reads as absent and is made again, so a planted pickle or library is never loaded. The cache
folder is created 0700 and refused (exit 2) when another user may write into it.
"""

from __future__ import annotations

import os
import stat
import tempfile
from collections.abc import Callable, Iterable
from functools import cache
from pathlib import Path
from typing import Any

from maglevgen.derive import memo
from maglevgen.errors import InputError
from maglevgen.infrastructure.hashing import (
    ContentHash,
    closure_hash,
    keyed_hex,
    package_root,
    same_digest,
)
from maglevgen.version import __version__

__all__ = ["DEFAULT_PARAMS_NAME", "STORE", "DiskStore", "cache_root", "default_cache_dir",
           "derivation_fingerprint", "install_store", "key_file", "params_digest", "sign",
           "sign_file", "signature_ok", "toolchain_fingerprint", "write_atomic"]

# What the cached C of the derivation depends on besides the generator's source closure.
# (every template render_runtime_sources renders or imports)
DERIVATION_TEMPLATES = ("maglev_simulate.*.j2", "maglev_tick_law.c.j2",
                        "maglev_plant_lag.c.j2", "maglev_checks.c.j2", "maglev_errors.h.j2",
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
    """The cache folder: ``cache_dir`` when given, else `default_cache_dir`; created 0700
    and refused (InputError) when another user owns it or may write into it."""
    root = Path(cache_dir) if cache_dir else default_cache_dir()
    _check_private(str(root))
    return root


@cache
def _check_private(root: str) -> None:
    path = Path(root)
    try:
        path.mkdir(mode=0o700, parents=True, exist_ok=True)
        st = path.stat()
    except OSError:
        return  # nothing cached can be written there: every entry is made afresh
    if st.st_uid != os.getuid():
        raise InputError(f"cache folder {root}: owned by another user (uid {st.st_uid}); set "
                         "MAGLEVGEN_CACHE to a folder of your own")
    if st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        raise InputError(f"cache folder {root}: writable by other users (mode "
                         f"{stat.S_IMODE(st.st_mode):o}); run chmod go-w {root} or set "
                         "MAGLEVGEN_CACHE to a private folder")


def key_file() -> Path:
    """Where the cache's signing key is kept: the user's config folder, not the cache."""
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "maglevgen" / "cache.key"


@cache
def _signing_key() -> bytes:
    """The HMAC key (32 random bytes, 0600, made on first use). A key file another user
    may read is refused; where none can be kept, a key for this process alone (nothing
    cached before is trusted, nothing cached now is trusted by a later run)."""
    path = key_file()
    for _ in range(2):
        try:
            fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW)
        except FileNotFoundError:
            try:
                path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
                fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
            except FileExistsError:
                continue  # made by a concurrent run meanwhile: read it
            except OSError:
                return os.urandom(32)
            with os.fdopen(fd, "wb") as f:
                key = os.urandom(32)
                f.write(key)
            return key
        except OSError:
            return os.urandom(32)
        with os.fdopen(fd, "rb") as f:
            st = os.fstat(f.fileno())
            if st.st_uid != os.getuid() or st.st_mode & 0o077:
                raise InputError(f"cache key {path}: readable or owned by another user (mode "
                                 f"{stat.S_IMODE(st.st_mode):o}); run chmod 600 {path}, or "
                                 "delete it (the cache is then made again)")
            key = f.read(64)
        if len(key) >= 32:
            return key
        return os.urandom(32)  # a truncated key file: trust nothing cached
    return os.urandom(32)


def sign(data: bytes) -> str:
    """The HMAC-SHA256 of ``data`` under the user's cache key, in hex (64 digits)."""
    return keyed_hex(_signing_key(), data)


def sign_file(path: Path) -> str:
    """`sign` of the file at ``path``."""
    return keyed_hex(_signing_key(), path=path)


def signature_ok(signature: str | bytes, expected: str) -> bool:
    """``signature`` (as read from disk) equals ``expected`` (`sign`'s), in constant time."""
    if isinstance(signature, bytes):
        signature = signature.decode("ascii", "replace")
    return same_digest(signature.strip(), expected)


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

    File layout: 64 hex digits of the payload's HMAC (`sign`: the user's key), then the
    payload; a signature that does not verify reads as a miss before anything is unpickled
    (a pickle runs code: only the user's own runs' entries are loaded).
    """

    def __init__(self, progress: Callable[[str], None] | None = None) -> None:
        self.progress = progress
        self.misses = 0  # entries derived afresh by this process (what the tests observe)

    def path(self, module: str, key: str) -> Path:
        digest = ContentHash(_module_key(module), key).hexdigest(32)
        return cache_root(None) / "memo-signed" / f"{digest}.pkl"

    def get(self, module: str, key: str) -> Any:
        try:
            blob = self.path(module, key).read_bytes()
            if signature_ok(blob[:64], sign(blob[64:])):
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
        write_atomic(self.path(module, key), sign(data).encode() + data)


STORE = DiskStore()


def install_store() -> DiskStore:
    """Share derive.memo's results across processes through `STORE` (derive/ does no I/O
    itself; the application installs the store when it builds a carriage)."""
    memo.set_store(STORE)
    return STORE
