"""Physical AMB parameters from closed-loop data without trusting the observer.

The method for the real diagnostic case. The deadbeat method of
:mod:`maglevid.identify.deadbeat` identifies the *observer/controller*; it is
exact only when the observer's model is the plant that runs. In a diagnosis
the observer was built on the nominal bearing and the bearing has changed,
so the observer state is not the plant state and that method is biased even
without noise; and a mirror-symmetric controller makes ``[[C, 0], [-F, Fe]]``
singular, so it cannot be used at all. This module identifies the *plant*
``u -> y`` directly. Whatever the controller and observer do, the plant obeys
its own difference equation, so the estimate is exact without noise for any
(linear) controller, and with instrumental variables from ``r`` it is
consistent under measurement noise.

1. An exact plant ARX with full-rank regressors
-----------------------------------------------
The plant has ``n = 4`` states and ``ny = 3`` outputs ``[x, i1, i2]``; only the
velocity is hidden. ``x(k-1)`` follows from ``[y(k); x_pos(k-1)]`` and ``u(k-1)``::

    [y(k); x_pos(k-1)] = [C A; e_0^T] x(k-1) + [C B; 0] u(k-1)

where ``[C A; e_0^T]`` is invertible (position responds to velocity:
``A[0, 1] != 0``). Hence ``x(k) = A x(k-1) + B u(k-1)`` and
``y(k+1) = C A x(k) + C B u(k)`` are exact linear functions of

    phi(k) = [y(k), x_pos(k-1), u(k), u(k-1)]           (3 + 1 + 2 + 2 = 8)

    y(k+1) = Theta phi(k),  Theta = [Theta_y, theta_h, Theta_u0, Theta_u1].

The full ARX(2) with all of ``y(k-1)`` would be exact too, but its regressors
are exactly collinear (``y(k) - (CA)_meas y(k-1) - CB u(k-1)`` is a multiple of
the velocity in all three rows); dropping the lagged currents removes that and
leaves 8 linearly independent regressors.

2. A minimal realization from Theta
-----------------------------------
Write ``x(k) = Psi [y(k); x_pos(k-1); u(k-1)]``. Rows 0, 2, 3 of ``Psi`` just copy
``y(k)``; only the velocity row ``psi^T`` is unknown. So
``Theta`` restricted to ``[x_pos(k-1), u(k-1)]`` is ``(C A)[:, 1] psi_{pos,u}^T``:
the ``3 x 3`` matrix ``H = [theta_h, Theta_u1]`` has rank one, ``H = a w^T``.
With ``h(k) = w^T [x_pos(k-1); u(k-1)]``, scaled so that ``w_0 = 1``, the model
is the 4-state system::

    y(k+1) = Theta_y y(k) + a h(k) + Theta_u0 u(k)
    h(k+1) = w_0 x_pos(k) + w_u^T u(k)

    Atilde = [[Theta_y, a], [w_0 e_0^T, 0]],  Btilde = [Theta_u0; w_u^T],  Ctilde = [I, 0].

Without noise ``H`` has rank one exactly; with noise its rank-one part (the
leading singular pair of ``H`` with rows and columns scaled to unit RMS
signals) is the consistent reduced-rank estimate.

3. The transformation to physical coordinates
---------------------------------------------
``x = T xi`` with ``x = [x, dx/dt, i1, i2]``. ``C T = Ctilde`` fixes rows 0, 2, 3 of
``T`` (the measured states). The velocity is the time derivative of the
position, ``dx/dt = Ctilde_0 d(xi)/dt = Ctilde_0 (Atilde_c xi + Btilde_c u)``; in
physical coordinates ``B_c`` has no position row (eq. (3)), so ``Ctilde_0
Btilde_c = 0`` and row 1 of ``T`` is ``Ctilde_0 Atilde_c`` with ``Atilde_c =
ln(Atilde)/dt`` (eq. (8))::

    T = [Ctilde_0; Ctilde_0 Atilde_c; Ctilde_1; Ctilde_2],
    A = T Atilde T^-1,  B = T Btilde,  A_c = T Atilde_c T^-1 (row 0 = [0, 1, 0, 0]).

``T`` is unique: the measured states fix three rows, the kinematic identity
``d/dt x = velocity`` the fourth. It applies to the discrete model as well
(a state transformation commutes with the zero-order hold). ``Ctilde_0
Btilde_c`` is a check (it appears as ``B_c[0]`` and enters the structure
residual).

Any other 4-state realization with these outputs (subspace, ERA) is put into
physical coordinates the same way: :func:`to_physical_coordinates`.

4. Instruments
--------------
See :mod:`maglevid.identify.iv`: ``"loop"`` simulates the known controller and
observer around the nominal (observer) model driven by the recorded ``r`` and
uses the same regressors built from those noise-free signals (basic IV);
``"lags"`` uses lags of ``r`` (two-stage least squares).

5. The operating point
----------------------
A recording holds the deviations from the point the bearing *settled* at, plus
constants: a faulty bearing under the nominal bias settles away from the
nominal point (:func:`maglevid.physics.amb.settled_operating_point`), and a rig
may log absolute currents or voltages. With ``y = y_0 + dy``, ``u = u_0 + du``
the plant ARX reads ``y(k+1) = Theta phi(k) + c`` with ``c = (I - Theta_y) y_0 -
theta_h x_0 - (Theta_u0 + Theta_u1) u_0``; the regression estimates ``c`` with
``Theta`` (``intercept=True`` of :class:`~maglevid.identify.arx.RegressionAccumulator`,
a constant regressor that is also an instrument), so ``Theta``, its covariance
and everything derived from them are the same, to rounding, whatever constants
``y``, ``u`` and ``r`` carry. The realization scales of section 2 are standard
deviations, and the ``"loop"`` instruments are simulated from rest at ``r(0)``
(a constant offset of ``r`` then shifts them by a constant only). Without the
constant, an offset of the size of the signals is read as dynamics: a noise-free
``R2 +5 %`` record with the nominal bias gave ``R2 = -17 ohm`` (issue 12).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError, IdentificationError, ModelError
from maglevid.identify.arx import LinearFit, solve_regression_blocks
from maglevid.identify.iv import simulate_loop_signals
from maglevid.identify.options import AMB_OPTIONS, declared
from maglevid.identify.result import IdentificationResult
from maglevid.identify.uncertainty import DCLevels, amb_result, centred_sumsq, with_dc_levels
from maglevid.lti import StateSpace, undiscretize
from maglevid.physics.amb import C_AMB, INPUT_NAMES, OUTPUT_NAMES, STATE_NAMES

__all__ = [
    "METHODS",
    "fit_physical",
    "format_percentage_index",
    "percentage_index",
    "physical_transformation",
    "plant_regression",
    "plant_regression_blocks",
    "realize_plant_arx",
    "to_physical_coordinates",
]

logger = logging.getLogger(__name__)

#: Index of the position among the outputs ``[x, i1, i2]``.
POSITION = 0


def plant_regression(y: np.ndarray, u: np.ndarray, *, start: int) -> tuple[np.ndarray, np.ndarray]:
    """``y(k+1)`` and ``phi(k) = [y(k), x_pos(k-1), u(k), u(k-1)]``, rows ``k = start .. N-2``.

    See the module notes, section 1.
    """
    lhs, parts = plant_regression_blocks(y, u, start=start)
    return lhs, np.hstack(parts)


def plant_regression_blocks(
    y: np.ndarray, u: np.ndarray, *, start: int
) -> tuple[np.ndarray, list[np.ndarray]]:
    """:func:`plant_regression` with ``phi`` as its four column blocks (views, no copy)."""
    N = y.shape[0]
    if not 1 <= start < N - 1:
        raise DataError(f"`start` must be in 1..{N - 2}; got {start}")
    cur = slice(start, N - 1)
    prev = slice(start - 1, N - 2)
    return y[start + 1 :], [y[cur], y[prev, POSITION : POSITION + 1], u[cur], u[prev]]


def realize_plant_arx(
    theta: np.ndarray,
    *,
    ny: int,
    nu: int,
    y_scale: np.ndarray | None = None,
    h_scale: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Minimal 4-state realization of the plant ARX (module notes, section 2).

    Parameters
    ----------
    theta : ndarray
        ``Theta`` (``ny x (ny + 1 + 2 nu)``), flat or 2-D.
    ny, nu : int
    y_scale : ndarray, shape (ny,), optional
        RMS of the outputs (row scaling of ``H`` before its rank-one split).
    h_scale : ndarray, shape (1 + nu,), optional
        RMS of ``[x_pos, u]`` (column scaling).

    Returns
    -------
    Atilde, Btilde, Ctilde : ndarray
        The realization (``Ctilde = [I, 0]``).
    h_singular_values : ndarray
        Singular values of the scaled ``H``; the second relative to the first
        measures how far the estimate is from the rank-one structure.
    """
    Theta = np.asarray(theta, dtype=float).reshape(ny, ny + 1 + 2 * nu)
    Ty = Theta[:, :ny]
    H = np.hstack([Theta[:, ny : ny + 1], Theta[:, ny + 1 + nu :]])  # [theta_h, Theta_u1]
    Tu0 = Theta[:, ny + 1 : ny + 1 + nu]
    ry = np.ones(ny) if y_scale is None else np.asarray(y_scale, dtype=float)
    ch = np.ones(1 + nu) if h_scale is None else np.asarray(h_scale, dtype=float)
    U, s, Vt = np.linalg.svd(H / ry[:, None] * ch[None, :])
    a = U[:, 0] * s[0] * ry  # H ~ a w^T
    w = Vt[0] / ch
    # Fix the scale (and sign) of the hidden state h by w_0 = 1, so that the
    # realization is a continuous function of Theta (the delta method
    # differentiates it); w_0 != 0 because the lagged position carries the velocity.
    if w[0] == 0:
        raise IdentificationError(
            "the lagged position has no weight in the plant ARX: the velocity is not "
            "reconstructed and the model is not the AMB of eq. (3)"
        )
    a, w = a * w[0], w / w[0]
    n = ny + 1
    At = np.zeros((n, n))
    At[:ny, :ny] = Ty
    At[:ny, ny] = a
    At[ny, POSITION] = w[0]
    Bt = np.vstack([Tu0, w[1:][None, :]])
    Ct = np.hstack([np.eye(ny), np.zeros((ny, 1))])
    return At, Bt, Ct, s


