"""Building blocks of the subspace methods: Hankel accumulators, factor, fast recursion.

Exact algebra, so ``rtol = 1e-12`` against direct (slow, obvious) computations;
the direct Gram is itself rounded, so entries are compared relative to the
largest entry.
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.lib.stride_tricks import sliding_window_view

from maglevid.identify._hankel import _HankelQR, _LagGram, factor_gram, lower_factor
from maglevid.identify._recursion import linear_recursion


def _hankel(z: np.ndarray, w: int) -> np.ndarray:
    N, m = z.shape
    return sliding_window_view(z, (w, m)).reshape(N - w + 1, w * m)


CHUNKINGS = {
    "whole": [500],
    "irregular": [1, 2, 3, 50, 444],
    "tiny": [7] * 71 + [3],
    "ones": [1] * 500,
}


@pytest.mark.parametrize("chunks", list(CHUNKINGS.values()), ids=list(CHUNKINGS))
@pytest.mark.parametrize(
    ("max_lag", "group_block"), [(0, 2048), (1, 2048), (3, 2), (8, 3), (19, 2)]
)
def test_lag_gram_equals_the_gram_of_the_hankel_rows_for_every_window(
    chunks, max_lag, group_block, monkeypatch
):
    """Reference: ``H^T H`` of the explicit Hankel rows. The lagged sums are GEMMs over
    groups of L samples, ``group_block`` groups at a time (small blocks: several per
    chunk); L = 0 has no next-group product, L = 19 is horizon 10's."""
    from maglevid.identify import _hankel as hankel_module

    monkeypatch.setattr(hankel_module, "_GROUP_BLOCK", group_block)
    z = np.random.default_rng(0).standard_normal((500, 3)) + 0.5
    acc = _LagGram(3, max_lag)
    pos = 0
    for c in chunks:
        acc.update(z[pos : pos + c])
        pos += c
    assert acc.n == 500
    for w in range(1, max_lag + 2):
        H = _hankel(z, w)
        G = H.T @ H
        np.testing.assert_allclose(acc.gram(w), G, rtol=0, atol=1e-12 * np.abs(G).max())


@pytest.mark.parametrize("chunks", list(CHUNKINGS.values())[:3], ids=list(CHUNKINGS)[:3])
def test_tsqr_factor_reproduces_the_gram(chunks):
    z = np.random.default_rng(1).standard_normal((500, 2))
    acc = _HankelQR(2, 6)
    pos = 0
    for c in chunks:
        acc.update(z[pos : pos + c])
        pos += c
    H = _hankel(z, 6)
    G = H.T @ H
    np.testing.assert_allclose(acc.R.T @ acc.R, G, rtol=0, atol=1e-12 * np.abs(G).max())


