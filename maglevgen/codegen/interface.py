"""The parameter-dependent C interface files (maglev.h, main.c, CMake example, README,
manifest) and what every generated file shares: options, banner, templates.

Kept apart from the code generator (maglevgen.codegen.generate) so that a build after a
parameter edit renders these from the cached function table without importing SymPy or CasADi.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING

from maglevgen.codegen.checks import entry_checks, error_defines
from maglevgen.codegen.emit import c_literal, template_env
from maglevgen.codegen.simulate_api import manifest_entries
from maglevgen.derive import conventions as cv
from maglevgen.derive.structure import input_names_of
from maglevgen.errors import InputError
from maglevgen.infrastructure.text import c_string
from maglevgen.params import entry_limits
from maglevgen.version import __version__

if TYPE_CHECKING:
    from maglevgen.carriage import DerivedCarriage

__all__ = ["C_NAME", "FUNCTION_TABLE", "INT_TYPES", "IO_DOCS", "SIMULATE_FILES", "SINGLE_FILE",
           "GenerateOptions", "banner", "interface_context", "render_interface", "template_env"]

C_NAME = "maglev_functions"
SIMULATE_FILES = ("maglev_simulate.c", "maglev_simulate.h")
SINGLE_FILE = "maglev.c"  # --single-file: the one translation unit
FUNCTION_TABLE = "functions.json"
PRECISIONS = ("double", "single")
PARAMETER_MODES = ("baked", "runtime")

# Units and meaning of the inputs/outputs of the generated functions (manifest and header).
IO_DOCS: dict[str, str] = {
    "x": "state, MAGLEV_X_* order",
    "u": "inputs, MAGLEV_U_* order",
    "p": "parameters, MAGLEV_P_* order",
    "v": "[m/s] forward speed",
    "accel": "[m/s^2] along-track acceleration (0: the constant-speed trim)",
    "xdot": "state derivative",
    "A": "df/dx", "B": "df/du",
    "x_trim": "trim state", "F_prop": "[N] propulsion force",
    "K": "per axis (row, MAGLEV_AXIS_* order): position gain, rate gain",
    "c_damping": "per axis: damping gain of the optimized damping controller",
    "k": "per axis stiffness [N/m or N*m/rad], MAGLEV_AXIS_* order",
    "m": "per axis mass or inertia [kg or kg*m^2], MAGLEV_AXIS_* order",
    "u_gen": "generalized forces/moments, MAGLEV_AXIS_* order",
    "F_arrays": "[N] array control forces, MAGLEV_U_* order from index 1",
    "dt": "[s] step",
    "K_pos": "position gains (5 x 5, column-major; diagonal for the per-axis designs)",
    "K_rate": "rate gains (5 x 5, column-major; diagonal for the per-axis designs)",
    "a_ref": "per axis reference positions (y, z, phi, theta, psi)",
    "x_next": "state after the step", "x0": "state",
    "gaps": "[m] gap of each array face's closest corner, in the parameter file's array order",
    "T": "minimum-norm allocation matrix (array forces x 5), from maglev_allocation_matrix",
    "lift": "[N] lift of each array, in the parameter file's array order",
    "drag": "[N] drag of each array, in the parameter file's array order",
    "K_magnetic": "magnetic stiffness K_st0 (5 x 5, MAGLEV_AXIS_* order, column-major)",
    "K_other": "stiffness of the gravity and propulsion moments (5 x 5, column-major)",
    "E": "control effectiveness (5 x array forces, column-major): u_gen = E F_arrays",
    # maglev_stiffness_parts' outputs: K_magnetic + K_other = their sum
    "gap_slope": "stiffness part: eq 3's gap slope -2k (5 x 5, column-major)",
    "rotating_arms": "stiffness part: the rotation of the moment arms (5 x 5, column-major)",
    "tilt": "stiffness part: the tilt across the face (5 x 5; zero for the point force)",
    "gravity": "stiffness part: gravity's moment of the CG offset (5 x 5, column-major)",
    "propulsion": "stiffness part: the propulsion force's moment (5 x 5, column-major)",
    # the sensors' readings (maglev_gap_reading, maglev_imu_reading)
    "point": "[m] the sensor's point, body axes, relative to O",
    "normal": "unit normal of the sensor's array face, body axes",
    "nominal_gap": "[m] that face's gap at the design pose",
    "reading": "[m] the gap the sensor reads along its turned normal",
    "H": "dreading/dx (1 x 12)",
    "gyro": "[rad/s] body rates (p, q, r) the gyro reads",
    "specific_force": "[m/s^2] what the accelerometer at the point reads, body axes",
    "H_x": "d(gyro, specific_force)/dx (6 x 12, column-major)",
    "H_xdot": "d(gyro, specific_force)/dxdot (6 x 12, column-major)",
}


INT_TYPES = {"int64": "long long int", "int32": "int"}  # --int: the C type of casadi_int


@dataclass(frozen=True)
class GenerateOptions:
    precision: str = "double"
    parameters: str = "baked"
    int_type: str = "int64"
    single_file: bool = False  # one translation unit (maglev.c) instead of two .c files

    def __post_init__(self) -> None:
        if self.int_type not in INT_TYPES:
            raise InputError(f"--int {self.int_type!r}: expected one of {tuple(INT_TYPES)}")
        if self.precision not in PRECISIONS:
            raise InputError(f"--precision {self.precision!r}: expected one of {PRECISIONS}")
        if self.parameters not in PARAMETER_MODES:
            raise InputError(f"--parameters {self.parameters!r}: expected one of "
                             f"{PARAMETER_MODES}")

    @property
    def command(self) -> str:
        extra = "" if self.int_type == "int64" else f" --int {self.int_type}"
        extra += " --single-file" if self.single_file else ""
        return (f"maglevgen generate --precision {self.precision} --parameters "
                f"{self.parameters}{extra}")


def _macro(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9]", "_", name).upper()


def _checked_range(name: str) -> str:
    """A parameter's range that the run-time-parameter C checks p against, for maglev.h."""

    lo, hi = entry_limits(name)
    return f"; checked range [{lo!r}, {hi!r}]"


