"""Direct closed-loop identification by the prediction-error method (ARX, ARMAX, OE-type).

The direct method fits the plant from its measured input and output as if the
loop were open (Ljung 1999, sec. 13.4). It is consistent in closed loop when the
noise model can describe the true noise, and it needs no knowledge of the
controller, so it survives nonlinear (saturating, clamped) controllers. For an
unstable plant the *predictor* must be stable; every structure here keeps it so:

``arx``     ``A y = B u + d + e``. Predictor polynomial 1: always stable. Linear
            least squares (``lstsq``).
``armax``   ``A y = B u + d + C e``. Predictor ``1/C``; ``C`` is kept stable by
            reflecting roots outside the unit circle (a change of the noise model
            only, never of ``A`` or ``B``).
``oe``      ``y = B/F u + H e`` with the Forssell & Ljung (1999) noise model
            ``H = F_a*/F_a`` (``F_a``: the factor of ``F`` with roots outside the
            unit circle, ``F_a*`` its monic mirror). For a stable ``F``, ``H = 1``
            and this is output error; for an unstable one the predictor
            ``F y = B u + F_s F_a* e`` is stable although ``B/F`` is not.

``d`` is one intercept per segment (the operating point). Validation is by one-step
and ``k``-step *prediction*, never by an open-loop simulation of an unstable model.

References
----------
L. Ljung, *System Identification: Theory for the User*, 2nd ed., 1999, ch. 7, 9, 13.
U. Forssell, L. Ljung, "Identification of unstable systems using output error and
Box-Jenkins model structures", IEEE TAC 45(1):137-141, 2000.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import optimize, signal

from maglevid.data import ClosedLoopData
from maglevid.exceptions import IdentificationError
from maglevid.identify.closedloop import (
    continuous_or_note,
    covariance_from_jacobian,
    extend_covariance,
    fit_percent,
    innovations_from_polynomials,
    pole_statistics,
    resolve_channel,
    resolve_segments,
    simo_polynomials_to_state_space,
    stabilise_noise_polynomial,
)
from maglevid.identify.options import Option, declared
from maglevid.identify.result import IdentificationResult

__all__ = ["METHODS", "OPTIONS_PEM", "fit_pem"]

log = logging.getLogger(__name__)

STRUCTURES = ("arx", "armax", "oe")


def _split_unstable(f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``F = F_s F_a``; returns ``(F_s, F_a*)`` with ``F_a*`` the monic mirror of ``F_a``."""
    r = np.roots(f)
    bad = np.abs(r) > 1.0
    Fs = np.real(np.poly(r[~bad])) if (~bad).any() else np.array([1.0])
    Fa_star = np.real(np.poly(1.0 / np.conj(r[bad]))) if bad.any() else np.array([1.0])
    return Fs, Fa_star


#: The options of ``pem`` (defaults: :func:`fit_pem`'s signature).
OPTIONS_PEM = (
    Option("output", "channel", "plant output channel"),
    Option("input", "channel", "plant input channel (a measured current: nk = 0)"),
    Option("structure", "str", "model structure of eq. A y = B u + d + C e", choices=STRUCTURES),
    Option("na", "int", "order of A (of F for oe)", low=1),
    Option("nb", "int", "number of B coefficients", low=1),
    Option("nk", "int", "input delay in samples (0: a term in u_k)", low=0),
    Option("nc", "int", "order of C (armax only)", low=0),
    Option("segments", "segments", "pieces [start, stop) of the record used (default all)"),
    Option("intercept", "bool", "one intercept d per segment (the operating point)"),
    Option("k_step", "int", "horizon of the k-step prediction fit", low=1),
    Option("burn_in", "int", "samples dropped per segment for filtered residuals", low=0),
    Option("max_nfev", "int", "limit on residual evaluations of the nonlinear fits", low=1),
)


