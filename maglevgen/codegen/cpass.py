"""Turn CasADi-generated C into firmware-grade C.

CasADi 3.8.2's generated C does not compile under ``-Wall -Wextra -Wpedantic -Werror`` (unused
``iw``/``w``/``mem`` parameters, clang's float-to-bool warnings on ``(a1?x:0)``/``(!a1)``), and
with ``casadi_real=float`` it still calls the double math functions and prints double literals,
so ``-Wdouble-promotion -Wfloat-conversion`` fail. :func:`postprocess` rewrites the text so that it
compiles warning-free with gcc and clang (``-std=c99``) under those flags plus ``-Wconversion``;
:func:`generate_c` runs ``casadi.CodeGenerator`` and applies it.

Design choices:

* Explicit float math (``sinf``, ``sqrtf``...) rather than ``<tgmath.h>``: the explicit names are
  plain C99 ``<math.h>``, work identically in gcc, clang, newlib and when the file is built as C++
  (CasADi wraps it in ``extern "C"``; ``<tgmath.h>`` is a different header in C++), and a missed
  double literal cannot silently select the double overload.
* ``casadi_int`` defaults to ``long long int`` (CasADi's own default): ``casadi.external`` reads the
  sparsity arrays as 64-bit, and a library built with ``int`` crashes it. Pass ``int_type="int"``
  for firmware that never goes through ``casadi.external``.
* The ``#ifndef casadi_real`` guards become ``#undef``/``#define``: float literals and ``sinf``
  are only right for the precision chosen at generation time, and two generated headers of
  different precision included in one translation unit must each declare their own ABI.
* Truth tests of reals are written as comparisons with 0 (``(a1!=0?x:0)``, ``(a1==0)``), which C
  defines to be the same thing, because clang flags the implicit real-to-bool conversion.
* Writable static or global data (CasADi emits it for functions with memory, e.g. ``nlpsol``) is
  not re-entrant firmware code: the pass refuses it with ``ValueError`` rather than hiding it.

Why a pass over the text at all: CasADi 3.8.2's ``CodeGenerator`` options (``casadi_real``,
``casadi_int``, ``with_header``, ``main``, ``mex``, ``cpp``, ...) choose the types, not the
math functions, the literals, the truth tests or the unused parameters, and
tests/test_cpass.py::test_raw_casadi_output_fails_the_same_flags shows its raw output failing
the flags. Every C file the toolchain writes otherwise comes from a template
(maglevgen.codegen.emit); this module is the one place that edits CasADi's text, on tokens
where the edit needs the C's structure. Besides :func:`postprocess`, :func:`static_helpers`
makes CasADi's runtime helpers static in every generated .c (external, a shared library
calls each ``casadi_fabs`` through the PLT: the distributed force law's right-hand side made
48 such calls per evaluation); for the checked entry points (maglevgen.codegen.checks):
:func:`unchecked_entry_points` makes each entry point a ``static NAME_unchecked``,
:func:`null_safe_version` guards the version function's pointers. Each refuses a text it
does not find where it expects it.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import tempfile
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any, Literal, NamedTuple, cast, get_args

import casadi as ca

from maglevgen.codegen.branches import guard_discarded_branches
from maglevgen.codegen.emit import float_literal, render

Precision = Literal["double", "single"]

__all__ = ["DOUBLE_MATH", "CompileError", "compile_check", "generate_c",
           "guard_discarded_branches", "null_safe_version", "postprocess", "static_helpers",
           "unchecked_entry_points"]


def _words(text: str) -> frozenset[str]:
    """The whitespace-separated words of ``text``."""
    return frozenset(text.split())


#: C99 <math.h> functions that take and return double and have a float ``...f`` variant.
DOUBLE_MATH = _words("""
    acos acosh asin asinh atan atan2 atanh cbrt ceil copysign cos cosh erf erfc exp exp2 expm1
    fabs fdim floor fma fmax fmin fmod frexp hypot ldexp lgamma llrint llround log log10 log1p
    log2 logb lrint lround modf nearbyint nextafter pow remainder remquo rint round scalbln
    scalbn sin sinh sqrt tan tanh tgamma trunc