def physical_transformation(Ac_tilde: np.ndarray, C_tilde: np.ndarray) -> np.ndarray:
    """``T`` with ``x_phys = T xi`` for states ``[x, dx/dt, i1, i2]`` (module notes, section 3).

    ``T = [Ctilde_0; Ctilde_0 Atilde_c; Ctilde_1; Ctilde_2]``.

    Raises
    ------
    IdentificationError
        ``T`` is singular: the derivative of the position adds nothing to the
        measured states (velocity unobservable from position).

    Examples
    --------
    >>> import numpy as np
    >>> from maglevid.physics.amb import AMBParameters, amb_matrices, C_AMB
    >>> Ac, Bc = amb_matrices(AMBParameters.nominal())
    >>> S = np.array([[2.0, 1, 0, 0], [0, 3, 0, 1], [1, 0, 1, 0], [0, 0, 0, 1]])
    >>> T = physical_transformation(np.linalg.solve(S, Ac @ S), C_AMB @ S)
    >>> np.allclose(T, S)
    True
    """
    c0 = C_tilde[POSITION]
    rows = [c0, c0 @ Ac_tilde] + [C_tilde[j] for j in range(C_tilde.shape[0]) if j != POSITION]
    T = np.vstack(rows)
    s = np.linalg.svd(T / np.linalg.norm(T, axis=1, keepdims=True), compute_uv=False)
    if s[-1] < 1e-12 * s[0]:
        raise IdentificationError(
            "the physical transformation is singular: the identified position does not "
            "depend on a state beyond the measured ones (velocity unobservable)"
        )
    return T


