"""Closed-loop simulation in the generated C against independent references.

References: scipy's adaptive DOP853 on the lambdified SymPy model (derive.numeric) with the
controller written out in numpy; python-control's LQR on the per-axis plants; the energy of
the linearised carriage (generalized mass and stiffness from the SymPy linearisation).
"""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
from pathlib import Path

import control
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.signal import find_peaks

from maglevgen.analyses.reference import reference_trajectory
from maglevgen.analyses.simulate import (
    AXIS_STATES,
    initial_state,
    rk4_stability_limit,
    run_scenarios,
    settling_time,
    simulate,
)
from maglevgen.carriage import DerivedCarriage
from maglevgen.cli import main
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.symbolic_reference import allocation_matrix, axis_plants
from maglevgen.controllers import names as controller_names
from maglevgen.errors import InputError
from maglevgen.params import load_params
from maglevgen.runtime.compile import CompileError, compile_shared
from maglevgen.runtime.library import runtime_sources, simulation_library

AXIS = {"lateral": 0, "vertical": 1, "roll": 2, "pitch": 3, "yaw": 4}


# The paper's claims about the hold runs (figs 3-8: the open loop keeps oscillating, damping
# and the paper-weight LQR make it decay) hold for eq 3's quasi-static circuits; with the
# circuits' lag (the default) the open loop grows and the per-axis LQR is unstable at 20 m/s
# (tests/test_circuit_lag.py, test_envelope.py). Those tests run on the quasi-static model.
@pytest.fixture(scope="module")
def qs_carriage(private_cache) -> DerivedCarriage:
    return DerivedCarriage(load_params(overrides=['model.circuit_dynamics="quasi-static"']))


@pytest.fixture(scope="module")
def qs_lib(qs_carriage: DerivedCarriage):
    return simulation_library(qs_carriage.structure)


@pytest.fixture(scope="module")
def qs_trim(qs_carriage: DerivedCarriage):
    return qs_carriage.trim()


@pytest.fixture(scope="module")
def qs_op(qs_lib, qs_carriage: DerivedCarriage):
    from maglevgen.analyses.simulate import Weights, operating_point

    return operating_point(qs_lib, qs_carriage.p, qs_carriage.params.operation.speed,
                           qs_carriage.params.track.min_gap, Weights.of(qs_carriage.params))


def _run(sim_lib, carriage: DerivedCarriage, op, controller: str, t_end: float, dt: float = 1e-3,
         **kw):
    return simulate(sim_lib, carriage.p, op, controller, t_end, dt,
                    carriage.params.track.min_gap, **kw)


# ------------------------------------------------------------------ accuracy of the C RK4


@pytest.mark.slow  # runs at four steps against solve_ivp, per controller
@pytest.mark.parametrize("controller", ["none", "damping", "lqr"])
def test_rk4_error_against_adaptive_reference_shrinks_as_dt4(sim_lib, carriage, op,
                                                             controller) -> None:
    """Max error (each state scaled by its excursion) vs DOP853 at rtol 1e-12; ratio ~ 2^4."""
    errors = []
    for dt in (8e-3, 4e-3):
        traj = _run(sim_lib, carriage, op, controller, 0.4, dt)
        ref = reference_trajectory(carriage.functions, carriage.p, op, controller, traj.t)
        scale = np.max(np.abs(ref - ref[0]), axis=0)[1:]
        errors.append(np.max(np.abs(traj.x - ref)[:, 1:] / scale))
    ratio = errors[0] / errors[1]
    assert 12 < ratio < 21, (errors, ratio)
    assert errors[1] < 1e-3


def test_generated_closed_loop_matches_reference_at_default_step(sim_lib, carriage, op) -> None:
    traj = _run(sim_lib, carriage, op, "lqr", 1.0)
    ref = reference_trajectory(carriage.functions, carriage.p, op, "lqr", traj.t)
    dev_c = traj.x[:, list(AXIS_STATES)] - op.a_trim
    dev_ref = ref[:, list(AXIS_STATES)] - op.a_trim
    np.testing.assert_allclose(dev_c, dev_ref, atol=1e-6 * np.max(np.abs(dev_ref)))


