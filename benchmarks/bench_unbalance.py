"""The bearing with a rotor's unbalance: maximum likelihood with and without its lines.

Monte Carlo of ``fit_ml`` (the diagnosis default) on the realistic bearing (nonlinear
plant under the nominal bias voltages, 0.1 N white force, the command line's sensor
noise, 30 000 samples) with a sinusoidal force on the rotor
(``simulate_amb_loop(unbalance=(N, Hz))``):

* ``no unbalance``: the reference (no line may be found);
* ``1 N at 50 Hz`` (G2.5 at 3000 rpm is 1.4 N on this rotor), ``1 N at 37.3 Hz``
  (between DFT bins), ``R1 x1.1, 1 N at 50 Hz`` (a fault moves the operating point);
* ``3 N at 50 Hz``: the position moves 4 % of the air gap, where the linearised model's
  bias starts to show (the fit's note warns above 3 %), reported, not judged;
* ``1 N at 50 Hz, periodic="none"``: the failure the profile removes, reported.

Truth: eq. (4) linearised where the bearing settles
(``metadata["operating_point_true"]["v"]``). Per case: RMS of the normalised errors of
v1..v9 and their 95 % coverage (pooled), the largest |z|, the lines found per record and
the median time per fit. docs/gosiewski.md, "Periodic disturbances".

Run from the repository root::

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python -m benchmarks.bench_unbalance --records 12
"""

from __future__ import annotations

import statistics
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numpy as np

from benchmarks.judge import calibration_bands

#: ``name -> (unbalance (N, Hz) or None, fault, periodic option, judged, method)``: the
#: method ``ml`` (the diagnosis default, lines profiled in its likelihood) or ``pbsid`` /
#: ``ssarx`` through the registry in physical coordinates (lines taken out of the record
#: before the fit, twenty-second session).
CASES: dict[str, tuple[Any, dict[str, float], Any, bool, str]] = {
    "no unbalance": (None, {}, "auto", True, "ml"),
    "1 N at 50 Hz": ((1.0, 50.0), {}, "auto", True, "ml"),
    "1 N at 37.3 Hz": ((1.0, 37.3), {}, "auto", True, "ml"),
    "R1 x1.1, 1 N at 50 Hz": ((1.0, 50.0), {"R1": 1.1}, "auto", True, "ml"),
    "3 N at 50 Hz": ((3.0, 50.0), {}, "auto", False, "ml"),
    '1 N at 50 Hz, periodic="none"': ((1.0, 50.0), {}, "none", False, "ml"),
    "PBSID-opt, no unbalance": (None, {}, "auto", True, "pbsid"),
    "PBSID-opt, 1 N at 50 Hz": ((1.0, 50.0), {}, "auto", True, "pbsid"),
    "SSARX, 1 N at 50 Hz": ((1.0, 50.0), {}, "auto", True, "ssarx"),
    'PBSID-opt, 1 N at 50 Hz, periodic="none"': ((1.0, 50.0), {}, "none", False, "pbsid"),
}
RECORDS = 12
SEED0 = 34001
N_SAMPLES = 30_000


def one_record(case: str, seed: int) -> dict[str, Any]:
    """One record of ``case``: z of v1..v9 against the settled point, lines, time."""
    from maglevid.identify.ml import fit_ml
    from maglevid.identify.registry import get_method
    from maglevid.physics.amb import V_NAMES, AMBParameters
    from maglevid.simulate.amb import simulate_amb_loop

    unbalance, fault, periodic, _, method = CASES[case]
    nominal = AMBParameters.nominal()
    rec = simulate_amb_loop(nominal.with_fault(**fault), nominal=nominal, n_samples=N_SAMPLES,
                            rng=seed, unbalance=unbalance)  # fmt: skip
    truth = np.asarray(rec.metadata["operating_point_true"]["v"])
    t0 = time.perf_counter()
    try:
        if method == "ml":
            res = fit_ml(rec, periodic=periodic)
        else:
            res = get_method(method)(rec, coordinates="physical", periodic=periodic)
    except Exception as exc:  # a failure is a result here
        return {"case": case, "seed": seed, "error": f"{type(exc).__name__}: {exc}"[:200]}
    dt = time.perf_counter() - t0
    v = np.array([res.parameters[k] for k in V_NAMES])
    se = np.array([res.std_errors()[k] for k in V_NAMES])
    return {
        "case": case,
        "seed": seed,
        "time_s": dt,
        "z": ((v - truth) / se).tolist(),
        "lines_hz": np.asarray(res.extras.get("periodic_hz", ())).tolist(),
    }


def run(records: int = RECORDS, workers: int = 2) -> dict[str, Any]:
    jobs = [(case, SEED0 + k) for case in CASES for k in range(records)]
    with ProcessPoolExecutor(max_workers=workers) as ex:
        rows = list(ex.map(one_record, *zip(*jobs, strict=True)))
    return {"records": records, "summary": {c: _summary(rows, c) for c in CASES}}


