"""`pip install .` (not editable): the wheel holds every file the package needs, and the
command installed from it into a fresh virtual environment outside the checkout works.

References: the checkout's own file list (``git ls-files`` of the installed folders, mapped
as pyproject.toml's package-dir maps them) for the wheel's contents, and the equilibrium
found by scipy's root on eq 3 and the static balance (tests/independent_reference.py) for
the installed command's `trim --json`.
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import venv
import zipfile
from pathlib import Path

import numpy as np
import pytest
from independent_reference import reference_trim

from maglevgen.carriage import DerivedCarriage

REPO = Path(__file__).resolve().parents[1]
# the checkout's folders and where pyproject.toml's package-dir installs them
INSTALLED = {"maglevgen": "maglevgen", "derive": "maglevgen/derive",
             "runtime": "maglevgen/runtime", "templates": "maglevgen/templates"}
pytestmark = pytest.mark.needs_cc  # the installed command compiles the generated C


def _tracked() -> list[str]:
    """The package's files in the checkout (git's list; a copy without .git: the folders)."""
    if shutil.which("git") and (REPO / ".git").exists():
        out = subprocess.run(["git", "ls-files", *INSTALLED], cwd=REPO, capture_output=True,
                             text=True, check=True).stdout.split()
        if out:
            return out
    return [p.relative_to(REPO).as_posix() for d in INSTALLED for p in (REPO / d).rglob("*")
            if p.is_file() and "__pycache__" not in p.parts]


def _source_copy(dest: Path) -> Path:
    """The checkout's tracked files copied to ``dest`` (without git: the tree less what a
    build or a run leaves): setuptools builds in the source tree, and its build/ folder in
    the checkout would stand where `maglevgen build` writes by default."""
    if shutil.which("git") and (REPO / ".git").exists():
        files = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True,
                               text=True, check=True).stdout.split("\0")
        for name in filter(None, files):
            if (REPO / name).is_file():
                (dest / name).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(REPO / name, dest / name)
        return dest
    shutil.copytree(REPO, dest, dirs_exist_ok=True, ignore=shutil.ignore_patterns(
        ".git", ".venv", "build", "*.egg-info", "__pycache__", "_build", ".pytest_cache"))
    return dest


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> tuple[Path, str]:
    """The wheel `pip wheel .` builds from a copy of the checkout (`_source_copy`), offline:
    the build backend already installed is used where it is (no download of setuptools),
    else pip's isolated build. The checkout gains no build/ folder."""
    out = tmp_path_factory.mktemp("wheel")
    src = _source_copy(tmp_path_factory.mktemp("source"))
    had_build = (REPO / "build").exists()
    offline = all(importlib.util.find_spec(m) for m in ("setuptools", "wheel"))
    # -v: pip passes the build backend's own output on (its deprecation banners among it)
    cmd = [sys.executable, "-m", "pip", "wheel", "-v", "--no-deps", "-w", str(out), str(src)]
    proc = subprocess.run(cmd + (["--no-build-isolation"] if offline else []),
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert had_build or not (REPO / "build").exists()
    (whl,) = out.glob("maglevgen-*.whl")
    return whl, proc.stdout + proc.stderr


def test_wheel_holds_every_file_of_the_package(wheel) -> None:
    whl, log = wheel
    assert "is absent from the `packages` configuration" not in log, log[-3000:]
    with zipfile.ZipFile(whl) as zf:
        names = set(zf.namelist())
    want = set()
    for path in _tracked():
        top, _, rest = path.partition("/")
        want.add(f"{INSTALLED[top]}/{rest}")
    missing = sorted(want - names)
    assert not missing, missing
    assert "maglevgen/templates/report/trim.tex.j2" in names  # the report's templates
    assert not any(n.startswith(("tests/", "docs/", "generated/", "bench/")) for n in names)


def test_wheel_builds_without_a_deprecation_warning(wheel) -> None:
    """setuptools warns of what it will stop accepting (a `project.license` table: "By
    2027-Feb-18 ... your builds will no longer be supported"); the build prints none of it,
    and the wheel's metadata carries the licence as an SPDX expression (PEP 639)."""
    whl, log = wheel
    flagged = [line for line in log.splitlines()
               if re.search(r"deprecat|BuildBackendWarning|no longer be supported", line, re.I)]
    assert not flagged, "\n".join(flagged)
    with zipfile.ZipFile(whl) as zf:
        (meta,) = [n for n in zf.namelist() if n.endswith(".dist-info/METADATA")]
        headers = zf.read(meta).decode().split("\n\n", 1)[0].splitlines()
    assert "License-Expression: MIT" in headers, headers


def test_installed_command_runs_outside_the_checkout(wheel, tmp_path: Path,
                                                     carriage: DerivedCarriage) -> None:
    """A fresh venv (its dependencies those of this environment, through a .pth file: no
    download) with the wheel installed by pip; `maglevgen trim --json` run from another
    folder imports the installed copy and finds the trim."""
    whl, _ = wheel
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=False).create(env_dir)
    py = env_dir / "bin" / "python"
    site = subprocess.run([str(py), "-c", "import sysconfig; print(sysconfig.get_paths()"
                           "['purelib'])"], capture_output=True, text=True,
                          check=True).stdout.strip()
    deps = dict.fromkeys(sysconfig.get_paths()[k] for k in ("purelib", "platlib"))
    # plain path lines: the .pth files there (this checkout's editable install) stay unread
    (Path(site) / "_maglevgen_test_deps.pth").write_text("\n".join(deps) + "\n")
    proc = subprocess.run([sys.executable, "-m", "pip", "--python", str(py), "install",
                           "--no-deps", "--no-index", str(whl)], capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    where = subprocess.run([str(py), "-c", "import maglevgen.templates as t; print(t.__file__)"],
                           cwd=elsewhere, env=env, capture_output=True, text=True, check=True)
    assert Path(where.stdout.strip()).is_relative_to(env_dir), where.stdout
    run = subprocess.run([str(env_dir / "bin" / "maglevgen"), "trim", "--json"], cwd=elsewhere,
                         env=env, capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stderr[-3000:]
    got = json.loads(run.stdout)
    ref = reference_trim(carriage.params, got["speed"])
    q = [got["state"][s] for s in ("y", "z", "phi", "theta", "psi")]
    np.testing.assert_allclose(q, ref.q, rtol=0, atol=1e-10)
    assert got["propulsion_force"] == pytest.approx(ref.f_prop, rel=1e-9)
    lift = [got["arrays"][a]["lift"] for a in carriage.params.arrays]
    np.testing.assert_allclose(lift, ref.arrays.lift, rtol=1e-9)
    assert list(elsewhere.iterdir()) == []  # nothing written where it ran
