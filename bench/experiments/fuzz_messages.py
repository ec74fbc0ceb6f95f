"""Messages as promised (issue 54): a small fuzzer of bad input, range edges and API arguments.

    python bench/experiments/fuzz_messages.py [--part a|b|c|all] [--timeout S] [--cli-edges]
        [--from KEY]

The promise (README, the developer guide): bad input gives exit 2 and ONE line on stderr, an
internal failure exit 1, and a command never exits 0 with a non-finite number in its output;
the Python API raises `maglevgen.InputError` naming the argument. Three parts:

(a) bad values for every key of the default parameter file, through ``--set`` and through a
    parameter file, and bad options of each command: anything but exit 2 with one stderr line
    is a finding;
(b) range edges per numeric key (the schema's lo and hi, just outside them, zero, negative,
    denormal, huge, tiny): a value outside the range must give exit 2 and one line; a value
    inside it exit 0 with finite numbers, or exit 2 and one line (no trim there). By default
    the values inside the range run the API's trim, gains and a short hold (what `trim`,
    `gains` and `simulate` print, without the envelope's verdicts: 15 s each);
    ``--cli-edges`` runs `maglevgen trim --json` itself for them;
(c) every argument of `maglevgen.load` and the `Carriage` methods with bad values: anything
    but an InputError whose message names the argument (or its command-line option) is a
    finding; a call that returns or runs past the timeout is listed for review.

Each case runs in a forked child of one process that has loaded the default carriage and its
library (fd 1 and 2 to files, its own process group, killed at the timeout), so a case costs
milliseconds unless it computes. Writes bench/experiments/fuzz_messages_results.json: the
counts and every finding. Not a test: tests/test_input_boundaries.py and
tests/test_api_arguments.py hold the cases it found.
"""

from __future__ import annotations

import argparse
import copy
import inspect
import json
import math
import os
import re
import signal
import sys
import tempfile
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench/: common.py

import contextlib

from common import EXPERIMENTS, log

from maglevgen.params import default_params_text, schema_table

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

RESULTS = EXPERIMENTS / "fuzz_messages_results.json"
DEFAULT = tomllib.loads(default_params_text())


# ------------------------------------------------------------------------------ running


def forked(fn: Callable[[], Any], timeout: float) -> dict[str, Any]:
    """Run ``fn`` in a forked child: {"value": what it returned (JSON), "stdout", "stderr",
    "status": "returned" | "raised" | "exit" | "timeout" | "killed"}."""
    with tempfile.TemporaryDirectory(prefix="fuzz-") as tmp:
        out, err, res = (Path(tmp) / n for n in ("out", "err", "res"))
        pid = os.fork()
        if pid == 0:  # the child
            code = 0
            try:
                os.setpgid(0, 0)
                os.chdir(tmp)
                fo, fe = os.open(out, os.O_WRONLY | os.O_CREAT), os.open(err, os.O_WRONLY |
                                                                          os.O_CREAT)
                sys.stdout.flush()
                sys.stderr.flush()
                os.dup2(fo, 1)
                os.dup2(fe, 2)
                try:
                    value = {"status": "returned", "value": fn()}
                except SystemExit as exc:
                    value = {"status": "exit", "value": exc.code}
                except BaseException as exc:
                    value = {"status": "raised", "type": type(exc).__name__,
                             "module": type(exc).__module__, "message": str(exc)[:500],
                             "trace": traceback.format_exc()[-1500:]}
                sys.stdout.flush()
                sys.stderr.flush()
                res.write_text(json.dumps(value, default=repr))
            except BaseException:
                code = 99
            os._exit(code)
        deadline = time.monotonic() + timeout
        status = None
        while time.monotonic() < deadline:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                break
            time.sleep(0.01)
        else:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            return {"status": "timeout", "stdout": _read(out), "stderr": _read(err)}
        if not res.exists():
            return {"status": "killed", "wait": status, "stdout": _read(out),
                    "stderr": _read(err)}
        result = json.loads(res.read_text())
        result.update(stdout=_read(out), stderr=_read(err))
        return result


def _read(p: Path, limit: int = 200_000) -> str:
    try:
        return p.read_bytes()[:limit].decode("utf-8", "replace")
    except OSError:
        return ""


