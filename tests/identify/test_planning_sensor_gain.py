"""`maglevid plan --fault gi1=...`: the bearing as seen through a sensor gain (issue 13, h13diag).

Reference: the derivation in cli/plan.py (SENSOR_GAIN_NOTE; docs/gosiewski.md,
"Experiment planning"). The loop and the identification see the states
z = diag(gx, gx, gi1, gi2) x, so eq. (4) holds with v2 gx/gi1, v3 gx/gi2,
v4 gi1/gx, v6 gi2/gx, v8 gi1, v9 gi2, and inverting it with the true m and i0
gives ki_j gx/gi_j, L_j and R_j x (gx/gi_j)^2, kw_j gx^2/gi_j and
x0 gx (ki1/gi1 + ki2/gi2)/(ki1 + ki2). gi_j is a current-sensor gain; an
amplifier gain is kw_j (``--fault kw1=...``), which moves kw1 alone.
"""

from __future__ import annotations

import json

import pytest

from maglevid.cli.main import main
from maglevid.physics.amb import AMBParameters

P = AMBParameters.nominal()
NAMES = "R1,R2,L1,L2,ki1,ki2,kw1,kw2,x0"


def _values(capsys, *faults: str) -> tuple[dict[str, float], dict]:
    args = ["--json", "plan", "--parameters", NAMES, "--seconds", "0.5"]
    for f in faults:
        args += ["--fault", f]
    assert main(args) == 0
    out = json.loads(capsys.readouterr().out)
    return {p["name"]: p["value"] for p in out["parameters"]}, out


@pytest.mark.parametrize(("gx", "gi1"), [(1.0, 1.05), (1.1, 0.95)])
def test_sensor_gain_plan_values_follow_the_derivation(capsys, gx, gi1):
    val, out = _values(capsys, f"gx={gx}", f"gi1={gi1}")
    r1, r2 = gx / gi1, gx  # gx/gi_j, gi2 = 1
    expected = {
        "R1": P.R1 * r1**2, "R2": P.R2 * r2**2, "L1": P.L1 * r1**2, "L2": P.L2 * r2**2,
        "ki1": P.ki1 * r1, "ki2": P.ki2 * r2, "kw1": P.kw1 * gx**2 / gi1, "kw2": P.kw2 * gx**2,
        "x0": P.x0 * gx * (P.ki1 / gi1 + P.ki2) / (P.ki1 + P.ki2),
    }  # fmt: skip
    for name, want in expected.items():
        assert val[name] == pytest.approx(want, rel=1e-9), name
    assert "current-sensor gain" in out["note"]


def test_gi1_1_05_shows_r1_over_gi1_squared(capsys):
    """The issue's example: R1 15.873 = 17.5 / 1.05^2, the apparent value."""
    val, _ = _values(capsys, "gi1=1.05")
    assert val["R1"] == pytest.approx(17.5 / 1.05**2, rel=1e-9)


def test_an_amplifier_gain_moves_kw1_alone_and_has_no_note(capsys):
    val, out = _values(capsys, "kw1=1.05")
    assert val["kw1"] == pytest.approx(1.05 * P.kw1, rel=1e-9)
    assert val["R1"] == pytest.approx(P.R1, rel=1e-9) and val["L1"] == pytest.approx(P.L1)
    assert "note" not in out
