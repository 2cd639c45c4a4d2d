"""The fault matrix: does ``diagnose`` name the right cause on the realistic bearing?

Each single-cause fault the simulator can plant (coil resistance, coil
constant, leakage inductance, amplifier gain per coil; rotor mass; air gap) at
1.5x and 3x its tolerance, ``seeds`` recordings each, plus ``healthy``
recordings of the nominal bearing, all on the realistic simulator: the
nonlinear magnet of eq. (1) under the nominal bias voltages (a fault moves the
operating point), the controller and observer designed on the nominal bearing,
sensor noise and -- where the simulator offers it -- a force disturbance.
Each recording is diagnosed against the design (``baseline="nominal"``) at the
default tolerance, as a user would.

Measured per fault level:

* **right cause**: verdict ``fault`` naming exactly the planted parameter;
* **detected**: ``fault`` or ``unexplained_change`` (something is wrong);
* **inconclusive**: the data could not resolve the tolerance;
* **wrong cause**: ``fault`` naming another parameter;
* **missed**: ``no_change`` or ``within_tolerance``;

and on the healthy recordings the **false-alarm** rate (``fault`` or
``unexplained_change``) and the inconclusive rate. Targets (issue 12): right
cause in >= 95 % at 3x tolerance, >= 80 % at 1.5x, false alarms <= 1 %.
A recording on which the loop loses the rotor (a fault the controller cannot
hold) is counted separately, not in the rates.

Run from the repository root::

    PYTHONPATH=src python -m benchmarks.bench_fault_matrix            # 5 seeds, 50 healthy
    PYTHONPATH=src python -m benchmarks.bench_fault_matrix --quick    # 1 seed, 10 healthy
    PYTHONPATH=src python -m benchmarks.bench_fault_matrix --workers 8 --out matrix.json

:func:`markdown_section` turns the results into the BENCHMARKS.md section.
"""

from __future__ import annotations

import argparse
import inspect
import json
import multiprocessing
import os
import platform
import sys
import time
from collections import Counter
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from maglevid.diagnose.compare import DEFAULT_TOLERANCE
from maglevid.diagnose.pipeline import diagnose
from maglevid.exceptions import MaglevidError
from maglevid.physics.amb import AMBParameters
from maglevid.simulate import simulate_amb_loop

#: Faults the simulator can plant, with the physical direction of each.
FAULTS: dict[str, int] = {
    "R1": +1, "R2": +1,      # heating, bad contact
    "K1": -1, "K2": -1,      # shorted turns
    "Ls1": +1, "Ls2": +1,    # leakage inductance
    "kw1": -1, "kw2": -1,    # amplifier / supply
    "m": +1,                 # added mass
    "x0": +1,                # wider air gap
}  # fmt: skip

#: Multiples of the tolerance at which each fault is planted.
LEVELS = (1.5, 3.0)

#: Sensor noise [m, A, A]: ~0.5 % of each channel's rms under the default
#: excitation (1.1 um, 2 mA) -- a good eddy-current probe and a shunt/Hall
#: current sensor at 10 kHz; the issue's "noise 0.5 % of each channel's rms".
NOISE_STD = (5e-9, 1e-5, 1e-5)

#: Record length [s] at the default 10 kHz.
RECORD_S = 5.0

#: Time the whole matrix may take in ``make bench`` [s]: with ``ml`` as the
#: diagnosis default (issue 13) each of the 170 diagnoses costs ~2-5 s of
#: maximum likelihood on a 5 s record, more than run_all's 600 s per task.
TIMEOUT_S = 2400

#: Workers in ``make bench`` (the matrix's recordings are independent).
DEFAULT_WORKERS = 2

NOMINAL = AMBParameters.nominal()


def simulator_options(record_s: float = RECORD_S, noise_std: Sequence[float] = NOISE_STD) -> dict:
    """The realistic simulator's options (a force disturbance where it is offered)."""
    opts: dict[str, Any] = {
        "nominal": NOMINAL,
        "plant_model": "nonlinear",
        "noise_std": tuple(noise_std),
        "n_samples": round(record_s / 1e-4),
        "dt": 1e-4,
    }
    if "force_std" in inspect.signature(simulate_amb_loop).parameters:
        # The simulator's realistic force disturbance on the rotor [N rms].
        from maglevid.simulate import amb

        opts["force_std"] = float(amb.DEFAULT_FORCE_STD)
    return opts


