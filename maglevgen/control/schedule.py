"""Gain schedules over speed: the trim drag, the reference and a controller's gains at nodes
across the envelope, interpolated by a natural cubic spline in the speed.

The C side (`maglev_schedule_eval` in maglev_simulate.c) evaluates the spline from the node
values and their second derivatives; the launch run (`maglev_launch`) schedules the gains in
the C loop with it. The spline is C2 in the speed, so a run that evaluates it at every RK4
stage keeps RK4's fourth order (a C0 or C1 interpolant would not).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from maglevgen.codegen.checks import MAX_DELAY_TICKS
from maglevgen.control.operating import (
    AXIS_STATES,
    N_AXES,
    OperatingPoint,
    checked_accelerating_trim,
)

if TYPE_CHECKING:
    from scipy.interpolate import CubicSpline

    from maglevgen.control.plant import LoopDesign
    from maglevgen.runtime.library import SimulationLibrary

__all__ = ["A_REF", "GAIN_TABLE_BOUND", "GAIN_TABLE_FIELDS", "GAIN_TABLE_NY", "K_DELAY", "K_LAG",
           "K_POS", "GainTable", "Reference", "Schedule", "accelerating_references",
           "clenshaw_lines", "field_errors", "field_scales", "field_slices", "gain_table_row",
           "gain_table_sources", "schedule_c_source", "schedule_lines", "speed_map",
           "tick_table_fields",
           "value_terms", "varying_values"]

# one node's values, in the order maglev_simulate.h's MAGLEV_SCHEDULE_* offsets give: the
# drag, the reference, K_pos and K_rate, then the tick law's K_lag and K_delay (room for
# MAX_DELAY_TICKS ticks; zero for a controller without them)
F_DRAG, A_REF, K_POS, K_RATE = 0, 1, 1 + N_AXES, 1 + N_AXES + N_AXES**2
K_LAG = K_RATE + N_AXES**2
K_DELAY = K_LAG + N_AXES**2
NY = K_DELAY + N_AXES**2 * MAX_DELAY_TICKS
DEFAULT_NODES = 64


@dataclass(frozen=True)
class Reference:
    """A node's reference and propulsion feedforward where they are not the constant-speed
    trim's: a_ref (trim y, z, phi, theta, psi) and the F_DRAG value [N], to which the launch
    adds F_extra = m a (maglev_launch: F_prop = F_DRAG + F_extra)."""

    a_ref: np.ndarray
    f_drag: float


def accelerating_references(lib: SimulationLibrary, p: np.ndarray,
                            points: list[OperatingPoint], acceleration: float, mass: float,
                            min_gap: float) -> list[Reference]:
    """The accelerating trim at each point's speed (`checked_accelerating_trim`: eqs 1-2 with
    the d'Alembert load -m a at the CG): its pose as a_ref and its propulsion less m a as
    F_DRAG, so that the launch's F_DRAG + m a is the accelerating trim's F_prop (its drag,
    at its own gaps, plus m a)."""
    refs = []
    for op in points:
        x, f_prop, _ = checked_accelerating_trim(lib, p, op.speed, acceleration, min_gap)
        refs.append(Reference(x[list(AXIS_STATES)], f_prop - mass * acceleration))
    return refs


def node_values(op: OperatingPoint, controller: str,
                reference: Reference | None = None,
                design: LoopDesign | None = None) -> np.ndarray:
    """(F_drag, a_ref, K_pos, K_rate, K_lag, K_delay, each matrix column-major) of a
    controller at a node; the trim's F_drag and a_ref, or ``reference``'s; the controller's
    continuous gains (K_lag, K_delay zero), or ``design``'s (its design at the tick on the
    loop as built, `plant.LoopDesign`: the gains the firmware's tick runs)."""
    K_pos, K_rate = op.gains(controller) if design is None else (design.K_pos, design.K_rate)
    f_drag, a_ref = (op.f_prop, op.a_trim) if reference is None \
        else (reference.f_drag, reference.a_ref)
    tick = np.zeros(NY - K_LAG)
    if design is not None and design.K_lag is not None and design.K_lag.size:
        tick[:N_AXES**2] = design.K_lag.ravel(order="F")
    if design is not None and design.K_delay is not None and design.K_delay.size:
        k_delay = design.K_delay.ravel(order="F")
        tick[N_AXES**2:N_AXES**2 + k_delay.size] = k_delay
    return np.concatenate([[f_drag], a_ref, K_pos.ravel(order="F"), K_rate.ravel(order="F"),
                           tick])


