"""BENCHMARKS.md from the results of bench/run.py (nothing here measures anything)."""

from __future__ import annotations

import json
import statistics
from importlib import import_module
from pathlib import Path

# BENCHMARKS.md from this line to its end holds the sections other scripts record on their own
# (run.OWN_SECTIONS' scripts, which a full run reruns in processes of their own, and
# bench/experiments/'s one-off measurements and the issues' runs, which it does not):
# a full run regenerates what is above the line and carries the rest over byte for byte.
KEPT_MARKER = "<!-- recorded separately: kept by make bench -->"
FIRMWARE_BEGIN = "<!-- firmware benchmark: bench/firmware.py -->"
# the headings of the sections run.py's last stages write: carried over when not measured
CARRIED_SECTIONS = {
    "envelope": "## Envelope and launch",
    "montecarlo": "## Monte Carlo (`maglevgen montecarlo`",
    "peers": "## Peers for the generated C",
}

CONTROLLER_GROUP = "controller_path"
# fewer instructions with calls: a wrapper, not the model's straight-line body
STRAIGHT_LINE_MIN = 1000
TEXT_LIMIT = 4096
DYNAMICS_LIMIT = 1.15
LOOP_LIMIT = 1.2


def _med(s: dict, fmt: str = "{:.3g}") -> str:
    """median [q1 - q3] of a summary."""
    return f"{fmt.format(s['median'])} [{fmt.format(s['q1'])}-{fmt.format(s['q3'])}]"


def _ratio(s: dict) -> str:
    return f"{s['median']:.3g}x [{s['q1']:.3g}-{s['q3']:.3g}]"


def _ns(s: dict) -> str:
    m = s["median"]
    if m >= 1e6:
        return _med({k: s[k] / 1e6 for k in ("median", "q1", "q3")}, "{:.3g}") + " ms"
    if m >= 1e3:
        return _med({k: s[k] / 1e3 for k in ("median", "q1", "q3")}, "{:.3g}") + " us"
    return _med(s, "{:.0f}") + " ns"


def _secs(s: dict) -> str:
    fmt = "{:.3g}" if s["median"] < 10 else "{:.1f}"
    return _med(s, fmt) + " s"


def _n(n: int, noun: str, plural: str | None = None) -> str:
    return f"{n} " + (noun if n == 1 else plural or noun + "s")


def _workflow_checks(wf: dict) -> list[str]:
    """What went differently from the plan in the workflow runs (empty: nothing)."""
    bad = []
    for kind in ("parameter_change", "with_pdf"):
        runs = wf[kind]["runs"]
        what = kind.replace("_", " ").replace("with pdf", "with-PDF")
        if not all(r["rebuilt"] for r in runs):
            bad.append(f"a {what} build did not rebuild")
        steps: dict[str, int] = {}
        for r in runs:
            for step in r["derived"]:
                steps[step] = steps.get(step, 0) + 1
        if steps:
            bad.append(
                f"{what} builds ({len(runs)}) announced derivation steps missing from the "
                "cache: " + ", ".join(f"`{k}` ({v}x)" for k, v in sorted(steps.items()))
            )
        if any(r["compiled"] for r in runs):
            n = sum(r["compiled"] for r in runs)
            bad.append(f"{n} of {len(runs)} {what} builds compiled the library")
    if any(r["rebuilt"] for r in wf["unchanged"]["runs"]):
        bad.append("an unchanged build regenerated its folder")
    return bad


def targets(r: dict) -> list[dict]:
    dyn = r["dynamics"]["c"]["generated_over_reference"]["median"]
    wf = _workflow_targets(r["workflow"]) if "workflow" in r else []
    loop = r["closed_loop"]["c"]["generated_over_reference"]["median"]
    ivp = next((v for k, v in r["closed_loop"].get("python", {}).items() if "solve_ivp" in k),
               None)
    text = r["footprint"]["groups"][CONTROLLER_GROUP]["text"]
    heap = r["footprint"]["heap_symbols"]
    return [
        *wf,
        {
            "name": f"generated maglev_dynamics within {DYNAMICS_LIMIT}x of the hand-written C "
            "(gcc -O2; the paper's model, the one the hand-written C computes)",
            "measured": f"{dyn:.3g}x",
            "met": dyn <= DYNAMICS_LIMIT,
        },
        {
            "name": f"closed loop (10 s, 1 kHz RK4) within {LOOP_LIMIT}x of the hand-written "
            "loop (gcc -O2; the paper's model)",
            "measured": f"{loop:.3g}x",
            "met": loop <= LOOP_LIMIT,
        },
        *(
            [{
                "name": "solve_ivp on the CSE-lambdified model: ratio recorded",
                "measured": f"{ivp['over_generated_c']['median']:.3g}x slower than the "
                "generated C (distributed law)",
                "met": True,
            }]
            if ivp
            else []
        ),
        {
            "name": f"controller path (gains + control + allocation) under "
            f"{TEXT_LIMIT // 1024} KiB of .text (float32, baked, -Os)",
            "measured": f"{text} B ({text / TEXT_LIMIT:.2f}x the limit)",
            "met": text < TEXT_LIMIT,
        },
        {
            "name": "no heap in the generated C",
            "measured": "no allocator symbols" if not heap else ", ".join(heap),
            "met": not heap,
        },
        *_montecarlo_targets(r.get("montecarlo")),
        *_lanes_targets(r.get("simd_batch"), r.get("casadi_peer")),
    ]


def _workflow_targets(wf: dict) -> list[dict]:
    lim = wf["limits_s"]
    cold = wf["cold"]["s"]["median"]
    param = wf["parameter_change"]["s"]["median"]
    same = wf["unchanged"]["s"]["median"]
    none_regenerated = not any(x["rebuilt"] for x in wf["unchanged"]["runs"])
    pdf = wf["pdf_step"]
    return [
        {
            "name": f"`maglevgen build` cold (empty cache, default carriage, --no-pdf) under "
            f"{lim['cold']:g} s",
            "measured": f"{cold:.1f} s ({cold / lim['cold']:.2f}x the limit)",
            "met": cold < lim["cold"],
        },
        {
            "name": f"rebuild after changing one parameter under {lim['parameter_change']:g} s "
            "apart from the PDF (--no-pdf)",
            "measured": f"{param:.2f} s ({param / lim['parameter_change']:.1f}x the limit)",
            "met": param < lim["parameter_change"],
        },
        {
            "name": f"unchanged rebuild under {lim['unchanged']:g} s, nothing regenerated",
            "measured": f"{same:.2f} s ({same / lim['unchanged']:.2f}x the limit); "
            + ("nothing regenerated" if none_regenerated else "**regenerated**"),
            "met": same < lim["unchanged"] and none_regenerated,
        },
        {
            "name": "the PDF step, timed on its own: recorded",
            "measured": f"{pdf['s']['median']:.1f} s added to the build (LaTeX alone "
            f"{pdf['latex_alone']['median']:.1f} s)",
            "met": True,
        },
    ]


