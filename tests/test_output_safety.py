"""Nothing of the user's lost (issue 54): ``--out`` writes only into a folder that is new,
empty or one maglevgen wrote before, a symbolic link only under the same rule, and the swap
never removes a file maglevgen did not write; the build folder's verification sees every path.

The command-line cases run the installed command in a child process with a temporary home as
its home and working folder, as a user would type them there; the reference is the disk: the
user's files byte for byte after the run.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from test_build import FAST, tree

from maglevgen.build import STAMP, build_changes
from maglevgen.cli import main
from maglevgen.infrastructure import output

REFUSED = "holds files maglevgen did not write"


def _digests(folder: Path) -> dict[str, str]:
    """Every entry below ``folder`` (links as links): relative name -> content digest."""
    out = {}
    for p in sorted(folder.rglob("*")):
        rel = str(p.relative_to(folder))
        if p.is_symlink():
            out[rel] = "link:" + os.readlink(p)
        elif p.is_file():
            out[rel] = hashlib.sha256(p.read_bytes()).hexdigest()
        else:
            out[rel] = "dir"
    return out


@pytest.fixture
def home(tmp_path: Path) -> Path:
    """A user's home with a thesis and a parameter file in it."""
    h = tmp_path / "home"
    h.mkdir()
    (h / "my_thesis.tex").write_text("\\documentclass{article}\n% three years of work\n")
    (h / "params.toml").write_text((Path(__file__).parents[1] / "maglevgen" /
                                    "carriage_llnl.toml").read_text())
    return h


def _run(home: Path, *argv: str) -> subprocess.CompletedProcess:
    """``maglevgen ARGV`` typed in ``home`` with HOME there (the cache and its key where the
    run's are: only the working folder and the home are the user's)."""
    config = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    env = {**os.environ, "HOME": str(home), "XDG_CONFIG_HOME": config}
    return subprocess.run([sys.executable, "-m", "maglevgen.cli", *argv], cwd=home, env=env,
                          capture_output=True, text=True, timeout=900)


def _assert_refused(done: subprocess.CompletedProcess, folder: Path) -> None:
    assert done.returncode == 2, done.stderr
    assert done.stdout == ""
    lines = done.stderr.splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith("maglevgen: error: ") and REFUSED in lines[0], lines[0]
    assert str(folder.resolve()) in lines[0], lines[0]
    assert "pick another --out or empty it" in lines[0]


def test_simulate_out_dot_keeps_the_users_files(home: Path) -> None:
    before = _digests(home)
    done = _run(home, "simulate", "--out", ".", "--t-end", "0.01")
    _assert_refused(done, home)
    assert _digests(home) == before
    assert sorted(p.name for p in home.parent.iterdir()) == ["home"]  # no temporary left


def test_envelope_out_holding_the_parameter_file_keeps_it(home: Path) -> None:
    folder = home / "study"
    folder.mkdir()
    (home / "params.toml").rename(folder / "params.toml")
    (folder / "notes.txt").write_text("speeds to try\n")
    before = _digests(home)
    done = _run(home, "envelope", "--params", "study/params.toml", "--speeds", "3",
                "--out", "study")
    _assert_refused(done, folder)
    assert _digests(home) == before


def test_build_out_with_a_users_data_file_is_refused(home: Path) -> None:
    proj = home / "proj3"
    proj.mkdir()
    (proj / "data.csv").write_text("t,x\n0,1\n")
    before = _digests(home)
    done = _run(home, "build", "--out", "proj3", *FAST)
    _assert_refused(done, proj)
    assert _digests(home) == before


def test_a_symlinked_out_to_a_users_folder_is_refused(home: Path) -> None:
    users = home / "work"
    users.mkdir()
    (users / "keep.txt").write_text("mine\n")
    (home / "link").symlink_to(users)
    before = _digests(home)
    done = _run(home, "simulate", "--out", "link", "--t-end", "0.01")
    _assert_refused(done, users)
    assert _digests(home) == before


def test_a_symlinked_out_is_followed_under_the_same_rule(tmp_path: Path) -> None:
    """An empty target is written through the link, which stays a link; written again (the
    folder is now maglevgen's), the target is replaced and the link still points to it."""
    target = tmp_path / "target"
    target.mkdir()
    link = tmp_path / "link"
    link.symlink_to(target)
    output.write_output({"a.txt": "one\n"}, link)
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert (target / "a.txt").read_text() == "one\n"
    output.write_output({"b/c.txt": "two\n"}, link)
    assert sorted(str(p.relative_to(target)) for p in target.rglob("*")) == \
        [output.MARKER, "b", "b/c.txt"]
    assert link.is_symlink()