def cli(argv: list[str], files: dict[str, str] | None = None) -> Callable[[], int]:
    """A case: `maglevgen ARGV` in the child's folder, ``files`` written there first."""
    def run() -> int:
        from maglevgen.cli import main

        for name, text in (files or {}).items():
            Path(name).write_text(text, encoding="utf-8")
        return main(argv)
    return run


def lines(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.strip()]


def cli_outcome(r: dict[str, Any]) -> tuple[int | str, int]:
    """(exit code or the child's fate, stderr lines)."""
    code = r["value"] if r["status"] in ("returned", "exit") else r["status"]
    if r["status"] == "raised":
        code = f"raised {r['type']}"
    return code, len(lines(r["stderr"]))


# ------------------------------------------------------------------------ the file's keys


def leaves(data: dict[str, Any], prefix: tuple[str, ...] = ()) -> list[tuple[str, Any]]:
    """(dotted key, value) of every non-table value of the default file (provenance's
    tables included: their `why` is a user text); `PATHS` keeps each key's parts."""
    out = []
    for k, v in data.items():
        path = (*prefix, k)
        if isinstance(v, dict):
            out += leaves(v, path)
        else:
            PATHS[".".join(path)] = path
            out.append((".".join(path), v))
    return out


PATHS: dict[str, tuple[str, ...]] = {}


class Raw(str):
    """A value already in TOML syntax."""


def toml_value(v: Any) -> str:
    if isinstance(v, Raw):
        return str(v)
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(toml_value(c) for c in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {toml_value(c)}" for k, c in v.items()) + "}"
    raise TypeError(type(v))


def dump(data: dict[str, Any], prefix: str = "") -> str:
    """The data as TOML: values first, then a [table] per nested dict (quoted keys)."""
    text = "".join(f"{json.dumps(k)} = {toml_value(v)}\n" for k, v in data.items()
                   if not isinstance(v, dict))
    for k, v in data.items():
        if isinstance(v, dict):
            name = f"{prefix}{json.dumps(k)}"
            text += f"\n[{name}]\n" + dump(v, name + ".")
    return text


def file_with(dotted: str, value: Any) -> str:
    """The default file with the key ``dotted`` (its parts split on dots, provenance's keys
    kept whole) set to ``value``."""
    data = copy.deepcopy(DEFAULT)
    parts = _parts(dotted)
    node = data
    for p in parts[:-1]:
        node = node[p]
    node[parts[-1]] = value
    return dump(data)


def _parts(dotted: str) -> tuple[str, ...]:
    return PATHS[dotted]


def _set_name(dotted: str) -> str | None:
    """The --set name of a key (quoted keys holding dots cannot be named by --set)."""
    return None if any("." in p for p in PATHS[dotted]) else dotted


# ---------------------------------------------------------------------- (a) bad input

BAD_VALUES = [Raw('"x"'), Raw('""'), Raw("true"), Raw("nan"), Raw("inf"), Raw("-inf"),
              Raw("[]"), Raw("{a = 1}"), Raw("1979-05-27"), Raw("07:32:00"),
              Raw("99999999999999999999999999"), Raw("-99999999999999999999999999"),
              Raw("[1.0, 2.0]"), Raw("[[1.0]]"), Raw("1e400"), Raw('"\\u0007"'),
              Raw('"' + "x" * 3000 + '"')]


def part_a(timeout: float, limit: int | None) -> tuple[int, list[dict]]:
    cases: list[tuple[str, Callable[[], int]]] = []
    for argv in BAD_OPTIONS:
        cases.append((" ".join(argv), cli(argv)))
    for argv, files in BAD_FILES:
        cases.append((" ".join(argv) + f" {sorted(files)}", cli(argv, files)))
    for key, value in leaves(DEFAULT):
        for v in BAD_VALUES:
            shown = v if len(v) < 40 else v[:20] + "..."
            name = _set_name(key)
            if isinstance(value, str) and v == '"x"':
                continue  # a text: "x" is one
            if name is not None:
                cases.append((f"--set {name}={shown}", cli(["params", "show", "--set",
                                                            f"{name}={v}"])))
            cases.append((f"file {key} = {shown}", cli(
                ["params", "show", "--params", "p.toml"], {"p.toml": file_with(key, v)})))
    return _run_cli_cases(cases, timeout, limit, lambda code, n: code == 2 and n == 1)