def test_trajectory_speed_and_deviation_are_numpys(sim_lib, carriage, op) -> None:
    """The run's speed is np.linalg.norm of (u, v, w) to the bit, and the axis deviation the
    axis states' columns less the equilibrium, both on a firmware-loop run (the speed moves)."""
    traj = _run(sim_lib, carriage, op, "lqr", 0.5, speed_gain=50.0)
    assert np.ptp(traj.speed) > 0
    np.testing.assert_array_equal(traj.speed, np.linalg.norm(traj.x[:, 6:9], axis=1))
    assert traj.equilibrium is not None
    np.testing.assert_array_equal(traj.axis_deviation,
                                  traj.x[:, list(AXIS_STATES)] - traj.equilibrium)


# ------------------------------------------------------------- behaviour of the scenarios


def _energy(carriage: DerivedCarriage, trim, traj) -> np.ndarray:
    """0.5 a_dot' M a_dot + 0.5 da' K da with M, K from the SymPy linearisation at trim."""
    M = np.diag(carriage.generalized_mass())
    K = carriage.total_stiffness(trim)
    K = (K + K.T) / 2
    da = traj.x[:, list(AXIS_STATES)] - traj.op.a_trim
    rate = np.gradient(traj.x[:, list(AXIS_STATES)], traj.t, axis=0)
    return (0.5 * np.einsum("ni,ij,nj->n", rate, M, rate)
            + 0.5 * np.einsum("ni,ij,nj->n", da, K, da))


def test_open_loop_oscillation_does_not_decay(qs_lib, qs_carriage, qs_op, qs_trim) -> None:
    """The paper's figs 3-4: with no control the disturbance keeps oscillating."""
    traj = _run(qs_lib, qs_carriage, qs_op, "none", 5.0)
    assert traj.c_status == 0  # every step taken, no contact
    assert traj.status in ("not settled", "diverging")  # never called settled
    ratio = _energy(qs_carriage, qs_trim, traj) / _energy(qs_carriage, qs_trim, traj)[0]
    assert ratio.max() < 3.0  # bounded over the run
    assert ratio[-1000:].min() > 0.5  # and not decaying: still at least half after 4-5 s


def test_damping_and_lqr_make_it_decay(qs_lib, qs_carriage, qs_op, qs_trim) -> None:
    for controller, t_end, bound in (("damping", 5.0, 1e-3), ("lqr", 10.0, 0.2)):
        traj = _run(qs_lib, qs_carriage, qs_op, controller, t_end)
        e = _energy(qs_carriage, qs_trim, traj)
        assert traj.c_status == 0
        # the damping settles within 5 s; the paper-weight LQR's slowest mode (-0.066 1/s)
        # decays but not to 5 % of the peak within 10 s
        assert traj.status == ("settled" if controller == "damping" else "not settled")
        assert e[-1] / e[0] < bound, controller
        assert np.all(e[1000::1000] < e[0]), controller


@pytest.mark.parametrize("controller", ["lqr", "coupled"])
def test_a_short_run_of_a_decaying_loop_is_not_called_diverging(qs_lib, qs_carriage, qs_op, qs_trim,
                                                                controller: str) -> None:
    """Over 0.5 s the axes the disturbance excites through the coupling (roll, yaw) peak after
    the first quarter, so a growth test alone calls the run diverging (the premise, from the
    states). The same loop over 10 s loses most of its energy (M and K of the SymPy
    linearisation, `_energy`): the short run is a transient, "not settled"."""
    short = _run(qs_lib, qs_carriage, qs_op, controller, 0.5)
    dev = np.abs(short.x[:, list(AXIS_STATES)] - qs_op.a_trim)
    n = dev.shape[0] // 4
    assert np.any(dev[-n:].max(axis=0) > dev[:n].max(axis=0))  # the premise
    long = _run(qs_lib, qs_carriage, qs_op, controller, 10.0)
    e = _energy(qs_carriage, qs_trim, long)
    assert long.c_status == 0 and e[-1] < 0.2 * e[0]
    assert short.c_status == 0 and short.status == "not settled"


