"""Single-electromagnet steel-ball levitator (the UAQ rig) with the inductance law L(y).

The ball hangs below an electromagnet; ``y`` is the air gap, measured downward
from the magnet face, so gravity increases ``y`` and the magnetic force
decreases it. States ``x = [y, dy/dt, i]``, input ``u`` (command voltage, V),
outputs ``[y, i]`` (both measured on the rig).

Inductance law used by the upstream benchmark (Santana Ramírez, "Levitador
Magnético Benchmark", UAQ; quoted in the headers of every ``dataset_*`` file)::

    L(y)  = k0 + k / (1 + y/a)                          (L1)
    L'(y) = dL/dy = -k a / (a + y)^2                    (L2)

Co-energy force (attractive, toward the magnet)::

    F(i, y) = 1/2 i^2 |L'(y)| = k a i^2 / (2 (a + y)^2)   (F1)

Newton and Faraday (flux ``lambda = L(y) i``)::

    m y''            = m g - F(i, y)                    (M1)
    ku u - v0        = R i + L(y) i' + i L'(y) y'       (E1)

``ku`` (coil volts per command volt) and ``v0`` (driver drop) describe the PWM
driver; the upstream model has ``ku = 1, v0 = 0``. On the rig ``u/i`` at the
operating point is 15-17 V/A, not ``R = 2.72 ohm``, so the driver is not ideal
(see ``docs/real-rigs.md``).

Equilibrium at gap ``y0`` (``F = m g``)::

    i0 = (a + y0) sqrt(2 m g / (k a))                   (Q1)

Linearisation at ``(y0, i0)`` (``dF/dy = -2 F/(a + y)``, ``dF/di = 2 F / i``)::

    dy'' = p^2 dy - b di,   p^2 = 2 g / (a + y0),  b = 2 g / i0        (LIN1)
    L0 di' = ku du - R di - i0 L'(y0) dy'                              (LIN2)

so the current-driven mechanical plant ``i -> y`` has the poles ``+-p``
(``p ~ 43.9 rad/s`` at 5 mm with the upstream values; ``exp(p 0.01) ~ 1.55``),
independent of ``R``, ``k0`` and the driver. The voltage-driven plant has a third
(electrical) pole and the back-EMF term shifts the unstable pole slightly.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from typing import Any

import numpy as np

from maglevid._validation import check_positive
from maglevid.exceptions import DataError, ModelError
from maglevid.lti import StateSpace, discretize

__all__ = [
    "LevitatorParameters",
    "current_gain",
    "equilibrium",
    "integrate_zoh",
    "levitator_rhs",
    "linearize",
    "mechanical_from_pole",
    "mechanical_state_space",
    "unstable_pole",
]

STATE_NAMES = ("y", "dy", "i")
MECH_STATE_NAMES = ("y", "dy")


@dataclass(frozen=True)
class LevitatorParameters:
    """Physical parameters of the single-magnet levitator, SI units.

    Parameters
    ----------
    m : float
        Ball mass [kg].
    g : float
        Gravitational acceleration [m/s^2].
    R : float
        Coil circuit resistance seen by the driver [ohm].
    k0 : float
        Inductance far from the ball [H] (eq. L1).
    k : float
        Inductance increment at zero gap [H] (eq. L1).
    a : float
        Length scale of the inductance law [m] (eq. L1).
    ku : float
        Driver gain, coil volts per command volt [V/V].
    v0 : float
        Driver voltage drop [V] (may be zero).

    Examples
    --------
    >>> p = LevitatorParameters.uaq()
    >>> round(float(equilibrium(p, 0.005)[0]), 3)
    0.465
    >>> round(float(unstable_pole(p, 0.005)), 2)
    43.86
    """

    m: float = 0.018
    g: float = 9.81
    R: float = 2.72
    k0: float = 0.0704
    k: float = 0.0327
    a: float = 0.0052
    ku: float = 1.0
    v0: float = 0.0

    def __post_init__(self) -> None:
        for f in fields(self):
            if f.name == "v0":
                v = float(self.v0)
                if not np.isfinite(v):
                    raise DataError(f"`v0` must be finite; got {self.v0!r}")
                object.__setattr__(self, "v0", v)
                continue
            object.__setattr__(self, f.name, check_positive(getattr(self, f.name), f.name))

    @classmethod
    def uaq(cls) -> LevitatorParameters:
        """The published UAQ values: ``m = 18 g``, ``R = 2.72 ohm``, ``k0 = 0.0704 H``,
        ``k = 0.0327 H``, ``a = 5.2 mm`` (upstream file headers), ideal driver."""
        return cls()

    def inductance(self, y: Any) -> np.ndarray:
        """``L(y)`` [H], eq. (L1)."""
        y = np.asarray(y, dtype=float)
        return self.k0 + self.k / (1.0 + y / self.a)  # eq. (L1)

    def inductance_gradient(self, y: Any) -> np.ndarray:
        """``dL/dy`` [H/m], eq. (L2) (negative: the inductance falls as the gap opens)."""
        y = np.asarray(y, dtype=float)
        return -self.k * self.a / (self.a + y) ** 2  # eq. (L2)

    def force(self, i: Any, y: Any) -> np.ndarray:
        """Magnetic force toward the magnet [N], eq. (F1)."""
        i = np.asarray(i, dtype=float)
        y = np.asarray(y, dtype=float)
        return self.k * self.a * i**2 / (2.0 * (self.a + y) ** 2)  # eq. (F1)

    def with_changes(self, **changes: float) -> LevitatorParameters:
        names = {f.name for f in fields(self)}
        for k in changes:
            if k not in names:
                raise DataError(f"unknown parameter {k!r}; expected one of {sorted(names)}")
        return replace(self, **changes)

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


def _check_gap(p: LevitatorParameters, y0: Any) -> float:
    y0 = float(y0)
    if not np.isfinite(y0) or y0 <= -p.a:
        raise DataError(f"`y0` must be a finite gap greater than -a = {-p.a:g} m; got {y0!r}")
    return y0


def equilibrium(p: LevitatorParameters, y0: float) -> tuple[float, float]:
    """Equilibrium current and command voltage ``(i0, u0)`` at gap ``y0`` (eq. (Q1))."""
    y0 = _check_gap(p, y0)
    i0 = (p.a + y0) * np.sqrt(2.0 * p.m * p.g / (p.k * p.a))  # eq. (Q1)
    u0 = (p.R * i0 + p.v0) / p.ku  # eq. (E1) at rest
    return float(i0), float(u0)


def unstable_pole(p: LevitatorParameters, y0: float) -> float:
    """Unstable pole ``sqrt(2 g / (a + y0))`` [rad/s] of the current-driven plant (LIN1)."""
    y0 = _check_gap(p, y0)
    return float(np.sqrt(2.0 * p.g / (p.a + y0)))  # eq. (LIN1)


def current_gain(p: LevitatorParameters, y0: float) -> float:
    """``b = 2 g / i0`` [m/s^2 per A], the acceleration per ampere at ``y0`` (LIN1)."""
    i0, _ = equilibrium(p, y0)
    return 2.0 * p.g / i0  # eq. (LIN1)


def mechanical_state_space(
    p: LevitatorParameters | None = None,
    y0: float = 0.005,
    *,
    pole: float | None = None,
    gain: float | None = None,
    dt: float | None = None,
) -> StateSpace:
    """Current-driven mechanical plant ``di -> dy`` (eq. (LIN1)), states ``[dy, dy']``.

    Give either parameters ``p`` (and ``y0``) or the pole ``p`` [rad/s] and gain ``b``
    directly (``pole=``, ``gain=``). ``dt`` returns the ZOH-sampled model.
    """
    if pole is None or gain is None:
        if p is None:
            raise DataError("give `p` (LevitatorParameters) or both `pole` and `gain`")
        pole, gain = unstable_pole(p, y0), current_gain(p, y0)
    A = np.array([[0.0, 1.0], [pole**2, 0.0]])
    B = np.array([[0.0], [-gain]])
    sys = StateSpace(A, B, [[1.0, 0.0]], None, None, MECH_STATE_NAMES, ("i",), ("y",))
    return sys if dt is None else discretize(sys, dt)


def linearize(p: LevitatorParameters, y0: float, *, dt: float | None = None) -> StateSpace:
    """Voltage-driven linear model ``du -> [dy, di]`` at gap ``y0`` (eqs. (LIN1)-(LIN2)).

    Returns the continuous model, or its ZOH sampling when ``dt`` is given.
    """
    i0, _ = equilibrium(p, y0)
    pole2 = 2.0 * p.g / (p.a + y0)
    b = 2.0 * p.g / i0
    L0 = float(p.inductance(y0))
    dL = float(p.inductance_gradient(y0))
    A = np.array(
        [
            [0.0, 1.0, 0.0],
            [pole2, 0.0, -b],  # eq. (LIN1)
            [0.0, -i0 * dL / L0, -p.R / L0],  # eq. (LIN2)
        ]
    )
    B = np.array([[0.0], [0.0], [p.ku / L0]])
    C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    sys = StateSpace(A, B, C, None, None, STATE_NAMES, ("u",), ("y", "i"))
    return sys if dt is None else discretize(sys, dt)


def mechanical_from_pole(
    pole: float, gain: float, y0: float, *, m: float = 0.018, g: float = 9.81
) -> dict[str, float]:
    """Invert (LIN1) and (Q1): ``a``, ``i0`` and ``k`` from the pole and the current gain.

    ``a = 2 g / p^2 - y0``, ``i0 = 2 g / b``, ``k = 2 m g (a + y0)^2 / (a i0^2)``.
    ``a`` includes any offset of the gap sensor (only ``a + y`` enters the force).
    A negative ``a`` is returned as is (it says the sensor offset or the force law
    is off), never clipped; ``k`` is then NaN.
    """
    pole = check_positive(pole, "pole")
    gain = check_positive(gain, "gain")
    a = 2.0 * g / pole**2 - y0
    i0 = 2.0 * g / gain
    k = 2.0 * m * g * (a + y0) ** 2 / (a * i0**2) if a > 0 else float("nan")
    return {"a": a, "i0": i0, "k": k}


def levitator_rhs(p: LevitatorParameters, state: Any, u: float) -> np.ndarray:
    """Right-hand side of (M1)-(E1) for the state ``[y, dy, i]`` and command ``u``."""
    y, v, i = state
    L = p.k0 + p.k / (1.0 + y / p.a)  # eq. (L1)
    dL = -p.k * p.a / (p.a + y) ** 2  # eq. (L2)
    F = p.k * p.a * i * i / (2.0 * (p.a + y) ** 2)  # eq. (F1)
    return np.array([v, p.g - F / p.m, (p.ku * u - p.v0 - p.R * i - i * dL * v) / L])


def integrate_zoh(
    p: LevitatorParameters,
    state: Any,
    u: float,
    dt: float,
    *,
    substeps: int = 8,
    gap_limits: tuple[float, float] | None = None,
) -> np.ndarray:
    """State after holding the command ``u`` for ``dt`` seconds (classical RK4).

    ``gap_limits=(y_min, y_max)`` models the mechanical stops (the magnet face and
    the bottom rest): the gap is clamped and the velocity set to zero on contact.
    Eight RK4 substeps at ``dt = 10 ms`` keep the error far below the 49 um
    quantisation of the rig's gap sensor (the fastest pole is ~60 rad/s).
    """
    if substeps < 1:
        raise ModelError(f"`substeps` must be >= 1; got {substeps}")
    x = np.asarray(state, dtype=float).copy()
    h = dt / substeps
    for _ in range(substeps):
        k1 = levitator_rhs(p, x, u)
        k2 = levitator_rhs(p, x + 0.5 * h * k1, u)
        k3 = levitator_rhs(p, x + 0.5 * h * k2, u)
        k4 = levitator_rhs(p, x + h * k3, u)
        x = x + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
        if gap_limits is not None:
            lo, hi = gap_limits
            if x[0] <= lo:
                x[0], x[1] = lo, max(x[1], 0.0)
            elif x[0] >= hi:
                x[0], x[1] = hi, min(x[1], 0.0)
        x[2] = max(x[2], 0.0)  # the driver cannot reverse the current
    return x
