"""The operating envelope, the coupled LQR, the gain schedule and the launch run.

References independent of the code under test: the SymPy model (lambdified, derive.numeric)
and its linearisation, python-control's ``lqr`` on plants assembled here, the allocation as
numpy's pseudo-inverse of the effectiveness matrix, scipy's ``CubicSpline`` for the schedule
and ``solve_ivp`` for the launch run.
"""

from __future__ import annotations

import ctypes
import json
import subprocess
import sys

import control
import numpy as np
import pytest
from independent_reference import spec_weights_reference
from scipy.integrate import solve_ivp

from maglevgen.analyses.envelope import STABILITY_MARGIN, compute_envelope
from maglevgen.analyses.simulate import AXIS_STATES, initial_state, launch
from maglevgen.carriage import DerivedCarriage
from maglevgen.cli import main
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.schedule import Schedule
from maglevgen.control.symbolic_reference import effectiveness
from maglevgen.derive import conventions as cv
from maglevgen.params import load_params

RED = [cv.STATE_INDEX[s] for s in ("y", "z", "phi", "theta", "psi", "v", "w", "p", "q", "r")]
AX = list(AXIS_STATES)


def _reference_eigenvalues(carriage: DerivedCarriage, v: float) -> dict[str, np.ndarray]:
    """Closed-loop eigenvalues of the ten-state loop at v, assembled from the SymPy model:
    its trim and Jacobians, gains from python-control, T = pinv(E)."""
    trim = carriage.trim(v)
    A, B = carriage.linearize(trim)
    T = np.linalg.pinv(effectiveness(carriage))
    Ar, Bg = A[np.ix_(RED, RED)], B[RED, 1:] @ T
    S = np.eye(5, 10)
    C = A[np.ix_(AX, RED)]  # the axis rates as a function of the reduced state
    k = np.diag(carriage.total_stiffness(trim))
    m = carriage.generalized_mass()
    (q1, q2), r = carriage.params.control.state_weights, carriage.params.control.input_weight
    Kp, Kr = np.zeros(5), np.zeros(5)
    for i in range(5):
        K, _, _ = control.lqr([[0, 1], [-k[i] / m[i], 0]], [[0], [1 / m[i]]],
                              np.diag([q1, q2]), [[r]])
        Kp[i], Kr[i] = np.asarray(K).ravel()
    c = np.where(k > 0, np.sqrt(np.maximum(k, 0) * m), 0.0)  # optimized damping sqrt(k m)
    K_c, _, _ = control.lqr(Ar, Bg, q1 * S.T @ S + q2 * C.T @ C, r * np.eye(5))
    q1s, q2s, rs = spec_weights_reference(carriage.params.control.spec, k, m, T)
    Q_s = S.T @ np.diag(q1s) @ S + C.T @ np.diag(q2s) @ C
    # symmetric to round-off, which python-control's check compares with an absolute eps
    K_s, _, _ = control.lqr(Ar, Bg, (Q_s + Q_s.T) / 2, np.diag(rs))
    return {
        "none": np.linalg.eigvals(Ar),
        "damping": np.linalg.eigvals(Ar - Bg @ (np.diag(c) @ C)),
        "lqr": np.linalg.eigvals(Ar - Bg @ (np.diag(Kp) @ S + np.diag(Kr) @ C)),
        "coupled": np.linalg.eigvals(Ar - Bg @ np.asarray(K_c)),
        "spec": np.linalg.eigvals(Ar - Bg @ np.asarray(K_s)),
    }




POINT = 'model.array_force="point"'
# the paper's model: eq 3 at the face centres with quasi-static circuits (no lag)
QUASI_STATIC = 'model.circuit_dynamics="quasi-static"'


@pytest.fixture(scope="module")
def envelope(carriage: DerivedCarriage, sim_lib):
    return compute_envelope(Plant(carriage, sim_lib), 12)


@pytest.fixture(scope="module")
def point_carriage(private_cache) -> DerivedCarriage:
    """The paper's force law (eq 3 at each face centre, quasi-static circuits): its per-axis
    LQR and damping control lose stability in the low part of the range."""
    return DerivedCarriage(load_params(None, [POINT, QUASI_STATIC]))


