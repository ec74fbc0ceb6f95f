"""Fail safe everywhere (issue 40): every generated C function under hostile inputs, the FMU
through FMPy, the last bad command lines.

The C harness is written here from the headers: every function that maglev.h,
maglev_functions.h, maglev_simulate.h and maglev_gain_table.h declare is called with a table
of hostile values (NaN, +-inf, +-1e30, 1e300, denormals, zeros, -1, negative counts, NULL
where the type allows it, schedules of 0 and 1 nodes, hostile parameter vectors), compiled
with AddressSanitizer and UndefinedBehaviorSanitizer (float-cast-overflow too) and run. The
references are independent of the code under test: the sanitizers for memory and undefined
behaviour, C99's isfinite on every output the call wrote, and the API's stated contract (an
error code with zeroed outputs, or 0 with finite outputs). A declared function the harness
does not know fails the test, so a new one cannot be forgotten.
"""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest

from maglevgen.carriage import DerivedCarriage
from maglevgen.codegen.checks import ERROR_CODES

REPO = Path(__file__).resolve().parents[1]
ERR = {name: value for name, (value, _) in ERROR_CODES.items()}
SANITIZE = ["-fsanitize=address,undefined,float-cast-overflow", "-fno-sanitize-recover=all",
            "-fno-omit-frame-pointer"]

#: hostile scalars (C expressions of double): written into one element, then into every
#: element, of each input in turn
HOSTILE = ["NAN", "INFINITY", "-INFINITY", "1e30", "-1e30", "1e300", "4.9e-324", "-4.9e-324",
           "2.2e-308", "0.0", "-0.0", "-1.0"]
#: the CasADi API's companions of each function (maglev_functions.h)
COMPANIONS = ("checkout", "release", "incref", "decref", "n_in", "n_out", "default_in",
              "name_in", "name_out", "sparsity_in", "sparsity_out", "work", "work_bytes")
#: the functions with their own signatures (maglev_simulate.h, maglev_gain_table.h)
OWN_SIGNATURE = ("maglev_simulate", "maglev_launch", "maglev_schedule_eval", "maglev_schedule",
                 "maglev_lyapunov_batch",
                 "maglev_functions_casadi_version", "maglev_functions_casadi_int_size",
                 "maglev_functions_casadi_real_size")


def _declared(headers: list[Path]) -> set[str]:
    """Every function name the headers declare (a prototype: a type, the name, '(')."""
    pat = re.compile(r"^\s*(?:const\s+)?[A-Za-z_][\w ]*?[\s*]+(maglev_\w+)\s*\(", re.M)
    return {m.group(1) for h in headers for m in pat.finditer(h.read_text())}


def _nominal(name: str, n: int, carriage: DerivedCarriage) -> list[float]:
    """A finite, physically sensible value of an input (what the hostile values replace)."""
    if name in ("x", "x0"):
        x = [0.0] * 12
        x[6] = 20.0  # forward speed: the trim's neighbourhood
        return x
    values = {"p": list(carriage.p), "v": [20.0], "dt": [1e-3], "F_prop": [1.0],
              "k": [1e4] * n, "m": [1.0] * n}
    if name in values:
        return values[name]
    if name in ("K_pos", "K_rate"):
        return [0.1 if i % 6 == 0 else 0.0 for i in range(n)]  # 0.1 I (5 x 5)
    return [0.5] * n  # K, c_damping, a_ref, u_gen, u, T, c (c is refilled from prepare)


def _c_array(name: str, values: list[float]) -> str:
    return f"static const double {name}[{max(len(values), 1)}] = {{" + ", ".join(
        repr(float(v)) for v in values) + "};\n" if values else \
        f"static const double {name}[1] = {{0.0}};\n"


def _casadi_calls(table: list[dict], carriage: DerivedCarriage, runtime: bool) -> str:
    """C: for each function, the hostile-input cases through call_case (see _PRELUDE)."""
    out = []
    for f in table:
        name, ins, outs = f["name"], f["inputs"], f["outputs"]
        tag = name.removeprefix("maglev_")
        nom = [_nominal(io["name"], io["rows"] * io["cols"], carriage) for io in ins]
        for i, vals in enumerate(nom):
            out.append(_c_array(f"nom_{tag}_{i}", vals))
        n_in, n_out = len(ins), len(outs)
        sz_in = ", ".join(str(io["rows"] * io["cols"]) for io in ins) or "0"
        sz_out = ", ".join(str(io["rows"] * io["cols"]) for io in outs) or "0"
        noms = ", ".join(f"nom_{tag}_{i}" for i in range(n_in)) or "0"
        p_at = next((i for i, io in enumerate(ins) if io["name"] == "p"), -1) if runtime else -1
        c_at = next((i for i, io in enumerate(ins) if io["name"] == "c"), -1)
        out.append(
            f"static void run_{tag}(void) {{\n"
            f"  static const int sz_in[] = {{{sz_in}}}, sz_out[] = {{{sz_out}}};\n"
            f"  static const double* noms[] = {{{noms}}};\n"
            f"  fn_t f = {{\"{name}\", {name}, {name}_work, {n_in}, {n_out}, sz_in, sz_out, "
            f"noms, {p_at}, {c_at}}};\n"
            f"  companions_{tag}();\n"
            "  hostile_cases(&f);\n}\n\n")
        # the companions: every index the API takes, in and out of range
        out.append(
            f"static void companions_{tag}(void) {{\n"
            "  static const maglev_int idx[] = {-1, 0, 1, 2, 1000, -1000000000LL, "
            "9000000000000000000LL};\n"
            "  maglev_int a, b, c, d;\n  unsigned k;\n"
            f"  int mem = {name}_checkout();\n  {name}_incref();\n"
            f"  for (k = 0; k < sizeof idx / sizeof idx[0]; ++k) {{\n"
            f"    volatile double dv = (double){name}_default_in(idx[k]);\n"
            f"    volatile const char* s1 = {name}_name_in(idx[k]);\n"
            f"    volatile const char* s2 = {name}_name_out(idx[k]);\n"
            f"    const maglev_int* sp = {name}_sparsity_in(idx[k]);\n"
            f"    const maglev_int* sq = {name}_sparsity_out(idx[k]);\n"
            "    (void)dv; (void)s1; (void)s2;\n"
            "    if (sp != 0) touch_sparsity(sp);\n    if (sq != 0) touch_sparsity(sq);\n"
            "  }\n"
            f"  (void){name}_n_in(); (void){name}_n_out();\n"
            f"  (void){name}_work(0, 0, 0, 0); (void){name}_work_bytes(0, 0, 0, 0);\n"
            f"  (void){name}_work(&a, &b, &c, &d); (void){name}_work_bytes(&a, &b, &c, &d);\n"
            f"  {name}_decref();\n  {name}_release(mem);\n  {name}_release(-1);\n"
            f"  {name}_release(1000000);\n"
            f"  record(\"{name}_companions\", \"indices\", 0, 1);\n"
            "}\n\n")
    out.append("static void run_all_casadi(void) {\n" + "".join(
        f"  run_{f['name'].removeprefix('maglev_')}();\n" for f in table) + "}\n")
    # forward declarations first: run_ calls companions_ defined after it
    fwd = "".join(f"static void companions_{f['name'].removeprefix('maglev_')}(void);\n"
                  for f in table)
    return fwd + "".join(out)


