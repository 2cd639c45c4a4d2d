"""The inconclusive verdict's way forward from the Cramér-Rao plan (issue 13, item 4).

Reference: the advice is a prediction; the test follows it (a new record at the
level and length it names) and checks that the interval it promised is met.
"""

from __future__ import annotations

import dataclasses
from dataclasses import replace

import numpy as np
import pytest

from maglevid.diagnose.isolate import FaultHypothesis, IsolationResult, isolate_fault
from maglevid.diagnose.pipeline import diagnose
from maglevid.diagnose.resolve import plan_unresolved, unresolved_parameters
from maglevid.physics.amb import AMBParameters
from maglevid.simulate import simulate_amb_loop

NOMINAL = AMBParameters.nominal()
FAULTY = NOMINAL.with_fault(R1=1.2)
#: Ten times the CLI's sensor noise and 0.2 s: the ml fit states R1 +19.4 % ± 4.2 %
#: (95 %), which straddles a 17 % tolerance, so the verdict is inconclusive with a
#: plan for the 2.4 % half-width that would decide it (the estimate's distance from
#: the boundary). Until the straddling rule (plants/amb.py) the tolerance here was
#: 3 %: an interval wholly beyond it is now a decided fault, not inconclusive.
LOOP = {"nominal": NOMINAL, "plant_model": "linear", "noise_std": (1e-6, 1e-3, 1e-3),
        "force_std": 0.0}  # fmt: skip
TOL = {"R1": 0.17}


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


def test_following_the_plan_gives_the_promised_interval(advice):
    """Records at the planned level and length (independent seeds): R1's 95 %
    half-width about the one the plan promised (the estimate's distance from the
    tolerance, 2.9 %). Since the model error is the measured 2 e^2 (h13diag) the
    plan's level at this length (1.63 V rms, 2000 samples) sits exactly where the
    expected half-width reaches it, no longer with the old term's pessimism, so
    one record's stated half-width scatters about it (measured on these seeds:
    0.72-1.12 of it): the mean of four within 0.7-1.05 of it and each below
    1.25 of it. Whether the new interval then clears the boundary depends on
    where the new estimate falls, so only the cause is asserted."""
    u, _ = advice
    need = u["needed_percent"] / 100
    n = round(u["plan_seconds"] / 1e-4)
    assert n == 2000  # never shorter than the recording (resolve._ExcitationGrid.needs)
    ratios = []
    for seed in (11, 12, 13, 14):
        rec = simulate_amb_loop(FAULTY, rng=seed, n_samples=n,
                                excitation_std=u["plan_excitation"], **LOOP)  # fmt: skip
        d = diagnose(rec, baseline="nominal", method="ml", tolerances=TOL)
        h = next(x for x in d.isolation.singles if x.parameters == ("R1",))
        ratios.append(1.96 * h.factor_std_errors[0] / need)
        assert d.isolation.best.parameters == ("R1",)
    assert 0.7 < np.mean(ratios) <= 1.05 and max(ratios) < 1.25, ratios


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
    # The scaling rule's advice stays, now carrying the amplifiers' limit (the
    # planner's default 4 V) so that it proposes no level beyond it (issue 13).
    assert [dataclasses.replace(u, amplifier_limit=None) for u in same] == un
    assert all(u.amplifier_limit == 4.0 for u in same) and "excitation r" in why


# --- The baseline's own uncertainty (resolve.py, module notes) ---------------------


def _single(se_n: float, se_f: float, g5: float = 50.0, f: float = 1.0) -> FaultHypothesis:
    """An "only R1 changed" fit whose sensitivity is on v5 alone (R1 moves v5)."""
    g = tuple(g5 if i == 4 else 0.0 for i in range(9))
    se = (se_n**2 + se_f**2) ** 0.5
    return FaultHypothesis(("R1",), (f,), (se,), 0.0, 8, 1.0, (se_n,), (se_f,), g)


def _iso(h: FaultHypothesis) -> IsolationResult:
    none = FaultHypothesis((), (), (), 50.0, 9, 1e-6)
    return IsolationResult(best=h, candidates=(h,), no_change=none, alpha=0.01, explained=True)


