"""Sphinx directives that render maglevgen's facts from their one source.

``maglev-parameters``
    The parameter file's reference from the schema (maglevgen.params.schema_table: every key,
    its unit, meaning, the paper's value, the allowed range and the reason for it), then the
    default carriage's parameter vector (maglevgen.params.flatten) with each value's
    provenance (the file's ``[provenance]`` table: "paper" with where, or "assumed" with why).
``maglev-examples``
    Every script of examples/ (its docstring, its source, then what running it printed and
    drew: the outputs stored in docs/_examples/, which tests/test_examples.py checks are those
    of running it now; _ext/example_outputs.py), in name order, so that a new example appears
    without editing the page.
``maglev-notebook``
    A Jupyter notebook's cells (markdown as text, code as Python blocks), each code cell with
    its outputs: the notebook is executed at build time (nbclient, the docs extra).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

from docutils import nodes
from docutils.statemachine import StringList
from sphinx.application import Sphinx
from sphinx.util.docutils import SphinxDirective

REPO = Path(__file__).resolve().parents[2]
EXAMPLES = REPO / "examples"


def _cell(text: str) -> str:
    """A table cell on one line, with the characters reST would read as markup escaped."""
    text = " ".join(str(text).split())
    return re.sub(r"([*`|_\\])", r"\\\1", text) if text else ".."


def _table(title: str, header: tuple[str, ...], rows: list[tuple[str, ...]],
           widths: str) -> list[str]:
    """A reST list-table; the first column is a key shown literally, the others escaped."""
    out = [f".. list-table:: {title}", "   :header-rows: 1", f"   :widths: {widths}", ""]
    for i, row in enumerate((header, *rows)):
        first = _cell(row[0]) if i == 0 or not row[0] else f"``{row[0]}``"
        out.append(f"   * - {first}")
        out += [f"     - {_cell(c)}" for c in row[1:]]
    return [*out, ""]


def _provenance(key: str, provenance: dict) -> str:
    """The provenance entry of ``key`` or of the nearest table that holds it."""
    parts = key.split(".")
    for n in range(len(parts), 0, -1):
        entry = provenance.get(".".join(parts[:n]))
        if entry is not None:
            return f"{entry.source}: {entry.why}"
    return ""


class _Rst(SphinxDirective):
    """A directive that writes reST lines and returns what they parse to."""

    def _parse(self, lines: list[str]) -> list[nodes.Node]:
        node = nodes.container()
        self.state.nested_parse(StringList(lines, source=self.get_source_info()[0]),
                                self.content_offset, node)
        return node.children


class ParametersDirective(_Rst):
    """The schema's every key, then the default carriage's values with their provenance."""

    has_content = False

    def run(self) -> list[nodes.Node]:
        from maglevgen.params import default_params_path, flatten, load_params, schema_table

        for source in sorted((REPO / "maglevgen" / "params").glob("*.py")):  # the schema
            self.env.note_dependency(str(source))
        self.env.note_dependency(str(default_params_path()))
        loaded = load_params()
        values = [(e.name, repr(float(e.value)), e.unit,
                   _provenance(e.name, loaded.params.provenance)) for e in flatten(loaded.params)]
        lines = _table("Every key of the schema", ("key", "unit", "meaning", "paper",
                                                   "allowed values and why"),
                       schema_table(), "20 6 30 8 36")
        lines += [".. _default-carriage-values:", ""]
        lines += _table("The default carriage (maglevgen/carriage_llnl.toml): the parameter "
                        "vector p in the generated C's order",
                        ("entry", "value", "unit", "provenance"), values, "25 12 8 55")
        names = {e.name for e in flatten(loaded.params)}
        others = [(k, f"{v.source}: {v.why}") for k, v in loaded.params.provenance.items()
                  if k not in names]
        lines += _table("The default carriage: provenance of the choices and of the tables "
                        "(an entry of p without its own line above takes its table's)",
                        ("key or table", "provenance"), others, "25 75")
        return self._parse(lines)


class ExamplesDirective(_Rst):
    """Each example script: a section with its docstring, its source and its stored
    outputs (stdout, then each figure captioned with the path the script wrote it to)."""

    has_content = False

    def run(self) -> list[nodes.Node]:
        from example_outputs import DEFAULT_OUT, STORE, scripts, stored

        lines: list[str] = []
        for path in scripts():
            self.env.note_dependency(str(path))
            doc = ast.get_docstring(ast.parse(path.read_text())) or ""
            rel = Path("..") / path.relative_to(REPO)
            lines += [f".. rubric:: {path.name}", "", "::", ""]
            lines += [f"    {line}" for line in doc.splitlines()]
            lines += ["", f".. literalinclude:: {rel.as_posix()}", "   :language: python",
                      "   :lines: " + f"{_after_docstring(path)}-", ""]
            text, figures = stored(path)
            self.env.note_dependency(str(STORE / path.stem / "output.txt"))
            lines += [f"Its output (``python examples/{path.name}``):", "",
                      ".. code-block:: text", "   :class: maglev-output", ""]
            lines += [f"   {line}" if line else "" for line in text.splitlines()]
            lines.append("")
            for name, png in figures.items():
                self.env.note_dependency(str(png))
                src = "/" + png.relative_to(REPO / "docs").as_posix()
                lines += [f".. figure:: {src}", f"   :alt: {DEFAULT_OUT}/{name}",
                          "   :class: maglev-output", "",
                          f"   ``{DEFAULT_OUT}/{name}``", ""]
        return self._parse(lines)


def _after_docstring(path: Path) -> int:
    """The first source line after the module docstring (1-based)."""
    tree = ast.parse(path.read_text())
    first = tree.body[0]
    return (first.end_lineno or 0) + 1 if isinstance(first, ast.Expr) else 1


def _markdown_to_rst(text: str) -> list[str]:
    """The plain Markdown of the notebook's text cells: headings, paragraphs and `code`."""
    out: list[str] = []
    for line in text.splitlines():
        m = re.match(r"^(#+)\s+(.*)$", line)
        if m:
            out += [f".. rubric:: {m.group(2)}", ""]
            continue
        out.append(re.sub(r"`([^`]+)`", r"``\1``", line))  # bold (**x**) reads the same
    return [*out, ""]


