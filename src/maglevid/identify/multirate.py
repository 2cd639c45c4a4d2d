"""Delta-model <-> T-model under output inter-sampling (Sun et al., Theorems 1 and 2).

The plant input is held for ``T = p Delta``; the output is sampled every
``Delta``. With the Delta-model ``x(k+1) = Lam x(k) + phi u(k), y(k) = psi x(k)``
and ``u(k) = u(m)`` for ``k = mp .. mp+p-1``, the state at the control
instants obeys

.. math::

    x((m+1)p) = \\Lambda^p x(mp) + \\Gamma u(m), \\qquad
    \\Gamma = \\sum_{i=0}^{p-1} \\Lambda^i \\varphi,

and the inter-sample ``y_j(m) = y(mp + j)`` is

.. math::

    y_j(m) = \\psi \\Lambda^j x(mp) + \\psi S_j u(m), \\qquad
    S_j = \\sum_{i=0}^{j-1} \\Lambda^i \\varphi .

With ``M(z) = I - Lam^p z^-1`` and ``R_j = sum_{i=j}^{p-1} Lam^i phi`` (so that
``Lam^j Gamma - Lam^p S_j = R_j``), ``adj(M) M = det(M) I`` turns the transfer
function ``psi Lam^j (zI - Lam^p)^-1 Gamma + psi S_j`` into

.. math::

    B_j(z^{-1}) = \\psi\\, \\mathrm{adj}(M) (S_j + z^{-1} R_j), \\qquad
    A(z^{-1}) = \\det M,

which is eq. (6a) (with ``tau_Delta = 1``). For ``j = 0``, ``S_0 = 0`` and
``R_0 = Gamma``: ``B_0 = z^-1 psi adj(M) sum_{i=0}^{p-1} Lam^i phi``. **The
printed eq. (5b) starts its sum at i = 1**; that drops ``phi`` and disagrees
with (6a) at ``j = 0`` and with the direct ZOH at ``T`` (tested). We use i = 0.

A plant delay of ``d`` whole control periods (``tau_T = d + 1``,
``tau_Delta = p d + 1``) multiplies every numerator by ``z^-d``.
"""

from __future__ import annotations

import numpy as np

from maglevid.exceptions import DataError, ModelError
from maglevid.lti import StateSpace

__all__ = [
    "intersample_numerators",
    "lift_intersample",
    "t_model_from_delta",
    "t_polynomials_from_delta",
]


def _check(sys_delta: StateSpace, p: int) -> int:
    if not sys_delta.is_discrete:
        raise ModelError("the Delta-model must be discrete (dt = Delta)")
    if sys_delta.nu != 1 or sys_delta.ny != 1:
        raise ModelError(f"Theorems 1-2 are stated for a SISO Delta-model; got {sys_delta!r}")
    if np.any(sys_delta.D != 0):
        raise ModelError("the Delta-model must be strictly proper (D = 0, tau_Delta >= 1)")
    if isinstance(p, bool) or not isinstance(p, (int, np.integer)) or p < 1:
        raise DataError(f"`p` must be an integer >= 1; got {p!r}")
    return int(p)


def lift_intersample(sys_delta: StateSpace, p: int) -> StateSpace:
    """The SIMO T-model of Fig. 3: one input ``u(m)``, outputs ``y_0(m) .. y_(p-1)(m)``.

    ``A = Lam^p``, ``B = Gamma``, row ``j`` of ``C`` is ``psi Lam^j`` and of ``D``
    is ``psi S_j``; ``dt = p Delta``.

    Examples
    --------
    >>> sys = StateSpace([[0.5]], [[1.0]], [[1.0]], dt=0.1)
    >>> lift_intersample(sys, 2).D.ravel().tolist()
    [0.0, 1.0]
    """
    p = _check(sys_delta, p)
    Lam, phi, psi = sys_delta.A, sys_delta.B, sys_delta.C
    n = sys_delta.nx
    C = np.empty((p, n))
    D = np.empty((p, 1))
    S = np.zeros((n, 1))  # S_j = sum_{i<j} Lam^i phi
    Lj = np.eye(n)  # Lam^j
    for j in range(p):
        C[j] = (psi @ Lj)[0]
        D[j] = (psi @ S)[0]
        S = S + Lj @ phi
        Lj = Lj @ Lam
    # after the loop: Lj = Lam^p, S = Gamma
    return StateSpace(Lj, S, C, D, p * sys_delta.dt, output_names=tuple(f"y{j}" for j in range(p)))


