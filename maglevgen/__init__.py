"""maglevgen: Inductrack maglev carriage dynamics and control, derived symbolically, as C."""

import os

__version__ = "0.1.0"

# Every matrix the toolchain factors is small (at most 24 x 24: Jacobians, Riccati
# Hamiltonians); there OpenBLAS's threads cost far more than they give, most of all on a busy
# machine (the envelope's 50 speeds: 3.8 s with the default threads, 0.21 s with one). Set
# before numpy is first imported; a value the user set is kept.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