@pytest.mark.parametrize("max_lag", [0, 2, 7, 150])
def test_moments_track_rms_and_mean(max_lag):
    # The sums of squares come from S_0 and the last L samples (L = 150: all pending).
    z = np.random.default_rng(2).standard_normal((100, 2)) * [1.0, 3.0] + [0.0, 2.0]
    acc = _LagGram(2, max_lag)
    acc.update(z[:37])
    acc.update(z[37:])
    np.testing.assert_allclose(acc.moments.mean(), z.mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(acc.moments.rms(), np.sqrt((z**2).mean(axis=0)), rtol=1e-12)


def test_pivoted_cholesky_factor_of_a_rank_deficient_gram_is_exact():
    rng = np.random.default_rng(3)
    X = rng.standard_normal((200, 4)) @ rng.standard_normal((4, 7))  # rank 4, 7 columns
    G = X.T @ X / 200
    F, rank = factor_gram(G)
    assert rank == 4 and F.shape == (7, 4)
    np.testing.assert_allclose(F @ F.T, G, rtol=0, atol=1e-12 * np.abs(G).max())
    L = lower_factor(F)
    assert L.shape == (7, 4)
    assert np.allclose(np.triu(L, 1), 0)
    np.testing.assert_allclose(L @ L.T, G, rtol=0, atol=1e-12 * np.abs(G).max())


def _loop(F, W, x0):
    x = x0.copy()
    X = np.empty_like(W)
    for t in range(W.shape[0]):
        X[t] = x
        x = F @ x + W[t]
    return X, x


@pytest.mark.parametrize(("N", "c"), [(1, 1), (7, 1), (64, 2), (1000, 1), (777, 5)])
@pytest.mark.parametrize("radius", [0.7, 1.01])
def test_linear_recursion_matches_the_sequential_loop(N, c, radius):
    rng = np.random.default_rng(4)
    n = 3
    Q = np.linalg.qr(rng.standard_normal((n, n)))[0]
    F = radius * Q  # spectral radius exactly `radius` (stable and unstable)
    W = rng.standard_normal((N, n, c))
    x0 = rng.standard_normal((n, c))
    X, x_end = linear_recursion(F, W, x0)
    X_ref, x_ref = _loop(F, W, x0)
    scale = max(1.0, np.abs(X_ref).max())
    np.testing.assert_allclose(X, X_ref, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(x_end, x_ref, rtol=0, atol=1e-12 * max(1.0, np.abs(x_ref).max()))
    X2, x2 = linear_recursion(F, W[:, :, 0], x0[:, 0])  # 2-D form
    np.testing.assert_allclose(X2, X[:, :, 0], rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(x2, x_end[:, 0], rtol=0, atol=1e-12 * scale)


def test_linear_recursion_continues_across_chunks():
    rng = np.random.default_rng(5)
    F = 0.9 * np.linalg.qr(rng.standard_normal((4, 4)))[0]
    W = rng.standard_normal((1000, 4))
    X_all, x_all = linear_recursion(F, W)
    X1, x1 = linear_recursion(F, W[:333])
    X2, x2 = linear_recursion(F, W[333:], x1)
    np.testing.assert_allclose(np.concatenate([X1, X2]), X_all, rtol=0, atol=1e-12)
    np.testing.assert_allclose(x2, x_all, rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    ("n_samples", "chunk"),
    [(1, None), (15, None), (16, None), (17, None), (1000, None), (1037, 160)],
)
def test_predictor_residuals_match_the_sample_by_sample_loop(n_samples, chunk, monkeypatch):
    """Block residuals (GEMMs over b = 16 samples) = the predictor run one sample at a time.

    Reference: the textbook loop ``x(t+1) = (A - K C) x(t) + (B - K D) u(t) + K y(t)``;
    lengths off the block size and past one chunk (2^16) exercise the partial last block
    and the state carried between chunks (a 160-sample chunk stands for the 2^16 one).
    """
    from maglevid.identify import subspace as ss
    from maglevid.lti import StateSpace

    if chunk is not None:
        monkeypatch.setattr(ss, "_CHUNK", chunk)
    rng = np.random.default_rng(3)
    A = np.array([[0.99, 0.05, 0.0], [-0.05, 0.99, 0.1], [0.0, 0.0, 0.5]])
    B, C, D = rng.standard_normal((3, 2)), rng.standard_normal((2, 3)), rng.standard_normal((2, 2))
    K = 0.1 * rng.standard_normal((3, 2))
    y, u = rng.standard_normal((n_samples, 2)), rng.standard_normal((n_samples, 2))
    e = ss._predictor_residuals(StateSpace(A, B, C, D, 1.0), K, y, u)
    x = np.zeros(3)
    ref = np.empty_like(y)
    for t in range(n_samples):
        ref[t] = y[t] - C @ x - D @ u[t]
        x = (A - K @ C) @ x + (B - K @ D) @ u[t] + K @ y[t]
    np.testing.assert_allclose(e, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    # ``mean`` subtracts per chunk what a centred copy of the record subtracts first:
    # the same elementwise differences, the same products (bitwise equal).
    mu, my = np.array([3.0, -1.0]), np.array([0.5, 2.0])
    got = ss._predictor_residuals(StateSpace(A, B, C, D, 1.0), K, y, u, (mu, my))
    want = ss._predictor_residuals(StateSpace(A, B, C, D, 1.0), K, y - my, u - mu)
    np.testing.assert_array_equal(got, want)


def test_riccati_doubling_matches_scipy_or_declines():
    """The doubling solver returns scipy's stabilising solution, or None (then scipy runs).

    Reference: ``scipy.linalg.solve_discrete_are`` (generalised Schur form) on random
    filter problems, stable and unstable ``A``, output noise from unit to 1e-12 variance.
    """
    import scipy.linalg as sla

    from maglevid.identify.subspace import _dare_doubling

    rng = np.random.default_rng(0)
    solved = 0
    for _ in range(100):
        n, ny = int(rng.integers(1, 7)), int(rng.integers(1, 4))
        A = rng.standard_normal((n, n))
        A *= rng.uniform(0.2, 1.3) / np.max(np.abs(np.linalg.eigvals(A)))
        C = rng.standard_normal((ny, n))
        scale = np.r_[np.ones(n), np.full(ny, 10 ** rng.uniform(-6, 0))]
        X = rng.standard_normal((n + ny, n + ny + 2)) * scale[:, None]
        cov = X @ X.T
        Q, S, R = cov[:n, :n], cov[:n, n:], cov[n:, n:] + 1e-12 * np.eye(ny)
        P = _dare_doubling(A, C, Q, R, S)
        if P is None:
            continue
        solved += 1
        P0 = sla.solve_discrete_are(A.T, C.T, Q, R, s=S)
        np.testing.assert_allclose(P, P0, rtol=0, atol=1e-8 * np.abs(P0).max())
    assert solved >= 50  # it is the usual route, not the exception


@pytest.mark.parametrize("offset", [0.0, 3.0, 1e4])
def test_one_step_fit_percentages_are_those_of_the_residuals(offset):
    """Reference: ``100 (1 - ||e|| / ||y - mean(y)||)`` per output, from the returned
    residuals and numpy. The centred sums come from the data stage's moments unless the
    offset makes them cancel (1e4 times the output RMS: the exact pass over the record)."""
    from maglevid.identify.subspace import fit_moesp

    rng = np.random.default_rng(5)
    u = rng.standard_normal((3000, 2))
    y = np.zeros((3000, 2))
    for t in range(1, 3000):  # a stable 2 x 2 first-order system plus noise
        y[t] = 0.8 * y[t - 1] + u[t - 1] @ [[1.0, 0.3], [-0.2, 0.5]]
    y = y + 0.05 * rng.standard_normal(y.shape) + offset
    res = fit_moesp(y, u, order=2, horizon=5)
    e = np.asarray(res.residuals)
    ref = 100.0 * (1.0 - np.linalg.norm(e, axis=0) / np.linalg.norm(y - y.mean(axis=0), axis=0))
    np.testing.assert_allclose(
        [res.fit["one_step_fit_percent_y1"], res.fit["one_step_fit_percent_y2"]], ref, rtol=1e-9
    )


def test_factored_projection_applies_gamma_pinv_like_the_full_projection():
    """``_Projected`` keeps ``Z = X Q Q^T`` as ``(X Q, Q)`` and applies ``Gamma^+`` first.
    Reference: the full projection formed, then ``Gamma^+ (Z - H U)`` by numpy's lstsq
    (the noise statistics' formula as written in Van Overschee & De Moor 1996, Ch. 4)."""
    from maglevid.identify.subspace import _Projected

    rng = np.random.default_rng(5)
    Q = np.linalg.qr(rng.standard_normal((60, 25)))[0]  # orthonormal basis, 60-dim rows
    X = rng.standard_normal((12, 60))
    Gam = rng.standard_normal((12, 4))
    H = rng.standard_normal((12, 8))
    U = rng.standard_normal((8, 60))
    Z = (X @ Q) @ Q.T
    ref = np.linalg.lstsq(Gam, Z - H @ U, rcond=None)[0]
    got = _Projected(X @ Q, Q).pinv_apply(Gam, H, U)
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-13 * np.abs(ref).max())
    ref0 = np.linalg.lstsq(Gam, Z, rcond=None)[0]
    got0 = _Projected(X @ Q, Q).pinv_apply(Gam)
    np.testing.assert_allclose(got0, ref0, rtol=0, atol=1e-13 * np.abs(ref0).max())


def test_kalman_gain_solve_equals_scipy_positive_definite_solve():
    """The gain's ``(A P C^T + S) Re^-1`` by LAPACK posv; reference: scipy.linalg.solve
    with ``assume_a="pos"`` (what the fit called before), to rounding."""
    import scipy.linalg as sla

    from maglevid.identify.subspace import _dare_doubling, _kalman_gain

    rng = np.random.default_rng(8)
    n, ny = 4, 3
    A = np.diag([0.9, 0.7, -0.5, 0.3]) + 0.05 * rng.standard_normal((n, n))
    C = rng.standard_normal((ny, n))
    W = rng.standard_normal((n + ny, 3 * (n + ny)))
    cov = W @ W.T / W.shape[1]
    K, Re, why = _kalman_gain(A, C, cov)
    assert why == ""
    Q, S, R = cov[:n, :n], cov[:n, n:], cov[n:, n:] + 1e-12 * np.eye(ny)
    P = _dare_doubling(A, C, Q, R, S)
    assert P is not None
    Re_ref = C @ P @ C.T + R
    K_ref = sla.solve(Re_ref.T, (A @ P @ C.T + S).T, assume_a="pos").T
    np.testing.assert_allclose(K, K_ref, rtol=1e-12, atol=1e-14)
    # (_kalman_gain first rebuilds cov from its eigen-decomposition: rounding-level change)
    np.testing.assert_allclose(Re, Re_ref, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("i", [1, 2, 10, 40])
def test_markov_toeplitz_is_the_block_lower_triangular_definition(i):
    # Definition (Van Overschee & De Moor 1996, eq. (2.19)): block (r, c) of H_i is
    # h[r - c] for r >= c and zero above the diagonal; built here entry by entry.
    from maglevid.identify.subspace import _toeplitz

    h = np.random.default_rng(i).standard_normal((i, 3, 2))
    H = np.zeros((3 * i, 2 * i))
    for r in range(i):
        for c in range(r + 1):
            H[3 * r : 3 * r + 3, 2 * c : 2 * c + 2] = h[r - c]
    got = _toeplitz(h)
    assert np.array_equal(got, H)  # a gather: the same numbers, not a computation
    assert got.flags.writeable and got.flags.c_contiguous


@pytest.mark.parametrize(("p", "m", "nu"), [(1, 2, 1), (4, 5, 2), (19, 5, 2), (7, 3, 0)])
def test_split_layout_interleave_is_the_ix_gather(p, m, nu):
    # The fold's block copies take X[k][:, k] (numpy's np.ix_ gather): the same numbers.
    from maglevid.identify._hankel import _interleave, _split_order

    k = _split_order(p, m, nu)
    assert sorted(k.tolist()) == list(range(p * m))  # a permutation of the columns
    X = np.random.default_rng(p).standard_normal((p * m, p * m))
    assert np.array_equal(_interleave(X, p, m, nu), X[np.ix_(k, k)])
    assert not k.flags.writeable
