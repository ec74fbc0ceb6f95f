"""`maglevgen build`: the main job, its cache and stamp, atomic output, bad input.

Every bad-input case runs against a folder holding a good build and checks that the build
fails with one line and exit 2, and leaves that folder byte for byte as it was, with no
temporary folders beside it.
"""

from __future__ import annotations

import hashlib
import hmac
import importlib
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from independent_reference import (
    array_loads,
    contact_gaps,
    generalized_mass,
    ise_optimal_damping,
    lqr_reference_mp,
    reference_trim,
    rigid_body_xdot,
    rotation,
    stiffness_fd,
)
from test_params_cli import BAD, edited, write_input

from maglevgen.build import STAMP, BuildOptions, run_build, up_to_date
from maglevgen.cli import main
from maglevgen.control.carriage_plant import Plant
from maglevgen.infrastructure.cache import key_file
from maglevgen.infrastructure.output import MARKER
from maglevgen.params import load_params

FAST = ["--t-end", "1", "--no-pdf"]


def assert_one_line_error(rc: int, out: str, err: str, expected: list[str]) -> None:
    """Exit 2, nothing on stdout, the error on one line (after any progress lines)."""
    assert rc == 2, err
    assert out == "" and "Traceback" not in err
    *progress, line = err.splitlines()
    assert line.startswith("maglevgen: error: "), err
    assert all(p.startswith("maglevgen: ") and "error" not in p for p in progress), err
    for s in expected:
        assert s in line, f"{s!r} not in {line!r}"


