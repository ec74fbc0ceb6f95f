"""The compiled simulation library of a carriage, cached on disk.

The derivation and the C generated from it with run-time parameters depend on the carriage's
*structure* (which arrays exist, which force components each has) and on this toolchain's
source, never on parameter values. Both caches are keyed accordingly:

- ``derivation/<key>/``: the generated C, keyed by the derivation's source files, the
  library versions, the structure and the precision, with a checksum file that detects a
  corrupted entry (which is then regenerated);
- the shared library, keyed by the content of those sources and the compiler flags
  (runtime/compile.py), so editing a parameter recompiles nothing.
"""

from __future__ import annotations

import ctypes
import json
import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from maglevgen.codegen.lanes import lane_kernels
from maglevgen.codegen.simulate_api import function as api_function
from maglevgen.derive.structure import Structure, numbered
from maglevgen.errors import MaglevError
from maglevgen.infrastructure.cache import (
    cache_root,
    derivation_fingerprint,
    sign,
    signature_ok,
    write_atomic,
)
from maglevgen.infrastructure.hashing import ContentHash, file_sha256, sha256_hex
from maglevgen.infrastructure.output import write_output
from maglevgen.runtime.compile import (
    DEFAULT_FLAGS,
    HOST_TUNED_FLAGS,
    CompileError,
    cached_shared,
    compile_shared,
    trusted,
)
from maglevgen.runtime.ffi import GeneratedLibrary
from maglevgen.runtime.runs import BatchBuffers, BatchRun, ControlLoop, Run

__all__ = ["SimulationLibrary", "build_libraries",
           "cached_simulation_library", "derivation_key", "loaded_library", "runtime_sources",
           "simulation_library"]

CHECKSUMS = "checksums.json"
#: the batch driver (templates/): many maglev_simulate runs per call, OpenMP across them
BATCH_SOURCE = "maglev_batch.c"
#: the lane driver (templates/): the same runs W at a time in SIMD lanes (issue 53)
LANES_SOURCE = "maglev_lanes.c"
#: the lane kernels' file (maglevgen.codegen.lanes), in a folder of its own keyed by its text
LANES_KERNELS = "maglev_lanes_kernels.c"
#: MAGLEV_SIM_ARGUMENT (maglev_simulate.h): the run refused an argument and wrote nothing
SIM_ARGUMENT = 4
#: gcc flags of the libraries a build compiles only for its comparisons (`build_libraries`:
#: the other force law, circuit model and actuator model): -O1, not -O2. The generated
#: functions are long straight-line code (CasADi's SX) where -O2's extra passes cost compile
#: time: gcc -O1 takes 19 s of CPU on the default carriage's library (1.9 MB of C) against
#: 47 s at -O2, and every output of every function is bitwise the same (no fast-math: IEEE
#: semantics at both levels; 420 calls and a whole closed-loop run compared, BENCHMARKS.md,
#: issue 37). The run time is within about 10 % either way (0.89x-1.07x measured), which a
#: comparison's few runs do not notice but a Monte-Carlo study would: a library compiled for
#: its own sake (`simulation_library`) keeps -O2. Either is reused where the other is asked
#: for and missing (`_cached`): the numbers are the same.
COMPARISON_FLAGS: tuple[str, ...] = tuple("-O1" if f == "-O2" else f for f in DEFAULT_FLAGS)

Progress = Callable[[str], None]


def _quiet(_: str) -> None:
    pass


def derivation_key(structure: Structure, precision: str) -> str:
    """The derivation folder's key: the structure with its arrays numbered (`numbered`: the
    generated C names none of them), so structures that differ only in array names share it."""
    return ContentHash(derivation_fingerprint(), repr(numbered(structure)),
                       precision).hexdigest(24)


def _checksums(files: dict[str, bytes]) -> str:
    """The folder's list of checksums, signed (`sign`: the C compiled into the libraries the
    tool loads is trusted only as this user's runs wrote it)."""
    sums = {name: sha256_hex(data) for name, data in sorted(files.items())}
    return json.dumps({"files": sums, "hmac": sign(json.dumps(sums, sort_keys=True).encode())},
                      indent=1, sort_keys=True) + "\n"


