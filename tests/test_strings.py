"""User strings through the one validation/escape point (issue 54): control characters in a
provenance text refused (exit 2, one line naming the key), lengths bounded, ``--set`` values a
single TOML value, LaTeX and Markdown escaping judged by LaTeX and a CommonMark renderer, and
a full disk in the cache's compile as exit 2.
"""

from __future__ import annotations

import errno
import html
import re
import subprocess
import unicodedata
from pathlib import Path

import pytest
from markdown_it import MarkdownIt

from maglevgen.cli import main
from maglevgen.errors import InputError
from maglevgen.infrastructure.text import markdown_code, shown_name
from maglevgen.report.format import tex_escape

DEFAULT = Path(__file__).resolve().parents[1] / "maglevgen" / "carriage_llnl.toml"


def _with_provenance(tmp_path: Path, why: str) -> Path:
    """The default file with the first provenance note's text replaced by ``why`` (a TOML
    basic string: every control character written as a \\u escape)."""
    text = DEFAULT.read_text()
    m = re.search(r'why = "((?:[^"\\]|\\.)*)"', text)
    assert m is not None
    escaped = "".join(f"\\u{ord(c):04x}" if ord(c) < 32 or ord(c) == 127 or c in '"\\' else c
                      for c in why)
    path = tmp_path / "p.toml"
    path.write_text(text[:m.start(1)] + escaped + text[m.end(1):])
    return path


def _one_line(capsys, rc: int, *expected: str) -> str:
    out, err = capsys.readouterr()
    assert rc == 2, err
    assert out == "" and len(err.splitlines()) == 1, err
    for s in expected:
        assert s in err, err
    return err


@pytest.mark.parametrize(("char", "code"), [("\0", "U+0000"), ("\x01", "U+0001"),
                                            ("\x7f", "U+007F"), ("\x1b", "U+001B")])
def test_control_characters_in_a_provenance_are_refused(tmp_path: Path, capsys, char: str,
                                                        code: str) -> None:
    path = _with_provenance(tmp_path, f"from the paper{char}[31m, table 1")
    rc = main(["trim", "--params", str(path), "--json"])
    _one_line(capsys, rc, "provenance", f"control character {code}")


def test_a_megabyte_provenance_is_refused(tmp_path: Path, capsys) -> None:
    path = _with_provenance(tmp_path, "x" * (1 << 20))
    rc = main(["trim", "--params", str(path), "--json"])
    _one_line(capsys, rc, "provenance", f"{1 << 20} characters long")


@pytest.mark.parametrize("value", ["9.3\nvehicle.length = 1", "9.3\n\n\n", "9.3\r", "9.3\t"])
def test_a_set_value_is_one_toml_value_on_one_line(capsys, value: str) -> None:
    rc = main(["trim", "--set", f"vehicle.mass={value}", "--json"])
    _one_line(capsys, rc, "--set vehicle.mass", "control character")


def test_a_set_value_with_a_second_key_is_refused() -> None:
    from maglevgen.params import parse_override

    assert parse_override("vehicle.mass = 9.3  # a comment") == ("vehicle.mass", 9.3)
    with pytest.raises(InputError, match="control character U\\+2028"):
        parse_override('vehicle.mass = 9.3 \u2028 x = 1')


HOSTILE = ("caf\u00e9 \u03bb \u03c2 \u4e2d \u00b5 \U0001f600 \u00e9\u0301 $x^2$ 50% #1 a_b {c} "
           "~ \\ \0\x01\x7f\x1b[31m \u202e")
# accented Latin letters, Greek and CJK: typeset (the first two) or shown as code points
INTERNATIONAL = ("M\u00fcller & Sch\u00f6n, \u00c5ngstr\u00f6m-Institut, caf\u00e9 "
                 "\u00d1and\u00fa fa\u00e7ade; Stra\u00dfe; \u03b1 = \u03c9/\u03bb, \u0394 \u03a9; "
                 "\u4e2d\u6587\u8cc7\u6599 (\U0001f600)")
TEMPLATE = Path(__file__).resolve().parents[1] / "templates" / "report.tex.j2"