@pytest.fixture(scope="module")
def point_lib(point_carriage: DerivedCarriage):
    from maglevgen.runtime.library import simulation_library

    return simulation_library(point_carriage.structure)


@pytest.fixture(scope="module")
def point_envelope(point_carriage: DerivedCarriage, point_lib):
    return compute_envelope(Plant(point_carriage, point_lib), 12)


@pytest.mark.parametrize("index", [0, 3, 6, 11])
def test_eigenvalues_match_an_independent_assembly(carriage, envelope, index) -> None:
    """Largest real part per controller at several speeds: the C path (envelope) against the
    SymPy linearisation closed by python-control's gains; the stable flag follows the sign."""
    v = float(envelope.speeds[index])
    ref = _reference_eigenvalues(carriage, v)
    for name, ev in ref.items():
        got = envelope.controllers[name].max_real[index]
        want = float(np.max(ev.real))
        assert got == pytest.approx(want, rel=1e-5, abs=1e-7), (name, v)
        assert bool(envelope.controllers[name].stable[index]) == (want < -STABILITY_MARGIN)


def test_default_verdicts_follow_independent_eigenvalues(carriage, envelope) -> None:
    """With the distributed array force and the circuits' lag (the default) each verdict is
    what the independently assembled eigenvalues say at every speed of the envelope: the
    coupled LQR, designed on the lagged model, holds; the per-axis LQR, whose rate gains
    (about 1 N s/m) are below the lag's negative damping above v_c, does not; without control
    the loop is unstable."""
    worst = {name: max(float(np.max(_reference_eigenvalues(carriage, float(v))[name].real))
                       for v in envelope.speeds) for name in envelope.controllers}
    for name, c in envelope.controllers.items():
        assert c.ok == (worst[name] < -STABILITY_MARGIN), name
        assert c.verdict.startswith("stable across" if c.ok else "UNSTABLE"), name
    assert envelope.controllers["coupled"].ok and envelope.controllers["damping"].ok
    assert not envelope.controllers["lqr"].ok
    assert envelope.controllers["spec"].ok
    assert not envelope.controllers["none"].ok


def test_point_force_verdicts(point_envelope) -> None:
    """The paper's point force: the per-axis LQR loses stability in the low part of the
    range; the coupled LQR holds across it; no control is unstable everywhere."""
    lqr, coupled, none = (point_envelope.controllers[n] for n in ("lqr", "coupled", "none"))
    assert coupled.ok and coupled.verdict.startswith("stable across")
    assert not lqr.ok and lqr.verdict.startswith("UNSTABLE for v in")
    (lo, hi), = lqr.unstable_ranges
    assert point_envelope.v_min < lo < hi < 20.0
    assert not none.ok and "UNSTABLE" in none.verdict


def test_unstable_range_edges_are_where_the_sign_changes(point_carriage, point_envelope) -> None:
    """Just inside the reported range the reference has a positive real part, just outside
    a negative one (point force law)."""
    (lo, hi), = point_envelope.controllers["lqr"].unstable_ranges
    for v, sign in ((lo - 0.02, -1), (lo + 0.02, 1), (hi - 0.02, 1), (hi + 0.02, -1)):
        worst = float(np.max(_reference_eigenvalues(point_carriage, v)["lqr"].real))
        assert np.sign(worst) == sign, v


def test_stable_range_gives_a_stable_verdict(point_lib) -> None:
    """With the envelope above the per-axis LQR's unstable range its verdict is stable."""
    c = DerivedCarriage(load_params(None, [POINT, QUASI_STATIC, "envelope.v_min=17.0"]))
    env = compute_envelope(Plant(c, point_lib), 8, ("lqr",))
    assert env.controllers["lqr"].ok
    ev = _reference_eigenvalues(c, 17.0)["lqr"]
    assert np.max(ev.real) < 0