_PRELUDE = r"""
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "maglev_functions.h"
#include "maglev_simulate.h"

#define MAXIO 8
#define MAXN 512
#define WORK 8192

typedef int (*api_t)(const maglev_real**, maglev_real**, maglev_int*, maglev_real*, int);
typedef int (*work_t)(maglev_int*, maglev_int*, maglev_int*, maglev_int*);
typedef struct {
  const char* name; api_t fn; work_t work; int n_in, n_out;
  const int* sz_in; const int* sz_out; const double* const* noms; int p_at, c_at;
} fn_t;

static long calls, failures;
static void hostile_parameters(const fn_t* f, const maglev_real** arg, maglev_real** res);
static const double hostile[] = {HOSTILE_VALUES};
#define NH ((int)(sizeof hostile / sizeof hostile[0]))

/* one line per failed property, and a count of every call */
static void record(const char* fn, const char* what, int rc, int ok) {
  ++calls;
  if (!ok) {
    ++failures;
    printf("FAIL %s %s rc=%d\n", fn, what, rc);
  }
}

static void touch_sparsity(const maglev_int* sp) {
  volatile maglev_int s = sp[0] + sp[1];  /* rows, cols: readable */
  (void)s;
}

static int all_finite(const maglev_real* a, int n) {
  int i;
  for (i = 0; i < n; ++i) if (!isfinite(a[i])) return 0;
  return 1;
}

static int all_zero(const maglev_real* a, int n) {
  int i;
  for (i = 0; i < n; ++i) if (a[i] != 0) return 0;
  return 1;
}

/* the buffers of one call: inputs (copies of the nominal values), outputs (poisoned) */
static maglev_real in_buf[MAXIO][MAXN], out_buf[MAXIO][MAXN], c_prepared[MAXN];
static maglev_real w_buf[WORK];
static maglev_int iw_buf[WORK];

static void load_nominal(const fn_t* f) {
  int i, j;
  for (i = 0; i < f->n_in; ++i) {
    for (j = 0; j < f->sz_in[i]; ++j) {
      in_buf[i][j] = (maglev_real)(i == f->c_at ? c_prepared[j] : f->noms[i][j]);
    }
  }
}

/* call with arg/res as given; check the contract: a known code; 0: every output written is
   finite; an error: every output the caller passed is zero */
static void call_case(const fn_t* f, const maglev_real** arg, maglev_real** res,
                      maglev_int* iw, maglev_real* w, const char* what, int want_rc) {
  int i, j, rc, ok = 1;
  for (i = 0; i < MAXIO; ++i) {
    for (j = 0; j < MAXN; ++j) out_buf[i][j] = (maglev_real)7;
  }
  rc = f->fn(arg, res, iw, w, 0);
  if (rc < 0 || rc > MAX_CODE) ok = 0;
  if (want_rc >= 0 && rc != want_rc) ok = 0;
  if (want_rc == -2 && rc == 0) ok = 0;  /* must be refused */
  if (res != 0) {
    for (i = 0; i < f->n_out; ++i) {
      if (res[i] == 0) continue;
      if (rc == 0 && !all_finite(res[i], f->sz_out[i])) ok = 0;
      if (rc != 0 && !all_zero(res[i], f->sz_out[i])) ok = 0;
    }
  }
  record(f->name, what, rc, ok);
}

static void setup(const fn_t* f, const maglev_real** arg, maglev_real** res) {
  int i;
  for (i = 0; i < 2 * MAXIO; ++i) { arg[i] = 0; res[i] = 0; }
  for (i = 0; i < f->n_in; ++i) arg[i] = in_buf[i];
  for (i = 0; i < f->n_out; ++i) res[i] = out_buf[i];
}

static void hostile_cases(const fn_t* f) {
  const maglev_real* arg[2 * MAXIO + 32];
  maglev_real* res[2 * MAXIO + 32];
  maglev_int sz_arg, sz_res, sz_iw, sz_w;
  char what[96];
  int i, j, h;
  f->work(&sz_arg, &sz_res, &sz_iw, &sz_w);
  if (sz_arg > 2 * MAXIO + 32 || sz_res > 2 * MAXIO + 32 || sz_iw > WORK || sz_w > WORK) {
    record(f->name, "harness buffers too small", 0, 0);
    return;
  }
  load_nominal(f);
  setup(f, arg, res);
  call_case(f, arg, res, iw_buf, w_buf, "nominal", -1);
  if (strcmp(f->name, "maglev_closed_loop_prepare") == 0) {  /* c for the prepared loop */
    for (j = 0; j < f->sz_out[0]; ++j) c_prepared[j] = out_buf[0][j];
  }
  /* NULL arg, res and (where used) work arrays: refused */
  call_case(f, 0, res, iw_buf, w_buf, "arg NULL", MAGLEV_ERR_ARGUMENT);
  call_case(f, arg, 0, iw_buf, w_buf, "res NULL", MAGLEV_ERR_ARGUMENT);
  if (sz_w > 0) call_case(f, arg, res, iw_buf, 0, "w NULL", MAGLEV_ERR_ARGUMENT);
  if (sz_iw > 0) call_case(f, arg, res, 0, w_buf, "iw NULL", MAGLEV_ERR_ARGUMENT);
  if (sz_iw == 0 && sz_w == 0) call_case(f, arg, res, 0, 0, "no work arrays", -1);
  for (i = 0; i < f->n_out; ++i) {  /* a NULL res[i] skips output i */
    setup(f, arg, res);
    res[i] = 0;
    sprintf(what, "res[%d] NULL", i);
    call_case(f, arg, res, iw_buf, w_buf, what, -1);
  }
  for (i = 0; i < f->n_in; ++i) {
    setup(f, arg, res);
    arg[i] = 0;  /* CasADi's zero input */
    sprintf(what, "arg[%d] NULL", i);
    call_case(f, arg, res, iw_buf, w_buf, what, i == f->p_at ? -2 : -1);
    for (h = 0; h < NH; ++h) {
      load_nominal(f);
      setup(f, arg, res);
      in_buf[i][0] = (maglev_real)hostile[h];
      sprintf(what, "input %d [0] = %g", i, hostile[h]);
      call_case(f, arg, res, iw_buf, w_buf, what,
                (i == f->p_at && !isfinite(hostile[h])) ? MAGLEV_ERR_NONFINITE : -1);
      for (j = 0; j < f->sz_in[i]; ++j) in_buf[i][j] = (maglev_real)hostile[h];
      sprintf(what, "input %d all = %g", i, hostile[h]);
      call_case(f, arg, res, iw_buf, w_buf, what, -1);
    }
  }
  load_nominal(f);
  if (f->p_at >= 0) hostile_parameters(f, arg, res);
}
"""