""")

#: Tokens that can start a declaration at the top of a CasADi function body.
_DECL_START = _words("""
    casadi_real casadi_int const int float double char unsigned signed long short struct union
    enum static void size_t volatile register _Bool typedef
""")

_OPENERS = frozenset("([{")
_CLOSERS = frozenset(")]}")

_LEX = re.compile(
    r"""
    (?P<comment>/\*.*?\*/|//[^\n]*)
  | (?P<string>"(?:\\.|[^"\\\n])*"|'(?:\\.|[^'\\\n])*')
  | (?P<number>\.?\d(?:[eEpP][+-]|[\w.])*)
  | (?P<ident>[A-Za-z_]\w*)
  | (?P<newline>\n)
  | (?P<space>(?:[ \t\r\f\v]|\\\n)+)
  | (?P<punct>->|\+\+|--|&&|\|\||[<>=!]=|<<=?|>>=?|[-+*/%&|^]=|\#\#|.)
    """,
    re.VERBOSE | re.DOTALL,
)


_NON_CODE = re.compile(
    r"""/\*.*?\*/|//[^\n]*|"(?:\\.|[^"\\\n])*"|'(?:\\.|[^'\\\n])*'""", re.DOTALL
)


class CompileError(RuntimeError):
    """The C compiler rejected a source: the message holds the command and its stderr."""


class Token(NamedTuple):
    """One lexical token of a C source: its kind, text, span and whether it is in a directive."""

    kind: str
    text: str
    start: int
    end: int
    pp: bool


@dataclass(frozen=True)
class _Body:
    """A function definition: the parameter names and the token indices of its braces."""

    params: tuple[str, ...]
    open_idx: int
    close_idx: int


# ----------------------------------------------------------------------------- lexing


def tokenize(src: str) -> list[Token]:
    """Lex C source into tokens (whitespace dropped, comments and strings kept as single tokens).

    Tokens on a preprocessor directive line carry ``pp=True``; backslash-newlines continue it.
    """
    tokens: list[Token] = []
    append = tokens.append
    line_start, in_pp = True, False
    for m in _LEX.finditer(src):
        kind = m.lastgroup or ""  # every alternative of _LEX is a named group
        if kind == "newline":
            line_start, in_pp = True, False
        elif kind != "space":
            text = m.group()
            if line_start and text == "#":
                in_pp = True
            line_start = False
            append(Token(kind, text, m.start(), m.end(), in_pp))
    return tokens


def _line_of(src: str, pos: int) -> tuple[int, str]:
    """1-based line number and text of the line holding offset ``pos``."""
    lineno = src.count("\n", 0, pos) + 1
    begin = src.rfind("\n", 0, pos) + 1
    end = src.find("\n", pos)
    return lineno, src[begin : end if end >= 0 else len(src)]


def _map_code(src: str, fn: Callable[[str], str]) -> str:
    """Apply ``fn`` to every stretch of ``src`` outside comments and string/char literals."""
    out: list[str] = []
    pos = 0
    for m in _NON_CODE.finditer(src):
        out.append(fn(src[pos : m.start()]))
        out.append(m.group())
        pos = m.end()
    out.append(fn(src[pos:]))
    return "".join(out)


def _apply_edits(src: str, edits: Iterable[tuple[int, int, str]]) -> str:
    """Replace the spans ``[start, end)`` by the given texts (spans must not overlap)."""
    out = src
    for start, end, text in sorted(edits, reverse=True):
        out = out[:start] + text + out[end:]
    return out


# ----------------------------------------------------------------------------- literals


def _is_float_literal(text: str) -> bool:
    """Whether a pp-number is a floating constant (decimal with '.'/exponent, or hex with 'p')."""
    low = text.lower()
    if low.startswith("0x"):
        return "p" in low
    return "." in low or "e" in low


