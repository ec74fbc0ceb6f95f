"""The lock-step batch in SIMD lanes (templates/maglev_lanes.c, maglevgen.codegen.lanes; issue
53) against the scalar loop it replaces: each run through the lanes against maglev_simulate of
the same inputs called on its own (`SimulationLibrary.simulate`, the loop checked against
solve_ivp elsewhere). The lanes evaluate every arithmetic statement of the stage function
as the scalar code does, per lane, with an exp and a sincos over the lanes that give libm's
bits (libm's per lane where they cannot): every state, input and gap must be equal to the
last bit, the status, the last sample and the saturated steps identical, for every lane count
this CPU runs and a batch that is no multiple of it."""

from __future__ import annotations

import ctypes
from dataclasses import replace

import numpy as np
import pytest

from maglevgen.analyses.simulate import LoopSetting, Weights, hold_run, operating_point
from maglevgen.codegen.lanes import WIDTHS, LaneError, kernel_name, lane_kernels
from maglevgen.control.sampled import Tick

DT = 1e-3
TICK = LoopSetting(250.0, 1, 2e-3)  # 4 steps a tick, one tick's delay, a 2 ms lag


def _widths(sim_lib) -> list[int]:
    return [w for w in WIDTHS if sim_lib.lane_width(w) == w]


@pytest.fixture(scope="module")
def runs(carriage, sim_lib, op):
    """Eleven runs (no multiple of 2, 4 or 8): two controllers at the nominal parameters, a
    heavier carriage with its own trim, a force budget that saturates, a disturbance that
    reaches contact half-way (step 145 of 300), a NaN parameter (the tick's command refuses
    it at step 0), a speed reference that overflows (the stage's error half-way), the
    continuous loop and a plain tick (both flown by maglev_simulate whole, beside the
    lanes)."""
    p2 = carriage.p.copy()
    p2[carriage.structure.param_names.index("vehicle.mass")] *= 1.04
    min_gap = carriage.params.track.min_gap
    op2 = operating_point(sim_lib, p2, op.speed, min_gap, Weights.of(carriage.params))
    bad = carriage.p.copy()
    bad[carriage.structure.param_names.index("vehicle.mass")] = np.nan
    dist = {"z": 2e-3, "phi": 4e-3}
    # a speed reference that overflows the propulsion half-way: the stage function's check
    # (non-finite output) ends the run with an error among running ones
    overflow = replace(hold_run(carriage.p, op, "spec", DT, dist, TICK, 500.0, 2e3).loop,
                       accel=1e307)

    def run(p, o, c, d, tick=TICK, budget=2e3):
        return hold_run(p, o, c, DT, d, tick, 500.0, budget)

    return [run(carriage.p, op, "lqr", dist), run(carriage.p, op, "spec", dist),
            run(p2, op2, "lqr", {"y": -1e-3}), run(carriage.p, op, "lqr", dist, budget=0.05),
            run(carriage.p, op, "lqr", {"z": -0.012}),
            run(bad, op, "lqr", dist), run(carriage.p, op, "lqr", dist, tick=None, budget=None),
            run(carriage.p, op, "coupled", dist, tick=Tick(250.0, 1)),
            run(p2, op2, "spec", {"z": -1e-3}), run(carriage.p, op, "lqr", {"theta": 2e-3}),
            run(carriage.p, op, "spec", {"psi": -3e-3})._replace(loop=overflow)]


def _same(a, b) -> bool:
    return (a.status == b.status and a.last == b.last
            and a.saturated_steps == b.saturated_steps and np.array_equal(a.x, b.x)
            and np.array_equal(a.u, b.u) and np.array_equal(a.gaps, b.gaps))


def _scalar(sim_lib, runs, n_steps: int, min_gap: float, n_u: int, n_g: int) -> list:
    return [sim_lib.simulate(r.x0, DT, n_steps, r.f_prop, r.k_pos, r.k_rate, r.a_ref, r.p,
                             min_gap, n_u, n_g, r.loop) for r in runs]


@pytest.mark.needs_cc
def test_lanes_equal_the_scalar_loop(carriage, sim_lib, op, runs) -> None:
    """Every lane count the CPU runs, on one and on two threads: each run bit for bit
    maglev_simulate's. The runs reach what they are meant to (a contact half-way,
    errors at once and half-way, saturated steps), so the comparison covers a lane ending among
    running lanes and the lane taking the next run."""
    n_u, n_g = op.allocation.shape[0] + 1, op.gaps.size
    min_gap = carriage.params.track.min_gap
    want = _scalar(sim_lib, runs, 300, min_gap, n_u, n_g)
    statuses = [w.status for w in want]
    assert statuses[4] == 1 and want[4].last < 200, (statuses[4], want[4].last)
    assert statuses[5] == 3 and want[5].last == 0  # MAGLEV_SIM_ERROR at once
    assert statuses[10] == 3 and 0 < want[10].last < 300, want[10].last  # an error half-way
    assert want[3].saturated_steps > 0
    assert statuses.count(0) == len(runs) - 3
    assert _widths(sim_lib)
    for w in _widths(sim_lib):
        for threads in (1, 2):
            got = sim_lib.simulate_batch(runs, DT, 300, min_gap, n_u, n_g, threads, lanes=w)
            for i, (a, b) in enumerate(zip(want, got, strict=True)):
                assert _same(a, b), (w, threads, i)