_NUMS = ["nan", "inf", "-inf", "1e400", "-1", "0", "1e-320", "x", ""]
_SIM = ["--out", "o", "--t-end", "0.05"]  # short, where the value under test is accepted
_MC = ["--out", "o", "--t-end", "0.05", "--samples", "4", "--workers", "1"]
_ROA = ["--speeds", "2", "--samples", "20"]


def _opt(argv: list[str], fixed: list[str]) -> list[str]:
    """``argv`` with the options of ``fixed`` it does not set itself."""
    out = list(argv)
    for i in range(0, len(fixed), 2):
        if fixed[i] not in argv:
            out += fixed[i:i + 2]
    return out


BAD_OPTIONS: list[list[str]] = [
    *[["trim", "--speed", v] for v in [*_NUMS, "1e308", "5e-324"]],
    *[["trim", "--acceleration", v] for v in ["nan", "inf", "-inf", "1e400", "x", "", "1e308",
                                              "-1e308"]],
    *[["gains", "--speed", v] for v in _NUMS],
    *[_opt(["simulate", "--t-end", v], _SIM) for v in [*_NUMS, "1e308"]],
    *[_opt(["simulate", "--dt", v], _SIM) for v in [*_NUMS, "1e308", "5e-324"]],
    *[_opt(["simulate", "--speed", v], _SIM) for v in _NUMS],
    *[_opt(["simulate", "--disturbance", v], _SIM) for v in
      ["z", "z=", "=1", "z=nan", "z=inf", "z=1", "z=0.01=2", "z=1e400", "\x1b[31m=1"]],
    _opt(["simulate", "--controller", "nope"], _SIM),
    _opt(["simulate", "--scenario", "nope"], _SIM),
    _opt(["simulate", "--out", ""], _SIM),
    _opt(["simulate", "--out", "/dev/null"], _SIM),
    _opt(["simulate", "--out", "/proc/self/x"], _SIM),
    *[_opt(["montecarlo", "--samples", v], _MC) for v in ["0", "-1", "x", "1e3",
                                                         "99999999999999999999999"]],
    *[_opt(["montecarlo", "--seed", v], _MC) for v in ["-1", "x", "1.5",
                                                      "99999999999999999999999999999"]],
    *[_opt(["montecarlo", "--workers", v], _MC) for v in ["0", "-1", "x", "100000"]],
    *[_opt(["montecarlo", "--scheduler", v], _MC) for v in ["", "nope", "tcp://", "tcp://:",
                                                           "tcp://h:99999", "\x1b"]],
    *[_opt(["montecarlo", "--t-end", v], _MC) for v in _NUMS],
    *[["envelope", "--speeds", v] for v in ["0", "-1", "x", "1000000", "1.5"]],
    *[_opt(["roa", "--speeds", v], _ROA) for v in ["0", "-1", "x", "1000000"]],
    *[_opt(["roa", "--samples", v], _ROA) for v in ["0", "-1", "x", "100000000000"]],
    *[_opt(["roa", "--batch", v], _ROA) for v in ["0", "-1", "x", "100000000000"]],
    *[_opt(["roa", "--workers", v], _ROA) for v in ["0", "-1", "x", "100000"]],
    *[_opt(["roa", "--seed", v], _ROA) for v in ["-1", "99999999999999999999999999999"]],
    _opt(["roa", "--controller", "nope"], _ROA),
    *[["fmu", "--out", "o", *opt] for opt in (["--kind", "x"], ["--fmi", "4"],
                                              ["--controller", "x"], ["--loop", "x"])],
    *[["generate", "--out", "o", *opt] for opt in (["--precision", "x"], ["--int", "x"],
                                                   ["--parameters", "x"])],
    *[["build", "--out", "o", *opt] for opt in (["--t-end", "nan"], ["--dt", "0"],
                                                ["--dt", "2"], ["--controller", "x"],
                                                ["--t-end", "1e9"])],
    ["report", "--out", "o", "--simulation", "nope"],
    ["report", "--out", "o", "--simulation", "/etc"],
    ["trim", "--params", "nope.toml"],
    ["trim", "--params", "/etc"],
    ["trim", "--params", "/dev/null"],
    ["trim", "--params", ""],
    ["trim", "--set", "vehicle.mass"],
    ["trim", "--set", "=1"],
    ["trim", "--set", "vehicle..mass=1"],
    ["trim", "--set", "vehicle.mass.x=1"],
    ["trim", "--set", "arrays.9.circuits=1"],
    ["trim", "--set", "nope=1"],
    ["trim", "--set", "vehicle=1"],
    ["trim", "--set", "vehicle.mass=1\n"],
    ["trim", "--set", "vehicle.mass=1 2"],
    ["trim", "--nope"],
    ["nope"],
    [],
]
BAD_FILES: list[tuple[list[str], dict[str, str]]] = [
    (["trim", "--params", "p.toml"], {"p.toml": text}) for text in (
        "", "x", "[vehicle]\nmass = 1\n", "\x00", "a = 1\na = 2\n",
        default_params_text() + "\n[vehicle]\n", default_params_text().replace("[arrays.6]",
                                                                              "[arrays.5]"),
        "[" * 5000, "a = " + "[" * 5000 + "]" * 5000,
        default_params_text().replace("mass = 9.3", "mass = 9.3\nmass = 9.4"),
    )
]


