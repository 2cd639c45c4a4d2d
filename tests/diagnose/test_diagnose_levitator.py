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
from maglevid.diagnose.levitator import LAW_INDEPENDENT
from maglevid.diagnose.pipeline import diagnose
from maglevid.exceptions import DataError
from maglevid.experiments.rigs import PUBLISHED, simulate_pd_dither_levitator
from maglevid.identify.greybox import fit_equilibrium_line
from maglevid.physics.levitator import unstable_pole

UAQ = "maglev-uaq-levitador"


def _session(shared_data, name):
    return next((shared_data / UAQ).glob(f"dataset_{name}_*.txt"))


@pytest.mark.slow  # ~45 s: the levitator consensus on a real session
def test_multistep_session_pole_agrees_with_its_own_equilibrium_line(shared_data):
    d = diagnose(_session(shared_data, "multiescalon"), mapping="uaq-levitador")
    assert d.method == "levitator" and "plant kind levitator" in d.method_reason
    res = d.identification
    lo, hi = res.extras["consensus"]["ci95"]
    y_ref = res.options["y_ref"]
    # Independent reference from the same record: the equilibrium currents at the four
    # plateaus (static data only, eq. (Q1)) give the pole at y_ref with its standard
    # error (docs/real-rigs.md: 51.9 +- 1.4 rad/s at 5 mm, a = 2.3 mm, against the
    # published a = 5.2 mm). The grey box (statics + dynamics, the better of two starts)
    # must agree with it within 3 of its standard errors, and its interval must not
    # exceed +-15 % (issue 14).
    line = fit_equilibrium_line(
        res.extras["segment_gaps"], res.extras["segment_mean_currents"], y_ref=y_ref
    )
    p = res.parameters["pole_rad_s"]
    assert abs(p - line["pole_rad_s"]) < 3 * line["pole_rad_s_se"]
    assert hi - lo < 0.3 * p
    pole = next(c for c in d.changes if c.name == "pole_rad_s")
    assert pole.baseline == pytest.approx(unstable_pole(PUBLISHED, y_ref), rel=1e-9)
    assert "published physics" in d.baseline["source"]


def test_healthy_session_is_compared_on_law_independent_quantities_only(shared_data):
    # Before: "Changed: k +18.6 %" on escalon with its pole within 1 % - k (and a) belong
    # to a force-law parameterisation (a absorbs a gap-sensor offset, k trades with a at
    # one gap) and must not decide the verdict.
    d = diagnose(_session(shared_data, "escalon"), mapping="uaq-levitador")
    names = {c.name for c in d.changes}
    assert "pole_rad_s" in names and names <= set(LAW_INDEPENDENT)
    # Since the levitator's fault isolation (issue 14) the verdict may name k or a as a
    # *cause* fitted to those law-independent observations (the pole and the segments'
    # equilibrium currents), never as a free estimate compared on its own: the verdict
    # comes from the isolation, and it says what it cannot tell apart.
    assert d.isolation is not None and d.verdict_code in ("fault", "inconclusive")
    assert d.isolation.best.parameters[0] == "gap_offset"


def test_a_dither_only_rig_log_is_diagnosed_without_a_baseline():
    # PD loop + current amplifier, white dither, no r column, no published physics
    log = simulate_pd_dither_levitator(6000, rng=np.random.default_rng(5))
    d = diagnose(log)
    truth = log.metadata["truth_pole_rad_s"]  # sqrt(2 g/(a + y0)) at the mean gap
    lo, hi = d.identification.extras["consensus"]["ci95"]
    assert lo < truth < hi
    # compared with nothing: identified, never a green "no change" (twenty-eighth session)
    assert d.verdict_code == "cannot_diagnose" and d.baseline["source"] == "none"
    assert d.verdict == "Cannot diagnose: no baseline (identified, not compared)"
    assert "nothing to compare with" in d.reasons[0]


def test_a_levitator_refuses_a_baseline_of_values():
    # An AMB baseline file given for a levitator log was ignored without a word and the
    # published physics used instead (found from outside, issue 16, thirteenth session).
    log = simulate_pd_dither_levitator(3000, rng=np.random.default_rng(5))
    with pytest.raises(DataError, match="a baseline of parameter values is not supported"):
        diagnose(log, baseline={"m": 1.8, "R1": 17.5})


