"""Linear closed-loop simulation and small test systems for the closed-loop methods.

A discrete plant ``x+ = A x + B (u + w) + K e``, ``y = C x + e + v`` under a discrete
controller fed by exogenous signals and the measured outputs: ``w`` input noise,
``v`` output noise, ``e`` innovations entering through ``K`` (an ARX or ARMAX noise
model when the plant is in observer form). All noise is white Gaussian, optional.
"""

from __future__ import annotations

import numpy as np

from maglevid.control.cascade_pid import pid_state_space
from maglevid.data import ClosedLoopData
from maglevid.identify.closedloop import innovations_from_polynomials
from maglevid.lti import StateSpace
from maglevid.physics.levitator import LevitatorParameters, mechanical_state_space

DT = 0.01
#: Mechanical plant i -> y of the UAQ levitator at 5 mm, ZOH-sampled (poles exp(+-p dt)).
MECH = mechanical_state_space(LevitatorParameters.uaq(), 0.005, dt=DT)


def mech_polynomials() -> tuple[np.ndarray, np.ndarray]:
    """``A(q^-1)``, ``B(q^-1)`` (``b0 = 0``) of :data:`MECH`."""
    den = np.poly(MECH.A)
    num = np.poly(MECH.A - MECH.B @ MECH.C) - den
    return den, num


def position_pid(kp: float = 100.0, ki: float = 50.0, kd: float = 1.5) -> StateSpace:
    """``i = -PID(r - y)``, inputs ``[r, y]``: the UAQ outer loop acting on the current."""
    pid = pid_state_space(kp, ki, kd, DT)
    M = np.array([[1.0, -1.0]])
    return StateSpace(pid.A, pid.B @ M, -pid.C, -pid.D @ M, DT)


def arx_plant(a: np.ndarray, b: np.ndarray, c: np.ndarray | None = None) -> tuple:
    """Observer-form plant and noise gain of ``A y = B u + C e``: ``(StateSpace, K)``."""
    inn = innovations_from_polynomials(a, [b], c)
    return StateSpace(inn.A, inn.B, inn.C, inn.D, DT), inn.K


def simulate_linear_loop(
    plant: StateSpace,
    controller: StateSpace,
    feedback: list[int],
    exogenous: np.ndarray,
    *,
    input_noise: float = 0.0,
    output_noise: np.ndarray | float = 0.0,
    innovations: tuple[np.ndarray, float] | None = None,
    rng: np.random.Generator | None = None,
    names: dict | None = None,
) -> ClosedLoopData:
    """Simulate; returns ClosedLoopData(y = measured outputs, u = plant input, r = exogenous).

    ``feedback[j]`` is the plant output feeding controller input ``j`` (``-1``: the
    next exogenous column). ``innovations = (K, std)`` adds ``K e`` to the state and
    ``e`` to the (single) output.
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
    if innovations is not None:
        Kn, s = innovations
        E = rng.standard_normal((n, plant.ny)) * s
    for t in range(n):
        y = plant.C @ x + V[t] + (E[t] if innovations is not None else 0.0)
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
        if innovations is not None:
            x = x + (Kn @ E[t]).ravel()
        Y[t] = y
        U[t] = u
    return ClosedLoopData(y=Y, u=U, r=r, dt=plant.dt, names=names or {})


def random_steps(n: int, *, hold: int, levels: tuple[float, ...], rng: np.random.Generator):
    """A reference of random levels held ``hold`` samples each."""
    return np.repeat(rng.choice(levels, size=-(-n // hold)), hold)[:n]
