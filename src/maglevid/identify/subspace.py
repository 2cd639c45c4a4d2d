"""MIMO subspace identification: MOESP and N4SID, in memory or streamed in chunks.

Implements

* MOESP: ordinary MOESP (Verhaegen & Dewilde 1992), PI-MOESP (past inputs as
  instruments) and PO-MOESP (past inputs and outputs as instruments, Verhaegen
  1994), the variant to use for noisy data;
* N4SID (Van Overschee & De Moor 1994): the oblique projection with the
  N4SID, MOESP and CVA weightings of the unifying theorem (Van Overschee & De
  Moor 1996, Ch. 4), the "robust" combined algorithm (A and C from the state
  equations, B and D by least squares afterwards) and the "simple" one (all
  four from the state sequences).

Both work from one triangular factor of the block-Hankel data, computed in
linear memory by :mod:`maglevid.identify._hankel` (Gram + pivoted Cholesky by
default, tall-skinny QR on request). :class:`SubspaceAccumulator` exposes the
streaming form: feed a record of any length chunk by chunk, then fit; the
result equals the in-memory one to rounding.

Notation (time-first data, horizon ``i``)
-----------------------------------------
``U_p = U_{0|i-1}``, ``U_f = U_{i|2i-1}``, ``Y_p``, ``Y_f`` likewise, ``W_p =
[U_p; Y_p]`` the block rows of the textbook Hankel matrices; ``Gamma_i`` the
extended observability matrix ``[C; CA; ...; CA^{i-1}]``; ``H_i`` the block
lower-triangular Toeplitz matrix of the Markov parameters ``D, CB, CAB, ...``.
Every product of data rows is taken on the factor ``F`` (``F F^T = H^T H / j``)
so the rows are represented in an orthonormal basis and "projection onto the
row space of X" is a small least-squares problem.

Nothing here stabilises an estimate: an unstable plant gives an unstable model.
"""

from __future__ import annotations

import functools
import logging
import math
import warnings
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import scipy.linalg as sla
from scipy.linalg import lapack

from maglevid._validation import as_signal, check_positive
from maglevid.exceptions import (
    DataError,
    IdentificationError,
    IllConditionedWarning,
    ModelError,
)
from maglevid.identify._hankel import (
    _HankelQR,
    _LagGram,
    factor_gram,
    factor_r,
    lower_factor,
)
from maglevid.identify._recursion import linear_recursion
from maglevid.identify.options import Option, bind_defaults
from maglevid.identify.result import IdentificationResult
from maglevid.lti import StateSpace, undiscretize

__all__ = ["DEFAULT_MAX_HORIZON", "METHODS", "SubspaceAccumulator", "fit_moesp", "fit_n4sid"]

logger = logging.getLogger(__name__)

#: Largest horizon the automatic rule considers (closed-loop unstable plants
#: sampled fast need 20-40; see docs/subspace.md).
DEFAULT_MAX_HORIZON = 40

#: The automatic horizon keeps at least this many Hankel rows per column.
_ROWS_PER_COLUMN_AUTO = 5
#: Any horizon needs at least this many Hankel rows per column.
_ROWS_PER_COLUMN_MIN = 2

_MOESP_WEIGHTINGS = ("po", "pi", "ordinary")
_N4SID_WEIGHTINGS = ("n4sid", "moesp", "cva")
_N4SID_VARIANTS = ("robust", "simple")
_FACTORIZATIONS = ("gram", "qr")
_BD_METHODS = ("subspace", "regression")

_EPS = float(np.finfo(float).eps)
#: LAPACK block size the workspaces of the direct calls are sized for (ILAENV gives 32).
_NB = 64

#: Default relative singular-value floor of the order choice, per factorisation:
#: the rounding level of noise-free data (measured, docs/subspace.md) times ~100.
_DEFAULT_RANK_TOL = {"gram": 1e-6, "qr": 1e-10}
#: Relative rank threshold of the row-space projections, per factorisation.
_PROJ_RCOND = {"gram": 1e-10, "qr": 1e-13}
#: Below this ratio s_n / s_1 the weakest retained direction is not resolved
#: reliably by the factorisation (Gram: errors ~ eps / ratio^2; QR: ~ eps / ratio).
_ILL_RATIO = {"gram": 1e-5, "qr": 1e-10}
#: Floor of ARX residual variances (channels scaled to unit RMS) in the horizon rule.
_ARX_VAR_FLOOR = 1e-12
#: Samples per chunk of the in-memory passes (a chunk of z stays in the L2/L3 cache).
_CHUNK = 1 << 16
#: Samples per block of the one-step residuals (``_predictor_residuals``).
_RESID_BLOCK = 16
#: The regression for B, D refuses a model that grows by more than this over the record.
_MAX_GROWTH = 1e12


# ----------------------------------------------------------------- data stage
@dataclass(frozen=True)
class _Stats:
    """What the data stage hands to the algorithms (scaled, normalised by sqrt(j))."""

    F: np.ndarray  # (k_rows, r): F F^T = Hs^T Hs / j, Hs the channel-scaled Hankel
    nu: int
    ny: int
    i_rows: int  # window of the Hankel rows is 2 * i_rows
    j: int
    n_samples: int
    scale: np.ndarray  # (m,) RMS of [u, y]
    mean: np.ndarray  # (m,)
    rank: int
    factorization: str

    @property
    def m(self) -> int:
        return self.nu + self.ny

    def u_rows(self, t0: int, t1: int) -> np.ndarray:
        """Row indices of u(t0..t1-1) (time-major, z = [u, y])."""
        return _channel_rows(self.m, 0, self.nu, t0, t1)

    def y_rows(self, t0: int, t1: int) -> np.ndarray:
        """Row indices of y(t0..t1-1)."""
        return _channel_rows(self.m, self.nu, self.ny, t0, t1)

    def rows(self, idx: np.ndarray) -> np.ndarray:
        return self.F[idx]


@functools.lru_cache(maxsize=256)
def _channel_rows(m: int, c0: int, nc: int, t0: int, t1: int) -> np.ndarray:
    """Rows ``t m + c0 + c`` for ``t0 <= t < t1``, ``c < nc`` (time-major), ascending.

    Cached (read-only): a fit asks for the same dozen index sets, each a few numpy
    calls, a fixed cost of every fit.
    """
    rows = (np.arange(t0, t1)[:, None] * m + np.arange(c0, c0 + nc)[None, :]).ravel()
    rows.flags.writeable = False
    return rows