def _float_suffix(text: str) -> str:
    """The type suffix of a floating literal: 'f', 'l' or ''.

    A hex float ends in a decimal exponent, so a trailing 'f' is a suffix there too.
    """
    last = text[-1].lower()
    return last if last in ("f", "l") else ""


def _literal_value(text: str) -> float:
    """The value of a floating literal (suffix ignored), as a Python float."""
    body = text[:-1] if _float_suffix(text) else text
    return float.fromhex(body) if body.lower().startswith("0x") else float(body)


def _suffix_literals(code: str) -> str:
    """Rewrite every unsuffixed floating literal in a code stretch as a float literal."""

    def repl(m: re.Match[str]) -> str:
        text = m.group(0)
        if not _is_float_literal(text) or _float_suffix(text) == "f":
            return text
        return float_literal(_literal_value(text))

    return re.sub(r"(?<![\w.])\.?\d(?:[eEpP][+-]|[\w.])*", repl, code)


# ----------------------------------------------------------------------------- rewrites


def _map_math_calls(code: str) -> str:
    """Rename calls of double math functions to their float variants (``sin(`` -> ``sinf(``)."""
    names = "|".join(sorted(DOUBLE_MATH, key=len, reverse=True))
    pattern = rf"(?<!\.)(?<!->)\b({names})\b(?=\s*\()"
    code = re.sub(pattern, lambda m: m.group(1) + "f", code)
    return re.sub(r"\bHUGE_VAL\b", "HUGE_VALF", code)


_OPERAND = r"\s*(?:\*\s*)?[A-Za-z_]\w*(?:\[\w+\])?(?:\+\+)?\s*"


def _explicit_truth_tests(code: str) -> str:
    """Write truth tests as comparisons with 0: ``(a?`` ``(!a)`` ``(a&&b)`` ``(a||b)`` ``if (a)``.

    C defines ``!E`` as ``0==E`` and ``&&``, ``||``, ``?:`` as comparisons of their operands with
    0, so this is the same program; clang's -Wfloat-conversion flags the implicit form for reals.
    The operand pattern only admits names, ``x[i]`` and ``*p++``, which all bind tighter than
    ``!=``, so no parentheses are needed.
    """
    code = re.sub(rf"\(!({_OPERAND})\)", lambda m: f"({m.group(1).strip()}==0)", code)
    code = re.sub(
        rf"\(({_OPERAND})(&&|\|\|)({_OPERAND})\)",
        lambda m: f"({m.group(1).strip()}!=0{m.group(2)}{m.group(3).strip()}!=0)",
        code,
    )
    code = re.sub(rf"\(({_OPERAND})\?", lambda m: f"({m.group(1).strip()}!=0?", code)
    return re.sub(
        rf"\b(if|while)(\s*)\(({_OPERAND})\)",
        lambda m: f"{m.group(1)}{m.group(2)}({m.group(3).strip()}!=0)",
        code,
    )


#: Exact snippets of CasADi's runtime library that need an explicit cast for -Wconversion
#: (an integer mixed into real arithmetic); applied verbatim, so a changed runtime is left alone.
_RUNTIME_FIXUPS = (
    ("((x-g0)*(ng-1)/dg)", "((x-g0)*(casadi_real)(ng-1)/dg)"),
)


def _runtime_fixups(code: str) -> str:
    """Apply the exact-text fix-ups of :data:`_RUNTIME_FIXUPS`."""
    for old, new in _RUNTIME_FIXUPS:
        code = code.replace(old, new)
    return code


def _outside_directives(fn: Callable[[str], str]) -> Callable[[str], str]:
    """Wrap a code rewrite so that it leaves preprocessor directive lines alone."""

    def wrapped(code: str) -> str:
        lines = code.split("\n")
        return "\n".join(ln if ln.lstrip().startswith("#") else fn(ln) for ln in lines)

    return wrapped


def _typed_special_constants(code: str) -> str:
    """Give INFINITY/NAN (float constants in C99) the casadi_real type, as in ``casadi_inf``."""
    return re.sub(
        r"(#define\s+casadi_(?:inf|nan)\s+)(INFINITY|NAN)\b", r"\1((casadi_real)\2)", code
    )