@dataclass(frozen=True)
class Schedule:
    """Node values of one controller on uniformly spaced speeds, and their spline.

    ``acceleration``: the along-track acceleration whose trim gives the reference and the
    drag (0: the constant-speed trim). The gains are those of the constant-speed
    linearisation in either case (the operating points')."""

    controller: str
    speeds: np.ndarray  # (n,) uniformly spaced
    values: np.ndarray  # (n, NY)
    acceleration: float = 0.0

    @classmethod
    def from_points(cls, points: list[OperatingPoint], controller: str,
                    references: list[Reference] | None = None,
                    acceleration: float = 0.0,
                    designs: list[LoopDesign] | None = None) -> Schedule:
        """The schedule of ``controller`` at the points' speeds; ``references`` (one per point,
        `accelerating_references` at ``acceleration``): the reference and drag in place of
        the constant-speed trim's; ``designs`` (one per point): the controller's gains on the
        loop as built (`node_values`) in place of its continuous gains."""
        speeds = np.array([op.speed for op in points])
        if len(speeds) < 2 or not np.allclose(np.diff(speeds), speeds[1] - speeds[0]):
            raise ValueError("a schedule needs two or more uniformly spaced nodes")
        if references is not None and len(references) != len(points):
            raise ValueError("a schedule needs one reference per node")
        if references is None and acceleration != 0:
            raise ValueError("an accelerating schedule needs the accelerating trim's "
                             "references")
        if designs is not None and len(designs) != len(points):
            raise ValueError("a schedule needs one design per node")
        refs = references if references is not None else [None] * len(points)
        des = designs if designs is not None else [None] * len(points)
        return cls(controller, speeds,
                   np.array([node_values(op, controller, r, d)
                             for op, r, d in zip(points, refs, des, strict=True)]),
                   float(acceleration))

    @property
    def spline(self) -> CubicSpline:
        from scipy.interpolate import CubicSpline  # local: the simulation path's import stays light

        return CubicSpline(self.speeds, self.values, axis=0, bc_type="natural")

    @property
    def second_derivatives(self) -> np.ndarray:
        """(n, NY) d^2/dv^2 of the spline at the nodes: what the C evaluation needs."""
        return self.spline(self.speeds, 2)

    def at(self, v: float | np.ndarray) -> np.ndarray:
        """The spline at v, clamped to the node range (as maglev_schedule_eval): (NY,) values
        at a speed, (n, NY) at an array of n speeds (one spline for all of them)."""
        v = np.asarray(v, dtype=float)
        return self.spline(np.clip(v, self.speeds[0], self.speeds[-1]))

    @staticmethod
    def unpack(row: np.ndarray) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        """(F_drag, a_ref, K_pos, K_rate) from one row of values."""
        return (float(row[F_DRAG]), row[A_REF:K_POS],
                row[K_POS:K_RATE].reshape(N_AXES, N_AXES, order="F"),
                row[K_RATE:K_LAG].reshape(N_AXES, N_AXES, order="F"))


def schedule_c_source(schedule: Schedule, precision: str = "double") -> str:
    """C for the firmware: the schedule's node values and second derivatives as static const
    tables and a `maglev_spline_schedule` (maglev_simulate.h) named ``maglev_embedded_schedule``
    for `maglev_schedule_eval` (templates/maglev_schedule.c.j2). Deterministic text (each value
    a C literal of ``precision``, maglevgen.codegen.emit.c_literal)."""
    from maglevgen.codegen.emit import render  # local: jinja2 only when C is written

    return render("maglev_schedule.c.j2", controller=schedule.controller,
                  speeds=[float(v) for v in schedule.speeds], values=schedule.values,
                  second_derivatives=schedule.second_derivatives,
                  acceleration=schedule.acceleration, precision=precision,
                  v0=float(schedule.speeds[0]),
                  dv=float(schedule.speeds[1] - schedule.speeds[0]))


