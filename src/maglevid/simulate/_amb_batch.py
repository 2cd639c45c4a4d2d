"""Many closed loops of one bearing at once: the nonlinear AMB loop vectorised over records.

:func:`maglevid.simulate.amb.simulate_amb_loops` runs here. The sample-by-sample
loop of :func:`maglevid.simulate.amb._simulate_nonlinear` costs ~7.5 us a
sample in Python (RK4 of eq. (1), observer eq. (43), control law eq. (42)); the
same loop on arrays of ``B`` records pays its per-sample Python and numpy-call
overhead once for all ``B``.

Equality with the one-record loop, bit for bit: every element goes through the
same IEEE operations in the same order. The RK4 stages below are those of
:func:`~maglevid.simulate.amb._rk4_stepper` with the two coils stacked in rows
(coil 2's ``+`` terms written as ``-`` of a negated constant, which rounds
identically: ``a - (-b) == a + b`` and ``(-h f) v / g == -(h f v / g)`` exactly),
and the observer/controller product is the same BLAS ``gemv`` per record as
there (a stacked ``matmul``; one ``gemm`` for the batch differs at 1e-16). Tested
(``tests/simulate/test_simulate_batch.py``).
"""

from __future__ import annotations

import math

import numpy as np

from maglevid.exceptions import ModelError
from maglevid.physics.amb import AMBParameters

__all__: list[str] = []


class _BatchRK4:
    """RK4 of eq. (1) under a constant input on ``(4, B)`` states ``[x, x', I1, I2]``.

    Same equations and operation order as
    :func:`~maglevid.simulate.amb._rk4_stepper` (one record on Python floats),
    with the coils as rows 0 and 1 of ``(2, B)`` arrays; every operation writes
    into a buffer made once (a numpy call on a few dozen numbers costs its
    overhead, not its arithmetic).
    """

    def __init__(self, p: AMBParameters, h: float, batch: int) -> None:
        col = lambda a, b: np.array([[a], [b]], dtype=float)  # noqa: E731
        self.x0, self.m, self.h = p.x0, p.m, h
        self.sign = col(1.0, -1.0)  # g_j = x0 - s_j x: x0 - x, x0 + x
        self.q = col(p.K1 / 4.0, p.K2 / 4.0)  # force constants
        self.hf = col(p.K1 / 2.0, p.K2 / 2.0)  # flux constants K_j / 2
        self.hs = col(p.K1 / 2.0, -p.K2 / 2.0)  # with eq. (1)'s sign of the motion EMF
        self.R = col(p.R1, p.R2)
        self.Ls = col(p.Ls1, p.Ls2)
        self.kw = col(p.kw1, p.kw2)
        self.hh, self.h6 = 0.5 * h, h / 6.0
        self.k = np.empty((4, 4, batch))  # the four stages' derivatives
        self.g, self.f, self.t, self.a = (np.empty((2, batch)) for _ in range(4))
        self.zs, self.acc, self.tmp = (np.empty((4, batch)) for _ in range(3))

    def _rhs(self, z: np.ndarray, fz: np.ndarray, k: np.ndarray) -> None:
        # eq. (1): m x'' = K1/4 (I1/g1)^2 - K2/4 (I2/g2)^2 + F_z,
        # (Ls_j + K_j/(2 g_j)) I_j' = kw_j u_j - R_j I_j -+ K_j I_j x' / (2 g_j^2)
        g, f, t = self.g, self.f, self.t
        np.multiply(self.sign, z[0], out=g)
        np.subtract(self.x0, g, out=g)  # g_j
        np.divide(z[2:4], g, out=f)  # I_j / g_j
        np.multiply(self.q, f, out=t)
        t *= f
        k[0] = z[1]
        np.subtract(t[0], t[1], out=k[1])
        k[1] += fz
        k[1] /= self.m
        ka = k[2:4]
        np.multiply(self.R, z[2:4], out=ka)
        np.subtract(self.a, ka, out=ka)  # kw_j u_j - R_j I_j
        np.multiply(self.hs, f, out=t)
        t *= z[1]
        t /= g
        ka -= t
        np.divide(self.hf, g, out=t)
        t += self.Ls  # Ls_j + K_j / (2 g_j)
        ka /= t

    def step(self, z: np.ndarray, u: np.ndarray, fz: np.ndarray) -> None:
        """``z`` (4, B) one step on, in place, under ``u`` (2, B) [V] and ``fz`` (B,) [N]."""
        k, zs, acc, tmp = self.k, self.zs, self.acc, self.tmp
        np.multiply(self.kw, u, out=self.a)
        self._rhs(z, fz, k[0])
        for i, c in ((1, self.hh), (2, self.hh), (3, self.h)):
            np.multiply(c, k[i - 1], out=zs)
            zs += z
            self._rhs(zs, fz, k[i])  # k[3, 0] is the stage-4 velocity, the one-record k4x
        np.multiply(2.0, k[1], out=acc)
        np.add(k[0], acc, out=acc)
        np.multiply(2.0, k[2], out=tmp)
        acc += tmp
        acc += k[3]
        acc *= self.h6
        z += acc


