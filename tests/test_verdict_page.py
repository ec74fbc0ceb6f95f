"""One verdict everywhere: the report's first page carries the verdict block of SUMMARY.md (and
stdout, which prints SUMMARY.md) word for word, for a passing and a failing verdict.

The first page is typeset from the build's own report.tex, cut after its summary section (the
pages before the cut are laid out as in the whole report: LaTeX sets page 1 before it reads
what follows), with one pdflatex pass; its text is read back with poppler's pdftotext -raw
(which keeps a hyphen at a line's end) and compared with SUMMARY.md's lines, the Markdown's
backticks and the line breaks taken out.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

from maglevgen.control.carriage_plant import Plant
from maglevgen.report.sections.summary import verdict_tex

pytestmark = pytest.mark.needs_tex


def _words(text: str) -> str:
    """Text as a reader compares it: no Markdown code marks, one space between words, the
    PDF's typographic quote as the Markdown's."""
    return re.sub(r"\s+", " ", text.replace("`", "").replace("\u2019", "'")).strip()


def _first_page(report_tex: str, folder: Path) -> str:
    """pdftotext of page 1 of ``report_tex`` cut after its summary (module docstring)."""
    start = report_tex.index(r"\section*{Summary of findings}")
    cut = report_tex.index(r"\section{", start)
    (folder / "report.tex").write_text(report_tex[:cut] + "\\end{document}\n")
    subprocess.run(["pdflatex", "-interaction=nonstopmode", "-halt-on-error", "report.tex"],
                   cwd=folder, check=True, capture_output=True, timeout=120)
    return subprocess.run(["pdftotext", "-raw", "-f", "1", "-l", "1", "report.pdf", "-"],
                          cwd=folder, check=True, capture_output=True, text=True).stdout


def _summary_block(summary: str) -> list[str]:
    """SUMMARY.md's verdict block: from the line after the parameter file's (and a warning)
    to the list of details, each line without its list mark."""
    lines = summary.split("\n\nDetails:", 1)[0].splitlines()
    head = next(i for i, ln in enumerate(lines) if ln.startswith("The embedded controller `"))
    return [ln.removeprefix("- ") for ln in lines[head:] if ln.strip()]


def _assert_on_page(lines: list[str], page: str) -> None:
    """Every line on the page, in order, word for word."""
    text, at = _words(page), 0
    for line in lines:
        found = text.find(_words(line), at)
        assert found >= 0, f"not on page 1 (in order): {line[:160]!r}"
        at = found + len(_words(line))


def test_page_one_carries_summarys_verdict_block_for_a_passing_build(default_build: Path,
                                                                    tmp_path: Path) -> None:
    """The default build (exit 0): its report's first page holds SUMMARY.md's verdict
    block, the head saying VERIFIED and every check deciding the exit code."""
    summary = (default_build / "SUMMARY.md").read_text()
    block = _summary_block(summary)
    assert "VERIFIED" in block[0] and "exits 0" in block[0]
    decisive = block[1:block.index(next(ln for ln in block if ln.startswith("Findings")))]
    assert any(ln.startswith("launch run") for ln in decisive)
    assert any(ln.startswith("region of attraction") for ln in decisive)
    page = _first_page((default_build / "report/report.tex").read_text(), tmp_path)
    _assert_on_page(decisive, page)
    _assert_on_page(block[:1], page)


def test_page_one_carries_the_failing_verdict_and_never_meets(default_build: Path,
                                                              tmp_path: Path, sim_lib) -> None:
    """A verdict that fails (a levitation decay no design reaches: build would exit 3),
    made by the build's own function, typeset into the default report's first page by the
    function the report uses: the page holds the verdict's lines (what SUMMARY.md prints),
    its head says FAILS and exit 3, and no "VERIFIED"."""
    from maglevgen.analyses.envelope import compute_envelope
    from maglevgen.analyses.verdicts import embedded_verdict
    from maglevgen.carriage import DerivedCarriage
    from maglevgen.params import load_params

    carriage = DerivedCarriage(load_params(
        None, ["control.spec.min_levitation_decay_rate=500"]))
    env = compute_envelope(Plant(carriage, sim_lib), 3, ("spec", "lqr"), other_models=False)
    verdict = embedded_verdict(carriage, env)
    assert verdict.reason is not None  # what `build` exits 3 with
    lines = [ln.removeprefix("- ") for ln in verdict.lines() if ln.strip()]
    assert "FAILS" in lines[0] and "exits 3" in lines[0]
    assert "levitation decay rate >= 500 1/s" in lines[1]
    tex = (default_build / "report/report.tex").read_text()
    start = tex.index("% the verdict block")
    end = tex.index("% end of the verdict block")
    page = _first_page(tex[:start] + verdict_tex(verdict) + tex[end:], tmp_path)
    _assert_on_page(lines, page)
    assert "VERIFIED" not in page
