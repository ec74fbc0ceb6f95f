"""`maglevgen report`: the LaTeX derivation report, rendered from the derivation itself.

The package, top down: ``render`` assembles the context of every section (``sections/``, one
module per section of the report, each returning plain data and LaTeX strings), renders
report.tex and writes the files; ``latex`` runs LaTeX; ``display`` turns SymPy expressions into
aligned displays; ``symbols`` names the parameters' symbols; ``format`` formats every number
and escapes every string that reaches LaTeX.
"""

from __future__ import annotations

from .latex import INSTALL_HINT, TEX_PACKAGES, LatexBuild, first_latex_error, overfull_boxes
from .render import (
    SECTION_TITLES,
    ReportFiles,
    ReportOptions,
    ReportResult,
    build_context,
    render_report,
    render_tex,
    report_files,
    write_report,
)
from .sections.actuators import RUN_DT, RUN_T_END
from .sections.force_law import force_curves
from .sections.simulation import SIMULATION_FIGURES

__all__ = ["INSTALL_HINT", "RUN_DT", "RUN_T_END", "SECTION_TITLES", "SIMULATION_FIGURES",
           "TEX_PACKAGES", "LatexBuild",
           "ReportFiles", "ReportOptions", "ReportResult", "build_context", "first_latex_error",
           "force_curves", "overfull_boxes", "render_report", "render_tex", "report_files",
           "write_report"]
