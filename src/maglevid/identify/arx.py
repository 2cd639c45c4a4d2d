"""Linear-regression kernel shared by the ARX-type methods.

Every equation-error method of :mod:`maglevid.identify` (the deadbeat
observer/controller ARX of Gosiewski & Paszowski eqs. (44)-(51), classic OKID
eqs. (27)-(31), the plant ARX of :mod:`maglevid.identify.physical`) reduces to

.. math::

    Y(k) = \\Theta \\, \\varphi(k) + \\varepsilon(k), \\qquad k = 1, \\dots, N,

with ``Y`` of shape ``(N, ny)``, regressors ``Phi`` of shape ``(N, n)`` and the
coefficient matrix ``Theta`` of shape ``(ny, n)`` (the paper's ``P``).
:func:`solve_linear_regression` solves it by least squares or by instrumental
variables through QR/``lstsq`` (never normal equations) and returns a
:class:`LinearFit` with a covariance of ``Theta`` that allows for serially
correlated, cross-correlated equation errors (a truncated-kernel HAC sandwich;
the equation errors of these ARX forms are moving averages of the measurement
noise of known finite order).

Derivation of the estimator and its covariance
----------------------------------------------
Columns are scaled to unit RMS first (``Phi_s = Phi D^-1``); the estimate is
invariant to it but rank decisions and conditioning are not. With instruments
``Z`` (``Z = Phi`` for least squares) and the thin QR ``Z_s = Q_z R_z``, the
instrumental-variable equations ``Z^T (Y - Phi theta) = 0`` become

    (Q_z^T Phi_s) theta_s = Q_z^T Y                      (R_z^T cancels)

solved by ``lstsq``: exactly when ``Z`` has ``n`` columns (basic IV, and LS),
in the least-squares sense when it has more (two-stage least squares, the
"extended" IV). In every case ``theta_s - theta_s0 = K Q_z^T eps`` with
``K = (Q_z^T Phi_s)^+``, i.e. ``theta_s - theta_s0 = Psi^T eps`` with the
effective instruments ``Psi = Q_z K^T``. For output ``i`` the coefficient error is
``sum_k psi(k) eps_i(k)``, so with scores ``g(k) = eps(k) (x) psi(k)``

    Cov(vec Theta_s) = sum_{|l| <= L} w_l sum_k g(k) g(k - l)^T,

``vec`` stacking the rows of ``Theta`` (row-major ``ravel``). ``L`` is the
moving-average order of the equation error (``hac_lags``), ``w_l = 1``
(truncated kernel: unbiased for a moving average of order ``L``) or Bartlett
weights ``1 - l/(L+1)`` (always positive semi-definite).

When the equation error is a *known* moving average of white measurement
noise, ``eps(k) = sum_{j=0}^{q} C_j w(k - j)`` with ``Cov(w) = Sigma_w`` (the
``C_j`` follow from the estimated coefficients and the known loop), the
covariance can be written exactly instead of estimated by a lag window::

    theta_s - theta_s0 = sum_t M(t) w(t),  M(t) = sum_j C_j (x) psi(t + j),
    Cov(vec Theta_s) = sum_t M(t) Sigma_w M(t)^T,

with ``Sigma_w`` fitted to the residual autocovariances ``R(l) = sum_j C_j
Sigma_w C_{j-l}^T``, ``l = 0..q``, by least squares. This matters on the
bearing: the position row of the plant ARX is nearly a second difference,
``eps ~ w(k+1) - 2 w(k) + w(k-1)``, whose long-run variance almost cancels; a
lag-window estimate of that small difference of large terms overstated the
standard errors of the position row 1.4-1.6x in a 30-record Monte Carlo
(N = 2e4), the structured one does not (coverage in ``docs/gosiewski.md``).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.linalg as sla
from scipy.linalg import lapack

from maglevid._validation import as_signal, check_finite
from maglevid.exceptions import DataError, IdentificationError

__all__ = [
    "ARXModel",
    "LinearFit",
    "RegressionAccumulator",
    "fit_arx",
    "hac_covariance",
    "lagged",
    "markov_from_arx",
    "solve_linear_regression",
    "solve_regression_blocks",
    "white_noise_covariance",
]

logger = logging.getLogger(__name__)

_KERNELS = ("truncated", "bartlett")


@dataclass(frozen=True, eq=False)
class LinearFit:
    """Solution of ``Y(k) = Theta phi(k) + eps(k)`` by LS or IV.

    Attributes
    ----------
    coefficients : ndarray, shape (ny, n)
        ``Theta``.
    covariance : ndarray, shape (ny*n, ny*n)
        Covariance of ``coefficients.ravel()`` (row-major: all coefficients of
        output 0 first).
    residuals : ndarray, shape (N, ny), or None
        ``Y - Phi Theta^T`` (equation errors; one-step prediction errors for an
        ARX whose regressors are all past or known). ``None`` when the rows were
        streamed and not kept (:class:`RegressionAccumulator`).
    rank : int
        Numerical rank of the (scaled) matrix solved.
    singular_values : ndarray
        Singular values of the column-scaled matrix solved (``Phi_s`` for LS,
        ``Q_z^T Phi_s`` for IV), largest first.
    estimator : str
        ``"ls"``, ``"iv"`` (as many instruments as regressors) or ``"2sls"``.
    hac_lags, kernel : int, str
        Lag window of the covariance (``covariance_method="hac"``).
    covariance_method : str
        ``"hac"`` (lag window) or ``"white-noise"`` (known moving average of
        white measurement noise; see the module notes).
    noise_covariance : ndarray or None
        ``Sigma_w`` fitted for ``"white-noise"``.
    notes : tuple of str
        Anything marginal (e.g. a covariance that needed its negative
        eigenvalues clipped).
    residual_sum_of_squares : ndarray, shape (ny,), or None
        ``sum_k eps(k)^2`` per left-hand side (also when ``residuals`` is None).
    n_rows : int or None
        Rows of the regression.
    intercept : ndarray, shape (ny,), or None
        The constant ``c`` of ``Y(k) = Theta phi(k) + c + eps(k)`` when the
        regression estimated one (``intercept=True``); ``None`` otherwise.
    regressor_means : ndarray, shape (n,), or None
        Means of the regressors over the rows (with ``intercept=True``).
    gram : ndarray, shape (n + ny, n + ny), or None
        ``X^T X`` of ``X = [Phi, Y]`` over the rows (of their deviations from the
        means with ``intercept=True``), from the first pass's triangular factor
        (``R^T R``, no further pass over the data): e.g. the centred sums of
        squares of ``Y`` for a one-step fit, or second moments of the regressors.
    """

    coefficients: np.ndarray
    covariance: np.ndarray
    residuals: np.ndarray | None
    rank: int
    singular_values: np.ndarray
    estimator: str
    hac_lags: int
    kernel: str
    notes: tuple[str, ...] = field(default=())
    covariance_method: str = "hac"
    noise_covariance: np.ndarray | None = None
    residual_sum_of_squares: np.ndarray | None = None
    n_rows: int | None = None
    intercept: np.ndarray | None = None
    regressor_means: np.ndarray | None = None
    gram: np.ndarray | None = None

    def __post_init__(self) -> None:
        for name in (
            "coefficients",
            "covariance",
            "residuals",
            "singular_values",
            "noise_covariance",
            "residual_sum_of_squares",
            "intercept",
            "regressor_means",
            "gram",
        ):
            a = getattr(self, name)
            if a is None:
                continue
            if not _frozen_owner(a):  # (the residuals of a fit: N x ny, not copied again)
                a = np.array(a, dtype=float)
                a.setflags(write=False)
            object.__setattr__(self, name, a)

    @property
    def std_errors(self) -> np.ndarray:
        """Standard errors of ``coefficients``, same shape."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None)).reshape(
            self.coefficients.shape
        )

    @property
    def condition_number(self) -> float:
        s = self.singular_values
        return float(s[0] / s[-1]) if s.size and s[-1] > 0 else float("inf")


