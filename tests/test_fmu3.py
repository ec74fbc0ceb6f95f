"""`maglevgen fmu --fmi 3`: the FMI 3.0 FMU, checked with FMPy as the client.

References: FMPy's FMI 3.0 validator (its schema and rules) and solvers (CVode),
`maglevgen simulate`'s run in the compiled simulation library, scipy's DOP853 on the
lambdified SymPy model (reference_trajectory), the parameter file read with tomllib, the
conventions' state units, and SymPy's SI dimension system (sympy.physics.units) for the FMI
3.0 unit definitions.
"""

from __future__ import annotations

import re
import subprocess
import sys
import zipfile
from pathlib import Path
from xml.etree import ElementTree

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from fmpy.validation import validate_fmu

from maglevgen.analyses.reference import reference_trajectory
from maglevgen.analyses.simulate import AXIS_STATES, DISTURBANCE, run_scenarios
from maglevgen.carriage import DerivedCarriage
from maglevgen.control.built_loop import Loop
from maglevgen.control.carriage_plant import Plant
from maglevgen.derive import conventions as cv
from maglevgen.exports.fmu import FMI_VERSIONS, build_fmu

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

REPO = Path(__file__).resolve().parents[1]
STATES = [s.name for s in cv.STATES]
pytestmark = pytest.mark.needs_cc


@pytest.fixture(scope="module")
def fmus(tmp_path_factory, carriage: DerivedCarriage, sim_lib):
    """FMI 3.0 FMUs of the default carriage by kind and controller, built on first use."""
    folder = tmp_path_factory.mktemp("fmu3")
    made: dict[tuple[str, str], Path] = {}

    def get(kind: str, controller: str = "lqr") -> Path:
        if (kind, controller) not in made:
            path = folder / f"{kind}_{controller}.fmu"
            path.write_bytes(build_fmu(Plant(carriage), kind, controller, fmi="3",
                                             loop=Loop.CONTINUOUS))
            made[kind, controller] = path
        return made[kind, controller]

    return get


def _states(res) -> np.ndarray:
    return np.column_stack([res[n] for n in STATES])


def _assert_close(x: np.ndarray, ref: np.ndarray, rtol: float) -> None:
    """Each state within rtol of its largest magnitude over the run."""
    scale = np.maximum(np.abs(ref).max(axis=0), 1e-300)
    worst = (np.abs(x - ref) / scale).max(axis=0)
    assert np.all(worst <= rtol), dict(zip(STATES, worst, strict=True))


@pytest.mark.parametrize("kind", ["me", "cs", "both"])
def test_fmpy_validates_the_fmi3_fmu(fmus, kind: str) -> None:
    path = fmus(kind)
    assert validate_fmu(str(path)) == []
    md = read_model_description(str(path))
    assert md.fmiVersion == "3.0"
    assert (md.modelExchange is not None) == (kind in ("me", "both"))
    assert (md.coSimulation is not None) == (kind in ("cs", "both"))
    with zipfile.ZipFile(path) as zf:
        names = set(zf.namelist())
        build = ElementTree.fromstring(zf.read("sources/buildDescription.xml"))
    assert "binaries/x86_64-linux/maglev.so" in names  # FMI 3.0's platform tuple
    listed = {f"sources/{e.get('name')}" for e in build.iter("SourceFile")}
    assert listed <= names and "sources/maglev_fmu.c" in listed
    assert not any(re.search(r"fmi[23]\w*\.h$", n) for n in names)  # headers stay FMPy's


def test_variables_start_values_and_units(fmus) -> None:
    md = read_model_description(str(fmus("both")))
    var = {v.name: v for v in md.modelVariables}
    raw = tomllib.loads((REPO / "maglevgen" / "carriage_llnl.toml").read_text())
    assert float(var["vehicle.mass"].start) == raw["vehicle"]["mass"]
    assert var["vehicle.mass"].unit == "kg" and var["vehicle.mass"].variability == "fixed"
    assert var["track.min_gap"].variability == "tunable"
    assert float(var["operation.speed"].start) == raw["operation"]["speed"]
    for s in cv.STATES:
        assert var[s.name].unit == s.unit and var[s.name].type == "Float64"
        assert var[f"der({s.name})"].derivative is var[s.name]
        assert float(var[f"disturbance.{s.name}"].start) == DISTURBANCE.get(s.name, 0.0)
    assert [u.variable.name for u in md.derivatives] == [f"der({s})" for s in STATES]
    assert {v.name for v in md.modelVariables if v.causality == "input"} == {
        "dF_prop", "ref.y", "ref.z", "ref.phi", "ref.theta", "ref.psi"}
    (time,) = [v for v in md.modelVariables if v.causality == "independent"]
    assert time.name == "time" and time.unit == "s"
    refs = [v.valueReference for v in md.modelVariables]
    assert refs == list(range(len(refs)))


