"""The levitator grey box's sandwich covariance and its fast kernels (issues 13 and 14).

References: the sandwich ``H^-1 S H^-1`` against the Fisher matrix ``s^2 (J'J)^-1`` for
white residuals (equal in expectation, Ljung 1999 sec. 9.3) and against the known
variance of least squares with AR(1) regressor and AR(1) errors (``var(beta) ~
s^2 (1 + phi rho)/((1 - phi rho) N var(x))``, Hamilton 1994 eq. (10.5.19) reasoning: the
long-run variance of ``x_t e_t``); the Riccati solver against scipy's QZ solver; the
one-step filter against the state recursion of ``InnovationsModel.predict``. The
Monte Carlo of the grey box's intervals is in benchmarks/bench_levitator_coverage.py
(``--per-fit``); here one coloured log checks the wiring.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla

from maglevid.experiments.rigs import simulate_pd_dither_levitator
from maglevid.identify.closedloop import InnovationsModel, covariance_from_jacobian
from maglevid.identify.greybox import (
    _one_step,
    fit_greybox_levitator,
    sandwich_covariance,
    solve_filter_riccati,
)


def _ar1(rng, n, phi):
    e = rng.standard_normal(n)
    x = np.empty(n)
    x[0] = e[0] / np.sqrt(1 - phi**2)
    for t in range(1, n):
        x[t] = phi * x[t - 1] + e[t]
    return x


def test_sandwich_is_the_fisher_matrix_for_white_residuals(rng):
    n = 4000
    J = rng.standard_normal((n, 3))
    e = 0.3 * rng.standard_normal(n)
    cov, lag = sandwich_covariance(J, e, [n], 1)
    fisher = covariance_from_jacobian(J, e, 3)
    assert lag >= 1  # at least the Newey-West rule
    np.testing.assert_allclose(np.diag(cov), np.diag(fisher), rtol=0.15)


def test_sandwich_covers_under_coloured_residuals_where_fisher_does_not(rng):
    # y = beta x + e, x and e AR(1) with 0.8: the long-run variance of x e is
    # (1 + 0.64)/(1 - 0.64) = 4.6 times the white value, so Fisher's 95 % intervals
    # cover far less; the sandwich's should be close to 95 %.
    n, runs, phi = 1500, 150, 0.8
    hit_s = hit_f = 0
    for _ in range(runs):
        x, e = _ar1(rng, n, phi), _ar1(rng, n, phi)
        y = 2.0 * x + e
        beta = float(x @ y / (x @ x))
        r = y - beta * x
        J = -x[:, None]  # d r / d beta
        se_s = np.sqrt(sandwich_covariance(J, r, [n], 1)[0][0, 0])
        se_f = np.sqrt(covariance_from_jacobian(J, r, 1)[0, 0])
        hit_s += abs(beta - 2.0) <= 1.96 * se_s
        hit_f += abs(beta - 2.0) <= 1.96 * se_f
    # binomial 150 draws: +-0.035 at 1 sd; Bartlett HAC under-covers slightly in finite N
    assert hit_s / runs >= 0.86
    assert hit_f / runs <= 0.75


def test_segments_do_not_leak_lags_across_boundaries(rng):
    # two independent segments: swapping them leaves the sandwich unchanged
    J = rng.standard_normal((600, 2))
    e = rng.standard_normal(600)
    a, _ = sandwich_covariance(J, e, [200, 400], 1)
    Js, es = np.vstack([J[200:], J[:200]]), np.r_[e[200:], e[:200]]
    b, _ = sandwich_covariance(Js, es, [400, 200], 1)
    np.testing.assert_allclose(a, b, rtol=1e-10)


def test_doubling_riccati_matches_scipy_on_the_unstable_levitator():
    dt, p = 0.01, 45.0
    A = np.array([[0.0, 1.0, 0.0], [p**2, 0.0, -20.0], [0.0, -300.0, -600.0]])
    Phi = sla.expm(A * dt)
    C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    Q = np.diag([0.0, 1e-2, 1e-4])
    R = np.diag([1e-10, 1e-6])
    ref = sla.solve_discrete_are(Phi.T, C.T, Q, R)
    np.testing.assert_allclose(solve_filter_riccati(Phi, C, Q, R), ref, rtol=1e-8, atol=1e-14)


@pytest.mark.parametrize("nx,ny", [(2, 1), (4, 2), (6, 2)])
def test_one_step_filter_is_the_state_recursion(rng, nx, ny):
    A = rng.standard_normal((nx, nx))
    A *= 0.9 / np.max(np.abs(np.linalg.eigvals(A)))
    inn = InnovationsModel(A, rng.standard_normal((nx, 1)), rng.standard_normal((ny, nx)),
                           rng.standard_normal((ny, 1)), np.zeros((nx, ny)))  # fmt: skip
    Y, U = rng.standard_normal((300, ny)), rng.standard_normal((300, 1))
    np.testing.assert_allclose(_one_step(inn, Y, U), inn.predict(Y, U, k=1), atol=1e-10)


def test_greybox_reports_its_covariance_and_the_fisher_one():
    # the simulated PD rig with what the noise model leaves out (bench's 'coloured' case)
    log = simulate_pd_dither_levitator(
        2500, rng=np.random.default_rng(3), force_colour=0.5, chatter=1e-3,
        quantum=(1e-6, 2.2e-3),
    )  # fmt: skip
    truth = log.metadata["truth_pole_rad_s"]
    res = fit_greybox_levitator(log, model="electromechanical", y_ref=float(log.y[:, 0].mean()))
    assert res.extras["covariance"] == "sandwich"
    assert any(n.startswith("covariance: sandwich") for n in res.notes)
    lo, hi = res.confidence_intervals(0.95)["pole_rad_s"]
    assert lo <= truth <= hi
    j = list(res.parameters).index("pole_rad_s")
    assert np.sqrt(res.covariance[j, j]) > res.extras["pole_se_fisher"]