def _frozen_owner(a: Any) -> bool:
    """A read-only float64 array that owns its data: immutable already, no copy needed."""
    return (
        isinstance(a, np.ndarray)
        and a.dtype == np.float64
        and a.flags.owndata
        and not a.flags.writeable
    )


def _zero_columns(s: np.ndarray, name: str, labels: Sequence[str] | None) -> None:
    zero = np.flatnonzero(s == 0)
    if zero.size:
        which = ", ".join(labels[j] if labels else str(j) for j in zero)
        raise IdentificationError(
            f"`{name}` column(s) {which} are identically zero: the corresponding "
            "coefficients cannot be identified (is the excitation on?)"
        )


# ---------------------------------------------------------------- chunked kernels
# Both passes of the regression work on row blocks, so that the in-memory fit and
# the streamed one (maglevid.identify.streaming: records larger than memory) are
# the same computation, and so that each block stays in the cache.

#: Rows per block of the running QR. Measured on 10^6 x 19 (one BLAS thread):
#: blocks of 1024 / 4096 / 8192 / 32768 rows took 0.32 / 0.28 / 0.44 / 1.18 s,
#: numpy's one-shot ``qr(mode="r")`` 2.7 s and ``lstsq`` on 8 of the columns 0.78 s.
_QR_BLOCK = 4096
#: Rows per block of the residual pass (residuals, effective instruments, lagged
#: products): fit_physical (IV) at 10^6 took 0.52 / 0.56 / 0.60 s with blocks of
#: 4096 / 16384 / 32768 rows (the deadbeat IV fit 0.74 / 0.81 / 1.02 s).
_PASS_BLOCK = 1 << 12


class _RunningQR:
    """Triangular ``R`` with ``R^T R = X^T X`` of row blocks fed in turn (tall-skinny QR).

    ``R <- qr([R; X_b])`` by Householder QR (LAPACK ``dgeqrf``) of the running
    factor stacked over the next ``_QR_BLOCK`` rows. Householder QR is backward
    stable column by column, so ``R`` is as accurate as a QR of the whole ``X``
    (the orthogonal factor is never formed), its columns scale with those of
    ``X`` (``R(X D) = R(X) D``), and a change of the block boundaries changes
    only the rounding.
    """

    def __init__(self, k: int) -> None:
        self.k = k
        self.R = np.zeros((0, k))
        self.n = 0
        # Fortran order: the column blocks are copied in column runs (long inner loops, not
        # rows of 1-3 doubles) and LAPACK factors the buffer in place (a C-ordered one is
        # first copied to Fortran order by scipy); the same matrix, so the same R.
        self._buf = np.empty((_QR_BLOCK + k, k), order="F")

    def update(
        self, blocks: Sequence[np.ndarray], names: Sequence[str], *, check: bool = True
    ) -> None:
        rows = blocks[0].shape[0]
        for s0 in range(0, rows, _QR_BLOCK):
            s1 = min(rows, s0 + _QR_BLOCK)
            r = self.R.shape[0]
            buf = self._buf[: r + s1 - s0]
            buf[:r] = self.R
            c = 0
            for blk in blocks:
                buf[r:, c : c + blk.shape[1]] = blk[s0:s1]
                c += blk.shape[1]
            if check and not np.isfinite(buf[r:]).all():
                for blk, name in zip(blocks, names):
                    check_finite(blk, name)
            qr, _, _, info = lapack.dgeqrf(buf, overwrite_a=True)
            if info < 0:  # pragma: no cover - LAPACK argument error
                raise RuntimeError(f"dgeqrf failed with info={info}")
            self.R = np.triu(qr[: min(qr.shape)])
        self.n += rows


