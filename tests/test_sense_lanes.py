"""The firmware's sense tick over SIMD lanes (templates/firmware_sense_lanes.c.j2, the Monte
Carlo's; issue 53) against the firmware's own maglev_sense_tick (templates/
firmware_maglev_sense.c.j2, compiled from the same folder): W runs' states ticked at once,
each lane's command, code and whole state after every tick equal to the last bit to the
scalar tick's on a copy of that run's state, at every lane count the CPU runs. The readings
are recorded runs' (the plant's, noisy), and the ticks reach every branch the scalar tick
has: a reading flagged invalid, NaN or out of its range, no usable gap (MAGLEV_ERR_SENSOR),
a non-finite speed reference, a corrupted state (the reset), speeds beyond the tables'
range, forces at the budget, lanes out of step (started at other ticks: another refresh
slice and buffer) and lanes that sit a tick out; on the library as the runs build it and on
the same sources built by clang (-Wall -Wextra -Werror, as the host's build of them)."""

from __future__ import annotations

import ctypes
from dataclasses import replace

import numpy as np
import pytest

from maglevgen.analyses.simulate import hold_run
from maglevgen.codegen.lanes import WIDTHS

DT = 1e-3
N_TICKS = 240
OK, ERR_SENSOR = 0, 9
P = ctypes.POINTER(ctypes.c_double)


def _api(library):
    """The host sense library's scalar and lane functions, typed."""
    lib = ctypes.CDLL(str(library.path))
    vp, i, ul, d = ctypes.c_void_p, ctypes.c_int, ctypes.c_ulong, ctypes.c_double
    sigs = {"maglev_host_sense_init": (i, [vp, P, ul, d]),
            "maglev_host_sense_tick": (i, [vp, P, ul, d, d, P]),
            "maglev_host_sense_lanes_new": (vp, [i]),
            "maglev_host_sense_lanes_free": (None, [vp]),
            "maglev_host_sense_lanes_move": (None, [vp, i, i, vp, i]),
            "maglev_host_sense_lanes_tick": (i, [vp, i, ctypes.POINTER(i), ctypes.POINTER(vp),
                                                 P, ctypes.POINTER(ul), P, P, P,
                                                 ctypes.POINTER(i)])}
    for name, (res, args) in sigs.items():
        f = getattr(lib, name)
        f.restype, f.argtypes = res, args
    return lib


@pytest.fixture(scope="module")
def recorded(carriage, sim_lib, op, sensed_tick):
    """Readings of four recorded runs on the sensors (N_TICKS ticks each, noisy, from
    disturbed starts) and the sense library they were flown with."""
    sensed, k_v, budget = sensed_tick
    n_u, n_g = op.allocation.shape[0] + 1, op.gaps.size
    out = []
    for k, dist in enumerate(({"z": 1e-3}, {"phi": 2e-3}, {"y": -1e-3}, {"theta": 1e-3})):
        run = hold_run(carriage.p, op, "spec", DT, dist, replace(sensed, seed=90 + k), k_v,
                       budget, n_steps=N_TICKS)
        traj = sim_lib.simulate(run.x0, DT, N_TICKS, run.f_prop, run.k_pos, run.k_rate,
                                run.a_ref, run.p, carriage.params.track.min_gap, n_u, n_g,
                                run.loop)
        assert traj.last == N_TICKS
        out.append(run.loop.sense.readings.copy())
    return out, sensed.firmware, op.speed, budget, carriage.structure.array_of_force


@pytest.fixture(scope="module")
def clang_library(recorded, tmp_path_factory):
    """The same firmware folder and sense lanes compiled by clang (`sense_library`'s flags,
    warnings as errors)."""
    from maglevgen.runtime.sense import sense_library

    firmware = recorded[1]
    return sense_library(firmware.files, tmp_path_factory.mktemp("clang"), cc="clang",
                         lanes=firmware.lanes)