def test_the_scaling_rule_counts_the_baseline_it_cannot_shrink():
    """Analytic: with the baseline's share ``se_b`` (from S_b and the sensitivity,
    ``se_b = f sqrt(S_b,55) / g5``) the length factor is
    ``k = (se_n^2 - se_b^2) / ((tol/z)^2 - se_b^2 - se_f^2)``. The estimate is
    on the baseline (f = 1), so the half-width that decides is the tolerance."""
    z, tol, f, g5 = 1.959963984540054, 0.03, 1.0, 50.0
    h = _single(se_n=0.03, se_f=0.002, g5=g5, f=f)
    se_b = 0.008
    S_b = np.zeros((9, 9))
    S_b[4, 4] = (se_b / f * g5) ** 2
    (u,) = unresolved_parameters(_iso(h), {"R1": tol}, baseline_covariance=S_b, duration_s=2.0)
    t2 = (tol / z) ** 2
    k = (0.03**2 - se_b**2) / (t2 - se_b**2 - 0.002**2)
    assert u.length_factor == pytest.approx(k, rel=1e-9)
    assert u.more_seconds == pytest.approx((k - 1) * 2.0, rel=1e-9)
    assert u.baseline_percent == pytest.approx(100 * z * se_b, rel=1e-9)
    # Without the baseline the same fit would promise a shorter record.
    (u0,) = unresolved_parameters(_iso(h), {"R1": tol}, duration_s=2.0)
    assert u0.length_factor < k and u0.baseline_percent is None
    # A baseline wider than the tolerance: no record of the present state helps.
    S_b[4, 4] = (0.02 / f * g5) ** 2  # se_b = 2 %: 95 % half-width 3.9 % > 3 %
    (ub,) = unresolved_parameters(_iso(h), {"R1": tol}, baseline_covariance=S_b)
    assert ub.baseline_limited and not ub.resolvable
    assert "the baseline itself is uncertain by ±3.9 %" in ub.advice()
    assert "re-record the baseline" in ub.advice()


def _r1(unresolved: list) -> list:
    return [u for u in unresolved if u.parameter == "R1"]


def test_the_cramer_rao_plan_with_a_baseline_needs_var_over_tol2_minus_var_b(advice):
    """Analytic (Sherman-Morrison): a baseline covariance ``c g g^T`` along the
    hypothesis's sensitivity adds exactly ``c`` to the log-factor's variance under
    any other covariance, so the plan at tolerance ``tol`` with that baseline must
    equal the plan without it at ``tol'`` with ``(tol'/z f)^2 = (tol/z f)^2 - c``
    (N = var / (tol^2 - var_b)). The isolation with the baseline is built the same
    way (its noise and total variances plus ``c``). Equal to the bisections'
    resolution (1e-3 in log10 of the samples)."""
    _, d = advice
    rec = simulate_amb_loop(FAULTY, rng=1, n_samples=2000, **LOOP)
    iso0 = d.isolation
    h = next(x for x in iso0.singles if x.parameters == ("R1",))
    g, f = np.asarray(h.sensitivity), h.factors[0]
    z = 1.959963984540054
    need = (f - 1) - TOL["R1"]  # the estimate's distance beyond the tolerance
    t2 = (need / (z * f)) ** 2
    c = 0.3 * t2
    S_b = c * np.outer(g, g)
    hb = dataclasses.replace(
        h,
        factor_std_errors=(f * ((h.factor_std_errors[0] / f) ** 2 + c) ** 0.5,),
        noise_std_errors=(f * ((h.noise_std_errors[0] / f) ** 2 + c) ** 0.5,),
    )
    iso_b = dataclasses.replace(
        iso0, candidates=tuple(hb if x is h else x for x in iso0.candidates)
    )
    tol0 = {"R1": (f - 1) - z * f * (t2 - c) ** 0.5}  # distance z f sqrt(t2 - c)
    ub = unresolved_parameters(iso_b, TOL, baseline_covariance=S_b, duration_s=0.2)
    u0 = unresolved_parameters(iso0, tol0, duration_s=0.2)
    fit = d.identification
    (pb,), _ = plan_unresolved(_r1(ub), iso_b, rec, fit, tolerances=TOL, baseline_covariance=S_b)
    (p0,), _ = plan_unresolved(_r1(u0), iso0, rec, fit, tolerances=tol0)
    assert pb.parameter == p0.parameter == "R1"
    assert pb.plan_seconds == pytest.approx(p0.plan_seconds, rel=1e-2)
    assert pb.more_seconds == pytest.approx(p0.more_seconds, rel=1e-2)
    assert pb.baseline_percent == pytest.approx(100 * z * f * c**0.5, rel=1e-6)
    assert "baseline's own" in pb.advice()
    # And the baseline costs time against the same tolerance with an exact baseline.
    (pe,), _ = plan_unresolved(
        _r1(unresolved_parameters(iso0, TOL, duration_s=0.2)), iso0, rec, fit, tolerances=TOL
    )
    # (At the present level: the shortest plan at the best level is at least the
    # recording's 0.2 s since h13diag, and both reach it.)
    assert pb.length_factor > 1.2 * pe.length_factor


