"""The C side of the benchmarks: building the drivers, timing from C, callgrind, footprint."""

from __future__ import annotations

import json
import re
import shutil
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from common import DRIVER_DIR, REFERENCE_DIR, log, run

SPEED_FLAGS = ("-std=c99", "-O2")
SIZE_FLAGS = (
    "-std=c99",
    "-Os",
    "-ffunction-sections",
    "-fdata-sections",
    "-fstack-usage",
    "-fcallgraph-info=su",
)
NO_PIE_SUFFIX = "_nopie"
HEAP_SYMBOLS = ("malloc", "calloc", "realloc", "free", "aligned_alloc", "posix_memalign")

# Footprint groups: the entry points a firmware image keeps; the linker keeps what they reach
# (ld -r --gc-sections). role "target": issue 9's controller path (gains + control +
# allocation: what runs on the controller, the gains recomputed from (k, m) when they change);
# "tick": what runs every control period; "schedule": what runs once per speed set-point
# (the trim's Newton solve among it); "other": for scale.
CONTROLLER_PATH = (
    "maglev_axis_gains",
    "maglev_lqr_control",
    "maglev_damping_control",
    "maglev_allocate",
)
SCHEDULE = ("maglev_trim", "maglev_axis_plants", "maglev_lqr_gains")


@dataclass(frozen=True)
class Group:
    key: str
    label: str
    roots: tuple[str, ...]
    role: str


FOOTPRINT_GROUPS: tuple[Group, ...] = (
    Group(
        "controller_path",
        "controller path (axis_gains + lqr_control + damping_control + allocate)",
        CONTROLLER_PATH,
        "target",
    ),
    Group(
        "tick",
        "one LQR tick (lqr_control + allocate)",
        ("maglev_lqr_control", "maglev_allocate"),
        "tick",
    ),
    Group("axis_gains", "axis_gains alone", ("maglev_axis_gains",), "tick"),
    Group("lqr_control", "lqr_control alone", ("maglev_lqr_control",), "tick"),
    Group("damping_control", "damping_control alone", ("maglev_damping_control",), "tick"),
    Group("allocate", "allocate alone", ("maglev_allocate",), "tick"),
    Group("trim", "trim (Newton in C)", ("maglev_trim",), "schedule"),
    Group(
        "axis_plants",
        "axis_plants (trim + stiffness and inertia)",
        ("maglev_axis_plants",),
        "schedule",
    ),
    Group(
        "lqr_gains",
        "lqr_gains (trim + plants + gains in one call)",
        ("maglev_lqr_gains",),
        "schedule",
    ),
    Group("schedule", "the whole schedule (trim + axis_plants + lqr_gains)", SCHEDULE, "schedule"),
    Group(
        "firmware",
        "schedule + controller path (a controller that retunes itself on board)",
        (*SCHEDULE, *CONTROLLER_PATH),
        "schedule",
    ),
    Group("dynamics", "dynamics", ("maglev_dynamics",), "other"),
    Group(
        "simulate",
        "simulate loop (maglev_simulate and the functions it calls)",
        ("maglev_simulate",),
        "other",
    ),
)


def _objects(
    cc: str, sources: Sequence[Path], flags: Sequence[str], out: Path, includes: Sequence[Path]
) -> list[Path]:
    out.mkdir(parents=True, exist_ok=True)
    objs = []
    for src in sources:
        obj = out / (src.stem + ".o")
        run([cc, *flags, *[f"-I{d}" for d in includes], "-c", src, "-o", obj], cwd=out)
        objs.append(obj)
    return objs


def build_runtime_driver(gen: Path, work: Path, cc: str = "gcc") -> Path:
    """bench_runtime: generated runtime-parameter C + hand-written reference + driver, -O2.

    Every file is its own translation unit compiled with the same flags, so neither model
    can be inlined into the timing loop.
    """
    sources = [
        gen / "maglev_functions.c",
        gen / "maglev_simulate.c",
        REFERENCE_DIR / "maglev_model.c",
        DRIVER_DIR / "bench_runtime.c",
    ]
    objs = _objects(cc, sources, SPEED_FLAGS, work, [gen, REFERENCE_DIR, DRIVER_DIR])
    exe = work / "bench_runtime"
    run([cc, *objs, "-o", exe, "-lm"])
    # the same objects linked at fixed addresses, for callgrind's per-instruction counts
    run([cc, *objs, "-no-pie", "-o", work / f"bench_runtime{NO_PIE_SUFFIX}", "-lm"])
    return exe


