"""The tool markers' hook (conftest.py): a loud skip with the install command, a failure in CI."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

PROBE = '''
import pytest

@pytest.mark.needs_arm
def test_arm():
    pass

@pytest.mark.needs_cc("no-such-tool-xyz")
def test_cc_extra():
    pass

def test_plain():
    pass
'''


def _run(tmp_path: Path, ci: str | None) -> subprocess.CompletedProcess[str]:
    shutil.copy(Path(__file__).with_name("conftest.py"), tmp_path / "conftest.py")
    (tmp_path / "test_probe.py").write_text(PROBE)
    env = {k: v for k, v in os.environ.items() if k != "CI"}
    env["PATH"] = str(tmp_path)  # no tool at all on PATH (the interpreter is called by path)
    if ci is not None:
        env["CI"] = ci
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "-rs", "-p", "no:cacheprovider",
                           "-o", "markers=needs_arm\nneeds_cc\nneeds_tex", "test_probe.py"],
                          cwd=tmp_path, env=env, capture_output=True, text=True)


def test_missing_tool_skips_loudly_with_the_install_command(tmp_path: Path) -> None:
    proc = _run(tmp_path, None)
    assert proc.returncode == 0, proc.stdout
    assert "1 passed, 2 skipped" in proc.stdout
    assert "TOOL MISSING, CHECK NOT RUN: needs_arm: arm-none-eabi-gcc not installed; " \
           "install: apt-get install -y gcc-arm-none-eabi" in proc.stdout
    assert "no-such-tool-xyz" in proc.stdout
    assert "2 tests NOT RUN for a missing tool" in proc.stdout


@pytest.mark.parametrize("ci", ["true", "1"])
def test_missing_tool_fails_under_ci(tmp_path: Path, ci: str) -> None:
    proc = _run(tmp_path, ci)
    assert proc.returncode == 1, proc.stdout
    assert "1 passed, 2 errors" in proc.stdout  # failed in setup, before the test body
    assert "CI is set: CI installs every tool" in proc.stdout
