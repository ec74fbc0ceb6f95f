"""`maglevgen fmu`: the generated carriage as an FMI 2.0 or FMI 3.0 FMU (model exchange,
co-simulation or both), for Simulink, Dymola, OpenModelica, FMPy and the like.

Everything in modelDescription.xml and in the wrapper's value-reference table comes from one
list of `FmuVariable` built from the manifest (names, units, descriptions, start values), the
same for both FMI versions, and both files are rendered from it by the templates of the
version (`FMI_VERSIONS`: fmu_model_description.xml.j2 and fmu_wrapper.c.j2 for 2.0,
fmu3_model_description.xml.j2 and fmu3_wrapper.c.j2 for 3.0), both wrappers around the one
version-independent model core fmu_core.c.j2. The model is the run-time-parameter C of the
carriage's structure (the cached derivation of its `Plant`'s library): every function takes
the parameter vector p, so a parameter set through fmi2SetReal (fmi3SetFloat64) before
initialization behaves like ``--set``: the trim (maglev_trim at ``operation.speed``), the
gains (maglev_lqr_gains) and the allocation are computed from it when the FMU leaves
initialization mode.

Controllers come from the registry (maglevgen.control) through `fmu_controllers`: one entry per
controller says how the wrapper gets the generalized forces u_gen (eqs 20-33) and which inputs
it adds.
"""

from __future__ import annotations

import io
import json
import re
import uuid
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING

from maglevgen.codegen.checks import ERROR_CODES, MAX_DELAY_TICKS
from maglevgen.derive import conventions as cv
from maglevgen.derive.conventions import Q_STATES
from maglevgen.derive.structure import Structure
from maglevgen.errors import InputError
from maglevgen.version import __version__

if TYPE_CHECKING:
    from maglevgen.control.built_loop import Loop, LoopSetting
    from maglevgen.control.carriage_plant import Plant
    from maglevgen.control.operating import OperatingPoint
    from maglevgen.control.plant import LoopDesign
    from maglevgen.exports.fmu_sense import FmuSense

__all__ = [
    "DEFAULT_FMI",
    "EXTERNAL",
    "FMI_VERSIONS",
    "FMU_LOOPS",
    "FMU_NAME",
    "KINDS",
    "build_fmu",
    "default_loop",
    "fmi_headers",
    "fmu_controllers",
]

# Imported by the command-line parser: nothing heavier than the conventions at module level.

KINDS = ("me", "cs", "both")
MODEL_IDENTIFIER = "maglev"
WRAPPER_C = "maglev_fmu.c"
FMU_NAME = "maglev.fmu"
# Parameters whose change the C takes into account at the next evaluation; every other one
# enters the trim, the gains or the allocation, computed once at initialization ("fixed").
TUNABLE_PARAMETERS = frozenset({"track.min_gap"})
DEFAULT_INTERNAL_STEP = 1e-3  # [s] the RK4 step of `maglevgen simulate`'s default
# how the FMU's built-in controller runs (the fixed parameters of the "tick" group; the
# ``--loop`` choices, parsed by the API; `build_fmu` takes the `Loop`): "firmware" the loop as
# built, as `maglevgen simulate --loop firmware` flies it
# (maglevgen.control.carriage_plant.Plant.loop and firmware_gains: the tick law of
# templates/maglev_tick_law.c.j2 at the tick of [control.spec] with its delay and the
# controller's gains at the tick, the speed loop and its integral, the force budget, each array
# force's first-order lag in the plant, as continuous states in model exchange), "sensed" that
# loop with the embedded controller's sense tick on the noisy readings of [sensors]
# (maglevgen.exports.fmu_sense), "continuous" the paper's law at every derivative evaluation
FMU_LOOPS: tuple[str, ...] = ("firmware", "sensed", "continuous")


def default_loop(params, controller: str) -> str:
    """The FMU's loop where none is asked, as a carriage flies: "sensed" for the embedded
    controller where the file has [sensors], else "firmware"."""
    embedded = params.envelope.embedded_controller
    return "sensed" if controller == embedded and params.sensors is not None else "firmware"


