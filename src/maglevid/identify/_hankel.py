"""Block-Hankel statistics in linear memory: the data stage of the subspace methods.

The subspace methods (:mod:`maglevid.identify.subspace`) need one thing from the
data: a factor ``F`` with ``F F^T = H^T H / j`` of the block-Hankel matrix

.. math::

    H = \\begin{bmatrix} z(0)^T & z(1)^T & \\cdots & z(w-1)^T \\\\
                        z(1)^T & z(2)^T & \\cdots & z(w)^T \\\\
                        \\vdots \\\\
                        z(j-1)^T & \\cdots & & z(N-1)^T \\end{bmatrix},
    \\qquad z(t) = \\begin{bmatrix} u(t) \\\\ y(t) \\end{bmatrix},

(time-first: one row per window start ``t``, ``j`` rows, ``k = w m`` columns,
``m = nu + ny``). ``F`` stands for the triangular factor ``L`` of the LQ
decomposition of the textbook (variables-as-rows) Hankel matrix ``H^T = L Q^T``:
any ``F`` with ``F F^T = L L^T`` represents the data rows in an orthonormal basis
of their span, so every row-space projection of the subspace algorithms can be
done on ``F`` alone. The full ``j x k`` matrix is never formed.

Two accumulators produce it, both fed chunk by chunk (so a record of 10^8
samples never has to be in memory) and both giving the same result, to
rounding, whatever the chunk boundaries:

``_LagGram`` (``factorization="gram"``, the fast route)
    The Gram matrix of a block-Hankel matrix is block-Toeplitz up to edge terms:

    .. math::

        G_{ab} = \\sum_{t=0}^{j-1} z(t+a) z(t+b)^T
               = S_\\tau - \\sum_{s=0}^{a-1} z(s) z(s+\\tau)^T
                 + \\sum_{s=N-L}^{a+j-1} z(s) z(s+\\tau)^T, \\qquad \\tau = b - a,

    with the lagged sums ``S_tau = sum_{s=0}^{N-1-L} z(s) z(s+tau)^T`` over every
    start ``s`` whose ``L`` successors exist, ``L`` the largest lag kept. The
    ``L + 1`` sums cost ``2 (L+1) m^2`` flops per sample, ``i`` times fewer than
    a Gram of the Hankel rows (``(2 i m)^2``); the edge sums need only the first
    and the last ``L`` samples. The Gram of ANY window ``w <= L + 1`` follows, so
    the horizon can be chosen after the pass over the data. The factor is then a
    pivoted Cholesky factorisation (LAPACK ``dpstrf``) of the channel-scaled
    Gram: no regularisation is added; directions whose Schur complement falls
    below ``k * eps * max(diag)`` (rounding level) are dropped, which is exact
    for the computed Gram. The Gram squares the condition number, so directions
    that are exactly dependent in noise-free data come out at about
    ``sqrt(eps)`` relative; see ``docs/subspace.md`` for the measured cost.

``_HankelQR`` (``factorization="qr"``, the accurate route)
    Tall-skinny QR: the Hankel rows of each chunk are stacked under the running
    triangular factor and re-triangularised by Householder QR (LAPACK
    ``dgeqrf``), ``R <- qr([R; H_chunk])``. Backward stable (errors of order
    ``eps`` relative, not ``sqrt(eps)``); about 5-20 times slower than the Gram
    route, and the window is fixed when the accumulator is made.
"""

from __future__ import annotations

import functools
from collections.abc import Iterator

import numpy as np
import scipy.linalg as sla
from numpy.lib.stride_tricks import as_strided, sliding_window_view
from scipy.linalg import lapack

from maglevid.exceptions import DataError

__all__: list[str] = []

#: Groups of ``L`` samples per GEMM in the lagged sums: 2048 x (L m) doubles (0.8 MB at
#: L = 19, m = 5) stay in the L2/L3 cache.
_GROUP_BLOCK = 2048


def _pieces(pending: np.ndarray, z: np.ndarray, span: int) -> Iterator[tuple[np.ndarray, int]]:
    """Yield ``(X, n_starts)``: windows ``X[s:s+span+1]`` for ``s < n_starts`` are complete.

    ``pending`` holds the last ``min(n, span)`` samples seen so far (whose windows
    were not complete); ``z`` is the new chunk. The windows are yielded exactly
    once over all calls, whatever the chunking. The big chunk ``z`` is not copied.
    """
    c0 = pending.shape[0]
    if c0:
        junction = np.concatenate([pending, z[:span]])
        n_st = min(c0, junction.shape[0] - span)
        if n_st > 0:
            yield junction, n_st
        if n_st < c0:  # the chunk was too short to complete the pending windows
            return
    n_z = z.shape[0] - span
    if n_z > 0:
        yield z, n_z