def _run_cli_cases(cases, timeout: float, limit: int | None,
                   good: Callable[[Any, int], bool]) -> tuple[int, list[dict]]:
    findings = []
    for i, (what, fn) in enumerate(cases[:limit]):
        r = forked(fn, timeout)
        code, n = cli_outcome(r)
        if not good(code, n):
            findings.append({"case": what, "exit": code, "stderr_lines": n,
                             "stderr": r["stderr"][-600:], "trace": r.get("trace", "")})
            log(f"finding: {what!r}: exit {code}, {n} stderr lines: {r['stderr'][-300:]!r}")
        if i % 100 == 0:
            log(f"{i}/{len(cases)}")
    return min(len(cases), limit or len(cases)), findings


# ------------------------------------------------------------------------ (b) range edges


def numeric_keys() -> list[tuple[str, float, float, bool, bool]]:
    """(key of the default file, lo, hi, vector, integer) of every numeric leaf with a range."""
    ranges = {}
    for key, _unit, _desc, _paper, allowed in schema_table():
        m = re.search(r"in \[([^,]+), ([^\]]+)\]", allowed)
        if m:
            ranges[key] = (float(m.group(1)), float(m.group(2)))
    out = []
    for key, value in leaves(DEFAULT):
        generic = re.sub(r"^(arrays|sensors\.gap_sensors)\.[^.]+\.", r"\1.<name>.", key)
        generic = re.sub(r"^tolerances\.parameters\..+\.(normal|uniform)$",
                         r"tolerances.parameters.<key>.\1", generic)
        if generic not in ranges or isinstance(value, (bool, str)):
            continue
        lo, hi = ranges[generic]
        vec = isinstance(value, list)
        integer = isinstance(value, int) or (vec and all(isinstance(c, int) for c in value))
        out.append((key, lo, hi, vec, integer))
    return out


def edge_values(lo: float, hi: float, integer: bool) -> list[tuple[float | int, bool]]:
    """(value, inside the range) at the edges of [lo, hi] and beyond."""
    vals: list[float | int] = [lo, hi, 0.0, -abs(hi), 5e-324, 1e308, -1e308, 1e-308]
    if integer:
        vals = [int(lo), int(hi), int(lo) - 1, int(hi) + 1, 0, -1, 2**63 - 1, -(2**63)]
    else:
        vals += [lo * (1 - 1e-9) if lo > 0 else lo - 1e-9 * max(1.0, abs(lo)),
                 hi * (1 + 1e-9) if hi > 0 else hi + 1e-9]
    seen, out = set(), []
    for v in vals:
        if v in seen:
            continue
        seen.add(v)
        out.append((v, lo <= v <= hi))
    return out


def _nonfinite(obj: Any, path: str = "") -> str | None:
    if isinstance(obj, float) and not math.isfinite(obj):
        return path or "(value)"
    if isinstance(obj, dict):
        for k, v in obj.items():
            if (bad := _nonfinite(v, f"{path}.{k}")) is not None:
                return bad
    if isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            if (bad := _nonfinite(v, f"{path}[{i}]")) is not None:
                return bad
    return None


