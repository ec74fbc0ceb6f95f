"""The report assembled: the context of every section, report.tex, the PDF, the files written.

Every equation in the report is a SymPy object from ``derive/`` (or built from its functions)
printed with ``sympy.latex``; every number comes from the compiled library through the same code
paths as ``maglevgen trim`` and ``maglevgen gains`` (their reports, imported in one place below);
the lambdified SymPy model, SciPy and mpmath appear only as references in the verification table.
The jinja2 templates in ``templates/report*`` only place them.

The output is written atomically: everything is rendered into a temporary folder, LaTeX runs
there, and only a successful build replaces the previous output. The .tex is deterministic: no
dates, fixed number formats, seeded random samples.
"""

from __future__ import annotations

import multiprocessing
import re
import shutil
import tempfile
from collections.abc import Callable, Mapping
from concurrent.futures import Future
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import maglevgen.report.latex as latex  # a module (tests patch its find_tex)
from maglevgen.analyses.queries import (  # the CLI's numbers, from the C
    accelerating_margins,
    gains_report,
    trim_point,
    trim_report,
)
from maglevgen.analyses.verdicts import cached_verdict, embedded_verdict
from maglevgen.control.carriage_plant import Plant
from maglevgen.errors import MaglevError
from maglevgen.infrastructure.output import write_output
from maglevgen.infrastructure.workers import process_pool
from maglevgen.report.figures import force_figures, pole_map
from maglevgen.report.latex import LatexBuild, latex_env
from maglevgen.report.sections.actuators import actuator_comparison_section
from maglevgen.report.sections.circuit_lag import CIRCUIT_LAG_FIGURE, circuit_lag
from maglevgen.report.sections.conventions import conventions_section
from maglevgen.report.sections.damping import damping_allocation_section
from maglevgen.report.sections.envelope import (
    ENVELOPE_FIGURE,
    ROA_FIGURE,
    envelope_checks,
    envelope_context,
    envelope_section,
    roa_context,
    roa_section,
)
from maglevgen.report.sections.force_law import force_curves, force_law_section
from maglevgen.report.sections.geometry import geometry_section
from maglevgen.report.sections.paper import paper_comparison_section
from maglevgen.report.sections.parameters import model_choices, parameter_rows
from maglevgen.report.sections.poles import POLE_FIGURE, pole_sets
from maglevgen.report.sections.riccati import riccati_section
from maglevgen.report.sections.rigid_body import rigid_body_section
from maglevgen.report.sections.sensing import sensing_section
from maglevgen.report.sections.simulation import Simulation, simulation_section
from maglevgen.report.sections.stiffness import stiffness_section
from maglevgen.report.sections.summary import summary
from maglevgen.report.sections.trim import trim_section
from maglevgen.report.sections.verification import verification_section
from maglevgen.version import __version__

__all__ = ["SECTION_TITLES", "ReportOptions", "build_context", "render_tex", "report_files",
           "write_report"]


@dataclass(frozen=True)
class ReportOptions:
    """What `write_report` does besides rendering the .tex."""

    simulation: Simulation = None  # `maglevgen simulate` output: its folder or its files
    verify_c: bool = True  # compile the generated C and compare it with the SymPy model
    build_pdf: bool = True  # run LaTeX when it is installed
    envelope: tuple[Any, bytes] | None = None  # (Envelope, stability map PNG) when computed
    gain_table: Mapping[str, Any] | None = None  # c/manifest.json's "gain_table" when built
    # the build's own hold runs (by controller) when made at the actuator comparison's length
    # and step: the comparison reuses them for the selected actuator model
    hold_runs: Mapping[str, Any] | None = None
    # the embedded controller's region of attraction (regions, figure PNG) when computed
    roa: tuple[Any, bytes] | None = None
    # the build's verdict (`maglevgen.analyses.verdicts.EmbeddedVerdict`): the first page's
    # block; None: a build's cached one, else the linear checks only, said so
    verdict: Any = None
    # the build's noisy holds of the output-feedback loop (output_feedback.NoisyHold); ():
    # the sensing section shows none
    holds: tuple[Any, ...] = ()


class Pending(Protocol):
    """Figures being drawn elsewhere (a concurrent.futures Future, or build's job)."""

    def result(self) -> dict[str, bytes]: ...


SECTION_TITLES: dict[str, str] = {
    "summary": "Summary of findings",
    "parameters": "Parameters",
    "nomenclature": "Nomenclature",
    "conventions": "Coordinate conventions and state order",
    "rigid_body": "Rigid-body equations (eqs 1-2)",
    "force_law": "Halbach field and force law (eqs 3-4)",
    "circuit_lag": "Track circuit lag: first-order circuit dynamics",
    "geometry": "Geometry and force and moment sums (eqs 8-12)",
    "trim": "Trim",
    "stiffness": "Linearisation and stiffness (eqs 5-19)",
    "damping": "Damping control and allocation (eqs 20-23)",
    "riccati": "Riccati equations and LQR gains (eqs 24-33)",
    "poles": "Pole map",
    "paper": "Paper versus derivation",
    "verification": "Verification",
    "envelope": "Operating envelope",
    "sensing": "Sensors and estimation",
    "simulation": "Simulation",
}


