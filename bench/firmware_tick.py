"""The embedded controller's tick on the Cortex-M4F: instructions, a cycle estimate, stack.

    python bench/firmware_tick.py

Builds `maglevgen firmware`'s folder of the default carriage with the README's flags and a
driver (bench/c/bench_tick.c) that calls ``maglev_tick`` N times on a state 1 mm / 1 mrad off
the table's trim at the middle speed (and bench/c/bench_sense_tick.c: ``maglev_sense_tick`` on
the trim's readings with each gap 0.1 mm off), and runs it under QEMU (mps2-an386) with one
instruction per translation block and the execution log (``-singlestep -d exec,nochain``):
every executed instruction is one log line with its address. The tick's instructions are the
lines of the run with N = 11 minus those with N = 1, over 10, outside ``main`` (the driver's
loop): the whole call path, newlib's sinf/cosf included.

Cycle estimate: each executed instruction weighted by the Cortex-M4 timings (ARM DDI 0439,
"Processor instruction timings", and the FPv4-SP's): 1 cycle, loads and stores 2, LDM/STM/PUSH
/POP and VLDM/VSTM/VPUSH/VPOP 1 + registers, VDIV/VSQRT 14, VMLA/VMLS/VFMA/VFMS 3, SDIV/UDIV
12 (their worst), and a taken branch (the next address is not the following instruction) 2
more for the pipeline refill; zero-wait-state memory (code in SRAM/TCM, or flash behind an
accelerator that hides its wait states, e.g. STM32F4's ART at 168 MHz). The share is of a
1 kHz tick's period at 168 MHz.

Stack: gcc's -fstack-usage per function and the worst path from maglev_tick through
-fcallgraph-info=su (newlib's functions not compiled with it: 0).

Writes bench/firmware_tick_results.json and its section of BENCHMARKS.md (between markers; the
rest of the file is left as it is).
"""

from __future__ import annotations

import json
import re
import sys
import tempfile
from collections import Counter
from itertools import pairwise
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import BENCH, ROOT, log, replace_section, run, worst_stack

from maglevgen.carriage import DerivedCarriage
from maglevgen.control.carriage_plant import Plant
from maglevgen.exports.firmware import FIRMWARE_FLAGS, firmware_files
from maglevgen.infrastructure.output import write_output
from maglevgen.params import load_params

RESULTS = BENCH / "firmware_tick_results.json"
BEGIN = "<!-- firmware tick benchmark: bench/firmware_tick.py -->"
END = "<!-- end of firmware tick benchmark -->"
CPU = list(FIRMWARE_FLAGS[:4])
CLOCK_MHZ = 168
TICK_HZ = 1000
SOURCES = ("maglev_tick", "maglev_gain_table", "maglev_sense_table", "maglev_functions")
#: the calls measured: entry point -> its driver in bench/c and the driver's defines
DRIVERS = {"maglev_tick": ("bench_tick.c", ()),
           "maglev_sense_tick": ("bench_sense_tick.c", ()),
           "maglev_sense_init": ("bench_sense_tick.c", ("-DBENCH_INIT",))}


def _cycles(mnemonic: str, operands: str) -> int:
    """The M4 cycles of one instruction, without a taken branch's refill (module docstring)."""
    base = mnemonic.split(".")[0]
    if base in ("vdiv", "vsqrt"):
        return 14
    if base in ("vmla", "vmls", "vfma", "vfms", "vnmla", "vnmls"):
        return 3
    if base in ("sdiv", "udiv"):
        return 12
    if base in ("push", "pop", "vpush", "vpop") or base.startswith(("ldm", "stm", "vldm",
                                                                     "vstm")):
        regs = re.search(r"\{([^}]*)\}", operands)
        n = 1
        if regs:
            n = 0
            for part in regs.group(1).split(","):
                a, _, b = part.strip().partition("-")
                n += (int(re.sub(r"\D", "", b)) - int(re.sub(r"\D", "", a)) + 1) if b else 1
        return 1 + n
    if base.startswith(("ldr", "str", "vldr", "vstr")):
        return 2
    return 1


