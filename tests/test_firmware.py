"""Firmware-grade generated C (issue 16): return codes, header work sizes.

References: the lift-off speed of the SymPy/SciPy derivation (maglevgen.derive.trim, no
generated C) for where a trim exists; numpy's isfinite for what is finite; the compiled
library's own ``NAME_work()`` (what the C reports at run time) for the header's macros.
"""

from __future__ import annotations

import ctypes
import json
import re
from pathlib import Path

import numpy as np
import pytest

from maglevgen.analyses.envelope import speed_range
from maglevgen.carriage import DerivedCarriage
from maglevgen.codegen.checks import ERROR_CODES
from maglevgen.codegen.generate import GenerateOptions, write_output
from maglevgen.control.carriage_plant import Plant
from maglevgen.runtime.compile import compile_shared
from maglevgen.runtime.ffi import GeneratedFunctionError, GeneratedLibrary

REPO = Path(__file__).resolve().parents[1]
ERR = {name: value for name, (value, _) in ERROR_CODES.items()}
TRIM_KIND = ("maglev_trim", "maglev_axis_plants", "maglev_lqr_gains")


@pytest.fixture(scope="module", params=["double", "single"])
def gen(request, carriage: DerivedCarriage, tmp_path_factory, rendered) -> tuple[str, Path, Path]:
    """(precision, generated folder, compiled library) with run-time parameters."""
    out = tmp_path_factory.mktemp(f"fw_{request.param}")
    write_output(rendered(carriage, GenerateOptions(request.param, "runtime")), out)
    lib = compile_shared([out / "maglev_functions.c"])
    return request.param, out, lib


def _call(gen, name: str, *args):
    precision, _, lib = gen
    return GeneratedLibrary(lib, precision).function(name)(*args)


def _code(gen, name: str, *args) -> tuple[int, list[np.ndarray]]:
    """(return code, outputs) of a call; outputs as the C left them (zeros on an error)."""
    precision, _, lib = gen
    fn = GeneratedLibrary(lib, precision).function(name)
    outs = [np.full(r * c, 7.0, dtype=fn.real) for r, c in fn.shapes_out]  # not zero before
    P = ctypes.POINTER(fn._creal)
    ins = [np.ascontiguousarray(np.ravel(a, order="F"), dtype=fn.real) for a in args]
    arg = (P * fn._sz_arg)(*[a.ctypes.data_as(P) for a in ins])
    res = (P * fn._sz_res)(*[o.ctypes.data_as(P) for o in outs])
    iw = (ctypes.c_longlong * fn._sz_iw)()
    w = (fn._creal * fn._sz_w)()
    return fn._fn(arg, res, iw, w, 0), outs


@pytest.mark.parametrize("name", TRIM_KIND)
def test_schedule_functions_refuse_bad_speeds(gen, carriage: DerivedCarriage, name: str) -> None:
    """v = 0, v < 0, NaN, +-inf and a NaN parameter give their MAGLEV_ERR_* code and zeroed
    outputs; below the derivation's lift-off speed (SymPy/SciPy trim, no C) there is no trim,
    above it (and far above the envelope's v_max) there is."""
    v_lift = carriage.lift_off_speed()
    p_nan = carriage.p.copy()
    p_nan[0] = np.nan
    cases = [(0.0, carriage.p, "MAGLEV_ERR_SPEED"), (-5.0, carriage.p, "MAGLEV_ERR_SPEED"),
             (np.nan, carriage.p, "MAGLEV_ERR_NONFINITE"),
             (np.inf, carriage.p, "MAGLEV_ERR_NONFINITE"),
             (-np.inf, carriage.p, "MAGLEV_ERR_NONFINITE"),
             (20.0, p_nan, "MAGLEV_ERR_NONFINITE")]
    for v, p, want in cases:
        rc, outs = _code(gen, name, [v], p)
        assert rc == ERR[want], (v, rc)
        assert all(np.all(o == 0) for o in outs), (v, outs)
    for v in (0.5, 2.0, 0.9 * v_lift):  # no equilibrium with every gap above track.min_gap
        rc, outs = _code(gen, name, [v], carriage.p)
        assert rc in (ERR["MAGLEV_ERR_NOT_CONVERGED"], ERR["MAGLEV_ERR_CONTACT"]), (v, rc)
        assert all(np.all(o == 0) for o in outs)
    for v in (1.1 * v_lift, 20.0, 3 * carriage.params.envelope.v_max):
        rc, outs = _code(gen, name, [v], carriage.p)
        assert rc == 0, (v, rc)
        assert all(np.all(np.isfinite(o)) for o in outs)


@pytest.fixture(scope="module", params=["double", "single"])
def baked_gen(request, carriage: DerivedCarriage, tmp_path_factory, rendered
              ) -> tuple[str, Path, Path]:
    """(precision, generated folder, compiled library) with baked parameters (and range)."""
    out = tmp_path_factory.mktemp(f"fw_baked_{request.param}")
    write_output(rendered(carriage, GenerateOptions(request.param, "baked"),
                          speed_range(carriage)), out)
    lib = compile_shared([out / "maglev_functions.c"])
    return request.param, out, lib


@pytest.mark.parametrize("name", TRIM_KIND)
def test_baked_schedule_functions_keep_to_the_envelope(baked_gen, carriage: DerivedCarriage,
                                                       name: str) -> None:
    """Baked parameters bake the envelope's [v_min, v_max]: just below v_min (from the
    derivation's lift-off speed, SymPy/SciPy, times 1 + envelope.lift_off_margin), just above
    the file's v_max, far outside, NaN and +-inf give their code with zeroed outputs; just
    inside both ends and between them the function succeeds with finite outputs (a trim
    exists there: above lift-off). maglev.h states the range it checks."""
    env = carriage.params.envelope
    v_min = (1 + env.lift_off_margin) * carriage.lift_off_speed()
    v_max = env.v_max
    refused = [(v_min * (1 - 1e-4), "MAGLEV_ERR_SPEED"), (v_max * (1 + 1e-4), "MAGLEV_ERR_SPEED"),
               (0.5 * v_min, "MAGLEV_ERR_SPEED"), (3 * v_max, "MAGLEV_ERR_SPEED"),
               (0.0, "MAGLEV_ERR_SPEED"), (np.nan, "MAGLEV_ERR_NONFINITE"),
               (np.inf, "MAGLEV_ERR_NONFINITE"), (-np.inf, "MAGLEV_ERR_NONFINITE")]
    for v, want in refused:
        rc, outs = _code(baked_gen, name, [v])
        assert rc == ERR[want], (v, rc)
        assert all(np.all(o == 0) for o in outs), (v, outs)
    for v in (v_min * (1 + 1e-4), 0.5 * (v_min + v_max), v_max * (1 - 1e-4)):
        rc, outs = _code(baked_gen, name, [v])
        assert rc == 0, (v, rc)
        assert all(np.all(np.isfinite(o)) and np.any(o != 0) for o in outs), (v, outs)
    header = (baked_gen[1] / "maglev.h").read_text()
    lo, hi = (float(re.search(rf"#define MAGLEV_V_{k} (\S+)", header).group(1))
              for k in ("MIN", "MAX"))
    assert abs(lo - v_min) <= 1e-5 * v_min and hi == v_max


def test_accelerating_trim_refuses_bad_input_and_agrees_with_the_derivation(
        gen, carriage: DerivedCarriage) -> None:
    """maglev_trim_accelerating's checked entry point: a NaN or infinite acceleration gives
    MAGLEV_ERR_NONFINITE, v <= 0 MAGLEV_ERR_SPEED, an acceleration that no equilibrium clear of
    the track holds (20 g: its thrust moment tips the carriage onto the track)
    NOT_CONVERGED or CONTACT, each with zeroed outputs; at the launch's acceleration and when
    braking, the pose and propulsion are derive/trim.py's (SymPy/SciPy, no C)."""
    from maglevgen.derive.trim import solve_trim

    p = carriage.p
    for v, a, want in ((20.0, np.nan, "MAGLEV_ERR_NONFINITE"),
                       (20.0, np.inf, "MAGLEV_ERR_NONFINITE"),
                       (np.nan, 5.0, "MAGLEV_ERR_NONFINITE"),
                       (0.0, 5.0, "MAGLEV_ERR_SPEED"), (-3.0, 5.0, "MAGLEV_ERR_SPEED")):
        rc, outs = _code(gen, "maglev_trim_accelerating", [v], [a], p)
        assert rc == ERR[want], (v, a, rc)
        assert all(np.all(o == 0) for o in outs)
    rc, outs = _code(gen, "maglev_trim_accelerating", [20.0], [196.0], p)
    assert rc in (ERR["MAGLEV_ERR_NOT_CONVERGED"], ERR["MAGLEV_ERR_CONTACT"]), rc
    assert all(np.all(o == 0) for o in outs)
    tol = 1e-10 if gen[0] == "double" else 2e-5  # float32: the Newton tolerance's pose
    for v, a in ((20.0, carriage.params.envelope.launch_acceleration), (30.0, -4.0)):
        rc, (x, f_prop) = _code(gen, "maglev_trim_accelerating", [v], [a], p)
        ref = solve_trim(carriage.functions, p, v, carriage.params.track.min_gap,
                         acceleration=a)
        assert rc == 0
        np.testing.assert_allclose(x, ref.x, rtol=0, atol=tol * max(1.0, v))
        assert f_prop[0] == pytest.approx(ref.u[0], rel=tol * 10)


def test_runtime_names_the_code(gen, carriage: DerivedCarriage) -> None:
    """The ctypes runtime raises with the code's name."""
    with pytest.raises(GeneratedFunctionError, match="MAGLEV_ERR_SPEED") as info:
        _call(gen, "maglev_trim", [0.0], carriage.p)
    assert info.value.code_name == "MAGLEV_ERR_SPEED"
    assert info.value.code == ERR["MAGLEV_ERR_SPEED"]


