"""Discrete PID-type controllers ``D(z^-1)/C(z^-1)`` and their loop margins (Sun et al., Fig. 1).

The controller acts on the error ``e = r - y`` at the control period ``dt``::

    C(q^-1) u(m) = D(q^-1) e(m),   D = d0 + d1 z^-1 + d2 z^-2,   C = 1 + c1 z^-1   (eq. (1b))

A PID in velocity form has ``C = 1 - z^-1`` and::

    d0 = Kp + Ki + Kd,   d1 = -Kp - 2 Kd,   d2 = Kd

(``u(m) - u(m-1) = Kp (e(m) - e(m-1)) + Ki e(m) + Kd (e(m) - 2 e(m-1) + e(m-2))``).

With the plant ``B/A`` the closed-loop characteristic polynomial is
``Gamma = C A + D B`` (Section 4.4).

**The printed controller of Section 5 does not stabilise the printed plant (28)**:
``C A + D B`` has a root at 1.1127 (tested). Worse, no PID does well on this
plant: the voltage-driven suspension has relative degree 3 and an electrical
pole at -40.6/s, so a PID (one net lead) leaves at best a peak sensitivity of
18.6 (phase margin ~3 deg, gain margins -0.4/+2 dB). :data:`RETUNED_PID` is
that best PID. :data:`RETUNED_LEAD_LAG` keeps the PID's orders (``n_d = 2``,
``n_c = 1``, so the identifiability condition (2) fails exactly as in the
paper) but moves the pole from ``z = 1`` to ``z = c``; it reaches a peak
sensitivity of 2.5. See ``docs/sun.md``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import optimize

from maglevid._validation import check_positive
from maglevid.exceptions import DataError, DesignError

__all__ = [
    "PAPER_PID",
    "RETUNED_LEAD_LAG",
    "RETUNED_PID",
    "DiscreteController",
    "LoopMargins",
    "closed_loop_poles",
    "closed_loop_polynomial",
    "loop_margins",
    "noise_gain",
    "tune_controller",
]

log = logging.getLogger(__name__)

KINDS = ("pid", "lead-lag", "transfer-function")


def _poly(x: Any, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.ndim != 1 or a.size == 0:
        raise DataError(f"`{name}` must be a non-empty 1-D coefficient list; got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise DataError(f"`{name}` has non-finite coefficients: {a.tolist()}")
    a = a.copy()
    a.setflags(write=False)
    return a


def _padd(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Sum of two polynomials in ``z^-1`` (ascending powers)."""
    n = max(x.size, y.size)
    out = np.zeros(n)
    out[: x.size] += x
    out[: y.size] += y
    return out


@dataclass(frozen=True, eq=False)
class DiscreteController:
    """A SISO discrete controller ``u = D(z^-1)/C(z^-1) e``, ``e = r - y`` (eq. (1b)).

    Parameters
    ----------
    num : sequence of float
        ``d0, d1, ...`` (ascending powers of ``z^-1``).
    den : sequence of float
        ``1, c1, ...``; ``den[0]`` must be 1 (a causal controller).
    dt : float
        Control period [s].
    kind : {"pid", "lead-lag", "transfer-function"}
        What the coefficients describe (recorded in ``loop["controller"]["type"]``).

    Examples
    --------
    >>> c = DiscreteController.pid(Kp=2.0, Ki=0.5, Kd=1.0, dt=0.01)
    >>> c.num.tolist(), c.den.tolist()
    ([3.5, -4.0, 1.0], [1.0, -1.0])
    >>> c.gains
    (2.0, 0.5, 1.0)
    """

    num: np.ndarray
    den: np.ndarray
    dt: float
    kind: str = "transfer-function"

    def __post_init__(self) -> None:
        num = _poly(self.num, "num")
        den = _poly(self.den, "den")
        if den[0] != 1.0:
            raise DataError(f"`den[0]` must be 1 (normalised, causal); got {den[0]!r}")
        if self.kind not in KINDS:
            raise DataError(f"`kind` must be one of {KINDS}; got {self.kind!r}")
        object.__setattr__(self, "num", num)
        object.__setattr__(self, "den", den)
        object.__setattr__(self, "dt", check_positive(self.dt, "dt"))

    @classmethod
    def pid(cls, *, Kp: float, Ki: float, Kd: float, dt: float) -> DiscreteController:
        """Velocity-form PID: ``D = (Kp+Ki+Kd) - (Kp+2Kd) z^-1 + Kd z^-2``, ``C = 1 - z^-1``."""
        return cls([Kp + Ki + Kd, -Kp - 2 * Kd, Kd], [1.0, -1.0], dt, "pid")

    @property
    def gains(self) -> tuple[float, float, float]:
        """``(Kp, Ki, Kd)`` of a velocity-form PID (raises for other structures)."""
        if self.den.size != 2 or self.den[1] != -1.0 or self.num.size != 3:
            raise DesignError("gains() needs a PID: den = [1, -1] and three numerator terms")
        d0, d1, d2 = self.num
        Kd = d2
        Kp = -d1 - 2 * Kd
        return (float(Kp), float(d0 - Kp - Kd), float(Kd))

    @property
    def orders(self) -> tuple[int, int]:
        """``(n_d, n_c)``: degrees of ``D`` and ``C`` (they enter condition (2))."""
        return self.num.size - 1, self.den.size - 1

    def frequency_response(self, omega: Any) -> np.ndarray:
        """``D/C`` at ``z = exp(j omega dt)``; ``omega`` in rad/s."""
        z1 = np.exp(-1j * np.atleast_1d(np.asarray(omega, dtype=float)) * self.dt)
        return np.polyval(self.num[::-1], z1) / np.polyval(self.den[::-1], z1)

    def to_dict(self) -> dict[str, Any]:
        """JSON-safe ``{"type", "num", "den", "dt"}`` (the ``loop["controller"]`` entry)."""
        return {
            "type": self.kind,
            "num": self.num.tolist(),
            "den": self.den.tolist(),
            "dt": self.dt,
        }

    @classmethod
    def from_dict(cls, d: Any) -> DiscreteController:
        return cls(np.asarray(d["num"]), np.asarray(d["den"]), d["dt"], d.get("type", KINDS[-1]))

    def __repr__(self) -> str:
        return (
            f"DiscreteController({self.kind}, num={np.round(self.num, 6).tolist()}, "
            f"den={np.round(self.den, 6).tolist()}, dt={self.dt:g})"
        )