# ------------------------------------------------------------------------------------------
# The firmware's gain table: maglev_schedule(v) from static const Chebyshev coefficients

#: one row of the firmware table: (name, number of values), in this order
GAIN_TABLE_FIELDS = (("F_prop", 1), ("a_ref", N_AXES), ("K", 2 * N_AXES),
                     ("c_damping", N_AXES), ("K_pos", N_AXES**2), ("K_rate", N_AXES**2))
GAIN_TABLE_NY = sum(n for _, n in GAIN_TABLE_FIELDS)


def tick_table_fields(delay: int) -> tuple[tuple[str, int], ...]:
    """The firmware table's row for the design at the tick (`plant.LoopDesign`) with ``delay``
    ticks of delay: GAIN_TABLE_FIELDS (K_pos and K_rate the tick design's), then K_lag (the
    gain on the predicted lagged generalized forces, 5 x 5) and K_delay (on the generalized
    forces in flight, newest first, 5 x 5 delay; absent without delay), column-major."""
    extra = (("K_lag", N_AXES**2),) + ((("K_delay", N_AXES**2 * delay),) if delay > 0 else ())
    return GAIN_TABLE_FIELDS + extra
#: the stated bound: each field's worst error over the envelope, relative to the field's
#: largest magnitude over the envelope (a gain matrix is judged as a whole: its entries that
#: are zero by symmetry are not divided by themselves)
GAIN_TABLE_BOUND = 1e-3
GAIN_TABLE_NODES = tuple(range(8, 41, 2))  # node counts tried, the smallest within the bound
DENSE_GRID = 201  # about 25 speeds between adjacent nodes: the error curve is smooth there
ZERO_VALUE = 1e-9  # relative to the field's scale: a value this small everywhere is zero
#: the share of GAIN_TABLE_BOUND each value's dropped Chebyshev terms may cost (`truncated`):
#: measured on the default carriage, the controller's table keeps 166 Clenshaw steps of 490
#: (9 of its 70 values constant), the sense tick's estimator 403 of 3262 (339 of 466)
DROP_SHARE = 0.1


def field_slices(fields: tuple[tuple[str, int], ...] = GAIN_TABLE_FIELDS
                  ) -> list[tuple[int, int]]:
    """(first index, size) of each field of a row."""
    out, i = [], 0
    for _, n in fields:
        out.append((i, n))
        i += n
    return out


def gain_table_row(op: OperatingPoint, controller: str, design: LoopDesign | None = None,
                   delay: int = 0) -> np.ndarray:
    """(F_prop, a_ref, K column-major, c_damping, K_pos, K_rate column-major) at a speed: the
    controller's continuous gains (GAIN_TABLE_FIELDS); with ``design`` (its design at the
    tick on the loop as built, ``delay`` ticks of delay) the row of `tick_table_fields`:
    K_pos and K_rate the design's, then K_lag and K_delay (zero where the design has none)."""
    if design is None:
        K_pos, K_rate = op.gains(controller)
    else:
        K_pos, K_rate = design.K_pos, design.K_rate
    row: list[Any] = [[op.f_prop], op.a_trim, op.K.ravel(order="F"), op.c_damping,
           K_pos.ravel(order="F"), K_rate.ravel(order="F")]
    if design is not None:
        K_lag = design.K_lag if design.K_lag is not None and design.K_lag.size \
            else np.zeros((N_AXES, N_AXES))
        K_delay = design.K_delay if design.K_delay is not None \
            else np.zeros((N_AXES, N_AXES * delay))
        if K_delay.shape != (N_AXES, N_AXES * delay):
            raise ValueError(f"K_delay {K_delay.shape}: not 5 x 5 x {delay} ticks of delay")
        row += [K_lag.ravel(order="F"), K_delay.ravel(order="F")]
    return np.concatenate(row)