def test_tick_functions_refuse_non_finite_inputs(gen, carriage: DerivedCarriage) -> None:
    """A NaN state (and an infinite gain) into each tick function: MAGLEV_ERR_NONFINITE and
    every output zero (no control force); the same call with finite inputs returns 0 and
    finite outputs."""
    rng = np.random.default_rng(3)
    x = rng.normal(scale=1e-3, size=12)
    x[6] = 20.0
    ticks = {
        "maglev_lqr_control": [x, rng.normal(size=(5, 2)), rng.normal(size=5)],
        "maglev_damping_control": [x, rng.normal(size=5)],
        "maglev_coupled_control": [x, rng.normal(size=(5, 5)), rng.normal(size=(5, 5)),
                                   rng.normal(size=5)],
        "maglev_allocate": [rng.normal(size=5)],
        "maglev_axis_gains": [np.abs(rng.normal(size=5)) + 1, np.abs(rng.normal(size=5)) + 1],
    }
    for name, args in ticks.items():
        rc, outs = _code(gen, name, *args, carriage.p)
        assert rc == 0 and all(np.all(np.isfinite(o)) and np.any(o != 0) for o in outs), name
        for bad in (np.nan, np.inf):
            first = np.array(args[0], dtype=float)
            first.flat[1] = bad  # the state's y, or u_gen / k
            rc, outs = _code(gen, name, first, *args[1:], carriage.p)
            assert rc == ERR["MAGLEV_ERR_NONFINITE"], (name, bad, rc)
            assert all(np.all(o == 0) for o in outs), (name, outs)
        if len(args) > 1:
            gain = np.array(args[1], dtype=float)
            gain.flat[0] = np.inf
            rc, _ = _code(gen, name, args[0], gain, *args[2:], carriage.p)
            assert rc == ERR["MAGLEV_ERR_NONFINITE"], (name, rc)


def test_tick_output_overflow_is_reported(gen, carriage: DerivedCarriage) -> None:
    """Finite inputs whose product overflows (a huge gain times a state offset): the output
    would be infinite, so the tick returns MAGLEV_ERR_NONFINITE_OUTPUT with zeros."""
    precision = gen[0]
    big = 1e300 if precision == "double" else 1e38
    x = np.zeros(12)
    x[1] = 1e10  # y offset
    rc, outs = _code(gen, "maglev_lqr_control", x, np.full((5, 2), big), np.zeros(5),
                     carriage.p)
    assert rc == ERR["MAGLEV_ERR_NONFINITE_OUTPUT"]
    assert np.all(outs[0] == 0)


def test_header_work_sizes_equal_work_functions(gen) -> None:
    """Each NAME_SZ_{ARG,RES,IW,W} in maglev.h equals what the compiled NAME_work() reports."""
    _, out, lib = gen
    header = (out / "maglev.h").read_text()
    macros = {m.group(1): int(m.group(2))
              for m in re.finditer(r"#define (\w+_SZ_(?:ARG|RES|IW|W)) (\d+)", header)}
    cdll = ctypes.CDLL(str(lib))
    names = sorted({k.rsplit("_SZ_", 1)[0] for k in macros})
    assert "MAGLEV_TRIM" in names and "MAGLEV_LQR_CONTROL" in names
    for macro_name in names:
        work = getattr(cdll, f"{macro_name.lower()}_work")
        sz = [ctypes.c_longlong() for _ in range(4)]
        assert work(*[ctypes.byref(s) for s in sz]) == 0
        got = [s.value for s in sz]
        want = [macros[f"{macro_name}_SZ_{k}"] for k in ("ARG", "RES", "IW", "W")]
        assert got == want, (macro_name, got, want)


# ------------------------------------------------------------------------------ table schedule

WARN = ["-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Werror", "-Wdouble-promotion",
        "-Wfloat-conversion", "-Wconversion"]


@pytest.fixture(scope="module")
def firmware(carriage: DerivedCarriage, sim_lib, tmp_path_factory) -> dict:
    """The table schedule over the envelope's range (fitted here, as maglevgen.analyses.envelope's
    gain_table does), the firmware loop, the exact rows at speeds, and the firmware folder
    (`render_firmware`, no plant) of each precision."""
    from maglevgen.control.schedule import GainTable, tick_table_fields
    from maglevgen.exports.firmware import firmware_loop, render_firmware

    v_min, v_max = Plant(carriage, sim_lib).speed_range
    setting = Plant(carriage, sim_lib).loop

    def rows(vs):
        return Plant(carriage, sim_lib).tick_table_rows(setting, vs)

    table = GainTable.fit(rows, v_min, v_max, tick_table_fields(setting.tick.delay))
    loop = firmware_loop(Plant(carriage, sim_lib))
    folders = {}
    for precision in ("single", "double"):
        folders[precision] = tmp_path_factory.mktemp(f"firmware_{precision}")
        write_output(render_firmware(carriage, table, loop, precision), folders[precision])
    return {"table": table, "loop": loop, "rows": rows, "folders": folders,
            "setting": setting}


@pytest.fixture(scope="module")
def gain_table(firmware):
    """(table, its C folder (the single-precision firmware folder), host libraries by
    precision, exact rows at speeds): maglev_gain_table.c compiled in each precision's
    firmware folder (its maglev_real is that folder's maglev_functions.h's)."""
    import subprocess

    libs = {}
    for precision, folder in firmware["folders"].items():
        so = folder / f"gt_{precision}.so"
        subprocess.run(["cc", *WARN, "-O2", "-fPIC", "-shared", "maglev_gain_table.c", "-o",
                        str(so)], cwd=folder, check=True)
        libs[precision] = so
    return firmware["table"], firmware["folders"]["single"], libs, firmware["rows"]


def _schedule_c(lib: Path, precision: str, v: float, ny: int | None = None
                ) -> tuple[int, np.ndarray]:
    """maglev_schedule(v) of a compiled table: (code, its ``ny`` outputs; default the
    firmware table's, `tick_table_fields` at the default delay)."""
    from maglevgen.control.schedule import tick_table_fields

    ny = ny or sum(n for _, n in tick_table_fields(1))
    real = ctypes.c_double if precision == "double" else ctypes.c_float
    fn = ctypes.CDLL(str(lib)).maglev_schedule
    fn.argtypes = [real, ctypes.POINTER(real)]
    out = (real * ny)(*([7.0] * ny))
    rc = fn(v, out)
    return rc, np.array(out[:], dtype=float)


@pytest.mark.needs_cc
@pytest.mark.parametrize("precision", ["double", "single"])
def test_table_schedule_against_exact_schedule(gain_table, carriage: DerivedCarriage,
                                               precision: str) -> None:
    """maglev_schedule (C, static tables) at 200 random speeds of [v_min, v_max], none a node
    nor a point of the fitting grid, against the exact schedule (Newton trim in C, closed-form
    gains, SciPy's CARE for the coupled LQR): every field within GAIN_TABLE_BOUND of its
    scale (single precision: plus float32 rounding); the per-axis gains also against the
    50-digit Riccati solution (mpmath) at three speeds, with the same measure."""
    from maglevgen.control.schedule import GAIN_TABLE_BOUND, field_errors
    from maglevgen.derive.riccati import lqr_gain_mp

    table, _, libs, rows = gain_table
    ny = table.coeffs.shape[1]
    speeds = np.random.default_rng(5).uniform(table.v_min, table.v_max, 200)
    got = np.array([_schedule_c(libs[precision], precision, v, ny) for v in speeds],
                   dtype=object)
    assert all(rc == 0 for rc in got[:, 0])
    approx = np.array(list(got[:, 1]), dtype=float)
    exact = rows(speeds)
    errors = field_errors(approx, exact, table.fields)
    slack = 1.0 if precision == "double" else 1.05
    assert set(errors) == {"F_prop", "a_ref", "K", "c_damping", "K_pos", "K_rate", "K_lag",
                           "K_delay"}
    assert max(errors.values()) <= GAIN_TABLE_BOUND * slack, errors
    # per-axis K (offset 6, 5 x 2 column-major) against mpmath's 50-digit LQR of the plants
    q1, q2 = carriage.params.control.state_weights
    r = carriage.params.control.input_weight
    for v in speeds[:3]:
        k, m = (np.ravel(a) for a in _plants(carriage, v))
        K = approx[list(speeds).index(v), 6:16].reshape(5, 2, order="F")
        ref = np.array([[float(g) for g in lqr_gain_mp(k[i], m[i], q1, q2, r)]
                        for i in range(5)])
        scale = np.max(np.abs(exact[:, 6:16]))  # the field's scale, as the bound's measure
        assert np.max(np.abs(K - ref)) / scale <= GAIN_TABLE_BOUND * slack


def _plants(carriage: DerivedCarriage, v: float):
    from maglevgen.runtime.library import simulation_library

    return simulation_library(carriage.structure).function("maglev_axis_plants")(v, carriage.p)


@pytest.mark.needs_cc
def test_table_schedule_return_codes(gain_table) -> None:
    """NaN and +-inf: MAGLEV_ERR_NONFINITE, out zero; v = 0, below v_min, above v_max:
    MAGLEV_ERR_SPEED with the nearer end's values (those at v_min / v_max themselves)."""
    table, _, libs, _ = gain_table
    for precision, lib in libs.items():
        for v in (np.nan, np.inf, -np.inf):
            rc, out = _schedule_c(lib, precision, v)
            assert rc == ERR["MAGLEV_ERR_NONFINITE"] and np.all(out == 0)
        rc_lo, at_lo = _schedule_c(lib, precision, table.v_min)
        rc_hi, at_hi = _schedule_c(lib, precision, table.v_max)
        assert rc_lo == rc_hi == 0
        for v, end in ((0.0, at_lo), (table.v_min * 0.99, at_lo), (-3.0, at_lo),
                       (table.v_max * 1.01, at_hi), (1e6, at_hi)):
            rc, out = _schedule_c(lib, precision, v)
            assert rc == ERR["MAGLEV_ERR_SPEED"], (precision, v)
            np.testing.assert_array_equal(out, end)


