"""Closed-loop AMB recordings and helpers shared by the identification tests."""

from __future__ import annotations

from typing import Any

import numpy as np
from _amb_loop import simulate_amb_loop

from maglevid.data import ClosedLoopData
from maglevid.physics.amb import AMBParameters

NOMINAL = AMBParameters.nominal()

#: Faults of the diagnosis tests: R1 +20 % (Example II), kw1 +20 % (Example III)
#: and shorted turns in coil 1 (K1 = N1^2 A mu0 -10 %: ki1, ks1, Lo1 all -10 %).
FAULTS: dict[str, dict[str, float]] = {
    "R1+20%": {"R1": 1.2},
    "kw1+20%": {"kw1": 1.2},
    "ki1-10%": {"K1": 0.9},
}


def make_loop(
    plant: AMBParameters = NOMINAL,
    *,
    observer_on: str = "nominal",
    symmetric: bool = False,
    n_samples: int = 2000,
    noise_std: Any = (0.0, 0.0, 0.0),
    seed: int = 0,
) -> ClosedLoopData:
    """A recording of the loop around ``plant``; controller and observer designed on NOMINAL.

    ``observer_on="plant"`` puts the running plant's model in the observer (the
    paper's assumption); ``symmetric=True`` uses a mirror-symmetric controller.
    """
    return simulate_amb_loop(
        plant,
        nominal=NOMINAL,
        observer_on=observer_on,
        symmetric=symmetric,
        n_samples=n_samples,
        noise_std=noise_std,
        rng=np.random.default_rng(seed),
    )


def v_true(data: ClosedLoopData) -> np.ndarray:
    return AMBParameters(**dict(data.metadata["truth"])).v()


def v_est(result: Any) -> np.ndarray:
    return np.array([result.parameters[f"v{i}"] for i in range(1, 10)])
