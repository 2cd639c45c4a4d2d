"""Closed-loop simulation of the voltage-controlled AMB (Gosiewski & Paszowski, Figs. 1-2).

:func:`simulate_amb_loop` is the public entry point; it is also the ``amb``
scenario of ``maglevid simulate`` (:data:`SCENARIO`, :func:`add_scenario_arguments`,
:func:`run_scenario`).

Signals (deviations from the nominal operating point, what the controller sees):

* ``y = [x, i1 - i0, i2 - i0] + noise`` [m, A, A], sampled at ``t = k dt``;
* ``u = u_f + r`` [V], the amplifier inputs *on top of* the bias voltages
  ``u_bias_j = R_j i0 / kw_j`` of the nominal bearing, held over one period;
* ``r`` the excitation, ``u_f`` the feedback (eq. (42)).

Two plant models:

* ``"linear"``: the ZOH-sampled linearisation of eqs. (3)-(4) of the real
  (possibly faulty) bearing, at ``x = 0, i1 = i2 = i0`` -- the paper's
  simulation; the true discrete model is exactly ``amb_state_space(plant, dt)``.
* ``"nonlinear"`` (default, the realistic bearing): eq. (1) with absolute
  currents under the *nominal* bias voltages, a white force disturbance on the
  rotor (:data:`DEFAULT_FORCE_STD`), integrated between samples under the
  zero-order hold by fixed-step RK4. A fault moves the equilibrium
  (e.g. a weaker coil needs more current); the integral action brings the rotor
  back to ``x = 0`` and the simulation starts at the loop's equilibrium (found
  by :func:`~maglevid.physics.amb.settled_operating_point`), so the record has
  no start-up transient; a loop unstable around that point is refused.
  The true linear model is then the linearisation at *that* point, recorded in
  ``metadata["operating_point_true"]``.

The default controller and observer are designed on the *nominal* bearing
(:func:`default_amb_controller`, :func:`default_amb_observer`), as in a real
diagnostic setting where the fault is unknown.
"""

from __future__ import annotations

import argparse
import inspect
import logging
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np

from maglevid._validation import check_positive
from maglevid.control import (
    IntegralStateFeedback,
    Observer,
    check_loop_matrix,
    design_deadbeat_observer,
    design_pole_placement,
    loop_matrix,
    loop_matrix_condition,
)
from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError, DesignError, ModelError
from maglevid.lti import StateSpace
from maglevid.physics.amb import (
    C_AMB,
    INPUT_NAMES,
    OUTPUT_NAMES,
    AMBParameters,
    OperatingPoint,
    amb_matrices,
    amb_state_space,
    bias_voltages,
    linearized_v,
    settled_operating_point,
)
from maglevid.simulate._amb_batch import simulate_nonlinear_batch
from maglevid.simulate._faults import check_faults, parse_fault
from maglevid.simulate.excitation import EXCITATION_KINDS, make_excitation
from maglevid.simulate.loop import closed_loop_system, simulate_linear_loop

__all__ = [
    "DEFAULT_DT",
    "DEFAULT_EXCITATION_STD",
    "DEFAULT_FORCE_STD",
    "DEFAULT_NOISE_STD",
    "DEFAULT_N_SAMPLES",
    "DEFAULT_POLES_S",
    "DEFAULT_SUBSTEPS",
    "OBSERVER_MODELS",
    "PLANT_MODELS",
    "SCENARIO",
    "SCENARIO_HELP",
    "SENSOR_GAINS",
    "add_scenario_arguments",
    "default_amb_controller",
    "default_amb_observer",
    "linearized_v",
    "nonlinear_equilibrium",
    "parse_fault",
    "run_scenario",
    "simulate_amb_loop",
    "simulate_amb_loops",
]

logger = logging.getLogger(__name__)

#: Control period [s]: 10 kHz, a usual AMB controller rate. The open-loop unstable
#: pole of the nominal bearing is at 455 rad/s (z = exp(0.0455)); the fastest
#: default closed-loop pole, 800 rad/s, is 0.08 rad per sample.
DEFAULT_DT = 1e-4

#: Record length (2 s at the default dt).
DEFAULT_N_SAMPLES = 20_000

#: Excitation standard deviation per amplifier input [V]. With the default
#: design it moves the rotor by ~1.1 um rms (0.3 % of the 350 um gap) and the
#: coil currents by ~2 mA rms (0.4 % of the bias): well inside the linear range
#: and well above the default noise.
DEFAULT_EXCITATION_STD = 1.0

#: Measurement noise standard deviations of ``[x, i1, i2]`` [m, A, A]: 0.1 um
#: (a good eddy-current displacement sensor: dynamic resolution ~0.01 % of a
#: 1 mm range at 10 kHz bandwidth) and 0.1 mA (a Hall-effect or shunt current
#: sensor read by a 16-bit converter over +-3 A: 1 LSB = 0.09 mA; Hall sensors
#: of that range are specified at 0.1-0.5 mA rms noise). See
#: ``docs/control-and-simulation.md``.
DEFAULT_NOISE_STD = (1e-7, 1e-4, 1e-4)

#: Standard deviation of the broadband force disturbance on the rotor [N],
#: white and held over each control period (nonlinear plant): 0.1 N, 0.6 % of
#: the rotor's weight and about a tenth of the force the default excitation
#: makes (``ki`` 490 N/A x ~2 mA rms); of the order of the unmodelled
#: aerodynamic, coupling and base-vibration forces on a small rotor.
DEFAULT_FORCE_STD = 0.1

#: s-plane poles [rad/s] of the default pole placement on the extended model
#: (eq. (41)): five real poles. The design is deliberately *not* mirror-symmetric
#: (see :func:`default_amb_controller`).
DEFAULT_POLES_S = (-400.0, -600.0, -800.0, -100.0, -30.0)

#: RK4 steps per control period of the nonlinear plant. The fastest open-loop
#: pole (455 rad/s) gives h|lambda| = 0.011 per step, local error ~1e-12 relative.
DEFAULT_SUBSTEPS = 4

#: Plant models :func:`simulate_amb_loop` accepts.
PLANT_MODELS = ("linear", "nonlinear")

#: Whose A, B the observer of eq. (43) runs on (its gain G is always designed
#: on the nominal bearing): ``"nominal"`` (a real controller) or ``"plant"``
#: (the real bearing's ZOH model -- how the paper's examples are reproduced).
OBSERVER_MODELS = ("nominal", "plant")

#: Sensor-gain faults (the names of the diagnosis hypotheses,
#: :data:`maglevid.diagnose.isolate.HYPOTHESES`): the displacement sensor and the
#: two current sensors. A gain ``g`` multiplies the measured deviation
#: (``y_j = g_j y_true_j + noise``); the controller sees the measured signal.
SENSOR_GAINS = ("gx", "gi1", "gi2")

