"""Two-stage (projection) closed-loop identification: instruments from the reference.

Van den Hof & Schrama (1993) identify the sensitivity ``r -> u`` first (stage 1)
and the plant from the simulated noise-free input ``u_r = S r`` (stage 2); Forssell
& Ljung (2000) made stage 1 a non-causal FIR projection. For an *unstable* plant
stage 2 cannot be an output-error fit (it would simulate ``G u_r`` open loop), so it
is an equation-error fit in which **every** regressor - lagged outputs as well as
lagged inputs - is replaced by its projection onto the reference. That is
two-stage least squares (2SLS, an instrumental-variable estimator)::

    stage 1:  Phi_hat = Z (Z'Z)^+ Z' Phi,  Z_t = [r_{t+n_nc}, ..., r_{t-n_fir+1}, 1_seg]
    stage 2:  theta   = argmin || y - Phi_hat theta ||,  Phi_t = [-y_{t-1..t-na}, x_{t-nk..}]

Only the part of the data that the reference explains is used, so the estimate is
consistent whatever the noise model, as long as the reference is uncorrelated with
the noise and persistently exciting enough (check the stage-1 fits and
:func:`maglevid.diagnose.quality.persistent_excitation_order`). Its covariance is
the 2SLS sandwich with a Newey-West (Bartlett) estimate of the coloured equation
error's long-run variance (Newey & West 1987).

References
----------
P. M. J. Van den Hof, R. J. P. Schrama, "An indirect method for transfer function
estimation from closed loop data", Automatica 29(6):1523-1527, 1993.
U. Forssell, L. Ljung, "A projection method for closed-loop identification",
IEEE TAC 45(11):2101-2106, 2000.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

import numpy as np

from maglevid.data import ClosedLoopData
from maglevid.exceptions import IdentificationError
from maglevid.identify.closedloop import (
    continuous_or_note,
    extend_covariance,
    fit_percent,
    innovations_from_polynomials,
    pole_statistics,
    resolve_channel,
    resolve_segments,
    simo_polynomials_to_state_space,
)
from maglevid.identify.options import Option, declared
from maglevid.identify.pem import OPTIONS_PEM
from maglevid.identify.result import IdentificationResult

__all__ = ["METHODS", "OPTIONS_TWO_STAGE", "fit_two_stage", "newey_west"]

log = logging.getLogger(__name__)


def newey_west(X: np.ndarray, e: np.ndarray, lags: int) -> np.ndarray:
    """Long-run covariance of ``X_t e_t`` with Bartlett weights (Newey & West 1987)::

    S = G_0 + sum_{l=1}^{L} (1 - l/(L+1)) (G_l + G_l'),  G_l = sum_t x_t e_t e_{t-l} x_{t-l}'
    """
    V = X * e[:, None]
    S = V.T @ V
    for lag in range(1, lags + 1):
        G = V[lag:].T @ V[:-lag]
        S += (1.0 - lag / (lags + 1.0)) * (G + G.T)
    return S


#: pem's declarations of the options both methods take.
_PEM = {o.name: o for o in OPTIONS_PEM}
#: The options of ``two-stage`` (defaults: :func:`fit_two_stage`'s signature).
OPTIONS_TWO_STAGE = (
    _PEM["output"], _PEM["input"],
    Option("reference", "channel", "external signal uncorrelated with the noise (instruments)"),
    _PEM["na"], _PEM["nb"], _PEM["nk"],
    Option("n_fir", "int", "causal lags of the reference in stage 1 (cover the settling)", low=1),
    Option("n_noncausal", "int", "non-causal lags of the reference (Forssell-Ljung)", low=0),
    _PEM["segments"],
    Option("intercept", "bool", "one intercept per segment, in both stages"),
    Option("hac_lags", "int", "Newey-West window (default na + nb + nk + 10)", low=0),
)  # fmt: skip


@declared(*OPTIONS_TWO_STAGE)
def fit_two_stage(
    data: ClosedLoopData,
    *,
    output: str = "y:0",
    input: str = "u:0",
    reference: str = "r:0",
    na: int = 2,
    nb: int = 2,
    nk: int = 1,
    n_fir: int = 40,
    n_noncausal: int = 0,
    segments: Sequence[Sequence[int]] | None = None,
    intercept: bool = True,
    hac_lags: int | None = None,
) -> IdentificationResult:
    """Two-stage (projection / 2SLS) estimate of a SISO plant from closed-loop data.

    The options are declared in :data:`OPTIONS_TWO_STAGE`. The steps are the
    module's equations: the instruments ``Z`` and regressors ``Phi``
    (:func:`_instruments_and_regressors`), stage 1 (projection of ``Phi`` onto
    ``Z``), stage 2 (least squares on the projected regressors) and its
    Newey-West sandwich covariance (:func:`_two_stage_least_squares`), then the
    one-step prediction fit.

    Returns
    -------
    IdentificationResult
        ``parameters``: ``a1..``, ``b..``, ``pole_z``, ``pole_rad_s`` (HAC covariance);
        ``fit``: one-step prediction fit of the ARX predictor and the stage-1 R^2 of
        the projected input and output (how much of each the reference explains).
    """
    ych = resolve_channel(data, output)
    xch = resolve_channel(data, input)
    rch = resolve_channel(data, reference)
    y, x, r = ych.values, xch.values, rch.values
    h = max(na, nk + nb - 1)
    # Rows t need y, x back to t - h and r back to t - h - n_fir + 1 (the lags of the
    # regressors are projected with instruments that reach as far) and forward n_nc.
    back = h + n_fir - 1
    segs = resolve_segments(data, segments, min_length=back + n_noncausal + 10 * (na + nb))
    hl = na + nb + nk + 10 if hac_lags is None else int(hac_lags)
    Z, Phi, Y, seg_id = _instruments_and_regressors(
        y, x, r, segs, na=na, nb=nb, nk=nk, n_fir=n_fir, n_noncausal=n_noncausal,
        intercept=intercept,
    )  # fmt: skip
    theta, cov_full, stage1 = _two_stage_least_squares(Z, Phi, Y, seg_id, len(segs), hl, na)
    n_model = na + nb
    cov = 0.5 * (cov_full[:n_model, :n_model] + cov_full[:n_model, :n_model].T)
    th = theta[:n_model]
    names = [f"a{j}" for j in range(1, na + 1)] + [f"b{j}" for j in range(nk, nk + nb)]
    notes = [
        f"plant {xch.name} -> {ych.name}; instruments: {rch.name} lags "
        f"{-n_noncausal}..{n_fir + h - 1} (2SLS)",
        f"covariance: 2SLS sandwich, Newey-West with {hl} lags",
    ]
    if stage1["stage1_r2_input"] < 0.1:
        notes.append(
            f"the reference explains only {100 * stage1['stage1_r2_input']:.1f} % of the input: "
            "weak instruments, expect a large variance and a bias toward the direct estimate"
        )
    pv, Jp, pn = pole_statistics(lambda t: np.r_[1.0, t[:na]], th, data.dt)
    notes.extend(pn)
    params = dict(zip(names, th.tolist()))
    params.update(pv)
    a = np.r_[1.0, th[:na]]
    b = np.r_[np.zeros(nk), th[na:n_model]]
    yhat = _one_step_prediction(y, x, segs, a, b, theta[n_model:] if intercept else None, h)
    fit = {"one_step_fit_percent": fit_percent(y, yhat, segs), **stage1}
    model = simo_polynomials_to_state_space(a, [b], data.dt, input_name=xch.name,
                                            output_names=(ych.name,))  # fmt: skip
    cont = continuous_or_note(model, notes) if nk >= 1 else None
    options: dict[str, Any] = {
        "output": output, "input": input, "reference": reference, "na": na, "nb": nb,
        "nk": nk, "n_fir": n_fir, "n_noncausal": n_noncausal,
        "segments": [list(sg) for sg in segs], "intercept": intercept, "hac_lags": hl,
    }  # fmt: skip
    resid = y - yhat  # NaN where there is no prediction (outside the segments)
    return IdentificationResult(
        method="two-stage",
        model=model,
        parameters=params,
        covariance=extend_covariance(cov, [Jp]),
        n_samples=int(sum(b0 - a0 for a0, b0 in segs)),
        options=options,
        residuals=resid[:, None],
        fit=fit,
        notes=tuple(notes),
        continuous_model=cont,
        extras={"A": a.tolist(), "B": b.tolist(), "intercepts": theta[n_model:].tolist()},
    )


def _instruments_and_regressors(
    y: np.ndarray,
    x: np.ndarray,
    r: np.ndarray,
    segs: list[tuple[int, int]],
    *,
    na: int,
    nb: int,
    nk: int,
    n_fir: int,
    n_noncausal: int,
    intercept: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``Z_t = [r_{t+n_nc}, ..., r_{t-n_fir-h+1}, 1_seg]`` and ``Phi_t = [-y_{t-1..t-na},
    x_{t-nk..}, 1_seg]`` with the targets ``y_t`` and each row's segment."""
    h = max(na, nk + nb - 1)
    back = h + n_fir - 1
    rows_Z, rows_P, tgt, sid = [], [], [], []
    for s, (a0, b0) in enumerate(segs):
        t = np.arange(a0 + back, b0 - n_noncausal)
        rows_Z.append(np.column_stack([r[t + j] for j in range(n_noncausal, -n_fir - h, -1)]))
        rows_P.append(
            np.column_stack(
                [-y[t - j] for j in range(1, na + 1)] + [x[t - nk - j] for j in range(nb)]
            )
        )
        tgt.append(y[t])
        sid.append(np.full(t.size, s))
    Z = np.vstack(rows_Z)
    Phi = np.vstack(rows_P)
    seg_id = np.concatenate(sid)
    if intercept:
        D = (seg_id[:, None] == np.arange(len(segs))[None, :]).astype(float)
        Z = np.hstack([Z, D])
        Phi = np.hstack([Phi, D])
    if Z.shape[0] < 3 * Z.shape[1]:
        raise IdentificationError(
            f"{Z.shape[0]} rows for {Z.shape[1]} instruments; "
            "give longer segments or a smaller n_fir"
        )
    return Z, Phi, np.concatenate(tgt), seg_id


def _two_stage_least_squares(
    Z: np.ndarray,
    Phi: np.ndarray,
    Y: np.ndarray,
    seg_id: np.ndarray,
    n_segments: int,
    hac_lags: int,
    na: int,
) -> tuple[np.ndarray, np.ndarray, dict[str, float]]:
    """Stage 1 ``Phi_hat = Z (Z'Z)^+ Z' Phi``, stage 2 ``theta = argmin ||Y - Phi_hat theta||``;
    ``(theta, sandwich covariance, stage-1 R^2 of the output and the input)``."""
    # Stage 1: projection of every regressor (and of y, for the diagnostics) onto Z.
    coef, *_ = np.linalg.lstsq(Z, np.column_stack([Phi, Y]), rcond=None)
    proj = Z @ coef
    Phi_hat, Y_hat = proj[:, :-1], proj[:, -1]

    def r2(a: np.ndarray, b: np.ndarray) -> float:
        """R^2 of a projection, against the per-segment means."""
        num = np.sum((a - b) ** 2)
        den = sum(np.sum((a[seg_id == s] - a[seg_id == s].mean()) ** 2) for s in range(n_segments))
        return float(1.0 - num / den) if den > 0 else float("nan")

    xcol = na  # first input regressor column: x_{t-nk}
    stage1 = {
        "stage1_r2_output": r2(Y, Y_hat),
        "stage1_r2_input": r2(Phi[:, xcol], Phi_hat[:, xcol]),
    }
    # Stage 2: least squares of the *measured* output on the projected regressors (2SLS).
    sv = np.linalg.svd(Phi_hat, compute_uv=False)
    if sv[-1] <= sv[0] * max(Phi_hat.shape) * np.finfo(float).eps:
        raise IdentificationError(
            "the projected regressors are rank deficient: the reference does not excite "
            "the loop enough for this model order (see stage-1 R^2)"
        )
    theta, *_ = np.linalg.lstsq(Phi_hat, Y, rcond=None)
    e = Y - Phi @ theta  # equation error with the measured regressors
    # Covariance: (Phi_hat' Phi_hat)^-1 S (Phi_hat' Phi_hat)^-1 by QR (no explicit inverse).
    # With Phi_hat = Q R:  (R'R)^-1 S (R'R)^-1 = R^-1 B R^-T,  B = R^-T S R^-1.
    _, R = np.linalg.qr(Phi_hat)
    S = newey_west(Phi_hat, e, hac_lags)
    B = np.linalg.solve(R.T, np.linalg.solve(R.T, S).T)
    cov_full = np.linalg.solve(R, np.linalg.solve(R, B).T).T
    return theta, cov_full, stage1


def _one_step_prediction(
    y: np.ndarray,
    x: np.ndarray,
    segs: list[tuple[int, int]],
    a: np.ndarray,
    b: np.ndarray,
    intercepts: np.ndarray | None,
    h: int,
) -> np.ndarray:
    """One-step prediction of the ARX predictor on each segment (NaN for its first ``h``)."""
    yhat = np.full(y.size, np.nan)
    for s, (a0, b0) in enumerate(segs):
        d = intercepts[s] if intercepts is not None else 0.0
        inn = innovations_from_polynomials(a, [b, np.array([d])])
        U = np.column_stack([x[a0:b0], np.ones(b0 - a0)])
        p1 = inn.predict(y[a0:b0, None], U, k=1)[:, 0]
        p1[:h] = np.nan
        yhat[a0:b0] = p1
    return yhat


METHODS = {"two-stage": fit_two_stage}
