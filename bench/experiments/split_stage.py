"""The instruction cache (issue 53): the per-stage right-hand side as one function (as built)
against the same stage split in two (the array forces apart from the rigid body) and split per
array (one array's force law called in a loop over the six arrays, then the rigid body).

    .venv/bin/python bench/experiments/split_stage.py [--reps N] [--calls N] [--out FILE]

The distributed law's `maglev_dynamics_prepared` is about 55 KB of straight-line code, more
than a 32 KB L1 instruction cache. Splitting it in two leaves the code run per stage as large;
one array's law called six times runs a sixth of it six times. Each variant is a
`maglev_dynamics_prepare`/`maglev_dynamics_prepared` pair (CasADi MX functions calling the SX
parts, each part's constants extracted as maglevgen.codegen.functions._prepared does; the array
law's for each array from p with that array's entries in the first array's places), generated
through the build's C pass (guarded branches included), compiled at the simulation library's
flags and timed per call in one C process, interleaved (bench/c/bench_prepared.c, the state of
bench/experiments/branches.py). Each variant's C is checked against CasADi's evaluation of the
model as built. Writes bench/experiments/split_stage_results.json.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import sys
import tempfile
from pathlib import Path

import casadi as ca
import numpy as np
import sympy as sp

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/: common.py
sys.path.insert(0, str(Path(__file__).resolve().parent))
from common import DRIVER_DIR, EXPERIMENTS, log, paired_ratios, run, summary
from laws import write_input

from maglevgen.carriage import DerivedCarriage
from maglevgen.codegen.branches import guard_discarded_branches
from maglevgen.codegen.casadi_model import casadi_model
from maglevgen.codegen.cpass import postprocess, static_helpers
from maglevgen.codegen.functions import _prepared
from maglevgen.codegen.sympy_casadi import SympyToCasadi, casadi_rewriting_off
from maglevgen.params import load_params
from maglevgen.runtime.compile import DEFAULT_FLAGS
from maglevgen.runtime.library import simulation_library

ARRAY_KEYS = ("position.x", "position.y", "position.z", "normal.x", "normal.y", "normal.z",
              "nominal_gap", "circuits")
N_OUT = 7  # per array: lift, drag, the two spreads, the arm's three components


def _pairs(syms, sx) -> dict:
    return {s: sx[i] for i, s in enumerate(syms)}


def layers(carriage: DerivedCarriage):
    """x, u, p; each array's (lift, drag, spread_L, spread_D, arm) as SX in (x, p); the rigid
    body's xdot in (x, u, A, p), A the 7 x n_arrays array outputs (casadi_model's layers)."""
    m = carriage.model
    x, u, p = (ca.SX.sym(n, v.shape[0]) for n, v in (("x", m.x), ("u", m.u), ("p", m.p)))
    mapping = {**_pairs(m.x, x), **_pairs(m.u, u), **_pairs(m.p, p)}
    n = len(m.arrays)
    speeds = SympyToCasadi(mapping)(m.array_speeds)
    conv = SympyToCasadi({**mapping, **_pairs(m.speed_sym, speeds)})
    lift, drag = conv(m.lift_at_speed), conv(m.drag_at_speed)
    spread, arms = conv(m.spread_at_speed), conv(sp.Matrix.vstack(*m.arms))
    per_array = [ca.vertcat(lift[k], drag[k], spread[k], spread[n + k], arms[3 * k:3 * k + 3])
                 for k in range(n)]
    A = ca.SX.sym("A", N_OUT, n)
    rules = {}
    for k in range(n):
        rules.update({m.lift_sym[k]: A[0, k], m.drag_sym[k]: A[1, k],
                      m.spread_sym[k]: A[2, k], m.spread_sym[n + k]: A[3, k]})
        rules.update({m.arm_sym[3 * k + i]: A[4 + i, k] for i in range(3)})
    wrench = SympyToCasadi({**mapping, **rules})(m.wrench)
    conv = SympyToCasadi({**mapping, **_pairs(m.wrench_sym, wrench)})
    xdot = ca.vertcat(conv(m.kinematics), conv(m.accelerations))
    return x, u, p, per_array, A, xdot


def variants(carriage: DerivedCarriage) -> tuple[dict[str, tuple[ca.Function, ca.Function]],
                                                  dict[str, int]]:
    """Each variant's (prepare, prepared) pair, and the SX instructions its stage runs."""
    x, u, p, per_array, A, xdot = layers(carriage)
    names = carriage.structure.param_names
    n = len(per_array)
    out = {}
    cm = casadi_model(carriage.model)
    whole = ca.Function("maglev_dynamics", [cm.x, cm.u, cm.p], [cm.xdot], ["x", "u", "p"],
                        ["xdot"], {"cse": True})
    out["one function (as built)"] = _prepared(whole, 2, "d")
    with casadi_rewriting_off():
        rigid = ca.Function("rigid", [x, u, A, p], [xdot], ["x", "u", "A", "p"], ["xdot"],
                            {"cse": True})
        r_prep, r_stage = _prepared(rigid, 3, "c")
        forces = ca.Function("forces", [x, p], [ca.horzcat(*per_array)], ["x", "p"], ["A"],
                             {"cse": True})
        f_prep, f_stage = _prepared(forces, 1, "c")
        array = ca.Function("array", [x, p], [per_array[0]], ["x", "p"], ["a"], {"cse": True})
        a_prep, a_stage = _prepared(array, 1, "c")
    first = [names.index(f"arrays.1.{k}") for k in ARRAY_KEYS]

    def swapped(pv, k: int):
        """p with array k's entries in the first array's places."""
        idx = list(range(pv.shape[0]))
        for i, j in zip(first, (names.index(f"arrays.{k + 1}.{key}") for key in ARRAY_KEYS),
                        strict=True):
            idx[i], idx[j] = j, i
        return pv[idx]

    pm, xm, um = ca.MX.sym("p", p.shape[0]), ca.MX.sym("x", x.shape[0]), ca.MX.sym("u",
                                                                                 u.shape[0])
    # the split in two
    nf, nr = f_prep.size1_out(0), r_prep.size1_out(0)
    prep2 = ca.Function("maglev_dynamics_prepare", [pm], [ca.vertcat(f_prep(pm), r_prep(pm))],
                        ["p"], ["d"])
    d2 = ca.MX.sym("d", nf + nr)
    stage2 = ca.Function("maglev_dynamics_prepared", [xm, um, d2],
                         [r_stage(xm, um, f_stage(xm, d2[:nf]), d2[nf:])], ["x", "u", "d"],
                         ["xdot"])
    out["forces | rigid body"] = (prep2, stage2)
    # per array: one array's law in a loop (map, serial) over the arrays' constants
    na = a_prep.size1_out(0)
    prep6 = ca.Function("maglev_dynamics_prepare", [pm], [ca.vertcat(
        *[a_prep(swapped(pm, k)) for k in range(n)], r_prep(pm))], ["p"], ["d"])
    d6 = ca.MX.sym("d", n * na + nr)
    arrays = a_stage.map(n, "serial")(ca.repmat(xm, 1, n), ca.reshape(d6[:n * na], na, n))
    stage6 = ca.Function("maglev_dynamics_prepared", [xm, um, d6],
                         [r_stage(xm, um, arrays, d6[n * na:])], ["x", "u", "d"], ["xdot"])
    out["per array (a loop of 6) | rigid body"] = (prep6, stage6)
    counts = {"one function (as built)": out["one function (as built)"][1].n_instructions(),
              "forces | rigid body": f_stage.n_instructions() + r_stage.n_instructions(),
              "per array (a loop of 6) | rigid body": n * a_stage.n_instructions()
              + r_stage.n_instructions()}
    return out, counts


