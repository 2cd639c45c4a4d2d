"""Closed-loop subspace identification: PBSID-opt and SSARX, from one VARX.

Open-loop subspace methods (:mod:`maglevid.identify.subspace`) are biased under
feedback: the future inputs are correlated with the past noise through the
controller. The predictor-based methods here are consistent whatever the
(causal, unknown) controller, because they only ever regress the output on the
*past* of ``z = [u, y]``, with which the innovation is uncorrelated.

Innovation form and its predictor (docs/subspace.md, eqs. (P1)-(P3))::

    x(t+1) = A x(t) + B u(t) + K e(t),    y(t) = C x(t) + D u(t) + e(t)       (P1)
    x(t+1) = Abar x(t) + Bbar u(t) + K y(t),  Abar = A - K C, Bbar = B - K D    (P2)
    x(t)   = Abar^p x(t-p) + sum_{k=1}^{p} Abar^{k-1} Btil z(t-k),  Btil = [Bbar, K]  (P3)

With ``Abar`` stable, ``Abar^p -> 0`` and the output obeys the VARX (P4)::

    y(t) = sum_{k=1}^{p} Xi_k z(t-k) + D u(t) + e(t),   Xi_k = C Abar^{k-1} Btil   (P4)

whose regressors are the past only: least squares is consistent in closed
loop. Both methods estimate (P4) once and differ in how they get the state:

* **PBSID-opt** (Chiuso 2007; van Wingerden & Verhaegen's optimised form):
  ``Gamma_f K_p`` is assembled from the VARX coefficients, block ``(i, c)``
  being ``Xi_{p+i-c}`` for ``c >= i`` and 0 otherwise (eq. (P5)); the SVD of
  ``Gamma_f K_p Z_p`` gives the order and the state sequence (eq. (P6)).
* **SSARX** (Jansson 2003): the VARX's predictor Markov parameters remove the
  effect of the future ``z`` from the future outputs, ``ytil_f = y_f - Htil_f
  z_f = Gamma_f x + e_f`` (eq. (P7)); ``ytil_f`` is regressed on the past and a
  canonical-correlation weighted SVD gives the state (eq. (P8)).

From the state sequence ``X``, ``[C D]`` and the innovations follow by least
squares on ``y(t)``, then ``[A B K]`` on ``x(t+1)`` (eq. (P9)): the model comes
with its Kalman gain, no Riccati equation is solved.

Data stage: everything above is a linear function of a window of ``w``
consecutive samples (``w = p + 1`` for PBSID-opt, ``p + f`` for SSARX), so the
fit needs only the Gram matrix of that window's Hankel rows, which the lagged
sums of :class:`~maglevid.identify._hankel._LagGram` give for a record of any
length in one pass (memory independent of ``N``); :class:`PredictorAccumulator`
is the streaming form. With ``remove_mean`` (the default) the Gram is centred
(regressions with an intercept), so constant offsets of ``y`` and ``u`` change
nothing.

Nothing here stabilises an estimate: an unstable plant gives an unstable model.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import scipy.linalg as sla
from scipy.linalg import lapack

from maglevid._validation import as_signal, check_positive
from maglevid.exceptions import DataError, IdentificationError, ModelError
from maglevid.identify._gram_operator import GramOperator, _window_sums
from maglevid.identify._hankel import _LagGram, factor_gram, lower_factor
from maglevid.identify._structured import (
    START_SAMPLES,
    StructuredFit,
    _zoh,
    fit_bearing_structure,
)
from maglevid.identify.options import Option, bind_defaults
from maglevid.identify.periodic import fit_without_lines
from maglevid.identify.physical import to_physical_coordinates
from maglevid.identify.result import IdentificationResult
from maglevid.identify.subspace import (
    _arx_horizon,
    _char_poly,
    _check_choice,
    _check_int,
    _check_rank_tol,
    _choose_order,
    _observability,
    _predictor_residuals,
    _regress,
    _Stats,
)
from maglevid.identify.uncertainty import (
    one_step_fit_percent,
    operating_point,
    with_physical_parameters,
)
from maglevid.lti import StateSpace, undiscretize
from maglevid.physics.amb import C_AMB, V_NAMES, amb_matrices, v_from_matrices

__all__ = ["DEFAULT_MAX_PAST", "METHODS", "PredictorAccumulator", "fit_pbsid", "fit_ssarx"]

logger = logging.getLogger(__name__)

#: Largest past the automatic rule considers. The VARX truncation is
#: ``|lambda_max(A - K C)|^p``; the bearing's predictor has a pole at ~0.98 and
#: p = 40 leaves v5/v7 3-5 % off at N >= 1e5, p = 80 0.7-2 % (docs/subspace.md).
#: PBSID-opt accumulates p lags, as many as MOESP at horizon 40.
DEFAULT_MAX_PAST = 80
#: Default future of SSARX: ``min(p, 40)`` (its Hankel window is ``p + f``).
_SSARX_FUTURE = 40

_ALGORITHMS = ("pbsid", "ssarx")
_WEIGHTINGS = ("cca", "none")
_COORDINATES = ("identified", "physical")
_PHYSICAL_FITS = ("transform", "structured")
#: Lags a stream keeps for the structured fit when not told (the in-memory cap
#: ``_structure_cap`` at N = 1e6): the window itself is chosen from the data,
#: (P16), up to the lags kept. docs/subspace.md, "Structured fit".
DEFAULT_STRUCTURE_PAST = 460
#: The structured fit's window grows like log N (P16): ``P = ln N / (-2 ln rho)``
#: with ``rho`` the transform's predictor spectral radius (the truncation
#: ``rho^P`` then falls like the standard error, ``N^{-1/2}``). The lags
#: accumulated before ``rho`` is known are those of this design radius (the
#: bearing's predictor: 0.983 on both simulated records); a slower predictor
#: gets the cap and a note.
_STRUCTURE_RHO = 0.985
#: The gain in ``j J`` (``N log det``, twice a log-likelihood) a structured fit that hit
#: its step limit may still predict and be kept, with a note: 1 is a step of about a
#: standard error (issue 16, twelfth session: one of 400 Monte Carlo fits at 1e4 stops
#: there); beyond it, or without a descent, the fit is refused (_structure_failure).
_STRUCTURE_LEFT = 1.0
#: Shortest automatic window of the structured fit.
_STRUCTURE_MIN = 40
#: (P23) Where the window-start state is left at 0 (P17), the automatic window is made
#: long enough that the term it drops, ``C Abar^P x(t-P)`` (RMS ~ ``rho^P`` times the
#: outputs'), is at most this fraction of the innovations' RMS (it then adds at most
#: 0.25 % to the residual variance), up to the lags of the design radius: (P16)'s
#: ``rho^P = N^{-1/2}`` left it at 6-28 % below N = 1e5 (SNR ~ 20), where the realistic
#: bearing's records at N = 4000 read v1..v9 up to 2.9x ML's errors (30 records), 1.9x
#: with it (100 records; docs/subspace.md, "The window's dropped term (P23)").
_STRUCTURE_DROPPED = 0.05
#: Relative singular-value floor of the order choice (Gram route, as MOESP's).
_DEFAULT_RANK_TOL = 1e-6
#: A gap ``s_n / s_{n+1}`` at least this large decides the automatic order; below it
#: (no clear gap: real rigs' singular values decay smoothly, the largest ratio lands
#: anywhere, e.g. order 44 at 1.38 on the UAQ levitator's step record) the order is
#: the one whose own one-step predictor has the smallest BIC (:func:`_order_by_bic`).
_CLEAR_GAP = 10.0
#: Orders the BIC compares (1..this, at most ``f ny``): a model's predictor is run
#: over the record for each.
_BIC_ORDERS = 20
#: ``options["order_rule"]`` of each way the order is set (``"auto"``: the gap, as MOESP's).
_ORDER_RULES = {"given": "given", "gap": "auto", "bic": "auto-bic", "structure": "structure"}
#: The order of ``coordinates="physical"`` when not given: eq. (4)'s states x, dx/dt, i1, i2.
_BEARING_ORDER = 4
#: Relative rank threshold of the least-squares steps.
_RCOND = 1e-10
#: The normal equations are used while the Cholesky diagonal spans less than this.
_CHOL_SPAN = 1e6
#: CCA weighting needs the corrected future's covariance resolved to this ratio.
_CCA_FLOOR = 1e-8
#: Vectors beyond the ``n`` wanted in :func:`_leading_eigenvectors`' block, and the most
#: iterations it takes before ``syevr`` is cheaper (~0.08 ms an iteration at 219 rows,
#: ``syevr`` ~1.5-2 ms there).
_SUBSPACE_EXTRA = 4
_SUBSPACE_STEPS = 8
#: Smallest ``(s_r / s_1)^2`` for which :class:`_LeftSVD` takes a bounded matrix's values
#: from the eigenvalues of ``P P^T`` (``s_r / s_1 >= 1e-3``).
_GRAM_SVD_SPAN = 1e-6
#: Samples per chunk of the in-memory pass over the lagged products (rounded to a
#: whole number of the accumulator's groups); docs/subspace.md, "Speed of the
#: transform path".
_PASS_CHUNK = 1 << 18
#: Records longer than this feed the lag pass with u and y apart (``update_split``).
_SPLIT_MIN = 1 << 18
#: The in-memory structured fit's lagged products are taken by FFT
#: (``_LagGram.load_fft``) from this many lags up: measured 7x (100 lags, N = 2e4)
#: to 40x (305 lags, 1e4) faster than the direct sums, equal to 2e-15 relative.
_FFT_MIN_LAGS = 100
#: The automatic past keeps at least this many Hankel rows per column.
_ROWS_PER_COLUMN = 5
#: Entries of one slab of :func:`_normalise` (256 kB of temporaries).
_NORMALISE_SLAB = 1 << 15


# ----------------------------------------------------------------- data stage
def _window_stats(
    acc: _LagGram,
    nu: int,
    ny: int,
    w: int,
    shift: np.ndarray,
    center: bool,
    blocks: int | None = None,
) -> _Stats:
    """Scaled, normalised factor of the Hankel rows of window ``w`` (centred if asked).

    ``blocks``: only the rows of ``z(0..blocks-1)`` (the Gram's leading block,
    still over the window's ``N - w + 1`` Hankel rows): what the VARX reads (the
    structured fit reads the window's Gram as an operator, :class:`_WindowGram`).

    Centring: with ``s_a = sum_t z(t+a)`` the column sums of the Hankel rows, the
    Gram of the rows less their means is ``G - s s^T / j``; ``s_a`` is the total
    less the first ``a`` and the last ``w - 1 - a`` samples (head and tail kept).
    """
    N = acc.n
    j = N - w + 1
    k = w if blocks is None else blocks
    mean = acc.moments.mean()
    var = acc.moments.sumsq / N - (mean**2 if center else 0.0)
    scale = np.sqrt(np.maximum(var, 0.0))
    zero = np.flatnonzero(scale <= 1e-12 * (np.abs(mean + shift) + 1e-300))
    if zero.size:
        c = int(zero[0])
        name = f"u[:, {c}]" if c < nu else f"y[:, {c - nu}]"
        raise DataError(
            f"`{name}` is constant; every input must excite the system and every output "
            "must be measured"
        )
    s = _window_sums(acc, w, k) if center else None  # s_a, a < k
    d = np.tile(1.0 / scale, k)

    def gram() -> np.ndarray:  # made again where the in-place Cholesky did not hold
        G = acc.gram(w, k)
        _normalise(G, s, d, j)
        return G

    F, rank = _factor(gram(), gram)
    return _Stats(
        F=F,
        nu=nu,
        ny=ny,
        i_rows=w // 2,
        j=j,
        n_samples=N,
        scale=scale,
        mean=mean + shift,
        rank=rank,
        factorization="gram",
    )


def _normalise(G: np.ndarray, s: np.ndarray | None, d: np.ndarray, j: int) -> None:
    """``G <- ((G - s s^T / j) * d d^T) / j`` in place (``s`` None: not centred).

    In slabs of rows, so that the two outer products are cache-sized temporaries:
    three passes over the whole Gram and two fresh ``(w m)^2`` temporaries were
    9-18 ms of the default fit's 1075-1530-row window at N = 1e4 (each fresh
    temporary ~0.1 s of page faults at ``w m = 2290``). The same operations on
    every entry, in the same order: the same numbers.
    """
    rows = max(1, _NORMALISE_SLAB // max(G.shape[1], 1))
    for r0 in range(0, G.shape[0], rows):
        g = G[r0 : r0 + rows]
        if s is not None:
            t = np.multiply.outer(s[r0 : r0 + rows], s)
            t /= j
            g -= t
        g *= np.multiply.outer(d[r0 : r0 + rows], d)
        g /= j


def _factor(
    G: np.ndarray, rebuild: Callable[[], np.ndarray] | None = None
) -> tuple[np.ndarray, int]:
    """``(F, rank)``, ``F F^T = G``: plain Cholesky (LAPACK ``dpotrf``) when ``G`` is
    well conditioned, else :func:`~maglevid.identify._hankel.factor_gram`'s pivoted one.

    With ``rebuild`` (a function making ``G`` again) the plain factor is taken in
    ``G``'s own memory (``G`` symmetric: its transpose is the same matrix in Fortran
    order, whose upper factor ``U``, ``U^T U = G``, read back in C order is ``L``): no
    second array of the Gram's size, which was page-faulted in at every fit (~700
    pages for SSARX's 600-row window at N = 1e4, ~2.8 us each on the benchmark's KVM
    guest; twenty-ninth session). The factor equals ``dpotrf``'s lower one to
    rounding (1e-16 measured). Where the plain factor does not hold, ``G`` is gone:
    ``rebuild()`` makes it again for the pivoted one (noise-free records).

    On a noisy record the Gram of the channel-scaled window is positive definite
    with a condition far below ``1 / eps``: the unpivoted factor is exact to
    rounding and 2-10x faster than ``dpstrf`` (405-2300 rows; docs/subspace.md,
    "Speed"). Every later step uses only products ``F_a F_b^T`` or orthogonal
    factorisations of rows of ``F``, unchanged by ``F -> F Q``. A noise-free
    (rank-deficient) or nearly so record -- the Cholesky diagonal spanning more
    than ``_CHOL_SPAN`` (condition above ~1e12) -- takes the pivoted factor and its rank.
    """
    if rebuild is None:
        c, info = lapack.dpotrf(G, lower=1, clean=1, overwrite_a=0)
    else:
        c, info = lapack.dpotrf(G.T, lower=0, clean=1, overwrite_a=1)
        c = c.T  # G's memory, C order: L
    if info == 0:
        dg = np.abs(np.diag(c))
        if dg.size and dg.min() > dg.max() / _CHOL_SPAN:
            return c, G.shape[0]
    return factor_gram(G if rebuild is None else rebuild())


def _leading(F: np.ndarray, rows: int) -> np.ndarray:
    """``F[:rows]``, only its first ``rows`` columns when the rest are zero.

    The factor of :func:`_factor`'s Cholesky path is lower triangular: the rows of
    ``z(0..w-1)`` live in its first ``w m`` columns, and every product and
    factorisation of them (the VARX, SSARX's regression (P7), the AIC, the SVD)
    is the same on those columns alone -- on the 600-column factor of SSARX's
    default window, 120-405 rows cost a fraction of the width.
    """
    X = F[:rows]
    if X.shape[1] > rows and not np.any(X[:, rows:]):
        return X[:, :rows]
    return X


def _lower(Y: np.ndarray) -> np.ndarray:
    """``L`` with ``L L^T = Y Y^T``: Cholesky of the product when well conditioned (the
    diagonal spanning less than ``_CHOL_SPAN``; ~10x faster than a QR of ``Y^T``),
    else :func:`~maglevid.identify._hankel.lower_factor`'s QR."""
    if Y.shape[1] >= Y.shape[0]:
        c, info = lapack.dpotrf(Y @ Y.T, lower=1, clean=1)
        dg = np.abs(np.diag(c))
        if info == 0 and dg.size and dg.min() > dg.max() / _CHOL_SPAN:
            return c
    return lower_factor(Y)


def _z_rows(st: _Stats, t0: int, t1: int) -> slice:
    """Rows of ``z(t0..t1-1)`` (time-major ``[u, y]``): a slice, so that ``st.F[...]`` is
    a view (an index array copied the rows: 1.2-1.8 MB a fit at N = 1e4, page-faulted in
    afresh each time; twenty-ninth session)."""
    m = st.m
    return slice(t0 * m, t1 * m)


# ------------------------------------------------------------- the algorithms
def _varx(st: _Stats, p: int, feedthrough: bool) -> tuple[np.ndarray, np.ndarray]:
    """VARX (P4): coefficients ``V`` (ny x p m) on ``z(t-p..t-1)`` (oldest first) and ``D``.

    Without feedthrough, on the Cholesky factor's rows (square lower triangular,
    :func:`_leading`), ``V = F_y L_p^{-1}`` by one triangular solve
    (:func:`_cholesky_solver`, as SSARX's regression): 4-5 ms less than the
    pivoted-QR least squares at p = 74 (PBSID-opt, N = 1e4), the same ``V`` to
    rounding on a well-conditioned factor; otherwise the pivoted QR.
    """
    ny, nu = st.ny, st.nu
    Zp = _leading(st.F, p * st.m)
    solve = None if feedthrough or Zp.shape[0] != Zp.shape[1] else _cholesky_solver(Zp)
    if solve is not None:
        return solve(st.F[st.y_rows(p, p + 1)]), np.zeros((ny, nu))
    X = st.F[_z_rows(st, 0, p)]
    if feedthrough:
        X = np.concatenate([X, st.F[st.u_rows(p, p + 1)]])
    theta = _regress(st.F[st.y_rows(p, p + 1)], X, _RCOND)  # eq. (P4)
    V = theta[:, : p * st.m]
    D = theta[:, p * st.m :] if feedthrough else np.zeros((ny, nu))
    return V, D


def _gamma_k(V: np.ndarray, p: int, f: int, m: int) -> np.ndarray:
    """``Gamma_f K_p`` (f ny x p m) from the VARX, eq. (P5): block (i, c) = Xi_{p+i-c}."""
    ny = V.shape[0]
    GK = np.zeros((f * ny, p * m))
    for i in range(f):  # row i: C Abar^i K_p = [0 (i blocks), V[:, blocks 0..p-1-i]]
        GK[i * ny : (i + 1) * ny, i * m :] = V[:, : (p - i) * m]
    return GK


def _state_map_pbsid(st: _Stats, V: np.ndarray, p: int, f: int) -> tuple[_LeftSVD, np.ndarray]:
    """The SVD of ``Gamma_f K_p Z_p`` (values; leading left vectors on demand) and
    ``Gamma_f K_p`` (P6)."""
    GK = _gamma_k(V, p, f, st.m)
    return _LeftSVD(GK @ st.F[_z_rows(st, 0, p)]), GK  # Gamma_f K_p Z_p, the factor's basis


class _LeftSVD:
    """Singular values of a wide ``P`` (rows << columns) and, on demand, its leading
    left singular vectors.

    ``P^T = Q R`` first: ``P`` and the square ``R^T`` have the same ``U`` and ``s``,
    and the right singular vectors are never formed. The values by ``gesdd`` without
    vectors; the ``n`` leading vectors, once the order is chosen from the values, as
    the leading eigenvectors of ``R^T R = P P^T`` (``syevr`` on that subset only). Their
    error is ~``eps s_1^2 / (s_n^2 - s_{n+1}^2)``: ~3e-10 at the UAQ rig's marginal
    gap of 1.28 with ``s_1 / s_n`` 1e3. The full SVD with both vector sets was 6.4-10
    ms of the transform's ~12 (1e4, 198 rows), this 2.7-3.3 (docs/subspace.md,
    "eighth session"). A tall ``P`` takes the SVD. ``bounded`` (values known to lie
    within a few decades, SSARX's canonical correlations): values and vectors from
    the eigenvalues of ``P P^T`` where they do span less than 1e3 (:meth:`_from_gram`).
    """

    def __init__(self, P: np.ndarray, bounded: bool = False) -> None:
        self._U: np.ndarray | None = None
        self._R: np.ndarray | None = None
        if P.shape[0] >= P.shape[1]:
            self._U, self.s, _ = np.linalg.svd(P, full_matrices=False)
            return
        if bounded and self._from_gram(P):
            return
        self._R = sla.qr(P.T, mode="r", check_finite=False)[0][: P.shape[0]]
        self.s = sla.svd(self._R, compute_uv=False, check_finite=False)

    def _from_gram(self, P: np.ndarray) -> bool:
        """Values and left vectors from the eigenvalues of ``P P^T`` (one ``syevd``), where
        the squared values span less than ``1 / _GRAM_SVD_SPAN`` (the values 1e3): they
        lose ``eps / (s_i / s_1)^2`` of their digits, 1e-10 at most then. For values that
        whitening bounds (SSARX's CCA weighting: canonical correlations, 1 down to ~0.09 on
        the bench records) this is 1.2 ms against 2.7 for the QR, the SVD and the vectors (120 x
        365, paper-like record at 1e4; values equal to 3e-15 relative, projectors to
        1e-15; thirty-first session). False, and nothing kept, where they span more."""
        lam, U = sla.eigh(P @ P.T, driver="evd", check_finite=False)
        if not lam[-1] > 0.0 or lam[0] < _GRAM_SVD_SPAN * lam[-1]:
            return False
        self.s, self._U = np.sqrt(lam[::-1]), U[:, ::-1]
        return True

    def vectors(self, n: int) -> np.ndarray:
        """The ``n`` leading left singular vectors (columns), largest first.

        Where the values show a wide gap after the ``n``-th, by subspace iteration on
        ``R^T R`` (:func:`_leading_eigenvectors`); else, or where its Ritz residual is
        not at rounding level, the leading eigenvectors by ``syevr``.
        """
        if self._U is not None:
            return self._U[:, :n]
        R = self._R
        assert R is not None  # the QR route: no vectors yet
        U = _leading_eigenvectors(R, self.s, n)
        if U is not None:
            return U
        G = R.T @ R
        r = G.shape[0]
        _, V = sla.eigh(G, subset_by_index=[r - n, r - 1], check_finite=False)
        return V[:, ::-1]


def _leading_eigenvectors(R: np.ndarray, s: np.ndarray, n: int) -> np.ndarray | None:
    """The ``n`` leading eigenvectors of ``R^T R`` (``s``: ``R``'s singular values), by
    subspace iteration, or None where that would not be cheap and exact.

    A block of ``b = n + _SUBSPACE_EXTRA`` vectors, ``Z <- orth(R^T R Z)``, converges to the
    leading ``n`` as ``(s_{b+1} / s_n)^{2k}`` (Golub & Van Loan, section 8.2.4): the
    iterations to rounding are known from the values before the first. Then
    Rayleigh-Ritz on the block, and the Ritz residual checked against rounding of
    ``s_1^2`` (None, for ``syevr``, when it is not there). On the transform's SVD of a
    clear gap (the bearing's four states: ``s_5 / s_4`` ~ 6e-4) four iterations, 0.35 ms
    against ``syevr``'s 2.0 ms on ``R^T R`` (PBSID-opt's 219 rows at N = 1e4,
    thirty-first session); SSARX's CCA-weighted values (gap ~3.6) take ``syevr``.
    The eigenvectors' signs: the largest entry positive.
    """
    r = R.shape[0]
    b = n + _SUBSPACE_EXTRA
    if b >= r or not s[n - 1] > 0.0:
        return None
    ratio = (s[b] / s[n - 1]) ** 2
    if not ratio < 1.0:
        return None
    steps = 1 if ratio == 0.0 else math.ceil(math.log(np.finfo(float).eps / 16) / math.log(ratio))
    if steps > _SUBSPACE_STEPS:
        return None
    Z = np.random.default_rng(0).standard_normal((r, b))
    for _ in range(steps + 1):  # one more: a random start's share of the leading space
        Z = np.linalg.qr(R.T @ (R @ Z))[0]
    Y = R @ Z
    lam, W = np.linalg.eigh(Y.T @ Y)
    U = Z @ W[:, : b - n - 1 : -1]
    res = R.T @ (R @ U) - U * lam[: b - n - 1 : -1]
    if not np.max(np.abs(res)) <= 64 * np.finfo(float).eps * s[0] ** 2:
        return None
    k = np.argmax(np.abs(U), axis=0)
    return U * np.sign(U[k, np.arange(n)])


def _corrected_future(st: _Stats, V: np.ndarray, D: np.ndarray, p: int, f: int) -> np.ndarray:
    """``ytil_f = y_f - Htil_f z_f`` (f ny x r), eq. (P7): one product with the block-Toeplitz
    ``Htil_f`` (row block i: ``Xi_{i-c}`` on ``z(p+c)``, c < i, and ``D`` on ``u(p+i)``)."""
    ny, nu, m = st.ny, st.nu, st.m
    Zf = st.F[p * m : (p + f) * m]  # z(p..p+f-1), time-major: a view, no copy
    H = np.zeros((f, ny, f, m))
    for i in range(1, f):  # Xi_k is V's block p - k
        H[i, :, :i, :] = V[:, (p - i) * m :].reshape(ny, i, m)
    H[np.arange(f), :, np.arange(f), :nu] = D
    Yf = Zf.reshape(f, m, -1)[:, nu:, :].reshape(f * ny, -1)
    return Yf - H.reshape(f * ny, f * m) @ Zf


def _cholesky_solver(Zp: np.ndarray, triangular: bool | None = None):  # type: ignore[no-untyped-def]
    """``Y -> M`` of ``Y ~ M Zp`` by the normal equations; None if ``Zp Zp^T`` is ill-conditioned.
    ``triangular``: :func:`_is_triangular` of ``Zp`` when already known.

    The normal equations square the condition number: used only while the
    Cholesky diagonal spans less than ``_CHOL_SPAN`` (condition below 1e12 on
    unit-RMS channels), where they lose no more than the data's own precision.
    A square lower-triangular ``Zp`` (the leading rows of :func:`_factor`'s
    Cholesky factor, :func:`_leading`) is already the Cholesky factor of ``Zp Zp^T``
    (positive diagonal, unique): ``M = Y_k Zp^{-1}`` by one triangular solve, no
    product, no factorisation (a third of SSARX's regression at N = 1e4; the same
    ``M`` to rounding).
    """
    k = Zp.shape[1]  # Y's columns past Zp's are multiplied by Zp's zeros (_leading)
    if _is_triangular(Zp) if triangular is None else triangular:
        d = np.abs(np.diag(Zp))
        if not d.size or d.min() <= d.max() / _CHOL_SPAN:
            return None
        return lambda Y: _right_solve(Zp, Y[:, :k])
    try:
        c = sla.cho_factor(Zp @ Zp.T, lower=True, check_finite=False)
    except np.linalg.LinAlgError:
        return None
    d = np.abs(np.diag(c[0]))
    if not d.size or d.min() <= d.max() / _CHOL_SPAN:
        return None
    return lambda Y: sla.cho_solve(c, Zp @ Y[:, :k].T, check_finite=False).T


def _is_triangular(Zp: np.ndarray) -> bool:
    """Whether ``Zp`` is square and lower triangular (:func:`_factor`'s Cholesky rows)."""
    return Zp.shape[0] == Zp.shape[1] and not np.any(np.triu(Zp, 1))


def _right_solve(Zp: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """``Y Zp^{-1}`` for a square lower-triangular ``Zp``: one triangular solve."""
    return sla.solve_triangular(Zp, Y.T, lower=True, trans="T", check_finite=False).T


@dataclass(frozen=True)
class _RightSolved:
    """The state map ``Y Zp^{-1}`` (``Y``'s rows x ``Zp``'s), left unformed: its rows are
    only ever read through a few combinations (the ``n`` states' ``L``,
    :func:`_state_matrix`), each one solve of ``n`` rows instead of one of all of ``Y``'s."""

    Y: np.ndarray
    Zp: np.ndarray
    __array_ufunc__ = None  # ``A @ self`` with an ndarray ``A`` comes here

    def __rmatmul__(self, A: np.ndarray) -> np.ndarray:
        return _right_solve(self.Zp, A @ self.Y)


def _qr_solver(Zp: np.ndarray):  # type: ignore[no-untyped-def]
    """``Y -> M`` of ``Y ~ M Zp``: basic least-squares solution by pivoted QR."""
    Q, R, piv = sla.qr(Zp.T, mode="economic", pivoting=True, check_finite=False)
    d = np.abs(np.diag(R))
    q = int(np.count_nonzero(d > _RCOND * d[0])) if d.size and d[0] > 0 else 0

    def solve(Y: np.ndarray) -> np.ndarray:
        M = np.zeros((Y.shape[0], Zp.shape[0]))
        M[:, piv[:q]] = sla.solve_triangular(R[:q, :q], Q[:, :q].T @ Y[:, : Q.shape[0]].T).T
        return M

    return solve


def _ssarx_regression(
    st: _Stats, p: int, f: int, feedthrough: bool
) -> tuple[np.ndarray, np.ndarray, Any, np.ndarray]:
    """VARX (P4) and ``beta`` of ``ytil_f ~ beta Z_p`` (P7), one factorisation of ``Z_p``.

    The rows of ``Z_p`` are factored once and both regressions, the VARX's
    ``y(p)`` and the corrected future ``ytil_f`` (formed with the VARX's
    coefficients), are solved on it: by Cholesky of ``Z_p Z_p^T`` when that is
    well conditioned (a noisy record; 3-4x faster than the QR at 1e4 samples),
    else by pivoted QR (``Z_p^T P = Q R``, the basic solution of a rank-deficient,
    noise-free record). Where ``Z_p`` is the Cholesky factor's square lower-triangular
    rows, ``beta = ytil_f,k Z_p^{-1}`` is returned unformed (:class:`_RightSolved`):
    what (P8) factors, ``beta Z_p``, is then ``ytil_f``'s first columns themselves,
    and the states read ``beta`` through ``n`` rows only (thirtieth session: the solve
    and the product with ``Z_p`` of all ``f ny`` rows were 2.5 ms of a 50 ms SSARX
    fit at N = 1e4).
    """
    Zp = _leading(st.F, p * st.m)  # rows of z(0..p-1)
    triangular = _is_triangular(Zp)  # one check of the ~1 MB upper triangle, for both
    chol = _cholesky_solver(Zp, triangular)
    solve = chol or _qr_solver(Zp)
    if feedthrough:
        V, D = _varx(st, p, True)
    else:
        V, D = solve(st.F[st.y_rows(p, p + 1)]), np.zeros((st.ny, st.nu))
    Yt = _corrected_future(st, V, D, p, f)
    if chol is not None and triangular:
        return V, D, _RightSolved(Yt[:, : Zp.shape[1]], Zp), Yt
    return V, D, solve(Yt), Yt


def _state_map_ssarx(
    st: _Stats, p: int, f: int, feedthrough: bool, weighting: str, notes: list[str]
) -> tuple[_LeftSVD, Any]:
    """The weighted SVD of eq. (P8) (values; leading left vectors on demand) and ``W1 beta``
    (an array, or :class:`_RightSolved` unformed)."""
    _, _, beta, Yt = _ssarx_regression(st, p, f, feedthrough)  # ytil_f = Gamma_f K_p Z_p + e
    T = None  # W1 = T^{-1}, or none
    if weighting == "cca":
        T = _lower(Yt)  # T T^T = ytil_f ytil_f^T / j
        dT = np.abs(np.diag(T)) if T.shape[1] == T.shape[0] else np.zeros(1)
        if not dT.min() > _CCA_FLOOR * dT.max():
            T = None
            notes.append(
                "weighting='cca' needs the corrected future outputs to have a full-rank "
                "covariance, which noise-free data lack; the SVD was not weighted"
            )
    bounded = T is not None  # CCA-weighted values are canonical correlations, at most 1
    if isinstance(beta, _RightSolved):  # W1 beta Z_p = W1 ytil_f,k
        Y = beta.Y if T is None else sla.solve_triangular(T, beta.Y, lower=True)
        return _LeftSVD(Y, bounded=bounded), _RightSolved(Y, beta.Zp)
    W1beta = beta if T is None else sla.solve_triangular(T, beta, lower=True)
    return _LeftSVD(W1beta @ _leading(st.F, p * st.m), bounded=bounded), W1beta


def _order(s: np.ndarray, order: int | None, n_max: int, rank_tol: float) -> tuple[int, float]:
    if order is None:
        return _choose_order(s, n_max, rank_tol)
    if order > s.size or s[order - 1] <= 0.0:
        raise IdentificationError(
            f"order={order} exceeds the rank of the predictor data "
            f"({int(np.count_nonzero(s > 0))}); increase `past`/`future`"
        )
    gap = float(s[order - 1] / s[order]) if s.size > order and s[order] > 0 else float("inf")
    return order, gap


def _system_from_states(
    st: _Stats, L: np.ndarray, p: int, feedthrough: bool
) -> tuple[np.ndarray, ...]:
    """``[C D]`` from ``y(t)``, then ``[A B K]`` from ``x(t+1)``, eq. (P9) (scaled units)."""
    X = L @ st.F[_z_rows(st, 0, p)]  # x(t)   = L Z_p(t)
    Xn = L @ st.F[_z_rows(st, 1, p + 1)]  # x(t+1) = L Z_p(t+1)
    Ut = st.F[st.u_rows(p, p + 1)]
    Yt = st.F[st.y_rows(p, p + 1)]
    n = X.shape[0]
    if feedthrough:
        CD = _regress(Yt, np.concatenate([X, Ut]), _RCOND)
        C, D = CD[:, :n], CD[:, n:]
    else:
        C, D = _regress(Yt, X, _RCOND), np.zeros((st.ny, st.nu))
    E = Yt - C @ X - D @ Ut  # innovations e(t)
    ABK = _regress(Xn, np.concatenate([X, Ut, E]), _RCOND)
    A, B, K = ABK[:, :n], ABK[:, n : n + st.nu], ABK[:, n + st.nu :]
    Re = E @ E.T  # the factor is normalised: sample covariance
    return A, B, C, D, K, 0.5 * (Re + Re.T)


# ------------------------------------------------------------------- options
@dataclass(frozen=True)
class _Options:
    algorithm: str
    order: int | None
    past: int | None
    future: int | None
    max_past: int
    dt: float
    feedthrough: bool
    weighting: str
    rank_tol: float
    remove_mean: bool
    coordinates: str
    physical_fit: str = "transform"
    structure_past: int | None = None
    structure_auto: bool = False  # structure_past is then the cap of (P16)


def _options(algorithm: str, **kw: Any) -> _Options:
    rank_tol = _check_rank_tol(kw["rank_tol"])
    max_past = _check_int(kw["max_past"], "max_past", 1)
    return _Options(
        algorithm=_check_choice(algorithm, "algorithm", _ALGORITHMS),
        order=_check_int(kw["order"], "order", 1),
        past=_check_int(kw["past"], "past", 1),
        future=_check_int(kw["future"], "future", 1),
        max_past=DEFAULT_MAX_PAST if max_past is None else max_past,
        dt=check_positive(kw["dt"], "dt"),
        feedthrough=bool(kw["feedthrough"]),
        weighting=_check_choice(kw["weighting"], "weighting", _WEIGHTINGS),
        rank_tol=_DEFAULT_RANK_TOL if rank_tol is None else rank_tol,
        remove_mean=bool(kw["remove_mean"]),
        coordinates=_check_choice(kw["coordinates"], "coordinates", _COORDINATES),
        physical_fit=_physical_fit(kw.get("physical_fit"), kw["coordinates"]),
        structure_past=_check_int(kw.get("structure_past"), "structure_past", 1),
    )


def _physical_fit(physical_fit: str | None, coordinates: str) -> str:
    """As given; by default ``"structured"`` in physical coordinates (issue 16: closer
    to ML than the transform on every measured record), else ``"transform"``."""
    if physical_fit is None:
        return "structured" if coordinates == "physical" else "transform"
    return _check_choice(physical_fit, "physical_fit", _PHYSICAL_FITS)


def _resolve_structure(opt: _Options, N: int, m: int, lags: int | None = None) -> _Options:
    """The structured fit's window: as given, else ``DEFAULT_STRUCTURE_PAST``, within the record.

    The record's limit is the factor's (two Hankel rows per column of the
    window, :func:`_check_window`): the 21 parameters need no more rows per
    column. ``lags`` caps it at what a stream's accumulator kept.
    """
    if opt.physical_fit == "structured" and opt.coordinates != "physical":
        raise DataError(
            "physical_fit='structured' fits the bearing's v1..v9: it needs coordinates='physical'"
        )
    if opt.physical_fit != "structured":
        return replace(opt, structure_past=None)
    P = opt.structure_past
    if P is not None:
        return opt
    P = min(_structure_cap(N), (N + 1) // (1 + 2 * m) - 1)
    if lags is not None:
        P = min(P, lags)
    return replace(opt, structure_past=max(P, 1), structure_auto=True)


def _structure_cap(N: int) -> int:
    """Lags accumulated for the automatic window (P16) at the design radius."""
    return math.ceil(math.log(max(N, 2)) / (-2.0 * math.log(_STRUCTURE_RHO)))


def _start_samples(opt: _Options, rho: float, P: int, y_rms: np.ndarray, Re: np.ndarray) -> int:
    """Samples the window-start state is rebuilt from, (P14), or 0 (P17).

    With the window of (P16) the state is left at 0 unless the truncated term
    ``C Abar^P x(t-P)``, ~ ``rho^P`` times the outputs' RMS, would exceed the
    innovations (``rho^P max_i y_rms_i / sqrt(Re_ii) > 1``: a high-SNR record,
    where the noise-free rebuild is accurate); on a noisier record the rebuild's
    noise, correlated with the window's first regressors, biased v1..v3 by ~1e-3
    at N = 1e6 (docs/subspace.md). A given window keeps (P14).
    """
    if not opt.structure_auto:
        return START_SAMPLES
    return START_SAMPLES if rho**P * _snr(y_rms, Re) > 1.0 else 0


def _snr(y_rms: np.ndarray, Re: np.ndarray) -> float:
    """``max_i y_rms_i / sqrt(Re_ii)``: the outputs' RMS over the innovations'."""
    return float(np.max(y_rms / np.sqrt(np.maximum(np.diag(Re), 1e-300))))


def _structure_window(cap: int, N: int, rho: float, snr: float | None = None) -> int:
    """(P16): ``P = ln N / (-2 ln rho)``, between ``_STRUCTURE_MIN`` and ``cap``; with the
    outputs' ``snr`` (:func:`_snr`) and the start state left at 0 there (P17), (P23):
    at least ``ln(snr / _STRUCTURE_DROPPED) / (-ln rho)``, up to ``_structure_cap(N)``
    (the lags kept in memory: a stream, which keeps more, chooses the same window)."""
    if not 0.0 < rho < 1.0:
        return cap
    P = math.ceil(math.log(max(N, 2)) / (-2.0 * math.log(rho)))
    if snr is not None and rho**P * snr <= 1.0:
        dropped = math.ceil(math.log(snr / _STRUCTURE_DROPPED) / (-math.log(rho)))
        P = max(P, min(dropped, _structure_cap(N)))
    return max(min(P, cap), min(_STRUCTURE_MIN, cap))


def _structure_lags(opt: _Options) -> int:
    """Lags of the structured fit's window (0 when it does not run)."""
    return opt.structure_past or 0


def _window(opt: _Options, p: int, f: int) -> int:
    """Samples per Hankel row: ``p + 1`` (PBSID-opt) or ``p + f`` (SSARX, at least p + 1)."""
    return p + 1 if opt.algorithm == "pbsid" else p + max(f, 1)


def _plan(N: int, m: int, ny: int, opt: _Options) -> tuple[int, int]:
    """``(p_top, lags)``: largest past the fit may choose and the lags to accumulate."""
    if opt.past is not None:
        p_top = opt.past
    else:
        p_top = int(min(opt.max_past, (N + 1) // (2 + 2 * _ROWS_PER_COLUMN * m)))
        need = max(2, _min_past(opt.order, ny))
        if p_top < need:
            # A past of one lag cannot hold a predictor of a dynamic loop: the record is
            # too short for the VARX at the rows per coefficient it needs.
            raise DataError(
                f"the record has {N} samples: too few for a VARX past of {need} lags on "
                f"{m} channels ({_ROWS_PER_COLUMN} rows per coefficient needs at least "
                f"{need * (2 + 2 * _ROWS_PER_COLUMN * m) - 1}); record longer, or pass `past`"
            )
    lags = _window(opt, p_top, _future(opt.algorithm, opt.future, p_top)) - 1
    return p_top, max(lags, _structure_lags(opt))


def _future(algorithm: str, future: int | None, p: int) -> int:
    """The future ``f``: as given, else ``p`` (PBSID-opt) or ``min(p, 40)`` (SSARX)."""
    if future is not None:
        return future
    return p if algorithm == "pbsid" else min(p, _SSARX_FUTURE)


def _min_past(order: int | None, ny: int) -> int:
    # f ny >= n with f = p by default: Gamma_f must have full column rank.
    return 1 if order is None else max(1, math.ceil(order / ny))


# ---------------------------------------------------------------- the driver
def _check_window(N: int, m: int, opt: _Options, p_top: int) -> int:
    """Samples per Hankel row of the widest window the fit may use (MOESP's rows)."""
    if opt.future is not None and opt.past is not None and opt.future > opt.past:
        raise DataError(f"`future`={opt.future} may not exceed `past`={opt.past}")
    W = max(
        _window(opt, p_top, _future(opt.algorithm, opt.future, p_top)), _structure_lags(opt) + 1
    )
    if N - W + 1 < 2 * W * m:
        raise DataError(
            f"the record has {N} samples; past={max(p_top, W - 1)} needs at least "
            f"{2 * W * m + W - 1} (2 x {W * m} Hankel columns)"
        )
    return W


def _choose_past(
    st_all: _Stats, opt: _Options, p_top: int, notes: list[str], extras: dict[str, Any]
) -> tuple[int, int, str]:
    """``(p, f, rule)``: the VARX order (given, or AIC up to ``p_top``) and the future."""
    if opt.past is not None:
        p, rule = opt.past, "given"
    else:
        lead = replace(st_all, F=_leading(st_all.F, (p_top + 1) * st_all.m))
        p_hat, aic = _arx_horizon(lead, p_top, opt.feedthrough)
        p, rule = max(p_hat, _min_past(opt.order, st_all.ny)), "auto"
        extras["varx_aic"] = aic
        notes.append(f"past {p} chosen automatically: VARX order by AIC over 1..{p_top}")
        if p_hat >= p_top:
            notes.append(
                f"the VARX order hit its upper limit {p_top}: the predictor may need a longer "
                "past than the record allows (pass past= or a longer record)"
            )
    f = _future(opt.algorithm, opt.future, p)
    if f > p:
        raise DataError(f"`future`={f} may not exceed `past`={p} (the VARX has p lags)")
    if opt.order is not None and opt.order > f * st_all.ny:
        raise DataError(
            f"`order`={opt.order} exceeds future * ny = {f * st_all.ny}; increase `future`/`past`"
        )
    return p, f, rule


def _identify_states(
    st: _Stats,
    opt: _Options,
    p: int,
    f: int,
    notes: list[str],
    data: tuple[np.ndarray, np.ndarray] | None = None,
    extras: dict[str, Any] | None = None,
) -> tuple[tuple[np.ndarray, ...], np.ndarray, int, float, str]:
    """VARX (P4), state sequence (P5)-(P8), order, ``(A, B, C, D, K, Re)`` (P9), scaled,
    and how the order was set (a key of ``_ORDER_RULES``).

    The automatic order is the largest gap of the singular values when it is clear
    (``_CLEAR_GAP``); otherwise, with the record in memory (``data``), the order of
    smallest BIC of the model's own one-step prediction errors (:func:`_order_by_bic`,
    its table in ``extras["order_bic"]``).
    """
    if opt.algorithm == "pbsid":
        V, _ = _varx(st, p, opt.feedthrough)
        svd, GK = _state_map_pbsid(st, V, p, f)
    else:
        svd, GK = _state_map_ssarx(st, p, f, opt.feedthrough, opt.weighting, notes)
    s = svd.s
    if opt.order is None and opt.coordinates == "physical":  # the bearing's 4 states
        n, gap = _order(s, _BEARING_ORDER, f * st.ny, opt.rank_tol)
        rule = "structure"
        notes.append(
            f"order {n}: the two-coil bearing's states (coordinates='physical'; "
            f"s_{n}/s_{n + 1} = {gap:.3g})"
        )
    else:
        n, gap = _order(s, opt.order, f * st.ny, opt.rank_tol)
        rule = "given" if opt.order is not None else "gap"
    system = None
    if rule == "gap" and gap < _CLEAR_GAP and data is not None:
        n_bic, bic, best = _order_by_bic(st, svd, GK, p, opt, data, min(f * st.ny, _BIC_ORDERS))
        if extras is not None:
            extras["order_bic"] = bic
        if n_bic:
            notes.append(
                f"order {n_bic} chosen automatically: no clear gap of the singular values "
                f"(the largest, s_{n}/s_{n + 1} = {gap:.3g}, is below {_CLEAR_GAP:g}), so "
                f"the order of smallest BIC of the model's one-step prediction errors "
                f"over 1..{bic.size} (stable predictors; `order_bic` in the extras); "
                "pass `order=` to override"
            )
            n, rule, system = n_bic, "bic", best
            gap = float(s[n - 1] / s[n]) if s.size > n and s[n] > 0 else float("inf")
    if system is None:
        system = _system_from_states(st, _state_matrix(svd, GK, n), p, opt.feedthrough)  # (P9)
    if rule == "gap":
        notes.append(
            f"order {n} chosen automatically: largest gap of the singular values "
            f"(s_{n}/s_{n + 1} = {gap:.3g}, values below {opt.rank_tol:.1e} x s_1 floored)"
        )
        if gap < _CLEAR_GAP:
            notes.append(
                f"order choice is marginal (gap ratio {gap:.3g} < {_CLEAR_GAP:g}); inspect "
                "`singular_values` and pass `order=` explicitly"
            )
    return system, s, n, gap, rule


def _state_matrix(svd: _LeftSVD, GK: Any, n: int, U: np.ndarray | None = None):  # type: ignore[no-untyped-def]
    """``L`` of ``X = L Z_p = S^{-1/2} U^T (Gamma K) Z_p`` for order ``n`` (``U``: the
    leading left vectors when already at hand, at least ``n`` of them)."""
    U = svd.vectors(n) if U is None else U[:, :n]
    return (U / np.sqrt(svd.s[:n])[None, :]).T @ GK


def _order_by_bic(  # type: ignore[no-untyped-def]
    st: _Stats, svd: _LeftSVD, GK: np.ndarray, p: int, opt: _Options, data, n_top: int
) -> tuple[int, np.ndarray, tuple[np.ndarray, ...] | None]:
    """``(order, BIC per order 1..n_top, that order's system (P9))``: each order's model
    run as its own
    steady-state predictor over the record (x_hat(0) = 0, the first ``p`` errors left
    out for every order alike), (P20) ``BIC(n) = N' log det Sigma_n + n (2 ny + nu) log N'``
    (Schwarz 1978; ``n (2 ny + nu)`` the innovation form's parameters beyond a basis,
    ``Sigma_n`` in the scaled units). A predictor that is not stable gets ``inf``; order 0
    (and no system) when none is.

    Why not the singular values alone: without a clear gap their largest ratio is a
    coin toss among dozens of orders, and a large order's model need not predict
    well (the UAQ levitator's step record: order 44 by the gap, one-step fit -54 %;
    order 3 fits 69 %, docs/subspace.md "Automatic order without a clear gap").
    """
    y, u = data
    nu, ny = st.nu, st.ny
    n_top = int(min(n_top, np.count_nonzero(svd.s > opt.rank_tol * svd.s[0])))
    mean = (st.mean[:nu], st.mean[nu:]) if opt.remove_mean else None
    U = svd.vectors(n_top)
    bic = np.full(n_top, np.inf)
    best = None
    N = y.shape[0] - p
    for n in range(1, n_top + 1):
        system = _system_from_states(st, _state_matrix(svd, GK, n, U), p, opt.feedthrough)
        model, K, _ = _unscale(system, st.scale, nu, opt.dt)
        if not np.max(np.abs(np.linalg.eigvals(model.A - K @ model.C))) < 1.0:
            continue
        E = _predictor_residuals(model, K, y, u, mean)[p:] / st.scale[nu:]
        sign, logdet = np.linalg.slogdet(E.T @ E / N)
        if sign > 0:
            b = N * logdet + n * (2 * ny + nu) * np.log(N)
            if b < np.min(bic):  # the first minimum, as argmin's
                best = system
            bic[n - 1] = b
    return (int(np.argmin(bic)) + 1 if best is not None else 0), bic, best


def _unscale(
    system: tuple[np.ndarray, ...], scale: np.ndarray, nu: int, dt: float
) -> tuple[StateSpace, np.ndarray, np.ndarray]:
    """Model, Kalman gain and innovation covariance in physical units (``z_s = z / scale``)."""
    As, Bs, Cs, Dn, Ks, Re = system
    s_u, s_y = scale[:nu], scale[nu:]
    model = StateSpace(
        As, Bs / s_u[None, :], Cs * s_y[:, None], (Dn * s_y[:, None]) / s_u[None, :], dt
    )
    return model, Ks / s_y[None, :], Re * np.outer(s_y, s_y)


def _coordinates(
    model: StateSpace,
    K: np.ndarray,
    Re: np.ndarray,
    gram: _WindowGram,
    opt: _Options,
    notes: list[str],
    extras: dict[str, Any],
) -> tuple[StateSpace, StateSpace | None, np.ndarray, np.ndarray, dict[str, float]]:
    """``(model, continuous, K, Re, parameters)`` in the coordinates asked for."""
    params: dict[str, float] = {}
    continuous = None
    if opt.coordinates == "physical":
        model, continuous, K, v = _bearing_coordinates(model, K)
        if opt.physical_fit == "structured":
            model, continuous, K, Re, v = _structured(model, K, Re, v, gram, opt, notes, extras)
        params.update(zip(V_NAMES, v.tolist()))
    else:
        try:
            continuous = undiscretize(model)
        except ModelError as exc:
            notes.append(f"no continuous-time model: {exc}")
    params.update({f"a{k + 1}": float(v) for k, v in enumerate(_char_poly(model.A))})
    return model, continuous, K, Re, params


@dataclass(frozen=True)
class _WindowGram:
    """The Gram of the Hankel rows of a window of ``k`` samples (``N - k + 1`` rows), as
    an operator (P18), on call.

    The structured fit's own window: its rows, not those of the widest window the VARX
    reads (``N - W + 1``), so that its FFT needs ``2k`` points instead of ``W + k``
    (540 -> 432-480 at N = 1e4 on the bench records: 8-12 % of the whole fit; the
    criterion over the 60-90 more rows moved v1..v9 by 0.01-0.16 standard errors;
    docs/subspace.md, "ninth session").
    """

    acc: _LagGram
    scale: np.ndarray
    center: bool

    @property
    def n_samples(self) -> int:
        return self.acc.n

    def __call__(self, k: int) -> GramOperator:
        return GramOperator(self.acc, k, k, self.scale, self.center)


def _structured(
    model: StateSpace,
    K: np.ndarray,
    Re: np.ndarray,
    v: np.ndarray,
    gram: _WindowGram,
    opt: _Options,
    notes: list[str],
    extras: dict[str, Any],
) -> tuple[StateSpace, StateSpace, np.ndarray, np.ndarray, np.ndarray]:
    """v1..v9, ``K`` and cov(v) by the structured weighted least-squares fit (P11)-(P18).

    ``gram(k)``: the Gram of the Hankel rows of ``k`` samples as an operator (P18),
    never formed: the fit reads it only through products, by FFT
    (docs/subspace.md, "seventh session").
    """
    P = _structure_lags(opt)
    rho = float(np.max(np.abs(np.linalg.eigvals(model.A - K @ model.C))))
    snr = _snr(gram.scale[2:], Re)
    if opt.structure_auto:
        P = _structure_window(P, gram.n_samples, rho, snr)
        if P == _structure_lags(opt) and rho >= _STRUCTURE_RHO:
            notes.append(
                f"the transform's predictor has spectral radius {rho:.4f}: the structured "
                f"fit's window {P} (the lags kept) leaves a truncation of {rho**P:.1e} "
                "(pass structure_past for a longer one)"
            )
    G = gram(P + 1)
    try:
        sf = fit_bearing_structure(
            G,
            v0=v,
            K0=K,
            dt=opt.dt,
            scale=gram.scale,
            j=G.j,
            initial_state=_start_samples(opt, rho, P, gram.scale[2:], Re),
        )
    except np.linalg.LinAlgError as exc:
        raise IdentificationError(_structure_failure(f"failed ({exc})", rho)) from exc
    _check_structure(sf, rho, notes)
    notes.append(
        f"v1..v9 by the structured weighted least-squares fit over a window of {P} lags "
        f"({'chosen from the data, (P16) and (P23)' if opt.structure_auto else 'given'}; "
        f"docs/subspace.md (P11)-(P16); {_steps(sf.iterations)}, window-start "
        f"state from {sf.start_samples} samples), started from the transform to "
        "physical coordinates"
    )
    extras.update(
        structure_lags=P,
        structure_iterations=sf.iterations,
        structure_start_samples=sf.start_samples,
        structure_covariance=sf.covariance,
        structure_predictor_radius=rho,
        # the RMS of the term the window drops, C Abar^P x(t-P), over the innovations'
        # (P17, P23; when the start state is rebuilt, what the rebuild takes out)
        structure_dropped=rho**P * snr,
    )
    disc = StateSpace(sf.Ad, sf.Bd, C_AMB.copy(), np.zeros((3, 2)), opt.dt)
    Ac, Bc = amb_matrices(sf.v)
    cont = StateSpace(Ac, Bc, C_AMB.copy(), np.zeros((3, 2)))
    return disc, cont, sf.K, sf.Re, sf.v


def _check_structure(sf: StructuredFit, rho: float, notes: list[str]) -> None:
    """Refuse a structured fit whose predictor is unstable or that stopped at its step
    limit more than ``_STRUCTURE_LEFT`` from its optimum (or without a descent); note one
    that stopped there closer. ``rho``: the start's predictor radius, for the message."""
    rho_fit = float(np.max(np.abs(np.linalg.eigvals(sf.Ad - sf.K @ C_AMB))))
    if not rho_fit < 1.0:
        why = f"ends on an unstable predictor (spectral radius {rho_fit:.4f})"
        raise IdentificationError(_structure_failure(why, rho))
    if sf.remaining > _STRUCTURE_LEFT:
        why = (
            f"stopped after {_steps(sf.iterations)} "
            + ("without a descent" if np.isinf(sf.remaining) else
               f"with a gain of {sf.remaining:.3g} in N log det still predicted")
        )  # fmt: skip
        raise IdentificationError(_structure_failure(why, rho))
    if sf.remaining > 0.0:
        notes.append(
            f"the structured fit stopped at its step limit ({_steps(sf.iterations)}) with "
            f"a gain of {sf.remaining:.2g} in N log det still predicted (below "
            f"{_STRUCTURE_LEFT:g}: within about a standard error of its optimum)"
        )


def _steps(n: int) -> str:
    """``"1 Gauss-Newton step"``, ``"n Gauss-Newton steps"``."""
    return f"{n} Gauss-Newton step" + ("" if n == 1 else "s")


def _structure_failure(why: str, rho: float) -> str:
    """Why the structured fit gives no v1..v9 here, what it started from, what to do.

    Refused rather than reported: an estimate that did not converge, or whose
    predictor is unstable, comes with intervals that mean nothing, and a diagnosis
    read it as a change in every parameter (a record with 20x the default sensor
    noise: docs/subspace.md, "twelfth session")."""
    start = (
        f"its start, the transform of the black-box model, has a predictor of spectral "
        f"radius {rho:.4f}"
    )
    if rho >= 1.0:
        start += " (not stable: the VARX past is too short for this record's predictor)"
    return (
        f"the structured fit of v1..v9 {why}; {start}. PBSID-opt and SSARX need a past "
        "longer than the closed-loop predictor's memory (slow with high sensor noise or "
        "little excitation): use method 'ml' (maximum likelihood through the Kalman "
        "predictor), or a longer record, more excitation or a larger max_past"
    )


def _fit_metrics(
    st: _Stats,
    model: StateSpace,
    K: np.ndarray,
    Re_s: np.ndarray,
    p: int,
    center: bool,
    data: tuple[np.ndarray, np.ndarray] | None,
    rho: float,
) -> tuple[dict[str, float], np.ndarray | None]:
    """One-step fit over the record (in memory) and the horizon predictor's fit (P9)."""
    nu = st.nu
    fit: dict[str, float] = {}
    residuals = None
    mean_u, mean_y = st.mean[:nu], st.mean[nu:]
    if data is not None and rho < 1.0:
        y, u = data
        # centred chunk by chunk, and the output's sum of squares about its mean from
        # the pass's moments (N var, as the scale): no centred copy of the record
        # (two copies and a pass were ~15 % of a fit at 1e6)
        residuals = _predictor_residuals(model, K, y, u, (mean_u, mean_y) if center else None)
        if center:
            sq_y = st.n_samples * st.scale[nu:] ** 2
        else:
            yc = y - y.mean(axis=0)
            sq_y = np.einsum("ij,ij->j", yc, yc)
        pct = one_step_fit_percent(np.einsum("ij,ij->j", residuals, residuals), sq_y)
        fit["one_step_fit_percent"] = float(np.mean(pct))
    # Fit of y(t) from the state of the last p samples, over the Hankel rows
    # (scaled units; the second moment less the mean unless the rows are centred).
    Fy = st.F[st.y_rows(p, p + 1)]
    var_y = np.einsum("ij,ij->i", Fy, Fy) - (0.0 if center else (mean_y / st.scale[nu:]) ** 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        hfit = 100.0 * (1.0 - np.sqrt(np.diag(Re_s) / np.maximum(var_y, 0.0)))
    fit["horizon_predictor_fit_percent"] = float(np.mean(hfit))
    return fit, residuals


def _stability_notes(model: StateSpace, K: np.ndarray, notes: list[str]) -> float:
    rho = float(np.max(np.abs(np.linalg.eigvals(model.A - K @ model.C)))) if model.nx else 0.0
    if not rho < 1.0:
        notes.append(f"the identified predictor A - K C is not stable (spectral radius {rho:.4g})")
    if not model.is_stable():
        notes.append(
            "the model is unstable (poles outside the unit circle); it is reported as found"
        )
    return rho


def _options_used(
    opt: _Options,
    n: int,
    order_rule: str,
    p: int,
    f: int,
    past_rule: str,
    extras: dict[str, Any],
) -> dict[str, Any]:
    options = {
        "order": n,
        "order_rule": _ORDER_RULES[order_rule],
        "past": p,
        "past_rule": past_rule,
        "future": f,
        "max_past": opt.max_past,
        "dt": opt.dt,
        "feedthrough": opt.feedthrough,
        "rank_tol": opt.rank_tol,
        "remove_mean": opt.remove_mean,
        "coordinates": opt.coordinates,
        "factorization": "gram",
    }
    if opt.coordinates == "physical":
        options["physical_fit"] = opt.physical_fit
        if opt.physical_fit == "structured":
            options["structure_past"] = extras.get("structure_lags", _structure_lags(opt))
            options["structure_past_rule"] = "auto" if opt.structure_auto else "given"
    if opt.algorithm == "ssarx":
        options["weighting"] = opt.weighting
    return options


def _fit(
    acc: _LagGram,
    nu: int,
    ny: int,
    opt: _Options,
    p_top: int,
    shift: np.ndarray,
    data: tuple[np.ndarray, np.ndarray] | None,
) -> IdentificationResult:
    """Everything after the pass over the data (in memory and streamed alike)."""
    notes: list[str] = []
    extras: dict[str, Any] = {}
    # one factor of the widest window the fit may use (the AIC's and the VARX's Hankel
    # rows are the same, rows 0..N - W, as MOESP's; the structured fit's are its own)
    W = _check_window(acc.n, nu + ny, opt, p_top)
    # the VARX reads the rows of its own window only; the structured fit reads the Gram
    # of its window (P16)'s own rows as an operator, once it is chosen (_structured)
    k_varx = min(W, _window(opt, p_top, _future(opt.algorithm, opt.future, p_top)))
    st_all = _window_stats(acc, nu, ny, W, shift, opt.remove_mean, k_varx)
    gram = _WindowGram(acc, st_all.scale, opt.remove_mean)
    p, f, past_rule = _choose_past(st_all, opt, p_top, notes, extras)
    st = replace(st_all, F=_leading(st_all.F, _window(opt, p, f) * st_all.m))  # z(0..w-1)
    system, s, n, gap, order_rule = _identify_states(st, opt, p, f, notes, data, extras)
    model, K, Re = _unscale(system, st.scale, nu, opt.dt)
    model, continuous, K, Re, params = _coordinates(model, K, Re, gram, opt, notes, extras)
    rho = _stability_notes(model, K, notes)
    Re_s = Re / np.outer(st.scale[nu:], st.scale[nu:])
    fit, residuals = _fit_metrics(st, model, K, Re_s, p, opt.remove_mean, data, rho)
    mean_u, mean_y = st.mean[:nu], st.mean[nu:]
    extras.update(
        kalman_gain=K,
        innovation_covariance=Re,
        predictor_spectral_radius=rho,
        past=p,
        future=f,
        order=n,
        order_gap_ratio=gap,
        hankel_rows=st.j,
        factor_rank=st.rank,
        channel_scale=st.scale,
        mean={"u": mean_u, "y": mean_y} if opt.remove_mean else None,
    )
    logger.debug("%s: order %d, past %d, future %d, j=%d", opt.algorithm, n, p, f, st.j)
    return IdentificationResult(
        method=opt.algorithm,
        model=model,
        parameters=params,
        covariance=_parameter_covariance(params, extras.get("structure_covariance"), opt.dt),
        n_samples=acc.n,
        options=_options_used(opt, n, order_rule, p, f, past_rule, extras),
        residuals=residuals,
        fit=fit,
        singular_values=s,
        notes=tuple(notes),
        continuous_model=continuous,
        extras=extras,
    )


def _parameter_covariance(
    params: dict[str, float], cov_v: np.ndarray | None, dt: float
) -> np.ndarray | None:
    """cov of ``[v1..v9, a1..a4]`` from the structured fit's cov(v) (P15), delta method.

    ``a = char. poly(A_d(v))``: ``d a_k = -tr(M_k dA_d)`` with ``M_1 = I``,
    ``M_{k+1} = A_d M_k + a_k I`` (Faddeev-LeVerrier; Jacobi's formula for
    ``det(zI - A_d)``, whose adjugate is ``sum_k M_k z^{n-k}``) and ``dA_d`` the ZOH's
    Frechet derivatives: exact, one stacked ``expm`` (central differences took 19
    exponentials and eigenvalue problems, 2-4 ms a fit, and agree to 7e-7 relative, their
    own error).
    """
    if cov_v is None:
        return None
    v = np.array([params[k] for k in V_NAMES])
    Ad, _, dAd, _ = _zoh(v, dt)
    a, n = _char_poly(Ad), Ad.shape[0]
    T = np.zeros((9 + n, 9))
    T[:9] = np.eye(9)
    Mk = np.eye(n)
    for k in range(n):
        T[9 + k] = -np.einsum("ij,dji->d", Mk, dAd)  # -tr(M_k dA_d / dv_d)
        Mk = Ad @ Mk + a[k] * np.eye(n)
    cov = T @ cov_v @ T.T
    return 0.5 * (cov + cov.T)


def _bearing_coordinates(
    model: StateSpace, K: np.ndarray
) -> tuple[StateSpace, StateSpace, np.ndarray, np.ndarray]:
    """The two-coil AMB model in states ``[x, dx/dt, i1, i2]`` (physical.py, section 3).

    :func:`~maglevid.identify.physical.to_physical_coordinates`; the Kalman gain
    transforms as ``T K``, with ``T^-1`` read off the two observability matrices
    (``O_phys = O T^-1``; both have full column rank).
    """
    if model.nu != 2:
        raise DataError(
            "coordinates='physical' is the two-coil bearing's transform: 4 states, outputs "
            f"[x, i1, i2], inputs [u1, u2]; got nx={model.nx}, ny={model.ny}, nu={model.nu}"
        )
    try:
        disc, cont = to_physical_coordinates(model)
    except DataError as exc:
        msg = f"coordinates='physical' is the two-coil bearing's transform: {exc}"
        raise DataError(msg) from exc
    except IdentificationError as exc:  # e.g. a pole on the negative real axis
        msg = (
            f"the black-box model cannot be put in the bearing's physical coordinates "
            f"({exc}); with little excitation or high sensor noise that estimate can be far "
            "off: use method 'ml' (maximum likelihood through the Kalman predictor), or a "
            "longer record or more excitation"
        )
        raise IdentificationError(msg) from exc
    Ti = sla.lstsq(_observability(model.A, model.C, 2), _observability(disc.A, disc.C, 2))[0]
    v, _ = v_from_matrices(cont.A, cont.B)
    return disc, cont, np.linalg.solve(Ti, K), v


# ------------------------------------------------------------- accumulator
class PredictorAccumulator:
    """Lagged products of ``z = [u, y]`` fed chunk by chunk; fit PBSID-opt or SSARX at the end.

    Memory is independent of the record length: ``L + 1`` lagged ``m x m``
    products and ``L`` head and tail samples, with ``L = p`` (PBSID-opt) or
    ``p + f - 1`` (SSARX) for the largest past ``p`` and future ``f`` the fit
    may use. A chunk boundary changes only the order of summation, so
    :meth:`fit` equals :func:`fit_pbsid` / :func:`fit_ssarx` on the whole record
    to rounding, without the time series of ``residuals``.

    Parameters
    ----------
    ny, nu : int
        Output and input channels.
    algorithm : {"pbsid", "ssarx"}
    past, future : int, optional
        Fixed past and future; when ``past`` is omitted it is chosen at fit time
        (AIC), up to ``max_past``.
    max_past : int
        Largest automatic past (default 80); reduced at fit time to what the
        record supports, as in memory.
    remove_mean : bool
        Centre the data (offset-invariant fit; default True).
    structure_past : int, optional
        The structured fit's window (``physical_fit="structured"``), kept as
        given, as in :func:`fit_pbsid`.
    structure_lags : int, optional
        Without ``structure_past``: lags kept for the structured fit's window
        chosen from the data, (P16) and (P23), up to them and the record (default: none
        beyond the VARX's; :func:`~maglevid.identify.streaming.identify_streamed`
        keeps ``DEFAULT_STRUCTURE_PAST``).

    Examples
    --------
    >>> import numpy as np
    >>> from maglevid.simulate.feedback import example_unstable_mimo, simulate_innovation_loop
    >>> plant, K, controller = example_unstable_mimo()  # unstable, in closed loop
    >>> y, u = simulate_innovation_loop(plant, K, controller, 3000, rng=0)  # no noise
    >>> acc = PredictorAccumulator(ny=2, nu=2, past=2)
    >>> for k in range(0, 3000, 700):
    ...     _ = acc.update(y[k:k + 700], u[k:k + 700])
    >>> res = acc.fit(order=3)
    >>> np.allclose(res.model.markov(8), plant.markov(8))
    True
    """

    def __init__(
        self,
        ny: int,
        nu: int,
        *,
        algorithm: str = "pbsid",
        past: int | None = None,
        future: int | None = None,
        max_past: int = DEFAULT_MAX_PAST,
        remove_mean: bool = True,
        structure_past: int | None = None,
        structure_lags: int | None = None,
    ) -> None:
        self.ny = _check_int(ny, "ny", 1, allow_none=False)
        self.nu = _check_int(nu, "nu", 1, allow_none=False)
        self.algorithm = _check_choice(algorithm, "algorithm", _ALGORITHMS)
        self.past = _check_int(past, "past", 1)
        self.future = _check_int(future, "future", 1)
        self.max_past = _check_int(max_past, "max_past", 1, allow_none=False)
        self.remove_mean = bool(remove_mean)
        assert self.ny is not None and self.nu is not None
        p_top = self.past if self.past is not None else self.max_past
        assert p_top is not None
        lags = p_top if self.algorithm == "pbsid" else p_top + _future("ssarx", future, p_top) - 1
        self.structure_past = _check_int(structure_past, "structure_past", 1)
        keep = _check_int(structure_lags, "structure_lags", 1) or 0
        self._acc = _LagGram(self.nu + self.ny, max(lags, self.structure_past or keep, 1))
        self._shift: np.ndarray | None = None

    @property
    def n_samples(self) -> int:
        """Samples seen so far."""
        return self._acc.n

    def update(self, y: Any, u: Any) -> PredictorAccumulator:
        """Add the next chunk: ``y`` (c, ny) and ``u`` (c, nu), time first. Returns self."""
        y = as_signal(y, "y", n_channels=self.ny)
        u = as_signal(u, "u", n_samples=y.shape[0], n_channels=self.nu)
        z = np.concatenate([u, y], axis=1)
        if self._shift is None:
            # A reference offset taken off every sample before the products: with
            # remove_mean the centred Gram then has no cancellation against a large
            # operating point (the shift itself drops out of the centred fit).
            self._shift = z.mean(axis=0) if self.remove_mean else np.zeros(z.shape[1])
        self._acc.update(z - self._shift)
        return self

    def fit(
        self,
        *,
        order: int | None = None,
        dt: float = 1.0,
        feedthrough: bool = False,
        weighting: str = "cca",
        rank_tol: float | None = None,
        coordinates: str = "identified",
        physical_fit: str | None = None,
    ) -> IdentificationResult:
        """Identify from the data seen so far (options as in :func:`fit_pbsid`)."""
        opt = _options(
            self.algorithm,
            order=order,
            past=self.past,
            future=self.future,
            max_past=self.max_past,
            dt=dt,
            feedthrough=feedthrough,
            weighting=weighting,
            rank_tol=rank_tol,
            remove_mean=self.remove_mean,
            coordinates=coordinates,
            physical_fit=physical_fit,
            structure_past=self.structure_past,  # given: as in memory; None: (P16)
        )
        assert self.ny is not None and self.nu is not None
        N = self.n_samples
        opt = _resolve_structure(opt, N, self.nu + self.ny, self._acc.L)  # window in notes
        p_top, lags = _plan(N, self.nu + self.ny, self.ny, opt)
        if self.past is None:
            p_top = min(p_top, self.max_past)
        if N < self._acc.min_samples():
            raise DataError(f"{N} samples are too few for the lags kept ({self._acc.L})")
        if lags > self._acc.L:
            raise DataError(f"order={order} needs a past above this accumulator's max_past")
        assert self._shift is not None
        return _fit(self._acc, self.nu, self.ny, opt, p_top, self._shift, None)


def _fit_in_memory(algorithm: str, y: Any, u: Any, kw: dict[str, Any]) -> IdentificationResult:
    opt = _options(algorithm, **kw)
    y = as_signal(y, "y", min_samples=2, copy=False)  # read only; no reference is kept
    N = y.shape[0]
    u = as_signal(u, "u", n_samples=N, copy=False)
    ny, nu = y.shape[1], u.shape[1]
    opt = _resolve_structure(opt, N, nu + ny)
    p_top, lags = _plan(N, nu + ny, ny, opt)
    if N < 2 * lags + 1:
        raise DataError(f"the record has {N} samples; the past asked for needs {2 * lags + 1}")
    acc = _LagGram(nu + ny, lags)
    # Chunks of a whole number of the accumulator's groups of ``lags`` samples: a
    # chunk's starts then fill whole groups (two GEMMs each), none is left to the
    # one-product-per-lag remainder, and few chunks (~2.6e5 samples) pay a junction
    # each: 10 % less than 65536-sample chunks at 1e6 and 119 lags. Above
    # ``_SPLIT_MIN`` samples u and y go in apart (``update_split``, MOESP's route: no
    # interleaved copy, 6 % less again at 1e6); below, its fold (~7 ms at 119 lags,
    # 20 % of a fit at 1e4) costs more than it saves. The same sums to rounding.
    step = max(lags, 1) * max(1, _PASS_CHUNK // max(lags, 1))
    shift = np.zeros(nu + ny)
    if opt.physical_fit == "structured" and lags >= _FFT_MIN_LAGS:
        # the structured fit's long window: its lagged products by blocked FFT, 10-40x
        # faster than the direct sums at 100-460 lags (docs/subspace.md, "sixth session").
        # One interleaved copy of the record serves the shift and the FFT: the shift's
        # own copy of the first chunk (the whole record below 2.6e5 samples) was 3-5 ms
        # of a fit at 1e5; the same values, reduced alike: the same shift.
        z = np.concatenate([u, y], axis=1)
        if opt.remove_mean:
            shift = z[:step].mean(axis=0)
            z -= shift
        acc.load_fft(z)
        return _fit(acc, nu, ny, opt, p_top, shift, (y, u))
    if opt.remove_mean:  # the first chunk's mean: centring the Gram without cancellation
        shift = np.concatenate([u[:step], y[:step]], axis=1).mean(axis=0)
    for t0 in range(0, N, step):  # the same accumulator a stream would use
        if N > _SPLIT_MIN:
            acc.update_split(u[t0 : t0 + step] - shift[:nu], y[t0 : t0 + step] - shift[nu:])
        else:
            z = np.concatenate([u[t0 : t0 + step], y[t0 : t0 + step]], axis=1)
            z -= shift
            acc.update(z)
    return _fit(acc, nu, ny, opt, p_top, shift, (y, u))


def _fit_lines(
    algorithm: str, y: Any, u: Any, periodic: Any, kw: dict[str, Any]
) -> IdentificationResult:
    """:func:`_fit_in_memory` with the record's periodic lines taken out first
    (``periodic``: :func:`~maglevid.identify.periodic.fit_without_lines`)."""
    name = "PBSID-opt" if algorithm == "pbsid" else "SSARX"
    return fit_without_lines(
        lambda y_, u_: _fit_in_memory(algorithm, y_, u_, kw),
        y,
        u,
        kw["dt"],
        periodic,
        method=name,
    )


# ------------------------------------------------------------- public API
def fit_pbsid(
    y: Any,
    u: Any,
    *,
    order: int | None = None,
    past: int | None = None,
    future: int | None = None,
    dt: float = 1.0,
    feedthrough: bool = False,
    rank_tol: float | None = None,
    remove_mean: bool = True,
    coordinates: str = "identified",
    max_past: int | None = None,
    physical_fit: str | None = None,
    structure_past: int | None = None,
    periodic: Any = "none",
    rng: np.random.Generator | None = None,
) -> IdentificationResult:
    """Innovation-form state-space model by PBSID-opt, consistent in closed loop.

    Implements the optimised predictor-based subspace identification of Chiuso
    (2007) in the form of van Wingerden & Verhaegen: one VARX of the one-step
    predictor (docs/subspace.md eq. (P4)), ``Gamma_f K_p`` assembled from its
    coefficients (P5), the state sequence from the SVD of ``Gamma_f K_p Z_p``
    (P6) and ``(A, B, C, D, K)`` by least squares on the states (P9).

    Parameters
    ----------
    y : array_like, shape (N, ny)
        Outputs, time first.
    u : array_like, shape (N, nu)
        Plant inputs (in closed loop: what the plant received).
    order : int, optional
        Model order. By default: 4 with ``coordinates="physical"`` (the bearing's
        states); else the largest gap of the singular values when it is clear
        (``s_n / s_{n+1} >= 10``), otherwise (records in memory) the order of smallest
        BIC of each candidate model's own one-step prediction errors over
        ``1..min(f ny, 20)`` (``options["order_rule"]`` says which: ``"auto"``,
        ``"auto-bic"``, ``"structure"``; the BIC table in ``extras["order_bic"]``).
    past : int, optional
        VARX order ``p`` (past window). Default: AIC over ``1..max_past``
        (the smallest exact order on noise-free data).
    future : int, optional
        Future window ``f <= p`` (rows of ``Gamma_f``); default ``p``.
    dt : float
        Sample time in seconds.
    feedthrough : bool
        Estimate ``D`` (default False: ``D = 0``, and ``u(t)`` may then depend on
        ``y(t)`` through the controller).
    rank_tol : float, optional
        Singular values below ``rank_tol * s_1`` count as zero in the order
        choice (default 1e-6).
    remove_mean : bool
        Centre the data (regressions with an intercept): constant offsets of
        ``y`` and ``u`` do not change the model. Default True.
    coordinates : {"identified", "physical"}
        ``"physical"``: the two-coil bearing's states ``[x, dx/dt, i1, i2]``
        (4 states, outputs ``[x, i1, i2]``), with ``v1..v9`` in ``parameters``.
    max_past : int, optional
        Upper limit of the automatic past (default 80, ``DEFAULT_MAX_PAST``).
    physical_fit : {"structured", "transform"}, optional
        With ``coordinates="physical"``: ``"structured"`` (the default there):
        v1..v9 and the Kalman gain fitted to the window's Gram matrix by
        weighted least squares in the bearing's structure, started from the
        transform (docs/subspace.md (P11)-(P16); near maximum likelihood on
        the bearing, 1-10 s on 1e4-1e6 samples; no pass over the data; with
        intervals, (P15)); or ``"transform"``: v1..v9 read off the black-box
        model transformed to physical coordinates (0.03-0.5 s, no covariance,
        4-50x ML's v error on the closed-loop bearing).
    structure_past : int, optional
        Lags of the structured fit's window (default: from the data, ``ln N / (-2 ln
        rho)``, ``rho`` the transform's predictor radius, (P16), or longer, so that the
        term it drops is <= 5 % of the innovations, (P23); docs/subspace.md).
    periodic : "none", "auto" or float or sequence of float
        Periodic lines (unbalance, mains hum) whose least-squares sinusoids are taken out
        of every channel before the fit (1 N at 50 Hz put the bearing's v1..v3 93 % off;
        :func:`maglevid.identify.periodic.fit_without_lines`): ``"none"`` (default here:
        the search costs a fifth of a fit at N = 1e4), frequencies [Hz], or ``"auto"``
        (strong in the record, or in the first fit's residuals; the CLI's default in
        physical coordinates).
    rng : numpy.random.Generator, optional
        Unused (deterministic); accepted for a uniform ``fit_*`` API.

    Returns
    -------
    IdentificationResult
        ``model`` (discrete, ``dt``); ``extras["kalman_gain"]`` ``K`` and
        ``extras["innovation_covariance"]``; ``parameters`` a1..an of
        ``det(zI - A)`` (and v1..v9 in physical coordinates);
        ``singular_values`` those used for the order; ``residuals`` the one-step
        prediction errors of ``(A, B, C, D, K)``.

    Raises
    ------
    DataError
        Bad shapes or options, too few samples, a constant channel.
    IdentificationError
        No information in the data, or an order above the rank found; in physical
        coordinates, a black-box model with no physical counterpart (a pole on the
        negative real axis), or a structured fit that breaks down, ends on an unstable
        predictor or stops at its step limit far from its optimum (a closed-loop
        predictor too slow for the VARX past: high sensor noise, little excitation).
        The message says what to use instead (method ``ml``).

    Notes
    -----
    Consistent under feedback with an unknown causal controller as ``N -> oo``
    and ``p -> oo`` (the truncation error is ``O(|lambda_max(A - K C)|^p)``).
    On noise-free closed-loop data the VARX is unique only while ``p ny <= n +
    n_c`` (``n_c`` the controller's order); the automatic past (AIC) picks the
    smallest exact order, where the result is exact.

    References
    ----------
    A. Chiuso, "The role of vector autoregressive modeling in predictor-based
    subspace identification," Automatica 43(6):1034-1048, 2007. J.-W. van
    Wingerden and M. Verhaegen, "Subspace identification of bilinear and LPV
    systems for open- and closed-loop data," Automatica 45(2):372-381, 2009.

    Examples
    --------
    >>> import numpy as np
    >>> from maglevid.simulate.feedback import example_unstable_mimo, simulate_innovation_loop
    >>> plant, K, controller = example_unstable_mimo()  # unstable, in closed loop
    >>> y, u = simulate_innovation_loop(plant, K, controller, 2000, rng=0)  # no noise
    >>> res = fit_pbsid(y, u)  # automatic past and order
    >>> res.options["order"], np.allclose(res.model.markov(8), plant.markov(8))
    (3, True)
    """
    del rng
    return _fit_lines(
        "pbsid",
        y,
        u,
        periodic,
        dict(
            order=order,
            past=past,
            future=future,
            dt=dt,
            feedthrough=feedthrough,
            weighting="none",
            rank_tol=rank_tol,
            remove_mean=remove_mean,
            coordinates=coordinates,
            max_past=max_past,
            physical_fit=physical_fit,
            structure_past=structure_past,
        ),
    )


def fit_ssarx(
    y: Any,
    u: Any,
    *,
    order: int | None = None,
    past: int | None = None,
    future: int | None = None,
    dt: float = 1.0,
    feedthrough: bool = False,
    weighting: str = "cca",
    rank_tol: float | None = None,
    remove_mean: bool = True,
    coordinates: str = "identified",
    max_past: int | None = None,
    physical_fit: str | None = None,
    structure_past: int | None = None,
    periodic: Any = "none",
    rng: np.random.Generator | None = None,
) -> IdentificationResult:
    """Innovation-form state-space model by SSARX (Jansson 2003), consistent in closed loop.

    The VARX (docs/subspace.md eq. (P4)) gives the predictor's Markov
    parameters; they remove the future ``z``'s effect from the future outputs
    (P7), the corrected future is regressed on the past and a
    canonical-correlation weighted SVD gives the state (P8); ``(A, B, C, D, K)``
    by least squares on the states (P9).

    Parameters
    ----------
    y, u, order, past, future, dt, feedthrough, rank_tol, remove_mean, coordinates, max_past
        As in :func:`fit_pbsid`, except that ``future`` defaults to ``min(past, 40)``
        (the Hankel window is ``past + future``).
    weighting : {"cca", "none"}
        ``W1 = (ytil_f ytil_f^T)^{-1/2}`` (canonical correlations, Jansson's
        choice; default) or ``W1 = I``. Noise-free data have a singular
        corrected-future covariance; the SVD is then unweighted (noted).
    physical_fit, structure_past, periodic, rng
        As in :func:`fit_pbsid`.

    Returns, Raises
        As :func:`fit_pbsid`.

    References
    ----------
    M. Jansson, "Subspace identification and ARX modeling," 13th IFAC Symposium
    on System Identification, Rotterdam, 2003.

    Examples
    --------
    >>> import numpy as np
    >>> from maglevid.simulate.feedback import example_unstable_mimo, simulate_innovation_loop
    >>> plant, K, controller = example_unstable_mimo()  # unstable, in closed loop
    >>> y, u = simulate_innovation_loop(plant, K, controller, 2000, e_std=0.1, rng=0)
    >>> res = fit_ssarx(y, u, order=3)
    >>> bool(np.max(np.abs(res.model.poles())) > 1.0)  # the unstable pole, found
    True
    """
    del rng
    return _fit_lines(
        "ssarx",
        y,
        u,
        periodic,
        dict(
            order=order,
            past=past,
            future=future,
            dt=dt,
            feedthrough=feedthrough,
            weighting=weighting,
            rank_tol=rank_tol,
            remove_mean=remove_mean,
            coordinates=coordinates,
            max_past=max_past,
            physical_fit=physical_fit,
            structure_past=structure_past,
        ),
    )


# --------------------------------------------------------------- registry
def _method(algorithm: str, summary: str):  # type: ignore[no-untyped-def]
    fit = fit_pbsid if algorithm == "pbsid" else fit_ssarx

    def run(data: Any, **options: Any) -> IdentificationResult:
        if getattr(data, "u", None) is None and getattr(data, "u_f", None) is not None:
            data = data.with_plant_input()
        if getattr(data, "u", None) is None:
            raise DataError(
                f"method {algorithm!r} needs the plant input `u` (or `u_f` and `r`), which "
                "the recording lacks"
            )
        options.setdefault("dt", data.dt)
        # the bearing's fit (physical coordinates) takes the record's periodic lines out;
        # elsewhere the registry's check only names them (docs/gosiewski.md, "Periodic
        # disturbances": on the UAQ levitator's records taking them out moved the
        # automatic order, 3 -> 45 on one)
        if options.get("coordinates") == "physical":
            options.setdefault("periodic", "auto")
        periodic = options.pop("periodic", "none")
        # a line can break the structured fit itself: the transform's residuals are then
        # searched (found from outside: a 1 um sensor line at 50 Hz on the position)
        structured = options.get("coordinates") == "physical" and not options.get("physical_fit")
        transform = {**options, "physical_fit": "transform"}
        res = fit_without_lines(
            lambda y_, u_: fit(y_, u_, **options), data.y_control, data.u, options["dt"],
            periodic, method="PBSID-opt" if algorithm == "pbsid" else "SSARX",
            excitation=getattr(data, "r", None),
            probe=(lambda y_, u_: fit(y_, u_, **transform)) if structured else None,
        )  # fmt: skip
        return with_physical_parameters(res, *operating_point(getattr(data, "loop", {}) or {}))

    run.__name__ = f"identify_{algorithm}"
    run.__doc__ = summary
    return run


#: Methods for ``maglevid identify --method NAME`` (see identify/registry.py).
METHODS = {
    "pbsid": _method(
        "pbsid",
        "PBSID-opt closed-loop subspace (Chiuso 2007): one VARX, consistent under feedback, "
        "innovation model with Kalman gain",
    ),
    "ssarx": _method(
        "ssarx",
        "SSARX closed-loop subspace (Jansson 2003): VARX-corrected future, CCA-weighted SVD, "
        "innovation model with Kalman gain",
    ),
}


def _declaration(algorithm: str) -> tuple[Option, ...]:
    """The options of ``pbsid`` / ``ssarx`` (maglevid.identify.options), defaults from
    :func:`fit_pbsid` / :func:`fit_ssarx` except ``dt`` (the recording's)."""
    opts = [
        Option("order", "int", "model order (default: a clear gap of the singular "
               "values, else the smallest BIC of the one-step prediction errors; 4 in "
               "physical coordinates)", low=1),
        Option("past", "int", "past window p (default: by AIC)", low=1),
        Option("future", "int", "future window f (default: from p)", low=1),
        Option("dt", "float", "sample time (default: the recording's)", default=None,
               optional=False, low=0, low_open=True, unit="s"),
        Option("feedthrough", "bool", "estimate a direct term D"),
        *((Option("weighting", "str", "weighting of the SVD", choices=_WEIGHTINGS),)
          if algorithm == "ssarx" else ()),
        Option("rank_tol", "float", "relative singular-value tolerance of the rank",
               low=0, low_open=True, high=1),
        Option("remove_mean", "bool", "identify on deviations from the means"),
        Option("coordinates", "str", "state coordinates of the model ('physical' when not "
               "given on a two-coil bearing's record: v1..v9, R, L, ki, kw)",
               choices=_COORDINATES),
        Option("max_past", "int", f"largest automatic past window (default "
               f"{DEFAULT_MAX_PAST})", low=1),
        Option("rng", "object", "random generator of the randomised checks"),
        Option("physical_fit", "str", "how v1..v9 come from the model with "
               "coordinates='physical': 'structured' (default; weighted fit of the "
               "bearing's structure to the VARX, docs/subspace.md (P11)-(P16)) or "
               "'transform' to physical coordinates", choices=_PHYSICAL_FITS),
        Option(
            "structure_past",
            "int",
            "window of physical_fit='structured' (default: from the data, (P16), (P23))",
            low=1,
        ),
        Option("periodic", "object", "periodic disturbances (unbalance, mains hum) taken "
               "out of every channel before the fit: 'auto' (found in the record and "
               "the first fit's residuals, not where the excitation r has a line; the "
               "default with coordinates='physical'), 'none' (the default otherwise) or "
               "frequencies [Hz]"),
    ]  # fmt: skip
    return bind_defaults(opts, fit_pbsid if algorithm == "pbsid" else fit_ssarx)


#: The options of each method, declared once (``--method list``, the CLI's --option).
OPTIONS = {"pbsid": _declaration("pbsid"), "ssarx": _declaration("ssarx")}