def _clenshaw_reference(c, t, real):
    """One value's Clenshaw in numpy scalars of ``real`` (np.float64 / np.float32), each
    operation rounded as the C's: b1 = b2 = 0; for k = n-1 down to 1, b0 = ((t2 b1) - b2) +
    c[k], b2 = b1, b1 = b0; then ((t b1) - b2) + c[0], from the table's coefficients rounded
    once to ``real`` (R(c))."""
    c = [real(x) for x in c]
    b1 = b2 = real(0)
    t2 = t + t
    for k in range(len(c) - 1, 0, -1):
        b0 = ((t2 * b1) - b2) + c[k]
        b2 = b1
        b1 = b0
    return ((t * b1) - b2) + c[0]


def _table_reference(table, v: float, real) -> tuple[int, float]:
    """(return code, t) of the table's _t helper at v, in ``real``: NaN or infinite v
    MAGLEV_ERR_NONFINITE (t unused), outside [v_min, v_max] MAGLEV_ERR_SPEED at the nearer
    end, t = (T_SCALE / v) - T_OFFSET with the C's constants rounded once to ``real``."""
    a, b = 1.0 / table.v_max, 1.0 / table.v_min
    v = real(v)
    if not np.isfinite(v):
        return ERR["MAGLEV_ERR_NONFINITE"], real(0)
    rc, vc = 0, v
    if v < real(table.v_min):
        rc, vc = ERR["MAGLEV_ERR_SPEED"], real(table.v_min)
    elif v > real(table.v_max):
        rc, vc = ERR["MAGLEV_ERR_SPEED"], real(table.v_max)
    return rc, (real(2.0 / (b - a)) / vc) - real((a + b) / (b - a))


@pytest.mark.needs_cc
def test_table_schedule_is_its_clenshaw_bit_for_bit(gain_table, firmware, tmp_path: Path
                                                    ) -> None:
    """maglev_schedule, maglev_schedule_varying and maglev_schedule_f_prop (the table's
    values written out with their coefficients, and the loop over the tables) compiled for the
    host in double and in float: every output at 1001 speeds across [v_min, v_max], both ends
    and their neighbours, below v_min, above v_max, NaN and +-inf, bit for bit the Clenshaw
    recurrence in numpy scalars of the same precision, operation by operation in the C's order
    (`_clenshaw_reference`), from the table's coefficients (GainTable); return codes too."""
    import subprocess

    from maglevgen.control.schedule import (
        field_slices,
        gain_table_sources,
        value_terms,
        varying_values,
    )

    table = gain_table[0]
    ny = table.coeffs.shape[1]
    terms = value_terms(table.coeffs)
    vary = varying_values(table)
    f_prop = dict(zip((n for n, _ in table.fields), field_slices(table.fields),
                      strict=True))["F_prop"][0]
    lo, hi = table.v_min, table.v_max
    speeds = [*np.linspace(lo, hi, 1001), np.nextafter(lo, 0), np.nextafter(lo, 1e9),
              np.nextafter(hi, 0), np.nextafter(hi, 1e9), 0.0, -3.0, 0.99 * lo, 1.01 * hi,
              1e6, np.nan, np.inf, -np.inf]
    forms = {"written": {"varying": True, "one_output": "F_prop"},
             "loop": {"varying": True, "one_output": "F_prop", "written_out": False}}
    for precision, folder in firmware["folders"].items():
        real = np.float64 if precision == "double" else np.float32
        creal = ctypes.c_double if precision == "double" else ctypes.c_float
        refs = []
        for v in speeds:
            rc, t = _table_reference(table, v, real)
            row = np.zeros(ny, dtype=real)
            if rc != ERR["MAGLEV_ERR_NONFINITE"]:
                for j in table.stored:
                    row[j] = _clenshaw_reference(table.coeffs[:terms[j], j], t, real)
            # _varying: at t = 0 for NaN or infinite v
            t0 = real(0) if rc == ERR["MAGLEV_ERR_NONFINITE"] else t
            varied = np.array([_clenshaw_reference(table.coeffs[:terms[j], j], t0, real)
                               for j in vary], dtype=real)
            refs.append((rc, row, varied))
        # the firmware folder's own table (gain_table's library), and both forms with
        # every function
        libs = {"firmware": gain_table[2][precision]}
        for form, kw in forms.items():
            src = tmp_path / f"{form}_{precision}"
            src.mkdir()
            files = {**gain_table_sources(table, **kw),
                     "maglev_functions.h": (folder / "maglev_functions.h").read_text()}
            for name, text in files.items():
                (src / name).write_text(text)
            libs[form] = src / "gt.so"
            subprocess.run(["cc", *WARN, "-O2", "-fPIC", "-shared", "maglev_gain_table.c",
                            "-o", str(libs[form])], cwd=src, check=True)
        for form, so in libs.items():
            lib = ctypes.CDLL(str(so))
            lib.maglev_schedule.argtypes = [creal, ctypes.POINTER(creal)]
            lib.maglev_schedule_f_prop.argtypes = [creal, ctypes.POINTER(creal)]
            for v, (rc, row, varied) in zip(speeds, refs, strict=True):
                out = (creal * ny)(*([7.0] * ny))
                assert lib.maglev_schedule(v, out) == rc, (form, precision, v)
                got = np.array(out[:], dtype=real)
                assert got.tobytes() == row.tobytes(), (form, precision, v, np.flatnonzero(
                    got.view(f"u{got.itemsize}") != row.view(f"u{row.itemsize}")))
                one = creal(7.0)
                assert lib.maglev_schedule_f_prop(v, ctypes.byref(one)) == rc
                assert real(one.value).tobytes() == row[f_prop].tobytes(), (form, v)
                if form == "firmware":
                    continue
                fn = lib.maglev_schedule_varying
                fn.argtypes = [creal, ctypes.c_int, ctypes.c_int, ctypes.POINTER(creal)]
                n = len(vary)
                out = (creal * n)(*([7.0] * n))
                assert fn(v, 0, n, out) == rc
                assert np.array(out[:], dtype=real).tobytes() == varied.tobytes(), (form, v)
                # a slice hanging over both ends: only the indices within [0, n) written
                out = (creal * n)(*([7.0] * n))
                assert fn(v, -2, 5, out) == rc
                part = np.full(n, 7.0, dtype=real)
                part[:3] = varied[:3]
                assert np.array(out[:], dtype=real).tobytes() == part.tobytes(), (form, v)

@pytest.mark.needs_cc
def test_table_gains_keep_the_closed_loop_eigenvalues(gain_table, firmware,
                                                      carriage: DerivedCarriage,
                                                      sim_lib) -> None:
    """Between the table's nodes (midpoints), the design model at the tick (the reduced body,
    the actuator lag on the generalized forces, the commands in flight; `plant.LoopPlant`)
    closed with the table's gains of the embedded controller (K_pos, K_rate, K_lag, K_delay)
    has its continuous-equivalent eigenvalues ln(z)/h within 1 % of |lambda| (and 1e-3 1/s)
    of those closed with control.dlqr's gains on the same model, and stays stable."""
    import control

    from maglevgen.analyses.envelope import loop_plant
    from maglevgen.control.lqr import weighted_qr
    from maglevgen.control.schedule import GainTable
    from maglevgen.control.spec import spec_weights

    table, _, libs, _ = gain_table
    setting = firmware["setting"]
    h, d = setting.tick.period, setting.tick.delay
    f, i = {}, 0
    for name, n in table.fields:
        f[name] = slice(i, i + n)
        i += n
    nodes = GainTable.nodes(len(table.coeffs), table.v_min, table.v_max)
    mids = 0.5 * (nodes[1:] + nodes[:-1])
    for op in Plant(carriage, sim_lib).points(mids):
        _, row = _schedule_c(libs["double"], "double", op.speed, table.coeffs.shape[1])
        K_pos = row[f["K_pos"]].reshape(5, 5, order="F")
        K_rate = row[f["K_rate"]].reshape(5, 5, order="F")
        K_table = np.hstack([K_pos @ np.eye(5, 10) + K_rate @ op.rate_map,
                             row[f["K_lag"]].reshape(5, 5, order="F"),
                             row[f["K_delay"]].reshape(5, 5 * d, order="F")])
        Phi, Gam = loop_plant(op, setting).design_model()
        q1, q2, r = spec_weights(op)
        Q, R = weighted_qr(op.rate_map, q1, q2, r)
        Qa = np.zeros_like(Phi)
        Qa[:10, :10] = Q
        K_exact, _, _ = control.dlqr(Phi, Gam, Qa, R)

        def s_plane(K: np.ndarray, Phi: np.ndarray = Phi, Gam: np.ndarray = Gam
                    ) -> np.ndarray:
            z = np.linalg.eigvals(Phi - Gam @ np.asarray(K))
            assert np.max(np.abs(z)) < 1
            return np.log(z[np.abs(z) > 1e-9].astype(complex)) / h

        ev_table, ev_exact = s_plane(K_table), s_plane(K_exact)
        for lam in ev_exact:  # each exact eigenvalue has a table one nearby
            assert np.min(np.abs(ev_table - lam)) <= 1e-2 * abs(lam) + 1e-3, (op.speed, lam)


# ------------------------------------------------------------------------------ Cortex-M4F

# the start-up and linker script the firmware folder's run_qemu.sh uses (one copy, in templates/)
QEMU_STARTUP = REPO / "templates" / "firmware_qemu_startup.c"
QEMU_LINK = REPO / "templates" / "firmware_qemu_link.ld"
M4_CPU = ["-mcpu=cortex-m4", "-mthumb", "-mfloat-abi=hard", "-mfpu=fpv4-sp-d16"]
#: the issue's firmware flags (README, Firmware use)
M4_FLAGS = [*M4_CPU, "-Os", "-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Wdouble-promotion",
            "-Wfloat-conversion", "-Werror", "-fno-math-errno"]
#: worst stack [bytes] of a per-tick function or the schedule, callees included (measured at
#: the default carriage: BENCHMARKS.md)
M4_STACK_BOUND = 256
M4_TICK = ("maglev_lqr_control", "maglev_damping_control", "maglev_coupled_control",
           "maglev_allocate", "maglev_schedule")
