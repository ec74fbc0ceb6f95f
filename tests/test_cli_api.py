"""The command line against the Python API, option by option (issue 33: the CLI is a printer
over the API).

- Every subcommand of ``maglevgen`` (argparse's parser walked: each subparser, each option's
  ``dest``) has an API entry point, and that entry point takes a parameter for each of its
  options: the same name, or the one of RENAMED. Only CLI_ONLY options (how the command
  prints) are the command line's own. A planted option without an API parameter is caught.
- Each command's function calls its entry point (it prints what the API computes); the
  `build` command calls the function `Carriage.build` calls (an up-to-date folder answers
  without numpy). Neither front end (nor analyses/queries.py, the functions behind trim, gains and
  envelope) reaches for another module's private name (read with `ast`).
- The options the API gained do what the command line does: the disturbance is the initial
  state's deviation from the trim (numpy on the API's trim); the checks are the CLI's
  (message and exit code of ``maglevgen.cli.main``). ``generate --int`` and
  ``--single-file`` go through `Carriage.generate` (tests/test_firmware.py checks their C).
"""

from __future__ import annotations

import argparse
import ast
import inspect
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

import maglevgen
from maglevgen import api, build, cli, params

#: options of the command line alone: how a command prints, not what it computes
CLI_ONLY: dict[str, str] = {
    "debug": "--debug: a traceback instead of the one-line error",
    "json": "--json: the report printed as JSON (the API returns it as data)",
    "raw": "params show --raw: the file printed as stored, without the units",
}

#: the option's API parameter where the names must differ (a Python keyword, a builtin, a
#: negative flag, a count that the API names as such)
RENAMED: dict[str, str] = {
    "int": "int_type",  # --int: `int` is a builtin
    "no_pdf": "pdf",  # --no-pdf: the API takes the positive flag, pdf=False
    "speeds": "n_speeds",  # --speeds N (envelope, roa): a count, not the speeds
}

#: each command's API entry point: the callables whose parameters take its options (the
#: carriage's --params and --set are `maglevgen.Carriage`'s)
ENTRY: dict[str, tuple[Callable, ...]] = {
    "params show": (api.load,),  # validates what is shown; the text is maglevgen.params'
    "params schema": (params.schema_table,),
    "trim": (api.Carriage, api.Carriage.trim),
    "gains": (api.Carriage, api.Carriage.gains_report),
    "generate": (api.Carriage, api.Carriage.generate),
    "firmware": (api.Carriage, api.Carriage.firmware),
    "simulate": (api.Carriage, api.Carriage.simulations),
    "montecarlo": (api.Carriage, api.Carriage.montecarlo),
    "envelope": (api.Carriage, api.Carriage.envelope),
    "roa": (api.Carriage, api.Carriage.roa),
    "fmu": (api.Carriage, api.Carriage.fmu),
    "build": (api.Carriage, api.Carriage.build),
    "report": (api.Carriage, api.Carriage.report),
}

#: what each command's function calls (the entry point's own function, or for `build` the
#: one function `Carriage.build` calls)
CALLS: dict[str, str] = {"params show": "load_params", "params schema": "schema_table",
                         "simulate": "simulations", "gains": "gains_report",
                         "build": "build_folder"}


def commands(parser: argparse.ArgumentParser,
             prefix: str = "") -> dict[str, argparse.ArgumentParser]:
    """Every leaf subcommand ("trim", "params show") of ``parser`` and its parser."""
    out: dict[str, argparse.ArgumentParser] = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                full = f"{prefix}{name}"
                inner = commands(sub, full + " ")
                out.update(inner or {full: sub})
    return out


def options(sub: argparse.ArgumentParser) -> list[str]:
    """The dest of each option of a subcommand (--help and subparsers aside)."""
    return [a.dest for a in sub._actions
            if not isinstance(a, (argparse._HelpAction, argparse._SubParsersAction))]


def api_parameters(entry: tuple[Callable, ...]) -> dict[str, inspect.Parameter]:
    out: dict[str, inspect.Parameter] = {}
    for fn in entry:
        out.update((n, p) for n, p in inspect.signature(fn).parameters.items() if n != "self")
    return out


def missing(parser: argparse.ArgumentParser) -> list[tuple[str, str]]:
    """(command, option) of every option without an API parameter; a command without an
    entry point is (command, "")."""
    out = []
    for name, sub in commands(parser).items():
        if name not in ENTRY:
            out.append((name, ""))
            continue
        taken = api_parameters(ENTRY[name])
        out += [(name, dest) for dest in options(sub)
                if dest not in CLI_ONLY and RENAMED.get(dest, dest) not in taken]
    return out


def test_every_command_option_is_an_api_parameter() -> None:
    parser = cli.build_parser()
    found = commands(parser)
    assert set(found) == set(ENTRY)
    assert len(found) == 13 and "params show" in found and "build" in found
    assert missing(parser) == []
    # the mapping is small and used: each renamed option exists, and its name is no parameter
    used = {dest for sub in found.values() for dest in options(sub)}
    assert set(RENAMED) <= used and set(CLI_ONLY) <= used
    for name, sub in found.items():
        taken = api_parameters(ENTRY[name])
        assert not {RENAMED[d] for d in options(sub) if d in RENAMED} - set(taken)
        assert not {d for d in options(sub) if d in RENAMED} & set(taken)