#: The controller printed in Section 5 (T = 2.4 ms). It does NOT stabilise (28).
PAPER_PID = DiscreteController([-0.5973e5, 1.1897e5, -0.5833e5], [1.0, -1.0], 2.4e-3, "pid")

#: The PID with the smallest peak sensitivity on the nominal plant (18.8; phase margin
#: 3.2 deg, stable for gains x0.95 .. x1.26), from ``tune_controller(a, b, 2.4e-3,
#: kind="pid", max_noise_gain=1e5)`` with the nominal (a, b) of eq. (28).
RETUNED_PID = DiscreteController(
    [-65439.37061043250, 129463.5452243798, -64024.20464773691], [1.0, -1.0], 2.4e-3, "pid"
)

#: Same orders as the PID (n_d = 2, n_c = 1), pole at z = 0.744 instead of 1: peak
#: sensitivity 2.21, phase margin 27 deg, gain margin +12.7 dB, noise gain 3e5 V/m,
#: from ``tune_controller(a, b, 2.4e-3, kind="lead-lag", max_noise_gain=3e5)``.
RETUNED_LEAD_LAG = DiscreteController(
    [-196041.4120160208, 371254.1828432992, -175725.8172434624],
    [1.0, -0.744013842422639],
    2.4e-3,
    "lead-lag",
)


def closed_loop_polynomial(controller: DiscreteController, a: Any, b: Any) -> np.ndarray:
    """``Gamma(z^-1) = C A + D B`` (Section 4.4), ascending powers of ``z^-1``."""
    a = _poly(a, "a")
    b = _poly(b, "b")
    return _padd(np.convolve(controller.den, a), np.convolve(controller.num, b))


def closed_loop_poles(controller: DiscreteController, a: Any, b: Any) -> np.ndarray:
    """Roots of ``z^n Gamma(z^-1)``: the closed-loop poles (stable iff all inside |z| = 1)."""
    g = np.trim_zeros(closed_loop_polynomial(controller, a, b), "b")
    return np.roots(g)


def noise_gain(controller: DiscreteController, a: Any, b: Any) -> float:
    """RMS of ``u`` per unit RMS of white noise on the measured output (``||D A/Gamma||_2``).

    With ``r = 0`` and ``y_meas = y + w``, ``u = -D A / Gamma w`` (eq. (16)). The
    H2 norm is computed from a discrete Lyapunov equation (exact, no truncation).
    """
    a = _poly(a, "a")
    b = _poly(b, "b")
    g = closed_loop_polynomial(controller, a, b)
    if np.max(np.abs(closed_loop_poles(controller, a, b)), initial=0.0) >= 1:
        return float("inf")
    # sum of the squared impulse response of D A / Gamma, long enough for the
    # slowest closed-loop pole to decay by 1e-12 (a Lyapunov solve is
    # ill-conditioned for poles this close to the unit circle).
    rmax = float(np.max(np.abs(closed_loop_poles(controller, a, b)), initial=0.0))
    n = int(min(5e6, max(100.0, np.log(1e-12) / np.log(max(rmax, 1e-3)))))
    impulse = np.zeros(n)
    impulse[0] = 1.0
    from scipy import signal  # ~1 s to import: only where it is used

    h = signal.lfilter(np.convolve(controller.num, a), g, impulse)
    return float(np.sqrt(np.dot(h, h)))