def build_controller_driver(
    gen: Path, work: Path, cc: str = "gcc", count_newton: bool = False
) -> Path:
    """bench_controller against a baked build (the build's precision), -O2.

    ``count_newton``: against a copy of the generated C whose trim Newton loop counts its
    iterations (`instrument_newton`), for `bench_controller INPUT schedule` only (the counter
    would be timed too).
    """
    work.mkdir(parents=True, exist_ok=True)
    source = gen / "maglev_functions.c"
    flags = SPEED_FLAGS
    if count_newton:
        counted = work / "maglev_functions_counted.c"
        counted.write_text(instrument_newton(source.read_text()))
        source, flags = counted, (*SPEED_FLAGS, "-DBENCH_NEWTON_COUNT")
    objs = _objects(cc, [source, DRIVER_DIR / "bench_controller.c"], flags, work, [gen, DRIVER_DIR])
    exe = work / "bench_controller"
    run([cc, *objs, "-o", exe, "-lm"])
    return exe


NEWTON_LOOP = re.compile(r"(for \(iter=0; iter<\d+; \+\+iter\) \{)")


def instrument_newton(c_source: str) -> str:
    """The generated C with a global counter of Newton iterations (bench_newton_iterations)
    incremented at the top of every iteration of CasADi's fast_newton loop."""
    if len(NEWTON_LOOP.findall(c_source)) != 1:
        raise RuntimeError("bench: expected exactly one Newton loop in the generated C")
    return "long bench_newton_iterations = 0;\n" + NEWTON_LOOP.sub(
        r"\1 ++bench_newton_iterations;", c_source
    )


def _fmt(values: np.ndarray) -> str:
    return " ".join(repr(float(v)) for v in np.ravel(values))


def write_runtime_input(
    path: Path, p: np.ndarray, loop: dict, X: np.ndarray, U: np.ndarray
) -> Path:
    lines = [
        _fmt(p),
        _fmt(loop["x0"]),
        _fmt([loop["F_prop"]]),
        _fmt(loop["k_pos"]),
        _fmt(loop["k_rate"]),
        _fmt(loop["a_ref"]),
        _fmt([loop["dt"], loop["n_steps"], loop["gap_min"]]),
        str(len(X)),
    ]
    lines += [f"{_fmt(x)} {_fmt(u)}" for x, u in zip(X, U, strict=True)]
    path.write_text("\n".join(lines) + "\n")
    return path


def write_controller_input(path: Path, speed: float, X: np.ndarray) -> Path:
    path.write_text("\n".join([repr(float(speed)), str(len(X)), *map(_fmt, X)]) + "\n")
    return path


def time_dynamics(exe: Path, inp: Path, reps: int, calls: int) -> dict:
    return json.loads(run([exe, inp, "dynamics", reps, calls]))


def time_simulate(exe: Path, inp: Path, reps: int) -> dict:
    return json.loads(run([exe, inp, "simulate", reps]))


def time_controller(exe: Path, inp: Path, reps: int, ms: float) -> dict:
    return json.loads(run([exe, inp, "time", reps, ms]))


def controller_schedule(exe: Path, inp: Path, speeds: Sequence[float]) -> dict:
    """Trim, residual, Newton iterations, plants and gains at each speed, from C."""
    return json.loads(run([exe, inp, "schedule", *(repr(float(v)) for v in speeds)]))


def callgrind(exe: Path, inp: Path, which: str, symbol: str, calls: int, work: Path) -> dict | None:
    """Per call of ``symbol`` (with everything it calls), from callgrind (deterministic):
    instructions (libm included), libm calls, and division instructions executed in the
    executable's own code (libm's not included); None without valgrind.

    Runs the position-dependent twin of ``exe`` (`build_runtime_driver` links it), so that
    callgrind's instruction addresses are objdump's.
    """
    if shutil.which("valgrind") is None:
        return None
    twin = exe.with_name(exe.name + NO_PIE_SUFFIX)
    exe = twin if twin.exists() else exe
    out = work / f"callgrind.{which}.out"
    run(
        [
            "valgrind",
            "--tool=callgrind",
            f"--callgrind-out-file={out}",
            "--collect-atstart=no",
            f"--toggle-collect={symbol}",
            "--dump-instr=yes",
            "--compress-pos=no",
            exe,
            inp,
            "count",
            which,
            calls,
        ]
    )
    text = out.read_text()
    m = re.search(r"^(?:summary|totals):\s+(\d+)", text, re.M)
    if m is None:
        return None
    libm = {k: round(v / calls, 2) for k, v in sorted(_libm_calls(text, exe.name).items())}
    result = {"instructions": int(m.group(1)) / calls, "libm_calls": libm}
    if exe is twin:
        executed = _executed_instructions(text, exe.name)
        divs = _division_addresses(exe)
        result["divisions"] = sum(executed.get(a, 0) for a in divs) / calls
    return result


