"""Single-axis magnetic suspension of a steel ball (Sun, Miyake, Ohmori & Sano, Section 5).

A ball of mass ``M`` hangs under an electromagnet; the coil (resistance ``R``)
is driven by a voltage ``U + u``; the gap to the magnet is ``gap + y`` (``y``
grows *away* from the magnet, with gravity). States ``x = [y, dy/dt, i]``,
input ``u`` [V], output ``y`` [m]; all are deviations from the operating point.

Nonlinear model (eqs. (22)-(25), corrected as listed below)::

    L(y)  = L_inf + Q / (gap + y)                                   (23)
    M y'' = M g - Q/2 ((I + i) / (gap + y))^2                        (25a)
    L(y) di/dt = U + u - R (I + i) + Q (I + i) / (gap + y)^2 dy/dt   (25b)

Operating point (eq. (26)): ``M g = Q/2 (I/gap)^2`` and ``U = R I``.
Linearisation (eq. (27), corrected)::

    M y'' = alpha y - eta i,     L di/dt = u - R i + eta dy/dt,
    G(s) = y/u = -eta / ((M s^2 - alpha)(L s + R) + eta^2 s),
    alpha = Q I^2 / gap^3 = 2 M g / gap,   eta = Q I / gap^2,   L = L_inf + Q/gap.

Decisions on the printed paper (tested in ``tests/physics/test_suspension.py``,
argued in ``docs/sun.md``):

* **Factors of 2.** With ``F = Q/2 (I/gap)^2`` of (24)-(26) the force slopes are
  ``dF/dgap = -Q I^2/gap^3`` and ``dF/di = Q I/gap^2``; the printed
  ``alpha = 2QI^2/Y^3`` and ``eta = 2QI/Y^2`` are twice these.
* **(25b) lacks ``dy/dt``.** ``d/dt (L(y) (I+i))`` has the term
  ``-Q (I+i)/(gap+y)^2 dy/dt``; the printed equation drops the derivative.
* **(27) lacks an ``s``.** The back-EMF term is ``gamma eta s`` (a velocity
  voltage), not a constant ``eta gamma``; and ``gamma`` = ``eta`` (the same
  ``Q I/gap^2``, energy conservation), the printed ``gamma = L I/Y`` being
  that with ``L = Q/Y`` the air-gap part of the inductance.
* **Sign.** ``G(s)`` is *negative* at high frequency (more voltage, more
  current, more pull, smaller gap); (28) prints negative ``b_i``, (27) a
  positive numerator. We follow (28).
* **"Y" is a sensor reading.** No parameter set satisfies the force balance
  (26) at a literal 6 mm gap with the dynamics of (28): (28)'s unstable pole
  fixes ``alpha = 2 M g / gap``, i.e. a 10.48 mm gap. The paper's ``Y`` (and the
  "r" of its Table 2) is read as the laser sensor's value, and
  ``gap = Y + Y_offset`` with ``Y_offset = 4.477 mm``. The offset also explains
  Table 2's nominal denominators at ``Y = 3, 4 mm`` (see :func:`table2_nominal`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import numpy as np

from maglevid._validation import check_positive
from maglevid.exceptions import DataError, ModelError
from maglevid.lti import StateSpace, discretize

__all__ = [
    "GRAVITY",
    "PRINTED_POLES_28",
    "PRINTED_TABLE2_NOMINAL",
    "PRINTED_T_MODEL_28",
    "T_PAPER",
    "SuspensionParameters",
    "continuous_from_t_model",
    "physical_from_continuous",
    "physical_from_t_model",
    "polynomials_from_state_space",
    "suspension_nonlinear_rhs",
    "suspension_state_space",
    "suspension_t_model",
    "suspension_transfer_function",
    "table2_nominal",
]

#: Standard gravity [m/s^2] (the paper does not say which value it used).
GRAVITY = 9.80665

#: Control period of the experiment [s] (Section 5.1).
T_PAPER = 2.4e-3

#: Eq. (28) as printed: ``(a1, a2, a3)`` and ``(b1, b2, b3)`` of the T-model at Y = 6 mm.
PRINTED_T_MODEL_28: dict[str, tuple[float, ...]] = {
    "a": (-2.9793, 2.9488, -0.9698),
    "b": (-0.0411e-6, -0.1631e-6, -0.0404e-6),
}

#: The poles printed under eq. (28).
PRINTED_POLES_28: tuple[float, ...] = (1.1058, 0.9666, 0.9071)

#: Nominal columns of Table 2 as printed, by sensor reading Y [m].
PRINTED_TABLE2_NOMINAL: dict[float, dict[str, tuple[float, ...]]] = {
    3e-3: {"a": (-2.9843, 2.9549, -0.9710), "b": (-0.05881e-6, -0.2336e-6, -0.0579e-6)},
    4e-3: {"a": (-2.9826, 2.9530, -0.9707), "b": (-0.0537e-6, -0.2134e-6, -0.0529e-6)},
    6e-3: {"a": (-2.9795, 2.9488, -0.9698), "b": (-0.0411e-6, -0.1631e-6, -0.0404e-6)},
}

STATE_NAMES = ("y", "dy", "i")


@dataclass(frozen=True)
class SuspensionParameters:
    """Physical parameters of the magnetic suspension, SI units.

    Parameters
    ----------
    M : float
        Mass of the steel ball [kg].
    R : float
        Resistance of the coil circuit [ohm].
    Q : float
        Inductance constant of eq. (23) [H m].
    L_inf : float
        Inductance far from the magnet, eq. (23) [H].
    Y : float
        Operating point as read by the gap sensor [m] (the paper's ``Y``).
    Y_offset : float
        Sensor offset: the physical gap is ``Y + Y_offset`` [m].
    g : float
        Gravity [m/s^2].

    Notes
    -----
    The current ``I`` and voltage ``U`` at the operating point follow from the
    force balance, eq. (26); they are properties, not inputs.

    Examples
    --------
    >>> p = SuspensionParameters.nominal()
    >>> round(p.gap * 1e3, 3), round(p.I, 4)
    (10.477, 1.253)
    """

    M: float
    R: float
    Q: float
    L_inf: float
    Y: float
    Y_offset: float = 0.0
    g: float = GRAVITY

    def __post_init__(self) -> None:
        for f in fields(self):
            v = float(getattr(self, f.name))
            if not np.isfinite(v):
                raise DataError(f"`{f.name}` must be finite; got {v!r}")
            object.__setattr__(self, f.name, v)
        for name in ("M", "R", "Q", "g"):
            check_positive(getattr(self, name), name)
        if self.L_inf < 0:
            raise DataError(f"`L_inf` must be >= 0; got {self.L_inf!r}")
        if self.gap <= 0:
            raise DataError(
                f"the gap Y + Y_offset = {self.gap!r} m must be positive "
                f"(Y={self.Y!r}, Y_offset={self.Y_offset!r})"
            )

    # ------------------------------------------------------ operating point
    @property
    def gap(self) -> float:
        """Physical gap ``Y + Y_offset`` [m]."""
        return self.Y + self.Y_offset

    @property
    def I(self) -> float:  # noqa: E743 - the paper's symbol
        """Operating current from the force balance ``M g = Q/2 (I/gap)^2`` [A] (eq. (26))."""
        return self.gap * float(np.sqrt(2.0 * self.M * self.g / self.Q))

    @property
    def U(self) -> float:
        """Operating voltage ``R I`` [V] (eq. (26))."""
        return self.R * self.I

    @property
    def L(self) -> float:
        """Inductance at the operating point ``L_inf + Q/gap`` [H] (eq. (23))."""
        return self.L_inf + self.Q / self.gap

    @property
    def alpha(self) -> float:
        """Negative stiffness ``Q I^2/gap^3 = 2 M g/gap`` [N/m] (eq. (27), corrected)."""
        return self.Q * self.I**2 / self.gap**3

    @property
    def eta(self) -> float:
        """Force/current factor ``Q I/gap^2`` [N/A], also the back-EMF constant [V s/m]."""
        return self.Q * self.I / self.gap**2

    @classmethod
    def nominal(cls, Y: float = 6e-3) -> SuspensionParameters:
        """The experiment of Section 5, fitted to eq. (28).

        ``M = 0.54 kg`` and ``R = 11.233 ohm`` are printed. ``Q``, ``L_inf`` and
        ``Y_offset`` minimise the largest mismatch, in half units of the last
        printed digit, to the printed poles ``1.1058, 0.9666, 0.9071`` and
        numerator ``b1..b3`` of (28) at ``T = 2.4 ms``; every one of those six
        numbers is reproduced to its printed digits (worst 0.70 half-unit).
        The printed ``a1..a3`` cannot all be matched by *any* model with those
        poles (see ``docs/sun.md``). ``Y`` is the sensor reading; 6 mm as in (28).
        """
        return cls(M=0.54, R=11.233, Q=7.4050e-4, L_inf=0.80125, Y=Y, Y_offset=4.477e-3)

    def at(self, Y: float) -> SuspensionParameters:
        """The same suspension at another operating point (sensor reading ``Y``)."""
        return replace(self, Y=float(Y))

    def to_dict(self) -> dict[str, float]:
        return asdict(self)

    def operating_point(self) -> dict[str, float]:
        """JSON-safe operating point: ``Y, Y_offset, gap, I, U, L, alpha, eta``."""
        return {
            "Y": self.Y,
            "Y_offset": self.Y_offset,
            "gap": self.gap,
            "I": self.I,
            "U": self.U,
            "L": self.L,
            "alpha": self.alpha,
            "eta": self.eta,
        }


# --------------------------------------------------------------- linear model
def suspension_state_space(p: SuspensionParameters, dt: float | None = None) -> StateSpace:
    """Linearised model (eq. (27), corrected); ZOH-sampled when ``dt`` is given.

    ``x = [y, dy/dt, i]``::

        A_c = [[0,        1,     0     ],     B_c = [[0  ],     C = [1, 0, 0]
               [alpha/M,  0,    -eta/M ],            [0  ],
               [0,        eta/L, -R/L  ]]            [1/L]]

    Examples
    --------
    >>> sys = suspension_state_space(SuspensionParameters.nominal(), dt=2.4e-3)
    >>> np.round(np.sort(sys.poles().real)[::-1], 4)
    array([1.1058, 0.9666, 0.9071])
    """
    M, L, R, al, eta = p.M, p.L, p.R, p.alpha, p.eta
    A = np.array([[0.0, 1.0, 0.0], [al / M, 0.0, -eta / M], [0.0, eta / L, -R / L]])
    B = np.array([[0.0], [0.0], [1.0 / L]])
    C = np.array([[1.0, 0.0, 0.0]])
    sys = StateSpace(A, B, C, None, None, STATE_NAMES, ("u",), ("y",))
    return sys if dt is None else discretize(sys, dt)


def suspension_transfer_function(p: SuspensionParameters) -> tuple[np.ndarray, np.ndarray]:
    """``(num, den)`` of ``G(s) = -eta / (M L s^3 + M R s^2 + (eta^2 - alpha L) s - alpha R)``.

    Descending powers of ``s`` (eq. (27) with its corrections).
    """
    M, L, R, al, eta = p.M, p.L, p.R, p.alpha, p.eta
    return np.array([-eta]), np.array([M * L, M * R, eta**2 - al * L, -al * R])


def polynomials_from_state_space(sys: StateSpace) -> tuple[np.ndarray, np.ndarray]:
    """``(a, b)`` of a discrete single-input model as polynomials in ``z^-1``.

    ``a = [1, a1, ..., an] = det(I - A z^-1)`` and ``b`` with one row
    ``[b0, b1, ..., bn]`` per output (a 1-D array for one output), ``b0 = D``.

    The numerator is the product ``A(z^-1) H(z^-1)`` truncated at ``z^-n``, with
    the Markov parameters ``h_0 = D, h_k = C A^(k-1) B``::

        b_k = sum_{i=0..k} a_i h_(k-i),   k = 0..n

    This avoids the cancellation of ``det(zI - A + bc) - det(zI - A)``, which
    loses eight digits when, as here, ``b`` is 1e-8 times ``a``.
    """
    if not sys.is_discrete or sys.nu != 1:
        raise ModelError(f"expected a discrete single-input model; got {sys!r}")
    n = sys.nx
    a = np.real(np.poly(sys.A)) if n else np.ones(1)
    h = sys.markov(n + 1)[:, :, 0]  # (n+1, ny): D, CB, CAB, ...
    b = np.array([[np.dot(a[: k + 1], h[k::-1, o]) for k in range(n + 1)] for o in range(sys.ny)])
    return a, (b[0] if sys.ny == 1 else b)


def suspension_t_model(
    p: SuspensionParameters, dt: float = T_PAPER
) -> tuple[np.ndarray, np.ndarray]:
    """The T-model (eq. (1a)) of the suspension: ``a = [1, a1, a2, a3]``, ``b = [0, b1, b2, b3]``.

    Examples
    --------
    >>> a, b = suspension_t_model(SuspensionParameters.nominal())
    >>> np.round(b[1:] * 1e6, 4)
    array([-0.0411, -0.1631, -0.0404])
    """
    return polynomials_from_state_space(suspension_state_space(p, dt))


def table2_nominal(
    p: SuspensionParameters | None = None, dt: float = T_PAPER
) -> dict[float, dict[str, np.ndarray]]:
    """The model's T-models at the sensor readings of Table 2 (3, 4 and 6 mm).

    Returns ``{Y: {"a": a1..a3, "b": b1..b3, "poles": z-poles}}`` for comparison
    with :data:`PRINTED_TABLE2_NOMINAL`.
    """
    p = SuspensionParameters.nominal() if p is None else p
    out: dict[float, dict[str, np.ndarray]] = {}
    for Y in PRINTED_TABLE2_NOMINAL:
        a, b = suspension_t_model(p.at(Y), dt)
        out[Y] = {"a": a[1:], "b": b[1:], "poles": np.sort(np.roots(a).real)[::-1]}
    return out


# ------------------------------------------------------------ nonlinear model
def suspension_nonlinear_rhs(p: SuspensionParameters, x: Any, u: float) -> np.ndarray:
    """Right-hand side of eq. (25) (corrected) in deviation variables.

    ``x = [y, dy/dt, i]``, ``u`` the voltage deviation from ``U``::

        y''   = g - Q/(2M) ((I + i)/(gap + y))^2
        di/dt = (u + U - R (I + i) + Q (I + i)/(gap + y)^2 dy/dt) / (L_inf + Q/(gap + y))

    At ``x = 0, u = 0`` all derivatives vanish (eq. (26)).
    """
    y, dy, i = float(x[0]), float(x[1]), float(x[2])
    gap = p.gap + y
    cur = p.I + i
    if gap <= 0:
        raise ModelError(f"the ball touched the magnet (gap {gap:.3g} m); the loop is unstable")
    ddy = p.g - 0.5 * p.Q / p.M * (cur / gap) ** 2  # eq. (25a)
    di = (u + p.U - p.R * cur + p.Q * cur / gap**2 * dy) / (p.L_inf + p.Q / gap)  # eq. (25b)
    return np.array([dy, ddy, di])


# ----------------------------------------------------------- inverse mapping
def continuous_from_t_model(a: Any, b: Any, dt: float) -> tuple[np.ndarray, float]:
    """Continuous poles and numerator constant of a T-model whose plant is ``k/prod(s - s_i)``.

    The poles are ``s_i = ln(z_i)/dt`` (Section 4.3 (1)); ``k`` matches the
    numerator's static gain: ``B(1)/A(1) = k / prod(-s_i)`` (the ZOH keeps the
    DC gain). A complex logarithm (a pole on the negative real axis) is refused.
    """
    a = np.asarray(a, dtype=float).ravel()
    b = np.asarray(b, dtype=float).ravel()
    z = np.roots(a)
    bad = z[(np.abs(z.imag) <= 1e-12 * np.abs(z)) & (z.real <= 0)]
    if bad.size:
        raise ModelError(
            f"pole(s) {', '.join(f'{v.real:.4g}' for v in bad)} on the negative real axis: "
            "no real continuous model samples to them under a zero-order hold"
        )
    s = np.log(z.astype(complex)) / dt
    dc = np.sum(b) / np.sum(a)
    k = float(np.real(dc * np.prod(-s)))
    return s, k


def physical_from_continuous(
    s: Any, k: float, *, M: float, g: float = GRAVITY, R: float | None = None
) -> dict[str, float]:
    """Physical parameters from the continuous poles ``s`` and numerator ``k``.

    With ``G(s) = k / (s^3 + c1 s^2 + c2 s + c3)`` and eq. (27)::

        c1 = R/L,  c2 = (eta^2 - alpha L)/(M L),  c3 = -alpha R/(M L),  k = -eta/(M L)

    Given ``M`` only, all four follow::

        alpha = -M c3/c1,  L = (c2 + alpha/M)/(k^2 M),  R = c1 L,  eta = -k M L

    but ``c2 + alpha/M`` is a small difference of large numbers (150 of 1870
    1/s^2 for the nominal plant), so ``L``, ``R`` and ``eta`` are then poorly
    determined. Given ``M`` and ``R`` (both printed in Section 5.1), ``c2`` is
    not needed::

        L = R/c1,  alpha = -M c3/c1,  eta = -k M L

    Through the force balance (26): ``gap = 2 M g/alpha``, ``I = 2 M g/eta``,
    ``Q = eta gap^2/I``, ``L_inf = L - Q/gap``.
    """
    s = np.asarray(s).ravel()
    if s.size != 3:
        raise ModelError(f"the suspension has 3 poles; got {s.size}")
    M = check_positive(M, "M")
    c = np.real(np.poly(s))  # [1, c1, c2, c3]
    c1, c2, c3 = c[1], c[2], c[3]
    if c1 <= 0 or c3 >= 0 or k == 0:
        raise ModelError(
            "the poles do not have the sign pattern of eq. (27) "
            f"(need R/L = {c1:.4g} > 0 and -alpha R/(M L) = {c3:.4g} < 0, k = {k:.4g} != 0)"
        )
    alpha = -M * c3 / c1
    if R is None:
        L = (c2 + alpha / M) / (k**2 * M)
        R = c1 * L
    else:
        R = check_positive(R, "R")
        L = R / c1
    eta = -k * M * L
    gap = 2 * M * g / alpha
    I = 2 * M * g / eta
    Q = eta * gap**2 / I
    return {
        "alpha": alpha,
        "eta": eta,
        "L": L,
        "R": R,
        "gap": gap,
        "I": I,
        "Q": Q,
        "L_inf": L - Q / gap,
    }


def physical_from_t_model(
    a: Any, b: Any, dt: float, *, M: float, g: float = GRAVITY, R: float | None = None
) -> dict[str, float]:
    """:func:`physical_from_continuous` of :func:`continuous_from_t_model` (one call)."""
    s, k = continuous_from_t_model(a, b, dt)
    return physical_from_continuous(s, k, M=M, g=g, R=R)
