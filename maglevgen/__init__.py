"""maglevgen: Inductrack maglev carriage dynamics and control, derived symbolically, as C.

The Python API (maglevgen/api/): ``maglevgen.load(params, overrides)`` returns a
`Carriage` whose methods mirror the commands (trim, gains, linearize, simulate, envelope,
generate, report, fmu). It is imported when first used, so ``import maglevgen`` (and the
command line) stays light.
"""

import os
from typing import Any

from maglevgen.errors import InputError, MaglevError, NoTrimError, VerificationError
from maglevgen.version import __version__

__all__ = [
    "Carriage",
    "EnvelopeResult",
    "Gains",
    "InputError",
    "MaglevError",
    "MonteCarloResult",
    "NoTrimError",
    "RegionResult",
    "ReportResult",
    "SimulationResult",
    "SimulationRuns",
    "TrimResult",
    "VerificationError",
    "__version__",
    "load",
]
_API = frozenset({"Carriage", "EnvelopeResult", "Gains", "MonteCarloResult", "RegionResult",
                  "ReportResult", "SimulationResult", "SimulationRuns", "TrimResult", "load"})


def __getattr__(name: str) -> Any:
    """The API's names, imported from maglevgen.api when first asked for (PEP 562), and the
    registry of controllers, `maglevgen.controllers`."""
    if name in _API:
        from maglevgen import api

        return getattr(api, name)
    if name == "controllers":
        import importlib  # `from maglevgen import controllers` would come back here

        return importlib.import_module("maglevgen.controllers")
    raise AttributeError(f"module 'maglevgen' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *__all__})

# Every matrix the toolchain factors is small (at most 24 x 24: Jacobians, Riccati
# Hamiltonians); there OpenBLAS's threads cost far more than they give, most of all on a busy
# machine (the envelope's 50 speeds: 3.8 s with the default threads, 0.21 s with one). Set
# before numpy is first imported; a value the user set is kept.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