def field_scales(exact: np.ndarray,
                 fields: tuple[tuple[str, int], ...] = GAIN_TABLE_FIELDS) -> np.ndarray:
    """Each value's scale (GAIN_TABLE_BOUND's measure): its field's largest |exact| over the
    rows (1 for a field zero everywhere)."""
    return np.concatenate([np.full(n, np.max(np.abs(exact[:, i:i + n])) or 1.0)
                           for i, n in field_slices(fields)])


def field_errors(approx: np.ndarray, exact: np.ndarray,
                 fields: tuple[tuple[str, int], ...] = GAIN_TABLE_FIELDS,
                 scale: np.ndarray | None = None) -> dict[str, float]:
    """Each field's worst |approx - exact| over the rows, relative to each value's ``scale``
    (default `field_scales`: the field's largest |exact|; GAIN_TABLE_BOUND's measure)."""
    scale = field_scales(exact, fields) if scale is None else scale
    rel = np.abs(approx - exact) / scale
    return {name: float(np.max(rel[:, i:i + n])) for (name, _), (i, n)
            in zip(fields, field_slices(fields), strict=True)}


@dataclass(frozen=True)
class GainTable:
    """Chebyshev series of the gain table's row in t, an affine map of 1/v onto [-1, 1] over
    [v_min, v_max]: the trim's lift and drag go as rational functions of v (eqs 5-7), which a
    polynomial in 1/v approximates with fewer terms than one in v (measured: F_prop to 1e-7
    with 12 terms in 1/v, 8e-5 in v)."""

    v_min: float
    v_max: float
    coeffs: np.ndarray  # (n, GAIN_TABLE_NY); zero columns for the values not stored
    errors: dict[str, float]  # field_errors on the dense grid
    stored: tuple[int, ...]  # the values stored; the others are zero over the envelope
    # a row's fields (name, size): the controller's gains, or another table's (the Kalman
    # filter's, maglevgen.control.estimation)
    fields: tuple[tuple[str, int], ...] = GAIN_TABLE_FIELDS

    @staticmethod
    def t_of(v: np.ndarray | float, v_min: float, v_max: float) -> np.ndarray:
        a, b = 1.0 / v_max, 1.0 / v_min
        return (2.0 / np.asarray(v, dtype=float) - (a + b)) / (b - a)

    @staticmethod
    def nodes(n: int, v_min: float, v_max: float) -> np.ndarray:
        """The n Chebyshev points (first kind) as speeds, increasing."""
        t = np.cos(np.pi * (np.arange(n) + 0.5) / n)
        a, b = 1.0 / v_max, 1.0 / v_min
        return np.sort(1.0 / ((a + b) / 2 + (b - a) / 2 * t))

    def __call__(self, v: np.ndarray | float) -> np.ndarray:
        from numpy.polynomial import chebyshev

        v = np.clip(v, self.v_min, self.v_max)
        return chebyshev.chebval(self.t_of(v, self.v_min, self.v_max), self.coeffs).T

    @classmethod
    def fit(cls, row_at, v_min: float, v_max: float,
            fields: tuple[tuple[str, int], ...] = GAIN_TABLE_FIELDS,
            drop_share: float = DROP_SHARE, value_scale=None) -> GainTable:
        """The smallest table of GAIN_TABLE_NODES within GAIN_TABLE_BOUND on a dense grid
        (the largest when none is); ``row_at(speeds)`` gives the exact rows of ``fields``.
        Each value's trailing terms are dropped (zeroed) while what they add stays within
        ``drop_share`` x GAIN_TABLE_BOUND of its field's scale on the dense grid (`truncated`;
        0: none dropped): the C's Clenshaw runs over a value's own terms, and a value
        constant over speed to that keeps one (the sense tick's code holds it as a literal);
        the node count is the undropped fit's, and the terms are dropped only where the
        table stays within the bound (or, past it, within the undropped table's error).
        ``value_scale(exact)``: each value's scale from the dense grid's exact rows (default
        `field_scales`), where a field's largest value is not the measure of its values."""
        from numpy.polynomial import chebyshev

        dense = np.linspace(v_min, v_max, DENSE_GRID)
        exact = row_at(dense)
        # values that vanish over the envelope (by the carriage's symmetry: the lateral and
        # vertical axes' cross gains, the trim's y, phi, psi) are not stored: a zero output
        # within ZERO_VALUE of each field's scale, counted in the errors like any other
        scale = (field_scales if value_scale is None else value_scale)(exact, fields)
        stored = tuple(int(j) for j in np.flatnonzero(np.max(np.abs(exact), axis=0)
                                                      > ZERO_VALUE * scale))
        table = None
        for n in GAIN_TABLE_NODES:
            nodes = cls.nodes(n, v_min, v_max)
            coeffs = chebyshev.chebfit(cls.t_of(nodes, v_min, v_max), row_at(nodes), n - 1)
            mask = np.zeros(coeffs.shape[1], dtype=bool)
            mask[list(stored)] = True
            coeffs[:, ~mask] = 0.0
            table = cls(v_min, v_max, coeffs, {}, stored, fields)
            errors = field_errors(table(dense), exact, fields, scale)
            table = cls(v_min, v_max, coeffs, errors, stored, fields)
            if max(errors.values()) <= GAIN_TABLE_BOUND:
                break
        assert table is not None
        if drop_share > 0:
            # the nodes as without dropping (the rows evaluated, the node count: the same);
            # the dropped terms kept only if the table stays within the bound
            coeffs = truncated(table.coeffs, cls.t_of(dense, v_min, v_max),
                               drop_share * GAIN_TABLE_BOUND * scale)
            errors = field_errors(cls(v_min, v_max, coeffs, {}, stored, fields)(dense), exact,
                                  fields, scale)
            if max(errors.values()) <= max(GAIN_TABLE_BOUND, max(table.errors.values())):
                table = cls(v_min, v_max, coeffs, errors, stored, fields)
        return table

    def manifest(self, precision_bytes: int = 4) -> dict:
        return {"interpolation": "Chebyshev series in 1/v (Clenshaw)",
                "v_min": self.v_min, "v_max": self.v_max, "nodes": len(self.coeffs),
                "bound": GAIN_TABLE_BOUND, "dense_grid": DENSE_GRID,
                "worst_relative_error": max(self.errors.values()),
                "relative_error_by_field": self.errors,
                "values_stored": len(self.stored),
                "coefficients_stored": int(np.sum(value_terms(self.coeffs)[list(self.stored)])),
                # each value's own terms; the stored indices (unsigned char, or unsigned short
                # past 256 outputs) and each value's first coefficient (unsigned short)
                "table_bytes_single": int(np.sum(value_terms(self.coeffs)[list(self.stored)])
                                          * precision_bytes + len(self.stored)
                                          * (1 if self.coeffs.shape[1] <= 256 else 2)
                                          + 2 * (len(self.stored) + 1))}


