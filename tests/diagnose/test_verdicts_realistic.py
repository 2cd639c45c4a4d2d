"""Verdicts on the bearing as it really is (issue 12): operating point, model error, inconclusive.

Reference values: the settled operating point and the linearisation there come
from eq. (1) at rest under the nominal bias voltages and the logged loop
(:func:`maglevid.physics.amb.settled_operating_point`, tested against the
simulator in tests/physics/test_operating_point.py); the fault factors are the
ones planted.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from maglevid.diagnose.isolate import MeasuredOperatingPoint, isolate_fault
from maglevid.diagnose.pipeline import diagnose
from maglevid.physics.amb import AMBParameters, settled_operating_point
from maglevid.report.html import VERDICT_STYLE, _verdict_banner
from maglevid.simulate import simulate_amb_loop
from maglevid.simulate.amb import default_amb_controller, default_amb_observer

NOMINAL = AMBParameters.nominal()
DT = 1e-4


def _loop() -> dict:
    return {
        "controller": default_amb_controller(NOMINAL, DT).to_dict(),
        "observer": default_amb_observer(NOMINAL, DT).to_dict(),
    }


@pytest.mark.parametrize(
    "fault", [{"K2": 0.92}, {"K1": 0.9}, {"R2": 1.13}, {"kw1": 0.93}, {"x0": 1.1}]
)
def test_exact_settled_v_is_named_as_the_single_cause(fault):
    # A coil-2 K -8 % under the nominal bias moves both coil currents (force balance):
    # at the design point it reads as a pair ("K2 and i0"); at the settled point it is K2.
    op = settled_operating_point(NOMINAL.with_fault(**fault), NOMINAL, _loop())
    measured = MeasuredOperatingPoint(op.x, op.I1 - NOMINAL.i0, op.I2 - NOMINAL.i0, "test")
    S = np.diag((1e-12 * op.v) ** 2)  # an exact record
    res = isolate_fault(op.v, S, NOMINAL, operating_point=measured, model_error=1e-3)
    ((name, factor),) = fault.items()
    assert res.explained and res.best.parameters == (name,)
    assert res.best.factors[0] == pytest.approx(factor, rel=1e-6)


def test_model_error_lets_an_exact_but_slightly_nonlinear_v_fit():
    # v 0.2 % off the linearisation with standard errors of 1e-13: without a model
    # error "nothing changed" is rejected at chi2 ~ 1e19; with 0.5 % it fits.
    v = NOMINAL.v() * (1 + 2e-3 * np.sin(np.arange(9)))
    S = np.diag((1e-13 * v) ** 2)
    assert not isolate_fault(v, S, NOMINAL, try_pairs=False).explained
    res = isolate_fault(v, S, NOMINAL, model_error=5e-3)
    assert res.explained and res.best.parameters == ()


@pytest.mark.parametrize(("noise", "force"), [((0.0, 0.0, 0.0), 0.0), ((5e-9, 1e-5, 1e-5), None)])
def test_healthy_nonlinear_bearing_is_no_change(noise, force):
    # On main the noise-free healthy bearing (every parameter within 0.03 %) got
    # "Unexplained change": standard errors of 1e-13 and no model error. Second case:
    # the realistic bearing (sensor noise, the simulator's default force disturbance).
    rec = simulate_amb_loop(
        NOMINAL, nominal=NOMINAL, plant_model="nonlinear", noise_std=noise, force_std=force,
        n_samples=30_000, rng=3,
    )  # fmt: skip
    # The noise-free case is diagnosed with `physical`: `ml` estimates the sensor noise
    # levels, so a noise-free record makes its Fisher matrix singular (issue 13).
    d = diagnose(rec, baseline="nominal", method="ml" if force is None else "physical")
    assert d.verdict_code == "no_change", d.verdict
    assert d.isolation.model_error >= 1e-3


def test_noise_free_linear_record_is_named_with_the_model_error_in_the_test():
    rec = simulate_amb_loop(
        NOMINAL.with_fault(R2=1.13), nominal=NOMINAL, plant_model="linear", noise_std=(0, 0, 0),
        rng=3,
    )  # fmt: skip
    # (Pinned to `physical`, diagnose's default before issue 13: this tests the isolation
    # and its model error on a noise-free record, and `ml` estimates the sensor noise
    # levels, so on a noise-free record its Fisher matrix is singular: "cannot diagnose".)
    d = diagnose(rec, baseline="nominal", method="physical")
    assert d.verdict_code == "fault" and d.isolation.best.parameters == ("R2",)
    assert d.isolation.best.factors[0] == pytest.approx(1.13, rel=2e-3)


def _readme_record(seed):
    """`maglevid simulate amb --fault R1=1.2` at main's CLI defaults before the realistic
    bearing: linear plant, noise 0.1 um / 0.1 mA, 2 s."""
    return simulate_amb_loop(
        NOMINAL.with_fault(R1=1.2), nominal=NOMINAL, plant_model="linear",
        noise_std=(1e-7, 1e-4, 1e-4), n_samples=20_000, rng=seed,
    )  # fmt: skip


@pytest.mark.parametrize("seed", [1, 2, 3, 4, 5])
def test_readme_walkthrough_default_noise_is_inconclusive(seed):
    # `maglevid simulate amb --fault R1=1.2` at main's CLI defaults (linear plant, noise
    # 0.1 um / 0.1 mA, 2 s; pinned here, the realistic defaults may change them):
    # R1's interval is about ±27 % against a ±5 % tolerance. On main this was a green
    # "No significant change" in 4 of 5 seeds.
    rec = _readme_record(seed)
    # `physical` pinned (diagnose's default before issue 13): the inconclusive verdict
    # needs a record the method cannot decide. The default `ml` decides this record
    # (R1 +20 % named: test_default_ml_names_r1_on_the_readme_record).
    d = diagnose(rec, baseline="nominal", method="physical")
    assert d.verdict_code == "inconclusive", d.verdict
    # The verdict names a record length (since the straddling rule its headline is the
    # cause furthest from deciding, seed 3 Ls1 -3.8 % ± 4.6 %: "21.1 min in all at
    # 0.242 V rms", the same excitation alone never deciding it with its model error).
    # Since h13diag (model error 2 e^2, floored at 0.1 %) the headline may be a cause
    # whose estimate sits closer to its tolerance than the floor lets any record
    # decide (seed 1: R2 +5.1 % against 5 %); the advice then says so and names the
    # tolerance that would be decided. R1's own advice names a record.
    assert any(
        k in d.verdict
        for k in ("s more of the same excitation", " in all at ", "no record resolves it")
    )
    r1 = next(u for u in d.resolution if u["parameter"] == "R1")
    assert "s more of the same excitation" in r1["advice"] or " in all at " in r1["advice"]
    # Where R1's interval straddles the tolerance the half-width that decides it is its
    # estimate's distance from 5 % (seed 3: +32 % ± 28 % needs ±27 %); where it lies
    # wholly beyond while "nothing changed" is kept (seed 5: +45 %), the tolerance.
    c, w = abs(r1["estimate_percent"]), r1["half_width_percent"]
    assert w > 5 and r1["needed_percent"] == pytest.approx(abs(c - 5) if c - w <= 5 else 5.0)
    out = json.loads(json.dumps(d.to_dict()))
    assert out["verdict_code"] == "inconclusive" and out["resolution"][0]["advice"]
    assert "to resolve the tolerance" in d.summary()
    # The report's banner (the full report renders plots: ~10 s, so only its banner here).
    html = _verdict_banner(d)
    assert 'data-verdict-code="inconclusive"' in html and "verdict-resolution" in html
    assert VERDICT_STYLE["inconclusive"][0] in html and "#15803d" not in html  # never green


def test_default_ml_names_r1_on_the_readme_record():
    # The record of the walkthrough above (seed 1) with diagnose's default, `ml`: the
    # planted R1 +20 % is named, within 4 of its stated standard errors.
    rec = _readme_record(1)
    d = diagnose(rec, baseline="nominal")
    assert d.method == "ml" and d.verdict_code == "fault", d.verdict
    assert d.isolation.best.parameters == ("R1",)
    assert abs(d.isolation.best.factors[0] - 1.2) < 4 * d.isolation.best.factor_std_errors[0]


def test_resolver_length_advice_holds_when_followed():
    # The advice scales the noise covariance by 1/N: a record k times longer should
    # bring R1's interval to its tolerance. Tolerance 20 % on R1 makes k small here.
    tol = {"R1": 0.2, "R2": 0.2, "m": 0.2}
    lin = {"nominal": NOMINAL, "plant_model": "linear", "noise_std": (1e-7, 1e-4, 1e-4)}
    short = simulate_amb_loop(NOMINAL, n_samples=20_000, rng=8, **lin)
    # `physical` pinned: the advice is for a record its method cannot resolve (`ml`,
    # the default since issue 13, resolves this one outright).
    d = diagnose(short, baseline="nominal", tolerances=tol, method="physical")
    r1 = next(u for u in d.resolution if u["parameter"] == "R1")
    k = r1["length_factor"]
    assert 1.5 < k < 6
    longer = simulate_amb_loop(NOMINAL, n_samples=round(20_000 * k), rng=9, **lin)
    d2 = diagnose(longer, baseline="nominal", tolerances=tol, method="physical")
    h = next(h for h in d2.isolation.singles if h.parameters == ("R1",))
    # The noise part scales as 1/N: 1.96 se within 15 % of the half-width that was
    # asked for (since the straddling rule: the estimate's distance from the 20 %
    # tolerance, not the tolerance).
    need = r1["needed_percent"] / 100
    assert 1.96 * h.factor_std_errors[0] == pytest.approx(need, rel=0.15)


def test_one_number_per_fault_is_labelled():
    rec = simulate_amb_loop(
        NOMINAL.with_fault(R1=1.2), nominal=NOMINAL, plant_model="nonlinear",
        noise_std=(5e-9, 1e-5, 1e-5), rng=2, n_samples=30_000,
    )  # fmt: skip
    d = diagnose(rec, baseline="nominal")
    assert d.verdict_code == "fault"
    assert "fit with only R1 changed" in d.verdict
    assert any(
        r.startswith("free estimate (every parameter fitted, m and i0 at the baseline's): R1")
        for r in d.reasons
    )
    assert "free estimates" in d.summary()


@pytest.mark.parametrize(
    ("fault", "exc"), [({"R2": 1.13}, 1.0), ({"K1": 0.9}, 0.05), ({"kw2": 0.93}, 1.0)]
)
def test_exact_nonlinear_records_are_isolated_to_the_single_cause(fault, exc):
    # Noise-free nonlinear records under the nominal bias (the operating point moved).
    # On main: R2 +13 % and K1 -10 % gave "Unexplained change" (chi2 ~ 1e7).
    # (K1 at the default 1 V excitation loses the rotor: 0.05 V keeps it levitated.)
    rec = simulate_amb_loop(
        NOMINAL.with_fault(**fault), nominal=NOMINAL, plant_model="nonlinear",
        noise_std=(0, 0, 0), force_std=0.0, excitation_std=exc, rng=3,
    )  # fmt: skip
    # (Pinned to `physical`, diagnose's default before issue 13: this tests the isolation
    # and its model error on a noise-free record, and `ml` estimates the sensor noise
    # levels, so on a noise-free record its Fisher matrix is singular: "cannot diagnose".)
    d = diagnose(rec, baseline="nominal", method="physical")
    ((name, factor),) = fault.items()
    assert d.verdict_code == "fault", d.verdict
    assert d.isolation.best.parameters == (name,)
    assert d.isolation.best.factors[0] == pytest.approx(factor, rel=5e-3)
    # The free estimates, referred to the design operating point: a fault moves the
    # point the bearing settles at under the nominal bias, and eq. (4) inverted at the
    # design bias read that move as changes of x0, K and Ls. Found from outside (issue
    # 16, fourteenth session): K1 x0.9 read K1 -1.6 %, Ls1 -9.7 %, Ls2 +10.2 %, x0 +6.5 %
    # here (-1.8 / +11 % with noise). Each v_i is now divided by what the measured point
    # does to the baseline's: the faulted parameter within 0.6 % of its planted change,
    # every other within 1.2 % (first order in the fault: measured 0.5 / 1.1 %).
    truth = NOMINAL.with_fault(**fault)
    for c in d.changes:
        planted = 100 * (getattr(truth, c.name) / getattr(NOMINAL, c.name) - 1)
        assert c.change_percent == pytest.approx(planted, abs=0.6 if planted else 1.2), c.name
    assert any("referred to the design operating point" in n for n in d.notes)


def test_a_mass_change_is_said_to_scale_every_free_estimate():
    # m x1.2: the free estimates hold m at the baseline's, so all twelve coil and
    # amplifier parameters read ~-16.7 % "changed"; the reasons now say why.
    rec = simulate_amb_loop(
        NOMINAL.with_fault(m=1.2), nominal=NOMINAL, plant_model="nonlinear",
        noise_std=(0, 0, 0), force_std=0.0, rng=3,
    )  # fmt: skip
    d = diagnose(rec, baseline="nominal", method="physical")
    assert d.isolation.best.parameters == ("m",)
    assert "the mass, not a change of each" in d.reasons[1]
    assert "reads about -16.7 %" in d.reasons[1]


def test_a_sensor_gain_in_the_verdict_says_what_it_does_to_the_free_estimates():
    # K1 x0.9 with the displacement sensor reading +5 %: the verdict named both, but the
    # free estimates (exact sensors assumed) listed 12 parameters "changed" and K1 at
    # +5.1 % against the verdict's -9.9 % (found from outside, seventeenth session). The
    # reasons now give the free estimates the verdict predicts; they match the table
    # within its own intervals. Reference: the planted K1 x0.9, gx
    # x1.05 read through T = diag(gx, gx, 1, 1) and eq. (4) inverted (analytic, isolate's
    # v_with_sensor_gains and physics.amb.parameters_from_v): K1 +4.19 %, K2 +15.76 %.
    rec = simulate_amb_loop(
        NOMINAL.with_fault(K1=0.9), nominal=NOMINAL, plant_model="nonlinear",
        noise_std=(0, 0, 0), force_std=0.0, rng=3, sensor_gains={"gx": 1.05},
    )  # fmt: skip
    d = diagnose(rec, baseline="nominal", method="physical")
    assert set(d.isolation.best.parameters) == {"K1", "gx"}, d.verdict
    (note,) = [r for r in d.reasons if r.startswith("the free estimates read v1..v9")]
    predicted = {
        k: float(v) for k, v in (w.rsplit(" ", 2)[:2] for w in
        note.split("predicts them at ")[1].split(":")[0].split(", "))
    }  # fmt: skip
    ci = {c.name: [100 * b / c.baseline for b in c.change_ci] for c in d.changes}
    assert predicted["K1"] == pytest.approx(4.19, abs=0.3)
    assert predicted["K2"] == pytest.approx(15.76, abs=0.3)
    for k, pct in predicted.items():  # each within the table's own (joint 95 %) interval
        assert ci[k][0] <= pct <= ci[k][1], (k, pct, ci[k])
    exact = simulate_amb_loop(
        NOMINAL.with_fault(K1=0.9), nominal=NOMINAL, plant_model="nonlinear",
        noise_std=(0, 0, 0), force_std=0.0, rng=3,
    )  # fmt: skip
    d = diagnose(exact, baseline="nominal", method="physical")  # exact sensors: no note
    assert not any(r.startswith("the free estimates read v1..v9") for r in d.reasons)


@pytest.mark.parametrize("factor", [2.0, 0.5])
def test_a_wrong_sample_time_is_named_not_diagnosed_as_a_fault(factor):
    # A user's record whose Ts is twice the loop's (no controller stated, so the sample-
    # time check has nothing to compare with) read "Unexplained change" with R, kw -87 %
    # and "data quality: all checks passed" (found from outside, seventeenth session).
    # Reference: a time axis scaled by c divides every continuous rate by c and multiplies
    # the velocity state by c: v1..v3 x c^-2, v5, v7..v9 x c^-1, v4, v6 unchanged.
    rec = simulate_amb_loop(
        NOMINAL, nominal=NOMINAL, plant_model="nonlinear", rng=11, n_samples=20_000
    )
    user = rec.replace(dt=rec.dt * factor, loop={"operating_point": dict(
        rec.loop["operating_point"])})  # fmt: skip
    d = diagnose(user, baseline=NOMINAL)
    assert d.verdict_code == "cannot_diagnose", d.verdict
    assert f"time axis scaled by {factor:.3g}" in d.verdict and "check Ts" in d.verdict
    assert diagnose(rec.replace(loop=user.loop), baseline=NOMINAL).verdict_code == "no_change"


def test_an_unexplained_change_gives_no_tolerance_advice_on_rejected_causes():
    # Three faults at once: no cause or pair fits, "Unexplained change". Its "to
    # resolve the tolerance" list named R2 +5.1 % and gi2 -5.1 %, neither changed, from
    # single-cause fits the verdict rejects (found from outside, issue 16, fourteenth
    # session): read as leads. The free estimates carry the evidence instead.
    rec = simulate_amb_loop(
        NOMINAL.with_fault(R1=1.15, kw2=0.88, Ls1=1.15), nominal=NOMINAL,
        plant_model="nonlinear", rng=7151, n_samples=30_000,
    )  # fmt: skip
    d = diagnose(rec, baseline="nominal")
    assert d.verdict_code == "unexplained_change", d.verdict
    assert d.resolution == ()
    changed = {c.name for c in d.changes if c.status == "changed"}
    assert {"R1", "Ls1", "kw2"} <= changed
