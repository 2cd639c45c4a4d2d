"""Direct closed-loop identification of an unstable plant by output inter-sampling.

Implements Sun, Miyake, Ohmori & Sano (T.SICE 36(4), 2000), Section 4, for a
single-input single-output plant whose output is sampled ``p >= 2`` times per
control period (:class:`~maglevid.data.ClosedLoopData` with ``p > 1``).

Why it works (Section 4.1)
--------------------------
Only ``y_0(m) = y(mT)`` reaches the controller. The other inter-samples
``y_j(m) = y(mT + j Delta)``, ``j = 1..p-1``, obey ``y_j = B_j/A u + w_j``
(Theorem 2, eq. (7)) with noise ``w_j`` that the loop never sees, so ``u`` is
independent of every ``w_j``: the single-input ``(p-1)``-output subsystem is an
*open-loop* problem with the common denominator ``A`` of the plant.

The algorithm
-------------
Step 1 (paper)
    ``A(z^-1)`` from the SIMO subsystem ``(u; y_1..y_{p-1})`` by MOESP (default)
    or N4SID of :mod:`maglevid.identify.subspace`, with feedthrough (``y_j``,
    ``j >= 1``, already responds to ``u(m)``).
Step 1b (ours, ``refine=True``, default)
    The subspace estimate is inefficient here: the plant's poles sit near 1 at
    the control rate, the excitation is the loop's filtered noise only and the
    signal-to-noise ratio of each inter-sample is about 1 (docs/sun.md measures
    2-5 times the Cramér-Rao bound, and a bias at long horizons). We refine it
    by output error on the same open-loop subsystem: minimise
    ``sum_j ||y_j - B_j/A u - h_j||^2`` over ``A`` with ``B_j`` and the free
    responses ``h_j`` solved by least squares (variable projection). ``1/A`` is
    applied *bilaterally* - the stable factor causally, the unstable factor
    anti-causally - the non-causal filtering the paper uses in Step 2-c
    (Forssell & Hjalmarsson, its ref. 15): the predictor stays bounded although
    ``B_j/A`` is unstable. The initial value is the subspace estimate on the raw
    data and on low-pass-filtered copies (the same filter on ``u`` and ``y_j``
    leaves ``B_j/A`` unchanged); real roots near the unit circle are also tried
    reflected, because the bilateral cost cannot move a root across it. The
    lowest cost wins. This is maximum likelihood for white Gaussian ``w_j``.
Step 2-a
    ``A = A_s A_u`` (roots inside / outside the unit circle), eqs. (8)-(9).
Step 2-b..2-d (``numerator="iv"``)
    ``u_f = u/A_s``, ``y_0f = A_u y_0`` (eqs. (11)-(12)), the instrument from
    the non-causal filter ``z^-n_us / A_u`` (time reversal, order-reversed
    ``A_u``, reversal), and the estimate (13) solved by ``lstsq`` (no inverse).
    ``numerator="iv-delayed"``: the Remark's instrument ``u_f(m - n1)``.
    Covariance: Section 4.4 with ``sigma_w^2`` from the residuals, plus the
    propagated uncertainty of ``A`` (independent: ``A`` comes from ``w_j``,
    ``j >= 1``, the IV noise from ``w_0``).
Section 4.3 (``numerator="physical"``, default)
    For a plant whose continuous numerator is a constant ``eta``:
    ``B_0 = eta lambda(A)`` with ``lambda`` the ZOH numerator of
    ``1/prod(s - s_i)``, ``s_i = ln(z_i)/T``, and ``eta`` from eq. (15),
    ``(p-1) eta sum(lambda) = sum_j B_j(1)``. The ``B_j(1)`` are taken from the
    output-error least squares given ``A`` (``gain_from="ls"``, default) or from
    the subspace model (``gain_from="subspace"``): the latter's ``B_j`` are
    badly biased in closed loop (nearly collinear inter-samples; docs/sun.md
    measures it), so ``"ls"`` is the default and both are in ``extras``.

Printed equations corrected here: (5b)'s sum starts at ``i = 0`` (see
:mod:`maglevid.identify.multirate`).
"""

from __future__ import annotations

import itertools
import logging
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg as sla
from scipy import optimize, signal

from maglevid.data import ClosedLoopData
from maglevid.exceptions import (
    DataError,
    IdentificationError,
    IllConditionedWarning,
    ModelError,
)
from maglevid.identify.closedloop import (
    continuous_or_note,
    covariance_from_jacobian,
    simo_polynomials_to_state_space,
)
from maglevid.identify.options import Option
from maglevid.identify.result import IdentificationResult, propagate_covariance
from maglevid.lti import StateSpace, discretize
from maglevid.physics.suspension import (
    GRAVITY,
    physical_from_t_model,
    polynomials_from_state_space,
)

__all__ = [
    "METHODS",
    "bilateral_filter",
    "data_matrix",
    "data_matrix_singular_values",
    "fit_conventional_direct",
    "fit_intersample",
    "split_stable_unstable",
    "zoh_unit_numerator",
]

log = logging.getLogger(__name__)

NUMERATORS = ("physical", "iv", "iv-delayed")
GAIN_SOURCES = ("ls", "subspace")
SUBSPACE = ("moesp", "n4sid")
#: Low-pass cutoffs (fraction of the control-rate Nyquist frequency) of the extra
#: subspace initialisations of Step 1b (PI-MOESP: the filtered noise is coloured);
#: None is the raw data with the user's settings. Measured in docs/sun.md: with
#: 9 s at p = 2 the raw-data subspace start lands in a wrong basin in half the
#: records, the 0.03-0.05 ones almost never.
AUTO_PREFILTERS: tuple[float | None, ...] = (None, 0.2, 0.1, 0.05, 0.03)
#: Real roots with 1/REFLECT_BAND < |z| < REFLECT_BAND are also tried reflected.
REFLECT_BAND = 1.25
#: Residual evaluations of the screening run of each Step 1b start.
SCREEN_NFEV = 24
#: Starts screened per number of roots outside the unit circle.
PER_GROUP = 3
#: Fewest control periods per estimated parameter.
MIN_PERIODS_PER_PARAMETER = 20


# --------------------------------------------------------------- polynomials
def split_stable_unstable(a: Any) -> tuple[np.ndarray, np.ndarray]:
    """``A = A_s A_u`` (eq. (8)): monic factors with roots inside / outside the unit circle.

    Polynomials in ``z^-1`` (``a[0] = 1``). A root exactly on the unit circle is
    counted as stable (causal filtering of a marginal mode).

    Examples
    --------
    >>> As, Au = split_stable_unstable(np.convolve([1, -0.5], [1, -2.0]))
    >>> As.tolist(), Au.tolist()
    ([1.0, -0.5], [1.0, -2.0])
    """
    a = np.asarray(a, dtype=float).ravel()
    if a.size == 0 or a[0] == 0:
        raise DataError(f"`a` must start with a nonzero coefficient; got {a.tolist()}")
    r = np.roots(a / a[0])
    out = np.abs(r) > 1.0
    As = np.atleast_1d(np.real(np.poly(r[~out]))) if (~out).any() else np.ones(1)
    Au = np.atleast_1d(np.real(np.poly(r[out]))) if out.any() else np.ones(1)
    return As, Au