def _montecarlo_targets(mc: dict | None) -> list[dict]:
    """Issue 37's targets for `maglevgen montecarlo`'s default study (bench/montecarlo.py)."""
    if mc is None or "study_vs_bare_c" not in mc:
        return []
    ratio, scaling = mc["study_vs_bare_c"]["median"], mc["scaling"]["median"]
    out = [
        {
            "name": "Monte Carlo: the study per run within 1.1x of the bare C loop (1 core)",
            "measured": f"{ratio:.3g}x",
            "met": ratio <= 1.1,
        },
        {
            "name": f"Monte Carlo: at least 1.8x on {mc['cores']} cores",
            "measured": f"{scaling:.3g}x ({mc['runs_per_s_all']:.0f} runs/s)",
            "met": scaling >= 1.8,
        },
    ]
    if "big_runs" in mc:
        out.append({"name": f"Monte Carlo: {mc['big_runs']} samples of the default study "
                            f"(`--loop {mc.get('loop', 'firmware')}`) under 60 s on "
                            f"{mc['cores']} cores",
                    "measured": f"{mc['big_s']:.1f} s (the bare C loop alone: "
                                f"{mc['big_floor_s']:.0f} s"
                                + (f"; with numpy's draw of the noise: "
                                   f"{mc['big_floor_noise_s']:.0f} s"
                                   if "big_floor_noise_s" in mc else "") + ")",
                    "met": mc["big_s"] < 60})
    if "big_firmware_s" in mc:
        out.append({"name": f"Monte Carlo: {mc['big_runs']} samples of the same study on "
                            f"`--loop firmware` (the exact state at the tick) under 60 s on "
                            f"{mc['cores']} cores",
                    "measured": f"{mc['big_firmware_s']:.1f} s",
                    "met": mc["big_firmware_s"] < 60})
    return out


# issue 53: the batch at W lanes against the scalar loop, per run against the scalar
# operation-count limit, and against every peer per CPU-second
LANES_SPEEDUP, LANES_W, LIMIT_RATIO = 3.0, 8, 1.5


def _lanes_targets(simd: dict | None, peer: dict | None) -> list[dict]:
    """Issue 53's targets from the same run's bench/simd_batch.py (each loop's scalar
    driver and lanes, taking turns in each repeat) and bench/casadi_peer.py (the operation
    count's scalar limit, the peers' runs per CPU-second)."""
    out = []
    key = f"W={LANES_W}"
    for loop, res in (simd or {}).items():
        if key not in res.get("speedup_vs_scalar", {}):
            out.append({"name": f"the batch at {LANES_W} lanes at least {LANES_SPEEDUP:g}x "
                                f"the scalar loop per core (`--loop {loop}`)",
                        "measured": f"not measured: this CPU runs lanes "
                                    f"{res.get('widths_this_cpu')}", "met": False})
            continue
        ratio = res["speedup_vs_scalar"][key]["median"]
        same = res["bitwise_same_as_scalar"][key]
        out.append({
            "name": f"the batch at {LANES_W} lanes at least {LANES_SPEEDUP:g}x the scalar loop "
                    f"per core, each run the scalar run's bits (`--loop {loop}`)",
            "measured": f"{ratio:.3g}x ({res['ms_per_run'][key]['median']:.3g} ms a run "
                        f"against {res['ms_per_run']['scalar']['median']:.3g}); "
                        + ("every run bit for bit" if same else "**runs differ**"),
            "met": ratio >= LANES_SPEEDUP and same})
        if peer is not None and loop == "firmware":  # the operation count is this loop's
            limit = peer["limit_ms_per_run"]["scalar"]
            per_run = res["ms_per_run"][key]["median"]
            out.append({
                "name": f"a run within {LIMIT_RATIO:g}x of the scalar operation-count limit on "
                        f"one core (`--loop firmware`, {LANES_W} lanes; the sense tick's "
                        "hand-written C has no CasADi operation count)",
                "measured": f"{per_run / limit:.3g}x ({per_run:.3g} ms against "
                            f"{limit:.3g} ms: {peer['operations_per_run'] / 1e6:.0f} M "
                            "operations at the machine's scalar peak)",
                "met": per_run <= LIMIT_RATIO * limit})
    if peer is not None:
        speedups = {k: v["median"] for k, v in peer["project_speedup"].items()}
        out.append({
            "name": "ahead of every peer per CPU-second (the same closed loop and inputs)",
            "measured": "; ".join(f"{v:.3g}x {k}" for k, v in speedups.items())
                        + ("" if peer.get("jax_skipped") is None
                           else f"; JAX not measured: {peer['jax_skipped']}"),
            "met": bool(speedups) and min(speedups.values()) > 1})
    return out


def _table(head: list[str], rows: list[list[str]]) -> list[str]:
    out = ["| " + " | ".join(head) + " |", "|" + "|".join(" --- " for _ in head) + "|"]
    out += ["| " + " | ".join(row) + " |" for row in rows]
    return [*out, ""]


def _machine(r: dict) -> list[str]:
    m, meta = r["machine"], r["meta"]
    rows = [
        ["CPU", m["cpu"]],
        ["cores", f"{m['logical_cpus']} logical, {m['usable_cpus']} usable by this process"],
        [
            "load average (1, 5, 15 min) at start / end",
            f"{', '.join(f'{x:.2f}' for x in m['loadavg_start'])} / "
            f"{', '.join(f'{x:.2f}' for x in m['loadavg_end'])}",
        ],
        ["OS", m["platform"]],
        ["C library", m["libc"]],
        ["gcc", m["gcc"]],
        ["clang", m["clang"]],
        ["valgrind", m["valgrind"]],
        ["Python", m["python"]],
        [
            "casadi / sympy / numpy / scipy",
            f"{m['casadi']} / {m['sympy']} / {m['numpy']} / {m['scipy']}",
        ],
        [
            "commit",
            f"{meta['git']['commit']}"
            + (" (with uncommitted changes)" if meta["git"]["dirty"] else ""),
        ],
    ]
    return _table(["", ""], rows)


