"""Issue 20's constraint: the parameter-edit rebuild after the restructure, paired against the
commit before it.

    python bench/experiments/paired_rebuild.py [--base 53a46aa] [--repeats 7] [--json out.json]

Both toolchains are copied into their installed layout (pyproject's package-dir: derive/,
runtime/ and templates/ under maglevgen/) and run from there through PYTHONPATH, each with a
cache and an output folder of its own. After one cold build each (untimed: it fills the cache),
every repeat runs `maglevgen build --no-pdf --set vehicle.mass=<a new value>` on both, in
alternating order (ABAB, BABA...), each a fresh process timed by wall clock from here; then the
same arguments again (the unchanged rebuild). The ratio new/base is taken within each repeat.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/: common.py
from common import ROOT, log, paired_ratios, summary

LAYOUT = (("maglevgen", ""), ("derive", "derive"), ("runtime", "runtime"),
          ("templates", "templates"))


def _layout(src: Path, dest: Path) -> Path:
    """The package as installed, from a source tree ``src``; returns the PYTHONPATH entry."""
    top = dest / "maglevgen"
    for folder, sub in LAYOUT:
        shutil.copytree(src / folder, top / sub if sub else top, dirs_exist_ok=True,
                        ignore=shutil.ignore_patterns("__pycache__"))
    return dest


def _checkout(commit: str, dest: Path) -> Path:
    """The source tree of ``commit`` (git archive), for the folders of LAYOUT."""
    dest.mkdir(parents=True)
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", commit,
                              *(f for f, _ in LAYOUT)], capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    return dest


def _build(path: Path, cache: Path, out: Path, sets: list[str]) -> tuple[float, str]:
    cmd = [sys.executable, "-m", "maglevgen.cli", "build", "--out", str(out), "--no-pdf"]
    for s in sets:
        cmd += ["--set", s]
    env = {**os.environ, "PYTHONPATH": str(path), "MAGLEVGEN_CACHE": str(cache)}
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, cwd=path, capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    return seconds, proc.stdout


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", default="53a46aa")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="maglevgen-paired-"))
    load_start = os.getloadavg()  # the machine is shared: the load is part of the result
    try:
        variants = {
            "base": _layout(_checkout(args.base, work / "base-src"), work / "base"),
            "new": _layout(ROOT, work / "new"),
        }
        for name, path in variants.items():
            log(f"{name}: cold build (fills its cache)")
            _build(path, work / f"cache-{name}", work / f"out-{name}", [])
        times: dict[str, list[float]] = {"base": [], "new": []}
        unchanged: dict[str, list[float]] = {"base": [], "new": []}
        for i in range(args.repeats):
            order = ("base", "new") if i % 2 == 0 else ("new", "base")
            sets = [f"vehicle.mass={9.3 + 0.01 * (i + 1):.2f}"]
            for name in order:
                seconds, _ = _build(variants[name], work / f"cache-{name}", work / f"out-{name}",
                                    sets)
                times[name].append(seconds)
            for name in order:
                seconds, out = _build(variants[name], work / f"cache-{name}",
                                      work / f"out-{name}", sets)
                if "is up to date" not in out:
                    raise RuntimeError(f"{name}: the unchanged rebuild rebuilt")
                unchanged[name].append(seconds)
            log(f"repeat {i + 1}: base {times['base'][-1]:.2f} s, new {times['new'][-1]:.2f} s; "
                f"unchanged {unchanged['base'][-1]:.3f} / {unchanged['new'][-1]:.3f} s")
        result = {
            "base": args.base, "repeats": args.repeats, "cpus": os.cpu_count(),
            "load_average_start": load_start, "load_average_end": os.getloadavg(),
            "parameter_edit_s": {n: summary(v) for n, v in times.items()},
            "parameter_edit_ratio_new_over_base": paired_ratios(times["new"], times["base"]),
            "unchanged_s": {n: summary(v) for n, v in unchanged.items()},
            "raw": {"parameter_edit": times, "unchanged": unchanged},
        }
        text = json.dumps(result, indent=1)
        print(text)
        if args.json:
            args.json.write_text(text + "\n")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
