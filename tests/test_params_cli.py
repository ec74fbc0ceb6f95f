"""The parameter file through the `maglevgen` command: bad input fails with exit code 2 and one
line on stderr naming the key and the value, before any model is built; good input round-trips.
"""

from __future__ import annotations

import copy
import json
import re
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

import maglevgen.carriage
from maglevgen.cli import main
from maglevgen.errors import InputError
from maglevgen.params import default_params_text, load_params, schema_rows, validate

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

DEFAULT_TEXT = default_params_text()
DEFAULT_DATA = tomllib.loads(DEFAULT_TEXT)
DELETE = object()
KEY_LINE = re.compile(r"^\s*([A-Za-z0-9_]+)\s*=")
TABLE_LINE = re.compile(r"^\s*\[([^\]]+)\]\s*(#.*)?$")


# ------------------------------------------------------------------------------ helpers


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)  # nan, inf, -inf are TOML too
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(c) for c in v) + "]"
    raise TypeError(type(v))


def _toml_key(key: str) -> str:
    """A bare key where TOML allows one, else a quoted key ("vehicle.mass" in [provenance])."""
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else json.dumps(key)


def dump_toml(data: dict[str, Any], prefix: str = "") -> str:
    """A tiny TOML writer: scalars and arrays first, then one [table] per nested dict."""
    lines = [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in data.items()
             if not isinstance(v, dict)]
    out = "\n".join(lines) + ("\n" if lines else "")
    for k, v in data.items():
        if isinstance(v, dict):
            name = f"{prefix}{_toml_key(k)}"
            out += f"\n[{name}]\n" + dump_toml(v, name + ".")
    return out


def edited(dotted: str, value: Any) -> str:
    """The default file with one dotted key set to ``value`` (or deleted), as TOML text."""
    data = copy.deepcopy(DEFAULT_DATA)
    *path, last = dotted.split(".")
    node = data
    for key in path:
        node = node.setdefault(key, {})
    if value is DELETE:
        del node[last]
    else:
        node[last] = value
    return dump_toml(data)


def replaced(old: str, new: str) -> str:
    assert DEFAULT_TEXT.count(old) == 1, old
    return DEFAULT_TEXT.replace(old, new)