def _hostile_parameter_code(carriage: DerivedCarriage) -> str:
    """C: hostile parameter vectors (refused: an error code) and NaN in each entry of p."""
    names = carriage.structure.param_names
    cases = [("vehicle.mass", "0.0"), ("vehicle.mass", "-9.3"), ("halbach.wavelength", "0.0"),
             ("halbach.wavelength", "-0.1"), ("circuit.resistance", "-1.5e-3"),
             ("circuit.resistance", "0.0"), ("circuit.inductance", "0.0"),
             ("circuit.inductance", "-2.6e-6"), ("vehicle.gravity", "-9.81"),
             ("halbach.magnets_per_wavelength", "0.0"), ("track.min_gap", "-1.0")]
    lines = []
    for key, value in cases:
        lines.append(f"  load_nominal(f); setup(f, arg, res); "
                     f"in_buf[f->p_at][{names.index(key)}] = (maglev_real){value};\n"
                     f"  call_case(f, arg, res, iw_buf, w_buf, \"p {key} = {value}\", -2);\n")
    return ("static void hostile_parameters(const fn_t* f, const maglev_real** arg, "
            "maglev_real** res) {\n  int j;\n" + "".join(lines) +
            f"  for (j = 0; j < {len(names)}; ++j) {{\n"
            "    char what[64];\n    load_nominal(f); setup(f, arg, res);\n"
            "    in_buf[f->p_at][j] = (maglev_real)NAN;\n"
            "    sprintf(what, \"p[%d] = NaN\", j);\n"
            "    call_case(f, arg, res, iw_buf, w_buf, what, MAGLEV_ERR_NONFINITE);\n"
            "  }\n  load_nominal(f);\n}\n")


