"""Closed-loop magnetic suspension with output inter-sampling (Sun et al., Figs. 1-3).

The controller runs at the control period ``T`` and holds its output ``u(m)``
over ``[mT, (m+1)T)``; the gap sensor is sampled every ``Delta = T/p``; white
noise ``w`` (standard deviation 0.1 mm in the paper) is added to *every*
output sample; only ``y(mT) + w(mT)`` reaches the controller, whose reference
is zero (the paper's "severe case": the noise is the only excitation).

Linear plant
    The loop is linear and driven by ``w_0`` alone, so every signal is a stable
    filter of the noise (Section 4.4, eq. (16)) with ``Gamma = C A + D B_0``::

        u   = -D A / Gamma w_0,     y_j = -D B_j / Gamma w_0 + w_j

    with the numerators ``B_j`` of Theorem 2. Computed by ``lfilter`` (no
    Python loop; never by running the unstable plant open-loop, which would
    amplify rounding errors by 1.1058^m).
Nonlinear plant
    Eq. (25) integrated by classical Runge-Kutta with ``substeps`` steps per
    output interval ``Delta``; the controller recursion ``C(q) u = D(q) e`` in
    between.

``warmup`` seconds are simulated and dropped, so the record starts from a
loop in its stationary regime (as a measurement would), not from rest.
"""

from __future__ import annotations

import argparse
import logging
from collections.abc import Callable, Iterable
from dataclasses import replace
from typing import Any

import numpy as np

from maglevid._validation import check_positive
from maglevid.control.pid import (
    RETUNED_LEAD_LAG,
    RETUNED_PID,
    DiscreteController,
    closed_loop_poles,
)
from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError, DesignError, ModelError
from maglevid.lti import StateSpace, discretize
from maglevid.physics.suspension import (
    SuspensionParameters,
    polynomials_from_state_space,
    suspension_state_space,
)
from maglevid.simulate._faults import check_faults, parse_fault

__all__ = [
    "CONTROLLERS",
    "SCENARIO",
    "SCENARIO_HELP",
    "add_scenario_arguments",
    "run_scenario",
    "simulate_suspension",
    "suspension_truth",
]

log = logging.getLogger(__name__)

SCENARIO = "suspension"
SCENARIO_HELP = (
    "steel-ball magnetic suspension of Sun et al. under PID-type feedback, output sampled "
    "p times per control period, noise on every sample (reference 0)"
)

#: Controllers by name: the retuned PID-order lead-lag (default) and the best PID.
CONTROLLERS: dict[str, DiscreteController] = {"lead-lag": RETUNED_LEAD_LAG, "pid": RETUNED_PID}


def _lifted(params: SuspensionParameters, dt: float, p: int) -> StateSpace:
    """SIMO T-level model of the inter-samples (Fig. 3): ``A = Lam^p``, row j = ``psi Lam^j``."""
    sd = discretize(suspension_state_space(params), dt / p)
    Lam, phi, psi = sd.A, sd.B, sd.C
    n = sd.nx
    C = np.empty((p, n))
    D = np.empty((p, 1))
    S = np.zeros((n, 1))
    Lj = np.eye(n)
    for j in range(p):
        C[j] = (psi @ Lj)[0]
        D[j] = (psi @ S)[0]
        S = S + Lj @ phi
        Lj = Lj @ Lam
    return StateSpace(Lj, S, C, D, dt)


def suspension_truth(
    params: SuspensionParameters, controller: DiscreteController, p: int
) -> dict[str, Any]:
    """The true linear model behind a simulation: T-model, ``B_j``, poles, closed loop."""
    dt = controller.dt
    a, B = polynomials_from_state_space(_lifted(params, dt, p))
    B = np.atleast_2d(B)
    z = np.roots(a)
    return {
        "a": a[1:].tolist(),
        "b": B[0, 1:].tolist(),
        "B": B.tolist(),
        "poles": np.sort(z.real)[::-1].tolist(),
        "continuous_poles": np.sort(np.log(z.astype(complex)).real / dt)[::-1].tolist(),
        "closed_loop_pole_moduli": np.sort(np.abs(closed_loop_poles(controller, a, B[0])))[
            ::-1
        ].tolist(),
        "parameters": {
            **params.to_dict(),
            **params.operating_point(),
        },
    }


