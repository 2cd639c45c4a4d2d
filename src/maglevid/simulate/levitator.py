"""The steel-ball levitator under its cascade: a twin of the UAQ rig, with faults.

:func:`simulate_uaq_twin` integrates the one-coil levitator's nonlinear physics
(:mod:`maglevid.physics.levitator`, eqs. (M1)-(E1)) under the rig's cascade
(:mod:`maglevid.control.cascade_pid`) with the rig's ADC quantisation, a held random
force disturbance and sensor noise. :func:`simulate_levitator` is a diagnosis record
of it: a faulty twin (any constant changed, the gap sensor's zero shifted) at one or
more gaps, whose recording states the *healthy* twin's physics with its driver, as a
rig's documentation would, so that ``maglevid diagnose`` compares against it. It is
also the ``levitator`` scenario of ``maglevid simulate`` (:data:`SCENARIO`,
:func:`add_scenario_arguments`, :func:`run_scenario`).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import fields, replace
from typing import Any

import numpy as np

from maglevid.control.cascade_pid import CascadeGains, CascadePID
from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError
from maglevid.physics.levitator import LevitatorParameters, equilibrium
from maglevid.simulate._faults import check_faults, parse_fault

__all__ = [
    "SCENARIO",
    "SCENARIO_HELP",
    "UAQ_I_STEP",
    "UAQ_TWIN",
    "UAQ_Y_STEP",
    "add_scenario_arguments",
    "run_scenario",
    "simulate_levitator",
    "simulate_uaq_twin",
]

#: Position and current quantisation steps of the UAQ rig (10-bit ADCs; README).
UAQ_Y_STEP = 0.05 / 1023
UAQ_I_STEP = 5.0 / (2.2 * 1023)
#: The UAQ rig's travel [m]: the ball rests on the bottom stop at a gap of ~19.7-20 mm
#: (the sessions' largest readings 19.99-20.4 mm; data README) and sticks to the magnet at
#: 0. The twin stops there too (a fallen ball's gap does not run on).
UAQ_TRAVEL = (0.0, 0.0199)

#: A twin of the UAQ rig: upstream inductance law and mass, and a driver fitted to
#: the records (u -> i: incremental 9.8 V/A, 2.6 V offset, ~17 ms time constant;
#: see docs/real-rigs.md), i.e. ``R = 5.05 ohm``, ``ku = 0.515``, ``v0 = 1.36 V``.
UAQ_TWIN = LevitatorParameters(R=5.05, ku=0.515, v0=1.36)


def simulate_uaq_twin(
    reference: Any,
    *,
    params: LevitatorParameters = UAQ_TWIN,
    gains: CascadeGains | None = None,
    force_noise: float = 0.3,
    y_noise: float = 1e-5,
    i_noise: float = 1e-3,
    quantise: bool = True,
    substeps: int = 4,
    rng: np.random.Generator | None = None,
) -> ClosedLoopData:
    """Simulate the UAQ levitator under its cascade at ``gains.dt`` (nonlinear).

    The ball starts at rest at ``reference[0]`` with the integrators at their
    equilibrium values. Each period: measure ``y`` and ``i`` (Gaussian noise, then
    the rig's ADC quantisation), run the cascade, hold ``u`` and integrate
    (M1)-(E1) with a random force disturbance held over the period. The ball stops at
    the rig's travel (:data:`UAQ_TRAVEL`: the magnet and the bottom stop).

    Parameters
    ----------
    reference : array_like, shape (N,)
        Gap reference ``yd`` [m].
    params : LevitatorParameters
    gains : CascadeGains, optional (UAQ gains)
    force_noise : float
        Standard deviation of the held disturbance acceleration [m/s^2].
    y_noise, i_noise : float
        Standard deviations of the measurement noise before quantisation [m, A].
    quantise : bool
        Round to the rig's 48.9 um and 2.2 mA steps.
    substeps : int
        RK4 substeps per period.
    rng : numpy.random.Generator, optional

    Returns
    -------
    ClosedLoopData
        ``y = [gap, i]`` (names ``("y", "i")``), ``u = [u]``, ``r = [yd]``, ``dt``;
        ``metadata["truth"]`` holds the parameters and ``loop["controller"]`` the
        gains.
    """
    rng = np.random.default_rng(0) if rng is None else rng
    g = CascadeGains.uaq() if gains is None else gains
    yd = np.asarray(reference, dtype=float).reshape(-1)
    n = yd.size
    dt = g.dt
    i0, u0 = equilibrium(params, yd[0])
    ctl = CascadePID(g, I0=-i0, J0=u0)
    m, gr, R, k0, k, a, ku, v0 = (
        params.m, params.g, params.R, params.k0, params.k, params.a, params.ku, params.v0
    )  # fmt: skip
    y, v, cur = float(yd[0]), 0.0, float(i0)
    Y = np.empty((n, 2))
    U = np.empty(n)
    dist = rng.standard_normal(n) * force_noise
    ny = rng.standard_normal(n) * y_noise
    ni = rng.standard_normal(n) * i_noise
    h = dt / substeps

    def rhs(y: float, v: float, c: float, u: float, w: float) -> tuple[float, float, float]:
        L = k0 + k / (1.0 + y / a)  # eq. (L1)
        dL = -k * a / (a + y) ** 2  # eq. (L2)
        F = k * a * c * c / (2.0 * (a + y) ** 2)  # eq. (F1)
        return v, gr - F / m + w, (ku * u - v0 - R * c - c * dL * v) / L

    for t in range(n):
        ym = y + ny[t]
        im = cur + ni[t]
        if quantise:
            ym = round(ym / UAQ_Y_STEP) * UAQ_Y_STEP
            im = round(im / UAQ_I_STEP) * UAQ_I_STEP
        _, u, _ = ctl.step(yd[t], ym, im)
        Y[t] = ym, im
        U[t] = u
        w = dist[t]
        for _ in range(substeps):
            k1 = rhs(y, v, cur, u, w)
            k2 = rhs(y + 0.5 * h * k1[0], v + 0.5 * h * k1[1], cur + 0.5 * h * k1[2], u, w)
            k3 = rhs(y + 0.5 * h * k2[0], v + 0.5 * h * k2[1], cur + 0.5 * h * k2[2], u, w)
            k4 = rhs(y + h * k3[0], v + h * k3[1], cur + h * k3[2], u, w)
            y += h / 6.0 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
            v += h / 6.0 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
            cur += h / 6.0 * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2])
            cur = max(cur, 0.0)
            if not UAQ_TRAVEL[0] <= y <= UAQ_TRAVEL[1]:  # at a stop: inelastic contact
                y = min(max(y, UAQ_TRAVEL[0]), UAQ_TRAVEL[1])
                v = 0.0
    return ClosedLoopData(
        y=Y,
        u=U,
        r=yd,
        dt=dt,
        names={"y": ("y", "i"), "u": ("u",), "r": ("yd",)},
        units={"y": ("m", "A"), "u": ("V",), "r": ("m",)},
        loop={"controller": "uaq-cascade", "gains": g.to_dict()},
        metadata={"source": "simulate_uaq_twin", "truth": params.to_dict()},
    )


#: The inductance law the twin's recording states (eq. (L1)).
_LAW = "L(y) = k0 + k/(1 + y/a)"
#: The gaps [m] and seconds at each of a diagnosis record (a 1 mm step saturates the
#: twin's driver and drops the ball; two gaps give the equilibrium line's slope).
DEFAULT_GAPS = (0.005, 0.0045)
DEFAULT_SECONDS_PER_GAP = 10.0
#: The constants a fault may change (``g`` is not a fault).
FAULT_NAMES = tuple(f.name for f in fields(LevitatorParameters) if f.name != "g")


def simulate_levitator(
    params: LevitatorParameters = UAQ_TWIN,
    *,
    gaps: Sequence[float] = DEFAULT_GAPS,
    seconds_per_gap: float = DEFAULT_SECONDS_PER_GAP,
    gap_offset: float = 0.0,
    baseline: LevitatorParameters = UAQ_TWIN,
    force_noise: float = 0.3,
    rng: int | np.random.Generator | None = None,
) -> ClosedLoopData:
    """A diagnosis record of the twin: ``params`` (faulty or not) under the cascade.

    The reference holds each of ``gaps`` for ``seconds_per_gap``; the gap sensor's
    zero is shifted by ``gap_offset`` (true gap = reading + offset): the true loop
    runs at ``reference + offset`` and the reading is logged. The recording states
    ``baseline``'s physics with its driver (``metadata["plant"]``: ``m``, ``R``,
    ``k0``, ``k``, ``a``, ``ku``, ``v0`` and the law), so a diagnosis compares the coil
    circuit and the command's level too; ``metadata["truth"]`` holds ``params`` and the offset.

    Parameters
    ----------
    params : LevitatorParameters
        The simulated rig (:data:`UAQ_TWIN` with a fault: ``dataclasses.replace``).
    gaps : sequence of float
        Reference gaps [m], held in turn.
    seconds_per_gap : float
    gap_offset : float
        Shift of the gap sensor's zero [m].
    baseline : LevitatorParameters
        The physics the recording states (the healthy rig).
    force_noise : float
        Standard deviation of the held disturbance acceleration [m/s^2].
    rng : int or numpy.random.Generator, optional

    Returns
    -------
    ClosedLoopData
        ``y = [gap, i]``, ``u = [u]``, ``r = [yd]`` at the cascade's 10 ms.
    """
    gaps = [float(g) for g in np.atleast_1d(np.asarray(gaps, dtype=float))]
    if not gaps or not all(0.0 < g < 0.05 for g in gaps):
        raise DataError(f"`gaps` must be gaps in metres between 0 and 0.05; got {gaps}")
    if not (math.isfinite(seconds_per_gap) and seconds_per_gap > 0):
        raise DataError(f"`seconds_per_gap` must be > 0; got {seconds_per_gap!r}")
    if not math.isfinite(gap_offset):
        raise DataError(f"`gap_offset` must be finite; got {gap_offset!r}")
    dt = CascadeGains.uaq().dt
    n = max(2, round(seconds_per_gap / dt))
    yd = np.concatenate([np.full(n, g) for g in gaps])
    gen = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
    d = simulate_uaq_twin(yd + gap_offset, params=params, force_noise=force_noise, rng=gen)
    y = np.array(d.y, dtype=float)
    y[:, 0] -= gap_offset
    b = baseline
    plant = {"m_kg": b.m, "R_ohm": b.R, "k0_H": b.k0, "k_H": b.k, "a_m": b.a, "ku": b.ku,
             "v0_V": b.v0, "inductance_model": _LAW}  # fmt: skip
    truth = {**params.to_dict(), "gap_offset_m": float(gap_offset)}
    return ClosedLoopData(
        y=y, u=d.u, r=yd, dt=d.dt, names={"y": ("y", "i"), "u": ("u",), "r": ("yd",)},
        units={"y": ("m", "A"), "u": ("V",), "r": ("m",)}, loop=dict(d.loop),
        metadata={"plant": plant, "truth": truth, "source": "simulate_levitator"},
    )  # fmt: skip


# -- the command line: ``maglevid simulate levitator`` ---------------------------------

SCENARIO = "levitator"
SCENARIO_HELP = (
    "steel-ball levitator (a twin of the UAQ rig) under its cascade, nonlinear, with the "
    "rig's ADC steps and a force disturbance; constants may be changed (faults) and the "
    "gap sensor's zero shifted; the recording states the healthy twin's physics"
)


def faulty_parameters(faults: Iterable[tuple[str, float]]) -> LevitatorParameters:
    """:data:`UAQ_TWIN` with each named constant multiplied by its factor."""
    faults = list(faults)
    check_faults(faults, FAULT_NAMES)
    params = UAQ_TWIN
    for name, factor in faults:
        params = replace(params, **{name: factor * getattr(params, name)})
    return params


def add_scenario_arguments(parser: argparse.ArgumentParser) -> None:
    """The scenario's options."""
    parser.add_argument(
        "--fault", action="append", type=parse_fault, default=[], metavar="NAME=FACTOR",
        help=f"multiply a constant of the twin ({', '.join(FAULT_NAMES)}), e.g. --fault "
        "R=1.3 (coil resistance +30 %%) or --fault ku=0.9 (driver gain -10 %%); repeatable",
    )  # fmt: skip
    parser.add_argument(
        "--gap-offset", type=float, default=0.0, metavar="MM",
        help="gap sensor's zero shifted by MM mm (true gap = reading + offset; default 0)",
    )  # fmt: skip
    parser.add_argument(
        "--gaps", type=float, nargs="+", default=[1e3 * g for g in DEFAULT_GAPS],
        metavar="MM", help="reference gaps held in turn [mm] (default %(default)s)",
    )  # fmt: skip
    parser.add_argument(
        "--seconds-per-gap", type=float, default=DEFAULT_SECONDS_PER_GAP,
        help="seconds at each gap (default %(default)s)",
    )  # fmt: skip
    parser.add_argument(
        "--force-noise", type=float, default=0.3,
        help="std of the held force disturbance [m/s^2] (default %(default)s)",
    )  # fmt: skip
    parser.add_argument("--seed", type=int, default=None, help="random seed (default: fresh)")


def run_scenario(
    args: argparse.Namespace, *, progress: Callable[..., Any] | None = None
) -> ClosedLoopData:
    """The record the command line asked for (``progress`` is not used: one pass), as
    a rig's log reads: the gap reference an extra channel (``metadata["extra_signals"]``,
    as the ``uaq-levitador`` preset keeps ``yd``), not ``r``, which is an excitation in
    the input's unit (``u = u_f + r``)."""
    d = simulate_levitator(
        faulty_parameters(args.fault),
        gaps=[1e-3 * g for g in args.gaps],
        seconds_per_gap=args.seconds_per_gap,
        gap_offset=1e-3 * args.gap_offset,
        force_noise=args.force_noise,
        rng=args.seed,
    )
    yd = {"unit": "m", "rate": "control", "values": np.asarray(d.r, dtype=float).reshape(-1)}
    names = {k: v for k, v in d.names.items() if k != "r"}
    units = {k: v for k, v in d.units.items() if k != "r"}
    meta = {**d.metadata, "extra_signals": {"yd": yd}, "seed": args.seed}
    return d.replace(r=None, names=names, units=units, metadata=meta)
