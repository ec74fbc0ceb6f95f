"""The firmware's sense tick (maglev_sense_init / maglev_sense_tick: the Kalman filter's update
on the sensors' readings, the law of maglev_tick on the updated estimate, the prediction) and
its schedule (estimation.sense_table).

References: the estimator's equations written out here in numpy (the table by Clenshaw in the
C's order at the speed of the cache in use, the update, the prediction with the lag and the
queue, the cache's refresh a slice a tick) and the law of
test_tick_state.NumpyTick (SymPy's rates, pinv of the SymPy effectiveness); the table's rows
against the EstimatorModel and KalmanDesign matrices and M against control.dlqe; the closed
loop of the C tick (linearised by central differences) around the plant built here
(control.c2d of the C's Jacobians with the lag, the delay, the sensors' linearisation) against
estimation.loop_as_built's eigenvalues; hostile readings under ASan/UBSan.
"""

from __future__ import annotations

import ctypes
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from test_tick_state import NumpyTick, _allocation, _clenshaw, _fields

from maglevgen.carriage import DerivedCarriage
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.operating import AXIS_STATES

OK = 0
NODES = 10  # the test's tables: Chebyshev interpolants at this many nodes (no dense check)


def _interpolant(rows, v_min: float, v_max: float, fields):
    """A GainTable interpolating ``rows`` at NODES Chebyshev nodes (every value stored that is
    not zero at all of them): the C's equations do not depend on how the table was fitted."""
    from numpy.polynomial import chebyshev

    from maglevgen.control.schedule import GainTable

    nodes = GainTable.nodes(NODES, v_min, v_max)
    exact = rows(nodes)
    coeffs = chebyshev.chebfit(GainTable.t_of(nodes, v_min, v_max), exact, NODES - 1)
    stored = tuple(int(j) for j in np.flatnonzero(np.max(np.abs(exact), axis=0) > 0))
    coeffs[:, [j for j in range(exact.shape[1]) if j not in stored]] = 0.0
    return GainTable(v_min, v_max, coeffs, {name: 0.0 for name, _ in fields}, stored, fields)


@pytest.fixture(scope="module")
def sense(carriage: DerivedCarriage, sim_lib, tmp_path_factory) -> dict:
    """The firmware folder in double precision with the sense tick (tables interpolating the
    exact schedules at NODES nodes), compiled into a host library."""
    from maglevgen.codegen.checks import ERROR_CODES
    from maglevgen.codegen.generate import write_output
    from maglevgen.control import estimation as est
    from maglevgen.control import sense_table as stab
    from maglevgen.control.schedule import tick_table_fields
    from maglevgen.derive import conventions as cv
    from maglevgen.exports.firmware import SenseSchedule, render_firmware

    params = carriage.params
    plant = Plant(carriage, sim_lib)
    v_min, v_max = plant.speed_range
    setting = loop = plant.loop
    table = _interpolant(lambda vs: plant.tick_table_rows(setting, vs), v_min,
                         v_max, tick_table_fields(setting.tick.delay))
    layout = est.SensorLayout.of(params)
    nu = carriage.model.u.shape[0]
    n_lag = nu - 1 if loop.actuator_lag > 0 else 0
    states = tuple(s for s in cv.STATE_NAMES if layout.track or s != "x")
    fields = stab.sense_fields(len(states), n_lag, nu, len(layout.names))

    def sense_rows(vs):
        pts = plant.points(vs)
        return np.array([sp.row() for sp in stab.sense_plants(
            sim_lib, carriage.p, params, pts, loop.actuator_lag, loop.delay_ticks)])

    sense_table = _interpolant(sense_rows, v_min, v_max, fields)
    schedule = SenseSchedule(sense_table, states, n_lag, layout.names,
                             stab.reading_ranges(layout), len(layout.gaps))
    folder = tmp_path_factory.mktemp("sense_tick")

    def build(table, schedule, folder) -> Path:
        """The folder with these tables rendered and compiled: its host library."""
        write_output(render_firmware(carriage, table, loop, "double", sense=schedule), folder)
        so = folder / "sense.so"
        subprocess.run(["cc", "-std=c99", "-O2", "-fPIC", "-shared", "-Wall", "-Wextra",
                        "-Werror", "maglev_tick.c", "maglev_gain_table.c", "maglev_sense_table.c",
                        "maglev_functions.c", "-lm", "-o", str(so)], cwd=folder, check=True)
        return so

    def frozen(v: float) -> Path:
        """The library with the law's table constant at its exact row at speed v: the
        feedforward and the reference not scheduled on the estimated speed, as in the loop as
        built (control.plant: F_ff and a_ref fixed); the estimator's table as above."""
        row = Plant(carriage, sim_lib).tick_table_rows(setting, [v])[0]
        coeffs = np.zeros_like(table.coeffs)
        coeffs[0] = row
        const = replace(table, coeffs=coeffs, stored=tuple(int(j) for j in np.flatnonzero(row)))
        return build(const, schedule, tmp_path_factory.mktemp("sense_frozen"))

    def render(precision: str, out: Path) -> None:
        write_output(render_firmware(carriage, table, loop, precision, sense=schedule), out)

    return {"so": build(table, schedule, folder), "table": table, "loop": loop,
            "render": render,
            "setting": setting, "folder": folder, "schedule": schedule, "layout": layout,
            "nu": nu, "frozen": frozen, "codes": {k: v for k, (v, _) in ERROR_CODES.items()}}


def _law_state(delay: int) -> type[ctypes.Structure]:
    class Law(ctypes.Structure):
        _fields_ = [("in_flight", ctypes.c_double * (5 * max(delay, 1))),
                    ("w_hat", ctypes.c_double * 5), ("xi", ctypes.c_double)]
    return Law


#: the cache's fields of the state (after `rejected`)
CACHE = ("tab", "v_tab", "use", "slice")


