"""The bearing's v1..v9 fitted to the VARX data of PBSID-opt / SSARX (structured WLS).

Why: the transform of a black-box model to physical coordinates
(:func:`~maglevid.identify.physical.to_physical_coordinates`) reads nine
numbers off a realisation with 36 free entries; the scatter of the other
entries passes into v1..v9, and it is 4-50x that of maximum likelihood on the
closed-loop bearing (docs/subspace.md, "Structured fit").

What (docs/subspace.md eqs. (P11)-(P13)): the predictor (P2) in the bearing's
structure, ``Abar(theta) = A_d(v) - K C``, ``Btil(theta) = [B_d(v), K]`` with
``A_d, B_d`` the ZOH of eq. (4) and ``K`` (4 x 3) free, predicts ``y(t)`` from
the past window ``Z_P(t)`` as ``V(theta) Z_P(t)``, ``V``'s blocks
``C Abar^{k-1} Btil`` (P4). The fit minimises the weighted prediction error
over the Hankel rows (P11)::

    J(theta) = tr( W (Y - V(theta) Z_P) (Y - V(theta) Z_P)^T ) / j,  W = Re^{-1}

which needs only products with the Gram matrix of the window, taken by FFT
without forming it (``_gram_operator``, (P18)): it is the VARX's least-squares
criterion with the 21 structured parameters in place of ``P (nu + ny) ny`` free ones, i.e. a
weighted least-squares fit of the structured Markov parameters to the VARX's,
with the VARX's own covariance ``(Z_P Z_P^T)^{-1} (x) Re`` as weight (P12).
With ``W`` the innovation covariance's inverse this is the prediction-error
criterion of the truncated predictor (Ljung 1999, eq. (7.12)), asymptotically
efficient for this model set when ``|lambda(Abar)|^P`` is negligible;
``W`` is the start's prediction errors' inverse covariance (P13). The state at
the window's start is not left at 0: ``C Abar^P x_hat(t-P)`` is added, with
``x_hat`` the plant's least-squares state from the window's first
``START_SAMPLES`` samples (P14) -- on a high-SNR record the truncation term
otherwise dominates the residual (the bearing's ``Abar`` has a pole at ~0.98).
Gauss-Newton on the normal equations, Levenberg-Marquardt damping, cost
differences evaluated without cancellation (:meth:`_Criterion.delta`); the start
is the transform's estimate. The derivative rows' products go through the (at most
eight) sequences the rows span (P22). Memory and time do not depend on ``N``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg as sla

from maglevid.physics.amb import C_AMB, amb_matrices

__all__ = ["START_SAMPLES", "StructuredFit", "fit_bearing_structure"]

#: Samples at the start of the window the predictor's initial state is
#: reconstructed from (P14); 0 leaves it at zero (the truncated predictor).
START_SAMPLES = 8
#: Stop when the next Gauss-Newton step would lower ``j J`` (twice a log-likelihood) by
#: less than this (its predicted gain ``-j g^T s``, free at every point; the achieved
#: gain of a damped step): that step is then at most ~``sqrt(0.01)`` = 0.1 standard
#: errors long (``j dJ = z^2``); measured <= 7e-3 standard errors from the optimum
#: converged to a gain of 1e-5, on the bench records at 1e4 and 1e5. (Judging a step
#: after taking it cost one Jacobian more per round; docs/subspace.md, "eighth session".)
_GAIN_TOL = 1e-2
#: The last round ends with the step of a point that predicts a gain below this (of ``j J``,
#: at or above ``_GAIN_TOL``): the step is taken, checked to lower the cost, and no point
#: is built after it (its Jacobian would only confirm convergence); the estimate is then
#: ~``sqrt(0.1)`` x (the steps' contraction) ~ 0.1 standard errors from the optimum or
#: closer (measured <= 9.3e-3 on the bench records at 1e4 and 1e5, <= 0.033 on 16 more
#: fits; 1 instead of 0.1 saved 0.75 points a fit for up to 0.11: docs/subspace.md,
#: "ninth session").
_FINAL_GAIN = 0.1
#: A full step is taken without a trial of its cost first when the last full step gained
#: within these factors of its prediction (the quadratic model holds): its point is built
#: at once and the cost's change read off the two points' encodings.
_TRUST = (0.5, 2.0)
#: Parameters: v1..v9 (relative to the start) and the Kalman gain's 12 entries (scaled).
_N_THETA = 21
#: Floor of the weighting's innovation covariance (channels scaled to unit RMS).
_RE_FLOOR = 1e-12
#: Gauss-Newton steps at most (6-16 in all are taken on the
#: bench's records since the start term's Jacobian is analytic; its forward
#: differences made the steps crawl on high-SNR records, 40 at N = 1e5).
_MAX_ITER = 20
#: Halvings of a failed undamped Gauss-Newton step before Levenberg-Marquardt damping.
_HALVINGS = 4
#: Columns of the random sketch a point's sequence basis is found from: the derivative
#: rows' sequences span at most ``2 n`` = 8 dimensions (P22), four more as a margin.
_SKETCH = 12
#: A point's derivative rows are encoded as they are when the sequence basis misses one
#: by more than this, relative to its norm (measured 3e-15 - 8e-15 on the bench records).
_BASIS_TOL = 1e-10


@dataclass(frozen=True)
class StructuredFit:
    """Result of :func:`fit_bearing_structure`, physical units."""

    v: np.ndarray  # v1..v9
    K: np.ndarray  # Kalman gain (4, 3), states [x, dx/dt, i1, i2]
    Ad: np.ndarray
    Bd: np.ndarray
    Re: np.ndarray  # innovation covariance of the window's predictor
    iterations: int
    start_samples: int  # samples the window-start state was rebuilt from (0: left at 0)
    covariance: np.ndarray  # (9, 9) of v1..v9, physical units, (P15)
    #: the last round's predicted gain in ``j J`` left at its end (0: ended by its stop
    #: rule; inf: no descent found though one was predicted)
    remaining: float = 0.0


def _zoh(v: np.ndarray, dt: float) -> tuple[np.ndarray, ...]:
    """``A_d, B_d`` of eq. (4) + ZOH and their derivatives in v1..v9.

    Each derivative is the Frechet derivative of ``expm`` along the direction of one
    ``v_i`` (eq. (4) is linear in v): the upper-right block of the exponential of
    ``[[M, E_i], [0, M]]`` (Van Loan 1978), all nine by one stacked ``expm``
    (nine ``expm_frechet`` calls were a sixth of a Gauss-Newton step).
    """
    Ac, Bc = amb_matrices(v)
    dAc, dBc = _directions()
    n, m = Bc.shape
    k = n + m
    X = np.zeros((9, 2 * k, 2 * k))
    X[:, :n, :n] = X[:, k : k + n, k : k + n] = Ac * dt
    X[:, :n, n:k] = X[:, k : k + n, k + n :] = Bc * dt
    X[:, :n, k : k + n] = dAc * dt
    X[:, :n, k + n :] = dBc * dt
    E = sla.expm(X)
    return E[0, :n, :n], E[0, :n, n:k], E[:, :n, k : k + n], E[:, :n, k + n :]


@functools.lru_cache(maxsize=1)
def _directions() -> tuple[np.ndarray, np.ndarray]:
    """``dA_c/dv_i``, ``dB_c/dv_i`` (9, 4, 4), (9, 4, 2): eq. (4) is linear in v."""
    A0 = amb_matrices(np.zeros(9))[0]  # the constant entry dx/dt
    dA, dB = zip(*(amb_matrices(e) for e in np.eye(9)), strict=True)
    return np.array(dA) - A0, np.array(dB)


def _plant(v: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``A_d, B_d``: eq. (4) and its ZOH (eq. (7)), without derivatives."""
    Ac, Bc = amb_matrices(v)
    M = np.zeros((6, 6))
    M[:4, :4], M[:4, 4:] = Ac * dt, Bc * dt
    E = sla.expm(M)
    return E[:4, :4], E[:4, 4:]