def test_a_folder_maglevgen_wrote_is_replaced_and_a_foreign_one_is_not(tmp_path: Path) -> None:
    out = tmp_path / "out"
    output.write_output({"x.txt": "1\n", "sub/y.txt": "2\n"}, out)
    output.write_output({"z.txt": "3\n"}, out)  # its own earlier output: replaced whole
    assert sorted(str(p.relative_to(out)) for p in out.rglob("*")) == [output.MARKER, "z.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["out"]  # nothing left beside it
    (out / "notes.txt").write_text("mine\n")
    with pytest.raises(output.InputError, match=REFUSED + r" \(notes.txt\)"):
        output.write_output({"z.txt": "4\n"}, out)
    assert (out / "notes.txt").read_text() == "mine\n" and (out / "z.txt").read_text() == "3\n"
    # an empty folder of the user's subfolder is not maglevgen's either
    (out / "notes.txt").unlink()
    (out / "empty").mkdir()
    with pytest.raises(output.InputError, match=r"\(empty/\)"):
        output.write_output({"z.txt": "4\n"}, out)


def test_the_swap_never_removes_a_file_added_after_the_check(tmp_path: Path,
                                                             monkeypatch) -> None:
    """A file added between the last check and the swap (the check switched off to make the
    window): the replaced output is removed name by name and the file is kept beside it."""
    out = tmp_path / "out"
    output.write_output({"x.txt": "1\n"}, out)
    (out / "late.txt").write_text("added during the run\n")
    monkeypatch.setattr(output, "check_owned", lambda _d: None)
    output.write_output({"y.txt": "2\n"}, out)
    kept = [p for p in tmp_path.rglob("late.txt")]
    assert len(kept) == 1 and kept[0].read_text() == "added during the run\n"
    assert not list(tmp_path.rglob("x.txt"))  # what maglevgen wrote is gone
    # a later run's stale cleaning leaves it too
    output.remove_stale_siblings(out.resolve())
    assert [p.read_text() for p in tmp_path.rglob("late.txt")] == ["added during the run\n"]


# ----------------------------------------------------------------- build folder verification

def _restamp(out: Path) -> None:
    """The stamp's key set to what this checkout computes for the suite's build options."""
    from maglevgen.build import BuildOptions, build_key
    from maglevgen.infrastructure.cache import DEFAULT_PARAMS_NAME, params_digest

    text = (Path(__file__).parents[1] / "maglevgen" / DEFAULT_PARAMS_NAME).read_text("utf-8")
    key = build_key(params_digest(text, []), (), BuildOptions(t_end=1.0, pdf=False), None)
    stamp = json.loads((out / STAMP).read_text())
    (out / STAMP).write_text(json.dumps({**stamp, "key": key}, indent=1) + "\n")


def _key(out: Path) -> str:
    return json.loads((out / STAMP).read_text())["key"]


def test_verification_sees_every_path(fresh_build: Path, tmp_path: Path) -> None:
    out = fresh_build
    key = _key(out)
    assert build_changes(out, key) is None
    stamp = (out / STAMP).read_text()
    listed = json.loads(stamp)["files"]

    (out / "c" / "evil.c").write_text("int evil;\n")
    assert build_changes(out, key) == "c/evil.c was added"
    (out / "c" / "evil.c").unlink()
    (out / "c" / "extra").mkdir()
    assert build_changes(out, key) == "c/extra/ was added"
    (out / "c" / "extra").rmdir()

    moved = tmp_path / "maglev.h"
    (out / "c" / "maglev.h").rename(moved)
    assert build_changes(out, key) == "c/maglev.h was removed"
    (out / "c" / "maglev.h").symlink_to(moved)  # the same bytes, through a link
    assert build_changes(out, key) == "c/maglev.h is a symbolic link"
    (out / "c" / "maglev.h").unlink()
    moved.rename(out / "c" / "maglev.h")
    assert build_changes(out, key) is None

    for name, change in [("SUMMARY.md", "dropped"), ("../outside.txt", "outside")]:
        edited = dict(listed)
        if change == "dropped":
            del edited[name]
        else:
            edited[name] = listed["SUMMARY.md"]
        (out / STAMP).write_text(json.dumps({**json.loads(stamp), "files": edited}))
        assert build_changes(out, key) is not None, change
    (out / STAMP).write_text(stamp)
    assert build_changes(out, key) is None


def test_a_file_added_to_a_build_is_refused_not_deleted(fresh_build: Path, capsys) -> None:
    out = fresh_build
    (out / "c" / "evil.c").write_text("int evil;\n")
    before = _digests(out)
    rc = main(["build", "--out", str(out), *FAST])
    _, err = capsys.readouterr()
    assert rc == 2
    line = err.splitlines()[-1]
    assert REFUSED in line and "c/evil.c" in line, err
    assert _digests(out) == before


@pytest.mark.slow  # a whole build of its own
def test_a_file_replaced_by_a_link_is_rebuilt_and_its_target_kept(fresh_build: Path,
                                                                  tmp_path: Path,
                                                                  capsys) -> None:
    out = fresh_build
    _restamp(out)  # the key of this toolchain (a default build made by an earlier checkout)
    ref = tree(out)
    target = tmp_path / "users_header.h"
    target.write_bytes((out / "c" / "maglev.h").read_bytes())
    (out / "c" / "maglev.h").unlink()
    (out / "c" / "maglev.h").symlink_to(target)
    assert main(["build", "--out", str(out), *FAST]) == 0
    err = capsys.readouterr().err
    assert f"rebuilding {out.resolve()}: c/maglev.h is a symbolic link" in err, err
    assert not (out / "c" / "maglev.h").is_symlink()
    assert tree(out) == ref
    assert target.read_bytes() == (out / "c" / "maglev.h").read_bytes()