class CSense:
    """maglev_sense_init / maglev_sense_tick of the compiled folder through ctypes."""

    def __init__(self, fx: dict, so: Path | None = None) -> None:
        from maglevgen.control.schedule import varying_values

        d, nu, n_lag = fx["loop"].delay_ticks, fx["nu"], fx["schedule"].n_lag
        nv = max(len(varying_values(fx["schedule"].table)), 1)

        class State(ctypes.Structure):
            _fields_ = [("x_pred", ctypes.c_double * 12),
                        ("f_pred", ctypes.c_double * max(n_lag, 1)),
                        ("u_flight", ctypes.c_double * (nu * max(d, 1))),
                        ("law", _law_state(d)), ("rejected", ctypes.c_ulong),
                        ("tab", (ctypes.c_double * nv) * 2), ("v_tab", ctypes.c_double * 2),
                        ("use", ctypes.c_uint), ("slice", ctypes.c_uint)]

        lib = ctypes.CDLL(str(so or fx["so"]))
        P = ctypes.POINTER(ctypes.c_double)
        self.nu, self.n_lag = nu, n_lag
        self._init, self._tick = lib.maglev_sense_init, lib.maglev_sense_tick
        self._init.argtypes = [ctypes.POINTER(State), P, ctypes.c_ulong, ctypes.c_double]
        self._tick.argtypes = [ctypes.POINTER(State), P, ctypes.c_ulong, ctypes.c_double,
                               ctypes.c_double, P]
        self.s = State()

    def init(self, y: np.ndarray, valid: int, v0: float) -> int:
        ys = np.ascontiguousarray(y, dtype=float)
        return self._init(ctypes.byref(self.s), ys.ctypes.data_as(ctypes.POINTER(
            ctypes.c_double)), valid, float(v0))

    def __call__(self, y: np.ndarray, valid: int, v_ref: float,
                 a_ref: float = 0.0) -> tuple[int, np.ndarray]:
        P = ctypes.POINTER(ctypes.c_double)
        ys = np.ascontiguousarray(y, dtype=float)
        u = np.full(self.nu, 7.0)
        rc = self._tick(ctypes.byref(self.s), ys.ctypes.data_as(P), valid, float(v_ref),
                        float(a_ref), u.ctypes.data_as(P))
        return rc, u

    def state(self) -> dict:
        s = self.s
        return {"x_pred": np.array(s.x_pred[:]), "f_pred": np.array(s.f_pred[:self.n_lag]),
                "u_flight": np.array(s.u_flight[:]), "in_flight": np.array(s.law.in_flight[:]),
                "w_hat": np.array(s.law.w_hat[:]), "xi": float(s.law.xi),
                "rejected": int(s.rejected), "tab": np.array([s.tab[0][:], s.tab[1][:]]),
                "v_tab": np.array(s.v_tab[:]), "use": int(s.use), "slice": int(s.slice)}

    def set_state(self, st: dict) -> None:
        s = self.s
        for name in ("x_pred", "f_pred", "u_flight"):
            for i, v in enumerate(st[name]):
                getattr(s, name)[i] = float(v)
        for name in ("in_flight", "w_hat"):
            for i, v in enumerate(st[name]):
                getattr(s.law, name)[i] = float(v)
        s.law.xi = float(st["xi"])
        if "tab" in st:  # the cache too
            for b in range(2):
                for i, v in enumerate(st["tab"][b]):
                    s.tab[b][i] = float(v)
                s.v_tab[b] = float(st["v_tab"][b])
            s.use, s.slice = int(st["use"]), int(st["slice"])


class NumpySense:
    """The sense tick's estimator (maglev_tick.h's equations), written out here in Python
    floats in the C's order: the table at the speed of the cache in use, the update on the
    usable readings, and (given the command) the prediction with the exact lag and the
    queue, then the cache's refresh (a slice at the other buffer's speed; after the last, the
    swap and the next refresh's speed: the new prediction's)."""

    def __init__(self, fx: dict) -> None:
        from maglevgen.control.schedule import varying_values
        from maglevgen.derive import conventions as cv
        from maglevgen.exports.firmware import SENSE_REFRESH_TICKS, refresh_slices

        self.sch, self.loop, self.nu = fx["schedule"], fx["loop"], fx["nu"]
        self.varying = varying_values(self.sch.table)
        self.slices, self.ticks = refresh_slices(self.sch.table), SENSE_REFRESH_TICKS
        self.f = _fields(self.sch.table)
        self.idx = [cv.STATE_INDEX[s] for s in self.sch.states]
        self.ne, self.nl, self.ny = len(self.idx), self.sch.n_lag, len(self.sch.readings)

    def update(self, st: dict, y: np.ndarray, valid: int) -> dict:
        table, f, ne, nc, ny, nu = (self.sch.table, self.f, self.ne, self.ne + self.nl,
                                    self.ny, self.nu)
        x = st["x_pred"]
        vc = float(st["v_tab"][st["use"]])
        g = _clenshaw(table, vc)
        x_trim = g[f["x_trim"]].copy()
        x_trim[6] += vc
        dz = [float(x[i] - x_trim[i]) for i in self.idx] + [float(v) for v in st["f_pred"]]
        du = [float(v) for v in st["u_flight"][-nu:]]
        du[0] -= float(g[f["F_prop"]][0])
        C, D, M = g[f["C"]], g[f["D"]], g[f["M"]]
        lo, hi = self.sch.ranges[:, 0], self.sch.ranges[:, 1]
        innov, rejected, n_gap = [0.0] * ny, 0, 0
        for j in range(ny):
            if (valid >> j) & 1 and np.isfinite(y[j]) and lo[j] <= y[j] <= hi[j]:
                acc = float(y[j]) - float(g[f["y_trim"]][j])
                for i in range(nc):
                    acc -= float(C[j + ny * i]) * dz[i]
                for i in range(nu):
                    acc -= float(D[j + ny * i]) * du[i]
                innov[j] = acc
                n_gap += j < self.sch.n_gap
            else:
                rejected |= 1 << j
        x_hat = x.copy()
        for i in range(ne):
            acc = 0.0
            for j in range(ny):
                acc += float(M[i + ne * j]) * innov[j]
            x_hat[self.idx[i]] += acc
            dz[i] += acc
        return {"g": g, "vc": vc, "x_trim": x_trim, "dz": dz, "du": du, "x_hat": x_hat,
                "rejected": rejected, "n_gap": n_gap, "innov": np.array(innov)}

    def predict(self, st: dict, up: dict, u: np.ndarray) -> dict:
        f, ne, nc, nu = self.f, self.ne, self.ne + self.nl, self.nu
        g, dz, du = up["g"], up["dz"], list(up["du"])
        if self.loop.delay_ticks == 0:
            du = [float(v) for v in u]
            du[0] -= float(g[f["F_prop"]][0])
        P, G = g[f["Phi_minus_I"]], g[f["Gamma"]]
        x_pred = st["x_pred"].copy()
        for i in range(ne):
            acc = dz[i]
            for j in range(nc):
                acc += float(P[i + ne * j]) * dz[j]
            for j in range(nu):
                acc += float(G[i + ne * j]) * du[j]
            x_pred[self.idx[i]] = up["x_trim"][self.idx[i]] + acc
        x_pred[0] += (1.0 / self.loop.tick_rate) * up["vc"]
        a = self.loop.lag_pole
        f_pred = np.array([a * st["f_pred"][i] + (1.0 - a) * du[1 + i]
                           for i in range(self.nl)])
        q = st["u_flight"]
        u_flight = np.concatenate([u, q[:-nu]]) if len(q) > nu else np.array(u, dtype=float)
        tab, v_tab, use, k = st["tab"].copy(), st["v_tab"].copy(), st["use"], st["slice"]
        back = 1 - use
        row = _clenshaw(self.sch.table, float(v_tab[back]))
        for i in range(self.slices[k], self.slices[k + 1]):
            tab[back, i] = row[self.varying[i]]
        k += 1
        if k == self.ticks:
            table = self.sch.table
            v = float(np.sqrt((x_pred[6] * x_pred[6] + x_pred[7] * x_pred[7])
                              + x_pred[8] * x_pred[8]))
            use, k = back, 0
            v_tab[1 - back] = min(max(v, table.v_min), table.v_max)
        return {"x_pred": x_pred, "f_pred": f_pred, "u_flight": u_flight, "tab": tab,
                "v_tab": v_tab, "use": use, "slice": k}


