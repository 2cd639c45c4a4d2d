"""Linear closed-loop simulation for the tests of the closed-loop methods.

A discrete plant ``x+ = A x + B (u + w)``, ``y = C x + v`` under a discrete
controller fed by exogenous signals and the measured outputs. ``w`` (input noise)
and ``v`` (output noise) are white and Gaussian; both are optional.
"""

from __future__ import annotations

import numpy as np

from maglevid.data import ClosedLoopData
from maglevid.lti import StateSpace


def simulate_linear_loop(
    plant: StateSpace,
    controller: StateSpace,
    feedback: list[int],
    exogenous: np.ndarray,
    *,
    input_noise: float = 0.0,
    output_noise: np.ndarray | float = 0.0,
    rng: np.random.Generator | None = None,
    names: dict | None = None,
) -> ClosedLoopData:
    """Simulate; returns ClosedLoopData(y = measured outputs, u = plant input, r = exogenous).

    ``feedback[j]`` is the plant output feeding controller input ``j`` (``-1``: the
    next exogenous column).
    """
    rng = np.random.default_rng(0) if rng is None else rng
    r = np.atleast_2d(np.asarray(exogenous, dtype=float).T).T
    n = r.shape[0]
    x = np.zeros(plant.nx)
    xk = np.zeros(controller.nx)
    Y = np.empty((n, plant.ny))
    U = np.empty((n, plant.nu))
    v = np.broadcast_to(np.asarray(output_noise, dtype=float), (plant.ny,))
    V = rng.standard_normal((n, plant.ny)) * v
    W = rng.standard_normal((n, plant.nu)) * input_noise
    for t in range(n):
        y = plant.C @ x + V[t]
        w = np.empty(controller.nu)
        e = 0
        for j, f in enumerate(feedback):
            if f >= 0:
                w[j] = y[f]
            else:
                w[j] = r[t, e]
                e += 1
        u = controller.C @ xk + controller.D @ w
        xk = controller.A @ xk + controller.B @ w
        x = plant.A @ x + plant.B @ (u + W[t])
        Y[t] = y
        U[t] = u
    return ClosedLoopData(y=Y, u=U, r=r, dt=plant.dt, names=names or {})