def banner(opts: GenerateOptions, params_sha256: str | None) -> str:
    """The first line of every generated file: what made it and from what.

    With run-time parameters the C does not depend on parameter values, so its banner names no
    parameter file and the same derivation gives byte-identical sources for any parameters.
    """
    source = ("the carriage derivation; parameters are the run-time input p"
              if params_sha256 is None else f"parameter file sha256 {params_sha256}")
    return (f"Generated by maglevgen {__version__} (`{opts.command}`) from {source}. "
            "Do not edit: regenerate.")




def c_sources(opts: GenerateOptions) -> list[str]:
    """The .c files of a generation (what CMake and the manifest list)."""
    return [SINGLE_FILE] if opts.single_file else [f"{C_NAME}.c", "maglev_simulate.c"]


def render_interface(carriage: DerivedCarriage, opts: GenerateOptions, table: list[dict],
                     speed_range: tuple[float, float] | None = None,
                     example: dict | None = None) -> dict[str, str]:
    """The parameter-dependent files: maglev.h, main.c, CMakeLists.txt, README.md, manifest.
    ``speed_range``: the baked trim's [v_min, v_max] (None: v > 0); ``example``: the
    controller main.c runs (`maglevgen.analyses.verdicts.generate_example`: the embedded
    controller's gains at a verified speed and the verdict there; None: main.c only trims)."""
    ctx = interface_context(carriage, opts, table, speed_range)
    if example is not None:
        ctx = {**ctx, **_example_context(example, ctx)}
    env = template_env()
    files = {name: env.get_template(f"{name}.j2").render(ctx)
             for name in ("maglev.h", "main.c", "CMakeLists.txt", "README.md")}
    manifest = _manifest(carriage, opts, table, ctx["params"], ctx["inputs"])
    if speed_range is not None:
        manifest["trim_speed_range"] = [float(v) for v in speed_range]
    files["manifest.json"] = json.dumps(manifest, indent=2) + "\n"
    return files