@pytest.mark.needs_cc
def test_lanes_equal_the_scalar_loop_over_ten_seconds(carriage, sim_lib, op, runs) -> None:
    """The issue's measure: 10 s at 1 kHz (10^4 RK4 steps), the widest lanes, five runs
    (one lane group of 4 and one run more, or a group of 8 part-filled): every state at the
    end, and the whole trajectories, bit for bit."""
    n_u, n_g = op.allocation.shape[0] + 1, op.gaps.size
    min_gap = carriage.params.track.min_gap
    chosen = [runs[i] for i in (0, 1, 2, 3, 8)]
    want = _scalar(sim_lib, chosen, 10_000, min_gap, n_u, n_g)
    assert [w.last for w in want].count(10_000) == 4  # the saturated one touches at 8.5 s
    got = sim_lib.simulate_batch(chosen, DT, 10_000, min_gap, n_u, n_g, 1, lanes=0)
    for a, b in zip(want, got, strict=True):
        assert np.array_equal(a.x[-1], b.x[-1])
        assert _same(a, b)


@pytest.mark.needs_cc
def test_lane_kernels_equal_the_scalar_functions(carriage, sim_lib, op) -> None:
    """The translated maglev_dynamics_prepared, maglev_gaps and maglev_coupled_control in each
    lane count against the library's own, lane by lane, on test_branches' poses about the
    trim (scales 0 to 0.3: the special functions' arguments on both sides of the series
    switch, test_branches checks that), the poses mixed across lanes so that a lane group's
    guard runs a block some lanes discard; plus a lane of NaN beside finite ones (the NaN
    stays in its lane: the others equal)."""
    prepare = sim_lib.function("maglev_dynamics_prepare")
    stage = sim_lib.function("maglev_dynamics_prepared")
    gaps = sim_lib.function("maglev_gaps")
    control = sim_lib.function("maglev_coupled_control")
    k_pos, k_rate = (np.ravel(k, order="F") for k in op.gains("lqr"))
    d = np.ravel(prepare(carriage.p)[0])
    rng = np.random.default_rng(53)
    poses = []
    for scale in (0.0, 1e-3, 0.1, 0.3):
        for _ in range(4):
            poses.append((op.x_trim + scale * rng.standard_normal(12),
                          rng.standard_normal(11) * 100))
    poses[5] = (np.full(12, np.nan), np.zeros(11))  # 16 poses: every lane count covers all
    order = rng.permutation(len(poses))
    kernels = sim_lib._lanes_functions()[2]
    P = ctypes.POINTER(ctypes.c_double)
    n_g = op.gaps.size
    for w in _widths(sim_lib):
        dynamics, gap_kernel, control_kernel = (
            getattr(kernels, kernel_name(f, w))
            for f in ("maglev_dynamics_prepared", "maglev_gaps", "maglev_coupled_control"))
        for start in range(0, len(poses) - w + 1, w):
            group = [poses[i] for i in order[start:start + w]]
            x = _aligned(np.array([g[0] for g in group]).T)
            u = _aligned(np.array([g[1] for g in group]).T)
            dd = _aligned(np.repeat(d[:, None], w, axis=1))
            pp = _aligned(np.repeat(carriage.p[:, None], w, axis=1))
            xdot, g = _aligned(np.zeros((12, w))), _aligned(np.zeros((n_g, w)))
            kp, kr, ar = (_aligned(np.repeat(np.asarray(v)[:, None], w, axis=1))
                          for v in (k_pos, k_rate, op.a_trim))
            u_gen = _aligned(np.zeros((5, w)))
            assert control_kernel((P * 5)(*(a.ctypes.data_as(P) for a in (x, kp, kr, ar, pp))),
                                  (P * 1)(u_gen.ctypes.data_as(P))) == 0
            assert dynamics((P * 3)(*(a.ctypes.data_as(P) for a in (x, u, dd))),
                            (P * 1)(xdot.ctypes.data_as(P))) == 0
            assert gap_kernel((P * 2)(*(a.ctypes.data_as(P) for a in (x, pp))),
                              (P * 1)(g.ctypes.data_as(P))) == 0
            for lane, (xs, us) in enumerate(group):
                if not np.all(np.isfinite(xs)):  # the scalar check refuses it: NaN out
                    assert not np.all(np.isfinite(xdot[:, lane]))
                    continue
                want = np.ravel(stage(xs, us, d)[0])
                assert np.array_equal(xdot[:, lane], want), (w, start, lane)
                assert np.array_equal(g[:, lane], np.ravel(gaps(xs, carriage.p)[0])), (w, lane)
                want = np.ravel(control(xs, k_pos, k_rate, op.a_trim, carriage.p)[0])
                assert np.array_equal(u_gen[:, lane], want), (w, lane)


