"""False drift alarms over repeated looks at a growing history (issue 12, item 5).

Run from the repository root::

    python -m benchmarks.bench_drift_looks                 # 20000 series, 12 and 24 looks

Drift-free series (one recording every 4 days, standard errors uniform 0.18-0.25,
true scatter ``sqrt(phi)`` times the stated errors) are tested at every look from 4
points on, at the pipeline's per-parameter level 0.01/13, with the plain WLS t-test
and with ``scale_floor=True`` (``phi = max(phi_hat, 1)``). The statistics are
``maglevid.diagnose.drift._wls``'s, vectorised over the series (the straight calls
agree: ``tests/diagnose/test_drift.py``). Prints the share of series with a false
alarm at any look. Results: ``docs/history.md``, drift test, repeated looks.
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy import special


def false_alarm_rates(n_series, n_points, phi, alpha, seed=0):
    """(plain t-test, floored) share of series with a false alarm at any look."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_points) * 4.0
    s = rng.uniform(0.18, 0.25, (n_series, n_points))
    y = rng.normal(0.0, 1.0, (n_series, n_points)) * s * np.sqrt(phi)
    plain = np.zeros(n_series, bool)
    floored = np.zeros(n_series, bool)
    for n in range(4, n_points + 1):
        w = 1.0 / s[:, :n] ** 2
        sw = w.sum(1)
        tau = t[:n] - ((w * t[:n]).sum(1) / sw)[:, None]
        S = (w * tau * tau).sum(1)
        a = (w * y[:, :n]).sum(1) / sw
        b = (w * tau * y[:, :n]).sum(1) / S
        phi_hat = (w * (y[:, :n] - a[:, None] - b[:, None] * tau) ** 2).sum(1) / (n - 2)
        plain |= 2 * special.stdtr(n - 2, -np.abs(b) / np.sqrt(phi_hat / S)) < alpha
        floored |= (
            2 * special.stdtr(n - 2, -np.abs(b) / np.sqrt(np.maximum(phi_hat, 1.0) / S)) < alpha
        )
    return float(plain.mean()), float(floored.mean())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--series", type=int, default=20000)
    args = ap.parse_args()
    alpha = 0.01 / 13
    print("| looks (points) | phi | plain t-test | scale_floor=True |")
    print("|---|---|---|---|")
    for n_points in (15, 27):
        for phi in (1.0, 1.5, 2.0, 4.0):
            plain, floored = false_alarm_rates(args.series, n_points, phi, alpha)
            print(f"| {n_points - 3} (4..{n_points}) | {phi:g} | {plain:.2g} | {floored:.2g} |")


if __name__ == "__main__":
    main()