def _pin_type(src: str, macro: str, precision_check: Callable[[str], None] | None) -> str:
    """Replace CasADi's ``#ifndef macro / #define macro T / #endif`` by ``#undef``/``#define``."""
    pattern = re.compile(
        rf"^#ifndef {macro}\n#define {macro} ([^\n]+)\n#endif\n", re.MULTILINE
    )

    def repl(m: re.Match[str]) -> str:
        ctype = m.group(1).strip()
        if precision_check is not None:
            precision_check(ctype)
        return (
            f"/* Fixed at generation time (maglevgen cpass): the code depends on it. */\n"
            f"#undef {macro}\n#define {macro} {ctype}\n"
        )

    return pattern.sub(repl, src)


def _pin_types(src: str, precision: Precision) -> str:
    """Pin casadi_real and casadi_int, checking that casadi_real matches ``precision``."""
    want = "float" if precision == "single" else "double"

    def check(ctype: str) -> None:
        if ctype != want:
            raise ValueError(
                f"source was generated with casadi_real={ctype}, not {want} ({precision})"
            )

    return _pin_type(_pin_type(src, "casadi_real", check), "casadi_int", None)


# ----------------------------------------------------------------------------- structure


def _match_close(tokens: list[Token], idx: int, open_: str, close: str) -> int:
    """Index of the token closing the bracket opened at ``idx`` (directive lines ignored)."""
    depth = 0
    for j in range(idx, len(tokens)):
        tok = tokens[j]
        if tok.pp or tok.kind != "punct":
            continue
        if tok.text == open_:
            depth += 1
        elif tok.text == close:
            depth -= 1
            if depth == 0:
                return j
    raise ValueError(f"unbalanced {open_!r} at offset {tokens[idx].start}")


def _code_indices(tokens: list[Token]) -> list[int]:
    """Indices of tokens that are code: not comments, not on directive lines."""
    return [i for i, t in enumerate(tokens) if not t.pp and t.kind != "comment"]


def _param_names(tokens: list[Token], lpar: int, rpar: int) -> tuple[str, ...]:
    """Names declared in the parameter list between the parentheses at ``lpar`` and ``rpar``."""
    names: list[str] = []
    current: list[Token] = []
    depth = 0
    for tok in tokens[lpar + 1 : rpar]:
        if tok.pp or tok.kind == "comment":
            continue
        depth += tok.text in _OPENERS
        depth -= tok.text in _CLOSERS
        if tok.text == "," and depth == 0:
            names.extend(_param_name(current))
            current = []
        else:
            current.append(tok)
    names.extend(_param_name(current))
    return tuple(names)


def _param_name(param: list[Token]) -> list[str]:
    """The declared name of one parameter (the last identifier outside brackets), if any."""
    depth, name = 0, None
    for tok in param:
        depth += tok.text in _OPENERS
        depth -= tok.text in _CLOSERS
        if tok.kind == "ident" and (depth == 0 or tok.text not in _DECL_START):
            name = tok.text
    return [] if name is None or name in _DECL_START else [name]


def _function_bodies(tokens: list[Token]) -> list[_Body]:
    """Every function definition: a top-level ``{`` right after a ``)``.

    ``extern "C" {`` blocks are transparent; initialiser braces (after ``=``) are skipped.
    """
    code = _code_indices(tokens)
    position = {idx: p for p, idx in enumerate(code)}
    bodies: list[_Body] = []
    pos = 0
    while pos < len(code):
        i = code[pos]
        tok = tokens[i]
        if tok.text != "{" or tok.kind != "punct":
            pos += 1
            continue
        prev = tokens[code[pos - 1]] if pos else None
        if prev is not None and prev.kind == "string":  # extern "C" {
            pos += 1
            continue
        close = _match_close(tokens, i, "{", "}")
        if prev is not None and prev.text == ")":
            lpar = _match_open_paren(tokens, code[pos - 1])
            bodies.append(_Body(_param_names(tokens, lpar, code[pos - 1]), i, close))
        pos = position[close] + 1
    return bodies


