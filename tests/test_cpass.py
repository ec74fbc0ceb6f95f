"""The firmware C pass: strict-warning compiles, casadi.external round trips, determinism.

Each check has a reference independent of the pass: the compilers themselves, the original
casadi.Function evaluated in Python, a second generation run, and regexes written here.
"""

from __future__ import annotations

import re
import subprocess
import tempfile
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from maglevgen.codegen.cpass import CompileError, compile_check, generate_c, postprocess

pytestmark = pytest.mark.needs_cc

NAME = "fw_test"
PRECISIONS = ("double", "single")
BASE_FLAGS = ["-std=c99", "-Wall", "-Wextra", "-Wpedantic", "-Werror"]
FLOAT_FLAGS = ["-Wdouble-promotion", "-Wfloat-conversion", "-Wconversion"]
RTOL = {"double": 1e-12, "single": 1e-5}
N_SAMPLES = 200
API_SUFFIXES = (
    "", "_checkout", "_release", "_incref", "_decref", "_n_in", "_n_out", "_default_in",
    "_name_in", "_name_out", "_sparsity_in", "_sparsity_out", "_work", "_work_bytes",
)
MATH_NAMES = (
    "sin", "cos", "tan", "exp", "log", "log10", "sqrt", "fabs", "fmax", "fmin", "pow", "atan2",
    "tanh", "sinh", "cosh", "asin", "acos", "atan", "floor", "ceil", "fmod", "hypot", "erf",
    "copysign", "expm1", "log1p", "cbrt", "round", "trunc",
)


# ----------------------------------------------------------------------------- functions


def _f() -> ca.Function:
    """SX: two inputs, a vector and a 2x2 matrix output, the usual math and branches."""
    x, p = ca.SX.sym("x", 3), ca.SX.sym("p", 2)
    y0 = (ca.sin(x[0]) * ca.cos(x[1]) + ca.exp(-x[2] ** 2) + ca.sqrt(ca.fabs(p[0]) + 1.5)
          + ca.fmax(x[0], p[1]) + ca.fmin(x[1], ca.inf) + 4.0)
    y1 = ca.if_else(x[0] > p[1], (x[0] ** 2 + 0.5) ** 2.5, x[1] / (1 + p[0] ** 2))
    y1 += ca.if_else(ca.logic_and(x[2] > 0, ca.logic_not(p[0] < 0)), 3.0, -1.25)
    y1 += ca.if_else(ca.logic_or(x[1] > 0.5, p[1] > 0.5), 0.1, 0.0) + 5.0
    M = ca.vertcat(
        ca.horzcat(ca.tan(x[0]) + 2.0, ca.log(2 + x[1] ** 2)),
        ca.horzcat(ca.atan2(x[2], p[0] + 3) + 2.0, ca.tanh(p[1]) / 7 + 1e-3 * ca.floor(4 * x[0])),
    )
    return ca.Function("f", [x, p], [ca.vertcat(y0, y1), M], ["x", "p"], ["y", "M"])


def _g(f: ca.Function) -> ca.Function:
    """MX calling f (a second function in the file), with a constant matrix and a product."""
    x, p = ca.MX.sym("x", 3), ca.MX.sym("p", 2)
    y, M = f(x, p)
    A = ca.DM([[1.5, -0.25], [0.125, 2.0]])
    return ca.Function("g", [x, p], [ca.mtimes(M + A, y) + 2.0, ca.sum1(y) * ca.norm_2(x + 3)])


def _sim() -> ca.Function:
    """A mapaccum loop over a small integrator step."""
    s, u = ca.SX.sym("s", 2), ca.SX.sym("u")
    step = ca.Function("step", [s, u], [ca.vertcat(s[0] + 0.1 * s[1],
                                                   s[1] + 0.1 * (u - ca.sin(s[0])))])
    return step.mapaccum("sim", 5)


def _lut() -> ca.Function:
    """A linear lookup table (CasADi's interpolant runtime: integer-to-real index arithmetic)."""
    return ca.interpolant("lut", "linear", [[-1.0, -0.25, 0.5, 1.5]], [2.0, 1.5, 3.25, 2.75])


@pytest.fixture(scope="module")
def functions() -> list[ca.Function]:
    f = _f()
    return [f, _g(f), _sim(), _lut()]


@pytest.fixture(scope="module")
def generated(functions: list[ca.Function]) -> dict[str, dict[str, str]]:
    return {prec: generate_c(functions, NAME, prec) for prec in PRECISIONS}


# ----------------------------------------------------------------------------- compiling


