"""The closed loop in JAX (jit + vmap + scan, CPU, float64) for bench/casadi_peer.py (issue 53).

The model is not written again: `sx_to_jax` translates the project's SX function
(``maglev_closed_loop``, the graph CasADi's codegen prints as C) instruction by instruction,
one jax.numpy operation for each of CasADi's (``if_else_zero`` as ``jnp.where``: both sides
computed, as CasADi's C does). `jax_simulation` puts it under the RK4 step
bench/casadi_peer.py gives CasADi (the same expressions; the four stages one copy of the
graph under a ``lax.scan`` over their offsets, which shortens XLA's compile about 2.5x
against four copies and runs no slower), ``lax.scan`` over the steps and ``vmap`` over the
runs, and compiles it once (``jit(...).lower(...).compile()``, timed).

JAX is an optional bench dependency (``pip install -e '.[bench]'``, which `make bench`
installs): `available` says whether it imports, and why not.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable

import casadi as ca
import numpy as np

#: one thread, as the other contenders: XLA's CPU client otherwise runs Eigen's thread pool
XLA_ONE_THREAD = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"

#: CasADi's unary operations (instruction id -> jax.numpy text of argument ``a``)
_UNARY = {"OP_NEG": "-{a}", "OP_EXP": "jnp.exp({a})", "OP_LOG": "jnp.log({a})",
          "OP_SQRT": "jnp.sqrt({a})", "OP_SQ": "{a} * {a}", "OP_TWICE": "2.0 * {a}",
          "OP_INV": "1.0 / {a}", "OP_SIN": "jnp.sin({a})", "OP_COS": "jnp.cos({a})",
          "OP_TAN": "jnp.tan({a})", "OP_ASIN": "jnp.arcsin({a})", "OP_ACOS": "jnp.arccos({a})",
          "OP_ATAN": "jnp.arctan({a})", "OP_SINH": "jnp.sinh({a})",
          "OP_COSH": "jnp.cosh({a})", "OP_TANH": "jnp.tanh({a})", "OP_FABS": "jnp.abs({a})",
          "OP_SIGN": "jnp.sign({a})", "OP_FLOOR": "jnp.floor({a})", "OP_CEIL": "jnp.ceil({a})",
          "OP_NOT": "jnp.where({a} == 0, 1.0, 0.0)", "OP_ASSIGN": "{a}",
          "OP_ERF": "jax.scipy.special.erf({a})", "OP_LOG1P": "jnp.log1p({a})",
          "OP_EXPM1": "jnp.expm1({a})"}
#: CasADi's binary operations (arguments ``a``, ``b``); comparisons give 0.0 or 1.0 as in C
_BINARY = {"OP_ADD": "{a} + {b}", "OP_SUB": "{a} - {b}", "OP_MUL": "{a} * {b}",
           "OP_DIV": "{a} / {b}", "OP_POW": "jnp.power({a}, {b})",
           "OP_CONSTPOW": "jnp.power({a}, {b})", "OP_ATAN2": "jnp.arctan2({a}, {b})",
           "OP_FMIN": "jnp.fmin({a}, {b})", "OP_FMAX": "jnp.fmax({a}, {b})",
           "OP_HYPOT": "jnp.hypot({a}, {b})", "OP_COPYSIGN": "jnp.copysign({a}, {b})",
           "OP_FMOD": "jnp.fmod({a}, {b})",
           "OP_LT": "jnp.where({a} < {b}, 1.0, 0.0)", "OP_LE": "jnp.where({a} <= {b}, 1.0, 0.0)",
           "OP_EQ": "jnp.where({a} == {b}, 1.0, 0.0)", "OP_NE": "jnp.where({a} != {b}, 1.0, 0.0)",
           "OP_AND": "jnp.where(({a} != 0) & ({b} != 0), 1.0, 0.0)",
           "OP_OR": "jnp.where(({a} != 0) | ({b} != 0), 1.0, 0.0)",
           "OP_IF_ELSE_ZERO": "jnp.where({a} != 0, {b}, 0.0)"}
#: the instructions that move data rather than compute (left out of the operation count)
DATA_OPS = ("OP_INPUT", "OP_OUTPUT", "OP_CONST", "OP_PARAMETER")


def _op_names() -> dict[int, str]:
    return {getattr(ca, n): n for n in dir(ca) if n.startswith("OP_")}


def operation_count(f: ca.Function) -> dict[str, int]:
    """The arithmetic instructions of an SX function by CasADi's operation name (inputs,
    outputs and constants left out): what one evaluation executes, both sides of every
    ``if_else`` included (CasADi's SX computes both)."""
    names = _op_names()
    count: dict[str, int] = {}
    for k in range(f.n_instructions()):
        op = names[f.instruction_id(k)]
        if op not in DATA_OPS:
            count[op] = count.get(op, 0) + 1
    return dict(sorted(count.items(), key=lambda kv: -kv[1]))


def sx_to_source(f: ca.Function, output: str) -> str:
    """Python text of ``def rhs(*inputs)``: f's output ``output`` (dense) from f's inputs
    (each a 1-D array of its nonzeros, column-major), one statement per SX instruction."""
    if not f.is_a("SXFunction"):
        raise TypeError(f"{f.name()} is not an SX function")
    names = _op_names()
    o_want = f.index_out(output)
    if f.sparsity_out(o_want).nnz() != f.numel_out(o_want):
        raise ValueError(f"{f.name()}'s {output} is not dense")
    lines = [f"def rhs({', '.join(f'i{i}' for i in range(f.n_in()))}):"]
    out = [None] * f.nnz_out(o_want)
    for k in range(f.n_instructions()):
        op = names[f.instruction_id(k)]
        arg, res = f.instruction_input(k), f.instruction_output(k)
        if op == "OP_INPUT":
            lines.append(f"    w{res[0]} = i{arg[0]}[{arg[1]}]")
        elif op == "OP_OUTPUT":
            if res[0] == o_want:
                # the work slot may be reused afterwards: keep the value under a name of its own
                lines.append(f"    o{res[1]} = w{arg[0]}")
                out[res[1]] = f"o{res[1]}"
        elif op == "OP_CONST":
            lines.append(f"    w{res[0]} = {float(f.instruction_constant(k))!r}")
        elif op in _UNARY:
            lines.append(f"    w{res[0]} = " + _UNARY[op].format(a=f"w{arg[0]}"))
        elif op in _BINARY:
            lines.append(f"    w{res[0]} = " + _BINARY[op].format(a=f"w{arg[0]}",
                                                                  b=f"w{arg[1]}"))
        else:
            raise NotImplementedError(f"{f.name()}: CasADi's {op} has no JAX translation here")
    if any(o is None for o in out):
        raise ValueError(f"{f.name()}'s {output} has entries no instruction writes")
    lines.append(f"    return jnp.stack([{', '.join(out)}])")
    return "\n".join(lines) + "\n"


def available() -> str | None:
    """None when JAX imports (on one thread, float64), else why not."""
    os.environ.setdefault("XLA_FLAGS", XLA_ONE_THREAD)
    try:
        import jax
    except ImportError as e:
        return f"JAX is not installed ({e}); pip install -e '.[bench]' adds it"
    jax.config.update("jax_enable_x64", True)
    jax.config.update("jax_platforms", "cpu")
    return None


def sx_to_jax(f: ca.Function, output: str = "xdot") -> Callable:
    """f's ``output`` as a Python function of f's inputs in jax.numpy (`sx_to_source`)."""
    import jax
    import jax.numpy as jnp
    scope = {"jax": jax, "jnp": jnp}
    exec(compile(sx_to_source(f, output), f"<{f.name()} in JAX>", "exec"), scope)
    return scope["rhs"]


def jax_simulation(closed_loop: ca.Function, n_steps: int, dt: float,
                   x0s: np.ndarray, thetas: dict[str, np.ndarray]):
    """(run, compile seconds {"wall", "cpu"}): ``run()`` -> the final states (n_x, runs) of
    RK4 at ``dt`` over ``n_steps`` steps of ``closed_loop``'s xdot, each run from its column
    of ``x0s`` with its slice of ``thetas`` (name -> array with the runs first; the inputs
    other than x), as one compiled XLA executable: jit of vmap (over the runs) of lax.scan (over the
    steps)."""
    import jax
    import jax.numpy as jnp
    rhs = sx_to_jax(closed_loop)
    names = [n for n in closed_loop.name_in() if n != "x"]
    at_x = closed_loop.index_in("x")

    def f(x, theta):
        args = [None] * closed_loop.n_in()
        args[at_x] = x
        for n, v in zip(names, theta, strict=True):
            args[closed_loop.index_in(n)] = v
        return rhs(*args)

    # the stages' offsets: k1 at x + 0 k0 (k0 = 0), k2 at x + dt/2 k1, k3 at x + dt/2 k2,
    # k4 at x + dt k3, as bench/casadi_peer.py's RK4 step (x + 0 k0 is x but for a -0.0)
    offsets = jnp.array([0.0, dt / 2, dt / 2, dt])

    def one(x0, theta):
        def step(x, _):
            def stage(k, c):
                k_next = f(x + c * k, theta)
                return k_next, k_next
            # one copy of the graph for XLA to compile, not four: a scan over the stages
            k1, k2, k3, k4 = jax.lax.scan(stage, jnp.zeros_like(x), offsets)[1]
            return x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4), None
        return jax.lax.scan(step, x0, None, length=n_steps)[0]

    batch = jax.jit(jax.vmap(one))
    xs = jnp.asarray(np.ascontiguousarray(x0s.T))
    th = [jnp.asarray(np.ascontiguousarray(thetas[n])) for n in names]
    t0, c0 = time.perf_counter(), time.process_time()
    compiled = batch.lower(xs, th).compile()
    compile_s = {"wall": time.perf_counter() - t0, "cpu": time.process_time() - c0}

    def run() -> np.ndarray:
        return np.asarray(compiled(xs, th).block_until_ready()).T

    return run, compile_s