#: Largest accepted unit-free loop-matrix condition for the default design.
_DEFAULT_DESIGN_MAX_CONDITION = 1e3


# ---------------------------------------------------------------------------
# Default designs
# ---------------------------------------------------------------------------
def default_amb_controller(
    nominal: AMBParameters, dt: float, *, poles_s: Sequence[float] = DEFAULT_POLES_S
) -> IntegralStateFeedback:
    """Default state feedback with integral action on the displacement.

    Pole placement (``scipy.signal.place_poles``, YT) on the extended model of
    eq. (41) built from the ZOH-sampled nominal bearing, ``E = [[1, 0, 0]]``,
    closed-loop poles ``exp(poles_s dt)``.

    Why this design: the identification (eqs. (44)-(51)) needs the loop matrix
    ``[[C, 0], [-F, F_e]]`` invertible. A mirror-symmetric controller -- what LQR
    with mirror-symmetric weights produces for the symmetric nominal bearing --
    makes it singular (``u_f1 + u_f2`` then depends on the common-mode current
    only); LQR with unequal input weights leaves it ill-conditioned (~1e5, the
    two coils' gains stay nearly proportional). Pole placement with real,
    distinct poles lets ``place_poles`` choose the eigenvectors for robustness,
    which for this model gives clearly different velocity/integral gains on the
    two coils: the unit-free condition number is ~5. The design is checked
    (:func:`~maglevid.control.check_loop_matrix`, limit 1e3) and the condition
    number is stored in ``info["loop_matrix_condition"]``.

    With the deadbeat observer on the nominal model the loop stays stable for a
    real bearing with any one of ``R1``, ``R2``, ``Ls1`` in (0, 3x), ``kw1 >= 0.17x``,
    ``K1`` in (0, 2.4x), ``m >= 0.11x``, ``x0 >= 0.956x``, ``i0 <= 1.046x``
    (the air gap and bias, which set the negative stiffness, are the sensitive ones).
    """
    sys = amb_state_space(nominal, dt)
    poles_s = np.asarray(poles_s, dtype=complex)
    ctrl = design_pole_placement(sys, poles=np.exp(poles_s * dt))
    cond = check_loop_matrix(sys.C, ctrl.F, ctrl.Fe, max_condition=_DEFAULT_DESIGN_MAX_CONDITION)
    info = dict(ctrl.info)
    info.update(
        {
            "poles_s": [[float(p.real), float(p.imag)] for p in poles_s],
            "loop_matrix_condition": cond,
            "loop_matrix_condition_raw": float(
                np.linalg.cond(loop_matrix(sys.C, ctrl.F, ctrl.Fe))
            ),
            "designed_on": "nominal",
        }
    )
    return IntegralStateFeedback(ctrl.F, ctrl.Fe, ctrl.E, ctrl.method, info)


def default_amb_observer(nominal: AMBParameters, dt: float) -> Observer:
    """Deadbeat observer (2 steps) on the ZOH-sampled nominal bearing."""
    return design_deadbeat_observer(amb_state_space(nominal, dt))


# ---------------------------------------------------------------------------
# Nonlinear plant
# ---------------------------------------------------------------------------
def nonlinear_equilibrium(
    plant: AMBParameters,
    nominal: AMBParameters,
    observer: Observer,
    controller: IntegralStateFeedback,
) -> dict[str, Any]:
    """Rest point of the nonlinear loop (no excitation, no noise).

    :func:`~maglevid.physics.amb.settled_operating_point` with this observer and
    controller and the nominal bearing's bias inputs, as a dict (``x``, ``I1``,
    ``I2``, ``y``, ``u_f``, ``x_hat``, ``e``, ``v`` and the rest of
    :class:`~maglevid.physics.amb.OperatingPoint`).

    Raises
    ------
    ModelError
        When no rest point is found (the fault is beyond what the integral
        action can compensate).
    """
    loop = {"controller": controller.to_dict(), "observer": observer.to_dict()}
    return asdict(settled_operating_point(plant, nominal, loop))


def _rk4_stepper(p: AMBParameters, h: float) -> Callable[..., tuple[float, float, float, float]]:
    """One RK4 step of eq. (1) under a constant input, on Python floats.

    The four stages are written out (no inner function calls): the step runs
    ``substeps`` times per sample inside a Python loop, where call overhead and
    small-array numpy calls would dominate. Same equations as
    :func:`maglevid.physics.amb.amb_nonlinear_rhs` (tested against it).
    """
    x0, m = p.x0, p.m
    q1, q2 = p.K1 / 4.0, p.K2 / 4.0  # force constants
    h1, h2 = p.K1 / 2.0, p.K2 / 2.0  # flux constants K_j / 2
    R1, R2, Ls1, Ls2, kw1, kw2 = p.R1, p.R2, p.Ls1, p.Ls2, p.kw1, p.kw2
    hh, h6 = 0.5 * h, h / 6.0

    def step(
        x: float, dx: float, I1: float, I2: float, u1: float, u2: float, fz: float = 0.0
    ) -> tuple[float, float, float, float]:
        # eq. (1): m x'' = K1/4 (I1/g1)^2 - K2/4 (I2/g2)^2 + F_z,
        # (Ls_j + K_j/(2 g_j)) I_j' = kw_j u_j - R_j I_j -+ K_j I_j x' / (2 g_j^2)
        a1 = kw1 * u1
        a2 = kw2 * u2
        # stage 1
        g1 = x0 - x
        g2 = x0 + x
        f1 = I1 / g1
        f2 = I2 / g2
        k1x = dx
        k1v = (q1 * f1 * f1 - q2 * f2 * f2 + fz) / m
        k1a = (a1 - R1 * I1 - h1 * f1 * dx / g1) / (Ls1 + h1 / g1)
        k1b = (a2 - R2 * I2 + h2 * f2 * dx / g2) / (Ls2 + h2 / g2)
        # stage 2
        xs, vs, i1s, i2s = x + hh * k1x, dx + hh * k1v, I1 + hh * k1a, I2 + hh * k1b
        g1 = x0 - xs
        g2 = x0 + xs
        f1 = i1s / g1
        f2 = i2s / g2
        k2x = vs
        k2v = (q1 * f1 * f1 - q2 * f2 * f2 + fz) / m
        k2a = (a1 - R1 * i1s - h1 * f1 * vs / g1) / (Ls1 + h1 / g1)
        k2b = (a2 - R2 * i2s + h2 * f2 * vs / g2) / (Ls2 + h2 / g2)
        # stage 3
        xs, vs, i1s, i2s = x + hh * k2x, dx + hh * k2v, I1 + hh * k2a, I2 + hh * k2b
        g1 = x0 - xs
        g2 = x0 + xs
        f1 = i1s / g1
        f2 = i2s / g2
        k3x = vs
        k3v = (q1 * f1 * f1 - q2 * f2 * f2 + fz) / m
        k3a = (a1 - R1 * i1s - h1 * f1 * vs / g1) / (Ls1 + h1 / g1)
        k3b = (a2 - R2 * i2s + h2 * f2 * vs / g2) / (Ls2 + h2 / g2)
        # stage 4
        xs, vs, i1s, i2s = x + h * k3x, dx + h * k3v, I1 + h * k3a, I2 + h * k3b
        g1 = x0 - xs
        g2 = x0 + xs
        f1 = i1s / g1
        f2 = i2s / g2
        k4v = (q1 * f1 * f1 - q2 * f2 * f2 + fz) / m
        k4a = (a1 - R1 * i1s - h1 * f1 * vs / g1) / (Ls1 + h1 / g1)
        k4b = (a2 - R2 * i2s + h2 * f2 * vs / g2) / (Ls2 + h2 / g2)
        return (
            x + h6 * (k1x + 2.0 * k2x + 2.0 * k3x + vs),
            dx + h6 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v),
            I1 + h6 * (k1a + 2.0 * k2a + 2.0 * k3a + k4a),
            I2 + h6 * (k1b + 2.0 * k2b + 2.0 * k3b + k4b),
        )

    return step


