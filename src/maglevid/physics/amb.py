"""Voltage-controlled two-coil active magnetic bearing (Gosiewski & Paszowski, eqs. (1)-(4)).

States ``x = [x, dx/dt, i1, i2]`` (displacement, velocity, coil currents deviating
from the bias ``i0``), inputs ``u = [u1, u2]`` (amplifier inputs, V), outputs
``y = [x, i1, i2]``.

Nonlinear model, eq. (1), with coil constants ``K_j = N_j^2 A mu_0``::

    m x'' = K1/4 (i1/(x0 - x))^2 - K2/4 (i2/(x0 + x))^2 + F_z
    kw1 u1 = R1 i1 + Ls1 i1' + K1/2 d/dt (i1/(x0 - x))
    kw2 u2 = R2 i2 + Ls2 i2' + K2/2 d/dt (i2/(x0 + x))

(the amplifier gain ``kw_j`` multiplies the command, as ``B_c`` of eq. (3) shows).
Linearised at ``x = 0, i1 = i2 = i0`` (eqs. (3)-(4))::

    A_c = [[0,   1,   0,   0 ],     B_c = [[0,  0 ],
           [v1,  0,   v2, -v3],            [0,  0 ],
           [0,  -v4, -v5,  0 ],            [v8, 0 ],
           [0,   v6,  0,  -v7]]            [0,  v9]]

    v1 = (ks1 + ks2)/m   v2 = ki1/m   v3 = ki2/m
    v4 = ki1/L1   v5 = R1/L1   v6 = ki2/L2   v7 = R2/L2   v8 = kw1/L1   v9 = kw2/L2
    ks_j = K_j i0^2 / (2 x0^3),  ki_j = K_j i0 / (2 x0^2),  Lo_j = K_j / (2 x0),
    L_j = Ls_j + Lo_j.

Decisions on the printed paper (each is tested in ``tests/physics/test_amb.py``
and explained in ``docs/papers.md``):

* **Inductances in H, not mH.** Only ``Ls = 0.086 H``, ``Lo = 0.343 H`` reproduce
  the printed ``A_C``, ``B_C`` (e.g. ``v8 = kw/(Ls+Lo) = 2.3316``).
* **ki is a force/current factor in N/A** (printed "A/m").
* **The printed ks, ki, Lo are rounded.** The printed matrix follows from one
  coil constant ``K = 2.4002878e-4 H m`` (``ks = 6.9979e5``, ``ki = 489.85``,
  ``Lo = 0.34290``); the rounded ``7e5, 490, 0.343`` give ``v1 = 777777.8``, not
  the printed ``777547.06``. :meth:`AMBParameters.nominal` uses this ``K``.
* **Row 4 of the printed A_C** shows ``+40.80`` on the diagonal; eq. (4) and
  the physics (resistive decay) give ``-v7``. We use ``-v7``.
* **C is printed with a duplicated row**; the outputs are ``[x, i1, i2]``, so
  ``C = [[1,0,0,0],[0,0,1,0],[0,0,0,1]]``.
* **B_F is garbled**; an external force enters the velocity row: ``B_F = [0, 1/m, 0, 0]^T``.
* The open-loop unstable pole is **not** ``sqrt(v1)``: the back-EMF coupling
  (``v2 v4``, ``v3 v6``) lowers it; use :func:`open_loop_poles`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import numpy as np
from scipy.optimize import root

from maglevid._validation import check_positive
from maglevid.exceptions import DataError, ModelError
from maglevid.lti import StateSpace

__all__ = [
    "C_AMB",
    "V_NAMES",
    "AMBParameters",
    "OperatingPoint",
    "amb_matrices",
    "amb_nonlinear_rhs",
    "amb_state_space",
    "bias_voltages",
    "linearized_v",
    "loop_dc_feedback",
    "open_loop_poles",
    "parameters_from_v",
    "ratios_from_v",
    "settled_operating_point",
    "v_from_matrices",
    "v_from_parameters",
]

#: Names of the structural elements of A_c, B_c (eq. (4)).
V_NAMES: tuple[str, ...] = tuple(f"v{i}" for i in range(1, 10))

#: Output matrix: y = [x, i1, i2] (the printed C has a duplicated row).
C_AMB = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]])
C_AMB.setflags(write=False)

STATE_NAMES = ("x", "dx", "i1", "i2")
INPUT_NAMES = ("u1", "u2")
OUTPUT_NAMES = ("x", "i1", "i2")

# Positions of v1..v9 in A_c (rows 0-3) and B_c (rows 4-7, columns of B_c), with
# the sign each carries in eq. (4).
_V_POS = (
    ("A", 1, 0, +1),  # v1
    ("A", 1, 2, +1),  # v2
    ("A", 1, 3, -1),  # v3
    ("A", 2, 1, -1),  # v4
    ("A", 2, 2, -1),  # v5
    ("A", 3, 1, +1),  # v6
    ("A", 3, 3, -1),  # v7
    ("B", 2, 0, +1),  # v8
    ("B", 3, 1, +1),  # v9
)


@dataclass(frozen=True)
class AMBParameters:
    """Physical parameters of one bearing axis, SI units.

    Parameters
    ----------
    m : float
        Rotor mass on the axis [kg].
    i0 : float
        Bias current of each coil [A].
    x0 : float
        Nominal air gap (clearance) [m].
    R1, R2 : float
        Coil resistances [ohm].
    Ls1, Ls2 : float
        Leakage inductances [H].
    K1, K2 : float
        Coil constants ``N^2 A mu_0`` [H m]; they fix ``ks``, ``ki`` and ``Lo``.
    kw1, kw2 : float
        Amplifier gains [V/V].

    Examples
    --------
    >>> p = AMBParameters.nominal()
    >>> round(p.ki1, 2), round(p.Lo1, 5)
    (489.85, 0.3429)
    """

    m: float
    i0: float
    x0: float
    R1: float
    R2: float
    Ls1: float
    Ls2: float
    K1: float
    K2: float
    kw1: float = 1.0
    kw2: float = 1.0

    def __post_init__(self) -> None:
        for f in fields(self):
            object.__setattr__(self, f.name, check_positive(getattr(self, f.name), f.name))

    # Derived quantities (eq. (4) and the text below it).
    @property
    def ks1(self) -> float:
        """Force/displacement factor of coil 1 [N/m]."""
        return self.K1 * self.i0**2 / (2 * self.x0**3)

    @property
    def ks2(self) -> float:
        return self.K2 * self.i0**2 / (2 * self.x0**3)

    @property
    def ki1(self) -> float:
        """Force/current factor of coil 1 [N/A]."""
        return self.K1 * self.i0 / (2 * self.x0**2)

    @property
    def ki2(self) -> float:
        return self.K2 * self.i0 / (2 * self.x0**2)

    @property
    def Lo1(self) -> float:
        """Air-gap inductance of coil 1 at the operating point [H]."""
        return self.K1 / (2 * self.x0)

    @property
    def Lo2(self) -> float:
        return self.K2 / (2 * self.x0)

    @property
    def L1(self) -> float:
        """Total inductance ``Ls1 + Lo1`` [H]."""
        return self.Ls1 + self.Lo1

    @property
    def L2(self) -> float:
        return self.Ls2 + self.Lo2

    @classmethod
    def nominal(cls) -> AMBParameters:
        """The paper's nominal bearing ("Computer simulation" section).

        ``m = 1.8 kg, i0 = 0.5 A, x0 = 0.35 mm, R = 17.5 ohm, Ls = 0.086 H, kw = 1``
        and ``K = v1 m x0^3 / i0^2`` with the printed ``v1 = 777547.06``, which
        reproduces every printed element of ``A_C`` and ``B_C``.
        """
        m, i0, x0 = 1.8, 0.5, 3.5e-4
        K = 777547.06 * m * x0**3 / i0**2  # from the printed v1; see module notes
        return cls(m=m, i0=i0, x0=x0, R1=17.5, R2=17.5, Ls1=0.086, Ls2=0.086, K1=K, K2=K)

    def with_fault(self, **factors: float) -> AMBParameters:
        """Copy with parameters multiplied by factors, e.g. ``with_fault(R1=1.2)``."""
        names = {f.name for f in fields(self)}
        for k in factors:
            if k not in names:
                raise DataError(f"unknown parameter {k!r}; expected one of {sorted(names)}")
        return replace(self, **{k: getattr(self, k) * float(v) for k, v in factors.items()})

    def v(self) -> np.ndarray:
        """The nine structural elements v1..v9 (eq. (4))."""
        return v_from_parameters(self)

    def to_dict(self) -> dict[str, float]:
        return asdict(self)

    def derived(self) -> dict[str, float]:
        """The derived factors ks, ki, Lo, L per coil."""
        return {
            k: getattr(self, k) for k in ("ks1", "ks2", "ki1", "ki2", "Lo1", "Lo2", "L1", "L2")
        }


def v_from_parameters(p: AMBParameters) -> np.ndarray:
    """v1..v9 from physical parameters (eq. (4))."""
    return np.array(
        [
            (p.ks1 + p.ks2) / p.m,
            p.ki1 / p.m,
            p.ki2 / p.m,
            p.ki1 / p.L1,
            p.R1 / p.L1,
            p.ki2 / p.L2,
            p.R2 / p.L2,
            p.kw1 / p.L1,
            p.kw2 / p.L2,
        ]
    )


def amb_matrices(v: Any) -> tuple[np.ndarray, np.ndarray]:
    """``A_c``, ``B_c`` of eq. (4) from ``v = [v1, ..., v9]`` or an :class:`AMBParameters`."""
    if isinstance(v, AMBParameters):
        v = v.v()
    v = np.asarray(v, dtype=float).reshape(-1)
    if v.size != 9:
        raise DataError(f"`v` must hold the 9 elements v1..v9; got {v.size}")
    A = np.zeros((4, 4))
    B = np.zeros((4, 2))
    A[0, 1] = 1.0
    for vi, (mat, r, c, sign) in zip(v, _V_POS):
        (A if mat == "A" else B)[r, c] = sign * vi
    return A, B


def amb_state_space(p: AMBParameters | Any, dt: float | None = None) -> StateSpace:
    """Continuous (or ZOH-sampled, when ``dt`` is given) linear model ``{A_c, B_c, C}``."""
    from maglevid.lti import discretize

    A, B = amb_matrices(p)
    sys = StateSpace(A, B, C_AMB, None, None, STATE_NAMES, INPUT_NAMES, OUTPUT_NAMES)
    return sys if dt is None else discretize(sys, dt)


def v_from_matrices(Ac: Any, Bc: Any) -> tuple[np.ndarray, float]:
    """Read v1..v9 off an identified ``A_c``, ``B_c`` in physical coordinates.

    Returns
    -------
    v : ndarray, shape (9,)
    structure_residual : float
        Largest element where eq. (4) has a structural 0 or 1 (the 1 in row 0 is
        compared with 1), relative to the size of its row. A large value means
        the realization is not in physical coordinates.
    """
    Ac = np.asarray(Ac, dtype=float)
    Bc = np.asarray(Bc, dtype=float)
    if Ac.shape != (4, 4) or Bc.shape != (4, 2):
        raise DataError(f"expected A_c (4, 4) and B_c (4, 2); got {Ac.shape} and {Bc.shape}")
    v = np.empty(9)
    mask_A = np.zeros((4, 4), bool)
    mask_B = np.zeros((4, 2), bool)
    for i, (mat, r, c, sign) in enumerate(_V_POS):
        M, mask = (Ac, mask_A) if mat == "A" else (Bc, mask_B)
        v[i] = sign * M[r, c]
        mask[r, c] = True
    mask_A[0, 1] = True
    resid = 0.0
    for r in range(4):
        scale_A = max(np.max(np.abs(Ac[r][mask_A[r]])) if mask_A[r].any() else 0.0, 1.0)
        resid = max(resid, float(np.max(np.abs(Ac[r][~mask_A[r]]), initial=0.0)) / scale_A)
        if mask_B[r].any():
            resid = max(
                resid,
                float(np.max(np.abs(Bc[r][~mask_B[r]]), initial=0.0))
                / np.max(np.abs(Bc[r][mask_B[r]])),
            )
        else:
            resid = max(resid, float(np.max(np.abs(Bc[r]))) / max(1.0, float(np.max(np.abs(Bc)))))
    resid = max(resid, abs(Ac[0, 1] - 1.0))
    return v, resid


def parameters_from_v(v: Any, *, m: float, i0: float) -> dict[str, float]:
    """Physical parameters identifiable from v1..v9 given the mass and bias current.

    Inverting eq. (4) with the force law of eq. (1) (``ks_j = ki_j i0 / x0``)::

        ki1 = m v2, ki2 = m v3, L1 = ki1/v4, L2 = ki2/v6,
        R1 = v5 L1, R2 = v7 L2, kw1 = v8 L1, kw2 = v9 L2,
        x0 = (ki1 + ki2) i0 / (m v1),  K_j = 2 x0^2 ki_j / i0,
        Lo_j = x0 ki_j / i0,  Ls_j = L_j - Lo_j,  ks_j = ki_j i0 / x0.

    ``ks1 + ks2 = m v1`` always; the split between the coils follows from the
    force law. A negative ``Ls_j`` (possible for noisy estimates) is returned as
    is, never clipped.
    """
    v = np.asarray(v, dtype=float).reshape(-1)
    if v.size != 9:
        raise DataError(f"`v` must hold the 9 elements v1..v9; got {v.size}")
    m = check_positive(m, "m")
    i0 = check_positive(i0, "i0")
    v1, v2, v3, v4, v5, v6, v7, v8, v9 = v
    if v4 == 0 or v6 == 0 or v1 == 0:
        raise ModelError("v1, v4 and v6 must be nonzero to invert eq. (4)")
    ki1, ki2 = m * v2, m * v3
    L1, L2 = ki1 / v4, ki2 / v6
    x0 = (ki1 + ki2) * i0 / (m * v1)
    out = {
        "ki1": ki1,
        "ki2": ki2,
        "L1": L1,
        "L2": L2,
        "R1": v5 * L1,
        "R2": v7 * L2,
        "kw1": v8 * L1,
        "kw2": v9 * L2,
        "ks_sum": m * v1,
        "x0": x0,
        "ks1": ki1 * i0 / x0,
        "ks2": ki2 * i0 / x0,
        "K1": 2 * x0**2 * ki1 / i0,
        "K2": 2 * x0**2 * ki2 / i0,
        "Lo1": x0 * ki1 / i0,
        "Lo2": x0 * ki2 / i0,
    }
    out["Ls1"] = L1 - out["Lo1"]
    out["Ls2"] = L2 - out["Lo2"]
    return out


def ratios_from_v(v: Any) -> dict[str, float]:
    """Scale-free ratios that need no prior knowledge (no m, no i0).

    ``ki1/ki2 = v2/v3``; ``R1/L1 = v5``, ``R2/L2 = v7`` (coil time constants);
    ``kw1/R1 = v8/v5``, ``kw2/R2 = v9/v7`` (static current gains);
    ``R1/R2``, ``L1/L2``, ``kw1/kw2`` through ``L_j = m v_{2|3} / v_{4|6}``, in
    which ``m`` cancels.
    """
    v = np.asarray(v, dtype=float).reshape(-1)
    _v1, v2, v3, v4, v5, v6, v7, v8, v9 = v
    l_ratio = (v2 / v4) / (v3 / v6)
    return {
        "ki1/ki2": v2 / v3,
        "R1/L1": v5,
        "R2/L2": v7,
        "kw1/R1": v8 / v5,
        "kw2/R2": v9 / v7,
        "L1/L2": l_ratio,
        "R1/R2": l_ratio * v5 / v7,
        "kw1/kw2": l_ratio * v8 / v9,
    }


def open_loop_poles(p: AMBParameters | Any) -> np.ndarray:
    """Eigenvalues of ``A_c`` (one real pole is positive: the bearing is unstable)."""
    A, _ = amb_matrices(p)
    return np.linalg.eigvals(A)


def amb_nonlinear_rhs(
    p: AMBParameters, state: np.ndarray, u: np.ndarray, Fz: float = 0.0
) -> np.ndarray:
    """Right-hand side of eq. (1) for absolute currents.

    ``state = [x, dx, I1, I2]`` with *absolute* coil currents; ``u = [u1, u2]`` the
    amplifier inputs (absolute; the bias voltage ``R_j i0 / kw_j`` holds the
    operating point). Solving eq. (1) for the current derivatives::

        d/dt (i/(x0 - x)) = i'/(x0 - x) + i x'/(x0 - x)^2
        => (Ls + K/(2 (x0 - x))) i1' = kw1 u1 - R1 i1 - K1 i1 x' / (2 (x0 - x)^2)
           (Ls + K/(2 (x0 + x))) i2' = kw2 u2 - R2 i2 + K2 i2 x' / (2 (x0 + x)^2)
    """
    x, dx, i1, i2 = state
    g1, g2 = p.x0 - x, p.x0 + x
    F = p.K1 / 4 * (i1 / g1) ** 2 - p.K2 / 4 * (i2 / g2) ** 2 + Fz
    di1 = (p.kw1 * u[0] - p.R1 * i1 - p.K1 * i1 * dx / (2 * g1**2)) / (p.Ls1 + p.K1 / (2 * g1))
    di2 = (p.kw2 * u[1] - p.R2 * i2 + p.K2 * i2 * dx / (2 * g2**2)) / (p.Ls2 + p.K2 / (2 * g2))
    return np.array([dx, F / p.m, di1, di2])


# ---------------------------------------------------------------------------
# The operating point a (faulty) bearing settles at under its controller
# ---------------------------------------------------------------------------
def linearized_v(p: AMBParameters, *, x: float, I1: float, I2: float) -> np.ndarray:
    """v1..v9 of eq. (4) for eq. (1) linearised at displacement ``x`` and currents ``I1, I2``.

    At ``x = 0, I1 = I2 = i0`` this is ``p.v()``. With gaps ``g1 = x0 - x``,
    ``g2 = x0 + x`` and inductances ``L_j(x) = Ls_j + K_j / (2 g_j)``::

        v1 = (K1 I1^2 / (2 g1^3) + K2 I2^2 / (2 g2^3)) / m
        v2 = K1 I1 / (2 g1^2) / m         v3 = K2 I2 / (2 g2^2) / m
        v4 = K1 I1 / (2 g1^2) / L1(x)     v6 = K2 I2 / (2 g2^2) / L2(x)
        v5 = R1 / L1(x)   v7 = R2 / L2(x)   v8 = kw1 / L1(x)   v9 = kw2 / L2(x)

    (at an equilibrium ``kw_j u_j = R_j I_j``, so the current equations have no
    ``x`` term).
    """
    g1, g2 = p.x0 - x, p.x0 + x
    L1, L2 = p.Ls1 + p.K1 / (2 * g1), p.Ls2 + p.K2 / (2 * g2)
    ki1, ki2 = p.K1 * I1 / (2 * g1**2), p.K2 * I2 / (2 * g2**2)
    ks = p.K1 * I1**2 / (2 * g1**3) + p.K2 * I2**2 / (2 * g2**3)
    return np.array(
        [ks / p.m, ki1 / p.m, ki2 / p.m, ki1 / L1, p.R1 / L1, ki2 / L2, p.R2 / L2, p.kw1 / L1,
         p.kw2 / L2]
    )  # fmt: skip


def bias_voltages(nominal: AMBParameters) -> np.ndarray:
    """Amplifier bias inputs ``R_j i0 / kw_j`` [V] that hold ``i_j = i0`` in the *nominal* bearing.

    A real controller applies these whatever the bearing has become; a fault
    then moves the operating point (see :func:`settled_operating_point`).
    """
    return np.array([nominal.R1 * nominal.i0 / nominal.kw1, nominal.R2 * nominal.i0 / nominal.kw2])


@dataclass(frozen=True)
class OperatingPoint:
    """Where a bearing settles under its loop, and eq. (4) linearised there.

    Attributes
    ----------
    x : float
        Rotor displacement [m].
    I1, I2 : float
        Absolute coil currents [A].
    U1, U2 : float
        Voltages across the coils ``kw_j u_j = R_j I_j`` [V].
    u : ndarray (2,)
        Absolute amplifier inputs ``u_bias + u_f`` [V].
    u_bias : ndarray (2,)
        The bias inputs the controller applies (those of the nominal bearing).
    u_f : ndarray (2,)
        The commanded offset: the feedback at rest [V].
    y : ndarray (3,)
        The measured deviations ``[x, I1 - i0, I2 - i0]`` from the *nominal*
        bias ``i0`` (what a recording logs at rest).
    x_hat, e : ndarray
        Observer state and integral state at rest (empty without a loop).
    v : ndarray (9,)
        :func:`linearized_v` at ``(x, I1, I2)``.
    A_c, B_c : ndarray
        ``amb_matrices(v)``.
    """

    x: float
    I1: float
    I2: float
    U1: float
    U2: float
    u: np.ndarray
    u_bias: np.ndarray
    u_f: np.ndarray
    y: np.ndarray
    x_hat: np.ndarray
    e: np.ndarray
    v: np.ndarray
    A_c: np.ndarray
    B_c: np.ndarray

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe form (``metadata["operating_point_true"]`` of a simulated recording)."""
        d = asdict(self)
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in d.items()}


