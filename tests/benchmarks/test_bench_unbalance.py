"""The unbalance section's verdicts (benchmarks/bench_unbalance.py) on results of the shape
its workers produce; no benchmark is run. Reference: the section's stated targets (the
calibration bands of benchmarks/judge.py, a line found where there is one, at 0.01 Hz)."""

from __future__ import annotations

import numpy as np
from benchmarks.bench_unbalance import CASES, _summary, markdown_section, targets
from benchmarks.judge import MET, NOT_MEASURED, NOT_MET, Judge, calibration_bands


def _rows(case: str, n: int, *, z: float, line: float | None) -> list[dict]:
    rng = np.random.default_rng(0)
    return [
        {"case": case, "seed": k, "time_s": 1.0, "z": (z * rng.standard_normal(9)).tolist(),
         "lines_hz": [] if line is None else [line, 2 * line]}
        for k in range(n)
    ]  # fmt: skip


def _result(n: int = 40, **override) -> dict:
    rows = []
    for case, (unbalance, *_) in CASES.items():
        z, line = override.get(case, (1.0, None if unbalance is None else unbalance[1]))
        rows += _rows(case, n, z=z, line=line)
    return {"records": n, "summary": {c: _summary(rows, c) for c in CASES}}


def test_calibrated_fits_meet_every_judged_target():
    judge = Judge()
    targets(_result(), judge)
    judged = sum(1 for c in CASES.values() if c[3])
    assert len(judge.verdicts) == 2 * judged  # the unjudged cases are reported only
    assert all(v.status == MET for v in judge.verdicts)


def test_biased_intervals_a_missed_line_and_a_failure_are_not_met():
    res = _result(**{"1 N at 50 Hz": (5.0, 50.0), "1 N at 37.3 Hz": (1.0, 37.4)})
    res["summary"]["R1 x1.1, 1 N at 50 Hz"] = {"records": 40, "failed": 40, "errors": ["x"]}
    judge = Judge()
    targets(res, judge)
    status = {v.target: v.status for v in judge.verdicts}

    def of(text: str) -> str:
        return next(s for t, s in status.items() if text in t)

    assert of("unbalance, 1 N at 50 Hz: ml's") == NOT_MET
    assert of("37.3 Hz: the line") == NOT_MET
    assert of("R1 x1.1, 1 N at 50 Hz: every record") == NOT_MEASURED
    assert "| 3 N at 50 Hz |" in "\n".join(markdown_section(res))


def test_calibration_bands_hold_a_calibrated_estimator():
    (lo, hi), (c_lo, c_hi) = calibration_bands(12)
    assert lo < 1.0 < hi and c_lo < 0.95 <= c_hi