def _loop_product(observer: Observer, controller: IntegralStateFeedback) -> np.ndarray:
    """The observer and controller of one sample as one matrix ``M``.

    With ``q = [x̂(k); e(k-1); y(k); r(k)]``::

        e(k)    = e(k-1) - E y(k)                                        eq. (39)/(43)
        u_f(k)  = -F x̂ + F_e e(k-1) - F_e E y(k)                         eq. (42)
        x̂(k+1) = (Abar - B F) x̂ + B F_e e(k-1) - (B F_e E + G) y + B r   eq. (43)

    and ``[x̂(k+1); e(k); u_f(k)] = M q``.
    """
    Abar, Bo, G = observer.A_bar, observer.B, observer.G
    F, Fe, E = controller.F, controller.Fe, controller.E
    nx, ne = Abar.shape[0], E.shape[0]
    Z = np.zeros
    return np.block(
        [
            [Abar - Bo @ F, Bo @ Fe, -Bo @ Fe @ E - G, Bo],
            [Z((ne, nx)), np.eye(ne), -E, Z((ne, 2))],
            [-F, Fe, -Fe @ E, Z((2, 2))],
        ]
    )


def _first_state(
    eq: dict[str, Any],
    controller: IntegralStateFeedback,
    i0: float,
    gains: Sequence[float],
    v0: np.ndarray,
) -> np.ndarray:
    """``[x̂(0); e(-1)]`` at the rest point ``eq``: ``e(-1) := e(0) + E y(0)`` gives ``e(0)``."""
    gx, gi1, gi2 = (float(g) for g in gains)
    x, I1, I2 = float(eq["x"]), float(eq["I1"]), float(eq["I2"])
    y0 = np.array([gx * x, gi1 * (I1 - i0), gi2 * (I2 - i0)]) + v0
    return np.concatenate([eq["x_hat"], np.asarray(eq["e"]) + controller.E @ y0])


def _simulate_nonlinear(
    plant: AMBParameters,
    nominal: AMBParameters,
    observer: Observer,
    controller: IntegralStateFeedback,
    *,
    dt: float,
    r: np.ndarray,
    v: np.ndarray,
    substeps: int,
    eq: dict[str, Any],
    progress: Callable[[Iterable[int]], Iterable[int]] | None,
    force: np.ndarray | None = None,
    gains: Sequence[float] = (1.0, 1.0, 1.0),
) -> tuple[np.ndarray, np.ndarray]:
    """Sample-by-sample loop with eq. (1) integrated by RK4 under ZOH. Returns y, u_f.

    ``force`` (N,): external force on the rotor [N], held over each period.
    ``gains``: sensor gains on ``[x, i1 - i0, i2 - i0]`` (:data:`SENSOR_GAINS`).
    """
    gx, gi1, gi2 = (float(g) for g in gains)
    N = r.shape[0]
    i0, x0 = nominal.i0, plant.x0
    ub1, ub2 = (float(b) for b in bias_voltages(nominal))
    M = _loop_product(observer, controller)
    step = _rk4_stepper(plant, dt / substeps)
    Y = np.empty((N, 3))
    UF = np.empty((N, 2))
    x, dx, I1, I2 = float(eq["x"]), 0.0, float(eq["I1"]), float(eq["I2"])
    state = _first_state(eq, controller, nominal.i0, gains, v[0]).tolist()
    ns = observer.nx + controller.ne
    chunk = 2000
    starts: Iterable[int] = range(0, N, chunk)
    if progress is not None:
        starts = progress(starts)
    fzs = np.zeros(N) if force is None else np.asarray(force, float).reshape(N)
    # Python floats throughout the inner loop: numpy scalars are several times slower.
    for start in starts:
        stop = min(start + chunk, N)
        vl, rl, fl = v[start:stop].tolist(), r[start:stop].tolist(), fzs[start:stop].tolist()
        ys, ufs = [], []
        for j in range(stop - start):
            (v0, v1, v2), (r0, r1) = vl[j], rl[j]
            # y(k), measured at t = k dt, through the sensors' gains
            yk = [gx * x + v0, gi1 * (I1 - i0) + v1, gi2 * (I2 - i0) + v2]
            out = (M @ np.array(state + yk + rl[j])).tolist()
            state = out[:ns]  # x̂(k+1), and e(k) as next sample's e(k-1)
            uf1, uf2 = out[ns], out[ns + 1]
            ys.append(yk)
            ufs.append((uf1, uf2))
            u1, u2 = ub1 + uf1 + r0, ub2 + uf2 + r1  # eq. (16), on the bias voltage
            fz = fl[j]
            for _ in range(substeps):  # RK4 under zero-order hold
                x, dx, I1, I2 = step(x, dx, I1, I2, u1, u2, fz)
            if not (abs(x) < x0 and math.isfinite(I1) and math.isfinite(I2)):
                raise ModelError(
                    f"the rotor reached the pole face at sample {start + j + 1} (x = {x:.3g} m, "
                    f"gap {x0:.3g} m): the loop does not hold this bearing with this excitation"
                )
        Y[start:stop] = ys
        UF[start:stop] = ufs
    return Y, UF


# ---------------------------------------------------------------------------
# Public entry point
# ---------------------------------------------------------------------------
def _make_rng(rng: Any) -> tuple[np.random.Generator, int | None]:
    if isinstance(rng, np.random.Generator):
        return rng, None
    if rng is None:
        # A fresh 63-bit seed (fits every file format's integer), recorded in the metadata.
        seed = int(np.random.SeedSequence().generate_state(1, dtype=np.uint64)[0] >> 1)
        return np.random.default_rng(seed), seed
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool) and rng >= 0:
        return np.random.default_rng(int(rng)), int(rng)
    raise DataError(
        f"`rng` must be a numpy Generator, a non-negative int seed or None; got {rng!r}"
    )