@dataclass(frozen=True)
class FmuTick:
    """What the FMU's tick parameters start at: ``loop``, the loop as built (`Plant.loop`:
    tick rate, delay, speed gain and integral, budget, actuator lag; its FMU carries the
    lagged array forces as continuous states, which model exchange integrates), None for the
    continuous law (every tick parameter 0); ``k_lag`` (25) and ``k_delay`` (25
    MAX_DELAY_TICKS, of which a loop reads its first 25 delay_ticks): the tick law's gains on
    the predicted lagged generalized forces and on those in flight, column-major
    (templates/maglev_tick_law.c.j2; empty: zero); ``sense``: that loop on the sensors (the
    firmware's sense tick computes the command from its tables; the gains above are fixed)."""

    loop: LoopSetting | None = None
    k_lag: tuple[float, ...] = ()
    k_delay: tuple[float, ...] = ()
    sense: FmuSense | None = None

    @property
    def firmware(self) -> bool:
        return self.loop is not None

    def starts(self) -> tuple[float, float, float, float, float, float]:
        """(tick_rate, delay_ticks, speed_gain, force_budget, actuator_lag, speed_integral)."""
        lp = self.loop
        if lp is None:
            return (0.0,) * 6
        return (float(lp.rate), float(lp.delay), float(lp.speed_gain), float(lp.force_budget),
                float(lp.lag), float(lp.speed_integral))


@dataclass(frozen=True)
class FmiVersion:
    """What differs between the FMI versions: the templates, the header the wrapper includes
    (FMPy's copy), the binaries' platform folder and the files beside modelDescription.xml."""

    name: str
    label: str
    model_description: str
    wrapper: str
    header: str
    platform: str
    build_description: str = ""  # FMI 3.0: sources/buildDescription.xml lists the sources


FMI_VERSIONS: dict[str, FmiVersion] = {v.name: v for v in (
    FmiVersion("2", "2.0", "fmu_model_description.xml", "fmu_wrapper.c", "fmi2Functions.h",
               "linux64"),
    FmiVersion("3", "3.0", "fmu3_model_description.xml", "fmu3_wrapper.c", "fmi3Functions.h",
               "x86_64-linux", build_description="fmu3_build_description.xml"),
)}
# FMI 2.0 by default: every FMI importer in use reads it (Simulink's and Dymola's older
# releases, OpenModelica's, libcosim, FMPy), while 3.0 importers are still arriving; `--fmi 3`
# gives the same model, controllers, start values and units as an FMI 3.0 FMU.
DEFAULT_FMI = "2"

# FMI 3.0 unit definitions: each symbol of the schema's and the conventions' units as powers
# of FMI's base units (kg, m, s, A, K, mol, cd, rad; the SI derived units by definition)
FMI3_BASE_UNITS = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")
_UNIT_SYMBOLS: dict[str, dict[str, int]] = {
    "1": {}, "-": {}, "kg": {"kg": 1}, "m": {"m": 1}, "s": {"s": 1}, "A": {"A": 1},
    "K": {"K": 1}, "mol": {"mol": 1}, "cd": {"cd": 1}, "rad": {"rad": 1},
    "Hz": {"s": -1}, "N": {"kg": 1, "m": 1, "s": -2}, "Pa": {"kg": 1, "m": -1, "s": -2},
    "J": {"kg": 1, "m": 2, "s": -2}, "W": {"kg": 1, "m": 2, "s": -3},
    "V": {"kg": 1, "m": 2, "s": -3, "A": -1}, "ohm": {"kg": 1, "m": 2, "s": -3, "A": -2},
    "H": {"kg": 1, "m": 2, "s": -2, "A": -2}, "T": {"kg": 1, "s": -2, "A": -1},
    "Wb": {"kg": 1, "m": 2, "s": -2, "A": -1},
}


def fmi3_base_unit(unit: str) -> tuple[tuple[str, int], ...]:
    """The exponents of FMI 3.0's base units of ``unit`` ("kg*m^2", "m/s^2", "N*m"; each
    ``/`` divides by the factor after it), in FMI's attribute order, zeros left out."""
    powers = dict.fromkeys(FMI3_BASE_UNITS, 0)
    for sign, factor in re.findall(r"(^|[*/])\s*([^*/]+)", unit.strip()):
        sym, _, exp = factor.strip().partition("^")
        if sym not in _UNIT_SYMBOLS or (exp and not re.fullmatch(r"-?\d+", exp)):
            raise ValueError(f"unit {unit!r}: {factor!r} is not a known unit symbol")
        n = (int(exp) if exp else 1) * (-1 if sign == "/" else 1)
        for base, e in _UNIT_SYMBOLS[sym].items():
            powers[base] += n * e
    return tuple((b, e) for b, e in powers.items() if e)


