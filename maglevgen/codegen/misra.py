"""MISRA C:2012 deviations of the generated C (cppcheck's misra addon), as Embedded Coder lists
them: per place (file, function, rule), what occurs there and why the generated code departs
from the rule.

`render_tick_sources` gives the per-tick functions alone (lqr_control, damping_control,
coupled_control, allocate, with their checked entry points) as one small file, maglev_tick.c,
whose text is maglev_functions.c's for those functions; tests/test_firmware.py checks it and
the table schedule (maglev_gain_table.c/.h) with ``cppcheck --addon=misra`` (seconds, where the
whole maglev_functions.c takes minutes: bench/firmware.py counts it by rule for BENCHMARKS.md).
The same test file checks every .c of `maglevgen firmware`'s folder (maglev_tick.c, main.c,
the table and the controller's functions, with maglev.h and the other headers) in every
preprocessor configuration (``--force``). Every finding there must lie in a place of
``DEVIATIONS`` (its rule, its file, its enclosing
function matching one of the place's patterns, found by `enclosing_functions`), and every
pattern of every place must be met by a finding; ``deviation_list`` is written beside the
generated code as MISRA_DEVIATIONS.md.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from fnmatch import fnmatchcase

__all__ = ["DEVIATIONS", "FILE_SCOPE", "deviation_list", "enclosing_functions"]

#: the "function" of a finding outside every function body (declarations, macros)
FILE_SCOPE = "(file scope)"
#: CasADi's per-function query API, generated beside each entry point NAME
_QUERIES = tuple(f"maglev_*_{q}" for q in (
    "checkout", "release", "incref", "decref", "n_in", "n_out", "default_in", "name_in",
    "name_out", "sparsity_in", "sparsity_out", "work", "work_bytes"))
_TICKS = ("maglev_lqr_control", "maglev_damping_control", "maglev_coupled_control",
          "maglev_allocate")


@dataclass(frozen=True)
class Deviation:
    """One place where the generated C departs from a rule, and why."""

    rule: str
    file: str
    functions: tuple[str, ...]  # fnmatch patterns of the enclosing function, or FILE_SCOPE
    what: str
    reason: str

    def covers(self, file: str, function: str, rule: str) -> str | None:
        """The pattern of this place that a finding (file, enclosing function, rule) lies in."""
        if rule != self.rule or file != self.file:
            return None
        return next((p for p in self.functions if fnmatchcase(function, p)), None)


_C = "maglev_functions.c"
_KEPT = ("CasADi's generated-code template, kept verbatim so that the C stays the output of a "
         "released CasADi (its users' calling convention)")
DEVIATIONS: tuple[Deviation, ...] = (
    Deviation("2.2", _C, ("maglev_*_work_bytes",),
              "`*sz_w = 0*sizeof(...)` of a function with no work of that kind",
              "the zero products are CasADi's uniform work-size template: " + _KEPT),
    Deviation("2.5", _C, (FILE_SCOPE,),
              "the MAGLEV_ERR_* return codes defined beside the checked entry points",
              "the same definitions as maglev.h's (documented interface); a function that "
              "returns none of them is not wrong"),
    Deviation("21.6", "main.c", (FILE_SCOPE,),
              "<stdio.h> included for printf",
              "only in the host example build (MAGLEV_HOST_EXAMPLE, defined by CMake for a "
              "host): it says what it runs; the board's build includes no stdio"),
    Deviation("2.5", "maglev_gain_table.h", (FILE_SCOPE,),
              "MAGLEV_SCHEDULE_* range and output offsets, MAGLEV_* return codes",
              "the documented interface of maglev_schedule for the caller; the .c needs "
              "only some of them"),
    Deviation("2.5", "maglev.h", (FILE_SCOPE,),
              "the state, input, axis and parameter index macros, dimensions, work sizes and "
              "return codes (`maglevgen firmware`'s folder)",
              "the documented interface for the caller; the firmware's .c files use some"),
    Deviation("2.5", "maglev_functions.h", (FILE_SCOPE,),
              "CasADi's NAME_SZ_ARG/RES/IW/W work-size macros", _KEPT),
    Deviation("2.5", "maglev_tick.h", (FILE_SCOPE,),
              "MAGLEV_TICK_RATE and MAGLEV_TICK_DELAY: the loop maglev_tick is to run in; "
              "the sense tick's MAGLEV_SENSE_Y_* reading indices and MAGLEV_SENSE_ALL_VALID",
              "the caller's settings (its timer and command pipeline) and the order in which "
              "it fills the readings; the ticks themselves compute one command"),
    Deviation("2.5", "maglev_sense_table.h", (FILE_SCOPE,),
              "MAGLEV_SENSE_SCHEDULE_* range and output offsets, MAGLEV_* return codes",
              "the documented interface of maglev_sense_schedule (the same template as "
              "maglev_gain_table.h); the .c needs only some of them"),
    Deviation("8.4", _C, (*_QUERIES, "maglev_*_casadi_*"),
              "CasADi's query functions of each entry point (work sizes, names, sparsity)",
              "declared in maglev_functions.h, which the .c does not include (CasADi's "
              "layout); both come from the same generator run. `--single-file` includes it"),
    Deviation("8.4", _C, _TICKS,
              "the checked entry points of the tick functions",
              "declared in maglev.h / maglev_functions.h, generated in the same run as the .c"),
    Deviation("8.9", _C, (FILE_SCOPE,),
              "CasADi's static const sparsity patterns (casadi_s0...)",
              "shared by an entry point and its sparsity query functions: " + _KEPT),
    Deviation("10.4", _C, ("maglev_*_work_bytes",),
              "`*sz_arg = 3*sizeof(...)`: int times size_t",
              "a constant expression whose value fits both types: " + _KEPT),
    Deviation("11.9", _C, ("casadi_f*",),
              "`if (res[0]!=0)` and `arg[1] ? ... : 0` in CasADi's function bodies",
              "CasADi's calling convention uses 0 for an output not requested (identical in "
              "meaning to NULL, which needs <stddef.h>): " + _KEPT),
    Deviation("11.9", _C, ("maglev_*_work",),
              "`if (sz_arg!=0)` tests of the optional size outputs", _KEPT),
    Deviation("11.9", _C, ("maglev_all_finite", "maglev_zero", "maglev_zero_res",
                           "maglev_pointers_ok", "maglev_*_casadi_version"),
              "`if (a == 0)`: an output not requested or a NULL pointer refused, in the "
              "checks' helpers and CasADi's version query",
              "the same 0 as CasADi's convention above, so that one file uses one form"),
    Deviation("11.9", "maglev_gain_table.c", ("maglev_schedule", "maglev_schedule_f_prop"),
              "`if (out == 0)`: a NULL output refused (MAGLEV_ERR_ARGUMENT)",
              "the same 0 as the generated functions' checks, so that the firmware's C uses "
              "one form (NULL needs <stddef.h>)"),
    Deviation("11.9", "maglev_sense_table.c", ("maglev_sense_schedule",),
              "`if (out == 0)`: a NULL output refused (MAGLEV_ERR_ARGUMENT)",
              "maglev_gain_table.c's template (one source), rendered for the sense tick's "
              "estimator"),
    Deviation("12.3", _C, ("casadi_f*",),
              "`casadi_real a0, a1, ...;` work variables declared in one statement",
              "declarations at the top of a generated function: " + _KEPT),
    Deviation("15.5", _C, tuple(f"maglev_*_{q}" for q in
                                ("default_in", "name_in", "name_out", "sparsity_in",
                                 "sparsity_out")),
              "`switch (i) { case 0: return ...; }` of the query functions", _KEPT),
    Deviation("15.5", _C, (*_TICKS, "maglev_all_finite"),
              "the checked entry points' `return MAGLEV_OK;` on success and the finiteness "
              "test's `return 0;` at the first non-finite value",
              "an early return keeps the checked path short and leaves no output "
              "half-written; the single-exit form would nest every check"),
    Deviation("16.6", _C, ("maglev_*_default_in",),
              "`switch (i) { default: return 0; }`: a query with no case", _KEPT),
    Deviation("20.5", _C, (FILE_SCOPE,),
              "`#undef casadi_real` / `#undef casadi_int` before their definitions",
              "the precision and integer type are fixed at generation time (maglevgen."
              "codegen.cpass); #undef makes a conflicting earlier definition impossible to miss"),
    Deviation("20.10", _C, (FILE_SCOPE,),
              "CasADi's CASADI_PREFIX(ID) namespace macro (`##`)",
              "CasADi's prefixing of internal names, evaluated at compile time: " + _KEPT),
)

_BLANK = re.compile(r"/\*.*?\*/|//[^\n]*|\"(?:\\.|[^\"\\\n])*\"|'(?:\\.|[^'\\\n])*'", re.S)
_SIGNATURE = re.compile(r"(\w+)\s*\([^;{}=]*\)\s*$")


def enclosing_functions(source: str) -> dict[int, str]:
    """Line number (from 1) -> the function whose definition (signature or body) holds it;
    lines at file scope are absent. Comments and strings are blanked first; preprocessor lines
    and CasADi's ``extern "C" {`` ... ``}`` are skipped (cppcheck reads the C, not C++)."""
    text = _BLANK.sub(lambda m: re.sub(r"[^\n]", " ", m.group(0)), source)
    result: dict[int, str] = {}
    depth, name, pending, first = 0, None, "", None
    for no, line in enumerate(text.split("\n"), 1):
        stripped = line.strip()
        if (stripped.startswith("#") or re.fullmatch(r"extern\s+\{", stripped)
                or (depth == 0 and stripped == "}")):
            continue
        here = name if depth > 0 else None
        for ch in line:
            if depth > 0:
                depth += (ch == "{") - (ch == "}")
                if depth == 0:
                    name, pending, first = None, "", None
            elif ch == "{":  # a body (a function's when a signature precedes it) opens
                m = _SIGNATURE.search(pending)
                name = m.group(1) if m else None
                if name is not None:
                    here = name
                    result.update(dict.fromkeys(range(first or no, no), name))
                depth, pending, first = 1, "", None
            elif ch == ";":
                pending, first = "", None
            else:
                if first is None and not ch.isspace():
                    first = no
                pending += ch
        if here is not None:
            result[no] = here
    return result


def deviation_list() -> str:
    """MISRA_DEVIATIONS.md: every place with its rule, what occurs there and why."""
    lines = ["# MISRA C:2012 deviations of the generated C", "",
             "Checked by `cppcheck --addon=misra` on the per-tick functions and the table "
             "schedule, and on every file of `maglevgen firmware`'s folder in every "
             "preprocessor configuration (tests/test_firmware.py): every finding lies in one "
             "of the places below (its file, its rule, its enclosing function matching a "
             "listed pattern) and every listed pattern holds a finding. The whole file's "
             "findings are counted by rule in BENCHMARKS.md (bench/firmware.py).", "",
             "| rule | file | function | what | reason |", "| --- | --- | --- | --- | --- |"]
    order = sorted(DEVIATIONS, key=lambda d: tuple(int(x) for x in d.rule.split(".")))
    lines += [f"| {d.rule} | {d.file} | " + ", ".join(f"`{p}`" if p != FILE_SCOPE else p
                                                       for p in d.functions)
              + f" | {d.what} | {d.reason} |" for d in order]
    return "\n".join(lines) + "\n"