def listing(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


def generic(key: str) -> str:
    return re.sub(r"^(arrays|sensors\.gap_sensors)\.[^.]+(\.|$)", r"\1.<name>\2", key)


def file_keys(text: str) -> list[tuple[str, str]]:
    """(dotted key, line) for every key line of a TOML file without multi-line values."""
    section, keys = "", []
    for line in text.splitlines():
        if m := TABLE_LINE.match(line):
            section = m.group(1).strip()
        elif m := KEY_LINE.match(line):
            keys.append((f"{section}.{m.group(1)}" if section else m.group(1), line))
    return keys


# ------------------------------------------------------------------------------ bad input

# (id, file text (bytes written as they are; None: the default file), extra argv,
#  substrings the one stderr line must contain)
BAD: list[tuple[str, str | bytes | None, list[str], list[str]]] = [
    ("malformed-toml", replaced("mass = 9.3\n", "mass = = 9.3\n"), [],
     ["malformed TOML", "line 8"]),
    ("malformed-unclosed-table", replaced("[track]", "[track"), [], ["malformed TOML"]),
    ("unknown-top-level", 'colour = "red"\n' + DEFAULT_TEXT, [], ["unknown key colour"]),
    ("unknown-table", DEFAULT_TEXT + "\n[wheels]\ncount = 4\n", [], ["unknown key wheels"]),
    ("unknown-nested", replaced("[vehicle]\n", '[vehicle]\ncolour = "red"\n'), [],
     ["unknown key vehicle.colour"]),
    ("unknown-in-array", edited("arrays.3.colour", "red"), [], ["unknown key arrays.3.colour"]),
    ("missing-key", edited("halbach.width", DELETE), [], ["missing key halbach.width"]),
    ("missing-table", edited("track", DELETE), [], ["missing key track"]),
    ("missing-inertia-entry", edited("vehicle.inertia_cg.yz", DELETE), [],
     ["missing key vehicle.inertia_cg.yz"]),
    ("type-str", edited("vehicle.mass", "heavy"), [], ["vehicle.mass = 'heavy'", "number"]),
    ("type-bool", edited("vehicle.mass", True), [], ["vehicle.mass = True"]),
    ("type-list", edited("arrays.3.circuits", [1]), [], ["arrays.3.circuits = [1]"]),
    ("type-float-for-int", edited("halbach.magnets_per_wavelength", 4.5), [],
     ["halbach.magnets_per_wavelength = 4.5"]),
    ("vec-too-short", edited("arrays.3.position", [0.0, 0.0]), [],
     ["arrays.3.position = [0.0, 0.0]"]),
    *[
        (f"{key}={value}", edited(key, value), [], [f"{key} = {value!r}:", "outside the range"])
        for key in ("vehicle.mass", "halbach.wavelength", "circuit.resistance",
                    "circuit.inductance", "halbach.width", "operation.speed")
        for value in (0, -5, 0.0, -1e-3)
    ],
    ("nan", edited("vehicle.inertia_cg.xz", float("nan")), [],
     ["vehicle.inertia_cg.xz = nan", "finite"]),
    ("inf", edited("halbach.wavelength", float("inf")), [],
     ["halbach.wavelength = inf", "finite"]),
    ("inertia-not-positive-definite", edited("vehicle.inertia_cg.xz", 0.5), [],
     ["vehicle.inertia_cg = [", "xz=0.5", "not positive definite"]),
    ("inertia-triangle",
     edited("vehicle.inertia_cg", {"xx": 0.01, "yy": 0.01, "zz": 1.0,
                                   "xy": 0.0, "xz": 0.0, "yz": 0.0}), [],
     ["vehicle.inertia_cg = [", "xx=0.01, yy=0.01, zz=1", "triangle inequality"]),
    ("actuators-unknown", edited("control.actuators", "sideways"), [],
     ["control.actuators = 'sideways':", "expected one of paper, normal"]),
    ("actuators-not-a-name", edited("control.actuators", 2), [], ["control.actuators = 2:"]),
    ("set-actuators-unknown", None, ["--set", 'control.actuators="Normal"'],
     ["control.actuators = 'Normal':", "expected one of paper, normal"]),
    ("lag-negative", edited("actuators.time_constant", -2e-3), [],
     ["actuators.time_constant = -0.002:", "outside the range [0, 1] s"]),
    ("lag-not-a-number", edited("actuators.time_constant", "2 ms"), [],
     ["actuators.time_constant = '2 ms':"]),
    ("rate-limit-zero", edited("actuators.rate_limit", 0.0), [],
     ["actuators.rate_limit = 0.0:", "outside the range"]),
    ("set-budget-above-drive", None, ["--set", "control.spec.force_budget=25"],
     ["control.spec.force_budget = 25:", "above actuators.force_limit = 20"]),
    ("actuators-unknown-key", edited("actuators.inductance", 0.01), [],
     ["unknown key actuators.inductance"]),
    ("inertia-unknown-word", edited("vehicle.inertia_cg", "cube"), [],
     ["vehicle.inertia_cg = 'cube':", 'or "box"']),
    ("set-inertia-box-without-height", edited("vehicle.height", DELETE),
     ["--set", 'vehicle.inertia_cg="box"'],
     ["vehicle.height", 'inertia_cg = "box" computes the inertia from the length, width and '
      "height"]),
    ("box-width-range", edited("vehicle.width", -0.25), ["--set", 'vehicle.inertia_cg="box"'],
     ["vehicle.width = -0.25:", "outside the range"]),
    ("zero-normal", edited("arrays.3.normal", [0.0, 0.0, 0.0]), [],
     ["arrays.3.normal = [0.0, 0.0, 0.0]", "non-zero"]),
    ("gap-below-min", edited("arrays.3.nominal_gap", 0.001), [],
     ["arrays.3.nominal_gap = 0.001", "track.min_gap"]),
    ("gap-equal-min", edited("arrays.6.nominal_gap", 0.002), [],
     ["arrays.6.nominal_gap = 0.002", "track.min_gap"]),
    ("nonexistent-file", None, ["--params", "nope.toml"],
     ["nope.toml", "cannot read", "No such file"]),
    ("directory", None, ["--params", "."], ["cannot read", "directory"]),
    ("not-utf8", DEFAULT_TEXT.encode().replace(b"mass = 9.3", b"mass = 9.3 \xff"), [],
     ["cannot read", "UTF-8"]),
    ("set-unknown-key", None, ["--set", "vehicle.colour=1"], ["vehicle.colour"]),
    ("set-unknown-table", None, ["--set", "wheels.count=4"], ["wheels"]),
    ("set-below-leaf", None, ["--set", "vehicle.mass.x=1"], ["vehicle.mass.x"]),
    ("set-malformed-value", None, ["--set", "vehicle.mass=abc"],
     ["vehicle.mass=abc", "not a TOML value"]),
    ("set-value-with-newline", None, ["--set", 'vehicle.mass="a\nb"'],
     ["--set vehicle.mass", "control character U+000A"]),
    ("set-no-equals", None, ["--set", "vehicle.mass"], ["vehicle.mass", "NAME=VALUE"]),
    ("set-bad-name", None, ["--set", "vehicle..mass=1"], ["vehicle..mass"]),
    ("set-invalid-value", None, ["--set", "vehicle.mass=-2"], ["vehicle.mass = -2:"]),
    ("set-wrong-type", None, ["--set", "arrays.3.circuits=[1]"],
     ["arrays.3.circuits = [1]"]),
]


def write_input(tmp_path: Path, text: str | bytes | None) -> Path:
    path = tmp_path / "params.toml"
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(DEFAULT_TEXT if text is None else text, encoding="utf-8")
    return path


def assert_one_line_error(rc: int, out: str, err: str, expected: list[str]) -> None:
    assert rc == 2, err
    assert out == ""
    assert err.endswith("\n")
    line = err[:-1]
    assert "\n" not in line, err
    assert line.startswith("maglevgen: error: "), err
    assert "Traceback" not in err
    for s in expected:
        assert s in line, f"{s!r} not in {line!r}"


@pytest.fixture
def no_model_build(monkeypatch: pytest.MonkeyPatch) -> None:
    """Make building a Carriage an internal error (exit 1), so a bad file must fail first."""

    def boom(*_a: object, **_k: object) -> None:
        raise AssertionError("model built before the parameter file was validated")

    monkeypatch.setattr(maglevgen.carriage, "DerivedCarriage", boom)


@pytest.mark.usefixtures("no_model_build")
@pytest.mark.parametrize("command", [["params", "show"], ["trim"]], ids=["show", "trim"])
@pytest.mark.parametrize(("text", "extra", "expected"), [c[1:] for c in BAD],
                         ids=[c[0] for c in BAD])
def test_bad_input_is_one_line_exit_2(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
    command: list[str], text: str | bytes | None, extra: list[str], expected: list[str],
) -> None:
    path = write_input(tmp_path, text)
    monkeypatch.chdir(tmp_path)
    argv = [*command, *(extra if "--params" in extra else ["--params", str(path), *extra])]
    before = listing(tmp_path)
    assert before == ["params.toml"]
    rc = main(argv)
    out, err = capsys.readouterr()
    assert_one_line_error(rc, out, err, expected)
    assert listing(tmp_path) == before


@pytest.mark.parametrize(
    ("command", "text", "expected"),
    [
        (["params", "show"], edited("vehicle.mass", -1.0), ["vehicle.mass = -1.0"]),
        (["params", "show"], replaced("[vehicle]\n", "[vehicle]\ncolour = 1\n"),
         ["vehicle.colour"]),
        (["trim"], edited("vehicle.inertia_cg", {"xx": 0.01, "yy": 0.01, "zz": 1.0,
                                                 "xy": 0.0, "xz": 0.0, "yz": 0.0}),
         ["vehicle.inertia_cg", "triangle"]),
    ],
    ids=["show-mass", "show-unknown", "trim-inertia"],
)
def test_bad_input_subprocess(
    tmp_path: Path, command: list[str], text: str, expected: list[str]
) -> None:
    path = write_input(tmp_path, text)
    proc = subprocess.run(
        [sys.executable, "-m", "maglevgen.cli", *command, "--params", path.name],
        cwd=tmp_path, capture_output=True, text=True, timeout=300, check=False,
    )
    assert_one_line_error(proc.returncode, proc.stdout, proc.stderr, expected)
    assert listing(tmp_path) == ["params.toml"]


# ------------------------------------------------------------------------------ good input


def test_toml_writer_round_trips() -> None:
    assert tomllib.loads(dump_toml(DEFAULT_DATA)) == DEFAULT_DATA
    assert validate(tomllib.loads(dump_toml(DEFAULT_DATA)), "test") == load_params().params


@pytest.mark.parametrize("use_file", [True, False], ids=["file", "default"])
def test_show_reparses_to_the_same_data(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], use_file: bool
) -> None:
    path = write_input(tmp_path, None)
    assert main(["params", "show", *(["--params", str(path)] if use_file else [])]) == 0
    out, err = capsys.readouterr()
    assert err == ""
    assert tomllib.loads(out) == DEFAULT_DATA
    assert out != DEFAULT_TEXT  # annotated