@dataclass(frozen=True)
class FmuController:
    """One controller of the FMU.

    ``law`` "axis": u_gen = -(k_pos (a - a_ref) + k_rate a_dot) inside the generated
    maglev_closed_loop_prepared (the path `maglevgen simulate` integrates), with k_pos and
    k_rate set at initialization as ``gains`` says (`FMU_GAINS`; the C of each is the macro
    of that name in templates/fmu_controllers.c.j2). ``law`` "generic": u_gen (5) from the
    state x, the controller inputs ``in`` and the ``gains`` storage (``gain_slots`` values),
    by the macro u_gen of that template; the array forces are then T u_gen and the
    derivatives come from maglev_dynamics. ``inputs``: "references" (axis position offsets
    from trim), "controls" (the generalized forces themselves) or "" (none).
    """

    name: str
    description: str
    law: str
    inputs: str = ""
    gains: str = "none"
    gain_slots: int = 1


# How the wrapper sets each registered controller's gains (maglevgen.control, Controller.fmu_gains):
# the inputs it adds and what its description says of the gains. "matrix": the gains need a
# Riccati solve the C does not hold: the toolchain solves it at export (maglevgen.control.operating,
# at operation.speed for the file's parameters) and the wrapper carries them as constants
# (MATRIX_K_POS, MATRIX_K_RATE); a parameter set through FMI changes the trim but not these
# gains.
FMU_GAINS: dict[str, tuple[str, str]] = {
    "none": ("", ""),
    "damping": ("", ", gains at operation.speed"),
    "axis": ("references", ", gains at operation.speed"),
    "matrix": ("references", ", gains solved at export for the parameter file at "
                             "operation.speed"),
}


EXTERNAL = FmuController("external", "generalized control forces are inputs (minimum-norm "
                         "allocation, eqs 22-23)", "generic", inputs="controls")


def fmu_controllers() -> dict[str, FmuController]:
    """Every registered controller (`maglevgen.controllers`) as the wrapper runs it, and
    ``external``."""
    from maglevgen import (
        controllers,  # local: `maglevgen fmu --help` and the CLI's start stay numpy-free
    )

    out = {}
    for c in controllers.REGISTRY.values():
        inputs, gains_at = FMU_GAINS[c.fmu_gains]
        out[c.name] = FmuController(c.name, c.description + gains_at, "axis", inputs=inputs,
                                    gains=c.fmu_gains)
    return {**out, EXTERNAL.name: EXTERNAL}


@dataclass(frozen=True)
class FmuVariable:
    """One ScalarVariable: its value reference is its index in the list (and in the C)."""

    name: str
    causality: str
    variability: str
    initial: str | None
    start: float | None
    unit: str
    description: str
    group: str
    derivative: int | None = None  # 1-based index of the state this is the derivative of

    @property
    def start_xml(self) -> str | None:
        return None if self.start is None else repr(float(self.start))


@dataclass(frozen=True)
class FmuModel:
    """What the templates need: the variables, their groups' first value reference, and the
    indices into the parameter vector the wrapper reads; ``structure``: the carriage's arrays
    and their forces (the gaps' names, each force's array)."""

    variables: tuple[FmuVariable, ...]
    controller: FmuController
    kind: str
    manifest: dict
    structure: Structure
    sense: FmuSense | None = None  # the sensed loop's sensors and firmware (`fmu_sense`)

    def first(self, group: str) -> int:
        return next((i for i, v in enumerate(self.variables) if v.group == group), -1)

    def count(self, group: str) -> int:
        return sum(v.group == group for v in self.variables)