def _column(lib, lanes, w: int, lane: int, size: int) -> bytes:
    """Lane ``lane``'s whole state, stored out of the lanes."""
    buf = np.zeros(size // 8 + 1)
    lib.maglev_host_sense_lanes_move(lanes, w, lane, buf.ctypes.data, 0)
    return buf.tobytes()


@pytest.mark.needs_cc
@pytest.mark.parametrize("w", list(WIDTHS))
def test_sense_lanes_tick_equals_the_firmware_tick(recorded, w) -> None:
    _compare(recorded, recorded[1].library, w)


@pytest.mark.needs_cc("clang")
@pytest.mark.parametrize("w", list(WIDTHS))
def test_sense_lanes_tick_equals_the_firmware_tick_clang(recorded, clang_library, w) -> None:
    _compare(recorded, clang_library, w)


def _compare(recorded, library, w: int) -> None:
    """The lanes' tick against the scalar tick of the same library (above)."""
    readings, _, speed, budget, array_of_force = recorded
    lib = _api(library)
    lanes = lib.maglev_host_sense_lanes_new(w)
    if not lanes:
        pytest.skip(f"this CPU has no {w}-lane vectors")  # the lane driver uses W=2 then
    ny = readings[0].shape[1]
    n_gap = 8
    size = library.state_size
    # the tick each lane's run starts at: the last one and, from 4 lanes, the one before 1 and
    # 2 ticks after the others (another refresh slice and buffer: out of step)
    start = [0] * w
    start[-1] = 1
    if w >= 4:
        start[-2] = 2
    state = [np.zeros(size // 8 + 1) for _ in range(w)]
    ref = [np.zeros(size // 8 + 1) for _ in range(w)]
    y_all = np.zeros((ny, w))
    u_all = np.zeros((11, w))
    active = (ctypes.c_int * w)()
    rc = (ctypes.c_int * w)()
    valid = (ctypes.c_ulong * w)()
    states = (ctypes.c_void_p * w)(*[s.ctypes.data for s in state])
    seen = {"fast": 0, "scalar": 0, "sensor": 0, "nonfinite": 0, "budget": 0}
    all_valid = (1 << ny) - 1
    try:
        for k in range(N_TICKS + 2):
            v_ref = np.full(w, speed)
            a_ref = np.zeros(w)
            for lane in range(w):
                n = k - start[lane]
                active[lane] = int(0 <= n < N_TICKS and not (lane == 1 and k % 7 == 3))
                if not active[lane]:
                    continue
                y = readings[lane % len(readings)][n].copy()
                bits = all_valid
                if lane == 0 and 40 <= n < 44:
                    bits &= ~(1 << 2)  # a gap flagged invalid
                if lane == 1 % w and n == 50:
                    y[3] = np.nan
                if lane == 2 % w and n == 60:
                    y[0] = 1.0  # beyond the gap's plausible range
                if lane == 3 % w and n in (70, 71):
                    bits &= ~((1 << n_gap) - 1)  # no gap: MAGLEV_ERR_SENSOR
                if lane == 0 and n == 80:
                    v_ref[lane] = np.nan
                if lane == 2 % w and 90 <= n < 100:
                    v_ref[lane] = 1.0  # below the tables' range
                if lane == 1 % w and 100 <= n < 110:
                    v_ref[lane] = 300.0  # above it
                if lane % 4 == 3 and 120 <= n < 150:
                    y[:n_gap] += 4e-3  # a large error: forces at the budget
                if lane == w - 1 and n == 160:
                    # a corrupted state in both (x_pred[0]): the tick starts again (its reset)
                    lib.maglev_host_sense_lanes_move(lanes, w, lane, state[lane].ctypes.data, 0)
                    state[lane][0] = ref[lane][0] = np.nan
                    lib.maglev_host_sense_lanes_move(lanes, w, lane, state[lane].ctypes.data, 1)
                y_all[:, lane] = y
                valid[lane] = bits
                if n == 0:
                    for s in (state[lane], ref[lane]):
                        assert lib.maglev_host_sense_init(s.ctypes.data, y.ctypes.data_as(P),
                                                          bits, v_ref[lane]) == OK
                    lib.maglev_host_sense_lanes_move(lanes, w, lane, state[lane].ctypes.data,
                                                     1)
            if not any(active):
                continue
            y_c = np.ascontiguousarray(y_all)
            u_all[:] = 0
            fast = lib.maglev_host_sense_lanes_tick(
                lanes, w, active, states, y_c.ctypes.data_as(P), valid,
                v_ref.ctypes.data_as(P), a_ref.ctypes.data_as(P), u_all.ctypes.data_as(P), rc)
            seen["fast"] += fast
            seen["scalar"] += sum(active) - fast
            for lane in range(w):
                if not active[lane]:
                    continue
                y = np.ascontiguousarray(y_all[:, lane])
                u = np.zeros(11)
                want = lib.maglev_host_sense_tick(ref[lane].ctypes.data, y.ctypes.data_as(P),
                                                  valid[lane], v_ref[lane], a_ref[lane],
                                                  u.ctypes.data_as(P))
                assert rc[lane] == want, (k, lane)
                assert u.tobytes() == u_all[:, lane].tobytes(), (k, lane, u, u_all[:, lane])
                assert _column(lib, lanes, w, lane, size) == ref[lane].tobytes(), (k, lane)
                seen["sensor"] += want == ERR_SENSOR
                seen["nonfinite"] += want not in (OK, ERR_SENSOR)
                norms = np.sqrt(np.bincount(array_of_force, u[1:] ** 2))
                seen["budget"] += bool(np.any(norms >= budget * (1 - 1e-9)))
    finally:
        lib.maglev_host_sense_lanes_free(lanes)
    # the cases were reached, and every tick took the vectors but those the scalar tick
    # answers with an error (lanes out of step, idle, at the budget or beyond the tables
    # included)
    assert seen["sensor"] > 0 and seen["nonfinite"] > 0 and seen["budget"] > 0, seen
    assert seen["scalar"] == seen["sensor"] + seen["nonfinite"], seen
