"""Classic OKID + ERA with the Case I transformation (Gosiewski & Paszowski eqs. (19)-(31)).

For comparison with the direct extraction of :mod:`maglevid.identify.deadbeat`:
identify an ARX model of the observer/controller (eqs. (27)-(29)), turn it into
observer/controller Markov parameters (eq. (31)), realize them by ERA
(:mod:`maglevid.identify.era`) in arbitrary coordinates, and transform to
physical coordinates with ``T = Cbar^-1 Ctilde`` (Case I, eqs. (22)-(24)), where
``Cbar`` is the known output matrix of the observer/controller.

With integral action (eqs. (39)-(45)) the observer/controller is

    z(k+1) = Abar z(k) + Bbar v(k) + [0; Etilde] v(k+1),  y_u(k) = P z(k),
    Abar = diag(A + Gd C, I), Bbar = [B, -Gd; 0, 0], P = [[C, 0], [-F, Fe]],

which is not in the form of eq. (18). With ``s(k) = z(k) - [0; Etilde] v(k)`` it
is ``s(k+1) = Abar s(k) + B' v(k)``, ``y_u(k) = P s(k) + b0 v(k)`` with
``B' = Bbar + Abar [0; Etilde]`` and the direct term ``b0 = P [0; Etilde]``
(known: ``[0; -Fe E y(k)]``). So the ARX model carries ``b0 v(k)`` on its left
side, ERA realizes ``(Abar, B', P)`` up to similarity, ``T = P^-1 Ctilde`` (eq. (23)),
and the physical matrices follow from eq. (24) after removing the direct part:
``Bbar = T Btilde - (T Atilde T^-1) [0; Etilde]``, ``B = Bbar[:n, :m]``,
``Gd = -Bbar[:n, m:]``, ``A = T Atilde T^-1 |_(n x n) - Gd C``.

For which ARX orders it is exact on this loop
---------------------------------------------
* ``order = 1``: exact (without noise). The observer/controller state is
  ``P^-1 y_u(k)`` (``P`` invertible), so its ARX model has order one, the
  regression on the distinct signals ``[y, u_f, u](k-1)`` is full rank, and the
  ARX model defines a system of exactly ``n + ne`` states whose Markov
  parameters ERA realizes exactly. The split of the ``y(k-1)`` coefficient
  (trap (a) of :mod:`~maglevid.identify.deadbeat`) changes ``Gd`` only. The
  paper's remark after eq. (36) that "only one Markov parameter exists" is not
  right: eq. (31) gives ``Y_k = a1^(k-1) (b1 + a1 b0)``, nonzero for all ``k``.
* ``order >= 2``: not exact. The lag-2 regressors are exact linear functions
  of the lag-1 ones (the order-1 relation holds on the data), so the
  regression is rank deficient by ``ny + nu`` and the ARX coefficients are
  not unique. Each solution agrees with the data, but the *system*
  ``v -> y_u`` it defines treats the ``y`` inside ``v`` and the ``y`` inside ``y_u``
  as independent signals; its Markov parameters differ from the
  observer/controller's and have more than ``n + ne`` states, so the ERA
  truncation is an approximation. The module returns the minimum-norm
  solution for ``order >= 2`` with a note; see ``docs/gosiewski.md`` for the
  size of the error.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError
from maglevid.identify.arx import lagged, markov_from_arx, solve_linear_regression
from maglevid.identify.deadbeat import (
    _noise_model,
    _signals,
    loop_matrices,
    loop_output_matrix,
)
from maglevid.identify.era import realize_era
from maglevid.identify.options import AMB_OPTIONS, Option, declared
from maglevid.identify.result import IdentificationResult
from maglevid.identify.uncertainty import DCLevels, amb_result, with_dc_levels

__all__ = ["METHODS", "case_one_transformation", "fit_okid_era", "observer_controller_markov"]


def observer_controller_markov(
    theta: np.ndarray,
    *,
    order: int,
    ny: int,
    nu: int,
    b0: np.ndarray,
    n_markov: int,
    PG: np.ndarray | None = None,
) -> np.ndarray:
    """Observer/controller Markov parameters from the ARX coefficients (eq. (31)).

    ``theta`` holds, for lags ``i = 1..order``, the coefficients of
    ``[y(k-i), u_f(k-i), u(k-i)]``. Only the sum of the ``y(k-i)`` coefficients
    of ``a_i`` and ``b_i`` is identified; the lag-1 split is ``b_1[:, nu:] = -PG``,
    ``a_1[:, :ny] = Theta_y + PG`` with ``PG = P [Gd'; 0]`` (``Gd'`` the loop's
    observer gain, so that the realized system is the paper's observer/controller;
    ``PG = 0`` when it is unknown), and ``b_i[:, nu:] = 0`` for ``i >= 2``.
    """
    nyu = ny + nu
    Theta = np.asarray(theta, dtype=float).reshape(nyu, order * (ny + 2 * nu))
    a = np.empty((order, nyu, nyu))
    b = np.zeros((order + 1, nyu, nu + ny))
    b[0] = b0
    w = ny + 2 * nu
    for i in range(order):
        blk = Theta[:, i * w : (i + 1) * w]
        a[i] = blk[:, :nyu]  # coefficients of y(k-i), u_f(k-i)
        b[i + 1][:, :nu] = blk[:, nyu:]  # coefficients of u(k-i)
    if PG is not None:
        a[0][:, :ny] += PG
        b[1][:, nu:] = -PG
    return markov_from_arx(a, b, n_markov)  # eq. (31)


def case_one_transformation(
    At: np.ndarray,
    Bt: np.ndarray,
    Ct: np.ndarray,
    *,
    P: np.ndarray,
    Et: np.ndarray,
    nx: int,
    nu: int,
    C: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Physical ``A, B, Gd`` from an ERA realization of the observer/controller (eqs. (22)-(24)).

    ``T = P^-1 Ctilde`` (eq. (23)); ``Abar = T Atilde T^-1``; ``Bbar = T Btilde -
    Abar [0; Etilde]`` (the direct term of the integrator, see module notes);
    ``B = Bbar[:n, :m]``, ``Gd = -Bbar[:n, m:]``, ``A = Abar[:n, :n] - Gd C`` (eq. (24)).
    """
    T = np.linalg.solve(P, Ct)  # eq. (23)
    Abar = T @ np.linalg.solve(T.T, At.T).T  # T At T^-1, eq. (24)
    Bbar = T @ Bt - Abar @ Et
    B = Bbar[:nx, :nu]
    Gd = -Bbar[:nx, nu:]
    A = Abar[:nx, :nx] - Gd @ C  # eq. (24)
    return A, B, Gd