@dataclass(frozen=True)
class LoopMargins:
    """Stability margins of the loop ``L = (D/C)(B/A)``.

    Attributes
    ----------
    stable : bool
        All closed-loop poles inside the unit circle.
    peak_sensitivity : float
        ``max |1/(1 + L)|`` (the modulus margin is its inverse).
    phase_margin_deg : float
        Smallest ``180 + arg L`` over the gain crossovers (degrees).
    crossover_rad_s : float
        Frequency of that crossover.
    gain_margin_lower, gain_margin_upper : float
        The loop stays stable for gains ``k L`` with ``lower < k < upper``
        (NaN when the loop is unstable at ``k = 1``).
    """

    stable: bool
    peak_sensitivity: float
    phase_margin_deg: float
    crossover_rad_s: float
    gain_margin_lower: float
    gain_margin_upper: float

    @property
    def modulus_margin(self) -> float:
        return 1.0 / self.peak_sensitivity

    def to_dict(self) -> dict[str, float | bool]:
        return {
            "stable": self.stable,
            "peak_sensitivity": self.peak_sensitivity,
            "modulus_margin": self.modulus_margin,
            "phase_margin_deg": self.phase_margin_deg,
            "crossover_rad_s": self.crossover_rad_s,
            "gain_margin_lower": self.gain_margin_lower,
            "gain_margin_upper": self.gain_margin_upper,
        }


def _loop(controller: DiscreteController, a: np.ndarray, b: np.ndarray, w: np.ndarray):
    z1 = np.exp(-1j * w)
    return (
        np.polyval(controller.num[::-1], z1)
        * np.polyval(b[::-1], z1)
        / (np.polyval(controller.den[::-1], z1) * np.polyval(a[::-1], z1))
    )


def loop_margins(
    controller: DiscreteController, a: Any, b: Any, *, n_grid: int = 20000
) -> LoopMargins:
    """Peak sensitivity, phase margin and the gain-margin interval of the loop.

    The frequency grid (``n_grid`` points on ``(0, pi/dt]``, logarithmic) is
    refined at each crossing with :func:`scipy.optimize.brentq`. For an
    open-loop unstable plant the gain margin is an interval: the loop is stable
    only between the gains ``k = -1/L(e^{jw})`` where ``L`` crosses the negative
    real axis, next below and above 1.
    """
    a = _poly(a, "a")
    b = _poly(b, "b")
    dt = controller.dt
    poles = closed_loop_poles(controller, a, b)
    stable = bool(np.all(np.abs(poles) < 1))
    w = np.pi * np.logspace(-6, 0, n_grid)  # rad/sample
    L = _loop(controller, a, b, w)
    Ms = float(np.max(np.abs(1.0 / (1.0 + L))))

    def refine(f, i):
        try:
            return optimize.brentq(f, w[i], w[i + 1], xtol=1e-14)
        except ValueError:  # pragma: no cover - sign change lost to rounding
            return w[i]

    # gain crossovers |L| = 1
    g = np.abs(L) - 1.0
    pm, wc = float("inf"), float("nan")
    for i in np.nonzero(np.sign(g[:-1]) * np.sign(g[1:]) < 0)[0]:
        wi = refine(lambda x: abs(_loop(controller, a, b, np.array([x]))[0]) - 1.0, i)
        Li = _loop(controller, a, b, np.array([wi]))[0]
        m = (np.degrees(np.angle(Li)) + 180.0 + 180.0) % 360.0 - 180.0
        if abs(m) < abs(pm):
            pm, wc = float(m), wi / dt
    # phase crossovers: Im L = 0 with Re L < 0 -> k = -1/L
    ks = []
    im = L.imag
    for i in np.nonzero(np.sign(im[:-1]) * np.sign(im[1:]) < 0)[0]:
        wi = refine(lambda x: _loop(controller, a, b, np.array([x]))[0].imag, i)
        Li = _loop(controller, a, b, np.array([wi]))[0]
        if Li.real < 0:
            ks.append(-1.0 / Li.real)
    for edge in (0.0, np.pi):  # L is real at z = 1 and z = -1 (unless C has a root there)
        with np.errstate(divide="ignore", invalid="ignore"):
            Le = _loop(controller, a, b, np.array([edge]))[0]
        if np.isfinite(Le) and Le.real < 0:
            ks.append(-1.0 / Le.real)
    ks_arr = np.array(ks)
    lower = float(np.max(ks_arr[ks_arr < 1], initial=0.0)) if stable else float("nan")
    upper = float(np.min(ks_arr[ks_arr > 1], initial=np.inf)) if stable else float("nan")
    return LoopMargins(stable, Ms, pm, wc, lower, upper)