def t_model_from_delta(sys_delta: StateSpace, p: int) -> StateSpace:
    """Theorem 1 in state-space form: ``(Lam^p, sum_{i<p} Lam^i phi, psi)`` at ``dt = p Delta``."""
    lifted = lift_intersample(sys_delta, p)
    return StateSpace(lifted.A, lifted.B, lifted.C[:1], None, lifted.dt)


def _adj_times(A: np.ndarray, psi: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Coefficients of ``psi adj(I - A z^-1) v`` in ``z^0 .. z^-(n-1)``.

    ``psi adj(I - A z^-1) v = det(I - A z^-1) psi (I - A z^-1)^-1 v``; its
    coefficients are the product of ``det(I - A z^-1)`` with the series
    ``sum_k psi A^k v z^-k``, truncated at ``z^-(n-1)`` (no cancellation).
    """
    n = A.shape[0]
    a = np.real(np.poly(A))
    h = np.empty(n)
    w = v.copy()
    for k in range(n):
        h[k] = (psi @ w).item()
        w = A @ w
    return np.array([np.dot(a[: k + 1], h[k::-1]) for k in range(n)])


def intersample_numerators(
    sys_delta: StateSpace, p: int, *, delay: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Common denominator and the numerators ``B_j`` of Theorem 2, eq. (6a).

    Parameters
    ----------
    sys_delta : StateSpace
        Strictly proper SISO Delta-model ``(Lam, phi, psi)``, ``dt = Delta``.
    p : int
        Inter-sampling rate.
    delay : int
        Extra plant delay in whole control periods (``tau_T - 1``).

    Returns
    -------
    a : ndarray, shape (n+1,)
        ``A(z^-1) = det(I - Lam^p z^-1)``, eq. (5a).
    B : ndarray, shape (p, n+1+delay)
        Row ``j``: coefficients of ``B_j(z^-1)`` in ``z^0, z^-1, ...``; row 0 is
        ``B(z^-1)`` of Theorem 1 (eq. (5b) with its sum from ``i = 0``).
    """
    p = _check(sys_delta, p)
    if isinstance(delay, bool) or not isinstance(delay, (int, np.integer)) or delay < 0:
        raise DataError(f"`delay` must be an integer >= 0; got {delay!r}")
    Lam, phi, psi = sys_delta.A, sys_delta.B, sys_delta.C
    n = sys_delta.nx
    Ap = np.linalg.matrix_power(Lam, p)
    a = np.real(np.poly(Ap))  # eq. (5a)
    B = np.zeros((p, n + 1 + delay))
    S = np.zeros((n, 1))
    Lj = np.eye(n)
    terms = [Lj @ phi]
    for _ in range(1, p):
        Lj = Lj @ Lam
        terms.append(Lj @ phi)  # Lam^i phi, i = 0..p-1
    for j in range(p):
        S = sum(terms[:j], np.zeros((n, 1)))  # S_j
        Rj = sum(terms[j:], np.zeros((n, 1)))  # R_j
        B[j, delay : delay + n] += _adj_times(Ap, psi, S)  # eq. (6a), first sum
        B[j, delay + 1 : delay + n + 1] += _adj_times(Ap, psi, Rj)  # eq. (6a), z^-1 sum
    return a, B


def t_polynomials_from_delta(
    sys_delta: StateSpace, p: int, *, delay: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Theorem 1, eqs. (5a)-(5b): ``(a, b)`` of the T-model in ``z^-1``."""
    a, B = intersample_numerators(sys_delta, p, delay=delay)
    return a, B[0]
