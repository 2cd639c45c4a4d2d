"""The Gram matrix of a Hankel window as an operator: products ``X G`` by FFT.

Why: the structured fit (``_structured.py``, docs/subspace.md (P11)-(P15))
reads the data only through products of its parameters' Markov-parameter
sensitivities with the Gram ``G`` of its window of ``k = P + 1`` samples
(``5 k`` = 1000-2300 rows on the bearing). Formed and factored, that Gram cost
as much as the rest of the fit, and each Gauss-Newton Jacobian was one
``(63 x 5k) (5k x 5k)`` product (docs/subspace.md, "sixth session"). ``G`` is
block-Toeplitz up to two corrections of low displacement rank, so ``X G`` for
``r`` rows costs ``O(r m k log k)`` by FFT instead of ``O(r m^2 k^2)``, and
``G`` itself is never formed (docs/subspace.md, "seventh session", (P18)).

What. For the Hankel rows ``t = 0..j-1`` of a window of ``w`` samples
(``j = N - w + 1``) and its leading ``k <= w`` samples, block ``(a, b)`` of the
Gram is ``G_ab = sum_{t<j} z(t+a) z(t+b)^T``. With ``St_tau`` the sum over
every pair of the record ``tau`` apart (``sum_{s <= N-1-tau} z(s) z(s+tau)^T``),

    G = T(St) - Lh Lh^T - Lt Lt^T                                            (P18)

``T(St)`` the block-Toeplitz matrix of the lags (``St_{-tau} = St_tau^T``),
``Lh`` the pairs before the first row (column ``i = 1..k-1``: block ``c`` is
``z(c - i)`` for ``c >= i``, else 0) and ``Lt`` those after the last row
(column ``i = 0..w-2``: block ``c`` is ``z(j + i + c)`` while ``i + c <= w - 2``).
Each product with ``T``, ``Lh``, ``Lh^T``, ``Lt``, ``Lt^T`` is a convolution or a
correlation of sequences of length ``<= w``: one FFT length ``n >= w + k``
holds them all without wrapping. The centring (``- s s^T / j``) and the
channel scaling follow as in the data stage (``pbsid._window_stats``), so the
operator is the same ``G`` that stage factors, to rounding.
"""

from __future__ import annotations

import numpy as np
import scipy.fft as sfft

from maglevid.identify._hankel import _LagGram

__all__: list[str] = []


