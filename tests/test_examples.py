"""Every script in examples/ runs on the default carriage and writes what it says it writes.

Each runs in its own process (as a user runs it) into a temporary folder; the derivation and
compile cache is the session's (conftest.private_cache, inherited through the environment).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.needs_cc  # the examples run the compiled library
EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
PNG = b"\x89PNG\r\n\x1a\n"
# what each example must leave in its output folder
OUTPUTS = {
    "regenerate_c.py": ("default/maglev.h", "heavier/maglev.h", "heavier/manifest.json"),
    "linearization.py": ("bode_heave.png", "step_heave.png"),
    "lqr_across_speed.py": ("lqr_across_speed.csv", "lqr_across_speed.png"),
    "montecarlo_study.py": ("lqr/montecarlo.md", "coupled/montecarlo.json",
                            "coupled/histograms.png"),
    "fmu_fmpy.py": ("maglev.fmu", "fmu_heave.png"),
}


def test_every_example_is_run() -> None:
    assert sorted(p.name for p in EXAMPLES.glob("*.py")) == sorted(OUTPUTS)


@pytest.mark.parametrize("name", sorted(OUTPUTS))
def test_example_runs(name: str, tmp_path: Path) -> None:
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, str(EXAMPLES / name), str(out)], cwd=tmp_path,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    # stderr: nothing but the one-time progress of a fresh cache (the test's private one)
    noise = [ln for ln in proc.stderr.splitlines()
             if not (ln.startswith("maglevgen: ") and "error" not in ln and "warning" not in ln)]
    assert proc.stdout.strip() and not noise, proc.stderr
    for rel in OUTPUTS[name]:
        data = (out / rel).read_bytes()
        assert data, rel
        if rel.endswith(".png"):
            assert data.startswith(PNG), rel
    if name == "lqr_across_speed.py":  # a row per speed, the coupled LQR stable at each
        table = np.loadtxt(out / "lqr_across_speed.csv", delimiter=",", skiprows=1)
        assert table.shape == (12, 7) and np.all(table[:, 4] < 0)
    if name == "regenerate_c.py":  # the mass change reached the baked C
        assert "maglev.h" in proc.stdout.split("changed by")[1].splitlines()[0]