def _api_edge(overrides: list[str]) -> Callable[[], dict]:
    """The API's trim, gains and a 0.2 s hold: their numbers, checked finite in the child."""
    def run() -> dict:
        import numpy as np

        import maglevgen
        try:
            c = maglevgen.load(overrides=overrides)
            report = {"trim": c.trim().to_dict(), "gains": c.gains_report()}
            sim = c.simulate(t_end=0.2)
            report["sim"] = {"x_finite": bool(np.isfinite(sim.x).all()),
                             "metrics": sim.metrics, "status": str(sim.status)}
            if not report["sim"]["x_finite"] and "contact" not in str(sim.status):
                return {"outcome": "nonfinite", "where": "simulate x"}
            bad = _nonfinite(json.loads(json.dumps(report, default=_np)))
            return {"outcome": "nonfinite", "where": bad} if bad else {"outcome": "ok"}
        except maglevgen.InputError as exc:
            return {"outcome": "input", "message": str(exc)[:300]}
    return run


def _np(o: Any) -> Any:
    import numpy as np

    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return repr(o)


def part_b(timeout: float, limit: int | None, cli_edges: bool,
           start: str | None = None) -> tuple[int, list[dict]]:
    findings, n = [], 0
    keys = numeric_keys()
    if start is not None:  # resume at a key, in the file's order
        names = [k[0] for k in keys]
        if start not in names:
            raise SystemExit(f"--from {start!r}: not a numeric key of the default file")
        keys = keys[names.index(start):]
    for key, lo, hi, vec, integer in keys:
        for v, inside in edge_values(lo, hi, integer):
            value = [v] * len(dict(leaves(DEFAULT))[key]) if vec else v
            item = f"{key}={toml_value(value)}"
            if limit is not None and n >= limit:
                return n, findings
            n += 1
            if not inside or cli_edges:
                r = forked(cli(["trim", "--json", "--set", item]), timeout)
                code, lines_ = cli_outcome(r)
                ok = (code == 2 and lines_ == 1) if not inside else (
                    (code == 2 and lines_ == 1) or (code == 0 and _json_finite(r["stdout"])))
                if not ok:
                    findings.append({"case": item, "inside": inside, "exit": code,
                                     "stderr_lines": lines_, "stderr": r["stderr"][-600:],
                                     "trace": r.get("trace", ""),
                                     "nonfinite": code == 0})
                    log(f"finding: {item}: exit {code}, {lines_} lines "
                        f"{r['stderr'][-200:]!r}")
                continue
            r = forked(_api_edge([item]), timeout)
            res = r.get("value") if r["status"] == "returned" else None
            if res is None or res["outcome"] == "nonfinite":
                findings.append({"case": item, "inside": True, "api": r["status"],
                                 "type": r.get("type"), "message": r.get("message"),
                                 "result": res, "trace": r.get("trace", "")})
                log(f"finding: {item}: {r['status']} {r.get('type')} {r.get('message')!r} "
                    f"{res}")
        log(f"{key}: {n} values so far")
    return n, findings


def _json_finite(stdout: str) -> bool:
    try:
        data = json.loads(stdout, parse_constant=lambda c: float(c))
    except ValueError:
        return False
    return _nonfinite(data) is None


# ---------------------------------------------------------------------------- (c) the API

API_BAD = [None, "x", "", -1, 0, float("inf"), float("-inf"), float("nan"), 10**400, True,
           2.5, [], {}, object(), 1j, b"x", "a\x00b", -1e308]
# the command-line option an argument stands for, where it is not --<name>
OPTION = {"n_speeds": "--speeds", "int_type": "--int", "pdf": "--no-pdf",
          "overrides": "--set", "params": "--params"}
METHODS = ["trim", "gains_report", "gains", "linearize", "axis_plant", "simulate",
           "simulations", "envelope", "montecarlo", "roa", "generate", "firmware", "report",
           "fmu", "build"]
REQUIRED = {"axis_plant": {"axis": "vertical"}, "generate": {"out": "o"}, "firmware": {"out": "o"},
            "report": {"out": "o"}, "fmu": {"out": "o"}}