def simulate_nonlinear_batch(
    plant: AMBParameters,
    *,
    M: np.ndarray,
    state0: np.ndarray,
    start: tuple[float, float, float],
    i0: float,
    u_bias: tuple[float, float],
    dt: float,
    r: np.ndarray,
    v: np.ndarray,
    force: np.ndarray,
    substeps: int,
    gains: tuple[float, float, float],
) -> tuple[np.ndarray, np.ndarray]:
    """``B`` loops of eq. (1) with the observer/controller product ``M``. Returns y, u_f.

    ``M`` maps ``q = [x̂(k); e(k-1); y(k); r(k)]`` to ``[x̂(k+1); e(k); u_f(k)]``
    (see :func:`~maglevid.simulate.amb._loop_product`); ``state0`` (B, nx + ne)
    the first ``[x̂(0); e(-1)]`` of each record; ``start`` the rest point
    ``(x, I1, I2)``; ``r`` (B, N, 2), ``v`` (B, N, 3), ``force`` (B, N).
    Returns ``y`` (B, N, 3) and ``u_f`` (B, N, 2).
    """
    B, N = r.shape[0], r.shape[1]
    ns = state0.shape[1]
    rk4 = _BatchRK4(plant, dt / substeps, B)
    z = np.empty((4, B))
    z[0], z[1], z[2], z[3] = start[0], 0.0, start[1], start[2]
    g = np.array([[gains[0]], [gains[1]], [gains[2]]])
    off = np.array([[0.0], [i0], [i0]])
    ub = np.array([[u_bias[0]], [u_bias[1]]])
    # record-major, as the records are kept: a sample is a strided (B, .) slice
    Y = np.empty((B, N, 3))
    UF = np.empty((B, N, 2))
    q = np.empty((B, M.shape[1]))
    q[:, :ns] = state0
    out = np.empty((B, M.shape[0]))
    q3, out3 = q[:, :, None], out[:, :, None]
    for k in range(N):
        yk = g * (z[[0, 2, 3]] - off) + v[:, k].T  # y(k) through the sensors' gains
        Y[:, k] = yk.T
        q[:, ns : ns + 3] = yk.T
        q[:, ns + 3 :] = r[:, k]
        # M @ q of every record: a stacked matmul calls the one-record loop's gemv per
        # record (so it rounds alike, bit for bit); one (B, 10) @ M.T gemm would not
        np.matmul(M, q3, out=out3)
        q[:, :ns] = out[:, :ns]  # x̂(k+1), and e(k) as next sample's e(k-1)
        uf = out[:, ns:].T
        UF[:, k] = uf.T
        u = ub + uf + r[:, k].T  # eq. (16), on the bias voltage
        for _ in range(substeps):  # RK4 under zero-order hold
            rk4.step(z, u, force[:, k])
        if not (np.abs(z[0]).max() < plant.x0 and math.isfinite(z[2:4].sum())):
            bad = int(np.argmax(~((np.abs(z[0]) < plant.x0) & np.isfinite(z[2:4]).all(0))))
            raise ModelError(
                f"record {bad}: the rotor reached the pole face at sample {k + 1} (x = "
                f"{z[0, bad]:.3g} m, gap {plant.x0:.3g} m): the loop does not hold this "
                "bearing with this excitation"
            )
    return Y, UF
