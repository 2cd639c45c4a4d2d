"""``maglevid history``: listing machines, trends with drift verdicts, JSON, errors."""

from __future__ import annotations

import json
import re
from datetime import datetime, timedelta, timezone

import numpy as np
import pytest

from maglevid.cli.main import main
from maglevid.diagnose.history import open_history

T0 = datetime(2026, 1, 5, 8, 0, tzinfo=timezone.utc)


@pytest.fixture
def store_path(tmp_path, rng):
    """pump-7: R1 drifts by 2 mohm/day over 15 weekly recordings, Ls1 is steady;
    spindle-2: two recordings only, by two methods."""
    path = tmp_path / "h.sqlite"
    with open_history(path) as s:
        for i in range(15):
            s.record_diagnosis(
                "pump-7",
                recording_hash=f"p{i}",
                recorded_at=T0 + timedelta(days=7 * i),
                method="deadbeat-arx",
                verdict="healthy",
                verdict_code="no_change",
                estimates={
                    "R1": (
                        2.0 + 0.002 * 7 * i + 0.01 * rng.standard_normal(),
                        0.01,
                        None,
                        None,
                        "ohm",
                        2.0,
                    ),
                    "Ls1": (0.03 + 1e-4 * rng.standard_normal(), 1e-4, None, None, "H", 0.03),
                },
            )
        for i, m in enumerate(["deadbeat-arx", "subspace"]):
            s.record_diagnosis(
                "spindle-2",
                recording_hash="s0",
                recorded_at=T0,
                method=m,
                verdict="healthy",
                verdict_code="no_change",
                estimates={"R1": (1.0 + i, None)},
            )
    return path


def run_json(capsys, *argv):
    code = main(["--json", "history", *map(str, argv)])
    return code, json.loads(capsys.readouterr().out)


def test_list_machines(store_path, capsys):
    code, out = run_json(capsys, "--list", "--store", store_path)
    assert code == 0
    assert [(m["name"], m["n_diagnoses"]) for m in out["machines"]] == [
        ("pump-7", 15),
        ("spindle-2", 2),
    ]
    assert main(["history", "--list", "--store", str(store_path)]) == 0
    text = capsys.readouterr().out
    assert "pump-7" in text and "spindle-2" in text


def test_trends_and_drift_verdicts(store_path, capsys):
    code, out = run_json(capsys, "pump-7", "--store", store_path, "--tolerance", "R1=0.5")
    assert code == 0
    assert out["n_diagnoses"] == 15 and set(out["parameters"]) == {"R1", "Ls1"}
    r1 = out["parameters"]["R1"]
    assert r1["unit"] == "ohm" and len(r1["points"]) == 15
    assert r1["points"][0]["recorded_at"] == T0.isoformat()
    d = r1["drift"]["deadbeat-arx"]
    assert d["drifting"] and d["p_value"] < 1e-6 and d["time_unit"] == "day"
    # Slope 2 mohm/day; the s.e. is ~8e-5 ohm/day, so 4 s.e. is a loose, fixed-seed check.
    assert abs(d["slope"] - 0.002) < 4 * d["slope_se"]
    # The limit 2.5 ohm (stored baseline 2 + 0.5) is reached 250 days after T0.
    assert d["limit"] == 2.5
    truth = T0 + timedelta(days=250)
    lo, hi = (datetime.fromisoformat(x) for x in d["crossing_ci_at"])
    assert lo < truth < hi
    assert not out["parameters"]["Ls1"]["drift"]["deadbeat-arx"]["drifting"]
    assert out["drifting"] == ["R1 (deadbeat-arx)"]
    # Text (issue 18: was one line per point, ~600 lines for a bearing): one line
    # per parameter, the drifting one first, with unit, latest, change, trend, verdict.
    argv = ["history", "pump-7", "--store", str(store_path), "--tolerance", "R1=0.5"]
    assert main(argv) == 0
    rows = capsys.readouterr().out.strip().splitlines()
    table = [r for r in rows if r.startswith(("R1 ", "Ls1 "))]
    assert len(table) == 2 and table[0].startswith("R1 ")
    assert "ohm" in table[0] and "ohm/day" in table[0] and table[0].endswith("DRIFTING")
    assert table[1].endswith("stable")
    # The true change at the last point: +0.002 * 98 days / 2 ohm = +9.8 %; one
    # point's noise is 0.01 ohm = 0.5 % of the baseline, so within 3 s.e. = 1.5 %.
    change = float(re.search(r"([+-]\d+\.\d) %", table[0]).group(1))
    assert abs(change - 9.8) < 1.5
    assert change == round(100 * (out["parameters"]["R1"]["latest"]["value"] - 2.0) / 2.0, 1)
    # --points: the series behind each line and the drift tests in full.
    assert main([*argv, "--points"]) == 0
    text = capsys.readouterr().out
    assert "R1 [ohm]" in text and "DRIFTING" in text and "no significant drift" in text
    assert "limit 2.5 ohm" in text