def _derivation(r: dict) -> list[str]:
    d = r["derivation"]
    n = d["summary"]["cold"]["total"]["n"]
    labels = {
        "import": "import maglevgen (sympy, casadi, numpy, scipy)",
        "params": "load and validate the parameter file",
        "derive": "symbolic derivation (SymPy, `build_model`)",
        "lambdify": "numeric layer (`DerivedCarriage.functions`: partials + lambdify)",
        "sources": "run-time-parameter C (`library.runtime_sources`: CasADi functions + C pass)",
        "compile": "compile -O2 (`library.simulation_library`: maglev_functions.c + "
        "maglev_simulate.c, gcc)",
        "total": "**total, fresh process**",
    }
    rows = [
        [lab, _med(d["summary"]["cold"][k], "{:.2f}"), _med(d["summary"]["cached"][k], "{:.2f}")]
        for k, lab in labels.items()
        if k in d["summary"]["cold"]
    ]
    second = d["summary"]["cold"]
    work = ("derive", "lambdify", "sources", "compile")
    cold_work = sum(d["summary"]["cold"][k]["median"] for k in work)
    cached_work = sum(d["summary"]["cached"][k]["median"] for k in work)
    if cached_work < 0.5 * cold_work:
        cache_note = (
            f"Derivation, numeric layer, C and compile take {cached_work:.2f} s cached against "
            f"{cold_work:.2f} s cold: the on-disk caches are in effect."
        )
    else:
        cache_note = (
            f"Derivation, numeric layer, C and compile take as long cached ({cached_work:.1f} "
            f"s) as cold ({cold_work:.1f} s): **the on-disk caches did not hit** (did the "
            "toolchain's source change between the cold and the cached run?)."
        )
    return [
        f"Each run is a fresh Python process ({n} cold/cached pairs, seconds, median "
        "[quartiles]) doing what the first steps of `maglevgen build` do (bench/"
        "derive_phases.py). The caches are the CLI's: "
        "maglevgen/infrastructure/cache.py (the memo store behind "
        "derive/memo.py, holding the derivation steps and the lambdified model) and "
        "runtime/library.py (the generated run-time-parameter C and the compiled library), "
        "all keyed by the toolchain's source, the library versions and the carriage's structure, "
        "never by parameter values. *Cold*: empty cache folder ($MAGLEVGEN_CACHE). *Cached*: a "
        "second fresh process on the folder the cold run filled. " + cache_note,
        "",
        *_table(["phase", "cold (s)", "cached (s)"], rows),
        f"Cached / cold total, paired: {_ratio(d['cached_over_cold'])}.",
        "",
        "In the same process, a second call (results held in memory): derivation "
        f"{second['second_derive']['median']:.3g} s, run-time-parameter C "
        f"{second['second_sources']['median']:.3g} s (its checksums verified), library "
        f"{second['second_compile']['median']:.3g} s. `maglevgen generate --parameters runtime` "
        "(`render` + write), which is not cached on disk, takes "
        f"{second['generate']['median']:.2f} s there: building the CasADi functions "
        f"{second['casadi_functions']['median']:.2f} s and writing their C "
        f"{second['c_code']['median']:.2f} s.",
        "",
    ]


def _workflow(r: dict) -> list[str]:
    wf = r["workflow"]
    lim = wf["limits_s"]
    n_cold = wf["cold"]["s"]["n"]
    n_re = wf["parameter_change"]["s"]["n"]
    pdf = wf["pdf_step"]

    def met(x: float, limit: float) -> str:
        return f"yes ({x / limit:.2f}x)" if x < limit else f"**no** ({x / limit:.2f}x)"

    rows = [
        [
            "cold: empty cache, no output folder, `--no-pdf`",
            f"< {lim['cold']:g} s",
            _secs(wf["cold"]["s"]),
            met(wf["cold"]["s"]["median"], lim["cold"]),
        ],
        [
            "one parameter changed (`--set vehicle.mass=...`, a new value each time), `--no-pdf`",
            f"< {lim['parameter_change']:g} s",
            _secs(wf["parameter_change"]["s"]),
            met(wf["parameter_change"]["s"]["median"], lim["parameter_change"]),
        ],
        [
            "unchanged: the same command again",
            f"< {lim['unchanged']:g} s",
            _secs(wf["unchanged"]["s"]),
            met(wf["unchanged"]["s"]["median"], lim["unchanged"]),
        ],
        [
            "one parameter changed, with the PDF",
            "-",
            _secs(wf["with_pdf"]["s"]),
            "-",
        ],
        [
            "the PDF step: with the PDF minus without (paired by repeat)",
            "recorded",
            _secs(pdf["s"]),
            "-",
        ],
        [
            f"LaTeX alone ({pdf['tool']} on a copy of the built report.tex, as the build runs it)",
            "recorded",
            _secs(pdf["latex_alone"]),
            "-",
        ],
    ]
    bad = _workflow_checks(wf)
    check = (
        "Every parameter-change build rebuilt without deriving or compiling anything (the "
        "caches hit), and every unchanged build printed that the folder is up to date."
        if not bad
        else "**Not as planned:** " + "; ".join(bad) + ". (A step re-derived in every build, "
        "the toolchain unchanged, is most likely one whose memo entry the next process cannot "
        "read back: maglevgen/infrastructure/cache.py treats an unreadable entry as absent.)"
    )
    return [
        *_floor(wf),
        "`maglevgen build` as an engineer runs it: each build is a fresh process "
        "(`python -m maglevgen.cli build --out DIR ...`) with a cache folder of its own "
        "($MAGLEVGEN_CACHE), timed from outside (wall clock, interpreter start included). "
        f"Cold: {_n(n_cold, 'run')}, each on an empty cache. Then, on the folder and cache of "
        f"the first cold run, {_n(n_re, 'repeat')} of: a parameter change, the same command "
        "again, the "
        "next parameter change with the PDF, and LaTeX alone. Seconds: median [quartiles].",
        "",
        *_table(["build", "target", "seconds", "met"], rows),
        check,
        "",
        *_workflow_breakdown(wf),
    ]


FLOOR_ROWS: tuple[tuple[str, str], ...] = (
    ("interpreter, light imports, cached library, the three simulations",
     "startup_to_simulations"),
    ("matplotlib import (once, in the drawing process)", "matplotlib_import"),
    ("simulation figures (three PNGs)", "simulation_figures"),
    ("report force figures (two PNGs)", "report_figures"),
    ("trajectories (three CSVs, one .npz)", "trajectories"),
)


def _floor(wf: dict) -> list[str]:
    """The CPU a parameter-change build spends on its outputs, whatever the report costs."""
    runs = wf.get("floor")
    if not runs:
        return []
    med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
    rows = [[label, f"{med[key]:.2f}"] for label, key in FLOOR_ROWS]
    rows.append(["**sum**", f"**{med['total']:.2f}**"])
    param = wf["parameter_change"]["s"]["median"]
    limit = wf["limits_s"]["parameter_change"]
    return [
        "**The floor of a parameter-change build** (`bench/build_floor.py`: one fresh "
        "process, each piece of work every parameter-change build does timed alone, CPU "
        f"seconds, median of {_n(len(runs), 'run')}). Spread over the machine's "
        f"{runs[0]['cores']} cores, these pieces alone need at least "
        f"{med['wall_lower_bound']:.2f} s of wall time, against the {limit:g} s target and "
        f"the {param:.2f} s measured below; the report's own work (symbolic imports, trim, "
        "gains, verification, LaTeX rendering) comes on top.",
        "",
        *_table(["piece", "CPU s"], rows),
        "",
    ]


