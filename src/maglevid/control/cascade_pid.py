"""The UAQ levitator's cascaded controller: position PID -> current reference -> current PI.

Exactly the law of the upstream acquisition script (``adquisicion_datos.py`` of
``JRavenelco/levitador-benchmark``; see ``/work/shared/data/maglev-uaq-levitador``),
sample time ``dt``, error ``e = yd - y`` [m], current error ``ei = id - i`` [A]::

    I_k  = I_{k-1} + ki dt e_k        if -i_max < I_{k-1} < i_max       (C1)
         = clip(I_{k-1}, -w i_max, w i_max)          otherwise
    v_k  = kp e_k + I_k + kd (e_k - e_{k-1}) / dt                        (C2)
    id_k = -clip(v_k, -i_max, 0)                                         (C3)
    J_k  = J_{k-1} + kii dt ei_k      if -u_max < J_{k-1} < u_max        (C4)
         = clip(J_{k-1}, -w u_max, w u_max)          otherwise
    u_k  = clip(kpi ei_k + J_k, 0, u_max)                                (C5)

with ``w = 0.95``. The integrals are updated *before* the output is formed, and a
clamped integrator skips its increment on that sample (as in the script). The
position error enters with a minus sign: the gap ``y`` grows away from the magnet,
so a ball below its reference (``e < 0``) needs more current.

While no clamp is active the law is linear and time invariant::

    id = -C_o(z) (yd - y),  C_o(z) = kp + ki dt / (1 - z^-1) + kd (1 - z^-1) / dt
    u  =  C_i(z) (id - i),  C_i(z) = kpi + kii dt / (1 - z^-1)

:func:`cascade_state_space` returns that linear law as a discrete
:class:`~maglevid.lti.StateSpace` with inputs ``[yd, y, i]`` and output ``u``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from maglevid._validation import as_signal, check_positive
from maglevid.exceptions import DataError
from maglevid.lti import StateSpace

__all__ = [
    "CascadeGains",
    "CascadePID",
    "CascadeReplay",
    "cascade_state_space",
    "pid_state_space",
    "replay_cascade",
]


@dataclass(frozen=True)
class CascadeGains:
    """Gains and limits of the cascade (eqs. (C1)-(C5)).

    Parameters
    ----------
    kp, ki, kd : float
        Position PID gains [A/m, A/(m s), A s/m].
    kpi, kii : float
        Current PI gains [V/A, V/(A s)].
    i_max : float
        Current-reference limit [A] (``Iref`` in the script).
    u_max : float
        Command limit [V] (``Vref``, the 9.86 V supply).
    dt : float
        Sample time [s].
    windup : float
        Factor ``w`` of the integrator clamp (``0.95``).
    """

    kp: float = 100.0
    ki: float = 50.0
    kd: float = 1.5
    kpi: float = 12.0
    kii: float = 3000.0
    i_max: float = 0.827
    u_max: float = 9.86
    dt: float = 0.01
    windup: float = 0.95

    def __post_init__(self) -> None:
        for f in fields(self):
            v = float(getattr(self, f.name))
            if not np.isfinite(v) or v < 0 or (f.name in ("dt", "i_max", "u_max") and v == 0):
                raise DataError(f"`{f.name}` must be a finite non-negative number; got {v!r}")
            object.__setattr__(self, f.name, v)

    @classmethod
    def uaq(cls) -> CascadeGains:
        """The gains of the UAQ acquisition script (``Ts = 0.01 s``)."""
        return cls()

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


class CascadePID:
    """Stateful cascade controller for simulation: ``step(yd, y, i) -> (id, u)``.

    Parameters
    ----------
    gains : CascadeGains
    I0, J0 : float
        Initial integrator states.
    e0 : float
        Previous position error (the script starts from 0).
    """

    def __init__(
        self,
        gains: CascadeGains | None = None,
        *,
        I0: float = 0.0,
        J0: float = 0.0,
        e0: float = 0.0,
    ) -> None:
        self.gains = CascadeGains.uaq() if gains is None else gains
        self.I = float(I0)
        self.J = float(J0)
        self.e_prev = float(e0)

    def step(self, yd: float, y: float, i: float, id_override: float | None = None) -> tuple:
        """One control period. Returns ``(id, u, flags)``; ``flags`` is a 4-tuple of
        booleans (outer output clipped, command clipped, I clamped, J clamped).

        ``id_override`` feeds a given current reference to the inner loop (used to
        replay the inner loop on a logged ``id``); the outer states still advance.
        """
        g = self.gains
        e = yd - y
        I_clamped = not (-g.i_max < self.I < g.i_max)
        if I_clamped:
            self.I = min(max(self.I, -g.windup * g.i_max), g.windup * g.i_max)  # eq. (C1)
        else:
            self.I += g.ki * g.dt * e  # eq. (C1)
        v = g.kp * e + self.I + g.kd * (e - self.e_prev) / g.dt  # eq. (C2)
        self.e_prev = e
        v_clip = min(max(v, -g.i_max), 0.0)
        idr = -v_clip  # eq. (C3)
        ei = (idr if id_override is None else id_override) - i
        J_clamped = not (-g.u_max < self.J < g.u_max)
        if J_clamped:
            self.J = min(max(self.J, -g.windup * g.u_max), g.windup * g.u_max)  # eq. (C4)
        else:
            self.J += g.kii * g.dt * ei  # eq. (C4)
        w = g.kpi * ei + self.J
        u = min(max(w, 0.0), g.u_max)  # eq. (C5)
        return idr, u, (v_clip != v, u != w, I_clamped, J_clamped)


@dataclass(frozen=True, eq=False)
class CascadeReplay:
    """Outputs and states of the cascade re-run on logged signals.

    Attributes
    ----------
    id, u : ndarray, shape (N,)
        Current reference [A] and command [V] the law produces.
    I, J : ndarray, shape (N,)
        Integrator states after each sample.
    outer_clipped, command_clipped, I_clamped, J_clamped : ndarray of bool, shape (N,)
        Where a limit of (C1)-(C5) was active.
    """

    id: np.ndarray
    u: np.ndarray
    I: np.ndarray
    J: np.ndarray
    outer_clipped: np.ndarray
    command_clipped: np.ndarray
    I_clamped: np.ndarray
    J_clamped: np.ndarray

    @property
    def linear(self) -> np.ndarray:
        """Samples where no limit was active (the law is linear there)."""
        return ~(self.outer_clipped | self.command_clipped | self.I_clamped | self.J_clamped)


def replay_cascade(
    yd: Any,
    y: Any,
    i: Any,
    *,
    gains: CascadeGains | None = None,
    id_logged: Any = None,
    I0: float = 0.0,
    J0: float = 0.0,
    e0: float = 0.0,
) -> CascadeReplay:
    """Re-run the cascade (C1)-(C5) on logged reference, gap and current.

    Parameters
    ----------
    yd, y, i : array_like, shape (N,)
        Logged position reference [m], gap [m] and coil current [A].
    gains : CascadeGains, optional
        Defaults to the UAQ gains.
    id_logged : array_like, shape (N,), optional
        Logged current reference. When given, the inner PI is driven by it
        (stage-wise replay), so an error of the outer stage does not accumulate in
        the inner integrator; this is how the README's check is made.
    I0, J0, e0 : float
        Initial integrator states and previous error.

    Returns
    -------
    CascadeReplay

    Notes
    -----
    A chained replay (``id_logged=None``) integrates any mismatch of ``id`` in the
    inner integrator, which has no feedback in a replay; drifts of a few volts over
    a long record are expected when the initial states are unknown. Compare the
    increments instead (:func:`maglevid.diagnose.quality.check_controller_increments`).
    """
    yd = as_signal(yd, "yd", n_channels=1)[:, 0]
    n = yd.shape[0]
    y = as_signal(y, "y", n_samples=n, n_channels=1)[:, 0]
    i = as_signal(i, "i", n_samples=n, n_channels=1)[:, 0]
    idl = None if id_logged is None else as_signal(id_logged, "id_logged", n_samples=n)[:, 0]
    ctl = CascadePID(gains, I0=I0, J0=J0, e0=e0)
    out = np.empty((n, 4))
    flags = np.zeros((n, 4), dtype=bool)
    for k in range(n):
        idr, u, f = ctl.step(yd[k], y[k], i[k], None if idl is None else idl[k])
        out[k] = idr, u, ctl.I, ctl.J
        flags[k] = f
    arrs = [out[:, j].copy() for j in range(4)] + [flags[:, j].copy() for j in range(4)]
    for a in arrs:
        a.setflags(write=False)
    return CascadeReplay(*arrs)


def pid_state_space(kp: float, ki: float, kd: float, dt: float) -> StateSpace:
    """Discrete PID ``v = kp e + I + kd (e_k - e_{k-1})/dt``, ``I_k = I_{k-1} + ki dt e_k``.

    The form of (C1)-(C2) without limits. States ``[I_{k-1}, e_{k-1}]``, input ``e``,
    output ``v``::

        v_k = (kp + ki dt + kd/dt) e_k + I_{k-1} - (kd/dt) e_{k-1}
    """
    dt = check_positive(dt, "dt")
    A = np.array([[1.0, 0.0], [0.0, 0.0]])
    B = np.array([[ki * dt], [1.0]])
    C = np.array([[1.0, -kd / dt]])
    D = np.array([[kp + ki * dt + kd / dt]])
    return StateSpace(A, B, C, D, dt, ("I", "e_prev"), ("e",), ("v",))


def cascade_state_space(gains: CascadeGains | None = None) -> StateSpace:
    """The cascade (C1)-(C5) without limits, inputs ``[yd, y, i]``, output ``u``.

    States ``[I_{k-1}, e_{k-1}, J_{k-1}]``. With ``e = yd - y``::

        v_k  = (kp + ki dt + kd/dt) e_k + I_{k-1} - (kd/dt) e_{k-1}
        ei_k = -v_k - i_k
        u_k  = (kpi + kii dt) ei_k + J_{k-1}
        I_k  = I_{k-1} + ki dt e_k,  e_k,  J_k = J_{k-1} + kii dt ei_k
    """
    g = CascadeGains.uaq() if gains is None else gains
    q = g.kp + g.ki * g.dt + g.kd / g.dt
    # e = [1, -1, 0] . [yd, y, i];  ei = -v - i.
    E = np.array([1.0, -1.0, 0.0])
    # v = q e + x1 - (kd/dt) x2  ->  ei = -q e - x1 + (kd/dt) x2 - i
    ei_x = np.array([-1.0, g.kd / g.dt, 0.0])
    ei_w = -q * E - np.array([0.0, 0.0, 1.0])
    c = g.kpi + g.kii * g.dt
    A = np.zeros((3, 3))
    B = np.zeros((3, 3))
    A[0, 0] = 1.0
    B[0] = g.ki * g.dt * E  # I_k
    B[1] = E  # e_k
    A[2] = g.kii * g.dt * ei_x
    A[2, 2] += 1.0
    B[2] = g.kii * g.dt * ei_w  # J_k
    C = (c * ei_x + np.array([0.0, 0.0, 1.0]))[None, :]
    D = (c * ei_w)[None, :]
    return StateSpace(A, B, C, D, g.dt, ("I", "e_prev", "J"), ("yd", "y", "i"), ("u",))