def test_too_little_levitation_cannot_be_diagnosed():
    # 6 s of levitation < MIN_LEVITATING_SECONDS = 10 s
    log = simulate_pd_dither_levitator(3000, rng=np.random.default_rng(5))
    d = diagnose(log)
    assert d.verdict_code == "cannot_diagnose"
    assert "too little usable levitation" in d.verdict


@pytest.mark.slow  # ~90 s: the levitator consensus on a real session, identify then diagnose
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


def test_history_pole_is_carried_to_this_records_gap(shared_data, tmp_path):
    # UAQ 'multiescalon' (4.85 mm) against the history's 'escalon' (4.25 mm): its pole
    # was compared with escalon's 52.88 rad/s as identified at escalon's own gap ("-0.1
    # %, unchanged"; found from outside, issue 16, fourteenth session). Reference: the
    # baseline's own law (the stored a, k, k0, R, ku) at this record's gap, eq. (Q1):
    # 50.76 rad/s, +4.1 %.
    from maglevid.diagnose.history import open_history
    from maglevid.diagnose.levitator import levitator_parameters_of

    store = open_history(tmp_path / "h.sqlite")
    kw = {"mapping": "uaq-levitador", "baseline": "history", "machine": "UAQ",
          "history": store, "method_options": {"disturbance": ["white"]}}  # fmt: skip
    diagnose(_session(shared_data, "escalon"), **kw)
    law = levitator_parameters_of(store.latest_estimates("UAQ"), PUBLISHED.m)
    d = diagnose(_session(shared_data, "multiescalon"), **kw)
    y_ref = d.identification.options["y_ref"]
    pole = next(c for c in d.changes if c.name == "pole_rad_s")
    assert pole.baseline == pytest.approx(unstable_pole(law, y_ref), rel=1e-9)
    assert abs(pole.baseline / 52.88 - 1) > 0.03  # not escalon's pole at its own gap
    assert any("carried to this record's gap" in n for n in d.notes)


def test_no_pole_keeps_the_identifications_reason_and_remedy():
    # `diagnose datos_levitador.txt` (noise only: no pole claimed) said "identification
    # gave no pole: no pole identified" twice, dropping why and what would resolve it,
    # which `identify` gives (found from outside, issue 16, fourteenth session; the real
    # record takes ~2 min, so the stage is fed the identification's result directly).
    from maglevid.data import ClosedLoopData
    from maglevid.identify.result import IdentificationResult
    from maglevid.plants.base import DiagnosisRun
    from maglevid.plants.levitator import LevitatorStages

    why = ("inconclusive: no excitation - only noise drives the loop ...; no pole claimed. "
           "What would resolve it: a reference step or a dither in the command")  # fmt: skip
    res = IdentificationResult(method="levitator", model=None,
                               parameters={"pole_rad_s": float("nan")},
                               options={"y_ref": 0.005}, notes=(why,))  # fmt: skip
    data = ClosedLoopData(y=np.zeros((10, 2)), u=np.zeros((10, 1)), dt=0.01)
    run = DiagnosisRun(data=data, method="levitator", common={}, notes=[], baseline=None,
                       tolerances=0.05, level=0.95, alpha=0.05, result=res, base={})  # fmt: skip
    d = LevitatorStages().compare(run)
    assert d.verdict_code == "cannot_diagnose"
    assert "What would resolve it: a reference step" in d.verdict


def test_a_levitator_log_in_other_units_or_order_is_refused_before_any_fit(shared_data):
    # UAQ chirp with the gap in mm learned a range of "0.00-14573.02 mm", with the gap and
    # current swapped the same, and with the current in mA ran 70 s into "no candidate
    # model gives an identifiable pole" (found from outside, seventeenth session).
    from maglevid.diagnose.levitator import levitator_checks
    from maglevid.io import read_recording

    d = read_recording(_session(shared_data, "chirp"), mapping="uaq-levitador")
    (ok,), segs = levitator_checks(d)
    assert ok.passed and segs
    y = np.array(d.y_control, copy=True)
    for edit, words in [
        (lambda y: y * [1e3, 1.0], "the gap is probably logged in mm"),
        (lambda y: y[:, ::-1], "the gap and the current are probably in each other's columns"),
        (lambda y: y * [1.0, 1e3], "it is probably logged in mA"),
    ]:
        (q,), segs = levitator_checks(d.replace(y=edit(y)))
        assert q.name == "units" and not q.passed and words in q.message and segs == []
    told = diagnose(d.replace(y=y * [1.0, 1e3]), baseline="nominal")
    assert told.verdict_code == "cannot_diagnose" and "probably logged in mA" in told.verdict