def simulate_suspension(
    *,
    p: int = 3,
    duration: float = 18.0,
    params: SuspensionParameters | None = None,
    controller: DiscreteController | str = "lead-lag",
    noise_std: float = 1e-4,
    plant: str = "linear",
    substeps: int = 4,
    warmup: float = 1.0,
    force_std: float = 0.0,
    design: SuspensionParameters | None = None,
    rng: np.random.Generator | int | None = None,
) -> ClosedLoopData:
    """Simulate the inter-sampled closed loop of Sun et al. and return the recording.

    Parameters
    ----------
    p : int
        Output samples per control period (1 = conventional sampling).
    duration : float
        Recorded time [s] (18 s in the paper); ``N = round(duration / T)`` periods.
    params : SuspensionParameters, optional
        Plant; :meth:`SuspensionParameters.nominal` (Y = 6 mm) by default.
    controller : DiscreteController or {"lead-lag", "pid"}
        Its ``dt`` is the control period ``T``. See :data:`CONTROLLERS`.
    noise_std : float
        Standard deviation of the white output noise [m] (0.1 mm in Section 5.2).
    plant : {"linear", "nonlinear"}
        Linearised model (27) or the nonlinear equations (25).
    substeps : int
        Runge-Kutta steps per output interval (nonlinear plant).
    warmup : float
        Seconds simulated before the record starts (dropped).
    force_std : float
        White force disturbance on the ball [N rms], held over each output sample
        (nonlinear plant only; 0 by default, the paper's setting: sensor noise
        alone). A force inside the loop is what Sun et al.'s output-error steps
        cannot tell from the plant (docs/sun.md, "Beyond the paper").
    design : SuspensionParameters, optional
        What the recording states as the suspension's design (``loop["design"]``:
        the diagnosis's nominal baseline; ``loop["physical"]``'s mass and resistance,
        which the engineer knows): ``params`` by default; the nominal suspension when
        ``params`` carries a fault.
    rng : numpy.random.Generator or int, optional
        Source of the noise; the same seed gives the same record.

    Returns
    -------
    ClosedLoopData
        ``y`` (N p, 1) measured gap deviation [m], ``u`` and ``u_f`` (N, 1) the
        controller's voltage [V]; ``loop`` = controller, ``T``, operating point
        (sensor reading ``Y``), the design's ``M``, ``R`` (``physical``) and its
        physical parameters (``design``); ``metadata["truth"]`` the true model
        (:func:`suspension_truth`), plus seed and options.

    Raises
    ------
    DesignError
        If the controller does not stabilise the linearised plant.

    Examples
    --------
    >>> rec = simulate_suspension(p=2, duration=0.24, rng=1)
    >>> rec.y.shape, rec.u.shape, rec.p
    ((200, 1), (100, 1), 2)
    """
    if isinstance(p, bool) or not isinstance(p, (int, np.integer)) or p < 1:
        raise DataError(f"`p` must be an integer >= 1; got {p!r}")
    p = int(p)
    params = SuspensionParameters.nominal() if params is None else params
    if isinstance(controller, str):
        if controller not in CONTROLLERS:
            raise DataError(
                f"`controller` must be one of {sorted(CONTROLLERS)}; got {controller!r}"
            )
        controller = CONTROLLERS[controller]
    if plant not in ("linear", "nonlinear"):
        raise DataError(f"`plant` must be 'linear' or 'nonlinear'; got {plant!r}")
    duration = check_positive(duration, "duration")
    noise_std, warmup, force_std = _checked_levels(noise_std, substeps, warmup, force_std, plant)
    seed = rng if isinstance(rng, (int, np.integer)) else None
    rng = np.random.default_rng(rng)

    dt = controller.dt
    N = round(duration / dt)
    n_warm = round(warmup / dt)
    if N < 2:
        raise DataError(f"`duration` {duration} s is shorter than two control periods of {dt} s")
    truth = suspension_truth(params, controller, p)
    if max(truth["closed_loop_pole_moduli"]) >= 1.0:
        raise DesignError(
            f"the controller {controller!r} does not stabilise the linearised plant: "
            f"closed-loop pole moduli {np.round(truth['closed_loop_pole_moduli'], 4).tolist()}"
        )
    W = noise_std * rng.standard_normal((n_warm + N, p))

    if plant == "linear":
        y, u = _simulate_linear(truth, controller, W)
    else:
        F = force_std * rng.standard_normal((n_warm + N, p)) if force_std else None
        y, u = _simulate_nonlinear(params, controller, W, int(substeps), F)
    y = y[n_warm:]
    u = u[n_warm:]

    design = params if design is None else design
    loop = {
        "controller": controller.to_dict(),
        "T": dt,
        "reference": 0.0,
        "operating_point": {"Y": params.Y},
        "physical": {"M": design.M, "R": design.R, "g": design.g},
        "design": design_values(design),
    }
    metadata = {
        "scenario": SCENARIO,
        "plant": plant,
        "noise_std": noise_std,
        "seed": None if seed is None else int(seed),
        "duration": N * dt,
        "warmup": n_warm * dt,
        "substeps": int(substeps) if plant == "nonlinear" else None,
        "force_std": force_std,
        "truth": truth,
    }
    return ClosedLoopData(
        y=y.reshape(-1, 1),
        u=u[:, None],
        u_f=u[:, None],
        dt=dt,
        p=p,
        names={"y": ("gap",), "u": ("voltage",), "u_f": ("voltage",)},
        units={"y": ("m",), "u": ("V",), "u_f": ("V",)},
        loop=loop,
        metadata=metadata,
    )


