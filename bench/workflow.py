"""Issue 8's workflow targets: `maglevgen build` timed as an engineer runs it.

Every build is a fresh process (``python -m maglevgen.cli build --out DIR ...``) on a cache
folder of its own ($MAGLEVGEN_CACHE), timed from this process (wall clock around the child):

- cold: an empty cache folder and no output folder, ``--no-pdf``;
- parameter change: ``--set vehicle.mass=<a new value each repeat> --no-pdf`` on the folder and
  cache a cold build filled;
- unchanged: the same arguments again (nothing may be regenerated);
- PDF: the same parameter change with the PDF (a new mass, so it rebuilds), paired in the same
  repeat with the build without it, and LaTeX alone (maglevgen.report.run_latex, what the build
  runs) on a copy of the folder's report.tex and figures.

Then where the parameter-change rebuild's time goes: the interpreter's start, the imports
(``python -X importtime``, self time summed per top-level package) and the stages of run_build
(bench/build_profile.py: wall-clock timers, and cProfile).
"""

from __future__ import annotations

import itertools
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

from common import BENCH, ROOT, log, paired_ratios, run, summary

COLD_LIMIT_S = 30.0
PARAM_LIMIT_S = 1.0
UNCHANGED_LIMIT_S = 0.5
UP_TO_DATE = "is up to date"  # what the CLI prints when it regenerated nothing


def _env(cache: Path) -> dict[str, str]:
    return {**os.environ, "MAGLEVGEN_CACHE": str(cache)}


def _cli(out: Path, sets: Sequence[str], pdf: bool) -> list[str]:
    cmd = [sys.executable, "-m", "maglevgen.cli", "build", "--out", str(out)]
    for s in sets:
        cmd += ["--set", s]
    return cmd if pdf else [*cmd, "--no-pdf"]


def build(out: Path, cache: Path, sets: Sequence[str] = (), pdf: bool = False) -> dict:
    """One `maglevgen build` in a fresh process: wall seconds and what it said it did."""
    cmd = _cli(out, sets, pdf)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=_env(cache), cwd=ROOT, capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr[-4000:]}")
    err = proc.stderr
    return {
        "s": seconds,
        "rebuilt": UP_TO_DATE not in proc.stdout,
        # the steps the CLI announced it derived (not found in the caches), and a compile
        "derived": sorted(set(re.findall(r"deriving (.+?) \(cached afterwards\)", err))),
        "compiled": "compiling" in err,
        "latex": "LaTeX" in err or "report.pdf" in err,
    }


def _masses(base: float) -> Iterator[str]:
    """A new vehicle.mass for every parameter-change build (never one built before)."""
    for k in itertools.count(1):
        yield f"{base * (1 + 1e-3 * k):.6g}"


def _latex_alone(report_dir: Path) -> dict:
    """LaTeX on its own, as the build runs it, on a copy of a built report folder."""
    from maglevgen.report import run_latex

    with tempfile.TemporaryDirectory(prefix="maglev_bench_tex_") as tmp:
        for f in report_dir.iterdir():
            if f.suffix in (".tex", ".png"):
                shutil.copy2(f, Path(tmp) / f.name)
        t0 = time.perf_counter()
        res = run_latex(Path(tmp))
        wall = time.perf_counter() - t0
    if not res.ok:
        raise RuntimeError(f"LaTeX failed on the built report: {res.error}")
    return {"s": wall, "tool": res.tool}


def _startup(reps: int) -> list[float]:
    out = []
    for _ in range(reps):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", "pass"], check=True)
        out.append(time.perf_counter() - t0)
    return out