def to_physical_coordinates(model: StateSpace) -> tuple[StateSpace, StateSpace]:
    """Any 4-state AMB realization with outputs ``[x, i1, i2]`` in physical coordinates.

    For models identified in arbitrary coordinates, e.g. by
    :func:`maglevid.identify.subspace.fit_moesp` or ERA: ``T`` of the module
    notes (section 3) from the continuous model, applied to both.

    Parameters
    ----------
    model : StateSpace
        Discrete (ZOH) or continuous model, 4 states, 3 outputs ``[x, i1, i2]``.

    Returns
    -------
    discrete, continuous : StateSpace
        In states ``[x, dx/dt, i1, i2]`` with ``C = [[1,0,0,0],[0,0,1,0],[0,0,0,1]]``
        (``discrete`` is ``None`` for a continuous input); read v1..v9 off the
        continuous one with :func:`maglevid.physics.amb.v_from_matrices`.

    Raises
    ------
    IdentificationError
        No real logarithm (discrete input) or a singular transformation.
    """
    if model.nx != 4 or model.ny != 3:
        raise DataError(
            f"an AMB model has 4 states and outputs [x, i1, i2]; got nx={model.nx}, ny={model.ny}"
        )
    try:
        cont = undiscretize(model) if model.is_discrete else model
    except ModelError as exc:
        raise IdentificationError(f"no continuous counterpart of the model: {exc}") from exc
    T = physical_transformation(cont.A, cont.C)
    names = {"state_names": STATE_NAMES, "input_names": INPUT_NAMES, "output_names": OUTPUT_NAMES}
    Ti = np.linalg.inv(T)
    phys_c = StateSpace(T @ cont.A @ Ti, T @ cont.B, cont.C @ Ti, cont.D, None, **names)
    if not model.is_discrete:
        return None, phys_c  # type: ignore[return-value]
    phys_d = StateSpace(T @ model.A @ Ti, T @ model.B, model.C @ Ti, model.D, model.dt, **names)
    return phys_d, phys_c