def _checked_levels(  # type: ignore[no-untyped-def]
    noise_std, substeps, warmup, force_std, plant
) -> tuple[float, float, float]:
    """The noise, warm-up and force options as floats, or the DataError naming the bad one."""
    noise_std = float(noise_std)
    if not np.isfinite(noise_std) or noise_std < 0:
        raise DataError(f"`noise_std` must be >= 0; got {noise_std!r}")
    if isinstance(substeps, bool) or not isinstance(substeps, (int, np.integer)) or substeps < 1:
        raise DataError(f"`substeps` must be an integer >= 1; got {substeps!r}")
    warmup = float(warmup)
    if not np.isfinite(warmup) or warmup < 0:
        raise DataError(f"`warmup` must be >= 0 seconds; got {warmup!r}")
    force_std = float(force_std)
    if not np.isfinite(force_std) or force_std < 0:
        raise DataError(f"`force_std` must be >= 0 N; got {force_std!r}")
    if force_std and plant != "nonlinear":
        raise DataError(
            "`force_std` needs plant='nonlinear' (the linear plant is the paper's "
            "simulation: sensor noise alone)"
        )
    return noise_std, warmup, force_std


def design_values(params: SuspensionParameters) -> dict[str, float]:
    """What a recording states as the suspension's design (``loop["design"]``): the
    physical parameters a diagnosis compares, and the unstable pole [rad/s]."""
    s = np.linalg.eigvals(suspension_state_space(params).A)
    return {
        "pole_rad_s": float(np.max(s.real)),
        "alpha": params.alpha,
        "eta": params.eta,
        "L": params.L,
        "gap": params.gap,
        "Q": params.Q,
        "L_inf": params.L_inf,
    }


