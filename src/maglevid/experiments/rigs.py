"""Real-rig results: the UAQ steel-ball levitator and the NTNU "Maggy" platform.

``maglevid reproduce rigs`` prints the tables of ``docs/real-rigs.md``: data quality
(levitating segments, controller replay, sample time, excitation, quantisation),
the unstable pole of the UAQ levitator by the direct, indirect, two-stage and
grey-box methods beside the published physics, and for Maggy the identified
controller, the dominant closed-loop mode and what the record can and cannot say
about the plant.

It also holds :func:`simulate_uaq_twin`, a nonlinear simulation of the UAQ rig
(physics of :mod:`maglevid.physics.levitator`, the exact cascade of
:mod:`maglevid.control.cascade_pid`, sensor quantisation), on which every method
is checked before it meets the real records.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Any

import numpy as np

from maglevid.control.cascade_pid import CascadeGains, CascadePID
from maglevid.data import ClosedLoopData
from maglevid.physics.levitator import LevitatorParameters, equilibrium

__all__ = [
    "PAPER",
    "PAPER_HELP",
    "UAQ_TWIN",
    "add_paper_arguments",
    "run_reproduction",
    "simulate_uaq_twin",
]

log = logging.getLogger(__name__)

PAPER = "rigs"
PAPER_HELP = "real-rig results: UAQ levitator (unstable pole by four methods) and Maggy"

#: Position and current quantisation steps of the UAQ rig (10-bit ADCs; README).
UAQ_Y_STEP = 0.05 / 1023
UAQ_I_STEP = 5.0 / (2.2 * 1023)

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
    (M1)-(E1) with a random force disturbance held over the period.

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


def add_paper_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--data",
        default=None,
        help="folder holding maglev-uaq-levitador/ and maggy-ntnu/ (default: ../shared/data)",
    )


def run_reproduction(args: argparse.Namespace) -> dict[str, Any]:  # pragma: no cover - later
    raise NotImplementedError(str(Path(args.out)))
