"""A second, independent checker of the FMUs: fmu_manipulation_toolbox's compliance checks
(`fmutool -check`: modelDescription.xml against the FMI standard's XSD schema of its version,
and the rules the schema cannot express: unique names and value references, causality and
variability, initial and start, the model structure), beside FMPy's `validate_fmu`, on FMI 2.0
and 3.0, model exchange and co-simulation.

A tampered FMU (two variables under one name) must fail the same checker, so that a pass
means something.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from fmpy.validation import validate_fmu

from maglevgen.carriage import DerivedCarriage
from maglevgen.control.built_loop import Loop
from maglevgen.control.carriage_plant import Plant
from maglevgen.exports.fmu import build_fmu

# the test extra installs it (pyproject.toml) beside this interpreter
FMUTOOL = str(Path(sys.executable).with_name("fmutool")) if Path(sys.executable).with_name(
    "fmutool").exists() else shutil.which("fmutool") or "fmutool"


def _check(path: Path) -> tuple[int, str]:
    proc = subprocess.run([FMUTOOL, "-input", str(path.resolve()), "-check"],
                          capture_output=True, text=True, timeout=300)
    return proc.returncode, proc.stdout + proc.stderr


@pytest.mark.parametrize("fmi", ["2", "3"])
@pytest.mark.parametrize(("kind", "loop"), [("me", "continuous"), ("cs", "continuous"),
                                            ("both", "firmware")])
def test_the_toolbox_checker_and_fmpy_accept_the_fmu(tmp_path: Path, carriage: DerivedCarriage,
                                                     sim_lib, fmi: str, kind: str,
                                                     loop: str) -> None:
    """Each kind; the firmware loop's FMU (the CLI's default) with the lagged array forces as
    continuous states besides the carriage's."""
    path = tmp_path / "maglev.fmu"
    path.write_bytes(build_fmu(Plant(carriage), kind, fmi=fmi, loop=Loop(loop)))
    code, log = _check(path)
    assert code == 0, log
    assert f"compliant with FMI-{fmi}.0" in log, log
    assert f"No semantic error against the FMI-{fmi} standard" in log, log
    assert not re.search(r"^(ERROR|CRITICAL)", log, re.M), log
    assert validate_fmu(str(path)) == []


def test_the_toolbox_checker_rejects_a_duplicate_variable_name(tmp_path: Path,
                                                               carriage: DerivedCarriage,
                                                               sim_lib) -> None:
    good = tmp_path / "good.fmu"
    good.write_bytes(build_fmu(Plant(carriage), "cs", fmi="2"))
    bad = tmp_path / "bad.fmu"
    with zipfile.ZipFile(good) as src, zipfile.ZipFile(bad, "w") as dst:
        for item in src.infolist():
            data = src.read(item.filename)
            if item.filename == "modelDescription.xml":
                names = re.findall(rb'<ScalarVariable name="([^"]+)"', data)
                data = data.replace(b'name="%s"' % names[1], b'name="%s"' % names[0], 1)
            dst.writestr(item, data)
    code, log = _check(bad)
    assert code != 0 or re.search(r"^(ERROR|CRITICAL)", log, re.M), log
