"""Regenerate the carriage's C after a parameter change, and see what the change moved.

    python examples/regenerate_c.py [OUT]

Writes OUT/default/ and OUT/heavier/ (``maglevgen generate`` for the LLNL carriage and for
one 2 kg heavier), then prints which generated files differ and how the trim moved.
"""

from __future__ import annotations

import sys
from pathlib import Path

import maglevgen

out = Path(sys.argv[1] if len(sys.argv) > 1 else "example_output/regenerate_c")

default = maglevgen.load()
mass = default.params.vehicle.mass + 2.0
heavier = maglevgen.load(overrides=[f"vehicle.mass={mass}"])

# baked: the parameter values are folded into the C, so the mass change shows in the source
written = {name: c.generate(out / name, precision="double", parameters="baked")
           for name, c in (("default", default), ("heavier", heavier))}
changed = [p.name for p in written["default"]
           if p.read_bytes() != (out / "heavier" / p.name).read_bytes()]
print(f"wrote {len(written['heavier'])} files to {out / 'heavier'}; "
      f"changed by vehicle.mass={mass:g}: {', '.join(changed)}")

for name, c in (("default", default), ("heavier", heavier)):
    trim = c.trim()
    print(f"{name:>8}: trim at {trim.speed:g} m/s, heave z = {trim.x[2] * 1e3:+.3f} mm, "
          f"smallest gap {trim.gaps.min() * 1e3:.3f} mm, F_prop = {trim.propulsion_force:.3f} N")