def test_heavier_carriage_is_unstable_at_the_design_speed(point_lib) -> None:
    """The issue's case (point force law): mass 12 kg makes the per-axis LQR unstable at
    20 m/s."""
    c = DerivedCarriage(load_params(None, [POINT, QUASI_STATIC, "vehicle.mass=12"]))
    env = compute_envelope(Plant(c, point_lib), 8, ("lqr", "coupled"))
    assert max(float(np.max(_reference_eigenvalues(c, 20.0)["lqr"].real)), 0) > 0
    assert any(lo <= 20.0 <= hi for lo, hi in env.controllers["lqr"].unstable_ranges)
    assert env.controllers["coupled"].ok


@pytest.mark.parametrize(("law", "controller", "speed", "stable"),
                         [("point", "lqr", 12.5, False), ("point", "none", 8.0, False),
                          ("distributed", "lqr", 9.0, True),
                          ("distributed", "damping", 30.0, True),
                          ("distributed", "coupled", 30.0, True)])
def test_simulation_agrees_with_the_verdict(request, law, controller, speed, stable) -> None:
    """Where the envelope says unstable with margin, the nonlinear run does not settle (it
    diverges or hits the track); where it is stable with margin, the run decays. The speed is
    held as the envelope assumes: the propulsion follows the trim drag at the current speed
    (maglev_launch without the acceleration force) and the gains stay those of the speed."""
    carriage, lib = (request.getfixturevalue(n) for n in (
        ("point_carriage", "point_lib") if law == "point" else ("carriage", "sim_lib")))
    points = Plant(carriage, lib).points(np.linspace(speed - 2.0, speed + 2.0, 5))
    op = points[2]
    worst = float(np.max(np.linalg.eigvals(op.reduced_closed_loop(controller)).real))
    assert (worst < -0.05) if stable else (worst > 0.2)
    traj = launch(lib, carriage.p, Schedule.from_points(points, controller), op, 1e3, 0.0,
                  1e-3, carriage.params.track.min_gap, max_time=10.0)
    assert abs(traj.speed[-1] - speed) < 1.0 or traj.status == "contact"
    if stable:
        dev = np.abs(traj.axis_deviation)
        assert traj.status != "contact" and traj.status != "diverging"
        # the slowest stable mode (-0.06 1/s for the paper-weight LQRs) leaves 0.55 after 10 s
        assert np.all(dev[-500:].max(axis=0) < 0.7 * dev.max(axis=0))
    else:
        assert traj.status in ("contact", "diverging")


# ------------------------------------------------------------------------------ schedule


def test_schedule_eval_in_c_equals_scipy_spline(carriage, sim_lib) -> None:
    """maglev_schedule_eval (C) against scipy's natural CubicSpline of the same nodes, with
    clamping outside the range and the non-finite code."""
    points = Plant(carriage, sim_lib).points(np.linspace(8.0, 30.0, 9))
    sched = Schedule.from_points(points, "coupled")
    spline = sched.spline
    y = np.ascontiguousarray(sched.values)
    d2 = np.ascontiguousarray(sched.second_derivatives)
    P = ctypes.POINTER(ctypes.c_double)
    s = sim_lib._Schedule(9, 8.0, sched.speeds[1] - 8.0, y.ctypes.data_as(P),
                          d2.ctypes.data_as(P))
    fn = sim_lib._lib.maglev_schedule_eval
    fn.restype = ctypes.c_int
    fn.argtypes = [ctypes.POINTER(sim_lib._Schedule), ctypes.c_double, P]
    out = np.zeros(y.shape[1])
    for v in np.random.default_rng(3).uniform(8.0, 30.0, 25):
        assert fn(ctypes.byref(s), v, out.ctypes.data_as(P)) == 0
        np.testing.assert_allclose(out, spline(v), rtol=1e-11, atol=1e-12)
    # Schedule.at on an array of speeds (what a launch's reference reads), clamped like the C
    speeds = np.concatenate([np.random.default_rng(4).uniform(8.0, 30.0, 20), [5.0, 45.0]])
    rows = sched.at(speeds)
    assert rows.shape == (speeds.size, y.shape[1])
    for v, row in zip(speeds, rows, strict=True):
        assert fn(ctypes.byref(s), v, out.ctypes.data_as(P)) in (0, 1)  # 1: clamped
        np.testing.assert_allclose(row, out, rtol=1e-11, atol=1e-12)
    assert fn(ctypes.byref(s), 40.0, out.ctypes.data_as(P)) == 1
    np.testing.assert_allclose(out, y[-1], rtol=1e-12, atol=1e-12)
    out[:] = 7.0
    assert fn(ctypes.byref(s), float("nan"), out.ctypes.data_as(P)) == 2
    assert np.all(out == 7.0)