def truncated(coeffs: np.ndarray, t: np.ndarray, tol: np.ndarray) -> np.ndarray:
    """``coeffs`` (terms x values, Chebyshev) with each value's trailing terms zeroed: the
    fewest leading terms whose series is within tol (per value) of the whole series at t.
    Zero trailing terms leave Clenshaw's result bit for bit (its b's stay +0 through them)."""
    from numpy.polynomial import chebyshev

    out = coeffs.copy()
    whole = chebyshev.chebval(t, coeffs)  # (values, points)
    done = np.zeros(coeffs.shape[1], dtype=bool)
    for k in range(1, len(coeffs)):
        ok = ~done & (np.max(np.abs(chebyshev.chebval(t, coeffs[:k]) - whole), axis=1) <= tol)
        out[k:, ok] = 0.0
        done |= ok
    return out


def varying_values(table: GainTable) -> list[int]:
    """The table's values of more than one term (indices into the row), in stored order:
    what ``function``_varying evaluates; the others are constant over speed."""
    terms = value_terms(table.coeffs)
    return [j for j in table.stored if terms[j] > 1]


def value_terms(coeffs: np.ndarray) -> np.ndarray:
    """Each value's terms: 1 + the index of its last nonzero coefficient (1 when none)."""
    nz = coeffs != 0
    last = len(coeffs) - 1 - np.argmax(nz[::-1], axis=0)
    return np.where(nz.any(axis=0), last + 1, 1)


