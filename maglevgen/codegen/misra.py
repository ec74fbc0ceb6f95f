"""MISRA C:2012 deviations of the generated C (cppcheck's misra addon), as Embedded Coder lists
them: the rule, where it occurs and why the generated code departs from it.

`render_tick_sources` gives the per-tick functions alone (lqr_control, damping_control,
coupled_control, allocate, with their checked entry points) as one small file, which
tests/test_firmware.py checks with ``cppcheck --addon=misra`` (seconds, where the whole
maglev_functions.c takes minutes: bench/firmware.py counts it by rule for BENCHMARKS.md).
Every finding there must have its rule in ``DEVIATIONS``; ``deviation_list`` is written beside
the generated code as MISRA_DEVIATIONS.md.
"""

from __future__ import annotations

#: rule -> (where in the generated C, why it is accepted)
DEVIATIONS: dict[str, tuple[str, str]] = {
    "2.2": ("the `(void)iw; (void)w; (void)mem;` casts and `*sz_w = 0*sizeof(...)` of CasADi's "
            "work-size functions",
            "the casts mark parameters of the fixed CasADi signature unused (no effect by "
            "design); the zero products are CasADi's uniform work-size template"),
    "2.5": ("macros of the headers (MAGLEV_* indices, offsets and ranges) and CasADi's "
            "casadi_* prefix macros",
            "they are the documented interface for the caller; a translation unit that does "
            "not use them is not wrong"),
    "8.4": ("every exported maglev_* function in the .c",
            "the declarations are in the generated header, which CasADi's .c does not "
            "include; the header and the .c come from the same generator run"),
    "8.9": ("CasADi's static const sparsity patterns (casadi_s0...)",
            "shared by the entry point and its sparsity query functions in CasADi's layout"),
    "10.4": ("`*sz_arg = 3*sizeof(...)` in CasADi's work_bytes functions",
             "int times size_t in a constant expression whose value fits both types"),
    "11.9": ("`if (res[0]!=0)` and `arg[1] ? ... : 0` pointer tests in CasADi's code and the "
             "checked entry points",
             "CasADi's calling convention uses 0 for an output not requested; identical in "
             "meaning to NULL (which needs <stddef.h>)"),
    "12.1": ("arithmetic expressions of CasADi's generated straight-line code",
             "C's precedence rules are unambiguous here and the expressions are generated, not "
             "edited; adding parentheses changes nothing the compiler sees"),
    "12.3": ("CasADi's declarations `casadi_real a0, a1, ...;`",
             "declarations of work variables at the top of a generated function"),
    "15.5": ("CasADi's entry and query functions (`if (...) return 1;` early returns) and the "
             "checked entry points",
             "an early return on a failed check keeps the checked path short and leaves no "
             "output half-written; the single-exit form would nest every check"),
    "15.6": ("one-line loops of CasADi's runtime helpers (casadi_copy, casadi_clear)",
             "CasADi's runtime library text, kept verbatim"),
    "16.6": ("`switch (i) { case 0: ...; default: ...}` of CasADi's name/sparsity queries",
             "a query with one input has one case; the switch is CasADi's uniform template"),
    "17.8": ("CasADi's runtime helpers that advance their pointer parameters (`*y++ = *x++`)",
             "CasADi's runtime library text, kept verbatim"),
    "20.5": ("`#undef casadi_real` / `#undef casadi_int` in maglev_functions.c",
             "the precision and integer type are fixed at generation time (maglevgen.codegen."
             "cpass); #undef makes a conflicting earlier definition impossible to miss"),
    "20.10": ("CasADi's CASADI_PREFIX(ID) namespace macro (`##`)",
              "CasADi's prefixing of internal names, evaluated at compile time"),
}


def deviation_list() -> str:
    """MISRA_DEVIATIONS.md: every deviation with its place and reason."""
    lines = ["# MISRA C:2012 deviations of the generated C", "",
             "Checked by `cppcheck --addon=misra` on the per-tick functions "
             "(tests/test_firmware.py) and counted by rule on the whole file "
             "(bench/firmware.py, BENCHMARKS.md). Every finding of the tick path has its rule "
             "here.", "", "| rule | where | reason |", "| --- | --- | --- |"]
    lines += [f"| {rule} | {where} | {why} |" for rule, (where, why) in
              sorted(DEVIATIONS.items(), key=lambda kv: tuple(int(x) for x in kv[0].split(".")))]
    return "\n".join(lines) + "\n"
