"""Standard errors and confidence intervals of v1..v9 and of the physical parameters."""

from __future__ import annotations

import numpy as np
import pytest
from _amb_cases import NOMINAL, make_loop, v_est, v_true

from maglevid.identify.deadbeat import fit_deadbeat_iv
from maglevid.identify.physical import (
    fit_physical,
    physical_transformation,
    realize_plant_arx,
)
from maglevid.identify.result import propagate_covariance
from maglevid.identify.uncertainty import PHYSICAL_NAMES
from maglevid.lti import StateSpace, undiscretize
from maglevid.physics.amb import parameters_from_v, v_from_matrices

#: A noise level at which the estimates move visibly (0.1 % of the signal RMS on
#: the currents, 0.1 % on the position) so that the intervals are tested.
NOISE = (1e-9, 3e-6, 3e-6)


@pytest.fixture(scope="module")
def noisy():
    data = make_loop(NOMINAL, observer_model="plant", n_samples=4000, noise_std=NOISE, seed=7)
    return data, fit_physical(data)


def test_frechet_jacobian_equals_brute_force_delta_method(noisy):
    data, res = noisy
    ny, nu, dt = 3, 2, data.dt
    y = np.asarray(data.y)
    u = np.asarray(data.u)
    # realization scales: standard deviations (deviations from the operating point,
    # issue 12), as fit_physical uses them
    ys = np.std(y, axis=0)
    hs = np.std(np.hstack([y[:, :1], u]), axis=0)

    def chain(theta):  # the whole chain with a fresh logm at every step
        At, Bt, Ct, _ = realize_plant_arx(theta, ny=ny, nu=nu, y_scale=ys, h_scale=hs)
        sc = undiscretize(StateSpace(At, Bt, Ct, dt=dt))
        T = physical_transformation(sc.A, Ct)
        v, _ = v_from_matrices(T @ sc.A @ np.linalg.inv(T), T @ sc.B)
        p = parameters_from_v(v, m=NOMINAL.m, i0=NOMINAL.i0)
        return np.concatenate([v, [p[k] for k in PHYSICAL_NAMES]])

    theta = res.extras["coefficients"].ravel()
    cov_theta = np.diag(res.extras["coefficient_std_errors"].ravel() ** 2)
    values, cov_brute = propagate_covariance(chain, theta, cov_theta)
    np.testing.assert_allclose(values, list(res.parameters.values()), rtol=1e-12)
    J = res.extras["jacobian"]
    _, cov_fast = values, J @ cov_theta @ J.T
    # Two finite-difference schemes (steps 1e-6 relative): agreement to ~1e-5.
    sd_b, sd_f = np.sqrt(np.diag(cov_brute)), np.sqrt(np.diag(cov_fast))
    np.testing.assert_allclose(sd_f, sd_b, rtol=1e-4)


def test_noisy_estimate_is_within_a_few_standard_errors(noisy):
    data, res = noisy
    se = np.array(list(res.std_errors().values()))[:9]
    z = (v_est(res) - v_true(data)) / se
    assert np.all(np.abs(z) < 4), z
    ci = res.confidence_intervals(0.999)
    for name in ("R1", "R2", "kw1", "kw2", "ki1", "L1"):
        lo, hi = ci[name]
        assert lo < getattr(NOMINAL, name) < hi, name


def test_result_reports_the_fitted_noise_level(noisy):
    _, res = noisy
    assert res.options["covariance"] == "white-noise"
    # The fitted measurement-noise std is within 10 % of the simulated one.
    sigma = np.sqrt(np.diag(res.extras["noise_covariance"]))
    np.testing.assert_allclose(sigma, NOISE, rtol=0.1)


@pytest.mark.slow
@pytest.mark.parametrize("fit", [fit_physical, fit_deadbeat_iv])
def test_confidence_intervals_cover_the_truth_at_their_nominal_rate(fit):
    # 40 independent records; 95 % intervals of v1..v9 and of six physical parameters.
    # 40 x 15 intervals, correlated within a record: the overall rate must be within
    # 0.95 +- 0.05 (about 3 binomial standard errors for 150 effective intervals).
    names = [f"v{i}" for i in range(1, 10)] + ["R1", "R2", "L1", "L2", "kw1", "kw2"]
    hits = []
    for seed in range(40):
        data = make_loop(
            NOMINAL, observer_model="plant", n_samples=3000, noise_std=NOISE, seed=seed
        )
        res = fit(data)
        truth = dict(zip([f"v{i}" for i in range(1, 10)], v_true(data)))
        truth.update({k: getattr(NOMINAL, k) for k in names[9:]})
        ci = res.confidence_intervals(0.95)
        hits.append([ci[k][0] <= truth[k] <= ci[k][1] for k in names])
    rate = float(np.mean(hits))
    assert abs(rate - 0.95) < 0.05, rate
