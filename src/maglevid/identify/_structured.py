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

from maglevid.identify.cramer_rao import NoiseModel, amb_linear_gaussian_model
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
#: Gauss-Newton steps per weighting round at most: on high-SNR records the
#: steps crawl along a valley (K against v5/v7); 20 keep the fit near 1-3 s.
_MAX_ITER = 20


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
    """``A_d, B_d`` of eq. (4) + ZOH and their derivatives in v (cramer_rao's public model)."""
    g = amb_linear_gaussian_model(v, dt, NoiseModel(sensor_std=(1.0, 1.0, 1.0)))
    return g.A, g.B, g.dA[:9], g.dB[:9]


def _plant(v: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``A_d, B_d``: eq. (4) and its ZOH (eq. (7)), without derivatives."""
    Ac, Bc = amb_matrices(v)
    M = np.zeros((6, 6))
    M[:4, :4], M[:4, 4:] = Ac * dt, Bc * dt
    E = sla.expm(M)
    return E[:4, :4], E[:4, 4:]


def _markov(Abar: np.ndarray, Btil: np.ndarray, P: int) -> np.ndarray:
    """``M_k = Abar^{k-1} Btil``, k = 1..P, stacked (P, n, m)."""
    M = np.empty((P, *Btil.shape))
    M[0] = Btil
    for k in range(1, P):
        M[k] = Abar @ M[k - 1]
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
    """``V`` (ny, P m; blocks oldest first) and ``dV`` (n_th, ny, P m)."""
    M = _markov(Abar, Btil, P)
    dM = np.empty((dAbar.shape[0], *M.shape))
    dM[:, 0] = dBtil
    for k in range(1, P):  # d(Abar M_{k-1}) = dAbar M_{k-1} + Abar dM_{k-1}
        dM[:, k] = dAbar @ M[k - 1] + np.einsum("ij,pjk->pik", Abar, dM[:, k - 1])
    # block c (oldest first) is Xi_{P-c} = C M_{P-c}: reverse k
    V = np.einsum("ij,kjm->ikm", Cs, M[::-1]).reshape(Cs.shape[0], -1)
    dV = np.einsum("ij,pkjm->pikm", Cs, dM[:, ::-1]).reshape(dM.shape[0], Cs.shape[0], -1)
    return V, dV


def _state_map(Ad: np.ndarray, Bs: np.ndarray, Cs: np.ndarray, k: int) -> np.ndarray:
    """``M`` (4, 5 k): ``x(t) ~ M [z(t); ...; z(t+k-1)]`` by least squares on the plant (P14).

    ``y(t+i) = Cs Ad^i x(t) + sum_{l<i} Cs Ad^{i-1-l} Bs u(t+l)`` (noise left out):
    ``x = Gamma_k^+ (Y_k - T_k U_k)``, scaled units, ``z = [u, y]``.
    """
    CA = np.empty((k, *Cs.shape))  # Cs Ad^i, i = 0..k-1, by one product each
    CA[0] = Cs
    for i in range(1, k):
        CA[i] = CA[i - 1] @ Ad
    CAB = CA @ Bs  # Cs Ad^i Bs
    S = np.zeros((3 * k, 5 * k))
    for i in range(k):
        S[3 * i : 3 * i + 3, 5 * i + 2 : 5 * i + 5] = np.eye(3)
        for l in range(i):
            S[3 * i : 3 * i + 3, 5 * l : 5 * l + 2] -= CAB[i - 1 - l]
    return np.linalg.pinv(CA.reshape(-1, Ad.shape[0])) @ S


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
    theta = np.concatenate([np.zeros(9), (K0 * sy[None, :]).ravel()])
    Cs = C_AMB / sy[:, None]
    k0 = min(initial_state, P)

    def start_term(th: np.ndarray) -> np.ndarray:  # C Abar^P x_hat(t-P), (P14)
        Ad, Bd = _plant(v0 * (1.0 + th[:9]), dt)
        Abar = Ad - th[9:].reshape(4, 3) @ Cs
        return Cs @ np.linalg.matrix_power(Abar, P) @ _state_map(Ad, Bd * su[None, :], Cs, k0)

    def residual(th: np.ndarray, jac: bool, W12: np.ndarray):  # type: ignore[no-untyped-def]
        if not jac:  # the trial steps: no derivatives (9 Frechet derivatives, P Markov steps)
            Ad, Bd = _plant(v0 * (1.0 + th[:9]), dt)
            Ks = th[9:].reshape(4, 3)
            M = _markov(Ad - Ks @ Cs, np.concatenate([Bd * su[None, :], Ks], axis=1), P)
            V = np.einsum("ij,kjm->ikm", Cs, M[::-1]).reshape(Cs.shape[0], -1)
            if k0:
                V[:, : 5 * k0] += start_term(th)
            return W12 @ (Fy - V @ Fz), None
        Abar, Btil, dAbar, dBtil, Cs_, *_ = _model(th, v0, dt, sy, su)
        V, dV = _predictor_blocks(Abar, Btil, dAbar, dBtil, Cs_, P)
        if k0:
            V[:, : 5 * k0] += start_term(th)
        R = W12 @ (Fy - V @ Fz)
        if k0:  # the start term's derivative by forward differences (a 3 x 5 k0 block)
            base = start_term(th)
            for i in range(th.size):
                h = 1e-7 * max(1.0, abs(th[i]))
                t2 = th.copy()
                t2[i] += h
                dV[i, :, : 5 * k0] += (start_term(t2) - base) / h
        J = -np.einsum("ij,pjk->pik", W12, dV @ Fz).reshape(th.size, -1).T
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
    than ``_GAIN_TOL``, or after ``max_iter`` steps.
    """
    R, J = residual(theta, True)
    cost = float(np.sum(R * R))
    lam, it = 0.0, 0
    for it in range(1, max_iter + 1):  # noqa: B007 - the count is returned
        d = np.linalg.norm(J, axis=0)
        d[d == 0] = 1.0
        Js, r = J / d, -R.ravel()
        while True:
            if lam:
                k = Js.shape[1]
                Js_l = np.vstack([Js, np.sqrt(lam) * np.eye(k)])
                step = np.linalg.lstsq(Js_l, np.concatenate([r, np.zeros(k)]), rcond=None)[0]
            else:
                step = np.linalg.lstsq(Js, r, rcond=None)[0]
            R_new, _ = residual(theta + step / d, False)
            c_new = float(np.sum(R_new * R_new))
            if c_new <= cost or lam > 1e8:
                break
            lam = 1e-4 if lam == 0 else lam * 10.0
        if c_new > cost:
            break
        gain = (cost - c_new) * j
        theta, cost = theta + step / d, c_new
        lam = 0.0 if lam <= 1e-3 else lam / 10.0
        R, J = residual(theta, True)
        if gain < _GAIN_TOL:
            break
    return theta, R, it
