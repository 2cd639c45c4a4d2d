"""The inter-sampled suspension on the hard case: Sun et al.'s method against maximum likelihood.

Monte Carlo of ``fit_intersample`` (Sun et al., with our output-error refinement) and
``fit_intersample_ml`` (maximum likelihood on every inter-sample, the kind's default)
on the same records, 18 s at p = 3 under the lead-lag controller:

* ``linear``: the paper's simulation (eq. (27), 0.1 mm sensor noise alone);
* ``nonlinear``: eq. (25) by RK4 at the same noise;
* ``nonlinear + force``: 0.05 mm noise and a 0.05 N rms force on the ball (1 % of its
  weight), held per output sample;
* ``nonlinear, 0.1 N``: 0.1 mm noise and 0.1 N.

Truth: the simulator's linearisation at the operating point (``metadata["truth"]``).
Per method and parameter: the mean relative error (bias), its scatter, the mean stated
standard error (for ML the Cramér-Rao bound at the estimate), RMS of the normalised
errors, coverage of the 95 % intervals, and the records without physical parameters.

Run from the repository root::

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python -m benchmarks.bench_suspension_hard
    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python -m benchmarks.bench_suspension_hard --records 8
"""

from __future__ import annotations

import statistics
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numpy as np

from benchmarks.judge import calibration_bands

#: ``name -> (plant, sensor noise [m], force [N rms])``.
CASES: dict[str, tuple[str, float, float]] = {
    "linear": ("linear", 1e-4, 0.0),
    "nonlinear": ("nonlinear", 1e-4, 0.0),
    "nonlinear + force": ("nonlinear", 5e-5, 0.05),
    "nonlinear, 0.1 N": ("nonlinear", 1e-4, 0.1),
}
METHODS = ("intersample", "intersample-ml")
PARAMETERS = ("pole_rad_s", "alpha", "eta", "L", "gap", "Q")
RECORDS = 24
SEED0 = 7000


def one_record(case: str, seed: int) -> dict[str, Any]:
    """Both fits on one record: estimates, standard errors, truth, times."""
    from maglevid.identify.intersample import fit_intersample
    from maglevid.identify.intersample_ml import fit_intersample_ml
    from maglevid.simulate.suspension import simulate_suspension

    plant, noise, force = CASES[case]
    rec = simulate_suspension(p=3, plant=plant, noise_std=noise, force_std=force, rng=seed)
    truth = rec.metadata["truth"]
    tv = {"pole_rad_s": truth["continuous_poles"][0], **dict(truth["parameters"])}
    out: dict[str, Any] = {"case": case, "seed": seed, "truth": {k: tv[k] for k in PARAMETERS}}
    for name, fit in (("intersample", fit_intersample), ("intersample-ml", fit_intersample_ml)):
        t0 = time.perf_counter()
        try:
            res = fit(rec)
        except Exception as exc:  # a failure is a result here
            out[name] = {"error": f"{type(exc).__name__}: {exc}"[:200]}
            continue
        se = res.std_errors()
        out[name] = {
            "time_s": time.perf_counter() - t0,
            "est": {k: res.parameters.get(k) for k in PARAMETERS},
            "se": {k: se.get(k) for k in PARAMETERS},
        }
    return out


def run(records: int = RECORDS, workers: int = 2) -> dict[str, Any]:
    jobs = [(case, SEED0 + 100 * i + k) for i, case in enumerate(CASES) for k in range(records)]
    with ProcessPoolExecutor(max_workers=workers) as ex:
        rows = list(ex.map(one_record, *zip(*jobs, strict=True)))
    return {"records": records, "summary": summarise(rows)}


