"""A second FMI importer: the FMI 2.0 co-simulation FMU run by libcosim (the Open Simulation
Platform's co-simulation library, through libcosimpy; its own FMU loader, FMI Library), not
by FMPy; and the FMI 2.0 model-exchange FMU loaded by that FMI Library (exported by
libcosimpy's libcosimc) and integrated by scipy.

Why libcosim and not OMSimulator: the `omsimulator` package on PyPI is a source
distribution whose build downloads OMSimulator's binaries from openmodelica.org, which a
machine that reaches only the package registries cannot do; libcosimpy's wheel carries its
library. libcosim imports FMI 1.0 and 2.0 co-simulation FMUs only: the FMI 3.0 FMUs and
model exchange are checked with FMPy (tests/test_fmu3.py, tests/test_fmu.py).

References: `maglevgen simulate`'s runs in the compiled simulation library (the same RK4
arithmetic, so the trajectories must agree bit for bit at every communication point), with
the parameter file's mass and with ``--set vehicle.mass=10.5``; scipy's DOP853 on the
lambdified SymPy model (reference_trajectory) for model exchange, which FMI Library's
caller here integrates with scipy's LSODA (libcosim has no model-exchange solver).
"""

from __future__ import annotations

import ctypes
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description

from maglevgen.analyses.reference import reference_trajectory
from maglevgen.analyses.simulate import AXIS_STATES, run_scenarios
from maglevgen.carriage import DerivedCarriage
from maglevgen.control.built_loop import Loop
from maglevgen.control.carriage_plant import Plant
from maglevgen.derive import conventions as cv
from maglevgen.exports.fmu import build_fmu
from maglevgen.params import load_params

if sys.version_info < (3, 11):  # libcosimpy's wheels start at Python 3.11
    pytest.importorskip("libcosimpy")
from libcosimpy.CosimEnums import CosimVariableType
from libcosimpy.CosimExecution import CosimExecution
from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
from libcosimpy.CosimObserver import CosimObserver
from libcosimpy.CosimSlave import CosimLocalSlave

STATES = [s.name for s in cv.STATES]
STEP_NS = 1_000_000  # the communication step, 1 ms, in libcosim's nanoseconds
pytestmark = pytest.mark.needs_cc