def _sympy_dimensions(unit: str) -> dict[str, int]:
    """The unit's SI dimensions from SymPy, plus the radian's exponent (SymPy counts angles
    as dimensionless; FMI keeps rad as a base unit)."""
    import sympy
    from sympy.physics import units as su
    from sympy.physics.units.systems.si import SI, dimsys_SI

    names = {"kg": su.kilogram, "m": su.meter, "s": su.second, "N": su.newton, "ohm": su.ohm,
             "H": su.henry, "T": su.tesla, "rad": su.radian, "A": su.ampere}
    expr = 1 if unit in ("1", "-") else sympy.sympify(unit.replace("^", "**"), locals=names)
    dims = dimsys_SI.get_dimensional_dependencies(SI.get_dimensional_expr(expr))
    base = {"mass": "kg", "length": "m", "time": "s", "current": "A"}
    out = {base[d.name.name]: int(e) for d, e in dims.items()}
    rad = sum((-1 if sign == "/" else 1) * int(exp or 1)
              for sign, exp in re.findall(r"(^|[*/])rad(?:\^(-?\d+))?", unit))
    if rad:
        out["rad"] = rad
    return out


def test_unit_definitions_are_the_si_dimensions(fmus) -> None:
    md = read_model_description(str(fmus("both")))
    used = {v.unit for v in md.modelVariables}
    defined = {u.name: u for u in md.unitDefinitions}
    assert used <= set(defined)
    assert {"kg", "m", "m/s", "rad/s", "N", "kg*m^2", "ohm", "H", "T"} <= used
    for name, unit in defined.items():
        got = {k: int(getattr(unit.baseUnit, k)) for k in
               ("kg", "m", "s", "A", "K", "mol", "cd", "rad") if getattr(unit.baseUnit, k)}
        assert got == _sympy_dimensions(name), name


def test_cs_reproduces_maglevgen_simulate(fmus, carriage: DerivedCarriage, sim_lib) -> None:
    """Same RK4 arithmetic as `maglevgen simulate`: the trajectory bit for bit, at one
    internal step per communication step and at ten."""
    ref = run_scenarios(Plant(carriage, sim_lib), ("lqr",), 1.0, 1e-3).trajectories[0]
    res = simulate_fmu(str(fmus("both")), fmi_type="CoSimulation", stop_time=1.0,
                       output_interval=1e-3, output=STATES)
    assert np.array_equal(res["time"], ref.t)
    assert np.array_equal(_states(res), ref.x)
    res10 = simulate_fmu(str(fmus("both")), fmi_type="CoSimulation", stop_time=1.0,
                         output_interval=1e-2, output=STATES)
    assert np.array_equal(_states(res10), ref.x[::10])


@pytest.mark.parametrize("controller", ["damping", "none"])
def test_cs_other_controllers_reproduce_maglevgen_simulate(fmus, carriage: DerivedCarriage, sim_lib,
                                                           controller: str) -> None:
    ref = run_scenarios(Plant(carriage, sim_lib), (controller,), 0.3, 1e-3).trajectories[0]
    res = simulate_fmu(str(fmus("cs", controller)), fmi_type="CoSimulation", stop_time=0.3,
                       output_interval=1e-3, output=STATES)
    assert np.array_equal(_states(res), ref.x)


