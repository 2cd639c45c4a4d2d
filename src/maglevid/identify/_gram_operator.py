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

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.fft as sfft

from maglevid.identify._hankel import _LagGram

__all__: list[str] = []

#: numpy's FFTs write into a given array from 2.0 on
_FFT_OUT = np.lib.NumpyVersion(np.__version__) >= "2.0.0"


@dataclass(frozen=True)
class Encoded:
    """Rows ``X`` (r, k m) as :meth:`GramOperator.inner` reads them: their spectra, their
    products with the head's and the tail's columns of (P18) and with the window's
    sums. Linear in ``X``: the difference of two encodings is the encoding of the rows'
    difference."""

    flat: np.ndarray  # (r, 2 nf m) float: X(f), row-major over (f, m), re/im interleaved
    yh: np.ndarray  # (k - 1, r): (X D Lh)^T
    yt: np.ndarray  # (w - 1, r): (X D Lt)^T
    sp: np.ndarray | None  # (r,): X D s (centring), None when not centred
    # the rows weighted, X(f) (c_f / n) D R(f) D (r, nf, m), made at the first product
    # that reads them on the left (GramOperator._weighted) and kept for the next
    weighted: list[Any] = field(default_factory=list, repr=False, compare=False)

    def __getitem__(self, rows: slice) -> Encoded:
        sp = None if self.sp is None else self.sp[rows]
        return Encoded(self.flat[rows], self.yh[:, rows], self.yt[:, rows], sp)

    def __sub__(self, other: Encoded) -> Encoded:
        sp = None if self.sp is None or other.sp is None else self.sp - other.sp
        return Encoded(self.flat - other.flat, self.yh - other.yh, self.yt - other.yt, sp)


