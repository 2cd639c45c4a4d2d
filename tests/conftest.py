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


@pytest.fixture(scope="session")
def amb_r1_fault():
    """The README's bearing: R1 +20 %, the demo's sensor noise (5 nm, 10 uA), 20 000
    periods, controller and deadbeat observer designed on the nominal bearing."""
    from maglevid.physics.amb import AMBParameters
    from maglevid.simulate import simulate_amb_loop

    nominal = AMBParameters.nominal()
    return simulate_amb_loop(
        nominal.with_fault(R1=1.2),
        nominal=nominal,
        dt=1e-4,
        n_samples=20_000,
        noise_std=(5e-9, 1e-5, 1e-5),
        rng=1,
    )