def _markov(
    Abar: np.ndarray, Btil: np.ndarray, P: int, out: np.ndarray | None = None
) -> np.ndarray:
    """``M_k = Abar^{k-1} Btil``, k = 1..P, state-major (n, P, m), by doubling.

    ``M_{L+1..2L} = Abar^L M_{1..L}``: ``log2 P`` products instead of ``P`` small ones
    (a Python loop of 4 x 4 products was a third of a Gauss-Newton step), each one
    GEMM ``(n x n) (n x L m)`` in this layout (the step-major stack of 4 x 5 blocks was
    as many tiny products per level); ``out`` (n, P, m) is written into when given.
    """
    n, m = Btil.shape
    M = np.empty((n, P, m)) if out is None else out
    M[:, 0] = Btil
    L, Ap = 1, Abar
    while L < P:
        c = min(L, P - L)
        np.matmul(Ap, M[:, :c].reshape(n, c * m), out=M[:, L : L + c].reshape(n, c * m))
        L += c
        if L < P:
            Ap = Ap @ Ap
    return M


def _blocks_of(Cs: np.ndarray, M: np.ndarray) -> np.ndarray:
    """``C M_{P-c}`` (P, ny, m), block-major, oldest block first, of a state-major ``M``."""
    n, P, m = M.shape
    return (Cs @ M.reshape(n, -1)).reshape(-1, P, m)[:, ::-1].transpose(1, 0, 2)


def _radius(A: np.ndarray) -> float:
    """``max |lambda(A)|``, the spectral radius (inf for a matrix with a non-finite
    entry: a step far past the stable region)."""
    if not np.all(np.isfinite(A)):
        return float("inf")
    return float(np.max(np.abs(np.linalg.eigvals(A))))


def _model(theta: np.ndarray, v0: np.ndarray, dt: float, sy: np.ndarray, su: np.ndarray):  # type: ignore[no-untyped-def]
    """Scaled predictor ``(Abar, Btil, dAbar, dBtil)`` at ``theta = [dv/v0 (9), K_s (12)]``."""
    v = v0 * (1.0 + theta[:9])
    Ad, Bd, dAd, dBd = _zoh(v, dt)
    Cs = C_AMB / sy[:, None]
    Ks = theta[9:].reshape(4, 3)
    Bs = Bd * su[None, :]
    Abar = Ad - Ks @ Cs
    Btil = np.concatenate([Bs, Ks], axis=1)
    n_th = theta.size
    dAbar = np.zeros((n_th, 4, 4))
    dBtil = np.zeros((n_th, 4, 5))
    dAbar[:9] = dAd * v0[:, None, None]
    dBtil[:9, :, :2] = dBd * (v0[:, None, None] * su[None, None, :])
    for a in range(4):
        for b in range(3):
            i = 9 + 3 * a + b
            dAbar[i, a, :] = -Cs[b]
            dBtil[i, a, 2 + b] = 1.0
    return Abar, Btil, dAbar, dBtil, Cs, v, Ad, Bd, Ks


