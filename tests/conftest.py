"""Shared fixtures: the default carriage, built once per test session."""

from __future__ import annotations

import pytest

from maglevgen.carriage import Carriage
from maglevgen.params import load_params


@pytest.fixture(scope="session")
def carriage() -> Carriage:
    return Carriage(load_params())


@pytest.fixture(scope="session")
def trim(carriage: Carriage):
    return carriage.trim()
