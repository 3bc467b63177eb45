"""Shared test fixtures.

Tests generate their own data. Tests that use the real scenes of
``../shared/data`` (or ``$SEED2GS_DATA``) take the ``shared_data`` fixture,
which marks them ``shared_data`` (``-m shared_data`` selects them all) and
skips them with a reason when the scenes are absent.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


def shared_data_dir() -> Path | None:
    env = os.environ.get("SEED2GS_DATA")
    cand = Path(env) if env else REPO.parent / "shared" / "data"
    return cand if cand.is_dir() else None


def pytest_collection_modifyitems(config, items):
    """Mark every test that uses the real scenes (the ``shared_data`` fixture) ``shared_data``."""
    for item in items:
        if "shared_data" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.shared_data)


@pytest.fixture
def shared_data() -> Path:
    """Directory of the real scenes; skips the test when it is not there."""
    d = shared_data_dir()
    if d is None:
        pytest.skip("real scenes not found: put them in ../shared/data or set SEED2GS_DATA")
    return d


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def dask_client():
    """One embedded 2-worker Dask cluster shared by every batch test (a start costs seconds)."""
    from seed2gs_inverse.batch import batch_client

    with batch_client(None, n_workers=2) as client:
        yield client
