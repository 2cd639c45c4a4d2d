"""ML and IV on the realistic bearing: coverage, bias and precision at the settled point.

Run from the repository root::

    python -m benchmarks.bench_ml_realistic --runs 20 --n 10000     # ~4 min on one busy core

The realistic default of :func:`~maglevid.simulate.amb.simulate_amb_loop`:
the nonlinear magnet (eq. (1), RK4) under the nominal bias voltages, a 0.1 N
white force disturbance and the command line's sensor noise. The reference of
every estimate is eq. (4) linearised at the operating point the (faulty)
bearing settles at (``metadata["operating_point_true"]["v"]``). For the
healthy bearing and R1 +20 %, kw1 -20 %, K1 -10 % it reports, per method
(``ml`` with the force disturbance estimated, ``physical`` IV):

* the pooled coverage of the stated 95 % intervals of v1..v9;
* per v_i the mean error in units of the standard deviation over the runs
  (``bias/sd``), the median stated relative standard error, and the ratio of
  the scatter to the median stated standard error (``sd/se``: 1 when honest);
* the model error of the linearisation: ML on a record of the same bearing
  without sensor noise or force (the sensor noise stated at 1e-3 of the
  default so the criterion is defined), its error from the settled point in
  units of ML's standard error at the default noise;
* the median time of each fit.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from maglevid.identify.ml import fit_ml
from maglevid.identify.physical import fit_physical
from maglevid.physics.amb import V_NAMES, AMBParameters
from maglevid.simulate.amb import simulate_amb_loop

NOM = AMBParameters.nominal()
CASES = {"healthy": {}, "R1+20%": {"R1": 1.2}, "kw1-20%": {"kw1": 0.8}, "K1-10%": {"K1": 0.9}}
METHODS = {"ML": fit_ml, "IV": fit_physical}


def _v(res) -> np.ndarray:
    return np.array([res.parameters[k] for k in V_NAMES])


def _se(res) -> np.ndarray:
    se = res.std_errors()
    return np.array([se[k] for k in V_NAMES])


def run_case(fault: dict, runs: int, n: int, seed0: int) -> dict:
    plant = NOM.with_fault(**fault)
    err = {k: [] for k in METHODS}
    se = {k: [] for k in METHODS}
    cover = {k: 0 for k in METHODS}
    times = {k: [] for k in METHODS}
    force = []
    for s in range(runs):
        d = simulate_amb_loop(plant, nominal=NOM, n_samples=n, rng=seed0 + s)
        vt = np.asarray(d.metadata["operating_point_true"]["v"])
        for name, fit in METHODS.items():
            t = time.perf_counter()
            res = fit(d)
            times[name].append(time.perf_counter() - t)
            err[name].append(_v(res) - vt)
            se[name].append(_se(res))
            ci = res.confidence_intervals(0.95)
            cover[name] += sum(ci[k][0] <= x <= ci[k][1] for k, x in zip(V_NAMES, vt))
            if name == "ML":
                force.append(res.extras["force_std"])
    # the model error of the linearisation: no sensor noise, no force
    d0 = simulate_amb_loop(
        plant, nominal=NOM, n_samples=n, noise_std=(0, 0, 0), force_std=0.0, rng=seed0
    )
    vt0 = np.asarray(d0.metadata["operating_point_true"]["v"])
    r0 = fit_ml(d0, start=vt0, noise_std=(1e-10, 1e-7, 1e-7), force_std=0.0)
    out = {"fault": fault, "runs": runs, "n": n, "force_std_ml": float(np.mean(force))}
    for name in METHODS:
        e, sd_ = np.array(err[name]), np.array(se[name])
        sd = e.std(axis=0, ddof=1)
        med_se = np.median(sd_, axis=0)
        out[name] = {
            "coverage": cover[name] / (9 * runs),
            "bias_over_sd": (e.mean(axis=0) / sd).round(2).tolist(),
            "rel_se_percent": (100 * med_se / np.abs(vt0)).round(3).tolist(),
            "sd_over_se": (sd / med_se).round(2).tolist(),
            "median_time_s": float(np.median(times[name])),
        }
    model_error = (_v(r0) - vt0) / np.median(se["ML"], axis=0)
    out["model_error_over_ml_se"] = model_error.round(3).tolist()
    out["model_error_relative"] = ((_v(r0) - vt0) / np.abs(vt0)).tolist()
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    ap.add_argument("--n", type=int, default=10_000)
    ap.add_argument("--seed", type=int, default=1000)
    ap.add_argument("--cases", nargs="*", default=list(CASES))
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    results = {}
    for c in a.cases:
        t = time.perf_counter()
        r = run_case(CASES[c], a.runs, a.n, a.seed)
        results[c] = r
        print(f"== {c}  ({time.perf_counter() - t:.0f} s; ML force_std {r['force_std_ml']:.4f} N)")
        for name in METHODS:
            m = r[name]
            cov, t = m["coverage"], m["median_time_s"]
            print(f"  {name}: coverage {cov:.3f}, median time {t:.2f} s")
            print(f"    bias/sd {m['bias_over_sd']}")
            print(f"    se %    {m['rel_se_percent']}")
            print(f"    sd/se   {m['sd_over_se']}")
        print(f"  model error / ML se {r['model_error_over_ml_se']}")
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(results, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
