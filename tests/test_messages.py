"""Messages as promised (issue 54): the cases bench/experiments/fuzz_messages.py found, each a
bad value that ended in exit 1, in exit 2 with several stderr lines, or in a bare TypeError /
ValueError / OverflowError / MemoryError from the Python API.

The promise (TESTING.md, the developer guide): a bad command-line value is exit 2 and ONE
stderr line naming the option and the value; the API raises `maglevgen.InputError` whose
message names the argument (as its command-line option). Every case here is refused before
any work (no library, no computation): the expected option names and ranges are written here.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

import maglevgen
from maglevgen.cli import main
from maglevgen.errors import InputError

# (argv, the option the one line must name): found by the fuzzer's part (a)
CLI_CASES = [
    (["montecarlo", "--samples", "99999999999999999999999"], "--samples"),  # 7 lines
    (["montecarlo", "--workers", "100000"], "--workers"),  # started 100000 processes
    (["montecarlo", "--scheduler", "tcp://h:99999"], "--scheduler"),  # tried it: 8 lines
    (["envelope", "--speeds", "0"], "--speeds"),  # exit 0: the default 50 speeds
    (["envelope", "--speeds", "-1"], "--speeds"),  # 2 lines
    (["envelope", "--speeds", "1000000"], "--speeds"),  # 2 lines
    (["roa", "--speeds", "0"], "--speeds"),  # 2 lines
    (["roa", "--speeds", "1000000"], "--speeds"),  # 2 lines
    (["roa", "--samples", "100000000000"], "--samples"),  # exit 1: MemoryError (7 TiB)
    (["roa", "--seed", "-1"], "--seed"),  # exit 1: numpy's ValueError
    (["roa", "--workers", "100000"], "--workers"),  # 100000 threads
    (["roa", "--batch", "100000000000"], "--batch"),
]


@pytest.mark.parametrize(("argv", "option"), CLI_CASES, ids=[" ".join(a) for a, _ in CLI_CASES])
def test_a_bad_option_is_one_line_naming_it(argv: list[str], option: str, capsys,
                                            tmp_path: Path) -> None:
    rc = main([*argv, "--out", str(tmp_path / "out")])
    out, err = capsys.readouterr()
    assert rc == 2, err
    assert out == "" and len(err.splitlines()) == 1, err
    assert err.startswith(f"maglevgen: error: {option} ") and argv[-1] in err, err
    assert not (tmp_path / "out").exists()


@pytest.fixture(scope="module")
def carriage() -> maglevgen.Carriage:
    return maglevgen.load()


# (method, keyword arguments, the option the InputError must name)
API_CASES = [
    ("load", {"params": -1}, "--params"),  # TypeError from pathlib
    ("load", {"params": "a\x00b"}, "--params"),  # ValueError: embedded null byte
    ("load", {"overrides": [1]}, "--set"),  # TypeError: argument of type 'int'
    ("load", {"overrides": None}, "--set"),  # TypeError: not iterable
    ("trim", {"speed": "x"}, "--speed"),  # TypeError from math.isfinite
    ("trim", {"speed": 10**400}, "--speed"),  # OverflowError: int too large for a float
    ("gains", {"speed": [1.0]}, "--speed"),
    ("trim", {"acceleration": "x"}, "--acceleration"),  # ValueError from float()
    ("trim", {"acceleration": 10**400}, "--acceleration"),  # OverflowError
    ("trim", {"acceleration": math.inf}, "--acceleration"),
    ("axis_plant", {"axis": []}, "axis"),  # TypeError: unhashable type
    ("simulate", {"disturbance": 2.5}, "--disturbance"),  # TypeError: not iterable
    ("simulate", {"disturbance": b"x"}, "--disturbance"),  # AttributeError: partition
    ("envelope", {"n_speeds": 0}, "--speeds"),  # ran with the default 50 speeds
    ("envelope", {"n_speeds": 2.5}, "--speeds"),  # TypeError from numpy's linspace
    ("envelope", {"out": 1}, "--out"),  # TypeError from pathlib
    ("montecarlo", {"samples": True}, "--samples"),  # ran one sample
    ("montecarlo", {"seed": "x"}, "--seed"),  # TypeError: '<' between str and int
    ("montecarlo", {"workers": 2.5}, "--workers"),
    ("montecarlo", {"scheduler": 1}, "--scheduler"),  # TypeError from re
    ("montecarlo", {"controller": ""}, "--controller"),  # ran the embedded controller
    ("montecarlo", {"loop": "x", "samples": 2}, "--loop"),  # refused after the library
    ("roa", {"seed": -1}, "--seed"),  # ValueError from numpy
    ("roa", {"n_speeds": math.nan}, "--speeds"),
    ("roa", {"samples": 10**11}, "--samples"),  # MemoryError
    ("roa", {"out": b"x"}, "--out"),
    ("generate", {"out": None}, "--out"),  # TypeError from pathlib
    ("generate", {"out": "o", "single_file": "no"}, "--single-file"),  # "no" is true
    ("firmware", {"out": "o", "with_plant": 1}, "--with-plant"),
    ("firmware", {"out": "", "allow_unstable": False}, "--out"),  # the current folder
    ("report", {"out": "o", "simulation": 0}, "--simulation"),  # 0 read as no simulation
    ("fmu", {"out": 3.5}, "--out"),
    ("fmu", {"out": "o", "allow_unstable": "yes"}, "--allow-unstable"),
    ("build", {"out": "a\0b"}, "--out"),  # ValueError: embedded null byte
    ("build", {"out": "o", "pdf": "false"}, "--no-pdf"),  # "false" is true
    ("generate", {"out": "o", "int_type": []}, "--int"),  # TypeError: unhashable type
    ("fmu", {"out": "o", "fmi": {}}, "--fmi"),  # TypeError: unhashable type
    ("fmu", {"out": "o", "kind": "x"}, "--kind"),  # after the verification's minutes
    ("fmu", {"out": "o", "controller": ""}, "--controller"),  # the embedded one, verified
    ("build", {"out": "o", "controller": 0}, "--controller"),  # the default, built
    ("build", {"out": "o", "t_end": 1j}, "--t-end"),  # TypeError from json.dumps
]


@pytest.mark.parametrize(("method", "kwargs", "option"), API_CASES,
                         ids=[f"{m}-{next(iter(k))}={next(iter(k.values()))!r:.20}"
                              for m, k, _ in API_CASES])
def test_a_bad_api_argument_is_an_input_error_naming_it(
        carriage: maglevgen.Carriage, method: str, kwargs: dict, option: str,
        tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)  # "o", "" and the like: nothing written where the tests run
    (tmp_path / "mine.txt").write_text("the user's")
    call = maglevgen.load if method == "load" else getattr(carriage, method)
    with pytest.raises(InputError) as err:
        call(**kwargs)
    message = str(err.value)
    assert message.startswith(option + " "), message
    assert "\n" not in message
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine.txt"]


def test_an_unbounded_cost_is_null_in_the_gains_json() -> None:
    """vehicle.length = 0.001 m (the bottom of its range; found by the fuzzer's part (b)): the
    per-axis design is unstable on the coupled linearisation, and its LQR cost, infinite,
    reached `gains --json` as `Infinity`, which JSON (RFC 8259) does not have. Now null,
    exactly where the design's poles reported beside it do not all decay."""
    rep = maglevgen.load(overrides=["vehicle.length=0.001"]).gains_report()
    json.dumps(rep, allow_nan=False)  # raises on a non-finite number
    c = rep["coupled"]
    for cost, poles in (("cost_per_axis_design", "poles_per_axis_design"),
                        ("cost_coupled_lqr", "poles_coupled_lqr")):
        unstable = max(p[0] for p in c[poles]) >= 0
        assert (c[cost] is None) == unstable, (cost, c[cost], c[poles])
    assert c["cost_per_axis_design"] is None  # the case found


def test_an_array_out_of_reach_leaves_the_gains_json_finite() -> None:
    """arrays.1.position = [-1000, -1000, -1000] m (the corner of its range; the fuzzer's part
    (b)): the array has no lift and no drag, and the speed mode's fixed-gap drag slope was
    0/0 = NaN in `gains --json`. JSON (RFC 8259) has no NaN: every number finite."""
    rep = maglevgen.load(overrides=["arrays.1.position=[-1000.0, -1000.0, -1000.0]"]
                         ).gains_report()
    json.dumps(rep, allow_nan=False)  # raises on a non-finite number
