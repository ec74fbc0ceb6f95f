"""What evaluating several Monte-Carlo samples' dynamics at once in SIMD lanes would buy.

    .venv/bin/python bench/experiments/simd_lanes.py [--reps N] [--out FILE]

An experiment, not a feature: the distributed law's `maglev_dynamics_prepared` (the function
the firmware loop evaluates at every RK4 stage, 78 % of a Monte-Carlo run's C) as CasADi
writes it, translated statement by statement into C over W-lane vectors (GCC's vector
extensions: every arithmetic statement, comparison and select on W samples at once, exp, sin
and cos per lane through libm). With ``memo``, an exp whose argument is -1 in every lane is
the stored exp(-1): that is the closed form's argument wherever the series branch is taken (the
Piecewise passes 1 to the branch it discards), so a flying carriage never needs it. ``stub``
replaces exp, sin and cos by the identity (wrong values: what the lanes' arithmetic alone
costs, the bound on what vector transcendentals could add). Each lane
is checked bit for bit against the scalar library at the same state (no contraction: -std=c99
keeps -ffp-contract=off). Timed per state in one process (bench/c/bench_lanes.c) for W = 2
(SSE2), 4 (AVX2) and 8 (AVX-512F) where the CPU has them. A batch driver that ran W samples
in lock step (ticks, delays, contacts per lane) is what would turn this into runs per second.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/: common.py
from common import DRIVER_DIR, EXPERIMENTS, log, run, summary
from law_instructions import dynamics, shared_library
from laws import write_input

from maglevgen.carriage import DerivedCarriage
from maglevgen.params import load_params
from maglevgen.runtime.library import simulation_library

LANES = {2: "", 4: "-mavx2", 8: "-mavx512f"}  # W: the flag its vectors need
CPU_FLAG = {2: "sse2", 4: "avx2", 8: "avx512f"}

_PRELUDE = """#include <math.h>
#include <string.h>
typedef double V __attribute__((vector_size({bytes})));
typedef long long VI __attribute__((vector_size({bytes})));
#define ZERO ((V){{0}})
#define ONE (ZERO + 1.0)
#define AND(x, m) ((V)((VI)(x) & (VI)(m)))
#define B2D(m) AND(ONE, (m))
static const double EXP_M1 = 0.36787944117144233;
static inline V vexp(V a) {{
    V r;
    int l;
{memo}    for (l = 0; l < {w}; ++l) r[l] = {exp}(a[l]);
    return r;
}}
static inline V vsin(V a) {{ V r; int l; for (l = 0; l < {w}; ++l) r[l] = {sin}(a[l]); return r; }}
static inline V vcos(V a) {{ V r; int l; for (l = 0; l < {w}; ++l) r[l] = {cos}(a[l]); return r; }}
static inline V vabs(V x) {{ return (V)((VI)x & ((VI){{0}} + 0x7fffffffffffffffLL)); }}
static inline V vsign(V x) {{  /* casadi_sign: x<0 ? -1 : x>0 ? 1 : x */
    VI lt = (VI)(x < ZERO), gt = (VI)(x > ZERO), eq = ~(lt | gt);
    return (V)((lt & (VI)(ZERO - 1.0)) | (gt & (VI)ONE) | (eq & (VI)x));
}}
"""
_MEMO = """    {
        int all = 1;
        for (l = 0; l < %d; ++l) all &= a[l] == -1.0;
        if (all) return ZERO + EXP_M1;
    }
