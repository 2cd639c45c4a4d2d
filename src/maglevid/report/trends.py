"""The report's ``trends`` input from the history store's output.

:func:`~maglevid.report.html.render_report` takes trends as plain data,
``{name: {"time": [...], "value": [...], "std_error": [...], "drift": {...}}}``.
``maglevid history MACHINE --json`` (:mod:`maglevid.cli.history`) gives, per
parameter, a list of points and one drift test per identification method.
:func:`trends_from_history` turns the second into the first, keeping one method
per parameter: estimates of different methods have different biases, and the
history command tests each method separately for the same reason.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Mapping, Sequence
from typing import Any

from maglevid.exceptions import DataError

__all__ = ["trends_from_history"]


def trends_from_history(
    history: Mapping[str, Any],
    *,
    method: str | None = None,
    parameters: Sequence[str] | None = None,
) -> dict[str, dict[str, Any]]:
    """Trends for the report from ``maglevid history --json`` output.

    Parameters
    ----------
    history : mapping
        The result of ``maglevid history MACHINE --json``:
        ``{"parameters": {name: {"unit": ..., "points": [{"recorded_at", "value",
        "std_error", "method", ...}], "drift": {method: {...}}}}}``.
    method : str, optional
        Identification method whose points to show (e.g. the diagnosis'
        ``method``). Default: per parameter, the method with the most points.
    parameters : sequence of str, optional
        Which parameters, in this order (default: all, in the history's order).

    Returns
    -------
    dict
        ``{name: {"time", "value", "std_error", "drift", "unit", "method"}}`` (and
        ``"step"`` when the history judged a step rather than a trend), plus
        ``"baseline"`` and the relative ``"tolerance"`` when the drift test had a
        band (the history's band half-width is absolute, the report's relative);
        a parameter without points of ``method`` is left out. A drift test the
        history skipped (too few points) is dropped, not shown as "no drift".

    Raises
    ------
    DataError
        If ``history`` has no ``"parameters"`` mapping or a requested parameter
        is missing.
    """
    params = history.get("parameters") if isinstance(history, Mapping) else None
    if not isinstance(params, Mapping):
        raise DataError(
            "`history` must be the output of `maglevid history MACHINE --json` "
            "(a mapping with 'parameters')"
        )
    names = list(parameters) if parameters is not None else list(params)
    missing = [n for n in names if n not in params]
    if missing:
        raise DataError(f"parameters {missing} are not in the history; it has {list(params)}")
    out: dict[str, dict[str, Any]] = {}
    for name in names:
        entry = params[name]
        points = list(entry.get("points", ()))
        if not points:
            continue
        chosen = method
        if chosen is None:
            chosen = Counter(str(p.get("method")) for p in points).most_common(1)[0][0]
        pts = [p for p in points if str(p.get("method")) == chosen]
        if not pts:
            continue
        drift = dict((entry.get("drift") or {}).get(chosen) or {})
        if "skipped" in drift:
            drift = {}
        band: dict[str, float] = {}
        base, tol = drift.get("baseline"), drift.get("tolerance")
        if isinstance(base, (int, float)) and base != 0 and math.isfinite(base):
            band["baseline"] = float(base)
            if isinstance(tol, (int, float)) and math.isfinite(tol):
                band["tolerance"] = abs(float(tol) / base)  # the history's band is absolute
        out[name] = {
            **band,
            "time": [str(p["recorded_at"]) for p in pts],
            "value": [float(p["value"]) for p in pts],
            "std_error": [
                math.nan if p.get("std_error") is None else float(p["std_error"]) for p in pts
            ],
            "drift": drift,
            "unit": entry.get("unit"),
            "method": chosen,
        }
        step = entry.get("step")
        if step and (entry.get("latest") or {}).get("method") == chosen:
            out[name]["step"] = dict(step)  # the history judged a step, not a trend
    return out
