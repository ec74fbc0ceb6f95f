"""The firmware folder's C, rendered (nothing written): the single-precision C of the embedded
controller's path only (``envelope.embedded_controller``): the table schedule
(maglev_gain_table.c, `maglevgen.control.schedule.gain_table_sources`), the controller's
per-tick function and the allocation (maglev_functions.c, baked, with the checked entry points
of maglevgen.codegen.checks), the tick that joins them with the speed loop and the force budget
(maglev_tick.c), an example main.c, a CMake project with a Cortex-M4F toolchain file, the MISRA
deviation list and a README saying what to call when. `maglevgen firmware`
(maglevgen.exports.firmware) writes it; the host's runs on the sensors
(maglevgen.analyses.sensed) compile it in double precision and fly its sense tick.

With ``[sensors]`` the tick also has maglev_sense_tick (the Kalman filter on the readings, the
same law): its estimator's products are generated straight-line over the values its table
(maglev_sense_table.c) stores, a value constant over speed as a literal (`_sense_code`); its
varying values are cached in the caller's state and refreshed a slice a tick over
SENSE_REFRESH_TICKS ticks (`refresh_slices`), at a cost against evaluating the table every
tick that `sense_refresh_bound` states in maglev_tick.h. With the plant, the QEMU loop flies
maglev_sense_tick on the plant's readings too (`READINGS`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from importlib import resources
from typing import TYPE_CHECKING

import numpy as np

from maglevgen.codegen.checks import check_entries, error_defines
from maglevgen.codegen.cpass import generate_c
from maglevgen.codegen.emit import c_literal, render
from maglevgen.codegen.functions import bake_all, build_functions
from maglevgen.codegen.generate import function_table
from maglevgen.codegen.interface import C_NAME, GenerateOptions, interface_context, template_env
from maglevgen.codegen.lanes import KERNEL_PREFIX, WIDTHS, kernel_name, lane_kernels
from maglevgen.codegen.misra import deviation_list
from maglevgen.control import estimation as est
from maglevgen.control import sense_table as st
from maglevgen.control.built_loop import LoopSetting
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.schedule import (
    GainTable,
    clenshaw_lines,
    field_slices,
    gain_table_sources,
    schedule_lines,
    speed_map,
    value_terms,
    varying_values,
)
from maglevgen.controllers import controller as registered
from maglevgen.derive import conventions as cv
from maglevgen.errors import InputError
from maglevgen.version import __version__

if TYPE_CHECKING:
    from maglevgen.carriage import DerivedCarriage

__all__ = ["FIRMWARE_FLAGS", "QEMU_TICKS", "SENSE_REFRESH_TICKS", "TICK_INPUTS", "SenseSchedule",
           "host_sense_sources", "refresh_slices", "render_firmware", "sense_refresh_bound",
           "sense_schedule"]

#: the Cortex-M4F flags of the folder's README and toolchain file (the firmware build)
FIRMWARE_FLAGS = ("-mcpu=cortex-m4", "-mthumb", "-mfloat-abi=hard", "-mfpu=fpv4-sp-d16", "-Os",
                  "-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Wdouble-promotion",
                  "-Wfloat-conversion", "-Werror", "-fno-math-errno")

#: each per-tick function's inputs after the state x: the gain table's fields they read
#: (maglevgen.control.schedule.GAIN_TABLE_FIELDS), in the function's input order
TICK_INPUTS = {
    "maglev_coupled_control": ("K_pos", "K_rate", "a_ref"),
    "maglev_lqr_control": ("K", "a_ref"),
    "maglev_damping_control": ("c_damping",),
}
ALLOCATE = "maglev_allocate"
#: the sensors' measurement functions (codegen.functions): the QEMU loop's readings of the plant
READINGS = ("maglev_gap_reading", "maglev_imu_reading")
PLANT = "maglev_dynamics"  # --with-plant: the float32 plant in the image (HIL/SIL)
#: run_qemu.sh's closed loop: ticks from the trim with the heave 1 mm off (1 s at 1 kHz)
QEMU_TICKS = 1000
#: the host sense lanes' kernels begin so (not the run-time-parameter library's lane kernels)
HOST_KERNEL_PREFIX = "maglev_fw_lanes_"



#: the sense tick's readings at most: one bit each in C's unsigned long (32 bits at least)
MAX_READINGS = 32
#: what each kind of reading is, its unit (the sense tick's header and the manifest)
READING_KINDS = {"gap": ("m", "gap sensor {name}: the gap along its face's normal"),
                 "gyro": ("rad/s", "gyro: body rate about {axis}"),
                 "accel": ("m/s^2", "accelerometer: specific force along body {axis}"),
                 "track": ("m", "track sensor: position along the track")}


@dataclass(frozen=True)
class SenseSchedule:
    """What the sense tick needs beyond the law's: the estimator's table over speed
    (`maglevgen.control.estimation.sense_table`), its plant states, lagged forces, readings
    (names, plausible ranges) and the gap readings' count (the first ones)."""

    table: GainTable
    states: tuple[str, ...]  # the estimator's plant states (EstimatorModel.states)
    n_lag: int
    readings: tuple[str, ...]  # SensorLayout.names
    ranges: np.ndarray  # (n_readings, 2) estimation.reading_ranges
    n_gap: int

    def reading_rows(self) -> list[dict]:
        """Each reading: its name, index, unit, what it is and its plausible range."""
        out = []
        for i, name in enumerate(self.readings):
            kind, _, rest = name.partition("_")
            unit, what = READING_KINDS[kind]
            axis = {"p": "x", "q": "y", "r": "z"}.get(rest, rest)
            out.append({"name": name, "index": i, "unit": unit,
                        "what": what.format(name=rest, axis=axis),
                        "lo": float(self.ranges[i, 0]), "hi": float(self.ranges[i, 1])})
        return out

    def manifest(self) -> dict:
        return {"function": "maglev_sense_tick", "init": "maglev_sense_init",
                "readings": self.reading_rows(), "estimator_states": list(self.states),
                "lagged_forces": self.n_lag,
                "plausible_ranges": {"gap": f"[0, {st.GAP_RANGE:g} x nominal gap]",
                                     "gyro_rad_s": st.GYRO_RANGE,
                                     "accel_m_s2": st.ACCEL_RANGE,
                                     "track_m": st.TRACK_RANGE},
                "table": self.table.manifest()}


