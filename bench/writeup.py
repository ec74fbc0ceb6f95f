"""BENCHMARKS.md from the results of bench/run.py (nothing here measures anything)."""

from __future__ import annotations

CONTROLLER_GROUP = "controller path (lqr_gains + lqr_control + allocate)"
TEXT_LIMIT = 4096
DYNAMICS_LIMIT = 1.15
LOOP_LIMIT = 1.2


def _med(s: dict, fmt: str = "{:.3g}") -> str:
    """median [q1 - q3] of a summary."""
    return f"{fmt.format(s['median'])} [{fmt.format(s['q1'])}-{fmt.format(s['q3'])}]"


def _ratio(s: dict) -> str:
    return f"{s['median']:.3g}x [{s['q1']:.3g}-{s['q3']:.3g}]"


def _ns(s: dict) -> str:
    m = s["median"]
    if m >= 1e6:
        return _med({k: s[k] / 1e6 for k in ("median", "q1", "q3")}, "{:.3g}") + " ms"
    if m >= 1e3:
        return _med({k: s[k] / 1e3 for k in ("median", "q1", "q3")}, "{:.3g}") + " us"
    return _med(s, "{:.0f}") + " ns"


def targets(r: dict) -> list[dict]:
    dyn = r["dynamics"]["c"]["generated_over_reference"]["median"]
    loop = r["closed_loop"]["c"]["generated_over_reference"]["median"]
    ivp = next(v for k, v in r["closed_loop"]["python"].items() if "solve_ivp" in k)
    text = r["footprint"]["groups"][CONTROLLER_GROUP]["text"]
    heap = r["footprint"]["heap_symbols"]
    return [
        {
            "name": f"generated maglev_dynamics within {DYNAMICS_LIMIT}x of the hand-written C "
            "(gcc -O2)",
            "measured": f"{dyn:.3g}x",
            "met": dyn <= DYNAMICS_LIMIT,
        },
        {
            "name": f"closed loop (10 s, 1 kHz RK4) within {LOOP_LIMIT}x of the hand-written "
            "loop (gcc -O2)",
            "measured": f"{loop:.3g}x",
            "met": loop <= LOOP_LIMIT,
        },
        {
            "name": "solve_ivp on the CSE-lambdified model: ratio recorded",
            "measured": f"{ivp['over_generated_c']['median']:.3g}x slower than the generated C",
            "met": True,
        },
        {
            "name": f"controller path under {TEXT_LIMIT // 1024} KiB of .text "
            "(float32, baked, -Os)",
            "measured": f"{text} B",
            "met": text < TEXT_LIMIT,
        },
        {
            "name": "no heap in the generated C",
            "measured": "no allocator symbols" if not heap else ", ".join(heap),
            "met": not heap,
        },
    ]


def _table(head: list[str], rows: list[list[str]]) -> list[str]:
    out = ["| " + " | ".join(head) + " |", "|" + "|".join(" --- " for _ in head) + "|"]
    out += ["| " + " | ".join(row) + " |" for row in rows]
    return [*out, ""]


def _machine(r: dict) -> list[str]:
    m, meta = r["machine"], r["meta"]
    rows = [
        ["CPU", m["cpu"]],
        ["cores", f"{m['logical_cpus']} logical, {m['usable_cpus']} usable by this process"],
        [
            "load average (1, 5, 15 min) at start / end",
            f"{', '.join(f'{x:.2f}' for x in m['loadavg_start'])} / "
            f"{', '.join(f'{x:.2f}' for x in m['loadavg_end'])}",
        ],
        ["OS", m["platform"]],
        ["C library", m["libc"]],
        ["gcc", m["gcc"]],
        ["clang", m["clang"]],
        ["valgrind", m["valgrind"]],
        ["Python", m["python"]],
        [
            "casadi / sympy / numpy / scipy",
            f"{m['casadi']} / {m['sympy']} / {m['numpy']} / {m['scipy']}",
        ],
        [
            "commit",
            f"{meta['git']['commit']}"
            + (" (with uncommitted changes)" if meta["git"]["dirty"] else ""),
        ],
    ]
    return _table(["", ""], rows)