def _check_settled_loop(
    eq: dict[str, Any],
    observer: Observer,
    controller: IntegralStateFeedback,
    dt: float,
    gains: Sequence[float] = (1.0, 1.0, 1.0),
) -> None:
    """DesignError when the loop is unstable around the settled point (it would diverge)."""
    lin = amb_state_space(np.asarray(eq["v"]), dt)
    lin = StateSpace(np.asarray(lin.A), np.asarray(lin.B), np.diag(gains) @ lin.C, dt=dt)
    rho = float(np.max(np.abs(closed_loop_system(lin, observer, controller).poles())))
    if rho >= 1.0:
        raise DesignError(
            f"the closed loop is unstable at the point this bearing settles at (I1 = "
            f"{eq['I1']:.4g} A, I2 = {eq['I2']:.4g} A; largest pole magnitude {rho:.6f}): the "
            "controller designed on the nominal bearing cannot hold it"
        )


def _force_std(force_std: Any, plant_model: str) -> float:
    if force_std is None:
        return DEFAULT_FORCE_STD if plant_model == "nonlinear" else 0.0
    f = float(force_std)
    if not (math.isfinite(f) and f >= 0):
        raise DataError(f"`force_std` must be a non-negative number [N]; got {force_std!r}")
    if f > 0 and plant_model != "nonlinear":
        raise DataError(
            "a force disturbance needs the nonlinear plant (plant_model='nonlinear'); the "
            "linear plant of eqs. (3)-(4) has no force input"
        )
    return f


def _unbalance(unbalance: Any, plant_model: str, dt: float) -> tuple[float, float] | None:
    """``(amplitude [N], frequency [Hz])`` checked, or None."""
    if unbalance is None:
        return None
    try:
        amp, hz = (float(x) for x in unbalance)
    except (TypeError, ValueError):
        raise DataError(
            f"`unbalance` must be (amplitude [N], frequency [Hz]); got {unbalance!r}"
        ) from None
    if not (math.isfinite(amp) and amp >= 0):
        raise DataError(f"`unbalance`: the amplitude must be a number >= 0 [N]; got {amp!r}")
    if not (math.isfinite(hz) and 0 < hz < 0.5 / dt):
        raise DataError(
            f"`unbalance`: the frequency must lie in (0, {0.5 / dt:g}) Hz, below the Nyquist "
            f"frequency of dt = {dt:g} s; got {hz!r}"
        )
    if plant_model != "nonlinear":
        raise DataError(
            "an unbalance force needs the nonlinear plant (plant_model='nonlinear'); the "
            "linear plant of eqs. (3)-(4) has no force input"
        )
    return amp, hz


def _linear_operating_point(
    plant: AMBParameters,
    nominal: AMBParameters,
    controller: IntegralStateFeedback,
    observer: Observer,
) -> dict[str, Any]:
    """The linear plant's operating point: ``x = 0, i = i0``, ``v = plant.v()``."""
    Ac, Bc = amb_matrices(plant)
    zero2 = np.zeros(2)
    ub = bias_voltages(nominal)
    return OperatingPoint(
        x=0.0, I1=plant.i0, I2=plant.i0, U1=plant.R1 * plant.i0, U2=plant.R2 * plant.i0,
        u=ub, u_bias=ub, u_f=zero2, y=np.zeros(3), x_hat=np.zeros(observer.nx),
        e=np.zeros(controller.ne), v=plant.v(), A_c=Ac, B_c=Bc,
    ).to_dict()  # fmt: skip


def _sensor_gains(sensor_gains: Any) -> tuple[float, float, float]:
    """``(gx, gi1, gi2)`` from a dict of :data:`SENSOR_GAINS` (default 1)."""
    given = dict(sensor_gains or {})
    unknown = sorted(set(given) - set(SENSOR_GAINS))
    if unknown:
        raise DataError(f"unknown sensor gains {unknown}; expected names from {SENSOR_GAINS}")
    out = tuple(float(given.get(k, 1.0)) for k in SENSOR_GAINS)
    if not all(math.isfinite(g) and g > 0 for g in out):
        raise DataError(f"sensor gains must be positive finite numbers; got {given!r}")
    return out  # type: ignore[return-value]


def _noise_std(noise_std: Any) -> np.ndarray:
    s = np.asarray(noise_std, dtype=float).reshape(-1)
    if s.size != 3 or not np.all(np.isfinite(s)) or np.any(s < 0):
        raise DataError(
            "`noise_std` must be 3 non-negative numbers (x [m], i1 [A], i2 [A]); "
            f"got {noise_std!r}"
        )
    return s


def _check_bias_current(plant: AMBParameters, nominal: AMBParameters, plant_model: str) -> None:
    """Refuse an ``i0`` fault on the nonlinear plant, where it would change nothing."""
    if plant_model == "nonlinear" and plant.i0 != nominal.i0:
        raise DataError(
            "an i0 fault has no effect on the nonlinear plant: its bias currents follow from "
            "the nominal bias voltages and the coil resistances (a wrong bias current is an R1/"
            "R2 or kw1/kw2 fault there); use plant_model='linear' (--plant linear) to move "
            "the linearisation point i0"
        )


