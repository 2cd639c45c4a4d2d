"""``_LagGram.update_split`` (u and y apart, no interleaved copy) against the direct sums.

Reference: the lagged sums ``S_tau = sum_s z(s) z(s + tau)^T`` computed directly
(``z[:N-L].T @ z[tau:N-L+tau]``), the definition in ``identify/_hankel.py``; and the
interleaved route ``update(z)`` of the same module, which the fits used before.
"""

import itertools
import tracemalloc

import numpy as np
import pytest

from maglevid.identify._hankel import _LagGram


def _direct(z: np.ndarray, L: int) -> np.ndarray:
    N = z.shape[0]
    return np.stack([z[: N - L].T @ z[t : N - L + t] for t in range(L + 1)])


@pytest.mark.parametrize(
    ("N", "nu", "ny", "L"),
    [(20_000, 2, 3, 19), (7_001, 1, 2, 6), (3_000, 2, 1, 1), (2_000, 1, 1, 0)],
)
def test_split_equals_direct_sums_whatever_the_chunks(N, nu, ny, L):
    rng = np.random.default_rng(N + L)
    u = rng.standard_normal((N, nu))
    y = rng.standard_normal((N, ny)) + 2.0  # a mean: the channel sums are checked too
    z = np.concatenate([u, y], axis=1)
    ref = _direct(z, L)
    whole = _LagGram(nu + ny, L)
    whole.update_split(u, y)
    chunked = _LagGram(nu + ny, L)
    # chunks shorter than a group, than L, and long ones; the split and general routes mix
    cuts = sorted({0, 1, 3, L + 2, 5 * L + 40, N // 3, N // 3 + 7, N - 5, N})
    for a, b in itertools.pairwise(cuts):
        chunked.update_split(u[a:b], y[a:b])
    interleaved = _LagGram(nu + ny, L)
    interleaved.update(z)
    scale = np.abs(ref).max()
    for acc in (whole, chunked):
        assert acc.n == N
        np.testing.assert_allclose(acc.S, ref, rtol=0, atol=1e-13 * scale)  # rounding
        np.testing.assert_allclose(acc.S, interleaved.S, rtol=0, atol=1e-13 * scale)
        np.testing.assert_allclose(acc.moments.sum, z.sum(axis=0), rtol=1e-12)
        np.testing.assert_allclose(acc.moments.sumsq, (z * z).sum(axis=0), rtol=1e-12)
        np.testing.assert_array_equal(acc.head, interleaved.head)
        np.testing.assert_array_equal(acc.pending, interleaved.pending)
        w = L + 1
        np.testing.assert_allclose(acc.gram(w), interleaved.gram(w), rtol=0, atol=1e-13 * scale)


def test_split_memory_does_not_grow_with_the_record():
    # The split route copies a block of groups at a time (a cache-sized buffer), never
    # the record: its peak allocation is the same for 10^5 and 10^6 samples.
    rng = np.random.default_rng(0)
    peaks = []
    for N in (100_000, 1_000_000):
        u = rng.standard_normal((N, 2))
        y = rng.standard_normal((N, 3))
        acc = _LagGram(5, 19)
        tracemalloc.start()
        acc.update_split(u, y)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    assert peaks[1] < 1.5 * peaks[0] + 100_000
    assert peaks[1] < 4 * 2**20  # bytes: the (2049 x 95) buffer and the sums, not 40 MB


def test_moesp_through_the_split_route_equals_the_interleaved_route(monkeypatch):
    # The fit from update_split against the same fit with update_split replaced by the
    # former interleaved route (update of z = [u, y]): the same model to rounding.
    from benchmarks.bench_subspace import make_data

    from maglevid.identify.subspace import fit_moesp

    y, u, _ = make_data(30_000, 0.1)
    split = fit_moesp(y, u, order=4, horizon=10)
    monkeypatch.setattr(
        _LagGram, "update_split", lambda self, u, y: self.update(np.concatenate([u, y], axis=1))
    )
    inter = fit_moesp(y, u, order=4, horizon=10)
    for a, b in ((split.model.A, inter.model.A), (split.model.C, inter.model.C)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-11 * np.abs(b).max())
    np.testing.assert_allclose(split.model.markov(8), inter.model.markov(8), rtol=0, atol=1e-11)
