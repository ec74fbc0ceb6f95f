"""`maglevgen report`: the PDF builds cleanly, shows the derived numbers, follows the parameters.

The gains in the PDF are read back with pdftotext and compared with `gains_report` (the data of
`maglevgen gains --json`, computed by python-control and the closed form). TeX-dependent tests
carry ``needs_tex`` (conftest: skipped loudly with the install command when latexmk or
pdftotext is missing, a failure under CI); the report also compiles the generated C to verify
it, so the tests that build one carry ``needs_cc``.
"""

from __future__ import annotations

import itertools
import json
import os
import re
import shutil
import subprocess
import tempfile
import unicodedata
from pathlib import Path

import numpy as np
import pytest

from maglevgen import report as rp
from maglevgen.analyses.queries import gains_report
from maglevgen.carriage import DerivedCarriage
from maglevgen.cli import main
from maglevgen.control.carriage_plant import Plant
from maglevgen.errors import InputError, MaglevError
from maglevgen.infrastructure import output
from maglevgen.params import default_params_text, load_params
from maglevgen.report import display, latex, render
from maglevgen.report import format as fmt
from maglevgen.report.sections import parameters, simulation, stiffness

OVERFULL_BOUND_PT = 0.0  # widest overfull box the PDF may have: none (a table in the margin)
#: the PDF's date in the module's reports (SOURCE_DATE_EPOCH: 2023-11-14 22:13:20 UTC)
EPOCH = 1_700_000_000
RTOL = 1e-4  # the report prints 6 significant digits
MASS = 12.0


def _run_cli(tmp: Path, *args: str) -> Path:
    out = tmp / "report"
    assert main(["report", "--out", str(out), *args]) == 0
    return out


@pytest.fixture(scope="module")
def default_report(tmp_path_factory) -> Path:
    """`maglevgen report` on the default carriage (PDF included where TeX is installed),
    dated by SOURCE_DATE_EPOCH = `EPOCH`."""
    old = os.environ.get("SOURCE_DATE_EPOCH")
    os.environ["SOURCE_DATE_EPOCH"] = str(EPOCH)
    try:
        return _run_cli(tmp_path_factory.mktemp("default"))
    finally:
        if old is None:
            os.environ.pop("SOURCE_DATE_EPOCH", None)
        else:
            os.environ["SOURCE_DATE_EPOCH"] = old


@pytest.fixture(scope="module")
def mass_report(tmp_path_factory) -> Path:
    return _run_cli(tmp_path_factory.mktemp("mass"), "--set", f"vehicle.mass={MASS}")


@pytest.fixture(scope="module")
def default_context(carriage: DerivedCarriage):
    return rp.build_context(carriage)


def _pdf_text(pdf: Path) -> str:
    text = subprocess.run(
        ["pdftotext", "-layout", str(pdf), "-"], check=True, capture_output=True, text=True
    ).stdout
    return unicodedata.normalize("NFKC", text).replace("\u2212", "-")


# a number as pdftotext prints it (2.5, 2.5 × 10-4) or the .tex writes it (2.5 \times 10^{-4})
_NUM = r"-?\d+(?:\.\d+)?(?:\s*(?:×|\\times)\s*10\^?\{?-?\d+\}?)?"


def _value(text: str) -> float:
    """The value of a number matched by _NUM."""
    flat = re.sub(r"[\^{}]", "", text.replace("\\times", "×"))
    mant, _, exp = flat.partition("×")
    return float(mant) * 10.0 ** int(exp.strip()[2:]) if exp else float(mant)


def _gain_rows(text: str, sep: str) -> dict[str, list[float]]:
    """axis -> (k, m, K1, K2) from the closed-form gains table (pdftotext or .tex)."""
    start = text.rindex("Gains for this carriage")  # the section, not the contents entry
    rows = {}
    for axis in ("lateral", "vertical", "roll", "pitch", "yaw"):
        m = re.search(
            rf"^\s*{axis}\s*{sep}\s*\$?({_NUM})\$?\s*{sep}\s*\$?({_NUM})\$?\s*{sep}"
            rf"\s*\$?({_NUM})\$?\s*{sep}\s*\$?({_NUM})",
            text[start:],
            re.MULTILINE,
        )
        assert m, f"no gains row for {axis}"
        rows[axis] = [_value(g) for g in m.groups()]
    return rows


def _assert_gains_match(rows: dict[str, list[float]], ref: dict) -> None:
    for axis, (k, m, K1, K2) in rows.items():
        a = ref["axes"][axis]
        np.testing.assert_allclose([k, m], [a["stiffness"], a["inertia"]], rtol=RTOL, err_msg=axis)
        np.testing.assert_allclose([K1, K2], a["K_closed_form"], rtol=RTOL, err_msg=axis)
        np.testing.assert_allclose([K1, K2], a["K_numerical"], rtol=RTOL, err_msg=axis)


# -------------------------------------------------------------------------------- the PDF


@pytest.mark.needs_cc
@pytest.mark.needs_tex
def test_pdf_builds_without_errors_or_wide_overfull_boxes(default_report: Path) -> None:
    assert (default_report / "report.pdf").stat().st_size > 10_000
    log = (default_report / "report.log").read_text(errors="replace")
    assert not re.search(r"^! ", log, re.MULTILINE), rp.first_latex_error(log)
    assert "LaTeX Warning: Reference" not in log and "undefined references" not in log
    wide = [w for w in rp.overfull_boxes(log) if w > OVERFULL_BOUND_PT]
    assert not wide, f"overfull boxes wider than {OVERFULL_BOUND_PT} pt: {wide}"


# the page-fill check: how much of a page's text block its content spans
HALF_FULL = 0.5
_A4_HEIGHT_PT = 842.0
_MARGIN_PT = 2.2 / 2.54 * 72  # report.tex.j2: geometry's margin=2.2cm on every side


def page_fill(pdf: Path, dpi: int = 20) -> list[float]:
    """Per page, the share of the text block's height that its content spans, from the first
    inked row to the last (poppler's pdftoppm renders each page in grey: text, tables and
    figures alike; the page number below the block does not count). A page of floats that
    LaTeX centred counts by its floats' height, not by where they sit."""
    from PIL import Image

    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(["pdftoppm", "-r", str(dpi), "-gray", str(pdf), f"{tmp}/p"], check=True)
        fills = []
        for png in sorted(Path(tmp).glob("p-*.pgm"), key=lambda q: int(q.stem.split("-")[1])):
            rows = (np.asarray(Image.open(png)) < 200).any(axis=1)
            m = round(_MARGIN_PT / 72 * dpi)
            inked = np.nonzero(rows[m:len(rows) - m])[0]
            span = inked[-1] - inked[0] + 1 if inked.size else 0
            fills.append(span / (len(rows) - 2 * m))
    return fills