DIVISIONS = ("divsd", "divss", "vdivsd", "vdivss", "divpd", "divps", "vdivpd", "vdivps")


def _division_addresses(exe: Path) -> set[int]:
    """Addresses of the floating-point division instructions in an executable (objdump)."""
    out = set()
    for line in run(["objdump", "-d", "--no-show-raw-insn", exe]).splitlines():
        m = re.match(r"^\s+([0-9a-f]+):\s+(\S+)", line)
        if m and m.group(2) in DIVISIONS:
            out.add(int(m.group(1), 16))
    return out


def _executed_instructions(text: str, exe_name: str) -> dict[int, int]:
    """How often each instruction of the executable ran, from a callgrind file written with
    --dump-instr=yes --compress-pos=no (cost lines: address, line, Ir)."""
    counts: dict[int, int] = {}
    obs: dict[str, str] = {}
    in_exe = skip_next = False
    for line in text.splitlines():
        if line.startswith(("ob=", "cob=")):
            value = line.split("=", 1)[1]
            m = re.match(r"\((\d+)\)(?: (.*))?", value)
            if m:  # compressed: "(id) name" defines the id, "(id)" refers to it
                if m.group(2):
                    obs[m.group(1)] = m.group(2)
                value = obs.get(m.group(1), "")
            if line.startswith("ob="):
                in_exe = Path(value).name == exe_name
        elif line.startswith("calls="):
            skip_next = True  # the next cost line is the call's inclusive cost
        elif line.startswith("0x"):
            if skip_next:
                skip_next = False
                continue
            parts = line.split()
            if in_exe and len(parts) >= 3:
                addr = int(parts[0], 16)
                counts[addr] = counts.get(addr, 0) + int(parts[-1])
    return counts


def _libm_calls(text: str, exe_name: str) -> dict[str, int]:
    """Calls from the executable's own code into libm, by function, from a callgrind file."""
    names: dict[str, dict[str, str]] = {"ob": {}, "fn": {}}
    ob = fn_ob = callee_ob = callee = None
    counts: dict[str, int] = {}

    def name(kind: str, value: str) -> str:
        m = re.match(r"\((\d+)\)(?: (.*))?", value)
        if m is None:
            return value
        if m.group(2):
            names[kind][m.group(1)] = m.group(2)
        return names[kind].get(m.group(1), "")

    for line in text.splitlines():
        key, _, value = line.partition("=")
        if key == "ob":
            ob = name("ob", value)
        elif key == "fn":
            name("fn", value)
            fn_ob = ob
        elif key == "cob":
            callee_ob = name("ob", value)
        elif key == "cfn":
            callee = name("fn", value)
        elif key == "calls":
            target_ob = callee_ob or fn_ob
            if (
                callee
                and target_ob
                and "libm" in target_ob
                and fn_ob
                and Path(fn_ob).name == exe_name
            ):
                base = re.sub(r"^_+|_fma$|@.*$", "", callee)
                counts[base] = counts.get(base, 0) + int(value.split()[0])
            callee_ob = callee = None
    return counts


def count_math_calls(c_source: str, function_comment: str) -> dict[str, int]:
    """libm calls and divisions written in the body of the generated function after a comment
    (CasADi's straight-line code: each is executed once per call)."""
    start = c_source.index(function_comment)
    body = c_source[start : c_source.index("\n}\n", start)]
    names = ("sin", "cos", "tan", "exp", "sqrt", "pow", "atan2", "log")
    counts = {n: len(re.findall(rf"\b{n}f?\(", body)) for n in names}
    counts["divisions"] = len(re.findall(r"\)/\(|[\w)]/[\w(]", body))
    return {k: v for k, v in counts.items() if v}


