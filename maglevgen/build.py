"""`maglevgen build`: the main job. Parameters -> C -> library -> simulations -> report.

Slow, parameter-independent work is cached on disk (maglevgen.runtime.library: the derivation's C,
the compiled library, the lambdified model), so after a parameter edit only the
parameter-dependent steps run. The whole output tree is assembled in a temporary folder and
swapped in at once (maglevgen.infrastructure.output); BUILD.json records the key of the inputs and
every
file's checksum, so an unchanged rebuild verifies the tree and does nothing else.
"""

from __future__ import annotations

import json
import re
import shutil
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Executor, ThreadPoolExecutor
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

from maglevgen.analyses.verdicts import (
    EmbeddedVerdict,
    JudgedRun,
    build_holds,
    embedded_runs,
    embedded_verdict,
    store_verdict,
    verify_embedded,
)
from maglevgen.derive import conventions as cv
from maglevgen.errors import VerificationError
from maglevgen.infrastructure import progress
from maglevgen.infrastructure.cache import DEFAULT_PARAMS_NAME, params_digest, toolchain_fingerprint
from maglevgen.infrastructure.columns import fcolumn_plain
from maglevgen.infrastructure.hashing import ContentHash, file_sha256, sha256_hex
from maglevgen.infrastructure.output import (
    MARKER,
    check_writable,
    clean_stale_siblings,
    foreign_entry,
    owned_names,
    write_output,
)
from maglevgen.infrastructure.text import markdown_code, shown_name
from maglevgen.infrastructure.workers import Job, PendingFiles, Shared, child, submit
from maglevgen.version import __version__

if TYPE_CHECKING:
    from maglevgen.params import LoadedParams

__all__ = ["MESSAGE_LIMIT", "STAMP", "BuildOptions", "BuildResult", "build_changes",
           "build_folder", "build_key", "other_structures", "run_build", "up_to_date",
           "verify_embedded"]

STAMP = "BUILD.json"
SUMMARY = "SUMMARY.md"


@dataclass(frozen=True)
class BuildOptions:
    t_end: float = 10.0
    dt: float = 1e-3
    pdf: bool = True
    allow_unstable: bool = False  # not in the key: it changes the exit code only

    def as_dict(self) -> dict:
        return {"t_end": self.t_end, "dt": self.dt, "pdf": self.pdf}


def _compiler_identity() -> str:
    from maglevgen.runtime.compile import compiler_name

    name = compiler_name()
    return f"{name}={shutil.which(name)}"


def build_key(params_sha256: str, overrides: tuple[str, ...], opts: BuildOptions,
              tex: str | None) -> str:
    """Everything a build's output depends on, hashed (the parameters by their text's digest:
    the same text always validates the same way, and the validator is part of the toolchain)."""
    return ContentHash(json.dumps({"params_sha256": params_sha256, "overrides": list(overrides),
                                   "options": opts.as_dict(), "compiler": _compiler_identity(),
                                   "tex": tex}, sort_keys=True),
                       toolchain_fingerprint()).hexdigest()


def build_changes(out_dir: Path, key: str) -> str | None:
    """What differs between ``out_dir`` and a complete build for ``key`` (one line), or None
    when it is one: the stamp's key, then every path of the folder against the stamp's list
    (a file removed, changed, replaced by a symbolic link, added; an entry naming a place
    outside the folder), the output marker listing the same files."""
    stamp_path = out_dir / STAMP
    if not out_dir.is_dir():
        return "no build there yet"
    if stamp_path.is_symlink() or not stamp_path.is_file():
        return f"no {STAMP} there"
    try:
        stamp = json.loads(stamp_path.read_text(encoding="utf-8"))
        if not isinstance(stamp, dict) or stamp.get("key") != key:
            return "the inputs, the options or the toolchain changed"
        listed = stamp["files"]
        if not isinstance(listed, dict):
            return f"{STAMP} lists no files"
        names = owned_names(out_dir)
        expected = {*listed, STAMP, MARKER}
        if names != expected:  # an entry outside the folder, or lists that disagree
            return f"{STAMP} or {MARKER} does not list the folder's files"
        for name, digest in sorted(listed.items()):
            path = out_dir / name
            shown = shown_name(name)
            if any(p.is_symlink() for p in (path, *path.parents) if out_dir in p.parents):
                return f"{shown} is a symbolic link"
            if not path.is_file():
                return f"{shown} was removed"
            if file_sha256(path) != digest:
                return f"{shown} changed"
        extra = foreign_entry(out_dir, expected)
        if extra is not None:
            return f"{shown_name(extra)} was added"
    except (OSError, ValueError, KeyError, AttributeError, TypeError) as exc:
        return f"{STAMP} cannot be read ({type(exc).__name__})"
    return None