def sense_schedule(plant: Plant, v_min: float, v_max: float,
                   loop: LoopSetting) -> SenseSchedule | None:
    """The sense tick's schedule of ``plant`` over [v_min, v_max] with ``loop``'s delay
    and actuator lag; None when the parameter file has no [sensors] (no sense tick)."""
    carriage, lib = plant.carriage, plant.lib
    params = carriage.params
    if params.sensors is None:
        return None
    layout = est.SensorLayout.of(params)
    if len(layout.names) > MAX_READINGS:
        raise InputError(f"sensors: {len(layout.names)} readings; the sense tick's flags "
                         f"word holds {MAX_READINGS} (fewer gap sensors)")
    table = st.sense_table(lib, carriage.p, params,
                            plant.point, v_min, v_max,
                            loop.actuator_lag, loop.delay_ticks)
    n_lag = len(carriage.model.input_names) - 1 if loop.actuator_lag > 0 else 0
    states = tuple(s for s in cv.STATE_NAMES if layout.track or s != "x")
    return SenseSchedule(table, states, n_lag, layout.names, st.reading_ranges(layout),
                         len(layout.gaps))


#: the sense tick's refresh of its estimator's varying values: one slice a tick into the
#: buffer not in use, the buffers swapped when it is full (every this many ticks)
SENSE_REFRESH_TICKS = 4


