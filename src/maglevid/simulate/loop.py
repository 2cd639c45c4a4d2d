"""Observer-based closed loop of Figs. 1-2 (Gosiewski & Paszowski) with a linear plant.

Time indexing (one control period ``k``, zero computation delay)::

    y(k)     = C_p x(k) + v(k)                          measured at t = k dt
    e(k)     = e(k-1) - E y(k)         (k >= 1)          eq. (39)/(43), measured y
    u_f(k)   = -F x̂(k) + F_e e(k)                        eq. (42)
    u(k)     = u_f(k) + r(k)                             eq. (16), held over [k dt, (k+1) dt)
    x(k+1)   = A_p x(k) + B_p u(k)                       plant (ZOH, eq. (6))
    x̂(k+1)  = (A_o + G C_o) x̂(k) + B_o u(k) - G y(k)    eq. (43), observer model {A_o, B_o, C_o}

``e(0)`` and ``x̂(0)`` are initial conditions; ``y(0)`` enters ``x̂(1)`` but not
the integral (eq. (43) integrates ``y(k+1)`` into ``e(k+1)``).

The plant ``{A_p, B_p, C_p}`` and the observer's model ``{A_o, B_o, C_o}`` may
differ: the diagnostic case is a controller and observer designed on the
nominal bearing while the real one has a fault.

For fast simulation the loop is one linear system. The integral is driven by
``v(k+1)``, one sample ahead; the state ``e'(k) = e(k) + E v(k)`` removes that:
``e'(k+1) = e'(k) - E v(k) - E C_p x(k+1)`` and ``e(k) = e'(k) - E v(k)``. With
``z = [x; x̂; e']`` and inputs ``w = [r; v]``::

    u(k)    = K_u z + D_u w,     K_u = [0, -F, F_e],  D_u = [I, -F_e E]
    z(k+1)  = A_cl z + B_cl w
    [y; u_f] = C_cl z + D_cl w

(matrices in :func:`closed_loop_system`), run by :func:`maglevid.simulate.kernel.simulate_lti`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np

from maglevid._validation import as_signal, readonly
from maglevid.control.integral import IntegralStateFeedback
from maglevid.control.observer import Observer
from maglevid.exceptions import DataError, DesignError
from maglevid.lti import StateSpace
from maglevid.simulate.kernel import _simulate_checked, simulate_lti

__all__ = ["LoopSignals", "closed_loop_system", "replay_feedback", "simulate_linear_loop"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class LoopSignals:
    """Signals of a simulated loop, time first (read-only arrays).

    ``y`` (N, ny) measured outputs (noise included), ``u`` (N, nu) plant input,
    ``r`` (N, nu) excitation, ``u_f`` (N, nu) feedback, ``x_hat0`` and ``e0`` the
    initial observer and integral states.
    """

    y: np.ndarray
    u: np.ndarray
    r: np.ndarray
    u_f: np.ndarray
    x_hat0: np.ndarray
    e0: np.ndarray


def _check_loop(plant: StateSpace, observer: Observer, controller: IntegralStateFeedback) -> None:
    if not isinstance(plant, StateSpace) or not plant.is_discrete:
        raise DataError("`plant` must be a discrete maglevid StateSpace (ZOH-sampled)")
    nu, ny = plant.nu, plant.ny
    if observer.ny != ny or observer.nu != nu:
        raise DataError(
            f"observer model has nu={observer.nu}, ny={observer.ny}; "
            f"the plant has nu={nu}, ny={ny}"
        )
    if controller.F.shape != (nu, observer.nx) or controller.ny != ny:
        raise DataError(
            f"controller F has shape {controller.F.shape} and E {controller.E.shape}; the loop "
            f"needs F ({nu}, {observer.nx}) and E (ne, {ny})"
        )
    if (
        plant.dt is not None
        and observer.dt is not None
        and abs(plant.dt - observer.dt) > 1e-12 * plant.dt
    ):
        raise DataError(
            f"observer designed for dt={observer.dt:g} s but the plant is sampled at "
            f"dt={plant.dt:g} s"
        )


def closed_loop_system(
    plant: StateSpace, observer: Observer, controller: IntegralStateFeedback
) -> StateSpace:
    """The loop of eqs. (6), (16), (39), (42), (43) as one discrete system.

    States ``[x; x̂; e']`` (module notes), inputs ``[r; v]`` (excitation,
    measurement noise), outputs ``[y; u_f]``.
    """
    _check_loop(plant, observer, controller)
    Ap, Bp, Cp = plant.A, plant.B, plant.C
    Ao, Bo, Co, G = observer.A, observer.B, observer.C, observer.G
    F, Fe, E = controller.F, controller.Fe, controller.E
    nx, nxo, ne, nu, ny = Ap.shape[0], Ao.shape[0], E.shape[0], Bp.shape[1], Cp.shape[0]
    Ku = np.hstack([np.zeros((nu, nx)), -F, Fe])  # u_f from z, eq. (42)
    Du = np.hstack([np.eye(nu), -Fe @ E])  # u from [r; v]
    Z = np.zeros
    A0 = np.block(
        [
            [Ap, Z((nx, nxo)), Z((nx, ne))],
            [-G @ Cp, Ao + G @ Co, Z((nxo, ne))],  # eq. (43) with y = C_p x + v
            [-E @ Cp @ Ap, Z((ne, nxo)), np.eye(ne)],  # e'(k+1) = e' - E v - E C_p x(k+1)
        ]
    )
    Bu = np.vstack([Bp, Bo, -E @ Cp @ Bp])
    Bv = np.vstack([Z((nx, ny)), -G, -E])
    A = A0 + Bu @ Ku
    B = Bu @ Du + np.hstack([Z((A.shape[0], nu)), Bv])
    C = np.vstack([np.hstack([Cp, Z((ny, nxo + ne))]), Ku])
    D = np.block([[Z((ny, nu)), np.eye(ny)], [Z((nu, nu)), -Fe @ E]])
    return StateSpace(A, B, C, D, plant.dt)


def simulate_linear_loop(
    plant: StateSpace,
    observer: Observer,
    controller: IntegralStateFeedback,
    *,
    r: Any,
    noise: Any = None,
    x0: Any = None,
    x_hat0: Any = None,
    e0: Any = None,
    kernel: str = "auto",
    allow_unstable: bool = False,
) -> LoopSignals:
    """Simulate the loop of Figs. 1-2 with a linear discrete plant.

    Parameters
    ----------
    plant : StateSpace
        The real plant (discrete), in deviation coordinates.
    observer : Observer
        Observer (its own model, possibly the nominal one).
    controller : IntegralStateFeedback
    r : array_like, shape (N, nu)
        Excitation.
    noise : array_like, shape (N, ny), optional
        Measurement noise ``v`` added to ``C_p x`` (zero when omitted).
    x0, x_hat0, e0 : array_like, optional
        Initial plant, observer and integral states (zero by default).
    kernel : {"auto", "block", "loop"}
        See :func:`~maglevid.simulate.kernel.simulate_lti`.
    allow_unstable : bool
        Simulate even when the loop is unstable (only sensible for short records).

    Returns
    -------
    LoopSignals

    Raises
    ------
    DesignError
        When the loop with this plant is unstable (unless ``allow_unstable``).
    """
    sys = closed_loop_system(plant, observer, controller)
    nu, ny, ne = plant.nu, plant.ny, controller.ne
    r = as_signal(r, "r", n_channels=nu)
    N = r.shape[0]
    v = (
        np.zeros((N, ny))
        if noise is None
        else as_signal(noise, "noise", n_samples=N, n_channels=ny)
    )
    rho = float(np.max(np.abs(sys.poles())))
    if rho >= 1.0 and not allow_unstable:
        raise DesignError(
            f"the closed loop is unstable with this plant (largest pole magnitude {rho:.6f}): "
            "the controller/observer cannot hold this bearing"
        )
    x = np.zeros(plant.nx) if x0 is None else np.asarray(x0, float).reshape(plant.nx)
    xh = (
        np.zeros(observer.nx) if x_hat0 is None else np.asarray(x_hat0, float).reshape(observer.nx)
    )
    e = np.zeros(ne) if e0 is None else np.asarray(e0, float).reshape(ne)
    z0 = np.concatenate([x, xh, e + controller.E @ v[0]])  # e'(0) = e(0) + E v(0)
    if noise is None:  # v = 0: the loop driven by r alone (no (N, nu + ny) input of zeros)
        sys_r = StateSpace(sys.A, sys.B[:, :nu], sys.C, sys.D[:, :nu], dt=sys.dt)
        out, _ = _simulate_checked(sys_r, r, z0, kernel)
    else:
        out, _ = _simulate_checked(sys, np.hstack([r, v]), z0, kernel)
    y, u_f = out[:, :ny], out[:, ny:]
    return LoopSignals(_frozen(y), _frozen(u_f + r), r, _frozen(u_f), readonly(xh), readonly(e))


def _frozen(a: np.ndarray) -> np.ndarray:
    """Mark a freshly computed array (or a view of one) read-only, without a copy."""
    a.setflags(write=False)
    return a


def replay_feedback(
    observer: Observer,
    controller: IntegralStateFeedback,
    *,
    y: Any,
    r: Any = None,
    u: Any = None,
    x_hat0: Any = None,
    e0: Any = None,
    kernel: str = "auto",
) -> np.ndarray:
    """Re-run the observer and controller (eqs. (42)-(43)) on recorded signals.

    Parameters
    ----------
    observer, controller
        The loop's observer and controller (e.g. from a recording's ``loop``).
    y : array_like, shape (N, ny)
        Recorded (measured) outputs.
    r : array_like, shape (N, nu), optional
        Recorded excitation: the observer is fed ``u = u_f + r`` with the
        re-computed ``u_f`` (the controller re-run as in the loop).
    u : array_like, shape (N, nu), optional
        Recorded plant input instead of ``r``: the observer is fed the recorded
        ``u``. Give exactly one of ``r`` and ``u``.
    x_hat0, e0 : array_like, optional
        Initial observer and integral states (zero by default).

    Returns
    -------
    ndarray, shape (N, nu)
        ``u_f``. With the recording's initial states this is the recorded
        ``u_f`` to round-off. With ``u`` given and zero initial states, a
        deadbeat observer gives the recorded ``u_f`` after its nilpotency index
        except for the constant ``F_e e(0)``.

    Notes
    -----
    ``e'(k) = e(k) + E y(k)`` accumulates the past outputs,
    ``e'(k+1) = e'(k) - E y(k)``, so the observer/controller is a linear system
    with inputs ``[r; y]`` (or ``[u; y]``), run by the fast kernel.
    """
    if (r is None) == (u is None):
        raise DataError("give exactly one of `r` (excitation) and `u` (plant input)")
    E, F, Fe = controller.E, controller.F, controller.Fe
    Ao, Bo, Co, G = observer.A, observer.B, observer.C, observer.G
    nx, ne, nu, ny = Ao.shape[0], E.shape[0], Bo.shape[1], Co.shape[0]
    drive = as_signal(r if u is None else u, "r" if u is None else "u", n_channels=nu)
    y = as_signal(y, "y", n_samples=drive.shape[0], n_channels=ny)
    Z = np.zeros
    C = np.hstack([-F, Fe])  # u_f = -F x̂ + Fe (e' - E y)
    D = np.hstack([Z((nu, nu)), -Fe @ E])
    if u is None:
        # x̂(k+1) = (A+GC) x̂ + B (u_f + r) - G y
        A = np.block([[Ao + G @ Co - Bo @ F, Bo @ Fe], [Z((ne, nx)), np.eye(ne)]])
        B = np.block([[Bo, -Bo @ Fe @ E - G], [Z((ne, nu)), -E]])
    else:
        # x̂(k+1) = (A+GC) x̂ + B u - G y
        A = np.block([[Ao + G @ Co, Z((nx, ne))], [Z((ne, nx)), np.eye(ne)]])
        B = np.block([[Bo, -G], [Z((ne, nu)), -E]])
    xh = np.zeros(nx) if x_hat0 is None else np.asarray(x_hat0, float).reshape(nx)
    e = np.zeros(ne) if e0 is None else np.asarray(e0, float).reshape(ne)
    sys = StateSpace(A, B, C, D, observer.dt or 1.0)
    z0 = np.concatenate([xh, e + E @ y[0]])
    u_f, _ = simulate_lti(sys, np.hstack([drive, y]), x0=z0, kernel=kernel)
    return u_f
