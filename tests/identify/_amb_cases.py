"""Closed-loop AMB recordings and helpers shared by the identification tests."""

from __future__ import annotations

from functools import cache
from typing import Any

import numpy as np

from maglevid.control import IntegralStateFeedback, design_lqr
from maglevid.data import ClosedLoopData
from maglevid.physics.amb import AMBParameters, amb_state_space
from maglevid.simulate import simulate_amb_loop

NOMINAL = AMBParameters.nominal()
DT = 1e-4

#: Faults of the diagnosis tests: R1 +20 % (Example II), kw1 +20 % (Example III)
#: and shorted turns in coil 1 (K1 = N1^2 A mu0 -10 %: ki1, ks1, Lo1 all -10 %).
FAULTS: dict[str, dict[str, float]] = {
    "R1+20%": {"R1": 1.2},
    "kw1+20%": {"kw1": 1.2},
    "ki1-10%": {"K1": 0.9},
}


@cache
def symmetric_controller() -> IntegralStateFeedback:
    """LQR with mirror-symmetric weights on the nominal bearing: mirror-symmetric gains."""
    Q = np.diag([1e10, 0.0, 1e2, 1e2, 1e3]) * DT
    return design_lqr(amb_state_space(NOMINAL, DT), Q=Q, R=np.eye(2))


def make_loop(
    plant: AMBParameters = NOMINAL,
    *,
    observer_model: str = "nominal",
    symmetric: bool = False,
    n_samples: int = 2000,
    noise_std: Any = (0.0, 0.0, 0.0),
    seed: int = 0,
) -> ClosedLoopData:
    """A linear-plant recording around ``plant``; controller and observer gain from NOMINAL.

    ``observer_model="plant"`` runs the observer on the real plant's model (the
    paper's examples), ``"nominal"`` on the nominal one (a real diagnosis);
    ``symmetric=True`` replaces the default controller by a mirror-symmetric LQR.
    """
    return simulate_amb_loop(
        plant,
        dt=DT,
        nominal=NOMINAL,
        observer_model=observer_model,
        controller=symmetric_controller() if symmetric else None,
        n_samples=n_samples,
        noise_std=noise_std,
        rng=seed,
        plant_model="linear",
    )


def v_true(data: ClosedLoopData) -> np.ndarray:
    return np.asarray(data.metadata["truth_v"], dtype=float)


def v_est(result: Any) -> np.ndarray:
    return np.array([result.parameters[f"v{i}"] for i in range(1, 10)])
