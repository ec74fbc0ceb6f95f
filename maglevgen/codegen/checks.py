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
  (``track.min_gap``, as ``maglevgen.control.operating.checked_trim``);
* the CasADi function's own return code (``MAGLEV_ERR_INTERNAL``), then every output finite
  (``MAGLEV_ERR_NONFINITE_OUTPUT``).

On any error every output that the caller asked for (non-NULL ``res[i]``) is set to zero: the
safe state of a tick is no control force, and a failed trim must not look like a pose.

This module is imported by the ctypes runtime for the code names, so it imports nothing heavy.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence

__all__ = ["ERROR_CODES", "MAX_DELAY_TICKS", "check_entries", "entry_checks", "error_defines",
           "error_name", "work_sizes"]

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
    "MAGLEV_ERR_SENSOR": (9, "no usable reading of a sensor the function needs (the sense "
                             "tick: no gap reading flagged valid, finite and in its range) "
                             "(outputs zeroed)"),
}
ERROR_NAMES: dict[int, str] = {v: k for k, (v, _) in ERROR_CODES.items()}

#: the largest computation delay, in ticks, that the simulation loop's command buffer holds
#: (maglev_simulate.h's MAGLEV_SIM_MAX_DELAY; maglevgen.analyses.simulate.Tick refuses more): a
#: firmware's computation takes a tick or two, not more
MAX_DELAY_TICKS = 4

TRIM_KIND = ("maglev_trim", "maglev_trim_accelerating", "maglev_axis_plants",
             "maglev_lqr_gains")
#: the Newton solves maglev_trim_checked calls: the constant-speed and the accelerating trim
TRIM_SOLVES = ("maglev_trim", "maglev_trim_accelerating")
TICK_KIND = ("maglev_lqr_control", "maglev_damping_control", "maglev_coupled_control",
             "maglev_allocate", "maglev_axis_gains")

#: inputs not checked for finiteness at entry (their outputs are): the prepared constants c
#: and d, which maglev_closed_loop_prepare and maglev_dynamics_prepare checked when they made
#: them, enter every RK4 stage of a run (four calls a step), where checking their 300-400
#: values again cost 10 to 20 % of the run
UNCHECKED_INPUTS = {("maglev_closed_loop_prepared", "c"), ("maglev_dynamics_prepared", "d")}

#: largest |acceleration| [m/s^2, rad/s^2] at an accepted trim, per precision: double as
#: checked_trim; single a hundred times the Newton tolerance (float32 rounding of the
#: accelerations at trim is 2e-6 to 1e-5, codegen.functions.NEWTON_TOLERANCES)
TRIM_TOLERANCES = {"double": "1e-8", "single": "1e-3f"}


def error_name(code: int) -> str:
    """The MAGLEV_ERR_* name of a return code (``MAGLEV_ERR_<code>`` for an unknown one)."""
    return ERROR_NAMES.get(code, f"MAGLEV_ERR_{code}")


def error_defines(names: Sequence[str] | None = None, docs: bool = True) -> str:
    """The ``#define MAGLEV_*`` lines of ERROR_CODES (``names``: only those, in ERROR_CODES'
    order), each with its meaning as a comment when ``docs`` (identical text in maglev.h and
    the C: a benign redefinition in C). Rendered by templates/maglev_errors.h.j2."""
    from maglevgen.codegen.emit import (
        template_env,  # local: the ctypes runtime imports this module light
    )

    codes = [(k, v, doc if docs else "") for k, (v, doc) in ERROR_CODES.items()
             if names is None or k in names]
    return template_env().get_template("maglev_errors.h.j2").render(codes=codes)


def work_sizes(source: str) -> dict[str, tuple[int, int, int, int]]:
    """(sz_arg, sz_res, sz_iw, sz_w) of every function as its generated ``NAME_work`` reports
    them (CasADi's codegen counts differently from ``Function.sz_w()``)."""
    pat = re.compile(r"int (\w+)_work\(casadi_int \*sz_arg[^{]*\{\s*"
                     r"if \(sz_arg!=0\) \*sz_arg = (\d+);\s*if \(sz_res!=0\) \*sz_res = (\d+);"
                     r"\s*if \(sz_iw!=0\) \*sz_iw = (\d+);\s*if \(sz_w!=0\) \*sz_w = (\d+);")
    return {m.group(1): (int(m.group(2)), int(m.group(3)), int(m.group(4)), int(m.group(5)))
            for m in pat.finditer(source)}


def _sizes(io: Sequence[Mapping]) -> list[int]:
    return [int(d["rows"]) * int(d["cols"]) for d in io]


def _p_index(fn: Mapping, runtime: bool) -> int | None:
    """The position of the parameter vector p among ``fn``'s inputs (None: none, or baked)."""
    names = [io["name"] for io in fn["inputs"]]
    return names.index("p") if runtime and "p" in names else None


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