def simulate_amb_loop(
    plant: AMBParameters,
    *,
    dt: float = DEFAULT_DT,
    n_samples: int = DEFAULT_N_SAMPLES,
    nominal: AMBParameters | None = None,
    controller: IntegralStateFeedback | None = None,
    observer: Observer | None = None,
    excitation_std: float | Sequence[float] = DEFAULT_EXCITATION_STD,
    excitation: str = "gaussian",
    noise_std: Sequence[float] = DEFAULT_NOISE_STD,
    plant_model: str = "nonlinear",
    force_std: float | None = None,
    unbalance: Sequence[float] | None = None,
    substeps: int = DEFAULT_SUBSTEPS,
    rng: Any = None,
    observer_model: str = "nominal",
    kernel: str = "auto",
    progress: Callable[[Iterable[int]], Iterable[int]] | None = None,
    sensor_gains: dict[str, float] | None = None,
) -> ClosedLoopData:
    """Simulate the AMB under observer-based state feedback with integral action.

    Implements the loop of Gosiewski & Paszowski, Fig. 2: plant eq. (1) or
    (3)-(7), observer eq. (43), control law eq. (42), excitation eq. (16), plus
    white measurement noise. Time indexing: see :mod:`maglevid.simulate.loop`
    and ``docs/control-and-simulation.md``.

    Parameters
    ----------
    plant : AMBParameters
        The real bearing (e.g. ``AMBParameters.nominal().with_fault(R1=1.2)``).
    dt : float
        Control period [s].
    n_samples : int
        Number of control periods N.
    nominal : AMBParameters, optional
        The bearing the controller and observer are designed on (default: ``plant``).
    controller : IntegralStateFeedback, optional
        Default :func:`default_amb_controller` on ``nominal``.
    observer : Observer, optional
        Default :func:`default_amb_observer` (deadbeat) on ``nominal``.
    excitation_std : float or (2,) sequence
        Excitation standard deviation per input [V].
    excitation : {"gaussian", "prbs"}
        White Gaussian or random binary (``+-excitation_std``) excitation.
    noise_std : (3,) sequence
        Measurement noise standard deviation of ``[x, i1, i2]`` [m, A, A].
    plant_model : {"nonlinear", "linear"}
        See the module notes. Default ``"nonlinear"``: the realistic bearing
        (eq. (1) under the nominal bias voltages, so a fault moves the
        operating point).
    force_std : float, optional
        Standard deviation [N] of a white force disturbance on the rotor, held
        over each period, drawn after the noise (nonlinear plant only). Default
        :data:`DEFAULT_FORCE_STD` for the nonlinear plant, 0 for the linear one
        (which has no force input).
    unbalance : (2,) sequence, optional
        ``(amplitude [N], frequency [Hz])`` of a sinusoidal force on the rotor, held
        over each period, phase 0 at the first sample: a rotor's unbalance at its
        running speed (nonlinear plant only; no draw from ``rng``, so the other
        signals of a seed do not change). Default: none.
    substeps : int
        RK4 steps per control period (nonlinear plant only).
    rng : numpy.random.Generator, int or None
        Randomness (excitation first, then noise). An int is a seed and is
        recorded; ``None`` draws a fresh seed and records it.
    observer_model : {"nominal", "plant"}
        ``"nominal"`` (default): the observer runs on its own model (the
        nominal bearing's, or that of the ``observer`` given) -- what a real
        controller does. ``"plant"``: the observer keeps its gain ``G`` but runs
        on the real bearing's ZOH model ``A, B`` (for the nonlinear plant: its
        linearisation at ``i0``), as the paper's examples evidently do ("the
        same actual observer gain ... in all examples"): then the exact ARX
        model of eq. (47) holds with the real ``A, B``. With ``"nominal"`` and
        a fault, eq. (47) with one lag is only approximate (see the docs).
    kernel : {"auto", "block", "loop"}
        Linear plant only: see :func:`~maglevid.simulate.kernel.simulate_lti`.
    progress : callable, optional
        Wraps an iterable of chunk start indices (e.g. a progress bar); used by
        the nonlinear plant, whose loop runs in Python.
    sensor_gains : dict, optional
        Sensor faults ``{"gx": g, "gi1": g, "gi2": g}`` (:data:`SENSOR_GAINS`,
        default 1): the measured deviation is ``g`` times the true one (plus
        noise), and the controller acts on the measured signal. Nonlinear plant:
        a current-sensor gain cannot be combined with a fault that moves that
        coil's rest current (DataError).

    Returns
    -------
    ClosedLoopData
        ``y`` (N, 3) measured ``[x, i1, i2]`` deviations, ``u``, ``r``, ``u_f``
        (N, 2); ``loop`` with the controller, the observer (its own discrete
        model), ``C``, the operating point and the nominal parameters;
        ``metadata`` with the truth and the seed.

    Raises
    ------
    DesignError
        When the loop with this plant is unstable (nonlinear plant: around the
        point it settles at; e.g. ``K2 -8 %`` with the default design).
    ModelError
        Nonlinear plant: no rest point, or the rotor reaches the pole face.

    Examples
    --------
    >>> from maglevid.physics.amb import AMBParameters
    >>> p = AMBParameters.nominal().with_fault(R1=1.2)
    >>> d = simulate_amb_loop(p, nominal=AMBParameters.nominal(), n_samples=500, rng=1)
    >>> d.y.shape, d.u.shape, d.loop["observer"]["type"]
    ((500, 3), (500, 2), 'deadbeat')
    """
    s = _setup(dict(locals()))  # every argument, by name
    r, v, force, meta = _draw(s, rng)
    if plant_model == "linear":
        y, u_f, u = _run_linear(s.bearing, r, v, kernel, meta)
    else:
        y, u_f, u = _run_nonlinear(s.bearing, r, v, force, s.substeps, progress, meta)
    return _record(s, r, y, u_f, u, meta)


def simulate_amb_loops(
    plant: AMBParameters, *, rngs: Sequence[Any], **options: Any
) -> list[ClosedLoopData]:
    """Many records of one bearing in one loop: ``simulate_amb_loop`` for each of ``rngs``.

    Record ``b`` is exactly (bit for bit, tested) what
    ``simulate_amb_loop(plant, rng=rngs[b], **options)`` returns: each record
    draws its excitation, noise and force from its own ``rngs[b]`` in the same
    order. On the nonlinear plant the ``B = len(rngs)`` loops run together
    (:mod:`maglevid.simulate._amb_batch`: the per-sample Python overhead is
    paid once for all records): ~35-45 us a sample for the whole batch plus ~1 us
    per record (CPU, load 2-3; ``docs/control-and-simulation.md``), so it pays from
    ``B`` of about 6 on. The linear plant, already vectorised in time
    (:func:`~maglevid.simulate.kernel.simulate_lti`), runs record by record.

    Parameters
    ----------
    plant : AMBParameters
        The real bearing, the same for every record.
    rngs : sequence
        One ``rng`` per record (a Generator, a non-negative int seed, or None
        for a fresh recorded seed), as ``simulate_amb_loop``'s ``rng``.
    **options
        Any other keyword of :func:`simulate_amb_loop` except ``rng`` and
        ``progress``.

    Returns
    -------
    list of ClosedLoopData
        One record per entry of ``rngs``, in order.

    Raises
    ------
    DataError
        An unknown option, ``rng`` or ``progress`` among ``options``, no
        ``rngs``, or any argument ``simulate_amb_loop`` refuses.
    DesignError, ModelError
        As :func:`simulate_amb_loop`; a rotor reaching the pole face names
        the record.

    Examples
    --------
    >>> from maglevid.physics.amb import AMBParameters
    >>> p = AMBParameters.nominal()
    >>> a, b = simulate_amb_loops(p, rngs=[1, 2], n_samples=300, force_std=0.0)
    >>> bool((a.y == simulate_amb_loop(p, rng=1, n_samples=300, force_std=0.0).y).all())
    True
    """
    kernel = _batch_options(options)
    rngs = list(rngs) if isinstance(rngs, Sequence) and not isinstance(rngs, str) else None
    if not rngs:
        raise DataError("`rngs` must be a non-empty sequence of rngs (one per record)")
    bound = inspect.signature(simulate_amb_loop).bind(plant, **options)
    bound.apply_defaults()
    s = _setup(bound.arguments)
    drawn = [_draw(s, rng) for rng in rngs]
    if s.plant_model == "linear":
        runs = [_run_linear(s.bearing, r, v, kernel, meta) for r, v, _, meta in drawn]
    else:
        runs = _run_nonlinear_batch(s, drawn)
    return [
        _record(s, r, y, u_f, u, meta)
        for (r, _, _, meta), (y, u_f, u) in zip(drawn, runs, strict=True)
    ]