def _compilers() -> list:
    return [
        pytest.param("gcc", marks=pytest.mark.needs_cc("gcc")),
        pytest.param("clang", marks=pytest.mark.needs_cc("clang")),
    ]


@pytest.mark.parametrize("cc", _compilers())
@pytest.mark.parametrize("precision", PRECISIONS)
def test_compiles_warning_free(generated, precision: str, cc: str) -> None:
    """The .c alone, and a unit including header then source (prototypes must agree)."""
    sources = dict(generated[precision])
    sources["both.c"] = f'#include "{NAME}.h"\n#include "{NAME}.c"\n'
    compile_check(sources, BASE_FLAGS + FLOAT_FLAGS, cc=cc)


def test_raw_casadi_output_fails_the_same_flags(functions) -> None:
    """The reference the pass is needed against: CasADi's own text does not compile clean."""
    with tempfile.TemporaryDirectory() as tmp:
        opts = {"with_header": True, "verbose": False, "casadi_real": "float"}
        cg = ca.CodeGenerator(NAME, opts)
        for fn in functions:
            cg.add(fn)
        cg.generate(tmp + "/")
        raw = (Path(tmp) / f"{NAME}.c").read_text()
    with pytest.raises(CompileError, match=r"unused parameter|float"):
        compile_check({f"{NAME}.c": raw}, BASE_FLAGS + FLOAT_FLAGS)


def test_int_casadi_int_compiles(functions) -> None:
    """Firmware may choose int for casadi_int (casadi.external needs the 64-bit default)."""
    out = generate_c(functions, NAME, "single", int_type="int")
    assert "#define casadi_int int\n" in out[f"{NAME}.c"]
    compile_check(out, BASE_FLAGS + FLOAT_FLAGS)


# ----------------------------------------------------------------------------- round trip


def _shim(names: list[str]) -> str:
    """A double-ABI wrapper around the single-precision library, for casadi.external.

    casadi.external always passes double buffers; the wrapper converts each input and output
    element between double and float and forwards to the float function renamed ``sp_<name>``.
    """
    renames = "".join(f"#define {n} sp_{n}\n#define {n}_default_in sp_{n}_default_in\n"
                      for n in names)
    undefs = "".join(f"#undef {n}\n#undef {n}_default_in\n" for n in names)
    wrappers = "".join(_SHIM_WRAPPER.replace("NAME", n) for n in names)
    return (f"{renames}#include \"{NAME}.c\"\n{undefs}#include <stdlib.h>\n"
            f"{_SHIM_NNZ}{wrappers}")


_SHIM_NNZ = """
static long long shim_nnz(const long long* sp) {
  return sp[2] == 1 ? sp[0] * sp[1] : sp[2 + sp[1]];
}
"""

_SHIM_WRAPPER = """
int NAME(const double** arg, double** res, long long* iw, double* w, int mem) {
  long long sz_arg, sz_res, sz_iw, sz_w, i, k;
  long long n_in = NAME_n_in(), n_out = NAME_n_out();
  const float** a; float** r; float* fw; int flag;
  (void)w;
  NAME_work(&sz_arg, &sz_res, &sz_iw, &sz_w);
  a = calloc((size_t)sz_arg + 1, sizeof *a);
  r = calloc((size_t)sz_res + 1, sizeof *r);
  fw = calloc((size_t)sz_w + 1, sizeof *fw);
  for (i = 0; i < n_in; ++i) {
    if (arg[i]) {
      long long nz = shim_nnz(NAME_sparsity_in(i));
      float* b = malloc(((size_t)nz + 1) * sizeof *b);
      for (k = 0; k < nz; ++k) b[k] = (float)arg[i][k];
      a[i] = b;
    }
  }
  for (i = 0; i < n_out; ++i) {
    if (res[i]) r[i] = malloc(((size_t)shim_nnz(NAME_sparsity_out(i)) + 1) * sizeof(float));
  }
  flag = sp_NAME(a, r, iw, fw, mem);
  for (i = 0; i < n_out; ++i) {
    if (res[i]) {
      long long nz = shim_nnz(NAME_sparsity_out(i));
      for (k = 0; k < nz; ++k) res[i][k] = (double)r[i][k];
      free(r[i]);
    }
  }
  for (i = 0; i < n_in; ++i) free((void*)a[i]);
  free(a); free(r); free(fw);
  return flag;
}
double NAME_default_in(long long i) { return (double)sp_NAME_default_in(i); }
"""


