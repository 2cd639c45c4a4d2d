"""Reports rendered once per session (rendering draws five figures: a few seconds)."""

from __future__ import annotations

from datetime import datetime, timezone

import pytest

from diagnosis_examples import (
    blocked_diagnosis,
    example_controller,
    example_trends,
    faulty_diagnosis,
)
from maglevid.report import write_report

GENERATED = datetime(2026, 3, 14, 10, 0, 0, tzinfo=timezone.utc)


@pytest.fixture(scope="session")
def fault_diagnosis():
    return faulty_diagnosis()


@pytest.fixture(scope="session")
def fault_report(fault_diagnosis, tmp_path_factory):
    """Path of the full report: R1 fault, closed loop, trends."""
    path = tmp_path_factory.mktemp("report") / "fault.html"
    return write_report(
        fault_diagnosis,
        path,
        trends=example_trends(),
        controller=example_controller(),
        generated_at=GENERATED,
    )


@pytest.fixture(scope="session")
def blocked_report(tmp_path_factory):
    """Path of the report of a diagnosis the quality checks stopped."""
    path = tmp_path_factory.mktemp("report") / "blocked.html"
    return write_report(blocked_diagnosis(), path, generated_at=GENERATED)
