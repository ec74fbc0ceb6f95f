"""The FMU's built-in controller at the firmware's tick (templates/fmu_tick.c.j2): the command
sampled at the tick, held (ZOH), applied after the delay, with the speed loop and the force
budget, in FMI 2.0 and 3.0, co-simulation and model exchange.

References: FMPy runs the FMUs (its CS master; CVode for model exchange, the ticks as time
events); the host firmware loop of the same controller (`maglevgen simulate`'s
maglev_simulate with a maglev_control_loop, itself held against DOP853 in test_tick.py); the
same loop one tick less delayed, to show that the delay is the FMU's.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu

from maglevgen.analyses.simulate import Tick, firmware_loop, simulate
from maglevgen.derive import conventions as cv
from maglevgen.exports.fmu import build_fmu

STATES = [s.name for s in cv.STATES]
T_END = 0.3  # [s]: the disturbance's first ticks saturate the budget, then the loop settles


@pytest.fixture(scope="module")
def fmus(tmp_path_factory, carriage):
    """The embedded (`spec`) controller's FMU, firmware loop, both kinds, per FMI version."""
    folder = tmp_path_factory.mktemp("fmu_tick")
    made: dict[str, Path] = {}

    def get(fmi: str) -> Path:
        if fmi not in made:
            made[fmi] = folder / f"spec_fmi{fmi}.fmu"
            made[fmi].write_bytes(build_fmu(carriage, "both", "spec", fmi=fmi,
                                            loop="firmware"))
        return made[fmi]

    return get


@pytest.fixture(scope="module")
def host(carriage, sim_lib, op):
    """The firmware loop on the host, and the same loop with one tick less of delay."""
    tick, k_v, budget = firmware_loop(carriage, sim_lib)

    def run(delay: int):
        return simulate(sim_lib, carriage.p, op, "spec", T_END, 1e-3,
                        carriage.params.track.min_gap, tick=Tick(tick.rate, delay),
                        speed_gain=k_v, force_budget=budget)

    return {"loop": (tick, k_v, budget), "ref": run(tick.delay),
            "early": run(tick.delay - 1)}


def _states(res) -> np.ndarray:
    return np.column_stack([res[n] for n in STATES])


def _scaled(x: np.ndarray, ref: np.ndarray) -> float:
    """max |x - ref|, each state relative to its excursion in the reference."""
    scale = np.maximum(np.abs(ref - ref[0]).max(axis=0), 1e-12)
    return float(np.max(np.abs(x - ref) / scale))


@pytest.mark.parametrize("fmi", ["2", "3"])
def test_cs_runs_the_firmware_loop_of_the_host(fmus, host, fmi) -> None:
    """Co-simulation: the FMU's states equal the host firmware loop's at every sample (the
    same RK4 and tick arithmetic in double) with communication steps of one and of ten RK4
    steps; the run with one tick less delay is far off; the start values are the loop's."""
    path = fmus(fmi)
    tick, k_v, budget = host["loop"]
    var = {v.name: v for v in read_model_description(str(path)).modelVariables}
    assert float(var["tick_rate"].start) == tick.rate
    assert float(var["delay_ticks"].start) == tick.delay
    assert float(var["speed_gain"].start) == k_v
    assert float(var["force_budget"].start) == budget
    ref = host["ref"]
    assert ref.saturated_time > 0  # the budget acts in this run
    res = simulate_fmu(str(path), fmi_type="CoSimulation", stop_time=T_END,
                       output_interval=1e-3, output=[*STATES, "F_prop"])
    assert np.array_equal(_states(res), ref.x)
    np.testing.assert_array_equal(res["F_prop"], ref.u[:, 0])
    res10 = simulate_fmu(str(path), fmi_type="CoSimulation", stop_time=T_END,
                         output_interval=1e-2, output=STATES)
    assert np.array_equal(_states(res10), ref.x[::10])
    assert _scaled(ref.x, host["early"].x) > 1e-3


@pytest.mark.parametrize("fmi", ["2", "3"])
def test_me_ticks_as_time_events(fmus, host, fmi) -> None:
    """Model exchange: CVode between the ticks (time events) follows the host loop to the
    host RK4's own error (test_tick.py: 3e-7 of the excursion), well inside the difference
    one tick of delay makes."""
    res = simulate_fmu(str(fmus(fmi)), fmi_type="ModelExchange", solver="CVode",
                       relative_tolerance=1e-10, stop_time=T_END, output_interval=1e-3,
                       output=STATES, record_events=False)
    ref = host["ref"]
    assert np.allclose(res["time"], ref.t, atol=1e-12)
    err = _scaled(_states(res), ref.x)
    assert err < 1e-5
    assert _scaled(host["early"].x, ref.x) > 100 * err


def test_a_tick_off_the_rk4_grid_is_refused(fmus) -> None:
    """A tick whose period is not a whole number of rk4_step: co-simulation refuses it at
    initialization (fmi2ExitInitializationMode answers fmi2Error, FMPy raises). FMPy runs in
    a fresh interpreter: in the suite's worker, the ctypes callbacks of the model-exchange runs
    before (CVode's right-hand side, the logger) can fire in this test's error path, which
    once ended the worker with a segfault and once failed this test on their exceptions."""
    script = ("import sys\n"
              "from fmpy import simulate_fmu\n"
              "from fmpy.fmi1 import FMICallException\n"
              "try:\n"
              "    simulate_fmu(sys.argv[1], fmi_type='CoSimulation', stop_time=0.01,\n"
              "                 output_interval=1e-3, start_values={'tick_rate': 300.0})\n"
              "except FMICallException as exc:\n"
              "    print('refused:', exc)\n"
              "    sys.exit(0)\n"
              "sys.exit(5)\n")
    run = subprocess.run([sys.executable, "-c", script, str(fmus("2"))], capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, (run.returncode, run.stdout, run.stderr[-2000:])
    assert "fmi2ExitInitializationMode" in run.stdout, run.stdout
