"""Firmware figures (issue 16): Cortex-M4F footprint, x86 time per call, MISRA counts.

    python bench/firmware.py [--no-misra]

Cortex-M4F (arm-none-eabi-gcc -Os, the README's firmware flags): for each group of entry
points, the bytes of .text and .rodata that the linker keeps (a program that references only
that group, --gc-sections, newlib's libm included) minus those of an empty program, and the
worst stack from -fcallgraph-info=su (the generated code's own frames; libm's not included).
x86-64 (gcc -O2, bench/c/bench_firmware.c): ns per call of the ticks, of the table schedule
maglev_schedule and of the Newton schedule (maglev_trim + maglev_lqr_gains) at the same
speeds, in the same run (median of 5 rounds). MISRA C:2012 (cppcheck --addon=misra, about half
an hour on 2 busy cores): the findings of the whole maglev_functions.c (one preprocessor
configuration, WHOLE_FILE_FLAGS) and of the tick path, by rule, and cppcheck's own findings.
Writes bench/firmware_results.json and the firmware section of BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import BENCH, ROOT, log, paired_ratios, replace_section, run, summary, worst_stack

from maglevgen.analyses.envelope import speed_range
from maglevgen.carriage import DerivedCarriage
from maglevgen.codegen.generate import GenerateOptions, render, render_tick_sources, write_output
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.schedule import GainTable, gain_table_sources
from maglevgen.params import load_params
from maglevgen.runtime.library import simulation_library

RESULTS = BENCH / "firmware_results.json"
BEGIN, END = "<!-- firmware benchmark: bench/firmware.py -->", "<!-- end of firmware benchmark -->"
CPU = ["-mcpu=cortex-m4", "-mthumb", "-mfloat-abi=hard", "-mfpu=fpv4-sp-d16"]
FLAGS = [*CPU, "-Os", "-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Wdouble-promotion",
         "-Wfloat-conversion", "-Werror", "-fno-math-errno", "-ffunction-sections",
         "-fdata-sections"]
GROUPS = {
    "LQR tick (lqr_control + allocate)": ("maglev_lqr_control", "maglev_allocate"),
    "coupled tick (coupled_control + allocate)": ("maglev_coupled_control", "maglev_allocate"),
    "damping tick (damping_control + allocate)": ("maglev_damping_control", "maglev_allocate"),
    "table schedule (maglev_schedule)": ("maglev_schedule",),
    "Newton schedule (trim + lqr_gains)": ("maglev_trim", "maglev_lqr_gains"),
    "dynamics": ("maglev_dynamics",),
}
LINK = """MEMORY { FLASH (rx) : ORIGIN = 0x0, LENGTH = 4M
         RAM (rwx) : ORIGIN = 0x20000000, LENGTH = 4M }
