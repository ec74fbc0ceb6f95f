"""The firmware's sense tick on the host: its folder compiled in double precision, and what a run
on the sensors gives maglev_simulate (maglev_sensing, maglev_simulate.h).

A run on the sensors flies the firmware's own C (maglev_sense_init / maglev_sense_tick, the
estimator and the law over the tables the folder holds) around the run-time-parameter plant:
maglev_simulate reads the plant through the generated measurement functions, adds the caller's
noise and calls the sense tick through the pointers of a `Sensing`. The folder's files
(`maglevgen.analyses.firmware_sources.render_firmware`, precision "double") are written under
the cache, keyed by their content, with the glue (templates/maglev_host_sense.c: the functions
with the state untyped and the state's size) and compiled as every library is
(runtime/compile.py: keyed by the sources' bytes and the flags, signed, loaded only when the
signature verifies).
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np

from maglevgen.derive import conventions as cv
from maglevgen.errors import MaglevError
from maglevgen.infrastructure.cache import cache_root
from maglevgen.infrastructure.hashing import ContentHash
from maglevgen.infrastructure.output import write_output
from maglevgen.runtime.compile import HOST_TUNED_FLAGS, compile_shared, trusted

__all__ = ["SenseLibrary", "Sensing", "sense_library"]

#: the glue compiled into the folder (not generated: the same for every carriage)
HOST_SENSE_SOURCE = "maglev_host_sense.c"
#: the firmware folder's C the sense tick needs (the QEMU and example files left out)
SENSE_SOURCES = ("maglev_tick.c", "maglev_gain_table.c", "maglev_sense_table.c",
                 "maglev_functions.c")
#: the sense tick over SIMD lanes (analyses.firmware_sources.host_sense_sources), compiled
#: beside the folder's C when given: not a file of the firmware folder
LANES_SOURCE = "maglev_sense_lanes.c"
#: the warnings the firmware's own build treats as errors, on the host's compile too
HOST_FLAGS = (*HOST_TUNED_FLAGS, "-Wall", "-Wextra", "-Werror")


class SenseLibrary:
    """A firmware folder's sense tick compiled for the host: the addresses of its init and
    tick (maglev_sense_init_fn, maglev_sense_tick_fn) and the size of its state."""

    def __init__(self, path: Path) -> None:
        if not trusted(path):
            raise MaglevError(f"refusing to load {path}: not a library maglevgen compiled in "
                              "this cache (its signature does not verify)")
        self.path = Path(path)
        self._lib = ctypes.CDLL(str(self.path))
        size = self._lib.maglev_host_sense_state_size
        size.restype, size.argtypes = ctypes.c_size_t, []
        self.state_size = int(size())
        init = ctypes.cast(self._lib.maglev_host_sense_init, ctypes.c_void_p).value
        tick = ctypes.cast(self._lib.maglev_host_sense_tick, ctypes.c_void_p).value
        if init is None or tick is None:
            raise MaglevError(f"{path}: no sense tick in the library")
        self.init: int = init
        self.tick: int = tick
        #: the address of its maglev_sense_lanes (maglev_simulate.h: the sense tick over the
        #: Monte Carlo's SIMD lanes), None when compiled without them
        self.lanes: int | None = None
        if hasattr(self._lib, "maglev_host_sense_lanes"):
            self.lanes = ctypes.cast(self._lib.maglev_host_sense_lanes, ctypes.c_void_p).value

    def __reduce__(self):
        """Another process loads the same library (its signature checked again there)."""
        return (SenseLibrary, (self.path,))

    def new_state(self) -> np.ndarray:
        """Storage for one run's maglev_sense_state (8-byte aligned; the run initialises it)."""
        return np.zeros(-(-self.state_size // 8), dtype=np.float64)


def sense_library(files: dict[str, str], cache_dir: Path | None = None,
                  cc: str | None = None, lanes: str | None = None) -> SenseLibrary:
    """The sense tick of a firmware folder rendered in double precision (``files``: name ->
    text, with maglev_sense_table.c), compiled for the host or reused from the cache;
    ``lanes``: that sense tick over SIMD lanes (`LANES_SOURCE`) compiled with it."""
    missing = [n for n in SENSE_SOURCES if n not in files]
    if missing or "double" not in files.get("maglev.h", ""):
        raise ValueError("the host's sense tick needs a firmware folder in double precision "
                         f"with [sensors] (missing: {', '.join(missing) or 'double precision'})")
    glue = (resources.files("maglevgen.templates") / HOST_SENSE_SOURCE).read_text()
    needed = {n: t for n, t in files.items() if n.endswith((".c", ".h"))
              and not n.startswith("qemu_") and n != "main.c"}
    needed[HOST_SENSE_SOURCE] = glue
    if lanes is not None:
        needed[LANES_SOURCE] = lanes
    key = ContentHash(*(f"{n}\0{t}" for n, t in sorted(needed.items()))).hexdigest(24)
    folder = cache_root(cache_dir) / "firmware" / key
    if not all((folder / n).is_file() and (folder / n).read_text() == t
               for n, t in needed.items()):
        write_output(needed, folder, ours=True)
    extra = (LANES_SOURCE,) if lanes is not None else ()
    lib = compile_shared([folder / n for n in (*SENSE_SOURCES, HOST_SENSE_SOURCE, *extra)],
                         HOST_FLAGS, cc=cc, cache_dir=cache_root(cache_dir) / "lib")
    return SenseLibrary(lib)


@dataclass(eq=False)
class Sensing:
    """A run's sensors and sense tick (maglev_sensing, maglev_simulate.h): each gap sensor's
    body point, face normal and nominal gap (rows), the IMU's point (None: no IMU), whether
    the track position is read, each reading's resolution (0: not rounded) and the noise
    added at each tick (rows of the readings; None: none), in the readings' order (gaps, the
    gyro's p q r, the accelerometer's x y z, the track). ``rows``: ticks whose readings and
    prediction the run records (`readings`, `predicted`; with ``n_inputs``, the plant's
    input count, the sense tick's commands too: `commands`); after a run, ``tick_error`` holds
    the sense function's code that ended it (0: none did). One Sensing serves one run at a
    time: it holds the sense tick's state."""

    library: SenseLibrary
    gap_point: np.ndarray
    gap_normal: np.ndarray
    gap_nominal: np.ndarray
    imu_point: np.ndarray | None
    track: bool
    step: np.ndarray
    noise: np.ndarray | None = None
    rows: int = 0
    n_inputs: int = 0  # the plant's inputs (MAGLEV_NU): the commands' width; 0: not kept
    readings: np.ndarray = field(init=False)
    predicted: np.ndarray = field(init=False)
    commands: np.ndarray = field(init=False)
    _state: np.ndarray = field(init=False, repr=False)
    _struct: object = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        f64 = np.float64
        self.gap_point = np.ascontiguousarray(np.reshape(self.gap_point, (-1, 3)), dtype=f64)
        self.gap_normal = np.ascontiguousarray(np.reshape(self.gap_normal, (-1, 3)), dtype=f64)
        self.gap_nominal = np.ascontiguousarray(np.ravel(self.gap_nominal), dtype=f64)
        if self.imu_point is not None:
            self.imu_point = np.ascontiguousarray(np.ravel(self.imu_point), dtype=f64)
        self.step = np.ascontiguousarray(np.ravel(self.step), dtype=f64)
        if self.noise is not None:
            self.noise = np.ascontiguousarray(np.reshape(self.noise, (-1, self.ny)), dtype=f64)
        if self.step.size != self.ny:
            raise ValueError(f"{self.step.size} resolutions for {self.ny} readings")
        self.readings = np.zeros((self.rows, self.ny))
        self.predicted = np.zeros((self.rows, cv.N_STATES))
        self.commands = np.zeros((self.rows if self.n_inputs else 0, self.n_inputs))
        self._state = self.library.new_state()

    @property
    def n_gap(self) -> int:
        return int(self.gap_nominal.size)

    @property
    def ny(self) -> int:
        """The readings: the gaps, six of the IMU, one of the track."""
        return self.n_gap + (6 if self.imu_point is not None else 0) + int(self.track)

    @property
    def tick_error(self) -> int:
        return 0 if self._struct is None else int(self._struct.tick_error)  # type: ignore[attr-defined]

    def struct(self, struct_type: type[ctypes.Structure]) -> ctypes.Structure:
        """The maglev_sensing of this run (``struct_type``: the library's ctypes type of it),
        kept by this object (its pointers address this object's arrays)."""
        P = ctypes.POINTER(ctypes.c_double)

        def c(a: np.ndarray | None):
            return None if a is None else a.ctypes.data_as(P)

        init_fn, tick_fn = (f for _, f in struct_type._fields_[:2])  # type: ignore[misc]
        s = struct_type(
            ctypes.cast(self.library.init, init_fn), ctypes.cast(self.library.tick, tick_fn),
            self._state.ctypes.data_as(ctypes.c_void_p), self.ny, self.n_gap, int(self.track),
            c(self.gap_point), c(self.gap_normal), c(self.gap_nominal), c(self.imu_point),
            c(self.step), c(self.noise), 0 if self.noise is None else self.noise.shape[0],
            c(self.readings) if self.rows else None, c(self.predicted) if self.rows else None,
            c(self.commands) if self.commands.size else None, self.rows, 0,
            self.library.lanes)
        self._struct = s
        return s