def bilateral_filter(a: Any, x: Any) -> np.ndarray:
    """``x / A(z^-1)`` with the stable factor applied causally, the unstable one anti-causally.

    For ``A_u = 1 + alpha_1 z^-1 + ... + alpha_n z^-n`` the bounded solution of
    ``A_u v = x`` runs backwards in time: with ``xbar(k) = x(N-1-k)``,
    ``alpha_n vbar(k) + ... + vbar(k-n) = xbar(k-n)`` (the order-reversed
    polynomial of Step 2-c, whose roots ``1/z_i`` are inside the unit circle).
    The record's edges start both filters from rest; their transients are
    homogeneous solutions of ``A`` (see :func:`_homogeneous`).

    Parameters
    ----------
    a : array_like
        ``[1, a1, ..., an]``.
    x : array_like, shape (N,) or (N, k)
        Signal(s), time first.
    """
    return _bilateral(*split_stable_unstable(a), np.asarray(x, dtype=float))


def _bilateral(As: np.ndarray, Au: np.ndarray, x: np.ndarray) -> np.ndarray:
    v = signal.lfilter([1.0], As, x, axis=0)
    n = Au.size - 1
    if n:
        num = np.zeros(n + 1)
        num[n] = 1.0
        v = signal.lfilter(num, Au[::-1], v[::-1], axis=0)[::-1]
    return v


def _noncausal_instrument(Au: np.ndarray, uf: np.ndarray) -> np.ndarray:
    # Step 2-c: v = Omega(z) u_f with Omega(z) = z^-n_us / A_u(z^-1) expanded in
    # powers of z (eq. (17)): reverse time, filter by 1/(alpha_n + ... + z^-n_us),
    # reverse again. (No z^-n numerator: that would align v with u_f(m) and break
    # eq. (20).)
    if Au.size == 1:
        return uf.copy()
    return signal.lfilter([1.0], Au[::-1], uf[::-1])[::-1]


def zoh_unit_numerator(a: Any, dt: float) -> np.ndarray:
    """``lambda_1..lambda_n``: ZOH numerator of ``1/prod(s - s_i)``, ``s_i = ln(z_i)/dt``.

    Section 4.3 (1)-(2): the discrete model of ``eta/prod(s - s_i)`` sampled with
    a zero-order hold is ``eta (lambda_1 z^-1 + ... + lambda_n z^-n)/A(z^-1)``.

    Raises
    ------
    ModelError
        A pole at zero or on the negative real axis (no real logarithm).
    """
    a = np.asarray(a, dtype=float).ravel()
    z = np.roots(a)
    bad = z[(np.abs(z.imag) <= 1e-12 * np.maximum(np.abs(z), 1e-300)) & (z.real <= 0)]
    if bad.size:
        raise ModelError(
            f"pole(s) {', '.join(f'{v.real:.4g}' for v in bad)} at zero or on the negative real "
            "axis: no continuous-time pole samples to them, so eq. (15) does not apply"
        )
    s = np.log(z.astype(complex)) / dt
    den = np.real(np.poly(s))
    n = den.size - 1
    A = np.zeros((n, n))
    A[0] = -den[1:]
    A[1:, :-1] = np.eye(n - 1)
    B = np.zeros((n, 1))
    B[0, 0] = 1.0
    C = np.zeros((1, n))
    C[0, -1] = 1.0
    _, lam = polynomials_from_state_space(discretize(StateSpace(A, B, C), dt))
    return lam[1:]


# --------------------------------------------------------- output error (1b)
def _homogeneous(As: np.ndarray, Au: np.ndarray, N: int) -> np.ndarray:
    """Basis (N, n) of the free responses of ``A(q) y = 0`` on the record, bounded.

    Stable factor: causal responses to unit initial states; unstable factor:
    anti-causal responses to unit final states.
    """
    cols = []
    zeros = np.zeros(N)
    for k in range(As.size - 1):
        zi = np.zeros(As.size - 1)
        zi[k] = 1.0
        cols.append(signal.lfilter([1.0], As, zeros, zi=zi)[0])
    nu = Au.size - 1
    for k in range(nu):
        zi = np.zeros(nu)
        zi[k] = 1.0
        rev = Au[::-1] / Au[-1]
        cols.append(signal.lfilter([1.0], rev, zeros, zi=zi)[0][::-1])
    return np.column_stack(cols) if cols else np.zeros((N, 0))


def _design(a: np.ndarray, u: np.ndarray, nb: int) -> tuple[np.ndarray, np.ndarray]:
    """``[z^-l u / A]_{l=0..nb-1}`` (bilateral) and the free-response basis."""
    N = u.size
    As, Au = split_stable_unstable(a)
    uf = _bilateral(As, Au, u)
    Phi = np.zeros((N, nb))
    for l in range(nb):
        Phi[l:, l] = uf[: N - l]
    return Phi, _homogeneous(As, Au, N)


