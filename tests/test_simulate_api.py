"""The ctypes signatures of the simulation library against the C that declares them.

The reference is the C text itself: maglev_simulate.h as generated (the run-time-parameter
header beside the compiled library, and the committed baked one) and templates/maglev_batch.c,
parsed here by a strict regular expression of this file's own, with its own map from C types
to ctypes; nothing of maglevgen.codegen.simulate_api (from which the library's signatures, the
header's prototypes and the manifest's ``simulate_functions`` are all made) is used to read
them.
"""

from __future__ import annotations

import ctypes
import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# a declaration or definition: return type, name, the arguments up to ")" then ";" or "{"
_PROTOTYPE = re.compile(r"^(long long|int) (maglev_\w+)\(([^;{}()]*)\)\s*([;{])", re.M)
# one argument as the API writes it: [const ]TYPE[*] NAME
_ARGUMENT = re.compile(r"^(const )?(maglev_real|long long|int|maglev_control_loop|"
                       r"maglev_spline_schedule|maglev_simulate_fn)(\*)? ([A-Za-z_]\w*)$")
# typedef struct { ... } NAME; with one "TYPE NAME[, NAME];" member per line
_STRUCT = re.compile(r"typedef struct \{\n(.*?)\n\} (maglev_\w+);", re.S)
_MEMBER = re.compile(r"^\s*(const )?(maglev_real|long long|int|void|maglev_sensing|"
                     r"maglev_sense_init_fn|maglev_sense_tick_fn|maglev_sense_lanes)(\*)? "
                     r"([\w, ]+);")

WANTED = {"maglev_simulate", "maglev_launch", "maglev_lyapunov_batch"}


def _arguments(text: str) -> list[tuple[str, bool, str]]:
    """(base type, pointer, name) of each argument of a parameter list."""
    out = []
    for item in " ".join(text.split()).split(","):
        m = _ARGUMENT.match(item.strip())
        assert m, f"argument {item.strip()!r} is not of the API's form"
        out.append((m.group(2), m.group(3) == "*", m.group(4)))
    return out


def _prototypes(text: str) -> dict[str, tuple[str, list[tuple[str, bool, str]]]]:
    return {m.group(2): (m.group(1), _arguments(m.group(3))) for m in _PROTOTYPE.finditer(text)}


def _structs(text: str) -> dict[str, list[tuple[str, str, bool]]]:
    """name -> (member, base type, pointer) of each typedef struct of ``text``."""
    out = {}
    for body, name in _STRUCT.findall(text):
        members = []
        for line in body.splitlines():
            m = _MEMBER.match(line.split("/*")[0])
            if m:
                members += [(n.strip(), m.group(2), m.group(3) == "*")
                            for n in m.group(4).split(",")]
        out[name] = members
    return out


def _scalar(c_type: str):
    return {"maglev_real": ctypes.c_double, "long long": ctypes.c_longlong,
            "int": ctypes.c_int}[c_type]


# a member's ctypes description from the C alone: the sense functions' pointer types by
# their arguments (maglev_simulate.h's typedefs), a nested struct by its members
_SENSE_FUNCTIONS = {
    "maglev_sense_init_fn": (ctypes.c_int, ctypes.c_void_p, ctypes.POINTER(ctypes.c_double),
                             ctypes.c_ulong, ctypes.c_double),
    "maglev_sense_tick_fn": (ctypes.c_int, ctypes.c_void_p, ctypes.POINTER(ctypes.c_double),
                             ctypes.c_ulong, ctypes.c_double, ctypes.POINTER(ctypes.c_double))}


def _member(t: str, p: bool, structs: dict):
    if t in _SENSE_FUNCTIONS:
        return ("function", _SENSE_FUNCTIONS[t])
    if t == "maglev_sense_lanes":
        # filled by the firmware's host library (its maglev_host_sense_lanes), passed through
        # as that object's address
        assert p, f"{t} held by value"
        return ("address",)
    if t == "void":
        assert p, "a void member"
        return ("address",)
    if t in structs:
        assert p, f"{t} held by value"
        return ("pointer to", tuple((n, _member(mt, mp, structs)) for n, mt, mp in structs[t]))
    return ctypes.POINTER(_scalar(t)) if p else _scalar(t)