class _LagSums:
    """``S[l] = sum_t a(t) a(t + l)^T``, ``l = 0..L``, of a signal fed in consecutive chunks.

    The products are taken on the channel-major layout (one contiguous row of
    samples per channel, ``a^T``): ``S[l] += aT[:, :n-l] @ aT[:, l:].T`` is then a
    product of contiguous rows, ~20 % faster for these 5-35 channels than on the
    time-major chunk (docs/performance.md, 6b). The last ``L`` samples of each
    chunk are kept, and the pairs straddling a chunk boundary (tail sample, new
    sample) are added by one small product per lag, so each pair is counted
    exactly once; the result equals the sums over the whole signal
    (``a[:N-l].T @ a[l:]``) up to the order of summation.
    """

    def __init__(self, width: int, max_lag: int) -> None:
        self.L = max(int(max_lag), 0)
        self.S = np.zeros((self.L + 1, width, width))
        self.tail = np.zeros((width, 0))  # channel-major: the last <= L samples
        self.n = 0

    def update(self, a: np.ndarray) -> None:
        """Add a time-major chunk ``a`` (c, width)."""
        self.update_channels(np.ascontiguousarray(a.T))

    def update_channels(self, aT: np.ndarray) -> None:
        """Add a channel-major chunk ``aT`` (width, c): row ``i`` is channel ``i``."""
        tail, T = self.tail, self.tail.shape[1]
        nc = aT.shape[1]
        for lag in range(self.L + 1):
            if lag < nc:  # pairs inside the chunk
                self.S[lag] += aT[:, : nc - lag] @ aT[:, lag:].T
            j0, j1 = max(0, lag - T), min(lag, nc)  # new samples whose partner is in the tail
            if j0 < j1:
                self.S[lag] += tail[:, T + j0 - lag : T + j1 - lag] @ aT[:, j0:j1].T
        if self.L:
            old = max(0, T - (self.L - min(self.L, nc)))  # tail samples still within L
            self.tail = np.concatenate([tail[:, old:], aT[:, max(0, nc - self.L) :]], 1)
        self.n += nc


def _hac_from_lags(S_g: np.ndarray, lags: int, kernel: str) -> tuple[np.ndarray, bool]:
    """HAC sum from the lagged score products ``S_g[l] = sum_k g(k) g(k+l)^T``."""
    S = np.array(S_g[0])
    for lag in range(1, lags + 1):
        w = 1.0 if kernel == "truncated" else 1.0 - lag / (lags + 1.0)
        X = S_g[lag]
        S += w * (X + X.T)
    S = 0.5 * (S + S.T)
    lam, V = np.linalg.eigh(S)
    tol = 1e-10 * max(float(lam[-1]), 0.0)
    clipped = bool(lam[0] < -tol)
    if lam[0] < 0:
        S = (V * np.clip(lam, 0.0, None)) @ V.T
    return S, clipped


def _check_kernel(kernel: str, lags: int) -> None:
    if kernel not in _KERNELS:
        raise DataError(f"`kernel` must be one of {_KERNELS}; got {kernel!r}")
    if lags < 0:
        raise DataError(f"`lags` must be >= 0; got {lags}")


def hac_covariance(
    residuals: np.ndarray, psi: np.ndarray, *, lags: int, kernel: str = "truncated"
) -> tuple[np.ndarray, bool]:
    """HAC sum ``sum_l w_l sum_k g(k) g(k-l)^T`` with ``g(k) = eps(k) (x) psi(k)``.

    Parameters
    ----------
    residuals : ndarray, shape (N, ny)
    psi : ndarray, shape (N, n)
        Effective instruments (``theta_hat - theta = Psi^T eps``).
    lags : int
        Largest lag ``L`` (the moving-average order of the equation error).
    kernel : {"truncated", "bartlett"}

    Returns
    -------
    S : ndarray, shape (ny*n, ny*n)
        Symmetric and positive semi-definite (negative eigenvalues, which the
        truncated kernel can produce in short records, are clipped).
    clipped : bool
        Whether clipping was needed beyond rounding level.
    """
    _check_kernel(kernel, lags)
    N = residuals.shape[0]
    G = (residuals[:, :, None] * psi[:, None, :]).reshape(N, -1)
    acc = _LagSums(G.shape[1], lags)
    acc.update(G)
    return _hac_from_lags(acc.S, lags, kernel)


def _check_ma(ma: Sequence[np.ndarray], ny: int) -> list[np.ndarray]:
    C = [np.atleast_2d(np.asarray(c, dtype=float)) for c in ma]
    nw = C[0].shape[1]
    if any(c.shape != (ny, nw) for c in C):
        raise DataError(f"every MA coefficient must have shape ({ny}, {nw})")
    return C


def _white_noise_from_lags(
    R: Sequence[np.ndarray], Gam: Sequence[np.ndarray], C: Sequence[np.ndarray]
) -> tuple[np.ndarray, np.ndarray, bool]:
    """:func:`white_noise_covariance` from lagged products.

    ``R(l) = sum_t eps(t+l) eps(t)^T / N`` for ``l <= min(q, 20)`` and
    ``Gam(l) = sum_t psi(t) psi(t+l)^T`` for ``l <= q`` (missing lags count as zero).
    """
    ny, nw = C[0].shape
    n = Gam[0].shape[0]
    q = len(C) - 1
    lags = range(len(R))
    # Sigma_w from R(l) = sum_{j>=l} C_j Sigma_w C_{j-l}^T, l = 0..min(q, 20), by lstsq
    # over the symmetric basis E_ab + E_ba. Each equation (entry (a, b) of R(l)) is
    # weighted by 1/sqrt(R_aa(0) R_bb(0)): the channels differ by orders of magnitude
    # (m against A), and unweighted the small channels' equations would not count.
    r0 = np.sqrt(np.clip(np.diag(R[0]), np.finfo(float).tiny, None))
    wgt = np.tile((1.0 / np.outer(r0, r0)).ravel(), len(lags))
    basis = []
    for a in range(nw):
        for b in range(a, nw):
            E = np.zeros((nw, nw))
            E[a, b] = E[b, a] = 1.0
            basis.append(E)
    design = np.array(
        [
            np.concatenate(
                [sum(C[j] @ E @ C[j - lag].T for j in range(lag, q + 1)).ravel() for lag in lags]
            )
            for E in basis
        ]
    ).T
    target = np.concatenate([r.ravel() for r in R])
    coef, *_ = np.linalg.lstsq(design * wgt[:, None], target * wgt, rcond=None)
    sigma = sum(c * E for c, E in zip(coef, basis))
    lam, V = np.linalg.eigh(sigma)
    clipped = bool(lam[0] < -1e-8 * max(float(lam[-1]), 0.0))
    sigma = (V * np.clip(lam, 0.0, None)) @ V.T
    # sum_t M(t) Sigma M(t)^T with M(t) = sum_j C_j (x) psi(t + j) expands, by
    # (A (x) b)(C (x) d)^T = (A C^T) (x) (b d^T), into
    #   S = sum_{j, j'} (C_j Sigma C_j'^T) (x) Gamma(j' - j),
    #   Gamma(l) = sum_t psi(t) psi(t + l)^T,  Gamma(-l) = Gamma(l)^T,
    # which needs only q + 1 lagged products of psi.

    def gamma(lag: int) -> np.ndarray:
        if abs(lag) >= len(Gam):
            return np.zeros((n, n))
        return Gam[lag] if lag >= 0 else Gam[-lag].T

    S = np.zeros((ny * n, ny * n))
    for j in range(q + 1):
        CS = C[j] @ sigma
        for jp in range(q + 1):
            S += np.kron(CS @ C[jp].T, gamma(jp - j))
    return 0.5 * (S + S.T), sigma, clipped


