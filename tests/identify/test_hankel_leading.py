"""The leading block of a window's Gram (issue 16, sixth session).

Reference: ``_LagGram.gram(w)``, the whole Gram of the window (itself tested
against direct sums of the Hankel rows in test_lag_gram_split.py); its leading
``blocks`` block rows and columns are the same sums, so they must be bitwise
equal.
"""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.identify._hankel import _LagGram


@pytest.mark.parametrize("L, N", [(1, 50), (7, 400), (60, 5_000)])
def test_leading_blocks_equal_the_whole_gram(L, N):
    z = np.random.default_rng(L).standard_normal((N, 5)) * [1.0, 3.0, 1e-5, 2e-5, 1e-4]
    acc = _LagGram(5, L)
    acc.update(z[: N // 3])
    acc.update(z[N // 3 :])  # the head and tail kept across chunks
    for w in sorted({1, L // 2 + 1, L + 1}):
        G = acc.gram(w)
        for k in sorted({1, max(w // 3, 1), w}):
            assert np.array_equal(acc.gram(w, k), G[: 5 * k, : 5 * k]), (w, k)


def test_leading_blocks_out_of_range_are_refused():
    acc = _LagGram(2, 5)
    acc.update(np.random.default_rng(0).standard_normal((100, 2)))
    for k in (0, 5):
        with pytest.raises(ValueError, match="blocks"):
            acc.gram(4, k)
