"""The benchmark suite: derivation, generation, the `maglevgen build` workflow, generated-code
speed and footprint, against the usual alternatives, measured in one run. Writes BENCHMARKS.md
and bench/results.json.

    python bench/run.py [--quick] [--out BENCHMARKS.md] [--json bench/results.json]

(`make bench` runs it in the project's virtual environment.) Every ratio pairs two figures
taken in the same repeat: C contenders alternate inside the C drivers; each Python repeat is
followed by a short C run whose median it is divided by. Figures are medians of repeats.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import alternatives as alt
import casadi_peer
import envelope as envelope_bench
import native
import peers as peers_bench
import simd_batch
import workflow
import writeup
from common import BENCH, ROOT, log, paired_ratios, run, summary, time_calls

from maglevgen.analyses.envelope import speed_range
from maglevgen.carriage import DerivedCarriage
from maglevgen.codegen.functions import build_functions
from maglevgen.codegen.generate import GenerateOptions, render, write_output
from maglevgen.control.symbolic_reference import allocation_matrix
from maglevgen.derive import conventions as cv
from maglevgen.infrastructure.cache import toolchain_fingerprint
from maglevgen.params import load_params
from maglevgen.runtime.compile import compile_shared
from maglevgen.runtime.ffi import GeneratedLibrary

# The closed loop: 10 s at 1 kHz from trim plus the toolchain's disturbance (per axis y, z,
# phi, theta, psi), LQR gains at the default speed.
DISTURBANCE = np.array(list(cv.DISTURBANCE.values()))
DT, N_STEPS = 1e-3, 10_000
N_SAMPLES = 64  # states near trim cycled through by the per-call timings
COMPILERS = ("gcc", "clang")  # the C drivers' compilers (clang where installed)
# the schedule (trim, plants, gains) in float32 and float64 at these multiples of the speed
SCHEDULE_SPEED_FACTORS = (0.4, 0.6, 1.0, 1.5, 2.25)
# generated functions maglev_simulate may call (the first three: the model's right-hand side,
# by the name of its current and earlier versions), counted by callgrind when it does
RHS_FUNCTIONS = ("maglev_closed_loop_prepared", "maglev_closed_loop", "maglev_rk4_step")
LOOP_FUNCTIONS = (
    *RHS_FUNCTIONS,
    "maglev_closed_loop_prepare",
    "maglev_gaps",
    "maglev_allocation_matrix",
)


@dataclass(frozen=True)
class Repeats:
    derive: int = 3  # cold + cached derivation pairs (fresh processes)
    c_dynamics: int = 41  # repeats inside the C driver, each of C_CALLS calls per contender
    c_calls: int = 20_000
    c_simulate: int = 41
    py_dynamics: int = 5  # repeats of each Python per-call contender
    py_loop: int = 3  # repeats of each Python closed-loop contender
    precision_rounds: int = 5
    controller_ms: float = 10.0
    build_cold: int = 2  # `maglevgen build` from an empty cache (fresh processes)
    build_rebuild: int = 5  # parameter change, unchanged and PDF builds, each
    build_profile: int = 3  # profiled parameter-change builds, per kind (timers, cProfile)

    @classmethod
    def quick(cls) -> Repeats:
        return cls(
            derive=1,
            c_dynamics=5,
            c_calls=5000,
            c_simulate=3,
            py_dynamics=2,
            py_loop=1,
            precision_rounds=2,
            controller_ms=2.0,
            build_cold=1,
            build_rebuild=1,
            build_profile=1,
        )


# ------------------------------------------------------------------------------ machine


def _first_line(cmd: list[str]) -> str:
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, check=False)
        return (out.stdout or out.stderr).strip().splitlines()[0]
    except (OSError, IndexError):
        return "not installed"


def machine() -> dict:
    import scipy
    import sympy

    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        affinity = len(os.sched_getaffinity(0))
    except AttributeError:
        affinity = os.cpu_count()
    return {
        "cpu": cpu,
        "logical_cpus": os.cpu_count(),
        "usable_cpus": affinity,
        "platform": platform.platform(),
        "python": platform.python_version(),
        "gcc": _first_line(["gcc", "--version"]),
        "clang": _first_line(["clang", "--version"]),
        "valgrind": _first_line(["valgrind", "--version"]),
        "libc": " ".join(platform.libc_ver()),
        "casadi": ca.__version__,
        "sympy": sympy.__version__,
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "loadavg_start": os.getloadavg(),
    }


def git_state() -> dict:
    try:
        head = run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT).strip()
        dirty = bool(run(["git", "status", "--porcelain"], cwd=ROOT).strip())
    except (RuntimeError, OSError):
        return {"commit": "unknown", "dirty": None}
    return {"commit": head, "dirty": dirty}


# --------------------------------------------------------------------------- derivation


def derivation(work: Path, reps: Repeats) -> dict:
    """Fresh-process derivation + generation + compile: cold (empty caches), then cached
    (a second fresh process on the same cache folder), in pairs."""
    cold, cached = [], []
    for i in range(reps.derive):
        cache = work / f"derive_cache{i}"
        env = {**os.environ, "MAGLEVGEN_CACHE": str(cache)}
        for runs in (cold, cached):
            log(f"derivation run {i + 1}/{reps.derive} ({'cold' if runs is cold else 'cached'})")
            out = run(
                [sys.executable, BENCH / "derive_phases.py", work / f"derive_out{i}"], env=env
            )
            runs.append(json.loads(out.strip().splitlines()[-1]))
    phases = list(cold[0])
    return {
        "cold": cold,
        "cached": cached,
        "summary": {
            "cold": {k: summary([r[k] for r in cold]) for k in phases},
            "cached": {k: summary([r[k] for r in cached]) for k in phases},
        },
        "cached_over_cold": paired_ratios([r["total"] for r in cached], [r["total"] for r in cold]),
    }


# ------------------------------------------------------------------------------- set-up

# The force laws timed side by side in every C timing (model.array_force; the default first),
# and the model the hand-written C (bench/reference/maglev_model.c) computes: the paper's point
# law with quasi-static circuits (tests/test_bench_reference.py checks it against that build),
# so the hand-written C is compared with that build only.
DEFAULT_LAW = "distributed"
LAWS: dict[str, tuple[str, ...]] = {
    "distributed": (),
    "point": ('model.array_force="point"',),
}
PAPER = "paper"
PAPER_OVERRIDES = ('model.array_force="point"', 'model.circuit_dynamics="quasi-static"')
VARIANTS: dict[str, tuple[str, ...]] = {**LAWS, PAPER: PAPER_OVERRIDES}


@dataclass
class Variant:
    """One carriage model's run-time-parameter double build and its C drivers."""

    label: str
    overrides: tuple[str, ...]
    carriage: DerivedCarriage
    gen: dict[str, Path]  # "double_runtime" and, for the laws, the two baked builds
    lib: GeneratedLibrary
    lib_path: Path
    loop: alt.Loop
    X: np.ndarray
    U: np.ndarray
    exe: dict[str, Path]  # compiler -> bench_runtime (generated + hand-written + driver)
    runtime_input: Path
    controller_exe: dict[str, Path]  # precision -> bench_controller (laws only)
    newton_exe: dict[str, Path]  # the same, with the trim's Newton iterations counted
    controller_input: Path | None


