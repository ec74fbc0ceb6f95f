"""Input boundaries through the `maglevgen` command: names that would reach C or LaTeX,
extreme and absurd numbers, nesting deeper than the schema, what a library's message or
warning would add, the folders a killed build leaves, and what `make run` sets up.

Every bad input must give exit 2 and one stderr line naming the key and the value, leave a
good build folder byte for byte as it was, with nothing beside it. The expected ranges are
written here (the specification), not read from the schema.
"""

from __future__ import annotations

import copy
import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import types
import warnings
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_build import FAST, assert_one_line_error, siblings, tree
from test_params_cli import DEFAULT_DATA, DEFAULT_TEXT, edited, replaced

import maglevgen.carriage
from maglevgen.cli import main
from maglevgen.errors import InputError
from maglevgen.infrastructure import output, texsetup

# ------------------------------------------------------------------------------ the cases

INJECTED_NAMES = [
    "6\\input{/etc/passwd}",  # LaTeX
    "3*/INJECTED_C/*",  # a C comment closed early
    "a b",  # CasADi and sympy.symbols split it
    "",
    "x" * 17,
    "\u00e43",  # non-ASCII
    "a\nb",  # a newline in the one error line
    "1.2",
]


def renamed(old: str, new: str) -> str:
    """The default file with array ``old``'s table named ``new`` (a TOML quoted key), and its
    [provenance] entries and gap sensors following it (a provenance key that names nothing, a
    sensor on no array, is refused)."""
    text = replaced(f"[arrays.{old}]", f"[arrays.{json.dumps(new)}]")
    text = text.replace(f'array = "{old}"', f"array = {json.dumps(new)}")
    return text.replace(f'"arrays.{old}.', json.dumps(f"arrays.{new}.")[:-1])


def nested(depth: int, open_: str = "[", close: str = "]") -> str:
    return open_ * depth + "1.0" + close * depth


# (id, file text, substrings the one error line must contain)
CASES: list[tuple[str, str, list[str]]] = [
    *[(f"name-{i}", renamed("3", name),
       ["arrays.<name> = ", repr(name)[:20], "letters, digits or underscores"])
      for i, name in enumerate(INJECTED_NAMES)],
    ("name-same-upper-case", renamed("6", "A").replace("[arrays.3]", "[arrays.a]"),
     ["arrays.<name> = 'A'", "same as array 'a'"]),
    # extreme finite numbers (the issue's: each gave exit 1 or several lines)
    *[(f"{key}={value!r}", edited(key, value), [f"{key} = {value!r}:", f"outside the range {rng}"])
      for key, rng in [("vehicle.mass", "[0.001, 1e+06] kg"),
                       ("halbach.wavelength", "[0.001, 10] m"),
                       ("circuit.resistance", "[1e-09, 1000] ohm"),
                       ("operation.speed", "[0.001, 1000] m/s"),
                       ("arrays.3.circuits", "[0.1, 100000]"),
                       ("vehicle.gravity", "[0.1, 100] m/s^2")]
      for value in (1e308, -1e308, 1e-308)],
    # absurd values the schema used to accept
    ("nominal-gap-1.2e19", edited("arrays.3.nominal_gap", 1.2e19),
     ["arrays.3.nominal_gap = 1.2e+19:", "outside the range [1e-05, 1] m"]),
    ("length-3.9e8", edited("vehicle.length", 3.9e8),
     ["vehicle.length = 390000000.0:", "outside the range [0.001, 1000] m"]),
    ("gravity-1.9e-7", edited("vehicle.gravity", 1.9e-7),
     ["vehicle.gravity = 1.9e-07:", "outside the range [0.1, 100] m/s^2"]),
    ("position-component", edited("arrays.3.position", [0.0, 0.0, 1e308]),
     ["arrays.3.position = [0.0, 0.0, 1e+308]:", "component 2", "[-1000, 1000] m"]),
    ("magnets-huge-int", edited("halbach.magnets_per_wavelength", 2**62),
     [f"halbach.magnets_per_wavelength = {2**62}:", "[2, 256]"]),
    # a choice outside its list, and a number where a choice goes
    *[(f"array-force-{i}", edited("model.array_force", value),
       ["model.array_force = ", repr(value)[:12], "one of distributed, point"])
      for i, value in enumerate(["Point", "distributed ", "", "sinhc"])],
    ("array-force-number", edited("model.array_force", 1.0),
     ["model.array_force = 1.0", "string"]),
    *[(f"circuit-dynamics-{i}", edited("model.circuit_dynamics", value),
       ["model.circuit_dynamics = ", repr(value)[:12], "one of first-order, quasi-static"])
      for i, value in enumerate(["first order", "Quasi-static", "", "lagged"])],
    ("circuit-dynamics-number", edited("model.circuit_dynamics", 1.0),
     ["model.circuit_dynamics = 1.0", "string"]),
    ("circuit-pitch-0", edited("circuit.pitch", 0.0),
     ["circuit.pitch = 0.0:", "outside the range [0.0001, 1] m"]),
    # nesting deeper than the schema (4 levels: document, arrays, an array, its position)
    ("nested-array-10", replaced("position = [0.26, 0.0, -0.03]", "position = " + nested(10)),
     ["arrays.3.position.0 = ", "nested deeper than the schema's 4 levels"]),
    ("nested-array-5000", replaced("mass = 9.3\n", "mass = " + nested(5000) + "\n"),
     ["line 8 (key 'mass')", "nested deeper than the schema's 4 levels"]),
    ("nested-inline-table-5000", DEFAULT_TEXT.replace("[track]\n", "[track]\nx = "
                                                      + nested(5000, "{a = ", "}") + "\n"),
     ["(key 'x')", "nested deeper"]),
    ("nested-inline-table-6", DEFAULT_TEXT.replace("[track]\n", "[track]\nx = "
                                                   + nested(6, "{a = ", "}") + "\n"),
     ["track.x.a.a = ", "nested deeper than the schema's 4 levels"]),
]


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "params.toml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.fixture
def no_model_build(monkeypatch: pytest.MonkeyPatch) -> None:
    """Building a DerivedCarriage fails the test: a bad input must be refused before any work."""

    def boom(*_a: object, **_k: object) -> None:
        raise AssertionError("model built before the input was refused")

    monkeypatch.setattr(maglevgen.carriage, "DerivedCarriage", boom)