#: the smallest normal float: a coefficient at least this large is the same nonzero normal
#: number as a double and as a float (maglev_real either), so Clenshaw's first step,
#: ((t2 * 0) - 0) + c, is c exactly (flush-to-zero or not)
_NORMAL = float(np.finfo(np.float32).tiny)


def clenshaw_lines(coeffs, target: str) -> list[str]:
    """One value's Clenshaw written out as C statements (one a line) with its coefficients
    ``coeffs`` (c[0], ..., c[n-1]) as literals R(c) and its result into ``target``: the
    operations of the loop over its terms (b1 = b2 = 0; for k = n-1 down to 1:
    b0 = ((t2 * b1) - b2) + c[k], b2 = b1, b1 = b0; then ((t * b1) - b2) + c[0]), in the same
    order, so its result bit for bit. The loop's first step from b1 = b2 = 0 gives c[n-1]
    exactly when that is a nonzero normal float (both precisions): taken (b1 = R(c[n-1]));
    a one-term value is then the literal alone. Uses the C variables t, t2 (t + t), b0, b1,
    b2 (maglev_real) and the macro R (the cast to maglev_real)."""
    from maglevgen.codegen.emit import c_literal  # local: jinja2 only when C is written

    cs = [c_literal(float(c)) for c in coeffs]
    top = len(cs) - 1
    exact = abs(float(coeffs[top])) >= _NORMAL
    if top == 0 and exact:
        return [f"{target} = R({cs[0]});"]
    lines = [f"b1 = R({cs[top]});" if top > 0 and exact else "b1 = R(0);", "b2 = R(0);"]
    for c in reversed(cs[1:top] if top > 0 and exact else cs[1:]):
        lines += [f"b0 = ((t2 * b1) - b2) + R({c});", "b2 = b1;", "b1 = b0;"]
    lines.append(f"{target} = ((t * b1) - b2) + R({cs[0]});")
    return lines


def _clenshaw_vars(lines: list[str]) -> list[str]:
    """The work variables `clenshaw_lines`'s ``lines`` use (besides t), to declare."""
    return [name for name in ("t2", "b0", "b1", "b2")
            if any(re.search(rf"\b{name}\b", ln) for ln in lines)]


def speed_map(table: GainTable) -> tuple[float, float]:
    """(T_SCALE, T_OFFSET) of the table's evaluation: t = T_SCALE / v - T_OFFSET maps 1/v
    over [1/v_max, 1/v_min] onto [-1, 1] (every written evaluation of a table takes these,
    so the same constants)."""
    a, b = 1.0 / table.v_max, 1.0 / table.v_min
    return 2.0 / (b - a), (a + b) / (b - a)


def schedule_lines(table: GainTable, prefix: str = "MAGLEV_SCHEDULE") -> list[list[str]]:
    """Each stored value's Clenshaw written out (`clenshaw_lines`), its output named by the
    header's field macro: out[<prefix>_OUT_<FIELD> + k] (the written-out ``function`` of
    `gain_table_sources`, and the sense tick's lanes: the same lines)."""
    terms = [int(k) for k in value_terms(table.coeffs)[list(table.stored)]]
    fields = [(name, first, size) for (name, size), (first, _) in zip(
        table.fields, field_slices(table.fields), strict=True)]

    def named(j: int) -> str:
        name, first = next((nm, f) for nm, f, size in fields if f <= j < f + size)
        return f"out[{prefix}_OUT_{name.upper()}{f' + {j - first}' if j > first else ''}]"

    return [clenshaw_lines(table.coeffs[:k, j], named(j))
            for j, k in zip(table.stored, terms, strict=True)]


