"""The Cramér-Rao bound of the AMB's physical parameters from closed-loop data.

Noise model (the one :func:`maglevid.simulate.amb.simulate_amb_loop` draws, plus
optional amplifier noise the simulator does not draw)::

    x(k+1) = A(v) x(k) + B(v) (u(k) + a(k)) + b_F(v) f(k)          (ZOH of eq. (3))
    y(k)   = C x(k) + c + e(k),   e ~ N(0, diag(s_x^2, s_i1^2, s_i2^2))

``u`` is the *logged* amplifier input (feedback plus excitation), ``e`` the
sensor noise of ``[x, i1, i2]``, ``f`` a force disturbance on the rotor [N]
held over each sample (``b_F`` is the ZOH of ``B_F = [0, 1/m, 0, 0]^T``), ``a``
amplifier noise [V] held over each sample, ``c`` constant offsets of the
outputs. The simulator draws ``e`` and, on its default nonlinear plant, ``f``
(``force_std``, 0.1 N; ``a = 0``); :meth:`NoiseModel.from_data` reads both from
the record's metadata. On the nonlinear plant the model is eq. (3) linearised at
the settled operating point (``metadata["operating_point_true"]["v"]``).

Innovations form
----------------
With ``Q = s_F^2 b_F b_F^T + B diag(s_a^2) B^T`` and ``R = diag(s^2)`` the
stationary Kalman predictor (stabilising solution ``P`` of the filter DARE;
``(A, C)`` is observable, so it exists for the unstable bearing, also with
``Q = 0``)::

    P = A P A^T + Q - K S K^T,  S = C P C^T + R,  K = A P C^T S^-1
    xh(k+1) = A xh(k) + B u(k) + K eps(k),  eps(k) = y(k) - c - C xh(k)

gives white innovations ``eps ~ N(0, S)``. ``u`` is a function of past ``y``
and of ``r`` (independent of the noise), so the likelihood of ``y`` given its
past and ``u`` is the product of the innovation densities whether or not the
controller is known (Ljung, *System Identification*, 2nd ed., sec. 13.4)::

    -log L(theta) = 1/2 sum_k eps_k^T S^-1 eps_k + N/2 log det S + const.   (1)

Fisher information
------------------
Differentiating (1) twice and taking expectations (``E eps eps^T = S``, the
innovations independent of their past) gives the asymptotic Fisher matrix
(Söderström & Stoica, *System Identification*, eq. (B.54))::

    I_ij = sum_k psi_i(k)^T S^-1 psi_j(k) + N/2 tr(S^-1 S_i S^-1 S_j),      (2)

with ``psi_i = d eps / d theta_i`` and ``S_i = dS / d theta_i``. The
sensitivities follow one linear recursion per parameter, with the predictor's
own dynamics ``F = A - K C`` (stable by construction)::

    sigma_i(k+1) = F sigma_i(k) + A_i xh(k) + B_i u(k) + K_i eps(k),  psi_i = -C sigma_i  (3)

``A_i, B_i`` are exact (Fréchet derivative of the matrix exponential of the
augmented ``[[A_c, B_c, B_F], [0, 0, 0]] dt``). ``K_i`` follows from the
derivative of the DARE: in Joseph form ``P = F P F^T + Q + K R K^T`` the
derivative with respect to ``K`` vanishes at the optimal gain, so::

    P_i = F P_i F^T + A_i P F^T + F P A_i^T + Q_i + K R_i K^T       (discrete Lyapunov)
    S_i = C P_i C^T + R_i,   K_i = (A_i P C^T + A P_i C^T - K S_i) S^-1.          (4)

The bound of ``v = [v1..v9]`` is the ``v`` block of ``I^-1`` (nuisance
parameters -- unknown noise levels, offsets, initial state -- included in
``I`` when they are estimated); R, L, ki, kw, x0, ks, ... follow by the delta
method through :func:`~maglevid.physics.amb.parameters_from_v`.

For a *design* the expectation in (2) is taken over one long simulated record
of the loop. Because everything is linear, ``psi = psi_r + psi_e`` (the parts
driven by the excitation and by the noise, independent), so the information
per sample at excitation level ``alpha`` is ``alpha^2 I_r + I_e``: two
simulations give the bound at every excitation level and record length
(:mod:`maglevid.identify.planning`).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import scipy.linalg as sla

from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError, IdentificationError
from maglevid.identify._recursion import linear_recursion
from maglevid.identify.result import propagate_covariance
from maglevid.identify.uncertainty import PHYSICAL_NAMES, RATIO_NAMES, operating_point
from maglevid.physics.amb import (
    C_AMB,
    V_NAMES,
    AMBParameters,
    amb_matrices,
    parameters_from_v,
    ratios_from_v,
)

__all__ = [
    "CramerRaoBound",
    "LinearGaussianModel",
    "NoiseModel",
    "PredictorStatistics",
    "amb_linear_gaussian_model",
    "bound_from_fisher",
    "cramer_rao_bound",
    "derived_parameters",
    "eliminate_nuisance",
    "evaluation_point",
    "fit_nuisance",
    "invert_information",
    "pinv_information",
    "plant_from_v",
    "predictor_derivatives",
    "predictor_statistics",
    "steady_state_predictor",
    "without_derivatives",
]

#: Samples per chunk of the sensitivity recursion (bounds the memory: N x n x p floats).
CHUNK = 32_768


# ---------------------------------------------------------------------------
# The noise model
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class NoiseModel:
    """Noise of the AMB loop (module notes): sensor, force disturbance, amplifier.

    Parameters
    ----------
    sensor_std : (3,) sequence
        Standard deviations of the sensor noise on ``[x, i1, i2]`` [m, A, A]
        (the simulator's ``noise_std``); all must be positive.
    force_std : float
        Standard deviation of a force disturbance on the rotor [N], held over
        each sample (0: none, as in the simulator).
    amplifier_std : (2,) sequence
        Standard deviation of noise added to each amplifier input [V], held
        over each sample (0: none, as in the simulator).
    """

    sensor_std: tuple[float, float, float]
    force_std: float = 0.0
    amplifier_std: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        s = np.asarray(self.sensor_std, dtype=float).reshape(-1)
        if s.size != 3 or not np.all(np.isfinite(s)) or np.any(s <= 0):
            raise DataError(
                f"`sensor_std` must be 3 positive numbers (x [m], i1 [A], i2 [A]); "
                f"got {self.sensor_std!r}"
            )
        a = np.asarray(self.amplifier_std, dtype=float).reshape(-1)
        if a.size != 2 or not np.all(np.isfinite(a)) or np.any(a < 0):
            raise DataError(f"`amplifier_std` must be 2 numbers >= 0; got {self.amplifier_std!r}")
        f = float(self.force_std)
        if not np.isfinite(f) or f < 0:
            raise DataError(f"`force_std` must be a number >= 0; got {self.force_std!r}")
        object.__setattr__(self, "sensor_std", tuple(float(x) for x in s))
        object.__setattr__(self, "amplifier_std", tuple(float(x) for x in a))
        object.__setattr__(self, "force_std", f)

    @classmethod
    def from_data(cls, data: ClosedLoopData) -> NoiseModel | None:
        """The simulator's noise model from ``metadata["noise_std"]`` and ``["force_std"]``
        (``None`` without positive sensor noise levels)."""
        meta = data.metadata if isinstance(data.metadata, Mapping) else {}
        s = meta.get("noise_std")
        if s is None or np.any(np.asarray(s, dtype=float) <= 0):
            return None
        f = meta.get("force_std")
        f = 0.0 if f is None or not np.isfinite(float(f)) else float(f)
        return cls(tuple(np.asarray(s, dtype=float).tolist()), force_std=f)  # type: ignore[arg-type]

    def to_dict(self) -> dict[str, Any]:
        return {
            "sensor_std": list(self.sensor_std),
            "force_std": self.force_std,
            "amplifier_std": list(self.amplifier_std),
        }


# ---------------------------------------------------------------------------
# A linear Gaussian model with its parameter derivatives
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class LinearGaussianModel:
    """``x+ = A x + B u + w, y = C x + e`` with ``Cov w = Q``, ``Cov e = R`` and
    the derivatives of ``A, B, Q, R`` with respect to ``p`` parameters
    (leading axis of ``dA, dB, dQ, dR``)."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    dA: np.ndarray
    dB: np.ndarray
    dQ: np.ndarray
    dR: np.ndarray
    names: tuple[str, ...] = ()

    @property
    def n_params(self) -> int:
        return self.dA.shape[0]


def _zoh_with_derivatives(
    Ac: np.ndarray, Bc: np.ndarray, dAc: np.ndarray, dBc: np.ndarray, dt: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``Ad, Bd`` (ZOH, eq. (7)) and their exact derivatives for each ``(dAc, dBc)``."""
    n, m = Bc.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n], M[:n, n:] = Ac * dt, Bc * dt
    dAd = np.empty((len(dAc), n, n))
    dBd = np.empty((len(dAc), n, m))
    X = None
    for i in range(len(dAc)):
        E = np.zeros_like(M)
        E[:n, :n], E[:n, n:] = dAc[i] * dt, dBc[i] * dt
        X, L = sla.expm_frechet(M, E, compute_expm=True)
        dAd[i], dBd[i] = L[:n, :n], L[:n, n:]
    if X is None:
        X = sla.expm(M)
    return X[:n, :n], X[:n, n:], dAd, dBd


def amb_linear_gaussian_model(
    v: Any,
    dt: float,
    noise: NoiseModel,
    *,
    m: float | None = None,
    estimate_noise: bool = False,
    estimate_force: bool = False,
) -> LinearGaussianModel:
    """The AMB's discrete model and noise covariances with derivatives (module notes).

    Parameters
    ----------
    v : (9,) array_like
        v1..v9 of eq. (4).
    dt : float
        Control period [s].
    noise : NoiseModel
    m : float, optional
        Rotor mass [kg]; needed only for a force disturbance (``B_F = [0, 1/m, 0, 0]``).
    estimate_noise : bool
        Also differentiate with respect to ``log s_x, log s_i1, log s_i2``
        (the parameters are then ``v1..v9`` and those three).
    estimate_force : bool
        Also differentiate with respect to the force disturbance's variance
        ``s_F^2`` [N^2] (last parameter, ``force_var``). The variance, not its
        log, so that ``s_F = 0`` (no disturbance) is an ordinary point on the
        boundary of the parameter space (``dQ / d s_F^2 = b_F b_F^T``). Without
        ``m`` the disturbance is an acceleration [m/s^2] (``B_F = [0, 1, 0, 0]``).
    """
    v = np.asarray(v, dtype=float).reshape(-1)
    Ac, Bc = amb_matrices(v)
    n = 4
    bF = np.zeros((n, 1))
    if noise.force_std > 0 or estimate_force:
        if m is None and not estimate_force:
            raise DataError("a force disturbance needs the rotor mass `m`")
        bF[1, 0] = 1.0 if m is None else 1.0 / float(m)
    Bx = np.hstack([Bc, bF])
    dAc = np.zeros((9, n, n))
    dBx = np.zeros((9, n, 3))
    for i in range(9):
        Ai, Bi = amb_matrices(np.eye(9)[i])
        dAc[i] = Ai - amb_matrices(np.zeros(9))[0]  # eq. (4) is linear in v
        dBx[i, :, :2] = Bi
    Ad, Bxd, dAd, dBxd = _zoh_with_derivatives(Ac, Bx, dAc, dBx, dt)
    Bd, bFd = Bxd[:, :2], Bxd[:, 2:]
    dBd, dbFd = dBxd[:, :, :2], dBxd[:, :, 2:]
    Sa = np.diag(np.square(noise.amplifier_std))
    sF2 = noise.force_std**2
    Q = sF2 * bFd @ bFd.T + Bd @ Sa @ Bd.T
    dQ = sF2 * (dbFd @ bFd.T + bFd @ dbFd.transpose(0, 2, 1))
    dQ += dBd @ Sa @ Bd.T + Bd @ Sa @ dBd.transpose(0, 2, 1)
    s2 = np.square(noise.sensor_std)
    R = np.diag(s2)
    dR = np.zeros((9, 3, 3))
    names = tuple(V_NAMES)
    if estimate_noise:
        dAd = np.concatenate([dAd, np.zeros((3, n, n))])
        dBd = np.concatenate([dBd, np.zeros((3, n, 2))])
        dQ = np.concatenate([dQ, np.zeros((3, n, n))])
        dRn = np.zeros((3, 3, 3))
        for j in range(3):
            dRn[j, j, j] = 2.0 * s2[j]  # d s^2 / d log s
        dR = np.concatenate([dR, dRn])
        names = (*names, "log_sx", "log_si1", "log_si2")
    if estimate_force:
        dAd = np.concatenate([dAd, np.zeros((1, n, n))])
        dBd = np.concatenate([dBd, np.zeros((1, n, 2))])
        dQ = np.concatenate([dQ, (bFd @ bFd.T)[None]])
        dR = np.concatenate([dR, np.zeros((1, 3, 3))])
        names = (*names, "force_var")
    return LinearGaussianModel(Ad, Bd, C_AMB.copy(), Q, R, dAd, dBd, dQ, dR, names)


# ---------------------------------------------------------------------------
# The steady-state Kalman predictor and its derivatives (eq. (4))
# ---------------------------------------------------------------------------
def steady_state_predictor(
    A: np.ndarray, C: np.ndarray, Q: np.ndarray, R: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``K, P, S`` of the stationary Kalman predictor (module notes).

    The DARE is solved in coordinates scaled by the noise levels (``R -> I``,
    states scaled by the measured channels' noise), which keeps it well
    conditioned when positions are 1e-7 m and currents 1e-4 A.

    Raises
    ------
    IdentificationError
        No stabilising solution (a mode that is neither observed nor stable).
    """
    n, _ny = A.shape[0], C.shape[0]
    w = np.sqrt(np.diag(R))
    # State scale: each state scaled like the output that sees it most, else 1.
    d = np.ones(n)
    for j in range(n):
        col = np.abs(C[:, j])
        if col.max() > 0:
            d[j] = w[np.argmax(col)] / col.max()
    if n == 4 and np.allclose(C, C_AMB):
        d[1] = d[0] / 1e-4  # velocity: about position noise per 0.1 ms
    As = A * (1.0 / d)[:, None] * d[None, :]
    Cs = C * (1.0 / w)[:, None] * d[None, :]
    Qs = Q / np.outer(d, d)
    Rs = R / np.outer(w, w)
    try:
        with warnings.catch_warnings():
            # An ill-conditioned DARE (a parameter far from any bearing) is a failure here.
            warnings.simplefilter("error", sla.LinAlgWarning)
            Ps = sla.solve_discrete_are(As.T, Cs.T, Qs, Rs)
    except (np.linalg.LinAlgError, ValueError, sla.LinAlgWarning) as exc:
        raise IdentificationError(
            f"the Kalman predictor has no stabilising solution: {exc}"
        ) from exc
    Ps = 0.5 * (Ps + Ps.T)
    P = Ps * np.outer(d, d)
    S = C @ P @ C.T + R
    S = 0.5 * (S + S.T)
    K = np.linalg.solve(S, (A @ P @ C.T).T).T
    if np.max(np.abs(np.linalg.eigvals(A - K @ C))) >= 1.0:
        raise IdentificationError("the Kalman predictor is not stable (A - K C)")
    return K, P, S


def predictor_derivatives(
    model: LinearGaussianModel, K: np.ndarray, P: np.ndarray, S: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """``dK, dS`` of eq. (4) for every parameter.

    The Lyapunov equations are solved with ``F`` balanced (LAPACK's ``gebal``: a
    diagonal similarity by powers of 2, exact): in SI units ``F`` mixes entries
    ~1e-4 and ~1e4, and at 1e-3 of the default sensor noise the direct solver's
    ``I - F (x) F`` had rcond 3e-17, so that ML's trial points there were rejected as
    ill-conditioned and the scoring crawled for 50 iterations without converging
    (healthy nonlinear bearing, 2e4 samples; found from outside, twenty-fifth
    session). The DARE's noise scales (:func:`steady_state_predictor`) were tried
    first: they assume the bearing's 0.1 ms period for the velocity and made a record
    timed in ms (dt 1000x) ill-conditioned instead."""
    A, C = model.A, model.C
    F = A - K @ C
    Fs, (dsc, _) = sla.matrix_balance(F, permute=False, separate=True)
    dd = np.outer(dsc, dsc)
    p = model.n_params
    dK = np.empty((p, *K.shape))
    dS = np.empty((p, *S.shape))
    for i in range(p):
        Ai = model.dA[i]
        rhs = Ai @ P @ F.T
        rhs = rhs + rhs.T + model.dQ[i] + K @ model.dR[i] @ K.T
        Pi = sla.solve_discrete_lyapunov(Fs, rhs / dd) * dd  # P_i = F P_i F' + rhs
        Pi = 0.5 * (Pi + Pi.T)
        Si = C @ Pi @ C.T + model.dR[i]
        dS[i] = 0.5 * (Si + Si.T)
        dK[i] = np.linalg.solve(S, (Ai @ P @ C.T + A @ Pi @ C.T - K @ dS[i]).T).T
    return dK, dS


# ---------------------------------------------------------------------------
# Innovations, sensitivities and the sums of eqs. (1)-(2)
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class PredictorStatistics:
    """Sums over a record of the predictor's innovations and sensitivities.

    Parameter order: the model's ``p`` parameters, then (``nuisance=True``)
    the output offsets ``c`` (ny) and the initial predictor state (n).
    """

    neg_log_likelihood: float
    gradient: np.ndarray
    fisher: np.ndarray
    innovation_covariance: np.ndarray  # S of the model
    sample_covariance: np.ndarray  # sum eps eps^T / N
    n_samples: int
    K: np.ndarray
    residuals: np.ndarray | None = None
    names: tuple[str, ...] = field(default=())


def predictor_statistics(
    model: LinearGaussianModel,
    y: np.ndarray,
    u: np.ndarray,
    *,
    offset: np.ndarray | None = None,
    x0: np.ndarray | None = None,
    nuisance: bool = True,
    keep_residuals: bool = False,
    chunk: int = CHUNK,
) -> PredictorStatistics:
    """Innovations and eqs. (1)-(2) of the steady-state predictor over one record.

    Parameters
    ----------
    model : LinearGaussianModel
    y : ndarray, shape (N, ny)
    u : ndarray, shape (N, nu)
        The logged plant input.
    offset : (ny,) array_like, optional
        Output offsets ``c`` (zero when omitted).
    x0 : (n,) array_like, optional
        Initial predictor state (zero when omitted).
    nuisance : bool
        Include ``c`` and ``x0`` as parameters in the gradient and Fisher matrix.
    keep_residuals : bool
        Return the innovations ``eps`` (N, ny).
    chunk : int
        Samples per chunk (memory ``chunk x n x p`` floats).
    """
    A, B, C = model.A, model.B, model.C
    n, ny = A.shape[0], C.shape[0]
    K, P, S = steady_state_predictor(A, C, model.Q, model.R)
    dK, dS = predictor_derivatives(model, K, P, S)
    F = A - K @ C
    p = model.n_params
    q = p + (ny + n if nuisance else 0)
    c = np.zeros(ny) if offset is None else np.asarray(offset, dtype=float)
    xh = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float).copy()
    Li = np.linalg.inv(np.linalg.cholesky(S))  # S^-1 = Li^T Li
    sig = np.zeros((n, q))
    if nuisance:
        sig[:, p + ny :] = np.eye(n)  # d xh(0) / d x0
    # Forcing of the offset sensitivities: d xh(k+1)/dc = F sigma - K (constant).
    force_c = -K if nuisance else None
    info = np.zeros((q, q))
    grad_lin = np.zeros(q)
    sum_ee = np.zeros((ny, ny))
    N = y.shape[0]
    eps_all = np.empty((N, ny)) if keep_residuals else None
    Bu_all = u @ B.T
    for s0 in range(0, N, chunk):
        s1 = min(N, s0 + chunk)
        yc = y[s0:s1] - c
        # predictor: xh(k+1) = F xh(k) + B u(k) + K (y(k) - c)
        Xh, xh_end = linear_recursion(F, Bu_all[s0:s1] + yc @ K.T, xh)
        eps = yc - Xh @ C.T
        # eq. (3): forcing A_i xh + B_i u + K_i eps for every parameter
        W = np.zeros((s1 - s0, n, q))
        W[:, :, :p] = (
            np.einsum("pij,kj->kip", model.dA, Xh)
            + np.einsum("pij,kj->kip", model.dB, u[s0:s1])
            + np.einsum("pij,kj->kip", dK, eps)
        )
        if nuisance:
            W[:, :, p : p + ny] = force_c
        if q:
            Sig, sig = linear_recursion(F, W, sig)
            psi = -np.einsum("ij,kjq->kiq", C, Sig)
            if nuisance:
                psi[:, :, p : p + ny] -= np.eye(ny)
            psi_w = np.einsum("ij,kjq->kiq", Li, psi).reshape(-1, q)
            eps_w = (eps @ Li.T).reshape(-1)
            info += psi_w.T @ psi_w
            grad_lin += psi_w.T @ eps_w
        sum_ee += eps.T @ eps
        if eps_all is not None:
            eps_all[s0:s1] = eps
        xh = xh_end
    Si = np.linalg.inv(S)
    # eq. (2), second term, and the S-dependent terms of the gradient of eq. (1).
    SidS = np.einsum("ij,pjk->pik", Si, dS)
    info[:p, :p] += 0.5 * N * np.einsum("pij,qji->pq", SidS, SidS)
    grad = grad_lin.copy()
    grad[:p] += 0.5 * N * np.trace(SidS, axis1=1, axis2=2) - 0.5 * np.einsum(
        "pij,ji->p", SidS @ Si, sum_ee
    )
    _, logdet = np.linalg.slogdet(S)
    nll = 0.5 * float(np.trace(Si @ sum_ee)) + 0.5 * N * logdet
    names = model.names
    if nuisance:
        names = (
            names + tuple(f"offset_y{j}" for j in range(ny)) + tuple(f"xh0_{j}" for j in range(n))
        )
    return PredictorStatistics(
        neg_log_likelihood=nll,
        gradient=grad,
        fisher=0.5 * (info + info.T),
        innovation_covariance=S,
        sample_covariance=sum_ee / N,
        n_samples=N,
        K=K,
        residuals=eps_all,
        names=names,
    )


# ---------------------------------------------------------------------------
# The bound
# ---------------------------------------------------------------------------
def derived_parameters(
    v: np.ndarray, *, m: float | None, i0: float | None
) -> tuple[tuple[str, ...], np.ndarray]:
    """Names and values of the physical parameters (given ``m``, ``i0``) or ratios."""
    if m is not None and i0 is not None:
        p = parameters_from_v(v, m=m, i0=i0)
        return PHYSICAL_NAMES, np.array([p[k] for k in PHYSICAL_NAMES])
    r = ratios_from_v(v)
    return RATIO_NAMES, np.array([r[k] for k in RATIO_NAMES])


@dataclass(frozen=True)
class CramerRaoBound:
    """The Cramér-Rao bound of v1..v9 and of the physical parameters.

    Attributes
    ----------
    names : tuple of str
        ``v1..v9`` then the physical parameters (or the scale-free ratios).
    values : ndarray
        The parameters at which the bound is evaluated (the truth for a design).
    covariance : ndarray
        The bound for ``n_samples`` samples (delta method beyond ``v``).
    n_samples : int
    fisher_v : ndarray, shape (9, 9)
        Information about ``v`` per sample with the nuisance parameters
        eliminated (the inverse of the ``v`` block of ``I^-1``, divided by N).
    noise : NoiseModel
    m, i0 : float or None
    """

    names: tuple[str, ...]
    values: np.ndarray
    covariance: np.ndarray
    n_samples: int
    fisher_v: np.ndarray
    noise: NoiseModel
    m: float | None = None
    i0: float | None = None
    notes: tuple[str, ...] = ()

    def std(self) -> dict[str, float]:
        """Smallest achievable standard deviation of each parameter."""
        return dict(zip(self.names, np.sqrt(np.clip(np.diag(self.covariance), 0, None)).tolist()))

    def relative_std(self) -> dict[str, float]:
        """``std / |value|`` for each parameter."""
        s = self.std()
        return {
            k: float(s[k] / abs(v)) if v != 0 else float("inf")
            for k, v in zip(self.names, self.values.tolist())
        }

    def for_samples(self, n_samples: int) -> CramerRaoBound:
        """The same bound for a record of ``n_samples`` samples (information ∝ N)."""
        if n_samples < 1:
            raise DataError(f"`n_samples` must be >= 1; got {n_samples!r}")
        return bound_from_fisher(
            self.fisher_v * n_samples,
            self.values[:9],
            n_samples=n_samples,
            noise=self.noise,
            m=self.m,
            i0=self.i0,
            notes=self.notes,
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "n_samples": self.n_samples,
            "parameters": dict(zip(self.names, self.values.tolist())),
            "std": self.std(),
            "relative_std": self.relative_std(),
            "noise": self.noise.to_dict(),
            "notes": list(self.notes),
        }


def bound_from_fisher(
    fisher_v: np.ndarray,
    v: np.ndarray,
    *,
    n_samples: int,
    noise: NoiseModel,
    m: float | None,
    i0: float | None,
    notes: Sequence[str] = (),
) -> CramerRaoBound:
    """:class:`CramerRaoBound` from the (nuisance-free) information about ``v``."""
    v = np.asarray(v, dtype=float)
    cov_v = invert_information(fisher_v)
    dnames, _ = derived_parameters(v, m=m, i0=i0)

    def chain(vv: np.ndarray) -> np.ndarray:
        return np.concatenate([vv, derived_parameters(vv, m=m, i0=i0)[1]])

    values, cov = propagate_covariance(chain, v, cov_v)
    return CramerRaoBound(
        names=tuple(V_NAMES) + tuple(dnames),
        values=values,
        covariance=0.5 * (cov + cov.T),
        n_samples=int(n_samples),
        fisher_v=np.asarray(fisher_v) / n_samples,
        noise=noise,
        m=m,
        i0=i0,
        notes=tuple(notes),
    )


def invert_information(M: np.ndarray) -> np.ndarray:
    """Inverse of a symmetric positive-definite information matrix, scaled for conditioning.

    Raises
    ------
    IdentificationError
        The (scaled) matrix is singular to working precision: some combination
        of the parameters is not identifiable from this record.
    """
    d = np.sqrt(np.clip(np.diag(M), 1e-300, None))
    Ms = M / np.outer(d, d)
    if not np.all(np.isfinite(Ms)) or np.linalg.cond(Ms) > 1e14:
        raise IdentificationError(
            "the Fisher information is singular: some combination of the parameters is not "
            "identifiable from this record"
        )
    inv = np.linalg.inv(Ms) / np.outer(d, d)
    return 0.5 * (inv + inv.T)


def pinv_information(M: np.ndarray) -> np.ndarray:
    """Pseudo-inverse of a nuisance block (directions without information carry none)."""
    d = np.sqrt(np.clip(np.diag(M), 1e-300, None))
    return np.linalg.pinv(M / np.outer(d, d), rcond=1e-12, hermitian=True) / np.outer(d, d)


def without_derivatives(model: LinearGaussianModel) -> LinearGaussianModel:
    """The same model with no parameters (innovations and nuisance sensitivities only)."""
    return replace(
        model, dA=model.dA[:0], dB=model.dB[:0], dQ=model.dQ[:0], dR=model.dR[:0], names=()
    )


def fit_nuisance(
    model: LinearGaussianModel, y: np.ndarray, u: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Output offsets ``c`` and initial predictor state that minimise eq. (1).

    The innovations are affine in ``(c, x0)``, so one Gauss-Newton step from
    zero is the exact least-squares solution.
    """
    st = predictor_statistics(without_derivatives(model), y, u)
    step = -pinv_information(st.fisher) @ st.gradient
    ny = model.C.shape[0]
    return step[:ny], step[ny:]


def eliminate_nuisance(fisher: np.ndarray, k: int) -> np.ndarray:
    """Information about the first ``k`` parameters with the others unknown (Schur complement).

    ``I_kk - I_kn I_nn^+ I_nk``: a nuisance direction without information (a
    start-up transient the record never shows) is dropped, not inverted.
    """
    A, B, D = fisher[:k, :k], fisher[:k, k:], fisher[k:, k:]
    red = A - B @ pinv_information(D) @ B.T
    return 0.5 * (red + red.T)


def cramer_rao_bound(
    data: ClosedLoopData,
    *,
    v: Any = None,
    noise: NoiseModel | None = None,
    estimate_noise: bool = False,
    estimate_force: bool = False,
    m: float | None = None,
    i0: float | None = None,
) -> CramerRaoBound:
    """The Cramér-Rao bound of v1..v9 and the physical parameters for one recording.

    The Fisher information (eq. (2)) is evaluated on the recorded ``y``, ``u``
    at the parameters ``v`` (by default the simulated truth in
    ``metadata["truth_v"]``, or that of the linearisation at the true
    operating point of a nonlinear simulation); offsets and initial state are
    nuisance parameters, and so are the three sensor noise levels when
    ``estimate_noise`` is true.

    Parameters
    ----------
    data : ClosedLoopData
        A two-coil AMB recording (``y = [x, i1, i2]``, ``u`` logged).
    v : (9,) array_like, optional
        Where to evaluate the bound (an estimate for a real recording).
    noise : NoiseModel, optional
        Default :meth:`NoiseModel.from_data` (the simulator's ``noise_std``).
    estimate_noise : bool
        Treat the sensor noise levels as unknown.
    estimate_force : bool
        Treat the force disturbance's variance as unknown (as the ``ml``
        method does by default; the bound at ``force_std = 0`` is then that of
        an interior point, slightly wider than ML's on the boundary).
    m, i0 : float, optional
        Mass and bias current; default ``data.loop["operating_point"]``.

    Returns
    -------
    CramerRaoBound

    Raises
    ------
    DataError
        Not an AMB recording, no ``v`` and no truth, or no noise model.

    Examples
    --------
    >>> from maglevid.physics.amb import AMBParameters
    >>> from maglevid.simulate.amb import simulate_amb_loop
    >>> d = simulate_amb_loop(AMBParameters.nominal(), n_samples=2000, rng=1)
    >>> b = cramer_rao_bound(d)
    >>> 0 < b.relative_std()["R1"] < 1
    True
    """
    y, u = _amb_signals(data)
    v = evaluation_point(data, v)
    noise = NoiseModel.from_data(data) if noise is None else noise
    if noise is None:
        raise DataError(
            "no noise model: pass `noise=NoiseModel(sensor_std=...)` (the recording's metadata "
            "has no positive `noise_std`)"
        )
    op_m, op_i0 = operating_point(data.loop)
    m = op_m if m is None else m
    i0 = op_i0 if i0 is None else i0
    model = amb_linear_gaussian_model(
        v, data.dt, noise, m=m, estimate_noise=estimate_noise, estimate_force=estimate_force
    )
    offset, x0 = fit_nuisance(model, y, u)
    stats = predictor_statistics(model, y, u, offset=offset, x0=x0)
    fisher_v = eliminate_nuisance(stats.fisher, 9)
    return bound_from_fisher(fisher_v, v, n_samples=y.shape[0], noise=noise, m=m, i0=i0)


def _amb_signals(data: ClosedLoopData) -> tuple[np.ndarray, np.ndarray]:
    if not isinstance(data, ClosedLoopData):
        raise DataError(f"`data` must be ClosedLoopData; got {type(data).__name__}")
    if data.p != 1 or data.y.shape[1] != 3 or data.u is None or data.u.shape[1] != 2:
        raise DataError(
            "the bound needs a two-coil AMB recording: y = [x, i1, i2] at the control rate and "
            f"the logged u (2 inputs); got y {data.y.shape}, p = {data.p}"
        )
    return np.asarray(data.y, dtype=float), np.asarray(data.u, dtype=float)


def evaluation_point(data: ClosedLoopData, v: Any) -> np.ndarray:
    if v is not None:
        v = np.asarray(v, dtype=float).reshape(-1)
        if v.size != 9 or not np.all(np.isfinite(v)):
            raise DataError(f"`v` must be 9 finite numbers; got {v.size}")
        return v
    meta = data.metadata if isinstance(data.metadata, Mapping) else {}
    op = meta.get("operating_point_true")
    if isinstance(op, Mapping) and "v" in op:
        return np.asarray(op["v"], dtype=float)
    if "truth_v" in meta:
        return np.asarray(meta["truth_v"], dtype=float)
    raise DataError("pass `v` (e.g. an estimate): the recording carries no true parameters")


def plant_from_v(v: np.ndarray, *, m: float, i0: float) -> AMBParameters:
    """:class:`AMBParameters` whose linearisation has ``v`` (given ``m``, ``i0``)."""
    p = parameters_from_v(v, m=m, i0=i0)
    if p["Ls1"] <= 0 or p["Ls2"] <= 0 or p["x0"] <= 0:
        raise DataError("these v1..v9 give a non-physical bearing (negative leakage inductance)")
    return AMBParameters(
        m=m,
        i0=i0,
        x0=p["x0"],
        R1=p["R1"],
        R2=p["R2"],
        Ls1=p["Ls1"],
        Ls2=p["Ls2"],
        K1=p["K1"],
        K2=p["K2"],
        kw1=p["kw1"],
        kw2=p["kw2"],
    )
