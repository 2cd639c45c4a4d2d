"""The deadbeat observer/controller ARX method of Gosiewski & Paszowski, eqs. (44)-(51).

A bearing runs under integral state feedback ``u = -F xh + Fe e + r`` (eq. (42))
with an observer (eq. (43)) and an integrator ``e(k+1) = e(k) - E y(k+1)``
(eq. (39)). The observer/controller has the state ``z = [xh; e]`` (``n + ne``)
and the outputs ``y_u = [y; u_f]`` (``ny + nu``); when these numbers are equal
and the output matrix ``P = [[C, 0], [-F, Fe]]`` (``[Cbar Ctilde]`` of eq. (45))
is invertible, ``z(k) = P^-1 y_u(k)`` (eq. (46)) and the observer/controller
obeys the exact first-order ARX model (eq. (47))::

    y_u(k+1) = a1 y_u(k) + b0 v(k+1) + b1 v(k),      v = [u; y]
    a1 = P diag(A + Gd C, I) P^-1,  b0 = P [0; Etilde],  b1 = P [B, -Gd; 0, 0]   (48)

from which ``[[L11, L12], [L21, L22]] = P^-1 a1 P``, ``[[M11, M12], [M21, M22]] =
P^-1 b1`` (eq. (50)) and ``B = M11, Gd = -M12, A = L11 - Gd C`` (eq. (51)).

Two traps the printed equations hide
------------------------------------
(a) **The observer gain is not identifiable.** ``y(k)`` appears twice among the
    regressors of eq. (29): in ``y_u(k)`` (coefficient ``a1[:, :ny]``) and in
    ``v(k)`` (coefficient ``b1[:, nu:]``). The printed normal matrix
    ``V V^T`` is therefore exactly singular (rank deficient by ``ny``) and only
    the sum ``a1[:, :ny] + b1[:, nu:]`` is determined. Writing the split as
    ``b1[:, nu:] = -P [Gd'; 0]`` for an arbitrary ``Gd'``::

        a1(Gd') = P diag(A + Gd' C, I) P^-1,   b1(Gd') = P [B, -Gd'; 0, 0]

    fit the data equally well, and eq. (51) returns ``Gd = Gd'`` but
    ``A = L11 - Gd' C = A`` and ``B = M11 = B`` for every ``Gd'``: the plant is
    identifiable, the observer gain is not (it is known anyway: the loop's own
    ``G``). Even a split that is not of this form (e.g. the minimum-norm
    ``lstsq`` split of the printed regression) gives the right ``A``: with
    ``b1[:, nu:] = P [M12; M22]``, ``L11 = A - M12 C`` and ``Gd = -M12``.
    This module regresses on the *distinct* signals ``[y(k), u_f(k), u(k)]``,
    which is full rank, and reports ``a1, b1`` for the split ``Gd' = G`` (the
    loop's observer gain) when it is known, else ``Gd' = 0``.
(b) **b0 v(k+1) is known.** ``b0 v(k+1) = [0; -Fe E y(k+1)]`` holds the
    integrator's use of the *next* output; it is a known function of the data
    (``Fe``, ``E`` known), so it belongs on the left-hand side:
    ``[y(k+1); u_f(k+1) + Fe E y(k+1)] = Theta [y(k); u_f(k); u(k)]``.
    Estimating it as printed would put ``v(k+1) = [u; y](k+1)`` among the
    regressors: ``y(k+1)`` is then the left-hand side itself and, being a
    linear function of ``[y, u_f, u](k)``, exactly collinear with the other
    regressors (a rank-deficient problem). Dropping it instead still fits
    (for the same reason) but with the coefficients ``(I - [0; Fe E][I, 0])
    Theta``; ``A`` and ``B`` survive that (``P^-1 [0; Fe E][I, 0] P = [0, 0; E C,
    0]`` touches only the integrator row) but ``P^-1 a1 P`` loses the structure
    ``diag(A + Gd C, I)`` that serves as a check of the model.

Sign of ``Ctilde``: eq. (45) prints ``Ctilde = [0; -Fe]``, but eqs. (42) and (44)
give ``u_f = -F x + Fe e``, i.e. ``Ctilde = [0; Fe]``; we use the latter.

When the method is exact, and when it is not
--------------------------------------------
The relation holds for the observer's signals. The recording holds the
*measured* ``y``, not the observer's ``yh = C xh``; they are equal only when the
observer state equals the plant state, i.e. when the observer was built on the
very plant that runs and its error has decayed (a deadbeat observer: after
two samples). Then the method is exact without noise. It is biased

* under measurement noise (errors in variables: ``y(k)`` is a regressor) --
  use ``estimator="iv"`` ("deadbeat-iv");
* when the observer's model is the nominal plant and the bearing has changed
  (the diagnostic case): ``xh != x`` and the ARX relation is no longer exact,
  even without noise -- use :mod:`maglevid.identify.physical`;
* and it is impossible when ``P`` is singular, which a mirror-symmetric
  controller (``u_f1 + u_f2`` independent of velocity and of ``e``) produces.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

import numpy as np
import scipy.linalg as sla

from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError, IdentificationError
from maglevid.identify.arx import solve_regression_blocks
from maglevid.identify.iv import simulate_loop_signals
from maglevid.identify.options import AMB_OPTIONS, declared
from maglevid.identify.result import IdentificationResult
from maglevid.identify.uncertainty import (
    DCLevels,
    amb_result,
    one_step_fit_percent,
    with_dc_levels,
)
from maglevid.physics.amb import C_AMB

__all__ = [
    "METHODS",
    "deadbeat_regression",
    "deadbeat_regression_blocks",
    "fit_deadbeat",
    "fit_deadbeat_arx",
    "fit_deadbeat_iv",
    "loop_matrices",
    "loop_output_matrix",
    "observer_controller_arx",
    "observer_noise_ma",
    "plant_from_observer_controller",
]

logger = logging.getLogger(__name__)


def loop_output_matrix(C: Any, F: Any, Fe: Any) -> np.ndarray:
    """``P = [[C, 0], [-F, Fe]]``, the map from ``[xh; e]`` to ``[y; u_f]`` (eqs. (44)-(46)).

    Raises
    ------
    IdentificationError
        ``P`` is not square, or singular to working precision. A mirror-symmetric
        controller on a symmetric bearing (``F`` rows equal up to the mirror
        ``x -> -x, i1 <-> i2``) makes it singular: ``u_f1 + u_f2`` then depends on
        neither the velocity nor the integrator, so ``[y; u_f]`` does not
        determine the observer state and eq. (46) fails. Use the ``physical``
        method, which needs no such inverse.
    """
    C = np.atleast_2d(np.asarray(C, dtype=float))
    F = np.atleast_2d(np.asarray(F, dtype=float))
    Fe = np.atleast_2d(np.asarray(Fe, dtype=float))
    ny, nx = C.shape
    nu, ne = Fe.shape
    if F.shape != (nu, nx):
        raise DataError(f"`F` has shape {F.shape}; expected ({nu}, {nx})")
    if ny + nu != nx + ne:
        raise IdentificationError(
            f"the deadbeat ARX method needs outputs + inputs = states (eq. (46)): "
            f"ny + nu = {ny + nu}, nx + ne = {nx + ne}"
        )
    P = np.block([[C, np.zeros((ny, ne))], [-F, Fe]])
    s = np.linalg.svd(P / np.linalg.norm(P, axis=1, keepdims=True), compute_uv=False)
    if s[-1] < 1e-10 * s[0]:
        raise IdentificationError(
            "the observer/controller output matrix [[C, 0], [-F, Fe]] is singular "
            f"(relative smallest singular value {s[-1] / s[0]:.2g}); eq. (46) cannot "
            "recover the observer state. A mirror-symmetric controller does this "
            "(u_f1 + u_f2 independent of velocity and integrator). Use method 'physical'"
        )
    return P


def loop_matrices(data: ClosedLoopData) -> dict[str, np.ndarray]:
    """``C, F, Fe, E`` and, where recorded, the observer gain ``G`` from ``data.loop``."""
    loop = data.loop
    ctrl = loop.get("controller") if isinstance(loop, Mapping) else None
    if not isinstance(ctrl, Mapping) or not all(k in ctrl for k in ("F", "Fe", "E")):
        raise IdentificationError(
            "the deadbeat ARX method needs the controller gains F, Fe and E in "
            "data.loop['controller'] (eqs. (39), (42)); this recording lacks them"
        )
    out = {k: np.atleast_2d(np.asarray(ctrl[k], dtype=float)) for k in ("F", "Fe", "E")}
    C = loop.get("C")
    if C is None and isinstance(loop.get("observer"), Mapping):
        C = loop["observer"].get("C")
    if C is None:
        C = C_AMB
    out["C"] = np.atleast_2d(np.asarray(C, dtype=float))
    obs = loop.get("observer")
    if isinstance(obs, Mapping) and obs.get("G") is not None:
        out["G"] = np.atleast_2d(np.asarray(obs["G"], dtype=float))
    return out


def deadbeat_regression(
    y: np.ndarray, u: np.ndarray, u_f: np.ndarray, *, E: Any, Fe: Any, start: int
) -> tuple[np.ndarray, np.ndarray]:
    """Left-hand side and regressors of eq. (47), rows ``k = start .. N-2``.

    ``[y(k+1); u_f(k+1) + Fe E y(k+1)] = Theta [y(k); u_f(k); u(k)]``: the known
    term ``b0 v(k+1) = [0; -Fe E y(k+1)]`` is moved to the left (trap (b)) and
    ``y(k)`` appears once (trap (a)); ``Theta = [Theta_y, Theta_f, Theta_u]``
    with ``Theta_y = a1[:, :ny] + b1[:, nu:]``, ``Theta_f = a1[:, ny:]``,
    ``Theta_u = b1[:, :nu]``.

    Returns
    -------
    lhs : ndarray, shape (N - 1 - start, ny + nu)
    phi : ndarray, shape (N - 1 - start, ny + 2 nu)
    """
    lhs, parts = deadbeat_regression_blocks(y, u, u_f, E=E, Fe=Fe, start=start)
    return np.hstack(lhs), np.hstack(parts)


def deadbeat_regression_blocks(
    y: np.ndarray, u: np.ndarray, u_f: np.ndarray, *, E: Any, Fe: Any, start: int
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """:func:`deadbeat_regression` as column blocks: ``lhs = [y(k+1), u_f(k+1) + Fe E y(k+1)]``
    (a view of ``y`` and one ``(N, nu)`` array) and ``phi`` (views, no copy)."""
    E = np.atleast_2d(np.asarray(E, dtype=float))
    Fe = np.atleast_2d(np.asarray(Fe, dtype=float))
    N = y.shape[0]
    if not 0 <= start < N - 1:
        raise DataError(f"`start` must be in 0..{N - 2}; got {start}")
    nxt = slice(start + 1, N)
    cur = slice(start, N - 1)
    # eq. (47), b0 v(k+1) moved left: [y(k+1), u_f(k+1) + Fe E y(k+1)]; y(k+1) stays a
    # view (the regression takes column blocks), only the second block is new
    w = y[nxt] @ (Fe @ E).T
    w += u_f[nxt]
    return [y[nxt], w], [y[cur], u_f[cur], u[cur]]


def plant_from_observer_controller(
    theta: np.ndarray, P: np.ndarray, *, nx: int, ny: int, nu: int
) -> tuple[np.ndarray, np.ndarray]:
    """Discrete ``A, B`` from ``Theta = [Theta_y, Theta_f, Theta_u]`` (eqs. (49)-(51)).

    With the split ``Gd' = 0`` (trap (a)): ``a1 = [Theta_y, Theta_f]``, ``b1 =
    [Theta_u, 0]``, so ``L = P^-1 a1 P`` (eq. (50)), ``M11 = (P^-1 Theta_u)[:nx]``,
    ``Gd = 0`` and ``A = L11`` (eq. (51)); any other split gives the same ``A``.
    """
    Theta = np.asarray(theta, dtype=float).reshape(ny + nu, ny + 2 * nu)
    a1 = Theta[:, : ny + nu]
    L = np.linalg.solve(P, a1 @ P)  # eq. (50)
    M = np.linalg.solve(P, Theta[:, ny + nu :])  # eq. (50), u-columns of b1
    return L[:nx, :nx], M[:nx]  # eq. (51) with Gd' = 0: A = L11, B = M11


def observer_controller_arx(
    theta: np.ndarray, P: np.ndarray, Gd: np.ndarray, *, C: np.ndarray, nu: int
) -> dict[str, np.ndarray]:
    """The paper's ``a1, b1, L, M`` for the split ``Gd`` of the ``y(k)`` coefficient (eq. (48)).

    ``a1 = [Theta_y + P [Gd; 0], Theta_f]``, ``b1 = [Theta_u, -P [Gd; 0]]``;
    then eqs. (50)-(51). Returned blocks let one check the structure
    ``L12 = 0, L21 = 0, L22 = I, M21 = M22 = 0`` of eq. (49).
    """
    ny, nx = C.shape
    Theta = np.asarray(theta, dtype=float).reshape(ny + nu, ny + 2 * nu)
    ne = P.shape[0] - nx
    PG = P @ np.vstack([Gd, np.zeros((ne, ny))])
    a1 = np.hstack([Theta[:, :ny] + PG, Theta[:, ny : ny + nu]])
    b1 = np.hstack([Theta[:, ny + nu :], -PG])
    L = np.linalg.solve(P, a1 @ P)
    M = np.linalg.solve(P, b1)
    B = M[:nx, :nu]  # eq. (51)
    Gd_hat = -M[:nx, nu:]  # eq. (51)
    A = L[:nx, :nx] - Gd_hat @ C  # eq. (51)
    return {"a1": a1, "b1": b1, "L": L, "M": M, "A": A, "B": B, "Gd": Gd_hat}


def observer_noise_ma(
    Theta: np.ndarray,
    P: np.ndarray,
    *,
    G: np.ndarray,
    A_obs: np.ndarray,
    C: np.ndarray,
    max_terms: int = 200,
) -> list[np.ndarray]:
    """The equation error of eq. (47) as a moving average of white measurement noise.

    The regression uses the measured ``y_m = y + w`` where the observer/controller
    has ``yh = C xh``. With the observer's model equal to the plant, the observer
    error obeys ``x - xh -> (A + G C)(x - xh) + G w``, so
    ``eta = y_m - yh = sum_j H_j w(k - j)`` with ``H_0 = I``,
    ``H_j = C (A_o + G C)^(j-1) G``. Substituting ``yh = y_m - eta`` in the exact
    relation gives the equation error

        eps(k) = [eta(k+1); 0] - (Theta_y + P [G; 0]) eta(k)
               = sum_j C_j w(k + 1 - j),  C_j = [I; 0] H_j - Xi H_{j-1},

    ``Xi = Theta_y + P [G; 0]`` (the ``y`` coefficient of ``a1`` for the loop's
    own split). A deadbeat observer makes it finite (``H_j = 0`` for ``j > 2``);
    otherwise terms are kept until ``(A_o + G C)^j`` is negligible.
    """
    ny = C.shape[0]
    nyu = P.shape[0]
    ne = P.shape[0] - C.shape[1]
    Xi = Theta[:, :ny] + P @ np.vstack([G, np.zeros((ne, ny))])
    S1 = np.vstack([np.eye(ny), np.zeros((nyu - ny, ny))])
    Abar = A_obs + G @ C
    H = [np.eye(ny)]
    Ak = np.eye(Abar.shape[0])
    scale = max(float(np.max(np.abs(C @ G))), 1e-300)
    for _ in range(max_terms):
        Hj = C @ Ak @ G
        if np.max(np.abs(Hj)) <= 1e-13 * scale:
            break
        H.append(Hj)
        Ak = Ak @ Abar
    out = [S1 @ H[0]]
    for j in range(1, len(H) + 1):
        Cj = -Xi @ H[j - 1]
        if j < len(H):
            Cj = Cj + S1 @ H[j]
        out.append(Cj)
    return out


def _integrator_block_residual(L: np.ndarray, P: np.ndarray, G: np.ndarray, *, nx: int) -> float:
    # Eq. (49) says P^-1 a1 P = diag(A + Gd C, I): the blocks coupling the
    # observer state and the integrator are 0 and the integrator block is I.
    # Measured unit-free: scale the states by their RMS along the record.
    ne = P.shape[0] - nx
    if ne == 0:
        return 0.0
    # z = P^-1 yu (eq. 46) sample by sample; its mean square is the diagonal of
    # P^-1 G P^-T with G the second moment of the deviations of yu = [y; u_f] from the
    # operating point, so only that small matrix is needed (the caller's G: the
    # regression's own centred Gram, no pass over the record).
    M = sla.solve(P, sla.solve(P, G).T)
    sz = np.sqrt(np.maximum(np.diag(M), 0.0))
    sz[sz == 0] = 1.0
    Ls = L * sz[None, :] / sz[:, None]
    return max(
        float(np.max(np.abs(Ls[:nx, nx:]))),
        float(np.max(np.abs(Ls[nx:, :nx]))),
        float(np.max(np.abs(Ls[nx:, nx:] - np.eye(ne)))),
    )


def _noise_model(
    covariance: str,
    data: ClosedLoopData,
    P: np.ndarray,
    C: np.ndarray,
    mats: Mapping[str, np.ndarray],
    notes: list[str],
) -> Any:
    if covariance not in ("white-noise", "hac"):
        raise DataError(f"`covariance` must be 'white-noise' or 'hac'; got {covariance!r}")
    if covariance == "hac":
        return None
    obs = data.loop.get("observer") if isinstance(data.loop, Mapping) else None
    if "G" not in mats or not isinstance(obs, Mapping) or obs.get("A") is None:
        notes.append(
            "the observer is not recorded: the covariance uses a lag window (hac) instead of "
            "the white-noise model"
        )
        return None
    G = mats["G"]
    A_obs = np.atleast_2d(np.asarray(obs["A"], dtype=float))

    def noise_ma(Theta: np.ndarray) -> list[np.ndarray]:
        return observer_noise_ma(Theta, P, G=G, A_obs=A_obs, C=C)

    return noise_ma


def _signals(data: ClosedLoopData) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if not isinstance(data, ClosedLoopData):
        raise DataError(f"`data` must be a ClosedLoopData; got {type(data).__name__}")
    if data.p != 1:
        raise DataError(
            f"the deadbeat ARX method needs one output sample per control period; got p={data.p}"
        )
    if data.u is None and data.u_f is not None and data.r is not None:
        data = data.with_plant_input()
    if data.u is None or data.u_f is None:
        raise DataError("the deadbeat ARX method needs the plant input u and the feedback u_f")
    return np.asarray(data.y), np.asarray(data.u), np.asarray(data.u_f)


#: The options of the deadbeat methods, from the AMB methods' shared declaration.
_OPTION_NAMES = ("instruments", "skip", "instrument_lags", "covariance", "hac_lags", "m", "i0")


@declared(*(AMB_OPTIONS[n] for n in ("estimator", *_OPTION_NAMES)))
def fit_deadbeat(
    data: ClosedLoopData,
    *,
    estimator: str = "ls",
    instruments: str = "auto",
    skip: int = 10,
    instrument_lags: int = 30,
    covariance: str = "white-noise",
    hac_lags: int = 8,
    m: float | None = None,
    i0: float | None = None,
) -> IdentificationResult:
    """Physical AMB model from the observer/controller ARX (Gosiewski & Paszowski, eqs. (44)-(51)).

    Parameters
    ----------
    data : ClosedLoopData
        ``y = [x, i1, i2]``, ``u``, ``u_f`` (and ``r`` for IV), with
        ``data.loop["controller"]`` holding ``F``, ``Fe``, ``E`` and ``C`` known.
    estimator : {"ls", "iv"}
        ``"ls"``: the paper's least squares (biased under measurement noise).
        ``"iv"``: instrumental variables from the excitation ``r``.

    The other options are declared once (listed under *Options*):
    ``instruments`` for ``"iv"``; ``skip`` (a deadbeat observer converges in
    two samples); ``covariance="white-noise"`` (needs the observer in
    ``data.loop``) writes the equation error exactly as a moving average of
    white measurement noise (:func:`observer_noise_ma`).

    Returns
    -------
    IdentificationResult
        Discrete model and continuous model in physical coordinates
        ``[x, dx/dt, i1, i2]``, v1..v9 and physical parameters with covariance,
        the paper's ``a1, b0, b1, L, M`` in ``extras``.

    Raises
    ------
    IdentificationError
        Loop gains missing, ``[[C, 0], [-F, Fe]]`` singular, or a rank-deficient
        regression.

    Notes
    -----
    Exact without noise only when the observer runs on the true plant (see the
    module notes); the ``physical`` method is the one for diagnosis.

    References
    ----------
    Z. Gosiewski, M. Paszowski, "Diagnostics of magnetic bearings via
    identification of its physical parameters".
    """
    y, u, u_f = _signals(data)
    mats = loop_matrices(data)
    C, F, Fe, E = mats["C"], mats["F"], mats["Fe"], mats["E"]
    ny, nx = C.shape
    nu = F.shape[0]
    if y.shape[1] != ny or u.shape[1] != nu:
        raise DataError(
            f"the recording has {y.shape[1]} outputs and {u.shape[1]} inputs; the loop's C "
            f"and F expect {ny} and {nu}"
        )
    P = loop_output_matrix(C, F, Fe)  # [Cbar Ctilde] of eq. (45)
    N = y.shape[0]
    used_instruments, start = _instrument_plan(data, estimator, instruments, skip, instrument_lags)
    notes: list[str] = []
    if N - 1 - start <= 3 * (ny + 2 * nu):
        raise DataError(
            f"the recording has {N} samples; the deadbeat ARX needs well over "
            f"{start + 1 + 3 * (ny + 2 * nu)} (skip={skip})"
        )
    lhs, phi = deadbeat_regression_blocks(y, u, u_f, E=E, Fe=Fe, start=start)  # eq. (47)
    Z = _instrument_blocks(data, used_instruments, start, instrument_lags)
    names_y = data.channel_names("y")
    names_u = data.channel_names("u")
    labels = (
        [f"{n}(k)" for n in names_y]
        + [f"u_f{i + 1}(k)" for i in range(nu)]
        + [f"{n}(k)" for n in names_u]
    )
    noise_ma = _noise_model(covariance, data, P, C, mats, notes)
    fit = solve_regression_blocks(
        lhs, phi, Z, hac_lags=hac_lags, labels=labels, noise_ma=noise_ma, intercept=True
    )

    def to_discrete(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return plant_from_observer_controller(theta, P, nx=nx, ny=ny, nu=nu)  # eqs. (49)-(51)

    paper = _paper_form(fit, P, mats, notes)
    options = {
        "estimator": estimator,
        "instruments": used_instruments,
        "skip": int(skip),
        "instrument_lags": int(instrument_lags),
        "covariance": covariance,
        "hac_lags": int(hac_lags),
        "m": m,
        "i0": i0,
    }
    # One-step fit from the sums the regression already has: the residual sums of
    # squares of its second pass and the centred sums of squares of the left-hand side
    # from its triangular factor (LinearFit.gram), instead of another pass over lhs.
    nyu = ny + nu
    osf = one_step_fit_percent(fit.residual_sum_of_squares, np.diag(fit.gram)[-nyu:])
    res = amb_result(
        method="deadbeat-iv" if estimator == "iv" else "deadbeat-arx",
        to_discrete=to_discrete,
        fit=fit,
        Y=None,
        one_step_fit=osf,
        lhs_names=[*names_y, *(f"u_f{i + 1}" for i in range(nu))],
        dt=data.dt,
        loop=data.loop,
        n_samples=fit.n_rows,
        options=options,
        notes=notes,
        extras=paper,
        m=m,
        i0=i0,
    )
    dc = DCLevels(data.dt, y.shape[1], u.shape[1])
    dc.update(y, u)
    return with_dc_levels(res, dc, data.loop)


def _instrument_plan(
    data: ClosedLoopData, estimator: str, instruments: str, skip: int, instrument_lags: int
) -> tuple[str | None, int]:
    """The instruments used (None for least squares) and the first row of the regression."""
    start = int(skip)
    if estimator != "iv":
        return None, start
    if data.r is None:
        raise DataError("estimator='iv' needs the excitation r in the recording")
    kind = instruments
    if kind == "auto":
        kind = "loop" if isinstance(data.loop.get("observer"), Mapping) else "lags"
    if kind == "lags":
        start = max(start, int(instrument_lags))
    return kind, start


def _instrument_blocks(
    data: ClosedLoopData, kind: str | None, start: int, instrument_lags: int
) -> list[np.ndarray] | None:
    """Instruments for rows ``k = start .. N-2``: the loop's response to ``r``, or lagged ``r``."""
    if kind is None:
        return None
    r = np.asarray(data.r)
    N = r.shape[0]
    if kind == "loop":
        sim = simulate_loop_signals(data.loop, r - r[0], dt=data.dt)  # offset-free (physical.py)
        return [sim[k][start : N - 1] for k in ("y", "u_f", "u")]
    return [r[start - j : N - 1 - j] for j in range(int(instrument_lags) + 1)]  # lagged_excitation