def sense_refresh_bound(table: GainTable, acceleration: float, tick_rate: float,
                        grid: int = 2001) -> dict[str, float]:
    """What the sense tick's refresh costs against evaluating its table every tick: the values
    in use were evaluated at the scheduled speed of at most 2 x SENSE_REFRESH_TICKS ticks
    before (a refresh's ticks, then the ticks it is in use), when the speed moves by at most
    ``acceleration`` [m/s^2] a second; per field, the largest change of any of its values over
    that speed change on ``grid`` speeds, relative to the field's largest magnitude (the
    table's error measure)."""

    dv = acceleration * 2 * SENSE_REFRESH_TICKS / tick_rate
    v = np.linspace(table.v_min, table.v_max, grid)
    rows = table(v)
    moved = np.abs(table(np.minimum(v + dv, table.v_max)) - rows)
    return {name: float(np.max(moved[:, i:i + n]) / (np.max(np.abs(rows[:, i:i + n])) or 1.0))
            for (name, _), (i, n) in zip(table.fields, field_slices(table.fields), strict=True)}


def refresh_slices(table: GainTable) -> list[int]:
    """The refresh's slices: slice k evaluates the varying values [out[k], out[k + 1]) (the
    order of `schedule.varying_values`), SENSE_REFRESH_TICKS of them of about equal cost
    (a value's Clenshaw steps, its terms - 1, and about as much again for the value)."""

    terms = value_terms(table.coeffs)[varying_values(table)]
    cost = np.concatenate([[0.0], np.cumsum(terms)])  # (terms - 1) + 1 a value
    goals = cost[-1] * np.arange(1, SENSE_REFRESH_TICKS) / SENSE_REFRESH_TICKS
    cuts = [int(np.argmin(np.abs(cost - g))) for g in goals]
    return [0, *cuts, len(terms)]


def _sense_code(sense: SenseSchedule, nu: int) -> dict[str, list]:
    """The estimator's products as straight-line C over the values its table stores (a
    sparsity fixed at generation: a value zero over the envelope is no term), a one-term value
    a constant, a varying one tab[k] (`schedule.varying_values`: the refresh's cache). Each
    sum in the order of the dense loops it replaces (ascending index), so the result is theirs
    bit for bit (a zero term adds +-0)."""

    table = sense.table
    first = {name: i for (name, _), (i, _) in zip(table.fields, field_slices(table.fields),
                                                  strict=True)}
    terms = value_terms(table.coeffs)
    vary = {j: k for k, j in enumerate(varying_values(table))}
    stored = set(table.stored)
    ne, nl, ny = len(sense.states), sense.n_lag, len(sense.readings)
    nc = ne + nl
    idx = [cv.STATE_INDEX[s] for s in sense.states]

    def val(field: str, i: int) -> str | None:
        j = first[field] + i
        if j not in stored:
            return None
        if terms[j] > 1:
            return f"tab[{vary[j]}]"
        return f"R({c_literal(float(table.coeffs[0, j]))})"

    trim = [f"x_trim[{i}] = {val('x_trim', i) or 'R(0)'};" for i in range(len(cv.STATE_NAMES))]
    innov = []
    for j in range(ny):
        yt = val("y_trim", j)
        innov.append(f"acc = y[{j}] - {yt};" if yt else f"acc = y[{j}];")
        innov += [f"acc -= {c} * dz[{i}];" for i in range(nc) if (c := val("C", j + ny * i))]
        innov += [f"acc -= {d} * du[{i}];" for i in range(nu) if (d := val("D", j + ny * i))]
        innov.append(f"e[{j}] = acc;")
    update = []
    for i in range(ne):
        update.append("acc = R(0);")
        update += [f"acc += {m} * e[{j}];" for j in range(ny) if (m := val("M", i + ne * j))]
        update += [f"x_hat[{idx[i]}] += acc;", f"dz[{i}] += acc;"]
    predict = []
    for i in range(ne):
        predict.append(f"acc = dz[{i}];")
        predict += [f"acc += {a} * dz[{j}];" for j in range(nc)
                    if (a := val("Phi_minus_I", i + ne * j))]
        predict += [f"acc += {b} * du[{j}];" for j in range(nu)
                    if (b := val("Gamma", i + ne * j))]
        predict.append(f"x_pred[{idx[i]}] = x_trim[{idx[i]}] + acc;")
    pose = [sense.states.index(s) for s in ("y", "z", "phi", "theta", "psi")]
    pose_rows = [f"cp[{k + sense.n_gap * i}] = {val('C', k + ny * pose[i]) or 'R(0)'};"
                 for i in range(len(pose)) for k in range(sense.n_gap)]
    pose_rows += [f"yt[{k}] = {val('y_trim', k) or 'R(0)'};" for k in range(sense.n_gap)]
    # the refresh's slices: each varying value's Clenshaw written out with its coefficients
    # (`schedule.clenshaw_lines`: maglev_sense_schedule_varying's operations in its order)
    refresh: list[list[str]] = []
    bounds = refresh_slices(table)
    order = varying_values(table)
    for k in range(len(bounds) - 1):
        lines = []
        for i in range(bounds[k], bounds[k + 1]):
            lines += clenshaw_lines(table.coeffs[:terms[order[i]], order[i]], f"tab[{i}]")
        refresh.append(lines)
    # the law's estimate less the accelerating trim's change at the commanded acceleration a
    # (the launch's reference), and that trim's propulsion change
    accel = [f"x_law[{i}] -= a * {c};"
             for i in range(len(cv.STATE_NAMES)) if (c := val("x_accel", i))]
    return {"trim": trim, "f_prop": [val("F_prop", 0) or "R(0)"], "innov": innov,
            "accel": accel, "f_accel": [val("F_accel", 0) or "R(0)"],
            "refresh": refresh,
            "correct": update, "predict": predict, "pose_rows": pose_rows}


