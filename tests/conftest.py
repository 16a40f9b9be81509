"""Shared fixtures: the committed route sets, parsed once per test run."""
from __future__ import annotations

import pytest

from scenarios import set_path
from scenarios.routefile import read_routes


@pytest.fixture(scope="session")
def short_routes():
    return read_routes(set_path("town12_short"))[1]
