"""PRIVATE stand-in for maglevid.simulate.simulate_amb_loop until branch `sim` lands.

DELETE this file once `maglevid.simulate` and `maglevid.control` are merged into
main; the tests then use the real simulator. It follows the paper's equations
(39)-(43) literally, step by step, independently of maglevid.identify:

    y(k) = C x(k) + w(k)
    e(k) = e(k-1) - E y(k)                     (eq. (39))
    u_f(k) = -F xh(k) + Fe e(k)                (eq. (42))
    u(k) = u_f(k) + r(k)
    xh(k+1) = (Ao + G C) xh(k) + Bo u(k) - G y(k)   (eq. (43))
    x(k+1) = A x(k) + B u(k)
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from maglevid.data import ClosedLoopData
from maglevid.physics.amb import C_AMB, AMBParameters, amb_state_space

E_POS = np.array([[1.0, 0.0, 0.0]])


def deadbeat_gain(A: np.ndarray) -> np.ndarray:
    # A + G C = a c^T with a = A[:, 1] (the column C cannot touch) and c^T a = 0:
    # rank one and nilpotent, so (A + G C)^2 = 0 exactly.
    a = A[:, 1]
    c = np.array([-a[1] / a[0], 1.0, 0.0, 0.0])
    return (np.outer(a, c) - A)[:, [0, 2, 3]]


def lqr_integral(A, B, *, symmetric: bool):
    n = A.shape[0]
    Ae = np.block([[A, np.zeros((n, 1))], [-E_POS @ C_AMB @ A, np.eye(1)]])
    Be = np.vstack([B, -E_POS @ C_AMB @ B])
    Q = np.diag([1e10, 1e3, 1e2, 1e2, 1e6])
    R = np.eye(2) if symmetric else np.diag([1.0, 1.7])
    X = sla.solve_discrete_are(Ae, Be, Q, R)
    K = np.linalg.solve(R + Be.T @ X @ Be, Be.T @ X @ Ae)
    return K[:, :n], -K[:, n:]


def simulate_amb_loop(
    plant: AMBParameters,
    *,
    dt: float = 1e-4,
    n_samples: int = 2000,
    nominal: AMBParameters | None = None,
    observer_on: str = "nominal",
    symmetric: bool = False,
    excitation_std: float = 1.0,
    noise_std=(0.0, 0.0, 0.0),
    rng: np.random.Generator,
) -> ClosedLoopData:
    nominal = plant if nominal is None else nominal
    sp = amb_state_space(plant, dt)
    sn = amb_state_space(nominal, dt)
    A, B, C = sp.A, sp.B, C_AMB
    Ao, Bo = (sn.A, sn.B) if observer_on == "nominal" else (A, B)
    F, Fe = lqr_integral(sn.A, sn.B, symmetric=symmetric)
    G = deadbeat_gain(sn.A)
    r = rng.standard_normal((n_samples, 2)) * excitation_std
    w = rng.standard_normal((n_samples, 3)) * np.asarray(noise_std, dtype=float)
    x = np.zeros(4)
    xh = np.zeros(4)
    e = np.zeros(1)
    Y = np.empty((n_samples, 3))
    U = np.empty((n_samples, 2))
    Uf = np.empty((n_samples, 2))
    Aog = Ao + G @ C
    for k in range(n_samples):
        y = C @ x + w[k]
        e = e - E_POS @ y
        uf = -F @ xh + Fe @ e
        u = uf + r[k]
        Y[k], U[k], Uf[k] = y, u, uf
        xh = Aog @ xh + Bo @ u - G @ y
        x = A @ x + B @ u
    loop = {
        "controller": {"type": "state_feedback_integral", "F": F, "Fe": Fe, "E": E_POS},
        "observer": {"type": "prediction", "G": G, "A": Ao, "B": Bo, "C": C},
        "C": C,
        "operating_point": {"i0": nominal.i0, "x0": nominal.x0, "m": nominal.m},
        "nominal": nominal.to_dict(),
        "dt_design": dt,
    }
    return ClosedLoopData(
        y=Y,
        u=U,
        r=r,
        u_f=Uf,
        dt=dt,
        names={"y": ("x", "i1", "i2"), "u": ("u1", "u2")},
        loop=loop,
        metadata={"truth": plant.to_dict()},
    )