def chapter_ends(pdf: Path) -> set[int]:
    """The pages (1-based) after which a new section starts at the top of the next page, and
    the last page: where a page may end half empty. The sections are hyperref's named
    destinations (``section.N``, pdfinfo -dests) with their height on the page."""
    out = subprocess.run(["pdfinfo", "-dests", str(pdf)], check=True, capture_output=True,
                         text=True).stdout
    pages = int(re.search(r"^Pages:\s+(\d+)", subprocess.run(
        ["pdfinfo", str(pdf)], check=True, capture_output=True, text=True).stdout, re.M)[1])
    top = _A4_HEIGHT_PT - _MARGIN_PT - 36  # a heading's anchor within 36 pt of the block's top
    ends = {pages}
    for page, y in re.findall(r"^\s*(\d+) \[ XYZ\s+\S+\s+(\S+) .*\] \"section\.\d+\"$", out,
                              re.M):
        if float(y) >= top:
            ends.add(int(page) - 1)
    return ends


@pytest.mark.needs_tex  # poppler's pdftoppm and pdfinfo
def test_the_page_fill_check_flags_a_half_empty_page(tmp_path: Path) -> None:
    """The measure on a PDF made without LaTeX (matplotlib's PDF backend, A4): a page of 60
    lines spans its text block, a page of 5 lines at its top is flagged, the last page is a
    chapter end."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.backends.backend_pdf import PdfPages

    pdf = tmp_path / "pages.pdf"
    top, bottom = 1 - _MARGIN_PT / _A4_HEIGHT_PT, _MARGIN_PT / _A4_HEIGHT_PT
    with PdfPages(pdf) as pages:
        for n in (60, 5, 60, 3):
            fig = plt.figure(figsize=(8.27, 11.69))
            for i, y in enumerate(np.linspace(top - 0.01, bottom + 0.01, 60)[:n]):
                fig.text(0.15, y, f"line {i} of a page of {n}", fontsize=9)
            pages.savefig(fig)
            plt.close(fig)
    fill = page_fill(pdf)
    assert len(fill) == 4
    assert fill[0] > 0.95 and fill[2] > 0.95, fill
    assert fill[1] < 0.1 and fill[3] < 0.1, fill
    assert chapter_ends(pdf) == {4}


@pytest.mark.needs_tex
def test_no_page_of_the_builds_report_is_under_half_full(default_build: Path,
                                                         tmp_path: Path) -> None:
    """report.pdf of the default build (the suite's shared build: its report.tex compiled
    here): every page spans at least half of its text block, except where a section starts
    on the next page and on the last page (float placement: report.tex.j2's fractions)."""
    folder = Path(shutil.copytree(default_build / "report", tmp_path / "report"))
    made = latex.run_latex(folder)
    assert made.ok, made.error
    pdf = folder / "report.pdf"
    fill = page_fill(pdf)
    ends = chapter_ends(pdf)
    assert len(fill) > 20, len(fill)  # the whole report, not a stub
    thin = {i + 1: round(f, 2) for i, f in enumerate(fill) if f < HALF_FULL and i + 1 not in ends}
    assert not thin, f"pages under half full (page: share of the text block): {thin}"


@pytest.mark.needs_cc
@pytest.mark.needs_tex
def test_no_page_of_the_report_commands_pdf_is_under_half_full(default_report: Path) -> None:
    """The same for `maglevgen report` alone (no simulation chapter: other floats, other
    breaks), on the PDF the module has built already."""
    pdf = default_report / "report.pdf"
    fill, ends = page_fill(pdf), chapter_ends(pdf)
    thin = {i + 1: round(f, 2) for i, f in enumerate(fill) if f < HALF_FULL and i + 1 not in ends}
    assert not thin, f"pages under half full (page: share of the text block): {thin}"


@pytest.mark.needs_cc
@pytest.mark.needs_tex
def test_pdf_metadata_has_title_author_and_the_given_date(default_report: Path) -> None:
    """pdfinfo (poppler) reads the title, the author ("maglevgen": the parameter file names
    none) and the creation date SOURCE_DATE_EPOCH gave (datetime's reading of the epoch)."""
    import datetime

    info = dict(line.split(":", 1) for line in subprocess.run(
        ["pdfinfo", "-isodates", str(default_report / "report.pdf")], check=True,
        capture_output=True, text=True).stdout.splitlines() if ":" in line)
    info = {k.strip(): v.strip() for k, v in info.items()}
    assert info["Title"] == "Derivation report: Inductrack maglev carriage"
    assert info["Author"] == "maglevgen"
    want = datetime.datetime.fromtimestamp(EPOCH, datetime.timezone.utc)
    got = datetime.datetime.fromisoformat(info["CreationDate"].replace("Z", "+00:00"))
    assert got == want and got.year > 2000, info["CreationDate"]


def test_the_pdf_date_is_the_builds_without_source_date_epoch(monkeypatch) -> None:
    import time

    monkeypatch.delenv("SOURCE_DATE_EPOCH", raising=False)
    assert abs(int(latex.source_date_epoch()) - time.time()) < 120  # a loaded machine's slack
    monkeypatch.setenv("SOURCE_DATE_EPOCH", "1234567890")
    assert latex.source_date_epoch() == "1234567890"


@pytest.mark.needs_cc
@pytest.mark.needs_tex
def test_pdf_has_every_section_and_the_gains_command_numbers(
    default_report: Path, carriage: DerivedCarriage
) -> None:
    text = _pdf_text(default_report / "report.pdf")
    flat = re.sub(r"\s+", " ", text)
    for title in rp.SECTION_TITLES.values():
        assert title in flat, f"section {title!r} missing from the PDF"
    _assert_gains_match(_gain_rows(text, ""), gains_report(Plant(carriage), None))
    assert "No simulation results were given" in flat


@pytest.mark.needs_cc
@pytest.mark.needs_tex
def test_changed_mass_changes_the_report(mass_report: Path, default_report: Path) -> None:
    heavy = DerivedCarriage(load_params(None, [f"vehicle.mass={MASS}"]))
    ref = gains_report(Plant(heavy), None)
    text = _pdf_text(mass_report / "report.pdf")
    rows = _gain_rows(text, "")
    _assert_gains_match(rows, ref)
    default_rows = _gain_rows(_pdf_text(default_report / "report.pdf"), "")
    assert rows["vertical"][1] == MASS and default_rows["vertical"][1] == 9.3
    assert rows["vertical"][3] != default_rows["vertical"][3]
    mass_line = re.search(r"^\s*mass\s+m\s.*$", text, re.MULTILINE).group(0)
    assert re.search(rf"\b{MASS:g}\b", mass_line) and "set" in mass_line, mass_line
    tex = (mass_report / "report.tex").read_text()
    _assert_gains_match(_gain_rows(tex, "&"), ref)


# -------------------------------------------------------------------------------- the .tex


def test_tex_is_deterministic(default_report: Path, default_context, tmp_path: Path) -> None:
    ctx, files = default_context
    assert rp.render_tex(ctx) == (default_report / "report.tex").read_text(encoding="utf-8")
    for name, data in files.items():
        assert (default_report / name).read_bytes() == data, name


def test_tex_shows_every_equation_from_the_context(default_report: Path) -> None:
    tex = (default_report / "report.tex").read_text(encoding="utf-8")
    for tag in ("1", "2", "3", "4", "8", "9", "10", "11", "12", "13", "22", "23", "30", "31", "32"):
        assert f"\\tag{{{tag}" in tex or f"& {tag} &" in tex, f"eq {tag} missing"
    for tag in ("8", "12", "22", "23", "31", "32"):  # the printed forms, tagged apart
        assert f"\\tag{{{tag}, paper}}" in tex, f"eq {tag} as printed: not tagged (N, paper)"
    assert "\\date{}" in tex and "\\VAR{" not in tex and "\\BLOCK{" not in tex


def test_simulation_figures_are_copied_and_captioned(default_context, tmp_path: Path) -> None:
    ctx, _ = default_context
    sim = tmp_path / "sim"
    sim.mkdir()
    png = b"\x89PNG\r\n\x1a\n" + b"0" * 16  # copied as bytes, never decoded
    (sim / "levitation_pitch.png").write_bytes(png)
    (sim / "metrics.json").write_text('{"lqr": {"settling_time": 1.5, "ok": true}}')
    sim_ctx, files = simulation.simulation_section(sim)
    assert files.read() == {"sim_levitation_pitch.png": png}
    tex = rp.render_tex({**ctx, "simulation": sim_ctx})
    assert (
        "\\includegraphics[width=\\textwidth,height=0.42\\textheight,keepaspectratio]"
        "{sim_levitation_pitch.png}" in tex
    )
    assert "figs 3, 5 and 7" in tex and "travel\\_roll.png" in tex and "settling" in tex
    with pytest.raises(InputError, match="none of"):
        simulation.simulation_section(tmp_path)
    # in memory, as `maglevgen build` passes a simulate run's files, with its metrics format
    run = {
        "controller": "lqr",
        "status": "ok",
        "event": "",
        "axes": {
            "vertical": {
                "state": "z",
                "settling_time": None,
                "peak_deviation": 1e-3,
                "final_deviation": 2e-4,
                "unit": "m",
                "rms_control": 3.5,
                "force_unit": "N",
            }
        },
    }
    metrics = json.dumps({"speed": 20.0, "disturbance": "1 mm heave", "runs": [run]})
    sim_ctx, files = simulation.simulation_section({"travel_roll.png": png,
                                                    "metrics.json": metrics})
    assert list(files.read()) == ["sim_travel_roll.png"]
    assert sim_ctx["runs"][0]["controller"] == "lqr"
    tex = rp.render_tex({**ctx, "simulation": sim_ctx})
    assert "not settled" in tex and "1 mm heave" in tex and "\\texttt{lqr}: ok" in tex
    with pytest.raises(InputError, match="not a folder"):
        simulation.simulation_section(tmp_path / "nowhere")


# ------------------------------------------------------------------- failure and no TeX


@pytest.mark.needs_tex
def test_latex_failure_leaves_the_previous_output(
    default_context, carriage: DerivedCarriage, tmp_path: Path, monkeypatch
) -> None:
    out = tmp_path / "out"
    output.write_output({"report.tex": "previous"}, out)  # an earlier report of maglevgen's
    monkeypatch.setattr(render, "build_context", lambda *a, **k: default_context)
    monkeypatch.setattr(
        render,
        "render_tex",
        lambda ctx: "\\documentclass{article}\\begin{document}\\undefinedmacro\\end{document}\n",
    )
    with pytest.raises(
        MaglevError,
        match=r"LaTeX failed: .*report\.tex:1: Undefined control "
        r"sequence.*\.out\.failed/report\.log",
    ):
        rp.write_report(carriage, out)
    assert sorted(p.name for p in out.iterdir()) == [output.MARKER, "report.tex"]
    assert (out / "report.tex").read_text() == "previous"


def test_without_tex_the_tex_is_written_and_the_install_named(
    default_context, tmp_path: Path, monkeypatch, capsys
) -> None:
    monkeypatch.setattr(render, "build_context", lambda *a, **k: default_context)
    monkeypatch.setattr(latex, "find_tex", lambda: None)
    assert main(["report", "--out", str(tmp_path / "r")]) == 0
    out = capsys.readouterr()
    assert "report.tex" in out.out and "report.pdf" not in out.out
    assert "apt-get install" in out.err and "latexmk" in out.err
    assert sorted(p.name for p in (tmp_path / "r").iterdir()) == [
        ".maglevgen-output.json",
        "circuit_lag_damping.png",
        "envelope_region_of_attraction.png",
        "envelope_stability_map.png",
        "fig_disk_margins.png",
        "fig_force_gap.png",
        "fig_force_speed.png",
        "pole_map.png",
        "report.tex",
    ]


def test_missing_simulation_folder_is_bad_input(tmp_path: Path, capsys) -> None:
    assert (
        main(["report", "--simulation", str(tmp_path / "none"), "--out", str(tmp_path / "r")]) == 2
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a folder" in err[0]
    assert not (tmp_path / "r").exists()


# ----------------------------------------------------------------- parameter provenance


def test_parameter_sources_and_reasons_come_from_the_file() -> None:
    rows, notes = parameters.parameter_rows(load_params(None, [f"vehicle.mass={MASS}"]))
    by_key = {r.key: r for r in rows}
    assert by_key["vehicle.mass"].source == "set"
    assert by_key["vehicle.length"].source == "paper"
    assert by_key["halbach.wavelength"].source == "paper"
    assert by_key["arrays.3.nominal_gap"].source == "paper"
    assert by_key["arrays.6.nominal_gap"].source == "paper"  # same value as array 3's
    assert by_key["halbach.remanence"].source == "assumed"
    cg = by_key["vehicle.cg_offset"]
    assert cg.source == "assumed" and "CG sits" in notes[cg.note - 1].text
    inertia = {by_key[f"vehicle.inertia_cg.{c}"].note for c in ("xx", "yy", "xz")}
    assert len(inertia) == 1 and "no inertia" in notes[inertia.pop() - 1].text
    assert "13 circuits" in notes[by_key["arrays.2.circuits"].note - 1].text


def test_changed_value_in_a_file_is_marked(tmp_path: Path) -> None:
    text = default_params_text().replace("mass = 9.3\n", "mass = 11.0\n")
    path = tmp_path / "c.toml"
    path.write_text(text)
    rows, _ = parameters.parameter_rows(load_params(path))
    mass = next(r for r in rows if r.key == "vehicle.mass")
    assert mass.source == "changed" and mass.values == (11.0,) and mass.paper == "9.3 kg"


# ---------------------------------------------------------------------- LaTeX helpers


def test_number_formats() -> None:
    assert fmt.fnum(9.3) == "9.3"
    assert fmt.fnum(2.23521e-4) == r"2.23521 \times 10^{-4}"
    assert fmt.fnum(-1.5e7, 3) == r"-1.5 \times 10^{7}"
    assert fmt.ffixed(2.9647e-5) == "0.000029647"
    assert fmt.ffixed(16865.1234) == "16865.1"
    assert fmt.fcomplex(-1.5 + 0j) == "-1.5"


def test_a_column_takes_one_notation_and_reads_back_its_values() -> None:
    """fcolumn (LaTeX) and fcolumn_plain (text): a column whose magnitudes span 1e-5 to 1e-2
    prints every entry with an exponent, one within [1e-4, 1e5) every entry plainly; each
    entry reads back (parsed here) as its value to the digits asked; zeros and None pass."""
    from maglevgen.infrastructure.columns import fcolumn_plain

    wide = [2.23524e-4, 2.96472e-5, 3.63352e-2, 0.0]
    tex = fmt.fcolumn(wide)
    assert [r"\times" in c for c in tex] == [True, True, True, False]
    np.testing.assert_allclose([_value(c) for c in tex], wide, rtol=1e-6)
    plain = [2236.9, 9.3, 0.000223524, None]
    tex = fmt.fcolumn(plain)
    assert tex[-1] is None and not any(r"\times" in c for c in tex[:-1])
    np.testing.assert_allclose([float(c) for c in tex[:-1]], plain[:-1], rtol=1e-6)
    text = fcolumn_plain(wide)
    assert all("e" in c for c in text[:3]) and text[3] == "0"
    np.testing.assert_allclose([float(c) for c in text], wide, rtol=1e-3)
    text = fcolumn_plain([16865.1, 0.08149, 1234567.0], 5)
    assert all("e" in c for c in text)  # 1.2e6 is outside the plain range: all take one
    assert fcolumn_plain([16865.1, 0.08149], 5) == ["16865", "0.08149"]


def test_axis_tables_open_each_block_with_its_units() -> None:
    """axis_unit_row: a row of units before lateral and roll only (the rotations' after a
    rule), each quantity's unit by the block, a literal unit as given."""
    assert fmt.axis_unit_row("vertical", "k") == fmt.axis_unit_row("yaw", "k") == ""
    assert fmt.axis_unit_row("lateral", "k", "m", "1/s") == (
        "\\textit{translations} & [N/m] & [kg] & [1/s] \\\\\n")
    assert fmt.axis_unit_row("roll", "c", "", lead=2) == (
        "\\midrule\n\\textit{rotations} &  & [N\\,m\\,s/rad] &  \\\\\n")


def test_escape_and_long_sums_are_broken() -> None:
    assert fmt.tex_escape("a_b & 50% #1 {x} ~ ^") == (
        r"a\_b \& 50\% \#1 \{x\} \textasciitilde{} \^{}"
    )
    import sympy as sp

    x = sp.symbols("x0:40")
    lines = display.break_sum("S", sum(xi * sp.Symbol("y") for xi in x))
    assert len(lines) > 3 and lines[0].startswith("S &=")
    assert all(display._tex_width(line) <= display.LINE_WIDTH + 10 for line in lines)


def test_stiffness_display_is_keyed_by_the_geometry_it_shows() -> None:
    """The cached K_st0 display (keyed by the array geometry it substitutes) changes with the
    geometry, not with the mass, and equals what a fresh derivation renders."""
    base = DerivedCarriage(load_params(overrides=[]))
    heavier = DerivedCarriage(load_params(overrides=["vehicle.mass=12.5"]))
    moved = DerivedCarriage(load_params(overrides=["arrays.3.position=[0.26, 0.0, -0.031]"]))
    assert stiffness._shown_values(heavier) == stiffness._shown_values(base)
    assert stiffness._shown_values(moved) != stiffness._shown_values(base)
    assert ("arrays.3.position.z", -0.031) in stiffness._shown_values(moved)
    shown = stiffness._stiffness_display(moved.structure, stiffness._shown_values(moved),
                                         display.REPORT_SOURCE)
    assert shown != stiffness._stiffness_display(base.structure, stiffness._shown_values(base),
                                          display.REPORT_SOURCE)
    assert "0.031" in " ".join(shown[0].lines)  # the moved array's z arm, in the display
    stiffness._stiffness_display.cache_clear()  # in-process entries; the disk store bypassed below
    from maglevgen.derive import memo

    memo.set_store(None)
    try:
        fresh = stiffness._stiffness_display(moved.structure, stiffness._shown_values(moved),
                                      display.REPORT_SOURCE)
    finally:
        from maglevgen.infrastructure.cache import STORE

        memo.set_store(STORE)
    assert fresh == shown


# ------------------------------------------------------------------- the reviewer's page


@pytest.mark.needs_cc
@pytest.mark.needs_tex
def test_summary_page_has_the_verdicts_and_no_raw_python(default_report: Path,
                                                         carriage: DerivedCarriage) -> None:
    """Page 1 names the embedded controller's verdict (from `maglevgen envelope`'s data,
    computed here by envelope.compute_envelope), the summary (pages 1-2) every other
    controller's and the count of checks; nowhere a SymPy/Python repr."""
    from maglevgen.analyses.envelope import compute_envelope
    from maglevgen.controllers import title

    pdf = str(default_report / "report.pdf")
    pages = {n: subprocess.run(["pdftotext", "-f", "1", "-l", str(n), pdf, "-"], check=True,
                               capture_output=True, text=True).stdout for n in (1, 2)}
    page1, flat = (re.sub(r"\s+", " ", unicodedata.normalize("NFKC", pages[n])
                          .replace("\u2212", "-")) for n in (1, 2))
    env = compute_envelope(Plant(carriage))
    for name, c in env.controllers.items():
        verdict = re.sub(r"\s+", " ", c.verdict.replace("\u2212", "-"))
        on = page1 if name == carriage.params.envelope.embedded_controller else flat
        assert f"{title(name)}" in on and verdict[:40] in on, (name, verdict)
    assert re.search(r"Verification .*\d+ checks passed, \d+ failed", flat)
    text = _pdf_text(default_report / "report.pdf")
    for raw in ("Eq(", "sqrt(", "[["):
        assert raw not in text, f"raw Python/SymPy output {raw!r} in the PDF"


def _pages_ending_in_a_caption(text: str) -> list[tuple[int, str]]:
    """The pages (pdftotext's form feeds) whose last line of text, the page number aside,
    introduces what follows (ends in a colon) while the next page opens with a centred block
    (a table's rows, indented in pdftotext's layout): a caption left apart from its table. A
    paragraph that only breaks after a colon goes on at the left margin."""
    pages = [[ln for ln in page.splitlines() if ln.strip() and not ln.strip().isdigit()]
             for page in text.split("\f")]
    return [(n, lines[-1].strip()[-80:])
            for n, (lines, after) in enumerate(itertools.pairwise(pages), 1)
            if lines and after and lines[-1].rstrip().endswith(":")
            and after[0].startswith(" " * 8)]


def test_the_page_scanner_finds_a_caption_at_a_page_foot() -> None:
    page = "Largest relative error against the reference:\n\n\n   23\n"
    table = "\f          axis  naive\n          roll 1e-14\n"
    assert _pages_ending_in_a_caption("text\n" + page + table) == [
        (1, "Largest relative error against the reference:")]
    # the paragraph goes on at the margin: a break after a colon, not a caption
    assert _pages_ending_in_a_caption("text\n" + page + "\fits rest):\n" + table[1:]) == []
    assert _pages_ending_in_a_caption("text:\nthe table\n   23\n" + table) == []


@pytest.mark.needs_cc
@pytest.mark.needs_tex
def test_no_caption_ends_a_page_apart_from_its_table(default_report: Path,
                                                     mass_report: Path) -> None:
    """A table or figure introduced by a line ending in a colon starts on that line's page
    (LaTeX preferred the break before a centred table: four captions of the default report
    ended a page with a cached build verdict in it)."""
    for report in (default_report, mass_report):
        assert _pages_ending_in_a_caption(_pdf_text(report / "report.pdf")) == []


@pytest.mark.needs_cc
@pytest.mark.needs_tex
def test_no_raw_python_or_sympy_text_anywhere_in_the_pdf(default_report: Path) -> None:
    """What a reader of the PDF sees (pdftotext of every page, not the LaTeX source) has no
    SymPy or Python repr: no **, [[, Eq(, sqrt(, " * ", [1], no number with more than 7
    significant digits and no round-off noise below 1e-12 (tests/readable.py)."""
    from readable import raw_findings

    found = raw_findings(_pdf_text(default_report / "report.pdf"), "report.pdf")
    assert found == [], "\n".join(found)


@pytest.mark.needs_cc
@pytest.mark.needs_tex
def test_the_embedded_controller_is_given_in_full(default_report: Path, carriage: DerivedCarriage,
                                                  capsys) -> None:
    """The section "The embedded controller" (and page 1) give it in full: its weights at the
    design speed equal Bryson's rule and the damping-ratio root search of
    tests/independent_reference.py (from the plants and the allocation `gains --json`
    prints); its typeset K_pos and K_rate at v_min, V and v_max are `maglevgen gains --speed
    v --json`'s "embedded" matrices (a separate command: what `gains` prints and the report
    shows are the same), the design speed's also on page 1."""
    from independent_reference import spec_weights_reference

    tex = (default_report / "report.tex").read_text(encoding="utf-8")
    section = tex[tex.index(r"\subsection{The embedded controller"):]
    blocks = re.findall(r"\\\[ (v_\{\\min\}|V|v_\{\\max\}) = ([0-9.]+)\\,\\mathrm\{m/s\}:"
                        r"\\quad K_\\mathrm\{pos\} = \\begin\{bmatrix\}(.*?)\\end\{bmatrix\}, "
                        r"\\\]\s*\\\[ K_\\mathrm\{rate\} = \\begin\{bmatrix\}(.*?)"
                        r"\\end\{bmatrix\}", section, re.DOTALL)
    assert [b[0] for b in blocks] == ["v_{\\min}", "V", "v_{\\max}"], blocks
    page1 = tex[:tex.index(r"\tableofcontents")]
    assert r"\textbf{Embedded controller}" in page1
    for label, speed, K_pos, K_rate in blocks:
        assert main(["gains", "--speed", speed, "--json"]) == 0
        rep = json.loads(capsys.readouterr().out)
        e = rep["embedded"]
        assert e["controller"] == carriage.params.envelope.embedded_controller == "spec"
        for name, body in (("K_pos", K_pos), ("K_rate", K_rate)):
            got = np.array([[v.real for c in row.split("&") for v in _tex_values(c) or [0.0]]
                            for row in body.split(r"\\")])
            want = np.array(e[name])
            assert got.shape == want.shape, (label, name, got.shape)
            # 4 significant digits; the round-off of zeros printed as 0
            np.testing.assert_allclose(got, want, rtol=6e-4, atol=1e-9 * np.abs(want).max(),
                                       err_msg=f"{name} at {label}")
        if label != "V":
            continue
        assert K_pos in page1 and K_rate in page1  # the first page shows the design speed's
        axes = rep["axes"].values()
        k = np.array([a["stiffness"] for a in axes])
        m = np.array([a["inertia"] for a in axes])
        q1, q2, r = spec_weights_reference(carriage.params.control.spec, k, m,
                                           np.array(rep["allocation"]["minimum_norm"]))
        col = [b[0] for b in blocks].index("V")
        for i, axis in enumerate(rep["axes"]):
            row = re.search(rf"^{axis} & .*?\\\\$", section, re.MULTILINE)[0]
            cells = [_tex_values(c) for c in row.removesuffix(r"\\").split("&")[1:]]
            _a_max, _f_max, q1_txt, r_txt, *q2s = (c[0].real for c in cells)
            np.testing.assert_allclose([q1_txt, r_txt, q2s[col]], [q1[i], r[i], q2[i]],
                                       rtol=6e-4, err_msg=axis)


@pytest.mark.needs_cc
@pytest.mark.needs_tex
def test_summary_gain_rows_agree_with_gains_json(default_report: Path, carriage: DerivedCarriage,
                                                 capsys) -> None:
    """Every number of the summary's gains table (K1, K2, the poles) equals `gains --json`'s,
    parsed row by row from the PDF's text; the magnetic damping beside them equals central
    differences of the circuit-by-circuit force sum with the circuits' lag (test_build's
    reference)."""
    from independent_reference import generalized_mass, reference_trim
    from test_build import _magnetic_damping_reference

    assert main(["gains", "--json"]) == 0
    ref = json.loads(capsys.readouterr().out)
    prm = carriage.params
    c_mag = _magnetic_damping_reference(prm, reference_trim(prm, prm.operation.speed),
                                        generalized_mass(prm))
    text = _pdf_text(default_report / "report.pdf")
    page = text[: text.index("Paper discrepancies")]
    num = r"-?\d+(?:\.\d+)?(?:\s*[x×]\s*10-?\d+)?"
    for i, (axis, a) in enumerate(ref["axes"].items()):
        m = re.search(rf"^\s*{axis}\s+({num})\s+({num})\s+({num})\s+(.*)$", page,
                      re.MULTILINE)
        assert m, f"no summary row for {axis}"
        np.testing.assert_allclose([_value(m.group(1)), _value(m.group(2))],
                                   a["K_closed_form"], rtol=RTOL, err_msg=axis)
        assert _value(m.group(3)) == pytest.approx(c_mag[i], rel=RTOL, abs=1e-3), axis
        pole = r"(-?\d+(?:\.\d+)?)\s*([+-])\s*(\d+(?:\.\d+)?)\s*j|(-?\d+(?:\.\d+)?)"
        parts = re.findall(pole, m.group(4))
        poles = [complex(float(re_), float(im) * (1 if sg == "+" else -1)) if im else
                 complex(float(re_only), 0) for re_, sg, im, re_only in parts]
        want = [complex(*p) for p in a["closed_loop_poles"]]
        got = sorted(poles, key=lambda z: (z.real, z.imag))
        want = sorted(want, key=lambda z: (z.real, z.imag))
        assert len(got) == len(want), (axis, m.group(4))
        for g, w in zip(got, want, strict=True):
            assert abs(g - w) <= 1e-3 * abs(w), (axis, g, w)


def test_simulation_made_with_other_parameters_is_refused(tmp_path: Path, capsys) -> None:
    """`report --simulation DIR` with a folder simulated for another mass: exit 2, one line
    naming the folder and why, nothing written."""
    sim = tmp_path / "sim"
    assert main(["simulate", "--out", str(sim), "--t-end", "0.05",
                 "--set", "vehicle.mass=9.5"]) == 0
    capsys.readouterr()
    out = tmp_path / "r"
    assert main(["report", "--simulation", str(sim), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(sim) in err[0] and "other parameters" in err[0], err
    assert not out.exists()


def test_provenance_key_that_names_nothing_is_bad_input(tmp_path: Path) -> None:
    path = tmp_path / "c.toml"
    path.write_text(default_params_text() + '\n[provenance."vehicle.mas"]\nsource = "paper"\n'
                    'why = "typo"\n')
    with pytest.raises(InputError, match=r"provenance = 'vehicle.mas': names no parameter"):
        load_params(path)


# ------------------------------------------------------ one engine: the report = the CLI

_TEX_NUM = re.compile(r"(-?\d+(?:\.\d+)?)(?:\s*\\times\s*10\^\{(-?\d+)\})?")


def _tex_values(cell: str) -> list[complex]:
    """The numbers of one table cell or matrix of the .tex, as fnum/ffixed/fcomplex write
    them (``a \\times 10^{e}``, ``a + b\\,j``)."""
    out: list[complex] = []
    for part in re.split(r",\s(?![^{]*\})", cell):  # a list of poles: one complex each
        nums = [float(m) * 10 ** int(e or 0) for m, e in _TEX_NUM.findall(part)]
        if r"\,j" in part and len(nums) == 2:
            out.append(complex(nums[0], nums[1] * (-1 if re.search(r"\d\s-\s", part) else 1)))
        else:
            out += [complex(v) for v in nums]
    return out


def _section(tex: str, key: str) -> str:
    """The text of the report's section ``key`` (a key of SECTION_TITLES)."""
    start = tex.index(rf"\section{{{rp.SECTION_TITLES[key]}}}")
    end = tex.find(r"\section", start + 1)
    return tex[start:end if end > 0 else None]


def _axis_rows(section: str, axis: str) -> list[list[str]]:
    """The cells of every table row of ``section`` that starts with ``axis``."""
    return [[c.strip() for c in m.group(1).split("&")]
            for m in re.finditer(rf"^{axis} & (.*?)\\\\\s*$", section, re.MULTILINE)]


def _close(got: list[complex], want: list, rtol: float, what: str) -> None:
    want = [complex(*w) if isinstance(w, list | tuple) else complex(w) for w in want]
    assert len(got) == len(want), (what, got, want)
    for g, w in zip(got, want, strict=True):
        assert abs(g - w) <= rtol * abs(w) + 1e-300, (what, g, w)


@pytest.mark.needs_cc
def test_every_number_the_report_and_gains_json_both_print_agrees(default_report: Path,
                                                                  capsys) -> None:
    """The report's .tex read back number by number against `maglevgen gains --json` (a
    separate command): the Riccati tables (k, m, K closed form, poles, K numerical, K eq 32,
    P), the damping table (k, m, c*, and its poles against the roots of m s^2 + c s + k
    computed here), the generalized masses and the allocation's E and T."""
    assert main(["gains", "--json"]) == 0
    ref = json.loads(capsys.readouterr().out)
    tex = (default_report / "report.tex").read_text(encoding="utf-8")
    ric, damp = _section(tex, "riccati"), _section(tex, "damping")
    for axis, a in ref["axes"].items():
        gains, numerical, riccati = _axis_rows(ric, axis)
        vals = [v for c in gains for v in _tex_values(c)]
        _close(vals[:4], [a["stiffness"], a["inertia"], *a["K_closed_form"]], 1e-5, axis)
        got = sorted(vals[4:], key=lambda z: (z.real, z.imag))
        want = sorted((complex(*p) for p in a["closed_loop_poles"]),
                      key=lambda z: (z.real, z.imag))
        _close(got, want, 1e-3, f"{axis} poles")
        num = [_tex_values(c) for c in numerical]
        _close([num[0][0], num[1][0]], a["K_numerical"], 1e-5, f"{axis} K numerical")
        _close([num[3][0], num[4][0]], a["K_paper"], 1e-5, f"{axis} K eq 32")
        P = a["P_closed_form"]
        _close([v for c in riccati for v in _tex_values(c)], [P[0][0], P[0][1], P[1][1]],
               1e-5, f"{axis} P")
        (row,) = _axis_rows(damp, axis)
        k, m, c = a["stiffness"], a["inertia"], a["damping_gain"]
        _close(_tex_values(row[0]) + _tex_values(row[1]), [k, m], 1e-5, f"{axis} damping k, m")
        if c is None:
            assert row[2] == "---", (axis, row)
        else:
            _close(_tex_values(row[2]), [c], 1e-5, f"{axis} c*")
            got = sorted(_tex_values(row[3]), key=lambda z: (z.real, z.imag))
            roots = sorted(np.roots([m, c, k]), key=lambda z: (z.real, z.imag))
            _close(got, list(roots), 1e-3, f"{axis} damping poles")
    masses = re.search(r"with values \$\((.*?)\)\$ in kg", _section(tex, "stiffness")).group(1)
    _close(_tex_values(masses), [a["inertia"] for a in ref["axes"].values()], 1e-5, "masses")
    for name, key in (("E", "effectiveness"), ("T", "minimum_norm")):
        mat = re.search(rf"\\\[ {name} = \\begin\{{bmatrix\}}(.*?)\\end\{{bmatrix\}}", damp)
        want = np.array(ref["allocation"][key])
        got = [v for c in re.split(r"&|\\\\", mat.group(1)) for v in _tex_values(c)]
        assert len(got) == want.size, name
        np.testing.assert_allclose(np.real(got), want.ravel(), rtol=1e-3,
                                   atol=1e-12 * np.abs(want).max(), err_msg=name)


def test_simulation_metrics_are_named_with_units_and_every_figure_is_referenced(
    default_context, tmp_path: Path, capsys
) -> None:
    """The report with a real `maglevgen simulate` folder: the metrics table names each
    quantity in words with its unit (no raw JSON key such as ``rk4_stability_limit``) and
    shows metrics.json's values (read here); every figure has a label that the text
    references with \\ref."""
    sim = tmp_path / "sim"
    assert main(["simulate", "--out", str(sim), "--t-end", "0.05"]) == 0
    capsys.readouterr()
    data = json.loads((sim / "metrics.json").read_text())
    ctx, _ = default_context
    sim_ctx, _ = simulation.simulation_section(sim, ctx["sha256"])
    tex = rp.render_tex({**ctx, "simulation": sim_ctx})
    section = _section(tex, "simulation")
    table = section[section.index("quantity [unit]"):]
    table = table[: table.index(r"\end{longtable}")]
    keys = [k for k in data if "_" in k]  # those a reader would see as code
    assert "rk4_stability_limit" in keys
    for key in keys:
        assert tex_key_escaped(key) not in table and key not in table, key
    assert not re.search(r"[a-z0-9]\\_[a-z]", table), "a raw key in the metrics table"
    for words, unit, key in (("trim speed", "m/s", "speed"), ("RK4 step", "s",
                             "rk4_stability_limit"), ("propulsion force", "N",
                             "propulsion_force")):
        row = re.search(rf"^[^\n]*{words}[^\n&]*\[{re.escape(unit)}\] & \$([^$]+)\$", table,
                        re.MULTILINE)
        assert row, (words, unit)
        assert _tex_values(row.group(1))[0].real == pytest.approx(data[key], rel=1e-5), key

    figures = re.findall(r"\\begin\{figure\}(.*?)\\end\{figure\}", tex, re.DOTALL)
    assert tex.count(r"\includegraphics") == sum(f.count(r"\includegraphics") for f in figures)
    assert len(figures) >= 5  # force, envelope, poles and the simulation's
    outside = re.sub(r"\\begin\{figure\}.*?\\end\{figure\}", "", tex, flags=re.DOTALL)
    for fig in figures:
        (label,) = re.findall(r"\\label\{([^}]+)\}", fig)
        assert rf"\ref{{{label}}}" in outside, f"figure {label} is not referenced"


def tex_key_escaped(key: str) -> str:
    return key.replace("_", r"\_")


def test_stiffness_table_has_both_laws_and_the_roll_text_names_its_terms(
        default_context, default_report: Path) -> None:
    """Three columns (paper as printed, point, distributed): each law's column against central
    differences of the test's force sums; each parts row sums to the law's derived stiffness
    with gravity; the roll paragraph names the rotating-arms and gravity terms."""
    from independent_reference import reference_trim, stiffness_fd

    ctx, _files = default_context
    st = ctx["stiffness"]
    for law in ("point", "distributed"):
        prm = load_params(overrides=[f'model.array_force="{law}"']).params
        ref = reference_trim(prm, prm.operation.speed)
        k_mag = np.diag(stiffness_fd(prm, ref.q, prm.operation.speed, ref.f_prop, other=False))
        k_tot = np.diag(stiffness_fd(prm, ref.q, prm.operation.speed, ref.f_prop))
        for i, row in enumerate(st["rows"]):
            assert row[law] == pytest.approx(k_mag[i], rel=1e-5), (law, row["axis"])
        rows = [r for r in st["parts"] if r["law"] == law]
        assert [r["axis"] for r in rows] == [r["axis"] for r in st["rows"]]
        for i, r in enumerate(rows):
            assert sum(r["parts"]) == pytest.approx(r["total"], rel=1e-12, abs=1e-12)
            assert r["total"] == pytest.approx(k_tot[i], rel=1e-5), (law, r["axis"])
    tex = (default_report / "report.tex").read_text(encoding="utf-8")
    roll = tex[tex.index(r"\textbf{Roll.}"):]
    roll = roll[:roll.index("\n\n")]
    assert "rotating arms" in roll and "gravity's term" in roll and "tilt across" in roll


# ---------------------------------------------------------- tables: one quantity, one unit

_ENVS = re.compile(r"\\begin\{(tabular|longtable)\}(?:\{(?:[^{}]|\{[^{}]*\})*\})(.*?)"
                   r"\\end\{\1\}", re.DOTALL)
_CELL_NUMBER = re.compile(r"^\$(-?\d+(?:\.\d+)?)(\s*\\times\s*10\^\{-?\d+\})?\$(?:\s*\S+)?$")


def _tables(tex: str, with_header: bool = False) -> list:
    """Every tabular and longtable of the .tex: its data rows (after the header's \\midrule),
    each as its cells; the unit rows of the blocks (\\textit{translations}, ...) kept. With
    ``with_header``: (the header's text, the rows) each."""
    out = []
    for m in _ENVS.finditer(tex):
        body = m.group(2)
        header = body[:body.find(r"\midrule")]
        body = body[body.find(r"\midrule") + len(r"\midrule"):] if r"\midrule" in body else ""
        body = body.split(r"\endhead")[-1]
        rows = []
        for raw in re.split(r"\\\\\s*\n", body):
            raw = re.sub(r"\\(?:midrule|bottomrule|toprule)", "", raw).strip()
            if raw and "&" in raw:
                rows.append([c.strip() for c in raw.split("&")])
        out.append((header, rows) if with_header else rows)
    return out


@pytest.mark.needs_cc
def test_every_table_column_is_in_one_notation_and_gives_its_unit(default_report: Path
                                                                  ) -> None:
    """Each column of every table of the .tex prints its numbers in one notation (all plain
    decimals, or all a x 10^e: no 0.000223 above 2.96 x 10^-5); no header gives two units in
    one cell ([N/m; N m/rad]); every table whose rows are the five axes opens the
    translations' and the rotations' rows with a row of their units, and those units are the
    axis's (N/m and N m/rad for a stiffness, kg and kg m^2 for a generalized mass)."""
    tex = (default_report / "report.tex").read_text(encoding="utf-8")
    assert "; N" not in tex and "[translation; rotation]" not in tex
    tables = _tables(tex)
    assert len(tables) > 15
    mixed = []
    for header, rows in _tables(tex, with_header=True):
        if re.search(r"& \s*(?:unit|Unit)\s*(?:&|\\\\)", header):
            continue  # a list of quantities, each row its own with its unit (parameters, trim)
        for col in range(max((len(r) for r in rows), default=0)):
            kinds = {bool(m.group(2)) for r in rows if col < len(r)
                     if (m := _CELL_NUMBER.match(r[col])) and m.group(1) != "0"}
            if len(kinds) > 1:
                mixed.append([r[col] for r in rows if col < len(r)])
    assert mixed == [], mixed
    axis_tables = [rows for rows in tables if any(r[0] == r"\textit{translations}"
                                                  for r in rows) and rows[1][0] == "lateral"]
    # page 1, the circuits' lag, 9.2, 9.3, damping, the three Riccati tables, the spec
    # design's weights
    assert len(axis_tables) == 9, [rows[0] for rows in axis_tables]
    for rows in axis_tables:
        firsts = [r[0] for r in rows]
        lat, roll = firsts.index("lateral"), firsts.index("roll")
        t_units, r_units = rows[lat - 1], rows[roll - 1]
        assert t_units[0] == r"\textit{translations}", rows
        assert r_units[0] == r"\textit{rotations}", rows
        for unit_t, unit_r in zip(t_units[1:], r_units[1:], strict=True):
            assert (unit_t == "") == (unit_r == ""), (t_units, r_units)
            pairs = {("[N/m]", r"[N\,m/rad]"), ("[kg]", r"[kg\,m$^2$]"),
                     (r"[N\,s/m]", r"[N\,m\,s/rad]"), ("[m]", "[rad]"), ("[N]", r"[N\,m]"),
                     ("[1/N$^2$]", r"[1/(N\,m)$^2$]")}
            if unit_t != unit_r:  # a quantity whose unit follows the axis
                assert (unit_t, unit_r) in pairs or unit_r.endswith("rad$^2$]"), (unit_t,
                                                                                   unit_r)


@pytest.mark.needs_cc
def test_page_one_compares_each_printed_value_with_the_derived_one_beside_it(
        default_report: Path, carriage: DerivedCarriage) -> None:
    """The summary's two comparison tables read back from the .tex: the printed stiffnesses
    (eqs 7, 13-16 evaluated here at the reference trim) beside K_st0 (central differences of
    the test's force sums) and their difference in percent of that K_st0; the printed eq 32
    gain K1 = sqrt(k^2 + 1) - 1 beside the LQR gain (50-digit closed form here) and their
    ratio (to its two printed digits)."""
    from independent_reference import (
        generalized_mass,
        lqr_reference_mp,
        reference_trim,
        stiffness_fd,
    )
    from test_build import _paper_stiffness

    prm = carriage.params
    v = prm.operation.speed
    ref = reference_trim(prm, v)
    k_mag = np.diag(stiffness_fd(prm, ref.q, v, ref.f_prop, other=False))
    k_tot = np.diag(stiffness_fd(prm, ref.q, v, ref.f_prop))
    mass = generalized_mass(prm)
    paper = _paper_stiffness(prm, ref.arrays.lift)
    tex = (default_report / "report.tex").read_text(encoding="utf-8")
    page = tex[tex.index(r"\textbf{Paper discrepancies"):tex.index(r"\textbf{Speed mode}")]
    stiff, gains = _tables(page)
    axes = ("lateral", "vertical", "roll", "pitch", "yaw")
    got = {r[0]: r for r in stiff}
    assert sorted(got) == sorted(axes)
    for i, axis in enumerate(axes):
        _, unit, printed, derived, pct = got[axis]
        assert unit == ("N/m" if i < 2 else r"N\,m/rad")
        assert _value(printed.strip("$")) == pytest.approx(paper[i], rel=1e-4)
        assert _value(derived.strip("$")) == pytest.approx(k_mag[i], rel=1e-4)
        p = re.fullmatch(r"\$([+-]\d+\.\d)\\,\\%\$", pct)
        assert p, pct
        assert float(p[1]) == pytest.approx(100 * (paper[i] / k_mag[i] - 1), abs=0.051)
    rels = [abs(float(re.search(r"[+-]\d+\.\d", r[4])[0])) for r in stiff]
    assert rels == sorted(rels, reverse=True)  # largest first
    got = {r[0]: r for r in gains}
    assert sorted(got) == sorted(f"{a} K1" for a in axes)
    for i, axis in enumerate(axes):
        _, unit, printed, derived, ratio = got[f"{axis} K1"]
        K1 = float(lqr_reference_mp(k_tot[i], mass[i])[0][0])
        K1_paper = float(np.sqrt(k_tot[i] ** 2 + 1) - 1)
        assert _value(printed.strip("$")) == pytest.approx(K1_paper, rel=1e-4)
        assert _value(derived.strip("$")) == pytest.approx(K1, rel=1e-4)
        assert _value(ratio.strip("$")) == pytest.approx(K1_paper / K1, rel=0.051)


@pytest.mark.needs_cc
def test_the_region_statement_and_the_trim_state_are_typeset(default_report: Path) -> None:
    """The region of attraction's statement sets its mathematics ({V <= c} as $\\{V \\le c\\}$,
    not ASCII), and the trim's state column is in one notation (no 0.0000344784 above 20:
    the column rule of maglevgen.infrastructure.columns, read here from the numbers)."""
    tex = (default_report / "report.tex").read_text()
    assert r"\{V \textless{}= c\}" not in tex and "<=" not in tex
    assert r"$\{V \le c\}$" in tex and r"$\dot V < 0$" in tex
    start = tex.index("state & value & unit & meaning")
    rows = re.findall(r"^\$\\?\w+\$ & \$([^$]+)\$ & ", tex[start:tex.index(r"\bottomrule", start)],
                      re.M)
    assert len(rows) == 12, rows
    values = [_value(r) for r in rows]
    nonzero = [abs(v) for v in values if v != 0]
    exponents = [r for r in rows if r"\times" in r]
    plain = all(1e-4 <= v < 1e5 for v in nonzero)
    assert (not exponents) if plain else len(exponents) == len(nonzero), rows