_estack = ORIGIN(RAM) + LENGTH(RAM);
SECTIONS {
  .text : { KEEP(*(.vectors)) *(.text*) } > FLASH
  .rodata : { *(.rodata*) } > FLASH
  .ARM.exidx : { *(.ARM.exidx*) } > FLASH
  _sidata = LOADADDR(.data);
  .data : { _sdata = .; *(.data*) _edata = .; } > RAM AT > FLASH
  .bss : { _sbss = .; *(.bss*) *(COMMON) _ebss = .; } > RAM
}
"""


def _sources(carriage: DerivedCarriage, folder: Path) -> GainTable:
    write_output(render(carriage, GenerateOptions("single", "baked", "int32"),
                        speed_range(carriage)), folder)
    lib = simulation_library(carriage.structure)
    v_min, v_max = Plant(carriage, lib).speed_range
    table = Plant(carriage, lib).gain_table(v_min, v_max)
    for name, text in gain_table_sources(table).items():
        (folder / name).write_text(text)
    return table


def m4_footprint(folder: Path) -> dict:
    """Bytes kept per group on Cortex-M4F and the worst stack."""
    startup = ROOT / "templates" / "firmware_qemu_startup.c"  # the firmware folder's
    (folder / "bench.ld").write_text(LINK)
    objs = []
    for name in ("maglev_functions", "maglev_gain_table"):
        run(["arm-none-eabi-gcc", *FLAGS, "-fcallgraph-info=su", "-c", f"{name}.c", "-o",
             f"{name}.o"], cwd=folder)
        objs.append(f"{name}.o")
    run(["arm-none-eabi-gcc", *CPU, "-Os", "-c", str(startup), "-o", "startup.o"],
        cwd=folder)
    ci = "".join((folder / f"{n}.ci").read_text() for n in ("maglev_functions",
                                                             "maglev_gain_table"))

    def image(names: tuple[str, ...]) -> tuple[int, int]:
        decl = "".join(f"extern int {n}();\n" for n in names)
        keep = ", ".join(f"(void (*)(void)){n}" for n in names) or "0"
        (folder / "keep.c").write_text(
            f"{decl}void (*volatile const keep[])(void) = {{{keep}}};\n"
            "int main(void) { return keep[0] != 0; }\n")
        run(["arm-none-eabi-gcc", *CPU, "-Os", "-std=gnu99", "-c", "keep.c", "-o", "keep.o"],
            cwd=folder)
        run(["arm-none-eabi-gcc", *CPU, "-nostartfiles", "-T", "bench.ld", "-Wl,--gc-sections",
             "startup.o", "keep.o", *objs, "-lm", "-lc", "-o", "keep.elf"], cwd=folder)
        sizes = run(["arm-none-eabi-size", "-A", "keep.elf"], cwd=folder)
        got = {ln.split()[0]: int(ln.split()[1]) for ln in sizes.splitlines()
               if ln.startswith(".")}
        return got.get(".text", 0), got.get(".rodata", 0)

    base = image(())
    out = {}
    for group, names in GROUPS.items():
        text, rodata = image(names)
        out[group] = {"functions": names, "text": text - base[0], "rodata": rodata - base[1],
                      "stack": max(worst_stack(ci, n) for n in names)}
        log(f"M4 {group}: {out[group]}")
    return out


def x86_times(folder: Path) -> dict:
    run(["gcc", "-O2", "-std=c99", f"-I{folder}", f"-I{BENCH / 'c'}",
         str(BENCH / "c" / "bench_firmware.c"), str(folder / "maglev_functions.c"),
         str(folder / "maglev_gain_table.c"), "-lm", "-o", str(folder / "bench_fw")])
    raw = json.loads(run([folder / "bench_fw"]))
    out = {k: summary(v) for k, v in raw.items()}
    out["newton_vs_table"] = paired_ratios(raw["schedule_newton_ns"], raw["schedule_table_ns"])
    return out


# The whole file is checked in one preprocessor configuration, the one a compiler sees (none of
# CasADi's CASADI_* macros defined): cppcheck 2.10's default of up to 12 configurations did not
# finish in 55 minutes on the distributed law's file, whose largest function (the trim's Newton
# Jacobian, 14 000 lines) takes most of the time. The tick path is small: every configuration.
WHOLE_FILE_FLAGS = ("--max-configs=1",)


def misra_counts(folder: Path, carriage: DerivedCarriage) -> dict:
    def count(files: list[str], cwd: Path, *flags: str) -> tuple[dict[str, int], list[str]]:
        """MISRA findings by rule, and cppcheck's own findings (id file:line)."""
        import subprocess

        proc = subprocess.run(["cppcheck", "--addon=misra", "--std=c99", "--quiet", *flags,
                               "--template={id} {file}:{line}", *files], cwd=cwd,
                              capture_output=True, text=True, check=False)
        rules: Counter[str] = Counter()
        other = []
        for ln in proc.stderr.splitlines():
            ident = ln.split(" ", 1)[0]
            if ident.startswith("misra-c2012-"):
                rules[ident.removeprefix("misra-c2012-")] += 1
            elif ident and ident != "toomanyconfigs":
                other.append(ln)
        return dict(sorted(rules.items(), key=lambda kv: -kv[1])), other

    for name, text in render_tick_sources(carriage).items():
        (folder / name).write_text(text)
    t0 = time.perf_counter()
    whole, whole_other = count(["maglev_functions.c"], folder, *WHOLE_FILE_FLAGS)
    seconds = time.perf_counter() - t0
    log(f"MISRA whole file: {sum(whole.values())} findings in {seconds:.0f} s")
    tick, tick_other = count(["maglev_tick.c", "maglev_gain_table.c"], folder)
    return {"whole_file": whole, "tick_path": tick, "whole_file_flags": list(WHOLE_FILE_FLAGS),
            "whole_file_seconds": round(seconds), "cppcheck_findings": {
                "whole_file": whole_other, "tick_path": tick_other}}