def disassembly_stats(obj: Path, symbol: str) -> dict[str, int]:
    """Instruction mix of one compiled function (objdump): all, stack loads/stores, divisions,
    calls. For CasADi's straight-line code these static counts are also the per-call ones.
    A wrapper that only jumps to a local function is followed to that function."""
    for _ in range(3):
        asm = run(["objdump", "-d", "--no-show-raw-insn", f"--disassemble={symbol}", obj])
        insns = [
            line.split(":", 1)[1].strip()
            for line in asm.splitlines()
            if re.match(r"^\s+[0-9a-f]+:\s", line)
        ]
        target = re.match(r"jmp\s+\S+ <([^>+]+)>", insns[-1]) if insns else None
        if len(insns) > 3 or target is None:
            break
        symbol = target.group(1)
    return {
        "function": symbol,
        "instructions": len(insns),
        "stack_memory": sum("(%rsp)" in i or "(%rbp)" in i for i in insns),
        "divisions": sum(i.startswith(("divsd", "divss", "vdivsd", "vdivss")) for i in insns),
        "calls": sum(i.startswith("call") for i in insns),
    }


def newton_settings(c_source: str) -> dict[str, float] | None:
    """Stopping rule of the generated trim Newton (tolerances and iteration limit), if any."""
    tol = re.search(r"m\.abstol = ([0-9.eE+-]+)f?;", c_source)
    step = re.search(r"m\.abstol_step = ([0-9.eE+-]+)f?;", c_source)
    it = re.search(r"for \(iter=0; iter<(\d+); \+\+iter\)", c_source)
    if not (tol and step and it):
        return None
    return {
        "abstol": float(tol.group(1)),
        "abstol_step": float(step.group(1)),
        "max_iter": int(it.group(1)),
    }


# --------------------------------------------------------------------------------- footprint


def _section_sizes(obj: Path) -> dict[str, int]:
    sizes = {}
    for line in run(["size", "-A", obj]).splitlines():
        parts = line.split()
        if len(parts) >= 2 and parts[0].startswith(".") and parts[1].isdigit():
            sizes[parts[0]] = sizes.get(parts[0], 0) + int(parts[1])
    return sizes


def _kinds(sizes: dict[str, int]) -> dict[str, int]:
    text = sum(v for k, v in sizes.items() if k.startswith(".text"))
    rodata = sum(v for k, v in sizes.items() if k.startswith(".rodata"))
    data = sum(v for k, v in sizes.items() if k.startswith((".data", ".bss")))
    return {"text": text, "rodata": rodata, "data_bss": data}


def _kept(objs: Sequence[Path], roots: Sequence[str], out: Path) -> Path:
    """The relocatable object a linker keeps for these entry points (ld -r --gc-sections)."""
    cmd = ["ld", "-r", "--gc-sections", "-e", roots[0]]
    for r in roots[1:]:
        cmd += ["-u", r]
    run([*cmd, *objs, "-o", out])
    return out


def _callgraph(ci_files: Sequence[Path]) -> tuple[dict, dict]:
    """Frame size and kind of each function, and its callees, from -fcallgraph-info=su."""
    frames: dict[str, tuple[int, str]] = {}
    edges: dict[str, set[str]] = {}
    node = re.compile(r'^node: \{ title: "([^"]+)" label: "([^"]*)"')
    edge = re.compile(r'^edge: \{ sourcename: "([^"]+)" targetname: "([^"]+)"')
    for ci in ci_files:
        for line in ci.read_text().splitlines():
            if m := node.match(line):
                name = m.group(1).split(":")[-1]
                if b := re.search(r"(\d+) bytes \(([^)]+)\)", m.group(2)):
                    frames[name] = (int(b.group(1)), b.group(2))
            elif m := edge.match(line):
                edges.setdefault(m.group(1).split(":")[-1], set()).add(m.group(2).split(":")[-1])
    return frames, edges


def _worst_stack(root: str, frames: dict, edges: dict) -> tuple[int, list[str], set[str]]:
    """Deepest static stack from ``root`` (sum of frames on the worst call path), that path,
    and the external functions (libm) reached, whose own stack is not included."""
    memo: dict[str, tuple[int, list[str]]] = {}
    external: set[str] = set()

    def visit(fn: str, seen: frozenset) -> tuple[int, list[str]]:
        if fn in memo:
            return memo[fn]
        if fn not in frames:
            external.add(fn)
            return 0, []
        best = (0, [])
        for callee in sorted(edges.get(fn, ())):
            if callee in seen:
                continue
            depth, path = visit(callee, seen | {callee})
            if depth > best[0]:
                best = (depth, path)
        memo[fn] = (frames[fn][0] + best[0], [fn, *best[1]])
        return memo[fn]

    depth, path = visit(root, frozenset({root}))
    return depth, path, external


def _casadi_names(c_source: str) -> dict[str, str]:
    """CasADi's name of each generated static function (casadi_f4 -> maglev_trim_newton)."""
    pat = r"/\* (\w+):\([^\n]*\*/\s*\nstatic int casadi_(f\d+)\("
    return {f: name for name, f in re.findall(pat, c_source)}


