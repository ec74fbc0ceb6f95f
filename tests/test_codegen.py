"""Generated C against the SymPy model and the 50-digit LQR; firmware rules; determinism."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
from independent_reference import contact_gaps
from numbers_in_text import differences

from maglevgen.analyses.envelope import speed_range
from maglevgen.carriage import DerivedCarriage
from maglevgen.codegen.generate import GenerateOptions, render, write_output
from maglevgen.control.carriage_plant import Plant
from maglevgen.control.symbolic_reference import axis_plants
from maglevgen.derive import conventions as cv
from maglevgen.derive.riccati import lqr_gain_mp
from maglevgen.params import load_params
from maglevgen.runtime.compile import compile_shared
from maglevgen.runtime.ffi import GeneratedLibrary

REPO = Path(__file__).resolve().parents[1]
WARN = ["-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Werror"]
SINGLE_WARN = ["-Wdouble-promotion", "-Wfloat-conversion"]
TOL = {"double": 1e-12, "single": 1e-5}
A_STATES = [cv.STATE_INDEX[s] for s in cv.Q_STATES]  # the axis coordinates (y, z, phi, theta, psi)


@pytest.fixture(scope="module", params=["double", "single"])
def runtime_lib(request, carriage: DerivedCarriage, tmp_path_factory, rendered) -> tuple[str, Path]:
    out = tmp_path_factory.mktemp(f"gen_{request.param}")
    write_output(rendered(carriage, GenerateOptions(request.param, "runtime")), out)
    lib = compile_shared([out / "maglev_functions.c"])
    return request.param, lib


def _ext(runtime_lib: tuple[str, Path], name: str):
    precision, lib = runtime_lib
    fn = GeneratedLibrary(lib, precision).function(name)
    return lambda *a: [o.squeeze() if o.size == 1 else o for o in fn(*a)]


@pytest.mark.slow  # every function compiled as a CasADi external
@pytest.mark.needs_cc
def test_casadi_external_loads_every_function(carriage: DerivedCarriage, tmp_path: Path,
                                              rendered) -> None:
    out = tmp_path / "gen"
    write_output(rendered(carriage, GenerateOptions("double", "runtime")), out)
    lib = compile_shared([out / "maglev_functions.c"])
    manifest = json.loads((out / "manifest.json").read_text())
    ours = GeneratedLibrary(lib, "double")
    rng = np.random.default_rng(0)
    for f in manifest["functions"]:
        ext = ca.external(f["name"], str(lib))
        args = [rng.normal(size=(io["rows"], io["cols"])) for io in f["inputs"]]
        if f["inputs"][-1]["name"] == "p":  # p comes last (the prepared loop takes c instead)
            args[-1] = carriage.p
        if f["inputs"][0]["name"] == "v":
            args[0] = np.array([[20.0]])  # a speed with a trim, so the Newton solve converges
        if f["name"] == "maglev_axis_gains":  # physical plants (m > 0): NaN gains are an error
            args[0], args[1] = np.abs(args[0]) + 1, np.abs(args[1]) + 1
        names = [io["name"] for io in f["inputs"]]
        if "dt" in names:  # a 1 ms step near the design pose: a random O(1) s step from a
            # random O(1) pose overflows to inf, which every generated function now reports as
            # MAGLEV_ERR_NONFINITE_OUTPUT (issue 40) instead of returning it
            args[names.index("dt")] = np.array([[1e-3]])
            x = rng.normal(scale=1e-4, size=args[0].shape)
            x[6] += 20.0
            args[names.index("x")] = x
        got_ext = ext.call([ca.DM(a) for a in args])
        for a, b in zip(got_ext, ours.function(f["name"])(*args), strict=True):
            np.testing.assert_allclose(np.array(a), b, rtol=1e-15, equal_nan=True)


def test_dynamics_matches_sympy_model(runtime_lib, carriage: DerivedCarriage) -> None:
    precision, _ = runtime_lib
    f = _ext(runtime_lib, "maglev_dynamics")
    rng = np.random.default_rng(11)
    n = 1000
    X = rng.normal(scale=[1, 2e-3, 2e-3, .01, .01, .01, 2, .05, .05, .05, .05, .05], size=(n, 12))
    # in double, attitudes that reach both branches of the distributed law's sinhc, L and L'
    # (the series near trim, the closed forms past SERIES_BELOW: |k beta N p| > 0.25 from
    # about 30 mrad)
    if precision == "double":  # float32 at 0.1 rad (faces in contact) errs by 5e-4 here
        X[:, 3:6] *= np.resize([0.2, 3.0, 10.0], n)[:, None]
    X[:, 6] += 20.0
    X[:, 2] += 3e-5
    U = rng.normal(scale=5.0, size=(n, carriage.model.u.shape[0]))
    U[:, 0] += 70.0
    # The reference is the double-precision model at the inputs as the library sees them
    # (rounded to its precision); errors are measured against each component's typical size,
    # since a component that crosses zero has no meaningful relative error in float32.
    real = np.float32 if precision == "single" else np.float64
    p = carriage.p.astype(real).astype(float)
    refs, gots = [], []
    for x, u in zip(X.astype(real).astype(float), U.astype(real).astype(float), strict=True):
        refs.append(carriage.functions.xdot(x, u, p))
        gots.append(np.array(f(x, u, p)[0], dtype=float).ravel())
    refs, gots = np.array(refs), np.array(gots)
    worst = float(np.max(np.abs(gots - refs) / np.mean(np.abs(refs), axis=0)))
    assert worst < TOL[precision], worst


@pytest.mark.parametrize("speed", [8.0, 20.0, 45.0])
@pytest.mark.parametrize("override", [(), ("vehicle.mass=8.0",), ("control.input_weight=0.01",
                                                                  "vehicle.inertia_cg.yy=0.42")])
def test_lqr_gains_match_50_digit_reference(runtime_lib, speed: float, override) -> None:
    precision, _ = runtime_lib
    car = DerivedCarriage(load_params(overrides=list(override)))
    (q1, q2), r = car.params.control.state_weights, car.params.control.input_weight
    K, _c = _ext(runtime_lib, "maglev_lqr_gains")(speed, car.p)
    K = np.array(K)
    for i, (_axis, k, m) in enumerate(axis_plants(car, car.trim(speed))):
        ref = np.array([float(v) for v in lqr_gain_mp(k, m, q1, q2, r)])
        rel = np.max(np.abs(K[i] - ref) / np.abs(ref))
        assert rel < TOL[precision], (i, rel)


def test_trim_in_c_matches_python(runtime_lib, carriage: DerivedCarriage) -> None:
    precision, _ = runtime_lib
    for v in (6.0, 20.0, 80.0):
        x, fp = _ext(runtime_lib, "maglev_trim")(v, carriage.p)
        tr = carriage.trim(v)
        tol = 1e-9 if precision == "double" else 1e-4
        np.testing.assert_allclose(np.array(x).ravel(), tr.x, atol=tol * 20)
        assert float(fp) == pytest.approx(tr.u[0], rel=tol)


def test_allocation_is_pseudo_inverse(runtime_lib, carriage: DerivedCarriage) -> None:
    from maglevgen.control.symbolic_reference import allocation_matrix

    precision, _ = runtime_lib
    T = allocation_matrix(carriage)
    f = _ext(runtime_lib, "maglev_allocate")
    for u in np.random.default_rng(2).normal(size=(20, 5)):
        np.testing.assert_allclose(np.array(f(u, carriage.p)[0]).ravel(), T @ u,
                                   rtol=TOL[precision] * 10, atol=TOL[precision] * 10)


def test_gain_schedule_pieces_match_the_python_derivation(runtime_lib, carriage: DerivedCarriage,
                                                          trim) -> None:
    """axis_plants (trim in C) against the SymPy/scipy trim; axis_gains against the 50-digit
    Riccati solution and the damping sqrt(k m); the per-tick controllers against numpy."""
    precision, _ = runtime_lib
    tol = TOL[precision] * 10
    k, m = (np.array(a, dtype=float).ravel()
            for a in _ext(runtime_lib, "maglev_axis_plants")(trim.speed, carriage.p))
    plants = axis_plants(carriage, trim)
    np.testing.assert_allclose(k, [pk for _, pk, _ in plants], rtol=tol)
    np.testing.assert_allclose(m, [pm for _, _, pm in plants], rtol=tol)
    K, c = (np.array(a, dtype=float) for a in _ext(runtime_lib, "maglev_axis_gains")(
        [pk for _, pk, _ in plants], [pm for _, _, pm in plants], carriage.p))
    for i, (_axis, pk, pm) in enumerate(plants):
        ref = np.array([float(v) for v in lqr_gain_mp(pk, pm, 1, 1, 1)])
        np.testing.assert_allclose(K[i], ref, rtol=tol)
        assert c.ravel()[i] == pytest.approx(np.sqrt(max(pk, 0.0) * pm), rel=tol)
    rng = np.random.default_rng(5)
    idx = [1, 2, 3, 4, 5]
    for _ in range(10):
        x = trim.x + rng.normal(scale=1e-3, size=12)
        a_ref = trim.x[idx]
        rates = carriage.functions.kin(x).ravel()[idx]
        u_lqr = np.array(_ext(runtime_lib, "maglev_lqr_control")(x, K, a_ref, carriage.p)[0])
        np.testing.assert_allclose(u_lqr.ravel(), -(K[:, 0] * (x[idx] - a_ref) + K[:, 1] * rates),
                                   rtol=tol, atol=tol * np.max(np.abs(K)) * 1e-3)
        u_d = np.array(_ext(runtime_lib, "maglev_damping_control")(x, c, carriage.p)[0])
        np.testing.assert_allclose(u_d.ravel(), -c.ravel() * rates, rtol=tol,
                                   atol=tol * np.max(c) * 1e-3)


@pytest.fixture(scope="module")
def baked(carriage: DerivedCarriage, tmp_path_factory, rendered) -> dict[str, Path]:
    out = {}
    for precision in ("double", "single"):
        d = tmp_path_factory.mktemp(f"baked_{precision}")
        write_output(rendered(carriage, GenerateOptions(precision, "baked"),
                              speed_range(carriage)), d)
        out[precision] = d
    return out


def _gain_matrices(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Full 5 x 5 gains: a dominant diagonal (per-axis magnitudes) and cross-coupling terms,
    so a transposed or row/column-swapped gain layout in the C shows."""
    K_pos = np.diag(rng.uniform(1e3, 1e4, 5)) + rng.uniform(-300, 300, (5, 5))
    K_rate = np.diag(rng.uniform(10, 400, 5)) + rng.uniform(-20, 20, (5, 5))
    return K_pos, K_rate


