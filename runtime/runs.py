"""What a run of the compiled loop takes and gives, apart from the library that runs it: the
C loop's settings (maglev_control_loop), one run's result (maglev_simulate / maglev_launch) and
one run of a batch. Analyses build and read these; only the library
(`maglevgen.runtime.library`) loads C."""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from maglevgen.runtime.sense import Sensing

__all__ = ["BatchBuffers", "BatchRun", "ControlLoop", "Run"]


@dataclass(frozen=True)
class ControlLoop:
    """maglev_control_loop (maglev_simulate.h): how the C loop runs the controller.

    ``tick_steps`` RK4 steps per control tick (0: the command at every RK4 stage), the command
    applied ``delay_ticks`` ticks after its tick and held between; the speed loop
    F_prop = F_ff + ``k_v`` (v_ref(t) - |(u, v, w)|) - ``k_i`` xi, v_ref(t) = ``v_ref`` +
    ``accel`` t, xi the speed error's integral, clamped at each tick to |k_i xi| <= ``i_max``
    [N] (anti-windup; inf: no clamp); each array's control force limited to
    ``force_budget`` [N] (<= 0 or inf: no limit) and lagged by ``tau`` [s] in the plant (0: no
    lag), the tick law's prediction of the lagged forces assuming ``law_tau`` (the lag the
    firmware was designed for; None: ``tau``, the plant's); the tick law's gains ``k_lag``
    (25) and ``k_delay`` (25 delay_ticks), column-major (maglev_simulate's; empty: zero, the
    generalized forces u_gen as computed); ``sense``
    (tick_steps > 0): the loop on the sensors' readings through the firmware's sense tick
    (`maglevgen.runtime.sense.Sensing`) in place of the exact state's feedback.
    """

    tick_steps: int = 0
    delay_ticks: int = 0
    k_v: float = 0.0  # [N s/m]
    v_ref: float = 0.0  # [m/s]
    accel: float = 0.0  # [m/s^2]
    force_budget: float = 0.0  # [N]
    tau: float = 0.0  # [s]
    k_i: float = 0.0  # [N/m]
    i_max: float = float("inf")  # [N]
    k_lag: tuple[float, ...] = ()
    k_delay: tuple[float, ...] = ()
    sense: Sensing | None = None  # the sensors and the firmware's sense tick (runtime.sense)
    # [s] the lag the tick law's prediction assumes (the firmware's design); None: tau
    law_tau: float | None = None


class Run(NamedTuple):
    """What maglev_simulate / maglev_launch return: the last sample's index, the
    MAGLEV_SIM_* status, the rows of x, u and the gaps up to it, the RK4 steps taken with an
    array's control force at its budget."""

    last: int
    status: int
    x: np.ndarray
    u: np.ndarray
    gaps: np.ndarray
    saturated_steps: int


class BatchRun(NamedTuple):
    """One run of `SimulationLibrary.simulate_batch`: maglev_simulate's inputs but the step,
    the step count and gap_min, which all runs of a batch share."""

    x0: np.ndarray
    f_prop: float
    k_pos: np.ndarray  # 25, column-major as maglev_simulate takes it
    k_rate: np.ndarray
    a_ref: np.ndarray
    p: np.ndarray
    loop: ControlLoop | None


class BatchBuffers:
    """The rows `SimulationLibrary.simulate_batch` writes (x, u and the gaps of every run),
    kept from one call to the next: for a caller that reduces each call's runs before the
    next call (a Monte-Carlo worker), so a call writes into memory already mapped instead of
    fresh pages, which the kernel maps and zeroes one by one on the first write (here, under
    load, up to as long as the runs themselves: bench/simd_batch.py). The runs a call returns
    are views into these arrays, good until the next call with the same buffers. Not shared
    between threads."""

    def __init__(self) -> None:
        self._key: tuple | None = None
        self._arrays: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._noise: list[np.ndarray] = []

    def noise(self, j: int, shape: tuple[int, int]) -> np.ndarray:
        """Run j's noise array of a call on the sensors (``shape``: ticks x readings, float64,
        `maglevgen.analyses.sim_loop.reading_noise` fills it whole), kept as the rows are
        (a run's noise is its largest input: 1.2 MB for 10^4 ticks of 15 readings); made
        again when the shape changes."""
        while len(self._noise) <= j:
            self._noise.append(np.empty((0, 0)))
        if self._noise[j].shape != shape:
            self._noise[j] = np.empty(shape)
        return self._noise[j]

    def take(self, n: int, rows: int, widths: tuple[int, int, int], dtype
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Arrays (n, rows, width) of x, u and the gaps, grown when a call needs more runs,
        made again when the rows or widths change. Made NaN-filled, so that in the first
        call a row the C left unwritten would show as NaN; a later call gets the memory as
        the previous one left it, the C writing every row up to each run's last, the part
        a `Run` returns (tests/test_batch.py compares such runs with fresh ones)."""
        key = (rows, widths, np.dtype(dtype))
        arrays = self._arrays
        if arrays is None or self._key != key or arrays[0].shape[0] < n:
            x, u, g = (np.full((n, rows, w), np.nan, dtype=dtype) for w in widths)
            self._key, self._arrays = key, (x, u, g)
            return x, u, g
        return arrays[0][:n], arrays[1][:n], arrays[2][:n]