@pytest.mark.usefixtures("no_model_build")
@pytest.mark.parametrize(("text", "expected"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_input_through_trim(tmp_path: Path, capsys, text: str, expected: list[str]) -> None:
    rc = main(["trim", "--json", "--params", str(_write(tmp_path, text))])
    out, err = capsys.readouterr()
    assert_one_line_error(rc, out, err, expected)
    assert err.count("\n") == 1


@pytest.fixture(scope="module")
def good(tmp_path_factory, default_build, sim_lib) -> Path:
    return Path(shutil.copytree(default_build, tmp_path_factory.mktemp("boundaries") / "out"))


@pytest.mark.parametrize(("text", "expected"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
@pytest.mark.parametrize("command", ["build", "generate"])
def test_bad_input_leaves_the_good_build(good: Path, tmp_path: Path, capsys, command: str,
                                         text: str, expected: list[str]) -> None:
    before, names = tree(good), siblings(good)
    argv = [command, "--out", str(good), "--params", str(_write(tmp_path, text))]
    rc = main(argv + (FAST if command == "build" else []))
    out, err = capsys.readouterr()
    assert_one_line_error(rc, out, err, expected)
    assert tree(good) == before and siblings(good) == names


@pytest.mark.usefixtures("no_model_build")
@pytest.mark.parametrize(("argv", "expected"), [
    (["trim", "--speed", "1e308"], ["--speed 1e+308", "[0.001, 1000] m/s"]),
    (["gains", "--speed", "1e-9"], ["--speed 1e-09", "[0.001, 1000] m/s"]),
    (["trim", "--set", "arrays.3.position=" + nested(4)], ["arrays.3.position.0 = ", "nested"]),
    # (refused by its length before TOML parses it: the --set values are bounded)
    (["trim", "--set", "vehicle.mass=" + nested(5000)], ["--set vehicle.mass",
                                                        "characters long (at most 4000)"]),
    (["simulate", "--t-end", "1e308"], ["--t-end 1e+308", "[0.001, 10000] s"]),
    (["simulate", "--dt", "1e-308"], ["--dt 1e-308", "[1e-07, 1] s"]),
    (["simulate", "--dt", "1e-6", "--t-end", "100"], ["1e+08 steps", "more than 1e7"]),
    (["build", "--dt", "1e-6", "--t-end", "100", "--no-pdf"], ["1e+08 steps"]),
], ids=["trim-speed", "gains-speed", "set-nested", "set-nested-5000", "t-end", "dt", "steps",
        "build-steps"])
def test_bad_options(tmp_path: Path, monkeypatch, capsys, argv: list[str],
                     expected: list[str]) -> None:
    monkeypatch.chdir(tmp_path)
    rc = main(argv)
    out, err = capsys.readouterr()
    assert_one_line_error(rc, out, err, expected)
    assert list(tmp_path.iterdir()) == []


def test_schema_documents_every_range_with_its_reason(capsys) -> None:
    assert main(["params", "schema"]) == 0
    lines = capsys.readouterr().out.splitlines()
    for line in lines:
        key = line.split()[0]
        if key == "arrays.<name>":
            assert "1 to 16 ASCII letters, digits or underscores" in line
            continue
        if key == "tolerances.parameters.<key>":  # a name: an entry of the parameter vector
            assert "an entry of the parameter vector" in line
            continue
        if key == "envelope.embedded_controller":  # a name, not a number: its choices
            assert line.endswith("one of damping, lqr, coupled, spec"), line
            continue
        if key == "control.actuators":
            assert line.endswith("one of paper, normal"), line
            continue
        if key == "vehicle.inertia_cg":  # a table (its entries' ranges below) or "box"
            assert line.endswith('a table, or "box"'), line
            continue
        if key == "model.array_force":  # a name, not a number: its choices
            assert line.endswith("one of distributed, point"), line
            continue
        if key == "model.circuit_dynamics":
            assert line.endswith("one of first-order, quasi-static"), line
            continue
        if key == "sensors.gap_sensors.<name>":  # a name: any TOML key
            assert line.endswith("any TOML key"), line
            continue
        if key == "sensors.gap_sensors.<name>.array":  # a name: one of the arrays'
            assert line.endswith("a key of [arrays]"), line
            continue
        if key == "provenance.<key>":  # text about a value, not a number
            assert "paper or assumed" in line, line
            continue
        m = re.search(r"in \[(\S+), (\S+)\][^:]*: (.+)$", line)
        assert m, line
        lo, hi, why = float(m.group(1)), float(m.group(2)), m.group(3)
        assert lo < hi and len(why) > 10, line
    # the default carriage's values lie inside the ranges it lists
    ranges = {line.split()[0]: tuple(map(float, re.search(r"in \[(\S+), (\S+)\]", line).groups()))
              for line in lines
              if line.split()[0] not in ("arrays.<name>", "envelope.embedded_controller",
                                         "provenance.<key>", "control.actuators",
                                         "vehicle.inertia_cg", "model.array_force",
                                         "model.circuit_dynamics",
                                         "tolerances.parameters.<key>",
                                         "sensors.gap_sensors.<name>",
                                         "sensors.gap_sensors.<name>.array")}

    def leaves(data: Any, prefix: str = "") -> Any:
        for k, v in data.items():
            key = re.sub(r"^(arrays|sensors\.gap_sensors)\.[^.]+\.", r"\1.<name>.",
                         f"{prefix}{k}")
            if key.startswith("sensors.gap_sensors.<name>.array"):
                continue  # a name: one of the arrays
            if prefix.startswith("tolerances.parameters."):
                key = f"tolerances.parameters.<key>.{k}"
            if prefix == "tolerances.disturbance.":
                key = "tolerances.disturbance"
            if isinstance(v, dict):
                yield from leaves(v, f"{prefix}{k}.")
            else:
                yield key, v if isinstance(v, list) else [v]

    for key, values in leaves(DEFAULT_DATA):
        if key in ("envelope.embedded_controller", "control.actuators",
                   "model.array_force", "model.circuit_dynamics") or key.startswith(
                       "provenance."):
            continue
        lo, hi = ranges[key]
        assert all(lo <= c <= hi for c in values), key


# ------------------------------------------------------------------------------ one line

def test_a_libraries_multi_line_message_stays_one_line(monkeypatch, capsys) -> None:
    """SciPy's root() message (several lines in some versions) inside the no-trim error of
    the lambdified trim (the report's), raised where `maglevgen trim` meets a no-trim error
    (its own trim is the C's, which has no such message)."""
    from maglevgen.analyses import queries
    from maglevgen.carriage import DerivedCarriage
    from maglevgen.derive import trim as trim_mod
    from maglevgen.errors import NoTrimError
    from maglevgen.params import load_params

    def failing_root(fun, x0, **_k):
        return types.SimpleNamespace(x=x0 + 0.01, success=False,
                                     message="The iteration is not making good progress,\n"
                                             "  as measured by the\n improvement")

    monkeypatch.setattr(trim_mod, "root", failing_root)
    with pytest.raises(NoTrimError) as raised:
        DerivedCarriage(load_params(overrides=["vehicle.mass=9.31"])).trim()

    def no_trim(*_a):
        raise raised.value

    monkeypatch.setattr(queries, "trim_point", no_trim)
    rc = main(["trim", "--set", "vehicle.mass=9.31"])
    out, err = capsys.readouterr()
    assert_one_line_error(rc, out, err, ["did not converge", "not making good progress, as "
                                         "measured by the improvement"])


def test_floating_point_warnings_never_reach_the_terminal(monkeypatch, capsys) -> None:
    """A command whose arithmetic overflows: no warning is shown or recorded, the output is
    the command's own."""
    import numpy as np

    from maglevgen.analyses import queries

    real = queries.trim_report

    def overflowing(carriage, speed, **options):
        np.exp(np.array([1e3]))  # RuntimeWarning: overflow
        warnings.warn("a library's own warning", UserWarning, stacklevel=1)
        return real(carriage, speed, **options)

    monkeypatch.setattr(queries, "trim_report", overflowing)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        rc = main(["trim", "--json"])
    out, err = capsys.readouterr()
    assert rc == 0 and err == "" and seen == []
    assert json.loads(out)["speed"] == 20.0


# ------------------------------------------------------------------------------ fuzzing

_EXTREMES = [1e308, -1e308, 1e-308, 5e-324, -0.0, 0.0, 1e19, -1e19, 3.9e8, 2**63 - 1,
             -(2**63), 1, -1, 1e-7]
_VALUES = st.one_of(
    st.sampled_from(_EXTREMES),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(2**63), max_value=2**63 - 1),
    st.booleans(),
    st.text(max_size=6),
    st.lists(st.sampled_from([*_EXTREMES, 0.5, 0.01]), max_size=4),
    st.just({}),
)


def _paths(data: dict, prefix: tuple[str, ...] = ()) -> list[tuple[str, ...]]:
    out = []
    for k, v in data.items():
        out.append((*prefix, k))
        if isinstance(v, dict):
            out += _paths(v, (*prefix, k))
    return out


_PATHS = _paths(DEFAULT_DATA)


def _toml_key(k: str) -> str:
    return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else json.dumps(k)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v) if math.isfinite(v) else ("nan" if v != v else
                                                 ("inf" if v > 0 else "-inf"))
    if isinstance(v, int):
        return str(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(c) for c in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_toml_key(k)} = {_toml_value(c)}" for k, c in v.items()) + "}"
    raise TypeError(type(v))


def _dump(data: dict, prefix: str = "") -> str:
    out = "".join(f"{_toml_key(k)} = {_toml_value(v)}\n" for k, v in data.items()
                  if not isinstance(v, dict))
    for k, v in data.items():
        if isinstance(v, dict):
            name = f"{prefix}{_toml_key(k)}"
            out += f"\n[{name}]\n" + _dump(v, name + ".")
    return out


_MUTATION = st.tuples(st.sampled_from(_PATHS),
                      st.one_of(st.just(("delete",)), st.tuples(st.just("set"), _VALUES),
                                st.tuples(st.just("rename"), st.text(max_size=18))))


def _mutated(mutations) -> str:
    data = copy.deepcopy(DEFAULT_DATA)
    for path, action in mutations:
        node = data
        for k in path[:-1]:
            if not isinstance(node.get(k), dict):
                break
            node = node[k]
        else:
            last = path[-1]
            if last not in node:
                continue
            if action[0] == "delete":
                del node[last]
            elif action[0] == "set":
                node[last] = action[1]
            elif action[1] not in node:
                node[action[1]] = node.pop(last)
    return _dump(data)


def _no_constant(name: str) -> None:
    raise AssertionError(f"non-finite number {name} in the JSON")


@settings(max_examples=40, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(st.lists(_MUTATION, min_size=1, max_size=3))
def test_mutated_parameter_files_give_finite_json_or_one_line(tmp_path_factory, capsys,
                                                              mutations) -> None:
    path = tmp_path_factory.mktemp("fuzz") / "params.toml"
    path.write_text(_mutated(mutations), encoding="utf-8")
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        rc = main(["trim", "--json", "--params", str(path)])
    out, err = capsys.readouterr()
    assert seen == []
    *progress, last = err.splitlines() or [""]
    # progress lines (a new structure derives and compiles its library) are allowed
    assert all(p.startswith("maglevgen: ") and "error" not in p for p in progress), err
    if rc == 0:
        assert "error" not in last
        json.loads(out, parse_constant=_no_constant)
    else:
        assert rc == 2, err
        assert out == "" and last.startswith("maglevgen: error: "), err


# ------------------------------------------------------------------------------ injection

@pytest.mark.slow  # a whole build of its own
def test_a_name_with_an_underscore_reaches_c_and_latex_only_escaped(tmp_path: Path) -> None:
    """A valid name with the one LaTeX-special character names allow: in report.tex only as
    ``up\\_Front9``; in the C only in identifiers and one-line comments."""
    params = _write(tmp_path, renamed("3", "up_Front9"))
    out = tmp_path / "out"
    assert main(["build", "--out", str(out), *FAST, "--params", str(params)]) == 0
    tex = (out / "report/report.tex").read_text()
    escaped = tex.count("up\\_Front9") + tex.count("up\\_\\allowbreak{}Front9")  # keys break
    assert tex.count("Front9") == escaped > 5
    for name in ("c/maglev.h", "c/main.c"):
        lines = [ln for ln in (out / name).read_text().splitlines() if "FRONT9" in ln.upper()]
        assert lines
        for line in lines:
            assert line.count("/*") == line.count("*/") == 1, line
            if line.startswith("#define"):
                assert re.fullmatch(r"#define [A-Z_][A-Z0-9_]* \d+ +/\*.*\*/", line), line


def test_a_renamed_array_shares_the_derivation_of_its_numbered_structure(tmp_path: Path
                                                                         ) -> None:
    """An array's name is a label (the generated C holds p's indices, no name): the renamed
    carriage's structure, numbered, is the default one, so its derivation folder (C and
    library) is the default's; names not at their place are numbered by place."""
    from maglevgen.carriage import structure_of
    from maglevgen.derive.structure import numbered
    from maglevgen.params import load_params
    from maglevgen.runtime.library import derivation_key

    default = structure_of(load_params().params)
    renamed_s = structure_of(load_params(_write(tmp_path, renamed("3", "up_Front9"))).params)
    assert renamed_s != default and ("up_Front9", ("z",)) in renamed_s.arrays
    assert [n.replace("arrays.up_Front9.", "arrays.3.") for n in renamed_s.param_names] == \
        list(default.param_names)
    assert numbered(renamed_s) == numbered(default) == default
    assert derivation_key(renamed_s, "double") == derivation_key(default, "double")
    swapped = DEFAULT_TEXT.replace("[arrays.1]", "[arrays.x]").replace("[arrays.2]", "[arrays.1]")
    swapped = swapped.replace("[arrays.x]", "[arrays.2]").replace('"arrays.1.', '"arrays.x.')
    swapped = swapped.replace('"arrays.2.', '"arrays.1.').replace('"arrays.x.', '"arrays.2.')
    two_first = structure_of(load_params(_write(tmp_path, swapped)).params)
    assert [n for n, _ in two_first.arrays][:2] == ["2", "1"]
    assert numbered(two_first) == default  # by place: "2" first is array 1


# ------------------------------------------------------------------------------ killed builds

_CHILD = """
import os, sys, time
import maglevgen.infrastructure.output as o
from maglevgen.cli import main
from maglevgen.errors import InputError
stage = sys.argv[1]
real_replace, real_rmtree, real_write = o.os.replace, o.shutil.rmtree, o.Path.write_bytes
def signal_and_wait():
    open(sys.argv[2] + ".ready", "w").close()
    time.sleep(600)
if stage == "writing":  # killed while the new files are being written
    calls = [0]
    def write_bytes(self, data):
        calls[0] += 1 if "/.out." in str(self) else 0
        if calls[0] == 5:
            signal_and_wait()
        return real_write(self, data)
    o.Path.write_bytes = write_bytes
elif stage == "old":  # killed after the swap, while the old output is being removed
    def rmtree(path, *a, **k):
        if ".old." in str(path):
            signal_and_wait()
        return real_rmtree(path, *a, **k)
    o.shutil.rmtree = rmtree
elif stage == "between":  # killed with the output moved aside and the new one not in
    def replace(src, dst):
        if str(dst) == os.path.realpath(sys.argv[2]):
            signal_and_wait()
        return real_replace(src, dst)
    o.os.replace = replace
sys.exit(main(["build", "--out", sys.argv[2], "--t-end", "1", "--no-pdf",
               "--set", "vehicle.mass=9.25"]))
"""


@pytest.mark.slow  # a whole build of its own
@pytest.mark.parametrize("stage", ["writing", "old", "between"])
def test_a_killed_build_leaves_nothing_after_the_next_build(fresh_build: Path,
                                                            stage: str) -> None:
    out = fresh_build
    before = tree(out)
    ready = Path(f"{out}.ready")
    child = subprocess.Popen([sys.executable, "-c", _CHILD, stage, str(out)],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 300
        while not ready.exists():
            assert child.poll() is None and time.monotonic() < deadline, "child ended early"
            time.sleep(0.05)
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait()
    ready.unlink()
    left = [n for n in siblings(out) if n != "out"]
    assert left, "the kill left no temporary folder: the test did not test anything"
    # the next build (the default parameters again) removes them; the killed build's
    # previous output is intact, or put back where the kill left it aside
    assert main(["build", "--out", str(out), *FAST]) == 0
    assert siblings(out) == ["out"]
    assert tree(out) == before


def test_a_live_builds_folders_are_not_removed(tmp_path: Path) -> None:
    """A folder of the naming pattern that a live process holds locked stays; an unlocked
    one and a different output's are told apart."""
    out = tmp_path / "out"
    out.mkdir()
    live = output._Sibling(out)  # this process holds it, as a running build does
    stale = tmp_path / ".out.old.abcd_123"
    stale.mkdir()
    (stale / "d").mkdir()
    other = tmp_path / ".other.abcdefgh"
    other.mkdir()
    removed = output.remove_stale_siblings(out.resolve())
    assert [p.name for p in removed] == [stale.name]
    assert live.path.exists() and other.exists() and not stale.exists()
    live.remove()


def test_mount_point_output_refused_before_any_work(good: Path, monkeypatch, capsys,
                                                     no_model_build) -> None:
    before, names = tree(good), siblings(good)
    monkeypatch.setattr(output, "_mount_points", lambda: {str(good.resolve())})
    rc = main(["build", "--out", str(good), *FAST, "--set", "vehicle.mass=9.31"])
    out, err = capsys.readouterr()
    assert_one_line_error(rc, out, err, [f"cannot replace {good.resolve()}", "mount point"])
    assert tree(good) == before and siblings(good) == names


def test_mount_points_are_read_from_the_system() -> None:
    """/proc is a mount point in every Linux namespace; a fresh folder is not."""
    assert "/proc" in output._mount_points() and os.path.ismount("/proc")
    with pytest.raises(InputError, match="mount point"):
        output._check_replaceable(Path("/proc"))


# ------------------------------------------------------------------------------ make run

def _stub(folder: Path, name: str, body: str) -> None:
    path = folder / name
    path.write_text(f"#!/bin/sh\n{body}\n")
    path.chmod(0o755)


@pytest.mark.parametrize("case", ["root", "sudo", "no-sudo", "apt-fails", "no-apt", "present"])
def test_make_run_installs_tex_where_it_may(tmp_path: Path, monkeypatch, capsys,
                                           case: str) -> None:
    """texsetup against stub apt-get/sudo on PATH: what runs, and the one line it says."""
    stubs, log = tmp_path / "bin", tmp_path / "log"
    stubs.mkdir()
    installs = f'echo "apt-get $*" >> {log}; '
    if case != "no-apt":
        fail = "exit 100" if case == "apt-fails" else "true"
        tex = stubs / "latexmk"
        _stub(stubs, "apt-get", f'{installs}case "$*" in *latexmk*) '
              f'{fail}; printf "#!/bin/sh\\n" > {tex}; /bin/chmod +x {tex};; esac')
    if case in ("sudo", "no-sudo"):
        ok = "exit 1" if case == "no-sudo" else ""
        _stub(stubs, "sudo", f'echo "sudo $*" >> {log}; '
              f'[ "$2" = true ] && {{ {ok or "exit 0"}; }}; shift; exec "$@"')
    if case == "present":
        _stub(stubs, "pdflatex", "")
    monkeypatch.setenv("PATH", str(stubs))
    ok = texsetup.ensure_tex(euid=0 if case in ("root", "apt-fails") else 1000)
    err = capsys.readouterr().err
    ran = log.read_text().splitlines() if log.exists() else []
    install = ("apt-get install -y -qq --no-install-recommends latexmk texlive-latex-base "
               "texlive-latex-recommended texlive-fonts-recommended poppler-utils")
    if case == "present":
        assert ok and err == "" and ran == []
    elif case == "root":
        assert ok and ran == ["apt-get update -qq", install]
        assert err.count("\n") == 1 and "installing" in err
    elif case == "sudo":
        assert ok and ran == ["sudo -n true", "sudo -n apt-get update -qq", "apt-get update -qq",
                              f"sudo -n {install}", install]
    elif case == "no-sudo":
        assert not ok and ran == ["sudo -n true"]
        assert err.count("\n") == 1
        assert "sudo apt-get install --no-install-recommends latexmk" in err
    elif case == "apt-fails":
        assert not ok and ran == ["apt-get update -qq", install]
        assert err.count("\n") == 2 and "could not install TeX" in err.splitlines()[-1]
    else:
        assert not ok and ran == [] and err.count("\n") == 1 and "no apt-get" in err


@pytest.mark.slow  # a whole build of its own
def test_summary_says_why_the_pdf_was_skipped(good: Path, tmp_path: Path, monkeypatch) -> None:
    """--no-pdf, and no TeX on the machine: the summary lists report.tex alone and says why."""
    assert "report/ (report.tex; report.pdf skipped: --no-pdf was given)" in (
        good / "SUMMARY.md").read_text()
    assert "report/report.pdf" not in tree(good)
    import maglevgen.build as build
    import maglevgen.report as report

    monkeypatch.setattr(build, "_find_tex", lambda: None)
    monkeypatch.setattr(report.latex, "find_tex", lambda: None)
    out = tmp_path / "out"
    assert main(["build", "--out", str(out), "--t-end", "1"]) == 0
    summary = (out / "SUMMARY.md").read_text()
    assert "report.pdf skipped: TeX is not installed: `apt-get install" in summary
    assert "report/report.pdf" not in tree(out) and "report/report.tex" in tree(out)


def test_eq15s_ratio_without_a_front_upper_array_is_null_not_infinite(capsys) -> None:
    """arrays.3.position = [0, 0, 0] (a range-edge value of issue 54's fuzzer) moves the only
    upper array in front of the centre of mass onto it: eq 15's F_z3 does not exist, and the
    trim's JSON said -Infinity (not JSON). Now null, every other number finite."""
    rc = main(["trim", "--json", "--set", "arrays.3.position=[0, 0, 0]"])
    out, err = capsys.readouterr()
    assert rc == 0, err
    data = json.loads(out, parse_constant=_no_constant)
    arrays = DEFAULT_DATA["arrays"]
    # the reference: the parameter file's own geometry, with array 3 moved to the origin
    front_upper = [k for k, a in arrays.items()
                   if k != "3" and a["position"][0] > 0 and a["normal"][2] > 0]
    assert front_upper == []
    assert data["pitch_paper_form"]["net_front_ratio"] is None
