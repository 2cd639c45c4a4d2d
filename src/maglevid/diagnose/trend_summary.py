"""A machine's parameter trends with a drift and step test each: ``maglevid history``'s content.

Used by the ``history`` and ``diagnose --report`` commands and by the demo;
the report draws it with :func:`maglevid.report.trends_from_history`.
"""

from __future__ import annotations

import math
from datetime import datetime, timezone
from typing import Any

__all__ = ["history_summary"]

_DAY = 86400.0


def _iso(t: float) -> str | None:
    """ISO time of ``t`` seconds since 1970; None beyond the calendar (a near-flat trend)."""
    try:
        return datetime.fromtimestamp(t, tz=timezone.utc).isoformat()
    except (OverflowError, ValueError, OSError):
        return None


def _drift(
    trend: Any, rows: Any, tolerance: float | None, alpha: float, drift_method: str
) -> dict:
    """Drift test of the points ``rows`` (a boolean mask) of ``trend``; times in days."""
    import numpy as np

    from maglevid.diagnose.drift import detect_drift
    from maglevid.exceptions import DataError

    t = trend.time[rows]
    y = trend.value[rows]
    se = trend.std_error[rows]
    notes = []
    if se.size and not bool(np.all(se > 0)):  # NaN (unknown) or 0: cannot weight
        notes.append("some points have no standard error: equal weights (OLS)")
        se = None
    base = trend.baseline[rows]
    base = base[~np.isnan(base)]
    baseline = float(base[-1]) if tolerance is not None and base.size else None
    t0 = float(t.min()) if t.size else 0.0
    try:
        r = detect_drift(
            (t - t0) / _DAY,
            y,
            se,
            alpha=alpha,
            tolerance=tolerance,
            baseline=baseline,
            method=drift_method,
        )
    except DataError as exc:
        return {"skipped": str(exc), "drifting": None}
    out = r.to_dict()
    out["notes"] = notes + out["notes"]
    out["time_unit"] = "day"
    out["t_ref"] = _iso(t0 + r.t_ref * _DAY)
    if r.projected_crossing_time is not None:
        out["projected_crossing_at"] = _iso(t0 + r.projected_crossing_time * _DAY)
        if r.crossing_ci is not None:
            out["crossing_ci_at"] = [
                _iso(t0 + c * _DAY) if math.isfinite(c) else None for c in r.crossing_ci
            ]
    return out


def _step(t: Any, y: Any, se: Any, alpha: float) -> Any:
    """The change-point test of :func:`maglevid.diagnose.drift.detect_step` on one method's
    points (times in days), at ``alpha / STEP_SHARE`` as in ``diagnose`` and the fleet: the
    step is a second detector beside the drift test. ``None`` below 3 points. Points
    without a standard error: equal weights, the scale from the scatter."""
    import numpy as np

    from maglevid.diagnose.drift import STEP_SHARE, detect_step
    from maglevid.exceptions import DataError

    if len(y) < 3:
        return None
    if not bool(np.all(np.isfinite(se) & (se > 0))):
        se = None
    try:
        return detect_step(t / _DAY, y, se, alpha=alpha / STEP_SHARE)
    except DataError:  # e.g. non-finite values: no step test, the drift test says why
        return None


def _overview(trend: Any, drift: dict[str, dict], alpha: float) -> dict[str, Any]:
    """Latest value, change from the baseline, step test and the parameter's verdict.

    The step and trend are judged on the latest method's points (methods have
    different biases; mixing them fakes changes).
    """
    import numpy as np

    n = len(trend)
    if n == 0:
        return {"latest": None, "change_percent": None, "step": None, "verdict": "no data"}
    last = n - 1
    method = str(trend.method[last])
    rows = trend.method == method
    se_last = float(trend.std_error[last])
    base = float(trend.baseline[last])
    change = 100.0 * (trend.value[last] - base) / base if np.isfinite(base) and base else None
    t, y, se = trend.time[rows], trend.value[rows], trend.std_error[rows]
    step = _step(t, y, se, alpha)
    d = drift.get(method, {})
    step_dict = None
    verdict = "stable"
    if step is not None and step.is_step:
        step_dict = step.to_dict()
        step_dict["at"] = _iso(float(np.sort(t)[step.index]))
        step_dict["percent"] = 100.0 * step.size / step.before if step.before else None
        verdict = "STEP"
    elif d.get("drifting"):
        verdict = "DRIFTING"
    elif "skipped" in d or not d:
        verdict = "too few points"
    return {
        "latest": {
            "value": float(trend.value[last]),
            "std_error": se_last if math.isfinite(se_last) else None,
            "recorded_at": _iso(float(trend.time[last])),
            "method": method,
        },
        "change_percent": None if change is None else float(change),
        "step": step_dict,
        "verdict": verdict,
    }


def history_summary(
    store: Any,
    machine: str,
    *,
    parameters: list[str] | None = None,
    method: str | None = None,
    alpha: float = 0.01,
    drift_method: str = "wls",
    tolerances: dict[str, float] | None = None,
) -> dict[str, Any]:
    """Trends and drift tests of ``machine``'s parameters (the ``--json`` content)."""
    from maglevid.exceptions import DataError

    tolerances = tolerances or {}
    names = parameters or store.parameters(machine)
    unknown = sorted(set(tolerances) - set(names))
    if unknown:
        raise DataError(f"--tolerance for {unknown}, which are not shown")
    out: dict[str, Any] = {}
    drifting = []
    for name in names:
        trend = store.trend(machine, name, method=method)
        points = [
            {
                "recorded_at": _iso(float(trend.time[i])),
                "value": float(trend.value[i]),
                "std_error": None if math.isnan(trend.std_error[i]) else float(trend.std_error[i]),
                "method": str(trend.method[i]),
                "diagnosis_id": int(trend.diagnosis_id[i]),
            }
            for i in range(len(trend))
        ]
        # One test per method: methods have different biases, mixing them fakes drift.
        drift = {
            str(m): _drift(trend, trend.method == m, tolerances.get(name), alpha, drift_method)
            for m in dict.fromkeys(trend.method.tolist())
        }
        drifting += [f"{name} ({m})" for m, d in drift.items() if d.get("drifting")]
        out[name] = {"unit": trend.unit, "points": points, "drift": drift}
        out[name].update(_overview(trend, drift, alpha))
    n_diag = len({q["diagnosis_id"] for v in out.values() for q in v["points"]})
    return {
        "store": store.location,
        "machine": machine,
        "method": method,
        "alpha": alpha,
        "drift_method": drift_method,
        "n_diagnoses": n_diag,
        "parameters": out,
        "drifting": drifting,
    }