@pytest.mark.needs_cc
def test_reading_kernels_equal_the_scalar_functions(carriage, sim_lib, op) -> None:
    """The translated sensor readings (maglev_gap_reading, maglev_imu_reading: what a run on
    the sensors reads at each tick) in each lane count against the library's own, lane by
    lane, reading and Jacobian: random poses about the trim (scales 0 to 0.3), rates, sensor
    points and unit normals, different in every lane."""
    gap_reading = sim_lib.function("maglev_gap_reading")
    imu_reading = sim_lib.function("maglev_imu_reading")
    kernels = sim_lib._lanes_functions()[2]
    P = ctypes.POINTER(ctypes.c_double)
    rng = np.random.default_rng(530)

    def call(kernel, inputs, outputs) -> None:
        assert kernel((P * len(inputs))(*(a.ctypes.data_as(P) for a in inputs)),
                      (P * len(outputs))(*(a.ctypes.data_as(P) for a in outputs))) == 0

    for w in _widths(sim_lib):
        for scale in (0.0, 1e-3, 0.1, 0.3):
            x = _aligned(op.x_trim[:, None] + scale * rng.standard_normal((12, w)))
            xdot = _aligned(rng.standard_normal((12, w)))
            point = _aligned(rng.standard_normal((3, w)))
            normal = rng.standard_normal((3, w))
            normal = _aligned(normal / np.linalg.norm(normal, axis=0))
            nominal = _aligned(0.01 + 0.02 * rng.random((1, w)))
            pp = _aligned(np.repeat(carriage.p[:, None], w, axis=1))
            reading, H = _aligned(np.zeros((1, w))), _aligned(np.zeros((12, w)))
            call(getattr(kernels, kernel_name("maglev_gap_reading", w)),
                 (x, point, normal, nominal), (reading, H))
            gyro, force = _aligned(np.zeros((3, w))), _aligned(np.zeros((3, w)))
            H_x, H_xdot = _aligned(np.zeros((72, w))), _aligned(np.zeros((72, w)))
            call(getattr(kernels, kernel_name("maglev_imu_reading", w)),
                 (x, xdot, point, pp), (gyro, force, H_x, H_xdot))
            for lane in range(w):
                want = gap_reading(x[:, lane], point[:, lane], normal[:, lane], nominal[:, lane])
                assert np.array_equal(reading[:, lane], np.ravel(want[0])), (w, scale, lane)
                assert np.array_equal(H[:, lane], np.ravel(want[1])), (w, scale, lane)
                want = imu_reading(x[:, lane], xdot[:, lane], point[:, lane], carriage.p)
                for got, ref in zip((gyro, force, H_x, H_xdot), want, strict=True):
                    # the kernel's output column-major, as CasADi's
                    assert np.array_equal(got[:, lane], np.ravel(ref, order="F")), (w, lane)


@pytest.mark.needs_cc
def test_kept_sines_and_cosines_equal_the_scalar_functions(carriage, sim_lib, op) -> None:
    """The kernels keep their last sincos argument vectors and results
    (maglevgen.codegen.lanes): a sequence of calls through two kernels that take the same
    angles (the second call at each x finds them kept), with argument vectors the same as a
    kept one in every lane but one (not the same: computed), more distinct ones than are kept
    and then the first ones again, each lane against the library's own function at its own
    inputs."""
    stage = sim_lib.function("maglev_dynamics_prepared")
    gap_reading = sim_lib.function("maglev_gap_reading")
    d = np.ravel(sim_lib.function("maglev_dynamics_prepare")(carriage.p)[0])
    kernels = sim_lib._lanes_functions()[2]
    P = ctypes.POINTER(ctypes.c_double)
    rng = np.random.default_rng(5353)
    point, normal, nominal = np.array([0.5, 0.2, -0.1]), np.array([0.0, 0.6, 0.8]), 0.02
    for w in _widths(sim_lib):
        poses = [op.x_trim + 0.1 * rng.standard_normal(12) for _ in range(6)]
        u = _aligned(np.repeat(rng.standard_normal((11, 1)) * 100, w, axis=1))
        dd = _aligned(np.repeat(d[:, None], w, axis=1))
        pt, nm = (_aligned(np.repeat(v[:, None], w, axis=1)) for v in (point, normal))
        nom = _aligned(np.full((1, w), nominal))
        everywhere = [[i] * w for i in range(6)]
        one_off = [[1] + [0] * (w - 1), [0] * (w - 1) + [2]]  # pose 0 but in one lane
        mixed = [[lane % 6 for lane in range(w)], [(lane + 3) % 6 for lane in range(w)]]
        sequence = [everywhere[0], *one_off, *mixed, *everywhere[1:], everywhere[0], *one_off]
        for k, which in enumerate(sequence):
            x = _aligned(np.array([poses[i] for i in which]).T)
            xdot, reading, H = (_aligned(np.zeros(shape)) for shape in ((12, w), (1, w),
                                                                          (12, w)))
            assert getattr(kernels, kernel_name("maglev_dynamics_prepared", w))(
                (P * 3)(*(a.ctypes.data_as(P) for a in (x, u, dd))),
                (P * 1)(xdot.ctypes.data_as(P))) == 0
            assert getattr(kernels, kernel_name("maglev_gap_reading", w))(
                (P * 4)(*(a.ctypes.data_as(P) for a in (x, pt, nm, nom))),
                (P * 2)(reading.ctypes.data_as(P), H.ctypes.data_as(P))) == 0
            for lane in range(w):
                want = np.ravel(stage(x[:, lane], u[:, lane], d)[0])
                assert np.array_equal(xdot[:, lane], want), (w, k, lane)
                want = gap_reading(x[:, lane], point, normal, np.array([nominal]))
                assert np.array_equal(reading[:, lane], np.ravel(want[0])), (w, k, lane)
                assert np.array_equal(H[:, lane], np.ravel(want[1])), (w, k, lane)