M4_INPUTS = {  # what the emulated M4 and the host build both evaluate
    "X": [0.0, 1e-3, -5e-3, 2e-3, -1e-3, 3e-3, 20.0, 1e-2, -2e-2, 1e-2, 2e-2, -1e-2],
    "K_GAINS": [1.0, 2.0, 0.5, 1.5, 0.2, 1.1, 1.2, 0.9, 1.4, 0.8],
    "C_DAMPING": [3.0, 4.0, 0.5, 0.7, 0.2],
    "A_REF": [0.0, -2e-3, 0.0, 1e-3, 0.0],
}


def _worst_stack(ci_text: str, root: str) -> int:
    """Largest stack [bytes] on any call path from ``root`` in gcc's -fcallgraph-info=su graph
    (a function outside the file, e.g. libm's sinf, counts 0)."""
    own = {m.group(1): int(m.group(2)) for m in re.finditer(
        r'node: \{ title: "([^"]+)" label: "[^"]*?(\d+) bytes \(static\)', ci_text)}
    calls: dict[str, list[str]] = {}
    for m in re.finditer(r'edge: \{ sourcename: "([^"]+)" targetname: "([^"]+)"', ci_text):
        calls.setdefault(m.group(1), []).append(m.group(2))

    def worst(f: str, seen: frozenset) -> int:
        return own.get(f, 0) + max((worst(g, seen | {f}) for g in calls.get(f, ())
                                    if g not in seen), default=0)

    assert root in own, root
    return worst(root, frozenset())


@pytest.mark.slow  # two cross-compiles and a QEMU run: ~170 s loaded
@pytest.mark.needs_arm("qemu-system-arm", "arm-none-eabi-nm", "arm-none-eabi-size")
def test_cortex_m4_build_and_run(gain_table, carriage: DerivedCarriage, tmp_path: Path,
                                 rendered) -> None:
    """The single-precision baked C and the table schedule cross-compiled for Cortex-M4F with
    the firmware flags: no double arithmetic (__aeabi_d*, f2d, d2f) nor double libm call, no
    .data/.bss, every external symbol maglev_*, the ticks' and the schedule's stack (callees
    included) within M4_STACK_BOUND; then run on QEMU's mps2-an386 and compared with the host
    double build (baked double C, double table) to 1e-5 of each output vector's largest
    magnitude."""
    import subprocess

    from maglevgen.codegen.cpass import DOUBLE_MATH

    table, table_dir, table_libs, _ = gain_table
    src = tmp_path / "m4"
    write_output(rendered(carriage, GenerateOptions("single", "baked", "int32"),
                          speed_range(carriage)), src)
    for name in ("maglev_gain_table.c", "maglev_gain_table.h"):
        (src / name).write_text((table_dir / name).read_text())
    objs = []
    for name in ("maglev_functions", "maglev_gain_table"):
        subprocess.run(["arm-none-eabi-gcc", *M4_FLAGS, "-ffunction-sections", "-fdata-sections",
                        "-fstack-usage", "-fcallgraph-info=su", "-c", f"{name}.c",
                        "-o", f"{name}.o"], cwd=src, check=True)
        objs.append(f"{name}.o")
    symbols = subprocess.run(["arm-none-eabi-nm", *objs], cwd=src, check=True,
                             capture_output=True, text=True).stdout
    undefined = {ln.split()[-1] for ln in symbols.splitlines() if " U " in ln}
    defined = {ln.split()[-1] for ln in symbols.splitlines()
               if re.match(r"^[0-9a-f]+ [TDRB] ", ln)}
    assert not {s for s in undefined if s.startswith(("__aeabi_d", "__aeabi_f2d",
                                                      "__aeabi_d2f"))}, undefined
    assert not undefined & DOUBLE_MATH, undefined & DOUBLE_MATH
    assert all(s.startswith("maglev_") for s in defined), defined
    sizes = subprocess.run(["arm-none-eabi-size", "-A", *objs], cwd=src, check=True,
                           capture_output=True, text=True).stdout
    writable = [ln for ln in sizes.splitlines()
                if ln.startswith((".data", ".bss")) and int(ln.split()[1]) > 0]
    assert not writable, writable
    ci = "".join((src / f"{n}.ci").read_text() for n in ("maglev_functions", "maglev_gain_table"))
    stacks = {f: _worst_stack(ci, f) for f in M4_TICK}
    assert max(stacks.values()) <= M4_STACK_BOUND, stacks

    # run on the emulated M4
    m4 = REPO / "tests" / "c" / "m4"
    speeds = [table.v_min, 0.5 * (table.v_min + table.v_max), table.v_max, 13.7]
    defines = [f"-D{k}=" + ",".join(f"{v!r}f" for v in vals) for k, vals in M4_INPUTS.items()]
    defines.append("-DSPEEDS=" + ",".join(f"{v!r}f" for v in speeds))
    subprocess.run(["arm-none-eabi-gcc", *M4_CPU, "-Os", "-std=gnu99", "-Wall", "-Werror",
                    "-fno-math-errno", "-ffunction-sections", "-fdata-sections", *defines,
                    f"-I{src}", "-c", str(QEMU_STARTUP), str(m4 / "m4main.c")],
                   cwd=src, check=True)
    subprocess.run(["arm-none-eabi-gcc", *M4_CPU, "-nostartfiles", "-T", str(QEMU_LINK),
                    "-Wl,--gc-sections", f"{QEMU_STARTUP.stem}.o", "m4main.o", *objs, "-lm",
                    "-lc", "-o", "m4.elf"], cwd=src, check=True)
    run = subprocess.run(["qemu-system-arm", "-M", "mps2-an386", "-nographic", "-semihosting",
                          "-kernel", "m4.elf"], cwd=src, capture_output=True, text=True,
                         timeout=120, check=True)
    # `--single-file`: maglev.c with the same flags (and -Wmissing-prototypes: every external
    # function declared by the headers), linked with the same driver: the same output bits
    one = tmp_path / "m4_single"
    write_output(rendered(carriage, GenerateOptions("single", "baked", "int32",
                                                    single_file=True),
                          speed_range(carriage)), one)
    subprocess.run(["arm-none-eabi-gcc", *M4_FLAGS, "-Wmissing-prototypes", "-ffunction-sections",
                    "-fdata-sections", "-c", "maglev.c", "-o", "maglev.o"], cwd=one, check=True)
    assert _external(["arm-none-eabi-nm", str(one / "maglev.o")]) == _declared(one)
    subprocess.run(["arm-none-eabi-gcc", *M4_CPU, "-nostartfiles", "-T", str(QEMU_LINK),
                    "-Wl,--gc-sections", f"{QEMU_STARTUP.stem}.o", "m4main.o",
                    str(one / "maglev.o"),
                    "maglev_gain_table.o", "-lm", "-lc", "-o", "m4_single.elf"], cwd=src,
                   check=True)
    run_one = subprocess.run(["qemu-system-arm", "-M", "mps2-an386", "-nographic",
                              "-semihosting", "-kernel", "m4_single.elf"], cwd=src,
                             capture_output=True, text=True, timeout=120, check=True)
    assert run_one.stderr == run.stderr
    lines = run.stderr.split()  # QEMU writes semihosting output to stderr
    pos = 0

    def take(n: int) -> np.ndarray:
        nonlocal pos
        assert lines[pos] == "r0", (pos, lines[pos])  # the call's return code
        words = lines[pos + 1:pos + 1 + n]
        pos += 1 + n
        return np.array([np.uint32(int(h, 16)).view(np.float32) for h in words], dtype=float)

    # the host double build
    host = tmp_path / "host"
    write_output(rendered(carriage, GenerateOptions("double", "baked"), speed_range(carriage)),
                 host)
    # the run's content-keyed cache: baked_gen's double library when that ran in this process
    lib = GeneratedLibrary(compile_shared([host / "maglev_functions.c"]), "double")
    x = np.array(M4_INPUTS["X"])
    K = np.array(M4_INPUTS["K_GAINS"]).reshape(5, 2, order="F")
    u_gen = lib.function("maglev_lqr_control")(x, K, M4_INPUTS["A_REF"])[0].ravel()
    forces = lib.function("maglev_allocate")(u_gen)[0].ravel()
    damping = lib.function("maglev_damping_control")(x, M4_INPUTS["C_DAMPING"])[0].ravel()
    expected = [u_gen, forces, damping]
    ny = table.coeffs.shape[1]
    expected += [_schedule_c(table_libs["double"], "double", v, ny)[1] for v in speeds]
    got = [take(5), take(len(forces)), take(5)] + [take(ny) for _ in speeds]
    assert pos == len(lines)
    for want, have in zip(expected, got, strict=True):
        assert np.max(np.abs(have - want)) <= 1e-5 * np.max(np.abs(want)), (want, have)


def _declared(folder: Path) -> set[str]:
    """The functions maglev_functions.h and maglev_simulate.h declare (the documented API)."""
    decl = re.compile(r"^(?:\w+ )*\w+[ *]+(\w+)\([^;{)]*\);", re.M)
    return {m.group(1) for h in ("maglev_functions.h", "maglev_simulate.h")
            for m in decl.finditer((folder / h).read_text())}


def _external(nm: list[str]) -> set[str]:
    """The symbols an object file defines with external linkage (nm's upper-case types)."""
    import subprocess

    out = subprocess.run(nm, check=True, capture_output=True, text=True).stdout
    return {ln.split()[-1] for ln in out.splitlines() if re.match(r"^[0-9a-f]+ [TDRBC] ", ln)}