def fmu_variables(manifest: dict, structure: Structure, controller: FmuController, kind: str,
                  tick: FmuTick | None = None) -> tuple[FmuVariable, ...]:
    """Every FMU variable, in value-reference order, from the manifest and the structure (the
    arrays' gaps); ``tick``: the start values of the tick's parameters (a built-in
    controller's only; default: continuous). The continuous states are the carriage's, then,
    for a built-in controller on the firmware loop (``tick.firmware``), each array force
    component through its lag (``actuator.<force>``), their derivatives in the same order."""
    from maglevgen.analyses.simulate import DISTURBANCE, DISTURBANCE_DOC

    states = manifest["states"]
    t = tick or FmuTick()
    out: list[FmuVariable] = [
        FmuVariable(s["name"], "output", "continuous", "calculated", None, s["unit"],
                    f"{s['description']} (trim at operation.speed plus disturbance.{s['name']} "
                    "at the start)", "state") for s in states]
    # the loop as built: each array force through its lag is a continuous state after the
    # carriage's (model exchange's integrator takes it; co-simulation sets it exactly)
    forces = manifest["inputs"][1:] if controller.law == "axis" and t.firmware else []
    lagged = [{"name": f"actuator.{u['name']}", "unit": u["unit"]} for u in forces]
    out += [FmuVariable(a["name"], "local", "continuous", "calculated", None, a["unit"],
                        f"{u['description']} through the actuator's first-order lag "
                        "(actuator_lag; 0 at the start, the actuators at rest)", "state")
            for a, u in zip(lagged, forces, strict=True)]
    out += [FmuVariable(f"der({s['name']})", "local", "continuous", "calculated", None,
                        _per_second(s["unit"]), f"time derivative of {s['name']}", "derivative",
                        derivative=i + 1) for i, s in enumerate([*states, *lagged])]
    out += [FmuVariable(f"gap.{a}", "output", "continuous", "calculated", None, "m",
                        f"gap of array {a} (contact below track.min_gap)", "gap")
            for a in structure.array_names]
    out += [FmuVariable(u["name"], "output", "continuous", "calculated", None, u["unit"],
                        f"{u['description']}, as applied", "force") for u in manifest["inputs"]]
    prop = manifest["inputs"][0]
    out.append(FmuVariable(f"d{prop['name']}", "input", "continuous", None, 0.0, prop["unit"],
                           f"{prop['description']} added to the trim's (which balances the "
                           "drag at operation.speed)", "input"))
    if controller.inputs == "references":
        for s in Q_STATES:
            st = states[cv.STATE_INDEX[s]]
            out.append(FmuVariable(f"ref.{s}", "input", "continuous", None, 0.0, st["unit"],
                                   f"reference of {s} relative to its trim value", "cinput"))
    elif controller.inputs == "controls":
        out += [FmuVariable(c["name"], "input", "continuous", None, 0.0, c["unit"],
                            c["description"], "cinput") for c in manifest["controls"]]
    for e in manifest["parameter_vector"]:
        tunable = e["name"] in TUNABLE_PARAMETERS
        desc = e.get("description") or e["name"]
        out.append(FmuVariable(e["name"], "parameter", "tunable" if tunable else "fixed",
                               "exact", e["value"], e["unit"],
                               desc + ("" if tunable else " (fixed: enters the trim and gains, "
                                       "computed at initialization)"), "parameter"))
    for s in states:
        out.append(FmuVariable(f"disturbance.{s['name']}", "parameter", "fixed", "exact",
                               DISTURBANCE.get(s["name"], 0.0), s["unit"],
                               f"initial {s['name']} minus its trim value (default: "
                               f"{DISTURBANCE_DOC})", "disturbance"))
    if controller.law == "axis":
        fixed = " (fixed: set before initialization)"
        rate, delay, speed_gain, budget, lag, k_i = t.starts()
        out += [
            FmuVariable("tick_rate", "parameter", "fixed", "exact", rate, "1/s",
                        "the controller's tick rate [Hz]: the command computed from the state "
                        "sampled at each tick and held in between; 0: the continuous law"
                        + fixed,
                        "tick"),
            FmuVariable("delay_ticks", "parameter", "fixed", "exact", delay, "1",
                        "ticks from a command's computation to its application (a whole "
                        "number)" + fixed, "tick"),
            FmuVariable("speed_gain", "parameter", "fixed", "exact", speed_gain, "N*s/m",
                        "speed loop at the tick: F_prop = F_trim + dF_prop + speed_gain "
                        "(operation.speed - |(u, v, w)|)" + fixed, "tick"),
            FmuVariable("force_budget", "parameter", "fixed", "exact", budget, "N",
                        "each array's control force limited to this at the tick; 0: no "
                        "limit" + fixed, "tick"),
            FmuVariable("actuator_lag", "parameter", "fixed", "exact", lag, "s",
                        "each array's control force follows the command through a first-order "
                        "lag of this time constant (the tick only; 0: no lag)" + fixed, "tick"),
            FmuVariable("speed_integral", "parameter", "fixed", "exact", k_i,
                        "N/m", "speed loop's gain on the speed error's integral at the tick: "
                        "F_prop - speed_integral xi, xi += (|(u, v, w)| - operation.speed) / "
                        "tick_rate" + fixed, "tick")]
        # the tick law's gains (column-major): on the predicted lagged generalized forces, and
        # on those in flight, newest first, a 5 x 5 block per tick of delay up to the most
        na = len(Q_STATES)
        k_lag = _padded(t.k_lag, na * na)
        k_delay = _padded(t.k_delay, na * na * MAX_DELAY_TICKS)
        out += [FmuVariable(f"K_lag[{i % na + 1},{i // na + 1}]", "parameter", "fixed",
                            "exact", v, "1", "the tick law's gain from the predicted lagged "
                            f"generalized force {i // na + 1} to generalized force "
                            f"{i % na + 1} (w = u_gen - K_lag w_hat - K_delay w_flight)"
                            + fixed, "tick") for i, v in enumerate(k_lag)]
        out += [FmuVariable(f"K_delay[{i % na + 1},{i // na + 1}]", "parameter", "fixed",
                            "exact", v, "1", "the tick law's gain from generalized force "
                            f"{i // na % na + 1} computed {i // (na * na) + 1} tick(s) before "
                            f"to generalized force {i % na + 1} (columns past 5 delay_ticks "
                            "unused)" + fixed, "tick") for i, v in enumerate(k_delay)]
    if controller.law == "axis" and t.sense is not None:
        out += _sense_variables(t.sense)
    if kind in ("cs", "both"):
        out.append(FmuVariable("rk4_step", "parameter", "fixed", "exact", DEFAULT_INTERNAL_STEP,
                               "s", "internal RK4 step of co-simulation; every communication "
                               "step must be a whole multiple of it", "step"))
    return tuple(out)