def up_to_date(out_dir: Path, key: str) -> bool:
    """The folder holds a complete build for ``key`` and nothing else (`build_changes`)."""
    return build_changes(out_dir, key) is None


def cached_result(params_path: str | None, overrides: list[str], out_dir: Path,
                  opts: BuildOptions, why: list[str] | None = None) -> BuildResult | None:
    """The result of an up-to-date folder, checked from the parameter text alone (no schema,
    no derivation imported); None when anything needs building or cannot be read (and, for a
    folder holding a build, the line saying what changed appended to ``why``)."""
    try:
        if params_path is None:
            text = resources.files("maglevgen").joinpath(DEFAULT_PARAMS_NAME).read_text("utf-8")
        else:
            text = Path(params_path).read_text(encoding="utf-8")
        out_dir = Path(out_dir).resolve()
    except (OSError, UnicodeDecodeError):
        return None
    tex = _find_tex() if opts.pdf else None
    key = build_key(params_digest(text, overrides), tuple(overrides), opts, tex)
    changed = build_changes(out_dir, key)
    if changed is not None:
        if why is not None and (out_dir / STAMP).exists():
            why.append(f"rebuilding {shown_name(out_dir)}: {changed}")
        return None
    clean_stale_siblings(out_dir)  # what killed builds into this folder left beside it
    return _unchanged(out_dir)


def _unchanged(out_dir: Path) -> BuildResult:
    summary = (out_dir / SUMMARY).read_text()
    stamp = json.loads((out_dir / STAMP).read_text())
    # the stamp lists every file but itself and the output marker: counted too, as the build
    # that wrote them did
    return BuildResult(out_dir, False, summary, (*stamp["files"], STAMP, MARKER),
                       stamp.get("verification"), stamp.get("warning"))


@dataclass(frozen=True)
class BuildResult:
    out_dir: Path
    rebuilt: bool
    summary: str
    files: tuple[str, ...]
    verification: str | None = None  # why the build's verification failed (exit 3)
    warning: str | None = None  # the runs' one-line warning (a speed outside the envelope)

    def warnings(self, allow_unstable: bool = False) -> list[str]:
        """What the build warns about: the runs' warning, and the failed verification when
        ``allow_unstable`` lets it pass."""
        return [w for w in (self.warning, self.verification if allow_unstable else None) if w]

    def failure(self, allow_unstable: bool = False) -> VerificationError | None:
        """The error of a failed verification (exit 3) unless ``allow_unstable``: one short
        line (`verification_line`), the whole reason as its details."""
        if self.verification is None or allow_unstable:
            return None
        return VerificationError(verification_line(self.verification, self.out_dir / SUMMARY),
                                 self.verification)

    def verdicts(self) -> str:
        """SUMMARY.md's head: the parameter file and the verdicts, up to the outputs' list
        (what an unchanged rebuild prints)."""
        head = self.summary.split("\nOutputs:", 1)[0].rstrip()
        return head.split("\n", 1)[1].strip() + "\n" if "\n" in head else head + "\n"


def _shown(path: Path) -> str:
    """``path`` as a user names it: relative to the working folder when inside it."""
    try:
        return str(Path(path).relative_to(Path.cwd()))
    except ValueError:
        return str(path)


#: the longest exit-3 line (the details are in SUMMARY.md and --debug)
MESSAGE_LIMIT = 200


def verification_line(reason: str, summary: Path, limit: int = MESSAGE_LIMIT) -> str:
    """The one line `build` exits 3 with: which controller failed, the start of the first
    failed check and where to read the rest (``summary``, --debug), within ``limit``
    characters where the folder's name allows."""
    m = re.match(r"verification failed: the embedded controller (\S+ = '[^']*') (.*)", reason)
    key, rest = m.groups() if m else ("", reason.removeprefix("verification failed: "))
    rest = re.sub(r" \((maglevgen |--allow)[^()]*\)$", "", rest)  # the commands: in the details
    head = f"verification failed: {key}" if key else "verification failed"
    tail = f" (all of it: {_shown(summary)}, or --debug; --allow-unstable to accept)"
    room = max(limit - len(head) - len(tail) - 2, 24)
    if len(rest) > room:
        rest = rest[: room - 3].rsplit(" ", 1)[0].rstrip(",;") + "..."
    return f"{head}{' ' if rest.startswith('is ') else ': '}{rest}{tail}"