@pytest.mark.slow  # two firmware builds compiled in full
@pytest.mark.needs_cc
def test_single_file_is_the_two_file_build(carriage: DerivedCarriage, tmp_path: Path) -> None:
    """`generate --single-file`: one translation unit, maglev.c, that compiles warning-free
    for the host with the issue's flags plus -Wmissing-prototypes (an external function
    without a header prototype fails), defines exactly the functions the headers declare (every
    helper static), and gives the two-file build's results bit for bit (the trim, the gain
    schedule, a tick and maglev_simulate's trajectory)."""
    import subprocess

    from maglevgen.cli import main

    libs = {}
    for name, flag in (("two", []), ("one", ["--single-file"])):
        out = tmp_path / name
        assert main(["generate", "--out", str(out), *flag]) == 0
        sources = sorted(p.name for p in out.glob("*.c"))
        assert sources == (["maglev.c", "main.c"] if flag else
                           ["maglev_functions.c", "maglev_simulate.c", "main.c"])
        c_files = [out / s for s in sources if s != "main.c"]
        libs[name] = compile_shared(c_files)
        if flag:
            assert json.loads((out / "manifest.json").read_text())["files"]["c"] == ["maglev.c"]
            subprocess.run(["cc", *WARN, "-Wmissing-prototypes", "-O2", "-c", "maglev.c",
                            "-o", "maglev.o"], cwd=out, check=True)
            declared = _declared(out)
            assert {"maglev_trim", "maglev_simulate", "maglev_lqr_control"} <= declared
            assert _external(["nm", str(out / "maglev.o")]) == declared
            # the example builds through its CMake file from the one source
            subprocess.run(["cmake", "-S", ".", "-B", "build"], cwd=out, check=True,
                           capture_output=True)
            subprocess.run(["cmake", "--build", "build"], cwd=out, check=True,
                           capture_output=True)
    two, one = (GeneratedLibrary(libs[k], "double") for k in ("two", "one"))
    x = np.array(M4_INPUTS["X"])
    for name, args in (("maglev_trim", ([20.0],)), ("maglev_lqr_gains", ([31.0],)),
                       ("maglev_lqr_control", (x, np.ones((5, 2)), np.zeros(5))),
                       ("maglev_dynamics", (x, np.linspace(-1, 1, 11)))):
        for a, b in zip(two.function(name)(*args), one.function(name)(*args), strict=True):
            np.testing.assert_array_equal(a, b)
    trajectories = []
    for lib in (libs["two"], libs["one"]):
        sim = ctypes.CDLL(str(lib)).maglev_simulate
        sim.restype = ctypes.c_longlong
        D = ctypes.POINTER(ctypes.c_double)
        n = 200
        bufs = [np.zeros((n + 1) * k) for k in (12, 11, 6)]
        x0 = np.array(two.function("maglev_trim")([20.0])[0]).ravel()
        x0[2] += 1e-3
        K = np.diag([2e4, 2e4, 5e3, 5e3, 5e3]).ravel()
        status = ctypes.c_int()
        last = sim(x0.ctypes.data_as(D), ctypes.c_double(1e-3), ctypes.c_longlong(n),
                   ctypes.c_double(0.0), K.ctypes.data_as(D), (K / 50).ctypes.data_as(D),
                   np.zeros(5).ctypes.data_as(D), None, ctypes.c_double(0.0),
                   *[b.ctypes.data_as(D) for b in bufs], None, ctypes.byref(status))
        trajectories.append((last, status.value, bufs))
    assert trajectories[0][0] == n
    np.testing.assert_array_equal(np.concatenate(trajectories[0][2]),
                                  np.concatenate(trajectories[1][2]))


@pytest.mark.slow  # a cross-compiled build of its own
@pytest.mark.needs_arm("arm-none-eabi-objdump", "arm-none-eabi-nm")
def test_m4_square_root_is_the_fpu_instruction(carriage: DerivedCarriage, tmp_path: Path,
                                               rendered) -> None:
    """With -fno-math-errno (the README's firmware flags) the Cortex-M4F object computes
    square roots with the FPU's vsqrt.f32 and calls no sqrtf (newlib's errno-setting
    wrapper); without the flag it does call sqrtf: the check can see the difference."""
    import subprocess

    write_output(rendered(carriage, GenerateOptions("single", "baked", "int32"),
                          speed_range(carriage)), tmp_path)
    found = {}
    for name, flags in (("fast", M4_FLAGS), ("errno", [f for f in M4_FLAGS
                                                       if f != "-fno-math-errno"])):
        subprocess.run(["arm-none-eabi-gcc", *flags, "-c", "maglev_functions.c", "-o",
                        f"{name}.o"], cwd=tmp_path, check=True)
        asm = subprocess.run(["arm-none-eabi-objdump", "-d", f"{name}.o"], cwd=tmp_path,
                             check=True, capture_output=True, text=True).stdout
        syms = subprocess.run(["arm-none-eabi-nm", "-u", f"{name}.o"], cwd=tmp_path,
                              check=True, capture_output=True, text=True).stdout.split()
        found[name] = (len(re.findall(r"\bvsqrt\.f32\b", asm)), "sqrtf" in syms)
    assert found["fast"][0] > 0 and not found["fast"][1], found
    assert found["errno"][1], found  # newlib's sqrtf wrapper is called without the flag


# ------------------------------------------------------------------------------ MISRA C:2012


def test_enclosing_functions_on_a_planted_file() -> None:
    """The line -> function map the deviation places are matched with, on C written here
    with known answers: signatures over two lines, nested braces, braces in comments and
    strings, a static array initializer and a macro at file scope, CasADi's extern "C"."""
    from maglevgen.codegen.misra import enclosing_functions

    source = "\n".join([
        '#ifdef __cplusplus', 'extern "C" {', '#endif',             # 1-3
        'static const int casadi_s0[3] = {1, 2, 3};',               # 4: file scope
        '#define M(x) { x }',                                       # 5
        'static int f(const double* a,', '             int n) {',   # 6-7: f
        '  /* } not a brace */ const char* s = "{";',               # 8: f
        '  if (n) { return 1; }', '  return 0;', '}',               # 9-11: f
        'int g(void) { return 2; }',                                # 12: g
        'int h(int);',                                              # 13: file scope
        '#ifdef __cplusplus', '} /* extern "C" */', '#endif', ''])  # 14-16
    assert enclosing_functions(source) == {6: "f", 7: "f", 8: "f", 9: "f", 10: "f", 11: "f",
                                           12: "g"}


@pytest.mark.needs_arm("cppcheck")
def test_tick_path_misra_findings_are_all_justified(gain_table, carriage: DerivedCarriage,
                                                    tmp_path: Path) -> None:
    """cppcheck's MISRA C:2012 addon on the per-tick functions (single precision, baked;
    maglev_tick.c, whose text is maglev_functions.c's for them) and the table schedule: every
    finding lies in a listed place of the deviation list written beside the code
    (maglevgen.codegen.misra: its file, its rule, its enclosing function matching one of the
    place's patterns) and every pattern of every place holds a finding (no stale place); the
    list in generated/MISRA_DEVIATIONS.md names every place."""
    import subprocess

    from maglevgen.codegen.generate import render_tick_sources
    from maglevgen.codegen.misra import DEVIATIONS, FILE_SCOPE, enclosing_functions

    _, table_dir, _, _ = gain_table
    for name, text in render_tick_sources(carriage).items():
        (tmp_path / name).write_text(text)
    for name in ("maglev_gain_table.c", "maglev_gain_table.h"):
        (tmp_path / name).write_text((table_dir / name).read_text())
    # the header of these functions under the name the table's header includes
    (tmp_path / "maglev_functions.h").write_text((tmp_path / "maglev_tick.h").read_text())
    run = subprocess.run(["cppcheck", "--addon=misra", "--std=c99", "--quiet",
                          "--template={file}:{line}:{id}", "maglev_tick.c",
                          "maglev_gain_table.c"], cwd=tmp_path, capture_output=True,
                         text=True, timeout=300, check=True)
    findings = [ln.split(":") for ln in run.stderr.splitlines() if "misra-c2012-" in ln]
    assert findings, run.stderr  # the addon ran (CasADi's code has known deviations)
    functions = {}
    used, uncovered = set(), []
    for file, line, rule in findings:
        if file not in functions:
            functions[file] = enclosing_functions((tmp_path / file).read_text())
        function = functions[file].get(int(line), FILE_SCOPE)
        place = ("maglev_functions.c" if file == "maglev_tick.c" else file, function,
                 rule.removeprefix("misra-c2012-"))
        hits = [(i, d.covers(*place)) for i, d in enumerate(DEVIATIONS)]
        hits = [(i, p) for i, p in hits if p is not None]
        if not hits:
            uncovered.append((file, line, *place[1:]))
        used.update(hits)
    assert not uncovered, uncovered
    # the places of these files (the firmware folder's own are test_firmware_misra's)
    files = ("maglev_functions.c", "maglev_gain_table.c", "maglev_gain_table.h")
    listed = {(i, p) for i, d in enumerate(DEVIATIONS) for p in d.functions if d.file in files}
    assert listed == {(i, p) for i, p in used if DEVIATIONS[i].file in files}, \
        sorted(listed - used)
    md = (REPO / "generated" / "MISRA_DEVIATIONS.md").read_text()
    for d in DEVIATIONS:
        assert any(ln.startswith(f"| {d.rule} | {d.file} |") and d.what in ln
                   for ln in md.splitlines()), d


# ------------------------------------------------------------------------------ --int int32


@pytest.mark.slow  # two builds compiled in full
@pytest.mark.needs_cc
def test_int32_build_gives_the_int64_results(carriage: DerivedCarriage, tmp_path: Path,
                                             rendered) -> None:
    """`--int int32` (casadi_int = int for 32-bit MCUs): the header says so, and the trim and
    a tick called through the int32 ABI equal the default int64 build's bit for bit (the
    integer type only indexes sparsity and work)."""
    libs = {}
    for int_type in ("int64", "int32"):
        out = tmp_path / int_type
        write_output(rendered(carriage, GenerateOptions("double", "runtime", int_type)), out)
        text = (out / "maglev_functions.h").read_text()
        want = "int" if int_type == "int32" else "long long int"
        assert f"typedef {want} maglev_int;" in text
        libs[int_type] = GeneratedLibrary(
            compile_shared([out / "maglev_functions.c"]), "double", int_type)
    for name, args in (("maglev_trim", ([20.0], carriage.p)),
                       ("maglev_lqr_gains", ([15.0], carriage.p))):
        a, b = (libs[k].function(name)(*args) for k in ("int64", "int32"))
        for x, y in zip(a, b, strict=True):
            np.testing.assert_array_equal(x, y)