def _match_open_paren(tokens: list[Token], rpar: int) -> int:
    """Index of the ``(`` matching the ``)`` at ``rpar``."""
    depth = 0
    for j in range(rpar, -1, -1):
        tok = tokens[j]
        if tok.pp or tok.kind != "punct":
            continue
        if tok.text == ")":
            depth += 1
        elif tok.text == "(":
            depth -= 1
            if depth == 0:
                return j
    raise ValueError(f"unbalanced ')' at offset {tokens[rpar].start}")


def _leading_decls_end(tokens: list[Token], body: _Body) -> int:
    """Token index after which statements may go: the last leading declaration's ``;``.

    Returns ``body.open_idx`` if there is none, or if a directive line intervenes (a cast inserted
    inside one branch of an ``#if`` would vanish in the other).
    """
    last = body.open_idx
    i = body.open_idx + 1
    while i < body.close_idx:
        tok = tokens[i]
        if tok.pp:
            return last if last == body.open_idx else body.open_idx
        if tok.kind == "comment":
            i += 1
            continue
        if tok.text not in _DECL_START:
            return last
        end = _statement_end(tokens, i, body.close_idx)
        if end is None:
            return last
        last, i = end, end + 1
    return last


def _statement_end(tokens: list[Token], start: int, stop: int) -> int | None:
    """Index of the ``;`` ending the statement at ``start`` (None if a directive intervenes)."""
    depth = 0
    for j in range(start, stop):
        tok = tokens[j]
        if tok.pp:
            return None
        depth += tok.text in _OPENERS
        depth -= tok.text in _CLOSERS
        if tok.text == ";" and depth == 0:
            return j
    return None


def _unused_param_edits(src: str, tokens: list[Token], body: _Body) -> list[tuple[int, int, str]]:
    """Edits inserting ``(void)name;`` for each parameter the body never names.

    A body with preprocessor conditionals may name a parameter in one branch only, so there
    every parameter is cast (a cast of a used parameter is harmless).
    """
    inner = tokens[body.open_idx + 1 : body.close_idx]
    if any(t.pp and t.text in ("if", "ifdef", "ifndef") for t in inner):
        used: set[str] = set()
    else:
        used = {t.text for t in inner if t.kind == "ident"}
    unused = [p for p in body.params if p not in used]
    if not unused:
        return []
    after = tokens[_leading_decls_end(tokens, body)]
    casts = " ".join(f"(void){name};" for name in unused)
    eol = src.find("\n", after.end)
    if eol < 0 or eol > tokens[body.close_idx].start:  # one-line body
        return [(after.end, after.end, f" {casts}")]
    indent = "  " if after.text == "{" else _indent_of(src, after.start)
    return [(eol + 1, eol + 1, f"{indent}{casts}\n")]


def _indent_of(src: str, pos: int) -> str:
    """Leading whitespace of the line holding ``pos``."""
    begin = src.rfind("\n", 0, pos) + 1
    line = src[begin:pos]
    return line[: len(line) - len(line.lstrip())]


def _mark_unused_params(src: str, tokens: list[Token]) -> str:
    """Insert ``(void)p;`` casts for unused parameters (``iw``, ``w``, ``mem``...).

    ``tokens`` must be ``tokenize(src)``.
    """
    edits = [e for body in _function_bodies(tokens) for e in _unused_param_edits(src, tokens, body)]
    return _apply_edits(src, edits)


# ----------------------------------------------------------------------------- checks