def test_an_uncertain_baseline_is_named_not_planned(advice):
    """The isolation itself with a baseline whose v5 (R1's element) is uncertain by
    3 %: R1's baseline alone has a 95 % half-width of ~5.9 % > the 2.4 % that
    would decide the 17 % tolerance."""
    _, d = advice
    rec = simulate_amb_loop(FAULTY, rng=1, n_samples=2000, **LOOP)
    fit, iso0 = d.identification, d.isolation
    names = list(fit.parameters)
    idx = [names.index(f"v{i}") for i in range(1, 10)]
    v_hat = np.array([fit.parameters[f"v{i}"] for i in range(1, 10)])
    S_b = np.diag((0.03 * NOMINAL.v()) ** 2 * (np.arange(9) == 4) + (1e-4 * NOMINAL.v()) ** 2)
    iso_b = isolate_fault(
        v_hat, fit.covariance[np.ix_(idx, idx)], NOMINAL, baseline_covariance=S_b,
        operating_point=iso0.operating_point, model_error=iso0.model_error,
    )  # fmt: skip
    un = unresolved_parameters(iso_b, TOL, baseline_covariance=S_b, duration_s=0.2)
    u = next(x for x in un if x.parameter == "R1")
    assert u.baseline_limited and 5.0 < u.baseline_percent < 7.0
    planned, why = plan_unresolved(un, iso_b, rec, fit, tolerances=TOL, baseline_covariance=S_b)
    assert why is None
    # no plan can help: only the amplifiers' limit is added (for the scaling rule's advice)
    assert next(x for x in planned if x.parameter == "R1") == replace(u, amplifier_limit=4.0)
    assert "the baseline itself is uncertain" in u.advice()


def test_against_a_history_of_the_same_quality_the_advice_names_the_baseline(tmp_path):
    """End to end: the history baseline's standard errors reach the advice
    (plants/amb.py passes them to the resolver). The baseline is an ``ml``
    identification of a healthy record as noisy and as short as the new one, so
    R1's baseline alone has about the new record's half-width (~4 %), and the advice
    counts it."""
    from maglevid.diagnose.history import open_history

    store = open_history(tmp_path / "h.sqlite")
    opts = {"baseline": "history", "machine": "B1", "history": store, "method": "ml"}
    rec0 = simulate_amb_loop(NOMINAL, rng=3, n_samples=2000, **LOOP)
    diagnose(rec0.with_metadata(recorded_at="2026-01-01T00:00:00+00:00"), tolerances=TOL, **opts)
    rec1 = simulate_amb_loop(FAULTY, rng=1, n_samples=2000, **LOOP)
    d = diagnose(rec1.with_metadata(recorded_at="2026-01-08T00:00:00+00:00"), tolerances=TOL,
                 **opts)  # fmt: skip
    store.close()
    assert d.baseline["source"].startswith("earlier identification")
    r1 = next(u for u in d.resolution if u["parameter"] == "R1")
    assert 2.0 < r1["baseline_percent"] < 8.0, r1
    # The baseline's share is named in the advice (against the history the estimate
    # is +21 %: the 4.1 % that decides it is a little more than the baseline's 3.9 %,
    # and with the model error no record of the present state decides it).
    assert f"baseline's own ±{r1['baseline_percent']:.2g} %" in r1["advice"]


def test_same_excitation_advice_respects_a_limit_the_record_already_exceeds():
    # A record at 1 V rms with --max-excitation-std 0.8: "record about 12.3 s more of
    # the same excitation" asked for 1 V, beyond the stated limit (found from outside,
    # issue 16, fourteenth session). Reference: information ~ level^2 x length, so at
    # 0.8 V the 3 s record needs k (1/0.8)^2 times its length: 3 (5.1 x 1.5625 - 1).
    from maglevid.diagnose.resolve import Unresolved

    k = 5.1
    u = Unresolved(
        parameter="m", tolerance_percent=5.0, half_width_percent=6.0, length_factor=k,
        more_seconds=(k - 1) * 3.0, excitation_factor=k**0.5, excitation_rms=k**0.5 * 1.0,
        estimate_percent=2.3, needed_percent=2.7, amplifier_limit=0.8,
    )  # fmt: skip
    text = u.advice()
    assert "own 1 V rms is above the stated 0.8 V rms limit" in text
    assert f"about {3.0 * (k * 1.5625 - 1):.3g} s more" in text
    assert "above the stated" not in replace(u, amplifier_limit=1.5).advice()
