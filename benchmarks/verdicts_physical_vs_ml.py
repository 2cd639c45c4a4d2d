"""diagnose's verdict with `physical` and with `ml` on the same realistic recordings.

Run from the repository root (about 2 min on one busy core)::

    PYTHONPATH=src python -m benchmarks.verdicts_physical_vs_ml [--n 40000]

The measurement behind ``ml`` as diagnose's default for a two-coil bearing
(issue 13; the table in docs/diagnosis.md, section 2): the realistic bearing of
``maglevid simulate amb --plant nonlinear`` (eq. (1) under the nominal bias
voltages, 0.1 N force disturbance, the default sensor noise), one record per
row, ``diagnose(rec, baseline="nominal", method=m)`` at the default 5 %
tolerance. The current-sensor row multiplies the logged i1 by 1.05 and drops
the logged feedback: the simulator has no sensor gain, and the identified map
u -> y is then the one a sensor in the loop gives.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

from maglevid.diagnose.pipeline import diagnose
from maglevid.physics.amb import AMBParameters
from maglevid.simulate.amb import simulate_amb_loop

#: (label, fault factors, seed, gain on the logged i1 or None)
CASES = (
    ("healthy", {}, 42, None),
    ("healthy", {}, 43, None),
    ("healthy", {}, 44, None),
    ("healthy", {}, 46, None),
    ("R1 +20 %", {"R1": 1.2}, 41, None),
    ("R1 +20 %", {"R1": 1.2}, 45, None),
    ("R1 +10 %", {"R1": 1.1}, 45, None),
    ("kw1 -20 %", {"kw1": 0.8}, 41, None),
    ("kw1 -5 %", {"kw1": 0.95}, 45, None),
    ("kw2 -10 %", {"kw2": 0.9}, 41, None),
    ("Ls2 +20 %", {"Ls2": 1.2}, 41, None),
    ("K1 -10 %", {"K1": 0.9}, 41, None),
    ("gi1 +5 %", {}, 41, 1.05),
)


def _with_current_gain(rec, gain: float):
    y = np.array(rec.y, dtype=float)
    y[:, 1] *= gain
    keep = {k: v for k, v in rec.names.items() if k != "u_f"}
    units = {k: v for k, v in rec.units.items() if k != "u_f"}
    return dataclasses.replace(rec, y=y, u_f=None, names=keep, units=units)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=40_000, help="control periods per record")
    args = ap.parse_args(argv)
    nominal = AMBParameters.nominal()
    print("| truth | seed | `physical` | `ml` | seconds (physical, ml) |")
    print("| --- | --- | --- | --- | --- |")
    for label, fault, seed, gain in CASES:
        plant = nominal.with_fault(**fault) if fault else nominal
        rec = simulate_amb_loop(plant, nominal=nominal, n_samples=args.n, rng=seed)
        if gain is not None:
            rec = _with_current_gain(rec, gain)
        cells, times = [], []
        for method in ("physical", "ml"):
            t0 = time.perf_counter()
            d = diagnose(rec, baseline="nominal", method=method)
            times.append(time.perf_counter() - t0)
            cells.append(f"{d.verdict_code}: {d.verdict}")
        print(f"| {label} | {seed} | {cells[0]} | {cells[1]} | {times[0]:.1f}, {times[1]:.1f} |")


if __name__ == "__main__":
    main()