def test_external_controller_with_zero_forces_is_the_open_loop(fmus, carriage: DerivedCarriage,
                                                               sim_lib, op) -> None:
    md = read_model_description(str(fmus("cs", "external")))
    assert {v.name for v in md.modelVariables if v.causality == "input"} == {
        "dF_prop", *(c.name for c in cv.CONTROLS)}
    ref = run_scenarios(Plant(carriage, sim_lib), ("none",), 0.3, 1e-3).trajectories[0]
    res = simulate_fmu(str(fmus("cs", "external")), fmi_type="CoSimulation", stop_time=0.3,
                       output_interval=1e-3, output=STATES)
    _assert_close(_states(res), ref.x, 1e-9)
    push = simulate_fmu(str(fmus("cs", "external")), fmi_type="CoSimulation", stop_time=0.3,
                        output_interval=1e-3, output=["z", "F_z3"], start_values={"u_z": 5.0})
    assert push["F_z3"][0] == pytest.approx(5.0 * op.allocation[4, 1], rel=1e-12)


@pytest.mark.slow  # CVode and DOP853 runs (the FMI 2.0 twin stays in the default run)
def test_me_with_cvode_agrees_with_dop853_on_the_sympy_model(fmus, carriage: DerivedCarriage,
                                                             op) -> None:
    t_end, rtol = 0.5, 1e-10
    res = simulate_fmu(str(fmus("me")), fmi_type="ModelExchange", solver="CVode",
                       relative_tolerance=rtol, stop_time=t_end, output_interval=1e-3,
                       output=STATES, record_events=False)
    ref = reference_trajectory(carriage.functions, carriage.p, op, "lqr", res["time"])
    x = _states(res)
    idx = list(AXIS_STATES)
    peak = np.abs(ref[:, idx] - op.a_trim).max(axis=0)
    dev = np.abs(x[:, idx] - ref[:, idx]).max(axis=0)
    assert np.all(dev <= 1e-5 * peak), dev / peak
    _assert_close(x, ref, 1e-6)


def test_contact_ends_the_cs_run_where_maglevgen_simulate_ends_it(fmus, carriage, sim_lib,
                                                                   op) -> None:
    from maglevgen.analyses.simulate import simulate

    push = {**DISTURBANCE, "w": -1.0}
    ref = simulate(sim_lib, carriage.p, op, "lqr", 0.5, 1e-3, carriage.params.track.min_gap,
                   disturbance=push)
    assert ref.status == "contact"
    messages: list[str] = []
    res = simulate_fmu(str(fmus("both")), fmi_type="CoSimulation", stop_time=0.5,
                       output_interval=1e-3, output=STATES,
                       start_values={"disturbance.w": -1.0},
                       logger=lambda *a: messages.append(a[-1].decode()))
    assert res["time"][-1] == pytest.approx(ref.t[-1], abs=1e-12)
    _assert_close(_states(res), ref.x, 1e-12)
    assert any(m.startswith("contact at t = ") for m in messages)


def test_errors_are_status_codes_with_a_message(fmus) -> None:
    from fmpy import extract
    from fmpy.fmi1 import FMICallException
    from fmpy.fmi3 import FMU3Slave

    messages: list[str] = []
    with pytest.raises(FMICallException, match="fmi3ExitInitializationMode"):
        simulate_fmu(str(fmus("both")), fmi_type="CoSimulation", stop_time=0.01,
                     start_values={"operation.speed": 0.1},
                     logger=lambda *a: messages.append(a[-1].decode()))
    assert any("no trim at 0.1 m/s" in m for m in messages)

    path = fmus("both")
    md = read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    messages.clear()
    fmu = FMU3Slave(guid=md.guid, unzipDirectory=extract(str(path)),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="x")
    fmu.instantiate(logMessage=lambda env, status, cat, msg: messages.append(msg.decode()))
    with pytest.raises(FMICallException):  # a NaN is refused, and changes nothing
        fmu.setFloat64([vr["vehicle.mass"], vr["dF_prop"]], [9.0, float("nan")])
    assert any("not a finite number" in m for m in messages)
    assert fmu.getFloat64([vr["vehicle.mass"]]) == [9.3]  # the error state keeps the getters
    with pytest.raises(FMICallException):  # and refuses the rest until a reset
        fmu.enterInitializationMode(startTime=0.0)
    fmu.reset()
    fmu.enterInitializationMode(startTime=0.0)
    fmu.exitInitializationMode()
    fmu.setFloat64([vr["track.min_gap"]], [0.001])  # tunable
    with pytest.raises(FMICallException):
        fmu.setFloat64([vr["vehicle.mass"]], [10.0])
    assert any("fixed parameter" in m for m in messages)
    fmu.reset()
    fmu.enterInitializationMode(startTime=0.0)
    fmu.exitInitializationMode()
    with pytest.raises(FMICallException):  # 1.5 internal steps
        fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=1.5e-3)
    assert any("not a multiple of rk4_step" in m for m in messages)
    fmu.freeInstance()


