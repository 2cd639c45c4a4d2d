"""State feedback with integral action (Gosiewski & Paszowski, eqs. (39)-(42)).

The controller integrates selected measured outputs,

.. math::

    e(k+1) = e(k) - E\\,y(k+1),                                     \\qquad (39)

and feeds back the (estimated) state and the integral,

.. math::

    u(k) = u_f(k) + r(k) = -F x(k) + F_e e(k) + r(k).                 \\qquad (42)

``E`` is made of rows of the identity: which outputs have their steady-state
error nulled (for the bearing: the displacement, ``E = [[1, 0, 0]]``). With
``y(k+1) = C A x(k) + C B u(k)`` (eq. (6)) the integral joins the plant in the
extended model of eq. (41), on which the gains are designed::

    [x(k+1)]   [  A    0] [x(k)]   [  B  ]
    [e(k+1)] = [-ECA   I] [e(k)] + [-ECB ] u(k),     y(k) = [C 0] [x; e]

so that ``u = -K [x; e]`` with ``K = [F, -F_e]``.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np
import scipy.linalg as sla

from maglevid._validation import as_matrix, readonly
from maglevid.exceptions import DataError, DesignError
from maglevid.lti import StateSpace

__all__ = [
    "IntegralStateFeedback",
    "check_integral_selector",
    "closed_loop_poles",
    "design_lqr",
    "design_pole_placement",
    "extended_model",
    "integral_selector",
]

logger = logging.getLogger(__name__)


def integral_selector(indices: Any, ny: int) -> np.ndarray:
    """``E`` of eq. (39): the rows of the ``ny x ny`` identity listed in ``indices``.

    Examples
    --------
    >>> integral_selector([0], 3)
    array([[1., 0., 0.]])
    """
    idx = [int(i) for i in np.atleast_1d(indices)]
    if not idx or len(set(idx)) != len(idx) or min(idx) < 0 or max(idx) >= ny:
        raise DataError(
            f"`indices` must be distinct output indices in 0..{ny - 1}; got {list(indices)!r}"
        )
    return np.eye(ny)[idx]


def check_integral_selector(E: Any, ny: int) -> np.ndarray:
    """Validate ``E`` (rows of the identity, eq. (39)) and return it read-only."""
    E = as_matrix(E, "E", (None, ny))
    ok = np.all((E == 0) | (E == 1), axis=None) and np.all(E.sum(axis=1) == 1)
    if not ok or len(set(np.argmax(E, axis=1).tolist())) != E.shape[0]:
        raise DataError(
            f"`E` must be made of distinct rows of the {ny}x{ny} identity (eq. (39)); "
            f"got {E.tolist()}"
        )
    return E


def _require_discrete(sys: StateSpace, name: str = "sys") -> None:
    if not isinstance(sys, StateSpace):
        raise DataError(f"`{name}` must be a maglevid StateSpace; got {type(sys).__name__}")
    if not sys.is_discrete:
        raise DesignError(
            f"`{name}` is a continuous-time model; the controller and observer of eqs. (16)-(17) "
            "and (41)-(43) are designed on the ZOH-sampled model (discretize(sys, dt))"
        )


def extended_model(sys: StateSpace, E: Any = None) -> StateSpace:
    """The plant extended with the output integrals, eq. (41).

    Parameters
    ----------
    sys : StateSpace
        Discrete plant ``{A, B, C}`` of eq. (6).
    E : array_like, shape (ne, ny), optional
        Rows of the identity selecting the integrated outputs; default: the
        first output only (the displacement of the bearing).

    Returns
    -------
    StateSpace
        ``{[[A, 0], [-ECA, I]], [B; -ECB], [C, 0]}`` with states ``x`` then ``e``.
    """
    _require_discrete(sys)
    E = check_integral_selector(integral_selector([0], sys.ny) if E is None else E, sys.ny)
    nx, ne = sys.nx, E.shape[0]
    A, B, C = sys.A, sys.B, sys.C
    Ae = np.block([[A, np.zeros((nx, ne))], [-E @ C @ A, np.eye(ne)]])  # eq. (41)
    Be = np.vstack([B, -E @ C @ B])  # eq. (41)
    Ce = np.hstack([C, np.zeros((sys.ny, ne))])
    names = (*sys.state_names, *(f"e{i + 1}" for i in range(ne))) if sys.state_names else ()
    return StateSpace(Ae, Be, Ce, None, sys.dt, names, sys.input_names, sys.output_names)


def _freeze_info(info: Mapping[str, Any]) -> Mapping[str, Any]:
    return MappingProxyType(dict(info))


@dataclass(frozen=True, eq=False)
class IntegralStateFeedback:
    """State feedback with integral action, ``u = -F x + F_e e + r`` (eq. (42)).

    Parameters
    ----------
    F : array_like, shape (nu, nx)
        State feedback gain.
    Fe : array_like, shape (nu, ne)
        Integral gain (sign as in eq. (42): ``+F_e e``).
    E : array_like, shape (ne, ny)
        Integrated outputs, rows of the identity (eq. (39)).
    method : str
        How the gains were obtained (``"lqr"``, ``"pole_placement"``, ``"given"``).
    info : mapping
        JSON-safe design details (weights, poles, loop-matrix condition, ...).

    Examples
    --------
    >>> K = IntegralStateFeedback([[1.0, 2.0]], [[0.5]], [[1.0]])
    >>> K.gain.tolist()
    [[1.0, 2.0, -0.5]]
    """

    F: np.ndarray
    Fe: np.ndarray
    E: np.ndarray
    method: str = "given"
    info: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        F = as_matrix(self.F, "F")
        Fe = as_matrix(self.Fe, "Fe", (F.shape[0], None))
        E = as_matrix(self.E, "E", (Fe.shape[1], None))
        E = check_integral_selector(E, E.shape[1])
        object.__setattr__(self, "F", F)
        object.__setattr__(self, "Fe", Fe)
        object.__setattr__(self, "E", E)
        object.__setattr__(self, "info", _freeze_info(self.info))

    @property
    def nu(self) -> int:
        return self.F.shape[0]

    @property
    def nx(self) -> int:
        return self.F.shape[1]

    @property
    def ne(self) -> int:
        return self.E.shape[0]

    @property
    def ny(self) -> int:
        return self.E.shape[1]

    @property
    def gain(self) -> np.ndarray:
        """``K = [F, -F_e]`` so that ``u_f = -K [x; e]`` (eq. (42))."""
        return readonly(np.hstack([self.F, -self.Fe]))

    def feedback(self, x: Any, e: Any) -> np.ndarray:
        """``u_f = -F x + F_e e`` (eq. (42)) for one sample or time-first arrays."""
        return -np.asarray(x) @ self.F.T + np.asarray(e) @ self.Fe.T

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form (the ``loop["controller"]`` entry of a recording)."""
        return {
            "type": "state_feedback_integral",
            "F": self.F.tolist(),
            "Fe": self.Fe.tolist(),
            "E": self.E.tolist(),
            "method": self.method,
            "info": dict(self.info),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> IntegralStateFeedback:
        return cls(
            np.asarray(d["F"], float),
            np.asarray(d["Fe"], float),
            np.asarray(d["E"], float),
            str(d.get("method", "given")),
            dict(d.get("info", {})),
        )


def closed_loop_poles(sys: StateSpace, controller: IntegralStateFeedback) -> np.ndarray:
    """Poles of the extended model under full state feedback, ``eig(A_e - B_e K)``."""
    ext = extended_model(sys, controller.E)
    if controller.gain.shape != (ext.nu, ext.nx):
        raise DataError(
            f"controller gain has shape {controller.gain.shape}; the extended model needs "
            f"{(ext.nu, ext.nx)}"
        )
    return np.linalg.eigvals(ext.A - ext.B @ controller.gain)


def _poles_info(poles: np.ndarray) -> list[list[float]]:
    return [[float(p.real), float(p.imag)] for p in np.sort_complex(np.asarray(poles, complex))]


def design_lqr(
    sys: StateSpace, *, Q: Any, R: Any, E: Any = None, N: Any = None
) -> IntegralStateFeedback:
    """Discrete LQR on the extended model of eq. (41).

    Minimises ``sum z' Q z + u' R u + 2 z' N u`` with ``z = [x; e]`` through the
    discrete algebraic Riccati equation (``scipy.linalg.solve_discrete_are``).

    Parameters
    ----------
    sys : StateSpace
        Discrete plant.
    Q : array_like, shape (nx + ne, nx + ne)
        State weight (symmetric, positive semi-definite).
    R : array_like, shape (nu, nu)
        Input weight (symmetric, positive definite).
    E : array_like, optional
        Integrated outputs (default: the first output).
    N : array_like, shape (nx + ne, nu), optional
        Cross weight.

    Returns
    -------
    IntegralStateFeedback

    Raises
    ------
    DesignError
        If the Riccati equation has no stabilising solution.

    Notes
    -----
    For a mirror-symmetric bearing, mirror-symmetric weights give a
    mirror-symmetric controller, for which the loop matrix of eq. (46) is
    singular (see :func:`maglevid.control.check_loop_matrix`). Unequal input
    weights do not help much: the cheaper coil simply takes a larger share of
    every gain, so the two rows of ``[-F, F_e]`` stay almost proportional on the
    unmeasured states. Check the design before using it for identification.
    """
    ext = extended_model(sys, E)
    n, nu = ext.nx, ext.nu
    Q = as_matrix(Q, "Q", (n, n))
    R = as_matrix(R, "R", (nu, nu))
    S = np.zeros((n, nu)) if N is None else as_matrix(N, "N", (n, nu))
    Ae, Be = ext.A, ext.B
    try:
        P = sla.solve_discrete_are(Ae, Be, Q, R, s=S)
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise DesignError(
            f"the discrete Riccati equation of the extended model (eq. (41)) has no "
            f"stabilising solution with these Q, R: {exc}"
        ) from exc
    # K = (R + B'PB)^-1 (B'PA + N'), by a solve (never an explicit inverse).
    K = np.linalg.solve(R + Be.T @ P @ Be, Be.T @ P @ Ae + S.T)
    poles = np.linalg.eigvals(Ae - Be @ K)
    if np.max(np.abs(poles)) >= 1.0:
        raise DesignError(
            "the LQR design is not stabilising (largest pole magnitude "
            f"{np.max(np.abs(poles)):.6g})"
        )
    ctrl = IntegralStateFeedback(
        K[:, : sys.nx],
        -K[:, sys.nx :],  # eq. (42): u = -F x + F_e e  =>  F_e = -K_e
        _selector_from(E, sys.ny),
        "lqr",
        {"Q": Q.tolist(), "R": R.tolist(), "poles": _poles_info(poles), "dt": sys.dt},
    )
    logger.info("LQR design: closed-loop |z| max %.6f", float(np.max(np.abs(poles))))
    return ctrl


def design_pole_placement(
    sys: StateSpace, *, poles: Any, E: Any = None, method: str = "YT"
) -> IntegralStateFeedback:
    """Pole placement on the extended model of eq. (41) (``scipy.signal.place_poles``).

    Parameters
    ----------
    sys : StateSpace
        Discrete plant.
    poles : array_like, shape (nx + ne,)
        Desired discrete closed-loop poles (z-plane; use ``np.exp(s * dt)`` for
        s-plane poles). Complex poles come in conjugate pairs.
    E : array_like, optional
        Integrated outputs (default: the first output).
    method : {"YT", "KNV0"}
        Algorithm of :func:`scipy.signal.place_poles` (both choose the free
        eigenvectors for robustness; YT handles complex poles).

    Returns
    -------
    IntegralStateFeedback

    Raises
    ------
    DesignError
        If the poles cannot be placed (uncontrollable extended model, a pole
        repeated more often than the number of inputs, poles outside the unit
        circle) or the achieved poles differ from the requested ones.
    """
    ext = extended_model(sys, E)
    Evalid = _selector_from(E, sys.ny)
    poles = np.asarray(poles, dtype=complex).reshape(-1)
    if poles.size != ext.nx:
        raise DataError(f"`poles` must hold {ext.nx} poles (nx + ne); got {poles.size}")
    if np.any(np.abs(poles) >= 1.0):
        raise DesignError(
            "`poles` are discrete (z-plane) poles and must lie inside the unit circle; got "
            + ", ".join(f"{p:.4g}" for p in poles[np.abs(poles) >= 1.0])
        )
    want = poles.real if np.all(poles.imag == 0) else poles
    try:
        from scipy.signal import place_poles  # scipy.signal takes ~1 s to import

        res = place_poles(ext.A, ext.B, want, method=method)
    except ValueError as exc:
        raise DesignError(
            f"pole placement on the extended model (eq. (41)) failed: {exc}"
        ) from exc
    K = res.gain_matrix
    got = np.linalg.eigvals(ext.A - ext.B @ K)
    err = _pole_mismatch(got, poles)
    if err > 1e-6:
        raise DesignError(
            f"pole placement reached poles up to {err:.3g} away from those requested; the "
            "extended model may be nearly uncontrollable"
        )
    return IntegralStateFeedback(
        K[:, : sys.nx],
        -K[:, sys.nx :],  # eq. (42)
        Evalid,
        "pole_placement",
        {"poles": _poles_info(poles), "method": method, "dt": sys.dt},
    )


def _selector_from(E: Any, ny: int) -> np.ndarray:
    return check_integral_selector(integral_selector([0], ny) if E is None else E, ny)


def _pole_mismatch(got: np.ndarray, want: np.ndarray) -> float:
    """Largest distance between two pole sets matched greedily (small sets)."""
    got = list(np.asarray(got, complex))
    worst = 0.0
    for w in np.asarray(want, complex):
        d = [abs(g - w) for g in got]
        i = int(np.argmin(d))
        worst = max(worst, d[i])
        got.pop(i)
    return worst
