"""The comparison libraries' -O1 build (maglevgen.runtime.library.COMPARISON_FLAGS) against gcc -O2
of
the same generated C: bitwise the same numbers, and a library cached at either level serves
`simulation_library` without a second compile."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from maglevgen.runtime.compile import DEFAULT_FLAGS, compile_shared
from maglevgen.runtime.ffi import GeneratedLibrary
from maglevgen.runtime.library import (
    build_libraries,
    cached_simulation_library,
    runtime_sources,
    simulation_library,
)


@pytest.mark.slow  # two compiles of the point law's library (-O1 and -O2): about 15 s of CPU
def test_comparison_library_at_o1_has_the_o2_numbers_and_serves_both(carriage, private_cache,
                                                                     tmp_path) -> None:
    point = carriage.with_array_force("point")
    shared = runtime_sources(point.structure)  # the session cache's derivation (no compile)
    root = tmp_path / "cache"  # a cache holding that derivation and nothing compiled
    shutil.copytree(shared, root / "derivation" / shared.name)
    assert cached_simulation_library(point.structure, cache_dir=root) is None
    (o1,) = build_libraries((point.structure,), cache_dir=root)
    lib = cached_simulation_library(point.structure, cache_dir=root)
    assert lib is not None and lib.path == o1
    assert simulation_library(point.structure, cache_dir=root).path == o1  # not compiled again
    # the reference: gcc -O2 (the flags of every other library) on the same C files
    o2 = compile_shared(sorted(shared.glob("*.c")), DEFAULT_FLAGS, cache_dir=tmp_path / "o2")
    assert o2 != o1
    a, b = GeneratedLibrary(o1), GeneratedLibrary(o2)
    p = point.p
    rng = np.random.default_rng(7)
    n_u = a.function("maglev_dynamics").shapes_in[1][0]
    for speed in (8.0, 20.0, 40.0):
        x_a, f_a = a.function("maglev_trim")(speed, p)
        x_b, f_b = b.function("maglev_trim")(speed, p)
        assert np.array_equal(x_a, x_b) and np.array_equal(f_a, f_b)
        for _ in range(5):
            x = x_a.ravel() + rng.normal(0, 1e-3, x_a.size)
            u = np.r_[f_a.ravel(), rng.normal(0, 50.0, n_u - 1)]
            for name in ("maglev_dynamics", "maglev_jacobians", "maglev_gaps"):
                args = (x, p) if name == "maglev_gaps" else (x, u, p)
                out_a, out_b = a.function(name)(*args), b.function(name)(*args)
                assert all(np.array_equal(s, t) for s, t in zip(out_a, out_b, strict=True)), name