def _sense_context(sense: SenseSchedule, precision: str, nu: int, tick_rate: float,
                   acceleration: float) -> dict:

    names = sense.readings
    t_scale, t_offset = speed_map(sense.table)
    return {"code": _sense_code(sense, nu), "n_vary": len(varying_values(sense.table)),
            "refresh_ticks": SENSE_REFRESH_TICKS, "slices": refresh_slices(sense.table),
            # maglev_sense_table.c's V_MIN, V_MAX, T_SCALE, T_OFFSET: the same text, so the
            # same constants (gain_table_sources)
            "v_min": c_literal(sense.table.v_min), "v_max": c_literal(sense.table.v_max),
            "t_scale": c_literal(t_scale), "t_offset": c_literal(t_offset),
            "acceleration": acceleration,
            "refresh_bound": sense_refresh_bound(sense.table, acceleration, tick_rate),
            "n_states": len(sense.states), "n_lag": sense.n_lag, "n_gap": sense.n_gap,
            "state_index": [cv.STATE_INDEX[s] for s in sense.states],
            "pose_index": [sense.states.index(s) for s in ("y", "z", "phi", "theta", "psi")],
            "track_index": names.index("track_x") if "track_x" in names else -1,
            "readings": sense.reading_rows(),
            "lo": [c_literal(float(v), precision) for v in sense.ranges[:, 0]],
            "hi": [c_literal(float(v), precision) for v in sense.ranges[:, 1]],
            "gap_range": st.GAP_RANGE, "gyro_range": st.GYRO_RANGE,
            "accel_range": st.ACCEL_RANGE, "track_range": st.TRACK_RANGE}


def firmware_functions(controller_tick: str, with_plant: bool = False,
                       readings: bool = False) -> tuple[str, ...]:
    """The generated functions of the firmware folder, in maglev_functions.c's order;
    ``readings`` (with the plant): the sensors' measurement functions too (the QEMU loop's
    sense tick reads the plant through them)."""
    if controller_tick not in TICK_INPUTS:
        raise ValueError(f"no firmware tick for {controller_tick!r}")
    return (controller_tick, ALLOCATE) + ((PLANT,) if with_plant else ()) + (
        READINGS if with_plant and readings else ())