# (label, key in the timers' stages, key in cProfile's stages, depth)
STAGE_ROWS: tuple[tuple[str, str, str, int], ...] = (
    ("`run_build` (everything after the imports)", "run_build", "run_build", 0),
    ("key of the inputs (hashes the toolchain's source)", "build_key", "build_key", 1),
    (
        "cached run-time-parameter C found and verified (`library.runtime_sources`)",
        "runtime_sources",
        "runtime_sources",
        1,
    ),
    (
        "lambdified model from the memo store (`DerivedCarriage.functions`)",
        "model_functions",
        "carriage_functions",
        1,
    ),
    (
        "cached library found (`library.simulation_library`, in a worker thread)",
        "simulation_library",
        "simulation_library",
        1,
    ),
    (
        "C interface files (`render_interface`: maglev.h, main.c, CMake, manifest)",
        "render_interface",
        "render_interface",
        1,
    ),
    (
        "simulation (`run_scenarios`: trim, gains, stability limit, 3 closed-loop runs)",
        "run_scenarios",
        "run_scenarios",
        1,
    ),
    ("the C runs (`maglev_simulate` through ctypes)", "c_simulate", "c_simulate", 2),
    ("simulation metrics (`render_metrics`: metrics.json, metrics.md)", "render_metrics",
     "render_metrics", 1),
    ("report (`report_files`)", "report_files", "report_files", 1),
    ("report context (`build_context`, figures included)", "build_context", "build_context", 2),
    ("trim report", "trim_report", "trim_report", 3),
    (
        "gains report (closed form, numerical LQR, 50-digit reference, coupled model)",
        "gains_report",
        "gains_report",
        3,
    ),
    ("verification table", "verification", "verification", 3),
    (
        "waiting for the drawing process (`Job.result`: CSV and .npz trajectories, then "
        "the simulation's and the report's figures, drawn while the context is built)",
        "background_wait",
        "background_wait",
        3,
    ),
    ("LaTeX rendering (`render_tex`: report.tex)", "render_tex", "render_tex", 2),
    ("PDF (`run_latex`)", "run_latex", "run_latex", 2),
    ("SUMMARY.md (`summary_text`)", "summary_text", "summary_text", 1),
    ("writing the folder (`write_output`)", "write_output", "write_output", 1),
)


def _stage(st: dict, key: str) -> float | None:
    v = st.get("stages", {}).get(key)
    return None if v is None else v["median"]


def _workflow_breakdown(wf: dict) -> list[str]:
    tm, cp = wf.get("stages_timers") or {}, wf.get("stages_cprofile") or {}
    if not tm:
        return []
    imp = wf["imports"]
    start = wf["python_startup_s"]["median"]
    param = wf["parameter_change"]["s"]["median"]

    def pkgs(x: dict, n: int = 7) -> str:
        items = list(x["packages_s"].items())
        top = ", ".join(f"{k} {v:.2f}" for k, v in items[:n])
        rest = sum(v for _, v in items[n:])
        return f"{top}, the other {len(items) - n} packages {rest:.2f}"

    rows = [
        [
            "imports before `run_build` (the CLI, then the modules `run_build` imports)",
            f"{tm['import_s']['median']:.2f}",
            f"{cp['import_s']['median']:.2f}" if cp else "-",
        ]
    ]
    for label, tkey, ckey, depth in STAGE_ROWS:
        t, c = _stage(tm, tkey), _stage(cp, ckey) if cp else None
        if t is None and c is None:
            continue
        if depth and (t or 0) < 0.005 and (c or 0) < 0.005:
            continue
        rows.append(
            [
                "&emsp;" * depth + label,
                "-" if t is None else f"{t:.3f}" if t < 0.1 else f"{t:.2f}",
                "-" if c is None else f"{c:.3f}" if c < 0.1 else f"{c:.2f}",
            ]
        )
    if cp and _stage(cp, "imports") is not None:
        rows.append(
            [
                "imports inside `run_build` (part of the rows above)",
                "-",
                f"{_stage(cp, 'imports'):.2f}",
            ]
        )
    n_prof = tm["run_build_s"]["n"]
    run_build = _stage(tm, "run_build") or tm["run_build_s"]["median"]
    parts = {
        "the report": _stage(tm, "report_files") or 0.0,
        "the simulation metrics": _stage(tm, "render_metrics") or 0.0,
        "the simulation": _stage(tm, "run_scenarios") or 0.0,
        "the lambdified model": _stage(tm, "model_functions") or 0.0,
    }
    floor = start + tm["import_s"]["median"]
    whole = floor + run_build
    limit = wf["limits_s"]["parameter_change"]
    biggest = ", ".join(f"{k} {v:.2f} s" for k, v in sorted(parts.items(), key=lambda kv: -kv[1]))
    out = [
        "### Where the parameter-change rebuild's time goes",
        "",
        f"- Interpreter start (`python -c pass`): {start:.3f} s.",
        f"- Imports of the parameter-change build (`python -X importtime -m maglevgen.cli build "
        f"...`, self time summed per package, importtime's own overhead included): "
        f"{imp['parameter_change']['total_s']:.2f} s over {imp['parameter_change']['modules']} "
        f"modules: {pkgs(imp['parameter_change'])}.",
        f"- Imports of the unchanged build: {imp['unchanged']['total_s']:.2f} s over "
        f"{imp['unchanged']['modules']} modules: {pkgs(imp['unchanged'], 5)}.",
        "",
        f"The stages of `maglevgen.build.run_build` in a parameter-change build "
        f"(bench/build_profile.py, {_n(n_prof, 'fresh process', 'fresh processes')} of "
        "each kind, median seconds): "
        "*timers* wraps each stage function in a wall-clock timer and changes nothing else; "
        "*cProfile* is the cumulative time under the profiler, which slows Python-heavy work "
        "more than work in C, so only its proportions compare. Indented rows are part of the "
        "row above them.",
        "",
        *_table(["stage", "timers (s)", "cProfile cumulative (s)"], rows),
        f"So, timed from inside, a parameter-change rebuild is about {whole:.2f} s (the whole "
        f"command, timed from outside above: {param:.2f} s): the interpreter and the imports "
        f"before `run_build` {floor:.2f} s, then `run_build` {run_build:.2f} s, of which "
        f"{biggest}. The part that depends on the parameter values and runs in C (trim, gains "
        f"and the three closed-loop runs) takes {(_stage(tm, 'run_scenarios') or 0.0):.2f} s; "
        "the rest is Python: the report's context (SymPy displays of the derivation with "
        "the parameter values, the numerical checks) and the imports it triggers, and the "
        "import floor"
        + (
            f", which alone ({floor:.2f} s) exceeds the {limit:g} s target."
            if floor >= limit
            else f" ({floor:.2f} s)."
        )
        + " The trajectories and all figures are written by one forked child process (one "
        "matplotlib import) on the other core meanwhile; the parent waits for it "
        f"{(_stage(tm, 'background_wait') or 0.0):.2f} s in all. On two cores the build is "
        "bound by its total CPU time, so only less work (not more parallelism) shortens it "
        "further, and the floor above bounds it from below.",
        "",
    ]
    return out


LAW_LABELS = {
    "distributed": "distributed law (the default)",
    "point": "point law (`--set model.array_force=point`)",
    "paper": "the paper's model (point law, quasi-static circuits)",
}


