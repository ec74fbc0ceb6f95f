"""The Python API (maglevgen/api/) against the command line and python-control.

- Every number the API returns for a report is the one the CLI prints (``--json``), for the
  default carriage and a changed one; bad input raises the exception whose message the CLI
  prints, on one line.
- ``Carriage.linearize`` against ``control.linearize`` (finite differences) of a
  ``control.NonlinearIOSystem`` built here from the compiled ``maglev_dynamics``; the
  closed-loop poles that python-control's ``feedback`` gives on it against the envelope's.
- The gains against ``control.lqr`` on the API's plants.
- numpydoc's docscrape finds every parameter documented; the docstrings' examples run.
"""

from __future__ import annotations

import doctest
import inspect
import json
import re
import sys
import warnings
from pathlib import Path

import control
import numpy as np
import pytest
from numpydoc.docscrape import ClassDoc, FunctionDoc

import maglevgen
from maglevgen import api
from maglevgen.api import arguments, core, results, studies, writers
from maglevgen.cli import main
from maglevgen.controllers import names
from maglevgen.infrastructure.output import MARKER
from maglevgen.params import flatten

# every test runs the compiled library (the API's, or the CLI's)
pytestmark = pytest.mark.needs_cc

# the package's modules: the examples' doctest reads each (its own objects only)
API_MODULES = (api, arguments, core, results, studies, writers)
CHANGED = ("vehicle.mass=10.5", "control.state_weights=[2.0, 0.5]")
SPEED = 15.0


@pytest.fixture(scope="module")
def default() -> maglevgen.Carriage:
    return maglevgen.load()


@pytest.fixture(scope="module")
def changed() -> maglevgen.Carriage:
    return maglevgen.load(overrides=CHANGED)


def cli_json(capsys: pytest.CaptureFixture[str], *argv: str) -> dict:
    assert main(list(argv)) == 0
    return json.loads(capsys.readouterr().out)


def sets(overrides: tuple[str, ...]) -> list[str]:
    return [a for o in overrides for a in ("--set", o)]


# ------------------------------------------------------------------------ API vs CLI