@pytest.mark.needs_cc
def test_header_leaves_casadi_real_alone(carriage: DerivedCarriage, tmp_path: Path,
                                        rendered) -> None:
    """maglev.h (single precision) included after another CasADi module's
    ``#define casadi_real double``: casadi_real stays double (8 bytes) and the header's own
    maglev_real is float (4 bytes); the compiler checks both sizes."""
    import subprocess

    write_output(rendered(carriage, GenerateOptions("single", "baked", "int32"),
                          speed_range(carriage)), tmp_path)
    (tmp_path / "other.c").write_text(
        "#define casadi_real double\n#define casadi_int long long int\n#include \"maglev.h\"\n"
        "typedef char real_kept[sizeof(casadi_real) == 8 ? 1 : -1];\n"
        "typedef char int_kept[sizeof(casadi_int) == 8 ? 1 : -1];\n"
        "typedef char own_real[sizeof(maglev_real) == 4 ? 1 : -1];\n"
        "typedef char own_int[sizeof(maglev_int) == sizeof(int) ? 1 : -1];\n"
        "int use(void) { return (int)sizeof(real_kept) + (int)sizeof(int_kept)\n"
        "    + (int)sizeof(own_real) + (int)sizeof(own_int); }\n")
    subprocess.run(["cc", *WARN, "-c", "other.c", "-o", "other.o"], cwd=tmp_path, check=True)


# ------------------------------------------------------------------------- the firmware folder

#: the headers of `maglevgen firmware`'s folder
FIRMWARE_HEADERS = ("maglev.h", "maglev_functions.h", "maglev_gain_table.h", "maglev_tick.h")
FIRMWARE_SOURCES = ("maglev_tick.c", "maglev_gain_table.c", "maglev_functions.c", "main.c")
STRICT = ["-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Werror"]  # the flags


@pytest.mark.needs_cc("clang")
def test_firmware_headers_compile_together_in_any_order(firmware, tmp_path: Path) -> None:
    """Every header of the firmware folder included together, in both orders, under -std=c99
    -Wall -Wextra -Wpedantic -Werror with gcc and clang, for both precisions (one definition
    of maglev_real: the compiler checks its size, 4 or 8 bytes, in the translation unit);
    every .c of the folder compiles under the same flags. A typedef given twice (the table's
    old own maglev_real) fails here."""
    import subprocess

    for precision, folder in firmware["folders"].items():
        size = 4 if precision == "single" else 8
        for order, headers in (("forward", FIRMWARE_HEADERS),
                               ("reverse", FIRMWARE_HEADERS[::-1])):
            unit = folder / f"all_{order}.c"
            unit.write_text("".join(f'#include "{h}"\n' for h in headers)
                            + f"typedef char real_size[sizeof(maglev_real) == {size} ? 1 : -1];\n"
                            "int use(maglev_real v, maglev_real* u);\n"
                            "int use(maglev_real v, maglev_real* u) {\n"
                            "    maglev_tick_state s;\n"
                            "    return maglev_schedule(v, u) + maglev_tick_init(&s)\n"
                            "        + maglev_tick(&s, u, v, u)\n"
                            "        + (int)sizeof(real_size);\n}\n")
            for cc in ("gcc", "clang"):
                run = subprocess.run([cc, *STRICT, "-c", unit.name, "-o", f"{order}_{cc}.o"],
                                     cwd=folder, capture_output=True, text=True)
                assert run.returncode == 0, (precision, order, cc, run.stderr)
        for cc in ("gcc", "clang"):
            for source in FIRMWARE_SOURCES:
                run = subprocess.run([cc, *STRICT, "-c", source, "-o", f"{cc}_{source}.o"],
                                     cwd=folder, capture_output=True, text=True)
                assert run.returncode == 0, (precision, cc, source, run.stderr)


@pytest.mark.slow
@pytest.mark.needs_arm("cmake", "arm-none-eabi-nm")
def test_firmware_cmake_builds_for_cortex_m4f(firmware, tmp_path: Path) -> None:
    """The folder's CMake project configures and builds with its toolchain file
    (cortex-m4f.cmake): the example is an ARM ELF (its header's e_machine is 40, EM_ARM), and
    the library calls no double-precision helper (__aeabi_d*), only libm's float functions,
    and defines only maglev_* symbols (maglev_tick among them). About 15 s on a busy machine."""
    import shutil
    import subprocess

    src = tmp_path / "fw"
    shutil.copytree(firmware["folders"]["single"], src,
                    ignore=shutil.ignore_patterns("*.o", "*.so", "all_*.c"))
    for step in (["cmake", "-S", ".", "-B", "build", "-DCMAKE_TOOLCHAIN_FILE=cortex-m4f.cmake"],
                 ["cmake", "--build", "build"]):
        run = subprocess.run(step, cwd=src, capture_output=True, text=True)
        assert run.returncode == 0, run.stdout + run.stderr
    elf = (src / "build" / "maglev_firmware_example").read_bytes()
    assert elf[:4] == b"\x7fELF" and int.from_bytes(elf[18:20], "little") == 40  # EM_ARM
    nm = subprocess.run(["arm-none-eabi-nm", "-u", "build/libmaglev_firmware.a"], cwd=src,
                        check=True, capture_output=True, text=True).stdout
    assert "U sinf" in nm and not re.search(r"__aeabi_d|__aeabi_f2d", nm), nm
    defined = subprocess.run(["arm-none-eabi-nm", "-g", "--defined-only",
                              "build/libmaglev_firmware.a"], cwd=src, check=True,
                             capture_output=True, text=True).stdout
    names = {ln.split()[-1] for ln in defined.splitlines() if re.match(r"^[0-9a-f]+ ", ln)}
    assert "maglev_tick" in names and all(n.startswith("maglev_") for n in names), names


@pytest.mark.slow
@pytest.mark.needs_arm("cppcheck")
def test_firmware_misra_findings_are_all_justified(firmware) -> None:
    """cppcheck's MISRA C:2012 addon on every .c of the firmware folder (their headers with
    them) in every preprocessor configuration (--force): every finding lies in a listed place
    (file, enclosing function, rule) of maglevgen.codegen.misra.DEVIATIONS, and every place
    of the folder's own files (maglev.h, maglev_functions.h, maglev_tick.*, main.c) holds a
    finding (no stale place; the others are test_tick_path_misra_findings_are_all_justified's).
    About 12 s."""
    import subprocess

    from maglevgen.codegen.misra import DEVIATIONS, FILE_SCOPE, enclosing_functions

    folder = firmware["folders"]["single"]
    run = subprocess.run(["cppcheck", "--addon=misra", "--std=c99", "--force", "--quiet",
                          "--template={file}:{line}:{id}", *FIRMWARE_SOURCES], cwd=folder,
                         capture_output=True, text=True, timeout=300, check=True)
    findings = [ln.split(":") for ln in run.stderr.splitlines() if "misra-c2012-" in ln]
    assert {f for f, _, _ in findings} >= {"maglev_functions.c", "maglev.h"}, run.stderr
    used, uncovered = set(), []
    for file, line, rule in findings:
        function = enclosing_functions((folder / file).read_text()).get(int(line), FILE_SCOPE)
        hits = [(i, d.covers(file, function, rule.removeprefix("misra-c2012-")))
                for i, d in enumerate(DEVIATIONS)]
        hits = [(i, p) for i, p in hits if p is not None]
        if not hits:
            uncovered.append((file, line, function, rule))
        used.update(hits)
    assert not uncovered, uncovered
    own = ("maglev.h", "maglev_functions.h", "maglev_tick.h", "maglev_tick.c", "main.c")
    listed = {(i, p) for i, d in enumerate(DEVIATIONS) for p in d.functions if d.file in own}
    assert listed and listed <= used, sorted(listed - used)


def test_firmware_command_refuses_bad_input(tmp_path: Path, capsys) -> None:
    """`maglevgen firmware`: an output path that is a file, an unknown embedded controller
    and an unknown precision exit 2 with one line naming the value, before any slow work,
    and write nothing."""
    from maglevgen.cli import main

    afile = tmp_path / "a_file"
    afile.write_text("x")
    cases = ((["firmware", "--out", str(afile)], str(afile)),
             (["firmware", "--out", str(tmp_path / "fw"), "--set",
               'envelope.embedded_controller="bogus"'], "bogus"))
    for argv, named in cases:
        capsys.readouterr()
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and named in err[0], err
    with pytest.raises(SystemExit) as exc:
        main(["firmware", "--precision", "quad", "--out", str(tmp_path / "fw")])
    assert exc.value.code == 2 and "quad" in capsys.readouterr().err
    assert afile.read_text() == "x" and not (tmp_path / "fw").exists()


U32 = 2.0 ** -24  # float32's unit roundoff
#: roundings per tick that the closed-loop bound counts for every term of the state update:
#: four RK4 stages, each rounding the force law's products, exponentials and sums a few
#: (about four) times; the state and the command stored once per tick
ROUNDINGS = 16