def gain_table_sources(table: GainTable, stem: str = "maglev_gain_table",
                       function: str = "maglev_schedule", prefix: str = "MAGLEV_SCHEDULE",
                       title: str = "gain schedule", summary: str = "",
                       varying: bool = False, one_output: str | None = None,
                       written_out: bool = True) -> dict[str, str]:
    """``stem``.h and .c (default maglev_gain_table): ``function(v, out)`` (default
    maglev_schedule) from static const tables, its macros ``prefix``_* (the range, the row's
    size and each field's offset); ``title`` and ``summary`` (comment lines, " * " each: what
    out holds) describe the table in the header (default: the controller's gain table). One
    template for every such table (the controller's, the sense tick's estimator).
    ``one_output``: a one-value field also evaluated alone, ``function``_<field>(v, out)
    (the tick's propulsion feedforward at the speed reference).

    maglev_real is the generated functions' (the header includes maglev_functions.h, the one
    definition of the type): the table has the precision of the C beside it; no libm call, no
    writable data. Returns 0, MAGLEV_ERR_NONFINITE (out zeroed) or MAGLEV_ERR_SPEED (v outside
    [v_min, v_max]: out holds the nearer end's values). Each value's series is stored to its
    last nonzero term (`value_terms`: `GainTable.fit`'s drop_share zeroes the rest).
    ``varying``: also ``function``_varying(v, from, count, out), the values of more than one
    term (`varying_values`) from..from+count-1 into out[] at those indices (the sense tick's
    refresh: one slice a tick; the one-term values are constants in its code), a loop over
    static tables of the coefficients. ``written_out``: ``function`` evaluates each stored
    value's Clenshaw written out with its coefficients as literals (`clenshaw_lines`: the
    loop's operations in its order, so its values bit for bit; no loop, no table read: the
    tick's cost), else the loop over the tables (smaller code where the function is off the
    tick's path); the one-value function is written out either way.
    """
    from maglevgen.codegen.checks import error_defines  # local: jinja2 only when C is written
    from maglevgen.codegen.emit import render

    n, ny = table.coeffs.shape
    terms = [int(k) for k in value_terms(table.coeffs)[list(table.stored)]]
    fields = [(name, first, size) for (name, size), (first, _) in zip(
        table.fields, field_slices(table.fields), strict=True)]
    t_scale, t_offset = speed_map(table)
    ctx = {"v_min": table.v_min, "v_max": table.v_max, "ny": ny, "nterms": n,
           "fields": fields, "errors": table.errors, "dense_grid": DENSE_GRID,
           "bound": GAIN_TABLE_BOUND, "stored": table.stored, "coeffs": table.coeffs,
           "t_scale": t_scale, "t_offset": t_offset,
           "error_defines": error_defines(("MAGLEV_OK", "MAGLEV_ERR_NONFINITE",
                                           "MAGLEV_ERR_SPEED", "MAGLEV_ERR_ARGUMENT"),
                                          docs=False),
           "stem": stem, "function": function, "prefix": prefix, "title": title,
           "summary": summary, "terms": terms, "offsets": [0, *np.cumsum(terms).tolist()],
           "varying": [i for i, n in enumerate(terms) if n > 1] if varying else [],
           "one_output": None, "written_out": written_out}
    ctx["clenshaw"] = schedule_lines(table, prefix)
    ctx["clenshaw_vars"] = _clenshaw_vars([ln for lines in ctx["clenshaw"] for ln in lines])
    if one_output is not None:
        first, size = next((f, s) for name, f, s in fields if name == one_output)
        if size != 1:
            raise ValueError(f"one_output {one_output!r}: a field of one value expected")
        slot = list(table.stored).index(first) if first in table.stored else None
        lines = [] if slot is None else clenshaw_lines(table.coeffs[:terms[slot], first],
                                                       "*out")
        ctx["one_output"] = {"name": one_output, "slot": slot, "lines": lines,
                             "vars": _clenshaw_vars(lines)}
    return {f"{stem}{ext}": render(f"maglev_gain_table{ext}.j2", **ctx) for ext in (".h", ".c")}
