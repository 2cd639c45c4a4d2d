"""Maximum likelihood on the realistic bearing (the simulator's default).

The nonlinear magnet (eq. (1)) under the nominal bias voltages, a 0.1 N white
force disturbance on the rotor and the command line's sensor noise. ML's
noise model carries the force disturbance as an estimated parameter (its
variance); the reference of every estimate is eq. (4) linearised at the
operating point the (faulty) bearing settles at
(``metadata["operating_point_true"]["v"]``, as in
test_settled_point_identification.py). The linear-plant tests of exactness
and efficiency are in test_ml.py; the large Monte Carlo is
benchmarks/bench_ml_realistic.py (100 records per case: coverage 0.94-0.95,
scatter/stated error 0.9-1.2, docs/gosiewski.md, "Maximum likelihood").
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from maglevid.exceptions import DataError, IdentificationError
from maglevid.identify.cramer_rao import cramer_rao_bound
from maglevid.identify.ml import fit_ml
from maglevid.identify.physical import fit_physical
from maglevid.physics.amb import V_NAMES, AMBParameters
from maglevid.simulate.amb import DEFAULT_FORCE_STD, simulate_amb_loop

NOM = AMBParameters.nominal()
NOM_OP = {"m": NOM.m, "i0": NOM.i0, "x0": NOM.x0}
FAULTS = [{}, {"R1": 1.2}, {"kw1": 0.8}, {"K1": 0.9}]


def _v(res):
    return np.array([res.parameters[k] for k in V_NAMES])


def _se(res):
    return np.array([res.std_errors()[k] for k in V_NAMES])


def _settled(d):
    return np.asarray(d.metadata["operating_point_true"]["v"])


@pytest.fixture(scope="module")
def realistic():
    """One R1 +20 % record of the default kind (controller on the nominal bearing)."""
    return simulate_amb_loop(NOM.with_fault(R1=1.2), nominal=NOM, n_samples=6000, rng=31)


def test_small_monte_carlo_coverage_at_the_settled_point():
    """8 records (healthy, R1 +20 %, kw1 -20 %, K1 -10 %; two seeds each) x 9
    parameters = 72 intervals. At a true 95 % the misses are ~Binomial(72, 0.05)
    (mean 3.6; P(>= 12) = 2e-4 if independent): 0-11 accepted. The intervals
    must also be the efficient ones (v1, R1 to ~1 % on 0.6 s; IV's are ~40 %),
    or wide intervals would pass. Started from IV: also the convergence check."""
    misses, force = 0, []
    for k, fault in enumerate(FAULTS):
        for seed in (0, 1):
            d = simulate_amb_loop(
                NOM.with_fault(**fault), nominal=NOM, n_samples=6000, rng=200 + 10 * k + seed
            )
            res = fit_ml(d)
            assert res.extras["converged"], fault
            ci = res.confidence_intervals(0.95)
            misses += sum(not (ci[n][0] <= t <= ci[n][1]) for n, t in zip(V_NAMES, _settled(d)))
            assert res.std_errors()["R1"] < 0.02 * res.parameters["R1"], fault
            force.append(res.extras["force_std"])
    assert misses <= 11, misses
    # The force disturbance is estimated: 0.098 N mean over 400 records of 1e4
    # samples (benchmark); here 8 records of 6000, each within ~15 %.
    assert np.mean(force) == pytest.approx(DEFAULT_FORCE_STD, rel=0.1)


def test_without_the_force_disturbance_the_likelihood_is_not_the_datas(realistic):
    """ML told there is no force disturbance fits the wrong noise model (its
    intervals covered the settled point 77 % of the time on 20 records of 1e4,
    its scatter up to 2.3x its stated errors). The data reject that model: the
    likelihood-ratio statistic of
    the one extra parameter is far beyond chi2(1)'s 99.9 % point (10.8). With
    the force estimated every v_i is within 4 standard errors."""
    good = fit_ml(realistic)
    z = (_v(good) - _settled(realistic)) / _se(good)
    assert np.all(np.abs(z) < 4), z
    assert good.extras["force_std"] == pytest.approx(DEFAULT_FORCE_STD, rel=0.3)
    # ML's stated errors are the Cramér-Rao bound of the same model (force and
    # sensor levels unknown), at the estimate vs at the settled point: within 15 %.
    crb = cramer_rao_bound(realistic, estimate_noise=True, estimate_force=True).std()
    np.testing.assert_allclose(_se(good) / [crb[k] for k in V_NAMES], 1.0, atol=0.15)
    bad = fit_ml(realistic, force_std=0.0)
    lr = 2 * (bad.fit["neg_log_likelihood"] - good.fit["neg_log_likelihood"])
    assert lr > 100, lr


def test_ml_is_far_more_precise_than_iv_on_the_realistic_bearing(realistic):
    """The issue's target, >= 5x lower standard error than IV (the default
    ``physical``) on the parameters a coil fault moves; measured ~50x."""
    ml, iv = fit_ml(realistic).std_errors(), fit_physical(realistic).std_errors()
    for k in ("R1", "R2", "kw1", "kw2", "v1", "v5"):
        assert 5 * ml[k] < iv[k], (k, ml[k], iv[k])


def test_no_force_disturbance_puts_its_variance_on_the_bound():
    """A linear-plant record without force: the estimated variance stops at (or
    next to) its bound 0 and the fit still converges (the active set)."""
    d = simulate_amb_loop(
        NOM.with_fault(R1=1.2), nominal=NOM, n_samples=6000, rng=9,
        plant_model="linear", force_std=0.0,
    )  # fmt: skip
    res = fit_ml(d)
    assert res.extras["converged"]
    assert res.extras["force_std"] < 0.2 * DEFAULT_FORCE_STD
    z = (_v(res) - np.asarray(d.metadata["truth_v"])) / _se(res)
    assert np.all(np.abs(z) < 4), z


def test_force_option_errors(realistic):
    with pytest.raises(DataError, match="force_std"):
        fit_ml(realistic, force_std=-1.0)
    with pytest.raises(DataError, match="force_std"):
        fit_ml(realistic, force_std="guess")


def test_a_saturated_record_is_a_data_error(realistic):
    """The logged amplifier inputs clipped at 30 % of their peak (as the method
    contract's saturated record): the logged u is no longer what drove the
    bearing. Where the Kalman predictor's equations fail inside scipy, ML says
    so with one DataError at its own boundary (never a LinAlgError/ValueError,
    the contract test's case); where they do not (this record), the result says it
    did not converge, or (since the force disturbance's restart, thirteenth session
    of issue 16) that it converged only from a nonzero force, the clipped input read
    as a force on the rotor (R1 2.1 instead of 21 ohm). Either way the quality gate
    refuses such a record before `identify` or `diagnose` reads it."""
    from maglevid.diagnose.checks import run_checks

    d = realistic
    lim = 0.3 * float(np.max(np.abs(d.u)))
    u = np.clip(d.u, -lim, lim)
    sat = d.replace(u=u, u_f=u - d.r)
    assert any(q.name == "saturation" and not q.passed and q.blocking for q in run_checks(sat))
    try:
        res = fit_ml(sat)
    except DataError:
        return
    if res.extras["converged"]:
        assert any("restarted with it at" in n for n in res.notes)
    else:
        assert any("without converging" in n for n in res.notes)


def test_a_record_without_its_loop_starts_from_the_closed_loop_subspace_fit():
    # A user's own file (README, "Your own .mat file"): y, u, r, Ts and the operating
    # point, no controller and no nominal bearing. The IV start then has only lags of
    # r as instruments: on this healthy nonlinear bearing (seed 5, 2e4 samples) its R1
    # was 3.7 ohm (truth 17.5) and the scoring stopped after 2 iterations without
    # converging -- and `diagnose` called all 13 parameters changed (found from
    # outside, thirteenth session). PBSID-opt's structured fit needs no controller:
    # it is the other start, taken first when its likelihood is higher. Reference: the
    # settled point's v1..v9 (as above); measured within 1.6 standard errors.
    d = simulate_amb_loop(NOM, nominal=NOM, n_samples=20_000, rng=5)
    user = dataclasses.replace(d, loop={"operating_point": dict(NOM_OP)})
    with pytest.raises(DataError, match="instruments='lags'"):  # physical alone refuses
        fit_physical(user)
    iv = fit_physical(user, instruments="lags")  # ml's weak start, asked for by name
    assert abs(iv.parameters["R1"] / NOM.R1 - 1) > 0.5  # the weak start this is about
    res = fit_ml(user)
    assert res.extras["converged"]
    assert any("PBSID-opt structured fit (higher likelihood" in n for n in res.notes)
    z = (_v(res) - _settled(d)) / _se(res)
    assert np.max(np.abs(z)) < 3.0, z


def test_a_large_force_disturbance_is_found_from_a_nonzero_start():
    # A 2 N force disturbance (20x the simulator's default; rotor 2.3 um rms): from the
    # disturbance at 0, stage 1 fitted the dynamics without it and they absorbed the
    # force (R1 +42 % on this healthy bearing); every start then stopped after 60
    # iterations at -2 log L = -6.2e5, and diagnose said "Unexplained change" (found
    # from outside, issue 16, thirteenth session). Restarted with the disturbance at
    # 0.5 % of the rotor's weight it converges. Reference: the simulated force and the
    # settled point's v1..v9; measured 2.004 N and within 1.6 standard errors.
    d = simulate_amb_loop(NOM, nominal=NOM, n_samples=30_000, rng=62, force_std=2.0)
    res = fit_ml(d)
    assert res.extras["converged"]
    assert any("restarted with it at 0.088 N (converged)" in n for n in res.notes)
    assert abs(res.extras["force_std"] / 2.0 - 1) < 0.05
    z = (_v(res) - _settled(d)) / _se(res)
    assert np.max(np.abs(z)) < 3.0, z


def test_a_short_record_without_its_loop_starts_from_the_subspace_fit_when_iv_fails():
    # A user's own 0.25 s file of a healthy bearing (README recipe: no controller, no
    # nominal bearing): the IV start (lags of r) has no continuous model there, and ml
    # ended at "ml: physical: ... eq. (8)" -- diagnose said "Cannot diagnose" (found from
    # outside, issue 16, fourteenth session). It now starts from PBSID-opt's structured
    # fit. Reference: the optimum reached from the settled point's v1..v9 (the truth):
    # the same to 2e-9 standard errors (at 0.25 s it lies 3.3 standard errors from the
    # settled point in v2 -- the estimator's, not the start's: 2.6 at 0.5 s, 0.8 at 1 s).
    d = simulate_amb_loop(NOM, nominal=NOM, n_samples=30_000, rng=7, plant_model="nonlinear")
    user = dataclasses.replace(d.segment(0, 2500), loop={"operating_point": dict(NOM_OP)})
    with pytest.raises(IdentificationError):
        fit_physical(user, instruments="lags")
    res = fit_ml(user)
    assert res.extras["converged"]
    assert any("started from the PBSID-opt structured fit" in n for n in res.notes)
    ref = fit_ml(user, start=_settled(d))
    assert np.max(np.abs((_v(res) - _v(ref)) / _se(res))) < 1e-4


def test_ten_times_the_sensor_noise_on_the_lag_path():
    """10x the command line's sensor noise, kw1 +20 %, 20 000 samples: the record is
    long enough for the lag path, whose lags come from the IV start's predictor
    (radius 0.976, 1023 lags), while the nominal start that is tried first has
    0.996 (0.996^1023 = 0.015). Before the lag path widened its entries for a slow
    predictor, the truncated sums made slower predictors look better: the scoring
    walked to a point the DFT bins put 4.6e4 above (worse than) the start and then
    to eq. (1) = -4e10, where the information overflowed ("the record is degenerate";
    `maglevid diagnose`'s default method; found from outside, twenty-fifth
    session). Reference: the settled point's eq. (4); v within 4 standard errors."""
    d = simulate_amb_loop(
        NOM.with_fault(kw1=1.2),
        nominal=NOM,
        n_samples=20_000,
        noise_std=(1e-6, 1e-3, 1e-3),
        rng=80004,
    )
    res = fit_ml(d)
    assert any("lagged products" in n for n in res.notes)
    assert res.extras["converged"]
    z = (_v(res) - _settled(d)) / _se(res)
    assert np.max(np.abs(z)) < 4.0, z


def test_a_thousandth_of_the_sensor_noise_converges():
    """1e-3 x the command line's sensor noise (x 1e-10 m, currents 1e-7 A), a healthy
    bearing, 20 000 samples: the linearisation's own error dominates the noise (115 dB).
    The derivative Lyapunov equations were solved in SI units, where ``I - F (x) F`` had
    rcond 3e-17: trial points were rejected as ill-conditioned, the scoring crawled
    ~0.02 of eq. (1) an iteration and stopped unconverged ("Cannot diagnose"; the same
    at 3e-10 m, seed 84003 of the CLI). Solved with ``F`` balanced it converges
    (measured: 38 iterations, x's noise 1.01e-10 m, v within 0.19 % of the settled
    point's eq. (4), z up to 13: the linearisation's error, which diagnose's +-0.1 %
    model-error floor is for). Bounds: x's noise within 50 %, v within 0.5 %."""
    sensor = (1e-10, 1e-7, 1e-7)
    d = simulate_amb_loop(NOM, nominal=NOM, n_samples=20_000, noise_std=sensor, rng=84003)
    res = fit_ml(d)
    assert res.extras["converged"]
    assert res.extras["sensor_noise_std"][0] == pytest.approx(sensor[0], rel=0.5)
    assert np.max(np.abs(_v(res) / _settled(d) - 1)) < 0.005
