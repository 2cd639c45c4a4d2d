"""Lagged products by blocked FFT (issue 16, sixth session).

Reference: the direct sums of ``_LagGram.update`` (tested against the Hankel
rows' products in test_lag_gram_split.py). The FFT's rounding is relative to
the channels' energies, so the bound is on ``|S_fft - S| / sqrt(S_ii(0)
S_jj(0))``: measured 0.8e-15 - 1.5e-15 on the bench records (N = 1e4 - 1e6, 100-457
lags), including the nearly noise-free paper-like one; asserted 1e-13.
"""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.identify._hankel import _LagGram, lag_products_fft


def _direct(z: np.ndarray, L: int) -> _LagGram:
    acc = _LagGram(z.shape[1], L)
    acc.update(z)
    return acc


def _rel_err(S: np.ndarray, ref: np.ndarray) -> float:
    d = np.sqrt(np.diag(ref[0]))
    return float(np.max(np.abs(S - ref) / np.outer(d, d)))


@pytest.mark.parametrize("N, L", [(41, 20), (500, 7), (3001, 64), (20_000, 250)])
def test_fft_lag_products_equal_the_direct_sums(N, L):
    # mixed scales (volts, amperes, metres) and a mean, as a record before centring
    rng = np.random.default_rng(N)
    z = rng.standard_normal((N, 5)) * [1.0, 3.0, 1e-5, 2e-5, 1e-4] + [0.5, 0.0, 1e-5, 0.0, 0.0]
    ref = _direct(z, L)
    assert _rel_err(lag_products_fft(z, L, N - L), ref.S) < 1e-13
    acc = _LagGram(5, L)
    acc.load_fft(z)
    assert _rel_err(acc.S, ref.S) < 1e-13
    for name in ("head", "pending"):
        assert np.array_equal(getattr(acc, name), getattr(ref, name))
    assert acc.n == ref.n and np.allclose(acc.moments.sum, ref.moments.sum, rtol=1e-13)
    w = min(L + 1, 9)
    G, Gref = acc.gram(w), ref.gram(w)
    d = np.sqrt(np.diag(Gref))
    assert np.max(np.abs(G - Gref) / np.outer(d, d)) < 1e-13


def test_fft_lag_products_on_the_paper_like_record():
    # the nearly noise-free record (1e-10 m sensor noise), centred as the fit does
    from benchmarks.bench_amb_speed import bearing_case

    d, _ = bearing_case(20_000, case="diagnostic")
    z = np.concatenate([d.u, d.y], axis=1)
    z -= z[:5000].mean(axis=0)
    assert _rel_err(lag_products_fft(z, 300, 20_000 - 300), _direct(z, 300).S) < 1e-13


def test_load_fft_is_the_only_update():
    z = np.random.default_rng(0).standard_normal((200, 3))
    acc = _LagGram(3, 10)
    acc.update(z)
    with pytest.raises(ValueError, match="whole record"):
        acc.load_fft(z)
    with pytest.raises(ValueError, match="whole record"):
        _LagGram(3, 10).load_fft(z[:20])
    with pytest.raises(ValueError, match="samples"):
        lag_products_fft(z, 10, 195)