def realization_scales(
    sum_y2: np.ndarray, sum_u2: np.ndarray, n_samples: int
) -> tuple[np.ndarray, np.ndarray]:
    """RMS of the outputs and of ``[x_pos, u]`` (row and column scales of ``H``, section 2).

    Given the *centred* sums of squares these are standard deviations, which do
    not depend on the recording's operating point (section 5).
    """
    y_scale = np.sqrt(np.asarray(sum_y2, dtype=float) / n_samples)
    h_scale = np.concatenate([y_scale[POSITION : POSITION + 1], np.sqrt(sum_u2 / n_samples)])
    return y_scale, h_scale


def _plant_signals(data: ClosedLoopData) -> tuple[np.ndarray, np.ndarray]:
    if not isinstance(data, ClosedLoopData):
        raise DataError(f"`data` must be a ClosedLoopData; got {type(data).__name__}")
    if data.p != 1:
        raise DataError(
            f"the physical method needs one output sample per control period; got p={data.p}"
        )
    if data.u is None and data.u_f is not None and data.r is not None:
        data = data.with_plant_input()
    if data.u is None:
        raise DataError("the physical method needs the plant input u (or u_f and r)")
    if data.ny != 3 or data.nu != 2:
        raise DataError(
            f"the AMB model has outputs [x, i1, i2] and inputs [u1, u2]; the recording has "
            f"{data.ny} outputs and {data.nu} inputs"
        )
    C = data.loop.get("C") if isinstance(data.loop, Mapping) else None
    if C is not None and not np.allclose(np.asarray(C, dtype=float), C_AMB):
        raise DataError(
            "the physical method expects y = [x, i1, i2] (C = [[1,0,0,0],[0,0,1,0],[0,0,0,1]]); "
            f"the loop's C is {np.asarray(C).tolist()}"
        )
    return np.asarray(data.y), np.asarray(data.u)