def _readings(fx: dict, nps: NumpySense, st: dict, rng, scale: float = 3.0) -> np.ndarray:
    """Readings near what the filter predicts (its model's readings of its own prediction)
    with noise of ``scale`` times each reading's standard deviation."""
    up = nps.update(st, np.zeros(nps.ny), 0)
    f, g = nps.f, up["g"]
    C = g[f["C"]].reshape(nps.ny, -1, order="F")
    D = g[f["D"]].reshape(nps.ny, -1, order="F")
    y = g[f["y_trim"]] + C @ np.array(up["dz"]) + D @ np.array(up["du"])
    return y + scale * np.sqrt(fx["layout"].variances) * rng.standard_normal(nps.ny)


def test_the_accelerating_trim_is_linear_in_the_acceleration_as_the_tick_takes_it(
        sense, carriage, sim_lib) -> None:
    """The table's accelerating change (x_accel, F_accel), scaled by a, against the trim
    solved at a (maglev_trim_accelerating) less the steady one, at a = a_L / 2 and a_L (the
    tick's trim is exact at a_L and linear in between) at three speeds: the pose within 2 %
    of its change's largest entry, the body velocities within 2 % of theirs (w: the same
    speed along the track at the other pitch); and F_accel within 5 % of the mass
    (d'Alembert's m a, and the drag's change with the accelerating trim's pose)."""
    from maglevgen.control.operating import checked_accelerating_trim, checked_trim

    table = sense["schedule"].table
    f = _fields(table)
    a_launch = carriage.params.envelope.launch_acceleration
    min_gap = carriage.params.track.min_gap
    for v in (table.v_min, 0.5 * (table.v_min + table.v_max), table.v_max):
        row = _clenshaw(table, v)
        x0, f0 = checked_trim(sim_lib, carriage.p, v, min_gap)[:2]
        for a in (0.5 * a_launch, a_launch):
            xa, fa, _ = checked_accelerating_trim(sim_lib, carriage.p, v, a, min_gap)
            for part in (list(AXIS_STATES), [6, 7, 8]):  # the pose, the body velocities
                change = xa[part] - x0[part]
                assert np.max(np.abs(change)) > 0
                np.testing.assert_allclose(a * row[f["x_accel"]][part], change, rtol=0,
                                           atol=0.02 * np.max(np.abs(change)))
            assert a * float(row[f["F_accel"]][0]) == pytest.approx(fa - f0, rel=1e-2)
        assert float(row[f["F_accel"]][0]) == pytest.approx(carriage.params.vehicle.mass,
                                                            rel=5e-2)


@pytest.mark.needs_cc
def test_sense_tick_follows_the_numpy_estimator_tick_by_tick(sense, carriage, sim_lib) -> None:
    """20 ticks at three speeds from the trim with a heave and roll off it, noisy readings,
    some flagged invalid or out of range, the reference accelerating at 0, the launch's and
    half the launch's acceleration: from the C's state before each tick, the numpy
    update, the law (NumpyTick with the C's law state) on its estimate and the numpy
    prediction with the C's command. The estimator's state after the tick (prediction, lagged
    forces, the commands in flight, the cache) and the rejected readings bit for bit; the
    command to 1e-12 of its scale (CasADi's rates and allocation against SymPy's and pinv)."""
    from maglevgen.control import estimation as est

    fx = sense
    sch, loop = fx["schedule"], fx["loop"]
    T = _allocation(carriage)
    nps = NumpySense(fx)
    all_valid = (1 << nps.ny) - 1
    rng = np.random.default_rng(4949)
    speeds = [sch.table.v_min, 0.5 * (sch.table.v_min + sch.table.v_max), sch.table.v_max]
    a_launch = carriage.params.envelope.launch_acceleration
    assert a_launch > 0
    for op, a_ref in zip(Plant(carriage, sim_lib).points(speeds),
                         (0.0, a_launch, 0.5 * a_launch), strict=True):
        c = CSense(fx)
        y0 = est.measurement_model(sim_lib, carriage.p, op, fx["layout"]).y_trim.copy()
        y0[-1] = 12.5  # the track sensor: the position the estimate starts at
        assert c.init(y0, all_valid, op.speed) == OK
        st = c.state()
        assert st["x_pred"][0] == 12.5 and st["rejected"] == 0
        st["x_pred"][2] += 1e-3
        st["x_pred"][3] += 2e-3
        c.set_state(st)
        law = NumpyTick(carriage, fx["table"], loop, T)
        v_ref = op.speed * 1.01
        exercised = swaps = 0
        for k in range(20):
            st = c.state()
            y = _readings(fx, nps, st, rng)
            valid = all_valid
            if k % 5 == 3:
                valid &= ~(1 << int(rng.integers(nps.ny)))  # one flagged stale
            if k % 7 == 4:
                y[int(rng.integers(sch.n_gap))] = 1.0  # a gap of 1 m: out of range
            rc, u = c(y, valid, v_ref, a_ref)
            assert rc == OK, (op.speed, k, rc)
            up = nps.update(st, y, valid)
            law.in_flight, law.w_hat, law.xi = (st["in_flight"].copy(), st["w_hat"].copy(),
                                               st["xi"])
            # the law about the trim accelerating at a_ref: the estimate less its pose change
            x_law = up["x_hat"] - a_ref * up["g"][nps.f["x_accel"]]
            u_ref = law(x_law, v_ref)
            u_ref[0] += a_ref * float(up["g"][nps.f["F_accel"]][0])
            after = c.state()
            assert after["rejected"] == up["rejected"], (k, after["rejected"])
            exercised += after["rejected"] != 0
            scale_f = max(np.max(np.abs(u_ref[1:])), 1e-9)
            assert np.max(np.abs(u[1:] - u_ref[1:])) <= 1e-12 * scale_f, (op.speed, k)
            assert u[0] == pytest.approx(u_ref[0], rel=1e-13)
            pred = nps.predict(st, up, u)
            for name in ("x_pred", "f_pred", "u_flight", *CACHE):
                np.testing.assert_array_equal(after[name], pred[name], err_msg=f"{name} {k}")
            swaps += after["use"] != st["use"]
            assert after["xi"] == law.xi
        assert exercised >= 3
        assert swaps >= 4  # the cache refreshed, in use at a speed other than the init's
        assert np.max(np.abs(c.state()["f_pred"])) > 1e-3  # the lag is exercised


