"""The grey box's coloured force disturbance (``disturbance="ar1"``) and the levitator
consensus on a record with no excitation (issue 14).

References: the AR(1) model nests the white one (``c = 0``: the same spectrum and the
same Kalman predictor, an algebraic identity); under feedback a wrong noise model biases
a prediction-error fit (Ljung 1999, sec. 13.4) - the simulated rig's truth is known
(``sqrt(2 g/(a + y0))``, published UAQ physics). Monte Carlo in
benchmarks/bench_levitator_coverage.py, numbers in docs/real-rigs.md.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

import maglevid.identify.levitator as lev
from maglevid.experiments.rigs import simulate_pd_dither_levitator
from maglevid.identify.greybox import (
    _GreyboxModel,
    _one_step,
    _parameter_set,
    fit_greybox_levitator,
)
from maglevid.identify.result import IdentificationResult
from maglevid.physics.levitator import LevitatorParameters

Z95 = 1.959963984540054


def _strong_log(run: int = 0, n: int = 3000):
    # the bench's 'strong' case, its seed 14 (NOISE_CASES["strong"])
    rng = np.random.default_rng(np.random.SeedSequence([14, run]))
    return simulate_pd_dither_levitator(n, rng=rng, force_colour=0.9)


def _model(log, disturbance):
    opts = {
        "model": "electromechanical", "force_law": "inverse-square", "gap": "y:0",
        "current": "y:1", "command": "u:0", "m": 0.018, "g": 9.81,
        "use_equilibrium": True, "flux_lag": False, "free_gain": False,
        "current_hold": "foh", "burn_in": 20, "command_delay": False,
        "sensor_gain": False, "covariance": "sandwich", "disturbance": disturbance,
    }  # fmt: skip
    segs = [(0, log.n_samples)]
    p0 = LevitatorParameters(m=0.018, g=9.81, R=5.05, ku=0.515)
    names, start, bounds = _parameter_set(log, segs, opts, p0)
    opts["names"] = names
    return _GreyboxModel(log, segs, opts), start, bounds


def test_ar1_with_zero_coefficient_is_the_white_predictor():
    log = _strong_log(n=400)
    white, th_w, _ = _model(log, "white")
    ar1, th_c, (lo, hi) = _model(log, "ar1")
    assert th_c.size == th_w.size + 1 and (lo[-1], hi[-1]) == (0.0, 0.999)
    th_c = np.r_[th_w, 0.0]
    inn_w, Y, U = white.predictor(th_w, 0)
    inn_c, _, _ = ar1.predictor(th_c, 0)
    assert inn_c.A.shape[0] == inn_w.A.shape[0] + 1  # one more state, the plant unchanged
    np.testing.assert_allclose(inn_c.A[:-1, :-1], inn_w.A, rtol=0, atol=0)
    pw, pc = _one_step(inn_w, Y, U), _one_step(inn_c, Y, U)
    np.testing.assert_allclose(pc, pw, rtol=0, atol=1e-9 * np.max(np.abs(pw)))


def test_coloured_force_bias_goes_with_the_ar1_noise_model():
    log = _strong_log()
    truth = log.metadata["truth_pole_rad_s"]
    y_ref = float(log.y[:, 0].mean())
    out = {}
    for w in ("white", "ar1"):
        res = fit_greybox_levitator(log, model="electromechanical", y_ref=y_ref, disturbance=w)
        j = list(res.parameters).index("pole_rad_s")
        out[w] = (res.parameters["pole_rad_s"], np.sqrt(res.covariance[j, j]), res)
    # white noise model: +34 % on average over the bench's runs; here 58.6 +- 1.7 rad/s
    # against 43.8
    p, se, _ = out["white"]
    assert p - truth > 5 * se
    p, se, res = out["ar1"]
    assert abs(p - truth) <= Z95 * se
    assert res.extras["noise_parameters"]["acc_colour"] == pytest.approx(0.9, abs=0.06)
    assert res.options["disturbance"] == "ar1"


def _fake(pole, lo, hi, identified=True):
    cov = np.diag([1.0, ((hi - lo) / 2 / Z95) ** 2, 1e-6])
    return IdentificationResult(
        method="greybox-levitator", model=None,
        parameters={"a": 1.0, "pole_rad_s": pole if identified else float("nan"), "pole_z": 1.1},
        covariance=cov, notes=("fit",),
        extras={"pole_identified": identified},
    )  # fmt: skip


def _rows(scores):
    return [
        {"candidate": {"model": "electromechanical", "flux_lag": lag, "command_delay": False,
                       "disturbance": w},
         "validation": s, "fold_poles": [(p, p - 1, p + 1)]}
        for (w, lag, s, p) in scores
    ]  # fmt: skip


def _consensus(monkeypatch, rows, fits, noise_only):
    by_label = {lev._label(r["candidate"]): f for r, f in zip(rows, fits)}
    monkeypatch.setattr(lev, "_fit", lambda d, s, cand, common: by_label[lev._label(cand)])
    data = SimpleNamespace(dt=0.002)  # _consensus reads only the sample time
    # workers=1: the patched _fit lives in this process only
    return lev._consensus(data, [(0, 10)], rows, {}, 5, [], 1, noise_only, workers=1)


def test_noise_only_hull_covers_every_noise_model(monkeypatch):
    # the white model validates 10 points better: with an excitation it alone is
    # supported; with none, each noise model is ranked on its own and the hull holds both
    rows = _rows([("white", False, -100.0, 59.0), ("ar1", False, -110.0, 51.0)])
    fits = [_fake(59.0, 58.0, 60.0), _fake(51.0, 49.0, 53.0)]
    lo, hi = _consensus(monkeypatch, rows, fits, False).extras["consensus"]["ci95"]
    assert (lo, hi) == (58.0, 60.0)
    res = _consensus(monkeypatch, rows, fits, True)
    assert res.extras["consensus"]["ci95"] == [49.0, 60.0]
    assert res.parameters["pole_rad_s"] == 59.0  # the best-validated point


def test_noise_only_record_whose_coloured_model_identifies_nothing_is_inconclusive(monkeypatch):
    rows = _rows([("white", False, -100.0, 59.0), ("ar1", False, -110.0, 51.0)])
    fits = [_fake(59.0, 58.0, 60.0), _fake(51.0, 49.0, 53.0, identified=False)]
    res = _consensus(monkeypatch, rows, fits, True)
    c = res.extras["consensus"]
    assert np.isnan(c["pole_rad_s"]) and np.isnan(res.parameters["pole_rad_s"])
    assert c["inconclusive"].startswith("inconclusive: no excitation")
    assert "AR(1) force-disturbance" in c["inconclusive"]
    assert "reference step or a dither" in c["inconclusive"]
    assert c["noise_only_estimate"] == 59.0 and res.extras["pole_identified"] is False
    assert res.notes[0] == c["inconclusive"]
    # the same fits with an excitation: the white model answers
    assert _consensus(monkeypatch, rows, fits, False).parameters["pole_rad_s"] == 59.0


def _twin_fit(seed, **kw):
    from benchmarks.bench_levitator_isolation import faulty_twin

    from maglevid.experiments.rigs import UAQ_TWIN
    from maglevid.identify.levitator import find_levitator_segments

    d = faulty_twin(UAQ_TWIN, 0.0, seed=seed)
    _, segs, _ = find_levitator_segments(d)
    return fit_greybox_levitator(d, model="electromechanical", segments=segs, **kw)


def test_collapsed_noise_model_claims_no_pole(monkeypatch):
    # A healthy UAQ twin record (benchmarks' faulty_twin, seed 12) whose flux-lag + command-
    # delay fit, with the noise ratios unbounded, takes the likelihood's degenerate branch:
    # current measurement noise -> 0, coil-equation disturbance -> inf. It claimed pole
    # 43.3330 +- 0.0001 rad/s (truth 44.2 at 4.74 mm), R 12.67 +- 3e-5 ohm (truth 5.05); 17 %
    # of such fits over seeds 1-73 (found from outside, issue 16, fifteenth session).
    # Reference for the floor: sound fits have sigma_i/sigma_y at 0.12-0.19 of the record's
    # std(di)/std(dy), collapsed ones 1e-16 - 2e-4. Since the twenty-seventh session the
    # ratios are bounded to e^+-6.9 of their starts (greybox.NOISE_RATIO_RANGE, docs/real-
    # rigs.md item 16), which stops this fit short of the branch; the flag stays the guard
    # (the bounds still reach 2e-4 - 1e-3 of these records' ratio), tested with them lifted.
    import maglevid.identify.greybox as gb

    kw = {"flux_lag": True, "command_delay": True}
    monkeypatch.setattr(gb, "NOISE_RATIO_RANGE", np.inf)
    res = _twin_fit(12, **kw)
    assert res.extras["pole_identified"] is False and np.isnan(res.parameters["pole_rad_s"])
    assert any("noise model collapsed" in n for n in res.notes)
    monkeypatch.undo()
    bounded = _twin_fit(12, **kw)  # no collapse, and no pole claimed on a tight interval
    assert not any("collapsed" in n for n in bounded.notes)
    assert bounded.extras["pole_identified"] is False, bounded.notes
    sound = _twin_fit(7, **kw)  # another seed: sigma_i/sigma_y at 0.14 of the record's
    assert sound.extras["pole_identified"], sound.notes
    assert not any("collapsed" in n for n in sound.notes)


def test_a_coil_equation_left_to_noise_is_measured_and_said(monkeypatch):
    # UAQ twin, driver gain -15 %, seed 518 (found from outside, eighteenth session): with
    # the noise ratios unbounded the command-delay + AR(1) fit blows its voltage disturbance
    # up (2.5e5 x what the record's changes of command and gap allow): the pole stands, but
    # R/L reads 82 against 57.7 and the diagnosis named "R +40 %". A sound fit of the same
    # record stays below 2.1 (76 fits of twin and UAQ records: sound 1e-67 - 2.0, degenerate
    # 73 - 1e6). Bounded (greybox.NOISE_RATIO_RANGE, twenty-seventh session) the same fit
    # converges to a sound point; the flag stays the guard (the bound still reaches
    # ~900 x on this record), tested with the bounds lifted.
    from dataclasses import replace

    import maglevid.identify.greybox as gb
    from maglevid.identify.greybox import VOLTAGE_NOISE_CEILING, voltage_noise_share
    from maglevid.identify.levitator import find_levitator_segments
    from maglevid.simulate.levitator import UAQ_TWIN, simulate_levitator

    truth = replace(UAQ_TWIN, ku=0.85 * UAQ_TWIN.ku)
    d = simulate_levitator(truth, rng=518)
    _, segs, _ = find_levitator_segments(d)

    def fit(delay, noise):
        r = fit_greybox_levitator(d, segments=segs, model="electromechanical", command="u:0",
                                  command_delay=delay, disturbance=noise)  # fmt: skip
        p = r.parameters
        L = p["k0"] + p["k"] * p["a"] / (p["a"] + r.options["y_ref"])
        L_true = truth.inductance(r.options["y_ref"])
        return r, p["R"] / L / (truth.R / L_true) - 1, p["ku"] / L / (truth.ku / L_true) - 1

    monkeypatch.setattr(gb, "NOISE_RATIO_RANGE", np.inf)
    bad, r_err, _ = fit(True, "ar1")
    assert voltage_noise_share(bad) > 1e3 * VOLTAGE_NOISE_CEILING
    assert bad.extras["pole_identified"] and r_err > 0.3  # what the flag is for
    assert any(n.startswith("coil equation left to noise") for n in bad.notes)
    monkeypatch.undo()
    bounded, r_err, ku_err = fit(True, "ar1")  # the same model, the ratios bounded
    assert voltage_noise_share(bounded) < 2.1 and abs(r_err) < 0.05 and abs(ku_err) < 0.05
    assert not any(n.startswith("coil equation left to noise") for n in bounded.notes)
    good, r_err, ku_err = fit(False, "white")
    assert voltage_noise_share(good) < 2.1 and abs(r_err) < 0.05 and abs(ku_err) < 0.05
    assert not any(n.startswith("coil equation left to noise") for n in good.notes)