class GramOperator:
    """``X -> X G``: the scaled, normalised (and centred) Gram of a window's leading samples.

    Parameters
    ----------
    acc : _LagGram
        The data stage's lagged sums (``S_tau`` up to ``L >= w - 1``, the first and
        the last ``L`` samples).
    w : int
        The window whose Hankel rows are summed (``j = N - w + 1`` rows).
    k : int
        The leading samples of the window the operator covers (``k <= w``).
    scale : ndarray, shape (m,)
        Channel scale; ``G`` is that of ``z / scale``, divided by ``j``.
    center : bool
        Subtract the rows' means (``G - s s^T / j``), as the data stage does.
    """

    def __init__(self, acc: _LagGram, w: int, k: int, scale: np.ndarray, center: bool) -> None:
        L, m, N = acc.L, acc.m, acc.n
        if not 1 <= k <= w <= L + 1:
            raise ValueError(f"window {w}, samples {k}: need 1 <= k <= w <= {L + 1}")
        self.m, self.k, self.w = m, k, w
        self.j = N - w + 1
        self.n = n = sfft.next_fast_len(w + k, real=True)
        head, tail = acc.head, acc.pending  # z(0..L-1), z(N-L..N-1)
        # every pair tau apart: S_tau (starts s <= N-1-L) plus the pairs among the tail
        nt = sfft.next_fast_len(L + k, real=True)
        tf = sfft.rfft(tail, n=nt, axis=0)
        tt = sfft.irfft(tf.conj()[:, :, None] * tf[:, None, :], n=nt, axis=0)[:k]
        St = acc.S[:k] + tt  # (k, m, m), St[tau][a, b] = sum_s z_a(s) z_b(s + tau)
        R = np.zeros((n, m, m))  # R(d) = G block (a, a + d): St_d for d >= 0, St_{-d}^T else
        R[:k] = St
        R[n - k + 1 :] = St[1:][::-1].transpose(0, 2, 1)
        self._Rf = sfft.rfft(R, axis=0)  # (nf, m, m)
        self._hf = sfft.rfft(head[: k - 1], n=n, axis=0)  # h(s) = z(s), s < k - 1
        self._gf = sfft.rfft(tail[L - (w - 1) :], n=n, axis=0)  # g(s) = z(j + s), s <= w - 2
        self._d = np.tile(1.0 / np.asarray(scale, dtype=float), k)
        self._s = _window_sums(acc, w, k) if center else None
        self._bufs: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def __call__(self, X: np.ndarray) -> np.ndarray:
        """``X G`` for ``X`` of shape (r, k m)."""
        r = X.shape[0]
        m, k, n, w = self.m, self.k, self.n, self.w
        Xs = X * self._d
        buf, res = self._buffers(r)  # reused: fresh megabyte temporaries page-fault
        buf[:, :k] = Xs.reshape(r, k, m).transpose(0, 2, 1).reshape(r * m, k)
        xf = np.fft.rfft(buf, axis=-1).reshape(r, m, -1).transpose(2, 0, 1)  # (nf, r, m)
        out = xf @ self._Rf  # T(St): out(b) = sum_a x(a) R(b - a)
        # head: Y(i) = sum_c x(c) h(c - i), i = 1..k-1; out(c) -= sum_i Y(i) h(c - i)^T
        Y = np.fft.irfft((xf @ self._hf.conj()[:, :, None])[:, :, 0].T, n=n, axis=-1)  # (r, n)
        Y[:, 0] = 0.0
        Y[:, k:] = 0.0
        out -= np.fft.rfft(Y, axis=-1).T[:, :, None] * self._hf[:, None, :]
        # tail: Y(i) = sum_c x(c) g(c + i), i = 0..w-2; out(c) -= sum_i Y(i) g(c + i)^T
        Y = np.fft.irfft((xf.conj() @ self._gf[:, :, None])[:, :, 0].T, n=n, axis=-1)
        Y[:, w - 1 :] = 0.0
        out -= np.fft.rfft(Y, axis=-1).T.conj()[:, :, None] * self._gf[:, None, :]
        np.fft.irfft(out.transpose(1, 2, 0).reshape(r * m, -1), n=n, axis=-1, out=res)
        XG = res[:, :k].reshape(r, m, k).transpose(0, 2, 1).reshape(r, k * m)
        if self._s is not None:
            XG -= np.outer(Xs @ self._s, self._s) / self.j
        XG *= self._d
        XG /= self.j
        return XG

    def _buffers(self, r: int) -> tuple[np.ndarray, np.ndarray]:
        """Zero-padded input and output rows for ``r`` rows (kept for the next call)."""
        if r not in self._bufs:
            self._bufs[r] = (np.zeros((r * self.m, self.n)), np.empty((r * self.m, self.n)))
        return self._bufs[r]


def _window_sums(acc: _LagGram, w: int, k: int) -> np.ndarray:
    """``s_a = sum_{t<j} z(t + a)``, a = 0..k-1, stacked (k m): the total less the first
    ``a`` and the last ``w - 1 - a`` samples (``pbsid._window_stats``'s centring)."""
    m = acc.m
    total = acc.moments.sum
    head = np.cumsum(np.concatenate([np.zeros((1, m)), acc.head[: w - 1]]), axis=0)
    tail = acc.pending[::-1][: w - 1]  # newest first
    tcum = np.cumsum(np.concatenate([np.zeros((1, m)), tail]), axis=0)
    return np.concatenate([total - head[a] - tcum[w - 1 - a] for a in range(k)])