def _build_library(sources: dict[str, str], precision: str, names: list[str],
                   workdir: Path) -> Path:
    """Build a shared library (-shared -fPIC -O2) from the generated source."""
    for fname, text in sources.items():
        (workdir / fname).write_text(text)
    main = f"{NAME}.c"
    if precision == "single":
        (workdir / "shim.c").write_text(_shim(names))
        main = "shim.c"
    lib = workdir / f"lib{NAME}_{precision}.so"
    cmd = ["gcc", "-std=c99", "-shared", "-fPIC", "-O2", main, "-o", str(lib), "-lm"]
    subprocess.run(cmd, cwd=workdir, check=True, capture_output=True, text=True)
    return lib


def _random_inputs(fn: ca.Function, rng: np.random.Generator) -> list[np.ndarray]:
    """N_SAMPLES inputs side by side, uniform in [-1, 1] and representable in float."""
    shapes = [(fn.size1_in(i), fn.size2_in(i) * N_SAMPLES) for i in range(fn.n_in())]
    return [rng.uniform(-1, 1, s).astype(np.float32).astype(np.float64) for s in shapes]


def _per_sample(out: ca.DM) -> np.ndarray:
    """A mapped output (samples side by side) as an (elements, samples) array."""
    arr = np.asarray(out)
    rows, cols = arr.shape[0], arr.shape[1] // N_SAMPLES
    return arr.reshape(rows, N_SAMPLES, cols).transpose(0, 2, 1).reshape(rows * cols, N_SAMPLES)


def _assert_close(got: np.ndarray, ref: np.ndarray, rtol: float, what: str) -> None:
    """Relative error per element, floored at rtol times the output's largest magnitude."""
    scale = np.max(np.abs(ref), axis=1, keepdims=True)
    err = np.abs(got - ref) / np.maximum(np.abs(ref), scale)
    assert np.all(np.isfinite(got)), what
    assert err.max() <= rtol, f"{what}: max relative error {err.max():.3g} > {rtol:g}"


@pytest.mark.parametrize("precision", PRECISIONS)
def test_external_matches_casadi(generated, functions, precision: str, tmp_path: Path) -> None:
    names = [fn.name() for fn in functions]
    lib = _build_library(generated[precision], precision, names, tmp_path)
    rng = np.random.default_rng(20240611)
    for fn in functions:
        ext = ca.external(fn.name(), str(lib))
        assert ext.name_in() == fn.name_in() and ext.name_out() == fn.name_out()
        assert all(ext.sparsity_out(i) == fn.sparsity_out(i) for i in range(fn.n_out()))
        inputs = _random_inputs(fn, rng)
        ref = fn.map(N_SAMPLES)(*inputs)
        got = ext.map(N_SAMPLES)(*inputs)
        ref, got = (ref, got) if isinstance(ref, tuple) else ((ref,), (got,))
        for k, (r, g) in enumerate(zip(ref, got, strict=True)):
            _assert_close(_per_sample(g), _per_sample(r), RTOL[precision],
                          f"{fn.name()} output {k} ({precision})")


def test_header_declares_casadi_api(generated, functions) -> None:
    header = generated["single"][f"{NAME}.h"]
    for fn in functions:
        for suffix in API_SUFFIXES:
            assert re.search(rf"\b{fn.name()}{suffix}\(", header), f"{fn.name()}{suffix}"


# ----------------------------------------------------------------------------- text checks