@pytest.mark.parametrize("which", ["default", "changed"])
def test_trim_and_gains_reports_are_the_cli_numbers(which: str, request: pytest.FixtureRequest,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    carriage = request.getfixturevalue(which)
    argv = [*sets(CHANGED if which == "changed" else ()), "--speed", str(SPEED), "--json"]
    cli_trim = cli_json(capsys, "trim", *argv)
    cli_gains = cli_json(capsys, "gains", *argv)
    assert cli_trim.pop("envelope") and cli_gains.pop("envelope")

    trim = carriage.trim(SPEED)
    assert trim.to_dict() == cli_trim  # bit for bit: JSON round-trips a double exactly
    assert trim.x.tolist() == [cli_trim["state"][s] for s in carriage.state_names]
    assert trim.gaps.tolist() == [a["gap"] for a in cli_trim["arrays"].values()]
    assert trim.propulsion_force == cli_trim["propulsion_force"]
    assert carriage.gains_report(SPEED) == cli_gains
    for axis, row in cli_gains["axes"].items():
        plant = carriage.axis_plant(axis, SPEED)
        assert plant.A.tolist() == row["A"] and plant.B.tolist() == row["B"]


def test_accelerating_trim_is_the_cli_trim_and_the_reference_root(
        default: maglevgen.Carriage, capsys: pytest.CaptureFixture[str]) -> None:
    """``Carriage.trim(V, acceleration=a)`` is ``maglevgen trim --acceleration a --json`` bit
    for bit, and its pose and propulsion are the root of the static balances with the
    d'Alembert load solved in tests/independent_reference.py; the text output names the
    acceleration and the m a in the propulsion."""
    from independent_reference import reference_trim

    cli = cli_json(capsys, "trim", "--speed", str(SPEED), "--acceleration", "5", "--json")
    assert cli.pop("envelope")
    trim = default.trim(SPEED, acceleration=5.0)
    assert trim.to_dict() == cli and trim.acceleration == cli["acceleration"] == 5.0
    ref = reference_trim(default.params, SPEED, 5.0)
    np.testing.assert_allclose(trim.x[1:6], ref.q, rtol=0, atol=1e-10)
    assert trim.propulsion_force == pytest.approx(ref.f_prop, rel=1e-9)
    assert trim.residual < 1e-8
    assert main(["trim", "--speed", str(SPEED), "--acceleration", "5"]) == 0
    out = capsys.readouterr().out
    assert f"Trim at {SPEED:g} m/s accelerating at 5 m/s^2" in out
    assert f"and m a = {default.params.vehicle.mass * 5:.6g} N" in out


def test_changed_carriage_changes_the_numbers(default: maglevgen.Carriage,
                                              changed: maglevgen.Carriage) -> None:
    """The overrides reach the numbers (else the test above could pass on the default)."""
    assert changed.params.vehicle.mass == 10.5 != default.params.vehicle.mass
    assert changed.trim(SPEED).propulsion_force != default.trim(SPEED).propulsion_force
    assert not np.allclose(changed.gains(SPEED).K_pos, default.gains(SPEED).K_pos)


@pytest.mark.parametrize("which", ["default", "changed"])
def test_envelope_is_the_cli_envelope(which: str, request: pytest.FixtureRequest,
                                      capsys: pytest.CaptureFixture[str],
                                      tmp_path: Path) -> None:
    carriage = request.getfixturevalue(which)
    cli = cli_json(capsys, "envelope", "--speeds", "7", "--json",
                   *sets(CHANGED if which == "changed" else ()))
    env = carriage.envelope(n_speeds=7, out=tmp_path / "env")
    assert env.to_dict() == cli
    assert env.speeds.tolist() == cli["speeds"]
    for name, row in cli["controllers"].items():
        assert env.max_real[name].tolist() == row["max_real"]
        assert env.verdicts[name] == row["verdict"]
    assert json.loads((tmp_path / "env" / "envelope.json").read_text()) == cli
    assert {p.name for p in env.paths} == {"envelope.json", "envelope.md", "stability_map.png"}


@pytest.mark.parametrize(("which", "controller"),
                         [("default", "lqr"), ("default", "none"), ("changed", "coupled")])
def test_simulation_is_the_cli_run(which: str, controller: str,
                                   request: pytest.FixtureRequest,
                                   capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    carriage = request.getfixturevalue(which)
    assert main(["simulate", "--controller", controller, "--t-end", "2", "--speed", str(SPEED),
                 *sets(CHANGED if which == "changed" else ()), "--out", str(tmp_path)]) == 0
    capsys.readouterr()
    run = carriage.simulate(controller=controller, speed=SPEED, t_end=2.0)
    with np.load(tmp_path / "trajectories.npz") as npz:
        table, cols = npz[controller], [str(c) for c in npz["columns"]]
    assert np.array_equal(np.column_stack([run.t, run.x, run.u, run.gaps]), table)
    (cli_metrics,) = json.loads((tmp_path / "metrics.json").read_text())["runs"]
    assert json.loads(json.dumps(run.metrics)) == cli_metrics
    assert run.status == cli_metrics["status"]
    df = run.to_dataframe()
    assert list(df.columns) == cols and np.array_equal(df.to_numpy(), table)
    assert list(run.units) == cols


def test_launch_is_the_cli_launch(default: maglevgen.Carriage,
                                  capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert main(["simulate", "--controller", "coupled", "--scenario", "launch",
                 "--out", str(tmp_path)]) == 0
    capsys.readouterr()
    run = default.simulate(controller="coupled", scenario="launch")
    with np.load(tmp_path / "trajectories.npz") as npz:
        assert np.array_equal(np.column_stack([run.t, run.x, run.u, run.gaps]), npz["coupled"])
    assert run.scenario == "launch" and run.metrics["scenario"] == "launch"
    # it accelerated from v_min to v_max (the envelope's ends)
    env = json.loads((tmp_path / "metrics.json").read_text())
    assert run.metrics["speed_end"] >= env["release_speed"] > run.metrics["speed_start"]


@pytest.mark.slow  # two reports built
def test_report_is_the_cli_report(default: maglevgen.Carriage,
                                  capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert main(["report", "--out", str(tmp_path / "cli")]) == 0
    cli_warnings = [line.split("warning: ", 1)[1] for line in capsys.readouterr().err.splitlines()
                    if "warning: verification failed" in line]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        paths = default.report(tmp_path / "api")
    assert [str(w.message) for w in caught if w.category is UserWarning] == cli_warnings
    # (the folder also holds the list of what maglevgen wrote, which no call returns)
    assert sorted(p.name for p in paths) == sorted(p.name for p in (tmp_path / "cli").iterdir()
                                                   if p.name != MARKER)
    assert (tmp_path / "api" / "report.tex").read_bytes() == \
        (tmp_path / "cli" / "report.tex").read_bytes()


def _cli_error(capsys: pytest.CaptureFixture[str], argv: list[str]) -> tuple[int, str]:
    rc = main(argv)
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("maglevgen: error: ")
    return rc, err.removeprefix("maglevgen: error: ").rstrip("\n")


@pytest.mark.parametrize(("call", "argv"), [
    (lambda: maglevgen.load(overrides=["vehicle.mass=-1"]),
     ["trim", "--set", "vehicle.mass=-1"]),
    (lambda: maglevgen.load(overrides=["vehicle.wings=2"]),
     ["trim", "--set", "vehicle.wings=2"]),
    (lambda: maglevgen.load("/nonexistent/carriage.toml"),
     ["trim", "--params", "/nonexistent/carriage.toml"]),
    (lambda: maglevgen.load().trim(1e9), ["trim", "--speed", "1e9"]),
    (lambda: maglevgen.load().trim(20.0, acceleration=float("nan")),
     ["trim", "--speed", "20", "--acceleration", "nan"]),
    (lambda: maglevgen.load().gains(0.05), ["simulate", "--speed", "0.05", "--out", "{tmp}"]),
    (lambda: maglevgen.load().simulate(dt=5.0), ["simulate", "--dt", "5", "--out", "{tmp}"]),
    (lambda: maglevgen.load().simulate(scenario="launch", speed=15.0),
     ["simulate", "--scenario", "launch", "--speed", "15", "--out", "{tmp}"]),
    (lambda: maglevgen.load().envelope(n_speeds=1), ["envelope", "--speeds", "1"]),
])
def test_errors_are_the_cli_errors(call, argv: list[str], capsys: pytest.CaptureFixture[str],
                                   tmp_path: Path) -> None:
    rc, message = _cli_error(capsys, [a.replace("{tmp}", str(tmp_path / "o")) for a in argv])
    with pytest.raises(maglevgen.MaglevError) as info:
        call()
    assert str(info.value) == message
    assert info.value.exit_code == rc == 2
    assert not (tmp_path / "o").exists()


def test_api_rejects_unknown_names(default: maglevgen.Carriage) -> None:
    for call in (lambda: default.gains(controller="pid"), lambda: default.axis_plant("surge"),
                 lambda: default.linearize(model="half"),
                 lambda: default.simulate(controller="pid"),
                 lambda: default.montecarlo(controller="pid"),
                 lambda: default.montecarlo(samples=0)):
        with pytest.raises(maglevgen.InputError):
            call()


def test_montecarlo_is_the_cli_study(default: maglevgen.Carriage, capsys, tmp_path: Path
                                    ) -> None:
    """The same seed gives the CLI's per-controller results (the timing aside)."""
    opts = dict(samples=6, seed=3, t_end=0.5, workers=1)
    api = default.montecarlo(controller="all", **opts)
    assert main(["montecarlo", "--json", "--controller", "all", "--samples", "6", "--seed",
                 "3", "--t-end", "0.5", "--workers", "1", "--out", str(tmp_path / "mc")]) == 0
    cli = json.loads(capsys.readouterr().out)
    assert api["controllers"] == cli["controllers"]
    assert set(api["controllers"]) == {"none", "damping", "lqr", "coupled", "spec"}


def test_both_array_force_laws_reach_the_api_and_the_study(default: maglevgen.Carriage,
                                                             capsys, tmp_path: Path) -> None:
    """model.array_force = "point" through the API: its trim against the test's root solve of
    eq 3 at the face centres (gaps at the closest corners); its Monte-Carlo study is the CLI's
    and differs from the distributed law's (the choice reaches the workers)."""
    from independent_reference import contact_gaps, reference_trim

    from maglevgen.params import load_params

    law = 'model.array_force="point"'
    point = maglevgen.load(overrides=[law])
    prm = load_params(overrides=[law]).params
    ref = reference_trim(prm, SPEED)
    np.testing.assert_allclose(point.trim(SPEED).gaps, contact_gaps(prm, ref.q), rtol=0,
                               atol=1e-10)
    opts = dict(samples=4, seed=5, t_end=0.3, workers=1)
    api_point = point.montecarlo(controller="coupled", **opts)
    cli = cli_json(capsys, "montecarlo", "--json", "--controller", "coupled", "--samples", "4",
                   "--seed", "5", "--t-end", "0.3", "--workers", "1", "--set", law,
                   "--out", str(tmp_path / "mc"))
    assert api_point["controllers"] == cli["controllers"]
    assert default.montecarlo(controller="coupled", **opts)["controllers"] \
        != api_point["controllers"]


def test_dataframe_without_pandas_says_what_to_install(default: maglevgen.Carriage,
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    run = default.simulate(t_end=0.01)
    monkeypatch.setitem(sys.modules, "pandas", None)  # import pandas now fails
    with pytest.raises(ImportError, match="pip install pandas"):
        run.to_dataframe()


# the physics a docstring describes cites the paper's equations
CITES_PAPER = ("Carriage.trim", "Carriage.gains_report", "Carriage.gains", "Carriage.linearize",
               "Carriage.axis_plant", "Carriage.simulate", "Carriage.generate", "Gains",
               "TrimResult")


# ------------------------------------------------------------- against python-control


def test_linearize_matches_control_linearize_of_the_compiled_dynamics(sim_lib) -> None:
    """Finite differences (python-control's) of the compiled dynamics at the compiled trim."""
    carriage = maglevgen.load()
    p = np.array([e.value for e in flatten(carriage.params)])  # the C's parameter vector
    f = sim_lib.function("maglev_dynamics")
    x0, f_prop = (a.ravel() for a in sim_lib.function("maglev_trim")(SPEED, p))
    n_u = len(carriage.input_names)
    u0 = np.zeros(n_u)
    u0[0] = f_prop[0]
    plant = control.nlsys(lambda t, x, u, params: f(x, u, p)[0].ravel(), None,
                          states=list(carriage.state_names), inputs=list(carriage.input_names),
                          outputs=list(carriage.state_names), name="maglev_dynamics")
    # python-control's forward differences at steps h and h/2, Richardson-extrapolated:
    # O(h^2) (a single step leaves an O(h) error, 1e-4 of a column at h = 1e-6)
    coarse, fine = (control.linearize(plant, x0, u0, eps=h, copy_names=True)
                    for h in (1e-5, 0.5e-5))
    sys = carriage.linearize(SPEED)
    assert sys.state_labels == fine.state_labels == list(carriage.state_names)
    assert sys.input_labels == fine.input_labels == list(carriage.input_names)
    for got, ref in ((sys.A, 2 * fine.A - coarse.A), (sys.B, 2 * fine.B - coarse.B)):
        scale = np.abs(ref).max(axis=0)  # per column: the entries of one derivative
        assert np.all(np.abs(got - ref) <= 1e-6 * scale + 1e-12)
    assert np.array_equal(sys.C, np.eye(12)) and not sys.D.any()
    # the stiffness shows where the paper puts it: heave pulls back, the trim is stable in z
    iz, iw = carriage.state_names.index("z"), carriage.state_names.index("w")
    assert sys.A[iw, iz] < 0


def test_poles_are_the_envelope_poles(default: maglevgen.Carriage) -> None:
    """python-control's feedback of the reduced plant and the API's K gives the envelope's
    largest real part at every speed, for every controller."""
    env = default.envelope(n_speeds=4)
    for i, v in enumerate(env.speeds):
        plant = default.linearize(float(v), model="reduced")
        for controller in names():
            g = default.gains(float(v), controller)
            loop = control.feedback(plant, g.K)  # u = -K x (C = I): A - B K
            poles = loop.poles()
            assert np.max(poles.real) == pytest.approx(env.max_real[controller][i],
                                                       rel=1e-9, abs=1e-12)
            assert np.allclose(np.sort_complex(poles), np.sort_complex(g.poles),
                               rtol=1e-9, atol=1e-12)


def test_gains_are_control_lqr(default: maglevgen.Carriage,
                               capsys: pytest.CaptureFixture[str]) -> None:
    """Per axis: control.lqr on the axis plant; coupled: control.lqr on the reduced plant with
    the per-axis weights put on the axis positions and rates."""
    (q1, q2), r = default.params.control.state_weights, default.params.control.input_weight
    lqr = default.gains(SPEED, "lqr")
    cli = cli_json(capsys, "gains", "--speed", str(SPEED), "--json")
    for i, axis in enumerate(api.AXES):
        K, _, _ = control.lqr(default.axis_plant(axis, SPEED), np.diag([q1, q2]), r)
        got = [lqr.K_pos[i, i], lqr.K_rate[i, i]]
        assert np.allclose(got, K.ravel(), rtol=1e-8)
        # the compiled closed form and the CLI's (Python) closed form
        assert np.allclose(got, cli["axes"][axis]["K_closed_form"], rtol=1e-12)
    assert np.count_nonzero(lqr.K_pos - np.diag(np.diag(lqr.K_pos))) == 0

    full = default.linearize(SPEED)
    reduced = default.linearize(SPEED, model="reduced")
    rows = [full.state_labels.index(s) for s in ("y", "z", "phi", "theta", "psi")]
    cols = [full.state_labels.index(s) for s in reduced.state_labels]
    C_rate = full.A[np.ix_(rows, cols)]  # axis rates from the reduced state (kinematics)
    S = np.eye(5, 10)
    Q = q1 * S.T @ S + q2 * C_rate.T @ C_rate
    K_ref, _, _ = control.lqr(reduced, Q, r * np.eye(5))
    assert np.allclose(default.gains(SPEED, "coupled").K, K_ref, rtol=1e-6, atol=1e-9)


# ----------------------------------------------------------------------- docstrings


def _members(cls: type) -> dict[str, object]:
    """A class's members defined in maglevgen: its own and its bases' there (`Carriage` is
    composed of the API's core, studies and writers), the most derived winning."""
    out: dict[str, object] = {}
    for base in reversed(cls.__mro__):
        if base.__module__.split(".")[0] == "maglevgen":
            out.update(vars(base))
    return out


def _public_names() -> list[tuple[str, object, str]]:
    """(name, object, kind) of every public name of maglevgen.api and of its classes."""
    out: list[tuple[str, object, str]] = []
    for name in api.__all__:
        obj = getattr(api, name)
        if not callable(obj):  # a constant (AXES, STATE_NAMES): nothing to document
            continue
        out.append((name, obj, "class" if inspect.isclass(obj) else "function"))
        if inspect.isclass(obj):
            for attr, member in _members(obj).items():
                if attr.startswith("_"):
                    continue
                if isinstance(member, property):
                    out.append((f"{name}.{attr}", member.fget, "property"))
                elif callable(member):
                    out.append((f"{name}.{attr}", member, "function"))
    return out


def _signature_names(fn: object) -> list[str]:
    return [("*" if p.kind is p.VAR_POSITIONAL else "**" if p.kind is p.VAR_KEYWORD else "")
            + p.name for p in inspect.signature(fn).parameters.values() if p.name != "self"]


def _documented(section: list) -> list[str]:
    return [n.strip() for p in section for n in p.name.split(",")]


PUBLIC = _public_names()


@pytest.mark.parametrize(("name", "obj", "kind"), PUBLIC, ids=[n for n, _, _ in PUBLIC])
def test_docstrings_document_every_parameter(name: str, obj: object, kind: str) -> None:
    """numpydoc's docscrape (as python-control's docstring test): every argument of every
    public function documented in order, a Returns section where something is returned, an
    Examples section; every field of a result class among its Attributes."""
    if name in CITES_PAPER:
        assert re.search(r"\b(eqs?|figs?) \d+", inspect.getdoc(obj) or ""), f"{name}: no eq"
    if kind == "property":
        assert FunctionDoc(obj)["Summary"], f"{name}: no summary"
        return
    doc = ClassDoc(obj) if kind == "class" else FunctionDoc(obj)
    assert doc["Summary"], f"{name}: no summary"
    fields = getattr(obj, "__dataclass_fields__", None)
    if fields is not None:  # a result class: its fields are its attributes
        assert list(fields) == _documented(doc["Attributes"]), f"{name}: attributes"
        return
    fn = obj.__init__ if kind == "class" else obj
    assert _documented(doc["Parameters"]) == _signature_names(fn), f"{name}: parameters"
    assert doc["Examples"], f"{name}: no Examples section"
    if kind == "function" and inspect.signature(obj).return_annotation != "None":
        assert doc["Returns"], f"{name}: no Returns section"
    assert doc["Raises"] or name.startswith(("TrimResult", "EnvelopeResult")), \
        f"{name}: no Raises section"


@pytest.mark.slow  # the examples build, export an FMU and a firmware folder: minutes
def test_docstring_examples_run() -> None:
    """Every Examples section in maglevgen/api/ runs (the report's only where TeX does:
    skipped, see its docstring)."""
    attempted = 0
    for module in API_MODULES:
        res = doctest.testmod(module,
                              optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
        assert res.failed == 0, module.__name__
        attempted += res.attempted
    assert attempted >= 40


def test_the_examples_are_found_in_every_module_of_the_api() -> None:
    """The modules the examples test runs hold every example of the package (a doctest
    finder reads a module's own objects only)."""
    names = {f"maglevgen.api.{p.stem}" for p in Path(api.__file__).parent.glob("*.py")}
    assert {m.__name__ for m in API_MODULES} == names - {"maglevgen.api.__init__"} | {
        "maglevgen.api"}
    finder = doctest.DocTestFinder()
    found = {t.name.rsplit(".", 1)[-1] for m in API_MODULES for t in finder.find(m)
             if t.examples}
    assert {"load", "Carriage", "trim", "simulate", "fmu", "to_dataframe"} <= found


def test_public_names_are_exported_lazily() -> None:
    import subprocess

    code = ("import sys, maglevgen; assert 'maglevgen.api' not in sys.modules; "
            "assert 'numpy' not in sys.modules; c = maglevgen.Carriage; "
            "assert c is __import__('maglevgen.api').api.Carriage; "
            "print(sorted(set(maglevgen.__all__) - set(dir(maglevgen))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip() == "[]"