#: Why ``instruments="auto"`` refuses a record without the loop's controller and observer
#: (issue 16, fourteenth session): with lags of ``r`` instead, simulated bearings (30 000
#: samples, simulator defaults, linear and nonlinear plant, four seeds each) gave x0 20-35
#: standard errors from the truth (the loop's instruments: every parameter within 1.6).
_NO_LOOP = (
    "physical builds its instruments by running the recorded loop (loop['controller'] and "
    "loop['observer']) on r, and this record has neither; with lags of r instead its "
    "estimates were measured biased on the bearing (x0 20-35 standard errors from the "
    "truth on simulated records), with intervals that exclude the truth. Use method "
    "'ml' (what `maglevid identify` chooses for such a record) or 'pbsid' with "
    "coordinates='physical', add the loop to the recording, or pass instruments='lags' "
    "(--option instruments=lags) to force lags of r"
)
#: The note of ``instruments="lags"`` (asked for by name).
_LAGS_NOTE = (
    "instruments are lags of r (asked for): exact on noise-free records, but weak on a "
    "bearing with noise -- simulated records gave x0 20-35 standard errors from the truth, "
    "so the intervals do not cover; the loop's instruments, ml or pbsid do"
)


def loop_recorded(loop: Any) -> bool:
    """Whether ``data.loop`` carries the controller and observer the ``"loop"``
    instruments are simulated with."""
    return (
        isinstance(loop, Mapping)
        and isinstance(loop.get("observer"), Mapping)
        and isinstance(loop.get("controller"), Mapping)
    )


_AMB_NAMES = ("estimator", "instruments", "skip", "instrument_lags", "covariance", "hac_lags")


@declared(*(AMB_OPTIONS[n] for n in (*_AMB_NAMES, "m", "i0")))
def fit_physical(
    data: ClosedLoopData,
    *,
    estimator: str = "iv",
    instruments: str = "auto",
    skip: int = 10,
    instrument_lags: int = 30,
    covariance: str = "white-noise",
    hac_lags: int = 4,
    m: float | None = None,
    i0: float | None = None,
) -> IdentificationResult:
    """Physical AMB model from the plant ARX, observer-independent (module notes).

    Parameters
    ----------
    data : ClosedLoopData
        ``y = [x, i1, i2]``, ``u`` (or ``u_f`` and ``r``); ``r`` and, for
        ``instruments="loop"``, ``data.loop`` with the controller and observer.

    The options are declared once (:data:`~maglevid.identify.options.AMB_OPTIONS`,
    listed under *Options*). ``covariance="white-noise"``: the equation error is
    ``w(k+1) - Theta_y w(k) - theta_h w_pos(k-1)`` for white measurement noise
    ``w``, its covariance written exactly in ``Cov(w)`` fitted to the residuals
    (:func:`maglevid.identify.arx.white_noise_covariance`); ``"hac"`` holds for
    any short-memory equation error but overstates the standard errors on this
    plant (see :mod:`maglevid.identify.arx`).

    Returns
    -------
    IdentificationResult
        Discrete and continuous model in physical coordinates, v1..v9 and
        physical parameters with covariance (delta method through the
        realization and the transformation), the plant ARX coefficients and the
        rank-one check in ``extras``.

    Raises
    ------
    DataError
        Wrong signals or too short a record.
    IdentificationError
        Rank-deficient regression, no real logarithm, or singular ``T``.
    """
    y, u = _plant_signals(data)
    ny = y.shape[1]
    N = y.shape[0]
    plan = plan_physical(
        estimator=estimator,
        instruments=instruments,
        skip=skip,
        instrument_lags=instrument_lags,
        covariance=covariance,
        has_r=data.r is not None,
        loop=data.loop,
        n_samples=N,
    )
    start, kind = plan["start"], plan["instruments"]
    lhs, phi = plant_regression_blocks(y, u, start=start)
    Z = None
    if kind == "loop":
        r = np.asarray(data.r)
        # from rest at the first excitation level: a constant offset of r changes
        # the instruments by a constant only (absorbed by the intercept)
        sim = simulate_loop_signals(data.loop, r - r[0], dt=data.dt)
        _, Z = plant_regression_blocks(sim["y"], sim["u"], start=start)
    elif kind == "lags":
        r = np.asarray(data.r)
        Z = [
            r[start - j : N - 1 - j] for j in range(int(instrument_lags) + 1)
        ]  # lagged_excitation
    fit = solve_regression_blocks(
        lhs,
        phi,
        Z,
        hac_lags=hac_lags,
        labels=physical_labels(data.channel_names("y"), data.channel_names("u")),
        noise_ma=physical_noise_ma(ny) if covariance == "white-noise" else None,
        intercept=True,
    )
    # bit-identical to the centred copies' sums (the covariance is sensitive to one
    # rounding of these scales: docs/performance.md, section 6b), without the copies
    y_scale, h_scale = realization_scales(centred_sumsq(y), centred_sumsq(u), N)
    dc = DCLevels(data.dt, ny, u.shape[1])
    dc.update(y, u)
    res = physical_result(
        fit,
        Y=lhs,
        y_scale=y_scale,
        h_scale=h_scale,
        dt=data.dt,
        loop=data.loop,
        names=data.channel_names("y"),
        plan=plan,
        hac_lags=hac_lags,
        m=m,
        i0=i0,
    )
    return with_dc_levels(res, dc, data.loop)


