"""bench_pbsid's verdicts on PARSIM-K above the N it runs at (issue 16).

Reference values: PARSIM_K_MEASURED, SIPPY PARSIM-K's time and peak resident
memory measured by ``python -m benchmarks.bench_pbsid --parsim-k-scaling`` and
stored with the script. No benchmark and no peer is run here.
"""

from __future__ import annotations

import numpy as np
from benchmarks.bench_pbsid import (
    PARSIM_K_MEASURED,
    PEER_MAX_N,
    PEER_MEMORY_GB,
    TRANSFORM,
    _time_checks,
    markdown_section,
    parsim_k_projection,
    parsim_k_verdict,
)
from benchmarks.judge import MET, NOT_MET, Judge


def test_memory_projection_is_the_measured_line():
    # The stored points lie on one line (linear in N) to 0.05 GB; the projection
    # passes through them and grows with N; the time is a lower bound from the
    # quietest per-sample cost measured.
    for n, t, gb, _ in PARSIM_K_MEASURED:
        proj_gb, proj_s = parsim_k_projection(n)
        assert abs(proj_gb - gb) < 0.05
        if n > 10_000:
            assert proj_s <= t + 1e-9
    gb6, s6 = parsim_k_projection(1_000_000)
    assert gb6 > PEER_MEMORY_GB  # the honest reason 1e6 is not run
    assert s6 > PARSIM_K_MEASURED[-1][1]


def test_unmeasured_points_say_why_and_do_not_count():
    text = parsim_k_verdict(1_000_000)
    assert text.startswith("not measured") and "GB" in text and "1e+06" in text
    # a transform row at 1e5 with PARSIM-K 60x slower, one at 1e6 without PARSIM-K
    ssarx = TRANSFORM["ssarx"]
    rows = [
        {"case": "issue", "N": 100_000, "tool": ssarx, "time_s": 0.1, "moesp_ratio": 1.5},
        {"case": "issue", "N": 100_000, "tool": "SIPPY PARSIM-K", "time_s": 6.0},
        {"case": "issue", "N": 10**6, "tool": ssarx, "time_s": 0.3, "moesp_ratio": 1.6},
    ]

    def get(case, n, tool):
        return next((r for r in rows if (r["case"], r["N"], r["tool"]) == (case, n, tool)), None)

    judge = Judge()
    _time_checks(rows, get, TRANSFORM["ssarx"], "ssarx, transform path", judge)
    peer = next(v for v in judge.verdicts if "PARSIM-K" in v.target)
    assert peer.status == MET  # judged on the measured 1e5 point (60x) only
    assert "60x" in peer.measured and "not measured at issue 1e+06" in peer.measured
    rows[1]["time_s"] = 4.0  # 40x: not met, whatever the unmeasured point
    judge = Judge()
    _time_checks(rows, get, TRANSFORM["ssarx"], "ssarx, transform path", judge)
    assert next(v for v in judge.verdicts if "PARSIM-K" in v.target).status == NOT_MET


def test_markdown_states_the_footprint():
    res = {"load": (1.0, 1.0, 1.0), "bearing": [], "generic": [], "suspension": []}
    text = "\n".join(markdown_section(res))
    assert f"above N = {PEER_MAX_N:.0e}" in text and "not measured" in text
    gb, _ = parsim_k_projection(1_000_000)
    assert f"~{gb:.1f} GB" in text and np.isfinite(gb)
