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

from maglevid._validation import as_signal
from maglevid.exceptions import DataError, IdentificationError

__all__ = [
    "ARXModel",
    "LinearFit",
    "fit_arx",
    "hac_covariance",
    "lagged",
    "markov_from_arx",
    "solve_linear_regression",
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
    residuals : ndarray, shape (N, ny)
        ``Y - Phi Theta^T`` (equation errors; one-step prediction errors for an
        ARX whose regressors are all past or known).
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
    """

    coefficients: np.ndarray
    covariance: np.ndarray
    residuals: np.ndarray
    rank: int
    singular_values: np.ndarray
    estimator: str
    hac_lags: int
    kernel: str
    notes: tuple[str, ...] = field(default=())
    covariance_method: str = "hac"
    noise_covariance: np.ndarray | None = None

    def __post_init__(self) -> None:
        for name in (
            "coefficients",
            "covariance",
            "residuals",
            "singular_values",
            "noise_covariance",
        ):
            if getattr(self, name) is None:
                continue
            a = np.array(getattr(self, name), dtype=float)
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


def _column_scale(M: np.ndarray, name: str, labels: Sequence[str] | None) -> np.ndarray:
    s = np.sqrt(np.mean(M**2, axis=0))
    zero = np.flatnonzero(s == 0)
    if zero.size:
        which = ", ".join(labels[j] if labels else str(j) for j in zero)
        raise IdentificationError(
            f"`{name}` column(s) {which} are identically zero: the corresponding "
            "coefficients cannot be identified (is the excitation on?)"
        )
    return s


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
    if kernel not in _KERNELS:
        raise DataError(f"`kernel` must be one of {_KERNELS}; got {kernel!r}")
    if lags < 0:
        raise DataError(f"`lags` must be >= 0; got {lags}")
    N = residuals.shape[0]
    G = (residuals[:, :, None] * psi[:, None, :]).reshape(N, -1)
    S = G.T @ G
    for lag in range(1, min(lags, N - 1) + 1):
        w = 1.0 if kernel == "truncated" else 1.0 - lag / (lags + 1.0)
        X = G[lag:].T @ G[:-lag]
        S += w * (X + X.T)
    S = 0.5 * (S + S.T)
    lam, V = np.linalg.eigh(S)
    tol = 1e-10 * max(float(lam[-1]), 0.0)
    clipped = bool(lam[0] < -tol)
    if lam[0] < 0:
        S = (V * np.clip(lam, 0.0, None)) @ V.T
    return S, clipped


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
    C = [np.atleast_2d(np.asarray(c, dtype=float)) for c in ma]
    N, ny = residuals.shape
    n = psi.shape[1]
    nw = C[0].shape[1]
    q = len(C) - 1
    if any(c.shape != (ny, nw) for c in C):
        raise DataError(f"every MA coefficient must have shape ({ny}, {nw})")
    # Sigma_w from R(l) = sum_{j>=l} C_j Sigma_w C_{j-l}^T, l = 0..min(q, 20), by lstsq
    # over the symmetric basis E_ab + E_ba. Each equation (entry (a, b) of R(l)) is
    # weighted by 1/sqrt(R_aa(0) R_bb(0)): the channels differ by orders of magnitude
    # (m against A), and unweighted the small channels' equations would not count.
    lags = range(min(q, 20) + 1)
    R = [residuals[lag:].T @ residuals[: N - lag] / N for lag in lags]
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
    Gam = [psi[: N - lag].T @ psi[lag:] for lag in range(min(q, N - 1) + 1)]

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

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> Phi = rng.standard_normal((200, 2))
    >>> fit = solve_linear_regression(Phi @ [[2.0], [-1.0]], Phi)
    >>> np.allclose(fit.coefficients, [[2.0, -1.0]])
    True
    """
    Phi = as_signal(Phi, "Phi")
    N, n = Phi.shape
    Y = as_signal(Y, "Y", n_samples=N)
    if labels is not None and len(labels) != n:
        raise DataError(f"`labels` has {len(labels)} names for {n} regressors")
    if N <= n:
        raise DataError(f"`Phi` has {N} rows for {n} regressors; need more rows than regressors")
    s = _column_scale(Phi, "Phi", labels)
    Phi_s = Phi / s
    if instruments is None:
        estimator = "ls"
        Z_s = Phi_s
    else:
        Z = as_signal(instruments, "instruments", n_samples=N)
        if Z.shape[1] < n:
            raise DataError(
                f"`instruments` has {Z.shape[1]} columns; need at least {n} (one per regressor)"
            )
        Z_s = Z / _column_scale(Z, "instruments", None)
        estimator = "iv" if Z.shape[1] == n else "2sls"
    Q, _ = np.linalg.qr(Z_s)
    if estimator != "ls":
        # A rank-deficient Z would make Q's extra columns arbitrary; check Z first.
        sz = np.linalg.svd(Z_s, compute_uv=False)
        if sz[-1] <= sz[0] * max(Z_s.shape) * np.finfo(float).eps:
            raise IdentificationError(
                "the instruments are linearly dependent; remove redundant instruments"
            )
    M = Q.T @ Phi_s  # (nz, n); for LS this is R of Phi_s
    U, sv, Vt = np.linalg.svd(M, full_matrices=False)
    tol = sv[0] * max(N, n) * np.finfo(float).eps
    rank = int(np.sum(sv > tol))
    notes = []
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
            + (", with the instruments" if estimator != "ls" else "")
            + "): the data do not determine the coefficients. Collinear regressors: "
            + ", ".join(names)
            + ". Remove the duplicated regressor or excite the loop more richly"
        )
    # theta_s = M^+ Q^T Y; K = M^+ = V diag(1/s) U^T.
    K = (Vt.T / sv) @ U.T  # (n, nz)
    QtY = Q.T @ Y
    theta_s = K @ QtY  # (n, ny)
    theta = theta_s / s[:, None]
    residuals = np.asarray(Y) - Phi @ theta
    psi = Q @ K.T  # effective instruments (N, n)
    sigma_w = None
    if noise_ma is None:
        method = "hac"
        S, clipped = hac_covariance(residuals, psi, lags=hac_lags, kernel=kernel)
        if clipped:
            notes.append(
                f"the {kernel}-kernel covariance with {hac_lags} lags had negative "
                "eigenvalues (short record); they were set to zero"
            )
    else:
        method = "white-noise"
        S, sigma_w, clipped = white_noise_covariance(residuals, psi, noise_ma(theta.T))
        if clipped:
            notes.append(
                "the noise covariance fitted to the residual autocovariances was not positive "
                "semi-definite (the equation error may not be the assumed moving average of "
                "white measurement noise); its negative part was set to zero"
            )
    ny = Y.shape[1]
    d = np.tile(1.0 / s, ny)
    cov = S * d[:, None] * d[None, :]
    if sv[0] / sv[-1] > 1e10:
        notes.append(f"the regression is ill-conditioned (condition {sv[0] / sv[-1]:.2g})")
        logger.warning(notes[-1])
    return LinearFit(
        coefficients=theta.T,
        covariance=cov,
        residuals=residuals,
        rank=rank,
        singular_values=sv,
        estimator=estimator,
        hac_lags=int(hac_lags),
        kernel=kernel,
        notes=tuple(notes),
        covariance_method=method,
        noise_covariance=sigma_w,
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
