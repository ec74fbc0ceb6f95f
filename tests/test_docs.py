"""The documentation site (`make docs`): it builds with warnings as errors, and it documents
everything the package exposes.

References: the objects themselves, not the documentation's sources: ``maglevgen.__all__``
and the public members of the API's classes (read by ``inspect``), every command and option
of the argparse parser (walked here), every key of the schema (``params.schema_table``) and
every entry of the default carriage's parameter vector, read back from the built HTML and
from Sphinx's object inventory (``objects.inv``).
"""

from __future__ import annotations

import argparse
import html
import inspect
import re
import subprocess
import sys
from pathlib import Path

import pytest

import maglevgen
from maglevgen.cli import build_parser
from maglevgen.params import flatten, load_params, schema_table

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The HTML site built as `make docs` builds it (-W: any warning fails the build)."""
    out = tmp_path_factory.mktemp("docs")
    proc = subprocess.run([sys.executable, "-m", "sphinx", "-W", "--keep-going", "-E", "-q",
                           "-b", "html", "-d", str(out / "doctrees"), str(DOCS),
                           str(out / "html")], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-5000:]
    assert proc.stderr.strip() == "", proc.stderr[-5000:]
    return out / "html"


def _text(page: Path) -> str:
    """A page's visible text, tags removed and entities decoded, whitespace collapsed."""
    body = re.sub(r"<[^>]+>", "", page.read_text(encoding="utf-8"))
    return " ".join(html.unescape(body).split())


def _inventory(site: Path) -> set[str]:
    from sphinx.util.inventory import InventoryFile

    with open(site / "objects.inv", "rb") as f:
        inv = InventoryFile.load(f, "", lambda base, uri: uri)
    return {name for kind, entries in inv.items() if kind.startswith("py:") for name in entries}


def _public_api() -> list[str]:
    """Every public object: maglevgen.__all__ and the public members of its classes (those
    defined in maglevgen: `Carriage`'s come from the API's core, studies and writers)."""
    names = [f"maglevgen.{n}" for n in maglevgen.__all__]
    for n in maglevgen.__all__:
        obj = getattr(maglevgen, n)
        if inspect.isclass(obj) and not issubclass(obj, BaseException):
            ours = [vars(b) for b in obj.__mro__ if b.__module__.split(".")[0] == "maglevgen"]
            names += [f"maglevgen.{n}.{m}" for m, _ in inspect.getmembers(obj)
                      if not m.startswith("_") and any(m in v for v in ours)]
    return names


def _commands(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()
              ) -> list[tuple[tuple[str, ...], argparse.ArgumentParser]]:
    out = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                out.append(((*path, name), sub))
                out += _commands(sub, (*path, name))
    return out


def test_every_public_api_object_is_documented(site: Path) -> None:
    documented = _inventory(site)
    missing = [n for n in _public_api() if n not in documented]
    assert not missing, missing
    assert len(_public_api()) > len(maglevgen.__all__)  # the classes' methods were walked
    page = _text(site / "api.html")
    assert "Examples" in page and "Parameters" in page  # numpydoc's sections rendered


def test_every_command_and_option_is_in_the_cli_reference(site: Path) -> None:
    raw = (site / "cli.html").read_text(encoding="utf-8")
    text = _text(site / "cli.html")
    commands = _commands(build_parser())
    assert {p[0] for p, _ in commands} >= {"trim", "gains", "fmu", "build", "params"}
    for path, sub in commands:
        assert f'id="maglevgen-{"-".join(path)}"' in raw, path
        for action in sub._actions:
            if isinstance(action, argparse._HelpAction):
                continue  # -h, which sphinx-argparse leaves out of every command
            for opt in action.option_strings:
                assert opt in text, (path, opt)
            for choice in action.choices or ():
                if not isinstance(action, argparse._SubParsersAction):
                    assert str(choice) in text, (path, choice)


def test_every_parameter_key_unit_and_range_is_in_the_reference(site: Path) -> None:
    text = _text(site / "parameters.html")
    for key, unit, _desc, _paper, allowed in schema_table():
        assert key in text, key
        assert " ".join(allowed.split()) in text, (key, allowed)
        assert unit in text, (key, unit)
    loaded = load_params()
    for e in flatten(loaded.params):  # every entry of p with its value
        assert f"{e.name} {float(e.value)!r}" in text, e.name
    for key, prov in loaded.params.provenance.items():  # every reason the file gives
        assert " ".join(prov.why.split()) in text, key