# The stages of fit_physical, shared with the streamed fit of records larger than
# memory (maglevid.identify.streaming): the same plan, regressors and result.


def plan_physical(
    *,
    estimator: str,
    instruments: str,
    skip: int,
    instrument_lags: int,
    covariance: str,
    has_r: bool,
    loop: Mapping[str, Any],
    n_samples: int | None,
) -> dict[str, Any]:
    """Checked options of :func:`fit_physical`: first row, instruments used, notes.

    ``n_samples=None`` (a stream of unknown length) skips the record-length check.
    """
    if estimator not in ("ls", "iv"):
        raise DataError(f"`estimator` must be 'ls' or 'iv'; got {estimator!r}")
    if instruments not in ("auto", "loop", "lags"):
        raise DataError(f"`instruments` must be 'auto', 'loop' or 'lags'; got {instruments!r}")
    if covariance not in ("white-noise", "hac"):
        raise DataError(f"`covariance` must be 'white-noise' or 'hac'; got {covariance!r}")
    start = max(int(skip), 1)
    kind = None
    notes: list[str] = []
    if estimator == "iv":
        if not has_r:
            raise DataError("estimator='iv' needs the excitation r in the recording")
        kind = instruments
        if kind == "auto":
            if not loop_recorded(loop):
                raise DataError(_NO_LOOP)
            kind = "loop"
        if kind == "lags":
            notes.append(_LAGS_NOTE)
            start = max(start, int(instrument_lags))
    n_reg = 3 + 1 + 2 * 2
    if n_samples is not None and n_samples - 1 - start <= 3 * n_reg:
        raise DataError(
            f"the recording has {n_samples} samples; the plant ARX needs well over "
            f"{start + 1 + 3 * n_reg}"
        )
    return {
        "start": start,
        "instruments": kind,
        "notes": notes,
        "options": {
            "estimator": estimator,
            "instruments": kind,
            "skip": int(skip),
            "instrument_lags": int(instrument_lags),
            "covariance": covariance,
        },
    }


def physical_labels(ynames: Sequence[str], unames: Sequence[str]) -> list[str]:
    """Names of the regressors ``phi(k) = [y(k), x_pos(k-1), u(k), u(k-1)]``."""
    return (
        [f"{n}(k)" for n in ynames]
        + [f"{ynames[POSITION]}(k-1)"]
        + [f"{n}(k)" for n in unames]
        + [f"{n}(k-1)" for n in unames]
    )


