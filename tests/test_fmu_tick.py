"""The FMU's built-in controller at the firmware's tick (templates/fmu_tick.c.j2): the loop as
built, as `maglevgen simulate --loop firmware` flies it (issue 49): the command sampled at the
tick by the firmware tick's law (the design at the tick: K_pos, K_rate, K_lag, K_delay), held
(ZOH), applied after the delay, with the speed loop and its integral, the force budget and each
array force's first-order lag in the plant, in FMI 2.0 and 3.0, co-simulation and model
exchange (the lagged forces as continuous states).

References: FMPy runs the FMUs (its CS master; CVode for model exchange, the ticks as time
events); the host firmware loop of the same controller (`maglevgen simulate`'s
maglev_simulate with a maglev_control_loop, itself held against DOP853 in test_host_loop.py);
for model exchange the tick's law in numpy (test_host_loop.NumpyLaw) on the plant integrated
by SciPy's DOP853 with the array forces as states; the same loop one tick less delayed, to
show that the delay is the FMU's.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu

from maglevgen.analyses.simulate import firmware_gains, run_loop, simulate
from maglevgen.control.built_loop import Loop
from maglevgen.control.carriage_plant import Plant
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
            made[fmi].write_bytes(build_fmu(Plant(carriage), "both", "spec", fmi=fmi,
                                            loop=Loop.FIRMWARE))
        return made[fmi]

    return get


@pytest.fixture(scope="module")
def host(carriage, sim_lib, op):
    """The firmware loop on the host (`firmware_loop`: its FirmwareTick with the lag and the
    speed integral), and the same loop with one tick less of delay."""
    tick, k_v, budget = run_loop(Plant(carriage, sim_lib), "firmware")
    assert tick.lag > 0  # the plant's lag is exercised

    def run(delay: int):
        return simulate(sim_lib, carriage.p, op, "spec", T_END, 1e-3,
                        carriage.params.track.min_gap,
                        tick=dataclasses.replace(tick, delay=delay), speed_gain=k_v,
                        force_budget=budget)

    return {"loop": (tick, k_v, budget), "ref": run(tick.delay),
            "early": run(tick.delay - 1)}


def _states(res) -> np.ndarray:
    return np.column_stack([res[n] for n in STATES])


def _scaled(x: np.ndarray, ref: np.ndarray) -> float:
    """max |x - ref|, each state relative to its excursion in the reference."""
    scale = np.maximum(np.abs(ref - ref[0]).max(axis=0), 1e-12)
    return float(np.max(np.abs(x - ref) / scale))


@pytest.mark.parametrize("fmi", ["2", "3"])
def test_cs_runs_the_firmware_loop_of_the_host(fmus, host, op, fmi) -> None:
    """Co-simulation: the FMU's states and applied inputs (the propulsion, the lagged array
    forces) equal the host firmware loop's at every sample (the same RK4, lag exponential and
    tick law in double) with communication steps of one and of ten RK4 steps; the run with one
    tick less delay is far off; the start values are the loop's and the design's."""
    path = fmus(fmi)
    tick, k_v, budget = host["loop"]
    var = {v.name: v for v in read_model_description(str(path)).modelVariables}
    assert float(var["tick_rate"].start) == tick.rate
    assert float(var["delay_ticks"].start) == tick.delay
    assert float(var["speed_gain"].start) == k_v
    assert float(var["force_budget"].start) == budget
    assert float(var["actuator_lag"].start) == tick.lag
    assert float(var["speed_integral"].start) == tick.speed_integral
    design = firmware_gains(op, "spec", tick)
    for name, K in (("K_lag", design.K_lag), ("K_delay", design.K_delay)):
        assert K is not None and K.size  # the design at the tick feeds both back
        for (i, j), v in np.ndenumerate(K):
            assert float(var[f"{name}[{i + 1},{j + 1}]"].start) == v
    ref = host["ref"]
    assert ref.saturated_time > 0  # the budget acts in this run
    forces = [v.name for v in read_model_description(str(path)).modelVariables
              if v.name.startswith("actuator.")]
    applied = [f.removeprefix("actuator.") for f in forces]
    assert len(applied) == ref.u.shape[1] - 1  # every array force has its lag
    res = simulate_fmu(str(path), fmi_type="CoSimulation", stop_time=T_END,
                       output_interval=1e-3, output=[*STATES, "F_prop", *applied, *forces])
    assert np.array_equal(_states(res), ref.x)
    np.testing.assert_array_equal(res["F_prop"], ref.u[:, 0])
    u = np.column_stack([res[n] for n in applied])
    np.testing.assert_array_equal(u, ref.u[:, 1:])
    np.testing.assert_array_equal(np.column_stack([res[n] for n in forces]), u)
    assert np.abs(u).max() > 1.0  # the lagged forces are exercised
    res10 = simulate_fmu(str(path), fmi_type="CoSimulation", stop_time=T_END,
                         output_interval=1e-2, output=STATES)
    assert np.array_equal(_states(res10), ref.x[::10])
    assert _scaled(ref.x, host["early"].x) > 1e-3


@pytest.mark.parametrize("fmi", ["2", "3"])
def test_cs_speed_integral_as_the_host(fmus, host, carriage, sim_lib, op, fmi) -> None:
    """The speed error's integral (0 in the default loop) set through its start value, k_i =
    m b^2 (test_host_loop's): the co-simulation equals the host loop at that FirmwareTick bit
    for bit (the design at the tick does not depend on k_i, so the FMU's gains still hold),
    and the propulsion differs from the loop without it."""
    tick, k_v, budget = host["loop"]
    b = carriage.params.control.spec.speed_bandwidth
    k_i = carriage.params.vehicle.mass * b**2
    with_i = dataclasses.replace(tick, speed_integral=k_i)
    ref = simulate(sim_lib, carriage.p, op, "spec", T_END, 1e-3, carriage.params.track.min_gap,
                   tick=with_i, speed_gain=k_v, force_budget=budget)
    res = simulate_fmu(str(fmus(fmi)), fmi_type="CoSimulation", stop_time=T_END,
                       output_interval=1e-3, output=[*STATES, "F_prop"],
                       start_values={"speed_integral": k_i})
    assert np.array_equal(_states(res), ref.x)
    np.testing.assert_array_equal(res["F_prop"], ref.u[:, 0])
    assert np.abs(ref.u[:, 0] - host["ref"].u[:, 0]).max() > 1e-6


T_ME = 0.05  # [s]: the reference's DOP853 from tick to tick, fifty ticks


@pytest.fixture(scope="module")
def me_reference(carriage, sim_lib, op, host):
    """The firmware loop with the array forces as states, by hand: the tick's law in numpy
    (test_host_loop.NumpyLaw: the axis rates from the lambdified SymPy model, the allocation
    from the SymPy effectiveness) at each tick, the command applied after the delay (the safe
    one first), the plant (the generated maglev_dynamics, which test_codegen holds against the
    SymPy model, with tau f' = u - f) integrated by DOP853 from tick to tick; (t, x, f) at
    every tick."""
    from scipy.integrate import solve_ivp
    from test_host_loop import NumpyLaw

    from maglevgen.analyses.simulate import DISTURBANCE, initial_state

    tick, k_v, budget = host["loop"]
    dyn = sim_lib.function("maglev_dynamics")
    law = NumpyLaw(carriage, op, firmware_gains(op, "spec", tick), tick, k_v, budget)
    nf, tau, h = carriage.model.u.shape[0] - 1, tick.lag, 1.0 / tick.rate
    queue = [np.concatenate([[op.f_prop], np.zeros(nf)])] * tick.delay
    z = np.concatenate([initial_state(op, DISTURBANCE), np.zeros(nf)])
    n = round(T_ME / h)
    zs = [z]
    for k in range(n):
        queue.append(law(z[:12]))
        u = queue.pop(0)

        def rhs(_t, zz, u=u):
            f = zz[12:]
            (xdot,) = dyn(zz[:12], np.concatenate([[u[0]], f]), carriage.p)
            return np.concatenate([np.asarray(xdot, dtype=float).ravel(), (u[1:] - f) / tau])

        sol = solve_ivp(rhs, (k * h, (k + 1) * h), z, method="DOP853", rtol=1e-12,
                        atol=1e-14)
        assert sol.success
        z = sol.y[:, -1]
        zs.append(z)
    zz = np.array(zs)
    return np.arange(n + 1) * h, zz[:, :12], zz[:, 12:]


@pytest.mark.parametrize("fmi", ["2", "3"])
def test_me_integrates_the_lagged_forces_as_states(fmus, host, me_reference, fmi) -> None:
    """Model exchange: CVode between the ticks (time events), the lagged array forces among
    its continuous states (actuator.*), against the loop with the forces as states by hand
    (`me_reference`) to CVode's tolerance, and against the host loop to the host RK4's own
    error; both well inside the difference one tick of delay makes."""
    path = fmus(fmi)
    forces = [v.name for v in read_model_description(str(path)).modelVariables
              if v.name.startswith("actuator.")]
    res = simulate_fmu(str(path), fmi_type="ModelExchange", solver="CVode",
                       relative_tolerance=1e-10, stop_time=T_END, output_interval=1e-3,
                       output=[*STATES, *forces], record_events=False)
    ref = host["ref"]
    assert np.allclose(res["time"], ref.t, atol=1e-12)
    x = _states(res)
    t_ref, x_ref, f_ref = me_reference
    n = t_ref.size
    assert np.allclose(res["time"][:n], t_ref, atol=1e-12)
    err_ref = _scaled(x[:n], x_ref)
    f = np.column_stack([res[n_] for n_ in forces])[:n]
    err_f = float(np.max(np.abs(f - f_ref)) / np.abs(f_ref).max())
    assert err_ref < 1e-7 and err_f < 1e-7, (err_ref, err_f)
    err_host = _scaled(x, ref.x)
    assert err_host < 2e-5, err_host
    assert _scaled(host["early"].x, ref.x) > 100 * err_host


def test_bad_tick_settings_are_refused(fmus, carriage, tmp_path) -> None:
    """A tick whose period is not a whole number of rk4_step, a negative actuator lag or speed
    integral gain, a lag or integral with the continuous law: the FMU refuses each at
    initialization (fmi2ExitInitializationMode answers fmi2Error, FMPy raises) with a message
    saying which; a non-finite law gain already at fmi2SetReal. Model exchange of an FMU
    exported with --loop continuous (no lagged forces among its states) refuses a lag. FMPy
    runs in a fresh
    interpreter: in the suite's worker, the ctypes callbacks of the model-exchange runs before
    (CVode's right-hand side, the logger) can fire in this test's error path, which once ended
    the worker with a segfault and once failed this test on their exceptions."""
    script = ("import sys\n"
              "from fmpy import simulate_fmu\n"
              "from fmpy.fmi1 import FMICallException\n"
              "cases = [{'tick_rate': 300.0}, {'actuator_lag': -1e-3},\n"
              "         {'speed_integral': -1.0}, {'K_lag[2,3]': float('nan')},\n"
              "         {'tick_rate': 0.0}]\n"
              "for start in cases:\n"
              "    log = []\n"
              "    try:\n"
              "        simulate_fmu(sys.argv[1], fmi_type='CoSimulation', stop_time=0.01,\n"
              "                     output_interval=1e-3, start_values=start,\n"
              "                     logger=lambda *a: log.append(a[-1].decode()))\n"
              "    except FMICallException as exc:\n"
              "        print('refused:', exc, '|', ' '.join(log))\n"
              "        continue\n"
              "    sys.exit(5)\n"
              "log = []\n"
              "try:\n"
              "    simulate_fmu(sys.argv[2], fmi_type='ModelExchange', stop_time=0.01,\n"
              "                 start_values={'tick_rate': 1000.0, 'actuator_lag': 2e-3},\n"
              "                 logger=lambda *a: log.append(a[-1].decode()))\n"
              "except FMICallException as exc:\n"
              "    print('refused:', exc, '|', ' '.join(log))\n"
              "    sys.exit(0)\n"
              "sys.exit(6)\n")
    continuous = tmp_path / "continuous.fmu"
    continuous.write_bytes(build_fmu(Plant(carriage), "me", "spec", loop=Loop.CONTINUOUS))
    run = subprocess.run([sys.executable, "-c", script, str(fmus("2")), str(continuous)],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, (run.returncode, run.stdout, run.stderr[-2000:])
    lines = run.stdout.splitlines()
    assert len(lines) == 6, lines
    assert all("fmi2ExitInitializationMode" in lines[i] for i in (0, 1, 2, 4, 5)), lines
    assert "not a whole multiple of rk4_step" in lines[0]
    assert "actuator_lag -0.001 s" in lines[1] and "speed_integral -1 N/m" in lines[2]
    assert "fmi2SetReal" in lines[3] and "nan is not finite" in lines[3], lines[3]
    # the firmware FMU's lag and integral start non-zero: tick_rate 0 alone is refused
    assert "act at the tick only" in lines[4]
    assert "needs the lagged array forces as continuous states" in lines[5], lines[5]