def _auto_max_horizon(n_samples: int, m: int, cap: int) -> int:
    # Largest i with j = N - 2i + 1 >= 5 * (2 i m) rows per column: i <= (N+1)/(2+10m).
    return int(min(cap, (n_samples + 1) // (2 + 2 * _ROWS_PER_COLUMN_AUTO * m)))


def _min_horizon(order: int | None, ny: int) -> int:
    # (i - 1) ny >= n: Gamma_{i-1} must have full column rank (shift invariance, N4SID).
    if order is None:
        return 2
    return max(2, math.ceil(order / ny) + 1)


def _check_rows(n_samples: int, i: int, m: int, what: str) -> None:
    j = n_samples - 2 * i + 1
    k = 2 * i * m
    if j < _ROWS_PER_COLUMN_MIN * k:
        need = _ROWS_PER_COLUMN_MIN * k + 2 * i - 1
        raise DataError(
            f"the record has {n_samples} samples; {what} needs at least {need} "
            f"(2 x {k} block-Hankel rows for horizon {i} with {m} channels)"
        )


def _stats_from(acc: _LagGram | _HankelQR, nu: int, ny: int, i_rows: int) -> _Stats:
    """Scaled, normalised factor of the Hankel rows of window ``2 i_rows``."""
    N = acc.n
    m = nu + ny
    w = 2 * i_rows
    j = N - w + 1
    moments = acc.moments  # (a property that assembles the sums: read once)
    scale = moments.rms()
    zero = np.flatnonzero(scale == 0.0)
    if zero.size:
        c = int(zero[0])
        name = f"u[:, {c}]" if c < nu else f"y[:, {c - nu}]"
        raise DataError(
            f"`{name}` is identically zero; every input must excite the system and every "
            "output must be measured"
        )
    d = np.tile(1.0 / scale, w)
    if isinstance(acc, _LagGram):
        G = acc.gram(w) * (d[:, None] * d[None, :]) / j
        F, rank = factor_gram(G)
        fact = "gram"
    else:
        R = acc.R
        if R.shape[1] != w * m:  # pragma: no cover - guarded by the caller
            raise ValueError("QR accumulator window does not match")
        F = factor_r(R) * d[:, None] / math.sqrt(j)
        rank = int(min(R.shape))
        fact = "qr"
    return _Stats(
        F=F,
        nu=nu,
        ny=ny,
        i_rows=i_rows,
        j=j,
        n_samples=N,
        scale=scale,
        mean=moments.mean(),
        rank=rank,
        factorization=fact,
    )


# ------------------------------------------------------- small linear algebra
def _orth(X: np.ndarray, rcond: float, ref: float = 0.0) -> np.ndarray:
    """Orthonormal basis (r x q) of the row space of ``X`` (p x r), rank by ``rcond``.

    Directions are kept while their pivot exceeds ``rcond`` times the largest
    pivot, or times ``ref`` when that is larger (the scale of the rows ``X`` was
    made from, when ``X`` is a residual that may be all rounding).
    """
    # Rank-revealing QR with column pivoting of X^T (LAPACK geqp3): |R_kk| decrease
    # and bracket the singular values within a factor growing like sqrt(k); at the
    # gaps used here (noise-free rank drops of many decades) it decides as the SVD
    # does, at a fraction of the cost (the projections are the bulk of a fit at a
    # long horizon).
    if X.shape[0] == 0:
        return np.zeros((X.shape[1], 0))
    # LAPACK directly, with a workspace for blocks of _NB (scipy.linalg.qr asks LAPACK
    # for the size first: two more calls, a third of the time on these small matrices).
    n = X.shape[0]
    qr, _, tau, _, info = lapack.dgeqp3(X.T, lwork=2 * n + (n + 1) * _NB)
    if info != 0:  # pragma: no cover - LAPACK argument error
        raise RuntimeError(f"dgeqp3 failed with info={info}")
    d = np.abs(np.diag(qr))
    if d.size == 0 or d[0] == 0.0:
        return np.zeros((X.shape[1], 0))
    q = int(np.count_nonzero(d > rcond * max(d[0], ref)))
    if q == 0:
        return np.zeros((X.shape[1], 0))
    # The first q columns of Q need only the first q reflectors (H_j leaves e_i, i < j).
    Q, _, info = lapack.dorgqr(qr[:, :q], tau[:q], lwork=q * _NB)
    if info != 0:  # pragma: no cover
        raise RuntimeError(f"dorgqr failed with info={info}")
    return Q


def _orth_extend(Q: np.ndarray, X: np.ndarray, rcond: float) -> np.ndarray:
    """Orthonormal basis of the row spaces of ``Q^T`` and ``X`` together (``Q`` first).

    The rows of ``X`` are orthogonalised against ``Q`` twice (classical Gram-Schmidt
    with re-orthogonalisation) and what is left is kept when it is above ``rcond``
    times the largest row of ``X``: a row that the basis already spans adds nothing.
    """
    if X.shape[0] == 0:
        return Q
    Xr = _perp(_perp(X, Q), Q)
    ref = float(np.max(np.linalg.norm(X, axis=1)))
    return np.concatenate([Q, _orth(Xr, rcond, ref)], axis=1)


def _perp(X: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """``X Pi_perp``: rows of ``X`` minus their projection on the row space with basis ``Q``."""
    return X - (X @ Q) @ Q.T


def _regress(Y: np.ndarray, X: np.ndarray, rcond: float) -> np.ndarray:
    """Coefficients ``M`` of ``Y ~ M X`` (rows are signals): least squares, pivoted QR."""
    if X.shape[0] == 0:
        return np.zeros((Y.shape[0], 0))
    # LAPACK gelsy directly (what scipy.linalg.lstsq(..., lapack_driver="gelsy") calls,
    # without its workspace query): a workspace for blocks of _NB.
    m, n = X.shape[1], X.shape[0]
    nrhs = Y.shape[0]
    B = np.zeros((max(m, n), nrhs))
    B[:m] = Y.T
    mn = min(m, n)
    lwork = max(mn + 2 * n + _NB * (n + 1), 2 * mn + _NB * nrhs)
    _, x, _, _, info = lapack.dgelsy(X.T, B, np.zeros(n, dtype=np.int32), rcond, lwork)
    if info != 0:  # pragma: no cover - LAPACK argument error
        raise RuntimeError(f"dgelsy failed with info={info}")
    return x[:n].T


def _pinv_apply(Gam: np.ndarray, X: np.ndarray) -> np.ndarray:
    """``Gamma^dagger X`` for a tall ``Gamma`` of full column rank (least squares)."""
    return _lstsq(Gam, X)


def _lstsq(X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Minimum-norm least squares (LAPACK ``gelsd``, singular values below ``eps s_1`` cut).

    What ``scipy.linalg.lstsq`` computes by default, through numpy's binding, which
    costs a third as much on these small systems (a fixed cost of every fit).
    """
    return np.linalg.lstsq(X, Y, rcond=_EPS)[0]


def _observability(A: np.ndarray, C: np.ndarray, i: int) -> np.ndarray:
    """``Gamma_i = [C; CA; ...; CA^{i-1}]``."""
    ny, n = C.shape
    G = np.empty((i * ny, n))
    blk = C
    for r in range(i):
        G[r * ny : (r + 1) * ny] = blk
        blk = blk @ A
    return G


def _markov(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray, i: int) -> np.ndarray:
    """``[D, CB, CAB, ..., CA^{i-2}B]``, shape (i, ny, nu)."""
    out = np.empty((i, C.shape[0], B.shape[1]))
    out[0] = D
    AkB = B
    for k in range(1, i):
        out[k] = C @ AkB
        AkB = A @ AkB
    return out


def _toeplitz(h: np.ndarray) -> np.ndarray:
    """Block lower-triangular Toeplitz ``H_i`` of Markov parameters ``h`` (i, ny, nu).

    One gather of ``[h; 0]`` by the cached block index ``r - c`` (``i`` above the
    diagonal: the zero block) instead of one assignment per block diagonal (5-8x
    faster at i = 10, a fixed cost of every fit; the same values).
    """
    i, ny, nu = h.shape
    hz = np.zeros((i + 1, ny, nu))
    hz[:i] = h
    return hz[_toeplitz_index(i)].transpose(0, 2, 1, 3).reshape(i * ny, i * nu)


@functools.lru_cache(maxsize=64)
def _toeplitz_index(i: int) -> np.ndarray:
    """Block index ``r - c`` of block ``(r, c)`` of ``H_i``, ``i`` where ``c > r``."""
    r = np.arange(i)
    idx = r[:, None] - r[None, :]
    idx = np.where(idx < 0, i, idx)
    idx.flags.writeable = False
    return idx


def _char_poly(A_or_poles: np.ndarray) -> np.ndarray:
    """``[a1, ..., an]`` of ``det(zI - A) = z^n + a1 z^{n-1} + ... + an``.

    Takes ``A`` or its eigenvalues (``np.poly`` of the matrix computes them first).
    """
    return np.real(np.poly(A_or_poles))[1:] if A_or_poles.size else np.zeros(0)


# ------------------------------------------------------------ order and horizon
def _choose_order(s: np.ndarray, n_max: int, rank_tol: float) -> tuple[int, float]:
    """Largest gap of the log singular values, with values below ``rank_tol * s_1`` floored.

    Returns the order and the ratio ``s_n / s_{n+1}`` at the chosen gap (floored).
    """
    if s.size == 0 or s[0] <= 0.0:
        raise IdentificationError(
            "all singular values are zero: the outputs carry no information about the "
            "inputs (check the data and the excitation)"
        )
    n_max = min(n_max, s.size - 1)
    if n_max < 1:
        return 1, float("inf")
    sf = np.maximum(s / s[0], rank_tol)
    gaps = np.log(sf[:n_max]) - np.log(sf[1 : n_max + 1])
    n = int(np.argmax(gaps)) + 1
    return n, float(np.exp(gaps[n - 1]))


def _arx_horizon(st: _Stats, p_max: int, feedthrough: bool) -> tuple[int, np.ndarray]:
    """ARX order by AIC from the leading ``p_max + 1`` time blocks of the factor.

    For ``p = 1..p_max``, ``y(t+p)`` is regressed on ``z(t..t+p-1)`` (and ``u(t+p)``
    with feedthrough) over the same Hankel rows; the residual covariance is the
    diagonal block of the lower-triangular factor of the rows in the order
    ``[y(t), u(t), y(t+1), u(t+1), ...]`` (``[u, y]`` per time with feedthrough).
    AIC(p) = j log det Sigma_p + 2 p m ny (Akaike 1974), with the eigenvalues of
    Sigma_p floored at 1e-12 (channels scaled to unit RMS): noise-free data then
    pick the smallest exact order instead of chasing rounding noise.
    """
    nu, ny, m = st.nu, st.ny, st.m
    w = p_max + 1
    lead = st.F[: w * m]
    aic = np.full(p_max + 1, np.inf)
    p = np.arange(1, p_max + 1)
    penalty = 2.0 * (p * m * ny + (nu * ny if feedthrough else 0))
    tri = lead.shape[1] == w * m and not np.any(np.triu(lead, 1))
    if tri and np.all(np.diagonal(lead) > 0.0):
        # F already lower triangular in the time-major order [u, y] with a positive
        # diagonal (a Cholesky factor, as pbsid's; the earlier rows then span exactly
        # the earlier columns): the residual of y(t+p) given z(t..t+p-1) (and u(t+p))
        # is in the y rows of the diagonal block p (their y columns): the same
        # Sigma_p as the reordered factor's, all p at once, without factorising.
        blocks = lead.reshape(w, m, w, m)[p, nu:, p, (nu if feedthrough else 0) :]
        ev = np.linalg.eigvalsh(blocks @ blocks.transpose(0, 2, 1))
        logdet = np.sum(np.log(np.maximum(ev, _ARX_VAR_FLOOR)), axis=1)
        aic[1:] = st.j * logdet + penalty
        return int(np.argmin(aic)), aic
    perm: list[int] = []
    for t in range(w):
        u_t = list(st.u_rows(t, t + 1))
        y_t = list(st.y_rows(t, t + 1))
        perm += (u_t + y_t) if feedthrough else (y_t + u_t)
    L = lower_factor(st.F[np.array(perm)])
    for k in range(1, p_max + 1):
        start = k * m + (nu if feedthrough else 0)
        Ly = L[start : start + ny, start:]
        ev = np.linalg.eigvalsh(Ly @ Ly.T) if Ly.shape[1] else np.zeros(ny)
        logdet = float(np.sum(np.log(np.maximum(ev, _ARX_VAR_FLOOR))))
        aic[k] = st.j * logdet + penalty[k - 1]
    return int(np.argmin(aic)), aic


# ------------------------------------------------------------- the algorithms
@dataclass
class _Core:
    """Scaled-coordinate estimate before B, D (and the pieces later steps reuse)."""

    A: np.ndarray
    C: np.ndarray
    B: np.ndarray | None
    D: np.ndarray | None
    s: np.ndarray
    n: int
    gap: float
    order_auto: bool
    K_hat: np.ndarray | None = None  # robust N4SID: unconstrained coefficient on U_f
    Z: tuple[_Projected, _Projected] | None = None  # (Z_i, Z_{i+1}) when already computed


def _order_and_gamma(
    U: np.ndarray, s: np.ndarray, order: int | None, n_max: int, rank_tol: float
) -> tuple[int, float, bool, np.ndarray]:
    if order is None:
        n, gap = _choose_order(s, n_max, rank_tol)
        auto = True
    else:
        n = order
        if n > s.size or s[n - 1] <= 0.0:
            raise IdentificationError(
                f"order={n} exceeds the rank of the projected data "
                f"({int(np.count_nonzero(s > 0))}); the instruments or the horizon are too "
                "small for it (increase `horizon`, or use weighting='po')"
            )
        gap = float(s[n - 1] / s[n]) if s.size > n and s[n] > 0 else float("inf")
        auto = False
    Gam = U[:, :n] * np.sqrt(s[:n])[None, :]
    return n, gap, auto, Gam


def _ac_from_gamma(Gam: np.ndarray, ny: int) -> tuple[np.ndarray, np.ndarray]:
    # Shift invariance: Gamma_i without its first block row = Gamma_{i-1} A.
    C = Gam[:ny].copy()
    A = _lstsq(Gam[:-ny], Gam[ny:])
    return A, C


def _moesp_core(
    st: _Stats,
    i: int,
    weighting: str,
    order: int | None,
    rank_tol: float,
    rcond: float,
    noise_model: bool = True,
) -> _Core:
    # LQ of [U_f; W_p; Y_f]: Y_f Pi_{U_f}^perp projected on the row space of the
    # instruments W_p Pi_{U_f}^perp is L32 Q2^T; its column space is that of
    # Gamma_i (Verhaegen 1994, PO-MOESP; W_p = U_p for PI-MOESP; ordinary MOESP
    # (Verhaegen & Dewilde 1992) takes Y_f Pi_{U_f}^perp itself, L22).
    ny = st.ny
    Uf = st.rows(st.u_rows(i, 2 * i))
    Yf = st.rows(st.y_rows(i, 2 * i))
    Qu = _orth(Uf, rcond)
    Yfp = _perp(Yf, Qu)
    if weighting == "ordinary":
        P = Yfp
    else:
        idx = st.u_rows(0, i)
        if weighting == "po":
            idx = np.concatenate([idx, st.y_rows(0, i)])
        Wpp = _perp(st.rows(idx), Qu)
        Qw = _orth(Wpp, rcond, float(np.max(np.linalg.norm(st.rows(idx), axis=1))))
        P = Yfp @ Qw  # L32 (up to an orthogonal factor on the right)
    U, s, _ = np.linalg.svd(P, full_matrices=False)
    n, gap, auto, Gam = _order_and_gamma(U, s, order, (i - 1) * ny, rank_tol)
    A, C = _ac_from_gamma(Gam, ny)
    # [Qu, Qw] spans [U_f; U_p; Y_p], the instruments of the noise statistics.
    Z = (
        _z_projections(st, i, rcond, np.concatenate([Qu, Qw], axis=1))
        if weighting == "po" and noise_model
        else None
    )
    return _Core(A=A, C=C, B=None, D=None, s=s, n=n, gap=gap, order_auto=auto, Z=Z)


def _bd_moesp(
    st: _Stats, i: int, A: np.ndarray, C: np.ndarray, feedthrough: bool, rcond: float
) -> tuple[np.ndarray, np.ndarray]:
    # Y_f = Gamma_i X_f + H_i U_f + noise. With Gamma_perp^T Gamma_i = 0 and the
    # regression on U_f (= L31 L11^{-1} in the LQ of [U_f; ...; Y_f]):
    #   M := Gamma_perp^T (Y_f / U_f) = Gamma_perp^T H_i(B, D),
    # linear in (B, D). With Gamma_perp^T = [Lc_0 ... Lc_{i-1}] (block columns),
    # block column c of M is  Lc_c D + sum_{r>c} Lc_r C A^{r-c-1} B.
    ny, nu = st.ny, st.nu
    n = A.shape[0]
    Gam = _observability(A, C, i)
    Qg = np.linalg.qr(Gam, mode="complete")[0]
    Gp = Qg[:, n:].T  # (i ny - n) x i ny
    Uf = st.rows(st.u_rows(i, 2 * i))
    Yf = st.rows(st.y_rows(i, 2 * i))
    M = _regress(Gp @ Yf, Uf, rcond)  # (i ny - n) x i nu
    p = Gp.shape[0]
    nd = ny if feedthrough else 0
    lhs = np.zeros((i * p, nd + n))
    rhs = np.zeros((i * p, nu))
    for c in range(i):
        rows = slice(c * p, (c + 1) * p)
        if feedthrough:
            lhs[rows, :ny] = Gp[:, c * ny : (c + 1) * ny]
        if c < i - 1:
            lhs[rows, nd:] = Gp[:, (c + 1) * ny :] @ Gam[: (i - c - 1) * ny]
        rhs[rows] = M[:, c * nu : (c + 1) * nu]
    sol = _lstsq(lhs, rhs)
    D = sol[:ny] if feedthrough else np.zeros((ny, nu))
    B = sol[nd:]
    return B, D


def _oblique(
    st: _Stats, Yf: np.ndarray, Uf: np.ndarray, Wp: np.ndarray, rcond: float
) -> tuple[np.ndarray, np.ndarray]:
    """Oblique projection ``Y_f /_{U_f} W_p`` and the basis of ``U_f``'s row space."""
    # Y_f / [W_p; U_f] = L_w W_p + L_u U_f; the oblique projection is L_w W_p, and
    # L_w is the regression of Y_f Pi_{U_f}^perp on W_p Pi_{U_f}^perp.
    Qu = _orth(Uf, rcond)
    Lw = _regress(_perp(Yf, Qu), _perp(Wp, Qu), rcond)
    return Lw @ Wp, Qu


def _n4sid_core(
    st: _Stats,
    i: int,
    weighting: str,
    variant: str,
    order: int | None,
    rank_tol: float,
    rcond: float,
    feedthrough: bool,
) -> _Core:
    ny, nu = st.ny, st.nu
    Up = st.rows(st.u_rows(0, i))
    Yp = st.rows(st.y_rows(0, i))
    Uf = st.rows(st.u_rows(i, 2 * i))
    Yf = st.rows(st.y_rows(i, 2 * i))
    Wp = np.concatenate([Up, Yp])
    O_i, Qu = _oblique(st, Yf, Uf, Wp, rcond)  # Van Overschee & De Moor (1994), Theorem 2
    # Weights W1 O_i W2 of the unifying theorem (1996, Ch. 4).
    T = None
    if weighting == "n4sid":
        M = O_i
    elif weighting == "moesp":
        M = _perp(O_i, Qu)
    else:  # cva: W1 = (Y_f Pi_perp Y_f^T)^{-1/2}, here through a triangular factor
        T = lower_factor(_perp(Yf, Qu))
        if T.shape[1] < T.shape[0] or np.min(np.abs(np.diag(T))) <= 1e-8 * np.max(
            np.abs(np.diag(T))
        ):
            raise IdentificationError(
                "weighting='cva' needs Y_f Pi_perp Y_f^T of full rank, which noise-free or "
                "deterministic data lack; use weighting='n4sid' or 'moesp'"
            )
        M = sla.solve_triangular(T, _perp(O_i, Qu), lower=True)
    U, s, _ = np.linalg.svd(M, full_matrices=False)
    n, gap, auto, Gam = _order_and_gamma(U, s, order, (i - 1) * ny, rank_tol)
    if T is not None:
        Gam = T @ Gam  # Gamma_i = W1^{-1} U_1 S_1^{1/2}
    Gm = Gam[:-ny]  # Gamma_{i-1}
    if variant == "simple":
        # X_i = Gamma_i^+ O_i, X_{i+1} = Gamma_{i-1}^+ O_{i-1};
        # [X_{i+1}; Y_i] = [A B; C D] [X_i; U_i] + residuals (least squares).
        Wpp = np.concatenate([st.rows(st.u_rows(0, i + 1)), st.rows(st.y_rows(0, i + 1))])
        O_m, _ = _oblique(
            st, st.rows(st.y_rows(i + 1, 2 * i)), st.rows(st.u_rows(i + 1, 2 * i)), Wpp, rcond
        )
        X_i = _pinv_apply(Gam, O_i)
        X_n = _pinv_apply(Gm, O_m)
        U_i = st.rows(st.u_rows(i, i + 1))
        Y_i = st.rows(st.y_rows(i, i + 1))
        AB = _regress(X_n, np.concatenate([X_i, U_i]), rcond)
        A, B = AB[:, :n], AB[:, n:]
        if feedthrough:
            CD = _regress(Y_i, np.concatenate([X_i, U_i]), rcond)
            C, D = CD[:, :n], CD[:, n:]
        else:
            C, D = _regress(Y_i, X_i, rcond), np.zeros((ny, nu))
        return _Core(A=A, C=C, B=B, D=D, s=s, n=n, gap=gap, order_auto=auto)
    # Robust: [Gamma_{i-1}^+ Z_{i+1}; Y_i] = [A; C] Gamma_i^+ Z_i + K U_f + residuals,
    # Z_i = Y_f / [W_p; U_f], Z_{i+1} = Y_f^- / [W_p^+; U_f^-]; K is linear in (B, D).
    # [U_f; W_p] = [U_f; U_p; Y_p]: its basis is Qu extended by W_p.
    Z_i, Z_n = _z_projections(st, i, rcond, _orth_extend(Qu, Wp, rcond))
    Y_i = st.rows(st.y_rows(i, i + 1))
    lhs = np.concatenate([Z_n.pinv_apply(Gm), Y_i])
    rhs = np.concatenate([Z_i.pinv_apply(Gam), Uf])
    sol = _regress(lhs, rhs, rcond)
    A, C = sol[:n, :n], sol[n:, :n]
    return _Core(
        A=A,
        C=C,
        B=None,
        D=None,
        s=s,
        n=n,
        gap=gap,
        order_auto=auto,
        K_hat=sol[:, n:],
        Z=(Z_i, Z_n),
    )


@dataclass(frozen=True)
class _Projected:
    """A projection ``Z = X Q Q^T`` on the row space with orthonormal basis ``Q``, kept
    as ``(X Q, Q)``: what uses ``Z`` applies a small matrix on the left first."""

    XQ: np.ndarray  # (p, q)
    Q: np.ndarray  # (r, q)

    def pinv_apply(
        self, Gam: np.ndarray, H: np.ndarray | None = None, U: np.ndarray | None = None
    ) -> np.ndarray:
        """``Gamma^+ Z``, or ``Gamma^+ (Z - H U)`` when ``H`` and ``U`` are given.

        Computed as ``(Gamma^+ X Q) Q^T - (Gamma^+ H) U``: the products of
        ``_innovation_stats`` associated the other way, ``Gamma^+`` (n rows) applied
        first, so the products with the (r x q) basis and with ``U`` have ``n``
        rows instead of ``p`` (at horizon 40, 4 instead of 120: the projections
        were a tenth of a bearing fit at N = 1e4). Equal to rounding.
        """
        if H is None or U is None:
            return _lstsq(Gam, self.XQ) @ self.Q.T
        q = self.XQ.shape[1]
        G = _lstsq(Gam, np.concatenate([self.XQ, H], axis=1))  # one factorisation
        return G[:, :q] @ self.Q.T - G[:, q:] @ U


def _z_projections(
    st: _Stats, i: int, rcond: float, Q1: np.ndarray | None = None
) -> tuple[_Projected, _Projected]:
    """``Z_i = Y_f / [W_p; U_f]`` and ``Z_{i+1} = Y_f^- / [W_p^+; U_f^-]`` (factored).

    ``Q1``, when given, is an orthonormal basis of the row space of
    ``[U_p; U_f; Y_p]`` already computed; the basis of the second projection is
    that one extended by ``y(i)``.
    """
    if Q1 is None:
        U_all = st.rows(st.u_rows(0, 2 * i))
        Q1 = _orth(np.concatenate([U_all, st.rows(st.y_rows(0, i))]), rcond)
    Q2 = _orth_extend(Q1, st.rows(st.y_rows(i, i + 1)), rcond)
    Z_i = _Projected(st.rows(st.y_rows(i, 2 * i)) @ Q1, Q1)
    Z_n = _Projected(st.rows(st.y_rows(i + 1, 2 * i)) @ Q2, Q2)
    return Z_i, Z_n


def _k_operator(A: np.ndarray, C: np.ndarray, i: int, nu: int, feedthrough: bool) -> np.ndarray:
    """Matrix ``N`` with ``vec-by-block(K(B, D)) = N [D; B]`` (robust N4SID, B and D step).

    ``K = [[B, Gamma_{i-1}^+ H_{i-1}] - A Gamma_i^+ H_i ; [D, 0] - C Gamma_i^+ H_i]``;
    block column ``c`` (input ``u(i+c)``) is ``N_c [D; B]`` with ``h(0) = D`` and
    ``h(k) = C A^{k-1} B = E_k [D; B]``.
    """
    ny, n = C.shape
    Gam = _observability(A, C, i)
    Gp = np.linalg.pinv(Gam)  # n x i ny  (small, full column rank)
    Gmp = np.linalg.pinv(Gam[:-ny]) if i > 1 else np.zeros((n, 0))
    # E_k (ny x (ny + n)): h(k) = E_k [D; B].
    E = np.zeros((i, ny, ny + n))
    E[0, :, :ny] = np.eye(ny)
    CAk = C.copy()
    for k in range(1, i):
        E[k, :, ny:] = CAk
        CAk = CAk @ A
    blocks = []
    for c in range(i):
        top = np.zeros((n, ny + n))
        bot = np.zeros((ny, ny + n))
        if c == 0:
            top[:, ny:] = np.eye(n)
            bot[:, :ny] = np.eye(ny)
        else:
            for r in range(c - 1, i - 1):
                top += Gmp[:, r * ny : (r + 1) * ny] @ E[r - c + 1]
        acc = np.zeros((n, ny + n))
        for r in range(c, i):
            acc += Gp[:, r * ny : (r + 1) * ny] @ E[r - c]
        top -= A @ acc
        bot -= C @ acc
        blocks.append(np.concatenate([top, bot]))
    Nmat = np.concatenate(blocks)  # (i (n + ny)) x (ny + n)
    return Nmat if feedthrough else Nmat[:, ny:]


def _bd_robust(
    K_hat: np.ndarray, A: np.ndarray, C: np.ndarray, i: int, nu: int, feedthrough: bool
) -> tuple[np.ndarray, np.ndarray]:
    ny = C.shape[0]
    Nmat = _k_operator(A, C, i, nu, feedthrough)
    # Right-hand side: block columns of K_hat stacked the same way.
    rhs = np.concatenate([K_hat[:, c * nu : (c + 1) * nu] for c in range(i)])
    sol = _lstsq(Nmat, rhs)
    if feedthrough:
        return sol[ny:], sol[:ny]
    return sol, np.zeros((ny, nu))


def _innovation_stats(
    st: _Stats,
    i: int,
    A: np.ndarray,
    B: np.ndarray,
    C: np.ndarray,
    D: np.ndarray,
    rcond: float,
    Z: tuple[_Projected, _Projected] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Residual covariance of the state equations (scaled units) and output residual rows.

    ``X_i = Gamma_i^+ (Z_i - H_i U_f)`` are the states of a bank of Kalman filters
    with ``i`` past samples (Van Overschee & De Moor 1996, Ch. 4); the residuals
    ``[X_{i+1} - A X_i - B U_i ; Y_i - C X_i - D U_i]`` estimate the process and
    measurement noise, the second block is the one-step prediction error.
    """
    ny = C.shape[0]
    Z_i, Z_n = _z_projections(st, i, rcond) if Z is None else Z
    Uf = st.rows(st.u_rows(i, 2 * i))
    Ufm = st.rows(st.u_rows(i + 1, 2 * i))
    h = _markov(A, B, C, D, i)
    Gam = _observability(A, C, i)
    X_i = Z_i.pinv_apply(Gam, _toeplitz(h), Uf)
    X_n = Z_n.pinv_apply(Gam[:-ny], _toeplitz(h[: i - 1]), Ufm)
    U_i = st.rows(st.u_rows(i, i + 1))
    Y_i = st.rows(st.y_rows(i, i + 1))
    rho_w = X_n - A @ X_i - B @ U_i
    rho_v = Y_i - C @ X_i - D @ U_i
    rho = np.concatenate([rho_w, rho_v])
    cov = rho @ rho.T  # F is normalised: this is the sample covariance
    return 0.5 * (cov + cov.T), rho_v


def _kalman_gain(
    A: np.ndarray, C: np.ndarray, cov: np.ndarray
) -> tuple[np.ndarray | None, np.ndarray | None, str]:
    """Steady-state predictor gain from ``[[Q, S], [S^T, R]]`` (scaled units)."""
    n = A.shape[0]
    ny = C.shape[0]
    ev, V = np.linalg.eigh(cov)
    cov = (V * np.maximum(ev, 0.0)) @ V.T  # remove rounding-level negative eigenvalues
    Q, S, R = cov[:n, :n], cov[:n, n:], cov[n:, n:]
    # Outputs are scaled to unit RMS: 1e-12 is far below any measurable noise and
    # only keeps R invertible for noise-free data.
    R = R + 1e-12 * np.eye(ny)
    P = _dare_doubling(A, C, Q, R, S)
    if P is None:  # not converged or not verified: the generalised-Schur solver decides
        try:
            P = sla.solve_discrete_are(A.T, C.T, Q, R, s=S)
        except (ValueError, np.linalg.LinAlgError) as exc:
            return None, None, f"the Kalman-filter Riccati equation has no solution ({exc})"
    Re = C @ P @ C.T + R
    # K = (A P C^T + S) Re^-1 by Cholesky (LAPACK posv: what scipy.linalg.solve with
    # assume_a="pos" computes, without its checks, a fixed cost of every fit).
    _, Kt, info = lapack.dposv(Re.T, (A @ P @ C.T + S).T)
    if info != 0:
        return None, None, "the innovation covariance is not positive definite"
    K = Kt.T
    rho = float(np.max(np.abs(np.linalg.eigvals(A - K @ C)))) if n else 0.0
    if not np.isfinite(rho) or rho >= 1.0:
        return None, None, f"the Kalman predictor is not stable (spectral radius {rho:.6g})"
    return K, Re, ""


def _dare_doubling(
    A: np.ndarray, C: np.ndarray, Q: np.ndarray, R: np.ndarray, S: np.ndarray
) -> np.ndarray | None:
    """Stabilising solution of the filter Riccati equation by structure-preserving doubling.

    ``P = A P A^T - (A P C^T + S)(C P C^T + R)^{-1}(A P C^T + S)^T + Q``, the
    equation ``scipy.linalg.solve_discrete_are(A.T, C.T, Q, R, s=S)`` solves.
    The cross term is removed (``Ab = A - S R^-1 C``, ``Qb = Q - S R^-1 S^T``) and
    the doubling iteration of W.-W. Lin & S.-F. Xu (SIAM J. Matrix Anal. Appl.
    28(1):26-39, 2006) run from ``A_0 = Ab^T``, ``G_0 = C^T R^-1 C``, ``H_0 = Qb``:

    ``W = I + G_k H_k``, ``A_{k+1} = A_k W^-1 A_k``,
    ``G_{k+1} = G_k + A_k W^-1 G_k A_k^T``, ``H_{k+1} = H_k + A_k^T H_k W^-1 A_k``;

    ``H_k`` converges quadratically to ``P``. A handful of n x n products instead of
    the generalised Schur form of a 2n pencil and its argument checks (0.12 ms
    against 0.35 ms at n = 4). When ``R`` is tiny (noise-free outputs) ``Qb`` loses
    digits to cancellation and the residual check declines. Returns ``None`` when
    it does not converge in 60 steps or the equation's residual is not at rounding
    level: the caller then uses scipy's solver.
    """
    n = A.shape[0]
    if n == 0:
        return None
    try:
        Rinv_C = np.linalg.solve(R, C)
        Rinv_St = np.linalg.solve(R, S.T)
        Ak = (A - S @ Rinv_C).T
        Gk = C.T @ Rinv_C
        Hk = Q - S @ Rinv_St
        eye = np.eye(n)
        for _ in range(60):
            # LAPACK gesv directly (numpy's solve costs twice as much on a 4 x 4).
            _, _, V, info = lapack.dgesv(eye + Gk @ Hk, np.concatenate([Ak, Gk], axis=1))
            if info != 0:  # W singular
                return None
            V1, V2 = V[:, :n], V[:, n:]  # W^-1 A_k, W^-1 G_k
            H_new = Hk + Ak.T @ Hk @ V1
            Gk = Gk + Ak @ V2 @ Ak.T
            Ak = Ak @ V1
            step = np.abs(H_new - Hk).max()
            Hk = H_new
            if step <= 1e-13 * np.abs(Hk).max():
                break
        else:
            return None
    except np.linalg.LinAlgError:
        return None
    P = 0.5 * (Hk + Hk.T)
    if not np.all(np.isfinite(P)):
        return None
    M = A @ P @ C.T + S
    APA, MRM = A @ P @ A.T, M @ np.linalg.solve(C @ P @ C.T + R, M.T)
    scale = sum(np.linalg.norm(T, 1) for T in (APA, MRM, Q, P))
    if not np.linalg.norm(APA - MRM + Q - P, 1) <= 1e-10 * scale:  # rounding level: accepted
        return None
    return P


def _predictor_residuals(
    model: StateSpace,
    K: np.ndarray,
    y: np.ndarray,
    u: np.ndarray,
    mean: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """One-step prediction errors of the steady-state Kalman predictor, x_hat(0) = 0.

    ``x_hat(t+1) = F x_hat(t) + M z(t)`` with ``F = A - K C``, ``M = [B - K D, K]``,
    ``z = [u; y]``, and ``e(t) = y(t) - C x_hat(t) - D u(t)``. Evaluated in blocks
    of ``b`` samples (superposition, as in :mod:`._recursion`): inside block ``k``

    ``e(kb + q) = sum_{p <= q} G_{q-p} z(kb + p) - C F^q s_k``,
    ``s_{k+1} = F^b s_k + sum_p F^{b-1-p} M z(kb + p)``,

    ``G_0 = [-D, I]``, ``G_r = -C F^{r-1} M``, ``s_k = x_hat(kb)``. Both sums over a
    block are one matrix product of the record viewed as ``(N/b) x (b m)`` (BLAS
    GEMM), and the block states ``s_k`` are the recursion of :mod:`._recursion` on
    ``N/b`` samples: 3-4x faster than that recursion over every sample, the same
    terms grouped differently (agreement to rounding). In chunks, memory flat.
    ``mean = (mean_u, mean_y)`` is subtracted chunk by chunk: the residuals of
    ``(y - mean_y, u - mean_u)`` without a centred copy of the record.
    """
    A, B, C, D = model.A, model.B, model.C, model.D
    n, ny, nu = A.shape[0], C.shape[0], B.shape[1]
    m = nu + ny
    b = _RESID_BLOCK
    F = A - K @ C
    M = np.concatenate([B - K @ D, K], axis=1)  # n x m
    Fp = np.empty((b + 1, n, n))  # F^0 .. F^b
    Fp[0] = np.eye(n)
    for q in range(b):
        Fp[q + 1] = F @ Fp[q]
    # Toeplitz of the block: row block p (input at p), column block q (output at q).
    G = np.zeros((b, m, b, ny))
    G0 = np.concatenate([-D, np.eye(ny)], axis=1).T  # m x ny
    Gr = -np.einsum("lj,rjk,km->rml", C, Fp[: b - 1], M)  # r = 1..b-1: -C F^{r-1} M
    for p in range(b):
        G[p, :, p] = G0
        G[p, :, p + 1 :] = Gr[: b - 1 - p].transpose(1, 0, 2)
    G = G.reshape(b * m, b * ny)
    E = np.einsum("pjk,km->pmj", Fp[b - 1 :: -1][:b], M).reshape(b * m, n)  # F^{b-1-p} M
    Phi = -np.einsum("lj,qjk->kql", C, Fp[:b]).reshape(n, b * ny)  # -C F^q
    # The rows of E and G that multiply u and y: the record viewed as (N/b) x (b nu) and
    # (N/b) x (b ny) blocks without interleaving z = [u, y] (a strided copy that cost
    # as much as the products).
    Eu, Ey = _split_rows(E, b, nu, ny)
    Gu, Gy = _split_rows(G, b, nu, ny)
    y = np.ascontiguousarray(y)
    u = np.ascontiguousarray(u)
    mu, my = (np.zeros(nu), np.zeros(ny)) if mean is None else mean
    N = y.shape[0]
    n_full = N - N % b  # samples in whole blocks; _CHUNK is a multiple of b
    e = np.empty_like(y)
    x = np.zeros(n)
    for t0 in range(0, n_full, _CHUNK):
        t1 = min(n_full, t0 + _CHUNK)
        Ub, Yb = u[t0:t1], y[t0:t1]
        if mean is not None:  # a chunk-sized copy, not one of the record
            Ub, Yb = Ub - mu, Yb - my
        Ub, Yb = Ub.reshape(-1, b * nu), Yb.reshape(-1, b * ny)
        S, x = linear_recursion(Fp[b], Ub @ Eu + Yb @ Ey, x)  # block states s_k, and x(t1)
        eb = e[t0:t1].reshape(-1, b * ny)  # a view: the sums land in e, no temporaries
        np.matmul(Ub, Gu, out=eb)
        eb += Yb @ Gy
        eb += S @ Phi
    if n_full < N:  # the last, partial block: zero-padded inputs, its start state x
        Z = np.zeros((b, m))
        Z[: N - n_full, :nu] = u[n_full:] - mu
        Z[: N - n_full, nu:] = y[n_full:] - my
        e[n_full:] = (Z.reshape(1, b * m) @ G + x @ Phi).reshape(b, ny)[: N - n_full]
    return e


def _split_rows(X: np.ndarray, b: int, nu: int, ny: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows of ``X`` (b m x c, time-major rows of ``z = [u, y]``) for ``u`` and for ``y``."""
    X3 = X.reshape(b, nu + ny, X.shape[1])
    return X3[:, :nu].reshape(b * nu, -1), X3[:, nu:].reshape(b * ny, -1)


def _bd_regression(
    A: np.ndarray, C: np.ndarray, y: np.ndarray, u: np.ndarray, feedthrough: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """B, D and x0 by least squares on the simulated response (linear in B, D, x0).

    ``y(t) = C A^t x0 + sum_{s<t} C A^{t-1-s} B u(s) + D u(t) + e(t)``. The
    regressors are simulated chunk by chunk and the problem is reduced by a
    running QR of ``[Phi | y]``, so memory stays linear in the chunk.
    """
    N, ny = y.shape
    nu = u.shape[1]
    n = A.shape[0]
    rho = float(np.max(np.abs(np.linalg.eigvals(A)))) if n else 0.0
    if rho > 1.0 and N * math.log(rho) > math.log(_MAX_GROWTH):
        raise IdentificationError(
            f"bd_method='regression' simulates the model over the record, but A has spectral "
            f"radius {rho:.6g} and grows by more than {_MAX_GROWTH:.0e} over {N} samples; "
            "use bd_method='subspace' (the default), which needs no simulation"
        )
    nxc = n + n * nu  # state columns: x0 basis, then B entries (q-major)
    nd = ny * nu if feedthrough else 0
    npar = nxc + nd
    R = np.empty((0, npar + 1))
    state = np.zeros((n, nxc))
    state[:, :n] = np.eye(n)
    chunk = max(4096, 65536 // max(1, nxc))
    for t0 in range(0, N, chunk):
        t1 = min(N, t0 + chunk)
        T = t1 - t0
        W = np.zeros((T, n, nxc))
        for q in range(nu):
            for p in range(n):
                W[:, p, n + q * n + p] = u[t0:t1, q]
        X, state = linear_recursion(A, W, state)
        Phi = np.zeros((T, ny, npar + 1))
        Phi[:, :, :nxc] = np.einsum("lp,tpc->tlc", C, X)
        if feedthrough:
            for q in range(nu):
                for l in range(ny):
                    Phi[:, l, nxc + q * ny + l] = u[t0:t1, q]
        Phi[:, :, npar] = y[t0:t1]
        R = np.linalg.qr(np.concatenate([R, Phi.reshape(T * ny, npar + 1)]), mode="r")
    theta = sla.lstsq(R[:npar, :npar], R[:npar, npar], check_finite=False)[0]
    x0 = theta[:n]
    B = theta[n:nxc].reshape(nu, n).T
    D = theta[nxc:].reshape(nu, ny).T if feedthrough else np.zeros((ny, nu))
    return B, D, x0


# ------------------------------------------------------------------- options
def _check_choice(value: Any, name: str, choices: tuple[str, ...]) -> str:
    if value not in choices:
        raise DataError(f"`{name}` must be one of {', '.join(map(repr, choices))}; got {value!r}")
    return str(value)


def _check_int(value: Any, name: str, low: int, allow_none: bool = True) -> int | None:
    if value is None and allow_none:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise DataError(
            f"`{name}` must be an integer >= {low}{' or None' if allow_none else ''}; "
            f"got {value!r}"
        )
    return int(value)


def _check_bool(value: Any, name: str) -> bool:
    if not isinstance(value, (bool, np.bool_)):
        raise DataError(f"`{name}` must be True or False; got {value!r}")
    return bool(value)


def _check_rank_tol(value: Any) -> float | None:
    if value is None:
        return None
    v = check_positive(value, "rank_tol")
    if v >= 1.0:
        raise DataError(
            f"`rank_tol` is relative to the largest singular value: 0 < rank_tol < 1; "
            f"got {value!r}"
        )
    return v


@dataclass(frozen=True)
class _Options:
    algorithm: str
    order: int | None
    horizon: int | None
    max_horizon: int
    dt: float
    feedthrough: bool
    weighting: str
    variant: str | None
    rank_tol: float | None
    factorization: str
    bd_method: str
    noise_model: bool = True


def _options(algorithm: str, **kw: Any) -> _Options:
    if algorithm == "moesp":
        weighting = _check_choice(kw["weighting"], "weighting", _MOESP_WEIGHTINGS)
        variant = None
    else:
        weighting = _check_choice(kw["weighting"], "weighting", _N4SID_WEIGHTINGS)
        variant = _check_choice(kw["variant"], "variant", _N4SID_VARIANTS)
    max_h = _check_int(kw["max_horizon"], "max_horizon", 2)
    return _Options(
        algorithm=algorithm,
        order=_check_int(kw["order"], "order", 1),
        horizon=_check_int(kw["horizon"], "horizon", 2),
        max_horizon=DEFAULT_MAX_HORIZON if max_h is None else max_h,
        dt=check_positive(kw["dt"], "dt"),
        feedthrough=bool(kw["feedthrough"]),
        weighting=weighting,
        variant=variant,
        rank_tol=_check_rank_tol(kw["rank_tol"]),
        factorization=_check_choice(kw["factorization"], "factorization", _FACTORIZATIONS),
        bd_method=_check_choice(kw["bd_method"], "bd_method", _BD_METHODS),
        noise_model=_check_bool(kw.get("noise_model", True), "noise_model"),
    )


# ---------------------------------------------------------------- the driver
def _fit(
    acc: _LagGram | _HankelQR,
    nu: int,
    ny: int,
    opt: _Options,
    i_rows: int,
    data: tuple[np.ndarray, np.ndarray] | None,
    stacklevel: int = 4,
) -> IdentificationResult:
    """Everything after the pass over the data (shared by both entry points)."""
    notes: list[str] = []
    extras: dict[str, Any] = {}
    st = _stats_from(acc, nu, ny, i_rows)
    rank_tol = _DEFAULT_RANK_TOL[st.factorization] if opt.rank_tol is None else opt.rank_tol
    rcond = _PROJ_RCOND[st.factorization]
    i, horizon_rule = _choose_horizon(st, opt, i_rows, extras, notes)
    st = replace(st, F=st.F[: 2 * i * st.m])  # the rows of window 2i
    core = _subspace_step(st, i, opt, rank_tol, rcond)
    _check_order(core, st, rank_tol, notes, stacklevel + 1)
    model, BD_scaled = _system(st, i, core, opt, rcond, data, extras)
    fit: dict[str, float] = {}
    residuals = None
    if opt.noise_model:
        residuals = _noise_model(st, i, model, core, BD_scaled, data, fit, extras, notes, rcond)
    else:
        notes.append(
            "noise model not computed (noise_model=False): no noise covariances, Kalman "
            "gain, residuals or fit percentages"
        )
    poles = np.linalg.eigvals(model.A)  # once: stability and the characteristic polynomial
    if not np.all(np.abs(poles) < 1.0):
        notes.append(
            "the model is unstable (poles outside the unit circle); it is reported as found"
        )
    continuous = None
    try:
        continuous = undiscretize(model)
    except ModelError as exc:
        notes.append(f"no continuous-time model: {exc}")
    extras.update(
        horizon=i,
        order=core.n,
        order_gap_ratio=core.gap,
        factor_rank=st.rank,
        hankel_rows=st.j,
        channel_scale=st.scale,
    )
    logger.debug("%s: order %d, horizon %d, j=%d", opt.algorithm, core.n, i, st.j)
    return IdentificationResult(
        method=opt.algorithm,
        model=model,
        parameters={f"a{k + 1}": float(v) for k, v in enumerate(_char_poly(poles))},
        covariance=None,
        n_samples=st.n_samples,
        options=_used_options(opt, st, i, core, horizon_rule, rank_tol, i_rows),
        residuals=residuals,
        fit=fit,
        singular_values=core.s,
        notes=tuple(notes),
        continuous_model=continuous,
        extras=extras,
    )


def _choose_horizon(
    st: _Stats, opt: _Options, i_rows: int, extras: dict[str, Any], notes: list[str]
) -> tuple[int, str]:
    """Horizon ``i`` (given, or ARX order + 1 by AIC) and its rule; checks it against the order."""
    ny = st.ny
    i_min = _min_horizon(opt.order, ny)
    if opt.horizon is not None:
        i = opt.horizon
        horizon_rule = "given"
    else:
        p_hat, aic = _arx_horizon(st, i_rows - 1, opt.feedthrough)
        i = min(i_rows, max(p_hat + 1, i_min))
        extras["arx_order"] = p_hat
        extras["arx_aic"] = aic
        horizon_rule = "auto"
        notes.append(
            f"horizon {i} chosen automatically: ARX order {p_hat} by AIC over 1..{i_rows - 1} "
            f"(horizon = ARX order + 1, at least {i_min}, at most {i_rows})"
        )
        if p_hat >= i_rows - 1:
            notes.append(
                f"the ARX order hit its upper limit {i_rows - 1}: the data may need a longer "
                "horizon than the record allows; pass horizon= or a longer record"
            )
    if i < i_min:
        raise DataError(
            f"`horizon`={i} is too short for order={opt.order} with {ny} output(s): "
            f"need (horizon - 1) * ny >= order, i.e. horizon >= {i_min}"
        )
    if opt.order is not None and opt.order > (i - 1) * ny:
        raise DataError(
            f"`order`={opt.order} exceeds (horizon - 1) * ny = {(i - 1) * ny}; "
            f"increase `horizon` to at least {i_min}"
        )
    return i, horizon_rule


def _subspace_step(st: _Stats, i: int, opt: _Options, rank_tol: float, rcond: float) -> _Core:
    """A, C (and B, D for simple N4SID), the order and its singular values."""
    if opt.algorithm == "moesp":
        return _moesp_core(st, i, opt.weighting, opt.order, rank_tol, rcond, opt.noise_model)
    return _n4sid_core(
        st,
        i,
        opt.weighting,
        opt.variant or "robust",
        opt.order,
        rank_tol,
        rcond,
        opt.feedthrough,
    )


def _check_order(
    core: _Core, st: _Stats, rank_tol: float, notes: list[str], stacklevel: int
) -> None:
    """Notes on an automatic order; a warning when the factorisation cannot resolve it."""
    n = core.n
    if core.order_auto:
        notes.append(
            f"order {n} chosen automatically: largest gap of the singular values "
            f"(s_{n}/s_{n + 1} = {core.gap:.3g}, values below {rank_tol:.1e} x s_1 floored)"
        )
        if core.gap < 10.0:
            notes.append(
                f"order choice is marginal (gap ratio {core.gap:.3g} < 10); inspect "
                "`singular_values` and pass `order=` explicitly"
            )
    ratio = float(core.s[n - 1] / core.s[0])
    if ratio < _ILL_RATIO[st.factorization]:
        msg = (
            f"s_{n}/s_1 = {ratio:.2e} is below {_ILL_RATIO[st.factorization]:.0e}: the "
            f"{st.factorization!r} factorisation does not resolve the weakest direction "
            "reliably (data spanning many decades, e.g. an unstable open-loop record, or a "
            "barely excited mode)"
            + ("; use factorization='qr'" if st.factorization == "gram" else "")
        )
        warnings.warn(msg, IllConditionedWarning, stacklevel=stacklevel)
        notes.append(msg)


def _system(
    st: _Stats,
    i: int,
    core: _Core,
    opt: _Options,
    rcond: float,
    data: tuple[np.ndarray, np.ndarray] | None,
    extras: dict[str, Any],
) -> tuple[StateSpace, tuple[np.ndarray, np.ndarray]]:
    """B, D, and the model in physical units; also ``(B, D)`` in scaled units."""
    nu = st.nu
    A, Cs = core.A, core.C
    if core.B is not None and core.D is not None:
        Bs, Ds = core.B, core.D
    elif opt.algorithm == "moesp":
        Bs, Ds = _bd_moesp(st, i, A, Cs, opt.feedthrough, rcond)
    else:
        Bs, Ds = _bd_robust(core.K_hat, A, Cs, i, nu, opt.feedthrough)
    # Back to physical units: z_s = z / scale.
    s_u, s_y = st.scale[:nu], st.scale[nu:]
    C = Cs * s_y[:, None]
    B = Bs / s_u[None, :]
    D = (Ds * s_y[:, None]) / s_u[None, :]
    if opt.bd_method == "regression":
        if data is None:
            raise DataError(
                "bd_method='regression' needs the signals in memory; the streaming "
                "accumulator supports bd_method='subspace' only"
            )
        B, D, x0 = _bd_regression(A, C, data[0], data[1], opt.feedthrough)
        extras["x0"] = x0
        Bs, Ds = B * s_u[None, :], (D / s_y[:, None]) * s_u[None, :]
    return StateSpace(A, B, C, D, opt.dt), (Bs, Ds)


def _used_options(
    opt: _Options,
    st: _Stats,
    i: int,
    core: _Core,
    horizon_rule: str,
    rank_tol: float,
    i_rows: int,
) -> dict[str, Any]:
    """Every option of the fit as used (``IdentificationResult.options``)."""
    options = {
        "order": core.n,
        "order_rule": "auto" if core.order_auto else "given",
        "horizon": i,
        "horizon_rule": horizon_rule,
        "max_horizon": i_rows if horizon_rule == "auto" else opt.max_horizon,
        "dt": opt.dt,
        "feedthrough": opt.feedthrough,
        "weighting": opt.weighting,
        "rank_tol": rank_tol,
        "factorization": st.factorization,
        "bd_method": opt.bd_method,
        "noise_model": opt.noise_model,
        "scale_channels": True,
    }
    if opt.variant is not None:
        options["variant"] = opt.variant
    return options


def _noise_model(
    st: _Stats,
    i: int,
    model: StateSpace,
    core: _Core,
    BD_scaled: tuple[np.ndarray, np.ndarray],
    data: tuple[np.ndarray, np.ndarray] | None,
    fit: dict[str, float],
    extras: dict[str, Any],
    notes: list[str],
    rcond: float,
) -> np.ndarray | None:
    """Noise covariances, Kalman gain and one-step residuals (into ``fit``, ``extras``, ``notes``).

    Returns the residuals over the record (``None`` without the record or without a
    stable steady-state predictor).
    """
    A, Cs, n = model.A, core.C, core.n
    Bs, Ds = BD_scaled
    nu, ny = st.nu, st.ny
    s_y = st.scale[nu:]
    cov, rho_v = _innovation_stats(st, i, A, Bs, Cs, Ds, rcond, core.Z)
    y_rows = st.y_rows(i, i + 1)
    y2 = np.einsum("ij,ij->i", st.F[y_rows], st.F[y_rows])  # second moment, scaled
    var_y = np.maximum(y2 - st.mean[nu:] ** 2 / s_y**2, 0.0)
    mse = np.einsum("ij,ij->i", rho_v, rho_v)
    with np.errstate(divide="ignore", invalid="ignore"):
        hfit = 100.0 * (1.0 - np.sqrt(mse / var_y))
    fit["horizon_predictor_fit_percent"] = float(np.mean(hfit))
    K_s, Re_s, why = _kalman_gain(A, Cs, cov)
    sy_m = np.diag(s_y)
    extras["noise_covariance"] = {
        "Q": cov[:n, :n],
        "S": cov[:n, n:] @ sy_m,
        "R": sy_m @ cov[n:, n:] @ sy_m,
    }
    residuals = None
    if K_s is None:
        notes.append(f"no steady-state Kalman predictor: {why}; one-step fit not computed")
    else:
        assert Re_s is not None
        K = K_s / s_y[None, :]
        extras["kalman_gain"] = K
        extras["innovation_covariance"] = sy_m @ Re_s @ sy_m
        if data is not None:
            y, u = data
            residuals = _predictor_residuals(model, K, y, u)
            num = np.sqrt(np.einsum("ij,ij->j", residuals, residuals))
            den = np.sqrt(_output_sumsq(st, y))
            with np.errstate(divide="ignore", invalid="ignore"):
                f = 100.0 * (1.0 - num / den)
            fit["one_step_fit_percent"] = float(np.mean(f))
            if ny > 1:
                for c in range(ny):
                    fit[f"one_step_fit_percent_y{c + 1}"] = float(f[c])
    return residuals


def _output_sumsq(st: _Stats, y: np.ndarray) -> np.ndarray:
    """``sum_t (y(t) - mean)^2`` per output: from the data stage's moments when exact enough.

    ``N (rms^2 - mean^2)`` loses ``log10(rms^2 / var)`` digits to cancellation; while that
    is under 6 (relative error ~1e-10, far below what a fit percentage shows) no pass over
    the record is needed, else the centred pass runs.
    """
    N, nu = st.n_samples, st.nu
    ms, mean = st.scale[nu:] ** 2, st.mean[nu:]
    var = ms - mean**2
    if np.all(var > 1e-6 * ms):
        return N * var
    return _centred_sumsq(y)


def _centred_sumsq(y: np.ndarray) -> np.ndarray:
    """``sum_t (y(t) - mean)^2`` per channel, chunk by chunk (no record-sized temporary)."""
    N, ny = y.shape
    mean = np.einsum("ij->j", y) / N  # (einsum: axis-0 reductions of (N, 3) are slow)
    tiled = np.tile(mean, min(N, _CHUNK))  # the subtraction on the flat chunk, contiguous
    out = np.zeros(ny)
    for t0 in range(0, N, _CHUNK):
        chunk = y[t0 : t0 + _CHUNK]
        yc = (chunk.reshape(-1) - tiled[: chunk.size]).reshape(-1, ny)
        out += np.einsum("ij,ij->j", yc, yc)
    return out


def _plan_in_memory(N: int, m: int, ny: int, opt: _Options) -> int:
    """Window half-length ``i_rows`` of the Hankel rows for an in-memory fit."""
    i_min = _min_horizon(opt.order, ny)
    if opt.horizon is not None:
        _check_rows(N, opt.horizon, m, f"horizon={opt.horizon}")
        return opt.horizon
    i_rows = _auto_max_horizon(N, m, opt.max_horizon)
    if i_rows < i_min:
        _check_rows(N, i_min, m, f"the shortest usable horizon ({i_min})")
        i_rows = i_min
    return i_rows


def _fit_in_memory(algorithm: str, y: Any, u: Any, kw: dict[str, Any]) -> IdentificationResult:
    opt = _options(algorithm, **kw)
    y = as_signal(y, "y", min_samples=2, copy=False)  # read only; no reference is kept
    N = y.shape[0]
    u = as_signal(u, "u", n_samples=N, copy=False)
    ny, nu = y.shape[1], u.shape[1]
    m = nu + ny
    i_rows = _plan_in_memory(N, m, ny, opt)
    acc: _LagGram | _HankelQR
    if opt.factorization == "gram":
        acc = _LagGram(m, 2 * i_rows - 1)
    else:
        acc = _HankelQR(m, 2 * i_rows)
    _feed(acc, u, y)  # the same accumulator a stream would use
    return _fit(acc, nu, ny, opt, i_rows, (y, u))


def _feed(acc: _LagGram | _HankelQR, u: np.ndarray, y: np.ndarray) -> None:
    """Pass ``z = [u, y]`` to ``acc`` in chunks, through one reused buffer.

    The accumulators keep no view of a chunk (they copy what they keep), so one
    cache-sized buffer serves every chunk: no allocation per chunk.
    """
    if isinstance(acc, _LagGram):
        acc.update_split(u, y)  # no interleaved copy of the record
        return
    N, nu = u.shape
    buf = np.empty((min(N, _CHUNK), nu + y.shape[1]))
    for t0 in range(0, N, _CHUNK):
        t1 = min(N, t0 + _CHUNK)
        z = buf[: t1 - t0]
        z[:, :nu] = u[t0:t1]
        z[:, nu:] = y[t0:t1]
        acc.update(z)


# ------------------------------------------------------------- public API
def fit_moesp(
    y: Any,
    u: Any,
    *,
    order: int | None = None,
    horizon: int | None = None,
    dt: float = 1.0,
    feedthrough: bool = False,
    weighting: str = "po",
    rank_tol: float | None = None,
    factorization: str = "gram",
    bd_method: str = "subspace",
    max_horizon: int | None = None,
    noise_model: bool = True,
    rng: np.random.Generator | None = None,
) -> IdentificationResult:
    """MIMO state-space model by MOESP (PO-MOESP by default).

    Implements ordinary MOESP (Verhaegen & Dewilde 1992), PI-MOESP and
    PO-MOESP (Verhaegen 1994) on the LQ factor of the block-Hankel data
    ``[U_f; W_p; Y_f]``: ``Gamma_i`` is the column space of ``L32`` (of ``L22``
    for ordinary MOESP), ``A`` and ``C`` follow from its shift invariance, and
    ``B``, ``D`` from the linear equations ``Gamma_perp^T L31 L11^{-1} =
    Gamma_perp^T H_i(B, D)``, solved by least squares (``lstsq``).

    Parameters
    ----------
    y : array_like, shape (N, ny)
        Outputs, time first (1-D = one channel).
    u : array_like, shape (N, nu)
        Inputs, same N. For closed-loop data this is the plant input.
    order : int, optional
        Model order; chosen automatically when omitted (largest gap of the
        singular values, see Notes).
    horizon : int, optional
        Block rows ``i`` of the past and of the future (the Hankel window is
        ``2i`` samples). Default: chosen from the data (see Notes).
    dt : float
        Sample time of the model in seconds.
    feedthrough : bool
        Estimate ``D``; when False (default, strictly proper plants such as
        sampled AMBs) ``D = 0``.
    weighting : {"po", "pi", "ordinary"}
        Instruments: past inputs and outputs (PO-MOESP, for noisy data; default),
        past inputs only (PI-MOESP, output-error noise), none (ordinary MOESP:
        noise-free data or white measurement noise).
    rank_tol : float, optional
        Singular values below ``rank_tol * s_1`` count as zero in the order choice.
        Default 1e-6 (``factorization="gram"``) or 1e-10 (``"qr"``).
    factorization : {"gram", "qr"}
        ``"gram"``: structured Gram matrix + pivoted Cholesky (fast; the default).
        ``"qr"``: tall-skinny Householder QR (about ``sqrt(eps)`` more accurate on
        noise-free data, several times slower). See ``docs/subspace.md``.
    bd_method : {"subspace", "regression"}
        ``"subspace"`` (default): B, D from the factor, no simulation (works for
        unstable models and in the streaming accumulator). ``"regression"``: least
        squares on the simulated response in ``(x0, B, D)``; refuses a model that
        grows by more than 1e12 over the record.
    max_horizon : int, optional
        Upper limit of the automatic horizon (default 40).
    noise_model : bool
        Compute the noise model (noise covariances, steady-state Kalman gain,
        one-step residuals and fit percentages; default). ``False`` returns the
        deterministic model ``A, B, C, D`` alone, as SLICOT's IB01AD/BD do: for
        batch fits where only the model matters (the noise model is much of the
        fixed cost on short records and ~30 % of the time on long ones).
    rng : numpy.random.Generator, optional
        Unused: the method is deterministic. Accepted for a uniform ``fit_*`` API.

    Returns
    -------
    IdentificationResult
        ``model`` (discrete, ``dt``); ``parameters`` a1..an of ``det(zI - A) =
        z^n + a1 z^{n-1} + ... + an`` (basis invariant; ``covariance`` is None);
        ``singular_values`` those of ``L32`` used for the order; ``residuals`` the
        steady-state Kalman one-step prediction errors; ``fit`` their fit
        percentage, never an open-loop simulation fit; ``extras`` noise
        covariances, Kalman gain, horizon and order details.

    Raises
    ------
    DataError
        NaN/inf, wrong shapes, too few samples for the horizon, an identically
        zero channel, or an invalid option.
    IdentificationError
        No information in the data (all singular values zero), or
        ``bd_method="regression"`` on a model that grows too fast.

    Notes
    -----
    Automatic horizon: one pass collects the lagged products up to lag
    ``2 i_max - 1`` with ``i_max = min(max_horizon, (N+1) // (2 + 10 m))`` (at
    least 5 Hankel rows per column). ARX models of orders ``p = 1..i_max - 1``
    are fitted from the same factor, the order ``p*`` minimising AIC is taken as
    the memory the one-step predictor needs, and ``i = max(p* + 1, i_min)`` with
    ``(i_min - 1) ny >= order``. The Hankel rows are then ``0..N - 2 i_max`` for
    either factorisation, so the result does not depend on it beyond rounding.

    Automatic order: singular values are scaled by ``s_1`` and floored at
    ``rank_tol``; the order is the index of the largest ratio ``s_n / s_{n+1}``
    for ``n <= (i - 1) ny``. A ratio below 10 is reported in ``notes``.

    Channels are scaled to unit RMS before the SVD (the model is returned in
    physical units), so the order choice does not depend on units. Means are
    not removed: detrend the data first when its operating point is not zero.

    In closed loop the future inputs are correlated with past noise, which biases
    every open-loop subspace method; the bias shrinks with the signal-to-noise
    ratio and is smaller with a long horizon (``docs/subspace.md``).

    References
    ----------
    M. Verhaegen and P. Dewilde, "Subspace model identification Part 1. The
    output-error state-space model identification class of algorithms," Int. J.
    Control 56(5):1187-1210, 1992. M. Verhaegen, "Identification of the
    deterministic part of MIMO state space models given in innovations form from
    input-output data," Automatica 30(1):61-74, 1994.

    Examples
    --------
    >>> import numpy as np
    >>> from maglevid.lti import StateSpace
    >>> sys = StateSpace([[0.9, 0.2], [-0.2, 0.9]], [[1.0], [0.0]], [[1.0, 0.0]], dt=1.0)
    >>> u = np.random.default_rng(0).standard_normal((2000, 1))
    >>> y, _ = sys.simulate(u)
    >>> res = fit_moesp(y, u, order=2, horizon=5)
    >>> np.allclose(np.sort_complex(res.model.poles()), np.sort_complex(sys.poles()))
    True
    """
    del rng
    return _fit_in_memory(
        "moesp",
        y,
        u,
        dict(
            order=order,
            horizon=horizon,
            dt=dt,
            feedthrough=feedthrough,
            weighting=weighting,
            variant=None,
            rank_tol=rank_tol,
            factorization=factorization,
            bd_method=bd_method,
            max_horizon=max_horizon,
            noise_model=noise_model,
        ),
    )


def fit_n4sid(
    y: Any,
    u: Any,
    *,
    order: int | None = None,
    horizon: int | None = None,
    dt: float = 1.0,
    feedthrough: bool = False,
    weighting: str = "n4sid",
    variant: str = "robust",
    rank_tol: float | None = None,
    factorization: str = "gram",
    bd_method: str = "subspace",
    max_horizon: int | None = None,
    noise_model: bool = True,
    rng: np.random.Generator | None = None,
) -> IdentificationResult:
    """MIMO state-space model by N4SID (oblique projection).

    Implements Van Overschee & De Moor (1994): the oblique projection ``O_i =
    Y_f /_{U_f} W_p`` (Theorem 2), the SVD of ``W1 O_i W2`` with the weights of
    the unifying theorem (1996, Ch. 4), and either the robust combined
    algorithm (``A``, ``C`` from ``[Gamma_{i-1}^+ Z_{i+1}; Y_i] = [A; C]
    Gamma_i^+ Z_i + K U_f``, then ``B``, ``D`` from ``K`` by least squares) or
    the simple one (``[X_{i+1}; Y_i] = [A B; C D][X_i; U_i]``).

    Parameters
    ----------
    y, u, order, horizon, dt, feedthrough, rank_tol, factorization, bd_method, max_horizon
        As in :func:`fit_moesp`.
    noise_model, rng
        As in :func:`fit_moesp`.
    weighting : {"n4sid", "moesp", "cva"}
        ``W1 = I, W2 = I`` (N4SID, default); ``W1 = I, W2 = Pi_{U_f}^perp``
        (MOESP); ``W1 = (Y_f Pi_perp Y_f^T)^{-1/2}, W2 = Pi_perp`` (CVA, needs
        noisy data).
    variant : {"robust", "simple"}
        The robust combined algorithm (default) or the state-sequence one.

    Returns
    -------
    IdentificationResult
        As :func:`fit_moesp`; ``singular_values`` are those of ``W1 O_i W2``.

    Raises
    ------
    DataError, IdentificationError
        As :func:`fit_moesp`; also ``weighting="cva"`` on noise-free data.

    Notes
    -----
    See :func:`fit_moesp` for the horizon and order rules and the closed-loop
    caveat.

    References
    ----------
    P. Van Overschee and B. De Moor, "N4SID: Subspace algorithms for the
    identification of combined deterministic-stochastic systems," Automatica
    30(1):75-93, 1994. P. Van Overschee and B. De Moor, Subspace Identification
    for Linear Systems, Kluwer, 1996, Ch. 4.

    Examples
    --------
    >>> import numpy as np
    >>> from maglevid.lti import StateSpace
    >>> sys = StateSpace([[0.9, 0.2], [-0.2, 0.9]], [[1.0], [0.0]], [[1.0, 0.0]], dt=1.0)
    >>> u = np.random.default_rng(0).standard_normal((2000, 1))
    >>> y, _ = sys.simulate(u)
    >>> res = fit_n4sid(y, u, order=2, horizon=5)
    >>> np.allclose(res.model.markov(6), sys.markov(6))
    True
    """
    del rng
    return _fit_in_memory(
        "n4sid",
        y,
        u,
        dict(
            order=order,
            horizon=horizon,
            dt=dt,
            feedthrough=feedthrough,
            weighting=weighting,
            variant=variant,
            rank_tol=rank_tol,
            factorization=factorization,
            bd_method=bd_method,
            max_horizon=max_horizon,
            noise_model=noise_model,
        ),
    )


class SubspaceAccumulator:
    """Block-Hankel statistics fed chunk by chunk; fit MOESP or N4SID at the end.

    The memory held is independent of the record length: ``2 i_max`` lagged
    ``m x m`` products and ``2 i_max`` head and tail samples (``"gram"``), or one
    ``2 i m`` square triangular factor (``"qr"``). A chunk boundary changes
    nothing but the order of summation, so :meth:`fit` equals :func:`fit_moesp`
    / :func:`fit_n4sid` on the whole record to rounding, except that it has no
    time-series ``residuals`` (the record is gone) and no ``bd_method=
    "regression"``.

    Parameters
    ----------
    ny, nu : int
        Output and input channels.
    horizon : int, optional
        Fixed horizon. When omitted it is chosen at :meth:`fit` time by the
        rule of :func:`fit_moesp`, from candidates up to ``max_horizon``.
    max_horizon : int
        Largest horizon :meth:`fit` may choose (default 40). For
        ``factorization="gram"`` it is reduced at fit time to what the record
        supports, exactly as the in-memory functions do; ``"qr"`` fixes the
        window to ``2 * max_horizon`` at construction.
    factorization : {"gram", "qr"}
        See :func:`fit_moesp`.

    Examples
    --------
    >>> import numpy as np
    >>> from maglevid.lti import StateSpace
    >>> sys = StateSpace([[0.9, 0.2], [-0.2, 0.9]], [[1.0], [0.0]], [[1.0, 0.0]], dt=1.0)
    >>> u = np.random.default_rng(0).standard_normal((3000, 1))
    >>> y, _ = sys.simulate(u)
    >>> acc = SubspaceAccumulator(ny=1, nu=1, horizon=5)
    >>> for k in range(0, 3000, 700):
    ...     _ = acc.update(y[k:k + 700], u[k:k + 700])
    >>> res = acc.fit(algorithm="moesp", order=2)
    >>> np.allclose(res.model.markov(6), sys.markov(6))
    True
    """

    def __init__(
        self,
        ny: int,
        nu: int,
        *,
        horizon: int | None = None,
        max_horizon: int = DEFAULT_MAX_HORIZON,
        factorization: str = "gram",
    ) -> None:
        self.ny = _check_int(ny, "ny", 1, allow_none=False)
        self.nu = _check_int(nu, "nu", 1, allow_none=False)
        self.horizon = _check_int(horizon, "horizon", 2)
        self.max_horizon = _check_int(max_horizon, "max_horizon", 2, allow_none=False)
        self.factorization = _check_choice(factorization, "factorization", _FACTORIZATIONS)
        i_top = self.horizon if self.horizon is not None else self.max_horizon
        assert i_top is not None and self.ny is not None and self.nu is not None
        m = self.ny + self.nu
        self._acc: _LagGram | _HankelQR
        if self.factorization == "gram":
            self._acc = _LagGram(m, 2 * i_top - 1)
        else:
            self._acc = _HankelQR(m, 2 * i_top)

    @property
    def n_samples(self) -> int:
        """Samples seen so far."""
        return self._acc.n

    def update(self, y: Any, u: Any) -> SubspaceAccumulator:
        """Add the next chunk: ``y`` (c, ny) and ``u`` (c, nu), time first. Returns self."""
        y = as_signal(y, "y", n_channels=self.ny, copy=False)  # copied into z below
        u = as_signal(u, "u", n_samples=y.shape[0], n_channels=self.nu, copy=False)
        if isinstance(self._acc, _LagGram):
            self._acc.update_split(u, y)
        else:
            self._acc.update(np.concatenate([u, y], axis=1))
        return self

    def fit(
        self,
        *,
        algorithm: str = "moesp",
        order: int | None = None,
        dt: float = 1.0,
        feedthrough: bool = False,
        weighting: str | None = None,
        variant: str = "robust",
        rank_tol: float | None = None,
        noise_model: bool = True,
    ) -> IdentificationResult:
        """Identify from the data seen so far.

        Parameters
        ----------
        algorithm : {"moesp", "n4sid"}
        order, dt, feedthrough, rank_tol, noise_model
            As in :func:`fit_moesp`.
        weighting : str, optional
            Default ``"po"`` for MOESP, ``"n4sid"`` for N4SID.
        variant : {"robust", "simple"}
            N4SID only.
        """
        algorithm = _check_choice(algorithm, "algorithm", ("moesp", "n4sid"))
        if weighting is None:
            weighting = "po" if algorithm == "moesp" else "n4sid"
        opt = _options(
            algorithm,
            order=order,
            horizon=self.horizon,
            dt=dt,
            feedthrough=feedthrough,
            weighting=weighting,
            variant=variant,
            rank_tol=rank_tol,
            factorization=self.factorization,
            bd_method="subspace",
            max_horizon=self.max_horizon,
            noise_model=noise_model,
        )
        assert self.ny is not None and self.nu is not None
        m = self.ny + self.nu
        N = self.n_samples
        if self.horizon is not None:
            _check_rows(N, self.horizon, m, f"horizon={self.horizon}")
            i_rows = self.horizon
        elif self.factorization == "gram":
            i_rows = _plan_in_memory(N, m, self.ny, opt)
            if i_rows > self.max_horizon:
                raise DataError(
                    f"order={order} needs horizon >= {i_rows}, above this accumulator's "
                    f"max_horizon={self.max_horizon}"
                )
        else:
            assert self.max_horizon is not None
            _check_rows(N, self.max_horizon, m, f"max_horizon={self.max_horizon}")
            i_rows = self.max_horizon
        if isinstance(self._acc, _LagGram) and N < self._acc.min_samples():
            raise DataError(f"{N} samples are too few for the lags kept ({self._acc.L})")
        return _fit(self._acc, self.nu, self.ny, opt, i_rows, None, stacklevel=3)


# --------------------------------------------------------------- registry
def centred_result(
    res: IdentificationResult, y_mean: np.ndarray, u_mean: np.ndarray
) -> IdentificationResult:
    """``res`` of a fit on deviations from the means, with the means recorded in ``extras``."""
    extras = dict(res.extras)
    extras["operating_point_means"] = {"y": np.asarray(y_mean), "u": np.asarray(u_mean)}
    note = "identified on deviations from the recording's means (its operating point)"
    return replace(res, extras=extras, notes=(*res.notes, note))


def _method(algorithm: str):  # type: ignore[no-untyped-def]
    fit = fit_moesp if algorithm == "moesp" else fit_n4sid

    def run(data: Any, **options: Any) -> IdentificationResult:
        if getattr(data, "u", None) is None:
            raise DataError(
                f"method {algorithm!r} needs the plant input `u`, which the recording lacks; "
                "when it holds `u_f` and `r`, use data.with_plant_input()"
            )
        options.setdefault("dt", data.dt)
        y, u = np.asarray(data.y_control), np.asarray(data.u)
        # Deviations from the recording's own operating point (issue 12): the
        # model is then the same whatever constant levels the channels carry.
        y_mean, u_mean = y.mean(axis=0), u.mean(axis=0)
        res = fit(y - y_mean, u - u_mean, **options)
        return centred_result(res, y_mean, u_mean)

    run.__name__ = f"identify_{algorithm}"
    run.__doc__ = (
        f"``{algorithm}`` on a ClosedLoopData: y_control and u less their means, dt from the data."
    )
    return run


#: Methods for ``maglevid identify --method NAME`` (see identify/registry.py).
METHODS = {"moesp": _method("moesp"), "n4sid": _method("n4sid")}
#: One line per method for ``maglevid identify --method list``.
DESCRIPTIONS = {
    "moesp": "MOESP subspace identification of a black-box state-space model u -> y",
    "n4sid": "N4SID subspace identification of a black-box state-space model u -> y",
}


def _declaration(algorithm: str) -> tuple[Option, ...]:
    """The options of ``moesp`` / ``n4sid`` (maglevid.identify.options), defaults from
    :func:`fit_moesp` / :func:`fit_n4sid` except ``dt`` (the recording's)."""
    moesp = algorithm == "moesp"
    opts = [
        Option("order", "int", "model order (default: from the singular values)", low=1),
        Option("horizon", "int", "block rows i (default: ARX order by AIC + 1)", low=2),
        Option("dt", "float", "sample time (default: the recording's)", default=None,
               optional=False, low=0, low_open=True, unit="s"),
        Option("feedthrough", "bool", "estimate a direct term D"),
        Option("weighting", "str", "weighting of the oblique/orthogonal projection",
               choices=_MOESP_WEIGHTINGS if moesp else _N4SID_WEIGHTINGS),
        *(() if moesp else (Option("variant", "str", "N4SID algorithm variant",
                                   choices=_N4SID_VARIANTS),)),
        Option("rank_tol", "float", "relative singular-value tolerance of the rank",
               low=0, low_open=True, high=1),
        Option("factorization", "str", "data factorisation", choices=_FACTORIZATIONS),
        Option("bd_method", "str", "how B and D are estimated", choices=_BD_METHODS),
        Option("max_horizon", "int", f"largest automatic horizon (default "
               f"{DEFAULT_MAX_HORIZON})", low=2),
        Option("noise_model", "bool", "estimate the Kalman gain and innovation covariance"),
        Option("rng", "object", "random generator of the randomised checks"),
    ]  # fmt: skip
    return bind_defaults(opts, fit_moesp if moesp else fit_n4sid)


#: The options of each method, declared once (``--method list``, the CLI's --option).
OPTIONS = {"moesp": _declaration("moesp"), "n4sid": _declaration("n4sid")}