@dataclass
class Setup:
    variants: dict[str, Variant]
    functions: tuple  # the default carriage's CasADi Functions (the Python contenders)
    work: Path

    @property
    def default(self) -> Variant:
        return self.variants[DEFAULT_LAW]

    @property
    def paper(self) -> Variant:
        return self.variants[PAPER]

    @property
    def laws(self) -> dict[str, Variant]:
        return {k: self.variants[k] for k in LAWS}


def _prepare_variant(label: str, overrides: tuple[str, ...], work: Path) -> Variant:
    log(f"{label}: deriving the carriage ({', '.join(overrides) or 'defaults'}) and generating")
    carriage = DerivedCarriage(load_params(None, list(overrides)))
    builds = [("double", "runtime")]
    if label in LAWS:
        builds += [("double", "baked"), ("single", "baked")]
    gen = {}
    for precision, params in builds:
        out = work / f"gen_{label}_{precision}_{params}"
        write_output(render(carriage, GenerateOptions(precision, params),
                            speed_range(carriage)), out)
        gen[f"{precision}_{params}"] = out
    rt = gen["double_runtime"]
    if not (rt / "maglev_simulate.c").exists():
        raise SystemExit("bench: the runtime build has no maglev_simulate.c; update maglevgen")
    lib_path = compile_shared(
        [rt / "maglev_functions.c", rt / "maglev_simulate.c"], cache_dir=work / f"lib_{label}"
    )
    lib = GeneratedLibrary(lib_path, "double")
    speed = carriage.params.operation.speed
    x_trim, f_prop = (a.ravel() for a in lib.function("maglev_trim")(speed, carriage.p))
    K, _c = lib.function("maglev_lqr_gains")(speed, carriage.p)
    a_trim = x_trim[alt.AXIS_IDX]
    x0 = x_trim.copy()
    x0[alt.AXIS_IDX] += DISTURBANCE
    loop = alt.Loop(
        x0=x0,
        F_prop=float(f_prop[0]),
        k_pos=K[:, 0].copy(),
        k_rate=K[:, 1].copy(),
        a_ref=a_trim,
        dt=DT,
        n_steps=N_STEPS,
        gap_min=carriage.params.track.min_gap,
    )
    # the same perturbations about each model's own trim
    rng = np.random.default_rng(2024)
    X = x_trim + rng.normal(
        scale=[0.5, 2e-3, 2e-3, 0.01, 0.01, 0.01, 2, 0.05, 0.05, 0.05, 0.05, 0.05],
        size=(N_SAMPLES, 12),
    )
    U = np.zeros((N_SAMPLES, carriage.model.u.shape[0]))
    U[:, 0] = loop.F_prop
    U += rng.normal(scale=5.0, size=U.shape)
    log(f"{label}: compiling the C drivers (-O2)")
    runtime_input = native.write_runtime_input(
        work / f"runtime_input_{label}.txt", carriage.p, loop.as_dict(), X, U
    )
    # the drivers compiled two at a time (nothing is timed yet)
    with ThreadPoolExecutor(2) as pool:
        exe_jobs = {
            cc: pool.submit(native.build_runtime_driver, rt, work / f"drv_{label}_runtime_{cc}",
                            cc=cc)
            for cc in COMPILERS
            if shutil.which(cc)
        }
        ctl_jobs, newton_jobs = {}, {}
        if label in LAWS:
            for p in ("double", "single"):
                ctl_jobs[p] = pool.submit(native.build_controller_driver, gen[f"{p}_baked"],
                                          work / f"drv_{label}_{p}")
                newton_jobs[p] = pool.submit(native.build_controller_driver, gen[f"{p}_baked"],
                                             work / f"drv_{label}_{p}_newton", count_newton=True)
        exe = {cc: j.result() for cc, j in exe_jobs.items()}
        controller_exe = {p: j.result() for p, j in ctl_jobs.items()}
        newton_exe = {p: j.result() for p, j in newton_jobs.items()}
    controller_input = (
        native.write_controller_input(work / f"controller_input_{label}.txt", speed, X)
        if label in LAWS
        else None
    )
    return Variant(label, overrides, carriage, gen, lib, lib_path, loop, X, U, exe,
                   runtime_input, controller_exe, newton_exe, controller_input)


