"""``maglevid reproduce gosiewski``: structure, exactness where exact, figures, text."""

from __future__ import annotations

import json

import numpy as np
import pytest

from maglevid.cli.main import build_parser
from maglevid.experiments import gosiewski


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    out = tmp_path_factory.mktemp("repro")
    args = build_parser().parse_args(
        ["-q", "reproduce", "gosiewski", "--out", str(out), "--n-samples", "4000",
         "--runs", "2", "--workers", "1", "--nonlinear-samples", "300", "--seed", "5"]
    )  # fmt: skip
    return args._reproduce(args)


def test_nominal_matrices_match_the_printed_ones(result):
    # The printed A_C, B_C are rounded to 2 and 4 decimals (row 4 sign decided).
    assert result["nominal"]["max_rel_diff_to_printed_percent"] < 0.01


def test_noise_free_examples_are_exact(result):
    for ex in ("I", "II", "III"):
        assert (
            result["examples"][ex]["noise_free"]["deadbeat-arx"]["max_abs_v_error_percent"] < 1e-6
        )


def test_fault_shows_up_in_the_right_element(result):
    # Example II: v5 = R1/L1 +20 %; Example III: v8 = kw1/L1 +20 %, at the noisy level.
    for ex, idx in (("II", 4), ("III", 7)):
        for m in ("deadbeat-iv", "physical"):
            ch = result["examples"][ex]["noisy"][m]
            assert ch["change_percent"][idx] == pytest.approx(20.0, abs=1.5)
            assert ch["flagged"][idx]
    ap = np.array(result["examples"]["II"]["noise_free"]["deadbeat-arx"]["A_p"], dtype=float)
    assert ap[2, 2] == pytest.approx(20.0, abs=1e-6)


def test_diagnostic_case_separates_the_methods(result):
    diag = result["diagnostic_case"]
    for label, row in diag.items():
        assert row["physical"] < 1e-6, label
    assert diag["kw1+20%"]["deadbeat-arx"] > 1.0
    assert "refused" in diag["R1+20%, mirror-symmetric controller"]["deadbeat-arx"]


def test_monte_carlo_figures_text_and_json(result):
    mc = result["monte_carlo"]
    assert mc["runs_per_example"] == 2 and len(mc["seeds"]) == 6 and len(set(mc["seeds"])) == 6
    assert set(mc["examples"]["I"]) == {"deadbeat-arx", "deadbeat-iv", "physical"}
    for path in result["figures"]:
        with open(path, "rb") as f:
            assert f.read(8) == b"\x89PNG\r\n\x1a\n"
    text = gosiewski.format_text(result)
    assert "×" in text and "Example II" in text and "19.7729" in text
    json.dumps(result, allow_nan=False)
