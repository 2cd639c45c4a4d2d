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

import numpy as np

from maglevid.exceptions import ModelError
from maglevid.physics.amb import AMBParameters

__all__: list[str] = []


class _BatchRK4:
    """RK4 of eq. (1) under a constant input on ``(4, B)`` states ``[x, x', I1, I2]``.

    Same equations and operation order as
    :func:`~maglevid.simulate.amb._rk4_stepper` (one record on Python floats),
    with the coils as rows 0 and 1 of ``(2, B)`` arrays.
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

    def _rhs(self, z: np.ndarray, a: np.ndarray, fz: np.ndarray, k: np.ndarray) -> None:
        # eq. (1): m x'' = K1/4 (I1/g1)^2 - K2/4 (I2/g2)^2 + F_z,
        # (Ls_j + K_j/(2 g_j)) I_j' = kw_j u_j - R_j I_j -+ K_j I_j x' / (2 g_j^2)
        g = self.x0 - self.sign * z[0]
        f = z[2:4] / g
        t = self.q * f * f
        k[0] = z[1]
        k[1] = (t[0] - t[1] + fz) / self.m
        k[2:4] = (a - self.R * z[2:4] - self.hs * f * z[1] / g) / (self.Ls + self.hf / g)

    def step(self, z: np.ndarray, u: np.ndarray, fz: np.ndarray) -> np.ndarray:
        """``z`` (4, B) after one step under ``u`` (2, B) [V] and ``fz`` (B,) [N]."""
        k, hh, h = self.k, self.hh, self.h
        a = self.kw * u
        self._rhs(z, a, fz, k[0])
        self._rhs(z + hh * k[0], a, fz, k[1])
        self._rhs(z + hh * k[1], a, fz, k[2])
        zs = z + h * k[2]
        self._rhs(zs, a, fz, k[3])  # k[3, 0] is the stage-4 velocity, the one-record k4x
        return z + self.h6 * (k[0] + 2.0 * k[1] + 2.0 * k[2] + k[3])


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
    # time-major copies: one contiguous (B, .) slice per sample
    rt, vt, ft = (np.ascontiguousarray(np.moveaxis(a, 1, 0)) for a in (r, v, force))
    Y = np.empty((N, 3, B))
    UF = np.empty((N, 2, B))
    q = np.empty((B, M.shape[1]))
    q[:, :ns] = state0
    out = np.empty((B, M.shape[0]))
    q3, out3 = q[:, :, None], out[:, :, None]
    for k in range(N):
        yk = g * (z[[0, 2, 3]] - off) + vt[k].T  # y(k) through the sensors' gains
        Y[k] = yk
        q[:, ns : ns + 3] = yk.T
        q[:, ns + 3 :] = rt[k]
        # M @ q of every record: a stacked matmul calls the one-record loop's gemv per
        # record (so it rounds alike, bit for bit); one (B, 10) @ M.T gemm would not
        np.matmul(M, q3, out=out3)
        q[:, :ns] = out[:, :ns]  # x̂(k+1), and e(k) as next sample's e(k-1)
        uf = out[:, ns:].T
        UF[k] = uf
        u = ub + uf + rt[k].T  # eq. (16), on the bias voltage
        for _ in range(substeps):  # RK4 under zero-order hold
            z = rk4.step(z, u, ft[k])
        if not (np.abs(z[0]).max() < plant.x0 and np.isfinite(z[2:4]).all()):
            bad = int(np.argmax(~((np.abs(z[0]) < plant.x0) & np.isfinite(z[2:4]).all(0))))
            raise ModelError(
                f"record {bad}: the rotor reached the pole face at sample {k + 1} (x = "
                f"{z[0, bad]:.3g} m, gap {plant.x0:.3g} m): the loop does not hold this "
                "bearing with this excitation"
            )
    return np.moveaxis(Y, 2, 0), np.moveaxis(UF, 2, 0)