def _simulate_linear(
    truth: dict[str, Any], controller: DiscreteController, W: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    # u = -D A/Gamma w_0 and y_j = -D B_j/Gamma w_0 + w_j (eq. (16) with r = 0).
    a = np.r_[1.0, truth["a"]]
    B = np.asarray(truth["B"])
    D, C = controller.num, controller.den
    gamma = np.zeros(max(C.size + a.size, D.size + B.shape[1]) - 1)
    gamma[: C.size + a.size - 1] += np.convolve(C, a)
    gamma[: D.size + B.shape[1] - 1] += np.convolve(D, B[0])
    w0 = W[:, 0]
    from scipy import signal  # ~1 s to import: only where it is used

    u = signal.lfilter(-np.convolve(D, a), gamma, w0)
    y = np.empty_like(W)
    for j in range(W.shape[1]):
        y[:, j] = signal.lfilter(-np.convolve(D, B[j]), gamma, w0) + W[:, j]
    return y, u


def _simulate_nonlinear(
    params: SuspensionParameters,
    controller: DiscreteController,
    W: np.ndarray,
    substeps: int,
    F: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (25) by RK4 under the controller; ``W`` the sensor noise and ``F`` (optional)
    the force on the ball [N, away from the magnet], both (N, p), held per sample."""
    n, p = W.shape
    h = controller.dt / p / substeps
    d = controller.num.tolist()
    c = controller.den.tolist()
    e_hist = [0.0] * len(d)  # e(m), e(m-1), ...
    u_hist = [0.0] * len(c)  # u(m), u(m-1), ...
    y = np.empty((n, p))
    u_out = np.empty(n)
    # Eq. (25) in scalar arithmetic (this loop runs N p substeps times; numpy's
    # per-call overhead would dominate). Same equations as suspension_nonlinear_rhs,
    # which the tests compare against.
    g, k_f, Q, R = params.g, 0.5 * params.Q / params.M, params.Q, params.R
    gap0, I0, U0, Linf = params.gap, params.I, params.U, params.L_inf

    force = [0.0]  # the held force per unit mass over the current sample

    def rhs(y_: float, v_: float, i_: float, um: float) -> tuple[float, float, float]:
        gp = gap0 + y_
        cur = I0 + i_
        if gp <= 0:
            raise ModelError(f"the ball touched the magnet (gap {gp:.3g} m)")
        r = cur / gp
        acc = g - k_f * r * r + force[0]
        return v_, acc, (um + U0 - R * cur + Q * r / gp * v_) / (Linf + Q / gp)

    x0 = x1 = x2 = 0.0
    for m in range(n):
        y0 = x0 + W[m, 0]
        e_hist = [-y0, *e_hist[:-1]]  # reference 0
        um = sum(di * ei for di, ei in zip(d, e_hist)) - sum(
            ci * ui for ci, ui in zip(c[1:], u_hist[:-1])
        )
        u_hist = [um, *u_hist[:-1]]
        u_out[m] = um
        y[m, 0] = y0
        for j in range(p):
            if j:
                y[m, j] = x0 + W[m, j]
            if F is not None:
                force[0] = F[m, j] / params.M
            for _ in range(substeps):  # classical RK4, input held
                a0, a1, a2 = rhs(x0, x1, x2, um)
                b0, b1, b2 = rhs(x0 + 0.5 * h * a0, x1 + 0.5 * h * a1, x2 + 0.5 * h * a2, um)
                c0, c1, c2 = rhs(x0 + 0.5 * h * b0, x1 + 0.5 * h * b1, x2 + 0.5 * h * b2, um)
                d0, d1, d2 = rhs(x0 + h * c0, x1 + h * c1, x2 + h * c2, um)
                x0 += h / 6.0 * (a0 + 2.0 * b0 + 2.0 * c0 + d0)
                x1 += h / 6.0 * (a1 + 2.0 * b1 + 2.0 * c1 + d1)
                x2 += h / 6.0 * (a2 + 2.0 * b2 + 2.0 * c2 + d2)
    return y, u_out


# ----------------------------------------------------------------- scenario
#: What ``--fault NAME=FACTOR`` may multiply: the ball's mass, the coil's inductance law
#: (``Q``, eq. (23)'s constant: shorted turns; ``L_inf``) and the gap sensor's offset
#: (``Y_offset``: the ball held at another physical gap). Not ``R``: the likelihood takes
#: the coil's resistance as the recording states it (docs/sun.md, Section 6).
FAULT_NAMES = ("M", "Q", "L_inf", "Y_offset")


def faulty_parameters(
    nominal: SuspensionParameters, faults: Iterable[tuple[str, float]]
) -> SuspensionParameters:
    """``nominal`` with each named parameter multiplied by its factor."""
    faults = list(faults)
    check_faults(faults, FAULT_NAMES)
    return replace(nominal, **{k: getattr(nominal, k) * f for k, f in faults})


def add_scenario_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--p", type=int, default=3, help="output samples per control period")
    parser.add_argument(
        "--fault", action="append", type=parse_fault, default=[], metavar="NAME=FACTOR",
        help="multiply a parameter of the simulated suspension (M ball mass, Q and L_inf of "
        "the inductance law, Y_offset the gap sensor's offset), e.g. --fault Q=0.9; the "
        "recording states the nominal design; repeatable",
    )  # fmt: skip
    parser.add_argument("--duration", type=float, default=18.0, help="record length [s]")
    parser.add_argument(
        "--noise-std-mm", type=float, default=0.1, help="output noise std [mm] (paper: 0.1)"
    )
    parser.add_argument(
        "--controller",
        choices=sorted(CONTROLLERS),
        default="lead-lag",
        help="retuned lead-lag of the PID's orders (default) or the best (poorly damped) PID",
    )
    parser.add_argument("--plant", choices=("linear", "nonlinear"), default="linear")
    parser.add_argument(
        "--Y-mm", type=float, default=6.0, help="operating point as read by the sensor [mm]"
    )
    parser.add_argument("--substeps", type=int, default=4, help="RK4 steps per output sample")
    parser.add_argument(
        "--force-std",
        type=float,
        default=0.0,
        metavar="N",
        help="white force disturbance on the ball [N rms] (nonlinear plant; default 0, the "
        "paper's sensor noise alone)",
    )
    parser.add_argument("--seed", type=int, default=0, help="noise seed (same seed, same record)")


def run_scenario(
    args: argparse.Namespace, *, progress: Callable[..., Iterable[Any]] | None = None
) -> ClosedLoopData:
    """Build the recording for ``maglevid simulate suspension``.

    ``progress`` is accepted for the scenario contract and not used: one
    simulation call, nothing to count.
    """
    nominal = SuspensionParameters.nominal(Y=args.Y_mm * 1e-3)
    return simulate_suspension(
        p=args.p,
        duration=args.duration,
        params=faulty_parameters(nominal, args.fault),
        design=nominal,
        controller=args.controller,
        noise_std=args.noise_std_mm * 1e-3,
        plant=args.plant,
        substeps=args.substeps,
        force_std=args.force_std,
        rng=args.seed,
    )
