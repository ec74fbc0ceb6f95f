"""How far a rebuilt library's numbers moved from another build's (e.g. before a change to
the generated C): the largest relative difference of maglev_dynamics, maglev_jacobians,
maglev_stiffness and maglev_trim over random states about the trim (not a test: both sides
are the program's; the tests check each against its independent references).

    .venv/bin/python bench/experiments/law_values.py OLD.so NEW.so [--law distributed]
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from maglevgen.carriage import DerivedCarriage
from maglevgen.params import load_params
from maglevgen.runtime.ffi import GeneratedLibrary


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    """max |a - b| / max(|b|) per output (entries near zero compared at the output's scale)."""
    scale = max(float(np.max(np.abs(b))), 1e-300)
    return float(np.max(np.abs(a - b))) / scale


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("old")
    ap.add_argument("new")
    ap.add_argument("--law", default="distributed")
    ap.add_argument("--samples", type=int, default=200)
    args = ap.parse_args(argv)
    carriage = DerivedCarriage(load_params()).with_array_force(args.law)
    p = carriage.p
    old, new = GeneratedLibrary(args.old), GeneratedLibrary(args.new)
    worst = dict.fromkeys(("dynamics", "jacobians", "stiffness", "trim"), 0.0)
    rng = np.random.default_rng(1)
    for v in np.linspace(8.0, 45.0, 8):
        a, b = new.function("maglev_trim")(v, p), old.function("maglev_trim")(v, p)
        worst["trim"] = max(worst["trim"], _rel(a[0], b[0]), _rel(a[1], b[1]))
    x_t, f_t = old.function("maglev_trim")(20.0, p)
    for _ in range(args.samples):
        # poses up to 5 mm and 0.1 rad off trim (arguments of sinhc/L on both branches)
        x = x_t.ravel() + np.r_[0, rng.uniform(-5e-3, 5e-3, 2), rng.uniform(-0.1, 0.1, 3),
                                rng.uniform(-1, 1, 3), rng.uniform(-1, 1, 3)]
        u = np.r_[f_t.ravel(), rng.uniform(-200, 200, 10)]
        for name, ins in (("dynamics", (x, u, p)), ("jacobians", (x, u, p)),
                          ("stiffness", (x, u[:1], p))):
            for a, b in zip(new.function(f"maglev_{name}")(*ins),
                            old.function(f"maglev_{name}")(*ins), strict=True):
                worst[name] = max(worst[name], _rel(a, b))
    for k, v in worst.items():
        print(f"{k}: largest relative difference {v:.3g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