def _typeset(tmp_path: Path, body: str) -> str:
    """``body`` in a document with the report's own preamble (templates/report.tex.j2: its
    class, packages and font encoding), built by pdflatex and read back by pdftotext (NFC)."""
    template = TEMPLATE.read_text()
    preamble = template[template.index("\\documentclass"):template.index("\\begin{document}")]
    doc = tmp_path / "t.tex"
    doc.write_text(preamble.replace("\\VAR{version}", "test")
                   + f"\\begin{{document}}\n{body}\n\\end{{document}}\n")
    done = subprocess.run(["pdflatex", "-interaction=nonstopmode", "-halt-on-error", doc.name],
                          cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout[-2000:]
    assert "Missing character" not in (tmp_path / "t.log").read_text()
    text = subprocess.run(["pdftotext", "t.pdf", "-"], cwd=tmp_path, capture_output=True,
                          text=True, check=True).stdout
    return unicodedata.normalize("NFC", text)


@pytest.mark.needs_tex
def test_escaped_unicode_and_control_characters_typeset(tmp_path: Path) -> None:
    """pdflatex (the report's engine, with the report's preamble) typesets the escaped text;
    what it prints keeps every ASCII letter of the input and the accented and Greek letters."""
    escaped = tex_escape(HOSTILE)
    assert all(32 <= ord(c) < 127 or c == "\n" for c in escaped), escaped
    text = _typeset(tmp_path, escaped)
    for word in ("caf\u00e9", "\u03bb", "50%", "#1", "{c}", "[31m", "[U+4E2D]", "[U+1F600]"):
        assert word in text, text
    assert re.search("a[ _]b", text), text  # OT1's underscore is a rule: pdftotext's space


@pytest.mark.needs_tex
def test_a_provenance_in_greek_accents_and_cjk_reaches_the_pdf(tmp_path: Path) -> None:
    """A provenance note with accented Latin, Greek and CJK text, as the report's parameter
    table takes it (`provenance_of` of a validated file, `tex_escape`): the accented and Greek
    letters typeset as themselves, the CJK shown as its code points (no font for it in the
    TeX Live packages the report needs), nothing dropped."""
    from maglevgen.params import load_params
    from maglevgen.report.sections.parameters import provenance_of

    loaded = load_params(_with_provenance(tmp_path, INTERNATIONAL))
    note = next(n for k in ("vehicle.mass", "halbach.remanence", "vehicle.length")
                if (n := provenance_of(k, loaded.params.provenance)) is not None
                and n.text == INTERNATIONAL)
    text = " ".join(_typeset(tmp_path, tex_escape(note.text)).split())
    expected = ("M\u00fcller & Sch\u00f6n, \u00c5ngstr\u00f6m-Institut, caf\u00e9 \u00d1and\u00fa "
                "fa\u00e7ade; Stra\u00dfe; \u03b1 = \u03c9/\u03bb,")
    assert expected in text, text
    # capital Delta: pdftotext reads the glyph's name as U+2206 (increment)
    assert "\u03a9" in text and ("\u0394" in text or "\u2206" in text), text
    # (a line may break after each code point)
    assert "[U+4E2D][U+6587][U+8CC7][U+6599]([U+1F600])" in text.replace(" ", ""), text


NAMES = ["carriage_llnl.toml", "x\x1b[31mred\x1b[0m.toml", "<script>alert(1)</script>.toml",
         "**bold** [link](http://x) `tick`.toml", "a\\b_c_.toml", "``double``"]


@pytest.mark.parametrize("name", NAMES)
def test_a_file_name_in_markdown_reads_as_itself(name: str) -> None:
    """CommonMark (markdown-it) renders the escaped heading and code span to the name's own
    text: no tag, no emphasis, no link; no control character reaches the output."""
    md = MarkdownIt("commonmark")
    shown = name.replace("\x1b", "\\x1b")
    heading = md.render(f"# maglevgen build: {shown_name(name, markdown=True)}")
    assert heading == f"<h1>maglevgen build: {html.escape(shown, quote=False)}</h1>\n"
    code = md.render(f"Parameter file: {markdown_code(name)}")
    assert code == f"<p>Parameter file: <code>{html.escape(shown, quote=False)}</code></p>\n"
    assert "\x1b" not in shown_name(name)


def test_an_escape_in_an_out_name_does_not_reach_the_terminal(tmp_path: Path, capsys) -> None:
    folder = tmp_path / "a\x1b[2Jb"
    folder.mkdir()
    (folder / "mine.txt").write_text("x")
    rc = main(["envelope", "--speeds", "3", "--out", str(folder)])
    err = _one_line(capsys, rc, "holds files maglevgen did not write", "a\\x1b[2Jb")
    assert "\x1b" not in err


@pytest.mark.needs_cc
def test_a_full_disk_in_the_cache_compile_is_exit_2(tmp_path: Path, monkeypatch) -> None:
    """gcc on a full disk (a wrapper that writes its message, removes its output and fails,
    as gcc does): one line, exit 2, no FileNotFoundError from the removed temporary."""
    from maglevgen.runtime import compile as cc

    fake = tmp_path / "gcc"
    fake.write_text("#!/bin/sh\nwhile [ $# -gt 0 ]; do [ \"$1\" = -o ] && rm -f \"$2\"; "
                    "shift; done\necho 'ld: final link failed: No space left on device' >&2\n"
                    "exit 1\n")
    fake.chmod(0o755)
    src = tmp_path / "a.c"
    src.write_text("int maglev_a(void) { return 1; }\n")
    with pytest.raises(InputError, match=r"cannot write to the cache folder .*No space left"):
        cc.compile_shared([src], cc=str(fake), cache_dir=tmp_path / "cache")
    assert not list((tmp_path / "cache").glob(".lib*"))  # no temporary left


def test_a_full_disk_anywhere_is_exit_2_with_one_line(monkeypatch, capsys) -> None:
    """An ENOSPC raised where no code expects it (the FMU's cache folder, say)."""
    import maglevgen.cli as cli

    def full(_args):
        raise OSError(errno.ENOSPC, "No space left on device", "/cache/fmu/x.c")

    parser = cli.build_parser()
    monkeypatch.setattr(cli, "build_parser", lambda: parser)
    sub = next(a for a in parser._actions if a.dest == "command")
    sub.choices["trim"].set_defaults(func=full)
    rc = cli.main(["trim"])
    _one_line(capsys, rc, "cannot write to /cache/fmu/x.c: No space left on device")
