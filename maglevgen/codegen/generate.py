"""`maglevgen generate`: the generated C, the readable header, the manifest, CMake and main.c.

Writers return (file name, text) pairs; `write_output` alone touches the disk, atomically.
"""

from __future__ import annotations

import json

import casadi as ca
import numpy as np

from maglevgen.carriage import DerivedCarriage
from maglevgen.codegen.checks import MAX_DELAY_TICKS, check_entries, work_sizes
from maglevgen.codegen.cpass import generate_c
from maglevgen.codegen.emit import c_literal
from maglevgen.codegen.emit import render as render_template
from maglevgen.codegen.functions import DESCRIPTIONS, PREFIX, bake_all, build_functions
from maglevgen.codegen.interface import (
    C_NAME,
    FUNCTION_TABLE,
    INT_TYPES,
    IO_DOCS,
    SIMULATE_FILES,
    SINGLE_FILE,
    GenerateOptions,
    banner,
    render_interface,
    template_env,
)
from maglevgen.codegen.misra import deviation_list
from maglevgen.codegen.simulate_api import SIMULATE_API
from maglevgen.derive import conventions as cv
from maglevgen.derive.model import CarriageModel
from maglevgen.infrastructure.output import write_output
from maglevgen.params import entry_limits

__all__ = ["GenerateOptions", "function_table", "render", "render_runtime_sources",
           "render_tick_sources", "write_output"]


def _io(fn: ca.Function, out: bool) -> list[dict]:
    n = fn.n_out() if out else fn.n_in()
    name = fn.name_out if out else fn.name_in
    sp_ = fn.sparsity_out if out else fn.sparsity_in
    return [{"name": name(i), "rows": sp_(i).size1(), "cols": sp_(i).size2(),
             "doc": IO_DOCS.get(name(i), "")} for i in range(n)]


def function_table(functions: list[ca.Function], source: str | None = None) -> list[dict]:
    """Name, description, inputs, outputs and work sizes of each function: those its generated
    ``NAME_work`` reports when ``source`` (the C) is given, else CasADi's Function counts."""
    work = work_sizes(source) if source is not None else {}
    table = []
    for f in functions:
        sz = work.get(f.name(), (f.sz_arg(), f.sz_res(), f.sz_iw(), f.sz_w()))
        table.append({
            "name": f.name(),
            "description": DESCRIPTIONS[f.name().removeprefix(PREFIX)],
            "inputs": _io(f, False), "outputs": _io(f, True),
            "sz_arg": sz[0], "sz_res": sz[1], "sz_iw": sz[2], "sz_w": sz[3],
        })
    return table


def _min_gap_c(model: CarriageModel, opts: GenerateOptions, p_value: np.ndarray | None) -> str:
    """track.min_gap as C inside maglev_trim_checked: p[i], or the baked value."""
    i = model.structure.param_names.index("track.min_gap")
    if p_value is None:
        return f"p[{i}]"
    return c_literal(p_value[i], opts.precision)


def _speed_range_c(opts: GenerateOptions,
                   speed_range: tuple[float, float] | None) -> tuple[str, str] | None:
    """The baked trim's [v_min, v_max] as C literals of the precision."""
    if speed_range is None:
        return None
    return tuple(c_literal(v, opts.precision) for v in speed_range)  # type: ignore[return-value]


def _p_limits_c(model: CarriageModel, opts: GenerateOptions) -> list[tuple[str, str]] | None:
    """With run-time parameters, each entry of p's schema range as C literals (the checked
    entry points refuse a p outside them: MAGLEV_ERR_PARAMETER)."""
    if opts.parameters != "runtime":
        return None
    return [tuple(c_literal(v, opts.precision) for v in entry_limits(n))  # type: ignore[misc]
            for n in model.structure.param_names]