def test_schedule_gains_reproduce_the_coupled_lqr(carriage, sim_lib) -> None:
    """At a node, the scheduled (K_pos, K_rate) written in (a, a') equal python-control's
    coupled LQR K (on the reduced state) through the rate map."""
    points = Plant(carriage, sim_lib).points([25.0, 26.0])
    op = points[0]
    _, _, K_pos, K_rate = Schedule.unpack(Schedule.from_points(points, "coupled").values[0])
    A = op.A
    Ar, Bg = A[np.ix_(RED, RED)], op.B[RED, 1:] @ np.linalg.pinv(effectiveness(carriage))
    C = A[np.ix_(AX, RED)]
    S = np.eye(5, 10)
    K_ref, _, _ = control.lqr(Ar, Bg, S.T @ S + C.T @ C, np.eye(5))
    np.testing.assert_allclose(K_pos @ S + K_rate @ C, np.asarray(K_ref), rtol=1e-6,
                               atol=1e-8 * np.abs(K_ref).max())


# ------------------------------------------------------------------------------- launch


def _launch_reference(carriage: DerivedCarriage, sched: Schedule, x0: np.ndarray, f_extra: float,
                      t: np.ndarray) -> np.ndarray:
    """The launch closed loop by DOP853 on the lambdified SymPy model, with the schedule
    evaluated by scipy's spline at |(u, v, w)| at every evaluation."""
    fns = carriage.functions
    T = np.linalg.pinv(effectiveness(carriage))
    n_u = carriage.model.u.shape[0]
    spline = sched.spline

    def rhs(_t: float, x: np.ndarray) -> np.ndarray:
        v = np.clip(np.linalg.norm(x[6:9]), sched.speeds[0], sched.speeds[-1])
        f_drag, a_ref, K_pos, K_rate = Schedule.unpack(spline(v))
        rates = fns.xdot(x, np.zeros(n_u), carriage.p).ravel()[AX]  # kinematics only
        u = np.concatenate([[f_drag + f_extra],
                            T @ -(K_pos @ (x[AX] - a_ref) + K_rate @ rates)])
        return fns.xdot(x, u, carriage.p).ravel()

    sol = solve_ivp(rhs, (t[0], t[-1]), x0, method="DOP853", t_eval=t, rtol=1e-12,
                    atol=1e-13)
    assert sol.success
    return sol.y.T


@pytest.mark.slow  # launch runs at four steps against solve_ivp
def test_launch_run_converges_to_the_reference_as_dt4(carriage, sim_lib) -> None:
    """maglev_launch with the schedule evaluated at every RK4 stage against solve_ivp on the
    SymPy model with the same schedule: the error shrinks as dt^4 between two step sizes."""
    points = Plant(carriage, sim_lib).points(np.linspace(7.0, 12.0, 11))
    sched = Schedule.from_points(points, "coupled")
    f_extra = carriage.params.vehicle.mass * 5.0
    trajs = [launch(sim_lib, carriage.p, sched, points[0], 40.0, f_extra, dt,
                    carriage.params.track.min_gap, max_time=0.8, hold_steps=0)
             for dt in (4e-3, 2e-3)]
    x0 = initial_state(points[0], trajs[0].disturbance)
    assert np.array_equal(initial_state(points[0], trajs[1].disturbance), x0)
    # one reference solve for both step sizes (the same initial value problem), sampled at
    # both runs' times: its steps do not depend on t_eval (dense output between them)
    t_ref = np.union1d(trajs[0].t, trajs[1].t)
    ref_all = _launch_reference(carriage, sched, x0, f_extra, t_ref)
    errors = []
    for traj in trajs:
        assert traj.c_status == 0 and traj.t[-1] == pytest.approx(0.8)
        ref = ref_all[np.searchsorted(t_ref, traj.t)]
        scale = np.maximum(np.abs(ref - ref[0]).max(axis=0), 1e-9)
        errors.append(float(np.max(np.abs(traj.x - ref) / scale)))
        # the speed follows the steady acceleration force: about 5 m/s^2
        assert traj.speed[-1] - traj.speed[0] == pytest.approx(0.8 * 5.0, rel=0.05)
    assert errors[1] < 1e-4  # relative to each state's excursion (the stiff coupled loop)
    assert 10.0 < errors[0] / errors[1] < 24.0  # 2^4 = 16