def _names_argument(message: str, arg: str) -> bool:
    option = OPTION.get(arg, "--" + arg.replace("_", "-"))
    return arg in message or option in message


def part_c(timeout: float, limit: int | None) -> tuple[int, list[dict], list[dict]]:
    import maglevgen
    from maglevgen.api import Carriage

    carriage = maglevgen.load()
    carriage._lib  # noqa: B018 - loaded before the forks
    cases: list[tuple[str, str, Any, Callable[[], Any]]] = []
    for arg in ("params", "overrides"):
        for v in API_BAD:
            cases.append(("load", arg, v, lambda a=arg, v=v: repr(maglevgen.load(**{a: v}))))
    for name in METHODS:
        sig = inspect.signature(getattr(Carriage, name))
        for arg, p in sig.parameters.items():
            if arg in ("self", "progress"):
                continue
            for v in API_BAD:
                if p.default is not inspect.Parameter.empty and _same(v, p.default):
                    continue
                if arg in ("out", "simulation") and v == "x":
                    continue  # a good folder name: the whole command would run
                kw = {**REQUIRED.get(name, {}), arg: v}
                if name in ("simulate", "simulations", "montecarlo", "build") and arg not in (
                        "t_end", "dt"):
                    kw.setdefault("t_end", 0.05)
                if name == "montecarlo" and arg != "samples":
                    kw.setdefault("samples", 2)
                cases.append((name, arg, v, lambda n=name, kw=kw: repr(
                    getattr(carriage, n)(**kw))[:200]))
    findings, review = [], []
    for i, (method, arg, v, fn) in enumerate(cases[:limit]):
        r = forked(fn, timeout)
        case = {"call": f"{method}({arg}={v!r:.40})"}
        if r["status"] == "raised":
            named = _names_argument(r["message"], arg)
            if r["type"] in ("InputError", "NoTrimError") and named:
                continue
            findings.append({**case, "raised": r["type"], "message": r["message"][:300],
                             "trace": r["trace"][-800:]})
            log(f"finding: {case['call']}: {r['type']}: {r['message'][:200]!r}")
        else:
            review.append({**case, "status": r["status"], "value": str(r.get("value"))[:200]})
        if i % 50 == 0:
            log(f"{i}/{len(cases)}")
    return min(len(cases), limit or len(cases)), findings, review


def _same(a: Any, b: Any) -> bool:
    try:
        return type(a) is type(b) and bool(a == b)
    except Exception:
        return False


# ------------------------------------------------------------------------------------ main


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--part", choices=("a", "b", "c", "all"), default="all")
    ap.add_argument("--timeout", type=float, default=120.0)
    ap.add_argument("--limit", type=int, default=None, help="at most N cases per part")
    ap.add_argument("--cli-edges", action="store_true")
    ap.add_argument("--from", dest="start", default=None,
                    help="part b: start at this key (file order), e.g. to resume a run")
    args = ap.parse_args()
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    import maglevgen.api  # imported once, before the forks
    import maglevgen.cli  # noqa: F401
    results = json.loads(RESULTS.read_text()) if RESULTS.exists() else {}
    out = RESULTS if args.limit is None else RESULTS.with_suffix(".partial.json")
    t0 = time.monotonic()
    if args.part in ("a", "all"):
        n, f = part_a(args.timeout, args.limit)
        results["a"] = {"cases": n, "findings": f}
        log(f"(a) {len(f)} of {n} bad-input runs not exit 2 with one line")
    if args.part in ("b", "all"):
        n, f = part_b(args.timeout, args.limit, args.cli_edges, args.start)
        # a resumed run keeps the earlier run's part b beside it
        results["b" if args.start is None else f"b from {args.start}"] = {
            "cases": n, "findings": f, "cli_edges": args.cli_edges}
        log(f"(b) {len(f)} of {n} range-edge values")
    if args.part in ("c", "all"):
        n, f, review = part_c(min(args.timeout, 30.0), args.limit)
        results["c"] = {"cases": n, "findings": f, "returned_or_timeout": review}
        log(f"(c) {len(f)} of {n} API calls without an InputError naming the argument")
    results["seconds"] = round(time.monotonic() - t0, 1)
    out.write_text(json.dumps(results, indent=1, default=repr) + "\n")


if __name__ == "__main__":
    main()
