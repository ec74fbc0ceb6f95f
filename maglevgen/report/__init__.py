"""`maglevgen report`: the LaTeX derivation report, rendered from the derivation itself.

The package, top down: ``render`` assembles the context of every section (``sections/``, one
module per section of the report, each returning plain data and LaTeX strings), renders
report.tex and writes the files; ``latex`` runs LaTeX; ``display`` turns SymPy expressions into
aligned displays; ``symbols`` names the parameters' symbols; ``format`` formats every number
and escapes every string that reaches LaTeX; ``figures`` draws the report's figures from plain
numbers, without SymPy.

The names below load their module on first use (PEP 562): the figure-drawing worker imports
``figures`` without the 2 s of SymPy that ``render`` costs.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

# name -> the module of this package that defines it
_EXPORTS = {
    "INSTALL_HINT": "latex", "first_latex_error": "latex", "overfull_boxes": "latex",
    "run_latex": "latex", "SECTION_TITLES": "render", "ReportOptions": "render",
    "build_context": "render", "render_tex": "render", "report_files": "render",
    "write_report": "render", "RUN_DT": "sections.actuators", "RUN_T_END": "sections.actuators",
    "force_curves": "sections.force_law",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(import_module(f"{__name__}.{_EXPORTS[name]}"), name)