def _laws_note(r: dict) -> str:
    if "laws" not in r["dynamics"]:
        return ""
    return (
        "Every C timing of sections 3, 4 and 6 runs the default carriage under its two force "
        "laws side by side: the distributed law (`model.array_force = \"distributed\"`, the "
        "default: the circuit model summed over each tilted face) and the paper's point law "
        "(`--set model.array_force=point`: eq 3 at the face centre), both with the default "
        "first-order circuits; their builds take turns in every round of the same run, and "
        "*distributed / point* is the median of the per-round ratios. The hand-written C model "
        "(bench/reference/maglev_model.c) computes neither exactly: it is the paper's model, the "
        "point law with quasi-static circuits (`model.circuit_dynamics = \"quasi-static\"`), "
        "which tests/test_bench_reference.py checks against that build to 1e-12 relative on 300 "
        "states near trim. So the hand-written C is compared only with a third build of that "
        "model, timed in the same rounds, never with the distributed law."
    )


def _laws_rows(laws: dict, unit: str) -> list[list[str]]:
    show = _ns if unit == "ns" else _med
    return [
        [
            cc,
            show(t[f"distributed_{unit}"]),
            show(t[f"point_{unit}"]),
            _ratio(t["distributed_over_point"]),
            show(t[f"paper_{unit}"]) if f"paper_{unit}" in t else "-",
        ]
        for cc, t in laws.items()
    ]


LAWS_HEAD = ["compiler (-O2)", "distributed law (default)", "point law", "distributed / point",
             "the paper's model (point, quasi-static)"]


def _dynamics(r: dict) -> list[str]:
    d = r["dynamics"]
    c = d["c"]
    calls = c["calls_per_repeat"]
    reps = c["generated_ns"]["n"]
    rows = [
        ["generated C (`maglev_dynamics`, runtime p, gcc -O2)", _ns(c["generated_ns"]), "1"],
        [
            "hand-written C (`ref_dynamics`, runtime p: constants from p at every call)",
            _ns(c["reference_ns"]),
            _ratio(_inv(c["generated_over_reference"])),
        ],
        [
            "hand-written C, constants from p prepared once (`ref_dynamics_c`)",
            _ns(c["reference_prepared_ns"]),
            _ratio(_inv(c["generated_over_reference_prepared"])),
        ],
    ]
    py_rows = []
    for label, v in d.get("python", {}).items():
        if "not_built" in v:
            py_rows.append([label, v["not_built"], "-"])
            continue
        build = f" (built in {v['build_s']:.1f} s)" if v["build_s"] else ""
        py_rows.append([label + build, _ns(v["ns"]), _ratio(v["over_generated_c"])])
    cgl = d.get("callgrind_laws") or {}
    instr = _instructions("call", (cgl.get("distributed") or {}).get("instructions"),
                          (cgl.get("point") or {}).get("instructions"))
    out = [
        "One call of xdot = f(x, u, p) for the default carriage, on 64 states and inputs near "
        "each model's trim taken in turn. C figures are timed from a C loop (bench/c/"
        f"bench_runtime.c, {reps} repeats of {calls} calls: each process of the driver times "
        "two repeats, the models' drivers take turns, the contenders of one model alternate "
        "within each repeat); each model is its own translation unit, so nothing is inlined "
        "into the loop. Time per call: median [quartiles].",
        "",
        "The generated `maglev_dynamics` under each force law, paired by round:",
        "",
        *_table(LAWS_HEAD, _laws_rows(d["laws"], "ns")),
        instr.strip(),
        "",
        "Against the hand-written C: the paper's model (point law, quasi-static circuits), the "
        "one the hand-written C computes; ratio: time / generated C time in the same repeat.",
        "",
        *_table(["implementation", "time per call", "x generated C"], rows),
        *_compilers(d, "ns"),
        "Python contenders, on the default (distributed) law: each Python repeat is followed by "
        "a short C timing of the generated function of the same law, which its ratio is taken "
        "against.",
        "",
        *(_table(["implementation", "time per call", "x generated C (distributed)"], py_rows)
          if py_rows else ["Not measured in this run.", ""]),
    ]
    cg = d["callgrind"]
    if cg.get("gen") and cg.get("ref"):
        g, h = cg["gen"], cg["ref"]
        libm = lambda x: ", ".join(f"{k} {v:g}" for k, v in x["libm_calls"].items())  # noqa: E731
        body = ", ".join(f"{k} {v}" for k, v in d["generated_body"].items())
        asm = d["generated_asm"]
        out += [
            "Where the time goes (callgrind, instructions per call including libm; deterministic):",
            "",
            *_table(
                ["", "instructions / call", "libm calls / call"],
                [
                    ["generated C", f"{g['instructions']:.0f}", libm(g)],
                    ["hand-written C", f"{h['instructions']:.0f}", libm(h)],
                ],
            ),
            f"The generated body as written (before gcc merges sin/cos pairs into sincos): "
            f"{body}. The instruction ratio is {g['instructions'] / h['instructions']:.2f}x, the "
            f"time ratio {c['generated_over_reference']['median']:.2f}x. "
            + (
                "In the compiled generated function (straight-line code, so these static "
                f"counts are also per call) {asm['stack_memory']} of its "
                f"{asm['instructions']} instructions load or store a stack slot: CasADi's SX "
                "code keeps its scalar temporaries in memory around its libm calls (every "
                "floating-point register is caller-saved on x86-64). "
                if asm["calls"] == 0 or asm["instructions"] >= STRAIGHT_LINE_MIN
                else f"(The compiled `{asm['function']}` is {asm['instructions']} instructions "
                f"with {asm['calls']} calls, a wrapper around the code holding the model: its "
                "stack traffic is not counted here.) "
            )
            + _divisions_note(g, h, "call")
            + " Stack traffic and divisions take more time per instruction than the "
            "arithmetic, which most likely explains why the time ratio exceeds the instruction "
            "ratio.",
            "",
        ]
    return out


def _divisions_note(
    gen: dict, ref: dict, unit: str, per_step: bool = False, why: str | None = None
) -> str:
    """Divisions executed per call (or step), generated vs hand-written, from callgrind;
    ``why``: the explanation when the generated code divides more often, if not the usual."""
    key = "divisions_per_step" if per_step else "divisions"
    if key not in gen or key not in ref:
        return ""
    g, h = gen[key], ref[key]
    if g > 1.5 * h and why:
        how = why
    elif g > 1.5 * h:
        how = (
            "the generated code divides more often: the hand-written model multiplies by "
            "reciprocals it computed once"
        )
    elif g < h / 1.5:
        how = "the generated code divides less often than the hand-written model"
    else:
        how = (
            "about as often (the SymPy->CasADi conversion keeps the reciprocals the "
            "expressions share)"
        )
    return (
        f"Division instructions executed per {unit} (callgrind, the model's own code, libm "
        f"not included): generated {g:.0f}, hand-written {h:.0f}: {how}."
    )


def _compilers(section: dict, unit: str) -> list[str]:
    """The generated / hand-written pair built by the other compilers."""
    other = section.get("other_compilers") or {}
    if not other:
        return []
    show = _ns if unit == "ns" else _med
    rows = [
        [
            cc,
            show(v[f"generated_{unit}"]),
            show(v[f"reference_{unit}"]),
            _ratio(v["generated_over_reference"]),
        ]
        for cc, v in other.items()
    ]
    return [
        "The same pair built by another compiler (both at -O2, the same driver):",
        "",
        *_table(["compiler", "generated C", "hand-written C", "generated / hand-written"], rows),
    ]