def build_folder(params: str | Path | None, overrides: Sequence[str], out_dir: str | Path,
                 opts: BuildOptions, controller: str | None = None,
                 step: Callable[[str], None] | None = None, bar=None) -> BuildResult:
    """`maglevgen build` and `maglevgen.Carriage.build`: ``out_dir`` brought up to date for
    the parameter file ``params`` (None: the LLNL carriage) with ``overrides``.

    An up-to-date folder is recognised from the parameter text alone (`cached_result`: no
    schema, numpy or derivation imported). Otherwise the input is checked before anything
    slow is announced (the parameters, --t-end and --dt, the folder), with the steps
    announced meanwhile held back (`progress.held`): bad input is then the only line on
    stderr. The envelope's trim, which needs the compiled library, is checked next, with its
    steps announced as they start (`check_build_inputs`). ``controller``: the same as ``--set
    envelope.embedded_controller="NAME"``. ``step`` announces the steps (None: quiet),
    ``bar`` opens a progress bar (`progress.bar`).
    """
    overrides = list(overrides)
    if controller:
        overrides.append(f'envelope.embedded_controller="{controller}"')
    out_dir = Path(out_dir)
    why: list[str] = []
    res = cached_result(None if params is None else str(params), overrides, out_dir, opts, why)
    if res is not None:
        return res
    from maglevgen.params import check_run_options, load_params

    step = step or (lambda _: None)
    with progress.held():  # bad input found here is the only line on stderr
        for line in why:
            step(line)
        loaded = load_params(params, overrides)
        check_run_options(opts.t_end, opts.dt)
        check_writable(out_dir)  # before any work (the library, the model)
    # the checks that need the compiled library, announced as they go: on a cold cache they
    # take minutes (a speed range without trim is then reported after those lines)
    check_build_inputs(loaded, step)
    return run_build(loaded, out_dir, opts, step=step, bar=bar)


def _find_tex() -> str | None:
    return shutil.which("latexmk") or shutil.which("pdflatex")


def check_build_inputs(loaded: LoadedParams, step: Callable[[str], None] = lambda _: None,
                       ) -> None:
    """The checks of a build's input that need the compiled library: the envelope's speed
    range has a trim (envelope.v_min above lift-off); an InputError naming the key otherwise.
    The library is cached for run_build, and so are the other models' (`other_structures`),
    built meanwhile in a second process; ``step`` announces what a cold cache makes."""
    from maglevgen.carriage import DerivedCarriage
    from maglevgen.control.carriage_plant import Plant
    from maglevgen.runtime.library import (
        build_libraries,
        cached_simulation_library,
        runtime_sources,
        simulation_library,
    )

    carriage = DerivedCarriage(loaded)
    others = [s for s in other_structures(carriage) if cached_simulation_library(s) is None]
    # a cold cache: the other models' libraries (which run_build's envelope and report read)
    # derived and compiled in a second process while this one makes the carriage's own
    with child() as building:
        pending = (submit(building, "building the other models' libraries", build_libraries,
                          tuple(others)) if others else None)
        if others:
            step(f"deriving and compiling {len(others)} other models' libraries in a second "
                 "process (cached afterwards)")
        lib = cached_simulation_library(carriage.structure)
        if lib is None:  # a cold cache: while gcc compiles the library (its own process),
            # this one lambdifies the model (the report's verification reads it; cached
            # afterwards), as run_build does, instead of waiting for gcc and lambdifying it
            # at the end of the build with nothing else left to overlap it. The derivation
            # first, alone: it and the lambdifying both hold the GIL, and gcc can only start
            # once it is done
            runtime_sources(carriage.structure, progress=step)
            with ThreadPoolExecutor(max_workers=1) as pool:
                compiling = pool.submit(simulation_library, carriage.structure, progress=step)
                step("lambdifying the model for the report's check while gcc compiles "
                     "(cached afterwards)")
                carriage.functions  # noqa: B018
                if not compiling.done():
                    step("compiling the simulation library (cached afterwards)")
                lib = compiling.result()
        progress.announce("envelope: checking the trim at envelope.v_min and v_max")
        Plant(carriage, lib).speed_range  # noqa: B018  (an InputError naming the key)
        if pending is not None and not pending.future.done():
            step("waiting for the other models' libraries (second process)")
        if pending is not None:
            pending.result()


