"""LaTeX: the jinja2 environment of the templates, and running latexmk (or pdflatex) on them."""

from __future__ import annotations

import os
import re
import subprocess
import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import jinja2

from maglevgen.infrastructure import texsetup
from maglevgen.infrastructure.texsetup import INSTALL_HINT
from maglevgen.report.display import display_filter, math_prose
from maglevgen.report.format import (
    axis_unit_row,
    fcolumn,
    fcomplex,
    ferr,
    ffixed,
    fnum,
    fpct,
    froundoff,
    tex_breakable,
    tex_escape,
    tex_key,
    tex_prose,
    tex_unit,
)

__all__ = ["INSTALL_HINT", "LatexBuild", "find_tex", "first_latex_error", "latex_env",
           "overfull_boxes", "run_latex", "source_date_epoch"]


def find_tex() -> str | None:
    """latexmk, pdflatex or None (looked up when called, so a test can take TeX away)."""
    return texsetup.find_tex()



def latex_env() -> jinja2.Environment:
    """jinja2 with LaTeX-safe delimiters: \\BLOCK{...}, \\VAR{...}, \\#{...}."""
    path = resources.files("maglevgen.templates")
    env = jinja2.Environment(
        loader=jinja2.FileSystemLoader(str(path)),
        block_start_string=r"\BLOCK{",
        block_end_string="}",
        variable_start_string=r"\VAR{",
        variable_end_string="}",
        comment_start_string=r"\#{",
        comment_end_string="}",
        line_statement_prefix=None,
        line_comment_prefix=None,
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
        autoescape=False,
        undefined=jinja2.StrictUndefined,
    )
    env.filters.update(
        tex=tex_escape,
        texbreak=tex_breakable,
        key=tex_key,
        unit=tex_unit,
        num=fnum,
        fixed=ffixed,
        complex=fcomplex,
        pct=fpct,
        err=ferr,
        display=display_filter,
        roundoff=froundoff,
        prose=tex_prose,
        mathprose=math_prose,
        column=fcolumn,
        unitrow=axis_unit_row,
    )
    return env





@dataclass(frozen=True)
class LatexBuild:
    """The outcome of running LaTeX on report.tex."""

    tool: str | None  # "latexmk", "pdflatex" or None (no TeX installed)
    ok: bool
    seconds: float
    error: str = ""  # the first LaTeX error line when not ok


_LATEX_FLAGS = ("-interaction=nonstopmode", "-halt-on-error", "-file-line-error")


def first_latex_error(log: str) -> str:
    """The first error line of a LaTeX log (file:line: message, or ! message)."""
    for line in log.splitlines():
        if re.match(r"^(\./)?[^:\s]+\.tex:\d+: ", line) or line.startswith("! "):
            return line.strip()
    return "unknown LaTeX error"


_OVERFULL = re.compile(r"^Overfull \\[hv]box \(([\d.]+)pt too (?:wide|high)\)", re.MULTILINE)


def overfull_boxes(log: str) -> list[float]:
    """The excess, in pt, of every overfull box reported in a LaTeX log."""
    return [float(m.group(1)) for m in _OVERFULL.finditer(log)]


def source_date_epoch() -> str:
    """The PDF's creation date (seconds since 1970): $SOURCE_DATE_EPOCH when set (the
    reproducible-builds convention: the same date, the same bytes), else the build's time."""
    given = os.environ.get("SOURCE_DATE_EPOCH", "").strip()
    return given if given.isdigit() else str(int(time.time()))


def run_latex(folder: Path, timeout: float = 600.0) -> LatexBuild:
    """Build report.pdf from report.tex in ``folder`` with latexmk (or pdflatex, 3 passes)."""
    tool = find_tex()
    if tool is None:
        return LatexBuild(None, False, 0.0, "")
    start = time.monotonic()
    if tool == "latexmk":
        cmds = [["latexmk", "-pdf", *_LATEX_FLAGS, "report.tex"]]
    else:
        cmds = [["pdflatex", *_LATEX_FLAGS, "report.tex"]] * 3
    env = dict(os.environ, SOURCE_DATE_EPOCH=source_date_epoch(), FORCE_SOURCE_DATE="1")
    for cmd in cmds:
        try:
            proc = subprocess.run(
                cmd,
                cwd=folder,
                capture_output=True,
                text=True,
                errors="replace",
                timeout=timeout,
                env=env,
                stdin=subprocess.DEVNULL,
            )
        except subprocess.TimeoutExpired:
            return LatexBuild(
                tool, False, time.monotonic() - start, f"{tool} did not finish within {timeout:g} s"
            )
        if proc.returncode != 0:
            log = folder / "report.log"
            text = log.read_text(errors="replace") if log.exists() else proc.stdout
            return LatexBuild(tool, False, time.monotonic() - start, first_latex_error(text))
    for ext in (".aux", ".fls", ".fdb_latexmk", ".out", ".toc"):
        (folder / f"report{ext}").unlink(missing_ok=True)
    return LatexBuild(tool, True, time.monotonic() - start)