@pytest.mark.parametrize("precision", PRECISIONS)
def test_byte_identical_across_runs_and_cwd(functions, generated, precision: str,
                                            tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    again = generate_c(functions, NAME, precision)
    assert again == generated[precision]
    for text in again.values():
        assert str(tmp_path) not in text and tempfile.gettempdir() + "/" not in text


def _code_only(text: str) -> str:
    """The text with comments and string literals blanked out."""
    text = re.sub(r"/\*.*?\*/", " ", text, flags=re.DOTALL)
    text = re.sub(r"//[^\n]*", " ", text)
    return re.sub(r'"(?:\\.|[^"\\\n])*"', '""', text)


UNSUFFIXED_FLOAT = re.compile(
    r"(?<![\w.])(?:\d+\.\d*|\.\d+|\d+(?=[eE]))(?:[eE][+-]?\d+)?(?![\w.])"
)


def test_single_has_no_double_calls_or_literals(generated) -> None:
    for fname, text in generated["single"].items():
        code = _code_only(text)
        for lineno, line in enumerate(code.splitlines(), 1):
            assert not re.search(rf"\b(?:{'|'.join(MATH_NAMES)})\s*\(", line), (fname, lineno,
                                                                             line)
            assert not UNSUFFIXED_FLOAT.search(line), (fname, lineno, line)
            assert not re.search(r"\bdouble\b", line), (fname, lineno, line)
    assert "sinf(" in generated["single"][f"{NAME}.c"]


def test_double_keeps_values_and_calls(generated) -> None:
    code = generated["double"][f"{NAME}.c"]
    assert "sin(" in code and "1.5000000000000000e+00" in code and "sinf(" not in code


# ----------------------------------------------------------------------------- unit level


def _wrap(body: str, real: str = "float") -> str:
    """A minimal CasADi-like unit around ``body``, with casadi_real defaulting to ``real``."""
    return (f"#ifndef casadi_real\n#define casadi_real {real}\n#endif\n\n"
            f"casadi_real h(casadi_real x, int k) {{\n{body}\n}}\n")


def test_literal_rewrite_leaves_identifiers_ints_hex_comments_alone() -> None:
    src = _wrap('  /* sin(1.5) */ const char* s = "2.5 exp(x)";\n'
                "  casadi_real a1e5 = 2.5, b = 1e300, c = 1e-300, d = 1.f, e = 0x1Fp0;\n"
                "  int arr[3] = {0, 0x1F, 10};\n"
                "  (void)s; (void)a1e5; (void)b; (void)c; (void)d; (void)e; (void)arr;\n"
                "  return sqrt(x) + 3. + pow(x, .5) + (casadi_real)arr[k];")
    out = postprocess(src, "single")
    assert "/* sin(1.5) */" in out and '"2.5 exp(x)"' in out
    assert "a1e5 = 2.50000000e+00f" in out and "b = INFINITY" in out and "c = 0.0f" in out
    assert "d = 1.f" in out and "e = 31.0f" in out and "{0, 0x1F, 10}" in out
    assert "sqrtf(x) + 3.0f + powf(x, 5.00000000e-01f) + (casadi_real)arr[k]" in out
    compile_check({"u.c": "#include <math.h>\n" + out}, BASE_FLAGS + FLOAT_FLAGS)


def test_unused_parameters_are_voided_after_declarations() -> None:
    out = postprocess(_wrap("  casadi_real r;\n  r = 2;\n  return r;"), "single")
    assert "  casadi_real r;\n  (void)x; (void)k;\n  r = 2;" in out


def test_unconvertible_text_raises_with_line() -> None:
    with pytest.raises(ValueError, match=r"line 6: return \(casadi_real\)\(\(double\)x\);"):
        postprocess(_wrap("  return (casadi_real)((double)x);"), "single")


def test_writable_static_data_is_refused() -> None:
    with pytest.raises(ValueError, match=r"file-scope data at line 5: static int counter"):
        postprocess(_wrap("  return x;", "double").replace("\n\n", "\n\nstatic int counter = 0;\n"),
                    "double")
    with pytest.raises(ValueError, match=r"block-scope static"):
        postprocess(_wrap("  static casadi_real last;\n  last = x;\n  return last;", "double"),
                    "double")


def test_solver_with_memory_is_refused() -> None:
    """CasADi emits writable memory pools for nlpsol: not re-entrant firmware code."""
    x = ca.MX.sym("x", 2)
    nlp = {"x": x, "f": ca.sumsqr(x - 1) + x[0] ** 4, "g": x[0] + x[1]}
    quiet = {"print_header": False, "print_iteration": False, "print_time": False,
             "qpsol": "qrqp", "qpsol_options": {"print_iter": False, "print_header": False}}
    solver = ca.nlpsol("s", "sqpmethod", nlp, quiet)
    with pytest.raises(ValueError, match=r"writable file-scope data at line \d+: static int"):
        generate_c([solver], "nlp_test", "double")


@pytest.mark.parametrize("precision", PRECISIONS)
def test_qp_solver_runtime_compiles(precision: str) -> None:
    """A larger slice of CasADi's runtime library (qrqp: QR, printing stubs) passes too."""
    x = ca.MX.sym("x", 2)
    qp = {"x": x, "f": ca.sumsqr(x - 1), "g": x[0] + x[1]}
    solver = ca.qpsol("qp", "qrqp", qp, {"print_iter": False, "print_header": False})
    compile_check(generate_c([solver], "qp_test", precision), BASE_FLAGS + FLOAT_FLAGS)


def test_precision_mismatch_is_refused() -> None:
    with pytest.raises(ValueError, match="casadi_real=float, not double"):
        postprocess(_wrap("  return x;"), "double")