def _disassembly(elf: Path) -> dict[int, tuple[str, str, int, str]]:
    """address -> (mnemonic, operands, size in bytes, function)."""
    text = run(["arm-none-eabi-objdump", "-d", "--no-show-raw-insn", elf])
    raw = run(["arm-none-eabi-objdump", "-d", elf])
    sizes = {}
    for ln in raw.splitlines():
        m = re.match(r"\s*([0-9a-f]+):\t([0-9a-f ]+?)\s*\t", ln)
        if m:
            sizes[int(m.group(1), 16)] = sum(len(w) // 2 for w in m.group(2).split())
    out, function = {}, "?"
    for ln in text.splitlines():
        f = re.match(r"[0-9a-f]+ <([^>]+)>:", ln)
        if f:
            function = f.group(1)
            continue
        m = re.match(r"\s*([0-9a-f]+):\t(\S+)\s*(.*)", ln)
        if m:
            addr = int(m.group(1), 16)
            out[addr] = (m.group(2), m.group(3), sizes.get(addr, 2), function)
    return out


def _trace(folder: Path, elf: str) -> list[int]:
    """The address of every instruction the run executes, in order."""
    log_file = folder / f"{elf}.log"
    run(["qemu-system-arm", "-M", "mps2-an386", "-nographic", "-semihosting", "-singlestep",
         "-d", "exec,nochain", "-D", log_file, "-kernel", elf], cwd=folder)
    return [int(m.group(1), 16) for m in re.finditer(r"^Trace \d+: \S+ \[[0-9a-f]+/([0-9a-f]+)/",
                                                      log_file.read_text(), re.M)]


def _profile(pcs: list[int], dis: dict) -> tuple[Counter, Counter]:
    """(executions per address, taken branches per address)."""
    count, taken = Counter(pcs), Counter()
    for a, b in pairwise(pcs):
        if a in dis and b != a + dis[a][2]:
            taken[a] += 1
    return count, taken


def measure() -> dict:
    """`maglev_tick`'s cost (the top-level keys), `maglev_sense_tick`'s ("sense_tick") and
    `maglev_sense_init`'s ("sense_init": the start, and what a tick that starts again adds)."""
    carriage = DerivedCarriage(load_params())
    with tempfile.TemporaryDirectory(prefix="bench_tick_") as tmp:
        folder = Path(tmp) / "fw"
        write_output(firmware_files(Plant(carriage)), folder)
        # the start-up and linker script the firmware folder's run_qemu.sh uses
        templates = ROOT / "templates"
        objs = []
        for name in SOURCES:
            run(["arm-none-eabi-gcc", *FIRMWARE_FLAGS, "-ffunction-sections", "-fdata-sections",
                 "-fstack-usage", "-fcallgraph-info=su", "-c", f"{name}.c", "-o", f"{name}.o"],
                cwd=folder)
            objs.append(f"{name}.o")
        run(["arm-none-eabi-gcc", *CPU, "-Os", "-c", templates / "firmware_qemu_startup.c",
             "-o", "startup.o"], cwd=folder)
        out = _measure_tick(folder, objs, "maglev_tick")
        out["sense_tick"] = _measure_tick(folder, objs, "maglev_sense_tick")
        out["sense_init"] = _measure_tick(folder, objs, "maglev_sense_init")
    return out


def _measure_tick(folder: Path, objs: list[str], entry: str) -> dict:
    """The cost of one call of ``entry`` (its driver in DRIVERS; module docstring)."""
    templates = ROOT / "templates"
    profiles = {}
    for n in (1, 11):
        driver, defines = DRIVERS[entry]
        run(["arm-none-eabi-gcc", *FIRMWARE_FLAGS, f"-DN_TICKS={n}", *defines, "-I.", "-c",
             BENCH / "c" / driver, "-o", "bench_tick.o"], cwd=folder)
        run(["arm-none-eabi-gcc", *CPU, "-nostartfiles", "-T",
             templates / "firmware_qemu_link.ld", "-Wl,--gc-sections", "startup.o",
             "bench_tick.o", *objs, "-lm", "-lc", "-o", f"tick{n}.elf"], cwd=folder)
        dis = _disassembly(folder / f"tick{n}.elf")
        pcs = _trace(folder, f"tick{n}.elf")
        profiles[n] = (dis, *_profile(pcs, dis))
    dis1, c1, t1 = profiles[1]
    dis, c11, t11 = profiles[11]
    # the same code in both images except main's loop count: compare by function + offset
    starts = {}
    for addr, (_, _, _, fn) in sorted(dis.items()):
        starts.setdefault(fn, addr)
    starts1 = {}
    for addr, (_, _, _, fn) in sorted(dis1.items()):
        starts1.setdefault(fn, addr)

    def keyed(d: dict, count: Counter, first: dict) -> Counter:
        out = Counter()
        for a, c in count.items():
            if a in d and d[a][3] != "main":
                out[(d[a][3], a - first[d[a][3]])] += c
        return out

    per = keyed(dis, c11, starts) - keyed(dis1, c1, starts1)
    per_taken = keyed(dis, t11, starts) - keyed(dis1, t1, starts1)
    by_key = {(fn, a - starts[fn]): (mn, ops) for a, (mn, ops, _, fn) in dis.items()}
    instructions = sum(per.values()) / 10
    cycles = (sum(c * _cycles(*by_key[k]) for k, c in per.items())
              + 2 * sum(per_taken.values())) / 10
    by_function = Counter()
    for (fn, _), c in per.items():
        by_function[fn] += c / 10
    fp_div = sum(c for k, c in per.items() if by_key[k][0].startswith(("vdiv", "vsqrt")))
    ci = "".join((folder / f"{n}.ci").read_text() for n in SOURCES)
    su = {}
    for n in SOURCES:
        for ln in (folder / f"{n}.su").read_text().splitlines():
            where, size, kind = ln.split("\t")
            su[where.rsplit(":", 1)[-1]] = (int(size), kind)
    stack = worst_stack(ci, entry)
    share = cycles / (CLOCK_MHZ * 1e6 / TICK_HZ) * 100
    return {"instructions": round(instructions), "cycles": round(cycles),
            "share_percent": share, "clock_mhz": CLOCK_MHZ, "tick_hz": TICK_HZ,
            "fp_divides_and_roots": fp_div // 10,
            "by_function": {k: round(v) for k, v in by_function.most_common()},
            "stack_bytes": stack,
            # the functions on the tick's path (the CasADi query functions are not)
            "stack_usage": {k: v[0] for k, v in sorted(su.items()) if k in by_function},
            "stack_kind": {k: v[1] for k, v in sorted(su.items()) if k in by_function}}


def section(r: dict) -> list[str]:
    s, i = r.get("sense_tick"), r.get("sense_init")
    sched = r["by_function"].get("maglev_schedule", 0)
    law = sum(r["by_function"].get(k, 0) for k in ("maglev_coupled_control", "maglev_allocate"))
    stack = ", ".join(f"`{k}` {v}" for k, v in r["stack_usage"].items())
    funcs = ", ".join(f"`{k}` {v}" for k, v in r["by_function"].items())
    return [BEGIN, "## 9. The embedded controller's tick on the Cortex-M4F "
            "(`maglevgen firmware`; bench/firmware_tick.py)", "",
            "`maglev_tick` of the default carriage (the `spec` controller designed at the "
            "tick: table schedule, coupled control, the delay and actuator-lag compensation "
            "with its state, speed loop, allocation, force budget), built with the folder "
            "README's flags and run under QEMU mps2-an386 with one instruction per "
            "translation block and the execution log: every executed instruction counted "
            "(the run with 11 ticks minus the run with 1, over 10; newlib's sinf/cosf "
            "included). Cycles: each instruction weighted by the Cortex-M4/FPv4-SP timings "
            "(loads/stores 2, LDM/STM/PUSH/POP 1 + registers, VDIV/VSQRT 14, VMLA/VFMA 3, a "
            "taken branch +2), zero wait states assumed (SRAM/TCM, or flash behind an "
            "accelerator such as STM32F4's ART).", "",
            "| tick | instructions per tick | estimated cycles | share of a 1 kHz period at "
            f"{r['clock_mhz']} MHz | worst stack (the tick and callees) |",
            "| --- | --- | --- | --- | --- |",
            f"| `maglev_tick` (ideal sensing) | {r['instructions']} | {r['cycles']} | "
            f"{r['share_percent']:.2f} % | {r['stack_bytes']} bytes |",
            *([f"| `maglev_sense_tick` (the readings: the Kalman filter and the same law) | "
               f"{s['instructions']} | {s['cycles']} | {s['share_percent']:.2f} % | "
               f"{s['stack_bytes']} bytes |"] if s else []),
            *([f"| `maglev_sense_init` (the start from the first readings; a sense tick whose "
               f"state is corrupted adds it: at most {s['share_percent'] + i['share_percent']:.0f} "
               f"% of the period) | {i['instructions']} | {i['cycles']} | "
               f"{i['share_percent']:.2f} % | {i['stack_bytes']} bytes |"] if s and i else []),
            "",
            f"Instructions by function: {funcs}. VDIV/VSQRT executed per tick: "
            f"{r['fp_divides_and_roots']}.", "",
            f"Stack per function on the path (-fstack-usage, bytes; newlib's not compiled "
            f"with it): {stack}.", "",
            f"`maglev_schedule` ({sched} instructions, {100 * sched / r['instructions']:.0f} % "
            "of the tick) is the Chebyshev table: each stored value's Clenshaw over its own "
            "terms written out with its coefficients as literals (the loop's operations in its "
            "order, so its values bit for bit; no loop, no table read). As a loop over the "
            "tables (`first[]`, `stored[]`, `coeffs[]`) it cost 2,928 instructions of a "
            "5,538-instruction, ~9,158-cycle tick, in 1.6 KB of flash (code and tables) where "
            "the written-out form takes 3.8 KB; the fit drops a value's terms within a tenth of "
            "the table's bound (with every value's 8 terms and the loop the tick was 7,455 "
            "instructions, ~12,154 cycles). The generated coupled control and allocation: "
            f"{law} instructions.", "",
            *([("`maglev_sense_tick` by function: " + ", ".join(
                f"`{k}` {v}" for k, v in list(s["by_function"].items())[:8])
                + ". The estimator's products run over its table's nonzero values only (a "
                "sparsity fixed at generation, straight-line code), the values constant over "
                "speed as literals; its varying values (`maglev_sense_schedule_varying`) are "
                "cached in the state and refreshed a slice a tick (4 ticks a refresh, "
                "written-out Clenshaw, inlined into `maglev_sense_tick`): issue 49's 10 % met. "
                "Evaluating the whole table every tick cost 52,696 instructions, ~85,932 "
                "cycles (51 %)."), ""]
              if s else []),
            END]


def main() -> int:
    r = measure()
    RESULTS.write_text(json.dumps(r, indent=1) + "\n")
    log(f"tick: {r['instructions']} instructions, ~{r['cycles']} cycles, "
        f"{r['share_percent']:.2f} % of 1 kHz at {CLOCK_MHZ} MHz, stack {r['stack_bytes']} B")
    replace_section(section(r), BEGIN, END)
    print(json.dumps({k: r[k] for k in ("instructions", "cycles", "share_percent",
                                         "stack_bytes")}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