def _inv(s: dict) -> dict:
    """A ratio summary turned upside down (the table shows x generated C)."""
    return {"median": 1 / s["median"], "q1": 1 / s["q3"], "q3": 1 / s["q1"]}


def _loop(r: dict) -> list[str]:
    lp = r["closed_loop"]
    c = lp["c"]
    loop = lp["loop"]
    rows = [
        ["generated C (`maglev_simulate`, runtime p, gcc -O2)", _med(c["generated_ms"]), "1", "-"],
        [
            "the same RK4 loop around the hand-written C model (`ref_simulate`)",
            _med(c["reference_ms"]),
            _ratio(_inv(c["generated_over_reference"])),
            f"x {c['agreement']['x']:.1g}, u {c['agreement']['u']:.1g}",
        ],
    ]
    py_rows = []
    for label, v in lp.get("python", {}).items():
        dev = v["max_deviation_from_generated_c"]
        py_rows.append(
            [
                f"{label} ({v['rhs_evaluations']} model evaluations)",
                _med(v["ms"]),
                _ratio(v["over_generated_c"]),
                "bit-identical"
                if dev["all_states_relative"] == 0
                else f"{dev['position_m'] * 1e6:.2g} um, {dev['attitude_rad'] * 1e6:.2g} urad",
            ]
        )
    cgl = lp.get("callgrind_laws") or {}
    per = {k: v.get("maglev_simulate", {}).get("instructions_per_step") for k, v in cgl.items()}
    instr = _instructions("RK4 step", per.get("distributed"), per.get("point"))
    steps = loop["n_steps"]
    return [
        f"{steps * loop['dt']:g} s of simulated time at {1 / loop['dt']:g} Hz ({steps} RK4 "
        "steps), closed loop from each model's trim at the default speed plus a disturbance of "
        "1 mm lateral, 1 mm heave and 2 mrad in roll, pitch and yaw, per-axis LQR gains from "
        "`maglev_lqr_gains`, the feedback and the minimum-norm allocation evaluated at every "
        "RK4 stage, constant propulsion, gaps checked at every sample; every contender records "
        "the states (and, in C, inputs and gaps) at every sample. C runs are timed from C "
        f"({c['generated_ms']['n']} repeats, two per process of the driver, the models' "
        "drivers taking turns, the generated and the hand-written loop alternating within a "
        "model's process). Time per 10 s run: median [quartiles].",
        "",
        "The generated `maglev_simulate` under each force law, paired by round (ms per run):",
        "",
        *_table(LAWS_HEAD, _laws_rows(lp["laws"], "ms")),
        instr.strip(),
        "",
        "Against the hand-written loop: the paper's model (point law, quasi-static circuits), "
        "the one the hand-written C computes; agreement: the pair's largest difference "
        "relative to each state's range.",
        "",
        *_table(["implementation", "ms per run", "x generated C", "agreement"], rows),
        *_compilers(lp, "ms"),
        "Python contenders, on the default (distributed) law: each Python repeat is followed by "
        "a short C run of the same law, which its ratio is taken against; agreement: the "
        "largest deviation from that generated C's trajectory in position and attitude.",
        "",
        *(_table(["implementation", "ms per run", "x generated C (distributed)", "agreement"],
                 py_rows) if py_rows else ["Not measured in this run.", ""]),
        *_loop_breakdown(r),
    ]


def _loop_breakdown(r: dict) -> list[str]:
    cg = r["closed_loop"].get("callgrind", {})
    dyn = r["dynamics"]["callgrind"].get("gen")
    worker = next((f for f in ("maglev_closed_loop_prepared", "maglev_closed_loop",
                               "maglev_rk4_step") if f in cg), None)
    if not dyn or worker is None or not all(k in cg for k in ("maglev_simulate", "ref_simulate")):
        return []
    per = {k: v["instructions_per_step"] for k, v in cg.items()}
    libm = lambda k: ", ".join(  # noqa: E731
        f"{n} {v:.3g}" for n, v in cg[k]["libm_calls_per_step"].items() if v >= 0.01
    )
    parts = ", ".join(
        (f"{per[k]:.0f}" if per[k] >= 10 else f"{per[k]:.2g}") + f" in `{k}`"
        for k in per
        if k not in ("maglev_simulate", "ref_simulate")
    )
    four = 4 * dyn["instructions"]
    c = r["closed_loop"]["c"]
    asm = r["closed_loop"].get("generated_asm")
    what = {
        "maglev_rk4_step": "`maglev_rk4_step`, one CasADi expression for the four stages with "
        "the feedback and the allocation",
        "maglev_closed_loop": "`maglev_closed_loop` (the model with the feedback and the "
        "allocation, the allocation matrix an input), called at each of the four stages",
        "maglev_closed_loop_prepared": "`maglev_closed_loop_prepared` (the model with the "
        "feedback and the allocation, and the gaps; what depends only on the run's constant "
        "inputs is computed once per run by `maglev_closed_loop_prepare`), called at each of "
        "the four stages",
    }[worker]
    worker_div = cg[worker].get("divisions_per_step")
    extra = (
        f"most of the difference is in `{worker}`, which executes more divisions than the "
        "four calls of `maglev_dynamics` it is made of (above)"
        if worker_div is not None and "divisions" in dyn and worker_div > 1.2 * 4 * dyn["divisions"]
        else None
    )
    out = [
        "Per RK4 step (callgrind, instructions including libm): the generated loop "
        f"{per['maglev_simulate']:.0f} ({parts}), the hand-written loop "
        f"{per['ref_simulate']:.0f}: a ratio of "
        f"{per['maglev_simulate'] / per['ref_simulate']:.2f}x in instructions against "
        f"{c['generated_over_reference']['median']:.2f}x in time. The model's right-hand side is "
        f"{what}: {per[worker]:.0f} instructions per step, {per[worker] - four:+.0f} beside four "
        f"calls of `maglev_dynamics` ({four:.0f})"
        + (
            f", and {cg[worker]['divisions_per_step']:.0f} division instructions per step "
            f"against {4 * dyn['divisions']:.0f} in four calls of `maglev_dynamics`"
            if "divisions_per_step" in cg[worker] and "divisions" in dyn
            else ""
        )
        + f". libm calls per step: generated {libm('maglev_simulate')}; hand-written "
        f"{libm('ref_simulate')}.",
        "",
    ]
    if asm:
        out += [
            f"Compiled, `{asm['function']}` is {asm['instructions']} straight-line instructions "
            f"of which {asm['stack_memory']} load or store a stack slot, the same pattern as in "
            "the dynamics. "
            + _divisions_note(
                cg["maglev_simulate"], cg["ref_simulate"], "step", per_step=True, why=extra
            ),
            "",
        ]
    return [
        *out,
        "Issue 6 expected about 5 ms for this run on a 2-core machine: here the generated loop "
        f"takes {c['generated_ms']['median']:.3g} ms and the hand-written one "
        f"{c['reference_ms']['median']:.3g} ms.",
        "",
    ]


ROLE_TITLES = {
    "target": "Every control tick, and the gains when (k, m) change (the controller path)",
    "schedule": "Once per speed set-point (the schedule: the trim's Newton solve in C)",
    "other": "For scale",
}