def _executed(path: Path) -> list[dict]:
    """The notebook's cells after running it top to bottom in a Jupyter kernel (nbclient, the
    docs extra), in a temporary folder: the page shows what the code prints today. A cell
    that fails fails the build (-W turns the warning into an error)."""
    import subprocess
    import tempfile

    import nbformat
    from nbclient import NotebookClient

    nb = nbformat.read(path, as_version=4)
    with tempfile.TemporaryDirectory() as tmp:
        NotebookClient(nb, timeout=600, kernel_name="python3",
                       resources={"metadata": {"path": tmp}}).execute(
                           stderr=subprocess.DEVNULL)  # the kernel's own notices: not the site's
    return [dict(c) for c in nb.cells]


def _outputs(cell: dict) -> list[str]:
    """A code cell's outputs as reST: printed text as a text block, a PNG inline."""
    lines: list[str] = []
    for out in cell.get("outputs", []):
        kind = out.get("output_type")
        data = out.get("data", {})
        text = out.get("text") if kind == "stream" else data.get("text/plain")
        if "image/png" in data:
            png = "".join(data["image/png"].split())
            lines += [".. raw:: html", "",
                      f'   <img class="maglev-output" alt="cell output" '
                      f'src="data:image/png;base64,{png}">', ""]
        elif text:
            text = "".join(text) if isinstance(text, list) else text
            lines += [".. code-block:: text", "   :class: maglev-output", ""]
            lines += [f"   {line}" if line else "" for line in text.splitlines()]
            lines.append("")
    return lines


class NotebookDirective(_Rst):
    """A notebook's cells in order, each code cell followed by its outputs (the notebook run
    at build time, `_executed`)."""

    required_arguments = 1

    def run(self) -> list[nodes.Node]:
        path = (REPO / "docs" / self.arguments[0]).resolve()
        self.env.note_dependency(str(path))
        lines: list[str] = []
        for cell in _executed(path):
            src = "".join(cell["source"])
            if cell["cell_type"] == "markdown":
                lines += _markdown_to_rst(src)
            elif cell["cell_type"] == "code":
                lines += [".. code-block:: python", ""]
                lines += [f"   {line}" if line else "" for line in src.splitlines()]
                lines.append("")
                lines += _outputs(cell)
        return self._parse(lines)


def setup(app: Sphinx) -> dict:
    app.add_directive("maglev-parameters", ParametersDirective)
    app.add_directive("maglev-examples", ExamplesDirective)
    app.add_directive("maglev-notebook", NotebookDirective)
    return {"version": "1", "parallel_read_safe": True}