def _check_no_writable_data(src: str, tokens: list[Token]) -> None:
    """Raise ValueError on writable static or global data (``static`` without ``const``).

    Block-scope ``static`` anywhere, and file-scope object declarations that are neither
    ``const``, ``typedef``, ``extern`` nor function prototypes, are refused.
    """
    bodies = _function_bodies(tokens)
    inside = {i for b in bodies for i in range(b.open_idx, b.close_idx + 1)}
    for i in _code_indices(tokens):
        tok = tokens[i]
        if tok.text == "static" and i in inside and not _followed_by_const(tokens, i):
            _fail(src, tok, "writable block-scope static data")
    for stmt in _top_level_statements(tokens, inside):
        if _is_writable_object(stmt):
            _fail(src, stmt[0], "writable file-scope data")


def _followed_by_const(tokens: list[Token], i: int) -> bool:
    """Whether the ``static`` at ``i`` declares const data (``static const T x``)."""
    return i + 1 < len(tokens) and tokens[i + 1].text == "const"


def _top_level_statements(tokens: list[Token], inside: set[int]) -> list[list[Token]]:
    """File-scope declarations (token lists up to their ``;``), function bodies excluded."""
    stmts: list[list[Token]] = []
    current: list[Token] = []
    depth = 0
    for i in _code_indices(tokens):
        tok = tokens[i]
        if i in inside:
            current = []
            continue
        if tok.text == "{" and current and current[-1].kind == "string":  # extern "C" {
            current = []
            continue
        depth += tok.text in _OPENERS
        depth -= tok.text in _CLOSERS
        if depth < 0:  # closing brace of extern "C"
            depth, current = 0, []
            continue
        if tok.text == ";" and depth == 0:
            if current:
                stmts.append(current)
            current = []
        else:
            current.append(tok)
    return stmts


def _is_writable_object(stmt: list[Token]) -> bool:
    """Whether a file-scope declaration defines a non-const object."""
    words = [t.text for t in stmt]
    if words[0] in ("struct", "union", "enum") and words[-1] == "}":
        return False  # a type definition, no object
    if any(w in ("typedef", "extern", "const") for w in words[: _declarator_start(words)]):
        return False
    before_init = words[: words.index("=")] if "=" in words else words
    return "(" not in before_init


def _declarator_start(words: list[str]) -> int:
    """Index where the declaration specifiers end (first '*', '(', '[', '=' or the name)."""
    for k, w in enumerate(words):
        if w in ("*", "(", "[", "="):
            return k
    return len(words)


def _fail(src: str, tok: Token, what: str) -> None:
    """Raise ValueError naming the line that holds ``tok``."""
    lineno, line = _line_of(src, tok.start)
    raise ValueError(f"{what} at line {lineno}: {line.strip()}")


def _check_single_clean(src: str, tokens: list[Token]) -> None:
    """Raise ValueError if single-precision code still holds any double literal, call or type."""
    for k, tok in enumerate(tokens):
        if tok.kind == "number" and _is_float_literal(tok.text) and _float_suffix(tok.text) != "f":
            _fail(src, tok, f"double literal {tok.text!r} left in single-precision code")
        if tok.kind == "ident" and tok.text in DOUBLE_MATH and _is_call(tokens, k):
            _fail(src, tok, f"double math call {tok.text}() left in single-precision code")
        if tok.kind == "ident" and tok.text in ("double", "HUGE_VAL"):
            _fail(src, tok, f"{tok.text!r} left in single-precision code")


def _is_call(tokens: list[Token], k: int) -> bool:
    """Whether the identifier at ``k`` is followed by ``(`` and not a member access."""
    nxt = tokens[k + 1].text if k + 1 < len(tokens) else ""
    prev = tokens[k - 1].text if k else ""
    return nxt == "(" and prev not in (".", "->")


# ----------------------------------------------------------------------------- entry points


def unchecked_entry_points(source: str, names: Iterable[str]) -> str:
    """``source`` with the CasADi entry point of each of ``names`` renamed to a ``static``
    ``NAME_unchecked``, for maglevgen.codegen.checks to define ``NAME`` around it; a name
    whose entry point is not found exactly once is a ValueError."""
    for name in names:
        head = f"CASADI_SYMBOL_EXPORT int {name}(const casadi_real** arg"
        if source.count(head) != 1:
            raise ValueError(f"entry point of {name} not found once in the generated C")
        source = source.replace(head, f"static int {name}_unchecked(const casadi_real** arg")
    return source