@pytest.mark.slow  # the CLI verifies the embedded controller before it writes: ~200 s loaded
def test_cli_writes_fmi3_with_the_embedded_controller(tmp_path: Path, carriage: DerivedCarriage,
                                                     sim_lib) -> None:
    """The default controller is the one the firmware embeds, run as the firmware runs it on
    the exact state (--loop firmware; the default, on the sensors, is test_fmu_sensed.py's):
    the CLI's FMU follows the host's firmware loop of that controller
    (`run_scenarios(loop="firmware")`: its design at the tick, the speed loop, the budget, the
    actuator lag) bit for bit."""
    out = tmp_path / "out"
    ok = subprocess.run([sys.executable, "-m", "maglevgen.cli", "fmu", "--fmi", "3", "--kind",
                         "cs", "--loop", "firmware", "--out", str(out)], capture_output=True,
                        text=True)
    assert ok.returncode == 0, ok.stderr
    embedded = carriage.params.envelope.embedded_controller
    assert "FMI 3.0" in ok.stdout and f"controller {embedded}" in ok.stdout
    assert read_model_description(str(out / "maglev.fmu")).fmiVersion == "3.0"
    # the FMU's firmware loop: the loop as built (the design at the tick, the speed loop and
    # its integral, the budget, the actuator lag), as `maglevgen simulate --loop firmware`
    ref = run_scenarios(Plant(carriage, sim_lib), (embedded,), 0.5, 1e-3,
                        loop=Loop.FIRMWARE).trajectories[0]
    res = simulate_fmu(str(out / "maglev.fmu"), fmi_type="CoSimulation", stop_time=0.5,
                       output_interval=1e-3, output=STATES)
    assert np.array_equal(_states(res), ref.x)
    bad = subprocess.run([sys.executable, "-m", "maglevgen.cli", "fmu", "--fmi", "4", "--out",
                          str(out)], capture_output=True, text=True)
    assert bad.returncode == 2 and "--fmi" in bad.stderr
    assert tuple(FMI_VERSIONS) == ("2", "3")


def test_instantiate_free_1000_times_without_a_leak(fmus, tmp_path: Path) -> None:
    """A C driver built with AddressSanitizer dlopen()s the FMI 3.0 binary (which allocates
    with calloc: FMI 3.0 passes no allocator); LeakSanitizer must find nothing left."""
    import shutil

    from maglevgen.exports.fmu import fmi_headers

    cc = shutil.which("gcc") or shutil.which("clang")
    assert cc is not None, "a C compiler is needed (the FMU itself is compiled with one)"
    path = fmus("both")
    md = read_model_description(str(path))
    with zipfile.ZipFile(path) as zf:
        zf.extractall(tmp_path / "fmu")
    exe = tmp_path / "driver"
    subprocess.run([cc, "-std=c99", "-g", "-fsanitize=address", f"-I{fmi_headers('3')}",
                    str(REPO / "tests" / "c" / "fmu3_leak_driver.c"), "-o", str(exe), "-ldl"],
                   check=True, capture_output=True)
    proc = subprocess.run([str(exe), str(tmp_path / "fmu/binaries/x86_64-linux/maglev.so"),
                           md.guid, "1000"], capture_output=True, text=True,
                          env={"ASAN_OPTIONS": "detect_leaks=1", "PATH": "/usr/bin:/bin"})
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "instances 1000" in proc.stdout
    assert "LeakSanitizer" not in proc.stderr


