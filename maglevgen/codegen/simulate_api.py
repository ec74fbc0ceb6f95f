"""The C API of the simulation loop (maglev_simulate.h) and the batch drivers (maglev_batch.c,
maglev_lanes.c) as data: each function's return type and arguments, in order.

One list serves every side of the interface: maglev_simulate.h.j2 renders the prototypes from
it, the manifest lists it (``simulate_functions``), and the ctypes runtime
(maglevgen.runtime.library) makes its signatures from it; tests/test_simulate_api.py parses the
header and maglev_batch.c, independently of this module, and compares.

Imports nothing: the ctypes runtime reads it on the simulation path.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["SIMULATE_API", "function", "manifest_entries"]


@dataclass(frozen=True)
class Argument:
    """One argument: its name and C type as the declaration writes them; ``runtime``: only
    with run-time parameters (the vector p), on a line of its own in the prototype."""

    name: str
    ctype: str
    runtime: bool = False


@dataclass(frozen=True)
class CFunction:
    """One function of the API: name, return type, arguments, the file that declares it."""

    name: str
    returns: str
    arguments: tuple[Argument, ...]
    declared_in: str = "maglev_simulate.h"

    def arguments_for(self, parameters: str) -> tuple[Argument, ...]:
        """The arguments with ``parameters`` "runtime" (p among them) or "baked" (no p)."""
        return tuple(a for a in self.arguments if parameters == "runtime" or not a.runtime)


def _args(spec: str) -> tuple[Argument, ...]:
    """``"const maglev_real* x0, maglev_real dt, ..."`` as Arguments; ``[...]`` marks the
    run-time-parameter ones."""
    out = []
    for item in spec.split(","):
        item = item.strip()
        runtime = item.startswith("[")
        ctype, _, name = item.strip("[]").rpartition(" ")
        out.append(Argument(name, ctype, runtime))
    return tuple(out)


_RUN_TAIL = ("[const maglev_real* p], maglev_real gap_min, maglev_real* x_traj, "
             "maglev_real* u_traj, maglev_real* gap_traj, long long* saturated, int* status")

SIMULATE_API: tuple[CFunction, ...] = (
    CFunction("maglev_simulate", "long long", _args(
        "const maglev_real* x0, maglev_real dt, long long n_steps, maglev_real F_prop, "
        "const maglev_real* K_pos, const maglev_real* K_rate, const maglev_real* a_ref, "
        "const maglev_control_loop* loop, " + _RUN_TAIL)),
    CFunction("maglev_launch", "long long", _args(
        "const maglev_real* x0, maglev_real dt, long long n_steps, maglev_real v_end, "
        "maglev_real F_extra, long long hold_steps, const maglev_spline_schedule* schedule, "
        "const maglev_control_loop* loop, " + _RUN_TAIL)),
    CFunction("maglev_lyapunov_batch", "int", _args(
        "long long n, const maglev_real* X, maglev_real F_prop, const maglev_real* K_pos, "
        "const maglev_real* K_rate, const maglev_real* a_ref, const maglev_real* x_trim, "
        "const maglev_real* P, [const maglev_real* p], maglev_real* V, maglev_real* V_dot, "
        "maglev_real* gaps")),
    # the batch driver (templates/maglev_batch.c, compiled against the run-time-parameter
    # maglev_simulate.h): n_runs maglev_simulate runs through the function pointer simulate
    CFunction("maglev_batch_simulate", "int", _args(
        "maglev_simulate_fn simulate, long long n_runs, int threads, int nx, int nu, int ng, "
        "long long n_p, const maglev_real* x0, maglev_real dt, long long n_steps, "
        "const maglev_real* F_prop, const maglev_real* K_pos, const maglev_real* K_rate, "
        "const maglev_real* a_ref, const maglev_control_loop* loops, const maglev_real* p, "
        "maglev_real gap_min, maglev_real* x_traj, maglev_real* u_traj, "
        "maglev_real* gap_traj, long long* last, long long* saturated, int* status"),
        declared_in="maglev_batch.c"),
    # the lane driver (templates/maglev_lanes.c, issue 53): the same runs, W at a time in SIMD
    # lanes; the lane count it runs (0: the widest this CPU has)
    CFunction("maglev_lanes_width", "int", _args("int width"), declared_in="maglev_lanes.c"),
    CFunction("maglev_lanes_simulate", "int", _args(
        "long long n_runs, int width, int threads, int nx, int nu, int ng, "
        "long long n_p, const maglev_real* x0, maglev_real dt, long long n_steps, "
        "const maglev_real* F_prop, const maglev_real* K_pos, const maglev_real* K_rate, "
        "const maglev_real* a_ref, const maglev_control_loop* loops, const maglev_real* p, "
        "maglev_real gap_min, maglev_real* x_traj, maglev_real* u_traj, "
        "maglev_real* gap_traj, long long* last, long long* saturated, int* status"),
        declared_in="maglev_lanes.c"),
)


def function(name: str) -> CFunction:
    """The API function ``name``."""
    return next(f for f in SIMULATE_API if f.name == name)


def manifest_entries(parameters: str) -> list[dict]:
    """The manifest's ``simulate_functions``: the functions maglev_simulate.h declares, with
    the arguments of ``parameters`` ("baked" or "runtime")."""
    return [{"name": f.name, "returns": f.returns, "declared_in": f.declared_in,
             "arguments": [{"name": a.name, "type": a.ctype} for a in f.arguments_for(parameters)]}
            for f in SIMULATE_API if f.declared_in == "maglev_simulate.h"]