def _paper_form(
    fit: Any, P: np.ndarray, mats: Mapping[str, np.ndarray], notes: list[str]
) -> dict[str, Any]:
    """The paper's ``a1, b0, b1, L, M`` (eqs. (47)-(49)) and how well the loop structure holds."""
    C, Fe, E = mats["C"], mats["Fe"], mats["E"]
    ny, nx = C.shape
    nu = mats["F"].shape[0]
    Gd_split = mats.get("G", np.zeros((nx, ny)))
    paper = observer_controller_arx(fit.coefficients, P, Gd_split, C=C, nu=nu)
    L, M = paper["L"], paper["M"]
    # second moment of the centred [y(k); u_f(k)] over the regression's rows: the first
    # ny + nu regressors (eq. (47)), from the fit's Gram
    G = fit.gram[: ny + nu, : ny + nu] / fit.n_rows
    struct = _integrator_block_residual(L, P, G, nx=nx)
    b0 = np.zeros((ny + nu, nu + ny))
    b0[ny:, nu:] = -Fe @ E  # eq. (48): b0 v(k+1) = [0; -Fe E y(k+1)]
    notes.append(
        "the observer gain Gd is not identifiable from converged closed-loop data (only the "
        "sum of the y(k) coefficients of a1 and b1 is); a1, b1 in extras use the split "
        + ("Gd' = G of the loop" if "G" in mats else "Gd' = 0")
        + "; A and B do not depend on it"
    )
    if struct > 1e-6:
        notes.append(
            f"the integrator block of P^-1 a1 P departs from [0, I] by {struct:.3g}: the "
            "observer/controller ARX is not exact on these data (noise, or an observer whose "
            "model is not the running plant); consider estimator='iv' or method 'physical'"
        )
    return {
        "P": P,
        "a1": paper["a1"],
        "b0": b0,
        "b1": paper["b1"],
        "L": L,
        "M": M,
        "Gd_split": Gd_split,
        "loop_structure_residual": struct,
    }