def _sense_plant(carriage: DerivedCarriage, precision: str) -> dict:
    """The QEMU loop's sensors on the plant: each gap sensor's body point, face normal and
    nominal gap, the IMU's point, each reading's noise (its standard deviation at the tick:
    estimation.SensorLayout), as C literals."""
    layout = est.SensorLayout.of(carriage.params)

    def lits(v) -> str:
        return ", ".join(c_literal(float(x), precision) for x in np.ravel(v))

    return {"gaps": [{"point": lits(g.point), "normal": lits(g.normal),
                      "nominal": c_literal(g.nominal_gap, precision)} for g in layout.gaps],
            "imu_point": None if layout.imu_point is None else lits(layout.imu_point),
            "sigma": lits(np.sqrt(layout.variances)), "track": bool(layout.track)}


def _banner(sha256: str, precision: str, with_plant: bool) -> str:
    extra = ("" if precision == "single" else f" --precision {precision}") + (
        " --with-plant" if with_plant else "")
    return (f"Generated by maglevgen {__version__} (`maglevgen firmware{extra}`) from parameter "
            f"file sha256 {sha256}. Do not edit: regenerate.")


def render_firmware(carriage: DerivedCarriage, table: GainTable, loop: LoopSetting,
                    precision: str = "single", with_plant: bool = False,
                    measured: dict | None = None, verdict: dict | None = None,
                    sense: SenseSchedule | None = None) -> dict[str, str]:
    """Every file of the firmware folder (nothing written).

    ``table``: the table schedule of the embedded controller over the envelope
    (`maglevgen.control.carriage_plant.Plant.gain_table`); ``loop``: the loop as built
    (`Plant.loop`: its tick, delay, speed-loop gains, actuator lag and force budget);
    ``precision``: "single" for the board, "double" for a host check of the same code;
    ``with_plant``: maglev_dynamics in the same image too (a closed loop on the target,
    e.g. under QEMU); ``measured``: the tick's cost on the Cortex-M4 at the default carriage
    (BENCHMARKS.md), quoted in the README; ``verdict``: the embedded controller's
    verification (`maglevgen.build.EmbeddedVerdict.to_json`; None: not checked, said so),
    into the README and the manifest; ``sense``: the estimator's schedule
    (`sense_schedule`; None: maglev_tick alone, ideal sensing).
    """
    return _firmware(carriage, table, loop, precision, with_plant, measured, verdict, sense)[0]


def host_sense_sources(carriage: DerivedCarriage, table: GainTable, loop: LoopSetting,
                       sense: SenseSchedule) -> tuple[dict[str, str], str]:
    """The firmware folder in double precision with its sense tick (`render_firmware`), and
    that sense tick over SIMD lanes for the host's Monte Carlo (maglev_sense_lanes.c,
    templates/firmware_sense_lanes.c.j2; not a file of the folder): the estimator's and
    the schedule's generated lines and the tick law's functions as lane kernels
    (`maglevgen.codegen.lanes`) of the folder's own maglev_functions.c."""
    files, ctx = _firmware(carriage, table, loop, "double", sense=sense)
    tick_fn = ctx["tick_function"]
    kernels = lane_kernels(files[f"{C_NAME}.c"], (tick_fn, ALLOCATE)).replace(
        KERNEL_PREFIX, HOST_KERNEL_PREFIX)
    f_prop = next(first for (name, _), (first, _) in zip(
        table.fields, field_slices(table.fields), strict=True) if name == "F_prop")
    terms = value_terms(table.coeffs)
    t_scale, t_offset = speed_map(table)
    schedule = {"v_min": c_literal(table.v_min), "v_max": c_literal(table.v_max),
                "t_scale": c_literal(t_scale), "t_offset": c_literal(t_offset),
                "clenshaw": schedule_lines(table),
                "f_prop": (clenshaw_lines(table.coeffs[:terms[f_prop], f_prop], "f_ff")
                           if f_prop in table.stored else [])}
    widths = [(w, target, "defined(__x86_64__)" if target else "1")
              for w, target in WIDTHS.items()]
    source = template_env().get_template("firmware_sense_lanes.c.j2").render(
        ctx, kernels=kernels, schedule=schedule, widths=widths,
        kernel_prefix=HOST_KERNEL_PREFIX,
        tick_kernel=kernel_name(tick_fn, 0).removeprefix(KERNEL_PREFIX).removesuffix("_w0"))
    return files, source


