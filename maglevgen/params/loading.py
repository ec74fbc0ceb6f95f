"""Loading a parameter file: the TOML, the `--set` overrides, the one-line errors."""

from __future__ import annotations

import difflib
import os
import re
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from maglevgen.errors import InputError
from maglevgen.infrastructure.cache import DEFAULT_PARAMS_NAME, params_digest
from maglevgen.infrastructure.text import check_text
from maglevgen.params.document import SCHEMA_DEPTH, Parameters
from maglevgen.params.fields import ModelError, short_repr
from maglevgen.params.reference import schema_rows

__all__ = ["LoadedParams", "default_params_path", "default_params_text", "load_params",
           "parse_override", "validate"]

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


def _too_deep(data: Any, limit: int) -> tuple[str, Any] | None:
    """The first (dotted key, value) nested deeper than ``limit`` levels, or None."""
    stack: list[tuple[Any, tuple[str, ...], int]] = [(data, (), 1)]
    while stack:
        node, path, depth = stack.pop()
        if not isinstance(node, (dict, list)):
            continue
        if depth > limit:
            return ".".join(path), node
        items = node.items() if isinstance(node, dict) else enumerate(node)
        stack.extend((v, (*path, str(k)), depth + 1) for k, v in reversed(list(items)))
    return None


def _deepest_line(text: str) -> str:
    """The line with the most brackets: where a nesting too deep for the parser sits."""
    lines = text.splitlines() or [""]
    i = max(range(len(lines)), key=lambda j: lines[j].count("[") + lines[j].count("{"))
    key = re.match(r"\s*([^=\s]+)\s*=", lines[i])
    return f"line {i + 1}" + (f" (key {short_repr(key.group(1), 40)})" if key else "")


def default_params_path() -> Path:
    return Path(str(resources.files("maglevgen") / DEFAULT_PARAMS_NAME))


def default_params_text() -> str:
    return (resources.files("maglevgen") / DEFAULT_PARAMS_NAME).read_text(encoding="utf-8")


@dataclass(frozen=True)
class LoadedParams:
    """Validated parameters with the text they came from (for hashing and provenance)."""

    params: Parameters
    source: str
    sha256: str
    overrides: tuple[str, ...]


#: one key of --set's NAME, as TOML writes a dotted key: a bare key or a "quoted" one (which
#: may hold dots: a toleranced entry's name, ``tolerances.parameters."vehicle.mass"``)
_KEY = r'[A-Za-z0-9_]+|"[^"\\\x00-\x1f\x7f]*"'
_BARE = re.compile(r"[A-Za-z0-9_]+")


def override_keys(name: str) -> tuple[str, ...] | None:
    """The keys of --set's NAME (TOML's dotted-key syntax, quotes removed), None when it is
    not one."""
    if not re.fullmatch(rf"(?:{_KEY})(?:\.(?:{_KEY}))*", name):
        return None
    return tuple(k[1:-1] if k.startswith('"') else k for k in re.findall(_KEY, name))


def _dotted(keys: Sequence[str]) -> str:
    return ".".join(k if _BARE.fullmatch(k) else f'"{k}"' for k in keys)


def _in_schema(keys: Sequence[str]) -> bool:
    """Whether the schema has the key (its ``<name>`` and ``<key>`` match any one key): one
    the file may omit."""
    for row in schema_rows():
        parts = row[0].split(".")
        if len(parts) == len(keys) and all(p == k or (p.startswith("<") and p.endswith(">"))
                                           for p, k in zip(parts, keys, strict=True)):
            return True
    return False


def _set_dotted(data: dict[str, Any], name: str, value: Any) -> None:
    keys = override_keys(name)
    assert keys is not None  # parse_override checked it
    node: Any = data
    for depth, key in enumerate(keys[:-1]):
        if isinstance(node, dict) and key not in node and _in_schema(keys[:depth + 1]):
            node[key] = {}  # a table the file omits, which the schema has
        if not isinstance(node, dict) or key not in node:
            bad = _dotted(keys[: depth + 1])
            raise InputError(f"--set {name}: unknown key {bad!r}{did_you_mean(bad)}")
        node = node[key]
    if not isinstance(node, dict) or (keys[-1] not in node and not _in_schema(keys)):
        raise InputError(f"--set {name}: unknown key {name!r}{did_you_mean(name)}")
    node[keys[-1]] = value


#: the longest --set value (a vector or a small table; a parameter file holds more)
MAX_SET = 4000


def did_you_mean(key: str) -> str:
    """`` (did you mean 'vehicle.mass'?)`` for a misspelt key: the closest of the schema's keys
    and tables (difflib, an array's name read as ``<name>``), or "" when none is close."""
    known: set[str] = set()
    for row in schema_rows():
        parts = row[0].split(".")
        known.update(".".join(parts[:i]) for i in range(1, len(parts) + 1))
    parts = key.split(".")
    generic = ".".join(["arrays", "<name>", *parts[2:]]) if parts[0] == "arrays" and len(
        parts) > 1 else key
    parent, _, last = generic.rpartition(".")
    siblings = sorted(k.rpartition(".")[2] for k in known if k.rpartition(".")[0] == parent)
    close = [f"{parent}.{c}" if parent else c
             for c in difflib.get_close_matches(last, siblings, n=1, cutoff=0.6)]
    # a misspelt table further up: the closest whole key
    depth = generic.count(".")
    close = close or difflib.get_close_matches(
        generic, sorted(k for k in known if k.count(".") == depth), n=1, cutoff=0.8)
    if not close or close[0] == generic:
        return ""
    suggestion = close[0]
    if generic != key and suggestion.startswith("arrays.<name>"):
        suggestion = suggestion.replace("<name>", parts[1], 1)
    return f" (did you mean {suggestion!r}?)"