def run_build(loaded: LoadedParams, out_dir: Path, opts: BuildOptions, step=print,
              bar=None) -> BuildResult:
    """Bring ``out_dir`` up to date for the parameters ``loaded``."""
    out_dir = check_writable(out_dir)
    tex = _find_tex() if opts.pdf else None
    key = build_key(loaded.sha256, loaded.overrides, opts, tex)
    if up_to_date(out_dir, key):
        return _unchanged(out_dir)

    from maglevgen.analyses import roa
    from maglevgen.analyses.envelope import compute_envelope, envelope_markdown
    from maglevgen.analyses.sim_loop import flown_loop
    from maglevgen.analyses.sim_output import (
        FIGURE_NAMES,
        render_figures,
        render_metrics,
        render_trajectories,
        trajectory_names,
    )
    from maglevgen.analyses.simulate import run_scenarios
    from maglevgen.carriage import DerivedCarriage
    from maglevgen.control.built_loop import Loop
    from maglevgen.control.carriage_plant import Plant
    from maglevgen.controllers import names as controller_names
    from maglevgen.infrastructure.cache import STORE
    from maglevgen.runtime.library import (
        build_libraries,
        cached_simulation_library,
        runtime_sources,
        simulation_library,
    )

    STORE.progress = step  # announce the derivation steps that are not cached yet
    carriage = DerivedCarriage(loaded)
    files: dict[str, str | bytes] = {}
    others = [s for s in other_structures(carriage) if cached_simulation_library(s) is None]
    # the other models' libraries (the envelope's model checks, the report's comparisons),
    # when not cached: derived and compiled in a second process (forked now, before this one
    # starts any thread) while this one builds its own library and runs the simulations
    with child() as building:
        pending = (submit(building, "building the other models' libraries", build_libraries,
                          tuple(others)) if others else None)
        if others:
            step(f"deriving and compiling {len(others)} other models' libraries in a second "
                 "process (cached afterwards)")
        lib = cached_simulation_library(carriage.structure)
        if lib is None:  # first build of this structure: gcc compiles (in its own process)
            # while this one lambdifies the model (both cached afterwards); the derivation
            # first, alone (it and the lambdifying both hold the GIL; gcc waits for it)
            runtime_sources(carriage.structure, progress=step)
            with ThreadPoolExecutor(max_workers=1) as pool:
                compiling = pool.submit(simulation_library, carriage.structure, progress=step)
                carriage.functions  # noqa: B018
                lib = compiling.result()
        # simulations (validates the speed's trim and the step against RK4's stability
        # limit); up to here a parameter edit has imported no SymPy, SciPy or CasADi
        step(f"simulations: the hold runs of {len(controller_names())} controllers in the firmware "
             f"loop ({opts.t_end:g} s at dt {opts.dt:g} s)")
        plant = Plant(carriage, lib)
        run = run_scenarios(plant, controller_names(), opts.t_end, opts.dt, bar=bar,
                            loop=Loop.FIRMWARE)
        if pending is not None:
            pending.result()  # the envelope's model checks read them from the cache
    # the noisy holds of the output-feedback loop (the firmware's sense tick, about 3 s per
    # 20 s hold)
    # in a child from here, while this process runs the envelope, the judged runs and the
    # region of attraction
    v_min, v_max = plant.speed_range
    with child(shared={"plant": plant}) as holding:
        holds_job = submit(holding, "the noisy holds of the output-feedback loop", build_holds,
                           Shared("plant"), v_min, v_max, opts.t_end)
        if carriage.params.sensors is not None:
            step("the embedded controller's noisy holds with its sensors and Kalman filter "
                 "(output-feedback loop, in a second process)")
        step("envelope: stability of each controller across the speed range")
        env = compute_envelope(plant)
        step("the embedded controller's hold and launch runs against [control.spec]")
        judged = embedded_runs(plant, env, run.op.speed, opts.t_end, opts.dt)
        step("envelope: the embedded controller's region of attraction (sampled)")
        regions = roa.study(plant, [carriage.params.envelope.embedded_controller],
                            roa.BUILD_SPEEDS, roa.BUILD_SAMPLING, flown_loop(plant))
        holds = holds_job.result()
    # every check deciding the exit code, once: SUMMARY.md, stdout and the report's first
    # page print its lines
    verdict = embedded_verdict(carriage, env, judged, regions[0], holds=holds)
    store_verdict(carriage, verdict, opts.t_end, opts.dt)
    # One child draws every figure (one matplotlib import for the simulation's and the
    # report's) and writes the trajectories, while this process imports the symbolic layers
    # and builds the report's context. Its jobs in the order they are needed: the simulation
    # figures, the report's figures (as soon as the trim is known), then the trajectories,
    # which it already holds (forked with them) and nothing reads before the end.
    with child(shared={"trajectories": run.trajectories}) as drawing:
        figures = submit(drawing, "drawing the figures", render_figures, Shared("trajectories"))
        step("c/: the run-time-parameter C, the interface and the gain table")
        files.update(_c_files(carriage, runtime_sources(carriage.structure, progress=step),
                              plant))
        files.update(_gain_table_c(plant, env, files["c/manifest.json"]))
        files["lib/libmaglev.so"] = lib.path.read_bytes()
        step("report: trim and force figures")
        report_figures = _draw_report_figures(drawing, plant)
        mapping = submit(drawing, "drawing the stability map", _stability_map, env)
        region_fig = submit(drawing, "drawing the region of attraction", roa.study_files,
                            regions)
        writing = submit(drawing, "writing the trajectories", render_trajectories,
                         Shared("trajectories"), run.input_names)
        sim_files = PendingFiles(render_metrics(run.trajectories, run.header(loaded.sha256)),
                                 {**dict.fromkeys(FIGURE_NAMES, figures),
                                  **dict.fromkeys(trajectory_names(run.trajectories), writing)})
        # the report (and its PDF where TeX is installed)
        stability_map = mapping.result()
        region_files = region_fig.result()
        report = _report_files(carriage, sim_files, opts, step, report_figures,
                               (env, stability_map["envelope/stability_map.png"]),
                               json.loads(files["c/manifest.json"])["gain_table"], run,
                               (regions, region_files["roa_extent.png"]), verdict, holds)
        files.update({f"simulation/{n}": sim_files[n] for n in sim_files})
        files.update(stability_map)
        files.update({f"envelope/{n}": b for n, b in region_files.items()})
    files.update({f"report/{n}": b for n, b in report.items()})
    step("SUMMARY.md, the schedule's C and the envelope's files; writing the folder")
    files["c/maglev_schedule.c"] = _schedule_c(plant, env)
    files["envelope/envelope.json"] = json.dumps(env.to_json(), indent=1) + "\n"
    files["envelope/envelope.md"] = envelope_markdown(env)
    summary = summary_text(plant, run, env, report_outputs(report, opts), regions,
                           judged, verdict)
    verification = verdict.reason
    if verification is not None:  # the whole reason (`build` exits 3 with its first words)
        said = verification.removeprefix("verification failed: ")
        summary += f"\nVerification failed (`maglevgen build` exits 3): {said}.\n"
    files[SUMMARY] = summary
    digests = {n: sha256_hex(b) for n, b in sorted(files.items())}
    files[STAMP] = json.dumps({"key": key, "maglevgen": __version__,
                               "params_sha256": loaded.sha256,
                               "overrides": list(loaded.overrides), "options": opts.as_dict(),
                               "verification": verification, "warning": run.warning,
                               "files": digests},
                              indent=1) + "\n"
    write_output(files, out_dir)
    return BuildResult(out_dir, True, summary, tuple(sorted([*files, MARKER])), verification,
                       run.warning)


