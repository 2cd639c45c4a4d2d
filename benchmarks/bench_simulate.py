"""Closed-loop AMB simulation: maglevid's block kernel vs ``scipy.signal.dlsim``.

Both simulate the same discrete closed loop (faulty plant R1 +20 %, kw1 +20 %,
K1 -10 %; deadbeat observer and default controller designed on the nominal
bearing; 9 states, inputs [r; noise], outputs [y; u_f]) for 10^6 samples.

Run from the repository root::

    PYTHONPATH=src python -m benchmarks.bench_simulate            # 10^6 samples, 3 repeats
    PYTHONPATH=src python -m benchmarks.bench_simulate --n-samples 200000 --repeats 1

Prints Markdown table rows: median wall time of the repeats, peak traced memory
(tracemalloc, a separate untimed run), speed-up and the largest difference
between the two outputs relative to each channel's range.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
import tracemalloc
from collections.abc import Callable
from typing import Any

import numpy as np
import scipy
from scipy.signal import dlsim

import maglevid
from maglevid.physics.amb import AMBParameters, amb_state_space
from maglevid.simulate.amb import (
    DEFAULT_DT,
    DEFAULT_NOISE_STD,
    default_amb_controller,
    default_amb_observer,
    simulate_amb_loop,
)
from maglevid.simulate.kernel import simulate_lti
from maglevid.simulate.loop import closed_loop_system


def _time(fn: Callable[[], Any], repeats: int) -> tuple[float, Any]:
    times, out = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def _peak_mb(fn: Callable[[], Any]) -> float:
    tracemalloc.start()
    tracemalloc.reset_peak()
    fn()
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    return peak / 2**20


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-samples", type=int, default=1_000_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--nonlinear-samples", type=int, default=20_000)
    args = ap.parse_args(argv)
    N = args.n_samples

    nom = AMBParameters.nominal()
    plant = nom.with_fault(R1=1.2, kw1=1.2, K1=0.9)
    dt = DEFAULT_DT
    cl = closed_loop_system(
        amb_state_space(plant, dt), default_amb_observer(nom, dt), default_amb_controller(nom, dt)
    )
    rng = np.random.default_rng(0)
    w = np.hstack([rng.standard_normal((N, 2)), rng.standard_normal((N, 3)) * DEFAULT_NOISE_STD])
    sys_tuple = (np.array(cl.A), np.array(cl.B), np.array(cl.C), np.array(cl.D), dt)

    def run_dlsim() -> np.ndarray:
        return dlsim(sys_tuple, w)[1]

    def run_kernel() -> np.ndarray:
        return simulate_lti(cl, w)[0]

    def run_full() -> Any:
        return simulate_amb_loop(plant, nominal=nom, n_samples=N, rng=0, plant_model="linear")

    t_dl, y_dl = _time(run_dlsim, args.repeats)
    t_k, y_k = _time(run_kernel, args.repeats)
    t_f, _ = _time(run_full, args.repeats)
    rel = float(np.max(np.abs(y_k - y_dl) / np.ptp(y_dl, axis=0)))
    m_dl, m_k, m_f = _peak_mb(run_dlsim), _peak_mb(run_kernel), _peak_mb(run_full)

    Nn = args.nonlinear_samples
    t_nl, _ = _time(
        lambda: simulate_amb_loop(
            plant, nominal=nom, n_samples=Nn, rng=0, plant_model="nonlinear"
        ),
        max(1, args.repeats),
    )

    print(
        f"<!-- maglevid {maglevid.__version__}, numpy {np.__version__}, "
        f"scipy {scipy.__version__}, python {sys.version.split()[0]}, median of {args.repeats} -->"
    )
    print("| benchmark | samples | time [s] | peak memory [MiB] | speed-up vs dlsim | max diff |")
    print("|---|---|---|---|---|---|")
    print(
        f"| scipy.signal.dlsim, closed loop (9 states) | {N:.0e} | {t_dl:.3f} | {m_dl:.0f} "
        "| 1 | - |"
    )
    print(
        f"| maglevid simulate_lti (block kernel) | {N:.0e} | {t_k:.3f} | {m_k:.0f} | "
        f"{t_dl / t_k:.0f}x | {rel:.1e} |"
    )
    print(
        f"| maglevid simulate_amb_loop (linear, design+signals+recording) | {N:.0e} | {t_f:.3f} | "
        f"{m_f:.0f} | {t_dl / t_f:.0f}x | - |"
    )
    print(
        f"| maglevid simulate_amb_loop (nonlinear RK4, 4 substeps) | {Nn:.0e} | {t_nl:.3f} | - | "
        f"{1e6 * t_nl / Nn:.0f} us/sample | - |"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
