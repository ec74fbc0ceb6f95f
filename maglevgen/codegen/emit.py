"""The one way C (and every other generated text file) is written: jinja2 templates.

`template_env` loads templates/ with the filters the C templates share; `c_literal` is the one
formatter of a floating value as a C literal of a precision (the templates' ``c`` filter, and
what the Python side passes to them where a literal is an argument). The regex pass over
CasADi's own output (maglevgen.codegen.cpass) is the only C that is rewritten rather than
rendered.

Light on purpose (numpy and jinja2): the gain schedule's and the FMU's C are rendered from
the simulation path.
"""

from __future__ import annotations

from functools import cache
from importlib import resources

import jinja2
import numpy as np

__all__ = ["c_literal", "float_literal", "render", "template_env"]


def _as_float32(value: float) -> float:
    """Round a double to the nearest IEEE single (inf beyond range), like a C ``(float)`` cast."""
    with np.errstate(over="ignore"):
        return float(np.float32(value))


def float_literal(value: float) -> str:
    """Print a non-negative double as a C float constant with the same float value.

    Integers up to 2**24 print as ``2.0f``; others with 9 significant digits (enough to round-trip
    any float) as ``1.00000001e-01f``; a value beyond float range becomes ``INFINITY`` (a float
    constant in C99) and one that underflows becomes ``0.0f``, which is what a cast would give and
    keeps clang's literal-range warnings quiet.
    """
    f32 = _as_float32(value)
    if f32 == float("inf"):
        return "INFINITY"
    if f32 == int(f32) and f32 <= 2.0**24:
        return f"{int(f32)}.0f"
    return f"{f32:.8e}f"


def c_literal(value: float, precision: str = "double") -> str:
    """``value`` as a C literal of ``precision``: double, the shortest text that reads back
    as the same double (``repr``); single, `float_literal` of the value rounded to float
    (signed), so that the literal is that float whatever the compiler's rounding of a
    decimal. Deterministic text."""
    if precision == "single":
        v = float(value)
        return f"-{float_literal(-v)}" if v < 0 else float_literal(v)
    if precision != "double":
        raise ValueError(f"precision must be 'double' or 'single', not {precision!r}")
    return repr(float(value))


@cache
def template_env() -> jinja2.Environment:
    """The templates' environment: strict undefined names, text kept as written (no
    whitespace trimming, the trailing newline kept), no escaping; the filter ``c``
    (`c_literal`)."""
    path = resources.files("maglevgen.templates")
    env = jinja2.Environment(loader=jinja2.FileSystemLoader(str(path)),
                             undefined=jinja2.StrictUndefined, keep_trailing_newline=True,
                             trim_blocks=False, lstrip_blocks=False, autoescape=False)
    env.filters["c"] = c_literal
    return env


def render(template: str, **context: object) -> str:
    """``templates/<template>`` rendered with ``context``."""
    return template_env().get_template(template).render(**context)