def _run_code(runtime: bool, nu: int, ng: int) -> str:
    """C: maglev_simulate, maglev_launch and maglev_schedule_eval under hostile arguments."""
    p_sim = " p_arg," if runtime else ""
    return (r"""
#define NS 4
#define NU_ """ + str(nu) + r"""
#define NG_ """ + str(ng) + r"""
static maglev_real xt[NS + 1][12], ut[NS + 1][NU_], gt[NS + 1][NG_];
static maglev_real x0n[12], kpos[25], krate[25], aref[5];
static maglev_real ys[3 * MAGLEV_SCHEDULE_NY], d2ys[3 * MAGLEV_SCHEDULE_NY];
static maglev_real pbuf[MAXN];
static const maglev_real* p_arg;
static const maglev_control_loop* loop_arg;  /* NULL: the plain loop */
static long long saturated_steps;

static void run_nominal(void) {
  int i;
  for (i = 0; i < 12; ++i) x0n[i] = 0;
  x0n[6] = (maglev_real)20;
  for (i = 0; i < 25; ++i) kpos[i] = krate[i] = (maglev_real)(i % 6 == 0 ? 0.1 : 0.0);
  for (i = 0; i < 5; ++i) aref[i] = 0;
  for (i = 0; i < 3 * MAGLEV_SCHEDULE_NY; ++i) {
    ys[i] = (maglev_real)(i % MAGLEV_SCHEDULE_NY >= MAGLEV_SCHEDULE_K_POS ? 0.05 : 0.0);
    d2ys[i] = 0;
  }
  ys[MAGLEV_SCHEDULE_F_DRAG] = (maglev_real)1;
  P_NOMINAL
}

/* the runs' contract: -1 exactly with MAGLEV_SIM_ARGUMENT; otherwise an index in
   [0, n_steps]; with MAGLEV_SIM_OK or _CONTACT every sample written is finite */
static void check_run(const char* fn, const char* what, long long ret, int st, int have_status,
                      long long n_steps, int must_refuse) {
  int ok = 1;
  long long k;
  if (have_status) {
    if ((ret == -1) != (st == MAGLEV_SIM_ARGUMENT)) ok = 0;
    if (st < 0 || st > MAGLEV_SIM_ARGUMENT) ok = 0;
    if (ret != -1 && (ret < 0 || ret > n_steps)) ok = 0;
    if ((st == MAGLEV_SIM_OK || st == MAGLEV_SIM_CONTACT) && ret >= 0) {
      for (k = 0; k <= ret; ++k) {
        if (!all_finite(xt[k], 12) || !all_finite(ut[k], NU_) || !all_finite(gt[k], NG_)) ok = 0;
      }
    }
  }
  if (must_refuse == 1 && ret != -1) ok = 0;          /* an invalid argument */
  if (must_refuse == 2 && have_status && st == MAGLEV_SIM_OK) ok = 0;  /* a bad p */
  record(fn, what, (int)ret, ok);
}

static void sim(const char* what, const maglev_real* x0, maglev_real dt, long long n,
                maglev_real F, const maglev_real* kp, const maglev_real* kr, const maglev_real* ar,
                maglev_real gmin, maglev_real* x, maglev_real* u, maglev_real* g, int use_status,
                int must_refuse) {
  int st = -7;
  long long ret = maglev_simulate(x0, dt, n, F, kp, kr, ar, loop_arg,""" + p_sim + r""" gmin,
                                  x, u, g, &saturated_steps, use_status ? &st : 0);
  check_run("maglev_simulate", what, ret, st, use_status, n, must_refuse);
}

static void launch(const char* what, const maglev_real* x0, maglev_real dt, long long n,
                   maglev_real v_end, maglev_real F_extra, long long hold,
                   const maglev_spline_schedule* s, maglev_real gmin, int must_refuse) {
  int st = -7;
  long long ret = maglev_launch(x0, dt, n, v_end, F_extra, hold, s, loop_arg,""" + p_sim
                                + r""" gmin, &xt[0][0], &ut[0][0], &gt[0][0], &saturated_steps,
                                &st);
  check_run("maglev_launch", what, ret, st, 1, n, must_refuse);
}

static void eval(const char* what, const maglev_spline_schedule* s, maglev_real v,
                 maglev_real* out, int must_refuse) {
  int i, rc, ok = 1;
  if (out != 0) for (i = 0; i < MAGLEV_SCHEDULE_NY; ++i) out[i] = (maglev_real)7;
  rc = maglev_schedule_eval(s, v, out);
  if (rc < MAGLEV_SCHEDULE_OK || rc > MAGLEV_SCHEDULE_INVALID) ok = 0;
  if (out != 0 && (rc == MAGLEV_SCHEDULE_OK || rc == MAGLEV_SCHEDULE_CLAMPED)
      && !all_finite(out, MAGLEV_SCHEDULE_NY)) ok = 0;
  if (out != 0 && rc == MAGLEV_SCHEDULE_INVALID && !all_zero(out, MAGLEV_SCHEDULE_NY)) ok = 0;
  if (must_refuse && rc != MAGLEV_SCHEDULE_INVALID) ok = 0;
  record("maglev_schedule_eval", what, rc, ok);
}

/* maglev_lyapunov_batch: MAGLEV_SIM_OK, _ERROR or _ARGUMENT; an invalid argument refused;
   a non-finite row gives NaN in V and V_dot */
static maglev_real Pm[144], xtrim[12], Vb[NS + 1], Vdb[NS + 1];
static void lyap(const char* what, long long n, const maglev_real* X, maglev_real F,
                 const maglev_real* kp, const maglev_real* P, const maglev_real* xr,
                 maglev_real* V, int must_refuse, int nan_rows) {
  int ok = 1, k;
  int rc = maglev_lyapunov_batch(n, X, F, kp, krate, aref, xr, P,""" + p_sim + r""" V, Vdb,
                                 &gt[0][0]);
  if (rc != MAGLEV_SIM_OK && rc != MAGLEV_SIM_ERROR && rc != MAGLEV_SIM_ARGUMENT) ok = 0;
  if (must_refuse == 1 && rc != MAGLEV_SIM_ARGUMENT) ok = 0;
  if (must_refuse == 0 && rc == MAGLEV_SIM_ARGUMENT) ok = 0;
  if (rc == MAGLEV_SIM_OK && nan_rows && V != 0) {
    for (k = 0; k < n; ++k) {
      if (!isnan(V[k]) || !isnan(Vdb[k])) ok = 0;
    }
  }
  record("maglev_lyapunov_batch", what, rc, ok);
}

static void run_lyapunov(void) {
  maglev_real* X = &xt[0][0];
  static const long long bad_n[] = {-1, LLONG_MIN, MAGLEV_SIM_MAX_STEPS + 1};
  char what[96];
  int h, i, k;
  run_nominal();
  for (i = 0; i < 144; ++i) Pm[i] = (maglev_real)(i % 13 == 0 ? 1 : 0);
  for (i = 0; i < 12; ++i) xtrim[i] = x0n[i];
  for (k = 0; k <= NS; ++k) for (i = 0; i < 12; ++i) xt[k][i] = x0n[i];
  lyap("nominal", NS, X, 1, kpos, Pm, xtrim, Vb, 0, 0);
  lyap("n 0", 0, X, 1, kpos, Pm, xtrim, Vb, 0, 0);
  for (i = 0; i < (int)(sizeof bad_n / sizeof bad_n[0]); ++i) {
    sprintf(what, "n %lld", bad_n[i]);
    lyap(what, bad_n[i], X, 1, kpos, Pm, xtrim, Vb, 1, 0);
  }
  lyap("X NULL", NS, 0, 1, kpos, Pm, xtrim, Vb, 1, 0);
  lyap("K_pos NULL", NS, X, 1, 0, Pm, xtrim, Vb, 1, 0);
  lyap("P NULL", NS, X, 1, kpos, 0, xtrim, Vb, 1, 0);
  lyap("x_trim NULL", NS, X, 1, kpos, Pm, 0, Vb, 1, 0);
  lyap("V NULL", NS, X, 1, kpos, Pm, xtrim, 0, 1, 0);
  for (h = 0; h < NH; ++h) {
    const maglev_real v = (maglev_real)hostile[h];
    sprintf(what, "F_prop %g", hostile[h]);
    lyap(what, NS, X, v, kpos, Pm, xtrim, Vb, !isfinite(v), 0);
    Pm[0] = v;
    sprintf(what, "P[0] %g", hostile[h]);
    lyap(what, NS, X, 1, kpos, Pm, xtrim, Vb, !isfinite(v), 0);
    Pm[0] = 1;
    xtrim[3] = v;
    sprintf(what, "x_trim[3] %g", hostile[h]);
    lyap(what, NS, X, 1, kpos, Pm, xtrim, Vb, !isfinite(v), 0);
    xtrim[3] = x0n[3];
    for (k = 0; k < NS; ++k) for (i = 0; i < 12; ++i) xt[k][i] = v;
    sprintf(what, "X all %g", hostile[h]);
    lyap(what, NS, X, 1, kpos, Pm, xtrim, Vb, 2, !isfinite(v));
    for (k = 0; k <= NS; ++k) for (i = 0; i < 12; ++i) xt[k][i] = x0n[i];
  }
}

static void run_simulations(void) {
  maglev_real* x = &xt[0][0];
  maglev_real* u = &ut[0][0];
  maglev_real* g = &gt[0][0];
  maglev_real bad[12], out[MAGLEV_SCHEDULE_NY];
  const maglev_real gmin = (maglev_real)0.002;
  maglev_spline_schedule s = {3, (maglev_real)15, (maglev_real)5, 0, 0}, t;
  static const long long bad_n[] = {-1, -1000000000LL, LLONG_MIN, LLONG_MAX,
                                    MAGLEV_SIM_MAX_STEPS + 1};
  static const int bad_nodes[] = {0, 1, -1, -2147483647 - 1, INT_MAX,
                                  MAGLEV_SCHEDULE_MAX_NODES + 1};
  static const long long holds[] = {-1, LLONG_MIN, 0, 1, 3, LLONG_MAX};
  char what[96];
  int h, i;
  s.y = ys;
  s.d2y = d2ys;
  run_nominal();
  sim("nominal", x0n, (maglev_real)1e-3, NS, 1, kpos, krate, aref, gmin, x, u, g, 1, 0);
  sim("n_steps 0", x0n, (maglev_real)1e-3, 0, 1, kpos, krate, aref, gmin, x, u, g, 1, 0);
  sim("x0 NULL", 0, (maglev_real)1e-3, NS, 1, kpos, krate, aref, gmin, x, u, g, 1, 1);
  sim("K_pos NULL", x0n, (maglev_real)1e-3, NS, 1, 0, krate, aref, gmin, x, u, g, 1, 1);
  sim("K_rate NULL", x0n, (maglev_real)1e-3, NS, 1, kpos, 0, aref, gmin, x, u, g, 1, 1);
  sim("a_ref NULL", x0n, (maglev_real)1e-3, NS, 1, kpos, krate, 0, gmin, x, u, g, 1, 1);
  sim("x_traj NULL", x0n, (maglev_real)1e-3, NS, 1, kpos, krate, aref, gmin, 0, u, g, 1, 1);
  sim("u_traj NULL", x0n, (maglev_real)1e-3, NS, 1, kpos, krate, aref, gmin, x, 0, g, 1, 1);
  sim("gap_traj NULL", x0n, (maglev_real)1e-3, NS, 1, kpos, krate, aref, gmin, x, u, 0, 1, 1);
  sim("status NULL", x0n, (maglev_real)1e-3, NS, 1, kpos, krate, aref, gmin, x, u, g, 0, 1);
  P_NULL_CASE
  for (i = 0; i < (int)(sizeof bad_n / sizeof bad_n[0]); ++i) {
    sprintf(what, "n_steps %lld", bad_n[i]);
    sim(what, x0n, (maglev_real)1e-3, bad_n[i], 1, kpos, krate, aref, gmin, x, u, g, 1, 1);
    launch(what, x0n, (maglev_real)1e-3, bad_n[i], 30, 1, 0, &s, gmin, 1);
  }
  for (h = 0; h < NH; ++h) {
    const maglev_real v = (maglev_real)hostile[h];
    const int bad_step = !(isfinite(v) && v > 0);
    sprintf(what, "dt %g", hostile[h]);
    sim(what, x0n, v, NS, 1, kpos, krate, aref, gmin, x, u, g, 1, bad_step);
    launch(what, x0n, v, NS, 30, 1, 0, &s, gmin, bad_step);
    sprintf(what, "F %g", hostile[h]);
    sim(what, x0n, (maglev_real)1e-3, NS, v, kpos, krate, aref, gmin, x, u, g, 1, !isfinite(v));
    launch(what, x0n, (maglev_real)1e-3, NS, 30, v, 0, &s, gmin, !isfinite(v));
    sprintf(what, "gap_min %g", hostile[h]);
    sim(what, x0n, (maglev_real)1e-3, NS, 1, kpos, krate, aref, v, x, u, g, 1, !isfinite(v));
    launch(what, x0n, (maglev_real)1e-3, NS, 30, 1, 0, &s, v, !isfinite(v));
    sprintf(what, "v_end %g", hostile[h]);
    launch(what, x0n, (maglev_real)1e-3, NS, v, 1, 0, &s, gmin, isnan(v));
    for (i = 0; i < 12; ++i) bad[i] = v;
    sprintf(what, "x0 all %g", hostile[h]);
    sim(what, bad, (maglev_real)1e-3, NS, 1, kpos, krate, aref, gmin, x, u, g, 1, 0);
    launch(what, bad, (maglev_real)1e-3, NS, 30, 1, 0, &s, gmin, 0);
    for (i = 0; i < 12; ++i) bad[i] = x0n[i];
    bad[2] = v;
    sprintf(what, "x0 z %g", hostile[h]);
    sim(what, bad, (maglev_real)1e-3, NS, 1, kpos, krate, aref, gmin, x, u, g, 1, 0);
    launch(what, bad, (maglev_real)1e-3, NS, 30, 1, 0, &s, gmin, 0);
    kpos[0] = v;
    sprintf(what, "K_pos[0] %g", hostile[h]);
    sim(what, x0n, (maglev_real)1e-3, NS, 1, kpos, krate, aref, gmin, x, u, g, 1, !isfinite(v));
    kpos[0] = (maglev_real)0.1;
    aref[1] = v;
    sprintf(what, "a_ref[1] %g", hostile[h]);
    sim(what, x0n, (maglev_real)1e-3, NS, 1, kpos, krate, aref, gmin, x, u, g, 1, !isfinite(v));
    aref[1] = 0;
    /* the schedule: spacing, first node, values */
    t = s;
    t.dv = v;
    sprintf(what, "schedule dv %g", hostile[h]);
    launch(what, x0n, (maglev_real)1e-3, NS, 30, 1, 0, &t, gmin, bad_step);
    eval(what, &t, 20, out, bad_step);
    t = s;
    t.v0 = v;
    sprintf(what, "schedule v0 %g", hostile[h]);
    launch(what, x0n, (maglev_real)1e-3, NS, 30, 1, 0, &t, gmin, !isfinite(v));
    eval(what, &t, 20, out, !isfinite(v));
    ys[MAGLEV_SCHEDULE_K_POS] = v;
    sprintf(what, "schedule value %g", hostile[h]);
    launch(what, x0n, (maglev_real)1e-3, NS, 30, 1, 1, &s, gmin, !isfinite(v));
    eval(what, &s, 20, out, 0);
    ys[MAGLEV_SCHEDULE_K_POS] = (maglev_real)0.05;
    sprintf(what, "v %g", hostile[h]);
    eval(what, &s, v, out, 0);
  }
  for (i = 0; i < (int)(sizeof bad_nodes / sizeof bad_nodes[0]); ++i) {
    t = s;
    t.n = bad_nodes[i];
    sprintf(what, "schedule n %d", bad_nodes[i]);
    launch(what, x0n, (maglev_real)1e-3, NS, 30, 1, 0, &t, gmin, 1);
    eval(what, &t, 20, out, 1);
  }
  for (i = 0; i < (int)(sizeof holds / sizeof holds[0]); ++i) {
    sprintf(what, "hold_steps %lld", holds[i]);
    launch(what, x0n, (maglev_real)1e-3, NS, 30, 1, holds[i], &s, gmin, holds[i] < 0);
  }
  t = s;
  t.y = 0;
  launch("schedule y NULL", x0n, (maglev_real)1e-3, NS, 30, 1, 0, &t, gmin, 1);
  eval("schedule y NULL", &t, 20, out, 1);
  t = s;
  t.d2y = 0;
  launch("schedule d2y NULL", x0n, (maglev_real)1e-3, NS, 30, 1, 0, &t, gmin, 1);
  eval("schedule d2y NULL", &t, 20, out, 1);
  t = s;
  t.v0 = (maglev_real)1e300;
  t.dv = (maglev_real)1e300;
  t.n = 3;
  eval("schedule last node overflows", &t, 20, out, !isfinite((maglev_real)3e300));
  launch("schedule NULL", x0n, (maglev_real)1e-3, NS, 30, 1, 0, 0, gmin, 1);
  eval("schedule NULL", 0, 20, out, 1);
  eval("out NULL", &s, 20, 0, 1);
  eval("nominal", &s, 20, out, 0);
  launch("nominal", x0n, (maglev_real)1e-3, NS, 30, 1, 0, &s, gmin, 0);
  launch("nominal held", x0n, (maglev_real)1e-3, NS, 30, 1, 2, &s, gmin, 0);
  /* the control loop (maglev_control_loop): a valid tick-held loop runs, each field out of
     its range is refused at entry */
  {
    static const maglev_control_loop good = {2, 1, (maglev_real)10, (maglev_real)20,
                                             (maglev_real)0.5, (maglev_real)1e4};
    maglev_control_loop bad_loop;
    loop_arg = &good;
    sim("loop tick", x0n, (maglev_real)1e-3, NS, 1, kpos, krate, aref, gmin, x, u, g, 1, 0);
    launch("loop tick", x0n, (maglev_real)1e-3, NS, 30, 1, 0, &s, gmin, 0);
    bad_loop = good;
    bad_loop.tick_steps = -1;
    loop_arg = &bad_loop;
    sim("loop tick_steps -1", x0n, (maglev_real)1e-3, NS, 1, kpos, krate, aref, gmin, x, u, g,
        1, 1);
    launch("loop tick_steps -1", x0n, (maglev_real)1e-3, NS, 30, 1, 0, &s, gmin, 1);
    bad_loop = good;
    bad_loop.tick_steps = LLONG_MAX;
    sim("loop tick_steps max", x0n, (maglev_real)1e-3, NS, 1, kpos, krate, aref, gmin, x, u, g,
        1, 0);
    launch("loop tick_steps max", x0n, (maglev_real)1e-3, NS, 30, 1, 0, &s, gmin, 0);
    for (i = 0; i < 4; ++i) {
      static const int delays[] = {-1, MAGLEV_SIM_MAX_DELAY + 1, INT_MAX, -2147483647 - 1};
      bad_loop = good;
      bad_loop.delay_ticks = delays[i];
      sprintf(what, "loop delay_ticks %d", delays[i]);
      sim(what, x0n, (maglev_real)1e-3, NS, 1, kpos, krate, aref, gmin, x, u, g, 1, 1);
      launch(what, x0n, (maglev_real)1e-3, NS, 30, 1, 0, &s, gmin, 1);
    }
    for (h = 0; h < NH; ++h) {
      const maglev_real v = (maglev_real)hostile[h];
      bad_loop = good;
      bad_loop.k_v = v;
      sprintf(what, "loop k_v %g", hostile[h]);
      sim(what, x0n, (maglev_real)1e-3, NS, 1, kpos, krate, aref, gmin, x, u, g, 1, !isfinite(v));
      launch(what, x0n, (maglev_real)1e-3, NS, 30, 1, 0, &s, gmin, !isfinite(v));
      bad_loop = good;
      bad_loop.v_ref = v;
      sprintf(what, "loop v_ref %g", hostile[h]);
      sim(what, x0n, (maglev_real)1e-3, NS, 1, kpos, krate, aref, gmin, x, u, g, 1, !isfinite(v));
      launch(what, x0n, (maglev_real)1e-3, NS, 30, 1, 0, &s, gmin, !isfinite(v));
      bad_loop = good;
      bad_loop.accel = v;
      sprintf(what, "loop accel %g", hostile[h]);
      sim(what, x0n, (maglev_real)1e-3, NS, 1, kpos, krate, aref, gmin, x, u, g, 1, !isfinite(v));
      launch(what, x0n, (maglev_real)1e-3, NS, 30, 1, 0, &s, gmin, !isfinite(v));
      bad_loop = good;
      bad_loop.force_budget = v;
      sprintf(what, "loop force_budget %g", hostile[h]);
      sim(what, x0n, (maglev_real)1e-3, NS, 1, kpos, krate, aref, gmin, x, u, g, 1, isnan(v));
      launch(what, x0n, (maglev_real)1e-3, NS, 30, 1, 0, &s, gmin, isnan(v));
    }
    loop_arg = 0;
  }
  P_HOSTILE_CASES
}
""")


