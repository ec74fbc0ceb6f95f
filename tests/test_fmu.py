"""`maglevgen fmu`: the FMI 2.0 FMU, checked with FMPy as the independent client.

References: FMPy's validator and solvers (CVode), `maglevgen simulate`'s run in the compiled
simulation library, scipy's DOP853 on the lambdified SymPy model, the parameter file read
with tomllib, and AddressSanitizer's leak checker on a C driver that dlopen()s the binary.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from fmpy.validation import validate_fmu

from maglevgen.analyses.reference import reference_trajectory
from maglevgen.analyses.simulate import AXIS_STATES, run_scenarios
from maglevgen.carriage import DerivedCarriage
from maglevgen.control.built_loop import Loop
from maglevgen.control.carriage_plant import Plant
from maglevgen.derive import conventions as cv
from maglevgen.exports.fmu import build_fmu, fmi_headers, fmu_controllers
from maglevgen.params import load_params

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

REPO = Path(__file__).resolve().parents[1]
STATES = [s.name for s in cv.STATES]


@pytest.fixture(scope="module")
def fmus(tmp_path_factory, carriage: DerivedCarriage, sim_lib):
    """FMUs of the default carriage by (kind, controller), built on first use."""
    folder = tmp_path_factory.mktemp("fmu")
    made: dict[tuple[str, str], Path] = {}

    def get(kind: str, controller: str = "lqr") -> Path:
        if (kind, controller) not in made:
            path = folder / f"{kind}_{controller}.fmu"
            path.write_bytes(build_fmu(Plant(carriage), kind, controller,
                                             loop=Loop.CONTINUOUS))
            made[kind, controller] = path
        return made[kind, controller]

    return get


def _states(res) -> np.ndarray:
    return np.column_stack([res[n] for n in STATES])


def _assert_close(x: np.ndarray, ref: np.ndarray, rtol: float) -> None:
    """Each state within rtol of its largest magnitude over the run (states near zero, such
    as the lateral ones, cannot be compared pointwise relative to themselves)."""
    scale = np.maximum(np.abs(ref).max(axis=0), 1e-300)
    worst = (np.abs(x - ref) / scale).max(axis=0)
    assert np.all(worst <= rtol), dict(zip(STATES, worst, strict=True))


@pytest.mark.parametrize("kind", ["me", "cs", "both"])
def test_fmpy_validates_the_fmu(fmus, kind: str) -> None:
    path = fmus(kind)
    assert validate_fmu(str(path)) == []
    md = read_model_description(str(path))
    assert (md.modelExchange is not None) == (kind in ("me", "both"))
    assert (md.coSimulation is not None) == (kind in ("cs", "both"))
    with zipfile.ZipFile(path) as zf:
        names = set(zf.namelist())
    assert "binaries/linux64/maglev.so" in names
    files = md.buildConfigurations[0].sourceFileSets[0].sourceFiles
    listed = {f"sources/{f}" for f in files}
    assert listed <= names and "sources/maglev_fmu.c" in listed
    assert not any(n.endswith("fmi2Functions.h") for n in names)  # headers stay FMPy's


def test_variables_come_from_the_parameter_file_and_the_conventions(fmus) -> None:
    md = read_model_description(str(fmus("both")))
    var = {v.name: v for v in md.modelVariables}
    raw = tomllib.loads((REPO / "maglevgen" / "carriage_llnl.toml").read_text())
    assert float(var["vehicle.mass"].start) == raw["vehicle"]["mass"]
    assert var["vehicle.mass"].unit == "kg" and var["vehicle.mass"].variability == "fixed"
    assert var["track.min_gap"].variability == "tunable"
    assert float(var["operation.speed"].start) == raw["operation"]["speed"]
    for s in cv.STATES:
        assert var[s.name].unit == s.unit and var[f"der({s.name})"].derivative is var[s.name]
    assert [u.variable.name for u in md.derivatives] == [f"der({s})" for s in STATES]
    assert {v.name for v in md.modelVariables if v.causality == "input"} == {
        "dF_prop", "ref.y", "ref.z", "ref.phi", "ref.theta", "ref.psi"}
    refs = [v.valueReference for v in md.modelVariables]
    assert refs == list(range(len(refs)))


@pytest.mark.parametrize("controller", ["lqr", "coupled", "damping"])
def test_cs_reproduces_maglevgen_simulate(fmus, carriage: DerivedCarriage, sim_lib,
                                          controller: str) -> None:
    """The CS FMU with a built-in controller against `maglevgen simulate` at the same step
    (the coupled LQR's full 5 x 5 gains, the others' diagonal ones)."""
    run = run_scenarios(Plant(carriage, sim_lib), (controller,), 1.0, 1e-3)
    ref = run.trajectories[0]
    res = simulate_fmu(str(fmus("cs", controller)), fmi_type="CoSimulation", stop_time=1.0,
                       output_interval=1e-3, output=STATES)
    assert np.allclose(res["time"], ref.t, rtol=0, atol=1e-12)
    _assert_close(_states(res), ref.x, 1e-9)
    # a communication step of ten internal steps lands on every tenth sample
    res10 = simulate_fmu(str(fmus("cs", controller)), fmi_type="CoSimulation", stop_time=1.0,
                         output_interval=1e-2, output=STATES)
    _assert_close(_states(res10), ref.x[::10], 1e-9)


def test_me_with_cvode_agrees_with_solve_ivp_on_the_sympy_model(fmus, carriage: DerivedCarriage,
                                                                op) -> None:
    t_end, rtol = 0.5, 1e-10
    res = simulate_fmu(str(fmus("me")), fmi_type="ModelExchange", solver="CVode",
                       relative_tolerance=rtol, stop_time=t_end, output_interval=1e-3,
                       output=STATES, record_events=False)
    ref = reference_trajectory(carriage.functions, carriage.p, op, "lqr", res["time"])
    x = _states(res)
    # the disturbance's response, relative to its peak: CVode's local error control at rtol
    # (absolute tolerance rtol times the unit nominals) accumulates over some 10^3 steps
    idx = list(AXIS_STATES)
    peak = np.abs(ref[:, idx] - op.a_trim).max(axis=0)
    dev = np.abs(x[:, idx] - ref[:, idx]).max(axis=0)
    assert np.all(dev <= 1e-5 * peak), dev / peak
    _assert_close(x, ref, 1e-6)


def test_mass_set_through_fmpy_equals_set_on_the_command_line(fmus, sim_lib) -> None:
    heavy = DerivedCarriage(load_params(None, ["vehicle.mass=10.5"]))
    ref = run_scenarios(Plant(heavy, sim_lib), ("lqr",), 0.5, 1e-3).trajectories[0]
    res = simulate_fmu(str(fmus("cs")), fmi_type="CoSimulation", stop_time=0.5,
                       output_interval=1e-3, output=STATES,
                       start_values={"vehicle.mass": 10.5})
    _assert_close(_states(res), ref.x, 1e-9)
    default = simulate_fmu(str(fmus("cs")), fmi_type="CoSimulation", stop_time=0.5,
                           output_interval=1e-3, output=STATES)
    assert np.abs(_states(default)[:, 2] - ref.x[:, 2]).max() > 1e-4  # the mass matters


def test_fixed_parameter_after_initialization_is_an_error(fmus) -> None:
    from ctypes import byref

    from fmpy import calloc, extract, free
    from fmpy.fmi1 import FMICallException
    from fmpy.fmi2 import (
        FMU2Slave,
        fmi2CallbackAllocateMemoryTYPE,
        fmi2CallbackFreeMemoryTYPE,
        fmi2CallbackFunctions,
        fmi2CallbackLoggerTYPE,
    )
    from fmpy.logging import addLoggerProxy

    path = fmus("cs")
    md = read_model_description(str(path))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    messages: list[str] = []
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(path)),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="x")
    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(lambda *a: messages.append(a[-1].decode()))
    cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    addLoggerProxy(byref(cb))
    fmu.instantiate(callbacks=cb)
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    fmu.setReal([vr["track.min_gap"]], [0.001])  # tunable
    with pytest.raises(FMICallException):
        fmu.setReal([vr["vehicle.mass"]], [10.0])
    assert any("fixed parameter" in m for m in messages)
    with pytest.raises(FMICallException):  # the error state: refused until a reset
        fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=1e-3)
    fmu.reset()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    with pytest.raises(FMICallException):  # 1.5 internal steps
        fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=1.5e-3)
    assert any("not a multiple of rk4_step" in m for m in messages)
    fmu.freeInstance()


def test_no_trim_is_an_error_through_the_logger(fmus) -> None:
    messages: list[str] = []
    with pytest.raises(Exception, match="fmi2ExitInitializationMode"):
        simulate_fmu(str(fmus("cs")), fmi_type="CoSimulation", stop_time=0.01,
                     start_values={"operation.speed": 0.1},
                     logger=lambda *a: messages.append(a[-1].decode()))
    assert any("no trim at 0.1 m/s" in m for m in messages)


def test_contact_ends_the_run_where_maglevgen_simulate_ends_it(fmus, carriage, sim_lib,
                                                                op) -> None:
    from maglevgen.analyses.simulate import DISTURBANCE, simulate

    push = {**DISTURBANCE, "w": -1.0}  # 1 m/s towards array 3: it touches the track
    ref = simulate(sim_lib, carriage.p, op, "none", 0.5, 1e-3, carriage.params.track.min_gap,
                   disturbance=push)
    assert ref.status == "contact"
    messages: list[str] = []
    res = simulate_fmu(str(fmus("cs", "none")), fmi_type="CoSimulation", stop_time=0.5,
                       output_interval=1e-3, output=STATES,
                       start_values={"disturbance.w": -1.0},
                       logger=lambda *a: messages.append(a[-1].decode()))
    assert res["time"][-1] == pytest.approx(ref.t[-1], abs=1e-12)
    _assert_close(_states(res), ref.x, 1e-9)
    assert any(m.startswith("contact at t = ") for m in messages)


def test_external_controller_takes_the_generalized_forces(fmus, carriage, sim_lib, op) -> None:
    """With u_gen = 0 and no references the external FMU is the open loop ("none")."""
    md = read_model_description(str(fmus("cs", "external")))
    assert {v.name for v in md.modelVariables if v.causality == "input"} == {
        "dF_prop", *(c.name for c in cv.CONTROLS)}
    ref = run_scenarios(Plant(carriage, sim_lib), ("none",), 0.3, 1e-3).trajectories[0]
    res = simulate_fmu(str(fmus("cs", "external")), fmi_type="CoSimulation", stop_time=0.3,
                       output_interval=1e-3, output=STATES)
    _assert_close(_states(res), ref.x, 1e-9)
    # a constant heave force moves the carriage the way T u_z does in the model
    push = simulate_fmu(str(fmus("cs", "external")), fmi_type="CoSimulation", stop_time=0.3,
                        output_interval=1e-3, output=["z", "F_z3"],
                        start_values={"u_z": 5.0})
    assert push["F_z3"][0] == pytest.approx(5.0 * op.allocation[4, 1], rel=1e-12)


def test_controllers_are_one_table() -> None:
    from maglevgen.cli import build_parser

    sub = next(a for a in build_parser()._subparsers._group_actions)
    fmu = sub.choices["fmu"]
    opt = next(a for a in fmu._actions if "--controller" in a.option_strings)
    assert tuple(opt.choices) == tuple(fmu_controllers())


def test_instantiate_free_1000_times_without_a_leak(fmus, tmp_path: Path) -> None:
    """A C driver built with AddressSanitizer dlopen()s the binary; LeakSanitizer and the
    driver's own count of the callbacks' allocations must both find nothing left."""
    cc = shutil.which("gcc") or shutil.which("clang")
    assert cc is not None, "a C compiler is needed (the FMU itself is compiled with one)"
    path = fmus("cs")
    md = read_model_description(str(path))
    with zipfile.ZipFile(path) as zf:
        zf.extractall(tmp_path / "fmu")
    exe = tmp_path / "driver"
    subprocess.run([cc, "-std=c99", "-g", "-fsanitize=address", f"-I{fmi_headers()}",
                    str(REPO / "tests" / "c" / "fmu_leak_driver.c"), "-o", str(exe), "-ldl"],
                   check=True, capture_output=True)
    proc = subprocess.run([str(exe), str(tmp_path / "fmu/binaries/linux64/maglev.so"),
                           md.guid, "1000"], capture_output=True, text=True,
                          env={"ASAN_OPTIONS": "detect_leaks=1", "PATH": "/usr/bin:/bin"})
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "instances 1000 allocations 2000 live 0" in proc.stdout
    assert "LeakSanitizer" not in proc.stderr


def test_cli_writes_the_fmu_and_rejects_bad_input(tmp_path: Path, sim_lib) -> None:
    out = tmp_path / "out"
    ok = subprocess.run([sys.executable, "-m", "maglevgen.cli", "fmu", "--kind", "me",
                         "--controller", "damping", "--out", str(out)],
                        capture_output=True, text=True)
    assert ok.returncode == 0, ok.stderr
    assert validate_fmu(str(out / "maglev.fmu")) == []
    bad = subprocess.run([sys.executable, "-m", "maglevgen.cli", "fmu", "--out", str(out),
                          "--set", "operation.speed=0.1"], capture_output=True, text=True)
    assert bad.returncode == 2
    assert len(bad.stderr.strip().splitlines()) == 1 and "no trim at 0.1" in bad.stderr
    assert validate_fmu(str(out / "maglev.fmu")) == []  # the good output is kept


@pytest.mark.slow  # the FMU rebuilt from its sources
def test_sources_rebuild_the_binary(fmus, tmp_path: Path) -> None:
    """The listed sources and FMPy's headers are enough: the rebuilt binary, put in place of
    the shipped one, gives the same trajectory."""
    path = fmus("cs")
    md = read_model_description(str(path))
    unzipped = tmp_path / "fmu"
    with zipfile.ZipFile(path) as zf:
        zf.extractall(unzipped)
    files = md.buildConfigurations[0].sourceFileSets[0].sourceFiles
    lib = unzipped / "binaries" / "linux64" / "maglev.so"
    shipped = simulate_fmu(str(unzipped), stop_time=0.05, output_interval=1e-3, output=STATES)
    lib.unlink()
    cc = shutil.which("gcc") or shutil.which("clang")
    subprocess.run([cc, "-std=c99", "-O2", "-fPIC", "-shared", f"-I{fmi_headers()}",
                    *[str(unzipped / "sources" / f) for f in files], "-o", str(lib), "-lm"],
                   check=True, capture_output=True)
    rebuilt = simulate_fmu(str(unzipped), stop_time=0.05, output_interval=1e-3, output=STATES)
    _assert_close(_states(rebuilt), _states(shipped), 1e-12)


@pytest.mark.slow  # an FMU of the normal-actuator carriage
def test_normal_actuators_fmu_reproduces_maglevgen_simulate(tmp_path: Path) -> None:
    """control.actuators = "normal" (one force along each array's normal): the FMU (both
    kinds) passes FMPy's validator, outputs one force per array (F_n1..F_n6), and its
    co-simulation with the built-in LQR follows `maglevgen simulate` on the same carriage,
    states and array forces. Over 0.5 s only: with normal actuators the roll about the
    normals' crossing line is barely controlled (slowest linearised mode about -0.005 1/s)
    and under the hold's drifting speed the LQR run reaches the track within 20 s; the two
    must agree on the drift too."""
    from maglevgen.runtime.library import simulation_library

    normal = DerivedCarriage(load_params(overrides=['control.actuators="normal"']))
    lib = simulation_library(normal.structure)
    path = tmp_path / "normal.fmu"
    path.write_bytes(build_fmu(Plant(normal), "both", "lqr", loop=Loop.CONTINUOUS))
    assert validate_fmu(str(path)) == []
    md = read_model_description(str(path))
    forces = [f"F_n{i}" for i in range(1, 7)]
    outputs = {v.name for v in md.modelVariables if v.causality == "output"}
    assert {"F_prop", *forces} <= outputs and not any(n.startswith("F_y") for n in outputs)
    ref = run_scenarios(Plant(normal, lib), ("lqr",), 0.5, 1e-3).trajectories[0]
    assert ref.u.shape[1] == 7
    res = simulate_fmu(str(path), fmi_type="CoSimulation", stop_time=0.5,
                       output_interval=1e-3, output=[*STATES, *forces])
    assert np.allclose(res["time"], ref.t, rtol=0, atol=1e-12)
    _assert_close(_states(res), ref.x, 1e-9)
    F = np.column_stack([res[n] for n in forces])
    np.testing.assert_allclose(F, ref.u[:, 1:], rtol=0, atol=1e-9 * np.abs(ref.u[:, 1:]).max())
    assert np.abs(F).max() > 0.05  # the controller acts (peaks about 0.25 N)
