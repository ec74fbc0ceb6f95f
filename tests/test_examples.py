"""Every script in examples/ runs on the default carriage and writes what it says it writes,
and what it prints and draws is what the documentation site shows under it.

Each runs in its own process, as a user runs it (``python examples/<name>``, no argument, its
default ``example_output/`` in a temporary folder); the derivation and compile cache is the
session's (conftest.private_cache, inherited through the environment). The site's copy of its
outputs (docs/_examples/, stored by ``make example-outputs``) is a snapshot of a run, not a
reference for the numbers: its check is that the page is current (this run's stdout equal
to the stored one but for the last digits of its numbers, `RTOL`; its pixels equal), while
the examples' numbers are checked against independent references by the tests of the API
they call.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "docs" / "_ext"))
import example_outputs
from numbers_in_text import differences

pytestmark = pytest.mark.needs_cc  # the examples run the compiled library
EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
PNG = b"\x89PNG\r\n\x1a\n"
# what each example must leave in its default output folder (example_output/...)
OUTPUTS = {
    "regenerate_c.py": ("regenerate_c/default/maglev.h", "regenerate_c/heavier/maglev.h",
                        "regenerate_c/heavier/manifest.json"),
    "linearization.py": ("linearization/bode_heave.png", "linearization/step_heave.png"),
    "lqr_across_speed.py": ("lqr_across_speed/lqr_across_speed.csv",
                            "lqr_across_speed/lqr_across_speed.png"),
    "montecarlo_study.py": ("montecarlo/lqr/montecarlo.md", "montecarlo/coupled/montecarlo.json",
                            "montecarlo/coupled/histograms.png"),
    "fmu_fmpy.py": ("fmu_fmpy/maglev.fmu", "fmu_fmpy/fmu_heave.png"),
}


def test_every_example_is_run() -> None:
    assert sorted(p.name for p in EXAMPLES.glob("*.py")) == sorted(OUTPUTS)


# LAPACK builds differ in the last digits of a Riccati solution: the page is current when its
# numbers agree to RTOL (tests/numbers_in_text.py)
RTOL = 1e-6


def test_output_comparison_tolerates_last_digits_only() -> None:
    stored = "K = [2.96471528e-05 1.00027568e+00]\npoles: -4.543-10.217j\n"
    assert differences(stored.replace("528e-05", "527e-05"), stored, RTOL) == []
    assert differences(stored.replace("2.964", "2.965"), stored, RTOL)
    assert differences(stored.replace("poles", "zeros"), stored, RTOL)
    assert differences(stored + "1.0\n", stored, RTOL)


@pytest.mark.parametrize("name", sorted(OUTPUTS))
def test_example_runs(name: str, tmp_path: Path) -> None:
    from matplotlib.testing.compare import compare_images

    proc = example_outputs.run(EXAMPLES / name, tmp_path, timeout=600)
    out = tmp_path / example_outputs.DEFAULT_OUT
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
        table = np.loadtxt(out / "lqr_across_speed/lqr_across_speed.csv", delimiter=",",
                           skiprows=1)
        assert table.shape == (12, 7) and np.all(table[:, 4] < 0)
    if name == "regenerate_c.py":  # the mass change reached the baked C
        assert "maglev.h" in proc.stdout.split("changed by")[1].splitlines()[0]
    # the site shows this run: the same stdout, the same figures pixel for pixel
    # (matplotlib's compare_images: RMS over the pixels; PNG metadata does not count)
    text, figures = example_outputs.stored(EXAMPLES / name)
    changed = differences(proc.stdout, text, RTOL)
    assert not changed, (f"{name}'s output is not what docs/_examples shows (make "
                         f"example-outputs): {changed[:5]}\n{proc.stdout}")
    assert sorted(proc.figures) == sorted(figures), (sorted(proc.figures), sorted(figures))
    for rel, png in figures.items():
        diff = compare_images(str(png), str(proc.figures[rel]), tol=0, in_decorator=True)
        assert diff is None, (f"{rel} differs from the site's copy (make example-outputs): "
                              f"{diff}")
