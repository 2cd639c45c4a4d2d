"""The regression kernel: LS/IV by QR, HAC covariance, ARX and Markov parameters."""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.exceptions import DataError, IdentificationError
from maglevid.identify.arx import (
    fit_arx,
    hac_covariance,
    lagged,
    markov_from_arx,
    solve_linear_regression,
)
from maglevid.lti import StateSpace


def test_exact_regression_recovered_to_rounding(rng):
    Phi = rng.standard_normal((300, 4)) * [1e-6, 1.0, 1e3, 1e-2]  # badly scaled columns
    Theta = rng.standard_normal((2, 4))
    Y = Phi @ Theta.T
    fit = solve_linear_regression(Y, Phi)
    # Exact algebra: each coefficient's error, weighted by its regressor's size, is at
    # rounding level of Y (a coefficient of a tiny regressor is only as well determined
    # as its contribution to Y, here 1e-9 of it).
    err = (fit.coefficients - Theta) * np.sqrt(np.mean(Phi**2, axis=0))
    assert np.max(np.abs(err)) < 1e-12 * np.sqrt(np.mean(Y**2))
    assert fit.estimator == "ls" and fit.rank == 4


def test_ls_covariance_matches_textbook_formula_for_white_noise(rng):
    # With white, homoscedastic errors and lags=0 the sandwich is
    # sum_k psi psi^T e^2 ~ sigma^2 (Phi^T Phi)^-1; compare with the residual variance.
    N = 4000
    Phi = rng.standard_normal((N, 3))
    e = rng.standard_normal((N, 1)) * 0.1
    fit = solve_linear_regression(Phi @ [[1.0], [2.0], [3.0]] + e, Phi)
    s2 = float(np.mean(fit.residuals**2))
    textbook = s2 * np.linalg.inv(Phi.T @ Phi)
    np.testing.assert_allclose(fit.covariance, textbook, rtol=0.1, atol=1e-7)


def test_rank_deficient_regression_names_the_collinear_regressors(rng):
    a = rng.standard_normal((100, 2))
    Phi = np.hstack([a, a[:, :1]])  # column 2 duplicates column 0
    with pytest.raises(IdentificationError, match=r"x.*z"):
        solve_linear_regression(a[:, :1], Phi, labels=["x", "y", "z"])
    fit = solve_linear_regression(a[:, :1], Phi, min_norm=True)
    # Minimum norm (in scaled coordinates): the duplicated coefficient is split evenly.
    np.testing.assert_allclose(fit.coefficients, [[0.5, 0.0, 0.5]], atol=1e-12)
    assert "not unique" in fit.notes[0]


def test_zero_regressor_is_an_error(rng):
    Phi = np.hstack([rng.standard_normal((50, 1)), np.zeros((50, 1))])
    with pytest.raises(IdentificationError, match="identically zero"):
        solve_linear_regression(Phi[:, :1], Phi)


def test_iv_with_regressors_as_instruments_is_ls(rng):
    Phi = rng.standard_normal((200, 3))
    Y = Phi @ rng.standard_normal((3, 2)) + 0.1 * rng.standard_normal((200, 2))
    ls = solve_linear_regression(Y, Phi)
    iv = solve_linear_regression(Y, Phi, instruments=Phi)
    np.testing.assert_allclose(iv.coefficients, ls.coefficients, rtol=1e-10)
    np.testing.assert_allclose(iv.covariance, ls.covariance, rtol=1e-8)
    assert iv.estimator == "iv"


def test_iv_removes_errors_in_variables_bias(rng):
    # y = 2 x0 + e, regressor measured with noise: LS is attenuated, IV is not.
    N = 20000
    z = rng.standard_normal(N)
    x0 = z + 0.5 * rng.standard_normal(N)
    x = x0 + 1.0 * rng.standard_normal(N)
    y = 2 * x0 + 0.1 * rng.standard_normal(N)
    ls = solve_linear_regression(y, x)
    iv = solve_linear_regression(y, x, instruments=z)
    assert ls.coefficients[0, 0] < 1.6  # attenuation factor 1.25/2.25
    se = float(np.sqrt(iv.covariance[0, 0]))
    assert abs(iv.coefficients[0, 0] - 2.0) < 4 * se


def test_two_stage_least_squares_with_more_instruments(rng):
    N = 5000
    Z = rng.standard_normal((N, 4))
    x = Z @ [1.0, 0.5, -0.3, 0.2] + rng.standard_normal(N)
    y = 3 * x
    fit = solve_linear_regression(y, x, instruments=Z)
    assert fit.estimator == "2sls"
    np.testing.assert_allclose(fit.coefficients, [[3.0]], rtol=1e-12)


def test_bad_shapes_are_errors(rng):
    with pytest.raises(DataError, match="shape"):
        solve_linear_regression(np.zeros((10, 1)), rng.standard_normal((11, 2)))
    with pytest.raises(DataError, match="more rows"):
        solve_linear_regression(np.zeros((2, 1)), rng.standard_normal((2, 2)))
    with pytest.raises(DataError, match="at least"):
        solve_linear_regression(
            np.zeros((20, 1)), rng.standard_normal((20, 2)), instruments=np.ones((20, 1))
        )
    bad = rng.standard_normal((20, 2))
    bad[3, 1] = np.nan
    with pytest.raises(DataError, match="non-finite"):
        solve_linear_regression(np.zeros((20, 1)), bad)


def test_hac_truncated_kernel_counts_each_lag_once():
    # Scores g(k) = e(k) psi(k) with psi = 1: S = sum_l w_l sum_k e(k) e(k-l).
    e = np.array([[1.0], [2.0], [-1.0], [0.5]])
    S, clipped = hac_covariance(e, np.ones((4, 1)), lags=1)
    expected = np.sum(e**2) + 2 * np.sum(e[1:] * e[:-1])
    assert S[0, 0] == pytest.approx(expected) and not clipped


def test_markov_from_arx_equals_state_space_markov():
    # y(k) = 0.5 y(k-1) - 0.2 y(k-2) + u(k-1) + 0.3 u(k-2), realized in observer form.
    a = np.array([[[0.5]], [[-0.2]]])
    b = np.array([[[0.0]], [[1.0]], [[0.3]]])
    ss = StateSpace([[0.5, 1.0], [-0.2, 0.0]], [[1.0], [0.3]], [[1.0, 0.0]], dt=1.0)
    np.testing.assert_allclose(markov_from_arx(a, b, 12), ss.markov(12), rtol=1e-12, atol=1e-15)


def test_fit_arx_recovers_a_simulated_mimo_arx(rng):
    N = 500
    u = rng.standard_normal((N, 2))
    y = np.zeros((N, 2))
    a1 = np.array([[0.5, 0.1], [0.0, -0.3]])
    b1 = np.array([[1.0, 0.0], [0.5, 2.0]])
    for k in range(1, N):
        y[k] = a1 @ y[k - 1] + b1 @ u[k - 1]
    model = fit_arx(y, u, na=1, nb=1)
    np.testing.assert_allclose(model.a[0], a1, atol=1e-12)
    np.testing.assert_allclose(model.b[1], b1, atol=1e-12)
    np.testing.assert_allclose(model.b[0], 0.0)


def test_lagged_builds_blocks_in_lag_order():
    x = np.arange(10.0)[:, None]
    L = lagged(x, [0, 2], 2, 5)
    np.testing.assert_array_equal(L, [[2, 0], [3, 1], [4, 2]])
    with pytest.raises(DataError, match="outside"):
        lagged(x, [3], 2, 5)