def _closed_loop_reference(carriage: DerivedCarriage, f_prop: float, k_pos: np.ndarray,
                           k_rate: np.ndarray, a_ref: np.ndarray):
    """x -> (xdot, u) of the closed loop on the SymPy model (derive.numeric), with the feedback
    u = (F_prop, T(-K_pos (a - a_ref) - K_rate a')) in numpy and T = pinv(E)."""
    from maglevgen.control.symbolic_reference import effectiveness

    idx = A_STATES
    T = np.linalg.pinv(effectiveness(carriage))
    n_u = carriage.model.u.shape[0]

    def f(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rates = carriage.functions.xdot(x, np.zeros(n_u), carriage.p)[idx]  # kinematics only
        u = np.concatenate([[f_prop], T @ -(k_pos @ (x[idx] - a_ref) + k_rate @ rates)])
        return carriage.functions.xdot(x, u, carriage.p), u

    return f


def _double_library(carriage: DerivedCarriage, parameters: str, tmp_path: Path,
                    rendered) -> GeneratedLibrary:
    """The double-precision generated C (run-time or baked parameters), compiled."""
    write_output(rendered(carriage, GenerateOptions("double", parameters),
                          speed_range(carriage)), tmp_path / "gen")
    return GeneratedLibrary(compile_shared([tmp_path / "gen" / "maglev_functions.c"]),
                            "double")


@pytest.mark.needs_cc
@pytest.mark.parametrize("parameters", ["runtime", "baked"])
def test_prepared_closed_loop_matches_the_sympy_model(carriage: DerivedCarriage, trim,
                                                      parameters: str, tmp_path: Path,
                                                      rendered) -> None:
    """maglev_closed_loop_prepare once, then maglev_closed_loop_prepared at many states (what
    maglev_simulate does): xdot, u and the gaps against the SymPy model with the feedback in
    numpy, T = pinv(E). The attitudes reach both branches of the distributed law's sinhc, L
    and L' (the series near trim, the closed forms past SERIES_BELOW)."""
    from maglevgen.control.symbolic_reference import effectiveness

    lib = _double_library(carriage, parameters, tmp_path, rendered)
    rng = np.random.default_rng(8)
    k_pos, k_rate = _gain_matrices(rng)
    a_ref, f_prop = trim.x[A_STATES], trim.u[0]
    reference = _closed_loop_reference(carriage, f_prop, k_pos, k_rate, a_ref)
    T = np.linalg.pinv(effectiveness(carriage))
    extra = (carriage.p,) if parameters == "runtime" else ()
    (c,) = lib.function("maglev_closed_loop_prepare")(f_prop, k_pos, k_rate, a_ref, T, *extra)
    prepared = lib.function("maglev_closed_loop_prepared")
    for k in range(21):
        tilt = (2e-3, 3e-2, 1e-1)[k % 3]
        x = trim.x + rng.normal(scale=[.1, 1e-3, 1e-3, tilt, tilt, tilt, .5, .01, .01, .01, .01,
                                       .01])
        xdot, u, gaps = (np.ravel(a) for a in prepared(x, c))
        xdot_ref, u_ref = reference(x)
        np.testing.assert_allclose(u, u_ref, rtol=1e-10, atol=1e-9)
        np.testing.assert_allclose(xdot, xdot_ref, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(gaps, contact_gaps(carriage.params, x[[1, 2, 3, 4, 5]]),
                                   rtol=1e-12, atol=1e-15)


@pytest.mark.needs_cc
@pytest.mark.parametrize("parameters", ["runtime", "baked"])
def test_rk4_step_matches_a_numpy_rk4_on_the_sympy_model(carriage: DerivedCarriage, trim,
                                                         parameters: str, tmp_path: Path,
                                                         rendered) -> None:
    """maglev_rk4_step (the MX step calling maglev_closed_loop four times; the baked one
    rebuilt around the baked right-hand side) against RK4 written out in numpy."""
    step = _double_library(carriage, parameters, tmp_path, rendered).function(
        "maglev_rk4_step")
    rng = np.random.default_rng(5)
    k_pos, k_rate = _gain_matrices(rng)
    a_ref, f_prop, dt = trim.x[A_STATES], trim.u[0], 2e-3
    f = _closed_loop_reference(carriage, f_prop, k_pos, k_rate, a_ref)
    extra = (carriage.p,) if parameters == "runtime" else ()
    for _ in range(5):
        x = trim.x + rng.normal(scale=[0, 1e-3, 1e-3, 2e-3, 2e-3, 2e-3, 0, .01, .01, .01, .01,
                                       .01])
        x_next, u = step(x, dt, f_prop, k_pos, k_rate, a_ref, *extra)
        k1, u0 = f(x)  # classical RK4 written out
        k2 = f(x + dt / 2 * k1)[0]
        k3 = f(x + dt / 2 * k2)[0]
        k4 = f(x + dt * k3)[0]
        np.testing.assert_allclose(np.ravel(x_next), x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4),
                                   rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(np.ravel(u), u0, rtol=1e-10, atol=1e-9)


@pytest.mark.parametrize("cc", [pytest.param(c, marks=pytest.mark.needs_cc(c))
                                for c in ("gcc", "clang")])
@pytest.mark.parametrize("precision", ["double", "single"])
def test_compiles_warning_free(baked: dict[str, Path], cc: str, precision: str,
                               tmp_path: Path) -> None:
    flags = WARN + (SINGLE_WARN if precision == "single" else [])
    d = baked[precision]
    for src in ("maglev_functions.c", "maglev_simulate.c", "main.c"):
        proc = subprocess.run([cc, *flags, "-c", str(d / src), "-o", str(tmp_path / "o.o")],
                              capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr


@pytest.mark.needs_cc("gcc")
def test_no_writable_globals_and_only_maglev_symbols(baked: dict[str, Path],
                                                    tmp_path: Path) -> None:
    obj = tmp_path / "f.o"
    subprocess.run(["gcc", "-std=c99", "-O2", "-c", str(baked["double"] / "maglev_functions.c"),
                    "-o", str(obj)], check=True)
    syms = subprocess.run(["nm", "--defined-only", str(obj)], capture_output=True, text=True,
                          check=True).stdout.split("\n")
    for line in filter(None, syms):
        kind, name = line.split()[-2:]
        assert kind not in "DBdbCc", f"writable data symbol {name}"
        if kind.isupper():
            assert name.startswith("maglev_"), name
    undefined = subprocess.run(["nm", "--undefined-only", str(obj)], capture_output=True,
                               text=True, check=True).stdout.split()
    for alloc in ("malloc", "calloc", "realloc", "free"):
        assert alloc not in undefined, f"heap allocation: {alloc}"
    sz = subprocess.run(["size", "-A", str(obj)], capture_output=True, text=True).stdout
    for section in (".data", ".bss"):
        for line in sz.splitlines():
            if line.startswith(section + " "):
                assert int(line.split()[1]) == 0, line


@pytest.mark.slow  # compiles the whole generated C (tens of seconds on a loaded machine)
@pytest.mark.needs_cc("gcc")
def test_generate_example_flies_the_embedded_controller_where_verified(
        carriage: DerivedCarriage, rendered, sim_lib, tmp_path: Path) -> None:
    """`maglevgen generate`'s main.c with the embedded controller's example: it says what it
    runs (the controller, the speed inside the envelope) and the verdict there, and its run
    from the default disturbance ends within 1 um / 1 urad of the trim, as a closed loop
    built here from the same gains (numpy eigenvalues of the C Jacobians with the allocation,
    `OperatingPoint.reduced_closed_loop`) decaying at its slowest rate predicts."""
    from maglevgen.analyses.verdicts import generate_example
    from maglevgen.control.operating import Weights, operating_point

    example = generate_example(Plant(carriage, sim_lib))
    v_min, v_max = Plant(carriage, sim_lib).speed_range
    name = carriage.params.envelope.embedded_controller
    assert example["controller"] == name and v_min <= example["speed"] <= v_max
    op = operating_point(sim_lib, carriage.p, example["speed"], carriage.params.track.min_gap,
                         Weights.of(carriage.params))
    rate = -np.max(np.linalg.eigvals(op.reduced_closed_loop(name)).real)
    assert example["verified"] == (rate >= carriage.params.control.spec.min_decay_rate)
    # the fixture's render (the same functions), its interface files rendered with the example
    from maglevgen.codegen.interface import render_interface

    opts = GenerateOptions("double", "baked")
    files = dict(rendered(carriage, opts, speed_range(carriage)))
    table = json.loads(files["manifest.json"])["functions"]
    files.update(render_interface(carriage, opts, table, speed_range(carriage), example))
    src = tmp_path / "gen"
    write_output(files, src)
    exe = tmp_path / "ex"
    subprocess.run(["gcc", "-std=c99", "-O0", "-o", str(exe), *(str(src / f) for f in (
        "main.c", "maglev_functions.c", "maglev_simulate.c")), "-lm"], check=True)
    out = subprocess.run([str(exe)], capture_output=True, text=True, check=True).stdout
    lines = out.splitlines()
    assert f"the embedded controller {name} " in lines[0]
    assert f"{example['speed']:.4g} m/s" in lines[0]
    assert lines[1] == f"verdict: {example['verdict']}"
    devs = [float(ln.split()[-1]) for ln in lines[3:8]]
    # 2 s at the slowest decay from a few mm / mrad: far below 1e-6 (the speed drifts slowly)
    assert rate * 2.0 > np.log(1e-3 / 1e-6)
    assert all(abs(d) < 1e-6 for d in devs), out


@pytest.mark.needs_cc("cmake")
def test_example_builds_with_cmake_and_runs(baked: dict[str, Path], tmp_path: Path) -> None:
    build = tmp_path / "build"
    subprocess.run(["cmake", "-S", str(baked["double"]), "-B", str(build)], check=True,
                   capture_output=True)
    subprocess.run(["cmake", "--build", str(build)], check=True, capture_output=True)
    out = subprocess.run([str(build / "maglev_example")], capture_output=True, text=True,
                         check=True).stdout
    values = [float(line.split("=")[1]) for line in out.splitlines() if "x[" in line]
    assert len(values) == 12 and all(np.isfinite(values))
    assert abs(values[2]) < 0.01  # the trim's heave, near the nominal gap


@pytest.mark.slow  # the library compiled under ASan/UBSan
@pytest.mark.needs_cc("gcc")
def test_sanitizers_on_random_inputs(baked: dict[str, Path], tmp_path: Path) -> None:
    """ASan + UBSan on a driver that calls every function with random inputs."""
    d = baked["double"]
    manifest = json.loads((d / "manifest.json").read_text())
    calls = []
    for f in manifest["functions"]:
        nin = [io["rows"] * io["cols"] for io in f["inputs"]]
        nout = [io["rows"] * io["cols"] for io in f["outputs"]]
        body = [f"  {{ /* {f['name']} */"]
        for i, n in enumerate(nin):
            body.append(f"    double in{i}[{n}]; fill(in{i}, {n});")
        for i, n in enumerate(nout):
            body.append(f"    double out{i}[{n}];")
        body.append(f"    const double* arg[{f['sz_arg']}]; double* res[{f['sz_res']}];")
        body += [f"    arg[{i}] = in{i};" for i in range(len(nin))]
        body += [f"    res[{i}] = out{i};" for i in range(len(nout))]
        body.append(f"    long long iw[{f['sz_iw'] + 1}]; double w[{f['sz_w'] + 1}];")
        body.append(f"    (void){f['name']}(arg, res, (maglev_int*)iw, w, 0); }}")
        calls.append("\n".join(body))
    driver = tmp_path / "driver.c"
    driver.write_text(
        '#include <stdlib.h>\n#include "maglev.h"\n'
        "static void fill(double* x, int n) { for (int i = 0; i < n; ++i) "
        "x[i] = (double)rand() / RAND_MAX - 0.5; }\n"
        "int main(void) { srand(1); for (int rep = 0; rep < 50; ++rep) {\n"
        + "\n".join(calls) + "\n} return 0; }\n")
    exe = tmp_path / "driver"
    cmd = ["gcc", "-std=c99", "-g", "-O1", "-fsanitize=address,undefined",
           "-fno-sanitize-recover=all", "-I", str(d), str(driver), str(d / "maglev_functions.c"),
           "-o", str(exe), "-lm"]
    subprocess.run(cmd, check=True, capture_output=True)
    proc = subprocess.run([str(exe)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-2000:]


# Library versions printed into the generated files (SymPy codegen leaves its version header
# out of comparisons the same way): the CasADi banner, the version function's body and the
# manifest's "versions" block. maglevgen's own version stays in the comparison.
_VERSION_LINES = (
    (re.compile(r"CasADi \d+\.\d+\.\d+\S*"), "CasADi <version>"),
    (re.compile(r"^(\s*\*(?:major|minor|patch) = )\d+;$", re.M), r"\1<n>;"),
)


#: a number of generated/ against a fresh generation: far below any change of the model or
#: of a design, above the spread of LAPACK builds (1e-12 relative seen in main.c's gains)
GENERATED_RTOL = 1e-9


def _without_version_banners(name: str, data: bytes) -> tuple[bytes, dict]:
    """The file with the library versions blanked out, and the versions it recorded."""
    text = data.decode()
    if name == "manifest.json":
        manifest = json.loads(text)
        versions = manifest.pop("versions", {})
        versions.pop("maglevgen", None)
        return json.dumps(manifest, indent=2).encode(), versions
    for pattern, repl in _VERSION_LINES:
        text = pattern.sub(repl, text)
    return text.encode(), {}


@pytest.mark.slow
def test_generated_folder_is_current(tmp_path: Path) -> None:
    """generated/ equals a fresh generation from another working folder, and two fresh
    generations under two hash seeds equal each other byte for byte.

    Not a numeric check (regenerating generated/ would accept a wrong physics): it checks that
    the committed output is current and deterministic. Library version banners are left out of
    the comparison; when the versions differ the failure says so, as a changed CasADi may
    change its C output with no change in the numbers. Against the committed folder each
    number counts to GENERATED_RTOL (tests/numbers_in_text.py): the example main.c prints
    Riccati gains to 12 digits, whose last differ between LAPACK builds.
    """
    repo = REPO / "generated"
    expected = {p.name: _without_version_banners(p.name, p.read_bytes())
                for p in repo.iterdir()}
    recorded = expected["manifest.json"][1]
    runs = {}
    for seed in ("0", "4242"):
        out = tmp_path / f"gen-{seed}"
        env = {**os.environ, "PYTHONHASHSEED": seed}
        subprocess.run([sys.executable, "-m", "maglevgen.cli", "generate", "--out", str(out)],
                       check=True, cwd=tmp_path, env=env, capture_output=True)
        runs[seed] = {p.name: p.read_bytes() for p in out.iterdir()}
    assert runs["0"] == runs["4242"], "the generation depends on PYTHONHASHSEED"
    fresh = {name: _without_version_banners(name, data) for name, data in runs["0"].items()}
    now = fresh["manifest.json"][1]
    note = "" if now == recorded else f" (versions differ: generated/ has {recorded}, " \
        f"this environment {now}; regenerate with `maglevgen generate --out generated`)"
    assert sorted(fresh) == sorted(expected), f"file names differ{note}"
    for name in sorted(fresh):
        changed = differences(fresh[name][0].decode(), expected[name][0].decode(),
                              GENERATED_RTOL)
        assert not changed, (f"generated/{name} differs from a fresh generation: "
                             f"{changed[:5]}{note}")


def test_version_banners_are_all_that_is_left_out() -> None:
    """The normalisation blanks the versions only: any other edit still shows."""
    c = (REPO / "generated" / "maglev_functions.c").read_bytes()
    blank, _ = _without_version_banners("maglev_functions.c", c)
    assert b"CasADi <version>" in blank and b"*major = <n>;" in blank
    assert blank.count(b"\n") == c.count(b"\n")
    edited = c.replace(b"*major = ", b"*minor = ", 1)
    assert _without_version_banners("maglev_functions.c", edited)[0] != blank
    m = json.loads((REPO / "generated" / "manifest.json").read_text())
    m["versions"]["casadi"] = "0.0.0"
    same, versions = _without_version_banners("manifest.json", json.dumps(m).encode())
    assert versions["casadi"] == "0.0.0"
    m["states"][0]["unit"] = "km"
    assert _without_version_banners("manifest.json", json.dumps(m).encode())[0] != same


def test_generation_is_deterministic(carriage: DerivedCarriage, rendered) -> None:
    a = rendered(carriage, GenerateOptions("single", "runtime"))  # runtime_lib's render
    b = render(DerivedCarriage(load_params()), GenerateOptions("single", "runtime"))
    assert a == b