def _p_run_code(carriage: DerivedCarriage, runtime: bool) -> dict[str, str]:
    """The run-time parameter parts of _run_code's C (empty with baked parameters)."""
    if not runtime:
        return {"P_NOMINAL": "", "P_NULL_CASE": "", "P_HOSTILE_CASES": ""}
    names = carriage.structure.param_names
    values = ", ".join(repr(float(v)) for v in carriage.p)
    hostile = [("vehicle.mass", "0.0"), ("vehicle.mass", "-1.0"),
               ("halbach.wavelength", "0.0"), ("circuit.resistance", "-1e-3"),
               ("circuit.inductance", "0.0"), ("vehicle.mass", "NAN")]
    cases = "".join(
        f"  run_nominal(); pbuf[{names.index(k)}] = (maglev_real){v};\n"
        f"  sim(\"p {k} = {v}\", x0n, (maglev_real)1e-3, NS, 1, kpos, krate, aref, gmin, x, u, "
        "g, 1, 2);\n"
        f"  launch(\"p {k} = {v}\", x0n, (maglev_real)1e-3, NS, 30, 1, 0, &s, gmin, 2);\n"
        for k, v in hostile)
    return {
        "P_NOMINAL": f"{{ static const double pv[] = {{{values}}}; for (i = 0; i < "
                     f"{len(names)}; ++i) pbuf[i] = (maglev_real)pv[i]; p_arg = pbuf; }}",
        "P_NULL_CASE": "p_arg = 0;\n  sim(\"p NULL\", x0n, (maglev_real)1e-3, NS, 1, kpos, "
                       "krate, aref, gmin, x, u, g, 1, 1);\n  launch(\"p NULL\", x0n, "
                       "(maglev_real)1e-3, NS, 30, 1, 0, &s, gmin, 1);\n  p_arg = pbuf;",
        "P_HOSTILE_CASES": cases + "  run_nominal();",
    }


