"""The Gram matrix of a Hankel window as an operator: products ``X G Y^T`` by FFT.

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

from dataclasses import dataclass

import numpy as np
import scipy.fft as sfft

from maglevid.identify._hankel import _LagGram

__all__: list[str] = []


@dataclass(frozen=True)
class Encoded:
    """Rows ``X`` (r, k m) as :meth:`GramOperator.inner` reads them: the weighted spectrum
    of the scaled rows, their products with the head's and the tail's columns of (P18)
    and with the window's sums."""

    xf: np.ndarray  # (nf, r, m) complex: rfft of X D, times sqrt(c_f / n)
    flat: np.ndarray  # (r, 2 nf m) float: the same, row-major, real and imaginary parts
    yh: np.ndarray  # (r, k - 1): X D Lh
    yt: np.ndarray  # (r, w - 1): X D Lt
    sp: np.ndarray | None  # (r,): X D s (centring), None when not centred

    def __getitem__(self, rows: slice) -> Encoded:
        sp = None if self.sp is None else self.sp[rows]
        return Encoded(self.xf[:, rows], self.flat[rows], self.yh[rows], self.yt[rows], sp)


class GramOperator:
    """``(X, Y) -> X G Y^T``: the scaled, normalised (and centred) Gram of a window's
    leading samples, as a bilinear form on rows encoded once (:meth:`encode`).

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

    Notes
    -----
    ``X T(St) Y^T = (1/n) sum_f X(f) R(f) Y(f)^H`` (Parseval, the linear convolution
    held without wrapping by ``n >= w + k``), summed over the half spectrum of the
    real sequences with weights ``c_f`` (1 at 0 and n/2, else 2) as one real GEMM;
    the corrections are products of the short time-domain sequences ``X Lh``,
    ``X Lt`` (one inverse FFT of ``r`` sequences each). Encoding ``r`` rows costs one
    real FFT of ``r m`` sequences of length ``n``; a product of ``r1`` and ``r2`` rows
    ``O(n m (m r1 + r1 r2))``.
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
        c = np.full(self._Rf.shape[0], 2.0)
        c[0] = 1.0
        if n % 2 == 0:
            c[-1] = 1.0
        self._wf = np.sqrt(c / n)  # Parseval's weights, half on each side
        self._hc = np.ascontiguousarray(self._hf.conj().T)  # (m, nf): the einsums' layout
        self._gc = np.ascontiguousarray(self._gf.conj().T)
        self._d = np.tile(1.0 / np.asarray(scale, dtype=float), k)
        self._s = _window_sums(acc, w, k) if center else None

    def encode(self, X: np.ndarray) -> Encoded:
        """Rows ``X`` (r, k m) for :meth:`inner`."""
        r = X.shape[0]
        m, k, n, w = self.m, self.k, self.n, self.w
        Xs = X * self._d
        buf = np.zeros((r * m, n))
        buf[:, :k] = Xs.reshape(r, k, m).transpose(0, 2, 1).reshape(r * m, k)
        xr = np.fft.rfft(buf, axis=-1).reshape(r, m, -1)  # (r, m, nf), contiguous
        # head: (X Lh)(i) = sum_c x(c) h(c - i), i = 1..k-1 (a correlation)
        yh = np.fft.irfft(np.einsum("rmf,mf->rf", xr, self._hc), n=n, axis=-1)[:, 1:k]
        # tail: (X Lt)(i) = sum_c x(c) g(c + i), i = 0..w-2: conj(X(f)) g(f), conjugated
        yt = np.fft.irfft(np.einsum("rmf,mf->rf", xr, self._gc).conj(), n=n, axis=-1)[:, : w - 1]
        xr *= self._wf
        xf = np.ascontiguousarray(xr.transpose(2, 0, 1))  # (nf, r, m): inner's matmul
        flat = np.ascontiguousarray(xr.transpose(0, 2, 1)).reshape(r, -1).view(float)
        sp = None if self._s is None else Xs @ self._s
        return Encoded(xf, flat, yh, yt, sp)

    def inner(self, A: Encoded, C: Encoded) -> np.ndarray:
        """``A G C^T`` (rA, rC), (P18)."""
        P = A.xf @ self._Rf  # (nf, rA, m): A(f) R(f), weighted
        Pf = np.ascontiguousarray(P.transpose(1, 0, 2)).reshape(P.shape[1], -1).view(float)
        out = Pf @ C.flat.T  # sum_f Re(A(f) R(f) C(f)^H), c_f / n
        out -= A.yh @ C.yh.T
        out -= A.yt @ C.yt.T
        if A.sp is not None and C.sp is not None:
            out -= np.outer(A.sp, C.sp) / self.j
        out /= self.j
        return out


def _window_sums(acc: _LagGram, w: int, k: int) -> np.ndarray:
    """``s_a = sum_{t<j} z(t + a)``, a = 0..k-1, stacked (k m): the total less the first
    ``a`` and the last ``w - 1 - a`` samples (the data stage's centring, ``G - s s^T / j``;
    ``pbsid._window_stats`` and :class:`GramOperator` alike)."""
    m = acc.m
    total = acc.moments.sum
    head = np.cumsum(np.concatenate([np.zeros((1, m)), acc.head[: w - 1]]), axis=0)
    tail = acc.pending[::-1][: w - 1]  # newest first
    tcum = np.cumsum(np.concatenate([np.zeros((1, m)), tail]), axis=0)
    return (total - head[:k] - tcum[w - 1 :: -1][:k]).reshape(-1)