def _firmware(carriage: DerivedCarriage, table: GainTable, loop: LoopSetting,
              precision: str = "single", with_plant: bool = False,
              measured: dict | None = None, verdict: dict | None = None,
              sense: SenseSchedule | None = None) -> tuple[dict[str, str], dict]:
    loop.check_embeddable()
    opts = GenerateOptions(precision, "baked", "int32")
    embedded = carriage.params.envelope.embedded_controller
    tick_fn = registered(embedded).tick_function
    if tick_fn is None or tick_fn not in TICK_INPUTS:
        raise ValueError(f"the embedded controller {embedded!r} has no firmware tick")
    names = firmware_functions(tick_fn, with_plant, sense is not None)
    built = build_functions(carriage.model, precision=precision).functions
    fns = [f for f in bake_all(tuple(built), carriage.p) if f.name() in names]
    fns.sort(key=lambda f: names.index(f.name()))
    text_banner = _banner(carriage.loaded.sha256, precision, with_plant)
    sources = generate_c(fns, C_NAME, precision, int_type="int")
    sources[f"{C_NAME}.c"] = check_entries(sources[f"{C_NAME}.c"], function_table(fns),
                                           precision, False, "0")
    files = {name: render("generated_file.j2", banner=text_banner, text=text)
             for name, text in sources.items()}
    fn_table = function_table(fns, files[f"{C_NAME}.c"])
    ctx = interface_context(carriage, opts, fn_table, None)
    ctx["banner"] = text_banner
    env = template_env()
    files["maglev.h"] = env.get_template("maglev.h.j2").render(ctx)
    files.update(gain_table_sources(table, one_output="F_prop"))
    if sense is not None:
        files.update(gain_table_sources(
            sense.table, "maglev_sense_table", "maglev_sense_schedule",
            "MAGLEV_SENSE_SCHEDULE", "estimator schedule (the sense tick's)",
            " * out[MAGLEV_SENSE_SCHEDULE_NOUT] = the estimator at v (maglev_tick.h's\n"
            " * maglev_sense_tick): F_prop [N] (trim propulsion), x_trim (the trim state, its u\n"
            " * less v), y_trim (the readings at trim), Phi_minus_I, Gamma, C, D and M (the\n"
            " * update's gain), column-major, on the estimator's plant states and lagged forces,\n"
            " * at the offsets above.", varying=True, written_out=False))

    if "K_lag" not in dict(table.fields):
        raise ValueError("the firmware's table carries the design at the tick "
                         "(`maglevgen.control.carriage_plant.Plant.gain_table`)")
    offsets, i = {}, 0
    for name, size in table.fields:
        offsets[name] = i
        i += size
    sizes = {k: max(f[f"sz_{k}"] for f in fn_table if f["name"] in (tick_fn, ALLOCATE))
             for k in ("arg", "res", "iw", "w")}
    structure = carriage.model.structure
    cost = measured or {}
    tick_ctx = {
        "ticks": QEMU_TICKS,
        "banner": text_banner, "precision": precision, "controller": embedded,
        "controller_title": registered(embedded).title, "tick_function": tick_fn,
        "tick_inputs": [name.upper() for name in TICK_INPUTS[tick_fn]],
        "tick_rate": c_literal(loop.tick_rate, precision), "tick_rate_value": loop.tick_rate,
        "delay_ticks": int(loop.delay_ticks),
        "k_v": c_literal(loop.speed_gain, precision), "k_v_value": loop.speed_gain,
        "k_i": c_literal(loop.speed_integral, precision),
        "i_max": c_literal(loop.c_integral_limit, precision),
        "tick_period": c_literal(1.0 / loop.tick_rate, precision),
        "lag_pole": c_literal(loop.lag_pole, precision),
        "lag_gain": c_literal(1.0 - loop.lag_pole, precision), "tau": loop.actuator_lag,
        "force_budget": c_literal(loop.force_budget, precision),
        "force_budget_value": loop.force_budget,
        "n_arrays": len(structure.arrays), "array_of_force": structure.array_of_force,
        "sz": sizes, "nu": len(carriage.model.input_names), "offsets": offsets,
        "v_min": table.v_min, "v_max": table.v_max, "nodes": len(table.coeffs),
        "table_error": max(table.errors.values()), "with_plant": with_plant,
        "flags": " ".join(FIRMWARE_FLAGS), "functions": [f["name"] for f in fn_table],
        "cost": cost, "error_defines": error_defines(),
        "sense_plant": (_sense_plant(carriage, precision) if sense is not None and with_plant
                        else None),
        "sense": None if sense is None else _sense_context(
            sense, precision, len(carriage.model.input_names), loop.tick_rate,
            carriage.params.envelope.launch_acceleration),
        "sense_nodes": 0 if sense is None else len(sense.table.coeffs),
        "sense_error": 0.0 if sense is None else max(sense.table.errors.values()),
        "verdict": (verdict or {}).get("verdict", "not checked (rendered without "
                                       "`maglevgen firmware`'s verification)"),
    }
    for name in ("maglev_tick.h", "maglev_tick.c", "main.c", "CMakeLists.txt",
                 "cortex-m4f.cmake", "README.md"):
        files[name] = env.get_template(f"firmware_{name}.j2").render(tick_ctx)
    if with_plant and precision == "single" and cost:
        # the closed loop on an emulated Cortex-M4F: `sh run_qemu.sh` (QEMU_FILES)
        files["qemu_loop.c"] = env.get_template("firmware_qemu_loop.c.j2").render(tick_ctx)
        files["run_qemu.sh"] = env.get_template("firmware_run_qemu.sh.j2").render(tick_ctx)
        for name in ("qemu_startup.c", "qemu_link.ld"):
            files[name] = (resources.files("maglevgen.templates") / f"firmware_{name}").read_text()
    files["MISRA_DEVIATIONS.md"] = deviation_list()
    manifest = {
        "generated_by": f"maglevgen {__version__}", "command": text_banner.split("`")[1],
        "precision": precision, "parameters": "baked", "casadi_int": "int",
        "params_sha256": carriage.loaded.sha256, "embedded_controller": embedded,
        "tick": {"function": "maglev_tick", "controller_tick": tick_fn,
                 "rate_hz": loop.tick_rate, "delay_ticks": int(loop.delay_ticks),
                 "speed_gain": loop.speed_gain, "speed_integral": loop.speed_integral,
                 "speed_integral_limit": loop.c_integral_limit,
                 "actuator_lag_s": loop.actuator_lag, "lag_pole": loop.lag_pole,
                 "force_budget": loop.force_budget,
                 "design": "the embedded controller's design at the tick on the loop as "
                           "built (maglevgen.control.plant), ideal sensing"},
        "verification": verdict,
        "sense_tick": None if sense is None else sense.manifest(),
        "gain_table": table.manifest(), "functions": fn_table,
        "flags": list(FIRMWARE_FLAGS),
    }
    files["manifest.json"] = json.dumps(manifest, indent=2) + "\n"
    return files, tick_ctx