class _OE:
    """Output-error fit of ``y_j = B_j/A u + free response + w_j`` (scaled data)."""

    def __init__(self, u: np.ndarray, Y: np.ndarray, n: int) -> None:
        self.su = float(np.sqrt(np.mean(u**2))) or 1.0
        self.sy = float(np.sqrt(np.mean(Y**2))) or 1.0
        self.u = u / self.su
        self.Y = Y / self.sy
        self.n = n
        self.nb = n + 1  # B_j has z^0..z^-n (feedthrough for j >= 1)

    def inner(self, a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        Phi, H = _design(a, self.u, self.nb)
        X = np.hstack([Phi, H])
        theta, *_ = np.linalg.lstsq(X, self.Y, rcond=None)
        R = self.Y - X @ theta
        return theta, R, X

    def residuals(self, a_tail: np.ndarray) -> np.ndarray:
        # The variable-projection residual (I - X X^+) Y through a thin QR of X: the
        # search only needs the projection, and QR is several times cheaper than
        # the SVD inside lstsq (the final linear parameters use lstsq, see inner()).
        Phi, H = _design(np.r_[1.0, a_tail], self.u, self.nb)
        Q, _ = sla.qr(np.hstack([Phi, H]), mode="economic", check_finite=False)
        return (self.Y - Q @ (Q.T @ self.Y)).ravel()

    def fit(self, a0: np.ndarray, max_nfev: int = 400) -> tuple[np.ndarray, float, int]:
        sol = optimize.least_squares(
            self.residuals, a0[1:], method="lm", xtol=1e-12, ftol=1e-12, max_nfev=max_nfev
        )
        return np.r_[1.0, sol.x], float(2 * sol.cost), int(sol.nfev)

    def cost(self, a: np.ndarray) -> float:
        return float(np.sum(self.residuals(np.asarray(a, dtype=float)[1:]) ** 2))

    def jacobian(self, a: np.ndarray, theta: np.ndarray) -> np.ndarray:
        """Jacobian of all residuals w.r.t. ``[a_1..a_n, B_1, h_1, B_2, h_2, ...]``."""
        q = self.Y.shape[1]
        n, nb = self.n, self.nb
        N = self.u.size
        nh = theta.shape[0] - nb
        Ja = np.empty((N * q, n))
        for k in range(n):
            h = 1e-6 * max(abs(a[k + 1]), 1.0)
            ap, am = a.copy(), a.copy()
            ap[k + 1] += h
            am[k + 1] -= h
            Pp, Hp = _design(ap, self.u, nb)
            Pm, Hm = _design(am, self.u, nb)
            # d(prediction)/da_k at fixed linear parameters, residual = y - prediction
            d = (np.hstack([Pp, Hp]) - np.hstack([Pm, Hm])) @ theta / (2 * h)
            Ja[:, k] = -d.ravel()
        Phi, H = _design(a, self.u, nb)
        X = np.hstack([Phi, H])
        Jl = np.zeros((N * q, q * (nb + nh)))
        for j in range(q):
            # residual index m*q + j (row-major ravel of R (N, q))
            Jl[j::q, j * (nb + nh) : (j + 1) * (nb + nh)] = -X
        return np.hstack([Ja, Jl])


def _reflections(a: np.ndarray) -> list[np.ndarray]:
    """``a`` and its variants with roots near |z| = 1 reflected to ``1/conj(z)``.

    Real roots are reflected one by one, a complex pair together; a complex pair
    close to the real axis (angle below 0.1 rad) is also tried as a double real
    root at its modulus and at the reflected modulus. The bilateral cost cannot
    move a root across the unit circle, so the starts must cover both sides.
    """
    r = np.roots(a)
    groups: list[list[np.ndarray]] = []
    used = np.zeros(r.size, bool)
    for i in range(r.size):
        if used[i] or not (1 / REFLECT_BAND < abs(r[i]) < REFLECT_BAND):
            continue
        if abs(r[i].imag) <= 1e-9 * abs(r[i]):
            used[i] = True
            groups.append([np.array([i]), np.array([1.0 / r[i].real])])
            continue
        j = next(
            (
                k
                for k in range(r.size)
                if k != i and not used[k] and np.isclose(r[k], np.conj(r[i]))
            ),
            None,
        )
        if j is None:  # pragma: no cover - np.roots of a real polynomial pairs its roots
            continue
        used[i] = used[j] = True
        m = abs(r[i])
        opts = [np.array([1 / np.conj(r[i]), 1 / r[i]])]
        if abs(np.angle(r[i])) < 0.1:
            opts += [np.array([m, m]), np.array([1 / m, 1 / m])]
        groups.append([np.array([i, j]), *opts])
    out = []
    for choice in itertools.product(*[range(len(g)) for g in groups]):
        rr = r.astype(complex).copy()
        for g, c in zip(groups, choice):
            if c:
                rr[g[0]] = g[c]
        out.append(np.real(np.poly(rr)))
    return out or [np.asarray(a, dtype=float)]


# ----------------------------------------------------------------- helpers
def _check_int(v: Any, name: str, lo: int) -> int:
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < lo:
        raise DataError(f"`{name}` must be an integer >= {lo}; got {v!r}")
    return int(v)


def _signals(data: ClosedLoopData, output: int) -> tuple[np.ndarray, np.ndarray]:
    if not isinstance(data, ClosedLoopData):
        raise DataError(f"`data` must be a ClosedLoopData; got {type(data).__name__}")
    if data.u is None:
        raise DataError("the recording has no plant input `u` (use data.with_plant_input())")
    if data.nu != 1:
        raise DataError(f"the method is single-input; `u` has {data.nu} channels")
    output = _check_int(output, "output", 0)
    if output >= data.ny:
        raise DataError(f"`output` {output} outside the recording's {data.ny} output channel(s)")
    u = np.asarray(data.u[:, 0], dtype=float)
    Y = np.asarray(data.y[:, output], dtype=float).reshape(data.n_samples, data.p)
    return u, Y


def _subspace(
    name: str,
    Y: np.ndarray,
    u: np.ndarray,
    *,
    order: int | None,
    horizon: int | None,
    weighting: str | None,
    dt: float,
    feedthrough: bool,
) -> IdentificationResult:
    from maglevid.identify import subspace as sub

    fit = {"moesp": sub.fit_moesp, "n4sid": sub.fit_n4sid}[name]
    kw: dict[str, Any] = {"order": order, "horizon": horizon, "dt": dt, "feedthrough": feedthrough}
    if weighting is not None:
        kw["weighting"] = weighting
    return fit(Y, u, **kw)


def _lowpass(cut: float, x: np.ndarray) -> np.ndarray:
    b, a = signal.butter(4, cut)
    return signal.lfilter(b, a, x, axis=0)


def _known_physics(
    data: ClosedLoopData, mass: float | None, resistance: float | None, gravity: float | None
) -> tuple[float | None, float | None, float]:
    phys = data.loop.get("physical", {}) if hasattr(data.loop, "get") else {}
    if mass is None and "M" in phys:
        mass = float(phys["M"])
    if resistance is None and "R" in phys:
        resistance = float(phys["R"])
    if gravity is None:
        gravity = float(phys["g"]) if "g" in phys else GRAVITY
    for name, v in (("mass", mass), ("resistance", resistance), ("gravity", gravity)):
        if v is not None and not (np.isfinite(v) and v > 0):
            raise DataError(f"`{name}` must be a positive number; got {v!r}")
    return mass, resistance, float(gravity)


# ------------------------------------------------------------ step 2 (IV)
def _iv_numerator(
    a: np.ndarray, u: np.ndarray, y0: np.ndarray, n: int, kind: str
) -> dict[str, Any]:
    """Steps 2-b..2-d: eq. (13) and the covariance of Section 4.4 (given ``A``)."""
    As, Au = split_stable_unstable(a)
    nus = Au.size - 1
    N = u.size
    uf = signal.lfilter([1.0], As, u)  # eq. (11)
    y0f = signal.lfilter(Au, [1.0], y0)  # eq. (12)
    if kind == "iv":
        v = _noncausal_instrument(Au, uf)
        shift = 0
    else:  # the Remark: v(m) = u_f(m - n1), n1 = max(0, 1 + n_us - tau_b), tau_b = 1
        shift = max(0, nus)
        v = np.r_[np.zeros(shift), uf[: N - shift]]
    # Rows: skip the start-up of 1/A_s (slowest stable root to 1e-3) and, for the
    # non-causal instrument, the end where the backward filter starts from rest
    # (fastest-decaying unstable root to 1e-6); both would correlate v with w_0.
    rs = np.abs(np.roots(As)) if As.size > 1 else np.zeros(0)
    ru = np.abs(np.roots(Au)) if nus else np.zeros(0)
    head = int(np.ceil(np.log(1e-3) / np.log(rs.max()))) if rs.size and rs.max() > 0 else 0
    tail = int(np.ceil(np.log(1e-6) / np.log(1 / ru.min()))) if ru.size and kind == "iv" else 0
    m0 = max(n + nus + shift, head, n)
    m1 = N - tail
    if m1 - m0 < MIN_PERIODS_PER_PARAMETER * n:
        raise IdentificationError(
            f"only {max(m1 - m0, 0)} usable periods for the IV numerator; need "
            f"{MIN_PERIODS_PER_PARAMETER * n}"
        )
    rows = np.arange(m0, m1)
    Phi = np.column_stack([uf[rows - k] for k in range(1, n + 1)])  # eq. (14)
    V = np.column_stack([v[rows - k] for k in range(1, n + 1)])
    VtPhi = V.T @ Phi
    theta = np.linalg.lstsq(VtPhi, V.T @ y0f[rows], rcond=None)[0]  # eq. (13)
    e = y0f[rows] - Phi @ theta
    alpha = Au
    s2 = float(np.mean(e**2) / np.sum(alpha**2))  # var(A_u w0) = sigma^2 sum alpha_i^2
    # Section 4.4: S = sigma^2 sum_k vt(k) vt(k)^T, vt(k) = sum_i alpha_i v(k+i) over
    # the instrument vectors; cov = (V'Phi)^-1 S (Phi'V)^-1 (solves, no inverse).
    Vfull = np.column_stack([v[np.clip(np.arange(N) - k, 0, None)] for k in range(1, n + 1)])
    Vt = np.zeros_like(V)
    for i, ai in enumerate(alpha):
        idx = np.clip(rows + i, 0, N - 1)
        Vt += ai * Vfull[idx]
    X = np.linalg.solve(VtPhi, Vt.T)
    cov = s2 * (X @ X.T)
    return {
        "b": theta,
        "cov": cov,
        "sigma_w": float(np.sqrt(s2)),
        "rows": (int(m0), int(m1)),
        "instrument_singular_values": np.linalg.svd(VtPhi / rows.size, compute_uv=False),
    }


# --------------------------------------------------------------- the method
def fit_intersample(
    data: ClosedLoopData,
    *,
    order: int | None = 3,
    subspace: str = "moesp",
    horizon: int | None = None,
    weighting: str | None = None,
    refine: bool = True,
    prefilters: tuple[float | None, ...] | None = AUTO_PREFILTERS,
    numerator: str = "physical",
    gain_from: str = "ls",
    output: int = 0,
    mass: float | None = None,
    resistance: float | None = None,
    gravity: float | None = None,
) -> IdentificationResult:
    """Identify an unstable plant in closed loop from output inter-samples (Sun et al.).

    Parameters
    ----------
    data : ClosedLoopData
        Multi-rate recording, ``p >= 2``: ``y`` (N p, ny), ``u`` (N, 1) held
        over each control period ``dt``; ``y[m p]`` is the sample the controller
        used. Works on any such recording (no knowledge of the controller).
    order : int or None
        Plant order ``n`` (3 for the suspension, eq. (27)); None: chosen by the
        subspace step from its singular values.
    subspace : {"moesp", "n4sid"}
        Step 1 algorithm (:func:`~maglevid.identify.subspace.fit_moesp` /
        :func:`~maglevid.identify.subspace.fit_n4sid`).
    horizon : int, optional
        Subspace horizon (block rows); automatic when omitted.
    weighting : str, optional
        Subspace weighting (the routine's default when omitted).
    refine : bool
        Step 1b: output-error refinement of ``A`` (default True). False gives the
        paper's pure subspace denominator, and no covariance.
    prefilters : tuple of float or None
        Low-pass cutoffs (fraction of the Nyquist frequency ``pi/dt``) of the
        subspace initialisations tried by Step 1b; ``None`` in it is the raw data.
    numerator : {"physical", "iv", "iv-delayed"}
        Section 4.3, eq. (15) (default; the plant's continuous numerator must be
        a constant); Step 2 with the non-causal instrument; Step 2 with the
        Remark's delayed instrument.
    gain_from : {"ls", "subspace"}
        Where eq. (15) takes ``B_j(1)``: least squares given ``A`` (default) or
        the subspace model.
    output : int
        Output channel (position) when ``y`` has several.
    mass, resistance, gravity : float, optional
        Ball mass [kg], coil-circuit resistance [ohm] and gravity [m/s^2] for the
        physical parameters; default ``data.loop["physical"]["M"]``, ``["R"]``,
        ``["g"]`` (gravity else 9.80665). Without the resistance, ``R`` is
        estimated too, poorly (see :func:`~maglevid.physics.suspension.physical_from_continuous`).

    Returns
    -------
    IdentificationResult
        ``model``: the T-model ``B_0/A`` in controllable canonical form;
        ``parameters``: ``a1..an``, ``b1..bn``, ``pole_z``/``pole_rad_s`` (largest
        real pole), and with ``n = 3`` and a mass the physical parameters of
        eq. (27) (``alpha, eta, L, R``; through the force balance ``gap, I, Q,
        L_inf``; ``Y_offset`` when ``loop["operating_point"]["Y"]`` is known);
        ``covariance``: joint, delta method (None when ``refine=False``);
        ``singular_values``: Step 1's; ``residuals``: the output errors of the
        inter-samples ``j >= 1``; ``extras``: the SIMO model, every step's
        estimate and both eq. (15) variants.

    Raises
    ------
    DataError
        ``p < 2`` (use :func:`fit_conventional_direct`), no input, several
        inputs, bad options, too short a record.
    IdentificationError
        The subspace step fails, or eq. (15) meets a pole on the negative real
        axis.

    References
    ----------
    L. Sun, Y. Miyake, H. Ohmori, A. Sano, "New direct closed-loop identification
    method for unstable systems and its application to magnetic suspension
    system", Trans. SICE 36(4):348-355, 2000.

    Examples
    --------
    >>> from maglevid.simulate.suspension import simulate_suspension
    >>> rec = simulate_suspension(p=3, duration=6.0, rng=0)
    >>> res = fit_intersample(rec)
    >>> res.parameters["pole_z"] > 1
    True
    """
    order, prefilters = _check_options(numerator, gain_from, subspace, order, prefilters)
    u, Y = _signals(data, output)
    mass, resistance, g = _known_physics(data, mass, resistance, gravity)
    p, N, dt = data.p, data.n_samples, data.dt
    _check_record(p, N, order)
    notes: list[str] = []
    Yi = Y[:, 1:]  # the open-loop-like subsystem j = 1..p-1

    # Steps 1 and 1b: A from the SIMO subsystem (u; y_1..y_{p-1}), Theorem 2, eq. (7)
    step1 = _Step1(subspace, horizon, weighting, dt)
    den = _denominator(step1, u, Yi, order, weighting, refine, prefilters, notes)
    n, a_hat, oe = den.sub.model.nx, den.a_hat, den.oe
    inter = _intersample_fit(oe, a_hat, p, refine)

    # Step 2 / Section 4.3: the numerator B_0 of y_0
    y0 = Y[:, 0]
    variants = _numerator_variants(a_hat, inter.B_ls, den.B_sub, u, y0, n, dt, numerator, notes)
    key = {"ls": "physical-ls", "subspace": "physical-subspace"}[gain_from]
    b_hat = variants[key if numerator == "physical" else numerator]["b"]
    theta = np.r_[a_hat[1:], b_hat]
    cov_theta = _theta_covariance(
        inter, a_hat, u, y0, n, p, dt, numerator, gain_from, variants, notes
    )

    # Derived parameters (largest real pole; eq. (27)'s physical parameters)
    names, all_params = _parameter_map(data, theta, n, dt, mass, g, resistance, notes)
    parameters, cov = _parameters(names, all_params, theta, cov_theta, notes)

    # The T-model B_0/A (the SIMO model of every inter-sample is in extras)
    a_full, b_full = np.r_[1.0, theta[:n]], np.r_[0.0, theta[n:]]
    model = simo_polynomials_to_state_space(a_full, [b_full], dt, output_names=("y",))
    continuous = continuous_or_note(model, notes)

    options = dict(
        order=order, subspace=subspace, horizon=horizon, weighting=weighting, refine=refine,
        prefilters=list(prefilters), numerator=numerator, gain_from=gain_from, output=output,
        mass=mass, resistance=resistance, gravity=g, p=p,
    )  # fmt: skip
    extras = _extras(a_full, b_full, inter, dt, p, den.step1_info, den.candidates, variants)
    return IdentificationResult(
        method="intersample",
        model=model,
        parameters=parameters,
        covariance=cov,
        n_samples=N,
        options=options,
        residuals=inter.R_oe * oe.sy,
        fit=_fit_metrics(inter, oe, Yi, numerator, variants),
        singular_values=den.sub.singular_values,
        notes=tuple(notes),
        continuous_model=continuous,
        extras=extras,
    )


# ------------------------------------------------------ the method's steps
def _check_options(
    numerator: str,
    gain_from: str,
    subspace: str,
    order: int | None,
    prefilters: tuple[float | None, ...] | None,
) -> tuple[int | None, tuple[float | None, ...]]:
    if numerator not in NUMERATORS:
        raise DataError(f"`numerator` must be one of {NUMERATORS}; got {numerator!r}")
    if gain_from not in GAIN_SOURCES:
        raise DataError(f"`gain_from` must be one of {GAIN_SOURCES}; got {gain_from!r}")
    if subspace not in SUBSPACE:
        raise DataError(f"`subspace` must be one of {SUBSPACE}; got {subspace!r}")
    if order is not None:
        order = _check_int(order, "order", 1)
    if prefilters is None:
        prefilters = (None,)
    for c in prefilters:
        if c is not None and not (isinstance(c, (float, int)) and 0 < c < 1):
            raise DataError(f"`prefilters` entries must be None or in (0, 1); got {c!r}")
    return order, prefilters


def _check_record(p: int, N: int, order: int | None) -> None:
    """``p >= 2`` and enough control periods for the parameters of Steps 1-2."""
    if p < 2:
        raise DataError(
            "the recording has p = 1 (no inter-samples): the direct method then identifies "
            "the controller's inverse; use fit_conventional_direct to see it, or record the "
            "output p >= 2 times per control period"
        )
    n_guess = order if order is not None else 3
    if N < MIN_PERIODS_PER_PARAMETER * (n_guess + (p - 1) * (2 * n_guess + 1)):
        raise DataError(
            f"the record has {N} control periods; at least "
            f"{MIN_PERIODS_PER_PARAMETER * (n_guess + (p - 1) * (2 * n_guess + 1))} are needed "
            f"for order {n_guess} and p = {p}"
        )


@dataclass(frozen=True)
class _Step1:
    """Step 1: the subspace fit of the SIMO subsystem, with feedthrough (``y_j``, ``j >= 1``)."""

    subspace: str
    horizon: int | None
    weighting: str | None
    dt: float

    def __call__(
        self, x_u: np.ndarray, x_y: np.ndarray, n: int | None, w: str | None
    ) -> IdentificationResult:
        try:
            return _subspace(
                self.subspace,
                x_y,
                x_u,
                order=n,
                horizon=self.horizon,
                weighting=w,
                dt=self.dt,
                feedthrough=True,
            )
        except (IdentificationError, ModelError) as exc:
            raise IdentificationError(f"step 1 ({self.subspace}) failed: {exc}") from exc


def _step1_summary(sub: IdentificationResult) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
    """``A`` and the ``B_j`` of the subspace model, and the step's record for ``extras``."""
    a_sub = np.real(np.poly(sub.model.A))
    _, B_sub = polynomials_from_state_space(sub.model)
    B_sub = np.atleast_2d(B_sub)
    info: dict[str, Any] = {
        "a": a_sub[1:],
        "B": B_sub,
        "poles": np.roots(a_sub),
        "singular_values": sub.singular_values,
        "horizon": sub.options.get("horizon"),
        "notes": list(sub.notes),
    }
    return a_sub, B_sub, info


@dataclass(frozen=True)
class _Denominator:
    """Steps 1 and 1b: the subspace fit and the (refined) denominator ``A``."""

    sub: IdentificationResult  # Step 1's subspace fit
    B_sub: np.ndarray  # its B_j, (p-1, n+1)
    step1_info: dict[str, Any]
    oe: _OE  # the output-error problem of Step 1b (also used given A)
    candidates: list[dict[str, Any]]  # Step 1b's starts and where they ended
    a_hat: np.ndarray  # [1, a_1..a_n]


def _denominator(
    step1: _Step1,
    u: np.ndarray,
    Yi: np.ndarray,
    order: int | None,
    weighting: str | None,
    refine: bool,
    prefilters: tuple[float | None, ...],
    notes: list[str],
) -> _Denominator:
    """Step 1 (subspace) and Step 1b (output-error refinement, variable projection)."""
    sub = step1(u, Yi, order, weighting)
    n = sub.model.nx
    a_sub, B_sub, step1_info = _step1_summary(sub)
    oe = _OE(u, Yi, n)
    candidates: list[dict[str, Any]] = []
    if refine:
        inits = _subspace_starts(step1, u, Yi, n, a_sub, prefilters, notes)
        candidates, a_hat = _refine_denominator(oe, inits)
    else:
        a_hat = a_sub
        notes.append("refine=False: the denominator is the subspace estimate; no covariance")
    return _Denominator(sub, B_sub, step1_info, oe, candidates, a_hat)


def _subspace_starts(
    step1: _Step1,
    u: np.ndarray,
    Yi: np.ndarray,
    n: int,
    a_sub: np.ndarray,
    prefilters: tuple[float | None, ...],
    notes: list[str],
) -> list[tuple[str, np.ndarray]]:
    """Step 1b's initial values: the subspace ``A`` on the raw and the low-passed data.

    The same filter on ``u`` and ``y_j`` leaves ``B_j/A`` unchanged (PI-MOESP on
    coloured noise), so each cutoff gives one more estimate of the same ``A``.
    """
    inits = [("raw", a_sub)]
    for cut in prefilters:
        if cut is None:
            continue
        try:
            w_lp = "pi" if step1.subspace == "moesp" else step1.weighting
            # only a starting point: a weak direction in the low-passed data is
            # expected and harmless here, so its warning becomes a log line
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", IllConditionedWarning)
                r = step1(_lowpass(cut, u), _lowpass(cut, Yi), n, w_lp)
            for w in caught:
                if issubclass(w.category, IllConditionedWarning):
                    log.info("start from low-passed data (%g): %s", cut, w.message)
                else:  # pragma: no cover
                    warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
            inits.append((f"lowpass {cut:g}", np.real(np.poly(r.model.A))))
        except IdentificationError as exc:
            notes.append(f"subspace initialisation on low-passed data ({cut:g}) failed: {exc}")
    return inits


def _refine_denominator(
    oe: _OE, inits: list[tuple[str, np.ndarray]]
) -> tuple[list[dict[str, Any]], np.ndarray]:
    """Step 1b: output-error search for ``A`` from every start; the lowest cost wins.

    Starts are grouped by how many roots lie outside the unit circle (the
    bilateral cost is discontinuous where a root crosses it, so each group is its
    own search region); the PER_GROUP starts of lowest cost in each group get a
    short run, and the two best after it are finished (the wrong basins of this
    problem are far apart in cost, docs/sun.md).
    """
    groups: dict[int, list[tuple[float, str, np.ndarray]]] = {}
    for label, a0 in inits:
        for start in _reflections(a0):
            n_out = int(np.sum(np.abs(np.roots(start)) > 1.0))
            try:
                c0 = oe.cost(start)
            except (np.linalg.LinAlgError, ValueError):
                continue
            if np.isfinite(c0):
                groups.setdefault(n_out, []).append((c0, label, start))
    candidates: list[dict[str, Any]] = []
    for members in groups.values():
        members.sort(key=lambda m: m[0])
        for _, label, start in members[:PER_GROUP]:
            try:
                a_fit, cost, _ = oe.fit(start, max_nfev=SCREEN_NFEV)
            except (np.linalg.LinAlgError, ValueError) as exc:
                log.info("output-error start from %s failed: %s", label, exc)
                continue
            if np.all(np.isfinite(a_fit)) and np.isfinite(cost):
                candidates.append(
                    {"init": label, "start_poles": np.roots(start), "a": a_fit, "cost": cost}
                )
    if not candidates:
        raise IdentificationError("the output-error refinement failed from every start")
    candidates.sort(key=lambda c: c["cost"])
    for cand in candidates[:2]:
        try:
            cand["a"], cand["cost"], _ = oe.fit(cand["a"])
        except (np.linalg.LinAlgError, ValueError) as exc:  # pragma: no cover
            log.info("finishing the start from %s failed: %s", cand["init"], exc)
    best = min(candidates[:2], key=lambda c: c["cost"])
    log.info("step 1b: best start %s, cost %.6g", best["init"], best["cost"])
    return candidates, best["a"]


@dataclass(frozen=True)
class _InterSampleFit:
    """The inter-samples ``y_j = B_j/A u + h_j + w_j`` given ``A`` (least squares)."""

    n: int
    theta_oe: np.ndarray  # scaled [B_j; h_j] per column j
    R_oe: np.ndarray  # scaled residuals (N, p-1)
    B_ls: np.ndarray  # (p-1, n+1): B_j, j = 1..p-1, in data units
    sigma_w: float
    cov_a_B: np.ndarray | None  # joint covariance of [a_1..a_n, B_1, ..., B_{p-1}]

    def B_std_error(self) -> np.ndarray | None:
        if self.cov_a_B is None:
            return None
        return np.sqrt(np.clip(np.diag(self.cov_a_B)[self.n :], 0.0, None)).reshape(
            self.B_ls.shape
        )


def _intersample_fit(oe: _OE, a_hat: np.ndarray, p: int, refine: bool) -> _InterSampleFit:
    """``B_j`` by least squares given ``A``; with a refined ``A`` their delta-method covariance."""
    n = oe.n
    theta_oe, R_oe, _ = oe.inner(a_hat)
    nb = n + 1
    B_ls = theta_oe[:nb].T * (oe.sy / oe.su)  # (p-1, n+1): B_j, j = 1..p-1
    dof = max(R_oe.size - (n + theta_oe.size), 1)
    sigma_w_inter = float(np.sqrt(np.sum(R_oe**2) / dof)) * oe.sy

    # joint covariance of [a, B_1, h_1, ..., B_q, h_q] (scaled units) from the OE Jacobian
    cov_a_B: np.ndarray | None = None
    if refine:
        J = oe.jacobian(a_hat, theta_oe)
        cov_full = covariance_from_jacobian(J, R_oe.ravel(), J.shape[1])
        q = p - 1
        nh = theta_oe.shape[0] - nb
        keep = list(range(n))
        for j in range(q):
            base = n + j * (nb + nh)
            keep += list(range(base, base + nb))
        cov_a_B = cov_full[np.ix_(keep, keep)]
        scale = np.r_[np.ones(n), np.full(q * nb, oe.sy / oe.su)]
        cov_a_B = cov_a_B * np.outer(scale, scale)
    return _InterSampleFit(n, theta_oe, R_oe, B_ls, sigma_w_inter, cov_a_B)


def _numerator_variants(
    a_hat: np.ndarray,
    B_ls: np.ndarray,
    B_sub: np.ndarray,
    u: np.ndarray,
    y0: np.ndarray,
    n: int,
    dt: float,
    numerator: str,
    notes: list[str],
) -> dict[str, Any]:
    """Every numerator of ``y_0``: eq. (15) with both ``B_j`` sources, and Step 2's two IVs.

    The chosen one must succeed; the others are kept in ``extras`` where they can
    be computed, with a note where not.
    """
    variants: dict[str, Any] = {}
    try:
        lam = zoh_unit_numerator(a_hat, dt)
        eta_ls = float(np.mean(B_ls.sum(axis=1)) / lam.sum())  # eq. (15)
        eta_sub = float(np.mean(B_sub.sum(axis=1)) / lam.sum())  # eq. (15), subspace B_j
        variants["physical-ls"] = {"eta": eta_ls, "b": eta_ls * lam}
        variants["physical-subspace"] = {"eta": eta_sub, "b": eta_sub * lam}
        variants["lambda"] = lam
    except ModelError as exc:
        if numerator == "physical":
            raise IdentificationError(f"eq. (15): {exc}; try numerator='iv'") from exc
        notes.append(f"eq. (15) not available: {exc}")
    for kind in ("iv", "iv-delayed"):
        try:
            variants[kind] = _iv_numerator(a_hat, u, y0, n, kind)  # eq. (13)
        except (IdentificationError, np.linalg.LinAlgError) as exc:
            if numerator == kind:
                raise IdentificationError(f"step 2 ({kind}): {exc}") from exc
            notes.append(f"step 2 ({kind}) not available: {exc}")
    return variants


def _theta_covariance(
    inter: _InterSampleFit,
    a_hat: np.ndarray,
    u: np.ndarray,
    y0: np.ndarray,
    n: int,
    p: int,
    dt: float,
    numerator: str,
    gain_from: str,
    variants: Mapping[str, Any],
    notes: list[str],
) -> np.ndarray | None:
    """Covariance of ``[a_1..a_n, b_1..b_n]``: the OE covariance of ``A`` carried through.

    Eq. (15) with least-squares ``B_j``: the delta method on ``(a, B_j) -> (a, b)``.
    IV (Section 4.4): the IV covariance given ``A`` plus the propagated uncertainty
    of ``A`` (independent: ``A`` comes from ``w_j``, ``j >= 1``, the IV noise from ``w_0``).
    """
    cov_a_B = inter.cov_a_B
    if cov_a_B is None:
        return None
    nb = n + 1
    if numerator == "physical" and gain_from == "ls":

        def ab_of(x: np.ndarray) -> np.ndarray:
            a_ = np.r_[1.0, x[:n]]
            Bs = x[n:].reshape(p - 1, nb)
            lam_ = zoh_unit_numerator(a_, dt)
            return np.r_[x[:n], np.mean(Bs.sum(axis=1)) / lam_.sum() * lam_]  # eq. (15)

        x0 = np.r_[a_hat[1:], inter.B_ls.ravel()]
        _, cov_theta = propagate_covariance(ab_of, x0, cov_a_B)
        return cov_theta
    if numerator in ("iv", "iv-delayed"):
        cov_a = cov_a_B[:n, :n]

        def b_of_a(x: np.ndarray) -> np.ndarray:
            return _iv_numerator(np.r_[1.0, x], u, y0, n, numerator)["b"]

        Ja = _jacobian(b_of_a, a_hat[1:], cov_a)
        return np.block(
            [
                [cov_a, cov_a @ Ja.T],
                [Ja @ cov_a, variants[numerator]["cov"] + Ja @ cov_a @ Ja.T],
            ]
        )
    notes.append("gain_from='subspace': the subspace B_j have no covariance; none is reported")
    return None


def _parameter_map(
    data: ClosedLoopData,
    theta: np.ndarray,
    n: int,
    dt: float,
    mass: float | None,
    g: float,
    resistance: float | None,
    notes: list[str],
) -> tuple[list[str], Any]:
    """Names and the map ``[a, b] -> [a, b, pole_z, pole_rad_s, (eq. (27) physical)]``."""
    names = [f"a{k}" for k in range(1, n + 1)] + [f"b{k}" for k in range(1, n + 1)]
    Y_op = None
    op = data.loop.get("operating_point", {}) if hasattr(data.loop, "get") else {}
    if "Y" in op:
        Y_op = float(op["Y"])
    derived_names = ["pole_z", "pole_rad_s"]
    phys_ok = n == 3 and mass is not None
    if phys_ok:
        try:
            physical_from_t_model(
                np.r_[1.0, theta[:n]], np.r_[0.0, theta[n:]], dt, M=mass, g=g, R=resistance
            )
        except ModelError as exc:
            phys_ok = False
            notes.append(f"no physical parameters: {exc}")
    elif n == 3:
        notes.append("no physical parameters: the ball mass is unknown (pass mass=...)")
    phys_keys = ["alpha", "eta", "L", "gap", "I", "Q", "L_inf"]
    if resistance is None:
        phys_keys.insert(3, "R")
    if phys_ok:
        derived_names += phys_keys + (["Y_offset"] if Y_op is not None else [])

    def all_params(x: np.ndarray) -> np.ndarray:
        a_ = np.r_[1.0, x[:n]]
        r = np.roots(a_)
        real = r[np.abs(r.imag) <= 1e-9 * np.maximum(1.0, np.abs(r))]
        z = real[np.argmax(np.abs(real))].real if real.size else np.abs(r).max()
        out = [*x, z, np.log(abs(z)) / dt]
        if phys_ok:
            ph = physical_from_t_model(a_, np.r_[0.0, x[n:]], dt, M=mass, g=g, R=resistance)
            out += [ph[k] for k in phys_keys]
            if Y_op is not None:
                out.append(ph["gap"] - Y_op)
        return np.array(out, dtype=float)

    return names + derived_names, all_params


def _parameters(
    names: list[str],
    all_params: Any,
    theta: np.ndarray,
    cov_theta: np.ndarray | None,
    notes: list[str],
) -> tuple[dict[str, float], np.ndarray | None]:
    """The reported parameters and their covariance (delta method through ``all_params``)."""
    if cov_theta is not None:
        values, cov = propagate_covariance(all_params, theta, cov_theta)
        cov = 0.5 * (cov + cov.T)  # J C J^T is symmetric up to rounding
    else:
        values, cov = all_params(theta), None
    parameters = dict(zip(names, values.tolist()))
    if parameters["pole_z"] <= 1.0:
        notes.append(
            f"no unstable real pole in the estimate (largest {parameters['pole_z']:.4g}); "
            "reported as is, never reflected"
        )
    return parameters, cov


def _fit_metrics(
    inter: _InterSampleFit, oe: _OE, Yi: np.ndarray, numerator: str, variants: Mapping[str, Any]
) -> dict[str, float]:
    """Fit of the inter-samples ``j >= 1`` in percent, ``sigma_w``; the IV's ``sigma_w0``."""
    rel = np.sqrt(np.sum(inter.R_oe**2) * oe.sy**2 / (Yi.size * float(np.var(Yi))))
    fit = {"intersample_fit_percent": 100.0 * (1.0 - float(rel)), "sigma_w": inter.sigma_w}
    if numerator in ("iv", "iv-delayed"):
        fit["sigma_w0_iv"] = variants[numerator]["sigma_w"]
    return fit


def _extras(
    a_full: np.ndarray,
    b_full: np.ndarray,
    inter: _InterSampleFit,
    dt: float,
    p: int,
    step1_info: dict[str, Any],
    candidates: list[dict[str, Any]],
    variants: dict[str, Any],
) -> dict[str, Any]:
    """Every step's estimate, and the SIMO model ``[B_0, B_1, ..., B_{p-1}]/A``."""
    simo = simo_polynomials_to_state_space(
        a_full, [b_full, *inter.B_ls], dt, output_names=tuple(f"y{j}" for j in range(p))
    )
    return {
        "step1": step1_info,
        "step1b_candidates": candidates,
        "a": a_full,
        "b": b_full,
        "B_intersample": inter.B_ls,
        # Standard errors of the B_j coefficients (delta method, OE Jacobian); None
        # without refinement.
        "B_intersample_std_error": inter.B_std_error(),
        "simo_model": simo,
        "numerator_variants": variants,
        "poles": np.roots(a_full),
        "continuous_poles": np.log(np.roots(a_full).astype(complex)) / dt,
        "stable_unstable": split_stable_unstable(a_full),
    }


def _jacobian(f: Any, x: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Central-difference Jacobian with the steps of :func:`propagate_covariance`."""
    f0 = np.asarray(f(x))
    J = np.empty((f0.size, x.size))
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    for i in range(x.size):
        h = 1e-6 * max(abs(x[i]), sd[i], 1e-300)
        xp, xm = x.copy(), x.copy()
        xp[i] += h
        xm[i] -= h
        J[:, i] = (np.asarray(f(xp)) - np.asarray(f(xm))) / (2 * h)
    return J


# ------------------------------------------------------ conventional (p = 1)
def fit_conventional_direct(
    data: ClosedLoopData,
    *,
    order: int = 3,
    subspace: str = "moesp",
    horizon: int | None = None,
    weighting: str | None = None,
    feedthrough: bool = False,
    output: int = 0,
) -> IdentificationResult:
    """The conventional direct method (Case 1, ``p = 1``): subspace on ``(u, y_0)``.

    Uses only the samples the controller saw (``y_0``), as a same-rate recording
    would. With a reference of zero the data obey the controller exactly,
    ``C(q) u + D(q) y_0 = 0``, so the "plant" that fits them best is
    ``-C/D`` - the controller's inverse - and with ``n_c, n_d <= 2`` the data
    matrix of Fig. 6 loses ``L - 2`` ranks (identifiability condition (2)
    fails). Returned for comparison; it does not find the unstable pole.
    """
    if subspace not in SUBSPACE:
        raise DataError(f"`subspace` must be one of {SUBSPACE}; got {subspace!r}")
    order = _check_int(order, "order", 1)
    u, Y = _signals(data, output)
    y0 = Y[:, :1]
    notes = [
        "conventional direct method: y_0 is fed back, so (u, y_0) obey the controller; "
        "the estimate is not the plant (Sun et al., Case 1)"
    ]
    # Ill-conditioning is this method's expected outcome (the data matrix is rank
    # deficient); the subspace routine's warnings are recorded as notes.
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", IllConditionedWarning)
            sub = _subspace(
                subspace,
                y0,
                u,
                order=order,
                horizon=horizon,
                weighting=weighting,
                dt=data.dt,
                feedthrough=feedthrough,
            )
    except (IdentificationError, ModelError) as exc:
        raise IdentificationError(f"conventional direct ({subspace}) failed: {exc}") from exc
    for w in caught:
        if issubclass(w.category, IllConditionedWarning):
            notes.append(f"ill-conditioned, as expected: {w.message}")
            log.info("conventional direct: %s", w.message)
        else:  # pragma: no cover - pass anything else on
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    a, b = polynomials_from_state_space(sub.model)
    n = a.size - 1
    names = [f"a{k}" for k in range(1, n + 1)] + [
        f"b{k}" for k in range(0 if feedthrough else 1, n + 1)
    ]
    values = np.r_[a[1:], b if feedthrough else b[1:]]
    return IdentificationResult(
        method="conventional-direct",
        model=sub.model,
        parameters=dict(zip(names, values.tolist())),
        covariance=None,
        n_samples=data.n_samples,
        options={
            "order": order,
            "subspace": subspace,
            "horizon": horizon,
            "weighting": weighting,
            "feedthrough": feedthrough,
            "output": output,
        },
        singular_values=sub.singular_values,
        notes=tuple(notes),
        extras={"a": a, "b": b, "poles": np.roots(a)},
    )


# ------------------------------------------------------------------ Fig. 6
def data_matrix(
    data: ClosedLoopData,
    *,
    j: int | None = None,
    L: int = 20,
    M: int = 2500,
    m1: int | None = None,
    output: int = 0,
) -> np.ndarray:
    """The data matrix ``Phi`` of Case 1, time first: row ``m`` is
    ``[y_j(m-1) .. y_j(m-L), u(m-1) .. u(m-L)]`` for ``m = m1 .. m1+M-1``.

    ``j`` defaults to ``p - 1`` (the paper's choice for Fig. 6); ``m1`` to ``L``.
    """
    u, Y = _signals(data, output)
    p, N = data.p, data.n_samples
    j = p - 1 if j is None else _check_int(j, "j", 0)
    if j >= p:
        raise DataError(f"`j` = {j} outside 0..{p - 1}")
    L = _check_int(L, "L", 1)
    M = _check_int(M, "M", 1)
    m1 = L if m1 is None else _check_int(m1, "m1", L)
    if m1 + M > N:
        raise DataError(f"rows m1..m1+M-1 = {m1}..{m1 + M - 1} exceed the record's {N} periods")
    rows = np.arange(m1, m1 + M)
    yj = Y[:, j]
    return np.column_stack(
        [yj[rows - k] for k in range(1, L + 1)] + [u[rows - k] for k in range(1, L + 1)]
    )


def data_matrix_singular_values(
    data: ClosedLoopData, *, scale: bool = True, **kw: Any
) -> np.ndarray:
    """Singular values of :func:`data_matrix` (Fig. 6), largest first.

    ``scale=True`` divides the ``y`` and the ``u`` columns by their RMS first, so
    the two blocks (metres and volts) count alike; a rank deficiency shows either way.
    """
    Phi = data_matrix(data, **kw)
    if scale:
        L = Phi.shape[1] // 2
        Phi = Phi.copy()
        for blk in (slice(0, L), slice(L, 2 * L)):
            rms = float(np.sqrt(np.mean(Phi[:, blk] ** 2)))
            if rms > 0:
                Phi[:, blk] /= rms
    return np.linalg.svd(Phi, compute_uv=False)


#: The output channel and the known physics, options of both inter-sample methods.
PHYSICS_OPTIONS = (
    Option("output", "int", "output channel (position) when y has several", low=0),
    Option("mass", "float", "ball mass (default: data.loop['physical']['M'])", low=0,
           low_open=True, unit="kg"),
    Option("resistance", "float", "coil-circuit resistance (default: "
           "data.loop['physical']['R'])", low=0, low_open=True, unit="ohm"),
    Option("gravity", "float", "gravity (default: data.loop['physical']['g'] or "
           "9.80665)", low=0, low_open=True, unit="m/s^2"),
)  # fmt: skip

METHODS = {"intersample": fit_intersample}
#: Its options, declared once (maglevid.identify.options; defaults: fit_intersample's).
OPTIONS = {
    "intersample": (
        Option("order", "int", "plant order n (None: chosen from the singular values)",
               low=1, optional=True),
        Option("subspace", "str", "step-1 subspace algorithm", choices=SUBSPACE),
        Option("horizon", "int", "subspace horizon (block rows; default automatic)", low=1),
        Option("weighting", "str", "subspace weighting (default: the routine's)"),
        Option("refine", "bool", "step 1b: output-error refinement of A"),
        Option("prefilters", "floats", "low-pass cutoffs (fraction of Nyquist) tried by "
               "step 1b; null: the raw data", low=0, low_open=True, high=1, optional=True),
        Option("numerator", "str", "eq. (15) physical numerator or step 2 IV (non-causal "
               "or delayed instrument)", choices=NUMERATORS),
        Option("gain_from", "str", "where eq. (15) takes B_j(1)", choices=GAIN_SOURCES),
        *PHYSICS_OPTIONS,
    )
}  # fmt: skip