def test_a_planted_option_without_an_api_parameter_is_caught() -> None:
    """The check above fails when a command gains an option the API lacks (and a new
    command without an entry point)."""
    parser = cli.build_parser()
    subs = commands(parser)
    subs["simulate"].add_argument("--frobnicate", type=float)
    subs["params schema"].add_argument("--width", type=int)
    assert missing(parser) == [("params schema", "width"), ("simulate", "frobnicate")]
    (action,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    action.add_parser("polish")
    assert ("polish", "") in missing(parser)


def test_defaults_agree() -> None:
    """An option's default is its API parameter's, where the API has one; the output folder
    aside (the command writes to ./NAME by default, the API only where asked, except for
    the writers whose result is the folder)."""
    differ = []
    for name, sub in commands(cli.build_parser()).items():
        taken = api_parameters(ENTRY[name])
        for a in sub._actions:
            p = taken.get(RENAMED.get(a.dest, a.dest))
            if p is None or p.default is inspect.Parameter.empty or a.dest == "out":
                continue
            cli_default = (not a.default) if a.dest == "no_pdf" else a.default
            if cli_default in (None, []) and p.default in (None, ()):
                continue
            if cli_default != p.default:
                differ.append((name, a.dest, cli_default, p.default))
    assert differ == []


def test_each_command_calls_its_entry_point() -> None:
    parser = cli.build_parser()
    for name, sub in commands(parser).items():
        func = sub.get_default("func")
        call = CALLS.get(name, ENTRY[name][-1].__name__)
        assert f"{call}(" in inspect.getsource(func), name
    # build's function is the one the API calls
    assert "build_folder(" in inspect.getsource(api.Carriage.build)
    assert build.build_folder.__module__ == "maglevgen.build"


def private_uses(path: Path) -> list[str]:
    """Each ``from .x import _y`` and ``obj._y`` (``self``/``cls`` aside, dunders aside)."""
    tree = ast.parse(path.read_text())
    out = []
    for n in ast.walk(tree):
        if isinstance(n, ast.ImportFrom) and n.level:
            out += [f"{path.name}:{n.lineno} {ast.unparse(n)}" for a in n.names
                    if a.name.startswith("_") and not a.name.startswith("__")]
        if (isinstance(n, ast.Attribute) and n.attr.startswith("_")
                and not n.attr.startswith("__")
                and not (isinstance(n.value, ast.Name) and n.value.id in ("self", "cls"))):
            out.append(f"{path.name}:{n.lineno} {ast.unparse(n)}")
    return out


def test_the_front_ends_use_no_private_name_of_another_module(tmp_path: Path) -> None:
    from maglevgen.analyses import queries

    files = [Path(m.__file__) for m in (cli, queries, build)]
    files += sorted(Path(api.__file__).parent.glob("*.py"))  # the API's package, every module
    assert [u for f in files for u in private_uses(f)] == []
    planted = tmp_path / "planted.py"  # the check itself, on the pattern it replaced
    planted.write_text("from .queries import _library\nlib = queries._library(c)\n"
                       "self._lib\nx.__name__\n")
    assert [u.split(" ", 1)[1] for u in private_uses(planted)] == [
        "from .queries import _library", "queries._library"]


# ------------------------------------------------------------- the options the API gained


@pytest.mark.needs_cc
def test_disturbance_is_the_initial_deviation_from_trim() -> None:
    """``disturbance`` (a mapping or ``--disturbance`` items): the run starts at the trim
    (the API's trim at the speed) plus exactly the given deviations, the other states at
    trim."""
    carriage = maglevgen.load()
    trim = carriage.trim(20.0)
    given = {"z": 0.002, "phi": -0.001, "w": 0.01}
    a = carriage.simulate("coupled", speed=20.0, t_end=0.01, disturbance=given)
    b = carriage.simulate("coupled", speed=20.0, t_end=0.01,
                          disturbance=["z=0.002", "phi=-0.001", "w=0.01"])
    want = trim.x.copy()
    for s, v in given.items():
        want[list(trim.state_names).index(s)] += v
    np.testing.assert_allclose(a.x[0], want, rtol=0, atol=1e-15)
    assert np.array_equal(a.x, b.x)


@pytest.fixture(scope="module")
def default() -> maglevgen.Carriage:
    return maglevgen.load()


@pytest.mark.parametrize(("call", "argv"), [
    (lambda c, out: c.simulations(disturbance={"zz": 1}, out=out),
     ["simulate", "--disturbance", "zz=1"]),
    (lambda c, out: c.simulations(disturbance=["z=abc"], out=out),
     ["simulate", "--disturbance", "z=abc"]),
    (lambda c, out: c.simulations(disturbance="z=0.5", out=out),
     ["simulate", "--disturbance", "z=0.5"]),
    (lambda c, out: c.simulations(check=True, out=out), ["simulate", "--check"]),
    (lambda c, out: c.montecarlo(seed=-1, out=out), ["montecarlo", "--seed", "-1"]),
    (lambda c, out: c.build(out, controller="pid"), ["build", "--controller", "spec",
                                                      "--dt", "5"]),
])
def test_gained_options_check_as_the_cli_does(call, argv: list[str], tmp_path: Path,
                                              default: maglevgen.Carriage,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    """The API's error is the line the command prints, exit code 2, nothing written (the
    build's: its --controller checked by argparse, by the schema in the API)."""
    out = tmp_path / "o"
    rc = cli.main([*argv, "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and err.startswith("maglevgen: error: ")
    with pytest.raises(maglevgen.InputError) as info:
        call(default, out)
    if argv[0] != "build":
        assert err == f"maglevgen: error: {info.value}\n"
    else:
        assert "--dt 5" in err and "envelope.embedded_controller" in str(info.value)
    assert not out.exists()
    with pytest.raises(maglevgen.InputError, match="--int 'int16'"):
        default.generate(out, int_type="int16")