def test_paper_claim_lqr_better_does_not_hold_with_its_weights(qs_lib, qs_carriage, qs_op) -> None:
    """Pinned derived behaviour (the report explains it): with Q = I, R = 1 the LQR rate gain
    is about 1 N s/m against the optimized damping's sqrt(k m) (hundreds), so the damping
    controller settles levitation height, pitch and lateral position better, not the LQR."""
    ctl = qs_carriage.params.control
    assert list(ctl.state_weights) == [1.0, 1.0] and ctl.input_weight == 1.0
    ise = {}
    for controller in ("damping", "lqr"):
        dev = _run(qs_lib, qs_carriage, qs_op, controller, 10.0).axis_deviation
        ise[controller] = np.sum(dev**2, axis=0) * 1e-3
    for axis in ("vertical", "pitch", "lateral"):
        assert ise["lqr"][AXIS[axis]] > 1.5 * ise["damping"][AXIS[axis]], axis


def test_lqr_heave_decays_at_the_rate_of_the_linearised_closed_loop(qs_lib, qs_carriage, qs_op,
                                                                    qs_trim) -> None:
    """The heave envelope decays at Re of the closed-loop pole of its frequency, built from
    the SymPy linearisation, python-control's per-axis LQR and the SymPy allocation."""
    A, B = qs_carriage.linearize(qs_trim)
    T = allocation_matrix(qs_carriage)
    gains = np.array([control.lqr(np.array([[0.0, 1.0], [-k / m, 0.0]]),
                                  np.array([[0.0], [1.0 / m]]), np.eye(2), np.eye(1))[0][0]
                      for _, k, m in axis_plants(qs_carriage, qs_trim)])
    S = np.zeros((5, 12))
    S[range(5), AXIS_STATES] = 1.0
    A_cl = A + B[:, 1:] @ T @ -(np.diag(gains[:, 0]) @ S + np.diag(gains[:, 1]) @ S @ A)
    poles = np.linalg.eigvals(A_cl)

    traj = _run(qs_lib, qs_carriage, qs_op, "lqr", 10.0)
    z = traj.axis_deviation[:, AXIS["vertical"]]
    late = traj.t > 2.0  # after the faster pitch-coupled mode has gone
    peaks, _ = find_peaks(np.abs(z[late]))
    t_peaks = traj.t[late][peaks]
    slope = np.polyfit(t_peaks, np.log(np.abs(z[late][peaks])), 1)[0]
    omega = np.pi / np.mean(np.diff(t_peaks))  # |z| peaks twice per period
    pole = poles[np.argmin(np.abs(poles.imag - omega))]
    assert omega == pytest.approx(pole.imag, rel=0.01)
    assert slope == pytest.approx(pole.real, rel=0.1)


def test_contact_is_reported_at_the_first_sample_past_the_crossing(sim_lib, carriage,
                                                                   op) -> None:
    min_gap = carriage.params.track.min_gap
    disturbance = {"w": -1.0}
    traj = _run(sim_lib, carriage, op, "none", 1.0, disturbance=disturbance)
    assert traj.status == "contact"
    assert "array(s) 3" in traj.event and "min_gap" in traj.event
    assert np.all(np.isfinite(traj.x)) and traj.t[-1] < 1.0
    assert traj.gaps[-1].min() < min_gap <= traj.gaps[:-1].min()
    # the crossing time by an event on the lambdified gaps (independent of the C)
    fns = carriage.functions
    u = np.zeros(traj.u.shape[1])
    u[0] = op.f_prop

    def gap_event(_t: float, x: np.ndarray) -> float:
        return float(np.min(fns.contact_gaps(x, carriage.p)) - min_gap)

    gap_event.terminal = True
    sol = solve_ivp(lambda _t, x: fns.xdot(x, u, carriage.p).ravel(), (0, 1.0),
                    initial_state(op, disturbance), method="DOP853", rtol=1e-10, atol=1e-12,
                    events=gap_event)
    t_cross = sol.t_events[0][0]
    assert t_cross <= traj.t[-1] < t_cross + traj.dt + 1e-12