def _derivation(r: dict) -> list[str]:
    d = r["derivation"]
    n = d["summary"]["cold"]["total"]["n"]
    labels = {
        "import": "import maglevgen (sympy, casadi, numpy, scipy)",
        "params": "load and validate the parameter file",
        "derive": "symbolic derivation (SymPy, `build_model`)",
        "lambdify": "numeric layer (`Carriage.functions`: partials + lambdify)",
        "generate": "`render` + write: CasADi functions, C, header, manifest, templates",
        "compile": "compile -O2 (maglev_functions.c + maglev_simulate.c, gcc)",
        "total": "**total, fresh process**",
    }
    rows = [
        [lab, _med(d["summary"]["cold"][k], "{:.2f}"), _med(d["summary"]["cached"][k], "{:.2f}")]
        for k, lab in labels.items()
    ]
    second = d["summary"]["cold"]
    work = ("derive", "lambdify", "generate")
    cold_work = sum(d["summary"]["cold"][k]["median"] for k in work)
    cached_work = sum(d["summary"]["cached"][k]["median"] for k in work)
    if cached_work < 0.5 * cold_work:
        cache_note = (
            f"Derivation, numeric layer and generation take {cached_work:.2f} s cached against "
            f"{cold_work:.2f} s cold: the on-disk cache is in effect."
        )
    else:
        cache_note = (
            f"Derivation, numeric layer and generation take as long cached ({cached_work:.1f} s) "
            f"as cold ({cold_work:.1f} s): no on-disk derivation cache is in effect, and only "
            "the compile, which runtime/compile.py caches by content hash, is faster. When a "
            "derivation cache lands, this column measures it with no change to the suite "
            "(bench/derive_phases.py says where to hook it)."
        )
    out = [
        f"Each run is a fresh Python process ({n} cold/cached pairs, seconds, median "
        "[quartiles]) doing what `maglevgen generate --parameters runtime` and a first compile "
        "do. *Cold*: empty cache folder ($MAGLEVGEN_CACHE). *Cached*: a second fresh process "
        "on the folder the cold run filled. " + cache_note,
        "",
        *_table(["phase", "cold (s)", "cached (s)"], rows),
        f"Cached / cold total, paired: {_ratio(d['cached_over_cold'])}.",
        "",
        "In the same process, a second call (derivation results held in memory, the library "
        "by the compile cache): derivation "
        f"{second['second_derive']['median']:.3g} s, generation "
        f"{second['second_generate']['median']:.2f} s, compile "
        f"{second['second_compile']['median']:.3g} s. Of the generation, building the CasADi "
        f"functions takes {second['casadi_functions']['median']:.2f} s and writing their C "
        f"{second['c_code']['median']:.2f} s.",
        "",
    ]
    return out


def _dynamics(r: dict) -> list[str]:
    d = r["dynamics"]
    c = d["c"]
    calls = c["calls_per_repeat"]
    reps = c["generated_ns"]["n"]
    rows = [
        ["generated C (`maglev_dynamics`, runtime p, gcc -O2)", _ns(c["generated_ns"]), "1"],
        [
            "hand-written C (`ref_dynamics`, runtime p: constants from p at every call)",
            _ns(c["reference_ns"]),
            _ratio(_inv(c["generated_over_reference"])),
        ],
        [
            "hand-written C, constants from p prepared once (`ref_dynamics_c`)",
            _ns(c["reference_prepared_ns"]),
            _ratio(_inv(c["generated_over_reference_prepared"])),
        ],
    ]
    for label, v in d["python"].items():
        build = f" (built in {v['build_s']:.1f} s)" if v["build_s"] else ""
        rows.append([label + build, _ns(v["ns"]), _ratio(v["over_generated_c"])])
    out = [
        "One call of xdot = f(x, u, p) for the default carriage, on 64 states and inputs near "
        "trim taken in turn. C figures are timed from a C loop (bench/c/bench_runtime.c, "
        f"{reps} repeats of {calls} calls, the contenders alternating within each repeat); "
        "each model is its own translation unit, so nothing is inlined into the loop. Python "
        "figures are timed from a Python loop, each repeat followed by a short C timing of the "
        "generated function that its ratio is taken against. Time per call: median "
        "[quartiles]; ratio: time / generated C time in the same repeat.",
        "",
        *_table(["implementation", "time per call", "x generated C"], rows),
        *_compilers(d, "ns"),
    ]
    cg = d["callgrind"]
    if cg.get("gen") and cg.get("ref"):
        g, h = cg["gen"], cg["ref"]
        libm = lambda x: ", ".join(f"{k} {v:g}" for k, v in x["libm_calls"].items())  # noqa: E731
        body = ", ".join(f"{k} {v}" for k, v in d["generated_body"].items())
        asm = d["generated_asm"]
        out += [
            "Where the time goes (callgrind, instructions per call including libm; deterministic):",
            "",
            *_table(
                ["", "instructions / call", "libm calls / call"],
                [
                    ["generated C", f"{g['instructions']:.0f}", libm(g)],
                    ["hand-written C", f"{h['instructions']:.0f}", libm(h)],
                ],
            ),
            f"The generated body as written (before gcc merges sin/cos pairs into sincos): "
            f"{body}. The instruction ratio is {g['instructions'] / h['instructions']:.2f}x, the "
            f"time ratio {c['generated_over_reference']['median']:.2f}x. In the compiled "
            "generated function (straight-line code, so these static counts are also per "
            f"call) {asm['stack_memory']} of its {asm['instructions']} instructions load or "
            f"store a stack slot and {asm['divisions']} are divisions: CasADi's SX code keeps "
            "its scalar temporaries in memory around its libm calls (every floating-point "
            "register is caller-saved on x86-64), and divides where the hand-written model "
            "multiplies by a reciprocal it computed once (13 divisions per call). Stack "
            "traffic and divisions take more time per instruction than the arithmetic, which "
            "most likely explains why the time ratio exceeds the instruction ratio.",
            "",
        ]
    return out