def test_parameter_filter_method_split_and_exit_code(store_path, capsys):
    code, out = run_json(capsys, "pump-7", "--store", store_path, "--parameter", "Ls1")
    assert list(out["parameters"]) == ["Ls1"]
    code, out = run_json(capsys, "pump-7", "--store", store_path, "--fail-on-drift")
    assert code == 3 and out["exit_code"] == 3
    code, out = run_json(capsys, "spindle-2", "--store", store_path, "--drift-method", "wls")
    drift = out["parameters"]["R1"]["drift"]
    assert set(drift) == {"deadbeat-arx", "subspace"}  # one test per method, never mixed
    assert all("at least 3" in d["skipped"] for d in drift.values())
    code, out = run_json(capsys, "spindle-2", "--store", store_path, "--method", "subspace")
    assert [p["value"] for p in out["parameters"]["R1"]["points"]] == [2.0]


def test_default_store_from_environment(store_path, capsys, monkeypatch, tmp_path):
    monkeypatch.setenv("MAGLEVID_HISTORY", str(store_path))
    code, out = run_json(capsys, "--list")
    assert code == 0 and len(out["machines"]) == 2
    monkeypatch.delenv("MAGLEVID_HISTORY")
    empty = tmp_path / "empty"
    empty.mkdir()
    monkeypatch.chdir(empty)
    code, out = run_json(capsys, "--list")
    assert code == 1 and "no history store" in out["message"]
    assert list(empty.iterdir()) == []  # reading never creates a store


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["nobody"], "no machine 'nobody'"),
        (["pump-7", "--parameter", "kw1"], "parameters: Ls1, R1"),
        ([], "give a MACHINE"),
        (["pump-7", "--tolerance", "R1"], "NAME=VALUE"),
        (["pump-7", "--tolerance", "R1=-1"], "NAME=VALUE"),
        (["pump-7", "--parameter", "R1", "--tolerance", "Ls1=1"], "not shown"),
        (["pump-7", "--alpha", "2"], "alpha"),
    ],
)
def test_errors_are_one_line_and_exit_1(store_path, capsys, argv, message):
    assert main(["history", *argv, "--store", str(store_path)]) == 1
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_json_is_strict(store_path, capsys):
    # No NaN/Infinity tokens: other tools must parse it.
    main(["--json", "history", "spindle-2", "--store", str(store_path)])
    text = capsys.readouterr().out
    assert "NaN" not in text and "Infinity" not in text
    assert np.isfinite(json.loads(text)["alpha"])


def test_a_step_is_reported_as_a_step(tmp_path, rng, capsys):
    # An amplifier loses 20 % of its gain between two weekly recordings (the demo's
    # AMB-3): the line says STEP with its date and size, not a drift.
    path = tmp_path / "s.sqlite"
    with open_history(path) as s:
        for i in range(12):
            kw1 = (1.0 if i < 7 else 0.8) + 0.005 * rng.standard_normal()
            s.record_diagnosis(
                "amp-3",
                recording_hash=f"a{i}",
                recorded_at=T0 + timedelta(days=7 * i),
                method="physical",
                verdict="-",
                verdict_code="no_change",
                estimates={"kw1": (kw1, 0.005, None, None, "V·V⁻¹", 1.0)},
            )
    code, out = run_json(capsys, "amp-3", "--store", path)
    kw1 = out["parameters"]["kw1"]
    assert code == 0 and kw1["verdict"] == "STEP"
    assert kw1["step"]["at"] == (T0 + timedelta(days=49)).isoformat()
    # Size -0.2 within 4 standard errors of the difference of the two means.
    assert abs(kw1["step"]["size"] + 0.2) < 4 * 0.005 * (1 / 7 + 1 / 5) ** 0.5
    assert main(["history", "amp-3", "--store", str(path)]) == 0
    line = next(r for r in capsys.readouterr().out.splitlines() if r.startswith("kw1"))
    assert "step at " + (T0 + timedelta(days=49)).date().isoformat() in line
    # The step column is drift.detect_step's (Student t with n - 2 = 10 dof, Bonferroni
    # over the 11 splits; issue 19 made it the one step test): a ~40-standard-error step
    # has p ~ 1e-11 there (the former normal-reference test printed "p < 1e-16").
    assert kw1["step"]["p_value"] < 1e-9 and kw1["step"]["is_step"]
    assert line.endswith("STEP") and f"p = {kw1['step']['p_value']:.2g}" in line
