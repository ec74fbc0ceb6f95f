"""Shared fixtures: the default carriage, built once per test session.

The derivation/compile cache goes to a per-session temporary folder, so the suite neither
reads nor writes the user's cache and always exercises a cold build first.
"""

from __future__ import annotations

import os
import tempfile

import pytest

from maglevgen.carriage import Carriage
from maglevgen.params import load_params


@pytest.fixture(scope="session")
def carriage() -> Carriage:
    return Carriage(load_params())


@pytest.fixture(scope="session")
def trim(carriage: Carriage):
    return carriage.trim()


@pytest.fixture(scope="session", autouse=True)
def private_cache():
    """MAGLEVGEN_CACHE for the whole session (also seen by CLI subprocesses)."""
    old = os.environ.get("MAGLEVGEN_CACHE")
    with tempfile.TemporaryDirectory(prefix="maglevgen-cache-") as d:
        os.environ["MAGLEVGEN_CACHE"] = d
        yield d
    if old is None:
        os.environ.pop("MAGLEVGEN_CACHE", None)
    else:
        os.environ["MAGLEVGEN_CACHE"] = old


@pytest.fixture(scope="session")
def sim_lib(carriage: Carriage, private_cache):
    """The compiled run-time-parameter simulation library of the default carriage."""
    from maglevgen.library import simulation_library

    return simulation_library(carriage.structure)


@pytest.fixture(scope="session")
def op(sim_lib, carriage: Carriage):
    """Trim and gains at the default speed, from the generated C."""
    from maglevgen.simulate import Weights, operating_point

    return operating_point(sim_lib, carriage.p, carriage.params.operation.speed,
                           carriage.params.track.min_gap, Weights.of(carriage.params))
