"""Generated functions that report failure: the checked entry points and the MAGLEV_ERR_* codes.

CasADi's generated functions return 0 whatever their inputs: the trim's Newton iterations end
after their count at any speed (all NaN at v = 0, a nonsensical pose below lift-off), a NaN
state passes through a control tick into the array forces and a zero mass gives infinite
accelerations. :func:`check_entries` renames the CasADi entry point of *every* generated
function to a ``static`` ``NAME_unchecked`` and defines ``NAME`` around it with the checks, so
that no exported function returns 0 with a NaN or an infinity in an output; the work sizes
(``NAME_work``) stay CasADi's: the trim's checks evaluate the dynamics and the gaps in the
caller's work arrays, which the Newton solve's sizes cover (checked at generation, else the
checks get their own on the stack).

Every function, in this order (``ENTRY_CHECKS``, which maglev.h states next to each one):

* ``arg`` and ``res`` not NULL, ``iw`` and ``w`` not NULL where the function uses them
  (``MAGLEV_ERR_ARGUMENT``; a NULL ``arg[i]`` is CasADi's zero input and a NULL ``res[i]``
  skips output i, as CasADi's API has it);
* every input finite (``MAGLEV_ERR_NONFINITE``);
* with run-time parameters, every entry of p inside its range of the parameter schema
  (maglevgen.params: a positive mass, wavelength, resistance, inductance, ...;
  ``MAGLEV_ERR_PARAMETER``);
* schedule functions (``TRIM_KIND``, each runs the trim Newton solve; the accelerating trim's
  with its acceleration, also checked finite): v in the envelope's [v_min, v_max] when the
  parameters are baked (the range is baked with them, the same as the table schedule's), v > 0
  with run-time parameters (the simulation library bisects the lift-off speed through it,
  below any v_min), the trim's accelerations within ``TRIM_TOLERANCES`` (the Newton solve
  converged; for the accelerating trim the accelerations less those of the translation at a,
  a/v times the trim's body velocity) and every gap at or above the track's minimum gap
  (``track.min_gap``, as ``maglevgen.operating.checked_trim``);
* the CasADi function's own return code (``MAGLEV_ERR_INTERNAL``), then every output finite
  (``MAGLEV_ERR_NONFINITE_OUTPUT``).

On any error every output that the caller asked for (non-NULL ``res[i]``) is set to zero: the
safe state of a tick is no control force, and a failed trim must not look like a pose.

This module is imported by the ctypes runtime for the code names, so it imports nothing heavy.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence

#: name -> (value, meaning): maglev.h documents them, the C returns them, the runtime names them.
ERROR_CODES: dict[str, tuple[int, str]] = {
    "MAGLEV_OK": (0, "success"),
    "MAGLEV_ERR_NONFINITE": (1, "an input is NaN or infinite (outputs zeroed)"),
    "MAGLEV_ERR_SPEED": (2, "speed outside the function's range: outside the envelope's "
                            "[v_min, v_max] for the baked Newton trim and maglev_schedule, "
                            "v <= 0 for the run-time-parameter trim (outputs zeroed; "
                            "maglev_schedule: the end node's values)"),
    "MAGLEV_ERR_NOT_CONVERGED": (3, "the trim's Newton iteration did not reach its tolerance "
                                    "(no trim: below lift-off?) (outputs zeroed)"),
    "MAGLEV_ERR_CONTACT": (4, "the trim has a gap below track.min_gap (outputs zeroed)"),
    "MAGLEV_ERR_NONFINITE_OUTPUT": (5, "an output came out NaN or infinite (outputs zeroed)"),
    "MAGLEV_ERR_INTERNAL": (6, "the CasADi function itself returned an error (outputs zeroed)"),
    "MAGLEV_ERR_PARAMETER": (7, "an entry of the run-time parameter vector p is outside its "
                                "range in the parameter schema (`maglevgen params schema`: "
                                "e.g. a mass, wavelength, resistance or inductance not "
                                "positive) (outputs zeroed)"),
    "MAGLEV_ERR_ARGUMENT": (8, "a required pointer is NULL (arg, res, a work array the "
                               "function uses, a table), or a count, size or step is out of "
                               "range (outputs zeroed where they can be reached)"),
}
ERROR_NAMES: dict[int, str] = {v: k for k, (v, _) in ERROR_CODES.items()}

#: the largest computation delay, in ticks, that the simulation loop's command buffer holds
#: (maglev_simulate.h's MAGLEV_SIM_MAX_DELAY; maglevgen.simulate.Tick refuses more): a
#: firmware's computation takes a tick or two, not more
MAX_DELAY_TICKS = 4

TRIM_KIND = ("maglev_trim", "maglev_trim_accelerating", "maglev_axis_plants",
             "maglev_lqr_gains")
#: the Newton solves maglev_trim_checked calls: the constant-speed and the accelerating trim
TRIM_SOLVES = ("maglev_trim", "maglev_trim_accelerating")
TICK_KIND = ("maglev_lqr_control", "maglev_damping_control", "maglev_coupled_control",
             "maglev_allocate", "maglev_axis_gains")

#: inputs not checked for finiteness at entry (their outputs are): the prepared constants c,
#: which maglev_closed_loop_prepare checked when it made them, enter every RK4 stage of a
#: run (four calls a step), where checking their 392 values again cost 10 to 20 % of the run
UNCHECKED_INPUTS = {("maglev_closed_loop_prepared", "c")}

#: largest |acceleration| [m/s^2, rad/s^2] at an accepted trim, per precision: double as
#: checked_trim; single a hundred times the Newton tolerance (float32 rounding of the
#: accelerations at trim is 2e-6 to 1e-5, codegen.functions.NEWTON_TOLERANCES)
TRIM_TOLERANCES = {"double": "1e-8", "single": "1e-3f"}


def error_name(code: int) -> str:
    """The MAGLEV_ERR_* name of a return code (``MAGLEV_ERR_<code>`` for an unknown one)."""
    return ERROR_NAMES.get(code, f"MAGLEV_ERR_{code}")


def error_defines() -> str:
    """The ``#define MAGLEV_ERR_*`` lines (identical text in maglev.h and the C: a benign
    redefinition in C)."""
    return "".join(f"#define {name} {value}  /* {doc} */\n"
                   for name, (value, doc) in ERROR_CODES.items())


def work_sizes(source: str) -> dict[str, tuple[int, int, int, int]]:
    """(sz_arg, sz_res, sz_iw, sz_w) of every function as its generated ``NAME_work`` reports
    them (CasADi's codegen counts differently from ``Function.sz_w()``)."""
    pat = re.compile(r"int (\w+)_work\(casadi_int \*sz_arg[^{]*\{\s*"
                     r"if \(sz_arg!=0\) \*sz_arg = (\d+);\s*if \(sz_res!=0\) \*sz_res = (\d+);"
                     r"\s*if \(sz_iw!=0\) \*sz_iw = (\d+);\s*if \(sz_w!=0\) \*sz_w = (\d+);")
    return {m.group(1): tuple(int(g) for g in m.groups()[1:]) for m in pat.finditer(source)}


def _sizes(io: Sequence[Mapping]) -> list[int]:
    return [int(d["rows"]) * int(d["cols"]) for d in io]


def _zero_outputs(outs: list[int]) -> str:
    return "".join(f"  maglev_zero_res(res, {i}, {n});\n" for i, n in enumerate(outs))


def _p_index(fn: Mapping, runtime: bool) -> int | None:
    """The position of the parameter vector p among ``fn``'s inputs (None: none, or baked)."""
    names = [io["name"] for io in fn["inputs"]]
    return names.index("p") if runtime and "p" in names else None


def _pointer_check(name: str, work: Mapping[str, tuple[int, ...]]) -> str:
    """The C condition that a required pointer is NULL: arg, res, and the work arrays that
    ``name``'s work sizes say it uses."""
    sz = work.get(name, (0, 0, 0, 0))
    return f"!maglev_pointers_ok(arg, res, iw, w, {int(sz[2] > 0)}, {int(sz[3] > 0)})"


def entry_checks(fn: Mapping, runtime: bool, work: Mapping[str, tuple[int, ...]]) -> str:
    """What the checked entry point of ``fn`` verifies, in its order (maglev.h's text)."""
    used = [w for w, k in (("iw", 2), ("w", 3)) if work.get(fn["name"], (0,) * 4)[k] > 0]
    steps = ["arg, res" + "".join(f", {w}" for w in used) + " not NULL (MAGLEV_ERR_ARGUMENT)"]
    skipped = [io["name"] for io in fn["inputs"] if (fn["name"], io["name"]) in UNCHECKED_INPUTS]
    if len(skipped) < len(fn["inputs"]):
        but = f" but {', '.join(skipped)} (checked where it is made)" if skipped else ""
        steps.append(f"every input{but} finite (MAGLEV_ERR_NONFINITE)")
    if _p_index(fn, runtime) is not None:
        steps.append("every p[i] in the range its MAGLEV_P_* line states (the schema's; "
                     "MAGLEV_ERR_PARAMETER)")
    if fn["name"] in TRIM_KIND:
        steps.append("v in range (MAGLEV_ERR_SPEED), a converged trim "
                     "(MAGLEV_ERR_NOT_CONVERGED) with every gap >= track.min_gap "
                     "(MAGLEV_ERR_CONTACT)")
    steps.append("every output finite (MAGLEV_ERR_NONFINITE_OUTPUT)")
    return "; ".join(steps) + "; on an error the requested outputs are zero"


def _checked(fn: Mapping, runtime: bool, work: Mapping[str, tuple[int, ...]]) -> str:
    """The checked entry point of a function that is not of TRIM_KIND."""
    name, ins, outs = fn["name"], _sizes(fn["inputs"]), _sizes(fn["outputs"])
    in_checks = " ||\n      ".join(f"!maglev_all_finite(arg[{i}], {n})"
                                   for i, (n, io) in enumerate(zip(ins, fn["inputs"],
                                                                   strict=True))
                                   if (name, io["name"]) not in UNCHECKED_INPUTS)
    out_checks = " ||\n      ".join(f"!maglev_all_finite(res[{i}], {n})"
                                    for i, n in enumerate(outs))
    ip = _p_index(fn, runtime)
    body = ""
    if in_checks:
        body += f"  }} else if ({in_checks}) {{\n    rc = MAGLEV_ERR_NONFINITE;\n"
    if ip is not None:
        body += f"  }} else if (!maglev_params_ok(arg[{ip}])) {{\n    rc = MAGLEV_ERR_PARAMETER;\n"
    return (
        f"CASADI_SYMBOL_EXPORT int {name}(const casadi_real** arg, casadi_real** res, "
        "casadi_int* iw, casadi_real* w, int mem) {\n"
        "  int rc = MAGLEV_OK;\n"
        f"  if ({_pointer_check(name, work)}) {{\n    rc = MAGLEV_ERR_ARGUMENT;\n"
        + body +
        f"  }} else if ({name}_unchecked(arg, res, iw, w, mem) != 0) {{\n"
        "    rc = MAGLEV_ERR_INTERNAL;\n"
        f"  }} else if ({out_checks}) {{\n    rc = MAGLEV_ERR_NONFINITE_OUTPUT;\n"
        "  } else {\n    return MAGLEV_OK;\n  }\n"
        + _zero_outputs(outs) + "  return rc;\n}\n\n")


def _speed_check(speed_range: tuple[str, str] | None) -> tuple[str, str]:
    """(comment, C statement) of the speed check: [v_min, v_max] (C literals), else v > 0."""
    if speed_range is None:
        return "v > 0", "if (!(*v > 0)) return MAGLEV_ERR_SPEED;"
    lo, hi = speed_range
    return (f"v in [{lo}, {hi}] (the envelope)",
            f"if (!((*v >= {lo}) && (*v <= {hi}))) return MAGLEV_ERR_SPEED;")


def _params_helper(limits: Sequence[tuple[str, str]]) -> str:
    """``maglev_params_ok``: every p[i] inside [lo_i, hi_i] (C literals; NaN fails)."""
    n = len(limits)
    lo = ",\n  ".join(a for a, _ in limits)
    hi = ",\n  ".join(b for _, b in limits)
    return (f"/* the ranges of the parameter schema (maglevgen.params), MAGLEV_P_* order */\n"
            f"static const casadi_real maglev_p_min[{n}] = {{\n  {lo}\n}};\n"
            f"static const casadi_real maglev_p_max[{n}] = {{\n  {hi}\n}};\n\n"
            "/* p inside the schema's ranges (a NULL p is CasADi's zero vector: no mass) */\n"
            "static int maglev_params_ok(const casadi_real* p) {\n  int i;\n"
            "  if (p == 0) return 0;\n"
            f"  for (i = 0; i < {n}; ++i) {{\n"
            "    if (!(p[i] >= maglev_p_min[i] && p[i] <= maglev_p_max[i])) return 0;\n"
            "  }\n  return 1;\n}\n\n")


def _trim_helper(table: Mapping[str, Mapping], work: Mapping[str, tuple[int, ...]],
                 precision: str, runtime: bool, min_gap: str,
                 speed_range: tuple[str, str] | None) -> str:
    """``maglev_trim_checked``: the trim at v (accelerating at *a when a is not NULL) into x and
    F_prop, with its checks."""
    used = (*TRIM_SOLVES, "maglev_dynamics", "maglev_gaps")
    sz = [max(work[f][k] for f in used) + 1 for k in range(2)]
    nx = table["maglev_dynamics"]["inputs"][0]["rows"]
    nu = table["maglev_dynamics"]["inputs"][1]["rows"]
    ng = table["maglev_gaps"]["outputs"][0]["rows"]
    n_p = table["maglev_trim"]["inputs"][1]["rows"] if runtime else 0
    p_arg = "p" if runtime else "0"
    tol = TRIM_TOLERANCES[precision]
    p_check = (f"  if (!maglev_all_finite(v, 1) || !maglev_all_finite(p, {n_p})) "
               "return MAGLEV_ERR_NONFINITE;\n"
               "  if (!maglev_params_ok(p)) return MAGLEV_ERR_PARAMETER;\n" if runtime else
               "  if (!maglev_all_finite(v, 1)) return MAGLEV_ERR_NONFINITE;\n")
    speed_doc, speed_check = _speed_check(speed_range)
    p_range = ", p in range" if runtime else ""
    return f"""/* the trim at *v into x and *F_prop (a NULL: maglev_trim; else the accelerating trim
   at *a, maglev_trim_accelerating): v, a and p finite{p_range}, {speed_doc}, the
   accelerations at the trim less those of the translation at a (a/v times the body velocity,
   derive/trim.py) within {tol} (the Newton solve converged), every gap >= track.min_gap */
static int maglev_trim_checked(const casadi_real* v, const casadi_real* a,
                               const casadi_real* p, casadi_real* x, casadi_real* F_prop,
                               casadi_int* iw, casadi_real* w) {{
  const casadi_real* arg[{sz[0]}];
  casadi_real* res[{sz[1]}];
  casadi_real u[{nu}], xdot[{nx}], gaps[{ng}], d;
  int i, rc;
  (void)p;
  if (v == 0) return MAGLEV_ERR_ARGUMENT;
  if (!maglev_all_finite(a, 1)) return MAGLEV_ERR_NONFINITE;
{p_check}  {speed_check}
  res[0] = x;
  res[1] = F_prop;
  arg[0] = v;
  if (a == 0) {{
    arg[1] = {p_arg};
    rc = maglev_trim_unchecked(arg, res, iw, w, 0);
  }} else {{
    arg[1] = a;
    arg[2] = {p_arg};
    rc = maglev_trim_accelerating_unchecked(arg, res, iw, w, 0);
  }}
  if (rc != 0) return MAGLEV_ERR_INTERNAL;
  if (!maglev_all_finite(x, {nx}) || !maglev_all_finite(F_prop, 1)) {{
    return MAGLEV_ERR_NOT_CONVERGED;
  }}
  for (i = 0; i < {nu}; ++i) u[i] = 0;
  u[0] = *F_prop;
  arg[0] = x;
  arg[1] = u;
  arg[2] = {p_arg};
  res[0] = xdot;
  if (maglev_dynamics_unchecked(arg, res, iw, w, 0) != 0) return MAGLEV_ERR_INTERNAL;
  for (i = 6; i < {nx}; ++i) {{
    d = xdot[i];
    if (a != 0 && i < 9) d -= (*a / *v) * x[i];
    if (!(d <= {tol} && d >= -{tol})) return MAGLEV_ERR_NOT_CONVERGED;
  }}
  arg[1] = {p_arg};
  res[0] = gaps;
  if (maglev_gaps_unchecked(arg, res, iw, w, 0) != 0) return MAGLEV_ERR_INTERNAL;
  for (i = 0; i < {ng}; ++i) {{
    if (!(gaps[i] >= {min_gap})) return MAGLEV_ERR_CONTACT;
  }}
  return MAGLEV_OK;
}}

"""


def _work_args(name: str, work: Mapping[str, tuple[int, ...]]) -> tuple[str, str]:
    """(declarations, ``iw, w`` arguments) for maglev_trim_checked inside ``name``: the
    caller's work arrays where ``name``'s own work sizes cover the trim, the dynamics and the
    gaps (they do: the Newton solve evaluates the dynamics), else arrays on the stack."""
    need = [max(work[f][k] for f in (*TRIM_SOLVES, "maglev_dynamics", "maglev_gaps"))
            for k in (2, 3)]
    if work[name][2] >= need[0] and work[name][3] >= need[1]:
        return "", "iw, w"
    return (f"  casadi_int iw_trim[{need[0] + 1}];\n  casadi_real w_trim[{need[1] + 1}];\n",
            "iw_trim, w_trim")


def _trim_kind(fn: Mapping, table: Mapping[str, Mapping], runtime: bool,
               work: Mapping[str, tuple[int, ...]]) -> str:
    name, outs = fn["name"], _sizes(fn["outputs"])
    nx = table["maglev_dynamics"]["inputs"][0]["rows"]
    p = "arg[1]" if runtime else "0"
    decl, iw_w = _work_args(name, work)
    pointers = (f"  if ({_pointer_check(name, work)}) {{\n"
                + _zero_outputs(outs).replace("  maglev", "    maglev")
                + "    return MAGLEV_ERR_ARGUMENT;\n  }\n")
    if name in TRIM_SOLVES:
        accel, p = ("arg[1]", "arg[2]" if runtime else "0") if name != "maglev_trim" \
            else ("0", p)
        body = (f"  casadi_real x[{nx}], F_prop;\n{decl}  int rc;\n" + pointers +
                f"  rc = maglev_trim_checked(arg[0], {accel}, {p},\n"
                "                           res[0] != 0 ? res[0] : x,\n"
                f"                           res[1] != 0 ? res[1] : &F_prop, {iw_w});\n"
                "  (void)iw; (void)w; (void)mem;\n"
                "  if (rc == MAGLEV_OK) return MAGLEV_OK;\n")
    else:
        body = (f"  casadi_real x[{nx}], F_prop;\n{decl}  int rc;\n" + pointers +
                f"  rc = maglev_trim_checked(arg[0], 0, {p}, x, &F_prop, {iw_w});\n"
                "  if (rc == MAGLEV_OK) {\n"
                f"    if ({name}_unchecked(arg, res, iw, w, mem) != 0) {{\n"
                "      rc = MAGLEV_ERR_INTERNAL;\n"
                "    } else if ("
                + " ||\n        ".join(f"!maglev_all_finite(res[{i}], {n})"
                                       for i, n in enumerate(outs))
                + ") {\n      rc = MAGLEV_ERR_NONFINITE_OUTPUT;\n"
                "    } else {\n      return MAGLEV_OK;\n    }\n  }\n")
    return (f"CASADI_SYMBOL_EXPORT int {name}(const casadi_real** arg, casadi_real** res, "
            "casadi_int* iw, casadi_real* w, int mem) {\n" + body
            + _zero_outputs(outs) + "  return rc;\n}\n\n")


_VERSION = re.compile(r"(CASADI_SYMBOL_EXPORT void \w+_casadi_version\(int\* major, int\* minor, "
                      r"int\* patch\) \{\n)((?:  \*\w+ = \d+;\n)+)\}")


def _version_null_safe(source: str) -> str:
    """CasADi's NAME_casadi_version(major, minor, patch) writes through its pointers
    unconditionally: a NULL one (which its type allows) must skip that number instead."""
    found = _VERSION.findall(source)
    if len(found) != 1:
        raise ValueError("the CasADi version function not found once in the generated C")

    def guard(m: re.Match) -> str:
        body = re.sub(r"  \*(\w+) = (\d+);", r"  if (\1 != 0) {\n    *\1 = \2;\n  }",
                      m.group(2))
        return m.group(1) + body + "}"

    return _VERSION.sub(guard, source)


def check_entries(source: str, table: Sequence[Mapping], precision: str, runtime: bool,
                  min_gap: str, speed_range: tuple[str, str] | None = None,
                  p_limits: Sequence[tuple[str, str]] | None = None) -> str:
    """``source`` (post-processed CasADi C) with a checked entry point for every function of
    ``table`` (TRIM_KIND's with the trim's checks). ``min_gap`` is the C expression of
    track.min_gap (``arg[..]`` is not in scope: with run-time parameters ``p[index]``, else a
    literal); ``speed_range``: (v_min, v_max) as C literals, the trim's accepted speeds (None:
    v > 0); ``p_limits``: with run-time parameters, each entry's (lo, hi) as C literals."""
    by_name = {f["name"]: f for f in table}
    wanted = [f["name"] for f in table]
    if runtime and p_limits is None:
        raise ValueError("run-time parameters need the schema's ranges of p (p_limits)")
    for name in wanted:
        head = f"CASADI_SYMBOL_EXPORT int {name}(const casadi_real** arg"
        if source.count(head) != 1:
            raise ValueError(f"entry point of {name} not found once in the generated C")
        source = source.replace(head, f"static int {name}_unchecked(const casadi_real** arg")
    source = _version_null_safe(source)
    work = work_sizes(source)
    block = [
        "/* Checked entry points (maglevgen.codegen.checks): MAGLEV_ERR_* as in maglev.h. */\n",
        error_defines(), "\n",
        "static int maglev_all_finite(const casadi_real* a, int n) {\n"
        "  int i;\n  if (a == 0) return 1;\n"
        "  for (i = 0; i < n; ++i) {\n    if (!isfinite(a[i])) return 0;\n  }\n  return 1;\n}\n\n"
        "static void maglev_zero(casadi_real* a, int n) {\n  int i;\n  if (a == 0) return;\n"
        "  for (i = 0; i < n; ++i) {\n    a[i] = 0;\n  }\n}\n\n"
        "/* output i zeroed, when res and res[i] are given */\n"
        "static void maglev_zero_res(casadi_real** res, int i, int n) {\n"
        "  if (res != 0) {\n    maglev_zero(res[i], n);\n  }\n}\n\n"
        "/* the pointers a function needs: arg and res, iw and w where it uses them */\n"
        "static int maglev_pointers_ok(const casadi_real** arg, casadi_real** res, "
        "const casadi_int* iw,\n"
        "                              const casadi_real* w, int need_iw, int need_w) {\n"
        "  int ok = 1;\n"
        "  if ((arg == 0) || (res == 0)) {\n    ok = 0;\n  }\n"
        "  if ((need_iw != 0) && (iw == 0)) {\n    ok = 0;\n  }\n"
        "  if ((need_w != 0) && (w == 0)) {\n    ok = 0;\n  }\n"
        "  return ok;\n}\n\n",
    ]
    if runtime and any(_p_index(f, runtime) is not None for f in table):
        block.append(_params_helper(p_limits or ()))
    if any(n in TRIM_KIND for n in wanted):
        block.append(_trim_helper(by_name, work, precision, runtime, min_gap, speed_range))
    for name in wanted:
        block.append(_trim_kind(by_name[name], by_name, runtime, work) if name in TRIM_KIND
                     else _checked(by_name[name], runtime, work))
    tail = "\n#ifdef __cplusplus\n} /* extern \"C\" */\n#endif\n"
    if not source.endswith(tail):
        raise ValueError("generated C does not end with its extern \"C\" block")
    return source[: -len(tail)] + "\n" + "".join(block) + tail