def test_sense_table_rows_are_the_estimators_matrices_and_m_is_dlqes(sense, carriage,
                                                                     sim_lib) -> None:
    """At a node of the table (where it interpolates) its row unpacks to the EstimatorModel's
    blocks (Phi's plant rows, the applied command's Gamma, C, D) and the KalmanDesign's M to
    1e-9 of each block's scale; the blocks the tick takes as exact are (the lag's rows of
    Phi: a I on the lagged forces, (1 - a) I on the applied array forces; the queue a shift);
    M's rows left out are below M_DROPPED_SHARE; and at three speeds M (sense_plants) equals
    P C' (C P C' + R)^-1 with P from control.dlqe to 1e-8 of M's largest entry."""
    import control

    from maglevgen.control import estimation as est
    from maglevgen.control import sense_table as stab
    from maglevgen.control.schedule import GainTable

    fx = sense
    sch, loop, nu = fx["schedule"], fx["loop"], fx["nu"]
    params, tau, d = carriage.params, loop.actuator_lag, loop.delay_ticks
    f = _fields(sch.table)
    nodes = GainTable.nodes(NODES, sch.table.v_min, sch.table.v_max)
    (op,) = Plant(carriage, sim_lib).points([nodes[3]])
    (point,) = est.estimator_points(sim_lib, carriage.p, params, [op], tau)
    model, design = point.model, point.design
    n, nl = model.n_x, model.n_lag
    row = _clenshaw(sch.table, float(nodes[3]))
    oldest = slice(n + nl + (d - 1) * nu, n + nl + d * nu)
    blocks = {"Phi_minus_I": model.Phi[:n, :n + nl] - np.eye(n, n + nl),
              "Gamma": model.Phi[:n, oldest], "C": model.C[:, :n + nl],
              "D": model.C[:, oldest], "M": design.M[:n]}
    for name, exact in blocks.items():
        got = row[f[name]].reshape(exact.shape, order="F")
        assert np.max(np.abs(got - exact)) <= 1e-9 * np.max(np.abs(exact)), name
    a = np.exp(-1.0 / (loop.tick_rate * tau))
    np.testing.assert_allclose(model.Phi[n:n + nl, n:n + nl], a * np.eye(nl), atol=1e-15)
    assert np.all(model.Phi[n:n + nl, :n] == 0)
    np.testing.assert_allclose(model.Phi[n:n + nl, oldest][:, 1:], (1 - a) * np.eye(nl),
                               atol=1e-15)
    assert np.max(np.abs(design.M[n:])) <= stab.M_DROPPED_SHARE * np.max(np.abs(design.M))
    for v in (sch.table.v_min, 20.0, sch.table.v_max):
        (opv,) = Plant(carriage, sim_lib).points([v])
        (sp,) = stab.sense_plants(sim_lib, carriage.p, params, [opv], tau, d)
        m = est.estimator_model(sim_lib, carriage.p, opv, params, tau=tau)
        _, P, _ = control.dlqe(m.Phi, np.eye(m.Phi.shape[0]), m.C, m.Q, m.R)
        M = P @ m.C.T @ np.linalg.inv(m.C @ P @ m.C.T + m.R)
        assert np.max(np.abs(sp.M - M[:n])) <= 1e-8 * np.max(np.abs(M)), v