_GAIN_TABLE_CASES = r"""
#include <math.h>
#include <stdio.h>
#include "maglev_gain_table.h"

/* maglev_schedule (the gain table) under hostile speeds and a NULL out */
void run_gain_table(long* calls, long* failures, const double* hostile, int nh) {
  maglev_real out[MAGLEV_SCHEDULE_NOUT];
  int h, i, rc, ok;
  for (h = 0; h <= nh; ++h) {
    const maglev_real v = h < nh ? (maglev_real)hostile[h] : (maglev_real)20;
    for (i = 0; i < MAGLEV_SCHEDULE_NOUT; ++i) out[i] = (maglev_real)7;
    rc = maglev_schedule(v, out);
    ok = rc == MAGLEV_OK || rc == MAGLEV_ERR_SPEED || rc == MAGLEV_ERR_NONFINITE;
    for (i = 0; i < MAGLEV_SCHEDULE_NOUT; ++i) {
      if (rc == MAGLEV_ERR_NONFINITE ? out[i] != 0 : !isfinite(out[i])) ok = 0;
    }
    ++*calls;
    if (!ok) { ++*failures; printf("FAIL maglev_schedule v=%g rc=%d\n", (double)v, rc); }
    rc = maglev_schedule(v, 0);
    ++*calls;
    if (rc != MAGLEV_ERR_ARGUMENT) {
      ++*failures;
      printf("FAIL maglev_schedule out NULL v=%g rc=%d\n", (double)v, rc);
    }
  }
}
"""

_MAIN = r"""
void run_gain_table(long* calls, long* failures, const double* hostile, int nh);

int main(void) {
  int major = -1, minor = -1, patch = -1;
  maglev_functions_casadi_version(0, 0, 0);  /* NULL: the numbers skipped */
  maglev_functions_casadi_version(&major, 0, 0);
  maglev_functions_casadi_version(&major, &minor, &patch);
  record("maglev_functions_casadi_version", "version", major, major >= 0 && minor >= 0);
  record("maglev_functions_casadi_int_size", "size",
         maglev_functions_casadi_int_size(),
         maglev_functions_casadi_int_size() == (int)sizeof(maglev_int));
  record("maglev_functions_casadi_real_size", "size",
         maglev_functions_casadi_real_size(),
         maglev_functions_casadi_real_size() == (int)sizeof(maglev_real));
  run_all_casadi();
  run_simulations();
  run_lyapunov();
  run_gain_table(&calls, &failures, hostile, NH);
  printf("CALLS %ld FAILURES %ld\n", calls, failures);
  return failures != 0;
}
"""


def _gain_table_sources() -> dict[str, str]:
    """maglev_gain_table.{c,h} of a table with every value stored (random coefficients: the
    hostile cases test the evaluator's checks, not the fit)."""
    from maglevgen.control.schedule import (
        GAIN_TABLE_FIELDS,
        GAIN_TABLE_NY,
        GainTable,
        gain_table_sources,
    )

    coeffs = np.random.default_rng(40).normal(size=(8, GAIN_TABLE_NY))
    table = GainTable(6.5, 40.0, coeffs, {n: 0.0 for n, _ in GAIN_TABLE_FIELDS},
                      tuple(range(GAIN_TABLE_NY)))
    return gain_table_sources(table)


def _harness(src: Path, table: list[dict], carriage: DerivedCarriage, runtime: bool) -> str:
    from maglevgen.codegen.checks import error_defines

    nu = len(carriage.model.input_names)
    ng = len(carriage.model.arrays)
    run = _run_code(runtime, nu, ng)
    for key, text in _p_run_code(carriage, runtime).items():
        run = run.replace(key, text)
    prelude = _PRELUDE.replace("HOSTILE_VALUES", ", ".join(HOSTILE))
    return (error_defines() + f"#define MAX_CODE {max(v for v, _ in ERROR_CODES.values())}\n"
            + prelude + _hostile_parameter_code(carriage) + _casadi_calls(table, carriage,
                                                                          runtime)
            + run + _MAIN)