#: Largest lag of the residual autocovariances the white-noise fit uses.
_WHITE_NOISE_MAX_LAG = 20


def white_noise_covariance(
    residuals: np.ndarray, psi: np.ndarray, ma: Sequence[np.ndarray]
) -> tuple[np.ndarray, np.ndarray, bool]:
    """Covariance sum for ``eps(k) = sum_j C_j w(k - j)`` with white ``w`` (module notes).

    Parameters
    ----------
    residuals : ndarray, shape (N, ny)
        Estimated equation errors (for ``Sigma_w``).
    psi : ndarray, shape (N, n)
        Effective instruments (``theta_hat - theta = Psi^T eps``).
    ma : sequence of ndarray, each (ny, nw)
        ``C_0 .. C_q``.

    Returns
    -------
    S : ndarray, shape (ny*n, ny*n)
        ``sum_t M(t) Sigma_w M(t)^T``.
    sigma_w : ndarray, shape (nw, nw)
        Fitted noise covariance (positive semi-definite).
    clipped : bool
        Whether the fitted ``Sigma_w`` had to be made positive semi-definite.
    """
    N, ny = residuals.shape
    C = _check_ma(ma, ny)
    q = len(C) - 1
    re = _LagSums(ny, min(q, _WHITE_NOISE_MAX_LAG))
    re.update(residuals)
    ps = _LagSums(psi.shape[1], min(q, N - 1))
    ps.update(psi)
    return _white_noise_from_lags([s.T / N for s in re.S], list(ps.S), C)


