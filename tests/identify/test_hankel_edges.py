"""The Gram's edge sums, block row by block row (issue 16, seventh session).

``_LagGram.gram`` builds block ``(a, a + tau)`` as ``S_tau`` less the head's and
plus the tail's running lagged sums, for all lags at once and in chunks of block
rows (``_edge_sums``). References:

- ``_per_lag``: the same formula one lag at a time with ``np.cumsum`` (the code
  before the change, b7871a3): the same products summed in the same order, so the
  Gram must be bitwise equal, whatever the chunking;
- ``H^T H`` of the explicit Hankel rows, to rounding.
"""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.identify import _hankel as hankel_module
from maglevid.identify._hankel import _LagGram


def _per_lag(acc: _LagGram, w: int, k: int) -> np.ndarray:
    """Block ``(a, a + tau)`` and its mirror, one lag at a time (b7871a3's gram)."""
    L, m = acc.L, acc.m
    head, tail = acc.head, acc.pending
    G = np.empty((k * m, k * m))
    for tau in range(k):
        n = k - tau
        hc = np.zeros((n, m, m))
        np.cumsum(np.einsum("si,sj->sij", head[: n - 1], head[tau : tau + n - 1]), 0, out=hc[1:])
        q = L - w + n
        tc = np.zeros((q + 1, m, m))
        np.cumsum(np.einsum("qi,qj->qij", tail[:q], tail[tau : tau + q]), 0, out=tc[1:])
        blk = acc.S[tau] - hc + tc[L - w + 1 :]
        for a in range(n):
            G[(a + tau) * m : (a + tau + 1) * m, a * m : (a + 1) * m] = blk[a].T
            G[a * m : (a + 1) * m, (a + tau) * m : (a + tau + 1) * m] = blk[a]
    return G


def _hankel_gram(z: np.ndarray, w: int, k: int) -> np.ndarray:
    j = z.shape[0] - w + 1
    H = np.concatenate([z[a : a + j] for a in range(k)], axis=1)
    return H.T @ H


@pytest.mark.parametrize("chunk", [1, 2, 3, 1 << 17])
@pytest.mark.parametrize("L, N", [(1, 50), (9, 300), (40, 2_000)])
def test_gram_equals_the_per_lag_sums_bitwise(L, N, chunk, monkeypatch):
    # 1-3 block rows per chunk at most (k <= L + 1 lags of 5 x 5): chunks carry their
    # running sums over, also through the tail rows before the first block row's
    monkeypatch.setattr(hankel_module, "_EDGE_CHUNK", chunk * 25 * (L + 1))
    rng = np.random.default_rng(L + chunk)
    z = rng.standard_normal((N, 5)) * [1.0, 3.0, 1e-5, 2e-5, 1e-4] + 0.3
    acc = _LagGram(5, L)
    acc.update(z[: N // 3])
    acc.update(z[N // 3 :])
    for w in sorted({1, L // 2 + 1, L + 1}):
        for k in sorted({1, max(w // 3, 1), w}):
            G = acc.gram(w, k)
            assert np.array_equal(G, _per_lag(acc, w, k)), (w, k)
            ref = _hankel_gram(z, w, k)
            np.testing.assert_allclose(G, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