def _intact(folder: Path) -> bool:
    """True when the folder's signed checksum list verifies and every C file and header in
    the folder is listed, present and unchanged."""
    try:
        listed = json.loads((folder / CHECKSUMS).read_text())
        sums = listed["files"]
        if not sums or not signature_ok(listed["hmac"],
                                        sign(json.dumps(sums, sort_keys=True).encode())):
            return False
        present = {p.name for p in folder.glob("*.[ch]")}
        return present <= set(sums) and all(
            not (folder / n).is_symlink() and file_sha256(folder / n) == s
            for n, s in sums.items())
    except (OSError, ValueError, AttributeError, KeyError, TypeError):
        return False


def runtime_sources(structure: Structure, precision: str = "double",
                    cache_dir: Path | None = None, progress: Progress = _quiet) -> Path:
    """The folder holding the run-time-parameter C of ``structure``: cached, or derived now."""
    folder = _derivation_folder(structure, precision, cache_dir)
    if _intact(folder):
        return folder
    progress("deriving the model and generating C (cached afterwards)")
    from maglevgen.codegen.generate import (
        render_runtime_sources,  # SymPy and CasADi: only on a miss
    )
    from maglevgen.derive.model import build_model

    files = render_runtime_sources(build_model(numbered(structure)), precision)
    data = {n: t.encode() for n, t in files.items()}
    write_output({**files, CHECKSUMS: _checksums(data)}, folder, ours=True)
    return folder


