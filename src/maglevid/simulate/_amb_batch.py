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
    """RK4 of eq. (1) under a constant input on the ``(4, B)`` state ``z = [x; I1; I2; x']``.

    Same equations and operation order as
    :func:`~maglevid.simulate.amb._rk4_stepper` (one record on Python floats),
    with the coils as rows of ``(2, B)`` arrays. Every operation writes into a
    buffer made once, through views made once: a numpy call on a few dozen
    numbers costs its overhead, not its arithmetic, and so does making a view.
    The step advances ``self.z`` in place.
    """

    def __init__(self, p: AMBParameters, h: float, z: np.ndarray) -> None:
        col = lambda a, b: np.array([[a], [b]], dtype=float)  # noqa: E731
        B = z.shape[1]
        self.x0, self.m, self.h = p.x0, p.m, h
        self.sign = col(1.0, -1.0)  # g_j = x0 - s_j x: x0 - x, x0 + x
        self.q = col(p.K1 / 4.0, p.K2 / 4.0)  # force constants
        self.hf = col(p.K1 / 2.0, p.K2 / 2.0)  # flux constants K_j / 2
        self.hs = col(p.K1 / 2.0, -p.K2 / 2.0)  # with eq. (1)'s sign of the motion EMF
        self.R = col(p.R1, p.R2)
        self.Ls = col(p.Ls1, p.Ls2)
        self.kw = col(p.kw1, p.kw2)
        self.hh, self.h6 = 0.5 * h, h / 6.0
        self.z = z
        self.k = np.empty((4, 4, B))  # the four stages' derivatives, rows as z
        self.g, self.f, self.t, self.a = (np.empty((2, B)) for _ in range(4))
        self.zs, self.acc, self.tmp = (np.empty((4, B)) for _ in range(3))
        split = lambda w: (w, w[0], w[1:3], w[3])  # noqa: E731
        self.zv, self.zsv = split(z), split(self.zs)
        self.kv = [split(self.k[i]) for i in range(4)]
        self.t0, self.t1 = self.t[0], self.t[1]

    def _rhs(self, zv: tuple[np.ndarray, ...], fz: np.ndarray, kv: tuple[np.ndarray, ...]) -> None:
        # eq. (1): m x'' = K1/4 (I1/g1)^2 - K2/4 (I2/g2)^2 + F_z,
        # (Ls_j + K_j/(2 g_j)) I_j' = kw_j u_j - R_j I_j -+ K_j I_j x' / (2 g_j^2)
        mul, div, sub = np.multiply, np.divide, np.subtract
        _, x, cur, dx = zv
        _, kx, ka, kd = kv
        g, f, t = self.g, self.f, self.t
        mul(self.sign, x, out=g)
        sub(self.x0, g, out=g)  # g_j
        div(cur, g, out=f)  # I_j / g_j
        mul(self.q, f, out=t)
        t *= f
        kx[...] = dx
        sub(self.t0, self.t1, out=kd)
        kd += fz
        kd /= self.m
        mul(self.R, cur, out=ka)
        sub(self.a, ka, out=ka)  # kw_j u_j - R_j I_j
        mul(self.hs, f, out=t)
        t *= dx
        t /= g
        ka -= t
        div(self.hf, g, out=t)
        t += self.Ls  # Ls_j + K_j / (2 g_j)
        ka /= t

    def step(self, u: np.ndarray, fz: np.ndarray) -> None:
        """``self.z`` one step on under ``u`` (2, B) [V] and ``fz`` (B,) [N]."""
        kv, zs, acc, tmp, z = self.kv, self.zs, self.acc, self.tmp, self.z
        mul = np.multiply
        mul(self.kw, u, out=self.a)
        self._rhs(self.zv, fz, kv[0])
        for i, c in ((1, self.hh), (2, self.hh), (3, self.h)):
            mul(c, kv[i - 1][0], out=zs)
            zs += z
            self._rhs(self.zsv, fz, kv[i])  # kv[3]'s x' row: the one-record k4x
        mul(2.0, kv[1][0], out=acc)
        np.add(kv[0][0], acc, out=acc)
        mul(2.0, kv[2][0], out=tmp)
        acc += tmp
        acc += kv[3][0]
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
    ns, x0 = state0.shape[1], plant.x0
    z = np.empty((4, B))
    z[0], z[1], z[2], z[3] = start[0], start[1], start[2], 0.0
    rk4 = _BatchRK4(plant, dt / substeps, z)
    x, cur, sensed = z[0], z[1:3], z[0:3]
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
    q_state, q_y, q_r = q[:, :ns], q[:, ns : ns + 3], q[:, ns + 3 :]
    out_state, uf = out[:, :ns], out[:, ns:].T
    yk, u = np.empty((3, B)), np.empty((2, B))
    sub, add, matmul = np.subtract, np.add, np.matmul
    for k in range(N):
        rk = r[:, k]
        sub(sensed, off, out=yk)  # y(k) through the sensors' gains
        yk *= g
        yk += v[:, k].T
        Y[:, k] = yk.T
        q_y[...] = yk.T
        q_r[...] = rk
        # M @ q of every record: a stacked matmul calls the one-record loop's gemv per
        # record (so it rounds alike, bit for bit); one (B, 10) @ M.T gemm would not
        matmul(M, q3, out=out3)
        q_state[...] = out_state  # x̂(k+1), and e(k) as next sample's e(k-1)
        UF[:, k] = uf.T
        add(ub, uf, out=u)
        u += rk.T  # eq. (16), on the bias voltage
        fk = force[:, k]
        for _ in range(substeps):  # RK4 under zero-order hold
            rk4.step(u, fk)
        if not (np.abs(x).max() < x0 and math.isfinite(cur.sum())):
            bad = int(np.argmax(~((np.abs(x) < x0) & np.isfinite(cur).all(0))))
            raise ModelError(
                f"record {bad}: the rotor reached the pole face at sample {k + 1} (x = "
                f"{x[bad]:.3g} m, gap {x0:.3g} m): the loop does not hold this "
                "bearing with this excitation"
            )
    return Y, UF