def _aligned(a: np.ndarray) -> np.ndarray:
    """A copy of ``a`` (C order) at a 64-byte boundary: the kernels load whole vectors."""
    buf = np.empty(a.size + 8)
    skip = (-buf.ctypes.data % 64) // 8
    out = buf[skip:skip + a.size].reshape(a.shape)
    out[...] = a
    return out


def test_the_translation_refuses_what_it_does_not_know() -> None:
    """A statement of a form the lanes do not translate is an error, not C passed through."""
    body = ("/* f:(x)->(y) */\nstatic int casadi_f0(const casadi_real** arg, "
            "casadi_real** res, casadi_int* iw, casadi_real* w, int mem) {\n"
            "  casadi_real a0;\n  a0=arg[0]? arg[0][0] : 0;\n  a0=tanh(a0);\n"
            "  if (res[0]!=0) res[0][0]=a0;\n  return 0;\n}\n")
    with pytest.raises(LaneError, match="tanh"):
        lane_kernels(body, ("f",))
    ok = body.replace("tanh", "exp")
    assert "vexp4(a0)" in lane_kernels(ok, ("f",))


_MVEC_HARNESS = """
typedef double V4 __attribute__((vector_size(32)));
#define F(f) \\
__attribute__((target("avx2"))) V4 _ZGVdN4v_##f(V4 a); \\
__attribute__((target("avx2"))) void mvec_##f(const double* a, double* r, long n) { \\
    long i; int l; \\
    for (i = 0; i + 4 <= n; i += 4) { \\
        V4 v, w; for (l = 0; l < 4; ++l) v[l] = a[i + l]; \\
        w = _ZGVdN4v_##f(v); for (l = 0; l < 4; ++l) r[i + l] = w[l]; \\
    } \\
}
F(exp)
F(sin)
F(cos)
"""


@pytest.mark.needs_cc
def test_libmvec_within_its_bound_against_mpmath(tmp_path, sim_lib) -> None:
    """The lanes' other math (``lane_math="libmvec"``, bench/simd_batch.py's experiment):
    glibc's AVX2 exp, sin and cos against mpmath at 50 digits, within 4 ulp (glibc's stated
    bound for libmvec) over exp's whole finite range, sin and cos on [-1000, 1000] and on the
    small angles the model takes them of (|a| <= 0.5)."""
    import subprocess

    import mpmath

    if sim_lib.lane_width(4) != 4:
        pytest.skip("no AVX2 on this CPU")
    src = tmp_path / "mvec.c"
    src.write_text(_MVEC_HARNESS)
    lib_path = tmp_path / "libmvec_harness.so"
    subprocess.run(["gcc", "-std=c99", "-O2", "-fPIC", "-shared", str(src), "-o",
                    str(lib_path), "-Wl,--no-as-needed,-lmvec", "-lm"], check=True)
    lib = ctypes.CDLL(str(lib_path))
    rng = np.random.default_rng(53)
    domains = {"exp": [(-745.0, 709.0), (-1.0, 1.0)],
               "sin": [(-1000.0, 1000.0), (-0.5, 0.5)], "cos": [(-1000.0, 1000.0), (-0.5, 0.5)]}
    mpmath.mp.dps = 50
    worst = {}
    for name, ranges in domains.items():
        a = np.concatenate([rng.uniform(lo, hi, 400) for lo, hi in ranges])
        r = np.zeros_like(a)
        fn = getattr(lib, f"mvec_{name}")
        real_p = ctypes.POINTER(ctypes.c_double)
        fn(a.ctypes.data_as(real_p), r.ctypes.data_as(real_p), ctypes.c_long(a.size))
        errs = []
        for x, got in zip(a, r, strict=True):
            ref = getattr(mpmath, name)(mpmath.mpf(float(x)))
            ulp = np.spacing(abs(float(ref))) if float(ref) != 0 else 5e-324
            if abs(float(ref)) < 2.2250738585072014e-308:  # subnormal results: absolute
                ulp = 5e-324
            errs.append(float(abs(mpmath.mpf(float(got)) - ref)) / ulp)
        worst[name] = max(errs)
    assert all(v <= 4.0 for v in worst.values()), worst