def test_non_finite_parameters_stop_the_run(sim_lib, carriage, op) -> None:
    p = carriage.p.copy()
    p[0] = np.nan
    last, status, x, _, g, _ = sim_lib.simulate(initial_state(op, {}), 1e-3, 100, op.f_prop,
                                             np.zeros(25), np.zeros(25), op.a_trim, p, 0.002,
                                             op.allocation.shape[0] + 1, op.gaps.size)
    # refused before the first step (the checked entry points reject a non-finite p:
    # MAGLEV_SIM_ERROR), not run to the end, not silently; nothing non-finite is written
    assert status == 3 and last == 0 and x.shape[0] == 1
    assert np.all(np.isfinite(x)) and np.all(np.isfinite(g))


def test_settling_time_definition() -> None:
    t = np.linspace(0, 10, 1001)
    assert settling_time(t, np.exp(-t) * np.cos(10 * t)) == pytest.approx(3.0, abs=0.2)
    assert settling_time(t, np.cos(t)) is None


def test_settling_is_about_the_final_value_and_above_a_floor() -> None:
    """A decay onto a steady offset settles as the decay alone does (the offset is the final
    deviation, not a failure to settle): exp(-t) falls to 5 % of its start at ln 20 = 3.0 s;
    a jitter below the floor settles at once, one above it never."""
    t = np.linspace(0, 10, 1001)
    decay = np.exp(-t) * np.cos(10 * t)
    for offset in (0.0, 0.3, -2.0):  # up to twice the excursion itself
        assert settling_time(t, offset + decay) == pytest.approx(np.log(20), abs=0.2)
    jitter = 1e-4 * np.sin(377 * t) * np.cos(61 * t)  # a bounded, non-decaying noise
    assert settling_time(t, jitter) is None  # within 5 % of its own excursion: never
    assert settling_time(t, jitter, floor=2e-4) == 0.0
    assert settling_time(t, 0.3 + decay + jitter, floor=5e-2) == pytest.approx(np.log(20),
                                                                          abs=0.2)
    assert settling_time(t, 0.3 + decay, floor=1.5) == 0.0  # never outside the floor
    # a decay into the band at 9.5 s: within the last 10 % of a 10 s run (the window its
    # final value is the mean of), too late to tell; in a 40 s run it settles at 9.5 s
    slow = np.log(20) / 9.5
    assert settling_time(t, np.exp(-slow * t) * np.cos(10 * t)) is None
    t40 = np.linspace(0, 40, 4001)
    assert settling_time(t40, np.exp(-slow * t40) * np.cos(10 * t40)) == pytest.approx(
        9.5, abs=0.3)


def test_rk4_stability_limit_matches_the_imaginary_axis_bound() -> None:
    # RK4 is stable on the imaginary axis up to |h omega| = 2 sqrt(2)
    assert rk4_stability_limit(np.array([50j, -50j])) == pytest.approx(2 * np.sqrt(2) / 50,
                                                                       rel=1e-9)
    # a decaying real mode: |1 + z + ... + z^4/24| = 1 at z = -2.785
    assert rk4_stability_limit(np.array([-1.0])) == pytest.approx(2.785293563, rel=1e-6)


def test_step_above_the_stability_limit_is_refused(carriage, sim_lib) -> None:
    with pytest.raises(InputError, match=r"RK4 stability limit 0\.0\d+ s"):
        run_scenarios(Plant(carriage, sim_lib), controller_names(), 1.0, 0.1)