class RegressionAccumulator:
    """``Y(k) = Theta phi(k) + eps(k)`` by LS or IV from rows fed in chunks (two passes).

    The kernel of :func:`solve_linear_regression`, usable on records that do not
    fit in memory (:mod:`maglevid.identify.streaming`). With ``X = [Z, Phi, Y]``
    (``[Phi, Y]`` for least squares) and ``R`` its triangular QR factor,
    accumulated block by block by :class:`_RunningQR`:

    * ``R = [[R_zz, R_zp, R_zy], ...]`` gives ``Q_z^T Phi = R_zp`` and
      ``Q_z^T Y = R_zy`` with ``Q_z = Z R_zz^-1`` (module notes: the
      instrumental-variable equations ``(Q_z^T Phi_s) theta_s = Q_z^T Y``), and
      the column scales ``||x_j|| = ||R[:, j]||``;
    * the effective instruments are ``psi = Q_z K^T = Z W`` with
      ``W = D_z^-1 R_zz,s^-1 K^T``; for least squares, with ``Phi_s = Q U S V^T``,
      ``psi = Phi_s V S^-2 V^T`` (which also holds for the minimum-norm solution);
    * the covariance needs lagged products of the residuals and of ``psi``
      (or of the scores ``eps (x) psi``), collected in a second pass over the
      same rows by :meth:`update_residuals`.

    Use: :meth:`update` for every chunk, :meth:`solve`, :meth:`update_residuals`
    for every chunk again (same rows, same order), :meth:`finish`.

    Parameters
    ----------
    n, ny : int
        Regressors and left-hand sides.
    nz : int, optional
        Instruments (``None``: least squares).
    labels : sequence of str, optional
        Regressor names, used in error messages.
    intercept : bool
        Estimate a constant ``c`` too: ``Y(k) = Theta phi(k) + c + eps(k)``, the
        constant also being an instrument. A column of ones is put *first* in
        ``X``; its QR step removes the column means from every other column, so
        the rest of ``R`` is the factor of the centred ``[Z, Phi, Y]`` and the
        slopes are those of the regression on deviations from the means over
        the rows (Frisch-Waugh-Lovell, which holds for IV when the constant is
        an included instrument). ``Theta``, its covariance and the effective
        instruments then refer to centred data, and the result is the same, to
        rounding, when constants are added to any column of ``Y``, ``Phi`` or
        ``Z``: the estimate is invariant to the operating point of a recording.
    """

    def __init__(
        self,
        n: int,
        ny: int,
        *,
        nz: int | None = None,
        labels: Sequence[str] | None = None,
        intercept: bool = False,
    ) -> None:
        if n < 1 or ny < 1:
            raise DataError(f"need at least one regressor and one output; got n={n}, ny={ny}")
        if labels is not None and len(labels) != n:
            raise DataError(f"`labels` has {len(labels)} names for {n} regressors")
        if nz is not None and nz < n:
            raise DataError(
                f"`instruments` has {nz} columns; need at least {n} (one per regressor)"
            )
        self.n, self.ny, self.nz = n, ny, nz
        self.labels = labels
        self.estimator = "ls" if nz is None else ("iv" if nz == n else "2sls")
        self.intercept = bool(intercept)
        self._qr = _RunningQR(int(self.intercept) + (0 if nz is None else nz) + n + ny)
        self._solved = False
        self._pass2: dict[str, Any] = {}

    @property
    def n_rows(self) -> int:
        """Rows seen by the first pass."""
        return self._qr.n

    def _parts(self, x: Any, name: str, width: int, rows: int | None) -> list[np.ndarray]:
        """``x`` as a list of 2-D column blocks (an array, or a list/tuple of arrays)."""
        items = list(x) if isinstance(x, (list, tuple)) else [x]
        parts = []
        for item in items:
            a = np.asarray(item, dtype=float)
            parts.append(a[:, None] if a.ndim == 1 else a)
        if any(a.ndim != 2 for a in parts):
            raise DataError(f"`{name}` must be 2-D (time first)")
        n_rows = {a.shape[0] for a in parts}
        got = sum(a.shape[1] for a in parts)
        if len(n_rows) != 1 or got != width or (rows is not None and n_rows != {rows}):
            shapes = [a.shape for a in parts]
            raise DataError(
                f"`{name}` has shape {shapes[0] if len(shapes) == 1 else shapes}; expected "
                f"({rows if rows is not None else 'N'}, {width})"
            )
        return parts

    def _blocks(
        self, Y: Any, Phi: Any, Z: Any
    ) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
        phi = self._parts(Phi, "Phi", self.n, None)
        rows = phi[0].shape[0]
        y = self._parts(Y, "Y", self.ny, rows)
        if (Z is None) != (self.nz is None):
            raise DataError("give `instruments` on every chunk, or on none")
        z = phi if Z is None else self._parts(Z, "instruments", self.nz or 0, rows)
        return z, phi, y

    def update(self, Y: Any, Phi: Any, instruments: Any = None, *, check: bool = True) -> None:
        """First pass: add rows ``Y`` (c, ny), ``Phi`` (c, n) and instruments (c, nz).

        Each may also be a list of column blocks with the same rows (e.g. views of
        the signals at different lags), which saves assembling the regressor.
        """
        if self._solved:
            raise DataError("the first pass is over (solve() was called)")
        z, phi, y = self._blocks(Y, Phi, instruments)
        blocks = phi + y if self.nz is None else z + phi + y
        names = (
            ["Phi"] * len(phi) + ["Y"] * len(y)
            if self.nz is None
            else ["instruments"] * len(z) + ["Phi"] * len(phi) + ["Y"] * len(y)
        )
        if self.intercept:
            blocks = [np.ones((phi[0].shape[0], 1)), *blocks]
            names = ["intercept", *names]
        self._qr.update(blocks, names, check=check)

    def solve(
        self,
        *,
        min_norm: bool = False,
        hac_lags: int = 0,
        kernel: str = "truncated",
        noise_ma: Callable[[np.ndarray], Sequence[np.ndarray]] | None = None,
    ) -> np.ndarray:
        """Coefficients ``Theta`` (ny, n) from the first pass; prepares the second.

        Options as in :func:`solve_linear_regression`.
        """
        _check_kernel(kernel, hac_lags)
        n, ny, nz = self.n, self.ny, self.nz
        N = self._qr.n
        if N <= n:
            raise DataError(
                f"`Phi` has {N} rows for {n} regressors; need more rows than regressors"
            )
        R = self._qr.R
        means = None
        if self.intercept:
            # Row 0 of R is the ones column's: R[0, j] / R[0, 0] = mean of column j;
            # the rest is the factor of the centred columns.
            means = R[0, 1:] / R[0, 0]
            R = R[1:, 1:]
        norms = np.linalg.norm(R, axis=0) / np.sqrt(N)  # RMS of each (centred) column of X
        k0 = 0 if nz is None else nz
        s = norms[k0 : k0 + n]
        _zero_columns(s, "Phi", self.labels)
        notes: list[str] = []
        R_y = R[:, k0 + n :]
        if nz is None:
            M = R[:n, :n] / s  # R of Phi_s: Q^T Phi_s
            QtY = R_y[:n]
        else:
            sz = norms[:nz]
            _zero_columns(sz, "instruments", None)
            Rzz = R[:nz, :nz] / sz
            # A rank-deficient Z would make Q_z arbitrary; check Z (R_zz) first.
            sv_z = np.linalg.svd(Rzz, compute_uv=False)
            if sv_z[-1] <= sv_z[0] * max(N, nz) * np.finfo(float).eps:
                raise IdentificationError(
                    "the instruments are linearly dependent; remove redundant instruments"
                )
            M = R[:nz, nz : nz + n] / s  # Q_z^T Phi_s
            QtY = R_y[:nz]
        U, sv, Vt = np.linalg.svd(M, full_matrices=False)
        tol = sv[0] * max(N, n) * np.finfo(float).eps
        rank = int(np.sum(sv > tol))
        labels = self.labels
        if rank < n and min_norm:
            notes.append(
                f"rank-deficient regression (rank {rank} of {n}): minimum-norm solution; the "
                "coefficients are not unique"
            )
            U, sv, Vt = U[:, :rank], sv[:rank], Vt[:rank]
        elif rank < n:
            null = Vt[-1] / s
            null = null / np.max(np.abs(null))
            big = np.flatnonzero(np.abs(null) > 1e-6)
            names = [labels[j] if labels else f"column {j}" for j in big]
            raise IdentificationError(
                f"the regression is rank deficient (rank {rank} of {n}"
                + (", with the instruments" if nz is not None else "")
                + "): the data do not determine the coefficients. Collinear regressors: "
                + ", ".join(names)
                + ". Remove the duplicated regressor or excite the loop more richly"
            )
        # theta_s = M^+ Q^T Y; K = M^+ = V diag(1/s) U^T.
        K = (Vt.T / sv) @ U.T  # (n, nz)
        theta = (K @ QtY) / s[:, None]  # (n, ny)
        if nz is None:
            W = (Vt.T / sv**2) @ Vt / s[:, None]  # psi = Phi_s V S^-2 V^T
        else:
            W = sla.solve_triangular(Rzz, K.T) / sz[:, None]  # psi = Z D_z^-1 R_zz,s^-1 K^T
        if sv[0] / sv[-1] > 1e10:
            notes.append(f"the regression is ill-conditioned (condition {sv[0] / sv[-1]:.2g})")
            logger.warning(notes[-1])
        p2: dict[str, Any] = {
            "theta": theta,
            "W": W,
            "s": s,
            "sv": sv,
            "rank": rank,
            "notes": notes,
            "hac_lags": int(hac_lags),
            "kernel": kernel,
            "sum_e2": np.zeros(ny),
            "n": 0,
            "eps0": np.zeros(ny),
            "psi0": np.zeros(n),
            "gram": R[:, k0:].T @ R[:, k0:],  # [Phi, Y]^T [Phi, Y] (centred with intercept)
        }
        if means is not None:
            # constants of the second pass: eps = Y - Phi Theta^T - c, psi = (Z - mean Z) W
            m_phi, m_y = means[k0 : k0 + n], means[k0 + n :]
            p2["intercept"] = m_y - m_phi @ theta
            p2["regressor_means"] = m_phi
            p2["eps0"] = p2["intercept"]
            p2["psi0"] = (m_phi if nz is None else means[:nz]) @ W
        if noise_ma is None:
            p2["scores"] = _LagSums(ny * n, hac_lags)
        else:
            C = _check_ma(noise_ma(theta.T), ny)
            q = len(C) - 1
            p2["ma"] = C
            p2["eps"] = _LagSums(ny, min(q, _WHITE_NOISE_MAX_LAG))
            p2["psi"] = _LagSums(n, min(q, N - 1))
        self._pass2 = p2
        self._solved = True
        return theta.T

    def update_residuals(self, Y: Any, Phi: Any, instruments: Any = None) -> np.ndarray:
        """Second pass: the same rows again; returns their residuals ``Y - Phi Theta^T``."""
        if not self._solved:
            raise DataError("call solve() after the first pass, before update_residuals()")
        z, phi, y = self._blocks(Y, Phi, instruments)
        p2 = self._pass2
        theta, W = p2["theta"], p2["W"]
        rows = phi[0].shape[0]
        out = np.empty((rows, self.ny))
        self._made = out  # finish() keeps this array as it is (frozen), not a copy

        # The column blocks of Phi (and of Z) are copied into one cache-sized buffer and
        # multiplied once by [Theta^T, 0; 0, W] (LS: [Theta^T, W]): one GEMM per block
        # instead of two small products per column block (1960 calls at 10^6). The block
        # is held channel-major (one row of samples per column, reused buffers): the copies,
        # the subtractions and the lagged products (_LagSums) then run along rows of
        # thousands of samples instead of rows of 2-7 doubles (docs/performance.md, 6b).
        n, ny = self.n, self.ny
        parts = phi if z is phi else phi + z
        k = sum(a.shape[1] for a in parts)
        M = np.zeros((k, ny + W.shape[1]))
        M[:n, :ny] = theta
        M[k - W.shape[0] :, ny:] = W
        MT = np.ascontiguousarray(M.T)
        nb = min(rows, _PASS_BLOCK)
        buf = np.empty((k, nb))
        chan_buf = np.empty((M.shape[1], nb))
        eps0 = p2["eps0"][:, None]
        psi0 = p2["psi0"][:, None]
        for s0 in range(0, rows, _PASS_BLOCK):
            s1 = min(rows, s0 + _PASS_BLOCK)
            B, c = buf[:, : s1 - s0], 0
            for a in parts:
                B[c : c + a.shape[1]] = a[s0:s1].T
                c += a.shape[1]
            chan = chan_buf[:, : s1 - s0]
            np.matmul(MT, B, out=chan)  # [Theta Phi^T; W^T Z^T] of the block
            epsT, psiT = chan[:ny], chan[ny:]
            c = 0
            for a in y:  # Y - Phi Theta^T, block by block of Y's columns
                np.subtract(a[s0:s1].T, epsT[c : c + a.shape[1]], out=epsT[c : c + a.shape[1]])
                c += a.shape[1]
            epsT -= eps0
            psiT -= psi0
            out[s0:s1] = epsT.T
            p2["sum_e2"] += np.einsum("ij,ij->i", epsT, epsT)
            if "scores" in p2:
                eps, psi = out[s0:s1], psiT.T
                p2["scores"].update((eps[:, :, None] * psi[:, None, :]).reshape(s1 - s0, -1))
            else:
                p2["eps"].update_channels(epsT)
                p2["psi"].update_channels(psiT)
        p2["n"] += rows
        return out

    def finish(self, residuals: np.ndarray | None = None) -> LinearFit:
        """The :class:`LinearFit` after the second pass (``residuals`` to keep, if any)."""
        p2 = self._pass2
        N = self._qr.n
        if not self._solved or p2["n"] != N:
            raise DataError(
                f"the second pass saw {p2.get('n', 0)} rows; the first saw {N}: feed the same "
                "rows to update_residuals() before finish()"
            )
        notes = list(p2["notes"])
        if residuals is not None and residuals is getattr(self, "_made", None):
            residuals.setflags(write=False)  # made by update_residuals: LinearFit keeps it
        sigma_w = None
        if "scores" in p2:
            method = "hac"
            S, clipped = _hac_from_lags(p2["scores"].S, p2["hac_lags"], p2["kernel"])
            if clipped:
                notes.append(
                    f"the {p2['kernel']}-kernel covariance with {p2['hac_lags']} lags had "
                    "negative eigenvalues (short record); they were set to zero"
                )
        else:
            method = "white-noise"
            R = [S.T / N for S in p2["eps"].S]
            S, sigma_w, clipped = _white_noise_from_lags(R, list(p2["psi"].S), p2["ma"])
            if clipped:
                notes.append(
                    "the noise covariance fitted to the residual autocovariances was not "
                    "positive semi-definite (the equation error may not be the assumed moving "
                    "average of white measurement noise); its negative part was set to zero"
                )
        d = np.tile(1.0 / p2["s"], self.ny)
        cov = S * d[:, None] * d[None, :]
        return LinearFit(
            coefficients=p2["theta"].T,
            covariance=cov,
            residuals=residuals,
            rank=p2["rank"],
            singular_values=p2["sv"],
            estimator=self.estimator,
            hac_lags=p2["hac_lags"],
            kernel=p2["kernel"],
            notes=tuple(notes),
            covariance_method=method,
            noise_covariance=sigma_w,
            residual_sum_of_squares=p2["sum_e2"],
            n_rows=N,
            intercept=p2.get("intercept"),
            regressor_means=p2.get("regressor_means"),
            gram=p2["gram"],
        )