def _vector_widths(sim_lib) -> list[int]:
    """The lane counts whose exp and sincos are vectors on this CPU (skip without any)."""
    widths = [w for w in (4, 8) if sim_lib.lane_width(w) == w]
    if not widths:
        pytest.skip("this CPU has neither AVX2 nor AVX-512F")
    return widths


def _glibc_x86() -> bool:
    """glibc 2.36 on x86-64 with FMA (where it runs its FMA build of exp and sincos): the
    build whose object code the lanes' exp and sincos were written from
    (maglevgen.codegen.lanes). Another build may contract other operations into FMAs: the
    lanes then fall back to libm per lane, the bits still libm's."""
    import platform
    from pathlib import Path

    libc, version = platform.libc_ver()
    cpuinfo = Path("/proc/cpuinfo")
    fma = cpuinfo.exists() and " fma " in f" {cpuinfo.read_text()} ".replace("\n", " ")
    return (libc == "glibc" and version == "2.36" and platform.machine() == "x86_64"
            and fma)


def _lanes_exp(sim_lib, w: int, x: np.ndarray) -> tuple[np.ndarray, int]:
    fn = getattr(sim_lib._lanes_functions()[2], f"maglev_lanes_exp_w{w}")
    fn.restype = ctypes.c_int
    y = np.empty_like(x)
    real_p = ctypes.POINTER(ctypes.c_double)
    used = fn(x.ctypes.data_as(real_p), y.ctypes.data_as(real_p), ctypes.c_long(x.size))
    return y, used


@pytest.mark.needs_cc
def test_the_lanes_exp_has_libms_bits(sim_lib) -> None:
    """The kernels' exp over 4 and 8 lanes (glibc's algorithm in FMA vectors,
    maglevgen.codegen.lanes) against libm's exp called through ctypes, bit for bit: 4 * 10^5
    arguments over the range where it runs (|x| from 2^-54 to 512), every one of its 128
    table entries at both ends of its interval, and glibc's special cases (tiny, 512 on,
    overflow, underflow, infinities, NaN), which it hands to libm. On glibc 2.36, whose exp
    this is, the vector form must be the one that ran (its self-check passed)."""

    libm = ctypes.CDLL("libm.so.6")
    libm.exp.restype, libm.exp.argtypes = ctypes.c_double, [ctypes.c_double]
    rng = np.random.default_rng(53)
    k = np.arange(-128 * 40, 128 * 40)
    x = np.concatenate([rng.uniform(-40, 40, 200_000), rng.uniform(-511.9, 511.9, 200_000),
                        k * np.log(2) / 128, k * np.log(2) / 128 + np.log(2) / 256,
                        np.nextafter(k * np.log(2) / 128 + np.log(2) / 256, 0),
                        [2.0**-54, -(2.0**-54), 2.0**-60, 0.0, -0.0, 512.0, -512.0, 709.78,
                         710.0, -745.1, -746.0, -1000.0, np.inf, -np.inf, np.nan, 5e-324]])
    x = np.concatenate([x, np.zeros(-x.size % 8)])
    ref = np.array([libm.exp(float(v)) for v in x])
    for w in _vector_widths(sim_lib):
        got, used = _lanes_exp(sim_lib, w, x)
        assert np.array_equal(got.view(np.int64), ref.view(np.int64)), w
        assert used == 1 or not _glibc_x86(), f"W={w}: the lanes' exp fell back to libm"