@pytest.mark.slow
@pytest.mark.needs_arm("qemu-system-arm")
def test_firmware_closed_loop_on_the_m4_against_the_host(firmware, carriage: DerivedCarriage,
                                                         sim_lib,
                                                          op, tmp_path: Path) -> None:
    """`maglevgen firmware --with-plant` built for the Cortex-M4F with the README's flags and
    run under QEMU (mps2-an386) in closed loop: maglev_tick at the tick rate with its delay,
    one RK4 step of the float32 maglev_dynamics per tick with the command held, 1 s from the
    default disturbance of the trim at the default speed. Reference: RK4 in numpy at the same
    tick over the host double library's dynamics, its coupled control and allocation (run-time
    parameters), the table evaluated by numpy's chebval, the designed tick's lag and delay
    compensation (plant.py's controller), the speed loop and the budget written here.

    The bound (per state, linear error propagation): the target's error obeys
    e[k+1] = Phi e[k] + d[k], Phi the one-tick map's Jacobian at the trim (state, the
    commands on their way and the controller's state, central differences of the
    reference), d the float32 rounding of one tick: ROUNDINGS * u32 * (max |x| over the
    run + dt |f| + dt m g sum_j |B_ij|) for the state (m g sum |B|: the size of the lift
    and weight terms that cancel in each acceleration, B from the host's Jacobians),
    ROUNDINGS * u32 * (|command| + budget) for the command and ROUNDINGS * u32 * budget for
    the controller's state. So
    |e[n]| <= sum_{j<=n} |Phi^j| d, checked for every state at every sample; the disturbance's
    response is at least 100 times the bound on the heave (the check can tell a wrong
    controller). Then a NaN in the measured heave: the tick returns MAGLEV_ERR_NONFINITE and
    zeroes the command on the target."""
    import subprocess

    from maglevgen.analyses.simulate import DISTURBANCE, initial_state
    from maglevgen.cli import main
    from maglevgen.controllers import controller
    from maglevgen.derive import conventions as cv
    from maglevgen.exports.firmware import FIRMWARE_FLAGS, TICK_INPUTS

    table, loop = firmware["table"], firmware["loop"]
    out = tmp_path / "fw"
    assert main(["firmware", "--with-plant", "--out", str(out)]) == 0
    n_ticks = round(loop.tick_rate)  # 1 s
    dt, depth = 1.0 / loop.tick_rate, loop.delay_ticks + 1
    x0 = initial_state(op, DISTURBANCE).astype(np.float32)
    v_ref = np.float32(op.speed)

    # the target
    m4 = REPO / "tests" / "c" / "m4"
    objs = []
    for name in ("maglev_tick", "maglev_gain_table", "maglev_functions"):
        subprocess.run(["arm-none-eabi-gcc", *FIRMWARE_FLAGS, "-ffunction-sections",
                        "-fdata-sections", "-c", f"{name}.c", "-o", f"{name}.o"], cwd=out,
                       check=True)
        objs.append(f"{name}.o")
    defines = ["-DX0=" + ",".join(f"{float(v)!r}f" for v in x0),
               f"-DV_REF={float(v_ref)!r}f", f"-DN_TICKS={n_ticks}"]
    subprocess.run(["arm-none-eabi-gcc", *M4_CPU, "-Os", "-std=gnu99", "-Wall", "-Werror",
                    "-fno-math-errno", *defines, "-I.", "-c", str(QEMU_STARTUP),
                    str(m4 / "closed_loop.c")], cwd=out, check=True)
    subprocess.run(["arm-none-eabi-gcc", *M4_CPU, "-nostartfiles", "-T", str(QEMU_LINK),
                    "-Wl,--gc-sections", f"{QEMU_STARTUP.stem}.o", "closed_loop.o", *objs, "-lm",
                    "-lc",
                    "-o", "loop.elf"], cwd=out, check=True)
    run = subprocess.run(["qemu-system-arm", "-M", "mps2-an386", "-nographic", "-semihosting",
                          "-kernel", "loop.elf"], cwd=out, capture_output=True, text=True,
                         timeout=300, check=True)

    def floats(line: str) -> np.ndarray:
        return np.array([np.uint32(int(h, 16)).view(np.float32) for h in line.split()[1:]],
                        dtype=float)

    lines = run.stderr.splitlines()
    xs = np.array([floats(ln) for ln in lines if ln.startswith("x ")])
    tail = {ln[0]: floats(ln) for ln in lines if ln[:2] in ("r ", "n ", "u ")}
    assert tail["r"][0] == 0 and xs.shape == (n_ticks + 1, 12), (tail, xs.shape)

    # the reference: numpy RK4 over the host's double C, the same tick, delay and hold
    p = carriage.p
    tick_fn = controller(carriage.params.envelope.embedded_controller).tick_function
    dyn, ctl, alloc = (sim_lib.function(n) for n in ("maglev_dynamics", tick_fn,
                                                     "maglev_allocate"))
    field, i = {}, 0
    for name, size in table.fields:
        field[name] = slice(i, i + size)
        i += size
    array_of = np.array([i for i, (_, comps) in enumerate(carriage.model.structure.arrays)
                         for _ in comps])
    budget = loop.force_budget
    nd = loop.delay_ticks
    nq = 5 * max(nd, 1)
    lag = float(np.exp(-1.0 / (loop.tick_rate * loop.actuator_lag)))

    def command(x: np.ndarray, cs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The designed tick (maglevgen.control.plant's controller) on the state x with the
        controller's state cs = (in flight, newest first; w_hat; xi): (command, next cs)."""
        v = float(np.linalg.norm(x[6:9]))
        g = table(v)
        q, w_hat, xi = cs[:nq], cs[nq:nq + 5], cs[-1]
        (u_gen,) = ctl(x, *[g[field[n]] for n in TICK_INPUTS[tick_fn]], p)
        w = u_gen.ravel() - g[field["K_lag"]].reshape(5, 5, order="F") @ w_hat
        if nd > 0:
            w = w - g[field["K_delay"]].reshape(5, nq, order="F") @ q
        (F,) = alloc(w, p)
        F = F.ravel()
        norm = np.sqrt(np.bincount(array_of, F ** 2))
        F = F * np.where(norm > budget, budget / np.maximum(norm, 1e-300), 1.0)[array_of]
        f_prop = g[field["F_prop"]][0] + loop.speed_gain * (float(v_ref) - v) \
            - loop.speed_integral * xi
        applied = q[-5:] if nd > 0 else w
        q1 = np.concatenate([w, q[:-5]]) if nd > 0 else q
        cs1 = np.concatenate([q1, lag * w_hat + (1 - lag) * applied,
                              [xi + dt * (v - float(v_ref))]])
        return np.concatenate([[f_prop], F]), cs1

    def f(x: np.ndarray, u: np.ndarray) -> np.ndarray:
        return dyn(x, u, p)[0].ravel()

    def rk4(x: np.ndarray, u: np.ndarray) -> np.ndarray:
        k1 = f(x, u)
        k2 = f(x + dt / 2 * k1, u)
        k3 = f(x + dt / 2 * k2, u)
        k4 = f(x + dt * k3, u)
        return x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)

    def tick(x: np.ndarray, queue: list[np.ndarray], cs: np.ndarray
             ) -> tuple[np.ndarray, list, np.ndarray]:
        """One tick: the command of delay ticks ago applied (queue[0]), the new one queued."""
        c, cs1 = command(x, cs)
        if depth == 1:
            return rk4(x, c), queue, cs1
        return rk4(x, queue[0]), [*queue[1:], c], cs1

    x = x0.astype(float)
    cs0 = np.zeros(nq + 6)  # maglev_tick_init
    first, _ = command(x, cs0)
    # before the first computed command: the safe one, no array force and the table's trim
    # propulsion at the measured speed
    safe = np.zeros(first.size)
    safe[0] = table(float(np.linalg.norm(x[6:9])))[field["F_prop"]][0]
    queue = [safe] * (depth - 1)
    cs = cs0
    ref = [x]
    for _ in range(n_ticks):
        x, queue, cs = tick(x, queue, cs)
        ref.append(x)
    ref = np.array(ref)

    # the bound: the one-tick map's Jacobian Phi at the trim, z = (x, queued commands, the
    # controller's state)
    nx, nu = 12, first.size
    x_trim = op.x_trim.astype(float)
    c_trim, _ = command(x_trim, cs0)

    def step(z: np.ndarray) -> np.ndarray:
        q = [z[nx + k * nu: nx + (k + 1) * nu] for k in range(depth - 1)]
        x1, q1, cs1 = tick(z[:nx], q, z[nx + (depth - 1) * nu:])
        return np.concatenate([x1, *q1, cs1])

    z0 = np.concatenate([x_trim, *[c_trim] * (depth - 1), cs0])
    h = 1e-6 * np.maximum(1.0, np.abs(z0))
    Phi = np.column_stack([(step(z0 + h[j] * e) - step(z0 - h[j] * e)) / (2 * h[j])
                           for j, e in enumerate(np.eye(z0.size))])
    _, B = sim_lib.function("maglev_jacobians")(x_trim, c_trim, p)
    weight = carriage.params.vehicle.mass * 9.81
    d_x = ROUNDINGS * U32 * (np.abs(ref).max(axis=0) + dt * (
        np.abs(f(x_trim, c_trim)) + weight * np.abs(B).sum(axis=1)))
    d_c = ROUNDINGS * U32 * (np.abs(c_trim) + budget)
    d_s = ROUNDINGS * U32 * np.full(nq + 6, budget)  # the state's forces, rounded each tick
    d = np.concatenate([d_x, *[d_c] * (depth - 1), d_s])
    power, bound = np.eye(z0.size), np.zeros(z0.size)
    for _ in range(n_ticks + 1):
        bound += np.abs(power) @ d
        power = Phi @ power
    bound = bound[:nx]
    error = np.abs(xs - ref).max(axis=0)
    assert np.all(error <= bound), (error, bound)
    z = cv.STATE_INDEX["z"]
    response = np.abs(ref[:, z] - x_trim[z]).max()
    assert response >= 100 * bound[z], (response, bound[z])

    # a NaN in the measured state, on the target: the code and a zero command
    assert tail["n"][0] == ERR["MAGLEV_ERR_NONFINITE"]
    assert tail["u"].size == nu and np.all(tail["u"] == 0), tail["u"]


def test_firmware_readme_quotes_the_recorded_tick_cost() -> None:
    """The tick's cost the folder's README quotes (maglevgen.exports.firmware.MEASURED) is the
    one bench/firmware_tick.py recorded (bench/firmware_tick_results.json), and the share of
    the 1 kHz period is the cycles over 168 000 (recomputed here)."""
    from maglevgen.exports.firmware import MEASURED

    recorded = json.loads((REPO / "bench" / "firmware_tick_results.json").read_text())
    for key in ("instructions", "cycles", "clock_mhz", "stack_bytes"):
        assert MEASURED[key] == recorded[key], key
    assert MEASURED["share_percent"] == pytest.approx(
        100 * recorded["cycles"] / (recorded["clock_mhz"] * 1e6 / 1000), abs=0.005)
    for mine, theirs in (("sense", "sense_tick"), ("sense_init", "sense_init")):
        for key in ("instructions", "cycles", "stack_bytes"):
            assert MEASURED[mine][key] == recorded[theirs][key], (mine, key)
        assert MEASURED[mine]["share_percent"] == pytest.approx(
            100 * recorded[theirs]["cycles"] / (recorded["clock_mhz"] * 1e6 / 1000), abs=0.005)


def _sampled_loop_growth(op, rate: float, delay: int) -> float:
    """The largest |z| of the spec design's sampled loop on the reduced linearisation at
    ``rate`` Hz with ``delay`` ticks: python-control's c2d (ZOH) of (A_r, B_g), the commands
    in flight as states, w[k] = -K x[k - delay] (an independent assembly of the loop)."""
    import control as ct

    from maglevgen.control.operating import N_AXES, REDUCED_INDEX

    A, B = op.reduced
    K_pos, K_rate = op.gains("spec")
    K = K_pos @ np.eye(N_AXES, len(REDUCED_INDEX)) + K_rate @ op.rate_map
    d = ct.c2d(ct.ss(A, B, np.eye(A.shape[0]), 0), 1.0 / rate, "zoh")
    n, m = A.shape[0], B.shape[1]
    N = n + delay * m
    M = np.zeros((N, N))
    M[:n, :n] = d.A
    if delay == 0:
        M[:n, :n] -= d.B @ K
    else:
        M[:n, n + (delay - 1) * m:] = d.B  # the oldest command applied
        M[n:n + m, :n] = -K  # the newest computed
        for j in range(1, delay):
            M[n + j * m:n + (j + 1) * m, n + (j - 1) * m:n + j * m] = np.eye(m)
    return float(np.max(np.abs(np.linalg.eigvals(M))))


@pytest.mark.slow
def test_firmware_verifies_before_it_writes(carriage: DerivedCarriage, sim_lib, tmp_path: Path,
                                            capsys) -> None:
    """`maglevgen firmware` runs `build`'s check first: at a 50 Hz tick the spec design's
    sampled loop is unstable (python-control's c2d of the linearisation with the delay, at
    some speed of the envelope), so the command exits 3 with one line naming the failure and
    writes nothing; with --allow-unstable it writes the folder, whose README and manifest
    carry the failed verdict. The default carriage's folder says verified, the spec, the
    model and the range."""
    from maglevgen.cli import main

    v_min, v_max = Plant(carriage, sim_lib).speed_range
    ops = Plant(carriage, sim_lib).points(np.linspace(v_min, v_max, 5))
    delay = carriage.params.control.spec.delay_ticks
    assert max(_sampled_loop_growth(op, 50.0, delay) for op in ops) > 1.0
    assert max(_sampled_loop_growth(op, 1000.0, delay) for op in ops) < 1.0

    out = tmp_path / "fw50"
    capsys.readouterr()
    assert main(["firmware", "--set", "control.spec.tick_rate=50", "--out", str(out)]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert not out.exists()
    # progress lines (a cold cache's derivations) may precede it; the error is one line
    errors = [ln for ln in err if ln.startswith("maglevgen: error")]
    assert errors == err[-1:] and "verification failed" in err[-1]
    assert "nothing written" in err[-1]
    assert main(["firmware", "--set", "control.spec.tick_rate=50", "--allow-unstable",
                 "--out", str(out)]) == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["verification"]["verified"] is False
    assert "NOT VERIFIED" in (out / "README.md").read_text()

    good = tmp_path / "fw"
    assert main(["firmware", "--out", str(good)]) == 0
    ver = json.loads((good / "manifest.json").read_text())["verification"]
    assert ver["verified"] is True and ver["spec"] == "[control.spec]"
    assert ver["range_m_per_s"] == pytest.approx([v_min, v_max], rel=1e-12)
    assert f"**Verdict**: {ver['verdict']}." in (good / "README.md").read_text()


# ------------------------------------------------------------- the folder's own checks


@pytest.fixture(scope="module")
def qemu_folder(firmware, carriage: DerivedCarriage, tmp_path_factory) -> Path:
    """`maglevgen firmware --with-plant`'s folder (single precision): it carries run_qemu.sh."""
    from maglevgen.exports.firmware import MEASURED, render_firmware

    folder = tmp_path_factory.mktemp("firmware_qemu")
    write_output(render_firmware(carriage, firmware["table"], firmware["loop"], "single", True,
                                 MEASURED), folder)
    return folder


@pytest.fixture(scope="module")
def qemu_sense_folder(firmware, carriage: DerivedCarriage, sim_lib, tmp_path_factory) -> Path:
    """The same with the sense tick (sense_schedule): its run_qemu.sh flies both ticks."""
    from maglevgen.exports.firmware import MEASURED, render_firmware, sense_schedule

    sense = sense_schedule(Plant(carriage, sim_lib), *Plant(carriage, sim_lib).speed_range,
                           firmware["loop"])
    assert sense is not None
    folder = tmp_path_factory.mktemp("firmware_qemu_sense")
    write_output(render_firmware(carriage, firmware["table"], firmware["loop"], "single", True,
                                 MEASURED, sense=sense), folder)
    return folder


def test_run_qemu_says_which_tool_is_missing(qemu_folder: Path, tmp_path: Path) -> None:
    """Without the cross-compiler on PATH the script runs nothing: one line naming the tool,
    exit 77 (automake's "skipped")."""
    import shutil
    import subprocess

    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for tool in ("dirname", "mkdir"):
        (bin_dir / tool).symlink_to(shutil.which(tool))
    run = subprocess.run([shutil.which("sh"), "run_qemu.sh"], cwd=qemu_folder,
                         env={"PATH": str(bin_dir)}, capture_output=True, text=True)
    assert run.returncode == 77, run.stdout + run.stderr
    lines = run.stdout.splitlines()
    assert len(lines) == 1 and "arm-none-eabi-gcc not found" in lines[0], lines
    assert not (qemu_folder / "qemu_build").exists()


@pytest.mark.slow
@pytest.mark.needs_arm("qemu-system-arm")
def test_run_qemu_runs_the_closed_loop_and_counts_a_tick(qemu_sense_folder: Path, firmware,
                                                        tmp_path: Path) -> None:
    """`sh run_qemu.sh` in the folder: the closed loop's line (the tick rate of the firmware
    loop, its ticks), a result that agrees with the heave it prints (settled: within 5 % of
    the 1 mm start); the same for maglev_sense_tick on the plant's readings (seeded noise: its
    every tick MAGLEV_OK, settled too); and one tick's instructions within 10 % of
    bench/firmware_tick.py's recorded count (its own driver, bench/c/bench_tick.c, a state
    1 mm / 1 mrad off)."""
    import shutil
    import subprocess

    from maglevgen.exports.firmware import MEASURED, QEMU_TICKS

    folder = tmp_path / "fw"
    shutil.copytree(qemu_sense_folder, folder)
    run = subprocess.run(["sh", "run_qemu.sh"], cwd=folder, capture_output=True, text=True,
                         timeout=600)
    assert run.returncode == 0, run.stdout + run.stderr
    out = run.stdout
    loop = re.search(r"(\d+) ticks at (\d+) Hz.*heave deviation at the end: (-?\d+) um", out)
    assert loop, out
    assert int(loop[1]) == QEMU_TICKS and int(loop[2]) == round(firmware["loop"].tick_rate)
    settled = abs(int(loop[3])) < 50
    assert ("result: settled" in out) == settled and settled, out
    sensed = re.search(r"sense tick on the plant's readings \((\d+) readings, seeded noise\): "
                       r"(\d+) ticks; heave deviation at the end: (-?\d+) um", out)
    assert sensed, out
    assert int(sensed[2]) == QEMU_TICKS and abs(int(sensed[3])) < 50, out
    assert "result (sense tick): settled" in out, out
    per_tick = int(re.search(r"per tick: (\d+) instructions", out)[1])
    assert abs(per_tick / MEASURED["instructions"] - 1) < 0.1, (per_tick, MEASURED)


@pytest.mark.needs_cc
def test_the_host_example_prints_what_it_runs(firmware, tmp_path: Path) -> None:
    """main.c built for a host as the folder's CMake does (MAGLEV_HOST_EXAMPLE): it says how
    many ticks of which controller it runs (the numbers of its own defines and of
    maglev_tick.h) and how they ended, and exits 0."""
    import subprocess

    src = firmware["folders"]["double"]
    exe = tmp_path / "example"
    subprocess.run(["gcc", "-std=c99", "-DMAGLEV_HOST_EXAMPLE", "-I", str(src),
                    *(str(src / f) for f in ("main.c", "maglev_tick.c", "maglev_gain_table.c",
                                             "maglev_functions.c")), "-lm", "-o", str(exe)],
                   check=True, capture_output=True, text=True)
    run = subprocess.run([str(exe)], capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stdout + run.stderr
    ticks = re.search(r"#define MAGLEV_EXAMPLE_TICKS (\d+)", (src / "main.c").read_text())[1]
    rate = re.search(r"#define MAGLEV_TICK_RATE \(?([0-9.]+)", (src / "maglev_tick.h")
                     .read_text())[1]
    lines = run.stdout.splitlines()
    assert lines[0].startswith(f"maglev_firmware_example: {ticks} ticks of maglev_tick"), lines
    assert f"{float(rate):g} Hz" in lines[0], (lines[0], rate)
    assert lines[-1].endswith("every tick returned MAGLEV_OK (exit 0)"), lines