# ------------------------------------------------------------------ library and its cache


def test_parameter_change_needs_no_regeneration_or_recompile(carriage, sim_lib,
                                                             private_cache) -> None:
    heavier = DerivedCarriage(load_params(None, ["vehicle.mass=12.0"]))
    messages: list[str] = []
    lib = simulation_library(heavier.structure, progress=messages.append)
    assert messages == [] and lib.path == sim_lib.path
    # and the run-time parameters take effect: the trim heave sinks with the mass
    from maglevgen.analyses.simulate import Weights, operating_point

    heavy_op = operating_point(lib, heavier.p, 20.0, heavier.params.track.min_gap,
                               Weights.of(heavier.params))
    assert heavy_op.x_trim[2] == pytest.approx(heavier.trim().x[2], abs=1e-9)
    assert heavy_op.x_trim[2] < carriage.trim().x[2]


@pytest.mark.slow
def test_corrupted_cache_entries_are_rebuilt(carriage, seeded_cache) -> None:
    cache = Path(seeded_cache) / "maglevgen"
    folder = runtime_sources(carriage.structure, cache_dir=cache)
    src = folder / "maglev_simulate.c"
    good = src.read_bytes()
    src.write_bytes(good.replace(b"return n_steps;", b"return n_steps + 1;"))
    messages: list[str] = []
    assert runtime_sources(carriage.structure, cache_dir=cache,
                           progress=messages.append) == folder
    assert any("deriving" in m for m in messages)  # the source entry was regenerated
    assert src.read_bytes() == good
    # a truncated library (corrupted before anything maps it) is detected and rebuilt
    sources = [folder / "maglev_functions.c", folder / "maglev_simulate.c"]
    so = compile_shared(sources, cache_dir=cache / "lib")
    size = so.stat().st_size
    so.write_bytes(so.read_bytes()[:5000])
    messages.clear()
    lib = simulation_library(carriage.structure, cache_dir=cache, progress=messages.append)
    assert [m for m in messages if "compiling" in m] and lib.path == so
    assert so.stat().st_size == size