def render_c(functions: list[ca.Function], opts: GenerateOptions, text_banner: str,
             model: CarriageModel, p_value: np.ndarray | None = None,
             speed_range: tuple[float, float] | None = None) -> dict[str, str]:
    """The C sources: the CasADi functions (post-processed, with the checked entry points of
    maglevgen.codegen.checks) and the simulation loop; ``speed_range``: the trim's accepted
    [v_min, v_max] (None: v > 0)."""
    sources = generate_c(functions, C_NAME, opts.precision, int_type=INT_TYPES[opts.int_type])
    sources[f"{C_NAME}.c"] = check_entries(sources[f"{C_NAME}.c"], function_table(functions),
                                           opts.precision, opts.parameters == "runtime",
                                           _min_gap_c(model, opts, p_value),
                                           _speed_range_c(opts, speed_range),
                                           _p_limits_c(model, opts))
    files = {name: render_template("generated_file.j2", banner=text_banner, text=text)
             for name, text in sources.items()}
    prepare = next(f for f in functions if f.name() == "maglev_closed_loop_prepare")
    dynamics_prepare = next(f for f in functions if f.name() == "maglev_dynamics_prepare")
    ctx = {"banner": text_banner, "parameters": opts.parameters, "precision": opts.precision,
           "nx": len(cv.STATES),
           "nu": len(model.input_names), "ng": len(model.arrays),
           "n_prepared": prepare.numel_out(0), "n_dynamics_prepared": dynamics_prepare.numel_out(0),
           "n_arrays": len(model.structure.arrays),
           "array_of_force": model.structure.array_of_force,
           "max_delay": MAX_DELAY_TICKS, "api": {f.name: f for f in SIMULATE_API}}
    env = template_env()
    for name in SIMULATE_FILES:
        files[name] = env.get_template(f"{name}.j2").render(ctx)
    if opts.single_file:
        files[SINGLE_FILE] = single_translation_unit(files.pop(f"{C_NAME}.c"),
                                                     files.pop("maglev_simulate.c"), text_banner)
    return files


def single_translation_unit(functions_c: str, simulate_c: str, text_banner: str) -> str:
    """maglev.c (`--single-file`): the functions and the simulation loop as one translation
    unit behind maglev.h and maglev_simulate.h, so every external function has its documented
    prototype in view (gcc's -Wmissing-prototypes checks it). Nothing else changes: the text is
    the two files'."""
    def body(text: str) -> str:
        return text.split("\n", 1)[1]  # without the banner line

    includes = '#include "maglev_simulate.h"\n'
    if simulate_c.count(includes) != 1:
        raise ValueError("maglev_simulate.c does not include its header once")
    return render_template("maglev.c.j2", banner=text_banner, file=SINGLE_FILE,
                  functions_body=body(functions_c),
                  simulate_body=body(simulate_c).replace(includes, ""))


def render_runtime_sources(model: CarriageModel, precision: str = "double") -> dict[str, str]:
    """The parameter-independent C of a carriage structure (what the simulation compiles) and
    the table of its functions (FUNCTION_TABLE, JSON) that the interface files are made from."""
    opts = GenerateOptions(precision, "runtime")
    built = build_functions(model, precision=precision, analysis=True)
    fns = [*built.functions, *built.analysis]
    files = render_c(fns, opts, banner(opts, None), model)
    files[FUNCTION_TABLE] = json.dumps(function_table(fns, files[f"{C_NAME}.c"]),
                                       indent=1) + "\n"
    return files


def render(carriage: DerivedCarriage, opts: GenerateOptions,
           speed_range: tuple[float, float] | None = None,
           example: dict | None = None) -> dict[str, str]:
    """Every output file's name and text (nothing written). ``speed_range``: the envelope's
    (v_min, v_max) (maglevgen.analyses.envelope.speed_range), baked into the trim's checks with the
    parameters; required with baked parameters. ``example``: main.c's controller
    (`render_interface`)."""
    if opts.parameters == "baked" and speed_range is None:
        raise ValueError("baked parameters need the envelope's speed range")
    built = build_functions(carriage.model, precision=opts.precision)
    fns = list(built.functions)
    if opts.parameters == "baked":
        fns = bake_all(tuple(fns), carriage.p)
    text_banner = banner(opts, carriage.loaded.sha256 if opts.parameters == "baked" else None)
    baked = opts.parameters == "baked"
    files = render_c(fns, opts, text_banner, carriage.model, carriage.p if baked else None,
                     speed_range if baked else None)
    c_text = files[SINGLE_FILE if opts.single_file else f"{C_NAME}.c"]
    files.update(render_interface(carriage, opts, function_table(fns, c_text),
                                  speed_range if baked else None, example))
    files["MISRA_DEVIATIONS.md"] = deviation_list()
    return files


TICK_FUNCTIONS = ("maglev_lqr_control", "maglev_damping_control", "maglev_coupled_control",
                  "maglev_allocate")


def render_tick_sources(carriage, precision: str = "single") -> dict[str, str]:
    """maglev_tick.c/.h: the per-tick functions alone, baked, as maglev_functions.c has them."""
    fns = bake_all(tuple(build_functions(carriage.model, precision=precision).functions),
                   carriage.p)
    tick = [f for f in fns if f.name() in TICK_FUNCTIONS]
    src = generate_c(tick, "maglev_tick", precision)
    src["maglev_tick.c"] = check_entries(src["maglev_tick.c"], function_table(tick), precision,
                                         False, "0")
    return src
