"""Monte Carlo of the AMB estimators: bias against record length, and interval coverage.

Run from the repository root::

    python -m benchmarks.bench_amb_mc                         # N = 1e4 .. 3e5, 50 seeds
    python -m benchmarks.bench_amb_mc --sizes 1e4 1e5 --runs 20 --workers 8 --json mc.json
    python -m benchmarks.bench_amb_mc --observer-model nominal --fault R1=1.2

For every record length ``N`` and every seed a closed-loop record of the
Gosiewski & Paszowski bearing is simulated (:func:`maglevid.simulate.simulate_amb_loop`,
default controller and deadbeat observer from the nominal bearing, white
Gaussian excitation of 1 V rms, white measurement noise ``--noise``) and
identified by

* ``deadbeat-arx`` -- the paper's least squares (errors in variables: biased),
* ``deadbeat-iv``  -- the same ARX model, instrumental variables from ``r``,
* ``physical``     -- the plant ARX with IV (observer-independent),
* ``physical-ls``  -- the plant ARX by least squares (biased, for contrast).

The table gives, per method and ``N``: the mean error of each ``v_i`` over the
seeds (the bias, with its Monte Carlo standard error), the mean over seeds of
the largest ``|v_i|`` error and its worst case over the seeds, and the fraction
of 95 % intervals that contain the truth. A consistent estimator's mean error
falls with ``N`` (like 1/sqrt(N), the Monte Carlo noise of the mean, once its
O(1/N) bias is below that); least squares stays at its bias.

Seeds are ``SeedSequence([--seed, N, run])``: the result does not depend on
``--workers``. Uses all cores by default (``ProcessPoolExecutor``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numpy as np

from maglevid.exceptions import MaglevidError
from maglevid.identify.deadbeat import fit_deadbeat_arx, fit_deadbeat_iv
from maglevid.identify.physical import fit_physical
from maglevid.physics.amb import AMBParameters
from maglevid.simulate import simulate_amb_loop

#: Paper-like noise (the level of maglevid reproduce gosiewski) [m, A, A].
PAPER_LIKE_NOISE = (1e-10, 3e-6, 3e-6)

METHODS = {
    "deadbeat-arx": lambda d: fit_deadbeat_arx(d),
    "deadbeat-iv": lambda d: fit_deadbeat_iv(d),
    "physical": lambda d: fit_physical(d),
    "physical-ls": lambda d: fit_physical(d, estimator="ls"),
}


def _seed(base: int, n: int, run: int) -> int:
    return int(np.random.SeedSequence([base, n, run]).generate_state(1, np.uint64)[0] >> 1)


def _task(spec: dict[str, Any]) -> dict[str, Any]:
    nominal = AMBParameters.nominal()
    plant = nominal.with_fault(**spec["fault"]) if spec["fault"] else nominal
    data = simulate_amb_loop(
        plant,
        nominal=nominal,
        n_samples=spec["n"],
        noise_std=spec["noise"],
        observer_model=spec["observer_model"],
        rng=spec["seed"],
        plant_model="linear",
    )
    vt = np.asarray(data.metadata["truth_v"])
    out: dict[str, Any] = {"n": spec["n"], "seed": spec["seed"], "err": {}, "z": {}, "t": {}}
    for name in spec["methods"]:
        t0 = time.process_time()
        try:
            res = METHODS[name](data)
        except (MaglevidError, np.linalg.LinAlgError):
            out["err"][name] = None
            continue
        out["t"][name] = time.process_time() - t0
        v = np.array([res.parameters[f"v{i}"] for i in range(1, 10)])
        se = np.array([res.std_errors()[f"v{i}"] for i in range(1, 10)])
        out["err"][name] = ((v / vt - 1) * 100).tolist()
        out["z"][name] = ((v - vt) / se).tolist()
    return out


def _summarise(runs: list[dict[str, Any]], sizes: list[int], methods: list[str]) -> dict:
    table: dict[str, Any] = {}
    for name in methods:
        table[name] = {}
        for n in sizes:
            rows = [r for r in runs if r["n"] == n and r["err"].get(name) is not None]
            failed = sum(1 for r in runs if r["n"] == n and r["err"].get(name) is None)
            if not rows:
                table[name][n] = {"runs": 0, "failed": failed}
                continue
            E = np.array([r["err"][name] for r in rows])
            Z = np.array([r["z"][name] for r in rows])
            R = len(rows)
            table[name][n] = {
                "runs": R,
                "failed": failed,
                "bias_percent": E.mean(axis=0).tolist(),
                "bias_mc_se_percent": (E.std(axis=0, ddof=1) / np.sqrt(R)).tolist()
                if R > 1
                else None,
                "largest_abs_bias_percent": float(np.max(np.abs(E.mean(axis=0)))),
                "mean_abs_error_percent": np.abs(E).mean(axis=0).tolist(),
                "mean_max_abs_error_percent": float(np.abs(E).max(axis=1).mean()),
                "worst_max_abs_error_percent": float(np.abs(E).max()),
                "coverage95": float((np.abs(Z) < 1.959964).mean()),
                "cpu_s_per_fit": float(np.mean([r["t"][name] for r in rows])),
            }
    return table


def _format(table: dict, sizes: list[int], meta: dict) -> str:
    lines = [
        f"AMB Monte Carlo: {meta['runs']} seeds per N, noise {meta['noise']}, observer model "
        f"{meta['observer_model']}, fault {meta['fault'] or 'none'}, {meta['workers']} workers, "
        f"{meta['wall_s']:.0f} s wall",
        f"{'method':>13} {'N':>8} {'|bias| max %':>13} {'mean max|err| %':>16} "
        f"{'worst %':>8} {'cover95':>8} {'cpu s':>6}   bias per v_i [%] (MC s.e.)",
    ]
    for name, per in table.items():
        for n in sizes:
            st = per[n]
            if not st["runs"]:
                lines.append(f"{name:>13} {n:>8}   (no successful fit, {st['failed']} failed)")
                continue
            se = st["bias_mc_se_percent"] or [float("nan")] * 9
            bias = " ".join(f"{b:7.3f}({s:.3f})" for b, s in zip(st["bias_percent"], se))
            lines.append(
                f"{name:>13} {n:>8} {st['largest_abs_bias_percent']:13.4f} "
                f"{st['mean_max_abs_error_percent']:16.4f} "
                f"{st['worst_max_abs_error_percent']:8.3f} {st['coverage95']:8.3f} "
                f"{st['cpu_s_per_fit']:6.2f}   {bias}"
            )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", nargs="+", type=float, default=[1e4, 3e4, 1e5, 3e5])
    ap.add_argument("--runs", type=int, default=50, help="seeds per size")
    ap.add_argument("--noise", type=float, nargs=3, default=list(PAPER_LIKE_NOISE))
    ap.add_argument("--observer-model", choices=("plant", "nominal"), default="plant")
    ap.add_argument("--fault", action="append", default=[], metavar="NAME=FACTOR")
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=list(METHODS))
    ap.add_argument("--workers", type=int, default=None, help="processes (default: all cores)")
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--json", default=None, help="write the full results here")
    args = ap.parse_args(argv)
    sizes = [int(s) for s in args.sizes]
    fault = {k: float(v) for k, v in (f.split("=", 1) for f in args.fault)}
    specs = [
        {
            "n": n,
            "seed": _seed(args.seed, n, run),
            "noise": list(args.noise),
            "fault": fault,
            "observer_model": args.observer_model,
            "methods": args.methods,
        }
        for n in sizes
        for run in range(args.runs)
    ]
    workers = max(1, args.workers or os.cpu_count() or 1)
    t0 = time.perf_counter()
    if workers == 1:
        runs = [_task(s) for s in specs]
    else:
        # Largest records first, so that the pool ends with short tasks.
        order = sorted(range(len(specs)), key=lambda i: -specs[i]["n"])
        with ProcessPoolExecutor(max_workers=workers) as pool:
            done = list(pool.map(_task, [specs[i] for i in order], chunksize=1))
        runs = [None] * len(specs)
        for i, r in zip(order, done):
            runs[i] = r
    wall = time.perf_counter() - t0
    table = _summarise(runs, sizes, args.methods)
    meta = {
        "runs": args.runs,
        "noise": list(args.noise),
        "observer_model": args.observer_model,
        "fault": fault,
        "workers": workers,
        "wall_s": wall,
        "seed": args.seed,
        "python": sys.version.split()[0],
        "numpy": np.__version__,
        "machine": platform.platform(),
    }
    print(_format(table, sizes, meta))
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"meta": meta, "table": table, "runs": runs}, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
