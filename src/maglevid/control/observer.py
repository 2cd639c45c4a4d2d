"""State observers in the sign convention of Gosiewski & Paszowski, eqs. (17) and (43).

.. math::

    \\hat x(k+1) = (A + G C)\\,\\hat x(k) + B u(k) - G y(k)               \\qquad (17)

``G`` is the *negative* of the usual Luenberger/Kalman gain ``L`` of
``x̂(k+1) = A x̂ + B u + L (y - C x̂)``: ``G = -L``. The observer is of the
prediction type: ``x̂(k)`` uses the measurements up to ``y(k-1)``.

With integral action the observer is extended by the integrator of eq. (39),
fed with the measured outputs (eq. (43)); that part has no gain to design and is
run by the simulation (:mod:`maglevid.simulate.loop`).

Three designs:

* :func:`design_deadbeat_observer` -- ``A + G C`` nilpotent: the estimate is
  exact after ``nu`` steps (``nu`` = largest observability index; 2 for the
  bearing). This is the observer that makes the paper's exact ARX model
  (eqs. (32)-(38), (44)-(51)) finite.
* :func:`design_kalman_observer` -- steady-state (predictor) Kalman filter from
  the Riccati equation of the dual problem.
* :func:`design_observer_pole_placement` -- ``eig(A + G C)`` at given poles.
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
    "OBSERVER_KINDS",
    "Observer",
    "design_deadbeat_observer",
    "design_kalman_observer",
    "design_observer_pole_placement",
    "observability_indices",
]

logger = logging.getLogger(__name__)

#: Kinds of observer a recording's ``loop["observer"]["type"]`` may name.
OBSERVER_KINDS = ("deadbeat", "kalman", "pole_placement", "given")


@dataclass(frozen=True, eq=False)
class Observer:
    """A prediction observer ``x̂(k+1) = (A + G C) x̂(k) + B u(k) - G y(k)`` (eq. (17)).

    Parameters
    ----------
    G : array_like, shape (nx, ny)
        Observer gain in the paper's sign convention (``G = -L``).
    A, B, C : array_like
        The *observer's* discrete model (usually the nominal plant), shapes
        ``(nx, nx)``, ``(nx, nu)``, ``(ny, nx)``.
    kind : str
        One of :data:`OBSERVER_KINDS`.
    dt : float or None
        Sample time of the model [s].
    info : mapping
        JSON-safe design details (e.g. ``nilpotency_index`` of a deadbeat design).

    Examples
    --------
    >>> obs = Observer([[-0.5]], [[0.5]], [[1.0]], [[1.0]])
    >>> obs.A_bar.tolist()
    [[0.0]]
    """

    G: np.ndarray
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    kind: str = "given"
    dt: float | None = None
    info: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        A = as_matrix(self.A, "A")
        nx = A.shape[0]
        if A.shape != (nx, nx):
            raise DataError(f"`A` must be square; got shape {A.shape}")
        B = as_matrix(self.B, "B", (nx, None))
        C = as_matrix(self.C, "C", (None, nx))
        G = as_matrix(self.G, "G", (nx, C.shape[0]))
        if self.kind not in OBSERVER_KINDS:
            raise DataError(f"`kind` must be one of {OBSERVER_KINDS}; got {self.kind!r}")
        object.__setattr__(self, "A", A)
        object.__setattr__(self, "B", B)
        object.__setattr__(self, "C", C)
        object.__setattr__(self, "G", G)
        object.__setattr__(self, "dt", None if self.dt is None else float(self.dt))
        object.__setattr__(self, "info", MappingProxyType(dict(self.info)))

    @property
    def nx(self) -> int:
        return self.A.shape[0]

    @property
    def nu(self) -> int:
        return self.B.shape[1]

    @property
    def ny(self) -> int:
        return self.C.shape[0]

    @property
    def A_bar(self) -> np.ndarray:
        """``A + G C``, the observer's state matrix (eq. (18))."""
        return readonly(self.A + self.G @ self.C)

    def poles(self) -> np.ndarray:
        """Eigenvalues of ``A + G C``."""
        return np.linalg.eigvals(self.A + self.G @ self.C)

    def model(self) -> StateSpace:
        """The observer's plant model ``{A, B, C}`` as a :class:`StateSpace`."""
        return StateSpace(self.A, self.B, self.C, None, self.dt)

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form (the ``loop["observer"]`` entry of a recording)."""
        return {
            "type": self.kind,
            "G": self.G.tolist(),
            "A": self.A.tolist(),
            "B": self.B.tolist(),
            "C": self.C.tolist(),
            "dt": self.dt,
            "info": dict(self.info),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> Observer:
        return cls(
            np.asarray(d["G"], float),
            np.asarray(d["A"], float),
            np.asarray(d["B"], float),
            np.asarray(d["C"], float),
            str(d.get("type", "given")),
            d.get("dt"),
            dict(d.get("info", {})),
        )


def _require_discrete(sys: StateSpace) -> None:
    if not isinstance(sys, StateSpace):
        raise DataError(f"`sys` must be a maglevid StateSpace; got {type(sys).__name__}")
    if not sys.is_discrete:
        raise DesignError(
            "`sys` is a continuous-time model; observers of eqs. (17)/(43) are designed on "
            "the ZOH-sampled model (discretize(sys, dt))"
        )


def _balance(A: np.ndarray) -> np.ndarray:
    """Diagonal ``d`` with ``D^-1 A D`` balanced (no permutation)."""
    _, T = sla.matrix_balance(A, permute=False)
    return np.diag(T).copy()


def _select_chains(
    Ainv: np.ndarray, C: np.ndarray, tol: float
) -> tuple[list[int], list[np.ndarray]]:
    """Greedy (Luenberger "crate") selection of the rows ``c_i A^-l``, l = 1, 2, ...

    Output ``i`` keeps contributing rows while its newest row is independent of
    all rows selected before. Returns the chain length of every output (its
    observability index for the pair ``(A^-1, C)``, which has the same index
    list as ``(A, C)``) and the selected rows.
    """
    n, q = Ainv.shape[0], C.shape[0]
    mu = [0] * q
    cur = [C[i].copy() for i in range(q)]
    Q = np.zeros((n, 0))
    active = list(range(q))
    while active and Q.shape[1] < n:
        still = []
        for i in active:
            v = cur[i] @ Ainv
            r = v - Q @ (Q.T @ v)
            r = r - Q @ (Q.T @ r)  # re-orthogonalise (Gram-Schmidt twice is enough)
            if np.linalg.norm(r) > tol * np.linalg.norm(v):
                Q = np.column_stack([Q, r / np.linalg.norm(r)])
                mu[i] += 1
                cur[i] = v
                still.append(i)
                if Q.shape[1] == n:
                    break
        active = still
    return mu, [cur[i] for i in range(q)]


def observability_indices(sys: StateSpace, *, tol: float = 1e-8) -> tuple[int, ...]:
    """Observability indices of ``(A, C)`` per output (greedy, in output order).

    Rank decisions are taken in balanced coordinates with relative tolerance ``tol``.
    For the bearing: ``(2, 1, 1)`` -- the displacement is observed with its
    derivative, each current on its own.
    """
    _require_discrete(sys)
    d = _balance(sys.A)
    Ab = sys.A / d[:, None] * d[None, :]
    Cb = sys.C * d[None, :]
    Ainv = _inverse_or_raise(Ab)
    mu, _ = _select_chains(Ainv, Cb, tol)
    return tuple(mu)


def _inverse_or_raise(Ab: np.ndarray) -> np.ndarray:
    s = np.linalg.svd(Ab, compute_uv=False)
    if s[-1] <= 1e-12 * s[0]:
        raise DesignError(
            "the deadbeat construction needs a nonsingular A (it solves a Sylvester equation "
            "between A and a nilpotent matrix); A is singular here. A ZOH-sampled model "
            "A = exp(A_c dt) is never singular"
        )
    return np.linalg.solve(Ab, np.eye(Ab.shape[0]))


def design_deadbeat_observer(
    sys: StateSpace, *, tol: float = 1e-8, nilpotency_tol: float = 1e-9
) -> Observer:
    """Deadbeat observer: ``A + G C`` nilpotent (Gosiewski & Paszowski, eqs. (17), (20)).

    Parameters
    ----------
    sys : StateSpace
        Discrete model ``{A, B, C}`` the observer is built on.
    tol : float
        Relative tolerance of the rank decisions that find the observability
        indices (taken in balanced coordinates).
    nilpotency_tol : float
        Largest accepted ``||(A+GC)^nu|| / max(1, ||A+GC||)^nu`` (balanced
        coordinates, 2-norm), where ``nu`` is the nilpotency index.

    Returns
    -------
    Observer
        ``kind="deadbeat"``; ``info["nilpotency_index"]`` = ``nu`` (the estimate is
        exact ``nu`` steps after start-up, for an exact model and no noise) and
        ``info["observability_indices"]``.

    Raises
    ------
    DesignError
        If ``(A, C)`` is unobservable, ``A`` is singular, or the computed ``A + GC``
        fails the nilpotency check.

    Notes
    -----
    ``scipy.signal.place_poles`` cannot place a pole more often than ``rank(C)``
    times, so "all poles at zero" is done by eigenstructure assignment on the
    dual pair ``(A', C')``. With the observability indices ``mu_i`` (found by a
    greedy rank test on the rows ``c_i A^-l``) take the nilpotent Jordan matrix
    ``J = diag(J_mu1, J_mu2, ...)`` (upper shift blocks) and the parameter matrix
    ``H`` with ``e_i`` in the first column of chain ``i`` and zeros elsewhere.
    The Sylvester equation

        A' T - T J = -C' H

    has a unique solution because ``A`` (= exp(A_c dt)) and ``J`` share no
    eigenvalue; chain by chain it is ``t_{i,l} = -(c_i A^-l)'``, so ``T`` is
    nonsingular exactly when the selected rows are independent. Then
    ``K = H T^-1`` gives ``(A' + C' K) T = T J``, i.e. ``A + G C`` similar to
    ``J'`` with ``G = K'``: nilpotent of index ``max mu_i``. Everything is done
    in the coordinates balancing ``A`` (the bearing's ``A`` mixes 1e-4 and
    1e+2 entries) and mapped back, ``G = D G_b``.

    Examples
    --------
    >>> from maglevid.physics.amb import AMBParameters, amb_state_space
    >>> obs = design_deadbeat_observer(amb_state_space(AMBParameters.nominal(), 1e-4))
    >>> obs.info["nilpotency_index"]
    2
    """
    _require_discrete(sys)
    n, q = sys.nx, sys.ny
    d = _balance(sys.A)
    Ab = sys.A / d[:, None] * d[None, :]  # D^-1 A D
    Cb = sys.C * d[None, :]  # C D
    Ainv = _inverse_or_raise(Ab)
    mu, _ = _select_chains(Ainv, Cb, tol)
    if sum(mu) < n:
        raise DesignError(
            f"(A, C) is not observable (the observability indices {mu} sum to {sum(mu)} < "
            f"nx = {n}): no deadbeat observer exists"
        )
    # Chains: t_{i,l} = -(c_i A^-l)', H e_i in the first column of chain i.
    cols, hcols, blocks = [], [], []
    for i in range(q):
        v = Cb[i].copy()
        for l in range(mu[i]):
            v = v @ Ainv
            cols.append(-v)
            h = np.zeros(q)
            if l == 0:
                h[i] = 1.0
            hcols.append(h)
        if mu[i]:
            blocks.append(np.eye(mu[i], k=1))
    T = np.column_stack(cols)
    H = np.column_stack(hcols)
    J = sla.block_diag(*blocks)
    # K = H T^-1  <=>  T' K' = H'; G_b = K'.
    Gb = np.linalg.solve(T.T, H.T)
    nu = max(mu)
    Abar_b = Ab + Gb @ Cb
    power = np.linalg.matrix_power(Abar_b, nu)
    rel = float(np.linalg.norm(power, 2) / max(1.0, np.linalg.norm(Abar_b, 2)) ** nu)
    sylv = float(np.max(np.abs(Ab.T @ T - T @ J + Cb.T @ H)))
    if not rel <= nilpotency_tol:
        raise DesignError(
            f"the deadbeat gain is numerically inaccurate: ||(A+GC)^{nu}|| relative = {rel:.3g} "
            f"> {nilpotency_tol:g} (cond(T) = {np.linalg.cond(T):.3g}); the model is close to "
            "unobservable"
        )
    G = Gb * d[:, None]  # G = D G_b
    logger.info("deadbeat observer: indices %s, nilpotency index %d, residual %.3g", mu, nu, rel)
    return Observer(
        G,
        sys.A,
        sys.B,
        sys.C,
        "deadbeat",
        sys.dt,
        {
            "nilpotency_index": nu,
            "observability_indices": list(mu),
            "nilpotency_residual": rel,
            "sylvester_residual": sylv,
        },
    )


def design_kalman_observer(sys: StateSpace, *, Q: Any, R: Any, N: Any = None) -> Observer:
    """Steady-state Kalman predictor in the paper's sign convention (``G = -L``).

    For ``x(k+1) = A x + B u + w``, ``y = C x + v`` with ``cov(w) = Q``,
    ``cov(v) = R`` and ``cov(w, v) = N``, the Riccati equation of the dual problem
    ``P = A P A' - (A P C' + N)(C P C' + R)^-1 (A P C' + N)' + Q`` gives the
    predictor gain ``L = (A P C' + N)(C P C' + R)^-1`` and ``G = -L`` (eq. (17)).

    Parameters
    ----------
    sys : StateSpace
        Discrete model.
    Q : array_like, shape (nx, nx)
        Process noise covariance.
    R : array_like, shape (ny, ny)
        Measurement noise covariance (positive definite).
    N : array_like, shape (nx, ny), optional
        Cross covariance.

    Raises
    ------
    DesignError
        If the Riccati equation has no stabilising solution.
    """
    _require_discrete(sys)
    n, q = sys.nx, sys.ny
    Q = as_matrix(Q, "Q", (n, n))
    R = as_matrix(R, "R", (q, q))
    S = np.zeros((n, q)) if N is None else as_matrix(N, "N", (n, q))
    A, C = sys.A, sys.C
    try:
        P = sla.solve_discrete_are(A.T, C.T, Q, R, s=S)  # dual of the LQR problem
    except (np.linalg.LinAlgError, ValueError) as exc:
        raise DesignError(
            f"the Kalman Riccati equation has no stabilising solution: {exc}"
        ) from exc
    # L' = (C P C' + R)^-1 (C P A' + N'), by a solve.
    L = np.linalg.solve(C @ P @ C.T + R, C @ P @ A.T + S.T).T
    G = -L  # eq. (17) sign convention
    obs = Observer(G, A, sys.B, C, "kalman", sys.dt, {"Q": Q.tolist(), "R": R.tolist()})
    if np.max(np.abs(obs.poles())) >= 1.0:
        raise DesignError("the Kalman observer is not stable (check Q, R and detectability)")
    return obs


def design_observer_pole_placement(sys: StateSpace, *, poles: Any, method: str = "YT") -> Observer:
    """Observer with ``eig(A + G C)`` at the given discrete poles (dual pole placement).

    ``place_poles(A', C', poles)`` returns ``K`` with ``eig(A' - C' K) = poles``, so
    ``G = -K'``. A pole may be repeated at most ``rank(C)`` times; for all poles at
    zero use :func:`design_deadbeat_observer`.
    """
    _require_discrete(sys)
    poles = np.asarray(poles, dtype=complex).reshape(-1)
    if poles.size != sys.nx:
        raise DataError(f"`poles` must hold nx = {sys.nx} poles; got {poles.size}")
    if np.any(np.abs(poles) >= 1.0):
        raise DesignError("observer `poles` are z-plane poles and must lie inside the unit circle")
    want = poles.real if np.all(poles.imag == 0) else poles
    try:
        from scipy.signal import place_poles  # scipy.signal takes ~1 s to import

        res = place_poles(sys.A.T, sys.C.T, want, method=method)
    except ValueError as exc:
        raise DesignError(f"observer pole placement failed: {exc}") from exc
    G = -res.gain_matrix.T
    return Observer(
        G,
        sys.A,
        sys.B,
        sys.C,
        "pole_placement",
        sys.dt,
        {"poles": [[float(p.real), float(p.imag)] for p in np.sort_complex(poles)]},
    )