def prepare(work: Path) -> Setup:
    for label in VARIANTS:
        (work / label).mkdir(parents=True, exist_ok=True)  # its callgrind files
    variants = {label: _prepare_variant(label, ov, work) for label, ov in VARIANTS.items()}
    names = [e.name for e in variants[PAPER].carriage.entries]
    for v in variants.values():  # one driver reads every model's p: the same vector
        if [e.name for e in v.carriage.entries] != names:
            raise SystemExit(f"bench: the {v.label} model's parameter vector differs")
    functions = build_functions(variants[DEFAULT_LAW].carriage.model).functions
    return Setup(variants, functions, work)


def _interleaved(s: Setup, cc: str, mode: str, reps: int, *args: int) -> dict[str, dict]:
    """bench_runtime ``mode`` of every model in turn, two repeats per process, the models'
    order reversed every round: each model's lists (generated and hand-written figures), the
    i-th entries of all models taken in the same round."""
    labels = [k for k, v in s.variants.items() if cc in v.exe]
    out: dict[str, dict] = {k: {} for k in labels}
    for r in range(max(1, (reps + 1) // 2)):
        for label in labels if r % 2 == 0 else labels[::-1]:
            v = s.variants[label]
            d = json.loads(run([v.exe[cc], v.runtime_input, mode, 2, *args]))
            for key, val in d.items():
                if isinstance(val, list) and key.endswith("_ns"):
                    out[label].setdefault(key, []).extend(val)
                else:
                    out[label][key] = val
    return out


def _laws_table(raw: dict[str, dict], scale: float = 1.0) -> dict:
    """Each model's generated-C figures and the distributed / point ratio per round."""
    gen = {k: np.array(v["generated_ns"]) / scale for k, v in raw.items()}
    out = {f"{k}_{'ns' if scale == 1.0 else 'ms'}": summary(g) for k, g in gen.items()}
    out["distributed_over_point"] = paired_ratios(gen["distributed"], gen["point"])
    return out


# ----------------------------------------------------------------------------- dynamics

# sympy.lambdify of the composed model without cse: under the distributed law a build that
# may not end in the run's time; a contender not built by then is recorded as such
LAMBDIFY_LIMIT_S = 300


@contextmanager
def _time_limit(seconds: int) -> Iterator[None]:
    """TimeoutError in the main thread after ``seconds`` (SIGALRM; SymPy is pure Python)."""

    def expired(_sig: int, _frame: object) -> None:
        raise TimeoutError

    previous = signal.signal(signal.SIGALRM, expired)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)



def _c_generated_dynamics_ns(s: Setup) -> float:
    """A short C timing of the generated dynamics (default law), to pair with a Python figure."""
    d = native.time_dynamics(s.default.exe["gcc"], s.default.runtime_input, 3, 20_000)
    return float(np.median(d["generated_ns"]))


def dynamics(s: Setup, reps: Repeats) -> dict:
    out: dict = {"laws": {}, "other_compilers": {}}
    for cc in COMPILERS:
        if cc not in s.paper.exe:
            continue
        log(f"dynamics: C built by {cc}, the models interleaved")
        raw = _interleaved(s, cc, "dynamics", reps.c_dynamics, reps.c_calls)
        out["laws"][cc] = _laws_table(raw)
        c = raw[PAPER]
        ref = {
            "calls_per_repeat": c["calls"],
            "generated_ns": summary(c["generated_ns"]),
            "reference_ns": summary(c["reference_ns"]),
            "reference_prepared_ns": summary(c["reference_prepared_ns"]),
            "generated_over_reference": paired_ratios(c["generated_ns"], c["reference_ns"]),
            "generated_over_reference_prepared": paired_ratios(
                c["generated_ns"], c["reference_prepared_ns"]
            ),
        }
        if cc == "gcc":
            out["c"] = {**ref, "raw": raw}
        else:
            out["other_compilers"][cc] = ref
    log("dynamics: callgrind instruction counts")
    exe, inp = s.paper.exe["gcc"], s.paper.runtime_input
    out["callgrind"] = {
        which: native.callgrind(exe, inp, which, sym, 2000, s.work / PAPER)
        for which, sym in (("gen", "maglev_dynamics"), ("ref", "ref_dynamics"))
    }
    out["callgrind_laws"] = {
        k: native.callgrind(v.exe["gcc"], v.runtime_input, "gen", "maglev_dynamics", 2000,
                            s.work / k)
        for k, v in s.laws.items()
    }
    out["generated_asm"] = native.disassembly_stats(
        s.paper.exe["gcc"].parent / "maglev_functions.o", "maglev_dynamics"
    )
    out["generated_body"] = native.count_math_calls(
        (s.paper.gen["double_runtime"] / "maglev_functions.c").read_text(),
        "/* maglev_dynamics:(",
    )
    return out


def python_dynamics(s: Setup, reps: Repeats) -> dict:
    v = s.default  # the Python contenders compute the default law: paired with its C
    p = v.carriage.p
    X, U = v.X, v.U
    n = len(X)
    contenders = {}
    dyn = alt.function_named(s.functions, "maglev_dynamics")
    contenders["casadi.Function (SX), numpy arrays in"] = (
        lambda i: dyn(X[i % n], U[i % n], p),
        5_000,
        0.0,
    )
    XD, UD, PD = [ca.DM(x) for x in X], [ca.DM(u) for u in U], ca.DM(p)
    contenders["casadi.Function (SX), casadi.DM in"] = (
        lambda i: dyn(XD[i % n], UD[i % n], PD),
        5_000,
        0.0,
    )
    ext = v.lib.function("maglev_dynamics")
    contenders["generated C through ctypes (runtime.ffi)"] = (
        lambda i: ext(X[i % n], U[i % n], p),
        10_000,
        0.0,
    )
    mf = v.carriage.functions
    contenders["maglevgen numeric layer (lambdified layers, cse)"] = (
        lambda i: mf.xdot(X[i % n], U[i % n], p),
        1_500,
        0.0,
    )
    out: dict = {}
    for cse in (True, False):
        log(f"dynamics: sympy.lambdify of the composed xdot, cse={cse}")
        label = f"sympy.lambdify numpy, {'with' if cse else 'without'} cse"
        try:
            with _time_limit(LAMBDIFY_LIMIT_S):
                f, build_s = alt.lambdify_xdot(v.carriage, cse)
        except TimeoutError:
            out[label] = {"not_built": f"lambdify not done within {LAMBDIFY_LIMIT_S} s"}
            log(f"dynamics: {label}: {out[label]['not_built']}")
            continue
        ref = np.asarray(f(X[0], U[0], p), dtype=float).ravel()
        want = ext(X[0], U[0], p)[0].ravel()
        if not np.allclose(ref, want, rtol=1e-9, atol=1e-9 * np.max(np.abs(want))):
            raise RuntimeError(f"lambdify (cse={cse}) disagrees with the generated C")
        contenders[label] = (
            (lambda i, f=f: f(X[i % n], U[i % n], p)),
            3_000 if cse else 6,
            build_s,
        )
    for label, (fn, calls, build_s) in contenders.items():
        log(f"dynamics: {label}")
        py, cg = [], []
        for _ in range(reps.py_dynamics):
            py.append(time_calls(fn, calls))
            cg.append(_c_generated_dynamics_ns(s))
        out[label] = {
            "calls_per_repeat": calls,
            "ns": summary(py),
            "build_s": build_s,
            "c_generated_ns": summary(cg),
            "over_generated_c": paired_ratios(py, cg),
            "raw_ns": py,
            "raw_c_generated_ns": cg,
        }
    return out


# -------------------------------------------------------------------------- closed loop


def _c_simulate_ns(s: Setup) -> float:
    d = native.time_simulate(s.default.exe["gcc"], s.default.runtime_input, 3)
    return float(np.median(d["generated_ns"]))


def _generated_trajectory(v: Variant) -> tuple[np.ndarray, int, int]:
    """maglev_simulate called once through ctypes: (x rows, last sample, status)."""
    import ctypes

    d = ctypes.POINTER(ctypes.c_double)
    lib = ctypes.CDLL(str(v.lib_path))
    fn = lib.maglev_simulate
    fn.restype = ctypes.c_longlong
    fn.argtypes = [
        d,
        ctypes.c_double,
        ctypes.c_longlong,
        ctypes.c_double,
        d,
        d,
        d,
        ctypes.c_void_p,  # loop: NULL, the plain loop
        d,
        ctypes.c_double,
        d,
        d,
        d,
        ctypes.c_void_p,  # saturated: NULL
        ctypes.POINTER(ctypes.c_int),
    ]
    lp, n = v.loop, v.loop.n_steps
    X, U, G = np.zeros((n + 1, 12)), np.zeros((n + 1, 11)), np.zeros((n + 1, 6))
    # the per-axis gains as the 5 x 5 (diagonal) matrices maglev_simulate takes
    arrs = [
        np.ascontiguousarray(a, dtype=float)
        for a in (lp.x0, np.diag(lp.k_pos), np.diag(lp.k_rate), lp.a_ref, v.carriage.p)
    ]
    ptr = [a.ctypes.data_as(d) for a in arrs]
    status = ctypes.c_int(-1)
    last = fn(
        ptr[0],
        lp.dt,
        n,
        lp.F_prop,
        ptr[1],
        ptr[2],
        ptr[3],
        None,
        ptr[4],
        lp.gap_min,
        X.ctypes.data_as(d),
        U.ctypes.data_as(d),
        G.ctypes.data_as(d),
        None,
        ctypes.byref(status),
    )
    return X[: last + 1], int(last), status.value


def _loop_callgrind(v: Variant, work: Path, symbols: tuple[tuple[str, str], ...]) -> dict:
    n = v.loop.n_steps
    cg = {}
    for which, sym in symbols:
        got = native.callgrind(v.exe["gcc"], v.runtime_input, which, sym, 1, work)
        if got is not None and got["instructions"] > 0:  # absent: maglev_simulate never calls it
            cg[sym] = {
                "instructions_per_step": got["instructions"] / n,
                "libm_calls_per_step": {k: x / n for k, x in got["libm_calls"].items()},
            }
            if "divisions" in got:
                cg[sym]["divisions_per_step"] = got["divisions"] / n
    return cg


def closed_loop(s: Setup, reps: Repeats) -> dict:
    out: dict = {
        "loop": {
            k: (x.tolist() if isinstance(x, np.ndarray) else x)
            for k, x in s.default.loop.as_dict().items()
        },
        "laws": {},
        "python": {},
        "other_compilers": {},
    }
    for cc in COMPILERS:
        if cc not in s.paper.exe:
            continue
        log(f"closed loop: C built by {cc}, the models interleaved")
        raw = _interleaved(s, cc, "simulate", reps.c_simulate)
        for label, d in raw.items():
            if (d["generated"]["last"], d["generated"]["status"]) != (N_STEPS, 0):
                raise RuntimeError(f"maglev_simulate ({label}, {cc}) stopped: {d['generated']}")
        out["laws"][cc] = _laws_table(raw, 1e6)
        c = raw[PAPER]
        ref = {
            "generated_ms": summary(np.array(c["generated_ns"]) / 1e6),
            "reference_ms": summary(np.array(c["reference_ns"]) / 1e6),
            "generated_over_reference": paired_ratios(c["generated_ns"], c["reference_ns"]),
        }
        if cc == "gcc":
            out["c"] = {
                **ref,
                "agreement": c["max_rel_diff"],
                "status": {"generated": c["generated"], "reference": c["reference"]},
                "raw": raw,
            }
        else:
            out["other_compilers"][cc] = ref
    log("closed loop: callgrind instruction counts per RK4 step")
    cg = _loop_callgrind(s.paper, s.work / PAPER, (
        ("simgen", "maglev_simulate"),
        *(("simgen", f) for f in LOOP_FUNCTIONS),
        ("simref", "ref_simulate"),
    ))
    out["callgrind"] = cg
    out["callgrind_laws"] = {
        k: _loop_callgrind(v, s.work / k, (("simgen", "maglev_simulate"),))
        for k, v in s.laws.items()
    }
    # the function holding the model in the loop: its compiled code's instruction mix
    worker = next((f for f in RHS_FUNCTIONS if f in cg), None)
    if worker is not None:
        out["generated_asm"] = native.disassembly_stats(
            s.paper.exe["gcc"].parent / "maglev_functions.o", worker
        )
    return out


def closed_loop_python(s: Setup, reps: Repeats) -> dict:
    """The Python contenders of the closed loop: the default law, against its generated C."""
    out: dict = {}
    v = s.default
    X_c, last, status = _generated_trajectory(v)
    if (last, status) != (v.loop.n_steps, 0):
        raise RuntimeError(f"maglev_simulate stopped at sample {last} with status {status}")
    rhs = alt.closed_loop_function(s.functions)
    names = {f.name() for f in s.functions}
    gaps = alt.function_named(s.functions, "maglev_gaps") if "maglev_gaps" in names else None
    kin = alt.lambdify_kinematics(v.carriage)
    xdot, _ = alt.lambdify_xdot(v.carriage, cse=True)
    T = allocation_matrix(v.carriage)
    p = v.carriage.p
    stages = 4 * v.loop.n_steps + 1
    contenders = {
        "Python RK4 loop over casadi.Function": lambda: (
            alt.casadi_rk4(rhs, gaps, v.loop, p)[0],
            stages,
        ),
        (
            f"scipy solve_ivp {alt.IVP_METHOD} (rtol {alt.IVP_RTOL:g}, atol {alt.IVP_ATOL:g}) "
            "on the CSE-lambdified model"
        ): lambda: alt.ivp_closed_loop(xdot, kin, T, v.loop, p),
    }
    for label, fn in contenders.items():
        py, cg = [], []
        for i in range(reps.py_loop):
            log(f"closed loop: {label} ({i + 1}/{reps.py_loop})")
            t0 = time.perf_counter_ns()
            X_py, nfev = fn()
            py.append(time.perf_counter_ns() - t0)
            cg.append(_c_simulate_ns(s))
        dev = np.abs(X_py - X_c)
        out[label] = {
            "ms": summary(np.array(py) / 1e6),
            "c_generated_ms": summary(np.array(cg) / 1e6),
            "over_generated_c": paired_ratios(py, cg),
            "rhs_evaluations": nfev,
            "max_deviation_from_generated_c": {
                "position_m": float(dev[:, 1:3].max()),
                "attitude_rad": float(dev[:, 3:6].max()),
                "all_states_relative": float(
                    (dev / np.maximum(np.abs(X_c).max(axis=0), 1e-300)).max()
                ),
            },
        }
    return out


# ------------------------------------------------------------------------------ precision


def precision(s: Setup, reps: Repeats) -> dict:
    """Firmware functions, float32 vs float64 (baked builds), of each force law: the four
    drivers in turn in every round (the order rotating); and the schedule each precision
    computes (trim, Newton iterations, gains) over speeds, for the default law."""
    drivers = [(law, prec) for law in LAWS for prec in ("single", "double")]
    rounds: dict[tuple[str, str], list[dict]] = {d: [] for d in drivers}
    for r in range(reps.precision_rounds):
        log(f"firmware functions, the laws in float32 and float64, round {r + 1}/"
            f"{reps.precision_rounds}")
        for law, prec in drivers[r % len(drivers):] + drivers[: r % len(drivers)]:
            v = s.variants[law]
            rounds[law, prec].append(
                native.time_controller(
                    v.controller_exe[prec], v.controller_input, 3, reps.controller_ms
                )
            )
    first = rounds[DEFAULT_LAW, "single"][0]
    kinds = [k for k in first if k.endswith("_ns")]
    out = {
        "kinds": {},
        "newton": {
            prec: native.newton_settings(
                (s.default.gen[f"{prec}_baked"] / "maglev_functions.c").read_text()
            )
            for prec in ("single", "double")
        },
    }

    def med(law: str, prec: str, k: str) -> list[float]:
        return [float(np.median(x[k])) for x in rounds[law, prec]]

    for k in kinds:
        single, double = med(DEFAULT_LAW, "single", k), med(DEFAULT_LAW, "double", k)
        pt_single, pt_double = med("point", "single", k), med("point", "double", k)
        out["kinds"][k.removesuffix("_ns")] = {
            "single_ns": summary(single),
            "double_ns": summary(double),
            "single_over_double": paired_ratios(single, double),
            "point_single_ns": summary(pt_single),
            "point_double_ns": summary(pt_double),
            "distributed_over_point_single": paired_ratios(single, pt_single),
            "distributed_over_point_double": paired_ratios(double, pt_double),
        }
    out["workspace_reals"] = {p: rounds[DEFAULT_LAW, p][0]["sz_w"] for p in ("single", "double")}
    out["schedule"] = schedule_accuracy(s.default)
    return out


def schedule_accuracy(v: Variant) -> dict:
    """The schedule of each baked build at several speeds: Newton iterations, the residual
    of its trim in its own precision, and how far float32's trim and gains are from float64's
    (and float64's from the run-time-parameter library's)."""
    log("schedule (trim, Newton iterations, gains) in float32 and float64")
    speed = v.carriage.params.operation.speed
    speeds = [speed * f for f in SCHEDULE_SPEED_FACTORS]
    got = {
        prec: native.controller_schedule(v.newton_exe[prec], v.controller_input, speeds)["speeds"]
        for prec in ("single", "double")
    }
    rows = []
    for sg, db in zip(got["single"], got["double"], strict=True):
        K_rt, _c = v.lib.function("maglev_lqr_gains")(db["speed"], v.carriage.p)
        K_rt = np.asarray(K_rt).ravel(order="F")  # column-major, as the C arrays

        def rel(a: str, b: dict, ref: dict = db) -> float:
            x, y = np.asarray(b[a]), np.asarray(ref[a])
            return float(np.max(np.abs(x - y) / np.maximum(np.abs(y), 1e-300)))

        rows.append(
            {
                "speed": db["speed"],
                "newton_iterations": {
                    "single": sg["newton_iterations"],
                    "double": db["newton_iterations"],
                },
                "residual": {"single": sg["residual"], "double": db["residual"]},
                "single_vs_double": {
                    "K_rel": rel("K", sg),
                    "c_damping_rel": rel("c_damping", sg),
                    "k_rel": rel("k", sg),
                    "F_prop_rel": rel("F_prop", sg),
                    "heave_m": abs(sg["x_trim"][2] - db["x_trim"][2]),
                    "pitch_rad": abs(sg["x_trim"][4] - db["x_trim"][4]),
                },
                "double_vs_runtime_K_rel": float(
                    np.max(np.abs(np.asarray(db["K"]) - K_rt) / np.abs(K_rt))
                ),
                "lqr_gains_vs_plants_then_gains_rel": {
                    prec: max(
                        rel("K_lqr_gains", g, {"K_lqr_gains": g["K"]}),
                        rel("c_lqr_gains", g, {"c_lqr_gains": g["c_damping"]}),
                    )
                    for prec, g in (("single", sg), ("double", db))
                },
            }
        )
    return {"speeds": rows, "default_speed": speed}


def footprint(s: Setup, work: Path) -> dict:
    log("footprint (-Os, single precision, baked parameters)")
    out = native.footprint(s.default.gen["single_baked"], work / "size_single")
    out["reference"] = native.reference_footprint(work / "size_ref")
    # the generated dynamics of the model the hand-written C computes
    out["generated_runtime_double_dynamics"] = native.footprint_runtime_dynamics(
        s.paper.gen["double_runtime"], work / "size_rt"
    )
    return out


# ---------------------------------------------------------------------------------- main


#: the measurements that write their own section of BENCHMARKS.md (between their markers) and
#: raw results, each in a process of its own; a full run reruns them (firmware.py's MISRA pass
#: about half an hour of it), --quick keeps them
OWN_SECTIONS = ("roa.py", "fmu.py", "firmware.py", "firmware_tick.py", "output_feedback.py")


def own_section(script: str) -> dict:
    """Run bench/``script`` (it writes its section and its results file): its wall time and
    exit status (a failure is logged and recorded, and the rest of the bench goes on; its
    section then keeps its last run's figures and date)."""
    t0 = time.perf_counter()
    rc = subprocess.run([sys.executable, str(BENCH / script)], cwd=ROOT).returncode
    if rc:
        log(f"bench/{script} FAILED (exit {rc}): its section is its last run's")
    return {"script": f"bench/{script}", "exit": rc, "wall_s": time.perf_counter() - t0}


def montecarlo_in_a_fresh_process(quick: bool) -> dict:
    """bench/montecarlo.py's figures, measured in a process of its own: its worker processes
    fork from the process that runs the study, and a fork of this one (every derivation and
    library of the suite in memory) ran the 2-process study at 1.43x instead of 1.92x."""
    with tempfile.TemporaryDirectory(prefix="maglev_bench_mc_") as tmp:
        out = Path(tmp) / "montecarlo.json"
        subprocess.run([sys.executable, str(BENCH / "montecarlo.py"), "--json", str(out),
                        *(["--quick"] if quick else [])], check=True,
                       stdout=subprocess.DEVNULL)
        return json.loads(out.read_text())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "BENCHMARKS.md")
    ap.add_argument("--json", type=Path, default=BENCH / "results.json")
    ap.add_argument(
        "--quick",
        action="store_true",
        help="few repeats: a smoke run of the suite, not figures to publish",
    )
    ap.add_argument("--work", type=Path, help="keep the build files in this folder")
    ap.add_argument(
        "--resume",
        type=Path,
        help="the partial results of an interrupted run (JSON.partial.json, written after "
        "each stage): its stages are kept, the others measured",
    )
    ap.add_argument(
        "--no-measure",
        action="store_true",
        help="with --resume: write BENCHMARKS.md and the JSON from its stages alone, measuring "
        "nothing (the sections of the stages it lacks are carried over from BENCHMARKS.md)",
    )
    args = ap.parse_args(argv)
    if args.no_measure and not args.resume:
        print("bench: --no-measure needs --resume PARTIAL.json", file=sys.stderr)
        return 2
    reps = Repeats.quick() if args.quick else Repeats()
    t0 = time.perf_counter()
    command = os.environ.get("MAGLEV_BENCH_COMMAND") or shlex.join(
        ["python", "bench/run.py", *(argv if argv is not None else sys.argv[1:])]
    )
    results: dict = {
        "meta": {
            "date_utc": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "command": command,
            "quick": args.quick,
            "git": git_state(),
            "repeats": reps.__dict__,
        },
        "machine": machine(),
    }
    done = json.loads(args.resume.read_text()) if args.resume else {}
    if done:
        results["meta"]["date_utc"] = done["meta"]["date_utc"]
        results["machine"]["loadavg_start"] = done["machine"]["loadavg_start"]
        now = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
        # --no-measure only writes: the resume that measured is the one to name
        results["meta"]["resumed_at"] = done["meta"].get("resumed_at", now) if args.no_measure \
            else now
        results["meta"]["git"] = done["meta"]["git"] if args.no_measure else git_state()
    earlier_s = done.get("meta", {}).get("elapsed_s", 0.0)
    partial = args.json.with_name(args.json.stem + ".partial.json")

    def stage(name: str, fn) -> None:
        if name in done:
            log(f"{name}: kept from {args.resume}")
            results[name] = done[name]
            return
        if args.no_measure:
            log(f"{name}: not measured (--no-measure)")
            return
        results[name] = fn()
        results["meta"]["elapsed_s"] = earlier_s + time.perf_counter() - t0
        partial.write_text(json.dumps(results, indent=1, default=float) + "\n")

    fingerprint_start = toolchain_fingerprint()
    with tempfile.TemporaryDirectory(prefix="maglev_bench_") as tmp:
        work = args.work or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        stage("derivation", lambda: derivation(work, reps))
        # the C figures first, then the build workflow, then the Python contenders
        prepared = ("dynamics", "closed_loop", "footprint", "precision", "dynamics_python",
                    "closed_loop_python")  # the stages that need prepare()
        if args.no_measure or all(k in done for k in prepared):
            results.update({k: done[k] for k in prepared if k in done})
        else:
            s = prepare(work)
            stage("dynamics", lambda: dynamics(s, reps))
            stage("closed_loop", lambda: closed_loop(s, reps))
            stage("footprint", lambda: footprint(s, work))
            stage("precision", lambda: precision(s, reps))
        stage("workflow", lambda: workflow.workflow(
            work, reps.build_cold, reps.build_rebuild, reps.build_profile
        ))
        if "s" in locals():
            stage("dynamics_python", lambda: python_dynamics(s, reps))
            stage("closed_loop_python", lambda: closed_loop_python(s, reps))
        stage("envelope", lambda: envelope_bench.run(3 if args.quick else 5))
        stage("montecarlo", lambda: montecarlo_in_a_fresh_process(args.quick))
        stage("peers", lambda: peers_bench.run_peers(
            7 if args.quick else 21, overrides=PAPER_OVERRIDES
        ))
        # CasADi's own codegen on the closed loop (issue 53): its own section, kept
        stage("casadi_peer", lambda: casadi_peer.run_section(3 if args.quick else 9))
        # the lock-step batch in SIMD lanes against the scalar driver (issue 53): kept too
        stage("simd_batch", lambda: simd_batch.run_section(16 if args.quick else 64,
                                                           2 if args.quick else 3))
        for script in OWN_SECTIONS if not args.quick else ():
            stage("own_" + script.removesuffix(".py"), lambda script=script: own_section(script))
    results["machine"]["loadavg_end"] = os.getloadavg()
    # the Python contenders, measured as stages of their own, in their sections
    for key, section in (("dynamics_python", "dynamics"), ("closed_loop_python", "closed_loop")):
        if key in results and section in results:
            results[section]["python"] = results.pop(key)
    # the toolchain's source (what keys every cache) must not change while the suite runs
    results["meta"]["toolchain_changed_during_run"] = toolchain_fingerprint() != fingerprint_start
    results["meta"]["wall_s"] = earlier_s + time.perf_counter() - t0
    results["targets"] = writeup.targets(results)
    args.json.write_text(json.dumps(results, indent=1, default=float) + "\n")
    # the sections other scripts recorded (below writeup.KEPT_MARKER) are carried over
    old = args.out.read_text() if args.out.exists() else None
    args.out.write_text(writeup.markdown(results, old))
    log(f"wrote {args.out} and {args.json} in {results['meta']['wall_s']:.0f} s")
    for t in results["targets"]:
        log(f"target {t['name']}: {t['measured']} ({'met' if t['met'] else 'MISSED'})")
    # a script whose section failed keeps its last run's figures: written, then said (exit 1)
    failed = [v["script"] for k, v in results.items()
              if k.startswith("own_") and isinstance(v, dict) and v.get("exit")]
    if failed:
        log(f"FAILED: {', '.join(failed)} (their sections are their last runs'); exit 1")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