@pytest.mark.parametrize("controller", ["damping", "coupled"])
def test_launch_follows_the_accelerating_trim_found_here(carriage, sim_lib,
                                                         controller: str) -> None:
    """An undisturbed launch from 8 to 12 m/s at envelope.launch_acceleration with the launch
    schedule (reference and feedforward of the accelerating trim, Plant.launch_schedule)
    from the accelerating trim at 8 m/s: at five speeds on the way the pitch and heave are
    those of the root of the static balances with the d'Alembert load -m a at the CG solved
    here (independent_reference) within a tenth of that trim's offset from the constant-speed
    one (4 to 4.6 mrad here; the launch used to keep it as a steady pitch deviation) and
    0.15 mm; the run's deviation from its equilibrium (the schedule's) is as small."""
    from independent_reference import reference_trim

    from maglevgen.control.operating import checked_accelerating_trim

    prm = carriage.params
    a, min_gap = prm.envelope.launch_acceleration, prm.track.min_gap
    points = Plant(carriage, sim_lib).points(np.linspace(8.0, 12.0, 9))
    x_start = checked_accelerating_trim(sim_lib, carriage.p, 8.0, a, min_gap)[0]
    traj = launch(sim_lib, carriage.p, Plant(carriage, sim_lib).launch_schedule(points, controller),
                  points[0], 12.0, prm.vehicle.mass * a, 1e-3, min_gap, max_time=2.0,
                  disturbance={}, x_start=x_start)
    assert traj.c_status == 0 and traj.speed[-1] >= 12.0
    pitch, heave = cv.STATE_INDEX["theta"], cv.STATE_INDEX["z"]
    for k in np.linspace(0, traj.t.size - 1, 5).astype(int):
        ref, still = (reference_trim(prm, float(traj.speed[k]), acc) for acc in (a, 0.0))
        offset = ref.q[3] - still.q[3]
        assert offset < -3e-3  # nose down: the CG above the thrust's line of action
        assert abs(traj.x[k, pitch] - ref.q[3]) < 0.1 * abs(offset), (traj.speed[k], k)
        assert abs(traj.x[k, heave] - ref.q[1]) < 1.5e-4
        assert abs(traj.axis_deviation[k, 3]) < 0.1 * abs(offset)


def test_launch_cli_reaches_release_speed(tmp_path, capsys) -> None:
    """simulate --scenario launch: every designed controller runs from v_min to v_max with
    the gains scheduled in C; metrics carry the scenario, speeds and statuses."""
    out = tmp_path / "launch"
    assert main(["simulate", "--scenario", "launch", "--controller", "coupled",
                 "--out", str(out)]) == 0
    m = json.loads((out / "metrics.json").read_text())
    run = m["runs"][0]
    assert m["scenario"] == "launch" and run["scenario"] == "launch"
    # the trajectory written beside it starts at v_min and ends at the release speed
    npz = np.load(out / "trajectories.npz")
    cols = [list(npz["columns"]).index(s) for s in ("u", "v", "w")]
    speed = np.linalg.norm(npz["coupled"][:, cols], axis=1)
    c = DerivedCarriage(load_params())
    assert speed[-1] >= c.params.envelope.v_max - 1e-9 > speed[-2]
    assert speed[0] < 0.5 * c.params.envelope.v_max
    assert np.all(np.diff(speed) > 0)  # the steady acceleration force: monotonic
    assert run["status"] in ("settled", "not settled")
    assert run["speed_at_contact"] is None