def _sense_variables(sense: FmuSense) -> list[FmuVariable]:
    """The sensed loop's noise parameters and each reading as the last tick took it."""
    from maglevgen.exports.fmu_sense import NOISE_GENERATOR

    fixed = " (fixed: set before initialization)"
    out = [
        FmuVariable("noise_seed", "parameter", "fixed", "exact", 0.0, "1",
                    f"the readings' noise generator's seed, a whole number in [0, 2^53] "
                    f"({NOISE_GENERATOR})" + fixed, "sense"),
        FmuVariable("noise_scale", "parameter", "fixed", "exact", 1.0, "1",
                    "every reading's noise, bias and resolution times this (0: exact "
                    "readings)" + fixed, "sense")]
    for name, unit, noise, bias, step in zip(sense.names, sense.units, sense.noise, sense.bias,
                                             sense.resolution, strict=True):
        out += [
            FmuVariable(f"sensor.{name}.noise", "parameter", "fixed", "exact", noise, unit,
                        f"RMS of {name}'s white noise at the tick (after its anti-alias "
                        "filter; the rounding to its resolution adds its own)" + fixed,
                        "sense"),
            FmuVariable(f"sensor.{name}.bias", "parameter", "fixed", "exact", bias, unit,
                        f"{name}'s in-run bias, its sign drawn once per run" + fixed, "sense"),
            FmuVariable(f"sensor.{name}.resolution", "parameter", "fixed", "exact", step, unit,
                        f"{name} rounded to a multiple of this (0: not rounded)" + fixed,
                        "sense")]
    out += [FmuVariable(f"reading.{name}", "output", "discrete", "calculated", None, unit,
                        f"{name} as the firmware read it at the last tick (noise and rounding "
                        "included)", "reading")
            for name, unit in zip(sense.names, sense.units, strict=True)]
    return out


def _padded(values: tuple[float, ...], n: int) -> tuple[float, ...]:
    """``values`` followed by zeros up to ``n`` (refused when longer)."""
    if len(values) > n:
        raise ValueError(f"{len(values)} gains where at most {n} fit")
    return (*map(float, values), *(0.0,) * (n - len(values)))


def _per_second(unit: str) -> str:
    return {"m": "m/s", "rad": "rad/s", "m/s": "m/s^2", "rad/s": "rad/s^2"}.get(unit,
                                                                                  f"{unit}/s")


def build_model(manifest: dict, structure: Structure, controller: str, kind: str,
                tick: FmuTick | None = None) -> FmuModel:
    if kind not in KINDS:
        raise InputError(f"--kind {kind!r}: expected one of {KINDS}")
    controllers = fmu_controllers()
    if controller not in controllers:
        raise InputError(f"--controller {controller!r}: expected one of "
                         f"{', '.join(controllers)}")
    ctl = controllers[controller]
    return FmuModel(fmu_variables(manifest, structure, ctl, kind, tick), ctl, kind, manifest,
                    structure, None if tick is None else tick.sense)


def _xml_escape(text: str) -> str:
    return (text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
            .replace('"', "&quot;"))


def _c_comment(text: str) -> str:
    return text.replace("*/", "* /")


