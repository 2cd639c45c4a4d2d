"""Shared fixtures: the real data beside the checkout, and a seeded generator.

In CI (``CI=true``) the real parts cannot be skipped: a test that needs the
PostgreSQL server (marker ``postgres``), Chromium (marker ``browser``) or the
real data (fixture ``shared_data``) and skips is reported as a failure naming
what is missing (:func:`pytest_runtest_makereport`).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

#: ``../shared/data`` beside the repository (CI clones with ../shared beside it).
SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"

#: What CI must provide, by the marker or fixture a test uses to ask for it.
REQUIRED_IN_CI = {
    "postgres": "a PostgreSQL server (source .ci/postgres.sh)",
    "browser": "Chromium (scripts/install-browser.sh)",
    "shared_data": f"the real data at {SHARED_DATA} (clone with ../shared beside it)",
}


def in_ci() -> bool:
    """True when the environment says this is a CI run (``CI=true``, as CI services set it)."""
    return os.environ.get("CI", "").strip().lower() == "true"


def required_resources(item: pytest.Item) -> list[str]:
    """The CI-required resources ``item`` asks for (markers and fixtures)."""
    names = [m.name for m in item.iter_markers()] + list(getattr(item, "fixturenames", ()))
    return [what for key, what in REQUIRED_IN_CI.items() if key in names]


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]):  # type: ignore[no-untyped-def]
    outcome = yield
    report = outcome.get_result()
    if not (report.skipped and in_ci() and not hasattr(report, "wasxfail")):
        return
    needed = required_resources(item)
    if not needed:
        return
    reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr)
    report.outcome = "failed"
    report.longrepr = (
        f"CI=true requires {' and '.join(needed)}, but the test skipped: {reason}. "
        "CI must not pass without its real parts."
    )


@pytest.fixture
def shared_data() -> Path:
    """Path of the real measured records; skips the test with a reason when absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data not found at {SHARED_DATA} (clone with ../shared beside it)")
    return SHARED_DATA


@pytest.fixture
def no_hang():
    """Fail (instead of hanging the run) if the test blocks for 60 s, e.g. on a FIFO."""
    import signal

    def hung(signum, frame):  # type: ignore[no-untyped-def]
        raise TimeoutError("blocked for 60 s (a read that never returns?)")

    old = signal.signal(signal.SIGALRM, hung)
    signal.alarm(60)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


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