def _entry(fn: Mapping, runtime: bool, work: Mapping[str, tuple[int, ...]], nx: int) -> dict:
    """What templates/maglev_checks.c.j2 needs of the checked entry point of ``fn``: its
    kind ("checked", or of TRIM_KIND "trim_solve" / "trim_kind"), the sizes of its inputs and
    outputs, which work arrays it needs, where its p (and the accelerating trim's a) are."""
    name, outs = fn["name"], _sizes(fn["outputs"])
    sz = work.get(name, (0, 0, 0, 0))
    entry = {"name": name, "out_sizes": outs, "outputs": list(enumerate(outs)),
             "need_iw": int(sz[2] > 0), "need_w": int(sz[3] > 0)}
    if name not in TRIM_KIND:
        entry["kind"] = "checked"
        entry["inputs"] = [(i, n) for i, (n, io) in enumerate(zip(_sizes(fn["inputs"]),
                                                               fn["inputs"], strict=True))
                           if (name, io["name"]) not in UNCHECKED_INPUTS]
        entry["p_index"] = _p_index(fn, runtime)
        return entry
    # the trims and the schedule functions: (v, [accel,] p) with p only at run time
    accelerating = name in TRIM_SOLVES and name != "maglev_trim"
    entry["kind"] = "trim_solve" if name in TRIM_SOLVES else "trim_kind"
    entry["accel_index"] = 1 if accelerating else None
    entry["p_index"] = (2 if accelerating else 1) if runtime else None
    entry["nx"] = nx
    entry["own_work"] = _own_work(name, work)
    return entry


def _trim_needs(work: Mapping[str, tuple[int, ...]]) -> list[tuple[int, ...]]:
    """The work sizes of what maglev_trim_checked calls: the Newton solves, the dynamics, the
    gaps."""
    return [work[f] for f in (*TRIM_SOLVES, "maglev_dynamics", "maglev_gaps")]


def _own_work(name: str, work: Mapping[str, tuple[int, ...]]) -> tuple[int, int] | None:
    """None when ``name``'s own work sizes (the caller's iw and w) cover maglev_trim_checked
    (they do: the Newton solve evaluates the dynamics), else the sizes of iw and w arrays of
    its own on the stack."""
    need = [max(sz[k] for sz in _trim_needs(work)) for k in (2, 3)]
    if work[name][2] >= need[0] and work[name][3] >= need[1]:
        return None
    return need[0] + 1, need[1] + 1


def _trim_helper(table: Mapping[str, Mapping], work: Mapping[str, tuple[int, ...]],
                 precision: str, runtime: bool, min_gap: str,
                 speed_range: tuple[str, str] | None) -> dict:
    """What templates/maglev_checks.c.j2 needs of ``maglev_trim_checked``: the trim at v
    (accelerating at *a when a is not NULL) into x and F_prop, with its checks."""
    dyn = table["maglev_dynamics"]
    return {"sz_arg": max(sz[0] for sz in _trim_needs(work)) + 1,
            "sz_res": max(sz[1] for sz in _trim_needs(work)) + 1,
            "nx": dyn["inputs"][0]["rows"], "nu": dyn["inputs"][1]["rows"],
            "ng": table["maglev_gaps"]["outputs"][0]["rows"],
            "n_p": table["maglev_trim"]["inputs"][1]["rows"] if runtime else 0,
            "runtime": runtime, "tol": TRIM_TOLERANCES[precision], "min_gap": min_gap,
            "speed_range": speed_range}


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
    # CasADi's own C rewritten (the entry points made static, its version function NULL-safe):
    # maglevgen.codegen.cpass, the one pass that edits CasADi's text
    from maglevgen.codegen.cpass import (  # local: CasADi, at generation
        null_safe_version,
        unchecked_entry_points,
    )
    from maglevgen.codegen.emit import (
        template_env,  # local: the ctypes runtime imports this module light
    )

    source = null_safe_version(unchecked_entry_points(source, wanted))
    work = work_sizes(source)

    nx = by_name["maglev_dynamics"]["inputs"][0]["rows"] if "maglev_dynamics" in by_name else 0
    block = template_env().get_template("maglev_checks.c.j2").render(
        error_defines=error_defines(),
        params={"lo": [lo for lo, _ in p_limits or ()], "hi": [hi for _, hi in p_limits or ()]}
        if runtime and any(_p_index(f, runtime) is not None for f in table) else None,
        trim=_trim_helper(by_name, work, precision, runtime, min_gap, speed_range)
        if any(n in TRIM_KIND for n in wanted) else None,
        entries=[_entry(by_name[n], runtime, work, nx) for n in wanted])
    tail = "\n#ifdef __cplusplus\n} /* extern \"C\" */\n#endif\n"
    if not source.endswith(tail):
        raise ValueError("generated C does not end with its extern \"C\" block")
    return source[: -len(tail)] + "\n" + block + tail