def tree(folder: Path) -> dict[str, str]:
    """Relative path -> sha256 of every file below ``folder``."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def siblings(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.parent.iterdir())


@pytest.fixture(scope="module")
def good(tmp_path_factory, default_build, sim_lib) -> Path:
    """A folder holding a complete build of the default carriage (this module's copy)."""
    return Path(shutil.copytree(default_build, tmp_path_factory.mktemp("build") / "out"))


def test_build_writes_every_stage_and_a_consistent_stamp(good: Path, carriage) -> None:
    names = set(tree(good))
    for expected in ("c/maglev_functions.c", "c/maglev_simulate.c", "c/maglev.h",
                     "c/manifest.json", "c/main.c", "lib/libmaglev.so",
                     "simulation/metrics.md", "simulation/levitation_pitch.png",
                     "report/report.tex", "SUMMARY.md", STAMP):
        assert expected in names, expected
    stamp = json.loads((good / STAMP).read_text())
    # every file but the stamp itself and the output marker (the list of what was written)
    assert set(stamp["files"]) == names - {STAMP, MARKER}
    assert json.loads((good / MARKER).read_text())["files"] == sorted(names - {MARKER})
    assert all(tree(good)[n] == d for n, d in stamp["files"].items())
    manifest = json.loads((good / "c/manifest.json").read_text())
    assert [p["value"] for p in manifest["parameter_vector"]] == list(carriage.p)


def _tex_number(text: str) -> float:
    """A number as the report prints it (maglevgen.report.format.fnum): 1.5, 1.5 \\times 10^{-4}."""
    m = re.fullmatch(r"\s*(-?[\d.]+)(?: \\times 10\^\{(-?\d+)\})?\s*", text)
    assert m, text
    return float(m.group(1)) * 10.0 ** int(m.group(2) or 0)


def test_gain_table_error_is_the_manifests_and_reproduced(good: Path, carriage,
                                                          sim_lib) -> None:
    """The firmware table's worst relative error: the report prints c/manifest.json's value
    (to its six digits), and that value is reproduced here on the manifest's dense grid: the
    built table (c/maglev_gain_table.c compiled in double) against the exact schedule computed
    in this test, the Newton trim and plants of the C with the per-axis LQR from
    python-control's lqr and the damping from the numerical ISE minimum
    (tests/independent_reference.py); each field's error relative to its largest magnitude.
    The embedded controller's fields (K_pos, K_rate, K_lag, K_delay: its design at the tick)
    against the design the table interpolates, evaluated at each speed
    (envelope.tick_table_rows); that design is checked against control.dlqr on a model built
    independently in tests/test_tick_state.py."""
    import ctypes
    import math

    import control
    from independent_reference import ise_optimal_damping

    from maglevgen.control.schedule import tick_table_fields
    from maglevgen.derive import conventions as cv
    from maglevgen.runtime.compile import compile_shared

    gt = json.loads((good / "c/manifest.json").read_text())["gain_table"]
    tex = (good / "report/report.tex").read_text()
    m = re.search(r"worst error relative to each field's largest magnitude is\s*\$([^$]+)\$",
                  tex)
    assert m, "the report does not state the table's error"
    assert math.isclose(_tex_number(m.group(1)), float(f"{gt['worst_relative_error']:.6g}"),
                        rel_tol=1e-12)

    lib_c = compile_shared([good / "c/maglev_gain_table.c"], cache_dir=good.parent / "gt",
                           flags=("-std=c99", "-O2", "-fPIC", "-shared"))  # c/'s: double
    schedule = ctypes.CDLL(str(lib_c)).maglev_schedule
    schedule.argtypes = [ctypes.c_double, ctypes.POINTER(ctypes.c_double)]
    fields = (("F_prop", 1), ("a_ref", 5), ("K", 10), ("c_damping", 5))
    p = carriage.p
    (q1, q2), r = carriage.params.control.state_weights, carriage.params.control.input_weight
    axes = [cv.STATE_INDEX[a] for a in ("y", "z", "phi", "theta", "psi")]
    # the table's length from its header: the tick design's fields follow the four above
    nout = int(re.search(r"#define MAGLEV_SCHEDULE_NOUT (\d+)",
                         (good / "c/maglev_gain_table.h").read_text()).group(1))
    speeds = np.linspace(gt["v_min"], gt["v_max"], gt["dense_grid"])
    table, exact = [], []
    for v in speeds:
        out = (ctypes.c_double * nout)()
        assert schedule(v, out) == 0
        table.append(np.array(out[:]))
        x, f_prop = (np.ravel(a) for a in sim_lib.function("maglev_trim")(v, p))
        k, mass = (np.ravel(a) for a in sim_lib.function("maglev_axis_plants")(v, p))
        K = np.array([control.lqr([[0, 1], [-k[i] / mass[i], 0]], [[0], [1 / mass[i]]],
                                  np.diag([q1, q2]), [[r]])[0].ravel() for i in range(5)])
        # no damping gain on an axis without restoring stiffness (maglev.h: c = 0 where k <= 0)
        c = [ise_optimal_damping(k[i], mass[i]) if k[i] > 0 else 0.0 for i in range(5)]
        exact.append(np.concatenate([f_prop, x[axes], K.ravel(order="F"), c]))
    assert carriage.params.envelope.embedded_controller == "spec"
    setting = Plant(carriage, sim_lib).loop
    tick_fields = tick_table_fields(setting.tick.delay)
    assert tick_fields[:4] == fields and sum(n for _, n in tick_fields) == nout
    n_first = sum(n for _, n in fields)
    design = Plant(carriage, sim_lib).tick_table_rows(setting, speeds)[:, n_first:]
    exact = [np.concatenate([e, d]) for e, d in zip(exact, design, strict=True)]
    fields = tick_fields
    table, exact = np.array(table), np.array(exact)
    errors, i = {}, 0
    for name, n in fields:
        errors[name] = (np.max(np.abs(table[:, i:i + n] - exact[:, i:i + n]))
                        / np.max(np.abs(exact[:, i:i + n])))
        i += n
    # to 1e-3 of each error, or 1e-4 of the bound where an error is far below it (there the
    # two damping references' own differences, ~1e-8, are a visible part of the error)
    for name, value in errors.items():
        assert math.isclose(value, gt["relative_error_by_field"][name], rel_tol=1e-3,
                            abs_tol=1e-4 * gt["bound"]), \
            (name, value, gt["relative_error_by_field"][name])
    assert math.isclose(max(errors.values()), gt["worst_relative_error"], rel_tol=1e-3)
    assert gt["worst_relative_error"] <= gt["bound"]


def _paper_stiffness(prm, lift: np.ndarray) -> np.ndarray:
    """The printed eqs 7 and 13-16 with the reference trim's array forces and the geometry."""
    arrays = list(prm.arrays.values())
    upper = [i for i, a in enumerate(arrays) if abs(a.normal[2]) > 1 - 1e-9]
    lower = [i for i in range(len(arrays)) if i not in upper]
    F = np.mean([lift[i] * abs(arrays[i].normal[1]) for i in lower])  # F_bncd_y
    F_up = np.mean(lift[upper])
    k = 2 * np.pi / prm.halbach.wavelength
    Lz = np.mean([abs(arrays[i].position[2]) for i in lower])
    Lx = np.mean([abs(arrays[i].position[0]) for i in upper])
    Lxla = np.mean([abs(arrays[i].position[0]) for i in lower])
    return np.array([8 * F * k, 2 * prm.vehicle.mass * prm.vehicle.gravity * k,
                     8 * F * k * Lz**2, 0.12 * F_up * k * Lx**2, 8 * F * k * Lxla**2])


def _magnetic_damping_reference(prm, ref, mass: np.ndarray) -> np.ndarray:
    """-m_i d(rate_i')/d(rate_i) of the circuit-by-circuit force sum with the circuits' lag
    (independent_reference.array_loads) and eqs 1-2, central differences at the reference
    trim, for the axis body rates v, w, p, q, r."""
    x = np.zeros(12)
    x[1:6] = ref.q
    x[6:9] = rotation(*ref.q[2:5]).T @ np.array([prm.operation.speed, 0.0, 0.0])
    out = []
    for i, j in enumerate((7, 8, 9, 10, 11)):
        e = np.zeros(12)
        e[j] = 1e-6
        plus, minus = (rigid_body_xdot(prm, y, array_loads(prm, y, lag=True)[2], ref.f_prop)
                       for y in (x + e, x - e))
        out.append(-mass[i] * (plus[j] - minus[j]) / 2e-6)
    return np.array(out)


def test_summary_numbers_match_independent_computations(good: Path, carriage) -> None:
    """Every number of SUMMARY.md, row by row, against tests/independent_reference.py: the trim
    (root of eq 3 and the static balance), stiffness (central differences), inertia (parallel
    axes), f_n, the LQR gain (hand-solved ARE, mpmath), the ISE-optimal damping (numerical
    minimum), the magnetic damping of the circuits' lag (central differences of the lagged
    circuit sum) and the printed stiffness of eqs 7, 13-16 with its difference from the
    derived."""
    prm = carriage.params
    v = prm.operation.speed
    ref = reference_trim(prm, v)
    lines = (good / "SUMMARY.md").read_text().splitlines()
    (trim_line,) = [ln for ln in lines if ln.startswith("Trim at ")]
    m = re.fullmatch(r"Trim at (\S+) m/s: heave (\S+) mm, pitch (\S+) mrad, F_prop (\S+) N; "
                     r"closest-corner gap per array: (.+) \(track.min_gap (\S+) mm\)\.", trim_line)
    assert m, trim_line
    speed, heave, pitch, f_prop, gaps, min_gap = m.groups()
    assert float(speed) == v and float(min_gap) == pytest.approx(prm.track.min_gap * 1e3)
    assert float(heave) == pytest.approx(ref.q[1] * 1e3, abs=1e-4)
    assert float(pitch) == pytest.approx(ref.q[3] * 1e3, abs=1e-4)
    assert float(f_prop) == pytest.approx(ref.f_prop, rel=1e-3)
    named = [re.fullmatch(r"(\S+) (\S+) mm", g) for g in gaps.split(", ")]
    assert all(named), gaps
    assert [g[1] for g in named] == list(prm.arrays)  # each gap by its array's name
    np.testing.assert_allclose([float(g[2]) for g in named], contact_gaps(prm, ref.q) * 1e3,
                               rtol=0, atol=6e-4)
    # the accelerating trim at v_min: the root with the d'Alembert load -m a at the CG
    (acc_line,) = [ln for ln in lines if ln.startswith("Accelerating trim at ")]
    m = re.fullmatch(r"Accelerating trim at (\S+) m/s and (\S+) m/s\^2 \(the launch's "
                     r"reference\): pitch (\S+) mrad \((\S+) mrad from the constant-speed "
                     r"trim\), smallest corner gap (\S+) mm \(array (\S+); (\S+) mm at "
                     r"constant speed; track.min_gap (\S+) mm\), F_prop (\S+) N\.", acc_line)
    assert m, acc_line
    v_lo, a, pitch_a, offset, gap_a, array, gap_0, _, f_prop_a = m.groups()
    assert float(a) == prm.envelope.launch_acceleration
    v_lo = float(v_lo)
    ref_a, ref_0 = (reference_trim(prm, v_lo, acc) for acc in (float(a), 0.0))
    assert float(pitch_a) == pytest.approx(ref_a.q[3] * 1e3, abs=2e-3)  # printed to 4 digits
    assert float(offset) == pytest.approx((ref_a.q[3] - ref_0.q[3]) * 1e3, abs=2e-3)
    gaps_a = contact_gaps(prm, ref_a.q)
    assert float(gap_a) == pytest.approx(gaps_a.min() * 1e3, abs=2e-3)
    assert array == list(prm.arrays)[int(np.argmin(gaps_a))]
    assert float(gap_0) == pytest.approx(contact_gaps(prm, ref_0.q).min() * 1e3, abs=2e-3)
    assert float(f_prop_a) == pytest.approx(ref_a.f_prop, rel=1e-3)
    k_tot = np.diag(stiffness_fd(prm, ref.q, v, ref.f_prop))
    k_mag = np.diag(stiffness_fd(prm, ref.q, v, ref.f_prop, other=False))
    mass = generalized_mass(prm)
    paper = _paper_stiffness(prm, ref.arrays.lift)
    assert prm.model.circuit_dynamics == "first-order"
    c_mag = _magnetic_damping_reference(prm, ref, mass)
    axes = ("lateral", "vertical", "roll", "pitch", "yaw")
    units = {"k": ("N/m", "N m/rad"), "m": ("kg", "kg m^2"), "c": ("N s/m", "N m s/rad")}

    # four tables: stiffness (translation, rotation), then gains (translation, rotation),
    # each row axis -> {column header: cell}
    starts = [i for i, ln in enumerate(lines)
              if ln.startswith(("| translation axis |", "| rotation axis |"))]
    assert len(starts) == 4, starts
    tables = []
    for at in starts:
        head = [c.strip() for c in lines[at].strip("|").split("|")][1:]
        rows_ = {}
        for row in lines[at + 2:]:
            if not row.startswith("|"):
                break
            cells = [c.strip() for c in row.strip("|").split("|")]
            rows_[cells[0]] = dict(zip(head, cells[1:], strict=True))
        tables.append(rows_)
    stiff, gains = {**tables[0], **tables[1]}, {**tables[2], **tables[3]}
    assert list(stiff) == list(axes) and list(gains) == list(axes)
    for i, axis in enumerate(axes):
        rot = int(i >= 2)
        uk, um, uc = units["k"][rot], units["m"][rot], units["c"][rot]
        s_row, g_row = stiff[axis], gains[axis]
        assert list(s_row) == [f"K_st0 [{uk}]", f"paper, printed [{uk}]", "paper / K_st0 - 1",
                               f"k [{uk}]", f"m [{um}]", "f_n [Hz]"], s_row
        assert list(g_row) == [f"K1 [{uk}]", f"K2 [{uc}]", f"damping c [{uc}]",
                               f"magnetic c_mag [{uc}]"], g_row
        K_st0, printed, rel, k_plant, m_axis, fn_txt = s_row.values()
        assert float(K_st0) == pytest.approx(k_mag[i], rel=1e-4)
        assert float(printed) == pytest.approx(paper[i], rel=1e-4)
        # the percentage is against the K_st0 beside it
        pct = re.fullmatch(r"([+-]\d+\.\d)%", rel)
        assert pct, rel
        assert float(pct[1]) == pytest.approx(100 * (paper[i] - k_mag[i]) / k_mag[i], abs=0.051)
        assert float(k_plant) == pytest.approx(k_tot[i], rel=1e-4)
        assert float(m_axis) == pytest.approx(mass[i], rel=1e-3)
        fn = np.sqrt(max(k_tot[i], 0.0) / mass[i]) / (2 * np.pi)
        assert float(fn_txt) == pytest.approx(fn, abs=6e-4)
        K1, K2, c_txt, c_mag_txt = (float(x) for x in g_row.values())
        K_ref, _ = lqr_reference_mp(k_tot[i], mass[i])
        np.testing.assert_allclose([K1, K2], [float(x) for x in K_ref], rtol=1e-3)
        assert c_mag_txt == pytest.approx(c_mag[i], rel=1e-3, abs=1e-6)
        c_ref = ise_optimal_damping(k_tot[i], mass[i]) if k_tot[i] > 0 else 0.0
        assert c_txt == pytest.approx(c_ref, rel=1e-3)
    # the header names the parameter file; no override in this build
    # (Markdown: the name's punctuation backslash-escaped, CommonMark's rule undoes it)
    heading = re.sub(r"\\([!-/:-@\[-`{-~])", r"\1", lines[0])
    assert heading == f"# maglevgen build: {carriage.loaded.source}"
    assert f"Parameter file: `{carriage.loaded.source}`" in lines[2]
    assert lines[2].endswith("overrides: none.")


def test_unchanged_rebuild_regenerates_nothing(good: Path, capsys) -> None:
    before = tree(good)
    mtimes = {p: p.stat().st_mtime_ns for p in good.rglob("*")}
    assert main(["build", "--out", str(good), *FAST]) == 0
    out = capsys.readouterr().out
    # the count is the files on disk, as the build that wrote them said ("wrote N files")
    assert f"is up to date ({len(before)} files; nothing regenerated;" in out, out
    # and the verdicts, as SUMMARY.md says them (its lines up to the outputs' list)
    summary = (good / "SUMMARY.md").read_text()
    verdicts = [t for t in summary.split("\nOutputs:")[0].splitlines() if t.startswith("- ")]
    assert verdicts and all(t in out.splitlines() for t in verdicts), out
    assert tree(good) == before
    assert {p: p.stat().st_mtime_ns for p in good.rglob("*")} == mtimes


@pytest.mark.slow  # a whole build of its own
def test_a_tampered_output_is_rebuilt(fresh_build: Path) -> None:
    out = fresh_build
    ref = tree(out)
    (out / "c" / "maglev.h").write_text("tampered\n")
    key = json.loads((out / STAMP).read_text())["key"]
    assert not up_to_date(out, key)
    assert main(["build", "--out", str(out), *FAST]) == 0
    assert tree(out) == ref


@pytest.mark.slow  # a whole build of its own
def test_parameter_change_rebuilds_without_rederiving_or_recompiling(
        good: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "heavy"
    # the hold speed 6 m/s lies below the envelope's v_min (1.6 x lift-off, about 7 m/s); the
    # worst sign of the default disturbance starts that hold inside the 3 mm gap margin, so the
    # build exits 3 and still writes every output
    assert main(["build", "--out", str(out), *FAST, "--set", "vehicle.mass=9.5",
                 "--set", "operation.speed=6.0"]) == 3
    err = capsys.readouterr().err
    assert "deriving" not in err and "compiling" not in err
    # one warning line for the speed outside the envelope, and SUMMARY.md names every
    # override and says the same
    env = json.loads((out / "envelope/envelope.json").read_text())
    warnings = [ln for ln in err.splitlines() if ln.startswith("maglevgen: warning: ")]
    assert len(warnings) == 1 and "operation.speed = 6 m/s is outside the envelope" in \
        warnings[0], err
    assert env["v_min"] > 6.0, env["v_min"]  # the reference: the envelope's own range
    summary = (out / "SUMMARY.md").read_text().splitlines()
    assert summary[2].endswith("overrides: `--set vehicle.mass=9.5`, "
                               "`--set operation.speed=6.0`."), summary[2]
    assert summary[4] == "Warning: " + warnings[0].removeprefix("maglevgen: warning: ") + "."
    manifest = json.loads((out / "c/manifest.json").read_text())
    mass = next(p for p in manifest["parameter_vector"] if p["name"] == "vehicle.mass")
    assert mass["value"] == 9.5
    # the parameter-independent C is identical, the parameter-dependent header is not
    assert (out / "c/maglev_functions.c").read_bytes() == \
        (good / "c/maglev_functions.c").read_bytes()
    assert (out / "c/maglev.h").read_bytes() != (good / "c/maglev.h").read_bytes()


# ---------------------------------------------------------------------------- bad input


def _assert_untouched(good: Path, before: dict[str, str], names: list[str]) -> None:
    assert tree(good) == before
    assert siblings(good) == names


@pytest.mark.parametrize(("text", "extra", "expected"),
                         [c[1:] for c in BAD if "--params" not in c[2]],
                         ids=[c[0] for c in BAD if "--params" not in c[2]])
def test_bad_parameters_leave_the_good_build(good: Path, tmp_path: Path, capsys, text,
                                             extra, expected) -> None:
    before, names = tree(good), siblings(good)
    path = write_input(tmp_path, text)
    rc = main(["build", "--out", str(good), *FAST, "--params", str(path), *extra])
    out, err = capsys.readouterr()
    assert_one_line_error(rc, out, err, expected)
    _assert_untouched(good, before, names)


@pytest.mark.parametrize(("argv", "expected"), [
    (["--set", "operation.speed=2.0"], ["no trim at 2 m/s"]),
    (["--set", "arrays.3.nominal_gap=0.001"], ["arrays.3.nominal_gap", "track.min_gap"]),
    (["--set", "vehicle.mass=0"], ["vehicle.mass = 0"]),
    (["--dt", "0.2"], ["--dt 0.2 s exceeds the RK4 stability limit"]),
], ids=["no-trim", "gap-below-track-limit", "zero-mass", "dt-above-rk4-limit"])
def test_bad_operating_inputs_leave_the_good_build(good: Path, capsys, argv, expected) -> None:
    before, names = tree(good), siblings(good)
    rc = main(["build", "--out", str(good), *FAST, *argv])
    out, err = capsys.readouterr()
    assert_one_line_error(rc, out, err, expected)
    _assert_untouched(good, before, names)


def test_inertia_not_positive_definite(good: Path, tmp_path: Path, capsys) -> None:
    before, names = tree(good), siblings(good)
    path = write_input(tmp_path, edited("vehicle.inertia_cg", {
        "xx": 0.01, "yy": 0.01, "zz": 1.0, "xy": 0.0, "xz": 0.0, "yz": 0.0}))
    rc = main(["build", "--out", str(good), *FAST, "--params", str(path)])
    out, err = capsys.readouterr()
    assert_one_line_error(rc, out, err, ["vehicle.inertia_cg"])
    _assert_untouched(good, before, names)


def test_missing_compiler(good: Path, monkeypatch, capsys) -> None:
    before, names = tree(good), siblings(good)
    monkeypatch.setenv("CC", "no-such-compiler")
    rc = main(["build", "--out", str(good), *FAST, "--set", "vehicle.mass=9.4"])
    out, err = capsys.readouterr()
    assert_one_line_error(rc, out, err, ["C compiler 'no-such-compiler' not found"])
    _assert_untouched(good, before, names)


def test_unwritable_output_folder(tmp_path: Path, capsys) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("x")
    rc = main(["build", "--out", str(blocker / "out"), *FAST])
    out, err = capsys.readouterr()
    assert_one_line_error(rc, out, err, ["cannot write to", "a-file"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a-file"]


def _broken(*_a, **_k) -> None:
    """A stage that fails (module level: a job sent to a child process is pickled)."""
    raise RuntimeError("simulated failure")


@pytest.mark.slow  # a whole build up to the failing stage, four times
@pytest.mark.parametrize(("module", "stage", "expected"), [
    ("maglevgen.build", "_report_files",
     "maglevgen: internal error: RuntimeError: simulated failure (rerun with --debug)"),
    # figures and trajectories: the jobs of a forked child (maglevgen.background)
    ("maglevgen.analyses.sim_output", "render_figures",
     "maglevgen: error: drawing the figures failed: RuntimeError: simulated failure"),
    ("maglevgen.report.figures", "force_figures",
     "maglevgen: error: drawing the report figures failed: RuntimeError: simulated failure"),
    ("maglevgen.analyses.sim_output", "render_trajectories",
     "maglevgen: error: writing the trajectories failed: RuntimeError: simulated failure"),
], ids=["report-stage", "child-first-job", "child-second-job", "child-third-job"])
def test_internal_failure_is_exit_1_and_leaves_the_good_build(good: Path, monkeypatch, capsys,
                                                              module: str, stage: str,
                                                              expected: str) -> None:
    before, names = tree(good), siblings(good)
    monkeypatch.setattr(importlib.import_module(module), stage, _broken)
    rc = main(["build", "--out", str(good), *FAST, "--set", "vehicle.mass=9.3001"])
    out, err = capsys.readouterr()
    assert rc == 1 and out == "" and "Traceback" not in err
    assert err.splitlines()[-1] == expected, err
    _assert_untouched(good, before, names)


def test_background_rendering_gives_the_files_of_an_in_process_run(good: Path, tmp_path: Path,
                                                                   sim_lib) -> None:
    """The build's simulation files (trajectories and figures written by a child while the
    report is built) equal `maglevgen simulate`'s, byte for byte."""
    sim = tmp_path / "sim"
    assert main(["simulate", "--out", str(sim), "--t-end", "1"]) == 0
    built = {n.removeprefix("simulation/"): d for n, d in tree(good).items()
             if n.startswith("simulation/")}
    alone = tree(sim)
    alone.pop(MARKER)  # the folder's own marker (the build keeps one at its root)
    for name in ("metrics.json", "metrics.md"):  # their headers name the command
        built.pop(name), alone.pop(name)
    assert built == alone


def _clear_in_process_derivations() -> None:
    """Drop the in-process results, so that the next build reads the disk store."""
    from maglevgen.derive import linearize, numeric, riccati

    for fn in (numeric.model_functions, numeric.lambdified_parts, linearize.stiffness_form,
               riccati._generic_closed_form,
               riccati._generic_stable_form, riccati._numpy_functions):
        fn.cache_clear()


@pytest.mark.slow
def test_corrupted_cache_entries_are_detected_and_rebuilt(tmp_path: Path, carriage, monkeypatch,
                                                          seeded_cache) -> None:
    """Every cache entry the carriage's own model comes from (its generated C, its compiled
    library, each derivation step this process reads) corrupted at once: each is detected,
    rebuilt, and the output is the same. (The other models' libraries are read through the
    same checks; rebuilding them too would triple the cost and test nothing more.)"""
    from maglevgen.infrastructure.cache import STORE
    from maglevgen.runtime.library import cached_simulation_library, runtime_sources

    cache = Path(seeded_cache)
    monkeypatch.setenv("MAGLEVGEN_CACHE", str(cache))
    log = tmp_path / "read.txt"  # a file: the build's forked children read the store too
    real_get = STORE.get

    def recording_get(module: str, key: str):
        with log.open("a") as f:
            f.write(f"{STORE.path(module, key)}\n")
        return real_get(module, key)

    monkeypatch.setattr(STORE, "get", recording_get)
    out = tmp_path / "out"
    loaded = load_params()
    opts = BuildOptions(t_end=1.0, pdf=False)
    _clear_in_process_derivations()
    run_build(loaded, out, opts, step=lambda _m: None)
    ref = tree(out)
    lib = cached_simulation_library(carriage.structure)
    read = [Path(line) for line in log.read_text().splitlines()]
    entries = {f for f in (*read, lib.path, *runtime_sources(carriage.structure).glob("*.c"))
               if f.exists()}
    assert len(entries) >= 8 and all(f.is_relative_to(cache) for f in entries)
    original = {f: f.read_bytes() for f in entries}
    for f, data in original.items():
        # a new truncated file in its place (the loaded library keeps its own pages)
        cut = f.with_name(f.name + ".cut")
        cut.write_bytes(data[: len(data) // 2])
        os.replace(cut, f)
    _clear_in_process_derivations()
    log.write_text("")
    steps: list[str] = []
    shutil_out = tmp_path / "out2"
    run_build(loaded, shutil_out, opts, step=steps.append)
    joined = " ".join(steps)
    assert "deriving the model and generating C" in joined and "compiling" in joined
    assert "deriving model_functions" in joined
    assert tree(shutil_out) == ref
    reread = {Path(line) for line in log.read_text().splitlines()}
    assert reread & set(original)
    for f, data in original.items():  # each entry the rebuild needed written again whole
        now = f.read_bytes()
        if f.suffix == ".pkl":  # the store's layout: the payload's HMAC, then the payload
            assert f not in reread or now[:64] == hmac.new(
                key_file().read_bytes(), now[64:], hashlib.sha256).hexdigest().encode(), f
        else:  # generated C and its compiled library: deterministic
            assert now == data, f


@pytest.mark.slow
def test_concurrent_builds_into_one_folder_end_consistent(tmp_path: Path, good: Path) -> None:
    out = tmp_path / "shared"
    env = {**os.environ}
    procs = [subprocess.Popen([sys.executable, "-m", "maglevgen.cli", "build", "--out",
                               str(out), *FAST, "--set", f"vehicle.mass={m}"], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
             for m in (9.3, 9.6)]
    for p in procs:
        _, err = p.communicate(timeout=600)
        assert p.returncode == 0, err
    stamp = json.loads((out / STAMP).read_text())
    assert tree(out) == {**stamp["files"], STAMP: tree(out)[STAMP], MARKER: tree(out)[MARKER]}
    mass = next(p["value"] for p in json.loads((out / "c/manifest.json").read_text())
                ["parameter_vector"] if p["name"] == "vehicle.mass")
    assert stamp["overrides"] == [f"vehicle.mass={mass}"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shared"]


@pytest.mark.slow  # a whole build of its own
def test_interrupted_build_leaves_the_previous_output(good: Path, monkeypatch) -> None:
    before, names = tree(good), siblings(good)
    from maglevgen.infrastructure import output

    real_write = output.Path.write_bytes
    calls = {"n": 0}

    def interrupt_midway(self, data):
        calls["n"] += 1
        if calls["n"] == 5:
            raise KeyboardInterrupt
        return real_write(self, data)

    monkeypatch.setattr(output.Path, "write_bytes", interrupt_midway)
    with pytest.raises(KeyboardInterrupt):
        run_build(load_params(None, ["vehicle.mass=9.2"]), good,
                  BuildOptions(t_end=1.0, pdf=False), step=lambda _m: None)
    monkeypatch.undo()
    _assert_untouched(good, before, names)


def test_up_to_date_check_is_fast_in_a_fresh_process(good: Path) -> None:
    """Not a timing assert (bench/ measures it): the fresh process must not import the
    derivation stack (sympy, casadi), nor even the parameter schema (pydantic, numpy), to
    decide that nothing needs doing."""
    code = ("import sys, maglevgen.cli as c; rc = c.main(['build', '--out', sys.argv[1], "
            "'--t-end', '1', '--no-pdf']); heavy = [m for m in ('sympy', 'casadi', "
            "'matplotlib', 'control', 'pydantic', 'numpy') if m in sys.modules]; "
            "print(rc, heavy)")
    proc = subprocess.run([sys.executable, "-c", code, str(good)], capture_output=True,
                          text=True, check=True)
    assert proc.stdout.splitlines()[-1] == "0 []", proc.stdout + proc.stderr


def test_report_lists_each_runs_speed_drift_from_the_trajectories(good: Path) -> None:
    """The report's simulation section states the speed drift of every run; the numbers are
    those of the trajectories written beside it (|(u, v, w)| from trajectories.npz)."""
    import re

    tex = (good / "report/report.tex").read_text()
    assert "Under the held propulsion the speed mode (section~\\ref{sec:speed-mode})" in tex
    found = re.findall(r"\\texttt\{(\w+)\}: [^\n]*\\\\\n\\multicolumn\{6\}\{l\}\{\\quad speed "
                       r"\$([-0-9.e]+)\$ to \$([-0-9.e]+)\$", tex)
    npz = np.load(good / "simulation/trajectories.npz")
    cols = [list(npz["columns"]).index(s) for s in ("u", "v", "w")]
    assert {c for c, _, _ in found} == {"none", "damping", "lqr", "coupled", "spec"}
    for controller, start, end in found:
        u = np.linalg.norm(npz[controller][:, cols], axis=1)  # the speed |(u, v, w)|
        assert float(start) == pytest.approx(u[0], rel=1e-5)
        assert float(end) == pytest.approx(u[-1], rel=1e-5)


def test_summary_explains_the_speed_mode_and_the_pitch_form(good: Path, carriage) -> None:
    """SUMMARY.md's speed-mode and pitch lines, parsed, against tests/test_explanations.py's
    references: the pole from root-solved trims at v +- h and from eq 3 at fixed gaps, the
    corrected eq 15 and central differences of the pitch moment."""
    from test_explanations import _references, point_pitch_fd

    prm = carriage.params
    v = prm.operation.speed
    ref = _references(prm, v)
    text = (good / "SUMMARY.md").read_text()
    m = re.search(r"- the speed mode: under the constant trim propulsion the speed is unstable "
                  r"\(12-state pole (\S+) 1/s\); .* = (\S+) 1/s: (\S+) 1/s from the drag law at "
                  r"fixed gaps .* and (\S+) 1/s from the re-trim .*; the (drag law|re-trim) "
                  r"dominates\.", text)
    assert m, text
    eig, trim, fixed, retrim, dominant = m.groups()
    assert float(trim) == pytest.approx(ref["trim"], abs=6e-5)
    assert float(fixed) == pytest.approx(ref["fixed"], abs=6e-5)
    assert float(retrim) == pytest.approx(ref["retrim"], abs=6e-5)
    # the embedded (spec) controller holds the attitude against the re-trim, so its 12-state
    # speed pole lies between the fixed-gap pole and the trim curve's (a weak controller's is
    # the latter: the gaps follow the trim)
    lo, hi = sorted((ref["fixed"], ref["trim"]))
    assert lo - 1e-3 <= float(eig) <= hi + 1e-3, (eig, ref)
    assert dominant == ("drag law" if abs(ref["fixed"]) > abs(ref["retrim"]) else "re-trim")
    tex = (good / "report/report.tex").read_text()
    for row, key in (("speed pole from the trim drag's total slope", "trim"),
                     ("\\quad of which the drag law at fixed gaps", "fixed"),
                     ("\\quad of which the re-trim", "retrim")):
        t = re.search(re.escape(row) + r" & \$([-0-9.]+)\$ & 1/s", tex)
        assert t, row
        assert float(t[1]) == pytest.approx(ref[key], rel=1e-3)
    assert f"The {dominant} dominates." in tex
    p = re.search(r"- pitch \(eq 15\): .* printed (\S+), with the sum .* (\S+), derived (\S+) "
                  r"N m/rad;", text)
    assert p, text
    rt = reference_trim(prm, v)
    K_fd = stiffness_fd(prm, rt.q, v, rt.f_prop, other=False)[3, 3]
    printed, corrected, derived = (float(g) for g in p.groups())
    assert derived == pytest.approx(K_fd, rel=1e-4)
    assert corrected == pytest.approx(point_pitch_fd(prm, rt.q, v, rt.f_prop), rel=5e-3)
    assert abs(printed / K_fd - 1) > 0.5


def test_summary_and_tables_have_no_raw_python_text(good: Path) -> None:
    """SUMMARY.md, simulation/metrics.md and envelope/envelope.md as a person reads them: none
    of the raw forms of tests/readable.py (**, [[, Eq(, sqrt(, " * ", [1], more than 7
    significant digits, round-off noise below 1e-12)."""
    from readable import raw_findings

    found = [f for name in ("SUMMARY.md", "simulation/metrics.md", "envelope/envelope.md")
             for f in raw_findings((good / name).read_text(), name)]
    assert found == [], "\n".join(found)


# ------------------------------------------------------------------------------ the README

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"


def _readme_and_site() -> str:
    """The README and the documentation site's own text (its pages and the guides they
    include): every number either states is checked here."""
    docs = REPO / "docs"
    return "\n\n".join(p.read_text() for p in [README, *sorted(docs.glob("*.rst")),
                                                  *sorted((docs / "_guides").glob("*.md"))])
_NUM_RE = re.compile(r"[-+]?\d+(?:\.\d+)?")


def _numbers(text: str) -> list[float]:
    return [float(x) for x in _NUM_RE.findall(text)]


def _readme_statement(text: str, start: str, end: str = ";") -> str:
    """The README's text from ``start`` to the next ``end`` (flattened to one line)."""
    flat = re.sub(r"\s+", " ", text)
    i = flat.index(start)
    return flat[i:flat.index(end, i + len(start))]


def test_the_readme_states_the_numbers_the_build_prints(good: Path) -> None:
    """Every number the README's "What the default build reports" (and the prose that repeats
    them) states is the one the default build prints: envelope.json's verdicts, SUMMARY.md's
    stiffness differences and accelerating trim, c/manifest.json's gain-table bound. A README
    that goes stale fails here."""
    readme = _readme_and_site()
    env = json.loads((good / "envelope/envelope.json").read_text())
    summary = (good / "SUMMARY.md").read_text()
    flat_summary = re.sub(r"\s+", " ", summary)
    ctl = env["controllers"]

    def printed(name: str) -> list[float]:
        return _numbers(ctl[name]["verdict"] + " " + ctl[name]["spec_verdict"])

    def assert_printed(stated: str, build: list[float]) -> None:
        for x in _numbers(stated):
            assert any(x == pytest.approx(b, rel=1e-9, abs=1e-12) for b in build), \
                f"README states {x:g} ({stated!r}); the build prints {build}"

    rng = _readme_statement(readme, "- envelope [")
    assert _numbers(rng)[:2] == [float(f"{env['v_min']:.4g}"), float(f"{env['v_max']:.4g}")]
    spec = _readme_statement(readme, "- the embedded controller `spec`", "1/s)")
    assert_printed(spec.split("`[control.spec]`)")[1], printed("spec"))
    assert ctl["spec"]["meets_spec"] and ctl["spec"]["stable"] is not False
    designs = _readme_statement(readme, "- the paper's designs fail", "time constant)")
    for name, part in zip(("damping", "lqr", "coupled"),
                          re.split(r"optimized damping|per-axis LQR|coupled LQR", designs)[1:],
                          strict=True):
        stated = re.sub(r"a \d+ s( time constant)?", "", part)
        assert_printed(stated, printed(name))
        assert not ctl[name]["meets_spec"]
    # the time constant is the slowest decay's inverse, rounded
    tau = int(re.search(r"a (\d+) s time constant", re.sub(r"\s+", " ", readme))[1])
    decay = re.search(r"slowest decay (\S+) 1/s", designs)[1]
    assert tau == round(1 / float(decay))
    # the per-axis LQR's unstable range, wherever the README repeats it
    lqr_range = re.search(r"UNSTABLE for v in \[(\S+), (\S+)\]", ctl["lqr"]["verdict"]).groups()
    stated = re.findall(r"per-axis\s+LQR[^.;]*?unstable\s+for\s+v\s+in\s+\[(\S+),\s+(\S+)\]",
                        readme, re.IGNORECASE | re.DOTALL)
    assert len(stated) >= 2 and all(s == lqr_range for s in stated), (stated, lqr_range)
    # the stiffness differences: SUMMARY.md's discrepancy line, the same words
    stiff = _readme_statement(readme, "- the paper's printed stiffnesses (eqs 13-19) differ "
                              "from the derived K_st0 by ", "%.")
    assert len(re.findall(r"(\w+) ([+-]\d+\.\d%)", stiff + "%")) == 5, stiff
    for axis, pct in re.findall(r"(\w+) ([+-]\d+\.\d%)", stiff + "%"):
        assert f"{axis} {pct}" in flat_summary, (axis, pct)
    # the spec verdict where the envelope section repeats it
    again = _readme_statement(readme, "default carriage `spec` meets it across", ";")
    assert_printed(again, printed("spec"))
    # the accelerating trim at v_min (SUMMARY.md's line)
    flat = re.sub(r"\s+", " ", readme)
    pitches = re.findall(r"at 5 m/s\^2 and v_min it pitches (\S+) mrad", flat)
    acc = re.search(r"Accelerating trim at \S+ m/s and (\S+) m/s\^2 .*?\((\S+) mrad from the "
                    r"constant-speed trim\)", summary)
    assert pitches and float(acc[1]) == 5.0
    assert all(float(p) == -float(acc[2]) for p in pitches), (pitches, acc[2])
    # the circuits' characteristic speed R/(kL), stated to 3 digits, wherever it is stated
    printed_vc = re.search(r"characteristic speed (\S+) m/s", summary)[1]
    vcs = re.findall(r"R/\(kL\) = (\d\S*) m/s", flat)
    assert vcs and all(float(vc) == pytest.approx(float(printed_vc), abs=0.006) for vc in vcs)
    # the coupled LQR's damping ratio at the paper's weights, wherever a page repeats it
    ratios = re.findall(r"damps to a ratio of (\S+?)[ ,;)]", flat)
    assert len(ratios) >= 2, ratios
    for r in ratios:
        assert_printed(r, printed("coupled"))
    # the gain table's bound
    table = json.loads((good / "c/manifest.json").read_text())["gain_table"]
    assert "holds its gains to 1e-3 of each matrix's largest entry" in re.sub(r"\s+", " ", readme)
    assert table["bound"] == 1e-3 and table["worst_relative_error"] <= table["bound"]


def test_the_readme_and_the_site_state_one_measurement_of_the_first_build() -> None:
    """The first build's times that the README and the site state are those of the one
    measurement BENCHMARKS.md records (its paragraph naming them), and no page repeats an
    older guess."""
    text = re.sub(r"\s+", " ", _readme_and_site())
    bench = re.sub(r"\s+", " ", (REPO / "BENCHMARKS.md").read_text())
    assert "half a minute" not in text
    stated = re.findall(r"\b(\d+ min \d+ s|\d+(?:\.\d+)? s) (?:of wall-clock|for ``maglevgen "
                        r"build --no-pdf``|wall)", text)
    stated += re.findall(r"(?:empty cache: )(\d+(?:\.\d+)? s)", text)
    assert stated, "no first-build time stated"
    measured = bench[bench.index("from an empty MAGLEVGEN_CACHE"):][:1200]
    for t in stated:
        assert t.replace(" s", "") in measured, (t, measured[:300])
    # and every CPU time stated beside them (user, system), as the measurement gives it
    cpu = re.findall(r"\b(\d+(?:\.\d+)?) s (?:of )?(?:user|system)\b", text)
    assert len(cpu) >= 4, cpu
    for t in cpu:
        assert re.search(rf"\b{re.escape(t)} s (?:user|system)", measured), (t, measured[:300])
    # `make bench`'s duration: the one BENCHMARKS.md's header gives for its last run
    took = re.search(r"the run took (\S+) min", bench)[1]
    said = re.findall(r"`make bench` \([^)]*?(\d+(?:\.\d+)?) min", text)
    assert said == [took], (said, took)

def test_other_structures_are_the_ones_the_envelope_and_the_report_read(carriage) -> None:
    """What a cold build derives and compiles in its second process: the other force law's
    and the other circuit model's structures (the envelope's checks, the stiffness and lag
    sections) and the normal actuators' (the report's comparison), made here the way those
    sections make them, each once and never the carriage's own."""
    from maglevgen.build import other_structures
    from maglevgen.report.sections.actuators import with_actuators

    want = [carriage.with_array_force("point").structure,
            carriage.with_circuit_dynamics("quasi-static").structure,
            with_actuators(carriage, "normal").structure]
    got = other_structures(carriage)
    assert got == want
    assert carriage.structure not in got


def test_the_default_build_judges_the_embedded_runs_and_passes(good: Path, carriage) -> None:
    """The default build's verification covers the embedded controller's runs: SUMMARY.md
    lists its holds at v_min, operation.speed and v_max and its launch, each flown on the
    sensors and meeting the run spec, and BUILD.json records no failure (exit 0, the
    fixture). The v_max hold's lateral peak lies between the least any controller within the
    force budget reaches from the default disturbance (the energy bound of
    `lateral_drift_overshoot` at the reference trim) and the file's allowed deviation; the
    firmware's design is stated."""
    from independent_reference import lateral_drift_overshoot

    from maglevgen.analyses.simulate import DISTURBANCE

    assert json.loads((good / STAMP).read_text())["verification"] is None
    env = json.loads((good / "envelope/envelope.json").read_text())
    summary = (good / "SUMMARY.md").read_text()
    prm = carriage.params
    speeds = sorted({env["v_min"], prm.operation.speed, env["v_max"]})
    # as a carriage flies them: the sense tick on noisy readings
    judged = (" (the firmware's sense tick on noisy readings, worst of 32 disturbance sign "
              "combinations): ")
    for v in speeds:
        assert f"- hold run at {v:.4g} m/s{judged}meets the specification (" in summary, v
    launch = next(ln for ln in summary.splitlines() if ln.startswith("- launch run ("))
    assert f"{judged}meets the specification (" in launch and "FAILS" not in launch
    line = next(ln for ln in summary.splitlines()
                if ln.startswith(f"- hold run at {env['v_max']:.4g} m/s"))
    peak = float(re.search(r"peak lateral deviation (\S+) m", line)[1])
    ref = reference_trim(prm, env["v_max"])
    dev = prm.control.spec.max_deviation
    bound = DISTURBANCE["y"] + lateral_drift_overshoot(
        prm, ref.q, env["v_max"], ref.f_prop, env["v_max"] * np.sin(DISTURBANCE["psi"]),
        np.array([dev.y, dev.z, dev.phi, dev.theta, dev.psi]))
    assert bound * (1 - 1e-3) <= peak <= dev.y
    flat = re.sub(r"\s+", " ", summary)
    assert "design is solved at the tick on the loop as built" in flat
    assert "which meets [control.spec] on the sampled-data loop at 1000 Hz with 1 tick of " \
           "delay and a 2 ms actuator lag" in flat


def test_summary_tables_print_each_column_in_one_notation_and_units_as_written(good: Path
                                                                              ) -> None:
    """Every Markdown table of SUMMARY.md and simulation/metrics.md: a column's numbers all
    plain decimals or all with an exponent (no 0.0002235 above 2.965e-05), and no '*' in a
    unit (Markdown would start emphasis at N*m): units as a person writes them, N m/rad."""
    number = re.compile(r"^[-+]?\d+(?:\.\d+)?(e[-+]\d+)?(?: \S+(?: \S+)?)?$")  # 2.5e-05 m
    for name in ("SUMMARY.md", "simulation/metrics.md"):
        lines = (good / name).read_text().splitlines()
        tables, current = [], []
        for ln in [*lines, ""]:
            if ln.startswith("|"):
                current.append([c.strip() for c in ln.strip().strip("|").split("|")])
            elif current:
                tables.append(current)
                current = []
        assert len(tables) >= 5, name  # SUMMARY: stiffness, gains, region; metrics: a run each
        for table in tables:
            head, rows = table[0], table[2:]
            assert not any("*" in c for r in table for c in r), (name, table)
            for col in range(len(head)):
                kinds = {bool(m.group(1)) for r in rows if (m := number.match(r[col]))
                         and float(r[col].split()[0]) != 0}
                assert len(kinds) <= 1, (name, head[col], [r[col] for r in rows])
    lines = (good / "SUMMARY.md").read_text().splitlines()
    heads = [ln for ln in lines if ln.startswith("| ") and "K1 [" in ln]
    assert [h.split("|")[2].strip() for h in heads] == ["K1 [N/m]", "K1 [N m/rad]"]
