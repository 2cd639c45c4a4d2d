"""Inter-sampled suspension (Sun et al.): simulation and identification timings.

Measures, on one machine in one run (compare ratios, not absolute times):

* the linear loop of ``simulate_suspension`` (closed-loop filters) for the
  paper's Monte Carlo size, 10 records of 18 s at p = 6, against a
  sample-by-sample state recursion of the same loop (the obvious Python loop);
* the nonlinear plant (RK4, 4 substeps per output sample) in us per output sample;
* ``fit_intersample`` (defaults) and the paper's pure subspace step
  (``refine=False``) per record of 18 s, for p = 2, 3, 6.

Run from the repository root::

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python -m benchmarks.bench_sun
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import scipy

import maglevid
from maglevid.identify.intersample import fit_intersample
from maglevid.lti import discretize
from maglevid.physics.suspension import SuspensionParameters, suspension_state_space
from maglevid.simulate.suspension import CONTROLLERS, simulate_suspension


def _median(f: Callable[[], Any], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _recursion(p: int, n: int, rng: np.random.Generator) -> np.ndarray:
    ctl = CONTROLLERS["lead-lag"]
    sd = discretize(suspension_state_space(SuspensionParameters.nominal()), ctl.dt / p)
    W = 1e-4 * rng.standard_normal((n, p))
    d, c = ctl.num, ctl.den
    e = np.zeros(d.size)
    uh = np.zeros(c.size)
    x = np.zeros(3)
    y = np.empty((n, p))
    for m in range(n):
        e = np.r_[-(sd.C @ x).item() - W[m, 0], e[:-1]]
        um = d @ e - c[1:] @ uh[:-1]
        uh = np.r_[um, uh[:-1]]
        for j in range(p):
            y[m, j] = (sd.C @ x).item() + W[m, j]
            x = sd.A @ x + sd.B[:, 0] * um
    return y


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)
    print(
        f"<!-- maglevid {maglevid.__version__}, numpy {np.__version__}, "
        f"scipy {scipy.__version__}, python {sys.version.split()[0]} -->"
    )
    print("| what | time |")
    print("|---|---|")
    t_lin = _median(
        lambda: [simulate_suspension(p=6, duration=18.0, rng=s) for s in range(10)], args.repeats
    )
    t_rec = _median(lambda: _recursion(6, 7500, np.random.default_rng(0)), 1) * 10
    print(f"| linear loop, 10 x 18 s at p = 6 (closed-loop filters) | {t_lin:.3f} s |")
    print(f"| same, sample-by-sample state recursion (reference) | {t_rec:.1f} s |")
    t_non = _median(lambda: simulate_suspension(p=3, duration=3.0, plant="nonlinear", rng=1), 1)
    print(f"| nonlinear plant, RK4 x4 per sample | {t_non / (1250 * 3) * 1e6:.1f} us/sample |")
    for p in (2, 3, 6):
        rec = simulate_suspension(p=p, duration=18.0, rng=p)
        t_fit = _median(lambda rec=rec: fit_intersample(rec), args.repeats)
        t_sub = _median(lambda rec=rec: fit_intersample(rec, refine=False), args.repeats)
        print(f"| fit_intersample, 18 s, p = {p}: defaults / refine=False | "
              f"{t_fit:.2f} s / {t_sub:.2f} s |")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
