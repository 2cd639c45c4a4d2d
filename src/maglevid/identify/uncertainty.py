"""Standard errors of v1..v9 and of the physical parameters, and the AMB result.

Every AMB method of :mod:`maglevid.identify` ends the same way: a coefficient
estimate ``theta`` (ARX/IV) with covariance ``Cov(theta)`` (the HAC sandwich of
:mod:`maglevid.identify.arx`) and a smooth map ``theta -> (A, B)`` into the
discrete model in physical coordinates. From there

    (A, B) --eq. (8)--> (A_c, B_c) --eq. (4)--> v1..v9 --inverse of eq. (4)--> R1, L1, ...

(:func:`maglevid.lti.undiscretize`, :func:`maglevid.physics.amb.v_from_matrices`,
:func:`maglevid.physics.amb.parameters_from_v`). The covariance follows by the
delta method, ``Cov(f(theta)) = J Cov(theta) J^T`` (as in
:func:`maglevid.identify.result.propagate_covariance`), with the Jacobian of
the whole chain assembled from central differences of the cheap algebraic
steps and the exact Fréchet derivative of the matrix logarithm (one
``expm_frechet`` Kronecker form per estimate instead of one ``logm`` per
finite-difference step, an order of magnitude faster at the same accuracy;
the test suite compares the two). The chain is smooth wherever ``ln(A)`` is real
and ``v1, v4, v6`` are nonzero.

Intervals are the normal-approximation ones of
:meth:`IdentificationResult.confidence_intervals`; their coverage is checked by
Monte Carlo in ``tests/identify/test_uncertainty.py`` (slow) and
``benchmarks/bench_amb_mc.py``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np
import scipy.linalg as sla

from maglevid.exceptions import IdentificationError, ModelError
from maglevid.identify.arx import LinearFit
from maglevid.identify.result import IdentificationResult, central_jacobian
from maglevid.lti import StateSpace, undiscretize
from maglevid.physics.amb import (
    C_AMB,
    INPUT_NAMES,
    OUTPUT_NAMES,
    STATE_NAMES,
    V_NAMES,
    parameters_from_v,
    ratios_from_v,
    v_from_matrices,
)

__all__ = [
    "DC_BATCH_SECONDS",
    "PHYSICAL_NAMES",
    "RATIO_NAMES",
    "DCLevels",
    "amb_result",
    "dc_level_note",
    "one_step_fit_percent",
    "operating_point",
    "v_from_discrete",
    "with_dc_levels",
    "with_physical_parameters",
]

logger = logging.getLogger(__name__)

#: Physical parameters reported beside v1..v9 when ``m`` and ``i0`` are known
#: (the output of :func:`parameters_from_v`, in this order).
PHYSICAL_NAMES: tuple[str, ...] = (
    "R1",
    "R2",
    "L1",
    "L2",
    "ki1",
    "ki2",
    "kw1",
    "kw2",
    "x0",
    "ks1",
    "ks2",
    "ks_sum",
    "K1",
    "K2",
    "Lo1",
    "Lo2",
    "Ls1",
    "Ls2",
)

#: Scale-free ratios reported when ``m`` or ``i0`` are unknown.
RATIO_NAMES: tuple[str, ...] = tuple(ratios_from_v(np.ones(9)))


def v_from_discrete(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, StateSpace]:
    """v1..v9 and the continuous model from a discrete model in physical coordinates."""
    sc = undiscretize(StateSpace(A, B, C_AMB, dt=dt))  # eq. (8)
    v, _ = v_from_matrices(sc.A, sc.B)  # eq. (4)
    return v, sc


def operating_point(loop: Mapping[str, Any]) -> tuple[float | None, float | None]:
    """``(m, i0)`` from ``loop["operating_point"]`` (``None`` where absent)."""
    op = loop.get("operating_point") if isinstance(loop, Mapping) else None
    if not isinstance(op, Mapping):
        return None, None
    m = op.get("m")
    i0 = op.get("i0")
    return (None if m is None else float(m)), (None if i0 is None else float(i0))


def with_physical_parameters(
    result: IdentificationResult, m: float | None, i0: float | None, *, strict: bool = False
) -> IdentificationResult:
    """``result`` (with v1..v9 and their covariance) extended by the physical parameters
    of eq. (4) at mass ``m`` and bias current ``i0`` (:data:`PHYSICAL_NAMES`), their
    covariance by the delta method (:func:`~maglevid.identify.result.central_jacobian` in v).

    For methods that estimate v1..v9 without the record's operating point (PBSID-opt and
    SSARX in physical coordinates take arrays): ``identify --method pbsid`` printed v1..v9
    only where the recording stated ``m`` and ``i0`` (found from outside, issue 16). Returned
    unchanged when ``m`` or ``i0`` is missing, v1..v9 or their covariance are absent, or the
    parameters are already there; also when v1..v9 are those of no physical bearing,
    unless ``strict`` (then the error is raised).
    """
    p = result.parameters
    names = list(p)
    if (
        m is None
        or i0 is None
        or result.covariance is None
        or not all(k in p for k in V_NAMES)
        or any(k in p for k in PHYSICAL_NAMES)
    ):
        return result
    idx = [names.index(k) for k in V_NAMES]
    v = np.array([p[k] for k in V_NAMES], dtype=float)

    def derived(vv: np.ndarray) -> np.ndarray:
        q = parameters_from_v(vv, m=m, i0=i0)
        return np.array([q[k] for k in PHYSICAL_NAMES])

    try:
        values, J = central_jacobian(derived, v)
    except (ModelError, ValueError, ArithmeticError):  # no physical bearing for these v
        if strict:
            raise
        return result
    cov = np.asarray(result.covariance, dtype=float)
    n, k = cov.shape[0], len(PHYSICAL_NAMES)
    full = np.zeros((n + k, n + k))
    full[:n, :n] = cov
    cross = cov[:, idx] @ J.T  # cov(theta, derived)
    full[:n, n:] = cross
    full[n:, :n] = cross.T
    full[n:, n:] = J @ cov[np.ix_(idx, idx)] @ J.T
    note = (
        f"physical parameters from v1..v9 with m = {m:.6g} kg and i0 = {i0:.6g} A "
        "(loop['operating_point']; eq. (4)), covariance by the delta method"
    )
    return replace(
        result,
        parameters={**p, **dict(zip(PHYSICAL_NAMES, map(float, values)))},
        covariance=full,
        notes=(*result.notes, note),
    )


def one_step_fit_percent(sum_sq_residuals: Any, sum_sq_centered: Any) -> np.ndarray:
    """``100 (1 - ||eps|| / ||Y - mean Y||)`` per channel from the two sums of squares.

    The one-step-ahead prediction fit (never an open-loop simulation fit of an
    unstable model); NaN for a constant channel.
    """
    num = np.sqrt(np.asarray(sum_sq_residuals, dtype=float))
    den = np.sqrt(np.asarray(sum_sq_centered, dtype=float))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den > 0, 100.0 * (1.0 - num / den), np.nan)


#: Rows per chunk of :func:`centred_sumsq` (a cache-sized temporary, not a record-sized one).
_CENTRE_CHUNK = 1 << 15


def centred_sumsq(x: np.ndarray) -> np.ndarray:
    """``sum_t (x(t) - mean)^2`` per column, chunk by chunk, bit-identical to the whole-record
    formula ``xc = x - x.mean(axis=0); einsum("ij,ij->j", xc, xc)``.

    Without its record-sized temporary (at 10^6 x 3 the allocation and first touch
    cost more than the arithmetic on this machine). Both that ``einsum`` and numpy's
    axis-0 sum of a C-ordered array add the rows in order, one after the other; each
    chunk's sum starts from the running total (added to its first row), so every
    rounding is the one of the whole-record sum. The bit-identity matters: the
    delta-method covariance moves by ~1e-4 when the realization scales move by one
    rounding (docs/performance.md, section 6b).
    """
    x = np.asarray(x, dtype=float)
    N = x.shape[0]
    mean = x.mean(axis=0)
    out = np.zeros(x.shape[1])
    for t0 in range(0, N, _CENTRE_CHUNK):
        c = x[t0 : t0 + _CENTRE_CHUNK] - mean
        c *= c
        c[0] += out
        out = np.add.reduce(c, axis=0)  # sequential over the rows, as the whole-record sum
    return out


def _one_step_fit(Y: np.ndarray, residuals: np.ndarray) -> np.ndarray:
    return one_step_fit_percent(np.einsum("ij,ij->j", residuals, residuals), centred_sumsq(Y))


def _augmented(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    n, m = B.shape
    M = np.eye(n + m)
    M[:n, :n] = A
    M[:n, n:] = B
    return M


def _log_derivative(M: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    # Frechet derivative of the principal logarithm at M: if X = log(M) then
    # L_exp(X, dX) = dM, so dX = L_exp(X, .)^-1 dM. The Kronecker form of
    # L_exp(X, .) is assembled from scipy's expm_frechet column by column and
    # factored once. Balancing M = D Mb D^-1 (as in lti.undiscretize) gives
    # dX = D L_log(Mb, D^-1 dM D) D^-1 and keeps the linear system well scaled.
    Mb, Tb = sla.matrix_balance(M, permute=False)
    d = np.diag(Tb)
    Xb = sla.logm(Mb)
    if np.iscomplexobj(Xb):
        Xb = Xb.real
    k = M.shape[0]
    K = np.empty((k * k, k * k))
    eye = np.eye(k)
    for idx in range(k * k):
        i, j = divmod(idx, k)
        _, L = sla.expm_frechet(Xb, np.outer(eye[i], eye[j]), compute_expm=True)
        K[:, idx] = L.ravel()
    lu = sla.lu_factor(K)

    def solve(dM: np.ndarray) -> np.ndarray:
        dMb = dM / d[:, None] * d[None, :]
        dXb = sla.lu_solve(lu, dMb.ravel()).reshape(k, k)
        return dXb * d[:, None] / d[None, :]

    return solve


def _steps(theta: np.ndarray, cov: np.ndarray, rel: float = 1e-6) -> np.ndarray:
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return rel * np.maximum(np.maximum(np.abs(theta), sd), 1e-300)


def amb_result(
    *,
    method: str,
    to_discrete: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    fit: LinearFit,
    Y: np.ndarray | None,
    lhs_names: Sequence[str],
    dt: float,
    loop: Mapping[str, Any],
    n_samples: int,
    options: Mapping[str, Any],
    to_physical: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]
    | None = None,
    notes: Sequence[str] = (),
    extras: Mapping[str, Any] | None = None,
    m: float | None = None,
    i0: float | None = None,
    singular_values: np.ndarray | None = None,
    one_step_fit: np.ndarray | None = None,
) -> IdentificationResult:
    """Assemble the :class:`IdentificationResult` of an AMB method.

    The chain ``theta -> (A, B) -> ln -> (A_c, B_c) -> physical coordinates ->
    v -> physical parameters`` is evaluated at the estimate, and its Jacobian
    (for the delta method) is taken by central differences of the cheap steps
    and the exact Fréchet derivative of the matrix logarithm in between.

    Parameters
    ----------
    method : str
        Registered method name.
    to_discrete : callable
        ``theta (flat, row-major coefficients) -> (A, B)``: the discrete model in
        the method's coordinates. It must be a continuous function of
        ``theta`` (no sign or ordering ambiguities).
    fit : LinearFit
        The regression (coefficients, covariance, residuals).
    Y : ndarray or None
        Left-hand side of the regression (for the one-step fit).
    lhs_names : sequence of str
        Names of the columns of ``Y``.
    dt : float
        Control period.
    loop : mapping
        ``data.loop`` (for ``m``, ``i0``).
    n_samples : int
        Rows of the regression.
    options : mapping
        Every option of the method.
    to_physical : callable, optional
        ``(A_c, B_c) -> (A_c, B_c, T)`` in physical coordinates ``[x, dx/dt, i1,
        i2]`` with ``x_phys = T xi``; identity when ``to_discrete`` already
        works in physical coordinates.
    m, i0 : float, optional
        Override ``loop["operating_point"]``.
    singular_values : ndarray, optional
        Singular values to report (default: those of the regression).
    one_step_fit : ndarray, optional
        One-step fit per left-hand side in percent, for a streamed regression
        whose ``Y`` and residuals were not kept (``Y`` is then ``None``); see
        :func:`one_step_fit_percent`.

    Returns
    -------
    IdentificationResult
        ``parameters`` = v1..v9, then the physical parameters (given ``m`` and
        ``i0``) or the scale-free ratios; ``covariance`` by the delta method.
    """
    notes = list(notes) + list(fit.notes)
    theta = fit.coefficients.ravel()
    cov_theta = fit.covariance
    to_phys = _identity_coordinates if to_physical is None else to_physical
    Ad, Bd = to_discrete(theta)
    sc = _undiscretize(method, Ad, Bd, dt)  # eq. (8)
    Ac, Bc, T = to_phys(sc.A, sc.B)
    v, structure = v_from_matrices(Ac, Bc)  # eq. (4)
    names, derived = _derived_parameters(loop, m, i0, notes)
    n = Bd.shape[0]

    def post(X: np.ndarray) -> np.ndarray:
        # X = ln(M) = [[A_c, B_c], [0, 0]] dt -> physical coordinates -> v (eq. (4)) -> derived
        Aci, Bci, _ = to_phys(X[:n, :n] / dt, X[:n, n:] / dt)
        vv, _ = v_from_matrices(Aci, Bci)
        return np.concatenate([vv, derived(vv)])

    values = np.concatenate([v, derived(v)])
    J = _delta_jacobian(to_discrete, post, theta, cov_theta, Ad, Bd, sc, dt, values.size)
    cov = J @ cov_theta @ J.T
    cov = 0.5 * (cov + cov.T)
    A_phys = T @ np.linalg.solve(T.T, Ad.T).T  # T Ad T^-1
    model = StateSpace(
        A_phys,
        T @ Bd,
        C_AMB,
        dt=dt,
        state_names=STATE_NAMES,
        input_names=INPUT_NAMES,
        output_names=OUTPUT_NAMES,
    )
    fitd = _fit_metrics(fit, Y, lhs_names, one_step_fit, structure, notes)
    ex = {
        "coefficients": fit.coefficients,
        "coefficient_std_errors": fit.std_errors,
        "estimator": fit.estimator,
        "hac_lags": fit.hac_lags,
        "covariance_method": fit.covariance_method,
        "noise_covariance": fit.noise_covariance,
        "jacobian": J,
    }
    ex.update(extras or {})
    return IdentificationResult(
        method=method,
        model=model,
        continuous_model=StateSpace(
            Ac,
            Bc,
            C_AMB,
            state_names=STATE_NAMES,
            input_names=INPUT_NAMES,
            output_names=OUTPUT_NAMES,
        ),
        parameters=dict(zip(names, values.tolist())),
        covariance=cov,
        n_samples=n_samples,
        options=dict(options),
        residuals=fit.residuals,
        fit=fitd,
        singular_values=fit.singular_values if singular_values is None else singular_values,
        notes=tuple(notes),
        extras=ex,
    )


def _identity_coordinates(
    Ac: np.ndarray, Bc: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return Ac, Bc, np.eye(Ac.shape[0])


def _undiscretize(method: str, Ad: np.ndarray, Bd: np.ndarray, dt: float) -> StateSpace:
    """The continuous model of eq. (8), or an IdentificationError saying why there is none."""
    try:
        return undiscretize(StateSpace(Ad, Bd, np.eye(Ad.shape[0]), dt=dt))  # eq. (8)
    except ModelError as exc:
        raise IdentificationError(
            f"{method}: the identified discrete model has no real continuous counterpart "
            f"({exc}); the estimate is unusable (too little excitation, too much noise, or "
            "a loop that does not match the method's assumptions)"
        ) from exc


def _derived_parameters(
    loop: Mapping[str, Any], m: float | None, i0: float | None, notes: list[str]
) -> tuple[list[str], Callable[[np.ndarray], np.ndarray]]:
    """Names and map ``v -> derived``: physical parameters given ``m`` and ``i0``, else ratios."""
    op_m, op_i0 = operating_point(loop)
    m = op_m if m is None else m
    i0 = op_i0 if i0 is None else i0
    if m is not None and i0 is not None:
        mass, bias = m, i0

        def physical(vv: np.ndarray) -> np.ndarray:
            p = parameters_from_v(vv, m=mass, i0=bias)
            return np.array([p[k] for k in PHYSICAL_NAMES])

        return list(V_NAMES) + list(PHYSICAL_NAMES), physical
    notes.append(
        "mass m or bias current i0 unknown (loop['operating_point']): physical "
        "parameters need them; reporting v1..v9 and scale-free ratios only"
    )

    def ratios(vv: np.ndarray) -> np.ndarray:
        return np.array(list(ratios_from_v(vv).values()))

    return list(V_NAMES) + list(RATIO_NAMES), ratios


def _delta_jacobian(
    to_discrete: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
    post: Callable[[np.ndarray], np.ndarray],
    theta: np.ndarray,
    cov_theta: np.ndarray,
    Ad: np.ndarray,
    Bd: np.ndarray,
    sc: StateSpace,
    dt: float,
    n_values: int,
) -> np.ndarray:
    """Delta method: ``J = d post / d theta = post'(X0) [L_log(M0, dM/dtheta)]``.

    ``M = [[Ad, Bd], [0, I]]``, ``X = ln(M)`` (eq. (8)); central differences for
    the cheap steps, the exact Fréchet derivative of the logarithm in between.
    """
    n = Bd.shape[0]
    M0 = _augmented(Ad, Bd)
    X0 = np.zeros_like(M0)
    X0[:n, :n] = sc.A * dt
    X0[:n, n:] = sc.B * dt
    dlog = _log_derivative(M0)
    h = _steps(theta, cov_theta)
    J = np.empty((n_values, theta.size))
    for i in range(theta.size):
        tp, tm = theta.copy(), theta.copy()
        tp[i] += h[i]
        tm[i] -= h[i]
        dM = (_augmented(*to_discrete(tp)) - _augmented(*to_discrete(tm))) / (2 * h[i])
        dX = dlog(dM)
        J[:, i] = (post(X0 + h[i] * dX) - post(X0 - h[i] * dX)) / (2 * h[i])
    return J


def _fit_metrics(
    fit: LinearFit,
    Y: np.ndarray | None,
    lhs_names: Sequence[str],
    one_step_fit: np.ndarray | None,
    structure: float,
    notes: list[str],
) -> dict[str, Any]:
    """One-step fit per left-hand side, the eq. (4) structure residual, the condition number."""
    if one_step_fit is not None:
        osf = np.asarray(one_step_fit, dtype=float)
    elif Y is None or fit.residuals is None:
        raise ValueError("amb_result needs Y and the residuals, or one_step_fit")
    else:
        osf = _one_step_fit(Y, fit.residuals)
    fitd = {f"one_step_fit_percent_{nm}": float(f) for nm, f in zip(lhs_names, osf)}
    fitd["one_step_fit_percent_min"] = float(np.nanmin(osf))
    fitd["structure_residual"] = float(structure)
    fitd["regression_condition"] = fit.condition_number
    if structure > 1e-3:
        notes.append(
            f"the continuous model departs from the structure of eq. (4) by {structure:.3g} "
            "(relative): elements that should be 0 are not; v1..v9 are read off anyway"
        )
    return fitd


# ---------------------------------------------------------------- DC levels
#: Length of the batches whose means give the standard errors of the DC levels [s].
DC_BATCH_SECONDS = 0.2

#: Fewest complete batches for an interval (Student t with ``nb - 1`` dof).
_DC_MIN_BATCHES = 5


class DCLevels:
    """Means of ``y`` and ``u`` in batches of fixed length, fed in chunks (streamable).

    The DC levels of a recording are evidence of their own (issue 12): with the
    loop's bias current ``i0`` and bias inputs ``u_bias`` they give the settled
    coil currents and amplifier inputs, and the coil equation of eq. (1)
    averaged over the record, ``kw_j mean(u_j) = R_j mean(I_j) + (flux_end -
    flux_start) / T``, a static estimate of ``R_j / kw_j`` that needs no model
    of the dynamics (the flux term is bounded, so it vanishes as ``1/T``).
    Standard errors come from the means of consecutive batches of
    :data:`DC_BATCH_SECONDS` (longer than the loop's slowest time constant, so
    the batch means are nearly independent), with Student-t intervals.
    """

    def __init__(self, dt: float, ny: int, nu: int) -> None:
        self.B = max(1, round(DC_BATCH_SECONDS / dt))
        self.ny, self.nu = ny, nu
        self.n = 0
        self.total = np.zeros(ny + nu)
        self.batches: list[np.ndarray] = []
        self._acc = np.zeros(ny + nu)
        self._fill = 0

    def update(self, y: np.ndarray, u: np.ndarray) -> None:
        y, u = np.asarray(y, float), np.asarray(u, float)
        ny, n = self.ny, y.shape[0]
        self.n += n
        # y and u apart (no (N, ny + nu) copy); einsum: axis-0 sums of (N, 3) are slow
        self.total[:ny] += np.einsum("ij->j", y)
        self.total[ny:] += np.einsum("ij->j", u)
        i = 0
        while i < n:
            take = min(self.B - self._fill, n - i)
            if self._fill == 0 and n - i >= self.B:
                # whole batches at once: their sums by one matrix-vector product per signal
                # (one einsum per batch was ~1000 calls on rows of 2-3 doubles at 10^6)
                k = (n - i) // self.B
                ones = np.ones(self.B)
                sums = np.empty((k, ny + self.nu))
                sums[:, :ny] = ones @ y[i : i + k * self.B].reshape(k, self.B, ny)
                sums[:, ny:] = ones @ u[i : i + k * self.B].reshape(k, self.B, self.nu)
                self.batches.extend(sums / self.B)
                i += k * self.B
                continue
            self._acc[:ny] += np.einsum("ij->j", y[i : i + take])
            self._acc[ny:] += np.einsum("ij->j", u[i : i + take])
            self._fill += take
            i += take
            if self._fill == self.B:
                self.batches.append(self._acc / self.B)
                self._acc = np.zeros_like(self._acc)
                self._fill = 0

    def evidence(
        self,
        loop: Mapping[str, Any],
        parameters: Mapping[str, float],
        std_errors: Mapping[str, float],
    ) -> dict[str, dict[str, Any]]:
        """Settled levels and static coil estimates, each ``{value, std_error, ci95}``.

        Always ``x`` (mean displacement). With ``loop["operating_point"]["i0"]``:
        the settled currents ``I1, I2``; with ``u_bias`` too: the amplifier inputs
        ``u1, u2`` and the static current gains ``g_j = I_j / u_j = kw_j / R_j``
        [A/V]; then ``kw_j = R_j g_j`` with ``R_j`` of the dynamic fit
        (``kwj_static``), and, with the nominal amplifier gain of
        ``loop["nominal"]`` taken as known, ``R_j = kw_j,nom / g_j``
        (``Rj_static``) and the coil voltage ``U_j = kw_j,nom u_j``.
        """
        from scipy import stats

        nb = len(self.batches)
        mean = self.total / max(self.n, 1)
        M = np.array(self.batches) if nb else np.full((1, mean.size), np.nan)
        t = float(stats.t.ppf(0.975, nb - 1)) if nb >= _DC_MIN_BATCHES else float("nan")

        def item(value: float, dev: np.ndarray) -> dict[str, Any]:
            ok = nb >= _DC_MIN_BATCHES
            se = float(np.std(dev, ddof=1) / np.sqrt(nb)) if ok else float("nan")
            return _level(value, se, t)

        out = {"x": item(mean[0], M[:, 0])}
        op = loop.get("operating_point") if isinstance(loop, Mapping) else None
        op = op if isinstance(op, Mapping) else {}
        if op.get("i0") is None or (self.ny, self.nu) != (3, 2):
            return out
        i0 = float(op["i0"])
        I, Ib = i0 + mean[1:3], i0 + M[:, 1:3]
        out.update({f"I{j + 1}": item(I[j], Ib[:, j]) for j in range(2)})
        if op.get("u_bias") is None:
            return out
        ub = np.asarray(op["u_bias"], float).reshape(2)
        U, Ub = ub + mean[3:5], ub + M[:, 3:5]
        nominal = loop.get("nominal") if isinstance(loop.get("nominal"), Mapping) else {}
        for j, c in enumerate("12"):
            g = I[j] / U[j]
            dg = (Ib[:, j] - g * Ub[:, j]) / U[j]  # ratio estimator, linearised per batch
            out[f"u{c}"] = item(U[j], Ub[:, j])
            out[f"g{c}"] = item(g, dg)
            R, se_R = parameters.get(f"R{c}"), std_errors.get(f"R{c}")
            if R is not None and se_R is not None:
                se_kw = float(np.hypot(g * se_R, R * out[f"g{c}"]["std_error"]))
                out[f"kw{c}_static"] = _level(R * g, se_kw, 1.96)
            kw_nom = nominal.get(f"kw{c}")
            if kw_nom is not None:
                out[f"R{c}_static"] = item(kw_nom / g, -kw_nom / g**2 * dg)
                out[f"U{c}"] = item(kw_nom * U[j], kw_nom * Ub[:, j])
        return out


def _level(value: float, se: float, t: float) -> dict[str, Any]:
    v, se = float(value), float(se)
    return {"value": v, "std_error": se, "ci95": [v - t * se, v + t * se]}


def dc_level_note(ev: Mapping[str, Mapping[str, Any]]) -> str | None:
    """One line of the settled levels and the static coil estimates, or None."""
    labels = {
        "I{j}": ("I{j}", "A"),
        "R{j}_static": ("R{j} (static, nominal kw{j})", "ohm"),
        "kw{j}_static": ("kw{j} (static, with the dynamic R{j})", ""),
    }
    parts = []
    for j in "12":
        for key, (label, unit) in labels.items():
            e = ev.get(key.format(j=j))
            if e is not None:
                text = f"{label.format(j=j)} = {e['value']:.5g} ± {e['std_error']:.2g}"
                parts.append(f"{text} {unit}".rstrip())
    if not parts:
        return None
    return "DC levels (settled operating point; ± one standard error): " + "; ".join(parts)


def with_dc_levels(
    res: IdentificationResult, dc: DCLevels, loop: Mapping[str, Any]
) -> IdentificationResult:
    """``res`` with the DC-level evidence in ``extras["dc_levels"]`` and a note."""
    ev = dc.evidence(loop, res.parameters, res.std_errors())
    note = dc_level_note(ev)
    extras = {**res.extras, "dc_levels": ev}
    return replace(res, extras=extras, notes=res.notes if note is None else (*res.notes, note))