def summarise(rows: list[dict[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for case in CASES:
        rs = [r for r in rows if r["case"] == case]
        out[case] = {m: _method_summary(rs, m) for m in METHODS}
    return out


def _method_summary(rs: list[dict[str, Any]], method: str) -> dict[str, Any]:
    ok = [r for r in rs if "est" in r[method] and r[method]["est"]["alpha"] is not None]
    summ: dict[str, Any] = {
        "records": len(rs),
        "without_physical": len(rs) - len(ok),
        "time_s": statistics.median(r[method]["time_s"] for r in rs if "time_s" in r[method])
        if any("time_s" in r[method] for r in rs)
        else None,
    }
    for k in PARAMETERS:
        rel = np.array([r[method]["est"][k] / r["truth"][k] - 1.0 for r in ok])
        se = np.array([r[method]["se"][k] / abs(r["truth"][k]) for r in ok])
        z = np.array([(r[method]["est"][k] - r["truth"][k]) / r[method]["se"][k] for r in ok])
        if not ok:
            summ[k] = None
            continue
        summ[k] = {
            "bias": float(rel.mean()),
            "sd": float(rel.std(ddof=1)) if rel.size > 1 else None,
            "mean_se": float(se.mean()),
            "rms_z": float(np.sqrt(np.mean(z**2))),
            "cover95": float(np.mean(np.abs(z) < 1.959964)),
        }
    return summ


def markdown_section(result: dict[str, Any]) -> list[str]:
    n = result["records"]
    L = [
        "## The inter-sampled suspension on the hard case: Sun et al. against maximum likelihood",
        "",
        f"`python -m benchmarks.bench_suspension_hard` ({n} records per case, 18 s at p = 3, "
        "lead-lag controller; truth: the linearisation at the operating point). Per "
        "parameter: bias (mean relative error) / scatter / mean stated standard error, all "
        '%; RMS of the normalised errors; 95 % coverage. docs/sun.md, "Beyond the paper".',
        "",
        "| case | method | records without physics | time per fit | "
        + " | ".join(PARAMETERS)
        + " |",
        "|---|---|---|---|" + "---|" * len(PARAMETERS),
    ]
    for case, by_method in result["summary"].items():
        for m, s in by_method.items():
            cells = []
            for k in PARAMETERS:
                v = s.get(k)
                cells.append(
                    "-"
                    if v is None
                    else f"{100 * v['bias']:+.1f} / {100 * (v['sd'] or 0):.1f} / "
                    f"{100 * v['mean_se']:.1f}; z {v['rms_z']:.2f}; {v['cover95']:.2f}"
                )
            t = "-" if s["time_s"] is None else f"{s['time_s']:.1f} s"
            L.append(
                f"| {case} | {m} | {s['without_physical']}/{s['records']} | {t} | "
                + " | ".join(cells)
                + " |"
            )
    return L


def targets(result: dict[str, Any], judge: Any) -> None:
    """ML's intervals hold the linearisation on every case (pooled alpha, eta, L, pole:
    RMS z and coverage within the bands a calibrated estimator keeps on this many
    records, :func:`calibration_bands`) and no bias is resolved (each mean error within
    3 of its standard errors, ``sd / sqrt(records)``)."""
    pooled = ("pole_rad_s", "alpha", "eta", "L")
    for case, by_method in result["summary"].items():
        s = by_method["intersample-ml"]
        if any(s.get(k) is None for k in pooled):
            judge.add(f"suspension intersample-ml, {case}: intervals", "no measurement", None)
            continue
        n = s["records"] - s["without_physical"]
        (r_lo, r_hi), (c_lo, c_hi) = calibration_bands(n)
        cover = float(np.mean([s[k]["cover95"] for k in pooled]))
        rms = float(np.sqrt(np.mean([s[k]["rms_z"] ** 2 for k in pooled])))
        judge.add(
            f"suspension intersample-ml, {case}: 95 % intervals cover the linearisation "
            "(alpha, eta, L, pole pooled; the bands a calibrated estimator keeps on this "
            "many records, 98 %)",
            f"coverage {cover:.3f} in [{c_lo:.2f}, {c_hi:.2f}], RMS z {rms:.2f} in "
            f"[{r_lo:.2f}, {r_hi:.2f}] over {n} records",
            c_lo <= cover <= c_hi and r_lo <= rms <= r_hi,
        )
        worst = max(abs(s[k]["bias"]) / (s[k]["sd"] / np.sqrt(n)) for k in pooled if s[k]["sd"])
        judge.add(
            f"suspension intersample-ml, {case}: no bias resolved (mean error within 3 "
            "of its standard errors)",
            f"largest |mean error| / its standard error {worst:.2f} over {n} records",
            worst < 3.0,
        )


def _measure(run_: Any, plan: dict[str, Any], args: Any) -> dict[str, Any]:
    records = 8 if plan.get("quick") else RECORDS
    out: dict[str, Any] = run_.call(
        "benchmarks.bench_suspension_hard:run", records=records, workers=1
    )
    return out


try:  # run_all's section registry (benchmarks/sections.py)
    from benchmarks.sections import Section
except ImportError:  # pragma: no cover
    pass
else:
    SECTION = Section("suspension_hard", _measure, markdown_section, targets)


def main(argv: list[str] | None = None) -> int:
    from benchmarks.sections import records_main

    return records_main(argv, doc=__doc__ or "", run=run, report=markdown_section, records=RECORDS)


if __name__ == "__main__":
    raise SystemExit(main())
