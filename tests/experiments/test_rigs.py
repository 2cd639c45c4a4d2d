"""Real-rig results (docs/real-rigs.md): the findings the tables rest on, with tolerances."""

from __future__ import annotations

import argparse

import numpy as np
import pytest

import maglevid.experiments.rigs as rigs
from maglevid.exceptions import IdentificationError
from maglevid.identify.greybox import fit_equilibrium_line, fit_greybox_levitator
from maglevid.identify.twostage import fit_two_stage
from maglevid.physics.levitator import unstable_pole

PUBLISHED_POLE = unstable_pole(rigs.PUBLISHED, 0.005)  # 43.86 rad/s


def _session(shared_data, name):
    d = rigs.load_uaq(rigs._uaq_path(shared_data, name))
    yd = d.r[:, 0]
    lev = rigs.uaq_segments(d, for_identification=True).bounds()
    steps = np.r_[False, np.diff(yd) != 0]
    op = rigs.split_segments(lev, steps, pad=(0, 150), min_length=300)
    return d, lev, op


def test_twin_resembles_the_rig_at_rest():
    d = rigs.simulate_uaq_twin(np.full(1500, 0.005), rng=np.random.default_rng(3))
    y, i = d.y[300:, 0], d.y[300:, 1]
    # README: gap std 50-100 um at rest, i0 = 0.42-0.47 A, u/i 15-17 V/A
    assert 40e-6 < y.std() < 150e-6
    assert 0.42 < i.mean() < 0.48
    assert 14.0 < d.u[300:, 0].mean() / i.mean() < 17.5


def test_load_uaq_gives_reference_and_controller(shared_data):
    d = rigs.load_uaq(rigs._uaq_path(shared_data, "escalon"))
    assert d.channel_names("y") == ("gap", "i") and d.channel_names("r") == ("yd",)
    assert set(np.unique(d.r)) == {0.004, 0.005}
    assert d.loop["controller"] == "uaq-cascade"


def test_quality_row_of_a_step_session(shared_data):
    d = rigs.load_uaq(rigs._uaq_path(shared_data, "multiescalon"))
    row = rigs.uaq_quality_row("multiescalon", d)
    assert row["law_equation_error_V"] < 0.01  # the documented law, to the logging floor
    assert row["best_dt_s"] == pytest.approx(0.01)
    assert row["y_step_um"] == pytest.approx(48.9, abs=0.1)
    assert row["usable_percent"] > 80


def test_equilibrium_line_disagrees_with_the_published_inductance_law(shared_data):
    d, _, op = _session(shared_data, "multiescalon")
    y, i = d.y[:, 0], d.y[:, 1]
    line = fit_equilibrium_line([y[a:b].mean() for a, b in op], [i[a:b].mean() for a, b in op])
    # Four plateaus (4, 4.5, 5, 6 mm): a = 2.3 +- 0.4 mm against the published 5.2 mm, so
    # the pole at 5 mm is 51.9 +- 1.4 rad/s; the published 43.9 lies > 5 SE away.
    assert line["a"] == pytest.approx(2.3e-3, abs=1.2e-3)
    assert line["pole_rad_s"] - 3 * line["pole_rad_s_se"] > PUBLISHED_POLE


@pytest.mark.parametrize("name", ["escalon", "multiescalon"])
def test_greybox_with_the_equilibrium_tie_obeys_the_static_force_balance(shared_data, name):
    d, _, op = _session(shared_data, name)
    res = fit_greybox_levitator(d, segments=op, y_ref=0.005)
    p = res.parameters
    # eq. (LIN1): the reported pole is sqrt(2 g/(a + y_ref)) of the fitted a (algebra)
    assert p["pole_rad_s"] == pytest.approx(np.sqrt(2 * 9.81 / (p["a"] + 0.005)), rel=1e-9)
    assert res.confidence_intervals(0.95)["pole_rad_s"][0] > 0  # unstable, never reflected
    # eq. (Q1): with the tie, the law's equilibrium current at each operating point must
    # match the measured mean current there. Tolerance 15 mA: the measured level drifts
    # by ~10 mA within a session (coil heating; docs/real-rigs.md) and is quantised at
    # 2.2 mA; a wrong a (e.g. the published 5.2 mm) misses the 4-6 mm currents by more.
    model = np.array(res.extras["segment_model_currents"])
    measured = np.array(res.extras["segment_mean_currents"])
    assert np.max(np.abs(model - measured)) < 15e-3


def test_two_stage_on_the_multistep_session_agrees_with_published_physics(shared_data):
    d, lev, _ = _session(shared_data, "multiescalon")
    res = fit_two_stage(d, input="y:1", nb=3, nk=0, segments=lev)
    est, se = res.parameters["pole_rad_s"], res.std_errors()["pole_rad_s"]
    # 41.6 +- 2.5 rad/s: within 1 SE of the published 43.9, and 4 SE below the equilibrium
    # line's 51.9 - the disagreement docs/real-rigs.md discusses. Locked in: unstable and
    # within 3 SE of the published pole.
    assert res.confidence_intervals(0.95)["pole_rad_s"][0] > 0
    assert abs(est - PUBLISHED_POLE) < 3 * se
    assert res.fit["stage1_r2_input"] > 0.5


def test_two_stage_refuses_the_constant_reference_session(shared_data):
    d, lev, _ = _session(shared_data, "constante")
    with pytest.raises(IdentificationError, match="rank deficient"):
        fit_two_stage(d, input="y:1", nb=3, nk=0, segments=lev)


def test_maggy_controller_and_oscillation(shared_data):
    m = rigs.maggy_results(shared_data)
    for un, ch in (("u1", "s1x"), ("u2", "s1y")):
        c = m["controller"][un]
        assert c["channel"] == ch
        assert c["arx22_r2"] > 0.99999 and c["static_pd_r2"] < 0.9  # README: 88 %
        # V2 firmware (DALPHA = 0.02): the derivative filter constant is read back within
        # 20 %; the feed-through compensation within 30 % of 1.55/255.
        assert c["v2_firmware"]["beta"] == pytest.approx(0.02, rel=0.2)
        assert c["v2_firmware"]["c"] == pytest.approx(1.55 / 255, rel=0.3)
    # README: a lightly damped ~4.5 Hz closed-loop oscillation dominates.
    assert m["oscillation"]["peak_hz"]["s1x"] == pytest.approx(4.5, abs=0.3)
    assert m["oscillation"]["ar_mode_hz"] == pytest.approx(4.5, abs=0.3)
    assert m["oscillation"]["ar_mode_damping"] < 0.1
    assert m["levitating_s"][0] == pytest.approx(3.0, abs=0.3)


@pytest.mark.slow
def test_reproduce_rigs_prints_the_tables(shared_data):
    args = argparse.Namespace(data=str(shared_data), sessions="escalon", skip_maggy=True,
                              quiet=True, json=False, out="unused")  # fmt: skip
    res = rigs.run_reproduction(args)
    text = rigs.format_text(res)
    assert "UAQ levitator: data quality" in text and "escalon" in text
    est = res["poles"]["sessions"]["escalon"]["estimates"]
    assert {"pem-arx i->y", "two-stage i->y", "greybox", "levitator consensus (own gap)"} <= set(
        est
    )