def _batch_options(options: dict[str, Any]) -> str:
    """Refuse what :func:`simulate_amb_loops` cannot take; pop and return ``kernel``."""
    keywords = set(inspect.signature(simulate_amb_loop).parameters) - {"plant"}
    bad = sorted(set(options) - (keywords - {"rng", "progress"}))
    if bad:
        raise DataError(
            f"simulate_amb_loops got {bad}: the records' rngs go in `rngs`; other options are "
            "simulate_amb_loop's keywords except rng and progress"
        )
    return str(options.pop("kernel", "auto"))


@dataclass(frozen=True)
class _Setup:
    """What every record of one call shares: the checked arguments and the loop."""

    bearing: _Bearing
    cond: float
    plant_model: str
    n_samples: int
    excitation_std: Any
    excitation: str
    noise: np.ndarray
    force_std: float
    substeps: int
    observer_model: str
    unbalance: tuple[float, float] | None = None


def _setup(args: dict[str, Any]) -> _Setup:
    """The arguments of :func:`simulate_amb_loop` (all of them, by name) checked, the
    controller and observer built."""
    plant, plant_model, excitation = args["plant"], args["plant_model"], args["excitation"]
    nominal, dt, n_samples, substeps = _check_arguments(
        plant, args["nominal"], args["dt"], args["n_samples"], plant_model, excitation,
        args["substeps"],
    )  # fmt: skip
    gains = _sensor_gains(args["sensor_gains"])
    _check_bias_current(plant, nominal, plant_model)
    noise = _noise_std(args["noise_std"])
    fstd = _force_std(args["force_std"], plant_model)
    unbalance = _unbalance(args["unbalance"], plant_model, dt)
    observer_model = args["observer_model"]
    controller, observer = _controller_observer(
        plant, nominal, dt, args["controller"], args["observer"], observer_model
    )
    cond = _loop_condition(observer, controller)
    bearing = _Bearing(plant, nominal, controller, observer, dt, gains)
    return _Setup(
        bearing, cond, plant_model, n_samples, args["excitation_std"], excitation, noise, fstd,
        substeps, observer_model, unbalance,
    )  # fmt: skip


def _draw(s: _Setup, rng: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, dict[str, Any]]:
    """One record's excitation, noise and force (in that order from ``rng``), and its metadata."""
    gen, seed = _make_rng(rng)
    n, noise, fstd = s.n_samples, s.noise, s.force_std
    r = make_excitation(n, 2, std=s.excitation_std, kind=s.excitation, rng=gen)  # eq. (16)
    # Noise drawn after the excitation, so r does not depend on noise_std.
    v = gen.standard_normal((n, 3)) * noise if np.any(noise) else np.zeros((n, 3))
    force = gen.standard_normal(n) * fstd if fstd > 0 else None  # after the noise
    if s.unbalance is not None:  # deterministic: no draw
        amp, hz = s.unbalance
        sine = amp * np.sin(2.0 * np.pi * hz * s.bearing.dt * np.arange(n))
        force = sine if force is None else force + sine
    plant = s.bearing.plant
    meta = {
        "simulated": True, "truth": plant.to_dict(), "truth_v": plant.v().tolist(),
        "seed": seed, "plant_model": s.plant_model,
        "excitation": {
            "kind": s.excitation, "std": np.broadcast_to(s.excitation_std, (2,)).tolist()
        },
        "noise_std": noise.tolist(), "force_std": fstd, "observer_model": s.observer_model,
        **({"unbalance": list(s.unbalance)} if s.unbalance is not None else {}),
        "sensor_gains": dict(zip(SENSOR_GAINS, s.bearing.gains, strict=True)),
    }  # fmt: skip
    return r, v, force, meta


def _record(
    s: _Setup,
    r: np.ndarray,
    y: np.ndarray,
    u_f: np.ndarray,
    u: np.ndarray,
    meta: dict[str, Any],
) -> ClosedLoopData:
    return ClosedLoopData(
        y=y,
        dt=s.bearing.dt,
        u=u,
        r=r,
        u_f=u_f,
        names={"y": OUTPUT_NAMES, "u": INPUT_NAMES, "r": ("r1", "r2"), "u_f": ("uf1", "uf2")},
        units={"y": ("m", "A", "A"), "u": ("V", "V"), "r": ("V", "V"), "u_f": ("V", "V")},
        loop=_loop_record(s.bearing, s.cond),
        metadata=meta,
    )


def _check_arguments(
    plant: Any,
    nominal: Any,
    dt: Any,
    n_samples: Any,
    plant_model: str,
    excitation: str,
    substeps: Any,
) -> tuple[AMBParameters, float, int, int]:
    """The bearings, ``dt``, ``N``, the plant and excitation kinds, RK4 substeps."""
    if not isinstance(plant, AMBParameters):
        raise DataError(f"`plant` must be AMBParameters; got {type(plant).__name__}")
    nominal = plant if nominal is None else nominal
    if not isinstance(nominal, AMBParameters):
        raise DataError(f"`nominal` must be AMBParameters; got {type(nominal).__name__}")
    dt = check_positive(dt, "dt")
    if isinstance(n_samples, bool) or int(n_samples) != n_samples or n_samples < 2:
        raise DataError(f"`n_samples` must be an integer >= 2; got {n_samples!r}")
    n_samples = int(n_samples)
    if plant_model not in PLANT_MODELS:
        raise DataError(f"`plant_model` must be one of {PLANT_MODELS}; got {plant_model!r}")
    if excitation not in EXCITATION_KINDS:
        raise DataError(f"`excitation` must be one of {EXCITATION_KINDS}; got {excitation!r}")
    if isinstance(substeps, bool) or int(substeps) != substeps or substeps < 1:
        raise DataError(f"`substeps` must be an integer >= 1; got {substeps!r}")
    return nominal, dt, n_samples, int(substeps)