def _as_regression_input(x: Any, name: str, n_samples: int | None = None) -> np.ndarray:
    """Time-first 2-D float array, finite; no copy when it already is one."""
    a = np.asarray(x, dtype=float)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2:
        raise DataError(
            f"`{name}` must be 1-D or 2-D (time first); got {a.ndim}-D shape {a.shape}"
        )
    if n_samples is not None and a.shape[0] != n_samples:
        raise DataError(
            f"`{name}` has shape {a.shape}; expected ({n_samples}, n) with time along axis 0"
        )
    check_finite(a, name)
    return a


def solve_linear_regression(
    Y: Any,
    Phi: Any,
    *,
    instruments: Any = None,
    hac_lags: int = 0,
    kernel: str = "truncated",
    labels: Sequence[str] | None = None,
    min_norm: bool = False,
    noise_ma: Callable[[np.ndarray], Sequence[np.ndarray]] | None = None,
    intercept: bool = False,
) -> LinearFit:
    """Least-squares or instrumental-variable solution of ``Y(k) = Theta phi(k) + eps(k)``.

    Parameters
    ----------
    Y : array_like, shape (N, ny)
        Left-hand sides, time first.
    Phi : array_like, shape (N, n)
        Regressors, time first.
    instruments : array_like, shape (N, nz), optional
        Instruments ``Z`` (``nz >= n``), uncorrelated with the equation error
        ``eps``; ``None`` gives least squares. ``nz == n``: basic IV;
        ``nz > n``: two-stage least squares.
    hac_lags : int
        Moving-average order of ``eps`` for the covariance (0: serially white).
    kernel : {"truncated", "bartlett"}
        Lag weights of the covariance.
    labels : sequence of str, optional
        Regressor names, used in error messages.
    noise_ma : callable, optional
        ``Theta -> [C_0, ..., C_q]``: the equation error as a moving average of
        white measurement noise (``eps(k) = sum_j C_j w(k - j)``). When given, the
        covariance is the structured white-noise one (module notes) and
        ``hac_lags``/``kernel`` are not used.
    min_norm : bool
        Accept a rank-deficient problem and return the minimum-norm solution
        (in the column-scaled coordinates) with a note, instead of raising.
        Only for demonstrations of non-identifiability (e.g. OKID with
        redundant lags); the covariance is then that of the minimum-norm
        estimator.
    intercept : bool
        Estimate a constant too (:class:`RegressionAccumulator`): the slopes
        are then invariant to constant offsets in ``Y``, ``Phi`` and the
        instruments, and the constant is ``LinearFit.intercept``.

    Returns
    -------
    LinearFit

    Raises
    ------
    DataError
        Shapes disagree, non-finite values, or fewer samples than unknowns.
    IdentificationError
        A regressor (or instrument) is identically zero, or the matrix to solve
        is rank deficient: the data do not determine ``Theta``. The message
        names the regressors of the collinear combination.

    Notes
    -----
    Computed by :class:`RegressionAccumulator` in row blocks: the triangular
    factor of ``[Z, Phi, Y]`` by a running QR (no orthogonal factor of ``N``
    rows is formed), then one pass for the residuals and the lagged products of
    the covariance. The same kernel serves records streamed from files.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> Phi = rng.standard_normal((200, 2))
    >>> fit = solve_linear_regression(Phi @ [[2.0], [-1.0]], Phi)
    >>> np.allclose(fit.coefficients, [[2.0, -1.0]])
    True
    """
    Phi = _as_regression_input(Phi, "Phi")
    N, n = Phi.shape
    Y = _as_regression_input(Y, "Y", n_samples=N)
    if labels is not None and len(labels) != n:
        raise DataError(f"`labels` has {len(labels)} names for {n} regressors")
    if N <= n:
        raise DataError(f"`Phi` has {N} rows for {n} regressors; need more rows than regressors")
    Z = None if instruments is None else _as_regression_input(instruments, "instruments", N)
    acc = RegressionAccumulator(
        n, Y.shape[1], nz=None if Z is None else Z.shape[1], labels=labels, intercept=intercept
    )
    acc.update(Y, Phi, Z, check=False)
    acc.solve(min_norm=min_norm, hac_lags=hac_lags, kernel=kernel, noise_ma=noise_ma)
    residuals = acc.update_residuals(Y, Phi, Z)
    return acc.finish(residuals)