def _footprint(r: dict) -> list[str]:
    f = r["footprint"]
    head = ["group", ".text", ".rodata", "worst stack", "largest functions (.text bytes)"]
    tables = []
    for role, title in ROLE_TITLES.items():
        rows = []
        for g in f["groups"].values():
            if g["role"] != role and not (role == "target" and g["role"] == "tick"):
                continue
            largest = ", ".join(
                f"{x.get('casadi_name', x['name'])} {x['bytes']}"
                for x in g["largest_functions"][:3]
            )
            label = f"**{g['label']}**" if g["role"] == "target" else g["label"]
            rows.append([label, str(g["text"]), str(g["rodata"]), str(g["stack_bytes"]), largest])
        if rows:
            tables += [f"{title}:", "", *_table(head, rows)]
    w = f["workspace_reals"]
    ref, gen_rt = f["reference"], f["generated_runtime_double_dynamics"]
    target = f["groups"][CONTROLLER_GROUP]
    roots = ", ".join(x.removeprefix("maglev_") for x in target["roots"])
    return [
        f"`maglevgen generate --precision single --parameters baked`, compiled with "
        f"`{f['compiler']} {' '.join(f['flags'])}`; each group is what the linker keeps for its "
        "entry points (`ld -r --gc-sections`), measured with `size -A` (bytes; .text is code, "
        ".rodata constants). Worst stack: the deepest static call path from "
        "`-fcallgraph-info=su` (the generated functions' own frames; libm's not included). "
        "Sizes are of host (x86-64) code: no ARM cross-compiler is installed here, so there "
        "are no Thumb-2 figures.",
        "",
        f"The controller path of the footprint target is {roots}: the per-tick feedback "
        "(`lqr_control` or `damping_control`), the allocation, and the closed-form gains from "
        "the per-axis stiffness and inertia (k, m). The trim and the plants (k, m) at a speed "
        "come from the schedule functions, run once per speed set-point (or on the host, their "
        "results stored in a table), listed separately below.",
        "",
        *tables,
        f"Whole generated file: .text {f['whole_file']['text']} B, .rodata "
        f"{f['whole_file']['rodata']} B, .data/.bss {f['whole_file']['data_bss']} B.",
        "",
        ("Heap: none. " if not f["heap_symbols"] else "Heap: **allocator calls found**. ")
        + "The only external symbols the objects use are "
        f"{', '.join(f['undefined_symbols'])}"
        + (
            f"; allocator symbols found: {', '.join(f['heap_symbols'])}."
            if f["heap_symbols"]
            else "; no malloc, calloc, realloc or free."
        )
        + " The caller passes the work arrays: "
        + ", ".join(f"{k.removeprefix('maglev_')} {v}" for k, v in w.items() if v)
        + " reals (4 bytes each in single precision); the other functions need none.",
        "",
        "For scale, the dynamics in double precision with run-time parameters (gcc -Os), in "
        "the paper's model (point law, quasi-static circuits: the one the hand-written C "
        "computes): "
        f"generated `maglev_dynamics` .text {gen_rt['text']} B, stack {gen_rt['stack_bytes']} B; "
        f"hand-written `ref_dynamics` .text {ref['ref_dynamics']['text']} B, stack "
        f"{ref['ref_dynamics']['stack_bytes']} B.",
        "",
    ]


PRECISION_ROWS = (
    ("every control tick", "tick", "one control tick: `lqr_control` + `allocate`"),
    ("every control tick", "lqr_control", "`maglev_lqr_control`"),
    ("every control tick", "damping_control", "`maglev_damping_control`"),
    ("every control tick", "allocate", "`maglev_allocate`"),
    ("when the gains change", "axis_gains", "`maglev_axis_gains` (closed-form LQR + damping)"),
    ("once per speed (schedule)", "trim", "`maglev_trim` (Newton in C)"),
    ("once per speed (schedule)", "axis_plants", "`maglev_axis_plants` (trim + k, m)"),
    ("once per speed (schedule)", "lqr_gains", "`maglev_lqr_gains` (trim + plants + gains)"),
)


def _precision(r: dict) -> list[str]:
    p = r["precision"]
    kinds = p["kinds"]
    laws = "point_double_ns" in next(iter(kinds.values()))
    rows = [
        [
            when,
            label,
            _ns(kinds[k]["single_ns"]),
            _ns(kinds[k]["double_ns"]),
            _ratio(kinds[k]["single_over_double"]),
            *(
                [
                    _ns(kinds[k]["point_single_ns"]),
                    _ns(kinds[k]["point_double_ns"]),
                    _ratio(kinds[k]["distributed_over_point_single"]),
                    _ratio(kinds[k]["distributed_over_point_double"]),
                ]
                if laws
                else []
            ),
        ]
        for when, k, label in PRECISION_ROWS
        if k in kinds
    ]
    n = next(iter(kinds.values()))["single_ns"]["n"]
    head = ["runs", "function", "float32", "float64", "float32 / float64"]
    if laws:
        head = ["runs", "function", "distributed float32", "distributed float64",
                "float32 / float64", "point float32", "point float64",
                "distributed / point, float32", "distributed / point, float64"]
    return [
        "Baked-parameter builds in each precision and under each force law, gcc -O2, timed "
        f"from C (bench/c/bench_controller.c); {n} rounds, each running the four drivers "
        "(two laws, two precisions) in turn, the order rotating between rounds; ratios per "
        "round. The ticks use the gains and reference the driver's own schedule computed at "
        "the default speed, in its precision; the per-tick functions (feedback, allocation) do "
        "not depend on the force law, the schedule functions (trim, plants) do.",
        "",
        *_table(head, rows),
        *_schedule_note(p),
    ]