def _function(manifest: dict, name: str) -> dict:
    return next(f for f in manifest["functions"] if f["name"] == name)


def render_files(model: FmuModel, guid: str, fmi: str = DEFAULT_FMI,
                 matrix_gains: tuple[list[float], list[float]] | None = None,
                 verdict: str = "") -> dict[str, str]:
    """modelDescription.xml, the wrapper C, the sources' note and (FMI 3.0) the build
    description, as text, for FMI version ``fmi`` ("2" or "3"); ``matrix_gains``: the
    (K_pos, K_rate) constants (column-major) of a controller whose gains are "matrix";
    ``verdict``: the controller's verification, appended to the model's description."""
    from maglevgen.codegen.emit import template_env

    man = model.manifest
    pnames = [e["name"] for e in man["parameter_vector"]]
    used = ["maglev_dynamics", "maglev_trim", "maglev_lqr_gains", "maglev_allocation_matrix",
            "maglev_closed_loop_prepare", "maglev_closed_loop_prepared", "maglev_gaps",
            "maglev_coupled_control",
            *(("maglev_gap_reading", "maglev_imu_reading") if model.sense else ())]
    sizes = {k: max(_function(man, f)[k] for f in used)
             for k in ("sz_arg", "sz_res", "sz_iw", "sz_w")}
    version = FMI_VERSIONS[fmi]
    units = sorted({v.unit for v in model.variables})
    sources = [*man["files"]["c"], *(model.sense.c_sources if model.sense else ()), WRAPPER_C]
    groups = ("state", "derivative", "gap", "force", "input", "cinput", "parameter",
              "disturbance", "tick", "sense", "reading", "step")
    ctx = {
        "model": model, "variables": model.variables, "controller": model.controller,
        "kind": model.kind, "guid": guid, "version": __version__, "units": units,
        "sources": sources, "identifier": MODEL_IDENTIFIER,
        "first": {g: model.first(g) for g in groups},
        "count": {g: model.count(g) for g in groups},
        "n_vars": len(model.variables), "sizes": sizes, "nx": len(man["states"]),
        "n_prepared": _function(man, "maglev_closed_loop_prepared")["inputs"][1]["rows"],
        "n_alloc": _function(man, "maglev_allocation_matrix")["outputs"][0]["rows"],
        "axis_states": [cv.STATE_INDEX[s] for s in Q_STATES],
        "p_speed": pnames.index("operation.speed"),
        "p_min_gap": pnames.index("track.min_gap"),
        "structure_outputs": [i + 1 for i, v in enumerate(model.variables)
                              if v.causality == "output"],
        "derivatives": [i + 1 for i, v in enumerate(model.variables) if v.group == "derivative"],
        "initial_unknowns": [i + 1 for i, v in enumerate(model.variables)
                             if v.initial == "calculated"],
        "xml": _xml_escape, "c_comment": _c_comment,
        "params_source": man["params_source"], "params_sha256": man["params_sha256"],
        "overrides": man["overrides"],
        "error_names": sorted((v, k) for k, (v, _) in ERROR_CODES.items() if v),
        "fmi": version,
        "max_delay": MAX_DELAY_TICKS, "array_of_force": model.structure.array_of_force,
        "matrix_gains": matrix_gains, "verdict": verdict, "sense": model.sense,
        # FMI 3.0: the independent variable time (unit s) beside the list's units
        "units3": [(u, fmi3_base_unit(u)) for u in sorted({*units, "s"})],
    }
    env = template_env()
    outputs = [("modelDescription.xml", version.model_description), (WRAPPER_C, version.wrapper),
               ("README.txt", "fmu_sources_README.txt")]
    if version.build_description:
        outputs.append(("buildDescription.xml", version.build_description))
    return {name: env.get_template(f"{tpl}.j2").render(ctx) for name, tpl in outputs}


def fmi_headers(fmi: str = DEFAULT_FMI) -> Path:
    """The folder of the FMI headers (fmi2Functions.h, fmi3Functions.h) as shipped by FMPy
    (never copied here)."""
    version = FMI_VERSIONS[fmi]
    try:
        import fmpy
    except ImportError:
        raise InputError(f"the FMI {version.label} headers come from FMPy: pip install "
                         "'maglevgen[fmu]'") from None
    folder = Path(fmpy.__file__).parent / "c-code"
    if not (folder / version.header).is_file():
        raise InputError(f"FMPy at {folder.parent} has no c-code/{version.header} (FMI "
                         f"{version.label}): pip install 'fmpy>=0.3.20'")
    return folder


