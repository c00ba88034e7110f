"""Shared fixtures: small deterministic scenes and the shared sample data."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

import gigapoint as gp

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
AUTZEN = SHARED_DATA / "autzen_trim.laz"


@pytest.fixture(scope="session")
def demo_small():
    """The demo scene at 200 000 points (20 batches)."""
    return gp.demo(200_000)


@pytest.fixture(scope="session")
def autzen_path():
    if not AUTZEN.exists():
        pytest.skip(f"shared sample {AUTZEN} not present")
    return AUTZEN


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


def pytest_report_header(config):
    import numba

    return f"gigapoint {gp.__version__}, numba {numba.__version__} ({numba.config.NUMBA_NUM_THREADS} threads), GIGAPOINT_REGEN={os.environ.get('GIGAPOINT_REGEN', '0')}"