def parse_override(item: str) -> tuple[str, Any]:
    """Parse ``NAME=VALUE`` where VALUE is a TOML value (``9.3``, ``[0, 0, 0.01]``, ``"x"``)."""
    if "=" not in item:
        raise InputError(f"--set {item!r}: expected NAME=VALUE")
    name, raw = (s.strip() for s in item.split("=", 1))
    if override_keys(name) is None:
        raise InputError(f"--set {short_repr(item)}: {short_repr(name)} is not a dotted "
                         'parameter name (keys with dots in them quoted: a."b.c")')
    bad = check_text(item.split("=", 1)[1], MAX_SET)  # before strip(): a trailing newline too
    if bad is not None:  # a newline would let the value add keys of its own to the TOML
        one_line = " (one TOML value on one line)" if "control" in bad else ""
        raise InputError(f"--set {name}: the value {bad}{one_line}")
    try:
        doc = tomllib.loads(f"v = {raw}")
        if list(doc) != ["v"]:
            raise InputError(f"--set {name}: the value {short_repr(raw)} is more than one TOML "
                             "value")
        value = doc["v"]
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"--set {short_repr(item)}: not a TOML value ({exc})") from None
    except RecursionError:
        raise InputError(f"--set {name}: arrays or inline tables nested deeper than the "
                         f"schema's {SCHEMA_DEPTH} levels") from None
    return name, value


def _format_loc(loc: Sequence[int | str]) -> str:
    return ".".join(str(p) for p in loc)


def _lookup(data: Any, loc: Sequence[int | str]) -> Any:
    for p in loc:
        try:
            data = data[p]
        except (KeyError, IndexError, TypeError):
            return None
    return data


def validate(data: dict[str, Any], origin: str) -> Parameters:
    """Validate raw TOML data; raise a one-line InputError naming the key and the value."""
    deep = _too_deep(data, SCHEMA_DEPTH)
    if deep is not None:
        raise InputError(f"{origin}: {deep[0]} = {short_repr(deep[1])}: nested deeper than the "
                         f"schema's {SCHEMA_DEPTH} levels of tables and arrays")
    try:
        return Parameters.model_validate(data)
    except ValidationError as exc:
        err = exc.errors(include_url=False)[0]
        ctx_err = (err.get("ctx") or {}).get("error")
        if isinstance(ctx_err, ModelError):
            key = _format_loc([p for p in [*err["loc"], ctx_err.key] if p != "Inertia"])
            raise InputError(f"{origin}: {key} = {ctx_err.value}: {ctx_err.reason}") from None
        loc = [p for p in err["loc"] if not (isinstance(p, str) and p.startswith("function-"))]
        if loc[:2] == ["vehicle", "inertia_cg"] and loc[2:3] in (["Inertia"], ["str"]):
            del loc[2]  # the member of ``Inertia | str`` pydantic names
        key = _format_loc(loc) or "(top level)"
        msg = err["msg"]
        if err["type"] == "missing":
            raise InputError(f"{origin}: missing key {key}") from None
        if err["type"] == "extra_forbidden":
            raise InputError(f"{origin}: unknown key {key}{did_you_mean(key)}") from None
        value = _lookup(data, loc)
        msg = msg.removeprefix("Value error, ")
        raise InputError(f"{origin}: {key} = {short_repr(value)}: {msg}") from None


def load_params(path: str | Path | None = None, overrides: Sequence[str] = ()) -> LoadedParams:
    """Load a parameter file (the default carriage when ``path`` is None) and apply overrides."""
    if isinstance(overrides, str):  # one "NAME=VALUE" would iterate by character
        overrides = (overrides,)
    if not isinstance(overrides, Sequence) or not all(isinstance(o, str) for o in overrides):
        raise InputError(f"--set {short_repr(overrides)}: expected NAME=VALUE strings (a list "
                         "of them)")
    if path is None:
        text, origin = default_params_text(), DEFAULT_PARAMS_NAME
    else:
        if not isinstance(path, (str, os.PathLike)) or isinstance(os.fspath(path), bytes) \
                or not os.fspath(path):
            raise InputError(f"--params {short_repr(path)}: expected a parameter file's path (a "
                             "non-empty str or pathlib.Path)")
        bad = check_text(os.fspath(path), 4096)
        if bad is not None:
            raise InputError(f"--params {short_repr(path)}: the path {bad}")
        p = Path(path)
        origin = str(p)
        try:
            text = p.read_text(encoding="utf-8")
        except OSError as exc:
            raise InputError(f"{origin}: cannot read parameter file ({exc.strerror})") from None
        except UnicodeDecodeError as exc:
            raise InputError(f"{origin}: cannot read parameter file (not UTF-8: byte "
                             f"{exc.object[exc.start]:#04x} at offset {exc.start})") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{origin}: malformed TOML: {exc}") from None
    except RecursionError:  # the parser recurses once per level of nesting
        raise InputError(f"{origin}: {_deepest_line(text)}: arrays or inline tables nested "
                         f"deeper than the schema's {SCHEMA_DEPTH} levels") from None
    for item in overrides:
        name, value = parse_override(item)
        _set_dotted(data, name, value)
    params = validate(data, origin)
    return LoadedParams(params, origin, params_digest(text, overrides), tuple(overrides))