Progress = Callable[[str], None]


def _quiet(_: str) -> None:
    pass


def build_fmu(plant: Plant, kind: str = "both", controller: str | None = None,
              cache_dir: Path | None = None, cc: str | None = None,
              progress: Progress = _quiet, fmi: str = DEFAULT_FMI,
              loop: Loop | None = None,
              verdict: str | Callable[[], str] = "") -> bytes:
    """The .fmu archive's bytes for ``plant``'s carriage (generated C from the cached
    derivation), an FMI ``fmi`` ("2": 2.0, "3": 3.0) FMU; ``controller`` None: the controller
    the firmware embeds (``envelope.embedded_controller``); ``loop`` (a `Loop` of FMU_LOOPS,
    None: as a carriage flies, ``SENSED`` for the embedded controller where the file has
    [sensors], else ``FIRMWARE``): the start values of the tick's parameters, ``FIRMWARE``
    those of the plant's loop as built (`Plant.loop`) with the controller's `firmware_gains`
    at operation.speed (a "matrix" controller's K_pos and K_rate too) and the lagged array
    forces as states, ``SENSED`` that loop with the embedded controller's firmware sense tick
    on the noisy readings of [sensors] in the binary (`maglevgen.exports.fmu_sense`),
    ``CONTINUOUS`` zeros (the law at every derivative evaluation); ``cache_dir``,
    ``cc``: where and with what the FMU's own C is compiled; ``verdict``: the controller's
    verification (`maglevgen.build.EmbeddedVerdict.text`), in the model's description, or a
    callable that returns it (or raises), called once the options are checked and before the
    slow work."""
    from maglevgen.codegen.interface import FUNCTION_TABLE, GenerateOptions, render_interface
    from maglevgen.control.built_loop import Loop
    from maglevgen.infrastructure.cache import cache_root
    from maglevgen.runtime.compile import compile_object, compile_shared

    carriage = plant.carriage
    if controller is None:
        controller = carriage.params.envelope.embedded_controller
    if fmi not in FMI_VERSIONS:
        raise InputError(f"--fmi {fmi!r}: expected one of {tuple(FMI_VERSIONS)}")
    version = FMI_VERSIONS[fmi]
    embedded = carriage.params.envelope.embedded_controller
    if loop is None:
        loop = Loop(default_loop(carriage.params, controller))
    if not isinstance(loop, Loop) or loop not in FMU_LOOPS:
        raise ValueError(f"loop {loop!r}: the FMU's loops are {', '.join(FMU_LOOPS)} (a Loop)")
    if loop is Loop.SENSED and (controller != embedded or carriage.params.sensors is None):
        raise InputError(f"--loop sensed: the firmware's sense tick flies the embedded "
                         f"controller {embedded!r} on the readings of [sensors]"
                         + ("" if controller == embedded else f", not {controller!r}")
                         + ("" if carriage.params.sensors is not None
                            else "; the parameter file has no [sensors]"))
    headers = fmi_headers(fmi)  # before any slow work: FMPy missing is bad input
    _check_trim(plant)
    if callable(verdict):
        verdict = verdict()
    builtin = controller in fmu_controllers() and controller != EXTERNAL.name
    tick, design = (_tick(plant, controller if builtin else None)
                    if loop in (Loop.FIRMWARE, Loop.SENSED) else (FmuTick(), None))
    if loop is Loop.SENSED:
        from maglevgen.exports.fmu_sense import fmu_sense

        tick = replace(tick, sense=fmu_sense(plant))
    folder = plant.runtime_sources("double", cache_dir, progress)
    table = json.loads((folder / FUNCTION_TABLE).read_text())
    interface = render_interface(carriage, GenerateOptions("double", "runtime"), table)
    manifest = json.loads(interface["manifest.json"])
    model = build_model(manifest, carriage.structure, controller, kind, tick)
    # the GUID names the model's content: same carriage, controller and kind, same GUID
    guid = "{" + str(uuid.uuid5(uuid.NAMESPACE_URL, "maglevgen:" + json.dumps(
        [manifest["params_sha256"], manifest["overrides"], controller, kind, __version__,
         json.loads(json.dumps([v.__dict__ for v in model.variables]))]
        + ([] if fmi == "2" else [f"fmi{fmi}"])))) + "}"  # FMI 2.0's GUID as before
    matrix = (_matrix_gains(plant, controller, design)
              if model.controller.gains == "matrix" else None)
    files = render_files(model, guid, fmi, matrix, verdict)
    sources: dict[str, bytes] = {n: (folder / n).read_bytes() for n in sorted(
        p.name for p in folder.iterdir() if p.suffix in (".c", ".h"))}
    if tick.sense is not None:  # the firmware's sense tick, under names of its own
        sources.update((n, t.encode()) for n, t in tick.sense.sources)
    sources[WRAPPER_C] = files[WRAPPER_C].encode()
    sources["manifest.json"] = interface["manifest.json"].encode()
    sources["README.txt"] = files["README.txt"].encode()
    if version.build_description:
        sources["buildDescription.xml"] = files["buildDescription.xml"].encode()
    # the wrapper's C is rendered per carriage (start values): compiled in its own folder,
    # cached by content like the simulation library
    build = cache_root(cache_dir) / "fmu" / guid.strip("{}")
    build.mkdir(parents=True, exist_ok=True)
    for name, data in sources.items():
        path = build / name
        if not path.exists() or path.read_bytes() != data:
            path.write_bytes(data)
    # the carriage functions (most of the compile time) once per derivation, shared by every
    # FMU of it; each FMU links them with its own wrapper
    functions = compile_object(folder / "maglev_functions.c", cc=cc,
                               cache_dir=cache_root(cache_dir) / "fmu" / "lib", progress=progress)
    flags = ("-std=c99", "-O2", "-fPIC", "-shared", f"-I{headers}")
    lib = compile_shared([*sorted(p for p in build.glob("*.c") if p.name != "maglev_functions.c"),
                          functions], flags=flags, cc=cc,
                         cache_dir=cache_root(cache_dir) / "fmu" / "lib", progress=progress)
    return _zip({"modelDescription.xml": files["modelDescription.xml"].encode(),
                 f"binaries/{version.platform}/{MODEL_IDENTIFIER}.so": lib.read_bytes(),
                 **{f"sources/{n}": d for n, d in sources.items()}})


