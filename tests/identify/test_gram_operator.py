"""The window's Gram as an operator, products by FFT (issue 16, seventh session; (P18)).

Reference: the Hankel rows themselves, ``H^T H / j`` formed from a sliding window
of the record (the textbook definition, no lagged sums), centred with the rows'
column means and channel-scaled as the data stage does. Rounding of the FFT
products is relative to the rows' and the Gram's norms: measured 2e-16 - 2.5e-15
of ``max |X G|`` on random records and on the bench's bearing records (N = 1e4,
215-306 of 306 samples); asserted 1e-12.
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.lib.stride_tricks import sliding_window_view

from maglevid.identify._gram_operator import GramOperator
from maglevid.identify._hankel import _LagGram


def _dense(z: np.ndarray, w: int, k: int, scale: np.ndarray, center: bool) -> np.ndarray:
    j, m = z.shape[0] - w + 1, z.shape[1]
    H = sliding_window_view(z, (w, m))[:, 0].reshape(j, w * m)[:, : k * m] / np.tile(scale, k)
    if center:
        H = H - H.mean(axis=0)
    return H.T @ H / j


def _record(rng, N, L, w, k, center):  # type: ignore[no-untyped-def]
    """``(z, acc, op, G)``: correlated channels (AR(1), pole 0.95) of unequal sizes with
    offsets of about their spread, their lagged sums, the operator and the dense Gram."""
    e = rng.standard_normal((N, 5))
    z = np.empty_like(e)
    z[0] = e[0]
    for t in range(1, N):
        z[t] = 0.95 * z[t - 1] + e[t]
    z = z * [1.0, 3.0, 1e-3, 0.2, 5.0] + [2.0, -5.0, 3e-3, 0.0, 10.0]
    acc = _LagGram(5, L)
    acc.update(z)
    scale = z.std(axis=0)
    return z, acc, GramOperator(acc, w, k, scale, center), _dense(z, w, k, scale, center)


# (N, L, w, k): a full window, shorter windows, k = 1, odd FFT lengths (next_fast_len)
CASES = [(300, 10, 11, 11), (300, 10, 11, 5), (300, 10, 8, 8), (257, 12, 9, 1), (5000, 60, 61, 47)]


@pytest.mark.parametrize("N, L, w, k", CASES)
@pytest.mark.parametrize("center", [True, False])
def test_gram_products_equal_the_hankel_rows(N, L, w, k, center):
    rng = np.random.default_rng(N + k)
    # correlated channels (AR(1), pole 0.95) of unequal sizes with offsets of about their
    # spread: the centring and the scaling matter. (The data stage takes off a shift
    # first, so that the centring G - s s^T / j does not cancel an offset many times
    # the spread: against rows centred first, that cancellation alone costs the
    # squared ratio in relative accuracy, here as in pbsid._window_stats.)
    z, acc, op, G = _record(rng, N, L, w, k, center)
    assert op.j == N - w + 1 and op.k == k
    Y = rng.standard_normal((4, k * 5))
    ey = op.encode(Y)
    for r in (1, 3, 66):
        X = rng.standard_normal((r, k * 5))
        ex = op.encode(X)
        # one encoding with itself, with another one, and row slices of one
        for got, ref in [
            (op.inner(ex, ex), X @ G @ X.T),
            (op.inner(ex, ey), X @ G @ Y.T),
            (op.inner(ex[r // 2 :], ex[: r // 2 + 1]), X[r // 2 :] @ G @ X[: r // 2 + 1].T),
        ]:
            assert np.max(np.abs(got - ref)) < 1e-12 * np.max(np.abs(ref))
    np.testing.assert_array_equal(acc.head, z[:L])  # the data stage's state is untouched


def test_encodings_survive_the_next_encoding():
    # The operator reuses its FFT buffers from one encoding of r rows to the next (the
    # temporaries are MB-sized): an encoding must keep nothing of them. Reference: the
    # first encoding's products, taken before the second encoding was made.
    rng = np.random.default_rng(7)
    z = rng.standard_normal((2000, 5))
    acc = _LagGram(5, 40)
    acc.update(z)
    op = GramOperator(acc, 41, 30, z.std(axis=0), True)
    X1, X2 = rng.standard_normal((2, 66, 30 * 5))
    e1 = op.encode(X1)
    before = op.inner(e1, e1)
    e2 = op.encode(X2)
    np.testing.assert_array_equal(op.inner(e1, e1), before)
    assert not np.allclose(op.inner(e2, e2), before)
    # the block-major entry point is the same encoding
    e3 = op.encode_blocks(np.ascontiguousarray(X1.reshape(66, 30, 5).transpose(1, 0, 2)))
    for a, b in [(e3.flat, e1.flat), (e3.yh, e1.yh), (e3.yt, e1.yt), (e3.sp, e1.sp)]:
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-14 * np.max(np.abs(b)))


def test_gram_operator_refuses_a_window_beyond_the_lags():
    acc = _LagGram(5, 10)
    acc.update(np.random.default_rng(0).standard_normal((100, 5)))
    with pytest.raises(ValueError, match="window"):
        GramOperator(acc, 12, 5, np.ones(5), True)
    with pytest.raises(ValueError, match="window"):
        GramOperator(acc, 8, 9, np.ones(5), True)


@pytest.mark.parametrize("N, L, w, k, b", [(300, 10, 11, 11, 10), (5000, 60, 61, 47, 47)])
@pytest.mark.parametrize("center", [True, False])
def test_sequence_rows_equal_the_hankel_rows(N, L, w, k, b, center):
    # Rows with one scalar sequence in one channel (e_c (x) q_j, the structured fit's
    # sequence basis, docs/subspace.md (P22)) take their products from the sequences'
    # spectra alone. Reference: the same rows written out (b blocks of sequence, the
    # rest zero) against the dense Gram of the Hankel rows, as above; measured
    # at most 9e-15 of the largest product, asserted 1e-12.
    _, _, op, G = _record(np.random.default_rng(N + b), N, L, w, k, center)
    rng = np.random.default_rng(b)

    def written(Q):  # rows (j, c): Q[:, j] in channel c over the first blocks
        X = np.zeros((Q.shape[1], 5, k, 5))
        for c in range(5):
            X[:, c, : Q.shape[0], c] = Q.T
        return X.reshape(Q.shape[1] * 5, k * 5)

    Q, U = rng.standard_normal((b, 3)), np.eye(min(4, k))  # a basis; unit rows (P14's)
    S, T = op.encode_sequences(Q), op.encode_sequences(U)
    X, E = written(Q), written(U)
    Y = rng.standard_normal((3, k * 5))
    for got, ref in [
        (op.sequence_gram(S), X @ G @ X.T),
        (op.sequence_gram(S, T), X @ G @ E.T),
        (op.inner_sequences(op.encode(Y), S), Y @ G @ X.T),
        (op.inner_sequences(op.encode(Y), T), Y @ G @ E.T),
    ]:
        assert np.max(np.abs(got - ref)) < 1e-12 * np.max(np.abs(ref))
    with pytest.raises(ValueError, match="blocks"):
        op.encode_sequences(np.ones((k + 1, 2)))