def run_case(case: Mapping[str, Any]) -> dict[str, Any]:
    """Simulate one recording and diagnose it; the outcome as a flat dict."""
    fault = dict(case["fault"])
    t0 = time.perf_counter()
    plant = NOMINAL.with_fault(**fault) if fault else NOMINAL
    out = {**case, "fault": fault}
    try:
        data = simulate_amb_loop(plant, rng=case["seed"], **case["options"])
    except MaglevidError as exc:
        return {**out, "outcome": "lost", "verdict_code": None, "why": str(exc)[:200]}
    d = diagnose(data, baseline="nominal")
    best = d.isolation.best.parameters if d.isolation is not None else ()
    out.update(
        verdict_code=d.verdict_code,
        verdict=d.verdict[:300],
        best=list(best),
        factors=list(d.isolation.best.factors) if d.isolation is not None else [],
        seconds=time.perf_counter() - t0,
    )
    out.pop("options")
    out["outcome"] = _outcome(fault, d.verdict_code, best)
    return out


def _outcome(fault: Mapping[str, float], code: str, best: Sequence[str]) -> str:
    if code == "cannot_diagnose":
        return "cannot_diagnose"
    if code == "inconclusive":
        return "inconclusive"
    if not fault:
        return "false_alarm" if code in ("fault", "unexplained_change") else "ok"
    if code == "fault":
        return "right" if tuple(best) == tuple(fault) else "wrong"
    if code == "unexplained_change":
        return "unexplained"
    return "missed"


def cases(
    *,
    seeds: int,
    healthy: int,
    record_s: float = RECORD_S,
    tolerance: float = DEFAULT_TOLERANCE,
    noise_std: Sequence[float] = NOISE_STD,
) -> list[dict[str, Any]]:
    """Every recording of the matrix (fault, level, seed, simulator options)."""
    opts = simulator_options(record_s, noise_std)
    out = []
    for name, sign in FAULTS.items():
        for level in LEVELS:
            factor = 1 + sign * level * tolerance
            for s in range(seeds):
                out.append(
                    {"fault": {name: factor}, "level": level, "seed": 1000 + s, "options": opts}
                )
    out += [{"fault": {}, "level": 0.0, "seed": 5000 + s, "options": opts} for s in range(healthy)]
    return out


def run_matrix(
    *,
    seeds: int = 5,
    healthy: int = 50,
    record_s: float = RECORD_S,
    workers: int = 1,
    noise_std: Sequence[float] = NOISE_STD,
) -> dict[str, Any]:
    """Run the matrix; rows per case and the rates (see module docs)."""
    todo = cases(seeds=seeds, healthy=healthy, record_s=record_s, noise_std=noise_std)
    t0 = time.perf_counter()
    load0 = os.getloadavg()
    if workers > 1:
        with multiprocessing.get_context("fork").Pool(workers) as pool:
            rows = pool.map(run_case, todo, chunksize=1)
    else:
        rows = [run_case(c) for c in todo]
    return {
        "rows": rows,
        "rates": rates(rows),
        "seeds": seeds,
        "healthy": healthy,
        "record_s": record_s,
        "noise_std": list(noise_std),
        "simulator": {
            k: v for k, v in simulator_options(record_s, noise_std).items() if k != "nominal"
        },
        "workers": workers,
        "wall_s": time.perf_counter() - t0,
        "load": [load0, os.getloadavg()],
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, "
        f"Python {sys.version.split()[0]}",
    }


def rates(rows: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, Any]]:
    """Outcome counts and rates per fault level ("healthy" for the nominal bearing)."""
    groups: dict[str, list[Mapping[str, Any]]] = {}
    for r in rows:
        key = "healthy" if not r["fault"] else f"{r['level']:g}x"
        groups.setdefault(key, []).append(r)
    out = {}
    for key, rs in groups.items():
        c = Counter(r["outcome"] for r in rs)
        n = sum(v for k, v in c.items() if k != "lost")
        frac = {k: (v / n if n else float("nan")) for k, v in c.items() if k != "lost"}
        out[key] = {"n": n, "lost": c.get("lost", 0), "counts": dict(c), "rates": frac}
    return out


def _pct(x: float | None) -> str:
    return "—" if x is None or not np.isfinite(x) else f"{100 * x:.0f} %"


def _noise_words(noise: Sequence[float]) -> str:
    """The noise relative to each channel's rms under the default excitation (1.1 um, 2 mA)."""
    rel = [noise[0] / 1.1e-6, noise[1] / 2e-3, noise[2] / 2e-3]
    return "about " + ", ".join(f"{100 * r:.2g} %" for r in rel) + " of each channel's rms"


def _judge(measured: float, target: float, *, at_most: bool = False) -> str:
    ok = measured <= target if at_most else measured >= target
    return "met" if ok else "**not met**"