def loop_dc_feedback(loop: Mapping[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The feedback at rest of an observer-based state feedback with integral action.

    ``loop`` holds ``"controller"`` (``F``, ``Fe``, ``E``; eq. (42)) and ``"observer"``
    (``A``, ``B``, ``C``, ``G``; eq. (43)), as in a recording's ``loop``. With
    constant signals the observer sits at its fixed point
    ``x̂ = W (B u_f - G y)``, ``W = (I - A - G C)^-1``, and ``u_f = -F x̂ + F_e e``;
    eliminating ``x̂``::

        u_f = P_y y + P_e e,   (I + F W B) P_y = F W G,   (I + F W B) P_e = F_e.

    Returns
    -------
    P_y : ndarray (nu, ny)
    P_e : ndarray (nu, ne)
    E : ndarray (ne, ny)
        The integrated outputs: at rest ``E y = 0``.
    """
    try:
        ctrl, obs = loop["controller"], loop["observer"]
        F, Fe, E = (np.asarray(ctrl[k], float) for k in ("F", "Fe", "E"))
        A, B, C, G = (np.asarray(obs[k], float) for k in ("A", "B", "C", "G"))
    except (KeyError, TypeError) as exc:
        raise DataError(
            "the loop must hold controller {F, Fe, E} and observer {A, B, C, G}; "
            f"missing {exc}"
        ) from None
    W = np.linalg.inv(np.eye(A.shape[0]) - A - G @ C)
    M = np.eye(F.shape[0]) + F @ W @ B
    return np.linalg.solve(M, F @ W @ G), np.linalg.solve(M, Fe), E


def settled_operating_point(
    plant: AMBParameters,
    nominal: AMBParameters,
    loop: Mapping[str, Any] | None = None,
    *,
    u_bias: Any = None,
    force: float = 0.0,
) -> OperatingPoint:
    """The equilibrium a (possibly faulty) bearing settles at, and eq. (4) there.

    The amplifiers apply the *nominal* bias inputs plus the command,
    ``u_j = u_bias_j + u_fj`` (``u_bias`` defaults to :func:`bias_voltages` of
    ``nominal``; a recording's ``loop["operating_point"]["u_bias"]`` is used when
    present). At rest, eq. (1) with ``x' = i' = 0`` gives::

        0 = K1/4 (I1/(x0 - x))^2 - K2/4 (I2/(x0 + x))^2 + force     (force balance)
        kw_j (u_bias_j + u_fj) = R_j I_j                             (coil j)

    and the loop (:func:`loop_dc_feedback`) gives ``u_f = P_y y + P_e e`` with
    ``y = [x, I1 - i0, I2 - i0]`` and ``E y = 0`` (the integral action drives the
    integrated outputs to their zero reference). Unknowns ``x, I1, I2, e``: as
    many as equations. Without a loop (``loop=None``) the commanded offset is
    zero: the open-loop rest point of the currents under the bias alone, with
    ``x`` from the force balance.

    Parameters
    ----------
    plant : AMBParameters
        The real bearing.
    nominal : AMBParameters
        The bearing the controller was designed on (its ``i0`` is the current
        the logged deviations are taken from).
    loop : mapping, optional
        ``{"controller": {...}, "observer": {...}}`` (a recording's ``loop``).
    u_bias : (2,) array_like, optional
        Bias inputs [V] (default: the loop's, else the nominal bearing's).
    force : float
        Static external force on the rotor [N] (e.g. a load), positive towards coil 1.

    Raises
    ------
    ModelError
        No rest point with the rotor inside the gap and positive currents (the
        fault is beyond what the loop compensates).

    Examples
    --------
    >>> nom = AMBParameters.nominal()
    >>> op = settled_operating_point(nom.with_fault(K2=0.92), nom)
    >>> round(op.x * 1e6, 2), round(op.I1, 4)     # no loop: the rotor moves off centre
    (-7.29, 0.5)
    """
    i0 = nominal.i0
    if u_bias is None:
        u_bias = (loop or {}).get("operating_point", {}).get("u_bias")
    ub = bias_voltages(nominal) if u_bias is None else np.asarray(u_bias, float).reshape(2)
    if loop is not None:
        Py, Pe, E = loop_dc_feedback(loop)
    else:
        Py, Pe, E = np.zeros((2, 3)), np.zeros((2, 0)), np.zeros((0, 3))
    ne = E.shape[0]
    kw, R = np.array([plant.kw1, plant.kw2]), np.array([plant.R1, plant.R2])
    e_scale = 1.0 / max(float(np.max(np.abs(Pe), initial=0.0)), 1e-300)
    f_scale = plant.K1 * i0**2 / (4 * plant.x0**2)
    y_scale = np.array([nominal.x0, i0, i0])

    def unpack(th: np.ndarray) -> tuple[float, float, float, np.ndarray]:
        return th[0] * nominal.x0, th[1] * i0, th[2] * i0, th[3:] * e_scale

    def resid(th: np.ndarray) -> np.ndarray:
        x, I1, I2, e = unpack(th)
        y = np.array([x, I1 - i0, I2 - i0])
        uf = Py @ y + Pe @ e
        g1, g2 = plant.x0 - x, plant.x0 + x
        f = plant.K1 / 4 * (I1 / g1) ** 2 - plant.K2 / 4 * (I2 / g2) ** 2 + force  # eq. (1)
        cur = (kw * (ub + uf) - R * np.array([I1, I2])) / (R * i0)
        return np.concatenate([[f / f_scale], cur, (E @ y) / (E @ y_scale)])

    sol = root(resid, np.concatenate([[0.0, 1.0, 1.0], np.zeros(ne)]), method="hybr",
               options={"xtol": 1e-14})  # fmt: skip
    res = float(np.max(np.abs(resid(sol.x))))
    x, I1, I2, e = unpack(sol.x)
    if res > 1e-9 or not (abs(x) < plant.x0 and I1 > 0 and I2 > 0):
        raise ModelError(
            "the bearing has no rest point with this loop "
            f"(residual {res:.3g}, x = {x:.3g} m, I1 = {I1:.3g} A, I2 = {I2:.3g} A): the fault is "
            "beyond what the loop can compensate"
        )
    return _operating_point(plant, loop, ub, Py, Pe, float(x), float(I1), float(I2), e, i0)


def _operating_point(
    plant: AMBParameters,
    loop: Mapping[str, Any] | None,
    ub: np.ndarray,
    Py: np.ndarray,
    Pe: np.ndarray,
    x: float,
    I1: float,
    I2: float,
    e: np.ndarray,
    i0: float,
) -> OperatingPoint:
    y = np.array([x, I1 - i0, I2 - i0])
    uf = Py @ y + Pe @ e
    x_hat = np.zeros(0)
    if loop is not None:
        obs = loop["observer"]
        A, B, C, G = (np.asarray(obs[k], float) for k in ("A", "B", "C", "G"))
        x_hat = np.linalg.solve(np.eye(A.shape[0]) - A - G @ C, B @ uf - G @ y)
    v = linearized_v(plant, x=x, I1=I1, I2=I2)
    Ac, Bc = amb_matrices(v)
    return OperatingPoint(
        x=x, I1=I1, I2=I2, U1=plant.R1 * I1, U2=plant.R2 * I2, u=ub + uf, u_bias=ub,
        u_f=uf, y=y, x_hat=x_hat, e=np.asarray(e, float), v=v, A_c=Ac, B_c=Bc,
    )  # fmt: skip
