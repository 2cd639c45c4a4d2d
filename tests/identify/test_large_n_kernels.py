"""The record-sized temporaries removed from the AMB fits (issue 15, large N).

References: numpy's direct formulas on the whole record (``((x - mean)**2).sum(0)``,
``d.T @ d``), and the immutability contract of :class:`LinearFit` (its arrays are
read-only; a caller's array is copied, never frozen in place).
"""

import numpy as np

from maglevid.identify.arx import LinearFit, RegressionAccumulator
from maglevid.identify.uncertainty import centred_sumsq


def test_centred_sums_equal_the_direct_formula_across_chunks():
    rng = np.random.default_rng(3)
    N = 100_003  # several chunks and a partial one
    y = rng.standard_normal((N, 3)) * [1e-5, 2.0, 3.0] + [1e-3, 5.0, -7.0]  # offsets
    u = rng.standard_normal((N, 2)) + 1.0
    yc = y - y.mean(axis=0)
    uc = u - u.mean(axis=0)
    # bit-identical to the whole-record formula the fits used (the covariance is sensitive
    # to one rounding of the scales: docs/performance.md, section 6b)
    np.testing.assert_array_equal(centred_sumsq(y), np.einsum("ij,ij->j", yc, yc))
    np.testing.assert_array_equal(centred_sumsq(u), np.einsum("ij,ij->j", uc, uc))


def _solved(rng, N=5000):
    phi = rng.standard_normal((N, 3))
    Y = phi @ np.array([[1.0], [-2.0], [0.5]]) + 0.1 * rng.standard_normal((N, 1))
    acc = RegressionAccumulator(3, 1)
    acc.update(Y, phi)
    theta = acc.solve()
    return acc, Y, phi, theta


def test_fit_keeps_its_own_residuals_frozen_without_a_copy():
    rng = np.random.default_rng(4)
    acc, Y, phi, theta = _solved(rng)
    res = acc.update_residuals(Y, phi)
    fit = acc.finish(res)
    assert fit.residuals is res  # the N x ny array is not copied again
    assert not fit.residuals.flags.writeable
    np.testing.assert_allclose(res, Y - phi @ theta.T, rtol=0, atol=1e-12)


def test_a_callers_array_is_copied_not_frozen():
    mine = np.arange(6.0).reshape(3, 2)
    fit = LinearFit(
        coefficients=np.zeros((1, 2)),
        covariance=np.eye(2),
        residuals=mine,
        rank=2,
        singular_values=np.ones(2),
        estimator="ls",
        hac_lags=0,
        kernel="truncated",
    )
    assert mine.flags.writeable  # the caller's array is untouched
    assert fit.residuals is not mine and not fit.residuals.flags.writeable
    mine[0, 0] = 99.0
    assert fit.residuals[0, 0] == 0.0