def _predictor_blocks(Abar, Btil, dAbar, dBtil, Cs, P, out=None, work=None):  # type: ignore[no-untyped-def]
    """``V`` (P, ny, m) and ``dV`` (P, ny, m, n_th), block-major, oldest block first.

    Block ``c`` is ``Xi_{P-c} = C M_{P-c}``; block-major because the Gram operator
    transforms along the blocks (``GramOperator.encode_blocks``); ``dV``'s parameter
    index last (below). ``out``: an array (P, ny, m, n_th) ``dV`` is written into (and
    returned); ``work``: the buffers :func:`_doubling_buffers` makes, reused from call
    to call (fresh MB-sized arrays are faulted in again at every call: docs/subspace.md,
    "eighth session").
    ``M_k = Abar^{k-1} Btil`` and ``dM_k`` by doubling: ``[dM; M]_{L+j}`` is
    ``[[Abar^L, d(Abar^L)], [0, Abar^L]] [dM_j; M_j]`` (the derivative of a power as a
    block-triangular power, Van Loan 1978), so ``dM_{L+j} = Abar^L dM_j + d(Abar^L) M_j``
    and ``d(Abar^2L) = Abar^L d(Abar^L) + d(Abar^L) Abar^L``: ``log2 P`` levels for all
    parameters. State-major (n, P, m, n_th), a level's ``Abar^L dM_j`` for every ``j``
    and parameter is one GEMM ``(n x n) (n x L m n_th)`` and ``d(Abar^L) M_j`` one
    ``(L m x n) (n x n_th)`` GEMM per state row, written in ``dM``'s own order (step-major,
    both were stacks of thousands of 4 x 4 products: 1.3-1.5 -> 0.5 ms a point on the
    bench records; with the parameter index between the steps and the inputs, adding
    ``d(Abar^L) M_j`` took a strided pass: 0.43 -> 0.23 ms on the paper-like record,
    twenty-ninth session; every result bitwise equal).
    """
    n_th = dAbar.shape[0]
    n, m = Btil.shape
    dM, M, Y, T = _doubling_buffers(n_th, P, Btil.shape, Cs.shape[0]) if work is None else work
    _markov(Abar, Btil, P, out=M)
    dM[:, 0] = dBtil.transpose(1, 2, 0)
    L, Ap, dAp = 1, Abar, dAbar
    w = n_th * m
    while L < P:
        c = min(L, P - L)
        np.matmul(Ap, dM[:, :c].reshape(n, c * w), out=dM[:, L : L + c].reshape(n, c * w))
        level = dM[:, L : L + c].reshape(n, c * m, n_th)  # a view: state a, (j, input), i
        dAM = T[: n * c * m * n_th].reshape(n, c * m, n_th)
        level += np.matmul(M[:, :c].reshape(n, c * m).T, dAp.transpose(1, 2, 0), out=dAM)
        L += c
        if L < P:
            dAp = Ap @ dAp + dAp @ Ap
            Ap = Ap @ Ap
    if out is None:
        out = np.empty((P, Cs.shape[0], m, n_th))
    np.matmul(Cs, dM.reshape(n, -1), out=Y.reshape(Cs.shape[0], -1))
    out[...] = Y[:, ::-1].transpose(1, 0, 2, 3)
    return _blocks_of(Cs, M), out


