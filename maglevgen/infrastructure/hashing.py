"""The one content-hash helper: every cache key and checksum in maglevgen is a sha256 built here.

- `ContentHash`: a key over labelled parts (text, bytes, files, library versions), each part
  framed by its label and length so that no two different inputs hash the same;
- `sha256_hex`: the checksum of a blob (BUILD.json, the cached C's list; the cache's entries
  are also signed, `maglevgen.infrastructure.cache.sign`);
- `source_closure`: the maglevgen source files a module depends on (its imports, followed
  through the package, function-local ones included), so that a cached result is keyed by
  every file that could change it (an edit to any of them is a cache miss).

Imports only the standard library: `maglevgen build` computes its key before anything heavy.
"""

from __future__ import annotations

import hashlib
import hmac
import re
import sys
from collections.abc import Iterable
from functools import cache
from importlib import metadata, util
from pathlib import Path

__all__ = ["ContentHash", "closure_hash", "file_sha256", "keyed_hex", "package_root",
           "same_digest", "sha256_hex", "source_closure"]

# The installed packages (pyproject's package-dir maps derive/, runtime/ under maglevgen.)
PACKAGES = ("maglevgen", "maglevgen.api", "maglevgen.params", "maglevgen.infrastructure",
            "maglevgen.derive", "maglevgen.codegen", "maglevgen.runtime", "maglevgen.control",
            "maglevgen.analyses", "maglevgen.exports", "maglevgen.report",
            "maglevgen.report.sections", "maglevgen.templates")


def sha256_hex(data: bytes | str) -> str:
    """The sha256 of a blob (text as UTF-8), in hex."""
    return hashlib.sha256(data.encode("utf-8") if isinstance(data, str) else data).hexdigest()


def file_sha256(path: Path) -> str:
    return sha256_hex(Path(path).read_bytes())


def keyed_hex(key: bytes, data: bytes | None = None, path: Path | None = None) -> str:
    """The HMAC-SHA256 under ``key`` of ``data``, or of the file at ``path``, in hex (the
    cache's signatures: maglevgen.infrastructure.cache.sign)."""
    h = hmac.new(key, digestmod=hashlib.sha256)
    if data is not None:
        h.update(data)
    if path is not None:
        with open(path, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                h.update(chunk)
    return h.hexdigest()


def same_digest(a: str, b: str) -> bool:
    """Two hex digests equal, compared in constant time."""
    return hmac.compare_digest(a.encode("ascii", "replace"), b.encode("ascii", "replace"))


class ContentHash:
    """A sha256 over labelled parts; ``hexdigest(n)`` the key (its first n hex digits)."""

    def __init__(self, *texts: str) -> None:
        self._h = hashlib.sha256()
        for text in texts:
            self.text("", text)

    def raw(self, data: bytes) -> ContentHash:
        """Unframed bytes: for a digest that must equal a plain sha256 (`sha256sum` of a
        parameter file)."""
        self._h.update(data)
        return self

    def bytes(self, label: str, data: bytes) -> ContentHash:
        self._h.update(f"{label}\0{len(data)}\0".encode() + data)
        return self

    def text(self, label: str, text: str) -> ContentHash:
        return self.bytes(label, text.encode("utf-8"))

    def file(self, label: str, path: Path) -> ContentHash:
        return self.bytes(label, Path(path).read_bytes())

    def files(self, files: Iterable[tuple[str, Path]]) -> ContentHash:
        for label, path in files:
            self.file(label, path)
        return self

    def versions(self, libs: Iterable[str]) -> ContentHash:
        """Python's and each library's version (from package metadata: nothing imported)."""
        self.text("python", repr(sys.version_info[:2]))
        for lib in libs:
            try:
                self.text(lib, metadata.version(lib))
            except metadata.PackageNotFoundError:
                self.text(lib, "-")
        return self

    def hexdigest(self, n: int = 64) -> str:
        return self._h.hexdigest()[:n]


@cache
def package_root(pkg: str) -> Path:
    parent, _, leaf = pkg.rpartition(".")
    if "." in parent:  # find_spec would import the parent package (report/ imports SymPy)
        return package_root(parent) / leaf
    spec = util.find_spec(pkg)
    if spec is None or not spec.submodule_search_locations:
        raise RuntimeError(f"package {pkg} not found")
    return Path(next(iter(spec.submodule_search_locations)))


@cache
def module_files() -> dict[str, Path]:
    """Every maglevgen module's name -> its source file."""
    out: dict[str, Path] = {}
    for pkg in PACKAGES[:-1]:
        for f in package_root(pkg).glob("*.py"):
            out[pkg if f.stem == "__init__" else f"{pkg}.{f.stem}"] = f
    return out


_IMPORT = re.compile(r"^[ \t]*import[ \t]+([\w. \t,]+)", re.MULTILINE)
_FROM = re.compile(r"^[ \t]*from[ \t]+(\.*)([\w.]*)[ \t]+import[ \t]+(\([^)]*\)|[^\n#]*)",
                   re.MULTILINE)


@cache
def imported_modules(module: str) -> frozenset[str]:
    """The maglevgen modules ``module`` imports (anywhere in it, functions included).

    A scan of the import statements' text (ast would cost ten times more, on every process
    that reads the memo store); an import-like line in a docstring only adds a dependency,
    which errs on the safe side."""
    mods = module_files()
    path = mods[module]
    text = path.read_text(encoding="utf-8")
    found: set[str] = set()
    for m in _IMPORT.finditer(text):
        found.update(n.split()[0] for n in m.group(1).split(",") if n.strip())
    for m in _FROM.finditer(text):
        dots, name, names = m.groups()
        base = name
        if dots:
            parts = module.split(".") if path.stem == "__init__" else module.split(".")[:-1]
            parts = parts[:len(parts) - len(dots) + 1]
            base = ".".join([*parts, *([name] if name else [])])
        for item in names.strip("()").replace("\\", " ").split(","):
            item = item.split("#")[0].split()
            if item:
                full = f"{base}.{item[0]}"
                found.add(full if full in mods else base)
    return frozenset(m for m in found if m in mods and m != module)


@cache
def source_closure(module: str) -> tuple[Path, ...]:
    """The source files of ``module`` and of every maglevgen module it reaches by imports."""
    seen, todo = {module}, [module]
    while todo:
        for m in imported_modules(todo.pop()) - seen:
            seen.add(m)
            todo.append(m)
    files = module_files()
    return tuple(files[m] for m in sorted(seen))


@cache
def _source_digest(path: Path) -> str:
    return file_sha256(path)


def closure_hash(module: str) -> ContentHash:
    """A ContentHash over ``module``'s source closure (each file's sha256, labelled by its
    folder and name)."""
    h = ContentHash()
    for p in source_closure(module):
        h.text(f"{p.parent.name}/{p.name}", _source_digest(p))
    return h
