"""Faulty nonlinear bearings against the linearisation at their settled point (issue 12).

Run from the repository root::

    python -m benchmarks.bench_settled_point                  # 7 cases x 10 seeds
    python -m benchmarks.bench_settled_point --seeds 20 --json settled.json

The realistic bearing (:func:`maglevid.simulate.simulate_amb_loop` defaults:
eq. (1) under the nominal bias voltages, 0.1 N force disturbance, sensor noise
0.1 um / 0.1 mA, 2 s at 10 kHz) with one fault of each kind. For each case:

* noise-free (no noise, no force): the largest relative error of v1..v9 of
  ``physical`` (IV) against ``metadata["operating_point_true"]["v"]``;
* realistic, ``--seeds`` records: the fraction of the 95 % intervals of
  v1..v9 that contain that truth, the RMS of the z-scores, and the coverage
  of the static ``R_j`` of the DC levels (``extras["dc_levels"]``, truth
  ``R_j kw_j,nom / kw_j``) and of the settled currents.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from maglevid.identify.physical import fit_physical
from maglevid.physics.amb import AMBParameters
from maglevid.simulate import simulate_amb_loop

NOM = AMBParameters.nominal()
CASES = {
    "healthy": {},
    "R1 +5 %": {"R1": 1.05},
    "R2 +5 %": {"R2": 1.05},
    "kw1 -20 %": {"kw1": 0.8},
    "kw2 -5 %": {"kw2": 0.95},
    "K1 -10 %": {"K1": 0.9},
    "K2 -5 %": {"K2": 0.95},
}


def _v(res):
    return np.array([res.parameters[f"v{i}"] for i in range(1, 10)])


def _se(res):
    se = res.std_errors()
    return np.array([se[f"v{i}"] for i in range(1, 10)])


def run_case(fault: dict, seeds: int, n: int) -> dict:
    plant = NOM.with_fault(**fault)
    d = simulate_amb_loop(plant, nominal=NOM, n_samples=n, noise_std=(0, 0, 0), force_std=0.0,
                          rng=1)  # fmt: skip
    vt = np.asarray(d.metadata["operating_point_true"]["v"])
    err0 = float(np.max(np.abs(_v(fit_physical(d)) / vt - 1)))
    z, dc_hits = [], []
    for s in range(seeds):
        d = simulate_amb_loop(plant, nominal=NOM, n_samples=n, rng=1000 + s)
        op = d.metadata["operating_point_true"]
        res = fit_physical(d)
        z.append((_v(res) - np.asarray(op["v"])) / _se(res))
        ev = res.extras["dc_levels"]
        truths = {"R1_static": plant.R1 / plant.kw1, "R2_static": plant.R2 / plant.kw2,
                  "I1": op["I1"], "I2": op["I2"]}  # fmt: skip
        dc_hits.append([ev[k]["ci95"][0] <= t <= ev[k]["ci95"][1] for k, t in truths.items()])
    Z = np.array(z)
    return {
        "noise_free_max_rel_error_v": err0,
        "coverage_95_v": float(np.mean(np.abs(Z) <= 1.96)),
        "rms_z_per_v": np.sqrt(np.mean(Z**2, axis=0)).round(2).tolist(),
        "coverage_95_dc": float(np.mean(dc_hits)),
    }


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--n-samples", type=int, default=20_000)
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    out = {name: run_case(f, args.seeds, args.n_samples) for name, f in CASES.items()}
    print(f"{'case':<10} {'noise-free max|err| v':>22} {'cover v':>8} {'cover DC':>9}  rms z")
    for name, r in out.items():
        err = 100 * r["noise_free_max_rel_error_v"]
        cov = f"{r['coverage_95_v']:>8.3f} {r['coverage_95_dc']:>9.3f}"
        print(f"{name:<10} {err:>20.3f} % {cov}  {r['rms_z_per_v']}")
    allz = np.mean([r["coverage_95_v"] for r in out.values()])
    print(f"overall coverage of v1..v9: {allz:.3f}; {time.perf_counter() - t0:.0f} s")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)
    return out


if __name__ == "__main__":
    main()