@pytest.mark.needs_cc
def test_the_lanes_fall_back_to_libm_where_their_check_fails(tmp_path, sim_lib) -> None:
    """Another C library or glibc build (its exp or sincos not these operations): the kernels
    built with one word of exp's table and one of sincos's changed, as such a build would
    differ, must find it on their first call and give libm's bits through libm per lane (the
    vector form reported unused), on the arguments the vector forms would have taken."""
    import subprocess

    from maglevgen.runtime.compile import HOST_TUNED_FLAGS

    widths = _vector_widths(sim_lib)
    source = lane_kernels((sim_lib.sources / "maglev_functions.c").read_text())
    exp_word = "0x3feff63da9fb3335ULL"  # H_1's bits, 2^(1/128) rounded (less 1 << 45)
    sc_word = (1 / 128 - (1 / 128) ** 3 / 6).hex()  # not sin(1/128)'s double-double
    assert exp_word in source
    broken = source.replace(exp_word, "0x3feff63da9fb3336ULL", 1)
    high = float.fromhex(broken.split("SC_TAB[8]")[1].split("{")[1].split(",")[4].strip())
    broken = broken.replace(high.hex(), sc_word, 1)
    src = tmp_path / "kernels.c"
    src.write_text(broken)
    lib_path = tmp_path / "kernels.so"
    subprocess.run(["gcc", *HOST_TUNED_FLAGS, "-shared", "-fPIC", str(src), "-o", str(lib_path),
                    "-lm"], check=True)
    lib = ctypes.CDLL(str(lib_path))
    libm = ctypes.CDLL("libm.so.6")
    libm.exp.restype, libm.exp.argtypes = ctypes.c_double, [ctypes.c_double]
    rng = np.random.default_rng(3)
    x = np.concatenate([rng.uniform(-40, 40, 4000), rng.uniform(-0.0117, 0.0117, 4000)])
    real_p = ctypes.POINTER(ctypes.c_double)
    for w in widths:
        exp_fn = getattr(lib, f"maglev_lanes_exp_w{w}")
        sc_fn = getattr(lib, f"maglev_lanes_sincos_w{w}")
        y, s, c = np.empty_like(x), np.empty_like(x), np.empty_like(x)
        assert exp_fn(x.ctypes.data_as(real_p), y.ctypes.data_as(real_p),
                      ctypes.c_long(x.size)) == 0, w
        assert sc_fn(x.ctypes.data_as(real_p), s.ctypes.data_as(real_p),
                     c.ctypes.data_as(real_p), ctypes.c_long(x.size)) == 0, w
        assert np.array_equal(y, [libm.exp(float(v)) for v in x]), w
        ref_s, ref_c = _lanes_sincos(sim_lib, w, x)[:2]  # the working kernels: libm's bits
        assert np.array_equal(s.view(np.int64), ref_s.view(np.int64)), w
        assert np.array_equal(c.view(np.int64), ref_c.view(np.int64)), w


@pytest.mark.needs_cc
def test_the_lanes_exp_within_glibcs_bound_against_mpmath(sim_lib) -> None:
    """The kernels' exp (the vector form of glibc's) against mpmath at 50 digits: within
    0.52 ulp, glibc's stated bound for its exp with FMA (0.509 ulp) and a margin."""
    import mpmath

    widths = _vector_widths(sim_lib)
    rng = np.random.default_rng(7)
    x = np.concatenate([rng.uniform(-40, 40, 2000), rng.uniform(-500, 500, 400)])
    mpmath.mp.dps = 50
    ref = [mpmath.exp(mpmath.mpf(float(v))) for v in x]
    for w in widths:
        got, _ = _lanes_exp(sim_lib, w, x)
        worst = max(float(abs(mpmath.mpf(float(g)) - r)) / np.spacing(abs(float(r)))
                    for g, r in zip(got, ref, strict=True))
        assert worst <= 0.52, (w, worst)