def _quiet(_msg: str) -> None:
    pass


def _margin_speeds(carriage, env) -> list[float]:
    """v_min, the design speed (where it lies inside the envelope) and v_max: where the
    report shows the accelerating trim."""
    v = carriage.params.operation.speed
    return [env.v_min, *([v] if env.v_min < v < env.v_max else []), env.v_max]


def build_context(
    carriage,
    options: ReportOptions = ReportOptions(),
    progress: Callable[[str], None] = _quiet,
    figures: Pending | None = None,
) -> tuple[dict[str, Any], dict[str, bytes]]:
    """Everything the templates show, and the binary files (figures) the report includes.

    ``progress`` is called with a short message before each slow step. The force figures are
    drawn in a child process (concurrent.futures, fork) while this one builds the context:
    ``figures`` when the caller has them drawn already (`maglevgen build`), else here.
    """
    loaded = carriage.loaded
    folder = isinstance(options.simulation, str | Path)
    # bad input fails before the slow steps; a folder must come from these parameters
    sim, sim_files = simulation_section(options.simulation, loaded.sha256 if folder else None)
    progress("report: envelope (stability across speed, in the compiled library)")
    plant = Plant(carriage)  # its library loads quietly, as the envelope section loaded it
    env, env_png = envelope_section(plant, options.envelope)
    progress("report: region of attraction (sampled, in the compiled library)")
    regions, roa_png = roa_section(plant, options.roa)
    progress("report: trim and stiffness")
    trim = trim_point(plant, None)  # the compiled library's trim, as `maglevgen trim`
    pool = None
    if figures is None:
        pool = process_pool(1, mp_context=multiprocessing.get_context("fork"))
        own: Future = pool.submit(force_figures, force_curves(plant, trim))
        figures = own
    try:
        trep = trim_report(plant, None)
        progress("report: LQR gains, coupled comparison and allocation")
        gains = gains_report(plant, None)
        progress("report: symbolic forms")
        force = force_law_section(carriage, trim, trep)
        progress("report: the circuits' lag (the other circuit model's library and envelope)")
        lag, lag_png = circuit_lag(plant, env, gains)
        rigid = rigid_body_section()
        alloc = damping_allocation_section(gains)
        alloc["actuators"] = actuator_comparison_section(carriage, progress, options.hold_runs)
        sections = {
            "conventions": conventions_section(carriage.model),
            "rigid_body": rigid,
            "force_law": force,
            "circuit_lag": lag,
            "geometry": geometry_section(carriage, gains),
            "trim": trim_section(
                trep, accelerating_margins(plant, _margin_speeds(carriage, env))),
            "stiffness": stiffness_section(plant, trim, trep, gains),
            "damping": alloc,
            "riccati": riccati_section(gains),
        }
        progress("report: comparison with the paper")
        paper = paper_comparison_section(gains, trep)
        progress("report: verification")
        checks = verification_section(
            plant, gains, trep, rigid, alloc, paper, progress if options.verify_c else None
        ) + envelope_checks(plant, env)
        progress("report: figures")
        poles = pole_sets(gains)
        files = dict(figures.result())
    finally:
        if pool is not None:
            pool.shutdown(cancel_futures=True)
    files.update(sim_files.read())
    files[ENVELOPE_FIGURE] = env_png
    files[ROA_FIGURE] = roa_png
    files[POLE_FIGURE] = pole_map(poles)
    files[CIRCUIT_LAG_FIGURE] = lag_png
    sensing, sensing_files = sensing_section(carriage, env, options.holds)
    files.update(sensing_files)
    rows, notes = parameter_rows(loaded)
    envelope = envelope_context(plant, env, options.gain_table)
    envelope["roa"] = roa_context(regions)
    # the verdict deciding `build`'s exit code, as SUMMARY.md prints it (one source)
    verdict = (options.verdict or cached_verdict(carriage)
               or embedded_verdict(carriage, env, (), regions[0] if regions else None,
                                   complete=False))
    ctx: dict[str, Any] = {
        "version": __version__,
        "titles": SECTION_TITLES,
        "source": Path(loaded.source).name,
        "sha256": loaded.sha256,
        "overrides": list(loaded.overrides),
        "speed": trep["speed"],
        "parameters": {
            "rows": rows,
            "notes": notes,
            "choices": model_choices(loaded.params),
            "B0": force["B0_value"],
            "B0_paper": force["B0_paper"],
            "B0_rel": force["B0_rel"],
        },
        **sections,
        "paper": paper,
        "checks": checks,
        "envelope": envelope,
        "sensing": sensing,
        "simulation": sim,
        "poles": {"figure": POLE_FIGURE, "sets": poles, "speed_mode": gains["speed_mode"]},
        "summary": summary(trep, gains, paper, checks, envelope, sections["stiffness"], lag,
                           verdict),
        "figures": sorted(f for f in files if f.startswith("fig_")),
    }
    return ctx, files


