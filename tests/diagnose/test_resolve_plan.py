"""The inconclusive verdict's way forward from the Cramér-Rao plan (issue 13, item 4).

Reference: the advice is a prediction; the test follows it (a new record at the
level and length it names) and checks that the interval it promised is met.
"""

from __future__ import annotations

import dataclasses

import pytest

from maglevid.diagnose.pipeline import diagnose
from maglevid.diagnose.resolve import plan_unresolved
from maglevid.physics.amb import AMBParameters
from maglevid.simulate import simulate_amb_loop

NOMINAL = AMBParameters.nominal()
FAULTY = NOMINAL.with_fault(R1=1.2)
#: Ten times the CLI's sensor noise and 0.2 s: the ml fit cannot resolve R1 to
#: ±3 % (it states ±4.2 %), so the verdict is inconclusive with a plan.
LOOP = {"nominal": NOMINAL, "plant_model": "linear", "noise_std": (1e-6, 1e-3, 1e-3),
        "force_std": 0.0}  # fmt: skip
TOL = {"R1": 0.03}


@pytest.fixture(scope="module")
def advice():
    rec = simulate_amb_loop(FAULTY, rng=1, n_samples=2000, **LOOP)
    d = diagnose(rec, baseline="nominal", method="ml", tolerances=TOL)
    assert d.verdict_code == "inconclusive", d.verdict
    return next(u for u in d.resolution if u["parameter"] == "R1"), d


def test_the_verdict_cites_the_plan(advice):
    u, d = advice
    assert "Cramér-Rao plan" in d.verdict and "V rms" in d.verdict
    assert u["plan_seconds"] > 0 and 0 < u["plan_excitation"] <= 4.0
    # The best level is inside the limits, and a longer record of the same kind helps.
    assert u["more_seconds"] > 0


@pytest.mark.parametrize("seed", [11, 12])
def test_following_the_plan_gives_the_promised_interval(advice, seed):
    """A record at the planned level and length (independent seed): R1's 95 %
    half-width within the tolerance (measured 2.6-2.7 % for 3 %, seeds 11-14: the
    model error's growth with the excursion is taken proportional, a little
    pessimistic), and not far inside it (the plan is not wildly conservative)."""
    u, _ = advice
    n = max(2000, round(u["plan_seconds"] / 1e-4))
    rec = simulate_amb_loop(FAULTY, rng=seed, n_samples=n, excitation_std=u["plan_excitation"],
                            **LOOP)  # fmt: skip
    d = diagnose(rec, baseline="nominal", method="ml", tolerances=TOL)
    h = next(x for x in d.isolation.singles if x.parameters == ("R1",))
    half = 1.96 * h.factor_std_errors[0]
    assert 0.7 * TOL["R1"] < half <= TOL["R1"], half
    assert d.verdict_code == "fault" and d.isolation.best.parameters == ("R1",)


def test_without_a_logged_excitation_the_scaling_rule_stays_with_the_reason(advice):
    _, d = advice
    rec = simulate_amb_loop(FAULTY, rng=1, n_samples=2000, **LOOP)
    names = {k: v for k, v in rec.names.items() if k != "r"}
    units = {k: v for k, v in rec.units.items() if k != "r"}
    bare = dataclasses.replace(rec, r=None, names=names, units=units)
    from maglevid.diagnose.resolve import unresolved_parameters
    from maglevid.identify.ml import fit_ml

    un = unresolved_parameters(d.isolation, TOL, duration_s=0.2)
    same, why = plan_unresolved(un, d.isolation, bare, fit_ml(rec), tolerances=TOL)
    assert same == un and "excitation r" in why