def other_structures(carriage) -> list:
    """The structures, other than the carriage's own, whose libraries a build reads: the
    envelope's alternate models (maglevgen.analyses.envelope.alternate_models: the other force law,
    the other circuit dynamics, which the report's stiffness and circuit-lag sections compare
    too) and the report's other actuator models (report.sections.actuators.with_actuators:
    only control.actuators changed, whose structure is made here without importing the
    report, SymPy and SciPy), in that order, each once."""
    from maglevgen.analyses.envelope import alternate_models
    from maglevgen.carriage import structure_of
    from maglevgen.params import ACTUATOR_MODELS

    params = carriage.params
    out = [alt.structure for _, alt in alternate_models(carriage)]
    out += [structure_of(params.model_copy(update={"control": params.control.model_copy(
        update={"actuators": name})})) for name in ACTUATOR_MODELS]
    return [s for i, s in enumerate(out) if s != carriage.structure and s not in out[:i]]


def _schedule_c(plant, env) -> str:
    """c/maglev_schedule.c: the embedded controller's launch schedule over ``env``'s range
    (what maglev_launch runs: the accelerating trim's reference and drag at
    envelope.launch_acceleration, the constant-speed gains on the envelope's loop as built,
    the design at the tick with its K_lag and K_delay; `Plant.launch_schedule`)."""
    import numpy as np

    from maglevgen.control.schedule import schedule_c_source

    nodes = np.linspace(env.v_min, env.v_max, plant.params.envelope.schedule_nodes)
    return schedule_c_source(plant.launch_schedule(plant.points(nodes),
                                                   plant.params.envelope.embedded_controller,
                                                   setting=env.loop))