def _casadi_name(symbol: str, names: dict[str, str]) -> str:
    """The CasADi function behind a compiled symbol (maglev_functions_f4.constprop.0 -> ...)."""
    base = symbol.split(".")[0]
    m = re.fullmatch(r"\w+?_(f\d+)", base)
    return names.get(m.group(1), base) if m else base


def footprint(gen_single_baked: Path, work: Path, cc: str = "gcc") -> dict:
    """.text / .rodata per group, worst-case stack and heap use of the single baked build."""
    work.mkdir(parents=True, exist_ok=True)
    sources = [gen_single_baked / "maglev_functions.c", gen_single_baked / "maglev_simulate.c"]
    objs = _objects(cc, sources, SIZE_FLAGS, work, [gen_single_baked])
    frames, edges = _callgraph(sorted(work.glob("*.ci")))
    casadi_names = _casadi_names(sources[0].read_text())
    groups = {}
    for group in FOOTPRINT_GROUPS:
        roots = group.roots
        kept = _kept(objs, roots, work / f"group_{group.key}.o")
        sizes = _section_sizes(kept)
        stacks = {r: _worst_stack(r, frames, edges) for r in roots}
        biggest = sorted(
            ((v, k.removeprefix(".text.")) for k, v in sizes.items() if k.startswith(".text")),
            reverse=True,
        )[:6]
        groups[group.key] = {
            "label": group.label,
            "role": group.role,
            "roots": list(roots),
            **_kinds(sizes),
            "largest_functions": [
                {"name": n, "casadi_name": _casadi_name(n, casadi_names), "bytes": v}
                for v, n in biggest
            ],
            "stack_bytes": max(s[0] for s in stacks.values()),
            "stack_path": max(stacks.values(), key=lambda s: s[0])[1],
            "stack_kinds": sorted({frames[f][1] for s in stacks.values() for f in s[1]}),
            "external_calls": sorted(set().union(*(s[2] for s in stacks.values()))),
        }
    whole = {k: 0 for k in ("text", "rodata", "data_bss")}
    for obj in objs:
        for k, v in _kinds(_section_sizes(obj)).items():
            whole[k] += v
    defined = {
        line.split()[-1]
        for obj in objs
        for line in run(["nm", "--defined-only", obj]).splitlines()
        if line.strip()
    }
    undefined = sorted(
        {s for obj in objs for s in run(["nm", "--undefined-only", obj]).split() if s != "U"}
        - defined
    )
    header = (gen_single_baked / "maglev_functions.h").read_text()
    workspace = {
        m.group(1): int(m.group(2)) for m in re.finditer(r"#define (maglev_\w+)_SZ_W (\d+)", header)
    }
    log(f"footprint: controller path .text {groups['controller_path']['text']} B")
    return {
        "compiler": cc,
        "flags": list(SIZE_FLAGS),
        "groups": groups,
        "whole_file": whole,
        "undefined_symbols": undefined,
        "heap_symbols": [s for s in undefined if s in HEAP_SYMBOLS],
        "workspace_reals": workspace,
    }


def reference_footprint(work: Path, cc: str = "gcc") -> dict:
    """The hand-written reference's dynamics (double, run-time parameters), for comparison."""
    work.mkdir(parents=True, exist_ok=True)
    objs = _objects(cc, [REFERENCE_DIR / "maglev_model.c"], SIZE_FLAGS, work, [REFERENCE_DIR])
    frames, edges = _callgraph(sorted(work.glob("*.ci")))
    out = {}
    for root in ("ref_dynamics", "ref_simulate"):
        sizes = _section_sizes(_kept(objs, [root], work / f"{root}.o"))
        out[root] = {**_kinds(sizes), "stack_bytes": _worst_stack(root, frames, edges)[0]}
    return out


def footprint_runtime_dynamics(gen_double_runtime: Path, work: Path, cc: str = "gcc") -> dict:
    """The generated dynamics in the build the reference is compared with (double, runtime)."""
    work.mkdir(parents=True, exist_ok=True)
    objs = _objects(
        cc, [gen_double_runtime / "maglev_functions.c"], SIZE_FLAGS, work, [gen_double_runtime]
    )
    frames, edges = _callgraph(sorted(work.glob("*.ci")))
    sizes = _section_sizes(_kept(objs, ["maglev_dynamics"], work / "dyn.o"))
    return {**_kinds(sizes), "stack_bytes": _worst_stack("maglev_dynamics", frames, edges)[0]}