def test_show_annotates_every_key_with_its_schema_unit(
    capsys: pytest.CaptureFixture[str],
) -> None:
    units = {key: unit for key, unit, _, _ in schema_rows()}
    assert main(["params", "show"]) == 0
    out = capsys.readouterr().out
    shown, raw = file_keys(out), file_keys(DEFAULT_TEXT)
    assert [k for k, _ in shown] == [k for k, _ in raw]
    assert len(shown) > 40
    for key, line in shown:
        if key.startswith("provenance."):  # where a value comes from: text, no unit
            continue
        assert generic(key) in units, key
        assert f"# [{units[generic(key)]}]" in line, line


def test_set_changes_the_loaded_value(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path = write_input(tmp_path, None)
    base = load_params(path)
    loaded = load_params(path, ["vehicle.mass=12.5", "arrays.3.position=[0.3, 0, -0.03]"])
    assert base.params.vehicle.mass == 9.3
    assert loaded.params.vehicle.mass == 12.5
    assert loaded.params.arrays["3"].position == [0.3, 0.0, -0.03]
    assert loaded.sha256 != base.sha256
    assert loaded.overrides == ("vehicle.mass=12.5", "arrays.3.position=[0.3, 0, -0.03]")
    assert main(["params", "show", "--params", str(path), "--set", "vehicle.mass=12.5"]) == 0
    assert capsys.readouterr().err == ""


def test_set_addresses_a_quoted_key_as_the_file_would(tmp_path: Path) -> None:
    """A key with dots in it (a toleranced entry's name) is quoted as TOML quotes it: the
    override gives the parameters of a file edited to the same entry, for an entry the file
    has and for one it omits (a table the schema has, added)."""
    text = default_params_text()
    line = '"sensors.imu.gyro_noise" = { uniform = 5e-5 }'
    assert line in text
    edited = tmp_path / "edited.toml"
    edited.write_text(text.replace(line, '"sensors.imu.gyro_noise" = { uniform = 1e-4 }\n'
                                   '"circuit.inductance" = { normal = 1e-7 }'), encoding="utf-8")
    loaded = load_params(None, ['tolerances.parameters."sensors.imu.gyro_noise".uniform=1e-4',
                                'tolerances.parameters."circuit.inductance"={ normal = 1e-7 }'])
    assert loaded.params.tolerances == load_params(edited).params.tolerances
    with pytest.raises(InputError, match=r"not a dotted parameter name \(keys with dots"):
        load_params(None, ['tolerances.parameters."vehicle.mass=1'])
    with pytest.raises(InputError, match=r"unknown key 'tolerances\.parametrs'"):
        load_params(None, ['tolerances.parametrs."vehicle.mass".normal=0.1'])


def test_show_raw_is_byte_identical(tmp_path: Path) -> None:
    path = write_input(tmp_path, None)
    proc = subprocess.run(
        [sys.executable, "-m", "maglevgen.cli", "params", "show", "--raw", "--params", str(path)],
        capture_output=True, timeout=120, check=False,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr == b""
    assert proc.stdout == path.read_bytes()


def test_show_raw_keeps_crlf(tmp_path: Path, capsysbinary: pytest.CaptureFixture[bytes]) -> None:
    path = tmp_path / "crlf.toml"
    path.write_bytes(DEFAULT_TEXT.replace("\n", "\r\n").encode())
    assert main(["params", "show", "--raw", "--params", str(path)]) == 0
    assert capsysbinary.readouterr().out == path.read_bytes()


def test_schema_lists_every_key(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["params", "schema"]) == 0
    out, err = capsys.readouterr()
    assert err == ""
    listed = {line.split()[0]: line for line in out.splitlines()}
    rows = schema_rows()
    assert len(listed) == len(rows) == len(out.splitlines())
    for key, unit, _, _ in rows:
        assert f"[{unit}]" in listed[key], key
    for key, _ in file_keys(DEFAULT_TEXT):
        if key.startswith("provenance."):  # one schema row: provenance.<key>
            assert "provenance.<key>" in listed
            continue
        assert generic(key) in listed, key