def solve_regression_blocks(
    Y: Any,
    Phi: Sequence[np.ndarray],
    instruments: Sequence[np.ndarray] | None = None,
    *,
    hac_lags: int = 0,
    kernel: str = "truncated",
    labels: Sequence[str] | None = None,
    noise_ma: Callable[[np.ndarray], Sequence[np.ndarray]] | None = None,
    intercept: bool = False,
) -> LinearFit:
    """:func:`solve_linear_regression` with the regressors given as column blocks.

    For the AMB methods, whose regressors are the recorded signals at a few lags:
    ``Phi = [y[k0:k1], y[k0-1:k1-1, :1], ...]`` are views of arrays a
    :class:`~maglevid.data.ClosedLoopData` has already checked (finite), so no
    ``N x n`` matrix is assembled and nothing is checked again. Same result as
    ``solve_linear_regression(Y, np.hstack(Phi), instruments=np.hstack(Z))``.
    """
    n = sum(np.shape(a)[1] if np.ndim(a) == 2 else 1 for a in Phi)
    Yp = list(Y) if isinstance(Y, (list, tuple)) else [Y]
    ny = sum(np.shape(a)[1] if np.ndim(a) == 2 else 1 for a in Yp)
    nz = None
    if instruments is not None:
        nz = sum(np.shape(a)[1] if np.ndim(a) == 2 else 1 for a in instruments)
    acc = RegressionAccumulator(n, ny, nz=nz, labels=labels, intercept=intercept)
    acc.update(Y, list(Phi), None if instruments is None else list(instruments), check=False)
    acc.solve(hac_lags=hac_lags, kernel=kernel, noise_ma=noise_ma)
    return acc.finish(
        acc.update_residuals(Y, list(Phi), None if instruments is None else list(instruments))
    )