def test_a_lost_ball_with_the_driver_at_its_top_is_said_so():
    # Driver gain -30 %: the ball falls at once and rests on the stop; the refusal read
    # only "above-range 19.9 s" (found from outside, seventeenth session).
    from dataclasses import replace

    from maglevid.diagnose.levitator import levitator_checks
    from maglevid.simulate.levitator import UAQ_TWIN, simulate_levitator

    d = simulate_levitator(replace(UAQ_TWIN, ku=0.7 * UAQ_TWIN.ku), rng=1)
    (q,), segs = levitator_checks(d)
    assert not q.passed and segs == []
    assert "outside the range for 100 % of the record (lost" in q.message
    assert "the driver could not hold the body" in q.message


def test_a_ball_lost_for_part_of_the_record_is_a_warning_and_the_refusal_says_so():
    # Driver gain -15 %, seed 29: the ball falls at the step to the second gap (47 % of
    # the record on the stop, the command at its top all that time); 10 s still levitate,
    # and the fits then read only "no candidate model gives an identifiable pole" (found
    # from outside, eighteenth session). The healthy twin, seed 36, loses its ball at the
    # same step: the refusal for too little levitation now says so (it needed 50 %).
    from dataclasses import replace

    from maglevid.diagnose.levitator import levitator_checks
    from maglevid.simulate.levitator import UAQ_TWIN, simulate_levitator

    d = simulate_levitator(replace(UAQ_TWIN, ku=0.85 * UAQ_TWIN.ku), rng=29)
    (ok, lost), segs = levitator_checks(d)
    assert ok.name == "levitation" and ok.passed and segs
    assert lost.name == "lost" and not lost.passed and not lost.blocking
    assert 0.4 < lost.value < 0.55 and "for 100 % of that time" in lost.message
    assert "the driver could not hold the body" in lost.message
    (q,), segs = levitator_checks(simulate_levitator(UAQ_TWIN, rng=36))
    assert not q.passed and segs and "too little usable levitation" in q.message
    assert "the driver could not hold the body" in q.message
    # a healthy record keeps one check
    (q,), _ = levitator_checks(simulate_levitator(UAQ_TWIN, rng=3))
    assert q.passed and "could not hold" not in q.message


def test_the_coil_circuit_comes_from_a_fit_that_determines_it():
    # Twin, driver gain -15 %, seed 518: the chosen model (command delay + AR(1)) left its
    # coil equation to noise and read R/L 80.8 +- 0.07 against 57.7: "Changed: explained
    # by coil circuit resistance R +40.0 %", the wrong culprit (found from outside,
    # eighteenth session). The coil circuit now comes from the best-ranked sound candidate.
    from dataclasses import replace

    from maglevid.simulate.levitator import UAQ_TWIN, simulate_levitator

    # Which candidate the consensus chooses on this record turns on rounding (on one
    # machine of the twenty-fifth session the command delay without AR(1), whose coil is
    # sound; verdict "ku -14.2 %"): the end-to-end claim is that the coil comes from a
    # sound fit, R/L and ku/L within 5 % and no resistance fault; the fallback itself is
    # tested on fixed fits
    # (tests/identify/test_levitator_consensus.py).
    truth = replace(UAQ_TWIN, ku=0.85 * UAQ_TWIN.ku)
    d = diagnose(simulate_levitator(truth, rng=518))
    coil = d.identification.extras["coil_circuit"]
    assert coil["chosen"] == (
        coil["model"] == d.identification.extras["consensus"]["chosen_model"]
    )
    assert coil["voltage_noise_share"] < 2.1
    assert d.verdict_code != "fault" or "resistance" not in d.verdict
    (line,) = [r for r in d.reasons if r.startswith("coil circuit R/L")]
    rl, kl = (float(line.split(" = ")[k].split()[0]) for k in (1, 2))
    y = d.identification.options["y_ref"]
    assert abs(rl / (truth.R / truth.inductance(y)) - 1) < 0.05
    assert abs(kl / (truth.ku / truth.inductance(y)) - 1) < 0.05
    assert coil["chosen"] or any(
        n.startswith("coil circuit (R, ku, k0 and the ratios") for n in d.notes
    )