def render_tex(ctx: dict[str, Any]) -> str:
    """report.tex from a context of `build_context`."""
    return latex_env().get_template("report.tex.j2").render(ctx)


@dataclass(frozen=True)
class ReportResult:
    """What `write_report` wrote."""

    out_dir: Path
    paths: list[Path]
    latex: LatexBuild
    failed_checks: list[str]  # verification rows whose error exceeds their bound


@dataclass(frozen=True)
class ReportFiles:
    """The report's files in memory, how LaTeX went and which checks failed."""

    files: dict[str, bytes]
    latex: LatexBuild
    failed_checks: list[str]


_KEEP = (".tex", ".pdf", ".log", ".png")


def render_report(
    carriage,
    options: ReportOptions = ReportOptions(),
    progress: Callable[[str], None] = _quiet,
    failed_dir: Path | None = None,
    figures: Pending | None = None,
) -> ReportFiles:
    """report.tex, its figures and, when ``options.build_pdf`` and TeX is installed,
    report.pdf and report.log: every file in memory.

    A LaTeX failure raises MaglevError naming the first error line and the log, kept with the
    failed build in ``failed_dir`` (default: a new temporary folder). ``figures``: see
    `build_context`.
    """
    ctx, files = build_context(carriage, options, progress, figures)
    progress("report: rendering report.tex")
    files["report.tex"] = render_tex(ctx).encode("utf-8")
    failed = [
        re.sub(r"\\texttt\{([^}]*)\}|\\", r"\1", c.what).replace("\\_", "_")
        for c in ctx["checks"]
        if c.status == "FAIL" and not c.finding
    ]
    result = LatexBuild(None, False, 0.0)
    if not (options.build_pdf and latex.find_tex() is not None):
        return ReportFiles(files, result, failed)
    with tempfile.TemporaryDirectory(prefix="maglevgen-report.") as scratch:
        build = Path(scratch)
        for name, data in sorted(files.items()):
            (build / name).write_bytes(data)
        progress("report: LaTeX, building report.pdf")
        result = latex.run_latex(build)
        if not result.ok:
            where = _keep_failed(build, failed_dir)
            raise MaglevError(f"LaTeX failed: {result.error} (log: {where})")
        files = {
            p.name: p.read_bytes()
            for p in sorted(build.iterdir())
            if p.is_file() and p.suffix in _KEEP
        }
    return ReportFiles(files, result, failed)


def _keep_failed(build: Path, failed_dir: Path | None) -> Path | str:
    """Copy a failed LaTeX build where the user can read its log; the log's path."""
    try:
        if failed_dir is None:
            failed_dir = Path(tempfile.mkdtemp(prefix="maglevgen-report-failed."))
        shutil.rmtree(failed_dir, ignore_errors=True)
        shutil.copytree(build, failed_dir)
        return failed_dir / "report.log"
    except OSError:
        return "not kept: the failed build could not be copied"


def report_files(
    carriage,
    simulation: Mapping[str, bytes | str] | None = None,
    pdf: bool = True,
    progress: Callable[[str], None] = _quiet,
    figures: Pending | None = None,
    envelope: tuple[Any, bytes] | None = None,
    gain_table: Mapping[str, Any] | None = None,
    hold_runs: Mapping[str, Any] | None = None,
    roa: tuple[Any, bytes] | None = None,
    verdict: Any = None,
    holds: tuple[Any, ...] = (),
) -> dict[str, bytes]:
    """The report's files in memory, for a caller that writes them itself (`maglevgen build`).

    ``simulation``: the files of a `maglevgen simulate` run (name -> content), or None;
    ``figures``: the report's figures being drawn already (see `build_context`);
    ``gain_table``: c/manifest.json's entry of the firmware table (else fitted here);
    ``hold_runs``: ReportOptions.hold_runs; ``roa``: ReportOptions.roa; ``verdict``:
    ReportOptions.verdict; ``holds``: ReportOptions.holds.
    """
    options = ReportOptions(simulation=simulation, build_pdf=pdf, envelope=envelope,
                            gain_table=gain_table, hold_runs=hold_runs, roa=roa,
                            verdict=verdict, holds=tuple(holds))
    return render_report(carriage, options, progress, figures=figures).files


def write_report(
    carriage,
    out_dir: Path,
    options: ReportOptions = ReportOptions(),
    progress: Callable[[str], None] = _quiet,
) -> ReportResult:
    """Render the report (`render_report`) and write it to ``out_dir`` at once
    (maglevgen.infrastructure.output.write_output swaps the folder in).

    On a LaTeX failure ``out_dir`` is left as it was and the failed build is kept in
    ``.<name>.failed`` beside it.
    """
    out_dir = Path(out_dir).resolve()
    res = render_report(carriage, options, progress,
                        failed_dir=out_dir.parent / f".{out_dir.name}.failed")
    paths = write_output(res.files, out_dir)
    return ReportResult(out_dir, paths, res.latex, res.failed_checks)