def lagged(signal: Any, lags: Sequence[int], start: int, stop: int) -> np.ndarray:
    """Stack ``signal(k - l)`` for each lag ``l``, rows ``k = start .. stop-1``.

    Parameters
    ----------
    signal : array_like, shape (N, c)
    lags : sequence of int
        Lags ``l`` (0 = current sample; negative = lead).
    start, stop : int
        Row range of ``k``; ``k - l`` must stay inside ``0 .. N-1``.

    Returns
    -------
    ndarray, shape (stop - start, c * len(lags))
        Blocks in the order of ``lags``.
    """
    x = np.asarray(signal, dtype=float)
    if x.ndim == 1:
        x = x[:, None]
    N = x.shape[0]
    for lag in lags:
        if start - lag < 0 or stop - lag > N:
            raise DataError(
                f"lag {lag} reaches outside the signal for rows {start}..{stop - 1} (N={N})"
            )
    return np.hstack([x[start - lag : stop - lag] for lag in lags])


@dataclass(frozen=True, eq=False)
class ARXModel:
    """MIMO ARX ``y(k) = sum_i a_i y(k-i) + sum_i b_i u(k-i) + b_0 u(k)`` (eq. (27))."""

    a: np.ndarray  # (na, ny, ny)
    b: np.ndarray  # (nb + 1, ny, nu); b[0] is the direct term (zero when nk >= 1)
    fit: LinearFit
    dt: float | None = None

    def markov(self, n: int) -> np.ndarray:
        """Markov parameters ``Y_0 .. Y_{n-1}`` by the recursion of eq. (31)."""
        return markov_from_arx(self.a, self.b, n)


def markov_from_arx(a: Any, b: Any, n: int) -> np.ndarray:
    """Markov parameters (impulse response) of an ARX model, eq. (31).

    ``Y_k = b_k + sum_{i=1}^{k} a_i Y_{k-i}`` with ``b_k = 0`` beyond the model
    order (Gosiewski & Paszowski eq. (31); the paper's recursion starts at
    ``Y_1 = b_1``; here ``Y_0 = b_0``, the direct term, is included).

    Parameters
    ----------
    a : array_like, shape (na, ny, ny)
        ``a_1 .. a_na``.
    b : array_like, shape (nb + 1, ny, nu)
        ``b_0 .. b_nb``.
    n : int
        Number of Markov parameters.

    Returns
    -------
    ndarray, shape (n, ny, nu)

    Examples
    --------
    >>> import numpy as np
    >>> Y = markov_from_arx([[[0.5]]], [[[0.0]], [[1.0]]], 4)
    >>> Y[:, 0, 0].tolist()
    [0.0, 1.0, 0.5, 0.25]
    """
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if a.ndim != 3 or b.ndim != 3 or a.shape[1:] != (b.shape[1], b.shape[1]):
        raise DataError(
            f"`a` must be (na, ny, ny) and `b` (nb+1, ny, nu); got {a.shape} and {b.shape}"
        )
    na = a.shape[0]
    out = np.zeros((n, b.shape[1], b.shape[2]))
    for k in range(n):
        acc = b[k].copy() if k < b.shape[0] else np.zeros(b.shape[1:])
        for i in range(1, min(k, na) + 1):
            acc += a[i - 1] @ out[k - i]  # eq. (31)
        out[k] = acc
    return out


def fit_arx(
    y: Any,
    u: Any,
    *,
    na: int,
    nb: int,
    direct: bool = False,
    instruments: Any = None,
    hac_lags: int = 0,
    dt: float | None = None,
) -> ARXModel:
    """Fit a MIMO ARX model by least squares (or IV) through QR/``lstsq``.

    ``y(k) = sum_{i=1}^{na} a_i y(k-i) + sum_{i=1}^{nb} b_i u(k-i) [+ b_0 u(k)]``
    (Gosiewski & Paszowski eq. (27); Ljung 1999, sec. 4.2).

    Parameters
    ----------
    y : array_like, shape (N, ny)
    u : array_like, shape (N, nu)
    na, nb : int
        Orders (``na >= 0``, ``nb >= 1``).
    direct : bool
        Estimate a direct term ``b_0``.
    instruments : array_like, shape (N - max(na, nb), nz), optional
        Instruments for the rows ``k = max(na, nb) .. N-1``.
    hac_lags : int
        Moving-average order of the equation error for the covariance.
    dt : float, optional
        Sample time, stored on the model.

    Returns
    -------
    ARXModel
    """
    y = as_signal(y, "y")
    u = as_signal(u, "u", n_samples=y.shape[0])
    if na < 0 or nb < 1:
        raise DataError(f"need na >= 0 and nb >= 1; got na={na}, nb={nb}")
    ny, nu = y.shape[1], u.shape[1]
    k0 = max(na, nb)
    N = y.shape[0]
    blocks = []
    if na:
        blocks.append(lagged(y, range(1, na + 1), k0, N))
    blocks.append(lagged(u, range(0 if direct else 1, nb + 1), k0, N))
    fit = solve_linear_regression(
        y[k0:], np.hstack(blocks), instruments=instruments, hac_lags=hac_lags
    )
    th = fit.coefficients
    a = (
        np.stack([th[:, i * ny : (i + 1) * ny] for i in range(na)])
        if na
        else np.zeros((0, ny, ny))
    )
    off = na * ny
    b = np.zeros((nb + 1, ny, nu))
    first = 0 if direct else 1
    for j, i in enumerate(range(first, nb + 1)):
        b[i] = th[:, off + j * nu : off + (j + 1) * nu]
    return ARXModel(a=a, b=b, fit=fit, dt=dt)