_VERSION = re.compile(r"(CASADI_SYMBOL_EXPORT void \w+_casadi_version\(int\* major, int\* minor, "
                      r"int\* patch\) \{\n)((?:  \*\w+ = \d+;\n)+)\}")


def null_safe_version(source: str) -> str:
    """CasADi's NAME_casadi_version(major, minor, patch) writes through its pointers
    unconditionally: a NULL one (which its type allows) must skip that number instead."""
    found = _VERSION.findall(source)
    if len(found) != 1:
        raise ValueError("the CasADi version function not found once in the generated C")

    def guard(m: re.Match) -> str:
        body = re.sub(r"  \*(\w+) = (\d+);", r"  if (\1 != 0) {\n    *\1 = \2;\n  }",
                      m.group(2))
        return m.group(1) + body + "}"

    return _VERSION.sub(guard, source)



# ----------------------------------------------------------------------------- one unit


#: a definition of one of CasADi's runtime helpers at the start of a line, not yet static
_CASADI_HELPER = re.compile(r"^((?:casadi_real|casadi_int|void|int) (casadi_\w+)\()", re.M)


def static_helpers(text: str) -> str:
    """CasADi's runtime helpers (casadi_copy, casadi_qr, ...), external in its own output,
    made static; those no function calls (CasADi emits the QR solve's whole family) removed,
    as a static function nobody calls is a warning."""
    while True:
        unused = [m for m in _CASADI_HELPER.finditer(text)
                  if len(re.findall(rf"\b{m.group(2)}\(", text)) == 1]
        if not unused:
            break
        for m in reversed(unused):  # the definition runs to the first "}" alone on a line
            end = text.index("\n}\n", m.start()) + 3
            text = text[:m.start()] + text[end:].lstrip("\n")
    return _CASADI_HELPER.sub(r"static \1", text)


# ----------------------------------------------------------------------------- public API


def postprocess(src: str, precision: Precision) -> str:
    """Make CasADi-generated C (a .c or .h) compile warning-free as firmware C.

    Changes: pins ``casadi_real``/``casadi_int`` (``#undef``/``#define`` instead of a default
    guard), casts unused parameters to void, writes real truth tests as comparisons with 0, types
    ``casadi_inf``/``casadi_nan`` as casadi_real; in single precision also suffixes every floating
    literal with ``f`` and calls the float math functions. Raises ValueError if writable
    static/global data is present, or if single-precision text still holds a double literal,
    double math call or the ``double`` type afterwards.
    """
    if precision not in ("double", "single"):
        raise ValueError(f"precision must be 'double' or 'single', not {precision!r}")
    out = _pin_types(src, precision)
    out = _map_code(out, _outside_directives(_explicit_truth_tests))
    out = _map_code(out, _typed_special_constants)
    out = _map_code(out, _runtime_fixups)
    if precision == "single":
        out = _map_code(out, _suffix_literals)
        out = _map_code(out, _map_math_calls)
    # Checked before the (void) casts go in, so that line numbers are those of ``src``.
    tokens = tokenize(out)
    _check_no_writable_data(out, tokens)
    if precision == "single":
        _check_single_clean(out, tokens)
    return _mark_unused_params(out, tokens)


def codegen_options(precision: Precision, int_type: str = "long long int") -> dict[str, Any]:
    """The ``casadi.CodeGenerator`` options used by :func:`generate_c`.

    ``with_header`` for the API declarations; no ``main``/``mex`` entry points (they need stdio
    and string.h); ``verbose`` off; ``casadi_real`` float for single precision.
    """
    return {
        "with_header": True,
        "main": False,
        "mex": False,
        "cpp": False,
        "verbose": False,
        "casadi_real": "float" if precision == "single" else "double",
        "casadi_int": int_type,
    }


