"""Shared fixtures: the real data beside the checkout, and a seeded generator."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

#: ``../shared/data`` beside the repository (CI clones with ../shared beside it).
SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture
def shared_data() -> Path:
    """Path of the real measured records; skips the test with a reason when absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data not found at {SHARED_DATA} (clone with ../shared beside it)")
    return SHARED_DATA


@pytest.fixture
def rng() -> np.random.Generator:
    """A fixed-seed generator: tests never use unseeded randomness."""
    return np.random.default_rng(20261122)