def test_envelope_cli_json_and_files(tmp_path, capsys) -> None:
    out = tmp_path / "env"
    assert main(["envelope", "--speeds", "6", "--json", "--out", str(out)]) == 0
    data = json.loads(capsys.readouterr().out)
    assert len(data["speeds"]) == 6
    assert set(data["controllers"]) == {"none", "damping", "lqr", "coupled", "spec"}
    for c in data["controllers"].values():
        assert c["stable"] == [r < -STABILITY_MARGIN for r in c["max_real"]]
    assert (out / "stability_map.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bad_envelope_input_is_one_line_exit_2(tmp_path) -> None:
    for sets, key in ((["envelope.v_min=2.0"], "envelope.v_min"),
                      (["envelope.v_min=50.0"], "envelope.v_min"),
                      (['envelope.embedded_controller="pid"'], "envelope.embedded_controller")):
        proc = subprocess.run([sys.executable, "-m", "maglevgen.cli", "envelope", "--speeds",
                               "4", *[a for s in sets for a in ("--set", s)]],
                              capture_output=True, text=True)
        assert proc.returncode == 2, proc.stderr
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and key in lines[0], proc.stderr


@pytest.mark.slow  # a whole build of its own
def test_build_exits_3_when_the_embedded_controller_is_unstable(tmp_path) -> None:
    """The per-axis LQR embedded with the point force law: outputs written, SUMMARY says
    UNSTABLE, exit 3 with one line; --allow-unstable turns it into a warning (exit 0)."""
    out = tmp_path / "b"
    args = [sys.executable, "-m", "maglevgen.cli", "build", "--no-pdf", "--t-end", "1",
            "--out", str(out), "--controller", "lqr", "--set", POINT, "--set", QUASI_STATIC]
    proc = subprocess.run(args, capture_output=True, text=True)
    assert proc.returncode == 3, proc.stderr
    err = [line for line in proc.stderr.splitlines() if "error" in line]  # besides progress
    assert len(err) == 1 and proc.stderr.strip().endswith(err[0])
    assert "lqr" in err[0] and "UNSTABLE" in err[0]
    summary = (out / "SUMMARY.md").read_text()
    assert "UNSTABLE for v in" in summary
    assert (out / "envelope" / "envelope.json").exists()
    again = subprocess.run([*args, "--allow-unstable"], capture_output=True, text=True)
    assert again.returncode == 0 and "warning" in again.stderr


@pytest.mark.slow  # the schedule table compiled and evaluated across the envelope
def test_embedded_schedule_table_compiles_and_evaluates(carriage, sim_lib, tmp_path) -> None:
    """c/maglev_schedule.c (static const tables) compiled with the runtime C: the firmware's
    maglev_schedule_eval(&maglev_embedded_schedule, v) equals scipy's spline of the nodes."""
    import shutil

    from maglevgen.control.schedule import schedule_c_source
    from maglevgen.runtime.compile import compile_shared
    from maglevgen.runtime.library import runtime_sources

    points = Plant(carriage, sim_lib).points(np.linspace(7.0, 40.0, 12))
    sched = Schedule.from_points(points, "coupled")
    src = tmp_path / "src"
    shutil.copytree(runtime_sources(carriage.structure), src)
    (src / "maglev_schedule.c").write_text(schedule_c_source(sched))
    lib = ctypes.CDLL(str(compile_shared(sorted(src.glob("*.c")), cache_dir=tmp_path / "c",
                                         flags=("-std=c99", "-O2", "-fPIC", "-shared",
                                                "-Wall", "-Werror"))))
    P = ctypes.POINTER(ctypes.c_double)
    fn = lib.maglev_schedule_eval
    fn.restype = ctypes.c_int
    fn.argtypes = [ctypes.c_void_p, ctypes.c_double, P]
    table = ctypes.c_void_p.in_dll(lib, "maglev_embedded_schedule")
    out = np.zeros(sched.values.shape[1])
    for v in (7.0, 13.3, 25.0, 39.99):
        assert fn(ctypes.addressof(table), v, out.ctypes.data_as(P)) == 0
        np.testing.assert_allclose(out, sched.spline(v), rtol=1e-12, atol=1e-12)