def _summary(rows: list[dict[str, Any]], case: str) -> dict[str, Any]:
    rs = [r for r in rows if r["case"] == case]
    ok = [r for r in rs if "z" in r]
    if not ok:
        return {"records": len(rs), "failed": len(rs), "errors": [r.get("error") for r in rs]}
    z = np.array([r["z"] for r in ok])
    return {
        "records": len(rs),
        "failed": len(rs) - len(ok),
        "rms_z": float(np.sqrt(np.mean(z**2))),
        "cover95": float(np.mean(np.abs(z) < 1.959964)),
        "max_abs_z": float(np.max(np.abs(z))),
        "lines_per_record": float(np.mean([len(r["lines_hz"]) for r in ok])),
        "first_line_hz": [r["lines_hz"][0] for r in ok if r["lines_hz"]],
        "time_s": statistics.median(r["time_s"] for r in ok),
    }


def markdown_section(result: dict[str, Any]) -> list[str]:
    n = result["records"]
    L = [
        "## The bearing with a rotor's unbalance: ML, PBSID-opt, SSARX and the lines",
        "",
        f"`python -m benchmarks.bench_unbalance` ({n} records per case, the realistic "
        f"bearing, {N_SAMPLES} samples; truth: the linearisation where it settles). v1..v9 "
        "pooled: RMS of the normalised errors, 95 % coverage, largest |z|; the lines the "
        "method found per record (the first one's frequency); median time per fit. `ml` "
        "profiles the lines in its likelihood; PBSID-opt and SSARX (structured fit, through "
        "the registry in physical coordinates) take them out of the record first. "
        'docs/gosiewski.md, "Periodic disturbances".',
        "",
        "| case | records (failed) | RMS z | coverage | max abs(z) | lines per record | "
        "first line [Hz] | time per fit |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for case, s in result["summary"].items():
        if "rms_z" not in s:
            L.append(f"| {case} | {s['records']} ({s['failed']}) | - | - | - | - | - | - |")
            continue
        f = s["first_line_hz"]
        fl = "-" if not f else f"{min(f):.3f} - {max(f):.3f}"
        L.append(
            f"| {case} | {s['records']} ({s['failed']}) | {s['rms_z']:.2f} | "
            f"{s['cover95']:.3f} | {s['max_abs_z']:.1f} | {s['lines_per_record']:.1f} | {fl} | "
            f"{s['time_s']:.2f} s |"
        )
    return L


def targets(result: dict[str, Any], judge: Any) -> None:
    """On the judged cases the intervals hold the settled point (pooled v1..v9: RMS z and
    coverage within the bands a calibrated estimator keeps on this many records), no
    record fails, and a line is found exactly where there is one (at its frequency to
    0.01 Hz)."""
    for case, (unbalance, _, _, judged, method) in CASES.items():
        s = result["summary"][case]
        if not judged:
            continue
        if "rms_z" not in s or s["failed"]:
            judge.add(f"bearing with unbalance, {case}: every record fitted", "no measurement",
                      None)  # fmt: skip
            continue
        n = s["records"]
        (r_lo, r_hi), (c_lo, c_hi) = calibration_bands(n)
        judge.add(
            f"bearing with unbalance, {case}: {method}'s 95 % intervals cover the settled point "
            "(v1..v9 pooled; the bands a calibrated estimator keeps on this many records, 98 %)",
            f"coverage {s['cover95']:.3f} in [{c_lo:.2f}, {c_hi:.2f}], RMS z "
            f"{s['rms_z']:.2f} in [{r_lo:.2f}, {r_hi:.2f}] over {n} records",
            c_lo <= s["cover95"] <= c_hi and r_lo <= s["rms_z"] <= r_hi,
        )
        if unbalance is None:
            ok, said = s["lines_per_record"] == 0, f"{s['lines_per_record']:.1f} lines per record"
        else:
            f = s["first_line_hz"]
            ok = len(f) == n and all(abs(x - unbalance[1]) <= 0.01 for x in f)
            said = f"first line on {len(f)} of {n} records, at {min(f, default=0):.3f}-" \
                   f"{max(f, default=0):.3f} Hz"  # fmt: skip
        judge.add(f"bearing with unbalance, {case}: the line found where there is one, and "
                  "only there", said, ok)  # fmt: skip


def _measure(run_: Any, plan: dict[str, Any], args: Any) -> dict[str, Any]:
    records = 4 if plan.get("quick") else RECORDS
    out: dict[str, Any] = run_.call("benchmarks.bench_unbalance:run", records=records, workers=1)
    return out


try:  # run_all's section registry (benchmarks/sections.py)
    from benchmarks.sections import Section
except ImportError:  # pragma: no cover
    pass
else:
    SECTION = Section("unbalance", _measure, markdown_section, targets)


def main(argv: list[str] | None = None) -> int:
    from benchmarks.sections import records_main

    return records_main(argv, doc=__doc__ or "", run=run, report=markdown_section, records=RECORDS)


if __name__ == "__main__":
    raise SystemExit(main())