def _new_pending(pending: np.ndarray, z: np.ndarray, span: int) -> np.ndarray:
    """The last ``span`` samples of ``[pending; z]`` (all of them when fewer)."""
    if z.shape[0] >= span:
        return np.array(z[z.shape[0] - span :], dtype=float)
    return np.concatenate([pending, z])[-span:].copy()


class _Moments:
    """Running channel sums (for scaling and for the mean in fit percentages)."""

    def __init__(self, m: int, squares: bool = True) -> None:
        self.n = 0
        self.sum = np.zeros(m)
        self.sumsq = np.zeros(m)
        self.squares = squares  # False: the owner fills in sumsq (``_LagGram``: from S_0)

    def update(self, z: np.ndarray) -> None:
        self.n += z.shape[0]
        self.sum += np.einsum("ij->j", z)  # 5x faster than z.sum(axis=0) on (N, 5)
        if self.squares:
            self.sumsq += np.einsum("ij,ij->j", z, z)

    def rms(self) -> np.ndarray:
        return np.sqrt(self.sumsq / max(self.n, 1))

    def mean(self) -> np.ndarray:
        return self.sum / max(self.n, 1)


class _LagGram:
    """Lagged sums ``S_tau`` plus head and tail samples: the Gram of any window <= L+1.

    Parameters
    ----------
    m : int
        Channels of ``z = [u, y]``.
    max_lag : int
        ``L``, the largest lag kept (window ``w = L + 1`` at most).
    """

    def __init__(self, m: int, max_lag: int) -> None:
        self.m = m
        self.L = max_lag
        self._p = max(max_lag, 1)  # samples per group of the grouped products
        pm = self._p * m
        self._S = np.zeros((max_lag + 1, m, m))  # the starts not in a group
        self._S_total: np.ndarray | None = None  # S, folded; None after an update
        # [W, C] in one buffer (W = sum_k P_k^T P_k, C = sum_k P_k^T P_{k+1}: the blocks
        # the fold reads), so that _fold reads both without a copy
        self._WC = np.zeros((pm, 2 * pm))
        self._half = (self._p // 2) * m  # columns of the first half of a group's samples
        # The same sums from ``update_split`` (u and y apart), columns in the split layout
        # of ``_split_layout``; folded into W and C when S is read.
        self._Ws: np.ndarray | None = None
        self._Cs: np.ndarray | None = None
        self._nu = 0
        self.head = np.empty((0, m))
        self.pending = np.empty((0, m))
        self._moments = _Moments(m, squares=False)

    @property
    def n(self) -> int:
        return self._moments.n

    @property
    def moments(self) -> _Moments:
        """Channel sums; the sums of squares are the diagonal of ``S_0`` (every start
        whose L successors exist) plus the last ``L`` samples: no pass of their own."""
        mo = self._moments
        tail = self.pending
        mo.sumsq = np.diagonal(self.S[0]).copy() + np.einsum("ij,ij->j", tail, tail)
        return mo

    @property
    def S(self) -> np.ndarray:
        """``S_tau``, tau = 0..L, shape (L+1, m, m)."""
        if self._S_total is None:
            self._S_total = self._S + self._fold()
            self._S_total.flags.writeable = False
        return self._S_total

    def update(self, z: np.ndarray) -> None:
        L = self.L
        if self.head.shape[0] < L:
            self.head = np.concatenate([self.head, z[: L - self.head.shape[0]]])
        for X, n_st in _pieces(self.pending, z, L):
            self._accumulate(X, n_st)
        self.pending = _new_pending(self.pending, z, L)
        self._moments.update(z)
        self._S_total = None

    def load_fft(self, z: np.ndarray) -> None:
        """The whole record at once, its lagged products by FFT (:func:`lag_products_fft`).

        Only as the first and only update (nothing accumulated yet): the same head,
        tail and channel sums as ``update(z)``, the ``S_tau`` equal to the direct
        sums to rounding (relative to ``sqrt(S_ii(0) S_jj(0))``; docs/subspace.md,
        "sixth session"). Faster for long windows: O(N log L m^2) instead of
        O(N L m^2).
        """
        N, L = z.shape[0], self.L
        if self.n or N < self.min_samples():
            raise ValueError("load_fft takes a whole record of at least 2 L + 1 samples")
        self.head = np.ascontiguousarray(z[:L])
        self.pending = np.ascontiguousarray(z[N - L :])
        self._moments.update(z)
        S = lag_products_fft(z, L, N - L)
        self._S = S
        self._S_total = S.copy()
        self._S_total.flags.writeable = False

    def update_split(self, u: np.ndarray, y: np.ndarray) -> None:
        """``update(np.concatenate([u, y], axis=1))`` without interleaving the chunk.

        The interleaved copy ``z = [u, y]`` of a record (rows of 2 + 3 doubles)
        cost as much as a third of the lagged products at N = 10^6. Here whole
        groups of ``p`` samples of ``u`` and of ``y`` are each a row of a reshape
        (no copy), copied per block of groups into one cache-resident buffer
        (row segments of ``p nu`` and ``p ny`` doubles) on which the same two GEMMs
        run; only the first ``L`` and the last ``2 L`` samples are interleaved.
        The same sums as ``update`` to rounding, whatever the chunking.
        """
        n, nu = u.shape
        L, p = self.L, self._p
        if self._nu and nu != self._nu:
            raise ValueError(f"u has {nu} channels; earlier chunks had {self._nu}")
        if n < 2 * p + L or 0 < self.pending.shape[0] < L:
            self.update(np.concatenate([u, y], axis=1))  # short: the general route
            return
        self._nu = nu
        if self.head.shape[0] < L:
            k = L - self.head.shape[0]
            self.head = np.concatenate([self.head, np.concatenate([u[:k], y[:k]], axis=1)])
        if self.pending.shape[0]:  # the starts left by the last chunk: a few rows
            junction = np.concatenate([self.pending, np.concatenate([u[:L], y[:L]], axis=1)])
            self._accumulate(junction, L)
        n_starts = n - L
        G = n_starts // p  # whole groups; the group after the last one is in the chunk
        mo = self._moments
        if G:  # (the channel sums of the grouped samples come with the products)
            mo.sum += self._accumulate_split(u, y, G)
        s0 = G * p
        if s0 < n_starts:
            self._accumulate(np.concatenate([u[s0:], y[s0:]], axis=1), n_starts - s0)
        self.pending = np.concatenate([u[n - L :], y[n - L :]], axis=1)
        mo.n += n
        mo.sum[:nu] += np.einsum("ij->j", u[s0:])
        mo.sum[nu:] += np.einsum("ij->j", y[s0:])
        self._S_total = None

    def _accumulate_split(self, u: np.ndarray, y: np.ndarray, G: int) -> np.ndarray:
        """W and C (split layout) of the starts in groups ``0..G-1`` of ``u``, ``y``.

        Returns the channel sums over those ``G p`` samples (a GEMV per block on the
        buffer while it is in the cache: a tenth of the cost of a pass of its own).
        """
        nu, ny, L, p = u.shape[1], y.shape[1], self.L, self._p
        h = p // 2
        pm = p * self.m
        if self._Ws is None:
            self._Ws = np.zeros((pm, pm))
            self._Cs = np.zeros((pm, pm))
        assert self._Cs is not None
        # split layout: [u, y of the first h samples | u, y of the last p - h samples]
        cut = (0, h * nu, h * self.m, h * self.m + (p - h) * nu, pm)
        nxt = 1 if L else 0  # the next group (its samples are in the chunk: p = L)
        buf = np.empty((min(G, _GROUP_BLOCK) + nxt, pm))
        ones = np.ones(min(G, _GROUP_BLOCK))
        col_sums = np.zeros(pm)
        for g0 in range(0, G, _GROUP_BLOCK):
            nb = min(_GROUP_BLOCK, G - g0)
            rows = nb + nxt
            Ub = u[g0 * p : (g0 + rows) * p].reshape(rows, p * nu)  # a view when contiguous
            Yb = y[g0 * p : (g0 + rows) * p].reshape(rows, p * ny)
            B = buf[:rows]
            B[:, cut[0] : cut[1]] = Ub[:, : h * nu]
            B[:, cut[1] : cut[2]] = Yb[:, : h * ny]
            B[:, cut[2] : cut[3]] = Ub[:, h * nu :]
            B[:, cut[3] : cut[4]] = Yb[:, h * ny :]
            self._products(self._Ws, self._Cs, B[:nb], B[1:rows] if L else None)
            col_sums += ones[:nb] @ B[:nb]
        return col_sums[self._split_order()].reshape(p, self.m).sum(axis=0)

    def _accumulate(self, X: np.ndarray, n_starts: int) -> None:
        # S_tau += sum_{s < n_starts} z(s) z(s+tau)^T, tau = 0..L, as two GEMMs per block.
        # Group the starts in rows of p = L samples: P_k = [z(kp), ..., z(kp+p-1)]
        # (a reshape of the record: no copy). For s = kp + a the partner s + tau is
        # in the same group (a + tau < p: block (a, a+tau) of W = sum_k P_k^T P_k)
        # or in the next one (block (a, a+tau-p) of C = sum_k P_k^T P_{k+1}); W and C
        # are folded into S_tau when S is read. Two (pm x pm) products per block of
        # groups: 4 p m^2 flops per sample against 2 (L+1) m^2 for one (m x m)
        # product per lag, but at GEMM speed (the one-lag products, m = 5 columns,
        # ran at a quarter of it).
        L, p = self.L, self._p
        G = n_starts // p
        if G:
            pm = p * self.m
            W, C = self._WC[:, :pm], self._WC[:, pm:]  # views: updated in place
            P = X[: G * p].reshape(G, pm)
            Pn = X[p : (G + 1) * p].reshape(G, pm) if L else None
            for g0 in range(0, G, _GROUP_BLOCK):
                Pb = P[g0 : g0 + _GROUP_BLOCK]
                self._products(W, C, Pb, None if Pn is None else Pn[g0 : g0 + _GROUP_BLOCK])
        s0 = G * p  # the last starts (fewer than p): one product per lag
        if s0 < n_starts:
            XT = X[s0:n_starts].T
            for tau in range(L + 1):
                self._S[tau] += XT @ X[s0 + tau : n_starts + tau]

    def _products(
        self, W: np.ndarray, C: np.ndarray, Pb: np.ndarray, Pn: np.ndarray | None
    ) -> None:
        """``W += Pb^T Pb`` and the blocks of ``C += Pb^T Pn`` that the fold reads.

        The columns of the first ``h = p // 2`` samples of a group come first (both
        layouts). The partner of start ``a`` in the next group is sample
        ``a + tau - p <= a`` (``p = L``): the rows of the first half need only the
        first half's columns of ``C``, so a quarter of ``C`` (never read) is not
        computed: 25 % fewer flops in ``C``.
        """
        W += Pb.T @ Pb  # (numpy: SYRK for a product with its own transpose)
        if Pn is None:
            return
        h = self._half
        C[h:] += Pb[:, h:].T @ Pn
        C[:h, :h] += Pb[:, :h].T @ Pn[:, :h]

    def _split_order(self) -> np.ndarray:
        """Column of the split layout for each column of the interleaved (z) layout."""
        return _split_order(self._p, self.m, self._nu)

    def _fold(self) -> np.ndarray:
        """The lag-tau blocks of the grouped products ``W``, ``C``, summed per lag."""
        m, p = self.m, self._p
        WC = self._WC
        if self._Ws is not None:
            assert self._Cs is not None
            pm = p * m
            WC = WC.copy()
            # W_s[k][:, k]: the split layout's 16 blocks copied into place (the same
            # values; a flat take over the (p m)^2 entries was 0.25-0.5 s at p = 381)
            WC[:, :pm] += _interleave(self._Ws, p, m, self._nu)
            WC[:, pm:] += _interleave(self._Cs, p, m, self._nu)
        # E[a, :, c, :] = block (a, c) of [W, C]: the partner of start a at lag tau is
        # column block c = a + tau (c >= p: the next group, C).
        E = WC.reshape(p, m, 2 * p, m)  # E[a, :, c, :]: block (a, c) of [W, C]
        # A strided view D[tau, i, j, a] = E[a, i, a + tau, j] (no copy), summed over a
        # along its last axis: ~100x faster than gathering by fancy indices (which was
        # half of SSARX's time at N = 1e4, issue 16); the same sums in another order.
        s0, s1, s2, s3 = E.strides
        D = as_strided(E, (self.L + 1, m, m, p), (s2, s1, s3, s0 + s2), writeable=False)
        return D.sum(axis=-1)  # (L+1, m, m)

    def min_samples(self) -> int:
        """Samples needed for the edge formula (head and tail disjoint from the middle)."""
        return 2 * self.L + 1

    def gram(self, w: int, blocks: int | None = None) -> np.ndarray:
        """``H^T H`` (unnormalised) for windows of ``w <= L + 1`` samples, rows 0..N-w.

        ``blocks``: only the leading ``blocks`` block rows and columns (the samples
        ``z(0..blocks-1)`` of the window, still summed over the window's ``N - w + 1``
        rows): the same numbers as ``gram(w)[:blocks m, :blocks m]``, at
        ``(blocks / w)^2`` of the cost (the structured fit's window (P16) is shorter
        than the lags kept; docs/subspace.md, "sixth session").

        Block ``(a, a + tau)`` is ``S_tau`` less the head's ``sum_{s<a} z(s) z(s+tau)^T``,
        plus the tail's ``sum_{q=0}^{a+L-w} tail(q) tail(q+tau)^T`` (``tail(q) =
        z(N-L+q)``). Both edge sums are running sums over ``a`` for every lag at
        once (:func:`_edge_sums`), so that block row ``a`` of the upper triangle is
        one contiguous write and the lower triangle its mirror: the same numbers
        (the same products, summed in the same order) as one lag at a time, whose
        ``k`` diagonals of scattered 5 x 5 blocks and ~10 small calls per lag were
        35 ms of the structured fit's 1530-row Gram (docs/subspace.md, "seventh session").
        """
        L, m, N = self.L, self.m, self.n
        if not 1 <= w <= L + 1:
            raise ValueError(f"window {w} outside 1..{L + 1}")
        k = w if blocks is None else blocks
        if not 1 <= k <= w:
            raise ValueError(f"blocks {k} outside 1..{w}")
        if N < self.min_samples():
            raise DataError(f"{N} samples are too few for lags up to {L}")
        St = self.S[:k].transpose(1, 0, 2)  # St[i, tau, j] = S_tau[i, j]
        G = np.empty((k * m, k * m))
        G4 = G.reshape(k, m, k, m)
        rows = max(1, _EDGE_CHUNK // (k * m * m))  # block rows per chunk: ~1 MB temporaries
        heads = _edge_sums(self.head, k, 0, k, rows)  # block row a: s < a
        tails = _edge_sums(self.pending, k, L - w + 1, k, rows)  # q < a + L - w + 1
        for (a0, hc), (_, tc) in zip(heads, tails, strict=True):
            blk = np.subtract(St[:, : hc.shape[2]], hc, out=hc)
            blk += tc
            for i in range(hc.shape[0]):  # block row a: blocks (a, a + tau), tau < k - a
                a = a0 + i
                G4[a, :, a:, :] = blk[i, :, : k - a]
        for a in range(1, k):  # the strictly lower triangle: the upper's mirror
            G[a * m : (a + 1) * m, : a * m] = G[: a * m, a * m : (a + 1) * m].T
        return G


#: Entries of one chunk of :func:`_edge_sums` (8 MB at most, ~1 MB for 5 channels).
_EDGE_CHUNK = 1 << 17


def _edge_sums(
    x: np.ndarray, k: int, first: int, n: int, rows: int
) -> Iterator[tuple[int, np.ndarray]]:
    """Running lagged sums ``C[r, i, tau, j] = sum_{q < r} x_i(q) x_j(q + tau)``, ``tau < k``.

    Yields ``(a0, C[first + a0 : first + a0 + rows, :, :k - a0])`` for ``a0 = 0,
    rows, ...`` below ``n`` (the rows before ``first`` are summed, not yielded):
    block row ``a`` of the Gram needs lags below ``k - a`` only. Rows of ``x`` past
    its end count as zeros. Summed in ``q`` order, row by row (``np.cumsum``'s
    order; a ``cumsum`` along the first axis loops over it innermost, 3x slower),
    each chunk continuing the last row of the one before: the same numbers as one
    running sum over all rows. The yielded array is the caller's to overwrite until
    the next one is drawn: one buffer holds every chunk (a fresh ~1 MB array per chunk
    was page-faulted in again whenever the caller's Gram had been allocated just
    before it, glibc trimming the freed chunks: 2.5 ms of SSARX's 5.7 ms Gram at
    N = 1e4, twenty-ninth session).
    """
    m = x.shape[1]
    total = first + n
    xp = np.zeros((total + k, m))  # x behind one zero row: C[r] sums q < r
    xp[1 : min(x.shape[0] + 1, xp.shape[0])] = x[: xp.shape[0] - 1]
    flat = xp.reshape(-1)
    starts = [*range(0, first, rows), *range(first, total, rows)]
    buf = np.empty(min(rows, max(total, 1)) * m * k * m)
    carry = None
    for r0, r1 in zip(starts, [*starts[1:], total], strict=True):
        lags = k if r0 < first else k - (r0 - first)
        # P[r, i, (tau, j)] = xp_i(r) xp_j(r + tau): samples r..r+lags-1, flat, are one
        # window of the flat record (a view)
        ahead = sliding_window_view(flat[r0 * m : (r1 + lags - 1) * m], lags * m)[::m]
        P = buf[: (r1 - r0) * m * lags * m].reshape(r1 - r0, m, lags * m)
        np.multiply(xp[r0:r1, :, None], ahead[:, None, :], out=P)
        if carry is not None:
            P[0] += carry[:, : lags * m]
        for r in range(1, r1 - r0):
            P[r] += P[r - 1]
        carry = P[-1].copy()
        if r0 >= first:
            yield r0 - first, P.reshape(r1 - r0, m, lags, m)


#: Samples per FFT block of :func:`lag_products_fft` at least this many times the lags.
_FFT_BLOCK_RATIO = 3
#: Blocks transformed together (bounds the temporaries: ~50 MB at 4096-point blocks).
_FFT_CHUNK = 128


def lag_products_fft(z: np.ndarray, L: int, n_starts: int) -> np.ndarray:
    """``S_tau = sum_{s < n_starts} z(s) z(s + tau)^T``, tau = 0..L, by blocked FFT.

    Overlap-save cross-correlation: the starts in blocks of ``B`` samples, each
    block ``X = z(s0..s0+B-1)`` and its continuation ``Y = z(s0..s0+B+L-1)``
    zero-padded to ``nfft >= B + L`` points, so that the circular correlation
    ``irfft(conj(X_f) Y_f)`` at lags 0..L has no wrapped terms. The cross-spectra
    ``conj(X_f)^T Y_f`` (m x m per frequency) are summed over the blocks and
    inverted once at the end: O(N m log nfft + N m^2) against the direct sums'
    O(N L m^2). ``z`` needs ``n_starts + L`` rows.
    """
    N, m = z.shape
    if n_starts + L > N:
        raise ValueError(f"{n_starts} starts and {L} lags need {n_starts + L} samples, not {N}")
    nfft = 1 << max(int(_FFT_BLOCK_RATIO * L + L - 1).bit_length(), 4)
    B = nfft - L
    z = np.ascontiguousarray(z, dtype=float)
    nf = nfft // 2 + 1
    Sf = np.zeros((nf, m, m), dtype=complex)
    s0, s1 = z.strides
    n_full = n_starts // B
    for b0 in range(0, n_full, _FFT_CHUNK):
        nb = min(_FFT_CHUNK, n_full - b0)
        X = z[b0 * B : (b0 + nb) * B].reshape(nb, B, m)
        Y = as_strided(z[b0 * B :], (nb, B + L, m), (B * s0, s0, s1), writeable=False)
        Xf = np.fft.rfft(X, n=nfft, axis=1).transpose(1, 2, 0).conj()  # (nf, m, nb)
        Yf = np.fft.rfft(Y, n=nfft, axis=1).transpose(1, 0, 2)  # (nf, nb, m)
        Sf += Xf @ Yf
    r = n_starts - n_full * B  # the last, partial block
    if r:
        a = n_full * B
        Xf = np.fft.rfft(z[a : a + r], n=nfft, axis=0)
        Yf = np.fft.rfft(z[a : a + r + L], n=nfft, axis=0)
        Sf += Xf.conj()[:, :, None] * Yf[:, None, :]
    return np.fft.irfft(Sf, n=nfft, axis=0)[: L + 1].copy()


@functools.lru_cache(maxsize=8)
def _split_order(p: int, m: int, nu: int) -> np.ndarray:
    """``k``: the column of the split layout for each column of the interleaved (z) layout
    of ``p`` samples of ``m`` channels (``nu`` inputs first). Cached, read-only."""
    ny, h = m - nu, p // 2
    a = np.arange(p)[:, None]
    c = np.arange(m)[None, :]
    first = np.where(c < nu, a * nu + c, h * nu + a * ny + (c - nu))
    ah = a - h
    second = h * m + np.where(c < nu, ah * nu + c, (p - h) * nu + ah * ny + (c - nu))
    k = np.where(a < h, first, second).reshape(-1)
    k.flags.writeable = False
    return k


def _interleave(X: np.ndarray, p: int, m: int, nu: int) -> np.ndarray:
    """``X[k][:, k]`` with ``k`` of :func:`_split_order`: a (p m x p m) matrix of the
    split layout in the interleaved one, by 16 strided block copies."""
    h = p // 2
    # (first sample, samples, first channel, channels, offset in the split layout)
    seg = [(0, h, 0, nu, 0), (0, h, nu, m - nu, h * nu)]
    seg += [(h, p - h, 0, nu, h * m), (h, p - h, nu, m - nu, h * m + (p - h) * nu)]
    out = np.empty((p, m, p, m))
    for a0, na, c0, nc, ro in seg:
        Xr = X[ro : ro + na * nc]
        for b0, nb, d0, nd, co in seg:
            blk = Xr[:, co : co + nb * nd].reshape(na, nc, nb, nd)
            out[a0 : a0 + na, c0 : c0 + nc, b0 : b0 + nb, d0 : d0 + nd] = blk
    return out.reshape(p * m, p * m)


@functools.lru_cache(maxsize=64)
def _upper_blocks(w: int) -> tuple[np.ndarray, np.ndarray]:
    """Block indices ``(a, b)``, ``a <= b < w`` (``np.triu_indices``, cached: 0.1-2 ms each)."""
    a, b = np.triu_indices(w)
    a.flags.writeable = False
    b.flags.writeable = False
    return a, b


class _HankelQR:
    """Running triangular factor ``R`` of the Hankel rows (tall-skinny QR), window ``w``."""

    def __init__(self, m: int, window: int) -> None:
        self.m = m
        self.w = window
        self.k = window * m
        self.R = np.empty((0, self.k))
        self.pending = np.empty((0, m))
        self.moments = _Moments(m)
        self.block = max(8 * self.k, 4096)

    @property
    def n(self) -> int:
        return self.moments.n

    def update(self, z: np.ndarray) -> None:
        span = self.w - 1
        for X, n_st in _pieces(self.pending, z, span):
            for s0 in range(0, n_st, self.block):
                s1 = min(n_st, s0 + self.block)
                Hc = sliding_window_view(X[s0 : s1 + span], (self.w, self.m))
                Hc = Hc.reshape(s1 - s0, self.k)  # copies: rows [z(s), ..., z(s+w-1)]
                self.R = np.linalg.qr(np.concatenate([self.R, Hc]), mode="r")
        self.pending = _new_pending(self.pending, z, span) if span else np.empty((0, self.m))
        self.moments.update(z)


def factor_gram(G: np.ndarray) -> tuple[np.ndarray, int]:
    """``F`` (k x r) with ``F F^T = G`` by pivoted Cholesky; ``r`` is the numerical rank.

    ``G`` should be scaled to unit-order diagonal first. LAPACK ``dpstrf`` stops
    when the largest remaining pivot falls below ``k * eps * max(diag(G))``; the
    discarded Schur complement is at the rounding level of ``G`` itself, so no
    regularisation is needed and none is added.
    """
    k = G.shape[0]
    tol = k * np.finfo(float).eps * float(np.max(np.diag(G)))
    c, piv, rank, info = lapack.dpstrf(G, tol=tol, lower=1)
    if info < 0:  # pragma: no cover - LAPACK argument error
        raise RuntimeError(f"dpstrf failed with info={info}")
    F = np.zeros((k, rank))
    F[piv - 1] = np.tril(c)[:, :rank]
    return F, int(rank)


def factor_r(R: np.ndarray) -> np.ndarray:
    """``F = R^T`` from a QR factor (already exact for ``R^T R``)."""
    return np.ascontiguousarray(R.T)


def lower_factor(F: np.ndarray) -> np.ndarray:
    """Lower-trapezoidal ``L`` with ``L L^T = F F^T`` (rows kept in ``F``'s order)."""
    R = sla.qr(F.T, mode="r", check_finite=False)[0]
    return R[: min(R.shape)].T