@dataclass(frozen=True)
class Sequences:
    """The rows ``e_c (x) q_j`` (one scalar sequence ``q_j`` over the blocks, in channel
    ``c`` alone; ``r m`` rows ordered ``(j, c)``) as :meth:`GramOperator.sequence_gram` and
    :meth:`GramOperator.inner_sequences` read them: the sequences' spectra, the rows'
    products with the head's and the tail's columns of (P18) and with the window's sums.
    Built by :meth:`GramOperator.encode_sequences` from ``r`` FFTs instead of ``r m``."""

    qf: np.ndarray  # (r, nf): the sequences' spectra, a sequence's contiguous
    yh: np.ndarray  # (k - 1, r m)
    yt: np.ndarray  # (w - 1, r m)
    sp: np.ndarray | None  # (r m,), None when not centred


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
    real sequences with weights ``c_f`` (1 at 0 and n/2, else 2). ``D R(f) D`` (``D``
    the channel scaling) is Hermitian (``St_{-tau} = St_tau^T``; not definite: the
    lags are truncated at ``k - 1``). A product weights its left rows once,
    ``X(f) (c_f / n) D R(f) D`` (one ``m x m`` product per frequency, kept with the
    encoding), and is then one real GEMM against the right rows' real and imaginary
    parts (docs/subspace.md, (P19) and "thirtieth session"). The corrections are
    products of the short time-domain sequences ``X Lh``, ``X Lt`` (one inverse FFT
    of ``r`` sequences each). Encoding ``r`` rows costs one real FFT of ``r m``
    sequences of length ``n``; a product of ``r1`` and ``r2`` rows ``O(n m r1 (m +
    r2))``. The rows come as ``(r, k m)`` (:meth:`encode`) or block-major
    ``(k, r, m)`` (:meth:`encode_blocks`, what the FFT along the blocks reads
    without a transposed copy).
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
        d = 1.0 / np.asarray(scale, dtype=float)
        # R(f) of the scaled channels, D R(f) D, weighted (c_f / n): Hermitian (St_{-tau} =
        # St_tau^T); every product reads it on one side (no eigenbasis: the batched
        # Hermitian eigensolver was 1 ms of the operator's 1.6, thirtieth session)
        nf = n // 2 + 1
        c = np.full(nf, 2.0)
        c[0] = 1.0
        if n % 2 == 0:
            c[-1] = 1.0
        self._Rw = sfft.rfft(R * np.outer(d, d), axis=0) * (c / n)[:, None, None]
        # the same, real, frequency-major with re/im interleaved: [Re; -Im] per frequency
        # (what sequence_gram's real part of a complex product reads)
        self._Rs = np.stack([self._Rw.real, -self._Rw.imag], axis=1).reshape(2 * nf, m * m)
        # (X D) conj(h): the head's and the tail's spectra, scaled and conjugated
        spec = lambda x: (sfft.rfft(x, n=n, axis=0) * d).conj()  # noqa: E731
        ht = spec(head[: k - 1])  # h(s) = z(s), s < k - 1
        gt = spec(tail[L - (w - 1) :])  # g(s) = z(j + s), s <= w - 2
        self._hg = np.stack([ht, gt], axis=-1)  # (nf, m, 2)
        self._scratch_arrays: dict[tuple[Any, ...], np.ndarray] = {}  # _scratch's
        self._st = self._us = None
        if center:  # sum_t x(t) s(t) = sum_f (c_f / n) Re(X(f) conj(S(f)))
            sf = spec(_window_sums(acc, w, k).reshape(k, m)) * (c / n)[:, None]
            self._st = np.stack([sf.real, -sf.imag], axis=-1).reshape(-1)
            self._us = sf  # (nf, m)

    def encode(self, X: np.ndarray) -> Encoded:
        """Rows ``X`` (r, k m), time-domain blocks (oldest first), for :meth:`inner`."""
        return self.encode_blocks(X.reshape(X.shape[0], self.k, self.m).transpose(1, 0, 2))

    def encode_blocks(self, Xb: np.ndarray) -> Encoded:
        """Rows as blocks ``Xb[c, row, :]`` (k, r, m), block-major: the FFT runs along the
        leading axis and writes the spectra straight into the row-major layout
        :meth:`inner` reads. ``Xb`` may also come zero-padded to the FFT's length (``n``
        blocks, those from ``k`` on zero): numpy's FFT then reads it in place instead of
        padding a copy (0.61 -> 0.38 ms for the 66 rows of a Gauss-Newton point on the
        issue record at N = 1e4)."""
        n, k, w = self.n, self.k, self.w
        if Xb.shape[0] not in (k, n):
            raise ValueError(f"{Xb.shape[0]} blocks: need k = {k} or the padded n = {n}")
        r, nf = Xb.shape[1], self._hg.shape[0]
        hg = self._scratch("head and tail spectra", (nf, r, 2), complex)
        yh, yt = self._scratch("head", (n, r)), self._scratch("tail", (n, r))
        flat = np.empty((r, nf, self.m), dtype=complex)
        Xf = flat.transpose(1, 0, 2)  # (nf, r, m), written in the row-major layout
        _rfft(Xb, n, Xf)
        # head: (X D Lh)(i) = sum_c x(c) h(c - i), i = 1..k-1 (a correlation); tail:
        # (X D Lt)(i) = sum_c x(c) g(c + i), i = 0..w-2: conj(X(f)) g(f), conjugated
        np.matmul(Xf, self._hg, out=hg)  # (nf, r, 2)
        _irfft(hg[:, :, 0], n, yh)
        _irfft(hg[:, :, 1].conj(), n, yt)
        flat = flat.reshape(r, -1).view(float)
        sp = None if self._st is None else flat @ self._st
        return Encoded(flat, yh[1:k].copy(), yt[: w - 1].copy(), sp)

    def _scratch(self, name: str, shape: tuple[int, ...], dtype: Any = float) -> np.ndarray:
        """A buffer kept for the next call asking for the same ``name`` and ``shape`` (no
        caller keeps one past its return): the encodings' and products' temporaries are
        up to several MB, and fresh ones are page-faulted in at every Gauss-Newton point
        (a loop of encodings of 66 rows took 7.2 ms each against 3.3 ms reused, N = 1e4,
        the issue record's window; ~2.8 us a 4 kB page on the benchmark's KVM guest)."""
        key = (name, shape, np.dtype(dtype).char)
        a = self._scratch_arrays.get(key)
        if a is None:
            a = self._scratch_arrays[key] = np.empty(shape, dtype=dtype)
        return a

    def inner(self, A: Encoded, C: Encoded) -> np.ndarray:
        """``A G C^T`` (rA, rC), (P18): ``sum_f Re(A(f) (c_f / n) D R(f) D C(f)^H)``, the
        weighted ``A(f) R(f)`` (:meth:`_weighted`) against ``C(f)``'s real and imaginary
        parts as one real product."""
        out = self._weighted(A).reshape(A.flat.shape[0], -1).view(float) @ C.flat.T
        return self._corrected(out, A, C)

    def _weighted(self, A: Encoded) -> np.ndarray:
        """``A(f) (c_f / n) D R(f) D`` (rA, nf, m), complex: one batched ``m x m`` product
        per frequency, made once per encoding (kept in ``A.weighted``): a point's
        residual rows are read on the left by three products, a trial's by two."""
        if A.weighted and A.weighted[0] is self:
            return A.weighted[1]
        rA, nf, m = A.flat.shape[0], self._Rw.shape[0], self.m
        AR = np.empty((rA, nf, m), dtype=complex)
        np.matmul(
            A.flat.view(complex).reshape(rA, nf, m).transpose(1, 0, 2),
            self._Rw,
            out=AR.transpose(1, 0, 2),
        )
        A.weighted[:] = [self, AR]
        return AR

    def _corrected(self, out: np.ndarray, A: Any, C: Any) -> np.ndarray:
        """The Toeplitz part's products ``out`` less the head's, the tail's and the
        centring's terms of (P18), over ``j``: ``A``, ``C`` any rows with ``yh``, ``yt``,
        ``sp`` (:class:`Encoded`, :class:`Sequences`)."""
        out -= A.yh.T @ C.yh
        out -= A.yt.T @ C.yt
        if A.sp is not None and C.sp is not None:
            out -= np.outer(A.sp, C.sp) / self.j
        out /= self.j
        return out

    def encode_sequences(self, Q: np.ndarray) -> Sequences:
        """The rows ``e_c (x) Q[:, j]`` (blocks oldest first, ``Q`` (b, r), ``b <= k``;
        the blocks from ``b`` on zero), for :meth:`sequence_gram` and
        :meth:`inner_sequences`. A row with one channel has the spectrum ``q_j(f) e_c``:
        its head, tail and sums products are ``q_j(f)`` times channel ``c``'s, so the
        ``r m`` rows cost ``r`` FFTs and two inverse FFTs of ``r m`` short sequences."""
        n, k, w, m = self.n, self.k, self.w, self.m
        if Q.shape[0] > k:
            raise ValueError(f"{Q.shape[0]} blocks: need at most k = {k}")
        r = Q.shape[1]
        qf = np.ascontiguousarray(np.fft.rfft(Q.T, n=n, axis=-1))  # (r, nf), row-major
        hq = self._scratch("sequence spectra", (2, r, m, qf.shape[1]), complex)  # head, tail
        y = self._scratch("sequence transforms", (2, r, m, n))
        np.multiply(qf[:, None, :], self._hg[:, :, 0].T[None], out=hq[0])
        np.multiply(qf.conj()[:, None, :], self._hg[:, :, 1].T.conj()[None], out=hq[1])
        _irfft(hq, n, y, axis=-1)  # (2, r, m, n)
        yh = y[0, :, :, 1:k].reshape(r * m, k - 1).copy().T  # copied: y is reused
        yt = y[1, :, :, : w - 1].reshape(r * m, w - 1).copy().T
        sp = None if self._us is None else (qf @ self._us).real.reshape(-1)
        return Sequences(qf, yh, yt, sp)

    def sequence_gram(self, S: Sequences, T: Sequences | None = None) -> np.ndarray:
        """``Phi G Psi^T`` (r m, r' m) of the rows of two :meth:`encode_sequences` (``Psi``
        = ``Phi`` when ``T`` is None): the Toeplitz part
        ``sum_f Re(q_j(f) conj(p_j'(f)) (c_f / n) R_cc'(f))`` as one real product
        ``(r r' x 2 nf) (2 nf x m^2)`` (the real part alone: half a complex product's
        arithmetic), then the corrections of (P18)."""
        T = S if T is None else T
        r, r2, m = S.qf.shape[0], T.qf.shape[0], self.m
        A = self._scratch("sequence products", (r, r2, S.qf.shape[1]), complex)  # row-major
        np.multiply(S.qf[:, None, :], T.qf.conj()[None, :, :], out=A)
        out = A.view(float).reshape(r * r2, -1) @ self._Rs  # re/im interleaved per f
        out = np.ascontiguousarray(out.reshape(r, r2, m, m).transpose(0, 2, 1, 3))
        out = out.reshape(r * m, r2 * m)
        return self._corrected(out, S, T)

    def inner_sequences(self, A: Encoded, S: Sequences) -> np.ndarray:
        """``A G Phi^T`` (rA, r m) for encoded rows ``A`` and the rows ``Phi`` of
        :meth:`encode_sequences`: the weighted rows ``A(f) (c_f / n) D R(f) D``
        (:meth:`_weighted`) against ``conj(q_j(f))``, the real part alone as one real
        product ``(rA m x 2 nf) (2 nf x r)``, then the corrections."""
        rA, m, r = A.flat.shape[0], self.m, S.qf.shape[0]
        AR = self._weighted(A).transpose(0, 2, 1).reshape(rA * m, -1)  # (rA m, nf), a copy
        out = AR.view(float) @ S.qf.view(float).T  # Re(AR conj(q)): (rA m, r)
        out = np.ascontiguousarray(out.reshape(rA, m, r).transpose(0, 2, 1)).reshape(rA, -1)
        return self._corrected(out, A, S)


def _rfft(x: np.ndarray, n: int, out: np.ndarray) -> None:
    """``out[...] = rfft(x, n, axis=0)``, in place where numpy can (``out=``, numpy >= 2)."""
    if _FFT_OUT:
        np.fft.rfft(x, n=n, axis=0, out=out)
    else:
        out[...] = np.fft.rfft(x, n=n, axis=0)


def _irfft(x: np.ndarray, n: int, out: np.ndarray, axis: int = 0) -> None:
    """``out[...] = irfft(x, n, axis)``, in place where numpy can."""
    if _FFT_OUT:
        np.fft.irfft(x, n=n, axis=axis, out=out)
    else:
        out[...] = np.fft.irfft(x, n=n, axis=axis)


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
