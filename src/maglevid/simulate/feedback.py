"""A generic MIMO plant in innovation form under a dynamic LTI controller (closed loop).

For methods that must not be tied to one plant: any ``(A, B, C, K)`` plant,
any discrete controller ``xc+ = Ac xc + Bc y``, ``u = Cc xc + Dc y + r``
(direct feedthrough of the measured ``y`` allowed), a white reference ``r``
and white innovations ``e``::

    x(t+1) = A x(t) + B u(t) + K e(t),   y(t) = C x(t) + e(t)

The loop is one linear system in ``[x; xc]`` with inputs ``[r; e]`` and
outputs ``[y; u]``, run by :func:`maglevid.simulate.kernel.simulate_lti`.
"""

from __future__ import annotations

import numpy as np

from maglevid.exceptions import DesignError
from maglevid.lti import StateSpace
from maglevid.simulate.kernel import simulate_lti

__all__ = ["example_unstable_mimo", "simulate_innovation_loop"]


def example_unstable_mimo() -> tuple[StateSpace, np.ndarray, StateSpace]:
    """``(plant, K, controller)``: an unstable 3-state, 2-in, 2-out plant and its controller.

    Plant pole 1.072 (and 0.589 +- 0.245j), noise gain ``K`` with ``A - K C``
    stable (spectral radius 0.62); a 2-state controller with direct
    feedthrough of ``y``, so ``u(t)`` depends on the current innovation. A test
    case of the closed-loop methods that is not a bearing (docs/subspace.md).
    """
    A = np.array([[1.05, 0.2, 0.0], [0.0, 0.7, 0.3], [0.1, -0.2, 0.5]])
    B = np.array([[0.0, 1.0], [1.0, 0.0], [0.5, 0.5]])
    C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    K = np.array([[0.5, 0.0], [0.1, 0.2], [0.0, 0.4]])
    ctrl = StateSpace(
        np.diag([0.5, 0.3]),
        0.5 * np.eye(2),
        -np.diag([0.2, 0.1]),
        -np.array([[0.0, 0.3], [0.6, 0.0]]),
        dt=1.0,
    )
    return StateSpace(A, B, C, np.zeros((2, 2)), dt=1.0), K, ctrl


def simulate_innovation_loop(
    plant: StateSpace,
    K: np.ndarray,
    controller: StateSpace,
    n_samples: int,
    *,
    r_std: float = 1.0,
    e_std: float = 0.0,
    rng: np.random.Generator | int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """``(y, u)`` of the closed loop, time first; ``plant.D`` must be 0.

    ``controller`` maps ``y`` to ``u`` (``nu`` outputs, ``ny`` inputs); the
    reference ``r`` (``r_std`` rms) is added to its output, the innovations
    ``e`` (``e_std`` rms) drive the plant through ``K`` and appear on ``y``.

    Raises
    ------
    DesignError
        The controller does not stabilise the plant.
    """
    A, B, C = plant.A, plant.B, plant.C
    ny, nu = plant.ny, plant.nu
    Ac, Bc, Cc, Dc = controller.A, controller.B, controller.C, controller.D
    nc = Ac.shape[0]
    Acl = np.block([[A + B @ Dc @ C, B @ Cc], [Bc @ C, Ac]])
    Bcl = np.block([[B, K + B @ Dc], [np.zeros((nc, nu)), Bc]])
    Ccl = np.block([[C, np.zeros((ny, nc))], [Dc @ C, Cc]])
    Dcl = np.block([[np.zeros((ny, nu)), np.eye(ny)], [np.eye(nu), Dc]])
    rho = float(np.max(np.abs(np.linalg.eigvals(Acl))))
    if rho >= 1.0:
        raise DesignError(f"the controller does not stabilise the plant (|pole| {rho:.4g})")
    g = np.random.default_rng(rng)
    w = np.hstack(
        [r_std * g.standard_normal((n_samples, nu)), e_std * g.standard_normal((n_samples, ny))]
    )
    out, _ = simulate_lti(StateSpace(Acl, Bcl, Ccl, Dcl, dt=plant.dt), w)
    return out[:, :ny], out[:, ny:]