def _compilers(section: dict, unit: str) -> list[str]:
    """The generated / hand-written pair built by the other compilers."""
    other = section.get("other_compilers") or {}
    if not other:
        return []
    show = _ns if unit == "ns" else _med
    rows = [
        [
            cc,
            show(v[f"generated_{unit}"]),
            show(v[f"reference_{unit}"]),
            _ratio(v["generated_over_reference"]),
        ]
        for cc, v in other.items()
    ]
    return [
        "The same pair built by another compiler (both at -O2, the same driver):",
        "",
        *_table(["compiler", "generated C", "hand-written C", "generated / hand-written"], rows),
    ]


def _inv(s: dict) -> dict:
    """A ratio summary turned upside down (the table shows x generated C)."""
    return {"median": 1 / s["median"], "q1": 1 / s["q3"], "q3": 1 / s["q1"]}


def _loop(r: dict) -> list[str]:
    lp = r["closed_loop"]
    c = lp["c"]
    loop = lp["loop"]
    rows = [
        ["generated C (`maglev_simulate`, runtime p, gcc -O2)", _med(c["generated_ms"]), "1", "-"],
        [
            "the same RK4 loop around the hand-written C model (`ref_simulate`)",
            _med(c["reference_ms"]),
            _ratio(_inv(c["generated_over_reference"])),
            f"x {c['agreement']['x']:.1g}, u {c['agreement']['u']:.1g}",
        ],
    ]
    for label, v in lp["python"].items():
        dev = v["max_deviation_from_generated_c"]
        rows.append(
            [
                f"{label} ({v['rhs_evaluations']} model evaluations)",
                _med(v["ms"]),
                _ratio(v["over_generated_c"]),
                "bit-identical"
                if dev["all_states_relative"] == 0
                else f"{dev['position_m'] * 1e6:.2g} um, {dev['attitude_rad'] * 1e6:.2g} urad",
            ]
        )
    steps = loop["n_steps"]
    return [
        f"{steps * loop['dt']:g} s of simulated time at {1 / loop['dt']:g} Hz ({steps} RK4 "
        "steps), closed loop from trim at the default speed plus a disturbance of 1 mm lateral, "
        "1 mm heave and 2 mrad in roll, pitch and yaw, per-axis LQR gains from "
        "`maglev_lqr_gains`, the feedback and the minimum-norm allocation evaluated at every "
        "RK4 stage, constant propulsion, gaps checked at every sample; every contender records "
        "the states (and, in C, inputs and gaps) at every sample. C runs are timed from C "
        f"({c['generated_ms']['n']} alternating repeats); each Python repeat is followed by a "
        "short C run its ratio is taken against. Time per 10 s run: median [quartiles]; "
        "agreement: the C pair's largest difference relative to each state's range, the "
        "Python contenders' largest deviation from the generated C's trajectory in position and "
        "attitude.",
        "",
        *_table(["implementation", "ms per run", "x generated C", "agreement"], rows),
        *_compilers(lp, "ms"),
        *_loop_breakdown(r),
    ]