def _gain_table_c(plant, env, manifest: str | bytes) -> dict[str, str]:
    """c/maglev_gain_table.{c,h}: the firmware's table schedule over ``env``'s range, and its
    measured worst error added to c/manifest.json (``gain_table``)."""
    from maglevgen.control.schedule import gain_table_sources

    table = plant.gain_table(env.v_min, env.v_max)
    data = json.loads(manifest)
    data["gain_table"] = table.manifest()
    return {**{f"c/{n}": t for n, t in gain_table_sources(table, one_output="F_prop").items()},
            "c/manifest.json": json.dumps(data, indent=2) + "\n"}


def _stability_map(env) -> dict[str, bytes]:
    from maglevgen.analyses.envelope_figures import disk_margins_png, stability_map_png

    out = {"envelope/stability_map.png": stability_map_png(env)}
    margins = next((c.margins for c in env.controllers.values() if c.margins is not None), None)
    if margins is not None:  # the embedded controller's
        out["envelope/disk_margins.png"] = disk_margins_png(margins)
    return out


def _c_files(carriage, folder: Path, plant) -> dict[str, str | bytes]:
    """c/: the cached run-time-parameter sources, and the interface files for these parameters
    (maglev.h, main.c with the embedded controller's example, CMake example, manifest)."""
    from maglevgen.analyses.verdicts import generate_example
    from maglevgen.codegen.interface import FUNCTION_TABLE, GenerateOptions, render_interface

    files: dict[str, str | bytes] = {f"c/{f.name}": f.read_bytes()
                                     for f in sorted(folder.iterdir()) if f.suffix in (".c", ".h")}
    table = json.loads((folder / FUNCTION_TABLE).read_text())
    for name, text in render_interface(carriage, GenerateOptions("double", "runtime"),
                                       table, None, generate_example(plant)).items():
        files[f"c/{name}"] = text
    return files


def _draw_report_figures(drawing: Executor, plant) -> Job:
    """Have ``drawing`` draw the report's force figures at the compiled library's trim (the
    curves are the library's array forces; v_c, eq 3's displayed form, imports SymPy)."""
    from maglevgen.analyses.queries import trim_point
    from maglevgen.report import force_curves
    from maglevgen.report.figures import force_figures

    return submit(drawing, "drawing the report figures", force_figures,
                  force_curves(plant, trim_point(plant, None)))


def _report_files(carriage, sim_files: Mapping[str, bytes], opts: BuildOptions,
                  step, figures: Job, envelope, gain_table: Mapping, run,
                  region=None, verdict: EmbeddedVerdict | None = None,
                  holds: tuple = ()) -> dict[str, bytes]:
    """report.tex (+ report.pdf) with the simulation figures and its own ``figures``;
    ``gain_table``: c/manifest.json's entry (the report shows its numbers); ``run``: the
    build's hold runs, which the actuator comparison reuses when they have its length and step;
    ``region``: (the regions of attraction, their figure); ``verdict``: the first page's;
    ``holds``: the noisy holds (the sensing section's table)."""
    from maglevgen.report import RUN_DT, RUN_T_END, report_files

    same = (opts.t_end, opts.dt) == (RUN_T_END, RUN_DT) and run.scenario == "hold"
    return report_files(carriage, sim_files, pdf=opts.pdf, progress=step, figures=figures,
                        envelope=envelope, gain_table=gain_table,
                        hold_runs={t.controller: t for t in run.trajectories} if same else None,
                        roa=region, verdict=verdict, holds=holds)


def report_outputs(report: Mapping[str, bytes], opts: BuildOptions) -> str:
    """What report/ holds, and why report.pdf is not among them when it is not."""
    from maglevgen.infrastructure.texsetup import INSTALL_HINT

    names = ", ".join(n for n in ("report.tex", "report.pdf") if n in report)
    if "report.pdf" in report:
        return f"report/ ({names})"
    why = ("--no-pdf was given" if not opts.pdf
           else f"TeX is not installed: `{INSTALL_HINT}` (or `make run` as root), then rerun")
    return f"report/ ({names}; report.pdf skipped: {why})"