def test_guides_theory_and_examples_are_rendered(site: Path) -> None:
    start = _text(site / "getting_started.html")
    assert "make run" in start and "make test" in start and "SUMMARY.md" in start
    assert "maglevgen build" in start
    assert "arm-none-eabi-gcc" in _text(site / "firmware.html")
    assert "modelDescription.xml" in _text(site / "fmu.html")
    theory = _text(site / "theory.html")
    for eqs in ("eqs 1-2", "eqs 3-4", "eqs 8-12", "eqs 5-19", "eqs 20-23", "eqs 24-33"):
        assert eqs in theory
    examples = _text(site / "examples.html")
    for script in sorted((REPO / "examples").glob("*.py")):
        assert script.name in examples
        last = [ln for ln in script.read_text().splitlines() if ln.strip()][-1].strip()
        assert html.unescape(last) in examples, script.name  # the whole source is shown
    assert "carriage.envelope(n_speeds=N_SPEEDS)" in examples  # the notebook's cells
    # with their outputs, executed at build time: the plant's states as the API names them,
    # each controller's envelope verdict and the envelope's plot
    page = (site / "examples.html").read_text()
    assert re.search(r"10 states: \[('\w+', ){9}'\w+'\]", examples), "no cell output"
    assert "stable across" in examples and "data:image/png;base64," in page
    # each script's stored output under it (tests/test_examples.py: the same as a run now),
    # its figures copied into the site byte for byte
    sys.path.insert(0, str(DOCS / "_ext"))
    from example_outputs import scripts, stored

    for script in scripts():
        text, figures = stored(script)
        assert text.strip(), script.name
        for line in text.splitlines():
            assert " ".join(html.unescape(line).split()) in examples, (script.name, line)
        for rel, png in figures.items():
            assert f"example_output/{rel}" in examples, rel
            shown = [p for p in (site / "_images").glob(f"{png.stem}*{png.suffix}")
                     if p.read_bytes() == png.read_bytes()]
            assert shown, rel


def test_the_readme_is_short_and_points_to_every_page(site: Path) -> None:
    """The README is a screen or two (the two commands, what and for whom, the verdicts, the
    site's parts); every page of the site is named there by its source, and each page it
    names exists."""
    readme = (REPO / "README.md").read_text()
    assert len(readme.splitlines()) <= 80, len(readme.splitlines())
    assert "make run" in readme and "make test" in readme
    pages = {p.stem for p in DOCS.glob("*.rst")} - {"index"}
    named = set(re.findall(r"`(\w+)\.rst`", readme))
    assert named == pages, (pages - named, named - pages)
    for stem in pages:
        assert (site / f"{stem}.html").is_file(), stem


def test_benchmarks_and_testing_are_included_not_copied(site: Path) -> None:
    """The site's benchmarks and testing pages carry BENCHMARKS.md's and TESTING.md's text
    (a sentence from each, read from the files), and docs/ holds no copy of either."""
    for name, page in (("BENCHMARKS.md", "benchmarks"), ("TESTING.md", "testing")):
        source = (REPO / name).read_text()
        para = next(ln for ln in source.splitlines()[1:]
                    if len(ln) > 60 and not set("`[*|_<") & set(ln))
        assert " ".join(para.split()) in _text(site / f"{page}.html"), (name, para)
        assert f"../{name}" in (DOCS / f"{page}.rst").read_text()
        copies = [p for p in DOCS.rglob("*.md") if para in p.read_text()]
        assert not copies, copies


def test_no_code_block_or_table_is_cut_at_1280px(site: Path) -> None:
    """The site's stylesheet wraps code blocks, lets wide tables scroll in their own box and
    widens alabaster's fixed 940 px column (what cut the parameter table and the commands'
    code at a 1280 px window): every page links it, and its rules are those."""
    css = (site / "_static" / "maglev.css").read_text()
    rules = dict(re.findall(r"([^{}]+)\{([^}]*)\}", re.sub(r"/\*.*?\*/", "", css, flags=re.S)))
    rules = {" ".join(k.split()): v for k, v in rules.items()}
    assert "pre-wrap" in rules["pre"]
    assert "overflow-x: auto" in rules["table.docutils"]
    assert "max-width: 100%" in rules["table.docutils"]
    assert "width: auto" in rules["div.document"]
    for page in site.glob("*.html"):
        if page.name in ("genindex.html", "search.html", "py-modindex.html"):
            continue
        assert "_static/maglev.css" in page.read_text(), page.name


