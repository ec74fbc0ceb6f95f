"""Where a cold `maglevgen build` spends its time: the build from an empty cache under py-spy
(every process sampled, --subprocesses) with a C compiler wrapper that logs each gcc's CPU
time, then the sampled time per process and stage.

    .venv/bin/python bench/experiments/cold_profile.py [--work DIR] [--rate HZ] [--out FILE]
    .venv/bin/python bench/experiments/cold_profile.py --raw FILE --cc-log FILE   (only the tables)

Needs py-spy (`pip install py-spy`). py-spy counts the time a process is running or waiting
for a core, so on a loaded machine the seconds overstate CPU time; the shares within a
process compare. The build's own CPU time comes from `/usr/bin/time`-like rusage of its
children, the compiles' from the wrapper's log.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from collections import Counter, defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/: common.py
from common import EXPERIMENTS, ROOT, log

# stages (a frame and what the table calls it), in the build's order
STAGES = (
    ("check_build_inputs (maglevgen/build.py)", "check_build_inputs (the CLI's first step)"),
    ("runtime_sources (runtime/library.py)", "derivation + CasADi + C pass (runtime_sources)"),
    ("build_functions (maglevgen/codegen/functions.py)", "CasADi functions (build_functions)"),
    ("_stiffness_parts (maglevgen/codegen/functions.py)",
     "SymPy Jacobians of the stiffness parts (_stiffness_parts)"),
    ("render_c (maglevgen/codegen/generate.py)", "C text and its checks (render_c, cpass)"),
    ("Carriage.functions (maglevgen/carriage.py)",
     "lambdified model (Carriage.functions: SymPy Jacobians, lambdify)"),
    ("run_build (maglevgen/build.py)", "run_build"),
    ("run_scenarios (maglevgen/analyses/simulate.py)", "three simulations (run_scenarios)"),
    ("compute_envelope (maglevgen/analyses/envelope.py)", "envelope (compute_envelope)"),
    ("study (maglevgen/analyses/roa.py)", "region of attraction (roa.study)"),
    ("_report_files (maglevgen/build.py)", "report (_report_files)"),
    ("_verification (maglevgen/report/sections/verification.py)", "report: verification"),
    ("render_figures (maglevgen/analyses/sim_output.py)", "figures (render_figures)"),
    ("_find_and_load (<frozen importlib._bootstrap>)", "imports"),
)

WRAPPER = """#!/bin/sh
# logs each compile: wall, user and system seconds, the C files' sizes, the flags
t=$(mktemp)
/usr/bin/time -f "%e %U %S" -o "$t" {cc} "$@"
rc=$?
sizes=""
for a in "$@"; do case "$a" in *.c) sizes="$sizes $(basename "$a")=$(stat -c %s "$a")";; esac; done
echo "$(cat "$t") |$sizes | $*" >> {log}
rm -f "$t"
exit $rc
"""


def profile(raw: Path) -> dict[str, dict[str, float]]:
    """Sampled seconds per process (its command's last process frame) and stage."""
    per: dict[str, Counter] = defaultdict(Counter)
    for line in raw.read_text().splitlines():
        stack, _, n = line.rpartition(" ")
        frames = [re.sub(r":\d+\)", ")", f) for f in stack.split(";")]
        procs = [f for f in frames if f.startswith("process ")]
        proc = procs[-1].split(":")[0] if procs else "?"
        per[proc]["(all)"] += int(n)
        seen = set(frames)
        for frame, _label in STAGES:
            if frame in seen:
                per[proc][frame] += int(n)
    return {p: dict(c) for p, c in per.items()}


def compiles(cc_log: Path) -> list[dict]:
    out = []
    for line in cc_log.read_text().splitlines():
        times, sizes, _flags = line.split(" | ", 2) if line.count(" | ") >= 2 else (line, "", "")
        wall, user, system = map(float, times.split()[:3])
        out.append({"wall_s": wall, "user_s": user, "system_s": system,
                    "sources": sizes.strip()})
    return out


def tables(prof: dict, cc: list[dict], rate: int) -> list[str]:
    lines = ["| process | stage | sampled s | share of the process |", "| --- | --- | --- | --- |"]
    for proc, counts in sorted(prof.items(), key=lambda kv: -kv[1]["(all)"]):
        total = counts["(all)"]
        lines.append(f"| {proc} | (all) | {total / rate:.0f} | 100 % |")
        for frame, label in STAGES:
            if counts.get(frame):
                lines.append(f"| | {label} | {counts[frame] / rate:.0f} | "
                             f"{100 * counts[frame] / total:.0f} % |")
    lines += ["", "| compile | user s | system s | wall s |", "| --- | --- | --- | --- |"]
    for c in cc:
        lines.append(f"| {c['sources']} | {c['user_s']:.1f} | {c['system_s']:.1f} | "
                     f"{c['wall_s']:.0f} |")
    lines.append(f"| **all compiles** | {sum(c['user_s'] for c in cc):.1f} | "
                 f"{sum(c['system_s'] for c in cc):.1f} | - |")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--work", type=Path, help="keep the cache and output here")
    ap.add_argument("--rate", type=int, default=20, help="py-spy samples per second")
    ap.add_argument("--raw", type=Path, help="an existing py-spy raw file: only the tables")
    ap.add_argument("--cc-log", type=Path, help="with --raw: the wrapper's compile log")
    ap.add_argument("--out", type=Path, default=EXPERIMENTS / "cold_profile_results.json")
    args = ap.parse_args(argv)
    if args.raw:
        cc = compiles(args.cc_log) if args.cc_log else []
        print("\n".join(tables(profile(args.raw), cc, args.rate)))
        return 0
    spy = shutil.which("py-spy") or str(Path(sys.executable).with_name("py-spy"))
    work = args.work or Path(tempfile.mkdtemp(prefix="maglevgen-cold-"))
    cache, out_dir = work / "cache", work / "out"
    shutil.rmtree(cache, ignore_errors=True)
    shutil.rmtree(out_dir, ignore_errors=True)
    cache.mkdir(parents=True)
    cc_log, raw = work / "cc.log", work / "pyspy.txt"
    cc_log.unlink(missing_ok=True)
    wrapper = work / "cc-logged"
    wrapper.write_text(WRAPPER.format(cc=shutil.which(os.environ.get("CC", "gcc")),
                                      log=cc_log))
    wrapper.chmod(0o755)
    env = {**os.environ, "MAGLEVGEN_CACHE": str(cache), "CC": str(wrapper)}
    load0 = os.getloadavg()
    log(f"cold build in {work} (load average {load0[0]:.2f})")
    t0 = time.perf_counter()
    subprocess.run([spy, "record", "--subprocesses", "-r", str(args.rate), "-f", "raw", "-o",
                    str(raw), "--", str(Path(sys.executable).with_name("maglevgen")), "build",
                    "--out", str(out_dir), "--no-pdf"], env=env, cwd=ROOT, check=True,
                   capture_output=True)
    wall = time.perf_counter() - t0
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    result = {"wall_s": wall, "user_s": kids.ru_utime, "system_s": kids.ru_stime,
              "load_average_start": load0, "load_average_end": os.getloadavg(),
              "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
              "profile": profile(raw), "compiles": compiles(cc_log), "rate": args.rate}
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(f"wall {wall:.0f} s, CPU {kids.ru_utime:.0f} s user + {kids.ru_stime:.0f} s system "
          "(py-spy's own included)")
    print("\n".join(tables(result["profile"], result["compiles"], args.rate)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