def summary_text(plant, run, env, report: str = "report/ (report.tex)",
                 regions=None, judged: tuple[JudgedRun, ...] = (),
                 verdict: EmbeddedVerdict | None = None) -> str:
    """Where each output is, and the numbers an engineer checks first; ``report``: what
    report/ holds (see `report_outputs`); ``regions``: the embedded controller's region of
    attraction (maglevgen.analyses.roa), when computed; ``judged``: the embedded controller's
    runs against [control.spec] (`embedded_runs`); ``verdict``: the block deciding the exit
    code (`maglevgen.analyses.verdicts`; default: from ``env``, ``judged`` and ``regions``)."""
    from maglevgen.analyses.queries import stiffness_table

    carriage = plant.carriage
    rows = stiffness_table(plant, run.op.speed)
    # one table per kind of axis, so that each column is one quantity in one unit
    # (units as a person writes them: a '*' in a Markdown table starts emphasis)
    kinds = (("Translation", (0, 1), {"k": _md_unit(rows[0].unit), "m": "kg", "c": "N s/m"}),
             ("Rotation", (2, 3, 4), {"k": _md_unit(rows[2].unit), "m": "kg m^2",
                                      "c": "N m s/rad"}))
    if verdict is None:
        verdict = embedded_verdict(carriage, env, judged, regions[0] if regions else None)
    lines = [*_summary_verdicts(carriage, run, env, regions, verdict),
             *_summary_trim(plant, run, env, report),
             *_summary_axes(carriage, run, plant.lib, rows, kinds),
             *_summary_paper(plant, run, rows),
             *_summary_runs(carriage, run, judged)]
    return "\n".join(lines) + "\n"


def _summary_verdicts(carriage, run, env, regions, verdict: EmbeddedVerdict) -> list[str]:
    """The file and overrides, then the verdict block (`EmbeddedVerdict.lines`: every check
    deciding the exit code, then the findings about the other controllers), what the
    specification was checked on, and the region of attraction."""
    embedded = carriage.params.envelope.embedded_controller
    loaded = carriage.loaded
    # the file's name and the overrides as the user typed them: escaped (maglevgen's text)
    sets = ", ".join(markdown_code(f"--set {o}") for o in loaded.overrides) or "none"
    lines = [f"# maglevgen build: {shown_name(loaded.source, markdown=True)}", "",
             f"Parameter file: {markdown_code(loaded.source)} (sha256 {loaded.sha256[:16]}...); "
             f"overrides: {sets}.", ""]
    if run.warning:
        lines += [f"Warning: {run.warning}.", ""]
    lines += [*verdict.lines(), "",
              "Details: envelope/envelope.md, envelope/stability_map.png, "
              "envelope/disk_margins.png, envelope/roa.md, simulation/metrics.md.", "",
              f"The specification ([control.spec]) was checked {env.checked_on()}.",
              env.firmware_design(embedded)]
    if regions:
        from maglevgen.analyses.roa import summary_lines

        lines += ["", *summary_lines(regions[0])]
    return lines


def _summary_trim(plant, run, env, report: str) -> list[str]:
    """The outputs, the trim at the design speed and the accelerating trim at v_min."""
    from maglevgen.analyses.queries import accelerating_margins

    carriage = plant.carriage
    op = run.op
    names = list(carriage.params.arrays)
    return ["",
            "Outputs: c/ (run-time-parameter C, maglev.h, CMake example, maglev_schedule.c), "
            "lib/libmaglev.so, simulation/ (trajectories, figs 3-8, metrics.md), envelope/, "
            f"{report}.", "",
            f"Trim at {op.speed:g} m/s: heave {op.x_trim[cv.STATE_INDEX['z']] * 1e3:+.4f} mm, "
            f"pitch {op.x_trim[cv.STATE_INDEX['theta']] * 1e3:+.4f} mrad, "
            f"F_prop {op.f_prop:.4g} N; closest-corner gap "
            "per array: " + ", ".join(f"{n} {g * 1e3:.3f} mm" for n, g in zip(names, op.gaps,
                                                                              strict=True))
            + f" (track.min_gap {carriage.params.track.min_gap * 1e3:g} mm).", "",
            accelerating_margins(plant, [env.v_min])[0].sentence(), ""]