def generate_c(
    functions: list[ca.Function],
    name: str,
    precision: str,
    *,
    int_type: str = "long long int",
) -> dict[str, str]:
    """Generate ``{name}.c`` and ``{name}.h`` for ``functions`` and post-process them (the .c
    with its runtime helpers static: `static_helpers`, and each if_else's discarded side
    skipped: `maglevgen.codegen.branches.guard_discarded_branches`).

    The result depends only on the functions, ``name``, ``precision`` and ``int_type``: the
    generator runs in a private temporary directory, and any trace of that path is refused.
    """
    if not functions:
        raise ValueError("generate_c needs at least one casadi.Function")
    if precision not in get_args(Precision):
        raise ValueError(f"precision {precision!r}: expected one of {get_args(Precision)}")
    prec = cast(Precision, precision)
    cg = ca.CodeGenerator(name, codegen_options(prec, int_type))
    for fn in functions:
        cg.add(fn)
    with tempfile.TemporaryDirectory(prefix="cpass_") as tmp:
        cg.generate(str(Path(tmp)) + "/")
        raw = {sfx: (Path(tmp) / f"{name}{sfx}").read_text() for sfx in (".c", ".h")}
        for text in raw.values():
            if tmp in text:
                raise ValueError("generated code contains the temporary directory path")
    # the banner (no time, path or host in it) and the header's include guard:
    # templates/casadi_output.j2
    guard = re.sub(r"\W", "_", name).upper() + "_H"
    return {f"{name}{sfx}": render("casadi_output.j2", file=f"{name}{sfx}", body=body,
                                   casadi_version=ca.__version__,  # type: ignore[attr-defined]
                                   precision=precision,
                                   guard=guard if sfx == ".h" else None)
            for sfx, body in ((".c", guard_discarded_branches(
                                  static_helpers(postprocess(raw[".c"], prec)))),
                              (".h", _own_types(postprocess(raw[".h"], prec))))}


def _own_types(header: str) -> str:
    """The header with its own types ``maglev_real``/``maglev_int`` (typedefs of the types the
    .c pins casadi_real/casadi_int to) instead of redefining the global casadi_* macros, which
    would silently switch any other CasADi-generated code in the same translation unit."""
    for macro, own in (("casadi_real", "maglev_real"), ("casadi_int", "maglev_int")):
        pattern = re.compile(rf"/\* Fixed at generation time \(maglevgen cpass\): the code "
                             rf"depends on it\. \*/\n#undef {macro}\n#define {macro} ([^\n]+)\n")
        header, n = pattern.subn(partial(_own_typedef, macro, own), header)
        if n != 1:
            raise ValueError(f"generated header does not pin {macro} once")
        header = _map_code(header, partial(_renamed, macro, own))
    return header


def _own_typedef(macro: str, own: str, m: re.Match[str]) -> str:
    return (f"/* {macro} of the .c, fixed at generation time (maglevgen cpass) */\n"
            f"typedef {m.group(1)} {own};\n")


def _renamed(macro: str, own: str, code: str) -> str:
    return re.sub(rf"\b{macro}\b", own, code)


def compile_check(sources: dict[str, str], flags: list[str], cc: str = "gcc") -> None:
    """Write ``sources`` to a temporary directory and compile each ``.c`` with ``cc -c``.

    Raises CompileError holding the command and the compiler's stderr on any failure
    (use ``-Werror`` in ``flags`` to fail on warnings), FileNotFoundError if ``cc`` is missing.
    """
    if shutil.which(cc) is None:
        raise FileNotFoundError(f"C compiler {cc!r} not found")
    with tempfile.TemporaryDirectory(prefix="cpass_cc_") as tmp:
        for fname, text in sources.items():
            (Path(tmp) / fname).write_text(text)
        for fname in sorted(f for f in sources if f.endswith(".c")):
            cmd = [cc, *flags, "-c", fname, "-o", f"{Path(fname).stem}.o"]
            proc = subprocess.run(cmd, cwd=tmp, capture_output=True, text=True, check=False)
            if proc.returncode != 0:
                raise CompileError(f"{' '.join(cmd)} failed:\n{proc.stderr}")