def _lanes_sincos(sim_lib, w: int, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    fn = getattr(sim_lib._lanes_functions()[2], f"maglev_lanes_sincos_w{w}")
    fn.restype = ctypes.c_int
    s, c = np.empty_like(x), np.empty_like(x)
    real_p = ctypes.POINTER(ctypes.c_double)
    used = fn(x.ctypes.data_as(real_p), s.ctypes.data_as(real_p), c.ctypes.data_as(real_p),
              ctypes.c_long(x.size))
    return s, c, used


@pytest.mark.needs_cc
def test_the_lanes_sincos_has_libms_bits(sim_lib) -> None:
    """The kernels' sincos over 4 and 8 lanes (glibc's for |x| below 3/256 in FMA vectors,
    libm's per lane else) against libm's sincos through ctypes, bit for bit: 2 * 10^5
    arguments log-uniform from 2^-40 to beyond 3/256, both signs, the bounds (2^-27, the
    table's points 0 and 1/128 and the midpoint between them, 3/256), zeros, subnormals,
    angles up to 4 rad and non-finite values. On glibc 2.36 the vector form must be the one
    that ran."""

    libm = ctypes.CDLL("libm.so.6")
    libm.sincos.restype = None
    dp = ctypes.POINTER(ctypes.c_double)
    libm.sincos.argtypes = [ctypes.c_double, dp, dp]
    rng = np.random.default_rng(27)
    edges = [2.0**-27, 2.0**-28, 1 / 128, 1 / 256, 3 / 256, 0.0, 5e-324, 1e-310]
    edges += [np.nextafter(v, d) for v in edges[:5] for d in (0.0, 1.0)]
    x = np.concatenate([
        rng.choice([-1.0, 1.0], 200_000) * 2.0 ** rng.uniform(-40, -6.3, 200_000),
        rng.uniform(-4.0, 4.0, 2000), edges, np.negative(edges), [np.inf, -np.inf, np.nan]])
    x = np.concatenate([x, np.zeros(-x.size % 8)])
    ref_s, ref_c = np.empty_like(x), np.empty_like(x)
    s1, c1 = ctypes.c_double(), ctypes.c_double()
    for i, v in enumerate(x):
        libm.sincos(float(v), ctypes.byref(s1), ctypes.byref(c1))
        ref_s[i], ref_c[i] = s1.value, c1.value
    for w in _vector_widths(sim_lib):
        s, c, used = _lanes_sincos(sim_lib, w, x)
        assert np.array_equal(s.view(np.int64), ref_s.view(np.int64)), w
        assert np.array_equal(c.view(np.int64), ref_c.view(np.int64)), w
        assert used == 1 or not _glibc_x86(), f"W={w}: the lanes' sincos fell back to libm"


@pytest.mark.needs_cc
def test_the_lanes_sincos_within_glibcs_bound_against_mpmath(sim_lib) -> None:
    """The kernels' sine and cosine where the vector form runs (|x| below 3/256) against
    mpmath at 50 digits: within 0.55 ulp, glibc's stated bound for them (0.548 ulp)."""
    import mpmath

    widths = _vector_widths(sim_lib)
    rng = np.random.default_rng(11)
    x = rng.choice([-1.0, 1.0], 2000) * 2.0 ** rng.uniform(-27, -6.42, 2000)
    mpmath.mp.dps = 50
    ref_s = [mpmath.sin(mpmath.mpf(float(v))) for v in x]
    ref_c = [mpmath.cos(mpmath.mpf(float(v))) for v in x]
    for w in widths:
        s, c, _ = _lanes_sincos(sim_lib, w, x)
        for got, ref in ((s, ref_s), (c, ref_c)):
            worst = max(float(abs(mpmath.mpf(float(g)) - r)) / np.spacing(abs(float(r)))
                        for g, r in zip(got, ref, strict=True))
            assert worst <= 0.55, (w, worst)


@pytest.mark.needs_cc
def test_roa_confirmation_batch_equals_single_runs(carriage, sim_lib, op) -> None:
    """roa's confirmation runs of one round go in one batch (the lanes): each (status,
    V(end) / V(start)) is the one `simulate` gives for its deviation alone."""
    from maglevgen.analyses import roa
    from maglevgen.analyses.simulate import run_loop, simulate
    from maglevgen.control.carriage_plant import Plant

    min_gap = carriage.params.track.min_gap
    tick, k_v, budget = loop = run_loop(Plant(carriage, sim_lib), "firmware")
    P = roa.lyapunov_matrix(op, "spec")
    assert P is not None
    d0 = roa.default_deviation()
    dxs = [m * d0 for m in (0.5, 1.0, -2.0, 40.0)]
    got = roa.confirmation_run(sim_lib, carriage.p, op, "spec", min_gap, loop)(dxs, P)
    index = list(roa.REDUCED_INDEX)
    for dx, (status, ratio) in zip(dxs, got, strict=True):
        traj = simulate(sim_lib, carriage.p, op, "spec", roa.CONFIRM_T_END, roa.CONFIRM_DT,
                        min_gap, dict(zip(roa.REDUCED_STATES, map(float, dx), strict=True)),
                        tick=tick, speed_gain=k_v, force_budget=budget)
        end = traj.x[-1, index] - op.x_trim[index]
        assert (status, ratio) == (traj.status, float(end @ P @ end / (dx @ P @ dx)))


@pytest.fixture(scope="module")
def sensed_runs(carriage, sim_lib, op):
    """A maker of eleven runs on the sensors (the firmware's sense tick, each run its own
    noise seed, readings, predictions and commands recorded) and a run on the exact state
    between them, ``n`` steps each, made afresh at each call (a run's sense state is its
    own): nominal and heavier carriages, a disturbance that reaches contact, a force budget
    the sense tick's law saturates at, a NaN parameter (an error at step 0) and a noise scale
    of 0."""
    from maglevgen.analyses.simulate import run_loop
    from maglevgen.control.carriage_plant import Plant

    plant = Plant(carriage, sim_lib)
    sensed, k_v, budget = run_loop(plant, "sensed", seed=53)
    firmware = run_loop(plant, "firmware")
    p2 = carriage.p.copy()
    p2[carriage.structure.param_names.index("vehicle.mass")] *= 1.04
    min_gap = carriage.params.track.min_gap
    op2 = operating_point(sim_lib, p2, op.speed, min_gap, Weights.of(carriage.params))
    bad = carriage.p.copy()
    bad[carriage.structure.param_names.index("vehicle.mass")] = np.nan
    cases = [(carriage.p, op, {"z": 1e-3}, budget, 1.0), (p2, op2, {"phi": 2e-3}, budget, 1.0),
             (carriage.p, op, {"y": -1e-3}, budget, 1.0),
             (carriage.p, op, {"z": 0.03}, budget, 1.0),
             (carriage.p, op, {"z": 2e-3, "phi": 4e-3}, 0.05, 1.0),
             (bad, op, {"z": 1e-3}, budget, 1.0), (carriage.p, op, {"theta": 1e-3}, budget, 0.0),
             (p2, op2, {"psi": -3e-3}, budget, 1.0), (carriage.p, op, {"z": -2e-3}, budget, 1.0),
             (carriage.p, op, {"y": 2e-3}, budget, 3.0), (p2, op2, {"z": 1e-3}, budget, 1.0)]

    def make(n: int) -> list:
        out = [hold_run(p, o, "spec", DT, d, replace(sensed, seed=53 + k, noise_scale=scale),
                        k_v, fb, n_steps=n)
               for k, (p, o, d, fb, scale) in enumerate(cases)]
        out.insert(3, hold_run(carriage.p, op, "spec", DT, {"z": 1e-3}, *firmware, n_steps=n))
        return out

    return make


def _same_sensing(a, b) -> bool:
    """Two runs' sense ticks recorded the same readings, predictions, commands and error."""
    if a.loop.sense is None:
        return b.loop.sense is None
    sa, sb = a.loop.sense, b.loop.sense
    return (np.array_equal(sa.readings, sb.readings) and np.array_equal(sa.predicted, sb.predicted)
            and np.array_equal(sa.commands, sb.commands) and sa.tick_error == sb.tick_error)


@pytest.mark.needs_cc
def test_sensed_runs_in_the_lanes_equal_the_scalar_loop(carriage, sim_lib, op,
                                                        sensed_runs) -> None:
    """Runs on the sensors fly in the lanes (the plant's stages in SIMD, each run's sense tick
    its own C per lane): at every lane count the CPU runs, the scalar driver (one
    maglev_simulate a run) and on two threads, a batch of twelve (no multiple of 8), every
    run bit for bit the run maglev_simulate makes on its own, its sense tick's readings,
    predictions, commands and error too. The runs reach what they are meant to: a contact,
    saturated steps, an error at once."""
    n_u, n_g, n = op.allocation.shape[0] + 1, op.gaps.size, 400
    min_gap = carriage.params.track.min_gap
    reference = sensed_runs(n)
    want = _scalar(sim_lib, reference, n, min_gap, n_u, n_g)
    statuses = [w.status for w in want]
    assert statuses[4] == 1 and 0 < want[4].last < n // 2, (statuses[4], want[4].last)  # contact
    assert want[5].saturated_steps > 0
    assert statuses[6] == 3 and want[6].last == 0  # the NaN parameter: an error at once
    assert statuses.count(0) == len(reference) - 2
    assert reference[0].loop.sense.readings.any() and reference[3].loop.sense is None
    for lanes, threads in [(None, 1), *((w, 1) for w in _widths(sim_lib)), (0, 2)]:
        batch = sensed_runs(n)
        got = sim_lib.simulate_batch(batch, DT, n, min_gap, n_u, n_g, threads, lanes=lanes)
        for i, (a, b) in enumerate(zip(want, got, strict=True)):
            assert _same(a, b), (lanes, threads, i)
        for i, (r, s) in enumerate(zip(reference, batch, strict=True)):
            assert _same_sensing(r, s), (lanes, threads, i)


def _compile_lanes(cc: str, tmp_path, sim_lib) -> None:
    """templates/maglev_lanes.c and the library's kernels, -Wall -Wextra -Werror."""
    import subprocess
    from pathlib import Path

    kernels = tmp_path / "kernels.c"
    kernels.write_text(lane_kernels((Path(sim_lib.sources) / "maglev_functions.c").read_text()))
    driver = Path(__file__).resolve().parents[1] / "templates" / "maglev_lanes.c"
    proc = subprocess.run([cc, "-std=c99", "-O1", "-fPIC", "-shared", "-Wall", "-Wextra",
                           "-Werror", f"-I{sim_lib.sources}", str(driver), str(kernels),
                           str(sim_lib.path), "-o", str(tmp_path / f"lanes_{cc}.so"), "-lm"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[:2000]


@pytest.mark.needs_cc
def test_the_lane_driver_compiles_without_warnings_gcc(tmp_path, sim_lib) -> None:
    _compile_lanes("gcc", tmp_path, sim_lib)


@pytest.mark.needs_cc("clang")
def test_the_lane_driver_compiles_without_warnings_clang(tmp_path, sim_lib) -> None:
    _compile_lanes("clang", tmp_path, sim_lib)


@pytest.mark.needs_cc
def test_sensed_runs_in_the_lanes_over_ten_seconds(carriage, sim_lib, op, sensed_runs) -> None:
    """The issue's measure on the sensors: 10 s at 1 kHz (10^4 ticks of the sense tick), the
    widest lanes, the twelve runs: every state at the end, the whole trajectories and the
    recorded readings bit for bit maglev_simulate's."""
    n_u, n_g, n = op.allocation.shape[0] + 1, op.gaps.size, 10_000
    min_gap = carriage.params.track.min_gap
    reference = sensed_runs(n)
    want = _scalar(sim_lib, reference, n, min_gap, n_u, n_g)
    assert sum(w.last == n for w in want) >= 6, [w.last for w in want]
    batch = sensed_runs(n)
    got = sim_lib.simulate_batch(batch, DT, n, min_gap, n_u, n_g, 1, lanes=0)
    for i, (a, b) in enumerate(zip(want, got, strict=True)):
        assert np.array_equal(a.x[-1], b.x[-1]), i
        assert _same(a, b), i
    for i, (r, s) in enumerate(zip(reference, batch, strict=True)):
        assert _same_sensing(r, s), i