def _controller_observer(
    plant: AMBParameters,
    nominal: AMBParameters,
    dt: float,
    controller: IntegralStateFeedback | None,
    observer: Observer | None,
    observer_model: str,
) -> tuple[IntegralStateFeedback, Observer]:
    """Control law eq. (42) and observer eq. (43), designed on ``nominal`` by default."""
    if controller is None:
        controller = default_amb_controller(nominal, dt)
    if observer is None:
        observer = default_amb_observer(nominal, dt)
    if observer.dt is not None and abs(observer.dt - dt) > 1e-12 * dt:
        raise DataError(f"the observer was designed for dt={observer.dt:g} s, not dt={dt:g} s")
    if observer_model not in OBSERVER_MODELS:
        raise DataError(
            f"`observer_model` must be one of {OBSERVER_MODELS}; got {observer_model!r}"
        )
    if observer_model == "plant":
        # The paper's simulation: the same gain G, with the real bearing's A, B in eq. (43).
        true = amb_state_space(plant, dt)
        info = dict(observer.info)
        info.update({"model": "plant", "gain_designed_on": "nominal"})
        observer = Observer(observer.G, true.A, true.B, observer.C, observer.kind, dt, info)
    if controller.F.shape != (2, observer.nx) or controller.ny != 3:
        raise DataError(
            f"controller has F {controller.F.shape}, E {controller.E.shape}; the bearing needs "
            f"F (2, {observer.nx}) and E (ne, 3)"
        )
    return controller, observer


def _loop_condition(observer: Observer, controller: IntegralStateFeedback) -> float:
    """Condition of ``[[C, 0], [-F, Fe]]`` (eqs. (44)-(51) invert it); a warning when bad."""
    cond = (
        loop_matrix_condition(observer.C, controller.F, controller.Fe)
        if (3 + 2 == observer.nx + controller.ne)
        else float("inf")
    )
    if not cond <= 1e8:
        logger.warning(
            "the loop matrix [[C, 0], [-F, Fe]] is singular or ill-conditioned (%.3g): the "
            "recording cannot be used for the identification of eqs. (44)-(51)",
            cond,
        )
    return cond


@dataclass(frozen=True)
class _Bearing:
    """The bearing in its loop: the real one, the nominal design, eqs. (42)-(43), ``dt``."""

    plant: AMBParameters
    nominal: AMBParameters
    controller: IntegralStateFeedback
    observer: Observer
    dt: float
    gains: tuple[float, float, float] = (1.0, 1.0, 1.0)


