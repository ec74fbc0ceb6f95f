"""Plant the three faults of issue 23 one at a time and check that a numeric test catches each.

Each fault is a one-line edit of derive/; the file is restored afterwards whatever happens.
Run from the repository root: ``python mutation/planted_faults.py`` (``make planted-faults``).
Exit 0 when every fault makes the named numeric tests fail, 1 otherwise.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# Numeric tests only: not the generated/ byte comparison, not the codegen-vs-SymPy tests.
NUMERIC = ["tests/test_independent.py", "tests/test_model.py", "tests/test_riccati.py",
           "tests/test_gains.py"]

FAULTS = {
    "gravity/propulsion stiffness sign (K_other)": (
        "derive/linearize.py",
        "K_other = -sp.Matrix.vstack(sp.zeros(2, 1), other).jacobian(q)",
        "K_other = sp.Matrix.vstack(sp.zeros(2, 1), other).jacobian(q)"),
    "stable-form branch of the Riccati closed form flipped": (
        "derive/riccati.py",
        "K1 = sp.Piecewise((K1_nonneg, _k >= 0), (K1_neg, True))",
        "K1 = sp.Piecewise((K1_neg, _k >= 0), (K1_nonneg, True))"),
    "drag sign flipped": (
        "derive/inductrack.py",
        "            * wl * resistance / (wl**2 + resistance**2)",
        "            * -wl * resistance / (wl**2 + resistance**2)"),
}


def main() -> int:
    caught = True
    for name, (rel, old, new) in FAULTS.items():
        path = ROOT / rel
        original = path.read_text()
        if original.count(old) != 1:
            print(f"{name}: the line to edit is not (uniquely) in {rel}", file=sys.stderr)
            return 1
        try:
            path.write_text(original.replace(old, new))
            proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                                   "-o", "addopts=", *NUMERIC], cwd=ROOT, capture_output=True,
                                  text=True)
        finally:
            path.write_text(original)
        failed = [ln.split(" - ")[0].removeprefix("FAILED ") for ln in proc.stdout.splitlines()
                  if ln.startswith("FAILED ")]
        summary = proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else proc.stderr
        print(f"## {name}\n{summary}")
        for f in failed:
            print(f"  caught by {f}")
        caught &= proc.returncode == 1 and bool(failed)
    return 0 if caught else 1


if __name__ == "__main__":
    sys.exit(main())