def _summary_axes(carriage, run, lib, rows, kinds) -> list[str]:
    """The stiffness tables (derived, printed, the plant) and the gain tables per kind of
    axis."""
    import numpy as np

    from maglevgen.analyses.magnetic_damping import axis_damping

    op = run.op
    k, m = (a.ravel() for a in lib.function("maglev_axis_plants")(op.speed, carriage.p))
    c_mag = axis_damping(op, m)  # the circuits' lag in the Jacobian's velocity columns
    lines = [f"Stiffness at trim: K_st0 (magnetic, the derivation's) beside the paper's printed "
             "eqs 13-19 and their difference from it; k = K_st0 plus the gravity and "
             "propulsion moments, the plant of the per-axis LQR, m its generalized mass "
             f"(model.circuit_dynamics = {carriage.params.model.circuit_dynamics}):", ""]
    for kind, idx, u in kinds:
        lines += [f"| {kind.lower()} axis | K_st0 [{u['k']}] | paper, printed [{u['k']}] | "
                  f"paper / K_st0 - 1 | k [{u['k']}] | m [{u['m']}] | f_n [Hz] |",
                  "| --- | --- | --- | --- | --- | --- | --- |"]
        # each column in one notation (fcolumn_plain): no 0.0002235 above 2.965e-05
        cols = [fcolumn_plain([rows[i].derived_magnetic for i in idx], 5),
                fcolumn_plain([rows[i].paper_value for i in idx], 5),
                [f"{rows[i].relative_difference:+.1%}" for i in idx],
                fcolumn_plain([k[i] for i in idx], 5), fcolumn_plain([m[i] for i in idx]),
                [f"{np.sqrt(max(k[i], 0.0) / m[i]) / (2 * np.pi):.3f}" for i in idx]]
        lines += [f"| {rows[i].axis} | " + " | ".join(c[j] for c in cols) + " |"
                  for j, i in enumerate(idx)]
        lines.append("")
    lines += ["Per-axis LQR gains (the paper's design, u = -(K1 a + K2 a')), the optimized "
              "damping c and the magnetic damping c_mag = -m A[rate, rate] of the circuits' "
              "lag at trim (negative feeds the motion):", ""]
    for kind, idx, u in kinds:
        lines += [f"| {kind.lower()} axis | K1 [{u['k']}] | K2 [{u['c']}] | damping c "
                  f"[{u['c']}] | magnetic c_mag [{u['c']}] |",
                  "| --- | --- | --- | --- | --- |"]
        cols = [fcolumn_plain([v[i] for i in idx])
                for v in (op.K[:, 0], op.K[:, 1], op.c_damping, c_mag)]
        lines += [f"| {rows[i].axis} | " + " | ".join(c[j] for c in cols) + " |"
                  for j, i in enumerate(idx)]
        lines.append("")
    return lines


def _summary_paper(plant, run, rows) -> list[str]:
    """Where the paper's printed forms differ from the derivation."""
    from maglevgen.analyses.queries import pitch_paper_form, trim_point

    pitch = pitch_paper_form(plant.carriage, trim_point(plant, run.op.speed),
                             next(r.paper_value for r in rows if r.axis == "pitch"))
    return ["Paper discrepancies found (details and evidence in the report):",
            "- printed stiffnesses (eqs 13-19) differ from the derived K_st0: "
            + ", ".join(f"{r.axis} {r.relative_difference:+.1%}" for r in rows) + ";",
            "- pitch (eq 15): the error is the net front force F_z3 - F_z1 - F_z2 where the "
            "upper and lower arrays' stiffnesses add (the arm L_x is right): printed "
            f"{pitch['printed']:.5g}, with the sum 2k sum_i F_i n_z,i^2 x_i^2 "
            f"{pitch['sum_of_contributions']:.5g}, derived {pitch['derived']:.5g} N m/rad;",
            "- eq 31 does not satisfy the Riccati equation eq 30, and eq 32's gain is not the "
            "LQR gain; the toolchain uses the derived closed form (stable in float32);",
            "- with Q = diag(state_weights), R = input_weight as in the paper the LQR damps "
            "heave and pitch less than the optimized damping (see simulation/metrics.md);",
            f"- the speed mode: {run.speed_mode.explanation()}.", ""]


def _summary_runs(carriage, run, judged) -> list[str]:
    """The simulations' statuses and their runs against [control.spec] (the embedded
    controller's judged runs are in the verdict block)."""
    lines = [f"Simulation `{traj.controller}`: {traj.status}"
             + (f" ({traj.event})" if traj.event else "") for traj in run.trajectories]
    lines += _run_spec_lines(run)
    return lines


def _md_unit(unit: str) -> str:
    """A unit as SUMMARY.md's tables print it: N m/rad, not N*m/rad."""
    return unit.replace("*", " ")


def _run_spec_lines(run) -> list[str]:
    """The runs against [control.spec] (`simulate.spec_verdict`): a block of its own."""
    from maglevgen.analyses.simulate import spec_verdict

    verdicts = [(t.controller, v) for t in run.trajectories
                if (v := spec_verdict(t)) is not None]
    if not verdicts:
        return []
    return ["", f"The {run.scenario} runs against [control.spec] (settling, peak deviation "
            "per axis, gap margin, speed held; simulation/metrics.md):", "",
            *(f"- `{c}`: {v.text()}" for c, v in verdicts)]