def test_missing_compiler_is_a_one_line_input_error(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("CC", "no-such-cc")
    (tmp_path / "a.c").write_text("int f(void) { return 0; }\n")
    with pytest.raises(InputError, match="C compiler 'no-such-cc' not found"):
        compile_shared([tmp_path / "a.c"], cache_dir=tmp_path / "c")


def test_compile_error_is_reported_and_nothing_cached(tmp_path) -> None:
    (tmp_path / "bad.c").write_text("int f(void) { return }\n")
    with pytest.raises(CompileError, match=r"compiling bad\.c failed: .*error"):
        compile_shared([tmp_path / "bad.c"], cache_dir=tmp_path / "c")
    assert not list((tmp_path / "c").glob("*.so"))


# ------------------------------------------------------------------------------ the CLI


@pytest.fixture(scope="module")
def cli_out(tmp_path_factory, sim_lib) -> Path:
    out = tmp_path_factory.mktemp("sim") / "out"
    assert main(["simulate", "--t-end", "2", "--out", str(out)]) == 0
    return out


def test_cli_writes_trajectories_figures_and_metrics(cli_out: Path, carriage) -> None:
    names = sorted(p.name for p in cli_out.iterdir())
    assert names == sorted([".maglevgen-output.json", "lateral_yaw.png", "levitation_pitch.png",
                            "travel_roll.png",
                            "metrics.json", "metrics.md", "trajectories.npz",
                            *(f"trajectory_{c}.csv" for c in controller_names())])
    for png in cli_out.glob("*.png"):
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    header = (cli_out / "trajectory_lqr.csv").read_text().splitlines()[2].split(",")
    assert header[:4] == ["t [s]", "x [m]", "y [m]", "z [m]"]
    assert "F_prop [N]" in header and "gap_6 [m]" in header
    data = np.loadtxt(cli_out / "trajectory_lqr.csv", delimiter=",", skiprows=3)
    assert data.shape == (2001, len(header))
    npz = np.load(cli_out / "trajectories.npz")
    assert list(npz["columns"]) == [h.split(" [")[0] for h in header]
    np.testing.assert_allclose(npz["lqr"], data, rtol=1e-9, atol=1e-300)
    # the rows are what numpy's own writer makes of the archived samples, byte for byte
    reference = io.StringIO()
    np.savetxt(reference, npz["lqr"], delimiter=",", fmt="%.10e")
    rows = (cli_out / "trajectory_lqr.csv").read_text().split("\n", 3)[3]
    assert rows == reference.getvalue()
    metrics = json.loads((cli_out / "metrics.json").read_text())
    runs = {r["controller"]: r for r in metrics["runs"]}
    assert set(runs) == set(controller_names())
    assert runs["damping"]["axes"]["vertical"]["settling_time"] is not None
    assert runs["none"]["axes"]["vertical"]["settling_time"] is None
    md = (cli_out / "metrics.md").read_text()
    assert "| vertical (z) |" in md and "not settled" in md


def test_cli_output_is_deterministic(cli_out: Path, tmp_path: Path) -> None:
    again = tmp_path / "again"
    assert main(["simulate", "--t-end", "2", "--out", str(again)]) == 0
    for f in cli_out.iterdir():
        assert (again / f.name).read_bytes() == f.read_bytes(), f.name


def test_cli_bad_step_exits_2_with_one_line(tmp_path: Path, sim_lib) -> None:
    out = tmp_path / "o"
    proc = subprocess.run([sys.executable, "-m", "maglevgen.cli", "simulate", "--dt", "0.2",
                           "--out", str(out)], capture_output=True, text=True,
                          env={**os.environ})
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1].startswith("maglevgen: error: --dt 0.2 s "
                                                           "exceeds the RK4 stability limit")
    assert not out.exists()


@pytest.mark.slow  # runs against solve_ivp
def test_reference_check_reports_small_deviation_and_catches_a_wrong_run(sim_lib, carriage,
                                                                         op) -> None:
    from maglevgen.analyses.reference import reference_check

    traj = _run(sim_lib, carriage, op, "lqr", 0.5)
    ok = reference_check(carriage.functions, carriage.p, traj)
    assert max(v["relative_to_peak"] for v in ok.values()) < 1e-4
    traj.x[:, AXIS_STATES[AXIS["pitch"]]] += 1e-4  # a run that drifted off in pitch
    bad = reference_check(carriage.functions, carriage.p, traj)
    assert bad["pitch"]["max_abs"] == pytest.approx(1e-4, rel=0.05)


def test_the_simulation_path_imports_no_symbolic_layer() -> None:
    """Running the compiled model (`maglevgen simulate`, the build's simulations) loads the
    parameters, the carriage and the cached library, and the build renders the C interface
    files, without importing SymPy, SciPy or CasADi (about a second of imports a parameter
    edit does not need before its simulations); the process that draws the report's figures
    does not import them either."""
    code = (
        "import sys\n"
        "from maglevgen.carriage import DerivedCarriage\n"
        "from maglevgen.runtime.library import cached_simulation_library\n"
        "from maglevgen.params import load_params\n"
        "import maglevgen.analyses.sim_output, maglevgen.analyses.simulate\n"
        "import maglevgen.report.figures\n"
        "from maglevgen.codegen.interface import GenerateOptions, render_interface\n"
        "c = DerivedCarriage(load_params(None, []))\n"
        "c.structure, c.p\n"
        "cached_simulation_library(c.structure)\n"
        "render_interface(c, GenerateOptions('double', 'runtime'), [])\n"
        "print(sorted(m for m in ('sympy', 'scipy', 'casadi', 'matplotlib') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=True).stdout
    assert out.strip() == "[]", out