def markdown_section(res: Mapping[str, Any]) -> list[str]:
    """The BENCHMARKS.md section: one table per level, the targets judged from the measurement."""
    r = res["rates"]
    sim = res["simulator"]
    disturbance = [k for k in sim if "force" in k or "disturb" in k]
    lines = [
        "## Fault matrix on the realistic bearing",
        "",
        f"Nonlinear magnet (eq. (1)) under the nominal bias voltages, controller and observer "
        f"designed on the nominal bearing, sensor noise {res['noise_std']} [m, A, A] "
        f"({_noise_words(res['noise_std'])}), "
        + (
            f"force disturbance {sim[disturbance[0]]:g} N rms on the rotor, "
            if disturbance
            else "no force disturbance, "
        )
        + f"{res['record_s']:g} s records at 10 kHz; each single-cause fault at 1.5x and 3x "
        f"the default ±{100 * DEFAULT_TOLERANCE:.0f} % tolerance, {res['seeds']} seeds each, "
        f"plus {res['healthy']} healthy recordings; `diagnose(..., baseline='nominal')`. "
        f"{res['wall_s']:.0f} s on {res['workers']} worker(s), {res['machine']}, load "
        f"{res['load'][0][0]:.1f} -> {res['load'][1][0]:.1f}.",
        "",
        "| recordings | n | right cause (healthy: no alarm) | wrong cause "
        "| unexplained (healthy: false alarm) | inconclusive | missed "
        "| cannot diagnose | loop lost the rotor |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for key in ("3x", "1.5x", "healthy"):
        if key not in r:
            continue
        g, q = r[key], r[key]["rates"]
        first = "ok" if key == "healthy" else "right"
        lines.append(
            f"| {key} | {g['n']} | {_pct(q.get(first, 0.0))} | {_pct(q.get('wrong', 0.0))} | "
            f"{_pct(q.get('unexplained', q.get('false_alarm', 0.0)))} | "
            f"{_pct(q.get('inconclusive', 0.0))} | {_pct(q.get('missed', 0.0))} | "
            f"{_pct(q.get('cannot_diagnose', 0.0))} | {g['lost']} |"
        )
    lines += ["", "| target | measured | |", "|---|---|---|"]
    for key, target in (("3x", 0.95), ("1.5x", 0.80)):
        if key in r:
            m = r[key]["rates"].get("right", 0.0)
            lines.append(
                f"| right cause at {key} tolerance >= {_pct(target)} | {_pct(m)} | "
                f"{_judge(m, target)} |"
            )
    if "healthy" in r:
        fa = r["healthy"]["rates"].get("false_alarm", 0.0)
        lines.append(f"| false alarms <= 1 % | {_pct(fa)} | {_judge(fa, 0.01, at_most=True)} |")
    lines += ["", "Per fault (right cause / n, all levels):", ""]
    per: dict[str, list[int]] = {}
    for row in res["rows"]:
        if row["fault"] and row["outcome"] != "lost":
            (k,) = row["fault"]
            acc = per.setdefault(f"{k} {row['level']:g}x", [0, 0])
            acc[0] += row["outcome"] == "right"
            acc[1] += 1
    lines.append(", ".join(f"{k}: {a}/{n}" for k, (a, n) in sorted(per.items())))
    lost = Counter(
        f"{next(iter(row['fault']))} {row['level']:g}x" for row in res["rows"]
        if row["outcome"] == "lost"
    )  # fmt: skip
    if lost:
        lines += [
            "",
            "The loop lost the rotor (not in the rates: the bearing would trip, no recording): "
            + ", ".join(f"{k} ({n})" for k, n in sorted(lost.items()))
            + ".",
        ]
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1 seed per fault, 10 healthy")
    ap.add_argument("--seeds", type=int, default=None)
    ap.add_argument("--healthy", type=int, default=None)
    ap.add_argument("--record-s", type=float, default=RECORD_S)
    ap.add_argument("--workers", type=int, default=DEFAULT_WORKERS)
    ap.add_argument(
        "--noise", type=float, nargs=3, default=NOISE_STD, metavar=("X", "I1", "I2"),
        help="sensor noise std [m A A] (default %(default)s)",
    )  # fmt: skip
    ap.add_argument("--out", default=None, help="write the results as JSON here")
    args = ap.parse_args(argv)
    seeds = args.seeds or (1 if args.quick else 5)
    healthy = args.healthy if args.healthy is not None else (10 if args.quick else 50)
    res = run_matrix(
        seeds=seeds,
        healthy=healthy,
        record_s=args.record_s,
        workers=args.workers,
        noise_std=args.noise,
    )
    if args.out:
        with open(args.out, "w", encoding="utf-8") as fh:
            json.dump(res, fh, indent=1, default=str)
    print("\n".join(markdown_section(res)))
    return 0


def markdown_from_json(path: str) -> list[str]:
    """The section again from a saved ``--out`` file (no re-run)."""
    with open(path, encoding="utf-8") as fh:
        return markdown_section(json.load(fh))


if __name__ == "__main__":
    sys.exit(main())