def _run_linear(
    b: _Bearing, r: np.ndarray, v: np.ndarray, kernel: str, meta: dict[str, Any]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The linear plant of eqs. (3)-(7) in the loop; ``meta`` gets its operating point."""
    plant, nominal, controller, observer, dt = b.plant, b.nominal, b.controller, b.observer, b.dt
    true = amb_state_space(plant, dt)
    # the sensors' gains scale the measured outputs: y = diag(g) C x + noise
    sensed = StateSpace(np.asarray(true.A), np.asarray(true.B), np.diag(b.gains) @ true.C, dt=dt)
    sig = simulate_linear_loop(sensed, observer, controller, r=r, noise=v, kernel=kernel)
    # the linear plant runs at the nominal point x = 0, i = i0 of the real bearing
    meta["operating_point_true"] = _linear_operating_point(plant, nominal, controller, observer)
    meta["initial_state"] = {
        "x_hat": np.asarray(sig.x_hat0).tolist(),
        "e": np.asarray(sig.e0).tolist(),
    }
    return sig.y, sig.u_f, sig.u


def _check_current_gains_at_rest(
    eq: dict[str, Any], i0: float, gains: tuple[float, float, float]
) -> None:
    """Refuse a current-sensor gain where the bearing rests off the bias current.

    The rest point is found for true sensors; a current-sensor gain leaves it
    unchanged only while ``I_j = i0`` there (the healthy coils' point). With a
    coil fault as well, the record would start off its rest point.
    """
    for j, (name, g) in enumerate(zip(("gi1", "gi2"), gains[1:], strict=True)):
        dev = float(eq[f"I{j + 1}"]) - i0
        if g != 1.0 and abs(dev) > 1e-9 * i0:
            raise DataError(
                f"a current-sensor fault {name}={g:g} together with a fault that moves coil "
                f"{j + 1}'s rest current ({dev:+.3g} A from i0) is not supported on the "
                "nonlinear plant; simulate them one at a time, or use the linear plant "
                "(plant_model='linear' in Python, --plant linear on the command line)"
            )


def _run_nonlinear(
    b: _Bearing,
    r: np.ndarray,
    v: np.ndarray,
    force: np.ndarray | None,
    substeps: int,
    progress: Callable[[Iterable[int]], Iterable[int]] | None,
    meta: dict[str, Any],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The bearing of eq. (1) from the point it settles at under the nominal bias voltages."""
    eq = _settle(b)
    y, u_f = _simulate_nonlinear(
        b.plant,
        b.nominal,
        b.observer,
        b.controller,
        dt=b.dt,
        r=r,
        v=v,
        substeps=substeps,
        eq=eq,
        progress=progress,
        force=force,
        gains=b.gains,
    )
    _nonlinear_meta(eq, substeps, meta)
    return y, u_f, u_f + r


def _run_nonlinear_batch(
    s: _Setup, drawn: list[tuple[np.ndarray, Any, np.ndarray | None, dict[str, Any]]]
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """:func:`_run_nonlinear` for every drawn record at once (:mod:`._amb_batch`)."""
    b = s.bearing
    eq = _settle(b)
    state0 = np.stack(
        [_first_state(eq, b.controller, b.nominal.i0, b.gains, v[0]) for _, v, _, _ in drawn]
    )
    r = np.stack([d[0] for d in drawn])
    v = np.stack([d[1] for d in drawn])
    zeros = np.zeros(s.n_samples)
    force = np.stack([zeros if d[2] is None else d[2] for d in drawn])
    drawn[:] = [(d[0], None, None, d[3]) for d in drawn]  # the noise and force stacked: freed
    y, u_f = simulate_nonlinear_batch(
        b.plant,
        M=_loop_product(b.observer, b.controller),
        state0=state0,
        start=(float(eq["x"]), float(eq["I1"]), float(eq["I2"])),
        i0=b.nominal.i0,
        u_bias=tuple(float(u) for u in bias_voltages(b.nominal)),  # type: ignore[arg-type]
        dt=b.dt,
        r=r,
        v=v,
        force=force,
        substeps=s.substeps,
        gains=b.gains,
    )
    del r, v, force
    out = []
    for i, (ri, _, _, meta) in enumerate(drawn):
        _nonlinear_meta(eq, s.substeps, meta)
        out.append((y[i], u_f[i], u_f[i] + ri))
    return out


def _settle(b: _Bearing) -> dict[str, Any]:
    """The rest point of the nonlinear loop, checked (stable, sensor gains allowed there)."""
    eq = nonlinear_equilibrium(b.plant, b.nominal, b.observer, b.controller)
    _check_settled_loop(eq, b.observer, b.controller, b.dt, b.gains)
    _check_current_gains_at_rest(eq, b.nominal.i0, b.gains)
    return eq


def _nonlinear_meta(eq: dict[str, Any], substeps: int, meta: dict[str, Any]) -> None:
    meta["substeps"] = substeps
    meta["operating_point_true"] = {
        k: (np.asarray(val).tolist() if isinstance(val, np.ndarray) else val)
        for k, val in eq.items()
    }
    meta["initial_state"] = {
        "x_hat": np.asarray(eq["x_hat"]).tolist(),
        "e": np.asarray(eq["e"]).tolist(),
    }


def _loop_record(b: _Bearing, cond: float) -> dict[str, Any]:
    """``data.loop``: what the identification methods may know about the loop."""
    controller, observer, nominal, dt = b.controller, b.observer, b.nominal, b.dt
    return {
        "controller": controller.to_dict(),
        "observer": observer.to_dict(),
        "C": C_AMB.tolist(),
        "operating_point": {
            "i0": nominal.i0,
            "x0": nominal.x0,
            "m": nominal.m,
            "u_bias": bias_voltages(nominal).tolist(),
        },
        "nominal": nominal.to_dict(),
        "dt_design": dt,
        "loop_matrix_condition": cond if math.isfinite(cond) else None,
    }


# ---------------------------------------------------------------------------
# ``maglevid simulate amb``
# ---------------------------------------------------------------------------
SCENARIO = "amb"
SCENARIO_HELP = (
    "voltage-controlled two-coil magnetic bearing (Gosiewski & Paszowski) under observer-based "
    "state feedback with integral action; controller and observer designed on the nominal "
    "bearing, the simulated one may have faults"
)


def _check_faults(faults: dict[str, float], nominal: AMBParameters) -> None:
    """``--fault`` names and factors, as the user wrote them: the accepted names include
    the sensor gains (the list left out gx, gi1, gi2: issue 16, fourteenth session)."""
    check_faults(faults.items(), sorted({f.name for f in fields(nominal)} | set(SENSOR_GAINS)))


def parse_floats(text: str) -> list[float]:
    """argparse type: comma-separated numbers, e.g. ``1e-7,1e-4,1e-4``."""
    try:
        return [float(s) for s in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated numbers; got {text!r}"
        ) from None


def add_scenario_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``maglevid simulate amb``."""
    parser.add_argument(
        "--fault",
        action="append",
        type=parse_fault,
        default=[],
        metavar="NAME=FACTOR",
        help="multiply a parameter of the simulated bearing (R1, R2, Ls1, Ls2, K1, K2, kw1, kw2, "
        "m, x0; i0 on the linear plant only) or a sensor's gain (gx displacement, gi1, gi2 "
        "coil currents), e.g. --fault R1=1.2 --fault gx=1.1; repeatable",
    )
    parser.add_argument(
        "--noise",
        type=parse_floats,
        default=list(DEFAULT_NOISE_STD),
        metavar="SX,SI1,SI2",
        help="measurement noise std of x [m], i1 [A], i2 [A] (default %(default)s)",
    )
    parser.add_argument(
        "--excitation-std",
        type=parse_floats,
        default=[DEFAULT_EXCITATION_STD],
        metavar="V[,V]",
        help="excitation std per amplifier input [V] (default %(default)s)",
    )
    parser.add_argument(
        "--excitation", choices=EXCITATION_KINDS, default="gaussian", help="excitation signal"
    )
    parser.add_argument(
        "--n-samples",
        type=int,
        default=DEFAULT_N_SAMPLES,
        help="control periods (default %(default)s)",
    )
    parser.add_argument(
        "--dt", type=float, default=DEFAULT_DT, help="control period [s] (default %(default)s)"
    )
    parser.add_argument(
        "--seed", type=int, default=None, help="random seed (default: fresh, recorded)"
    )
    parser.add_argument(
        "--plant",
        choices=PLANT_MODELS,
        default="nonlinear",
        help="plant model: nonlinear (eq. (1) under the nominal bias voltages, the realistic "
        "bearing; default) or linear (eq. (4) at the nominal point, the paper's simulation)",
    )
    parser.add_argument(
        "--force-std",
        type=float,
        default=None,
        metavar="N",
        help=f"white force disturbance on the rotor [N rms] (nonlinear plant; default "
        f"{DEFAULT_FORCE_STD} N, 0 for the linear plant)",
    )
    parser.add_argument(
        "--unbalance",
        type=_amplitude_frequency,
        default=None,
        metavar="N,HZ",
        help="sinusoidal force on the rotor: amplitude [N] and frequency [Hz], e.g. 1,50 "
        "(a rotor's unbalance at 3000 rpm; nonlinear plant)",
    )
    parser.add_argument(
        "--substeps",
        type=int,
        default=DEFAULT_SUBSTEPS,
        help="RK4 steps per period (nonlinear plant)",
    )
    parser.add_argument(
        "--observer-model",
        choices=OBSERVER_MODELS,
        default="nominal",
        help="model the observer runs on: the nominal bearing's (a real controller, default) or "
        "the simulated bearing's with the nominal gain (the paper's examples)",
    )


def run_scenario(
    args: argparse.Namespace, *, progress: Callable[..., Iterable[int]] | None = None
) -> ClosedLoopData:
    """Build the recording for ``maglevid simulate amb``.

    ``progress`` (default none), passed in by the caller (the CLI passes its
    bar): ``progress(iterable, desc=..., total=...)`` returns an iterable over
    the same items; it reports the nonlinear plant's chunks simulated.
    """
    nominal = AMBParameters.nominal()
    faults = dict(args.fault)
    _check_faults(faults, nominal)
    gains = {k: faults.pop(k) for k in SENSOR_GAINS if k in faults}
    plant = nominal.with_fault(**faults) if faults else nominal
    exc = args.excitation_std
    chunks = None
    if args.plant == "nonlinear" and progress is not None:
        from functools import partial

        total = -(-int(args.n_samples) // 2000)
        chunks = partial(progress, desc="simulating", total=total)
    return simulate_amb_loop(
        plant,
        dt=args.dt,
        n_samples=args.n_samples,
        nominal=nominal,
        excitation_std=exc[0] if len(exc) == 1 else exc,
        excitation=args.excitation,
        noise_std=args.noise,
        plant_model=args.plant,
        substeps=args.substeps,
        observer_model=args.observer_model,
        force_std=args.force_std,
        unbalance=args.unbalance,
        rng=args.seed,
        progress=chunks,
        sensor_gains=gains,
    )


def _amplitude_frequency(text: str) -> tuple[float, float]:
    """``"1,50"`` -> ``(1.0, 50.0)`` (``--unbalance``)."""
    parts = text.split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        return float(parts[0]), float(parts[1])
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected AMPLITUDE,FREQUENCY, e.g. 1,50 (1 N at 50 Hz); got {text!r}"
        ) from None