def _build(src: Path, out: Path, table: list[dict], carriage: DerivedCarriage,
           runtime: bool) -> subprocess.Popen:
    """Write the harness into ``out`` and start compiling it with the sanitizers (the
    generated C of ``src`` included); returns the compiler process (make's -j, in one)."""
    out.mkdir(parents=True, exist_ok=True)
    for name in ("maglev_functions.c", "maglev_functions.h", "maglev_simulate.c",
                 "maglev_simulate.h"):
        (out / name).write_text((src / name).read_text())
    for name, text in _gain_table_sources().items():
        (out / name).write_text(text)
    (out / "harness.c").write_text(_harness(src, table, carriage, runtime))
    (out / "gain_table_cases.c").write_text(_GAIN_TABLE_CASES)
    flags = ["-std=c99", "-O0", "-g", "-Wall", "-Wno-unused-function", "-Wno-unused-variable",
             *SANITIZE]
    script = (
        f"cc {' '.join(flags)} -c gain_table_cases.c &&"  # double: maglev_functions.h's
        f" cc {' '.join(flags)} -c maglev_gain_table.c &&"
        f" cc {' '.join(flags)} -c harness.c maglev_simulate.c maglev_functions.c &&"
        f" cc {' '.join(SANITIZE)} harness.o maglev_simulate.o maglev_functions.o"
        " gain_table_cases.o maglev_gain_table.o -lm -o harness")
    return subprocess.Popen(["sh", "-c", script], cwd=out, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


@pytest.fixture(scope="module")
def harnesses(carriage: DerivedCarriage, tmp_path_factory, private_cache) -> dict[str, tuple]:
    """{"baked": ..., "runtime": ...}: (source folder, function table, harness folder) of the
    committed generated/ (baked, double) and of the simulation library's run-time-parameter C,
    both compiled with the sanitizers (in parallel)."""
    from maglevgen.codegen.interface import FUNCTION_TABLE
    from maglevgen.runtime.library import runtime_sources

    runtime_src = runtime_sources(carriage.structure)
    cases = {
        "baked": (REPO / "generated",
                  json.loads((REPO / "generated" / "manifest.json").read_text())["functions"]),
        "runtime": (runtime_src, json.loads((runtime_src / FUNCTION_TABLE).read_text())),
    }
    base = tmp_path_factory.mktemp("failsafe")
    procs = {k: _build(src, base / k, table, carriage, k == "runtime")
             for k, (src, table) in cases.items()}
    for k, proc in procs.items():
        log, _ = proc.communicate()
        assert proc.returncode == 0, f"{k} harness did not compile:\n{log[-4000:]}"
    return {k: (src, table, base / k) for k, (src, table) in cases.items()}


@pytest.mark.needs_cc
@pytest.mark.parametrize("kind", ["baked", "runtime"])
def test_every_declared_function_is_called(harnesses, kind: str) -> None:
    """The harness covers exactly the functions the headers declare: the CasADi API ones
    (from the function table) with their companions, and the four with their own signature."""
    src, table, out = harnesses[kind]
    headers = [src / "maglev_functions.h", src / "maglev_simulate.h",
               out / "maglev_gain_table.h"]
    if (src / "maglev.h").exists():
        headers.append(src / "maglev.h")
    declared = _declared(headers)
    covered = {f["name"] for f in table} | {f"{f['name']}_{c}" for f in table
                                             for c in COMPANIONS} | set(OWN_SIGNATURE)
    assert declared == covered, (sorted(declared - covered), sorted(covered - declared))
    assert {"maglev_dynamics", "maglev_trim", "maglev_simulate", "maglev_schedule"} <= declared


@pytest.mark.needs_cc
@pytest.mark.parametrize("kind", ["baked", "runtime"])
def test_hostile_inputs_under_sanitizers(harnesses, kind: str) -> None:
    """Every call of the harness: no sanitizer report, no crash, and either an error code
    (outputs zeroed; -1 and MAGLEV_SIM_ARGUMENT for a run) or 0 with every output finite;
    NULL arg/res/work arrays, invalid counts, steps and schedules, hostile parameter vectors
    (mass, wavelength, resistance, inductance zero or negative, NaN in each entry) refused."""
    _, table, out = harnesses[kind]
    run = subprocess.run([str(out / "harness")], cwd=out, capture_output=True, text=True,
                         timeout=300, env={"ASAN_OPTIONS": "detect_leaks=0:abort_on_error=0",
                                           "UBSAN_OPTIONS": "print_stacktrace=1"})
    report = run.stderr + run.stdout
    assert "runtime error" not in report and "AddressSanitizer" not in report, report[-4000:]
    assert run.returncode == 0, report[-4000:]
    m = re.search(r"CALLS (\d+) FAILURES (\d+)", run.stdout)
    assert m is not None, report[-2000:]
    # the number of calls the table implies: at least the hostile values into each input
    per_input = 2 * len(HOSTILE)
    floor = sum(per_input * len(f["inputs"]) for f in table)
    assert int(m.group(1)) > floor, (m.group(1), floor)
    assert int(m.group(2)) == 0, run.stdout[-4000:]


# ------------------------------------------------------------------------------------- FMU

_FMU_DRIVER = r'''
import ctypes, json, math, sys
from ctypes import byref
from fmpy import calloc, extract, free, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (FMU2Slave, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                       fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
from fmpy.logging import addLoggerProxy

path = sys.argv[1]
md = read_model_description(path)
unzipped = extract(path)
settable = [v for v in md.modelVariables if v.causality in ("parameter", "input")
            and v.type == "Real"]
outputs = [v.valueReference for v in md.modelVariables if v.type == "Real"]
cb = fmi2CallbackFunctions()
cb.logger = fmi2CallbackLoggerTYPE(lambda *a: None)
cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
addLoggerProxy(byref(cb))
bad = []

slave = FMU2Slave(guid=md.guid, unzipDirectory=unzipped,
                  modelIdentifier=md.coSimulation.modelIdentifier, instanceName="h")

def new():
    """a fresh instance of the one loaded FMU"""
    slave.instantiate(callbacks=cb)
    return slave

def drop(fmu):
    """free the instance, keep the library loaded (FMPy's freeInstance also unloads it)"""
    fmu.fmi2FreeInstance(fmu.component)

def refused(call):
    try:
        call()
    except FMICallException:
        return True
    return False

def finish(fmu, what):
    """exit initialization, a step, every real: refused, or OK with finite values"""
    try:
        fmu.exitInitializationMode()
        fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=1e-3)
        values = fmu.getReal(outputs)
        if not all(math.isfinite(v) for v in values):
            bad.append(what + ": fmi2OK with a non-finite output")
    except FMICallException:
        pass
    refused(fmu.terminate)  # refused in the error state a refused call leaves
    drop(fmu)

n = 0
for v in settable:
    for value in HOSTILE:
        fmu = new()
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        n += 1
        if refused(lambda: fmu.setReal([v.valueReference], [value])):
            if not math.isfinite(value):
                drop(fmu)  # the refusal left the error state: only freeing is left to do
                continue
        elif not math.isfinite(value):
            bad.append(f"{v.name} = {value}: accepted")
        finish(fmu, f"{v.name} = {value}")
# out of order
# (a refused call leaves the error state: each case from a fresh instance, in step mode)
def stepping():
    fmu = new()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    return fmu

fmu = new()
n += 1
if not refused(lambda: fmu.doStep(currentCommunicationPoint=0.0, communicationStepSize=1e-3)):
    bad.append("doStep before initialization accepted")
drop(fmu)
fmu = new()
n += 1
if not refused(lambda: fmu.exitInitializationMode()):
    bad.append("exitInitializationMode before enter accepted")
drop(fmu)
fmu = new()
fmu.setupExperiment(startTime=0.0)
fmu.enterInitializationMode()
n += 1
if not refused(lambda: fmu.enterInitializationMode()):
    bad.append("enterInitializationMode twice accepted")
drop(fmu)
fmu = stepping()
n += 1
if not refused(lambda: fmu.setupExperiment(startTime=0.0)):
    bad.append("setupExperiment after initialization accepted")
drop(fmu)
for h in (float("nan"), float("inf"), -1e-3, 0.0, 1e300):
    fmu = stepping()
    n += 1
    if not refused(lambda: fmu.doStep(currentCommunicationPoint=0.0,
                                      communicationStepSize=h)):
        bad.append(f"doStep h = {h} accepted")
    values = fmu.getReal(outputs)
    if not all(math.isfinite(v) for v in values):
        bad.append(f"non-finite outputs after the refused step h = {h}")
    drop(fmu)
for t in (float("nan"), float("inf")):
    fmu = stepping()
    n += 1
    if not refused(lambda: fmu.doStep(currentCommunicationPoint=t,
                                      communicationStepSize=1e-3)):
        bad.append(f"doStep t = {t} accepted")
    drop(fmu)
# model exchange: hostile states and times
from fmpy.fmi2 import FMU2Model
me = FMU2Model(guid=md.guid, unzipDirectory=unzipped,
               modelIdentifier=md.modelExchange.modelIdentifier, instanceName="m")

def continuous():
    me.instantiate(callbacks=cb)
    me.setupExperiment(startTime=0.0)
    me.enterInitializationMode()
    me.exitInitializationMode()
    me.enterContinuousTimeMode()

nx = md.numberOfContinuousStates
Vec = ctypes.c_double * nx
for value in HOSTILE:
    n += 2
    if not math.isfinite(value):
        continuous()
        if not refused(lambda: me.setContinuousStates(Vec(*[value] * nx), nx)):
            bad.append(f"ME states = {value} accepted")
        me.fmi2FreeInstance(me.component)
        continuous()
        if not refused(lambda: me.setTime(value)):
            bad.append(f"ME time = {value} accepted")
        me.fmi2FreeInstance(me.component)
        continue
    continuous()
    try:
        me.setContinuousStates(Vec(*[value] * nx), nx)
        dx = Vec()
        me.getDerivatives(dx, nx)
        if not all(math.isfinite(v) for v in dx):
            bad.append(f"ME states = {value}: OK with non-finite derivatives")
    except FMICallException:
        pass
    me.fmi2FreeInstance(me.component)
print(json.dumps({"calls": n, "bad": bad}))
'''


@pytest.mark.needs_cc
@pytest.mark.parametrize("loop", ["continuous", "firmware"])
def test_fmu_hostile_values_and_out_of_order_calls(carriage: DerivedCarriage, sim_lib,
                                                   tmp_path: Path, loop: str) -> None:
    """Through FMPy (in a child process, so that a crash is a failure, not the end of the
    run): NaN, +-inf, +-1e30, denormals, zero and -1 into every real parameter and input
    before initialization, and out-of-order calls (a step before initialization, entering
    it twice, NaN/inf/negative/zero/huge communication steps and times; model exchange:
    the hostile values as every state and as the time): each is refused (fmi2Error or
    fmi2Discard) or followed by OK calls with every real finite. Both loops: the firmware
    loop's FMU adds the tick law's gains, the lag and the lagged forces' states."""
    import sys

    from maglevgen.control.built_loop import Loop
    from maglevgen.control.carriage_plant import Plant
    from maglevgen.exports.fmu import build_fmu

    path = tmp_path / "m.fmu"
    path.write_bytes(build_fmu(Plant(carriage), "both", "lqr", loop=Loop(loop)))
    hostile = [float("nan"), float("inf"), float("-inf"), 1e30, -1e30, 5e-324, 0.0, -1.0]
    driver = _FMU_DRIVER.replace("HOSTILE", repr(hostile).replace("nan", "float('nan')")
                                 .replace("inf", "float('inf')"))
    run = subprocess.run([sys.executable, "-c", driver, str(path)], capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    result = json.loads(run.stdout.strip().splitlines()[-1])
    assert result["calls"] > 8 * 10, result["calls"]
    assert result["bad"] == [], result["bad"][:20]


# ------------------------------------------------------------------------------------- CLI

def _cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    import sys

    return subprocess.run([sys.executable, "-m", "maglevgen.cli", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=600)


def _one_line_error(run: subprocess.CompletedProcess, *words: str) -> None:
    """Exit 2, nothing but one line on stderr, starting maglevgen: error: and naming words."""
    lines = run.stderr.splitlines()
    assert run.returncode == 2, (run.returncode, run.stderr[-2000:])
    assert len(lines) == 1 and lines[0].startswith("maglevgen: error: "), run.stderr[-2000:]
    for w in words:
        assert w in lines[0], (w, lines[0])


@pytest.mark.parametrize("depth", [50, 3000])
def test_deeply_nested_tables_are_refused(tmp_path: Path, depth: int) -> None:
    """[a.a.a...] table headers (not inline tables) nested past the schema's depth: exit 2
    and one line naming the key (before: RecursionError, exit 1)."""
    f = tmp_path / "deep.toml"
    f.write_text("[" + ".".join(["deep"] * depth) + "]\nx = 1\n")
    _one_line_error(_cli("trim", "--params", str(f), cwd=tmp_path), "deep.deep", "nested")


def test_negative_seed_is_refused(tmp_path: Path) -> None:
    _one_line_error(_cli("montecarlo", "--seed", "-1", "--samples", "2", cwd=tmp_path),
                    "--seed -1")


@pytest.mark.parametrize("args", [("trim", "--bogus"), ("trim", "--speed", "fast"),
                                  ("nosuchcommand",), ()])
def test_argparse_errors_are_one_line(tmp_path: Path, args: tuple[str, ...]) -> None:
    """Unknown options, bad values, unknown and missing commands: one line with a pointer to
    --help, no usage block."""
    _one_line_error(_cli(*args, cwd=tmp_path), "--help")


@pytest.mark.needs_cc
def test_build_below_lift_off_is_one_line(tmp_path: Path, sim_lib) -> None:
    """envelope.v_min below lift-off (1 m/s; the derivation's lift-off is about 6 m/s):
    the error is the only line on stderr, no progress line before it."""
    _one_line_error(_cli("build", "--set", "envelope.v_min=1.0", "--no-pdf", "--out",
                         str(tmp_path / "out"), cwd=tmp_path), "envelope.v_min")
    assert not (tmp_path / "out").exists()