def _matrix_gains(plant: Plant, controller: str, design: LoopDesign | None = None
                  ) -> tuple[list[float], list[float]]:
    """``controller``'s (K_pos, K_rate) at operation.speed, column-major: the constants
    MATRIX_K_POS and MATRIX_K_RATE of the wrapper (templates/fmu_tick.c.j2); ``design`` (a
    `plant.LoopDesign`, the firmware loop's `firmware_gains`): its K_pos and K_rate instead of
    the continuous gains."""
    if design is None:
        K_pos, K_rate = _operation_point(plant).gains(controller)
    else:
        K_pos, K_rate = design.K_pos, design.K_rate
    return ([float(v) for v in K_pos.ravel(order="F")],
            [float(v) for v in K_rate.ravel(order="F")])


def _operation_point(plant: Plant) -> OperatingPoint:
    """The operating point at operation.speed (NoTrimError where it has no trim)."""
    from maglevgen.control.operating import Weights, operating_point

    return operating_point(plant.lib, plant.p, plant.params.operation.speed, plant.min_gap,
                           Weights.of(plant.params))


def _tick(plant: Plant, controller: str | None) -> tuple[FmuTick, LoopDesign | None]:
    """(the firmware loop's settings (`Plant.loop`) as the tick's start values,
    ``controller``'s gains on it (`simulate.firmware_gains` at operation.speed: the design at
    the tick where it has one, a `plant.LoopDesign`; None for ``controller`` None)): what
    `maglevgen simulate --loop firmware` flies."""
    from maglevgen.control.built_loop import loop_design

    loop = plant.loop
    design = None
    if controller is not None:
        design = loop_design(_operation_point(plant), controller, loop)

    def flat(K) -> tuple[float, ...]:
        return () if K is None else tuple(float(v) for v in K.ravel(order="F"))

    return FmuTick(loop, flat(None if design is None else design.K_lag),
                   flat(None if design is None else design.K_delay)), design


def _check_trim(plant: Plant) -> None:
    """No FMU whose initialization would fail at its start values: the trim at
    operation.speed, checked as `maglevgen simulate` checks it (NoTrimError, exit 2)."""
    from maglevgen.control.operating import checked_trim

    checked_trim(plant.lib, plant.p, plant.params.operation.speed, plant.min_gap)


def _zip(members: dict[str, bytes]) -> bytes:
    """A deterministic zip: fixed member order and time stamps."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for name in sorted(members):
            info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            zf.writestr(info, members[name])
    return buf.getvalue()
