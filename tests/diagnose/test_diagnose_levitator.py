"""Diagnosis of one-coil levitators: the real UAQ records (../shared/data) and a rig log
without an excitation column (simulated, truth known).

Physics reference (docs/real-rigs.md): the published UAQ law puts the unstable pole at
sqrt(2 g/(a + y0)) = 43.7-45.6 rad/s over the sessions' gaps (4.2-5.1 mm, a = 5.2 mm).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from maglevid.cli.main import main
from maglevid.diagnose.pipeline import diagnose
from maglevid.experiments.rigs import PUBLISHED, simulate_pd_dither_levitator
from maglevid.physics.levitator import unstable_pole

UAQ = "maglev-uaq-levitador"


def _session(shared_data, name):
    return next((shared_data / UAQ).glob(f"dataset_{name}_*.txt"))


def test_multistep_session_pole_agrees_with_the_published_physics(shared_data):
    d = diagnose(_session(shared_data, "multiescalon"), mapping="uaq-levitador")
    assert d.method == "levitator" and "plant kind levitator" in d.method_reason
    lo, hi = d.identification.extras["consensus"]["ci95"]
    y_ref = d.identification.options["y_ref"]
    physics = unstable_pole(PUBLISHED, y_ref)  # 44.2 rad/s at 4.85 mm
    # Three reference steps excite the loop: the command-frame grey box must agree with
    # the published physics within 5 % (the spread of the equilibrium currents between
    # sessions, 0.42-0.47 A, is +-5 %), and its interval must not exceed +-15 %.
    assert abs(d.identification.parameters["pole_rad_s"] - physics) < 0.05 * physics
    assert hi - lo < 0.3 * physics
    pole = next(c for c in d.changes if c.name == "pole_rad_s")
    assert pole.baseline == pytest.approx(physics, rel=1e-9)
    assert "published physics" in d.baseline["source"]


def test_a_dither_only_rig_log_is_diagnosed_without_a_baseline():
    # PD loop + current amplifier, white dither, no r column, no published physics
    log = simulate_pd_dither_levitator(6000, rng=np.random.default_rng(5))
    d = diagnose(log)
    truth = log.metadata["truth_pole_rad_s"]  # sqrt(2 g/(a + y0)) at the mean gap
    lo, hi = d.identification.extras["consensus"]["ci95"]
    assert lo < truth < hi
    assert d.verdict_code == "no_change" and d.baseline["source"] == "none"
    assert "nothing to compare with" in d.reasons[0]


def test_too_little_levitation_cannot_be_diagnosed():
    # 6 s of levitation < MIN_LEVITATING_SECONDS = 10 s
    log = simulate_pd_dither_levitator(3000, rng=np.random.default_rng(5))
    d = diagnose(log)
    assert d.verdict_code == "cannot_diagnose"
    assert "too little usable levitation" in d.verdict


def test_identify_and_diagnose_from_the_command_line(shared_data, capsys):
    path = str(_session(shared_data, "multiescalon"))
    assert main(["--json", "identify", path, "--mapping", "uaq-levitador"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["plant_kind"] == "levitator" and res["method"] == "levitator"
    assert "one input and outputs [gap, current]" in res["plant_kind_reason"]
    lo, hi = res["ci95"]["pole_rad_s"]
    assert lo <= res["parameters"]["pole_rad_s"] <= hi
    assert res["candidates"] and res["segments_excluded"][0]["excluded"][0]["reason"] == (
        "lift-off"
    )
    assert main(["diagnose", path, "--mapping", "uaq-levitador"]) == 0
    assert "unstable pole" in capsys.readouterr().out