def _schedule_note(p: dict) -> list[str]:
    sched = p.get("schedule")
    newton = p.get("newton") or {}
    if not sched:
        return []
    rows = []
    for s in sched["speeds"]:
        it, res, d = s["newton_iterations"], s["residual"], s["single_vs_double"]
        rows.append(
            [
                f"{s['speed']:g}",
                f"{it['single']} / {it['double']}",
                f"{res['single']:.2g} / {res['double']:.2g}",
                f"{d['K_rel']:.1e}",
                f"{d['heave_m'] * 1e6:.2g} um, {d['pitch_rad'] * 1e6:.2g} urad",
                "identical"
                if s["double_vs_runtime_K_rel"] == 0
                else f"{s['double_vs_runtime_K_rel']:.1e}",
            ]
        )
    single, double = newton.get("single"), newton.get("double")
    iters = [s["newton_iterations"]["single"] for s in sched["speeds"]]
    diters = [s["newton_iterations"]["double"] for s in sched["speeds"]]
    trim = p["kinds"].get("trim", {}).get("single_over_double", {}).get("median")
    out = [
        "The schedule each build of the default law computes, at several speeds: Newton "
        "iterations of the trim "
        "(counted by an instrumented copy of the generated C), the largest acceleration left "
        "at its trim (the dynamics evaluated in the same precision), and how far float32's "
        "gains and trim are from float64's; the last column compares the float64 baked build "
        "with the run-time-parameter library the simulation uses.",
        "",
        *_table(
            [
                "speed (m/s)",
                "Newton iterations f32 / f64",
                "residual f32 / f64 (m/s^2, rad/s^2)",
                "K: f32 vs f64 (max rel.)",
                "trim heave, pitch: f32 vs f64",
                "K: baked f64 vs run-time lib",
            ],
            rows,
        ),
    ]
    if single and double and min(iters) >= 0:
        limit = single["max_iter"]
        at_limit = sum(i >= limit for i in iters)
        out += [
            "The trim Newton (CasADi's fast_newton, generated into `maglev_trim`, "
            "`maglev_axis_plants` and `maglev_lqr_gains`) stops when the residual is below "
            f"{single['abstol']:.2g} (float32) / {double['abstol']:.2g} (float64) or the step "
            f"below {single['abstol_step']:.2g} / {double['abstol_step']:.2g}, else after "
            f"{limit} iterations (NEWTON_TOLERANCES in maglevgen/codegen/functions.py). "
            + (
                f"With these precision-scaled tolerances float32 stops on its own in "
                f"{min(iters)}-{max(iters)} iterations (float64 {min(diters)}-{max(diters)}) "
                f"over these speeds, no longer after all {limit}"
                if at_limit == 0
                else f"**float32 still runs all {limit} iterations at {at_limit} of "
                f"{len(iters)} speeds**"
            )
            + (f"; the float32 trim takes {trim:.2g}x the float64 one's time." if trim else "."),
            "",
        ]
    return out


def _old_section(old: str | None, heading: str) -> list[str]:
    """The section of ``old`` above the kept part that starts with ``heading``, to its next
    heading or marker comment ([] when there is none)."""
    head = (old or "")[: len(old or "") - len(kept_part(old))]
    i = head.find("\n" + heading)
    if i < 0:
        return []
    ends = [j for j in (head.find("\n## ", i + 1), head.find("\n<!--", i + 1)) if j >= 0]
    body = head[i + 1 : min(ends) if ends else len(head)].rstrip("\n")
    return [*body.split("\n"), ""]


def kept_part(old: str | None) -> str:
    """What a full run keeps of the existing BENCHMARKS.md ``old``: from KEPT_MARKER to the end
    ('' without the marker)."""
    line = "\n" + KEPT_MARKER + "\n"  # the marker on a line of its own
    if not old or line not in old:
        return ""
    return old[old.index(line) + 1 :]


def document(generated: str, old: str | None) -> str:
    """The new BENCHMARKS.md: ``generated`` (the run's sections) in place of everything above
    the marker of ``old``, the marked part after it unchanged."""
    kept = kept_part(old)
    return generated.rstrip("\n") + "\n\n" + kept if kept else generated


def _instructions(per: str, distributed: float | None, point: float | None) -> str:
    """The callgrind sentence: instructions per ``per`` of both laws and their ratio ("" when
    either was not measured)."""
    if not (distributed and point):
        return ""
    return (f" Instructions per {per} (callgrind, libm included): distributed {distributed:.0f}, "
            f"point {point:.0f} ({distributed / point:.2f}x).")


def markdown(r: dict, old: str | None = None) -> str:
    """BENCHMARKS.md of the results ``r``, keeping the recorded-separately part of ``old`` (the
    file's current text)."""
    kept = kept_part(old)
    meta = r["meta"]
    out = [
        "# Benchmarks",
        "",
        "How fast and how small the toolchain and its generated C are, beside what an engineer "
        f"would otherwise use, all measured in one run. Produced by `{meta['command']}` "
        "(`make bench` runs `python bench/run.py` in the project's virtualenv) on "
        f"{meta['date_utc']}; the run took {meta['wall_s'] / 60:.1f} min. Do not edit: rerun. "
        "Raw figures: bench/results.json. The sections after the marker comment *recorded "
        "separately: kept by make bench* were recorded by other scripts, each on its own date, "
        "and are carried over unchanged.",
        "",
    ]
    if meta["quick"]:
        out += ["**Quick run (--quick): too few repeats to quote.**", ""]
    missing = [k for k in ("workflow", *CARRIED_SECTIONS) if k not in r]
    if missing:
        out += [
            f"Not measured in this run: {', '.join(missing)} (bench/run.py's last stages); "
            "their sections below are the previous file's, with the dates they give.",
            "",
        ]
    if meta.get("resumed_at"):
        out += [
            f"The run was interrupted and resumed on {meta['resumed_at']} (`--resume`): the "
            "stages measured before the interruption were kept (bench/results.json, "
            "`meta.resumed_at`); the time above is the sum of both parts.",
            "",
        ]
    if meta.get("toolchain_changed_during_run"):
        out += [
            "**The toolchain's source changed while the suite ran: the caches it keys may have "
            "missed and figures from before and after the change are mixed. Rerun.**",
            "",
        ]
    out += ["## Machine", "", *_machine(r)]
    out += [
        "## Targets",
        "",
        *_table(
            ["target", "measured (median)", "met"],
            [[t["name"], t["measured"], "yes" if t["met"] else "**no**"] for t in r["targets"]],
        ),
    ]
    out += [
        "Reading the tables: times are medians of repeats with the quartiles in brackets; "
        "every ratio divides two figures taken in the same repeat (the machine is shared and "
        "noisy, so figures from different moments are not compared) and is the median of "
        "those per-repeat ratios. " + _laws_note(r),
        "",
        "## 1. Derivation, generation and compile: cold and cached",
        "",
        *_derivation(r),
        *(["## 2. The main job: `maglevgen build`", "", *_workflow(r)] if "workflow" in r
          else _old_section(old, "## 2. The main job")),
        "## 3. `maglev_dynamics`: time per call",
        "",
        *_dynamics(r),
        "## 4. Closed loop: 10 s at 1 kHz, RK4",
        "",
        *_loop(r),
        "## 5. Footprint for firmware (single precision, baked parameters)",
        "",
        *_footprint(r),
        "## 6. Firmware functions: float32 vs float64",
        "",
        *_precision(r),
    ]
    fmu_results = Path(__file__).with_name("fmu_results.json")
    if fmu_results.exists():  # measured separately by bench/fmu.py: kept across full runs
        import fmu

        out += ["", *fmu.section(json.loads(fmu_results.read_text())), ""]
    for key, module in (("envelope", "envelope"), ("montecarlo", "montecarlo"),
                        ("peers", "peers")):
        if key in r:
            out += import_module(module).markdown(r[key])
        else:  # a stage this run did not measure (--no-measure): its section as it was
            out += _old_section(old, CARRIED_SECTIONS[key])
    firmware_results = Path(__file__).with_name("firmware_results.json")
    # measured separately by bench/firmware.py; its section, when in the kept part, stays there
    if firmware_results.exists() and FIRMWARE_BEGIN not in kept:
        import firmware

        out += ["", *firmware.section(json.loads(firmware_results.read_text()))]
    out += ["", KEPT_MARKER] if not kept else []
    return document("\n".join(out).rstrip() + "\n", old)