def importtime(cmd: Sequence[str], cache: Path) -> dict:
    """`python -X importtime` of a command: the total and the self time per top-level package
    (the self times of all modules add up to the total)."""
    proc = subprocess.run(
        [sys.executable, "-X", "importtime", *cmd[1:]],
        env=_env(cache),
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    if proc.returncode != 0:
        raise RuntimeError(f"importtime run failed:\n{proc.stderr[-4000:]}")
    per: dict[str, float] = {}
    n = 0
    for line in proc.stderr.splitlines():
        if not line.startswith("import time:") or "self [us]" in line:
            continue
        self_us, _cum, name = (part.strip() for part in line[len("import time:") :].split("|"))
        root = name.split(".")[0].lstrip("_") or name
        per[root] = per.get(root, 0.0) + int(self_us) / 1e6
        n += 1
    return {
        "total_s": sum(per.values()),
        "modules": n,
        "packages_s": dict(sorted(per.items(), key=lambda kv: -kv[1])),
    }


def profile(mode: str, out: Path, cache: Path, sets: Sequence[str]) -> dict:
    import json

    cmd = [sys.executable, BENCH / "build_profile.py", mode, out, "--no-pdf"]
    for s in sets:
        cmd += ["--set", s]
    return json.loads(run(cmd, cwd=ROOT, env=_env(cache)).strip().splitlines()[-1])


def floor_run(cache: Path) -> dict:
    """bench/build_floor.py: the CPU of the pieces every parameter-change build does."""
    import json

    cmd = [sys.executable, BENCH / "build_floor.py"]
    return json.loads(run(cmd, cwd=ROOT, env=_env(cache)).strip().splitlines()[-1])


def workflow(work: Path, cold_reps: int, rebuild_reps: int, profile_reps: int) -> dict:
    from maglevgen.params import load_params

    masses = _masses(load_params(None, []).params.vehicle.mass)
    cold = []
    for i in range(cold_reps):
        log(f"maglevgen build: cold (empty cache), {i + 1}/{cold_reps}")
        cold.append(build(work / f"wf_out{i}", work / f"wf_cache{i}"))
    cache, out = work / "wf_cache0", work / "wf_out0"
    param, unchanged, with_pdf, latex = [], [], [], []
    for j in range(rebuild_reps):
        log(f"maglevgen build: parameter change, unchanged, PDF ({j + 1}/{rebuild_reps})")
        sets = [f"vehicle.mass={next(masses)}"]
        param.append(build(out, cache, sets))
        unchanged.append(build(out, cache, sets))
        with_pdf.append(build(out, cache, [f"vehicle.mass={next(masses)}"], pdf=True))
        latex.append(_latex_alone(out / "report"))
    log("maglevgen build: where the time goes (importtime, timers, cProfile)")
    sets = [f"vehicle.mass={next(masses)}"]
    imports = {
        "parameter_change": importtime(_cli(out, sets, False), cache),
        "unchanged": importtime(_cli(out, sets, False), cache),
    }
    timers = [
        profile("timers", out, cache, [f"vehicle.mass={next(masses)}"]) for _ in range(profile_reps)
    ]
    cprof = [
        profile("cprofile", out, cache, [f"vehicle.mass={next(masses)}"])
        for _ in range(profile_reps)
    ]
    startup = _startup(5)
    floor = [floor_run(cache) for _ in range(profile_reps)]

    def s(rows: list[dict]) -> list[float]:
        return [r["s"] for r in rows]

    pdf_step = [a - b for a, b in zip(s(with_pdf), s(param), strict=True)]
    return {
        "limits_s": {
            "cold": COLD_LIMIT_S,
            "parameter_change": PARAM_LIMIT_S,
            "unchanged": UNCHANGED_LIMIT_S,
        },
        "cold": {"s": summary(s(cold)), "runs": cold},
        "parameter_change": {"s": summary(s(param)), "runs": param},
        "unchanged": {"s": summary(s(unchanged)), "runs": unchanged},
        "with_pdf": {"s": summary(s(with_pdf)), "runs": with_pdf},
        "pdf_step": {
            "s": summary(pdf_step),
            "latex_alone": summary(s(latex)),
            "tool": latex[0]["tool"],
            "with_over_without": paired_ratios(s(with_pdf), s(param)),
        },
        "python_startup_s": summary(startup),
        "floor": floor,
        "imports": imports,
        "stages_timers": _stage_summary(timers),
        "stages_cprofile": _stage_summary(cprof),
        "run_build_callees": cprof[0]["run_build_callees"] if cprof else [],
        "profile_runs": {"timers": timers, "cprofile": cprof},
    }


def _stage_summary(runs: list[dict]) -> dict:
    """Median seconds of every stage over the profiling runs (a stage absent from a run, e.g.
    one that was cached, counts as 0 there)."""
    if not runs:
        return {}
    keys = dict.fromkeys(k for r in runs for k in r["stages"])
    return {
        "import_s": summary([r["import_s"] for r in runs]),
        "run_build_s": summary([r["run_build_s"] for r in runs]),
        "all_rebuilt": all(r["rebuilt"] for r in runs),
        "stages": {
            k: summary([r["stages"].get(k, {}).get("seconds", 0.0) for r in runs]) for k in keys
        },
    }