def _doubling_buffers(
    n_th: int, P: int, shape: tuple[int, ...], ny: int
) -> tuple[np.ndarray, ...]:
    """``dM`` (n, P, m, n_th), ``M`` (n, P, m), ``C dM`` (ny, P, m, n_th) and a level's
    ``d(Abar^L) M_j`` (flat, up to ``P / 2`` steps) for :func:`_predictor_blocks`:
    reused from point to point, as a fresh array of this size is page-faulted in again
    each time (~2.8 us a 4 kB page on the benchmark's KVM guest; twenty-ninth session)."""
    n, m = shape
    return (
        np.empty((n, P, m, n_th)),
        np.empty((n, P, m)),
        np.empty((ny, P, m, n_th)),
        np.empty(n * (P // 2 + 1) * m * n_th),
    )


def _state_map(
    Ad: np.ndarray,
    Bs: np.ndarray,
    Cs: np.ndarray,
    k: int,
    dAd: np.ndarray | None = None,
    dBs: np.ndarray | None = None,
):  # type: ignore[no-untyped-def]
    """``M`` (4, 5 k): ``x(t) ~ M [z(t); ...; z(t+k-1)]`` by least squares on the plant (P14).

    ``y(t+i) = Cs Ad^i x(t) + sum_{l<i} Cs Ad^{i-1-l} Bs u(t+l)`` (noise left out):
    ``x = Gamma_k^+ (Y_k - T_k U_k)``, scaled units, ``z = [u, y]``. With ``dAd``,
    ``dBs`` (n_d, ...) the derivatives of ``Ad``, ``Bs`` along n_d directions, also
    ``dM`` (n_d, 4, 5 k), from those of ``Gamma_k`` and ``T_k`` and the derivative of
    the pseudo-inverse of a full-column-rank matrix (Golub & Pereyra 1973, eq. (4.12)):
    ``d(G^+) = -G^+ dG G^+ + (G^T G)^{-1} dG^T (I - G G^+)``.
    """
    CA = np.empty((k, *Cs.shape))  # Cs Ad^i, i = 0..k-1, by one product each
    CA[0] = Cs
    for i in range(1, k):
        CA[i] = CA[i - 1] @ Ad
    CAB = CA @ Bs  # Cs Ad^i Bs
    S = _input_map(CAB, k)
    S[:, np.arange(5 * k) % 5 >= 2] += np.eye(3 * k)  # the y(t+i) of Y_k
    G = CA.reshape(-1, Ad.shape[0])
    Gp = np.linalg.pinv(G)
    if dAd is None:
        return Gp @ S
    assert dBs is not None
    dCA = np.zeros((dAd.shape[0], *CA.shape))
    for i in range(1, k):  # d(CA_{i-1} Ad) = dCA_{i-1} Ad + CA_{i-1} dAd
        dCA[:, i] = dCA[:, i - 1] @ Ad + CA[i - 1] @ dAd
    dCAB = dCA @ Bs + CA[None] @ dBs[:, None]
    dG = dCA.reshape(dAd.shape[0], *G.shape)
    dGp = -Gp @ dG @ Gp + (Gp @ Gp.T) @ dG.transpose(0, 2, 1) @ (np.eye(G.shape[0]) - G @ Gp)
    return Gp @ S, dGp @ S + Gp @ _input_map(dCAB, k)


def _input_map(CAB: np.ndarray, k: int) -> np.ndarray:
    """``-T_k`` placed in the ``u`` columns of ``[z(t); ...; z(t+k-1)]``: (..., 3 k, 5 k).

    Block ``(i, l)``, ``l < i``, is ``-CAB[i - 1 - l]``: one gather by a cached index
    (a double loop of block assignments was a third of the start term's time).
    """
    idx, below = _toeplitz_index(k)
    T = CAB[..., idx, :, :] * below[:, :, None, None]  # (..., i, l, 3, 2)
    S = np.zeros((*CAB.shape[:-3], k, 3, k, 5))
    S[..., :2] = -np.swapaxes(T, -3, -2)
    return S.reshape(*CAB.shape[:-3], 3 * k, 5 * k)


@functools.lru_cache(maxsize=8)
def _toeplitz_index(k: int) -> tuple[np.ndarray, np.ndarray]:
    """``i - 1 - l`` (clipped at 0) and ``l < i`` for the blocks of :func:`_input_map`."""
    i, l = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    return np.maximum(i - 1 - l, 0), (l < i).astype(float)


def _power_derivative(
    Abar: np.ndarray, dAbar: np.ndarray, P: int
) -> tuple[np.ndarray, np.ndarray]:
    """``Abar^P`` and ``d(Abar^P)`` along each of ``dAbar`` (n_d, n, n): the diagonal and
    the upper-right blocks of ``[[Abar, dAbar_i], [0, Abar]]^P`` (Van Loan 1978's
    block-triangular trick for the power's Frechet derivative), all directions by one
    stacked ``matrix_power``."""
    n = Abar.shape[0]
    T = np.zeros((dAbar.shape[0], 2 * n, 2 * n))
    T[:, :n, :n] = Abar
    T[:, n:, n:] = Abar
    T[:, :n, n:] = dAbar
    TP = np.linalg.matrix_power(T, P)
    return TP[0, :n, :n], TP[:, :n, n:]


@dataclass(frozen=True)
class _Point:
    """The criterion's W-free parts at one ``theta`` (scaled units): what a new weighting,
    the normal equations, the cost differences and the secant term read, without
    another product with ``G``."""

    theta: np.ndarray
    V: np.ndarray  # (P, 3, 5): the predictor's blocks, the start term (P14) included
    enc: Any  # the residual rows X = [-V, I], encoded for the Gram's products
    M: np.ndarray  # (3 + 3 n_th) squared: [X; dV] G [X; dV]^T
    dV: Any  # the derivative rows, as products with encoded rows read them (``products``)
    rho: float = 0.0  # the predictor's spectral radius, max |lambda(Abar)|

    @property
    def Re(self) -> np.ndarray:
        """``X G X^T``: the prediction errors' covariance (scaled units)."""
        return self.M[:3, :3]


@dataclass(frozen=True)
class _EncodedRows:
    """Derivative rows ``dV`` encoded as they are (``GramOperator.encode_blocks``)."""

    enc: Any

    def products(self, gram: Any, e: Any) -> np.ndarray:
        """``Y G dV^T`` for the encoded rows ``e`` of ``Y``."""
        return gram.inner(e, self.enc)


@dataclass(frozen=True)
class _SequenceRows:
    """Derivative rows ``dV = coef Phi + sd E``: ``Phi`` the rows ``e_c (x) q_j`` of an
    orthonormal basis ``q_j`` of the rows' sequences over the blocks from ``k0`` on,
    ``E`` the unit rows of the first ``k0`` blocks (the start term's, (P14))."""

    seq: Any  # GramOperator.encode_sequences of the basis
    coef: np.ndarray  # (3 n_th, r m)
    unit: Any  # the unit rows (sequences: one block each), None without a start term
    unit_gram: np.ndarray | None  # E G E^T
    sd: np.ndarray | None  # (3 n_th, 5 k0): the rows on the first k0 blocks

    def products(self, gram: Any, e: Any) -> np.ndarray:
        """``Y G dV^T`` for the encoded rows ``e`` of ``Y``."""
        out = gram.inner_sequences(e, self.seq) @ self.coef.T
        if self.sd is not None:
            out += gram.inner_sequences(e, self.unit) @ self.sd.T
        return out

    def gram(self, gram: Any) -> np.ndarray:
        """``dV G dV^T`` (3 n_th, 3 n_th)."""
        D = self.coef @ gram.sequence_gram(self.seq) @ self.coef.T
        if self.sd is not None:
            T = self.coef @ gram.sequence_gram(self.seq, self.unit) @ self.sd.T
            D += T + T.T + self.sd @ self.unit_gram @ self.sd.T
        return D


class _Criterion:
    """(P11) through products with the window's Gram (P18): values, normal equations, steps.

    ``gram`` encodes rows and takes their products ``X G Y^T`` with the scaled,
    normalised Gram of the window's ``P + 1`` samples (``_gram_operator.GramOperator``);
    the columns of sample ``P`` are ``[u(P), y(P)]``, the predicted output's the last three.
    """

    def __init__(self, gram, v0, dt, su, sy, k0):  # type: ignore[no-untyped-def]
        self.gram, self.v0, self.dt, self.su, self.sy = gram, v0, dt, su, sy
        self.P = gram.k - 1
        self.Cs = C_AMB / sy[:, None]
        self.k0 = min(k0, self.P)
        # the rows' buffers, filled at each point (the encodings keep no reference),
        # zero-padded to the FFT's length (read in place: GramOperator.encode_blocks);
        # all 66 rows only where the sequence basis is not taken (made then, _dense_rows)
        self._rows: np.ndarray | None = None
        self._rows_x = np.zeros((gram.n, 3, 5))
        self._work = _doubling_buffers(_N_THETA, self.P, (4, 5), 3)
        # the derivative rows through their sequence basis (_sequence_rows), where the
        # operator takes such rows (the dense Gram of the tests does not)
        self._sequences = hasattr(gram, "encode_sequences")
        self._dv = np.empty((self.P, 3, 5, _N_THETA))  # dV, contiguous
        self._rows_v = np.zeros((gram.n, 3, 5))  # X = [-V, I] alone
        self._rows_v[self.P, :, 2:] = np.eye(3)
        # the sketch's rows drawn in the order (parameter, output, input), read in dV's
        sk = np.random.default_rng(0).standard_normal((_N_THETA, 3, 5, _SKETCH))
        self._sketch = sk.transpose(1, 2, 0, 3).reshape(-1, _SKETCH)
        self._residual = np.empty((self.P - self.k0, 15 * _N_THETA))  # _sequence_rows' E
        self._unit = self._unit_gram = None
        if self._sequences and self.k0:  # the unit rows of the first k0 blocks, (c, channel)
            self._unit = gram.encode_sequences(np.eye(self.k0))
            self._unit_gram = gram.sequence_gram(self._unit)

    def _start(self, Abar, Ad, Bs, dAbar=None, dBtil=None):  # type: ignore[no-untyped-def]
        """``C Abar^P x_hat(t-P)`` (P14), (k0, 3, 5) block-major; with ``dAbar``, ``dBtil``
        also its derivative (k0, 3, 5, n_th): ``Cs d(Abar^P) M + Cs Abar^P dM``, ``M``
        depending on v only (``Bs`` the scaled ``B_d``)."""
        k0, Cs = self.k0, self.Cs
        if dAbar is None:
            S = Cs @ np.linalg.matrix_power(Abar, self.P) @ _state_map(Ad, Bs, Cs, k0)
            return S.reshape(3, k0, 5).transpose(1, 0, 2)
        M, dM = _state_map(Ad, Bs, Cs, k0, dAbar[:9], dBtil[:9, :, :2])
        AP, dAP = _power_derivative(Abar, dAbar, self.P)
        CAP = Cs @ AP
        dS = Cs @ dAP @ M
        dS[:9] += CAP @ dM
        S = (CAP @ M).reshape(3, k0, 5).transpose(1, 0, 2)
        return S, dS.reshape(-1, 3, k0, 5).transpose(2, 1, 3, 0)

    def _predictor(self, th: np.ndarray) -> tuple[np.ndarray, ...]:
        """``(A_d, B_s, K_s, Abar)`` at ``th`` (scaled units), no derivatives."""
        Ad, Bd = _plant(self.v0 * (1.0 + th[:9]), self.dt)
        Ks = th[9:].reshape(4, 3)
        return Ad, Bd * self.su[None, :], Ks, Ad - Ks @ self.Cs

    def leaves_stable(self, p: _Point, th: np.ndarray, pred=None) -> bool:  # type: ignore[no-untyped-def]
        """Whether a step from ``p`` (a stable predictor) to ``th`` makes the predictor
        unstable: its cost rises for certain (``Abar^P`` grows), and the fit would be
        refused there; such a step is failed without its cost (twenty-ninth session:
        37 of the 114 failed trials on 20 paper-like records at 1e4, none of the
        accepted ones at or above 1)."""
        Abar = (self._predictor(th) if pred is None else pred)[3]
        return p.rho < 1.0 and not _radius(Abar) < 1.0

    def markov(self, th: np.ndarray, pred=None) -> np.ndarray:  # type: ignore[no-untyped-def]
        """``V(theta)`` (P, 3, 5), block-major, no derivatives (the trial steps);
        ``pred``: :meth:`_predictor`'s at ``th`` when already at hand."""
        Ad, Bs, Ks, Abar = self._predictor(th) if pred is None else pred
        V = _blocks_of(self.Cs, _markov(Abar, np.concatenate([Bs, Ks], axis=1), self.P))
        if self.k0:
            V[: self.k0] += self._start(Abar, Ad, Bs)
        return V

    def blocks(self, th: np.ndarray, out: np.ndarray | None = None):  # type: ignore[no-untyped-def]
        """``V`` (P, 3, 5) and ``dV`` (P, 3, 5, n_th) at ``th``, block-major, the start
        term (P14) included; ``dV`` written into ``out`` when given."""
        return self._blocks(th, out)[:2]

    def _blocks(self, th: np.ndarray, out: np.ndarray | None = None):  # type: ignore[no-untyped-def]
        """:meth:`blocks` and the predictor's ``Abar``."""
        Abar, Btil, dAbar, dBtil, Cs, _, Ad, _, _ = _model(th, self.v0, self.dt, self.sy, self.su)
        V, dV = _predictor_blocks(Abar, Btil, dAbar, dBtil, Cs, self.P, out, self._work)
        if self.k0:  # the start term and its derivative, analytic (k0 blocks each)
            S, dS = self._start(Abar, Ad, Btil[:, :2], dAbar, dBtil)
            V[: self.k0] += S
            dV[: self.k0] += dS
        return V, dV, Abar

    def point(self, th: np.ndarray) -> _Point:
        """``V``, ``dV`` and their Gram products.

        The 63 derivative rows are sequences over the window's blocks of one 4-state
        predictor and its derivative: entries of powers of ``[[Abar, dAbar_i], [0,
        Abar]]``, whose minimal polynomial divides ``p(q)^2`` (``p`` that of
        ``Abar``), so all of them lie in one space of at most ``2 n = 8`` sequences
        (docs/subspace.md, (P22)). Their products are taken through an orthonormal
        basis of it: ``r <= 8`` FFTs and an ``8 m``-row Gram instead of encoding 63
        rows; the residual rows ``X`` (3) are encoded as they are. Rows not
        represented to ``_BASIS_TOL`` by the basis are encoded as they are, all 66.
        """
        P, g = self.P, self.gram
        V, dV, Abar = self._blocks(th, out=self._dv)
        rho = _radius(Abar)
        dv = self._sequence_rows(dV) if self._sequences else None
        if dv is None:  # one encoding of the 66 rows [X; dV], X = [-V, I]
            rows = self._dense_rows()
            rows[:P, 1:] = dV.transpose(0, 3, 1, 2)  # (block, parameter, output, input)
            np.negative(V, out=rows[:P, 0])
            enc = g.encode_blocks(rows.reshape(rows.shape[0], -1, 5))
            M = g.inner(enc, enc)
            return _Point(th, V, enc[:3], 0.5 * (M + M.T), _EncodedRows(enc[3:]), rho)
        np.negative(V, out=self._rows_v[:P])
        enc = g.encode_blocks(self._rows_v)
        XdV = dv.products(g, enc)  # X G dV^T (3, 3 n_th)
        n = XdV.shape[1]
        M = np.empty((3 + n, 3 + n))
        M[:3, :3] = g.inner(enc, enc)
        M[:3, 3:], M[3:, :3] = XdV, XdV.T
        M[3:, 3:] = dv.gram(g)
        return _Point(th, V, enc, 0.5 * (M + M.T), dv, rho)

    def _dense_rows(self) -> np.ndarray:
        """The buffer of all 66 rows ``[X; dV]`` (n, 1 + n_th, 3, 5), made at first use."""
        if self._rows is None:
            self._rows = np.zeros((self.gram.n, 1 + _N_THETA, 3, 5))
            self._rows[self.P, 0, :, 2:] = np.eye(3)  # X's identity on y(t); dV's last 0
        return self._rows

    def _sequence_rows(self, dV: np.ndarray) -> _SequenceRows | None:
        """``dV`` (P, 3, 5, n_th) through an orthonormal basis of its sequences over the
        blocks from ``k0`` on (the first ``k0`` carry the start term: unit rows), found
        from a random sketch of the rows scaled to unit norm (pivoted QR, rank at
        ``1e-12`` of the largest pivot); None when a row's projection misses it by more
        than ``_BASIS_TOL`` of its norm (measured 3e-15 - 8e-15 on the bench records)."""
        P, k0 = self.P, self.k0
        R = dV[k0:].reshape(P - k0, -1)
        nrm = np.sqrt(np.einsum("ij,ij->j", R, R))
        nrm[nrm == 0.0] = 1.0
        Q, T, _ = sla.qr(R @ (self._sketch / nrm[:, None]), mode="economic", pivoting=True)
        d = np.abs(np.diag(T))
        r = int(np.sum(d > 1e-12 * d[0]))
        if r == 0:
            return None
        Q = Q[:, :r]
        coef = Q.T @ R
        E = np.matmul(Q, coef, out=self._residual)
        np.subtract(R, E, out=E)
        if not np.max(np.sqrt(np.einsum("ij,ij->j", E, E)) / nrm) <= _BASIS_TOL:
            return None
        Qb = np.zeros((P, r))
        Qb[k0:] = Q
        # the rows (parameter, output), the columns (basis sequence, input)
        coef = coef.reshape(r, 3, 5, -1).transpose(3, 1, 0, 2).reshape(-1, 5 * r)
        sd = dV[:k0].transpose(3, 1, 0, 2).reshape(-1, 5 * k0) if k0 else None
        seq = self.gram.encode_sequences(Qb)
        return _SequenceRows(seq, coef, self._unit, self._unit_gram, sd)

    def delta(self, p: _Point, th: np.ndarray, W: np.ndarray) -> float:
        """``J(theta) - J(p.theta)`` under ``W``, cancellation-free.

        With ``X = [-V, I]`` and ``dX = X(theta) - X(p)``: ``2 tr(W dX G X_p^T) +
        tr(W dX G dX^T)`` -- the first term a product with ``p``'s rows (whose true
        size is that of the prediction errors), the second a quadratic form in the
        small ``dV``; ``J`` itself (``tr(W X G X^T)``) would lose the ratio of the
        signal's to the errors' energy (~1e6 on a high-SNR record) to rounding.
        """
        return self.trial(p, th, W)[0]

    def trial(self, p: _Point, th: np.ndarray, W: np.ndarray) -> tuple[float, np.ndarray]:
        """:meth:`delta` and the prediction errors' covariance at ``theta`` (what the final
        step keeps): the rows ``dX = V(p) - V(theta)`` encoded once; ``inf`` without
        them for a step that leaves the stable predictors (:meth:`leaves_stable`)."""
        pred = self._predictor(th)
        if self.leaves_stable(p, th, pred):
            return float("inf"), p.Re
        rows = self._rows_x  # the last block (the current sample's) stays 0
        with np.errstate(over="ignore", invalid="ignore"):  # a step past the stable region
            np.subtract(p.V, self.markov(th, pred), out=rows[: self.P])
            return self._change(p, self.gram.encode_blocks(rows), W)

    def change(self, p: _Point, q: _Point, W: np.ndarray) -> float:
        """``J(q) - J(p)`` of two built points: :meth:`delta` with ``dX``'s encoding the
        difference of theirs (encodings are linear), no encoding of its own."""
        return self._change(p, q.enc - p.enc, W)[0]

    def _change(self, p: _Point, e, W: np.ndarray):  # type: ignore[no-untyped-def]
        """``J(theta) - J(p)`` from the encoded ``dX``, and the new prediction errors'
        covariance ``(X_p + dX) G (X_p + dX)^T`` from the same two products."""
        B = self.gram.inner(e, p.enc)  # dX G X_p^T
        E = self.gram.inner(e, e)
        return float(np.sum(W * (2.0 * B + E))), p.Re + B + B.T + E

    def cross(self, p0: _Point, p1: _Point, W: np.ndarray) -> np.ndarray:
        """``J_0^T R_1``: the old point's Jacobian against the new residual (the secant term)."""
        C = p0.dV.products(self.gram, p1.enc)  # X_1 G dV_0^T: (3, 3 n_th)
        B = C.reshape(3, -1, 3).transpose(1, 2, 0)  # [i, p, q] = dV_0(i, p) G X_1(q)^T
        return -np.einsum("ipq,qp->i", B, W)


def _normal(p: _Point, W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(J^T J, J^T R)`` of the whitened residual ``R = W^{1/2} (Fy - V Fz)`` at ``p``:
    ``tr(W dV_i Gzz dV_k^T)`` and ``-tr(W dV_i Gz: X^T)`` from ``p``'s Gram products."""
    n = p.theta.size
    B = p.M[3:, :3].reshape(n, 3, 3)  # [i, p, q] = dV(i, p) G X(q)^T
    D = p.M[3:, 3:].reshape(n, 3, n, 3)  # [i, p, k, q] = dV(i, p) G dV(k, q)^T
    H = np.einsum("ipkq,qp->ik", D, W)
    return 0.5 * (H + H.T), -np.einsum("ipq,qp->i", B, W)


def _weight(Re: np.ndarray) -> np.ndarray:
    """``W = (Re + floor I)^{-1}``; a noise-free record's ``Re`` (rounding, maybe slightly
    indefinite through ``G``) has its eigenvalues floored instead."""
    Re = Re + _RE_FLOOR * np.eye(3)
    try:
        sla.cholesky(Re, lower=True)
    except np.linalg.LinAlgError:
        lam, U = np.linalg.eigh(Re)
        Re = (U * np.maximum(lam, _RE_FLOOR)) @ U.T
    return np.linalg.inv(Re)


def fit_bearing_structure(
    gram,  # type: ignore[no-untyped-def]
    *,
    v0: np.ndarray,
    K0: np.ndarray,
    dt: float,
    scale: np.ndarray,
    j: int,
    max_iter: int = _MAX_ITER,
    initial_state: int = START_SAMPLES,
) -> StructuredFit:
    """Weighted least-squares fit of v1..v9 and ``K`` to the window's Gram (P11)-(P13), (P18).

    ``gram``: ``X -> X G`` for the Gram of the window's ``P + 1`` samples
    ``z(t-P..t-1), [u(t), y(t)]`` (oldest first), in the data stage's channel-scaled,
    normalised units (``scale`` the ``[u, y]`` RMS; ``gram.k = P + 1``); ``v0``, ``K0``
    the start in physical units. ``initial_state``: samples the window-start state is
    rebuilt from (P14), 0 to leave it at zero (the long windows of (P16)).
    """
    su, sy = scale[:2], scale[2:]
    theta = np.concatenate([np.zeros(9), (K0 * sy[None, :]).ravel()])
    crit = _Criterion(gram, v0, dt, su, sy, initial_state)
    # (P13): W from the start's prediction errors, one round (a consistent start's W;
    # the second round of the seventh to twenty-eighth sessions, W re-estimated at the
    # first round's end, moved v by <= 0.2 standard errors and cost 2-5 % of the fit:
    # docs/subspace.md, "twenty-ninth session")
    p = crit.point(theta)
    p, iterations, (theta, Re_s), remaining = _gauss_newton(
        crit, p, _weight(p.Re), j, max_iter, _GAIN_TOL, final=True
    )
    _, _, _, _, _, v, Ad, Bd, Ks = _model(theta, v0, dt, sy, su)
    Re = Re_s * np.outer(sy, sy)
    cov = _covariance(p, Re_s, j) * np.outer(v0, v0)
    return StructuredFit(v, Ks / sy[None, :], Ad, Bd, Re, iterations, crit.k0, cov, remaining)


def _covariance(p: _Point, Re: np.ndarray, j: int) -> np.ndarray:
    """``cov(dv/v0)`` (9, 9), (P15): ``(J^T J)^{-1} / j`` with ``W = Re^{-1}`` at the optimum.

    (P11) is the weighted least-squares fit (P12) of the structured Markov
    parameters to the VARX's, weighted by the VARX's inverse covariance
    ``Sigma_varx^{-1} = j (G (x) Re^{-1})``: the sandwich
    ``(J' W J)^{-1} J' W Sigma W J (J' W J)^{-1}`` collapses to
    ``(J' Sigma^{-1} J)^{-1}``, here ``(J^T J)^{-1} / j`` with ``J`` the
    Jacobian of the whitened residual of the normalised Gram, ``W``
    re-estimated at the optimum (``Re`` the estimate's prediction errors' covariance,
    ``p`` the last point built: the estimate itself, or one step before it when the
    last round ended on its final step); inverted with the columns scaled to unit norm.
    """
    H, _ = _normal(p, _weight(Re))
    d, Hs = _column_scaled(H)
    try:
        Hinv = sla.cho_solve(sla.cho_factor(Hs, lower=True), np.eye(H.shape[0]))
    except np.linalg.LinAlgError:  # not positive definite to rounding: the weak directions
        Hinv = np.linalg.pinv(Hs, hermitian=True)
    cov = Hinv / np.outer(d, d) / j
    return cov[:9, :9]


def _column_scaled(H: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(d, H / (d d^T))``: the normal equations with their columns scaled to unit
    diagonal (``d = sqrt|diag H|``, 1 where that is 0)."""
    d = np.sqrt(np.abs(np.diag(H)))
    d[d == 0] = 1.0
    return d, H / np.outer(d, d)


def _solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``A^{-1} b`` for the (scaled) normal equations: Cholesky, else least squares."""
    try:
        return sla.cho_solve(sla.cho_factor(A, lower=True), b)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(A, b, rcond=None)[0]


def _gauss_newton(  # type: ignore[no-untyped-def]
    crit: _Criterion, p: _Point, W: np.ndarray, j: int, max_iter: int, tol: float, final=False
):
    """Gauss-Newton on the normal equations with column scaling; Levenberg-Marquardt
    damping when a step fails. Returns the last point built, the steps taken, the
    estimate ``(theta, Re)`` (the last point's, or the final step's: below) and the gain
    in ``j J`` still predicted there: 0 when the round ended by its stop rule, the next
    Gauss-Newton step's after ``max_iter`` steps, inf when no descent was found by the
    most damped step while the undamped one predicted one.

    Stops when the next undamped step is predicted to lower ``j J`` (twice the
    log-likelihood change) by less than ``tol`` (``-j g^T s`` of the quadratic model
    the step minimises), when a damped step gained less, or after ``max_iter`` steps
    (the returned count: the steps taken). With ``final`` (the last round), a step
    predicted to gain less than ``_FINAL_GAIN`` is taken (its cost checked) and ends
    the fit without a point after it. An undamped Gauss-Newton
    step that raises the cost is first halved (up to ``_HALVINGS`` times: far
    from the optimum the predictor's ``Abar^P`` makes the full step overshoot
    along a good direction) before damping turns it towards the gradient; while the
    last full step gained as predicted (``_TRUST``), the next full step's point is built
    without a trial first. Near the
    optimum the problem is a large-residual one (the true curvature along the step
    ~1.75x ``J^T J``'s, so plain Gauss-Newton converges linearly): after each full
    step the second-order term ``S`` is updated by the secant rule of NL2SOL
    (:func:`_dgw`) and the next step solves ``(J^T J + S) s = -J^T r``; ``S`` is
    dropped after a halved or damped step and whenever ``J^T J + S`` is not positive
    definite. docs/subspace.md, "sixth" to "ninth session".
    """
    H, g = _normal(p, W)
    lam, it, h = 0.0, 0, 0
    Sq, trusted = None, False
    for it in range(1, max_iter + 1):
        d, Hs = _column_scaled(H)
        gs = g / d
        q = None  # the next point, when built before its cost is judged
        while True:
            if lam:
                step = _solve(Hs + lam * np.eye(gs.size), -gs)
                dc = crit.delta(p, p.theta + step / d, W)
            else:  # undamped: the Gauss-Newton step, halved while it raises the cost
                step = _newton_step(Hs, gs, d, Sq)
                if step is None:  # J^T J + S not positive definite: Gauss-Newton
                    Sq = None
                    step = _solve(Hs, -gs)
                pred = -j * float(gs @ step)
                if pred < tol:  # the predicted gain: converged
                    return p, it - 1, (p.theta, p.Re), 0.0
                dc0 = None  # the full step's cost change, when already tried
                if final and pred < _FINAL_GAIN:  # the last step, without a point after it
                    th = p.theta + step / d
                    dc0, Re = crit.trial(p, th, W)
                    if dc0 <= 0.0:
                        return p, it, (th, Re), 0.0
                step, dc, q, h = _undamped(crit, p, step, d, W, trusted, dc0)
            if dc <= 0.0 or lam > 1e8:
                break
            lam = 1e-4 if lam == 0 else lam * 10.0
        if not dc <= 0.0:  # (a NaN from an overflowing trial fails too)
            return p, it, (p.theta, p.Re), float("inf")
        gain = -dc * j
        p0, g0, full = p, g, not lam and h == 0
        trusted = full and _TRUST[0] * pred <= gain <= _TRUST[1] * pred
        p = crit.point(p.theta + step / d) if q is None else q
        lam = 0.0 if lam <= 1e-3 else lam / 10.0
        H, g = _normal(p, W)
        # the second-order term S by a secant update while the steps are full ones
        Sq = _dgw(Sq, step / d, g0, g, crit.cross(p0, p, W)) if full else None
        if lam and gain < tol:  # damped on: no prediction to judge the next step by
            return p, it, (p.theta, p.Re), 0.0
    d, Hs = _column_scaled(H)  # the step limit: what the next Gauss-Newton step predicts
    return p, it, (p.theta, p.Re), max(0.0, -j * float((g / d) @ _solve(Hs, -g / d)))


def _undamped(crit, p, step, d, W, trusted, dc0=None):  # type: ignore[no-untyped-def]
    """The undamped step, halved up to ``_HALVINGS`` times while it raises the cost:
    ``(step, cost change, its point or None, halvings)``. A trusted full step's point is
    built first and its cost change read off the encodings (no trial; the point is
    dropped if the cost rose); ``dc0``: the full step's cost change, already tried
    (and positive), so the halving starts at once."""
    h0 = 0
    if dc0 is not None:
        if _HALVINGS == 0:
            return step, dc0, None, 0
        step, h0 = 0.5 * step, 1
    elif trusted:
        th = p.theta + step / d
        q = None if crit.leaves_stable(p, th) else _finite_point(crit, th)
        dc = float("inf") if q is None else crit.change(p, q, W)
        if dc <= 0.0:
            return step, dc, q, 0
        if _HALVINGS == 0:
            return step, dc, None, 0
        step, h0 = 0.5 * step, 1
    for h in range(h0, _HALVINGS + 1):
        dc = crit.delta(p, p.theta + step / d, W)
        if dc <= 0.0 or h == _HALVINGS:
            break
        step = 0.5 * step
    return step, dc, None, h


def _finite_point(crit: _Criterion, th: np.ndarray) -> _Point | None:
    """``crit.point(th)``, or None where the predictor's powers overflow: a trusted full
    step far past the stable region (found from outside: a 1 um sensor line at 50 Hz on
    the bearing's position sent one to ``|Abar^P|`` ~ 1e308, and the fit ended in a
    ValueError of the sequence basis' QR instead of halving the step)."""
    with np.errstate(over="ignore", invalid="ignore"):
        try:
            q = crit.point(th)
        except (ValueError, np.linalg.LinAlgError):
            return None
    return q if np.all(np.isfinite(q.M)) else None


def _newton_step(Hs: np.ndarray, gs: np.ndarray, d: np.ndarray, Sq: np.ndarray | None):
    """``-(Hs + D^-1 S D^-1)^{-1} gs`` (scaled units), None when not positive definite;
    the Gauss-Newton step when there is no ``S`` yet."""
    if Sq is None:
        return _solve(Hs, -gs)
    try:
        cf = sla.cho_factor(Hs + Sq / np.outer(d, d), lower=True)
    except np.linalg.LinAlgError:
        return None
    return sla.cho_solve(cf, -gs)


def _dgw(Sq, s, g0, g1, g01):  # type: ignore[no-untyped-def]
    """Dennis, Gay & Welsch (1981) secant update of the second-order term ``S`` (NL2SOL).

    ``S`` approximates ``sum_i r_i Hess(r_i)``, which Gauss-Newton drops: with
    ``g = J^T R`` at the old (``g0``) and new (``g1``) points and ``g01 = J_0^T R_1``,
    ``y# = g1 - g01 = (J1 - J0)^T r1`` (what ``S`` must map the step ``s`` to) and
    ``y = g1 - g0`` the gradient's change, the symmetric rank-2 update of least change
    in the ``y``-weighted norm, ``S`` first sized by ``min(1, |s'y#| / |s'Ss|)``.
    Starts from 0 (``Sq`` None); left unchanged when ``s'y <= 0``.
    """
    if Sq is None:
        Sq = np.zeros((s.size, s.size))
    y = g1 - g0
    ys = g1 - g01
    sy = float(s @ y)
    if sy <= 0.0:
        return Sq
    sSs = float(s @ Sq @ s)
    tau = min(1.0, abs(float(s @ ys)) / abs(sSs)) if sSs != 0.0 else 1.0
    Sq = tau * Sq
    z = ys - Sq @ s
    return Sq + (np.outer(z, y) + np.outer(y, z)) / sy - float(z @ s) * np.outer(y, y) / sy**2
