"""The regression kernel's passes against their direct definitions.

References are the textbook sums computed on the whole array at once:
``S[l] = a[:N-l].T @ a[l:]`` for the lagged products and ``Xc^T Xc`` of the centred
``[Phi, Y]`` for the Gram a fit reports; the kernel computes them chunk by chunk,
channel-major and from the running QR factor, so they agree to rounding.
"""

import numpy as np
import pytest

from maglevid.identify.arx import _LagSums, solve_linear_regression, solve_regression_blocks


@pytest.mark.parametrize(
    ("n", "max_lag", "chunks"),
    [
        (50, 7, [3, 1, 10, 2, 34]),  # chunks shorter than the lag window
        (20, 0, [5, 15]),
        (30, 3, [1] * 30),  # one sample at a time
        (40, 20, [7, 33]),
        (12, 20, [12]),  # lags beyond the record count as zero
    ],
)
def test_lag_sums_any_chunking_equal_the_whole_record_sums(n, max_lag, chunks):
    rng = np.random.default_rng(1)
    a = rng.standard_normal((n, 4))
    acc, i = _LagSums(4, max_lag), 0
    for c in chunks:
        if c % 2:  # both entry points: time-major and channel-major chunks
            acc.update(a[i : i + c])
        else:
            acc.update_channels(np.ascontiguousarray(a[i : i + c].T))
        i += c
    for lag in range(max_lag + 1):
        ref = a[: n - lag].T @ a[lag:] if lag < n else np.zeros((4, 4))
        np.testing.assert_allclose(acc.S[lag], ref, rtol=1e-13, atol=1e-12)


def test_fit_gram_is_the_centred_gram_of_phi_and_y():
    rng = np.random.default_rng(2)
    N = 5000
    phi = rng.standard_normal((N, 3)) + np.array([10.0, -3.0, 0.5])  # offsets: centred Gram
    z = phi + 0.3 * rng.standard_normal((N, 3))
    y = phi @ [[1.0], [2.0], [-1.0]] + 0.1 * rng.standard_normal((N, 1)) + 4.0
    fit = solve_regression_blocks(y, [phi[:, :2], phi[:, 2:]], [z], intercept=True)
    X = np.hstack([phi, y])
    Xc = X - X.mean(axis=0)
    np.testing.assert_allclose(fit.gram, Xc.T @ Xc, rtol=1e-11, atol=1e-9 * N)
    # without the constant: the raw Gram
    fit = solve_linear_regression(y, phi)
    np.testing.assert_allclose(fit.gram, X.T @ X, rtol=1e-11)
