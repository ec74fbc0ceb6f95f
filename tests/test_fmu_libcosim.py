"""A second FMI importer: the FMI 2.0 co-simulation FMU run by libcosim (the Open Simulation
Platform's co-simulation library, through libcosimpy; its own FMU loader, FMI Library), not
by FMPy.

Why libcosim and not OMSimulator: the `omsimulator` package on PyPI is a source
distribution whose build downloads OMSimulator's binaries from openmodelica.org, which a
machine that reaches only the package registries cannot do; libcosimpy's wheel carries its
library. libcosim imports FMI 1.0 and 2.0 co-simulation FMUs only: the FMI 3.0 FMUs and
model exchange are checked with FMPy (tests/test_fmu3.py, tests/test_fmu.py).

References: `maglevgen simulate`'s runs in the compiled simulation library (the same RK4
arithmetic, so the trajectories must agree bit for bit at every communication point), with
the parameter file's mass and with ``--set vehicle.mass=10.5``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description

from maglevgen.carriage import Carriage
from maglevgen.derive import conventions as cv
from maglevgen.fmu import build_fmu
from maglevgen.params import load_params
from maglevgen.simulate import run_scenarios

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
def cs_fmu(tmp_path_factory, carriage: Carriage, sim_lib) -> Path:
    path = tmp_path_factory.mktemp("libcosim") / "cs.fmu"
    path.write_bytes(build_fmu(carriage, "cs", "lqr", fmi="2"))
    return path


def test_libcosim_run_is_maglevgen_simulate_bit_for_bit(cs_fmu: Path, carriage: Carriage,
                                                       sim_lib) -> None:
    ref = run_scenarios(carriage, ("lqr",), 1.0, 1e-3, lib=sim_lib).trajectories[0]
    t, x = _run(cs_fmu, 1_000_000_000, {})
    assert t.size >= 990 and t[0] == 0 and np.all(np.diff(t) == STEP_NS)
    k = t // STEP_NS
    assert np.array_equal(x, ref.x[k])
    assert np.abs(x[:, 2] - x[0, 2]).max() > 1e-4  # the run moves (the disturbance decays)


def test_libcosim_start_value_is_the_command_line_set(cs_fmu: Path, sim_lib) -> None:
    heavy = Carriage(load_params(None, ["vehicle.mass=10.5"]))
    ref = run_scenarios(heavy, ("lqr",), 0.5, 1e-3, lib=sim_lib).trajectories[0]
    t, x = _run(cs_fmu, 500_000_000, {"vehicle.mass": 10.5})
    assert np.array_equal(x, ref.x[t // STEP_NS])