@pytest.mark.needs_cc
def test_sense_tick_closed_loop_has_the_loop_as_built_eigenvalues(sense, carriage,
                                                                   sim_lib) -> None:
    """The C sense tick with the law's table constant at its exact row at a node of the
    estimator's table (the loop as built schedules neither the feedforward nor the reference
    on the speed; with them scheduled on the estimated speed, as the tick flies, the speed
    modes move by up to 4.5e-4 in z: test_tick_state's reference has their slopes),
    linearised by central differences (its command and next state against the readings and
    its state) closed around the plant built
    here (control.c2d of the C's Jacobians with each array force through its lag, the readings'
    linearisation of estimation.measurement_model, the command applied from the tick's queue):
    its eigenvalues with |z| > 1e-3 are those of estimation.loop_as_built (plant, sensors,
    the Kalman filter, the controller as built, delay, lag, speed integral) to 1e-6 (1 + |z|),
    both ways; the along-track position's z = 1 aside."""
    import control

    from maglevgen.analyses.envelope import loop_design, loop_plant
    from maglevgen.control import estimation as est
    from maglevgen.control.schedule import GainTable

    fx = sense
    sch, loop, nu, setting = fx["schedule"], fx["loop"], fx["nu"], fx["setting"]
    params, tau, d, h = carriage.params, loop.actuator_lag, loop.delay_ticks, 1 / loop.tick_rate
    assert d == 1  # the plant below takes the oldest command of the tick's queue
    nodes = GainTable.nodes(NODES, sch.table.v_min, sch.table.v_max)
    (op,) = Plant(carriage, sim_lib).points([nodes[NODES // 2]])
    nf = nu - 1  # the array forces
    x0 = op.x_trim.astype(float)
    u0 = np.concatenate([[op.f_prop], np.zeros(nf)])
    A, B = (np.asarray(m) for m in sim_lib.function("maglev_jacobians")(x0, u0, carriage.p))
    meas = est.measurement_model(sim_lib, carriage.p, op, fx["layout"])
    ny = len(meas.names)

    # --- the C tick as a linear map (its state, the readings) -> (command, next state)
    c = CSense(fx, fx["frozen"](op.speed))
    all_valid = (1 << ny) - 1
    assert c.init(meas.y_trim, all_valid, op.speed) == OK
    base = c.state()
    keys = ("x_pred", "f_pred", "u_flight", "in_flight", "w_hat", "xi")
    sizes = [np.size(base[k]) for k in keys]

    def pack(st: dict) -> np.ndarray:
        return np.concatenate([np.ravel(st[k]) for k in keys])

    def unpack(z: np.ndarray) -> dict:
        out, i = {k: base[k] for k in CACHE}, 0  # each tick from the init's cache
        for k, n in zip(keys, sizes, strict=True):
            out[k] = z[i:i + n] if k != "xi" else float(z[i])
            i += n
        return out

    z0 = pack(base)
    y0 = meas.y_trim.copy()
    y0[-1] = x0[0]

    def tick(zy: np.ndarray) -> np.ndarray:
        c.set_state(unpack(zy[:z0.size]))
        rc, u = c(zy[z0.size:], all_valid, op.speed)
        assert rc == OK
        return np.concatenate([u - u0, pack(c.state()) - z0])

    # at the fixed point: the trim drifts along the track by h v each tick
    steps = np.concatenate([np.full(z0.size, 1e-6), np.full(ny, 1e-7)])
    steps[sizes[0] + sizes[1]:sizes[0] + sizes[1] + sizes[2]] = 1e-3  # commands [N]
    zy0 = np.concatenate([z0, y0])
    J = np.column_stack([(tick(zy0 + e) - tick(zy0 - e)) / (2 * e[j])
                         for j, e in enumerate(np.diag(steps))])
    K_s = J[nu:]  # the command reaches the plant through the tick's queue (its state)
    nz = z0.size
    q_oldest = slice(sizes[0] + sizes[1] + (d - 1) * nu, sizes[0] + sizes[1] + d * nu)

    # --- the plant as built: x, the lagged array forces; the command from the tick's queue
    n_p = 12 + nf
    Ac, Bc = np.zeros((n_p, n_p)), np.zeros((n_p, nu))
    Ac[:12, :12], Ac[:12, 12:] = A, B[:, 1:]
    Ac[12:, 12:] = -np.eye(nf) / tau
    Bc[12:, 1:] = np.eye(nf) / tau
    Bc[:12, 0] = B[:, 0]
    pl = control.c2d(control.ss(Ac, Bc, np.eye(n_p), 0), h, method="zoh")
    Phi, Gam = np.asarray(pl.A), np.asarray(pl.B)
    Cy = np.hstack([meas.C, meas.D[:, 1:]])  # the accelerometer reads the lagged forces
    Dy = np.zeros_like(meas.D)
    Dy[:, 0] = meas.D[:, 0]
    n = n_p + nz
    L = np.zeros((n, n))
    Sel = np.zeros((nu, nz))  # the applied command: the oldest in the tick's queue
    Sel[:, q_oldest] = np.eye(nu)
    L[:n_p, :n_p] = Phi
    L[:n_p, n_p:] = Gam @ Sel
    # y = Cy x + Dy u_applied; the tick's next state from (its state, y)
    L[n_p:, :n_p] = K_s[:, nz:] @ Cy
    L[n_p:, n_p:] = K_s[:, :nz] + K_s[:, nz:] @ Dy @ Sel
    z_c = np.linalg.eigvals(L)

    # --- the reference: loop_as_built with the exact filter and the controller as built
    (point,) = est.estimator_points(sim_lib, carriage.p, params, [op], tau)
    plant = loop_plant(op, setting)
    gains = loop_design(op, params.envelope.embedded_controller, setting)
    z_r = np.linalg.eigvals(est.loop_as_built(point.model, point.design, plant, gains))
    assert np.max(np.abs(z_r)) < 1.0
    big_c, big_r = z_c[np.abs(z_c) > 1e-3], z_r[np.abs(z_r) > 1e-3]
    near_one = np.abs(big_c - 1.0) < 1e-9
    assert np.sum(near_one) >= 1  # the along-track position
    big_c = big_c[~near_one]
    for z in big_r:
        assert np.min(np.abs(big_c - z)) <= 1e-6 * (1 + abs(z)), (z, np.sort_complex(big_c))
    for z in big_c:
        assert np.min(np.abs(big_r - z)) <= 1e-6 * (1 + abs(z)), z


_HOSTILE_HARNESS = r"""
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <string.h>
#include "maglev_tick.h"

static const double hostile[] = {NAN, INFINITY, -INFINITY, 1e30, -1e30, 1e300, 4.9e-324,
                                 -4.9e-324, 2.2e-308, 0.0, -0.0, -1.0};
#define NH ((int)(sizeof hostile / sizeof hostile[0]))
#define NS ((int)(offsetof(maglev_sense_state, rejected) / sizeof(double)))
#define ALL MAGLEV_SENSE_ALL_VALID

/* after any call: a documented code; on an error the command all zeros; the command and
   the state finite */
static int check(int rc, const double* u, const maglev_sense_state* s, long* bad) {
    const double* v = (const double*)s;
    int i;
    if (rc != MAGLEV_OK && rc != MAGLEV_ERR_NONFINITE && rc != MAGLEV_ERR_NONFINITE_OUTPUT
        && rc != MAGLEV_ERR_ARGUMENT && rc != MAGLEV_ERR_SENSOR) ++*bad;
    for (i = 0; i < MAGLEV_NU; ++i) {
        if (rc != MAGLEV_OK && u[i] != 0.0) ++*bad;
        if (!isfinite(u[i])) ++*bad;
    }
    for (i = 0; i < NS; ++i) {
        if (!isfinite(v[i])) ++*bad;
    }
    return rc;
}

int main(void) {
    double y0[MAGLEV_SENSE_NY] = {Y0}, y[MAGLEV_SENSE_NY], u[MAGLEV_NU];
    maglev_sense_state s;
    long calls = 0, bad = 0, errors = 0, sensor = 0, left_out = 0;
    int h, i, k, rc;
    for (h = 0; h < NH; ++h) {
        /* a hostile value in each reading, then in all, for a few ticks each */
        for (i = -1; i < MAGLEV_SENSE_NY; ++i) {
            memcpy(y, y0, sizeof y);
            if (i < 0) { for (k = 0; k < MAGLEV_SENSE_NY; ++k) y[k] = hostile[h]; }
            else y[i] = hostile[h];
            if (maglev_sense_init(&s, y0, ALL, V_REF) != MAGLEV_OK) ++bad;
            for (k = 0; k < 3; ++k) {
                rc = check(maglev_sense_tick(&s, k == 1 ? y : y0, ALL, V_REF, 0.0, u), u, &s, &bad);
                errors += rc != MAGLEV_OK;
                sensor += rc == MAGLEV_ERR_SENSOR;
                if (k == 1 && i >= 0 && !isfinite(hostile[h]) && !((s.rejected >> i) & 1UL)) ++bad;
                left_out += k == 1 && s.rejected != 0UL;
                ++calls;
            }
            /* the first readings hostile */
            rc = check(maglev_sense_init(&s, y, ALL, V_REF), u, &s, &bad);
            rc = check(maglev_sense_tick(&s, y0, ALL, V_REF, 0.0, u), u, &s, &bad);
            ++calls;
        }
        /* the speed reference, at init and at a tick */
        rc = maglev_sense_init(&s, y0, ALL, hostile[h]);
        rc = check(maglev_sense_tick(&s, y0, ALL, hostile[h], 0.0, u), u, &s, &bad);
        errors += rc != MAGLEV_OK;
        ++calls;
        /* the reference's acceleration: a non-finite one an error, a finite one a command */
        (void)maglev_sense_init(&s, y0, ALL, V_REF);
        rc = check(maglev_sense_tick(&s, y0, ALL, V_REF, hostile[h], u), u, &s, &bad);
        if (!isfinite(hostile[h]) && rc != MAGLEV_ERR_NONFINITE) ++bad;
        errors += rc != MAGLEV_OK;
        ++calls;
        /* the estimator's own state, one entry then all */
        for (i = -1; i < NS; ++i) {
            double* v = (double*)&s;
            maglev_sense_init(&s, y0, ALL, V_REF);
            if (i < 0) { for (k = 0; k < NS; ++k) v[k] = hostile[h]; } else v[i] = hostile[h];
            for (k = 0; k < 3; ++k) {
                rc = check(maglev_sense_tick(&s, y0, ALL, V_REF, 0.0, u), u, &s, &bad);
                errors += rc != MAGLEV_OK;
                ++calls;
            }
        }
        /* the cache: each value of the table in use, then both speeds; after two refreshes'
           ticks every cached value finite again (a bad value in use shows as a bad estimate
           or prediction: a reset; the other buffer is rewritten before it is used) */
        for (i = -1; i < MAGLEV_SENSE_SCHEDULE_NVARY; ++i) {
            maglev_sense_init(&s, y0, ALL, V_REF);
            if (i < 0) { s.v_tab[0] = hostile[h]; s.v_tab[1] = hostile[h]; }
            else s.tab[s.use][i] = hostile[h];
            for (k = 0; k <= 2 * MAGLEV_SENSE_REFRESH_TICKS; ++k) {
                rc = check(maglev_sense_tick(&s, y0, ALL, V_REF, 0.0, u), u, &s, &bad);
                errors += rc != MAGLEV_OK;
                ++calls;
            }
            for (k = 0; k < MAGLEV_SENSE_SCHEDULE_NVARY; ++k) {
                if (!isfinite(s.tab[0][k]) || !isfinite(s.tab[1][k])) ++bad;
            }
            if (!isfinite(s.v_tab[0]) || !isfinite(s.v_tab[1])) ++bad;
        }
    }
    /* the cache's index and slice out of range: taken in range, no access outside */
    maglev_sense_init(&s, y0, ALL, V_REF);
    s.use = 12345U;
    s.slice = 99999U;
    for (k = 0; k < 3; ++k) {
        rc = check(maglev_sense_tick(&s, y0, ALL, V_REF, 0.0, u), u, &s, &bad);
        if (s.use > 1U || s.slice >= (unsigned)MAGLEV_SENSE_REFRESH_TICKS) ++bad;
        ++calls;
    }
    /* every reading flagged invalid; then the gaps only */
    maglev_sense_init(&s, y0, ALL, V_REF);
    rc = check(maglev_sense_tick(&s, y0, 0UL, V_REF, 0.0, u), u, &s, &bad);
    if (rc != MAGLEV_ERR_SENSOR || s.rejected != ALL) ++bad;
    rc = check(maglev_sense_tick(&s, y0, ALL & ~((1UL << MAGLEV_SENSE_NGAP) - 1UL), V_REF, 0.0, u),
               u, &s, &bad);
    if (rc != MAGLEV_ERR_SENSOR) ++bad;
    rc = check(maglev_sense_tick(&s, y0, ALL, V_REF, 0.0, u), u, &s, &bad);
    if (rc != MAGLEV_OK) ++bad;
    /* NULL pointers: nothing written but a zero command */
    maglev_sense_init(&s, y0, ALL, V_REF);
    if (maglev_sense_tick(NULL, y0, ALL, V_REF, 0.0, u) != MAGLEV_ERR_ARGUMENT) ++bad;
    if (maglev_sense_tick(&s, NULL, ALL, V_REF, 0.0, u) != MAGLEV_ERR_ARGUMENT) ++bad;
    if (maglev_sense_tick(&s, y0, ALL, V_REF, 0.0, NULL) != MAGLEV_ERR_ARGUMENT) ++bad;
    if (maglev_sense_init(NULL, y0, ALL, V_REF) != MAGLEV_ERR_ARGUMENT) ++bad;
    if (maglev_sense_init(&s, NULL, ALL, V_REF) != MAGLEV_ERR_ARGUMENT) ++bad;
    printf("calls %ld errors %ld bad %ld sensor %ld left_out %ld\n", calls, errors, bad,
           sensor, left_out);
    return bad != 0;
}
"""


@pytest.mark.needs_cc
def test_sense_tick_under_sanitizers_with_hostile_readings(sense, carriage, sim_lib) -> None:
    """maglev_sense_init / maglev_sense_tick under ASan and UBSan (no recovery) with hostile
    values (NaN, +-inf, +-1e30, 1e300, denormals, +-0, -1; the set of test_failsafe.py) in
    each reading and in all of them (at a tick and as the first readings), in the speed
    reference, and in each entry of the estimator's state and in all of them, in each value of
    the cache in use and in its speeds (every cached value finite again after two refreshes'
    ticks), the cache's index and slice out of range; every reading
    flagged invalid, then the gaps; NULL pointers: no sanitizer report, every code one the
    header documents, the command zero on an error and finite always, the state finite after
    every call (a non-finite one reset), a non-finite reading left out (its bit in
    s.rejected), MAGLEV_ERR_SENSOR when no gap reading is usable and MAGLEV_OK again when
    they are."""
    from test_failsafe import SANITIZE

    from maglevgen.control import estimation as est

    folder = sense["folder"]
    (op,) = Plant(carriage, sim_lib).points([20.0])
    y0 = est.measurement_model(sim_lib, carriage.p, op, sense["layout"]).y_trim.copy()
    y0[-1] = 100.0
    (folder / "hostile_sense.c").write_text(_HOSTILE_HARNESS)
    run = subprocess.run(["cc", "-std=c99", "-g", "-O1", *SANITIZE,
                          f"-DY0={','.join(repr(float(v)) for v in y0)}",
                          f"-DV_REF={float(op.speed)!r}", "hostile_sense.c", "maglev_tick.c",
                          "maglev_gain_table.c", "maglev_sense_table.c", "maglev_functions.c",
                          "-lm", "-o", "hostile_sense"],
                         cwd=folder, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    out = subprocess.run([str(folder / "hostile_sense")], cwd=folder, capture_output=True,
                         text=True, timeout=300)
    assert out.returncode == 0 and not out.stderr, out.stdout + out.stderr
    calls, errors, bad, sensor, left_out = (int(v) for v in out.stdout.split()[1::2])
    ny = len(y0)
    assert bad == 0 and calls > 1000, out.stdout
    # a non-finite or huge value (6 of the set) is out of every range: left out in each
    # reading and in all; in all, no gap is usable: MAGLEV_ERR_SENSOR
    assert sensor >= 6 and left_out >= 6 * (ny + 1), out.stdout
    assert errors >= sensor, out.stdout


@pytest.mark.slow
def test_the_firmware_sense_table_holds_the_estimator_within_its_bound(carriage,
                                                                       sim_lib) -> None:
    """`maglevgen firmware`'s sense table (sense_schedule: the GainTable fit with its dense
    check): its stated errors within GAIN_TABLE_BOUND, and at four speeds between its nodes
    each field within the bound of the exact rows (sense_plants), relative to the field's
    largest magnitude over those speeds and the ends; the manifest states the same table."""
    from maglevgen.control import estimation as est
    from maglevgen.control import sense_table as stab
    from maglevgen.control.schedule import GAIN_TABLE_BOUND
    from maglevgen.exports.firmware import firmware_loop, sense_schedule

    v_min, v_max = Plant(carriage, sim_lib).speed_range
    loop = firmware_loop(Plant(carriage, sim_lib))
    sch = sense_schedule(Plant(carriage, sim_lib), v_min, v_max, loop)
    assert sch is not None
    assert max(sch.table.errors.values()) <= GAIN_TABLE_BOUND
    speeds = np.concatenate([[v_min, v_max], np.random.default_rng(49).uniform(v_min, v_max, 4)])
    exact = np.array([sp.row() for sp in stab.sense_plants(
        sim_lib, carriage.p, carriage.params, Plant(carriage, sim_lib).points(speeds),
        loop.actuator_lag, loop.delay_ticks)])
    got = sch.table(speeds)
    for name, sl in _fields(sch.table).items():
        scale = np.max(np.abs(exact[:, sl]))
        assert np.max(np.abs(got[:, sl] - exact[:, sl])) <= GAIN_TABLE_BOUND * scale, name
    m = sch.manifest()
    assert m["table"]["nodes"] == len(sch.table.coeffs)
    assert [r["name"] for r in m["readings"]] == list(est.SensorLayout.of(
        carriage.params).names)


@pytest.mark.needs_cc
def test_sense_init_takes_the_pose_from_the_gaps(sense, carriage, sim_lib) -> None:
    """maglev_sense_init from readings of a carriage 1 mm / 1-2 mrad off the trim (each gap
    sensor's reading from the generated maglev_gap_reading at that state: the nonlinear
    geometry): the pose within 2 % of the offset (the linearisation's error) and equal to
    numpy's lstsq on the table's C and y_trim to 1e-9 of it; the velocities and rates the
    trim's, the track position the track sensor's; with only the four lower gaps usable
    (four readings, five pose states) the pose stays at the trim."""
    from maglevgen.control import estimation as est

    fx = sense
    layout, sch = fx["layout"], fx["schedule"]
    (op,) = Plant(carriage, sim_lib).points([17.0])
    meas = est.measurement_model(sim_lib, carriage.p, op, layout)
    offset = np.array([1e-3, -1e-3, 2e-3, -1e-3, 1.5e-3])  # y, z, phi, theta, psi
    x_true = op.x_trim.astype(float).copy()
    x_true[1:6] += offset
    gap_fn = sim_lib.function("maglev_gap_reading")
    y = meas.y_trim.copy()
    for j, g in enumerate(layout.gaps):
        y[j] = float(np.ravel(gap_fn(x_true, g.point, g.normal, g.nominal_gap)[0])[0])
    y[-1] = 3.0
    c = CSense(fx)
    all_valid = (1 << len(y)) - 1
    assert c.init(y, all_valid, op.speed) == OK
    x = c.state()["x_pred"]
    row = _clenshaw(sch.table, op.speed)
    f = _fields(sch.table)
    x_t = row[f["x_trim"]].copy()
    x_t[6] += op.speed
    dp = x[1:6] - x_t[1:6]
    assert np.max(np.abs(dp - offset)) <= 0.02 * np.max(np.abs(offset)), (dp, offset)
    ny, ng = len(y), sch.n_gap
    C = row[f["C"]].reshape(ny, -1, order="F")[:ng, [sch.states.index(s) for s in
                                                    ("y", "z", "phi", "theta", "psi")]]
    ref = np.linalg.lstsq(C, y[:ng] - row[f["y_trim"]][:ng], rcond=None)[0]
    assert np.max(np.abs(dp - ref)) <= 1e-9 * np.max(np.abs(ref)), (dp, ref)
    assert x[0] == 3.0
    np.testing.assert_array_equal(x[6:], x_t[6:])
    lower = sum(1 << j for j, g in enumerate(layout.gaps) if g.array in ("1", "2", "4", "5"))
    assert bin(lower).count("1") == 4
    assert c.init(y, lower | (1 << (ny - 1)), op.speed) == OK
    np.testing.assert_array_equal(c.state()["x_pred"][1:6], x_t[1:6])


@pytest.mark.needs_arm("arm-none-eabi-gcc", "arm-none-eabi-nm")
def test_sense_tick_builds_for_the_cortex_m4(sense, tmp_path: Path) -> None:
    """The single-precision folder with the sense tick cross-compiled for the Cortex-M4F with
    the README's flags (warnings as errors): no double arithmetic (__aeabi_d*, f2d, d2f) nor
    double libm call, no .data/.bss (no writable static state), every defined external
    symbol maglev_*, and maglev_sense_init / maglev_sense_tick / maglev_sense_schedule among
    them."""
    from maglevgen.codegen.cpass import DOUBLE_MATH
    from maglevgen.exports.firmware import FIRMWARE_FLAGS

    sense["render"]("single", tmp_path)
    objs = []
    for name in ("maglev_tick", "maglev_gain_table", "maglev_sense_table", "maglev_functions"):
        run = subprocess.run(["arm-none-eabi-gcc", *FIRMWARE_FLAGS, "-c", f"{name}.c", "-o",
                              f"{name}.o"], cwd=tmp_path, capture_output=True, text=True)
        assert run.returncode == 0, (name, run.stderr)
        objs.append(f"{name}.o")
    symbols = subprocess.run(["arm-none-eabi-nm", *objs], cwd=tmp_path, check=True,
                             capture_output=True, text=True).stdout
    lines = [ln.split() for ln in symbols.splitlines() if ln.strip() and ":" not in ln]
    undefined = {ln[-1] for ln in lines if ln[-2] == "U"}
    defined = {ln[-1] for ln in lines if len(ln) == 3 and ln[1] in "TDRB"}
    assert not {u for u in undefined if u.startswith(("__aeabi_d", "__aeabi_f2d",
                                                      "__aeabi_d2f"))}, undefined
    assert not undefined & DOUBLE_MATH, undefined & DOUBLE_MATH
    assert not [ln for ln in lines if len(ln) == 3 and ln[1] in "dDbB"], lines
    assert all(d.startswith("maglev_") for d in defined), defined
    assert {"maglev_sense_init", "maglev_sense_tick", "maglev_sense_schedule"} <= defined


def test_the_readme_quotes_the_recorded_sense_tick_cost() -> None:
    """The sense tick's cost the folder's README quotes (MEASURED["sense"]) is the one
    bench/firmware_tick.py recorded (bench/firmware_tick_results.json, "sense_tick"), its
    share the cycles over a 1 kHz period at the recorded clock (recomputed here)."""
    import json

    from maglevgen.exports.firmware import MEASURED

    recorded = json.loads((Path(__file__).resolve().parents[1] / "bench"
                           / "firmware_tick_results.json").read_text())["sense_tick"]
    for key in ("instructions", "cycles", "stack_bytes"):
        assert MEASURED["sense"][key] == recorded[key], key
    assert MEASURED["sense"]["share_percent"] == pytest.approx(
        100 * recorded["cycles"] / (recorded["clock_mhz"] * 1e6 / 1000), abs=0.005)


@pytest.mark.needs_cc
def test_sense_tick_holds_the_nonlinear_carriage_on_noisy_readings(sense, carriage,
                                                                     sim_lib) -> None:
    """The C sense tick flying the nonlinear plant for 1.5 s at 20 m/s (the generated
    dynamics by RK4 with each array force's lag exact, as output_feedback.noisy_hold; the
    command applied one tick after it was computed; each reading from the generated
    measurement equations plus white noise of its variance, seeded) from a heave 0.5 mm off
    the trim: every tick MAGLEV_OK, no contact, the heave back within 50 um, each array's
    force RMS over the last second within control.spec's 10 % of the budget, and the
    prediction's error over the last second of the order the filter predicts (its RMS on
    the gaps' states within 0.5 to 2 times sqrt of the DARE's a-priori P)."""
    from maglevgen.analyses.output_feedback import _rhs, _rk4
    from maglevgen.control import estimation as est

    fx = sense
    layout, loop, nu = fx["layout"], fx["loop"], fx["nu"]
    params, p = carriage.params, carriage.p
    (op,) = Plant(carriage, sim_lib).points([20.0])
    (point,) = est.estimator_points(sim_lib, p, params, [op], loop.actuator_lag)
    tau, h = loop.actuator_lag, 1.0 / loop.tick_rate
    dynamics = sim_lib.function("maglev_dynamics")
    gap_fn, imu_fn = sim_lib.function("maglev_gap_reading"), sim_lib.function(
        "maglev_imu_reading")
    gaps_fn = sim_lib.function("maglev_gaps")
    rng = np.random.default_rng(49)
    sigma = np.sqrt(layout.variances)
    ng = len(layout.gaps)
    u_trim = np.zeros(nu)
    u_trim[0] = op.f_prop
    groups = np.array([i for i, (_, comps) in enumerate(carriage.structure.arrays)
                       for _ in comps])

    def readings(x: np.ndarray, F: np.ndarray, du: np.ndarray) -> np.ndarray:
        y = np.empty(len(sigma))
        for j, g in enumerate(layout.gaps):
            y[j] = float(np.ravel(gap_fn(x, g.point, g.normal, g.nominal_gap)[0])[0])
        xdot = _rhs(dynamics, x, F, u_trim, du, tau, p, 0.0)
        gyro, acc, _, _ = imu_fn(x, xdot, layout.imu_point, p)
        y[ng:ng + 6] = np.concatenate([np.ravel(gyro), np.ravel(acc)])
        y[-1] = x[0]
        return y + sigma * rng.standard_normal(len(y))

    x = op.x_trim.astype(float).copy()
    x[2] += 5e-4
    F = np.zeros(nu - 1)
    applied = u_trim.copy()  # before the first command: the trim's (maglev_sense_init)
    c = CSense(fx)
    all_valid = (1 << len(sigma)) - 1
    assert c.init(readings(x, F, applied - u_trim), all_valid, op.speed) == OK
    n = 1500
    forces = np.zeros((n, len(carriage.structure.arrays)))
    err = np.zeros((n, 12))
    min_gap = np.inf
    for k in range(n):
        du = applied - u_trim
        rc, u = c(readings(x, F, du), all_valid, op.speed)
        assert rc == OK, k
        x, F = _rk4(dynamics, x, F, u_trim, du, tau, p, h)
        applied = u
        forces[k] = np.sqrt(np.bincount(groups, u[1:] ** 2))
        err[k] = c.state()["x_pred"] - x  # the prediction for the next tick
        min_gap = min(min_gap, float(np.min(gaps_fn(x, p)[0])))
    assert min_gap > params.track.min_gap
    assert abs(x[2] - op.x_trim[2]) < 5e-5
    rms = np.sqrt(np.mean(forces[500:] ** 2, axis=0))
    assert np.max(rms) <= 0.1 * params.control.spec.force_budget, rms
    predicted = np.sqrt(np.diag(point.design.P)[:12])
    got = np.sqrt(np.mean(err[500:] ** 2, axis=0))
    for i in (1, 2, 3, 4, 5):  # y, z, phi, theta, psi: what the gaps read
        assert 0.5 <= got[i] / predicted[i] <= 2.0, (i, got[i], predicted[i])


@pytest.mark.parametrize("speed", [7.0, 20.0, 40.0])
def test_the_update_without_some_readings_still_converges(sense, carriage, sim_lib,
                                                          speed: float) -> None:
    """What the sense tick does with a reading left out (its innovation 0, the steady-state
    M kept): the filter's error dynamics Phi (I - M S C), S the readings kept, stay stable
    (eigenvalues within 0.99 of the unit circle, numpy) with each gap sensor left out, with
    the IMU, the gyro or the accelerometer left out and with both left upper gaps out; without
    the track sensor the along-track position is left to the prediction (an eigenvalue 1:
    nothing else reads it) and the rest stays stable."""
    from maglevgen.control import estimation as est

    names = sense["layout"].names
    (point,) = est.estimator_points(sim_lib, carriage.p, carriage.params,
                                    Plant(carriage, sim_lib).points([speed]),
                                    sense["loop"].actuator_lag)
    m, d = point.model, point.design
    n = m.Phi.shape[0]

    def moduli(left_out) -> np.ndarray:
        S = np.diag([0.0 if name in left_out else 1.0 for name in names])
        return np.sort(np.abs(np.linalg.eigvals(m.Phi @ (np.eye(n) - d.M @ S @ m.C))))

    gaps = [name for name in names if name.startswith("gap_")]
    imu = [name for name in names if name.startswith(("gyro", "accel"))]
    cases = [[g] for g in gaps] + [imu, imu[:3], imu[3:], ["gap_g3l", "gap_g6l"]]
    for left_out in cases:
        assert moduli(left_out)[-1] < 0.99, left_out
    z = moduli(["track_x"])
    assert abs(z[-1] - 1.0) < 1e-9 and z[-2] < 1.0


@pytest.mark.needs_cc
def test_the_sense_cache_is_within_its_stated_bound_of_evaluating_every_tick(
        sense, carriage, sim_lib) -> None:
    """The cost of the cache against evaluating the estimator's table every tick: the C tick
    from near v_min with the predicted forward speed ramped at 0.9 x
    envelope.launch_acceleration (set before each tick; readings the filter's own, noiseless)
    for 5 refreshes. After each tick the speed of the table in use is within
    launch_acceleration x 2 MAGLEV_SENSE_REFRESH_TICKS ticks of the speed scheduled for the
    next tick, the cache holds the table at its speed bit for bit, and each field of the table
    in use is within exports.firmware.sense_refresh_bound (the bound maglev_tick.h states) of
    the table at the scheduled speed, relative to the field's largest magnitude."""
    from maglevgen.control import estimation as est
    from maglevgen.exports.firmware import SENSE_REFRESH_TICKS, sense_refresh_bound

    fx = sense
    loop, table = fx["loop"], fx["schedule"].table
    a, h = carriage.params.envelope.launch_acceleration, 1.0 / loop.tick_rate
    bound = sense_refresh_bound(table, a, loop.tick_rate)
    header = (fx["folder"] / "maglev_tick.h").read_text()
    for name, err in bound.items():
        assert f"{name} {err:.1e}" in header, name
    nps = NumpySense(fx)
    rows = table(np.linspace(table.v_min, table.v_max, 2001))
    f = _fields(table)
    scale = {name: np.max(np.abs(rows[:, sl])) or 1.0 for name, sl in f.items()}
    v0 = table.v_min + 0.5
    (op,) = Plant(carriage, sim_lib).points([v0])
    c = CSense(fx)
    all_valid = (1 << nps.ny) - 1
    y0 = est.measurement_model(sim_lib, carriage.p, op, fx["layout"]).y_trim
    assert c.init(y0, all_valid, v0) == OK
    rng = np.random.default_rng(0)
    worst = dict.fromkeys(f, 0.0)
    for k in range(5 * SENSE_REFRESH_TICKS):
        st = c.state()
        st["x_pred"][6] = v0 + 0.9 * a * h * k
        c.set_state(st)
        rc, _ = c(_readings(fx, nps, st, rng, scale=0.0), all_valid, float(st["x_pred"][6]))
        assert rc == OK, k
        after = c.state()
        x = after["x_pred"]
        v_now = min(max(float(np.sqrt(x[6] ** 2 + x[7] ** 2 + x[8] ** 2)), table.v_min),
                    table.v_max)
        v_use = float(after["v_tab"][after["use"]])
        assert abs(v_now - v_use) <= a * 2 * SENSE_REFRESH_TICKS * h, (k, v_now, v_use)
        row_use, row_now = _clenshaw(table, v_use), _clenshaw(table, v_now)
        np.testing.assert_array_equal(after["tab"][after["use"]][:len(nps.varying)],
                                      row_use[nps.varying])
        for name, sl in f.items():
            worst[name] = max(worst[name],
                              float(np.max(np.abs(row_use[sl] - row_now[sl]))) / scale[name])
    for name in f:
        assert worst[name] <= bound[name] * (1 + 1e-9), (name, worst[name], bound[name])
    assert max(worst.values()) > 0  # the cache lagged the speed