def physical_noise_ma(ny: int) -> Callable[[np.ndarray], list[np.ndarray]]:
    """The equation error as a moving average of white measurement noise (section 1)."""

    def noise_ma(Theta: np.ndarray) -> list[np.ndarray]:
        # eps(k) = w(k+1) - Theta_y w(k) - theta_h w_pos(k-1) (module notes, section 1)
        C2 = np.zeros((ny, ny))
        C2[:, POSITION] = -Theta[:, ny]
        return [np.eye(ny), -Theta[:, :ny], C2]

    return noise_ma


def physical_result(
    fit: LinearFit,
    *,
    Y: np.ndarray | None,
    y_scale: np.ndarray,
    h_scale: np.ndarray,
    dt: float,
    loop: Mapping[str, Any],
    names: Sequence[str],
    plan: Mapping[str, Any],
    hac_lags: int,
    m: float | None,
    i0: float | None,
    one_step_fit: np.ndarray | None = None,
    extra_notes: Sequence[str] = (),
    extra_options: Mapping[str, Any] | None = None,
) -> IdentificationResult:
    """Realization, physical coordinates and the result of :func:`fit_physical` (sections 2-3)."""
    ny = len(y_scale)
    nu = len(h_scale) - 1
    notes = list(plan["notes"]) + list(extra_notes)
    Ct = np.hstack([np.eye(ny), np.zeros((ny, 1))])

    def to_discrete(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        At, Bt, _, _ = realize_plant_arx(theta, ny=ny, nu=nu, y_scale=y_scale, h_scale=h_scale)
        return At, Bt

    def to_physical(Atc: np.ndarray, Btc: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        T = physical_transformation(Atc, Ct)
        return T @ np.linalg.solve(T.T, Atc.T).T, T @ Btc, T  # T Atc T^-1, T Btc

    _, _, _, hs = realize_plant_arx(
        fit.coefficients, ny=ny, nu=nu, y_scale=y_scale, h_scale=h_scale
    )
    rank_one = float(hs[1] / hs[0])
    if rank_one > 1e-2:
        notes.append(
            f"the lagged-input block of the plant ARX is far from rank one (s2/s1 = "
            f"{rank_one:.3g}); the plant may not be the 4-state AMB model of eq. (3)"
        )
    n_rows = fit.n_rows if fit.n_rows is not None else Y.shape[0]  # type: ignore[union-attr]
    options = {**plan["options"], "hac_lags": int(hac_lags), "m": m, "i0": i0}
    options.update(extra_options or {})
    return amb_result(
        method="physical",
        to_discrete=to_discrete,
        to_physical=to_physical,
        fit=fit,
        Y=Y,
        lhs_names=list(names),
        dt=dt,
        loop=loop,
        n_samples=int(n_rows),
        options=options,
        notes=notes,
        extras={"rank_one_ratio": rank_one, "h_singular_values": hs},
        m=m,
        i0=i0,
        one_step_fit=one_step_fit,
    )


# ---------------------------------------------------------------- percentage indices


def percentage_index(estimate: Any, reference: Any) -> np.ndarray:
    """``(estimate - reference) / reference * 100`` elementwise (array division).

    The paper's ``A_p``, ``B_p`` (Gosiewski & Paszowski, Example I). Elements
    where the reference is a structural zero are NaN (the paper prints x).
    """
    est = np.asarray(estimate, dtype=float)
    ref = np.asarray(reference, dtype=float)
    if est.shape != ref.shape:
        raise DataError(f"estimate {est.shape} and reference {ref.shape} differ in shape")
    out = np.full(ref.shape, np.nan)
    nz = ref != 0
    out[nz] = (est[nz] - ref[nz]) / ref[nz] * 100.0
    return out


def format_percentage_index(M: Any, *, digits: int = 4, width: int = 10) -> str:
    """Text of a percentage-index matrix, ``×`` at structural zeros as the paper prints it."""
    M = np.asarray(M, dtype=float)
    lines = []
    for row in np.atleast_2d(M):
        cells = ["×".rjust(width) if np.isnan(x) else f"{x:{width}.{digits}f}" for x in row]
        lines.append(" ".join(cells))
    return "\n".join(lines)


#: Registered with ``maglevid identify --method``.
METHODS: Mapping[str, Any] = {"physical": fit_physical}