@declared(
    Option("order", "int", "ARX order p of the observer/controller", low=1),
    Option("n_markov", "int", "Markov parameters computed (default: as the Hankels need)", low=1),
    Option("era_rows", "int", "block rows of the ERA Hankel matrices (default 2)", low=1),
    Option("era_cols", "int", "block columns of the ERA Hankel matrices (default 2)", low=1),
    *(AMB_OPTIONS[n] for n in ("skip", "covariance", "hac_lags", "m", "i0")),
)
def fit_okid_era(
    data: ClosedLoopData,
    *,
    order: int = 1,
    n_markov: int | None = None,
    era_rows: int | None = None,
    era_cols: int | None = None,
    skip: int = 10,
    covariance: str = "white-noise",
    hac_lags: int = 8,
    m: float | None = None,
    i0: float | None = None,
) -> IdentificationResult:
    """OKID/ERA of the observer/controller with the Case I transformation (eqs. (19)-(31)).

    Parameters
    ----------
    data : ClosedLoopData
        As for :func:`maglevid.identify.deadbeat.fit_deadbeat`.

    The options are declared once (listed under *Options*); ``order`` is exact
    only for 1 (see the module notes).

    Returns
    -------
    IdentificationResult
        Physical-coordinate models, v1..v9 and physical parameters (with the
        delta-method covariance through ARX -> Markov -> ERA -> T), the ERA
        singular values in ``singular_values``.
    """
    y, u, u_f = _signals(data)
    mats = loop_matrices(data)
    C, F, Fe, E = mats["C"], mats["F"], mats["Fe"], mats["E"]
    ny, nx = C.shape
    nu = F.shape[0]
    ne = E.shape[0]
    P = loop_output_matrix(C, F, Fe)
    nz = nx + ne
    rows = 2 if era_rows is None else int(era_rows)
    cols = 2 if era_cols is None else int(era_cols)
    n_markov = rows + cols + 1 if n_markov is None else int(n_markov)
    N = y.shape[0]
    start = max(int(skip), order)
    if N - start <= 3 * order * (ny + 2 * nu):
        raise DataError(f"the recording has {N} samples; too few for an ARX of order {order}")
    lhs = np.hstack([y[start:], u_f[start:] + y[start:] @ (Fe @ E).T])  # y_u(k) - b0 v(k)
    blocks = [
        lagged(np.hstack([y, u_f, u]), [i], start, N) for i in range(1, order + 1)
    ]  # eq. (28), each y(k-i) once
    phi = np.hstack(blocks)
    notes = [
        "OKID/ERA Case I: T = Cbar^-1 Ctilde (eq. (23)); exact without noise for ARX order 1 "
        "only (see maglevid.identify.okid)"
    ]
    # Order 1 is the deadbeat regression shifted by one sample: same noise model.
    noise_ma = _noise_model(covariance, data, P, C, mats, notes) if order == 1 else None
    fit = solve_linear_regression(
        lhs, phi, hac_lags=hac_lags, min_norm=order > 1, noise_ma=noise_ma, intercept=True
    )
    b0 = np.zeros((ny + nu, nu + ny))
    b0[ny:, nu:] = -Fe @ E
    Et = np.zeros((nz, nu + ny))
    Et[nx:, nu:] = -E  # [0; Etilde]
    PG = P @ np.vstack([mats.get("G", np.zeros((nx, ny))), np.zeros((ne, ny))])
    # scales of the deviations from the operating point (offset-invariant)
    out_scale = np.std(lhs, axis=0)
    in_scale = np.std(np.hstack([u, y]), axis=0)

    def markov(theta: np.ndarray) -> np.ndarray:
        return observer_controller_markov(
            theta, order=order, ny=ny, nu=nu, b0=b0, n_markov=n_markov, PG=PG
        )

    def era(Y: np.ndarray) -> tuple[Any, np.ndarray]:
        return realize_era(
            Y, order=nz, rows=rows, cols=cols, output_scale=out_scale, input_scale=in_scale
        )

    def to_discrete(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        sys, _ = era(markov(theta))
        A, B, _ = case_one_transformation(sys.A, sys.B, sys.C, P=P, Et=Et, nx=nx, nu=nu, C=C)
        return A, B

    Y = markov(fit.coefficients.ravel())
    _, s = era(Y)
    res = amb_result(
        method="okid-era",
        to_discrete=to_discrete,
        fit=fit,
        Y=lhs,
        lhs_names=[*data.channel_names("y"), *(f"u_f{i + 1}" for i in range(nu))],
        dt=data.dt,
        loop=data.loop,
        n_samples=lhs.shape[0],
        options={
            "order": order,
            "n_markov": n_markov,
            "era_rows": rows,
            "era_cols": cols,
            "skip": int(skip),
            "covariance": covariance if order == 1 else "hac",
            "hac_lags": int(hac_lags),
            "m": m,
            "i0": i0,
        },
        notes=notes,
        extras={"P": P, "markov": Y},
        m=m,
        i0=i0,
        singular_values=s,
    )
    dc = DCLevels(data.dt, y.shape[1], u.shape[1])
    dc.update(y, u)
    return with_dc_levels(res, dc, data.loop)


#: Registered with ``maglevid identify --method``.
METHODS: Mapping[str, Any] = {"okid-era": fit_okid_era}