"""


def function_body(c_source: str, name: str) -> str:
    """The CasADi body (``static int casadi_fN(...) {...}``) of the function ``name``."""
    at = c_source.index(f"/* {name}:")
    start = c_source.index("static int casadi_f", at)
    return c_source[start:c_source.index("\n}\n", start) + 3]


def translate(body: str, w: int, variant: str) -> str:
    """The body over W-lane vectors (``variant``: "", "memo" or "stub"); a statement of a kind
    not handled here is left as it is, so that the compiler refuses it (double and V do not
    mix)."""
    stub = variant == "stub"
    out = [_PRELUDE.format(bytes=8 * w, w=w, memo=_MEMO % w if variant == "memo" else "",
                           exp="" if stub else "exp", sin="" if stub else "sin",
                           cos="" if stub else "cos")]
    for line in body.splitlines():
        if line.startswith("static int casadi_f"):
            out.append("int lanes_prepared(const V** arg, V** res) {")
            continue
        if "(void)iw" in line:
            continue
        s = line.replace("casadi_real", "V")
        s = re.sub(r"arg\[(\d)\]\? (arg\[\d\]\[\d+\]) : 0", r"\2", s)
        s = s.replace("if (res[0]!=0) ", "")
        if m := re.fullmatch(r"\s*(a\d+)=\((a\d+)!=0\?(a\d+):0\);", s):
            s = f"  {m[1]}=AND({m[3]},{m[2]}!=ZERO);"
        elif m := re.fullmatch(r"\s*(a\d+)=\((a\d+)==0\);", s):
            s = f"  {m[1]}=B2D({m[2]}==ZERO);"
        elif m := re.fullmatch(r"\s*(a\d+)=\((a\d+)<(a\d+)\);", s):
            s = f"  {m[1]}=B2D({m[2]}<{m[3]});"
        elif m := re.fullmatch(r"\s*(a\d+)=(-?[0-9][0-9.e+-]*);", s):
            s = f"  {m[1]}=ZERO+{m[2]};"
        elif m := re.fullmatch(r"\s*(a\d+)=casadi_sq\((a\d+)\);", s):
            s = f"  {m[1]}=({m[2]}*{m[2]});"  # casadi_sq(x) is x*x
        s = s.replace("casadi_fabs(", "vabs(").replace("casadi_sign(", "vsign(")
        s = re.sub(r"\b(exp|sin|cos)\(", r"v\1(", s)
        out.append(s)
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--reps", type=int, default=9)
    ap.add_argument("--calls", type=int, default=40_000)
    ap.add_argument("--out", type=Path, default=EXPERIMENTS / "simd_lanes_results.json")
    args = ap.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="bench_lanes_"))
    carriage = DerivedCarriage(load_params())
    _f, prepare, prepared = dynamics(carriage.model)
    scalar = work / "scalar.so"
    source = shared_library(prepare, prepared, scalar)
    input_file = write_input(carriage, simulation_library(carriage.structure), work / "in.txt")
    body = function_body(source, "maglev_dynamics_prepared")
    cpu = Path("/proc/cpuinfo").read_text() if Path("/proc/cpuinfo").exists() else ""
    results = {}
    for w, flag in LANES.items():
        if CPU_FLAG[w] not in cpu.split():
            log(f"W = {w}: the CPU has no {CPU_FLAG[w]}")
            continue
        for variant in ("", "memo", "stub"):
            label = f"W={w}{', ' + variant if variant else ''}"
            log(label)
            lanes_c = work / f"lanes{w}{variant}.c"
            lanes_c.write_text(translate(body, w, variant))
            exe = work / f"bench_lanes{w}{variant}"
            flags = ["-std=c99", "-O2", *([flag] if flag else [])]
            run(["gcc", *flags, f"-DW={w}", "-o", exe, DRIVER_DIR / "bench_lanes.c", lanes_c,
                 "-ldl", "-lm"])
            raw = json.loads(run([exe, args.reps, args.calls, scalar, input_file]))
            s, v = summary(raw["scalar_ns"]), summary(raw["lanes_ns_per_state"])
            results[label] = {"bitwise_same": raw["bitwise_same"], "scalar_ns": s,
                              "lanes_ns_per_state": v,
                              "speedup": s["median"] / v["median"]}
    args.out.write_text(json.dumps(results, indent=1) + "\n")
    print("| lanes | scalar [ns per state] | lanes [ns per state] | speed-up | each lane "
          "bit for bit the scalar's (stub: not meant to be) |")
    print("| --- | --- | --- | --- | --- |")
    for label, r in results.items():
        print(f"| {label} | {r['scalar_ns']['median']:.0f} | "
              f"{r['lanes_ns_per_state']['median']:.0f} | {r['speedup']:.2f}x | "
              f"{'yes' if r['bitwise_same'] else '**no**'} |")
    shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