def test_build_description_rebuilds_the_binary(fmus, tmp_path: Path) -> None:
    """sources/buildDescription.xml's files and FMPy's FMI 3.0 headers are enough: the rebuilt
    binary (-O0: quick; the same IEEE arithmetic on x86-64) gives the shipped trajectory."""
    import shutil

    from maglevgen.exports.fmu import fmi_headers

    path = fmus("cs")
    unzipped = tmp_path / "fmu"
    with zipfile.ZipFile(path) as zf:
        zf.extractall(unzipped)
    build = ElementTree.parse(unzipped / "sources" / "buildDescription.xml").getroot()
    files = [e.get("name") for e in build.iter("SourceFile")]
    libs = [f"-l{e.get('name')}" for e in build.iter("Library")]
    lib = unzipped / "binaries" / "x86_64-linux" / "maglev.so"
    shipped = simulate_fmu(str(unzipped), stop_time=0.05, output_interval=1e-3, output=STATES)
    lib.unlink()
    cc = shutil.which("gcc") or shutil.which("clang")
    subprocess.run([cc, "-std=c99", "-O0", "-fPIC", "-shared", f"-I{fmi_headers('3')}",
                    *[str(unzipped / "sources" / f) for f in files], "-o", str(lib), *libs],
                   check=True, capture_output=True)
    rebuilt = simulate_fmu(str(unzipped), stop_time=0.05, output_interval=1e-3, output=STATES)
    _assert_close(_states(rebuilt), _states(shipped), 1e-12)


def test_hostile_times_steps_and_states_are_refused(fmus) -> None:
    """The FMI 2.0 wrapper's refusals (tests/test_failsafe.py) on the FMI 3.0 path: a NaN,
    infinite, negative, zero or huge communication step or a non-finite communication point
    (co-simulation), and a non-finite state through fmi3SetContinuousStates (model exchange),
    are error statuses with a message; after each refused step the instance still steps, with
    every state finite (the reference: math.isfinite, and FMPy's raise on an error status)."""
    import ctypes
    import math

    from fmpy import extract
    from fmpy.fmi1 import FMICallException
    from fmpy.fmi3 import FMU3Model, FMU3Slave

    path = fmus("both")
    md = read_model_description(str(path))
    states = [v.valueReference for v in md.modelVariables if v.name in STATES]
    messages: list[str] = []
    log = lambda env, status, cat, msg: messages.append(msg.decode())  # noqa: E731
    cs = FMU3Slave(guid=md.guid, unzipDirectory=extract(str(path)),
                   modelIdentifier=md.coSimulation.modelIdentifier, instanceName="cs")
    cs.instantiate(logMessage=log)
    nan, inf = float("nan"), float("inf")
    for t, h in [(0.0, nan), (0.0, inf), (0.0, -inf), (0.0, -1e-3), (0.0, 0.0), (0.0, 1e300),
                 (nan, 1e-3), (inf, 1e-3), (-inf, 1e-3)]:
        cs.reset()  # each refusal leaves the error state
        cs.enterInitializationMode(startTime=0.0)
        cs.exitInitializationMode()
        messages.clear()
        with pytest.raises(FMICallException):
            cs.doStep(currentCommunicationPoint=t, communicationStepSize=h)
        assert messages, (t, h)
    cs.reset()
    cs.enterInitializationMode(startTime=0.0)
    cs.exitInitializationMode()
    cs.doStep(currentCommunicationPoint=0.0, communicationStepSize=1e-3)
    assert all(math.isfinite(x) for x in cs.getFloat64(states))
    cs.terminate()
    cs.freeInstance()

    me = FMU3Model(guid=md.guid, unzipDirectory=extract(str(path)),
                   modelIdentifier=md.modelExchange.modelIdentifier, instanceName="me")
    me.instantiate(logMessage=log)
    n = len(states)
    vec = ctypes.c_double * n
    good, dx = vec(), vec()
    for value in (nan, inf, -inf):
        me.reset()  # each refusal leaves the error state
        me.enterInitializationMode(startTime=0.0)
        me.exitInitializationMode()
        me.enterContinuousTimeMode()
        me.getContinuousStates(good, n)
        messages.clear()
        with pytest.raises(FMICallException):
            me.setContinuousStates(vec(*[value] * n), n)
        assert any("not finite" in m for m in messages), value
        me.getContinuousStateDerivatives(dx, n)  # the error state's getters: the states
        assert all(math.isfinite(x) for x in dx) and all(math.isfinite(x) for x in good)
    me.freeInstance()