def test_the_summary_guide_follows_summary_md(site: Path, default_build: Path) -> None:
    """"Reading SUMMARY.md" names the parts of the default build's SUMMARY.md by the words
    that open each, in the file's order."""
    guide = (DOCS / "getting_started.rst").read_text()
    part = guide[guide.index("Reading SUMMARY.md"):guide.index("Exit codes")]
    openers = re.findall(r"^\d+\. ``([^`]+)``", part, re.M)
    assert len(openers) >= 8, openers
    summary = (default_build / "SUMMARY.md").read_text()
    where = [summary.find(o) for o in openers]
    assert all(w >= 0 for w in where), dict(zip(openers, where, strict=True))
    assert where == sorted(where), dict(zip(openers, where, strict=True))


def test_the_notebook_names_the_default_embedded_controller() -> None:
    """Where the example notebook names the default embedded controller, it names the one the
    default parameter file sets (envelope.embedded_controller)."""
    import json

    nb = json.loads((REPO / "examples" / "linearization_envelope.ipynb").read_text())
    text = " ".join("".join(c["source"]) for c in nb["cells"] if c["cell_type"] == "markdown")
    default = load_params().params.envelope.embedded_controller
    named = re.findall(r"default\s+embedded\s+controller\s+is\s+`(\w+)`", text)
    assert named == [default], (named, default)
    # and no other controller called the default one ("coupled, the default embedded ...")
    others = [n for n in re.findall(r"\"(\w+)\"\)?`\W{1,4}the\s+default\s+embedded", text)
              if n != default]
    assert not others, others


GUIDES = DOCS / "_guides"
# a cross-reference left as plain words: "(see Report below)", "see Firmware use",
# "BENCHMARKS.md section 9"
_PLAIN_REF = re.compile(r"\bsee (?!\{doc\}|\{ref\}|:doc:|:ref:|\[)[A-Z][\w-]*|"
                        r"\b[A-Z][\w-]* (?:below|above)\)|\(see (?:below|above)\)|"
                        r"BENCHMARKS\.md,? \(?section \d", re.M)


def test_the_guides_cross_references_are_links_that_resolve(site: Path) -> None:
    """The guides moved from the README into docs/_guides say "see ..." as Sphinx links, not
    as the README's section names ("see Report below"), and each link is in the built page
    that includes the guide (the build's -W has already failed any that does not resolve)."""
    texts = {p: p.read_text() for p in [*GUIDES.glob("*.md"), *DOCS.glob("*.rst")]}
    plain = [(p.name, m.group(0)) for p, t in texts.items() for m in _PLAIN_REF.finditer(t)]
    assert not plain, plain
    links = 0
    for rst in DOCS.glob("*.rst"):
        for guide in re.findall(r"\.\. include:: _guides/(\S+\.md)", texts[rst]):
            page = (site / f"{rst.stem}.html").read_text()
            for kind, target in re.findall(r"\{(doc|ref)\}`([^`]+)`", texts[GUIDES / guide]):
                want = f'href="{target}.html' if kind == "doc" else f'#{target}"'
                assert want in page, (rst.name, guide, target)
                links += 1
    assert links >= 10, links


def test_no_tracked_file_keeps_a_merge_conflict_marker() -> None:
    """git's own list of tracked files (``git ls-files``), each text file read: no line is a
    conflict marker a merge left (Sphinx renders them in Markdown without a warning)."""
    files = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True,
                           check=True).stdout.decode().split("\0")
    marker = re.compile(r"^(<{7}|>{7}) ", re.MULTILINE)
    found = []
    for name in filter(None, files):
        path = REPO / name
        if not path.is_file():
            continue
        try:
            text = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:  # a binary file
            continue
        found += [f"{name}:{text.count(chr(10), 0, m.start()) + 1}"
                  for m in marker.finditer(text)]
    assert found == [], found