def fit_deadbeat_arx(data: ClosedLoopData, **options: Any) -> IdentificationResult:
    """The paper's method with least squares (``fit_deadbeat(estimator="ls")``)."""
    if "estimator" in options:
        raise DataError("fit_deadbeat_arx is the least-squares method; use fit_deadbeat")
    return fit_deadbeat(data, estimator="ls", **options)


def fit_deadbeat_iv(data: ClosedLoopData, **options: Any) -> IdentificationResult:
    """The paper's observer/controller ARX estimated by instrumental variables.

    Consistent under white (or coloured) measurement noise independent of ``r``
    when the observer runs on the true plant; see :func:`fit_deadbeat`.
    """
    if "estimator" in options:
        raise DataError("fit_deadbeat_iv is the IV method; use fit_deadbeat")
    return fit_deadbeat(data, estimator="iv", **options)


#: Registered with ``maglevid identify --method``.
METHODS = {"deadbeat-arx": fit_deadbeat_arx, "deadbeat-iv": fit_deadbeat_iv}
#: Their options: fit_deadbeat's, the estimator fixed by the method.
_FIXED_ESTIMATOR = tuple(o for o in fit_deadbeat.options if o.name != "estimator")
OPTIONS = {"deadbeat-arx": _FIXED_ESTIMATOR, "deadbeat-iv": _FIXED_ESTIMATOR}