def tune_controller(
    a: Any,
    b: Any,
    dt: float,
    *,
    kind: str = "lead-lag",
    max_noise_gain: float,
    seed: int = 0,
    n_grid: int = 3000,
    maxiter: int = 300,
) -> DiscreteController:
    """Smallest peak sensitivity for a controller of the printed orders (``n_d = 2``, ``n_c = 1``).

    Minimises ``max |S|`` over ``D = -K (1 + e1 z^-1 + e2 z^-2)`` (and the pole
    ``c`` of ``C = 1 - c z^-1`` for ``kind="lead-lag"``; ``c = 1`` for a PID)
    subject to ``noise_gain <= max_noise_gain`` (``u`` RMS per metre RMS of
    output noise; a penalty), by differential evolution (seeded: deterministic;
    ``maxiter`` generations) polished with Nelder-Mead. About a minute for the
    suspension with the defaults.

    Raises
    ------
    DesignError
        If no stabilising controller within the noise budget is found.
    """
    if kind not in ("pid", "lead-lag"):
        raise DataError(f"`kind` must be 'pid' or 'lead-lag'; got {kind!r}")
    a = _poly(a, "a")
    b = _poly(b, "b")
    dt = check_positive(dt, "dt")
    max_noise_gain = check_positive(max_noise_gain, "max_noise_gain")
    w = np.pi * np.logspace(-4, 0, n_grid)
    sign = np.sign(b[np.nonzero(b)[0][0]])  # D of the sign of B: negative feedback

    def build(x: np.ndarray) -> DiscreteController:
        K = np.exp(x[0])
        c = 1.0 if kind == "pid" else x[3]
        return DiscreteController(sign * K * np.array([1.0, x[1], x[2]]), [1.0, -c], dt, kind)

    def cost(x: np.ndarray) -> float:
        ctl = build(x)
        rmax = np.max(np.abs(closed_loop_poles(ctl, a, b)), initial=0.0)
        if rmax >= 0.9995:
            return 1e3 + 1e3 * rmax
        Ms = np.max(np.abs(1.0 / (1.0 + _loop(ctl, a, b, w))))
        excess = noise_gain(ctl, a, b) / max_noise_gain - 1.0
        return float(Ms + 100.0 * max(excess, 0.0))

    # Global stage over two real zeros z_i = exp(-sigma_i dt), sigma_i in rad/s (the
    # stabilising region is a thin sliver in (e1, e2) near (-2, 1)); local stage in
    # (e1, e2), where the zeros may also become complex.
    def from_zeros(y: np.ndarray) -> np.ndarray:
        z1, z2 = np.exp(-y[1] * dt), np.exp(-y[2] * dt)
        return np.r_[y[0], -(z1 + z2), z1 * z2, y[3:]]

    nyq = np.pi / dt
    bounds = [
        (np.log(max_noise_gain * 1e-3), np.log(max_noise_gain * 10)),
        (-0.05 * nyq, 0.5 * nyq),
        (-0.05 * nyq, 0.5 * nyq),
    ]
    if kind == "lead-lag":
        bounds.append((-0.95, 0.999))
    res = optimize.differential_evolution(
        lambda y: cost(from_zeros(y)),
        bounds,
        seed=seed,
        tol=1e-10,
        maxiter=maxiter,
        popsize=20,
        polish=False,
    )
    res = optimize.minimize(
        cost,
        from_zeros(res.x),
        method="Nelder-Mead",
        options={"xatol": 1e-10, "fatol": 1e-10, "maxiter": 4000},
    )
    if res.fun >= 1e3:
        raise DesignError(
            f"no stabilising {kind} controller found within noise gain {max_noise_gain:g}"
        )
    ctl = build(res.x)
    log.info(
        "tuned %s: peak sensitivity %.3g, noise gain %.3g", kind, res.fun, noise_gain(ctl, a, b)
    )
    return ctl
