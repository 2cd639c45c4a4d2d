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

which needs only the Gram matrix of the window (the factor ``F`` the data stage
already holds): it is the VARX's least-squares criterion with the 21
structured parameters in place of ``P (nu + ny) ny`` free ones, i.e. a
weighted least-squares fit of the structured Markov parameters to the VARX's,
with the VARX's own covariance ``(Z_P Z_P^T)^{-1} (x) Re`` as weight (P12).
With ``W`` the innovation covariance's inverse this is the prediction-error
criterion of the truncated predictor (Ljung 1999, eq. (7.12)), asymptotically
efficient for this model set when ``|lambda(Abar)|^P`` is negligible;
``W`` is re-estimated from the structured residuals once (P13). The state at
the window's start is not left at 0: ``C Abar^P x_hat(t-P)`` is added, with
``x_hat`` the plant's least-squares state from the window's first
``START_SAMPLES`` samples (P14) -- on a high-SNR record the truncation term
otherwise dominates the residual (the bearing's ``Abar`` has a pole at ~0.98).
Levenberg-Marquardt with Marquardt's scaling; the start is the transform's
estimate. Memory and time do not depend on ``N``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from maglevid.physics.amb import C_AMB, amb_matrices

__all__ = ["START_SAMPLES", "StructuredFit", "fit_bearing_structure"]

#: Samples at the start of the window the predictor's initial state is
#: reconstructed from (P14); 0 leaves it at zero (the truncated predictor).
START_SAMPLES = 8
#: Stop when a step lowers ``j J`` (twice a log-likelihood) by less than this: the
#: optimum is then a small fraction of a standard error away.
_GAIN_TOL = 1e-3
#: Floor of the weighting's innovation covariance (channels scaled to unit RMS).
_RE_FLOOR = 1e-12
#: Gauss-Newton steps per weighting round at most (6-16 in all are taken on the
#: bench's records since the start term's Jacobian is analytic; its forward
#: differences made the steps crawl on high-SNR records, 40 at N = 1e5).
_MAX_ITER = 20
#: Halvings of a failed undamped Gauss-Newton step before Levenberg-Marquardt damping.
_HALVINGS = 4


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


def _markov(Abar: np.ndarray, Btil: np.ndarray, P: int) -> np.ndarray:
    """``M_k = Abar^{k-1} Btil``, k = 1..P, stacked (..., P, n, m), by doubling.

    ``M_{L+1..2L} = Abar^L M_{1..L}``: ``log2 P`` stacked products instead of ``P``
    small ones (a Python loop of 4 x 4 products was a third of a Gauss-Newton
    step); ``Abar`` and ``Btil`` may carry leading stack axes.
    """
    M = np.empty((*Btil.shape[:-2], P, *Btil.shape[-2:]))
    M[..., 0, :, :] = Btil
    L, Ap = 1, Abar
    while L < P:
        n = min(L, P - L)
        M[..., L : L + n, :, :] = Ap[..., None, :, :] @ M[..., :n, :, :]
        L += n
        if L < P:
            Ap = Ap @ Ap
    return M


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


def _predictor_blocks(Abar, Btil, dAbar, dBtil, Cs, P):  # type: ignore[no-untyped-def]
    """``V`` (ny, P m; blocks oldest first) and ``dV`` (n_th, ny, P m).

    ``dM_k = d(Abar^{k-1} Btil)`` is the upper block of ``T^{k-1} [dBtil; Btil]``
    with ``T = [[Abar, dAbar], [0, Abar]]`` (the derivative of a power as a
    block-triangular power): one doubling sequence for all parameters.
    """
    n, n_th = Abar.shape[0], dAbar.shape[0]
    M = _markov(Abar, Btil, P)
    T = np.zeros((n_th, 2 * n, 2 * n))
    T[:, :n, :n] = Abar
    T[:, n:, n:] = Abar
    T[:, :n, n:] = dAbar
    B = np.concatenate([dBtil, np.broadcast_to(Btil, dBtil.shape)], axis=1)
    dM = _markov(T, B, P)[:, :, :n, :]
    # block c (oldest first) is Xi_{P-c} = C M_{P-c}: reverse k
    V = np.einsum("ij,kjm->ikm", Cs, M[::-1]).reshape(Cs.shape[0], -1)
    dV = (Cs @ dM[:, ::-1]).transpose(0, 2, 1, 3).reshape(n_th, Cs.shape[0], -1)
    return V, dV


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
    """``-T_k`` placed in the ``u`` columns of ``[z(t); ...; z(t+k-1)]``: (..., 3 k, 5 k)."""
    S = np.zeros((*CAB.shape[:-3], 3 * k, 5 * k))
    for i in range(k):
        for l in range(i):
            S[..., 3 * i : 3 * i + 3, 5 * l : 5 * l + 2] -= CAB[..., i - 1 - l, :, :]
    return S


def _power_derivative(Abar: np.ndarray, dAbar: np.ndarray, P: int) -> np.ndarray:
    """``d(Abar^P)`` along each of ``dAbar`` (n_d, n, n): the upper-right block of
    ``[[Abar, dAbar_i], [0, Abar]]^P`` (Van Loan 1978's block-triangular trick for
    the power's Frechet derivative), all directions by one stacked ``matrix_power``."""
    n = Abar.shape[0]
    T = np.zeros((dAbar.shape[0], 2 * n, 2 * n))
    T[:, :n, :n] = Abar
    T[:, n:, n:] = Abar
    T[:, :n, n:] = dAbar
    return np.linalg.matrix_power(T, P)[:, :n, n:]


def fit_bearing_structure(
    Fy: np.ndarray,
    Fz: np.ndarray,
    *,
    v0: np.ndarray,
    K0: np.ndarray,
    dt: float,
    scale: np.ndarray,
    j: int,
    max_iter: int = _MAX_ITER,
    initial_state: int = START_SAMPLES,
) -> StructuredFit:
    """Weighted least-squares fit of v1..v9 and ``K`` to the window's Gram factor (P11)-(P13).

    ``Fy`` (ny, r) are the factor's rows of ``y(t)``, ``Fz`` (P m, r) those of
    ``z(t-P..t-1)`` (oldest first), in the data stage's channel-scaled units
    (``scale`` the ``[u, y]`` RMS); ``v0``, ``K0`` the start in physical units.
    ``initial_state``: samples the window-start state is rebuilt from (P14), 0
    to leave it at zero (the long windows of (P16)).
    """
    su, sy = scale[:2], scale[2:]
    P = Fz.shape[0] // 5
    Fz, Fy = _trim(Fz, Fy)
    theta = np.concatenate([np.zeros(9), (K0 * sy[None, :]).ravel()])
    Cs = C_AMB / sy[:, None]
    k0 = min(initial_state, P)

    def start_term(th: np.ndarray) -> np.ndarray:  # C Abar^P x_hat(t-P), (P14)
        Ad, Bd = _plant(v0 * (1.0 + th[:9]), dt)
        Abar = Ad - th[9:].reshape(4, 3) @ Cs
        return Cs @ np.linalg.matrix_power(Abar, P) @ _state_map(Ad, Bd * su[None, :], Cs, k0)

    def start_derivative(th, Abar, dAbar, dBtil):  # type: ignore[no-untyped-def]
        # d(Cs Abar^P M) = Cs d(Abar^P) M + Cs Abar^P dM; M depends on v only
        Ad, Bd = _plant(v0 * (1.0 + th[:9]), dt)
        M, dM = _state_map(Ad, Bd * su[None, :], Cs, k0, dAbar[:9], dBtil[:9, :, :2])
        out = Cs @ _power_derivative(Abar, dAbar, P) @ M
        out[:9] += Cs @ np.linalg.matrix_power(Abar, P) @ dM
        return out

    # The Jacobian's W-free part at the last point: each weighting round (P13) and the
    # covariance (P15) start where the last round ended, with a new W only (J is
    # linear in W^{1/2}): two of ~13 Jacobians, the same numbers bitwise.
    last: dict[str, object] = {}

    def residual(th: np.ndarray, jac: bool, W12: np.ndarray):  # type: ignore[no-untyped-def]
        if not jac:  # the trial steps: no derivatives (9 Frechet derivatives, P Markov steps)
            Ad, Bd = _plant(v0 * (1.0 + th[:9]), dt)
            Ks = th[9:].reshape(4, 3)
            M = _markov(Ad - Ks @ Cs, np.concatenate([Bd * su[None, :], Ks], axis=1), P)
            V = np.einsum("ij,kjm->ikm", Cs, M[::-1]).reshape(Cs.shape[0], -1)
            if k0:
                V[:, : 5 * k0] += start_term(th)
            return W12 @ (Fy - V @ Fz), None
        key = th.tobytes()
        if last.get("key") != key:  # the same point again (a new W): W-free parts kept
            Abar, Btil, dAbar, dBtil, Cs_, *_ = _model(th, v0, dt, sy, su)
            V, dV = _predictor_blocks(Abar, Btil, dAbar, dBtil, Cs_, P)
            if k0:
                V[:, : 5 * k0] += start_term(th)
            if k0:  # the start term's derivative, analytic (a 3 x 5 k0 block per parameter)
                dV[:, :, : 5 * k0] += start_derivative(th, Abar, dAbar, dBtil)
            # one GEMM of all 3 n_th rows (a stack of 3-row products ran at GEMV speed)
            dVF = (dV.reshape(-1, dV.shape[2]) @ Fz).reshape(th.size, 3, -1)
            last.update(key=key, E=Fy - V @ Fz, dVF=dVF)
        R = W12 @ last["E"]
        J = -np.einsum("ij,pjk->pik", W12, last["dVF"]).reshape(th.size, -1).T
        return R, J

    E, _ = residual(theta, False, np.eye(3))  # prediction errors of the start (scaled)
    iterations = 0
    for _ in range(2):  # (P13): W from the prediction errors, fit, W again, refit
        # unit-RMS channels: the floor keeps W finite on noise-free records
        Re = E @ E.T + _RE_FLOOR * np.eye(3)
        W12 = np.linalg.inv(sla.cholesky(Re, lower=True))
        weighted = functools.partial(residual, W12=W12)
        theta, R, it = _gauss_newton(weighted, theta, j, max_iter)
        iterations += it
        E = np.linalg.solve(W12, R)  # unweighted again
    _, _, _, _, _, v, Ad, Bd, Ks = _model(theta, v0, dt, sy, su)
    Re = (E @ E.T) * np.outer(sy, sy)
    cov = _covariance(residual, theta, E, j) * np.outer(v0, v0)
    return StructuredFit(v, Ks / sy[None, :], Ad, Bd, 0.5 * (Re + Re.T), iterations, k0, cov)


def _trim(Fz: np.ndarray, Fy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``Fz``, ``Fy`` without the columns where both are zero (contiguous copies).

    The data stage's Cholesky factor is lower triangular: the rows of the window
    ``z(t-P..t-1), y(t)`` live in its first ``5 P + 5`` columns, and the fit (P11)
    depends on the columns only through ``F F^T``. The Jacobian's product is
    ``O(P m r)`` per parameter: on the (P16) window the factor has ``r`` up to 1.4x
    ``5 P`` columns (the lags kept, not the window chosen).
    """
    nz = np.flatnonzero(np.any(Fz != 0.0, axis=0) | np.any(Fy != 0.0, axis=0))
    c = int(nz[-1]) + 1 if nz.size else 0
    return np.ascontiguousarray(Fz[:, :c]), np.ascontiguousarray(Fy[:, :c])


def _covariance(residual, theta: np.ndarray, E: np.ndarray, j: int) -> np.ndarray:  # type: ignore[no-untyped-def]
    """``cov(dv/v0)`` (9, 9), (P15): ``(J^T J)^{-1} / j`` with ``W = Re^{-1}`` at the optimum.

    (P11) is the weighted least-squares fit (P12) of the structured Markov
    parameters to the VARX's, weighted by the VARX's inverse covariance
    ``Sigma_varx^{-1} = j (G (x) Re^{-1})``: the sandwich
    ``(J' W J)^{-1} J' W Sigma W J (J' W J)^{-1}`` collapses to
    ``(J' Sigma^{-1} J)^{-1}``, here ``(J^T J)^{-1} / j`` with ``J`` the
    Jacobian of the whitened residual of the normalised factor, ``W``
    re-estimated at the optimum.
    """
    Re = E @ E.T + _RE_FLOOR * np.eye(3)
    W12 = np.linalg.inv(sla.cholesky(Re, lower=True))
    _, J = residual(theta, True, W12)
    d = np.linalg.norm(J, axis=0)
    d[d == 0] = 1.0
    Rinv = np.linalg.inv(np.linalg.qr(J / d, mode="r"))  # (J^T J)^{-1} = R^{-1} R^{-T}, scaled
    cov = (Rinv @ Rinv.T) / np.outer(d, d) / j
    return cov[:9, :9]


def _gauss_newton(residual, theta: np.ndarray, j: int, max_iter: int):  # type: ignore[no-untyped-def]
    """Gauss-Newton by QR with column scaling; Levenberg-Marquardt damping when a step fails.

    Stops when a step lowers ``j J`` (twice the log-likelihood change) by less
    than ``_GAIN_TOL``, or after ``max_iter`` steps. An undamped Gauss-Newton
    step that raises the cost is first halved (up to ``_HALVINGS`` times: far
    from the optimum the predictor's ``Abar^P`` makes the full step overshoot
    along a good direction) before damping turns it towards the gradient: one
    Jacobian fewer on some records, each worth ~1/13 of the fit. Near the optimum
    the problem is a large-residual one (the true curvature along the step ~1.75x
    ``J^T J``'s, so plain Gauss-Newton converges linearly): after each full step the
    second-order term ``S`` is updated by the secant rule of NL2SOL (:func:`_dgw`)
    and the next step solves ``(J^T J + S) s = -J^T r``; ``S`` is dropped after a
    halved or damped step and whenever ``J^T J + S`` is not positive definite.
    docs/subspace.md, "sixth session".
    """
    R, J = residual(theta, True)
    cost = float(np.sum(R * R))
    lam, it = 0.0, 0
    Sq = None
    h = 0
    for it in range(1, max_iter + 1):  # noqa: B007 - the count is returned
        d = np.linalg.norm(J, axis=0)
        d[d == 0] = 1.0
        Js, r = J / d, -R.ravel()
        while True:
            if lam:
                k = Js.shape[1]
                Js_l = np.vstack([Js, np.sqrt(lam) * np.eye(k)])
                step = np.linalg.lstsq(Js_l, np.concatenate([r, np.zeros(k)]), rcond=None)[0]
                c_new = _cost(residual, theta + step / d)
            else:  # undamped: the Gauss-Newton step, halved while it raises the cost
                step = _newton_step(Js, r, d, Sq)
                if step is None:  # J^T J + S not positive definite: Gauss-Newton
                    Sq = None
                    step = np.linalg.lstsq(Js, r, rcond=None)[0]
                for h in range(_HALVINGS + 1):
                    c_new = _cost(residual, theta + step / d)
                    if c_new <= cost or h == _HALVINGS:
                        break
                    step = 0.5 * step
            if c_new <= cost or lam > 1e8:
                break
            lam = 1e-4 if lam == 0 else lam * 10.0
        if c_new > cost:
            break
        gain = (cost - c_new) * j
        J0, R0, full = J, R, not lam and h == 0
        theta, cost = theta + step / d, c_new
        lam = 0.0 if lam <= 1e-3 else lam / 10.0
        R, J = residual(theta, True)
        # the second-order term S by a secant update while the steps are full ones
        Sq = _dgw(Sq, step / d, J0, R0, J, R) if full else None
        if gain < _GAIN_TOL:
            break
    return theta, R, it


def _cost(residual, theta: np.ndarray) -> float:  # type: ignore[no-untyped-def]
    """Sum of squares of the weighted residual at ``theta`` (no derivatives)."""
    R, _ = residual(theta, False)
    return float(np.sum(R * R))


def _newton_step(Js: np.ndarray, r: np.ndarray, d: np.ndarray, Sq: np.ndarray | None):
    """``(Js^T Js + D^-1 S D^-1)^{-1} Js^T r`` (scaled units), None when not positive
    definite; the Gauss-Newton step by least squares when there is no ``S`` yet."""
    if Sq is None:
        return np.linalg.lstsq(Js, r, rcond=None)[0]
    try:
        cf = sla.cho_factor(Js.T @ Js + Sq / np.outer(d, d), lower=True)
    except np.linalg.LinAlgError:
        return None
    return sla.cho_solve(cf, Js.T @ r)


def _dgw(Sq, s, J0, R0, J1, R1):  # type: ignore[no-untyped-def]
    """Dennis, Gay & Welsch (1981) secant update of the second-order term ``S`` (NL2SOL).

    ``S`` approximates ``sum_i r_i Hess(r_i)``, which Gauss-Newton drops: with
    ``y# = (J1 - J0)^T r1`` (what ``S`` must map the step ``s`` to) and ``y`` the
    gradient's change, the symmetric rank-2 update of least change in the
    ``y``-weighted norm, ``S`` first sized by ``min(1, |s'y#| / |s'Ss|)``. Starts
    from 0 (``Sq`` None); left unchanged when ``s'y <= 0``.
    """
    if Sq is None:
        Sq = np.zeros((s.size, s.size))
    r1 = R1.ravel()
    y = J1.T @ r1 - J0.T @ R0.ravel()
    ys = J1.T @ r1 - J0.T @ r1
    sy = float(s @ y)
    if sy <= 0.0:
        return Sq
    sSs = float(s @ Sq @ s)
    tau = min(1.0, abs(float(s @ ys)) / abs(sSs)) if sSs != 0.0 else 1.0
    Sq = tau * Sq
    z = ys - Sq @ s
    return Sq + (np.outer(z, y) + np.outer(y, z)) / sy - float(z @ s) * np.outer(y, y) / sy**2
