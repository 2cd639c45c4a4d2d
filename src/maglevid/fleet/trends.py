"""A machine's parameter trends from the history store, as the report draws them.

Shared by the fleet summary (:mod:`maglevid.fleet.summary`, drift tests) and the
workers (:mod:`maglevid.fleet.worker`, a machine's report); it imports neither,
so the fleet modules have no import cycle.
"""

from __future__ import annotations

import logging
from datetime import datetime, timezone
from typing import Any

import numpy as np

from maglevid.exceptions import MaglevidError

__all__ = ["MIN_DRIFT_POINTS", "diagnosed_parameters", "iso_time", "report_trends"]

logger = logging.getLogger(__name__)

#: Fewest usable points (finite value, standard error > 0) for a drift test
#: (the pipeline's own threshold: with 3 points the t-test has 1 degree of freedom).
MIN_DRIFT_POINTS = 4


def iso_time(t: float) -> str:
    """Seconds since 1970 UTC as ISO 8601 text (to the second)."""
    return datetime.fromtimestamp(t, tz=timezone.utc).isoformat(timespec="seconds")


def diagnosed_parameters() -> tuple[str, ...]:
    """The parameters a diagnosis follows (the pipeline's list)."""
    from maglevid.diagnose.pipeline import DIAGNOSED_PARAMETERS

    return DIAGNOSED_PARAMETERS


def report_trends(store: Any, machine: str, *, method: str | None) -> dict[str, dict[str, Any]]:
    """Parameter histories of ``machine`` in the form :func:`~maglevid.report.render_report` takes.

    Only the diagnosed parameters of ``method``; each with its drift test (times
    in seconds since 1970 UTC, as the report's trend plot expects) when it has
    enough points.
    """
    from maglevid.diagnose.drift import detect_drift

    out: dict[str, dict[str, Any]] = {}
    for name in diagnosed_parameters():
        try:
            tr = store.trend(machine, name, method=method)
        except MaglevidError:
            continue
        entry: dict[str, Any] = {
            "time": [iso_time(float(x)) for x in tr.time],
            "value": tr.value.tolist(),
            "std_error": tr.std_error.tolist(),
            "unit": tr.unit,
        }
        ok = np.isfinite(tr.value) & np.isfinite(tr.std_error) & (tr.std_error > 0)
        if ok.sum() >= MIN_DRIFT_POINTS and np.ptp(tr.time[ok]) > 0:
            try:
                entry["drift"] = detect_drift(
                    tr.time[ok], tr.value[ok], tr.std_error[ok]
                ).to_dict()
            except MaglevidError as exc:
                # Said, not dropped: the report's drift column shows why there is no test.
                logger.warning("%s: drift test of %s failed: %s", machine, name, exc)
                entry["drift"] = {"verdict": f"drift test failed: {exc}", "error": str(exc)}
        base = tr.baseline[np.isfinite(tr.baseline)]
        if base.size and base[-1] != 0:
            entry["baseline"] = float(base[-1])
        out[name] = entry
    return out
