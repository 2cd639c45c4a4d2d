"""The excitation of a rig that did not log it: recovered from the controller law.

Many rigs add a dither to their controller but log only the measured signals and
the command. If the controller is linear, ``D(q) u_k = N(q) w_k + c + D(q) d_k``
(``w``: the controller's inputs, ``d``: the dither), so the *equation error* of
the law

    e_k = D(q) u_k - N(q) w_k - c                                   (X1)

is ``D(q) d_k``: exogenous, as the dither is. With the law stated (``loop
["controller_law"]`` with a MISO ``a``, ``b``, ``intercept``) it is used as it is; else it
is fitted (:func:`maglevid.diagnose.quality.fit_controller_arx`, ``nk = 0``: a
digital controller computes ``u_k`` from ``w_k``). The fit is consistent when
the dither is white (``w_k`` depends on ``d`` only through the plant, with at
least one sample of delay). ``r = e`` filtered by ``1/D(q)`` when ``D`` is
stable gives ``d`` itself; otherwise ``e`` is kept (still a valid instrument).
The recovered ``r`` and the law (as a discrete MISO StateSpace in
``loop["controller"]`` with ``r`` as its first input, inputs in
``loop["controller_inputs"]``) let two-stage,
indirect and diagnose run on such a log.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from scipy import signal

from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError
from maglevid.identify.closedloop import resolve_channel
from maglevid.lti import StateSpace

__all__ = ["controller_state_space", "recover_excitation"]


def controller_state_space(a: Any, b: Any, dt: float) -> StateSpace:
    """``u = sum_j B_j(q)/A(q) w_j`` (``A = 1 + a_1 q^-1 + ...``, ``B_j = b_j0 + b_j1 q^-1 +
    ...``) in observer canonical form."""
    a = np.atleast_1d(np.asarray(a, dtype=float))
    b = np.atleast_2d(np.asarray(b, dtype=float))
    n = max(a.size, b.shape[1] - 1, 1)
    ap = np.zeros(n)
    ap[: a.size] = a
    bp = np.zeros((b.shape[0], n + 1))
    bp[:, : b.shape[1]] = b
    A = np.zeros((n, n))
    A[:, 0] = -ap
    A[: n - 1, 1:] = np.eye(n - 1)
    B = (bp[:, 1:] - np.outer(bp[:, 0], ap)).T
    C = np.zeros((1, n))
    C[0, 0] = 1.0
    D = bp[:, :1].T
    return StateSpace(A, B, C, D, dt)


def recover_excitation(
    data: ClosedLoopData,
    *,
    controller_inputs: Sequence[str] | None = None,
    na: int = 0,
    nb: int = 2,
    segments: Sequence[Sequence[int]] | None = None,
) -> tuple[ClosedLoopData, dict[str, Any]]:
    """The record with the dither recovered as ``r`` (eq. X1), and how it was found.

    Parameters
    ----------
    data : ClosedLoopData
        A same-rate record with one command ``u`` and no ``r``.
    controller_inputs : list of str, optional
        Channels the controller reads (default: every output, ``y:0 ... y:ny-1``).
    na, nb : int
        Orders of the fitted law (default ``0, 2``: a PD on each input).
    segments : list of (start, stop), optional
        Samples where the law holds (default: where the command is off its extreme
        values, so a saturated command does not bias the fit).

    Returns
    -------
    (ClosedLoopData, dict)
        The record with ``r`` (and ``u_f = u - r``) and ``loop["controller"]``; the
        report (``source``: "stated" or "fitted", ``r_squared``, ``a``, ``b``).
    """
    if data.p != 1 or data.u is None or data.nu != 1:
        raise DataError("recovering the excitation needs a same-rate record with one command u")
    if data.r is not None:
        raise DataError("the record already has an excitation r")
    if data.u_f is not None:
        # The feedback is logged: r = u - u_f exactly, nothing to recover (or fit).
        r_logged = data.u[:, 0] - data.u_f[:, 0]
        if not np.any(np.abs(r_logged) > 1e-9 * max(float(np.max(np.abs(data.u))), 1e-300)):
            raise DataError(
                "no excitation in this record: the logged command u equals the logged "
                "feedback u_f, so the loop is driven by noise alone and a method that needs "
                "an excitation (two-stage, indirect) cannot separate the plant from the "
                "controller; add a dither r, or sample the output faster than the control "
                "period (Sun et al.: p > 1, method intersample)"
            )
        loop = {**dict(data.loop), "excitation": "u - u_f (both logged)"}
        names = {**{k: tuple(v) for k, v in data.names.items()}, "r": ("dither",)}
        units = {**{k: tuple(v) for k, v in data.units.items()}, "r": data.units.get("u", ("",))}
        out = data.replace(r=r_logged[:, None], names=names, units=units, loop=loop)
        return out, {"source": "u - u_f (both logged)", "r_rms": float(np.std(r_logged))}
    inputs = list(controller_inputs or [f"y:{j}" for j in range(data.ny)])
    W = np.column_stack([resolve_channel(data, c).values for c in inputs])
    u = data.u[:, 0]
    law = data.loop.get("controller_law") if hasattr(data.loop, "get") else None
    if isinstance(law, Mapping) and "b" in law:
        a = np.atleast_1d(np.asarray(law.get("a", []), dtype=float))
        b = np.atleast_2d(np.asarray(law["b"], dtype=float))
        c0 = float(law.get("intercept", 0.0))
        report: dict[str, Any] = {"source": "stated (loop['controller_law'])"}
    else:
        a, b, c0, report = _fit_law(W, u, na, nb, segments)
    e = _equation_error(u, W, a, b, c0)
    stable = a.size == 0 or bool(np.all(np.abs(np.roots(np.r_[1.0, a])) < 1.0))
    r = signal.lfilter([1.0], np.r_[1.0, a], e) if stable and a.size else e
    report.update({"a": a.tolist(), "b": b.tolist(), "intercept": c0, "inputs": inputs,
                   "filtered_by_1_over_D": bool(stable and a.size),
                   "r_rms": float(np.std(r))})  # fmt: skip
    # the law with r as its first input: u = N/D w + r (r = d) or + r/D (r = D d)
    filtered = bool(stable and a.size)
    b_r = np.r_[1.0, a] if filtered else np.array([1.0])
    width = max(b.shape[1], b_r.size)
    B_all = np.zeros((b.shape[0] + 1, width))
    B_all[0, : b_r.size] = b_r
    B_all[1:, : b.shape[1]] = b
    K = controller_state_space(a, B_all, data.dt)
    names = {**{k: tuple(v) for k, v in data.names.items()}, "r": ("dither",)}
    units = {**{k: tuple(v) for k, v in data.units.items()}, "r": data.units.get("u", ("",))}
    loop = {**dict(data.loop), "controller": K.to_dict(), "controller_inputs": ["r:0", *inputs],
            "excitation": "recovered from the controller law (eq. X1)"}  # fmt: skip
    out = data.replace(r=r[:, None], u_f=(u - r)[:, None], names=names, units=units, loop=loop)
    return out, report


def _fit_law(
    W: np.ndarray, u: np.ndarray, na: int, nb: int, segments: Any
) -> tuple[np.ndarray, np.ndarray, float, dict[str, Any]]:
    from maglevid.diagnose.quality import fit_controller_arx

    mask = np.zeros(u.size, dtype=bool)
    if segments is None:
        mask[:] = (u > u.min()) & (u < u.max()) if np.ptp(u) > 0 else True
    else:
        for s0, s1 in segments:
            mask[int(s0) : int(s1)] = True
    fit = fit_controller_arx(W, u, na=na, nb=nb, nk=0, mask=mask)
    report = {"source": f"fitted (ARX na={na}, nb={nb}, nk=0)", "r_squared": fit.r_squared}
    return fit.a, fit.b, fit.intercept, report


def _equation_error(
    u: np.ndarray, W: np.ndarray, a: np.ndarray, b: np.ndarray, c0: float
) -> np.ndarray:
    e = signal.lfilter(np.r_[1.0, a], [1.0], u) - c0  # eq. (X1)
    for j in range(W.shape[1]):
        e -= signal.lfilter(b[j], [1.0], W[:, j])
    h = max(a.size, b.shape[1] - 1)
    e[:h] = 0.0  # no full history
    return e
