"""The example notebook (examples/linearization_envelope.ipynb) runs top to bottom in a
Jupyter kernel (nbclient), at a small resolution, and its numbers are right.

Reference: the closed-loop eigenvalues assembled from the SymPy model's trim and Jacobians
with python-control's gains and numpy's pseudo-inverse allocation
(test_envelope._reference_eigenvalues), none of which the notebook uses (it runs the
compiled C through the Python API).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import nbformat
import numpy as np
import pytest
from nbclient import NotebookClient
from test_envelope import _reference_eigenvalues

from maglevgen.carriage import DerivedCarriage

pytestmark = [pytest.mark.needs_cc, pytest.mark.slow]  # the compiled library; ~15 s (a kernel)
NOTEBOOK = Path(__file__).resolve().parents[1] / "examples" / "linearization_envelope.ipynb"
N_SPEEDS = 4


def test_notebook_runs_and_its_envelope_matches_the_sympy_eigenvalues(
        tmp_path: Path, carriage: DerivedCarriage, sim_lib) -> None:
    nb = nbformat.read(NOTEBOOK, as_version=4)
    assert all(not c.get("outputs") for c in nb.cells if c.cell_type == "code")  # stored clean
    out = tmp_path / "numbers.json"
    env = {"MAGLEVGEN_NOTEBOOK_SPEEDS": str(N_SPEEDS), "MAGLEVGEN_NOTEBOOK_OUT": str(out)}
    old = {k: os.environ.get(k) for k in env}
    os.environ.update(env)  # the kernel inherits this process's environment
    try:
        NotebookClient(nb, timeout=300, kernel_name="python3",
                       resources={"metadata": {"path": str(tmp_path)}}).execute()
    finally:
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    errors = [o for c in nb.cells for o in c.get("outputs", []) if o.output_type == "error"]
    assert not errors, errors
    printed = "".join(o.get("text", "") for c in nb.cells for o in c.get("outputs", [])
                      if o.output_type == "stream")
    assert "states:" in printed and "coupled" in printed and "stable across" in printed
    assert any(o.output_type == "display_data" and "image/png" in o.data
               for c in nb.cells for o in c.get("outputs", []))  # the envelope's plot

    got = json.loads(out.read_text())
    assert len(got["speeds"]) == N_SPEEDS
    for v, *rows in zip(got["speeds"], *(got["max_real"][n] for n in
                                          ("none", "damping", "lqr", "coupled")), strict=True):
        ref = _reference_eigenvalues(carriage, v)
        for name, value in zip(("none", "damping", "lqr", "coupled"), rows, strict=True):
            want = float(np.max(ref[name].real))
            assert value == pytest.approx(want, rel=1e-5, abs=1e-7), (v, name)
    ref = _reference_eigenvalues(carriage, got["speed"])
    for name in ("lqr", "coupled"):
        poles = np.sort_complex(np.array([complex(*p) for p in got["poles"][name]]))
        want = np.sort_complex(ref[name])
        np.testing.assert_allclose(poles, want, rtol=1e-5, atol=1e-6)