def _loop_breakdown(r: dict) -> list[str]:
    cg = r["closed_loop"].get("callgrind", {})
    dyn = r["dynamics"]["callgrind"].get("gen")
    need = ("maglev_simulate", "maglev_rk4_step", "maglev_gaps", "ref_simulate")
    if not dyn or not all(k in cg for k in need):
        return []
    per = {k: cg[k]["instructions_per_step"] for k in need}
    libm = lambda k: ", ".join(  # noqa: E731
        f"{n} {v:.3g}" for n, v in cg[k]["libm_calls_per_step"].items() if v >= 0.01
    )
    four = 4 * dyn["instructions"]
    c = r["closed_loop"]["c"]
    asm = r["closed_loop"].get("generated_asm")
    out = [
        "Per RK4 step (callgrind, instructions including libm): the generated loop "
        f"{per['maglev_simulate']:.0f} ({per['maglev_rk4_step']:.0f} in `maglev_rk4_step`, "
        f"{per['maglev_gaps']:.0f} in `maglev_gaps`), the hand-written loop "
        f"{per['ref_simulate']:.0f}: a ratio of "
        f"{per['maglev_simulate'] / per['ref_simulate']:.2f}x in instructions against "
        f"{c['generated_over_reference']['median']:.2f}x in time. `maglev_rk4_step` is one "
        "CasADi expression for the four stages, feedback and allocation included; it executes "
        f"{per['maglev_rk4_step'] - four:+.0f} instructions beside four calls of "
        f"`maglev_dynamics` ({four:.0f}), the parts that depend on p alone being shared "
        "between the stages. libm calls per step: generated "
        f"{libm('maglev_simulate')}; hand-written {libm('ref_simulate')}.",
        "",
    ]
    if asm:
        out += [
            f"Compiled, `maglev_rk4_step` is {asm['instructions']} straight-line instructions "
            f"of which {asm['stack_memory']} load or store a stack slot and "
            f"{asm['divisions']} are divisions (the hand-written step divides 28 times: once "
            "per array and once for 1/cos(theta) at each stage), the same pattern as in the "
            "dynamics.",
            "",
        ]
    return [
        *out,
        "Issue 6 expected about 5 ms for this run on a 2-core machine: here the generated loop "
        f"takes {c['generated_ms']['median']:.3g} ms and the hand-written one "
        f"{c['reference_ms']['median']:.3g} ms.",
        "",
    ]


def _footprint(r: dict) -> list[str]:
    f = r["footprint"]
    rows = []
    for label, g in f["groups"].items():
        largest = ", ".join(
            f"{x.get('casadi_name', x['name'])} {x['bytes']}" for x in g["largest_functions"][:3]
        )
        rows.append([label, str(g["text"]), str(g["rodata"]), str(g["stack_bytes"]), largest])
    w = f["workspace_reals"]
    ref, gen_rt = f["reference"], f["generated_runtime_double_dynamics"]
    return [
        f"`maglevgen generate --precision single --parameters baked`, compiled with "
        f"`{f['compiler']} {' '.join(f['flags'])}`; each group is what the linker keeps for its "
        "entry points (`ld -r --gc-sections`), measured with `size -A` (bytes; .text is code, "
        ".rodata constants). Worst stack: the deepest static call path from "
        "`-fcallgraph-info=su` (the generated functions' own frames; libm's not included). "
        "Sizes are of host (x86-64) code: no ARM cross-compiler is installed here, so there "
        "are no Thumb-2 figures.",
        "",
        *_table(
            ["group", ".text", ".rodata", "worst stack", "largest functions (.text bytes)"], rows
        ),
        f"Whole generated file: .text {f['whole_file']['text']} B, .rodata "
        f"{f['whole_file']['rodata']} B, .data/.bss {f['whole_file']['data_bss']} B.",
        "",
        ("Heap: none. " if not f["heap_symbols"] else "Heap: **allocator calls found**. ")
        + "The only external symbols the objects use are "
        f"{', '.join(f['undefined_symbols'])}"
        + (
            f"; allocator symbols found: {', '.join(f['heap_symbols'])}."
            if f["heap_symbols"]
            else "; no malloc, calloc, realloc or free."
        )
        + " The caller passes the work arrays: "
        + ", ".join(f"{k.removeprefix('maglev_')} {v}" for k, v in w.items() if v)
        + " reals (4 bytes each in single precision); the other functions need none.",
        "",
        "For scale, the dynamics in double precision with run-time parameters (gcc -Os): "
        f"generated `maglev_dynamics` .text {gen_rt['text']} B, stack {gen_rt['stack_bytes']} B; "
        f"hand-written `ref_dynamics` .text {ref['ref_dynamics']['text']} B, stack "
        f"{ref['ref_dynamics']['stack_bytes']} B.",
        "",
    ]