def _example_context(example: dict, ctx: dict) -> dict:
    """main.c's example: the speed, the gains, and its two printed lines as C strings
    (`c_string`: the one escaping of text reaching C)."""
    seconds = ctx["n_steps"] * float(ctx["dt"])
    what = (f"maglevgen example: the embedded controller {example['controller']} "
            f"({example['title']}), its gains at {example['speed']:.4g} m/s, in the closed loop "
            f"of maglev_rk4_step for {seconds:g} s from the default disturbance")
    return {"speed": c_literal(example["speed"], "double"),
            "example": {**example, "what": c_string(what, 72),
                        "verdict_c": c_string(example["verdict"], 72)}}


def interface_context(carriage: DerivedCarriage, opts: GenerateOptions, table: list[dict],
                      speed_range: tuple[float, float] | None = None) -> dict:
    """What the interface templates (maglev.h.j2 and its neighbours) read: the functions of
    ``table`` with their checks, the states, inputs, axes and parameters."""
    header_banner = banner(opts, carriage.loaded.sha256)
    runtime = opts.parameters == "runtime"
    params = [{"name": e.name, "macro": _macro(e.name), "unit": e.unit or "1",
               "description": e.description, "value": e.value, "value_repr": repr(e.value),
               "value_c": c_literal(e.value, opts.precision),
               "checked_range": _checked_range(e.name) if runtime else ""}
              for e in carriage.entries]
    work = {f["name"]: (f["sz_arg"], f["sz_res"], f["sz_iw"], f["sz_w"]) for f in table}
    inputs = [cv.PROPULSION] + [
        cv.Signal(n, "N", f"control force of array {n[3:]} along body {n[2]}")
        for n in input_names_of(carriage.structure)[1:]]
    ctx = {
        "banner": header_banner, "precision": opts.precision, "parameters": opts.parameters,
        "real_type": "float" if opts.precision == "single" else "double",
        "int_type": INT_TYPES[opts.int_type],
        "states": cv.STATES, "inputs": inputs, "controls": cv.CONTROLS, "params": params,
        "functions": [{**f, "checks": entry_checks(f, runtime, work)} for f in table],
        "speed": c_literal(carriage.params.operation.speed, "double"),
        "dt": "1e-3", "n_steps": 2000, "error_defines": error_defines(), "example": None,
        "c_sources": c_sources(opts),
        "speed_range": None if speed_range is None
        else [c_literal(v, "double") for v in speed_range],
    }
    return ctx


def _manifest(carriage: DerivedCarriage, opts: GenerateOptions, table: list[dict],
              params: list[dict],
              inputs: list) -> dict:
    return {
        "generated_by": f"maglevgen {__version__}",
        "command": opts.command,
        "precision": opts.precision,
        "parameters": opts.parameters,
        "casadi_int": INT_TYPES[opts.int_type],
        "params_sha256": carriage.loaded.sha256,
        "params_source": Path(carriage.loaded.source).name,
        "overrides": list(carriage.loaded.overrides),
        "versions": {"maglevgen": __version__,
                     **{lib: metadata.version(lib) for lib in ("casadi", "sympy", "numpy")}},
        "files": {"c": c_sources(opts), "casadi_header": f"{C_NAME}.h",
                  "header": "maglev.h", "simulate_header": "maglev_simulate.h"},
        "states": [{"name": s.name, "unit": s.unit, "description": s.description}
                   for s in cv.STATES],
        "inputs": [{"name": s.name, "unit": s.unit, "description": s.description}
                   for s in inputs],
        "controls": [{"name": s.name, "unit": s.unit, "description": s.description}
                     for s in cv.CONTROLS],
        "parameter_vector": [{"name": p["name"], "unit": p["unit"],
                              "description": p["description"], "value": p["value"]}
                             for p in params],
        "functions": table,
        # the simulation loop's C API (maglev_simulate.h), as the header declares it
        "simulate_functions": manifest_entries(opts.parameters),
    }