def section(r: dict) -> list[str]:
    fp = r["m4"]
    t = r["x86"]
    lines = [BEGIN, "## 8. Firmware (issue 16): Cortex-M4F footprint, schedule table, MISRA", "",
             f"Measured by `python bench/firmware.py` ({r['date_utc']} UTC; raw figures: "
             "bench/firmware_results.json). Single precision, baked parameters, `--int int32`; "
             "arm-none-eabi-gcc -Os with the README's firmware flags (`-fno-math-errno` "
             "included). Bytes that the linker keeps for a program referencing only the "
             "group, newlib's libm (sinf, cosf, expf) included, minus an empty program; worst "
             "stack: the deepest static call path (-fcallgraph-info=su; libm's frames not "
             "included).", "",
             "| group | .text | .rodata | worst stack |", "| --- | --- | --- | --- |"]
    lines += [f"| {g} | {v['text']} | {v['rodata']} | {v['stack']} |" for g, v in fp.items()]
    gt = r["gain_table"]
    lines += ["", f"The table schedule: a Chebyshev series in 1/v of {gt['nodes']} terms for "
              f"{gt['values_stored']} stored values over [{gt['v_min']:.4g}, {gt['v_max']:g}] "
              f"m/s; worst error on a {gt['dense_grid']}-speed grid relative to each field's "
              f"largest magnitude {gt['worst_relative_error']:.2g} (bound {gt['bound']:g}); "
              "tests/test_firmware.py bounds the ticks' and the schedule's stack at 256 B.", "",
              "x86-64 (gcc -O2, median of 5 rounds, same run):", "",
              "| call | time per call |", "| --- | --- |"]
    for key, label in (("lqr_control_ns", "lqr_control tick"),
                       ("coupled_control_ns", "coupled_control tick"),
                       ("allocate_ns", "allocate"),
                       ("schedule_table_ns", "maglev_schedule (table)"),
                       ("schedule_newton_ns", "maglev_trim + maglev_lqr_gains (Newton)")):
        lines.append(f"| {label} | {t[key]['median']:.3g} ns |")
    lines += ["", f"Newton schedule / table schedule: {t['newton_vs_table']['median']:.3g}x.", ""]
    if "misra" in r:
        whole, tick = r["misra"]["whole_file"], r["misra"]["tick_path"]
        when = r.get("misra_date_utc", r["date_utc"])
        kept = (f" Counted on {when} UTC, before the figures above (kept by `--no-misra`): "
                "rerun without it for counts of today's C." if when != r["date_utc"] else "")
        flags = " ".join(r["misra"].get("whole_file_flags", []))
        method = (f" The whole file with `{flags}` (the configuration a compiler sees; "
                  f"{r['misra']['whole_file_seconds'] / 60:.0f} min)." if flags else "")
        found = r["misra"].get("cppcheck_findings", {})
        other = [f"`{f}` ({where})" for where in ("whole_file", "tick_path")
                 for f in found.get(where, [])]
        if other:
            method += " cppcheck's own findings: " + "; ".join(other) + "."
        lines += ["MISRA C:2012 (cppcheck --addon=misra): findings by rule; every finding of "
                  "the tick path lies in a place (rule, file, function) of MISRA_DEVIATIONS.md "
                  "(generated beside the code)." + method + kept,
                  "", "| rule | whole maglev_functions.c | tick path + table schedule |",
                  "| --- | --- | --- |"]
        for rule in sorted(set(whole) | set(tick),
                           key=lambda s: tuple(int(x) for x in s.split(".") if x.isdigit())):
            lines.append(f"| {rule} | {whole.get(rule, 0)} | {tick.get(rule, 0)} |")
        lines.append(f"| total | {sum(whole.values())} | {sum(tick.values())} |")
    return [*lines, END]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-misra", action="store_true",
                    help="skip cppcheck (minutes): keep the last counts")
    args = ap.parse_args(argv)
    carriage = DerivedCarriage(load_params())
    with tempfile.TemporaryDirectory(prefix="bench_fw_") as tmp:
        folder = Path(tmp)
        table = _sources(carriage, folder)
        r = {"date_utc": time.strftime("%Y-%m-%d %H:%M", time.gmtime()),
             "gain_table": table.manifest(), "m4": m4_footprint(folder),
             "x86": x86_times(folder)}
        if not args.no_misra:
            r["misra"] = misra_counts(folder, carriage)
            r["misra_date_utc"] = r["date_utc"]
        elif RESULTS.exists() and "misra" in json.loads(RESULTS.read_text()):
            last = json.loads(RESULTS.read_text())  # the last counted, with its date
            r["misra"] = last["misra"]
            r["misra_date_utc"] = last.get("misra_date_utc", last["date_utc"])
    RESULTS.write_text(json.dumps(r, indent=1) + "\n")
    replace_section(section(r), BEGIN, END)
    log(f"wrote {RESULTS.name} and BENCHMARKS.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())