def _precision(r: dict) -> list[str]:
    p = r["precision"]
    labels = {
        "lqr_gains": "`maglev_lqr_gains` (trim Newton + closed-form LQR)",
        "lqr_control": "`maglev_lqr_control` (trim Newton + feedback)",
        "damping_control": "`maglev_damping_control` (trim Newton + feedback)",
        "allocate": "`maglev_allocate`",
        "tick": "one control tick: lqr_control + allocate",
    }
    rows = [
        [
            labels.get(k, k),
            _ns(v["single_ns"]),
            _ns(v["double_ns"]),
            _ratio(v["single_over_double"]),
        ]
        for k, v in p["kinds"].items()
    ]
    n = next(iter(p["kinds"].values()))["single_ns"]["n"]
    return [
        "Baked-parameter builds in each precision, gcc -O2, timed from C "
        f"(bench/c/bench_controller.c); {n} rounds alternating the float32 and float64 drivers, "
        "ratio per round.",
        "",
        *_table(["function", "float32", "float64", "float32 / float64"], rows),
        *_newton_note(p),
    ]


def _newton_note(p: dict) -> list[str]:
    nt = p.get("newton", {}).get("single")
    slow = p["kinds"].get("lqr_gains", {}).get("single_over_double", {}).get("median", 1.0)
    if not nt or slow < 1.5:
        return []
    return [
        "Why float32 is the slower one here: the trim Newton generated into `maglev_lqr_gains`, "
        "`maglev_lqr_control` and `maglev_damping_control` stops when the residual is below "
        f"{nt['abstol']:.3g} or the step below {nt['abstol_step']:.3g}, else after "
        f"{nt['max_iter']} iterations. Those are double-precision tolerances in the float32 "
        "build too; float32 resolves about 1e-7 relative and the residuals are accelerations "
        "of order 10 m/s^2, so in float32 every call runs all "
        f"{nt['max_iter']} iterations.",
        "",
    ]


def markdown(r: dict) -> str:
    meta = r["meta"]
    out = [
        "# Benchmarks",
        "",
        "How fast and how small the toolchain and its generated C are, beside what an engineer "
        f"would otherwise use, all measured in one run. Produced by `{meta['command']}` "
        "(`make bench` runs `python bench/run.py` in the project's virtualenv) on "
        f"{meta['date_utc']}; the run took {meta['wall_s'] / 60:.1f} min. Do not edit: rerun. "
        "Raw figures: bench/results.json.",
        "",
    ]
    if meta["quick"]:
        out += ["**Quick run (--quick): too few repeats to quote.**", ""]
    out += ["## Machine", "", *_machine(r)]
    out += [
        "## Targets",
        "",
        *_table(
            ["target", "measured (median)", "met"],
            [[t["name"], t["measured"], "yes" if t["met"] else "**no**"] for t in r["targets"]],
        ),
    ]
    out += [
        "Reading the tables: times are medians of repeats with the quartiles in brackets; "
        "every ratio divides two figures taken in the same repeat (the machine is shared and "
        "noisy, so figures from different moments are not compared) and is the median of "
        "those per-repeat ratios. The hand-written C model (bench/reference/maglev_model.c) "
        "computes the same derivative as the generated C (to 1e-12 relative on 300 states near "
        "trim, checked by tests/test_bench_reference.py; about 1e-14 in practice).",
        "",
        "## 1. Derivation, generation and compile",
        "",
        *_derivation(r),
        "## 2. `maglev_dynamics`: time per call",
        "",
        *_dynamics(r),
        "## 3. Closed loop: 10 s at 1 kHz, RK4",
        "",
        *_loop(r),
        "## 4. Footprint for firmware (single precision, baked parameters)",
        "",
        *_footprint(r),
        "## 5. Controller path: float32 vs float64",
        "",
        *_precision(r),
    ]
    return "\n".join(out).rstrip() + "\n"
