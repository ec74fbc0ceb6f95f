"""Sphinx configuration of maglevgen's documentation site (`make docs`: docs/_build/html).

The pages that list facts read them from their one source: the CLI reference from the argparse
parser (sphinx-argparse over maglevgen.cli.build_parser), the API reference from the numpydoc
docstrings (autodoc), the parameter reference from the schema (maglevgen.params.schema_table,
through the ``maglev-parameters`` directive of _ext/maglevdocs.py), the guides from
docs/_guides/*.md and BENCHMARKS.md/TESTING.md (myst-parser, included) and the examples
from examples/ (the notebook executed at build time; the scripts' outputs stored in
docs/_examples/ by `make example-outputs` and checked current by tests/test_examples.py).
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))

from maglevgen.version import __version__  # noqa: E402

project = "maglevgen"
author = "the maglevgen developers"
copyright = "2026, the maglevgen developers"
version = release = __version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.mathjax",
    "numpydoc",
    "sphinxarg.ext",
    "myst_parser",
    "maglevdocs",
]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
# _guides: included by the pages; _examples: the examples' stored outputs (maglev-examples)
exclude_patterns = ["_build", "_guides", "_examples"]
root_doc = "index"

# numpydoc: the docstrings' sections; no autosummary stubs (one page lists the whole API)
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False
autodoc_member_order = "bysource"
autodoc_typehints = "none"  # numpydoc's Parameters sections give the types
myst_heading_anchors = 3
smartquotes = False  # TOML values and option strings stay copyable ("box", --set a="b")

html_theme = "alabaster"
html_title = f"maglevgen {__version__}"
html_static_path = ["_static"]
# maglev.css: code blocks and wide tables wrap or scroll inside the page (none cut at 1280 px)
html_css_files = ["maglev.css"]
html_theme_options = {"page_width": "min(1240px, 96vw)", "body_max_width": "none"}