@dataclass(frozen=True)
class _Structure:
    """Orders and structure of the polynomial model ``A y = B u + d + C e``."""

    structure: str
    na: int
    nb: int
    nk: int
    nc: int  # effective: 0 unless armax

    @property
    def n_model(self) -> int:
        return self.na + self.nb + self.nc

    @property
    def history(self) -> int:
        """Samples of history a prediction needs: ``max(na, nk + nb - 1)``."""
        return max(self.na, self.nk + self.nb - 1)

    def polynomials(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
        """``(A, B, C, flipped)`` of ``theta``; ``C`` is the (stable) predictor polynomial."""
        na, nb = self.na, self.nb
        a = np.r_[1.0, theta[:na]]
        b = np.r_[np.zeros(self.nk), theta[na : na + nb]]
        if self.structure == "armax":
            c, flipped = stabilise_noise_polynomial(np.r_[1.0, theta[na + nb : self.n_model]])
        elif self.structure == "oe":
            Fs, Fa_star = _split_unstable(a)
            c, flipped = np.convolve(Fs, Fa_star), False
        else:
            c, flipped = np.array([1.0]), False
        return a, b, c, flipped

    def names(self) -> list[str]:
        return (
            [f"{'f' if self.structure == 'oe' else 'a'}{j}" for j in range(1, self.na + 1)]
            + [f"b{j}" for j in range(self.nk, self.nk + self.nb)]
            + [f"c{j}" for j in range(1, self.nc + 1)]
        )


@declared(*OPTIONS_PEM)
def fit_pem(
    data: ClosedLoopData,
    *,
    output: str = "y:0",
    input: str = "u:0",
    structure: str = "arx",
    na: int = 2,
    nb: int = 2,
    nk: int = 1,
    nc: int = 1,
    segments: Sequence[Sequence[int]] | None = None,
    intercept: bool = True,
    k_step: int = 5,
    burn_in: int = 20,
    max_nfev: int | None = None,
) -> IdentificationResult:
    """Direct prediction-error identification of a SISO plant in closed loop.

    The options are declared in :data:`OPTIONS_PEM` (``maglevid identify
    --method list``); an invalid one is a :class:`DataError`. The steps follow
    the module notes: the ARX least squares (also the start of the nonlinear
    fits), the ARMAX/OE prediction-error fit, the parameters with their
    covariance, the one- and k-step prediction fits.

    Parameters
    ----------
    data : ClosedLoopData
        Same-rate record (``p = 1``). For the UAQ levitator the mechanical plant
        is ``input="y:1"`` (measured current) to ``output="y:0"`` (gap).

    Returns
    -------
    IdentificationResult
        ``parameters``: ``a1..`` (``f1..`` for ``oe``), ``b1..``, ``c1..`` and the
        largest real pole ``pole_z`` with ``pole_rad_s = ln(pole_z)/dt``;
        ``covariance``: asymptotic, from the Jacobian of the prediction errors
        (``s^2 (J'J)^-1``), extended to the pole by the delta method.

    Raises
    ------
    DataError
        Bad options or channels.
    IdentificationError
        Too few samples or a failed optimisation.
    """
    ych = resolve_channel(data, output)
    uch = resolve_channel(data, input)
    y, u = ych.values, uch.values
    st = _Structure(structure, na, nb, nk, nc if structure == "armax" else 0)
    segs = resolve_segments(data, segments, min_length=st.history + burn_in + 10)
    options: dict[str, Any] = {
        "output": output, "input": input, "structure": structure, "na": na, "nb": nb,
        "nk": nk, "nc": st.nc, "segments": [list(s) for s in segs], "intercept": intercept,
        "k_step": k_step, "burn_in": burn_in,
    }  # fmt: skip
    notes: list[str] = [
        f"plant {uch.name} -> {ych.name}; direct method: the controller is not used",
    ]
    Phi, Y = _arx_regression(y, u, segs, st, intercept)
    theta_arx, *_ = np.linalg.lstsq(Phi, Y, rcond=None)
    if structure == "arx":
        theta, resid, J = theta_arx, Y - Phi @ theta_arx, Phi
    else:
        theta, resid, J = _prediction_error_fit(
            y, u, segs, st, theta_arx, intercept, burn_in, max_nfev, notes
        )
    cov = covariance_from_jacobian(J, resid, theta.size)[: st.n_model, : st.n_model]
    th = theta[: st.n_model]
    pole_vals, Jp, pnotes = pole_statistics(lambda t: np.r_[1.0, t[:na]], th, data.dt)
    notes.extend(pnotes)
    params = dict(zip(st.names(), th.tolist()))
    params.update(pole_vals)
    a, b, c, _ = st.polynomials(theta)
    yhat1, yhatk, res_full = _predictions(y, u, segs, st, theta, intercept, burn_in, k_step)
    fit = {
        "one_step_fit_percent": fit_percent(y, yhat1, segs),
        f"{k_step}_step_fit_percent": fit_percent(y, yhatk, segs),
        "residual_rms": float(np.sqrt(np.nanmean(res_full**2))),
        "n_parameters": float(theta.size),
    }
    model = simo_polynomials_to_state_space(
        a, [b], data.dt, input_name=uch.name, output_names=(ych.name,)
    )
    if nk == 0:
        notes.append("nk = 0: the model has a direct term in the current input sample")
    cont = continuous_or_note(model, notes) if nk >= 1 else None
    if uch.signal == "y":
        notes.append(
            f"input {uch.name} is a measured signal, not a held command: a ZOH reading of the "
            "model (continuous_model) is approximate; the poles ln(z)/dt are not"
        )
    return IdentificationResult(
        method="pem",
        model=model,
        parameters=params,
        covariance=extend_covariance(cov, [Jp]),
        n_samples=int(sum(b0 - a0 for a0, b0 in segs)),
        options=options,
        residuals=res_full[:, None],
        fit=fit,
        notes=tuple(notes),
        continuous_model=cont,
        extras={
            "intercepts": theta[st.n_model :].tolist(),
            "A": a.tolist(),
            "B": b.tolist(),
            "C": c.tolist(),
            "predictor_poles": np.roots(c).tolist() if c.size > 1 else [],
            "one_step_prediction": yhat1,
        },
    )


def _arx_regression(
    y: np.ndarray, u: np.ndarray, segs: list[tuple[int, int]], st: _Structure, intercept: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Regressors and targets of ``A y = B u + d + e`` (ARX, by linear least squares):
    rows ``[-y_{t-1..t-na}, u_{t-nk..t-nk-nb+1}, 1_seg]``, target ``y_t``."""
    h = st.history
    rows, targets, seg_id = [], [], []
    for s, (a0, b0) in enumerate(segs):
        t = np.arange(a0 + h, b0)
        cols = [-y[t - j] for j in range(1, st.na + 1)] + [u[t - st.nk - j] for j in range(st.nb)]
        rows.append(np.column_stack(cols))
        targets.append(y[t])
        seg_id.append(np.full(t.size, s))
    Phi = np.vstack(rows)
    sid = np.concatenate(seg_id)
    if intercept:
        Phi = np.hstack([Phi, (sid[:, None] == np.arange(len(segs))[None, :]).astype(float)])
    if Phi.shape[0] < 5 * Phi.shape[1]:
        raise IdentificationError(
            f"{Phi.shape[0]} equations for {Phi.shape[1]} parameters; give longer segments"
        )
    return Phi, np.concatenate(targets)


def _prediction_error_fit(
    y: np.ndarray,
    u: np.ndarray,
    segs: list[tuple[int, int]],
    st: _Structure,
    theta_arx: np.ndarray,
    intercept: bool,
    burn_in: int,
    max_nfev: int | None,
    notes: list[str],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ARMAX / OE: minimise the filtered prediction errors ``e = (A y - B u - d) / C``
    (Levenberg-Marquardt from the ARX estimate); ``(theta, residuals, Jacobian)``."""
    n_model, h = st.n_model, st.history
    x0 = np.r_[theta_arx[: st.na + st.nb], np.zeros(st.nc), theta_arx[st.na + st.nb :]]

    def residuals(theta: np.ndarray) -> np.ndarray:
        a, b, c, _ = st.polynomials(theta)
        out = []
        for s, (a0, b0) in enumerate(segs):
            w = signal.lfilter(a, [1.0], y[a0:b0]) - signal.lfilter(b, [1.0], u[a0:b0])
            if intercept:
                w = w - theta[n_model + s]
            e = signal.lfilter([1.0], c, w)
            out.append(e[h + burn_in :])
        return np.concatenate(out)

    try:
        sol = optimize.least_squares(residuals, x0, method="lm", max_nfev=max_nfev)
    except ValueError as exc:  # non-finite residuals
        raise IdentificationError(f"the {st.structure} fit failed: {exc}") from exc
    if not sol.success:
        notes.append(f"optimiser stopped: {sol.message}")
    if st.polynomials(sol.x)[3]:
        notes.append("roots of C outside the unit circle were reflected (noise model only)")
    return sol.x, sol.fun, sol.jac


def _predictions(
    y: np.ndarray,
    u: np.ndarray,
    segs: list[tuple[int, int]],
    st: _Structure,
    theta: np.ndarray,
    intercept: bool,
    burn_in: int,
    k_step: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One-step and ``k_step``-step predictions of the model's predictor (NaN where the
    predictor has not enough history) and the one-step residuals, on the whole record."""
    a, b, c, _ = st.polynomials(theta)
    yhat1 = np.full(y.size, np.nan)
    yhatk = np.full(y.size, np.nan)
    res_full = np.full(y.size, np.nan)
    skip = st.history if st.structure == "arx" else st.history + burn_in
    for s, (a0, b0) in enumerate(segs):
        d = theta[st.n_model + s] if intercept else 0.0
        inn = innovations_from_polynomials(a, [b, np.array([d])], c)
        U = np.column_stack([u[a0:b0], np.ones(b0 - a0)])
        p1 = inn.predict(y[a0:b0, None], U, k=1)[:, 0]
        pk = inn.predict(y[a0:b0, None], U, k=k_step)[:, 0]
        p1[:skip] = np.nan
        pk[: skip + k_step - 1] = np.nan
        yhat1[a0:b0], yhatk[a0:b0] = p1, pk
        res_full[a0:b0] = y[a0:b0] - p1
    return yhat1, yhatk, res_full


METHODS = {"pem": fit_pem}
