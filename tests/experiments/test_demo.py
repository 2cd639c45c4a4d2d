"""The demo fleet: right causes, no false alarm on the healthy one, drift before tolerance."""

from __future__ import annotations

import pytest

from maglevid.experiments.demo import DEMO_TOLERANCES, run_demo

# R1 rises by 15 % over 56 days: it crosses the 10 % tolerance on day 37.3.
R1_TOLERANCE_DAY = DEMO_TOLERANCES / 0.15 * 56


# Seed 1 once gave the healthy AMB-3 a false R1 drift alarm on day 24 (t-test p = 0.00026,
# scatter 0.33 of the stated errors by chance): each diagnosis re-tests the whole history.
# The pipeline's drift test floors the scale at the stated errors (docs/history.md).


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2])
def test_demo_flags_the_right_bearings(tmp_path, seed):
    # Every 4 days instead of 3 keeps the test at ~15 s per seed.
    res = run_demo(tmp_path / "demo", seed=seed, every_days=4)
    by = {}
    for r in res["rows"]:
        by.setdefault(r["machine"], []).append(r)
    # The healthy bearing is never flagged.
    assert all(r["verdict_code"] in ("no_change", "within_tolerance") for r in by["AMB-1"])
    # The heating coil: the first alarm is about R1 and comes before the tolerance is reached.
    alarms = [r for r in by["AMB-2"] if r["verdict_code"] in ("drift", "fault")]
    assert alarms and alarms[0]["day"] < R1_TOLERANCE_DAY
    assert "R1" in alarms[0]["verdict"]
    assert "coil 1 resistance" in by["AMB-2"][-1]["verdict"]
    # The amplifier: faults from day 35 on, naming amplifier 1; nothing before.
    for r in by["AMB-3"]:
        if r["day"] < 35:
            assert r["verdict_code"] in ("no_change", "within_tolerance"), r
        else:
            assert r["verdict_code"] == "fault" and "amplifier 1 gain" in r["verdict"], r
    assert set(res["reports"]) == {"AMB-2", "AMB-3"}


def test_demo_is_idempotent(tmp_path):
    a = run_demo(tmp_path / "d", weeks=1, every_days=7, n_samples=20_000)
    b = run_demo(tmp_path / "d", weeks=1, every_days=7, n_samples=20_000)
    assert [r["verdict_code"] for r in a["rows"]] == [r["verdict_code"] for r in b["rows"]]
    from maglevid.diagnose.history import open_history

    with open_history(tmp_path / "d" / "history.sqlite") as store:
        assert sum(len(store.diagnoses(m)) for m in ("AMB-1", "AMB-2", "AMB-3")) == 6