class SimulationLibrary(GeneratedLibrary):
    """The compiled run-time-parameter library: every generated function and maglev_simulate;
    ``sources``: its derivation folder (maglev_simulate.h, for the batch driver)."""

    def __init__(self, path: Path, precision: str = "double", sources: Path | None = None
                 ) -> None:
        if not trusted(path):  # never dlopen what this user's runs did not compile
            raise MaglevError(f"refusing to load {path}: not a library maglevgen compiled in "
                              "this cache (its signature does not verify)")
        super().__init__(path, precision)
        self.sources = sources
        self._batch = None
        self._lanes: dict[str, tuple] = {}  # lane math -> the lane driver's functions
        real = ctypes.c_float if precision == "single" else ctypes.c_double
        ptr = ctypes.POINTER(real)

        init_fn = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ptr, ctypes.c_ulong, real)
        tick_fn = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ptr, ctypes.c_ulong, real,
                                   ptr)

        class _Sensing(ctypes.Structure):  # maglev_sensing (maglev_simulate.h)
            _fields_ = [("init", init_fn), ("tick", tick_fn), ("state", ctypes.c_void_p),
                        ("ny", ctypes.c_int), ("n_gap", ctypes.c_int), ("track", ctypes.c_int),
                        ("gap_point", ptr), ("gap_normal", ptr), ("gap_nominal", ptr),
                        ("imu_point", ptr), ("step", ptr), ("noise", ptr),
                        ("n_noise", ctypes.c_longlong), ("readings", ptr), ("predicted", ptr),
                        ("commands", ptr), ("n_rows", ctypes.c_longlong),
                        ("tick_error", ctypes.c_int), ("lanes", ctypes.c_void_p)]

        self._Sensing = _Sensing

        class _Loop(ctypes.Structure):  # maglev_control_loop (maglev_simulate.h)
            _fields_ = [("tick_steps", ctypes.c_longlong), ("delay_ticks", ctypes.c_int),
                        ("k_v", real), ("v_ref", real), ("accel", real),
                        ("force_budget", real), ("tau", real), ("law_tau", real),
                        ("k_i", real),
                        ("i_max", real), ("K_lag", ptr), ("K_delay", ptr),
                        ("sense", ctypes.POINTER(_Sensing))]

        self._Loop = _Loop

        class _Schedule(ctypes.Structure):  # maglev_spline_schedule (maglev_simulate.h)
            _fields_ = [("n", ctypes.c_int), ("v0", real), ("dv", real), ("y", ptr),
                        ("d2y", ptr)]

        self._Schedule = _Schedule
        # each C type of the API's arguments (simulate_api: the header's text) as ctypes
        self._ctypes = {"maglev_real": real, "const maglev_real*": ptr, "maglev_real*": ptr,
                        "long long": ctypes.c_longlong, "int": ctypes.c_int,
                        "long long*": ctypes.POINTER(ctypes.c_longlong),
                        "int*": ctypes.POINTER(ctypes.c_int),
                        "const maglev_control_loop*": ctypes.POINTER(_Loop),
                        "const maglev_spline_schedule*": ctypes.POINTER(_Schedule),
                        "maglev_simulate_fn": ctypes.c_void_p}
        self._simulate = self._api(self._lib, "maglev_simulate")
        self._launch = self._api(self._lib, "maglev_launch")
        self._lyapunov = self._api(self._lib, "maglev_lyapunov_batch")

    def _api(self, lib: ctypes.CDLL, name: str):
        """``name`` of ``lib`` with its signature from maglevgen.codegen.simulate_api (the
        run-time-parameter arguments: this library takes p)."""
        f = api_function(name)
        fn = getattr(lib, name)
        fn.restype = self._ctypes[f.returns]
        fn.argtypes = [self._ctypes[a.ctype] for a in f.arguments_for("runtime")]
        return fn

    def _loop_struct(self, loop: ControlLoop, keep: list):
        """The maglev_control_loop of ``loop``; the arrays its pointers address go into
        ``keep`` (alive as long as the caller holds it)."""
        real = self._real
        P = ctypes.POINTER(ctypes.c_float if real == np.float32 else ctypes.c_double)

        def gains(values: tuple[float, ...]):
            if not values:
                return None
            a = np.ascontiguousarray(values, dtype=real)
            keep.append(a)
            return a.ctypes.data_as(P)

        sense = None
        if loop.sense is not None:
            if real != np.float64:
                raise ValueError("the sense tick runs in double precision: a double library")
            sense = ctypes.pointer(loop.sense.struct(self._Sensing))
            keep.append(sense)
        return self._Loop(loop.tick_steps, loop.delay_ticks, loop.k_v, loop.v_ref, loop.accel,
                          loop.force_budget, loop.tau,
                          loop.tau if loop.law_tau is None else loop.law_tau, loop.k_i,
                          loop.i_max, gains(loop.k_lag), gains(loop.k_delay), sense)

    def _loop(self, loop: ControlLoop | None, keep: list):
        """The maglev_control_loop of ``loop`` (a pointer), or NULL for None (``keep``: as
        `_loop_struct`)."""
        if loop is None:
            return None
        return ctypes.byref(self._loop_struct(loop, keep))

    def launch(self, x0: np.ndarray, dt: float, n_steps: int, v_end: float, f_extra: float,
               hold_steps: int, schedule, p: np.ndarray, gap_min: float, n_u: int,
               n_gaps: int, loop: ControlLoop | None = None) -> Run:
        """maglev_launch with ``schedule`` (maglevgen.control.schedule.Schedule): as
        ``simulate``."""
        real = self._real
        P = ctypes.POINTER(ctypes.c_float if real == np.float32 else ctypes.c_double)
        y = np.ascontiguousarray(schedule.values, dtype=real)
        d2y = np.ascontiguousarray(schedule.second_derivatives, dtype=real)
        sched = self._Schedule(len(schedule.speeds), float(schedule.speeds[0]),
                               float(schedule.speeds[1] - schedule.speeds[0]),
                               y.ctypes.data_as(P), d2y.ctypes.data_as(P))
        x0c, pc = (np.ascontiguousarray(a, dtype=real) for a in (x0, p))
        x = np.zeros((n_steps + 1, x0c.size), dtype=real)
        u = np.zeros((n_steps + 1, n_u), dtype=real)
        g = np.zeros((n_steps + 1, n_gaps), dtype=real)
        status, saturated = ctypes.c_int(-1), ctypes.c_longlong(0)
        keep: list = []
        last = self._launch(x0c.ctypes.data_as(P), dt, n_steps, v_end, f_extra, hold_steps,
                            ctypes.byref(sched), self._loop(loop, keep), pc.ctypes.data_as(P),
                            gap_min, x.ctypes.data_as(P), u.ctypes.data_as(P),
                            g.ctypes.data_as(P), ctypes.byref(saturated), ctypes.byref(status))
        _refused("maglev_launch", status.value)
        n = int(last) + 1
        return Run(int(last), status.value, x[:n], u[:n], g[:n], saturated.value)

    def simulate(self, x0: np.ndarray, dt: float, n_steps: int, f_prop: float,
                 k_pos: np.ndarray, k_rate: np.ndarray, a_ref: np.ndarray, p: np.ndarray,
                 gap_min: float, n_u: int, n_gaps: int, loop: ControlLoop | None = None) -> Run:
        """maglev_simulate: (last sample, status, x rows, u rows, gap rows up to that sample,
        steps saturated); ``loop``: how the controller runs (None: at every RK4 stage)."""
        real = self._real
        ins = [np.ascontiguousarray(a, dtype=real) for a in (x0, k_pos, k_rate, a_ref, p)]
        x = np.zeros((n_steps + 1, ins[0].size), dtype=real)
        u = np.zeros((n_steps + 1, n_u), dtype=real)
        g = np.zeros((n_steps + 1, n_gaps), dtype=real)
        status, saturated = ctypes.c_int(-1), ctypes.c_longlong(0)
        ptr = ctypes.POINTER(ctypes.c_float if real == np.float32 else ctypes.c_double)

        def c(a: np.ndarray):
            return a.ctypes.data_as(ptr)

        keep: list = []
        last = self._simulate(c(ins[0]), dt, n_steps, f_prop, c(ins[1]), c(ins[2]), c(ins[3]),
                              self._loop(loop, keep), c(ins[4]), gap_min, c(x), c(u), c(g),
                              ctypes.byref(saturated), ctypes.byref(status))
        _refused("maglev_simulate", status.value)
        n = int(last) + 1
        return Run(int(last), status.value, x[:n], u[:n], g[:n], saturated.value)


    def lyapunov_batch(self, X: np.ndarray, f_prop: float, k_pos: np.ndarray,
                       k_rate: np.ndarray, a_ref: np.ndarray, x_trim: np.ndarray,
                       P: np.ndarray, p: np.ndarray, n_gaps: int
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """maglev_lyapunov_batch: (V, dV/dt, gaps) at the rows of ``X`` (n x 12) of the closed
        loop with the gains ``k_pos``, ``k_rate`` (column-major 25 each), V = (x - x_trim)'
        P (x - x_trim); NaN where a row or its closed loop is not finite. One C call; the
        rows are independent, so callers may split X across threads (ctypes releases the
        GIL during the call)."""
        real = self._real
        Xc = np.ascontiguousarray(X, dtype=real)
        ins = [np.ascontiguousarray(a, dtype=real).ravel()
               for a in (k_pos, k_rate, a_ref, x_trim, P, p)]
        n = Xc.shape[0]
        V, Vd = np.zeros(n, dtype=real), np.zeros(n, dtype=real)
        g = np.zeros((n, n_gaps), dtype=real)
        ptr = ctypes.POINTER(ctypes.c_float if real == np.float32 else ctypes.c_double)

        def c(a: np.ndarray):
            return a.ctypes.data_as(ptr)

        status = self._lyapunov(n, c(Xc), f_prop, c(ins[0]), c(ins[1]), c(ins[2]), c(ins[3]),
                                c(ins[4]), c(ins[5]), c(V), c(Vd), c(g))
        _refused("maglev_lyapunov_batch", status)
        if status != 0:
            raise RuntimeError(f"maglev_lyapunov_batch: a generated function failed "
                               f"(status {status})")
        return V, Vd, g

    def _batch_function(self, cc: str | None = None):
        """maglev_batch_simulate: templates/maglev_batch.c compiled with -fopenmp against
        this library's maglev_simulate.h (cached as every library is), loaded once."""
        if self._batch is None:
            if self.sources is None:
                raise RuntimeError("this library was loaded without its sources: no batch")
            from importlib import resources

            src = Path(str(resources.files("maglevgen.templates") / BATCH_SOURCE))
            # the -I folder is the derivation's, keyed by its content: the key covers the header
            flags = (*DEFAULT_FLAGS, f"-I{self.sources}")
            try:
                lib = compile_shared([src], (*flags, "-fopenmp"), cc=cc,
                                     cache_dir=self.path.parent)
            except CompileError:  # a compiler without OpenMP: the same runs on one thread
                lib = compile_shared([src], flags, cc=cc, cache_dir=self.path.parent)
            if not trusted(lib):
                raise MaglevError(f"refusing to load {lib}: its signature does not verify")
            fn = self._api(ctypes.CDLL(str(lib)), "maglev_batch_simulate")
            self._batch = fn
        return self._batch

    def _lanes_functions(self, cc: str | None = None, math: str = "libm"):
        """(maglev_lanes_simulate, maglev_lanes_width, the loaded driver):
        templates/maglev_lanes.c with the lane kernels of this library's functions
        (maglevgen.codegen.lanes; ``math``: their exp, sin and cos),
        compiled with -fopenmp against its derivation folder and linked against the library
        itself (cached as every library is), loaded once."""
        if math not in self._lanes:
            if self.sources is None or self._real != np.float64:
                raise RuntimeError("the lanes run a double library loaded with its sources")
            from importlib import resources

            kernels = lane_kernels((self.sources / "maglev_functions.c").read_text(),
                                   math=math)
            folder = self.path.parent / "lanes" / sha256_hex(kernels.encode())[:24]
            if not _write_text(folder / LANES_KERNELS, kernels):
                raise MaglevError(f"cannot write the lane kernels into {folder}")
            src = Path(str(resources.files("maglevgen.templates") / LANES_SOURCE))
            flags = (*HOST_TUNED_FLAGS, f"-I{self.sources}",
                     *(["-Wl,--no-as-needed,-lmvec"] if math == "libmvec" else []))
            sources = [src, folder / LANES_KERNELS, self.path]
            try:
                lib = compile_shared(sources, (*flags, "-fopenmp"), cc=cc,
                                     cache_dir=self.path.parent)
            except CompileError:  # a compiler without OpenMP: the same runs on one thread
                lib = compile_shared(sources, flags, cc=cc, cache_dir=self.path.parent)
            if not trusted(lib):
                raise MaglevError(f"refusing to load {lib}: its signature does not verify")
            loaded = ctypes.CDLL(str(lib))
            self._lanes[math] = (self._api(loaded, "maglev_lanes_simulate"),
                                 self._api(loaded, "maglev_lanes_width"), loaded)
        return self._lanes[math]

    def lane_width(self, width: int = 0) -> int:
        """The lanes `simulate_batch` runs with ``lanes=width`` on this CPU (0: the widest
        it has, 8 with AVX-512F, 4 with AVX2, else 2); 0 when this CPU cannot run ``width``."""
        return int(self._lanes_functions()[1](width))

    def _auto_lanes(self, n: int, threads: int) -> int | None:
        """``lanes=0``'s lane count for n runs on ``threads``: the widest this CPU runs that
        the runs of a thread fill, or None (the scalar driver) when a thread has fewer than 2
        runs, for a single precision library, or where the lane driver does not compile."""
        if self._real != np.float64 or self.sources is None:
            return None
        try:
            widest = self.lane_width()
        except CompileError:
            return None
        per_thread = n // max(1, threads if threads > 0 else (os.cpu_count() or 1))
        if per_thread < 2:  # one run a thread: the lanes would run their other lanes idle
            return None
        return max(w for w in (2, 4, 8) if w <= widest and w <= per_thread)

    def simulate_batch(self, runs: list[BatchRun], dt: float, n_steps: int, gap_min: float,
                       n_u: int, n_gaps: int, threads: int = 0,
                       lanes: int | None = None, lane_math: str = "libm",
                       buffers: BatchBuffers | None = None) -> list[Run]:
        """Every run of ``runs`` as `simulate` makes it (one maglev_simulate call each, the
        same numbers), in one call of the batch driver on ``threads`` threads (0: every core,
        OpenMP's default). ``lanes``: None, one maglev_simulate per run (maglev_batch.c);
        else the lane driver (maglev_lanes.c) with that many lanes (0: `_auto_lanes`: the
        widest the CPU runs and the runs fill, the scalar driver where there are none): the
        runs with a tick W at a time in SIMD lanes (on the sensors too: each run's sense tick
        its own C per lane), the others as maglev_simulate, each run the same numbers
        (tests/test_simd_batch.py). ``lane_math``
        "libmvec": the lanes' exp, sin and cos by glibc's libmvec (bench/simd_batch.py's
        experiment: no longer the scalar run's bits). ``buffers``: the runs' rows written
        into these (`BatchBuffers`: the runs returned valid until the next call with them),
        else into new arrays."""
        real = self._real
        n = len(runs)
        if n == 0:
            return []
        if lanes == 0:
            lanes = self._auto_lanes(n, threads)
        elif lanes is not None and self.lane_width(lanes) == 0:
            raise ValueError(f"{lanes} lanes: this CPU runs {self.lane_width()} at most "
                             "(2, 4 or 8)")

        def stack(values) -> np.ndarray:
            return np.ascontiguousarray(np.array([np.ravel(v) for v in values], dtype=real))

        x0, kp, kr, ar, p = (stack(getattr(r, f) for r in runs)
                             for f in ("x0", "k_pos", "k_rate", "a_ref", "p"))
        fp = np.ascontiguousarray([r.f_prop for r in runs], dtype=real)
        plain = ControlLoop()  # the plain loop, as NULL: maglev_simulate's loop_plain
        keep: list = []
        loops = (self._Loop * n)(*[self._loop_struct(lp, keep)
                                  for lp in (r.loop or plain for r in runs)])
        n_x, rows = x0.shape[1], n_steps + 1
        if buffers is not None:
            x, u, g = buffers.take(n, rows, (n_x, n_u, n_gaps), real)
        else:
            x, u, g = (np.zeros((n, rows, w), dtype=real) for w in (n_x, n_u, n_gaps))
        last = np.zeros(n, dtype=np.int64)
        saturated = np.zeros(n, dtype=np.int64)
        status = np.full(n, -1, dtype=np.intc)
        P = ctypes.POINTER(ctypes.c_float if real == np.float32 else ctypes.c_double)
        LP = ctypes.POINTER(ctypes.c_longlong)

        def c(a: np.ndarray):
            return a.ctypes.data_as(P)

        common = (n_x, n_u, n_gaps, p.shape[1], c(x0), dt, n_steps, c(fp), c(kp), c(kr), c(ar),
                  loops, c(p), gap_min, c(x), c(u), c(g), last.ctypes.data_as(LP),
                  saturated.ctypes.data_as(LP),
                  status.ctypes.data_as(ctypes.POINTER(ctypes.c_int)))
        if lanes is None:
            rc = self._batch_function()(ctypes.cast(self._simulate, ctypes.c_void_p), n,
                                        threads, *common)
        else:
            rc = self._lanes_functions(math=lane_math)[0](n, lanes, threads, *common)
        if rc != 0:
            raise RuntimeError("the batch driver refused its arguments")
        out = []
        for i in range(n):
            _refused("maglev_simulate", int(status[i]))
            k = int(last[i]) + 1
            out.append(Run(int(last[i]), int(status[i]), x[i, :k], u[i, :k], g[i, :k],
                           int(saturated[i])))
        return out


def _write_text(path: Path, text: str) -> bool:
    """``text`` at ``path`` (`write_atomic`), unless the file holds it already."""
    try:
        if path.read_text() == text:
            return True
    except (OSError, UnicodeDecodeError):
        pass
    return write_atomic(path, text.encode())


def _refused(name: str, status: int) -> None:
    """An internal error when the C refused the arguments this module passed it (the
    callers validate every input first, so this is a bug, not bad input)."""
    if status == SIM_ARGUMENT:
        raise RuntimeError(f"{name} refused its arguments (MAGLEV_SIM_ARGUMENT): a step, "
                           "count, gain or pointer out of its range (maglev_simulate.h)")


def simulation_library(structure: Structure, precision: str = "double",
                       cache_dir: Path | None = None, cc: str | None = None,
                       progress: Progress = _quiet) -> SimulationLibrary:
    """Generate (or reuse) and compile (or reuse) the simulation library of ``structure``."""
    folder = runtime_sources(structure, precision, cache_dir, progress)
    lib = _cached(folder, cc, cache_dir) or compile_shared(
        _sources(folder), cc=cc, cache_dir=cache_root(cache_dir) / "lib", progress=progress)
    return SimulationLibrary(lib, precision, folder)


_LOADED: dict[tuple[Structure, Path | None, str | None], SimulationLibrary] = {}


def loaded_library(structure: Structure, cache_dir: Path | None = None,
                   cc: str | None = None) -> SimulationLibrary:
    """`simulation_library` of ``structure`` (double precision), loaded once in this process:
    what a worker process reuses for every chunk of a study it runs (`Plant.worker_library`)."""
    key = (structure, cache_dir, cc)
    if key not in _LOADED:
        _LOADED[key] = simulation_library(structure, cache_dir=cache_dir, cc=cc)
    return _LOADED[key]


def _cached(folder: Path, cc: str | None, cache_dir: Path | None) -> Path | None:
    """The compiled library of the C in ``folder`` when cached at either -O level
    (DEFAULT_FLAGS first, then COMPARISON_FLAGS: the same numbers), else None."""
    for flags in (DEFAULT_FLAGS, COMPARISON_FLAGS):
        lib = cached_shared(_sources(folder), flags, cc=cc, cache_dir=cache_root(cache_dir) / "lib")
        if lib is not None:
            return lib
    return None


def build_libraries(structures: tuple[Structure, ...], precision: str = "double",
                    cache_dir: Path | None = None, cc: str | None = None) -> list[Path]:
    """Derive and compile (or reuse) the library of each structure, gcc compiling one while
    the next is derived (gcc runs in its own process; the derivation holds the GIL); the
    libraries' paths. What `maglevgen build` runs in a second process for the other models
    its envelope and report compare (maglevgen.build), so that they are cached by the time
    they are asked for. Compiled at COMPARISON_FLAGS (-O1) where not cached at either level."""
    def compiled(folder: Path) -> Path:
        return _cached(folder, cc, cache_dir) or compile_shared(
            _sources(folder), COMPARISON_FLAGS, cc=cc, cache_dir=cache_root(cache_dir) / "lib")

    with ThreadPoolExecutor(max_workers=len(structures) or 1) as pool:
        compiling = [pool.submit(compiled, runtime_sources(s, precision, cache_dir))
                     for s in structures]
        return [f.result() for f in compiling]


def cached_simulation_library(structure: Structure, precision: str = "double",
                              cache_dir: Path | None = None, cc: str | None = None
                              ) -> SimulationLibrary | None:
    """The simulation library when its C and its compiled form are both cached and intact;
    None when something would have to be generated or compiled."""
    folder = _derivation_folder(structure, precision, cache_dir)
    if not _intact(folder):
        return None
    lib = _cached(folder, cc, cache_dir)
    return None if lib is None else SimulationLibrary(lib, precision, folder)


def _derivation_folder(structure: Structure, precision: str, cache_dir: Path | None) -> Path:
    return cache_root(cache_dir) / "derivation" / derivation_key(structure, precision)


def _sources(folder: Path) -> list[Path]:
    return sorted(folder.glob("*.c"))  # every C file the generator wrote (checksummed)