def _run(path: Path, t_end_ns: int, start: dict[str, float]) -> tuple[np.ndarray, np.ndarray]:
    """(communication points [ns], states) of a libcosim run of the FMU."""
    log_output_level(CosimLogLevel.ERROR)
    vr = {v.name: v.valueReference for v in read_model_description(str(path)).modelVariables}
    ex = CosimExecution.from_step_size(step_size=STEP_NS)
    idx = ex.add_local_slave(CosimLocalSlave(fmu_path=str(path), instance_name="maglev"))
    for name, value in start.items():
        assert ex.real_initial_value(idx, vr[name], value)
    obs = CosimObserver.create_time_series(buffer_size=t_end_ns // STEP_NS + 10)
    assert ex.add_observer(obs)
    for s in STATES:
        obs.start_time_series(idx, vr[s], CosimVariableType.REAL)
    assert ex.simulate_until(target_time=t_end_ns)
    cols, times = [], None
    for s in STATES:
        t, _, v = obs.time_series_real_samples(idx, vr[s], from_step=0,
                                               sample_count=t_end_ns // STEP_NS + 10)
        assert times is None or t == times
        times = t
        cols.append(v)
    return np.asarray(times), np.column_stack(cols)


@pytest.fixture(scope="module")
def cs_fmu(tmp_path_factory, carriage: DerivedCarriage, sim_lib) -> Path:
    path = tmp_path_factory.mktemp("libcosim") / "cs.fmu"
    path.write_bytes(build_fmu(Plant(carriage), "cs", "lqr", fmi="2", loop=Loop.CONTINUOUS))
    return path


def test_libcosim_run_is_maglevgen_simulate_bit_for_bit(cs_fmu: Path, carriage: DerivedCarriage,
                                                       sim_lib) -> None:
    ref = run_scenarios(Plant(carriage, sim_lib), ("lqr",), 1.0, 1e-3).trajectories[0]
    t, x = _run(cs_fmu, 1_000_000_000, {})
    assert t.size >= 990 and t[0] == 0 and np.all(np.diff(t) == STEP_NS)
    k = t // STEP_NS
    assert np.array_equal(x, ref.x[k])
    assert np.abs(x[:, 2] - x[0, 2]).max() > 1e-4  # the run moves (the disturbance decays)


def test_libcosim_start_value_is_the_command_line_set(cs_fmu: Path, sim_lib) -> None:
    heavy = DerivedCarriage(load_params(None, ["vehicle.mass=10.5"]))
    ref = run_scenarios(Plant(heavy, sim_lib), ("lqr",), 0.5, 1e-3).trajectories[0]
    t, x = _run(cs_fmu, 500_000_000, {"vehicle.mass": 10.5})
    assert np.array_equal(x, ref.x[t // STEP_NS])


class _Callbacks(ctypes.Structure):
    """fmi2CallbackFunctions, as FMI Library passes them to the FMU."""

    _fields_ = [("logger", ctypes.c_void_p), ("allocateMemory", ctypes.c_void_p),
                ("freeMemory", ctypes.c_void_p), ("stepFinished", ctypes.c_void_p),
                ("componentEnvironment", ctypes.c_void_p)]


def _fmi_library() -> ctypes.CDLL:
    """FMI Library's C API (fmi_import_*, fmi2_import_*) as libcosimc exports it."""
    import libcosimpy

    lib = ctypes.CDLL(str(Path(libcosimpy.__file__).parent / "libcosimc" / "libcosimc.so"))
    P, Int, D = ctypes.c_void_p, ctypes.c_int, ctypes.c_double
    Dp = ctypes.POINTER(ctypes.c_double)
    sig = {"jm_get_default_callbacks": (P, []), "fmi_import_allocate_context": (P, [P]),
           "fmi_import_get_fmi_version": (Int, [P, ctypes.c_char_p, ctypes.c_char_p]),
           "fmi2_import_parse_xml": (P, [P, ctypes.c_char_p, P]),
           "fmi2_import_create_dllfmu": (Int, [P, Int, ctypes.POINTER(_Callbacks)]),
           "fmi2_import_instantiate": (Int, [P, ctypes.c_char_p, Int, ctypes.c_char_p, Int]),
           "fmi2_import_setup_experiment": (Int, [P, Int, D, D, Int, D]),
           "fmi2_import_set_time": (Int, [P, D]),
           "fmi2_import_get_continuous_states": (Int, [P, Dp, ctypes.c_size_t]),
           "fmi2_import_set_continuous_states": (Int, [P, Dp, ctypes.c_size_t]),
           "fmi2_import_get_derivatives": (Int, [P, Dp, ctypes.c_size_t]),
           "fmi2_import_free_instance": (None, [P]), "fmi2_import_destroy_dllfmu": (None, [P]),
           "fmi2_import_free": (None, [P]), "fmi_import_free_context": (None, [P])}
    for name in ("enter_initialization_mode", "exit_initialization_mode",
                 "enter_continuous_time_mode", "terminate"):
        sig[f"fmi2_import_{name}"] = (Int, [P])
    for name, (res, args) in sig.items():
        f = getattr(lib, name)
        f.restype, f.argtypes = res, args
    return lib


@pytest.mark.slow  # about 20 s: LSODA through Python callbacks, and the DOP853 reference
def test_me_loaded_by_fmi_library_agrees_with_dop853_on_the_sympy_model(
        tmp_path: Path, carriage: DerivedCarriage, sim_lib, op) -> None:
    """The model-exchange FMU's derivatives through FMI Library (its own unzip, XML parser,
    dlopen and FMI 2.0 calls), integrated by scipy's LSODA, against DOP853 on the SymPy
    model: the bound of the FMPy/CVode test (1e-5 of the disturbance's peak)."""
    from scipy.integrate import solve_ivp

    path = tmp_path / "me.fmu"
    path.write_bytes(build_fmu(Plant(carriage), "me", "lqr", fmi="2", loop=Loop.CONTINUOUS))
    fmil = _fmi_library()
    libc = ctypes.CDLL(None)
    cb = _Callbacks(ctypes.cast(fmil.fmi2_log_forwarding, ctypes.c_void_p),
                    ctypes.cast(libc.calloc, ctypes.c_void_p),
                    ctypes.cast(libc.free, ctypes.c_void_p), None, None)
    ctx = fmil.fmi_import_allocate_context(fmil.jm_get_default_callbacks())
    unzipped = tempfile.mkdtemp(dir=tmp_path)
    assert fmil.fmi_import_get_fmi_version(ctx, str(path).encode(), unzipped.encode()) == 2
    fmu = fmil.fmi2_import_parse_xml(ctx, unzipped.encode(), None)
    assert fmu
    assert fmil.fmi2_import_create_dllfmu(fmu, 1, ctypes.byref(cb)) == 0  # ME, jm_status_success
    assert fmil.fmi2_import_instantiate(fmu, b"maglev", 0, None, 0) == 0
    assert fmil.fmi2_import_setup_experiment(fmu, 0, 0.0, 0.0, 0, 0.0) == 0
    assert fmil.fmi2_import_enter_initialization_mode(fmu) == 0
    assert fmil.fmi2_import_exit_initialization_mode(fmu) == 0
    assert fmil.fmi2_import_enter_continuous_time_mode(fmu) == 0
    n = len(STATES)
    buf, dbuf = (ctypes.c_double * n)(), (ctypes.c_double * n)()
    assert fmil.fmi2_import_get_continuous_states(fmu, buf, n) == 0
    x0 = np.array(buf)

    def f(t: float, x: np.ndarray) -> np.ndarray:
        buf[:] = x
        assert fmil.fmi2_import_set_time(fmu, t) == 0
        assert fmil.fmi2_import_set_continuous_states(fmu, buf, n) == 0
        assert fmil.fmi2_import_get_derivatives(fmu, dbuf, n) == 0
        return np.array(dbuf)

    t = np.linspace(0.0, 0.5, 501)
    try:
        sol = solve_ivp(f, (0.0, 0.5), x0, method="LSODA", t_eval=t, rtol=1e-10, atol=1e-12)
        assert sol.success, sol.message
    finally:
        fmil.fmi2_import_terminate(fmu)
        fmil.fmi2_import_free_instance(fmu)
        fmil.fmi2_import_destroy_dllfmu(fmu)
        fmil.fmi2_import_free(fmu)
        fmil.fmi_import_free_context(ctx)
    ref = reference_trajectory(carriage.functions, carriage.p, op, "lqr", t)
    x = sol.y.T
    idx = list(AXIS_STATES)
    peak = np.abs(ref[:, idx] - op.a_trim).max(axis=0)
    dev = np.abs(x[:, idx] - ref[:, idx]).max(axis=0)
    assert np.all(dev <= 1e-5 * peak), dev / peak
    np.testing.assert_allclose(x[0], ref[0], rtol=0, atol=1e-15)  # trim + disturbance