def build(prepare: ca.Function, prepared: ca.Function, path: Path) -> int:
    """The pair's C through the build's C pass into the shared library ``path``; returns the
    bytes of the library's .text."""
    gen = ca.CodeGenerator(path.stem + ".c", {"with_header": False})
    gen.add(prepare)
    gen.add(prepared)
    source = guard_discarded_branches(static_helpers(postprocess(gen.dump(), "double")))
    path.with_suffix(".c").write_text(source)
    run(["gcc", *DEFAULT_FLAGS, "-o", path, path.with_suffix(".c"), "-lm"])
    size = run(["size", "-A", path])
    return int(re.search(r"^\.text\s+(\d+)", size, re.M).group(1))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--reps", type=int, default=15)
    ap.add_argument("--calls", type=int, default=20_000)
    ap.add_argument("--out", type=Path, default=EXPERIMENTS / "split_stage_results.json")
    args = ap.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="bench_split_"))
    carriage = DerivedCarriage(load_params())
    log("functions")
    pairs, counts = variants(carriage)
    input_file = write_input(carriage, simulation_library(carriage.structure), work / "in.txt")
    p, x, u = (np.array(line.split(), float)
               for line in input_file.read_text().split("\n")[1:4])
    ref_prep, ref_stage = pairs["one function (as built)"]
    reference = np.array(ref_stage(x, u, ref_prep(p))).ravel()
    libs, text, agreement = {}, {}, {}
    for k, (label, (prep, stage)) in enumerate(pairs.items()):
        log(f"C: {label}")
        libs[label] = work / f"lib{k}.so"
        text[label] = build(prep, stage, libs[label])
        d = np.array(ca.external("maglev_dynamics_prepare", str(libs[label]))(p)).ravel()
        got = np.array(ca.external("maglev_dynamics_prepared", str(libs[label]))(x, u, d))
        # normwise: the accelerations near the trim are the small remainders of force sums
        # that cancel, where another order of the same operations rounds differently
        agreement[label] = float(np.max(np.abs(got.ravel() - reference))
                                 / np.max(np.abs(reference)))
    exe = work / "bench_prepared"
    run(["gcc", "-std=c99", "-O2", "-o", exe, DRIVER_DIR / "bench_prepared.c", "-ldl"])
    log(f"timing {len(libs)} builds ({args.reps} repeats of {args.calls} calls)")
    raw = json.loads(run([exe, args.reps, args.calls, input_file, *libs.values()]))
    ns = dict(zip(libs, raw, strict=True))
    base = ns["one function (as built)"]
    out = {"reps": args.reps, "calls": args.calls, "text_bytes": text,
           "sx_instructions_per_stage": counts,
           "max_relative_difference_to_casadi": agreement,
           "ns_per_stage": {k: summary(v) for k, v in ns.items()},
           "ratio_to_one_function": {k: paired_ratios(v, base) for k, v in ns.items()}}
    args.out.write_text(json.dumps(out, indent=1) + "\n")
    print("| stage | library .text [bytes] | SX instructions per stage | ns per stage (median) "
          "| / one function (per repeat) | max abs. difference / max abs. xdot (CasADi) |")
    print("| --- | --- | --- | --- | --- | --- |")
    for label in libs:
        print(f"| {label} | {text[label]} | {counts[label]} | "
              f"{out['ns_per_stage'][label]['median']:.0f} | "
              f"{out['ratio_to_one_function'][label]['median']:.3f} | "
              f"{agreement[label]:.1e} |")
    shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