def _ctypes_member(t):
    """The same description of a ctypes member type."""
    if t is ctypes.c_void_p:
        return ("address",)
    if hasattr(t, "_restype_"):
        return ("function", (t._restype_, *t._argtypes_))
    if hasattr(t, "_type_") and isinstance(t._type_, type) and issubclass(t._type_,
                                                                         ctypes.Structure):
        return ("pointer to", tuple((n, _ctypes_member(mt)) for n, mt in t._type_._fields_))
    return t


def _expected(base: str, pointer: bool, structs: dict):
    """The ctypes type of an argument, from the C alone (the double library)."""
    if base == "maglev_simulate_fn":  # a function pointer, passed as an address
        return ("function pointer",)
    if base in structs:
        assert pointer, f"{base} passed by value"
        return ("struct", tuple((n, _member(t, p, structs)) for n, t, p in structs[base]))
    return ("pointer", _scalar(base)) if pointer else ("scalar", _scalar(base))


def _actual(t):
    """The same description of a ctypes argtype."""
    if t is ctypes.c_void_p:
        return ("function pointer",)
    if hasattr(t, "_type_") and isinstance(t._type_, type) and issubclass(t._type_,
                                                                         ctypes.Structure):
        return ("struct", tuple((n, _ctypes_member(mt)) for n, mt in t._type_._fields_))
    if hasattr(t, "contents"):
        return ("pointer", t._type_)
    return ("scalar", t)


@pytest.fixture(scope="module")
def runtime_header(sim_lib) -> str:
    return (Path(sim_lib.sources) / "maglev_simulate.h").read_text()


def test_the_parse_finds_the_api(runtime_header: str) -> None:
    """The regular expressions see every function and struct (a parse that finds nothing
    would pass the comparisons below vacuously)."""
    assert set(_prototypes(runtime_header)) >= WANTED
    assert set(_structs(runtime_header)) >= {"maglev_control_loop", "maglev_spline_schedule"}
    assert "maglev_batch_simulate" in _prototypes((ROOT / "templates" / "maglev_batch.c")
                                                  .read_text())


def test_ctypes_signatures_match_the_header_and_the_batch_driver(sim_lib,
                                                                 runtime_header: str) -> None:
    """Every argument of maglev_simulate, maglev_launch, maglev_lyapunov_batch (the header
    the library was compiled from) and maglev_batch_simulate (maglev_batch.c): the ctypes
    argtype is the C type's, in the same place (and maglev_lanes_simulate, maglev_lanes_width:
    maglev_lanes.c's); the return types too; the structs passed by
    pointer have the header's members, in order, with their types."""
    structs = _structs(runtime_header)
    protos = _prototypes(runtime_header)
    protos.update(_prototypes((ROOT / "templates" / "maglev_batch.c").read_text()))
    protos.update(_prototypes((ROOT / "templates" / "maglev_lanes.c").read_text()))
    lanes_simulate, lanes_width, _ = sim_lib._lanes_functions()
    loaded = {"maglev_simulate": sim_lib._simulate, "maglev_launch": sim_lib._launch,
              "maglev_lyapunov_batch": sim_lib._lyapunov,
              "maglev_batch_simulate": sim_lib._batch_function(),
              "maglev_lanes_simulate": lanes_simulate, "maglev_lanes_width": lanes_width}
    for name, fn in loaded.items():
        ret, args = protos[name]
        assert fn.restype is _scalar(ret), name
        assert len(fn.argtypes) == len(args), (name, [a[2] for a in args])
        for (base, pointer, arg), t in zip(args, fn.argtypes, strict=True):
            assert _actual(t) == _expected(base, pointer, structs), f"{name}({arg})"


def test_manifest_lists_the_baked_header_api() -> None:
    """The committed baked folder: the manifest's simulate_functions are maglev_simulate.h's
    prototypes (no p: the parameters are baked), name by name and type by type."""
    folder = ROOT / "generated"
    protos = _prototypes((folder / "maglev_simulate.h").read_text())
    listed = json.loads((folder / "manifest.json").read_text())["simulate_functions"]
    assert {f["name"] for f in listed} == WANTED
    for f in listed:
        ret, args = protos[f["name"]]
        assert f["returns"] == ret
        assert [a["name"] for a in f["arguments"]] == [a[2] for a in args]
        assert [a["type"].removeprefix("const ") for a in f["arguments"]] == \
            [base + ("*" if ptr else "") for base, ptr, _ in args]
        assert "p" not in [a[2] for a in args]
