"""Monte Carlo of the AMB estimators against the Cramér-Rao bound (issue 13).

Run from the repository root::

    python -m benchmarks.bench_ml_crb --quick          # 20 records at N = 1e4, ~1 min
    python -m benchmarks.bench_ml_crb --json ml.json   # the make-bench plan, ~65 min (PLAN)
    python -m benchmarks.bench_ml_crb --n 1000000      # the plan's points at one N only

``make bench`` runs the same plan as a section (``SECTION``; each point in its
own worker process with its own time budget, so a slow point loses records,
not the section).

For every point (plant, noise level, record length N) up to ``runs``
closed-loop records of the two-coil bearing are simulated
(:func:`simulate_amb_loop`, controller and deadbeat observer designed on the
nominal bearing, 1 V rms white excitation; seeds differ between points, so
two points are two independent draws) and identified by

* ``LS``  -- ``physical`` with ``estimator="ls"`` (errors in variables: biased),
* ``IV``  -- ``physical`` (the default method),
* ``ML``  -- ``ml`` started from IV (sensor noise levels and force estimated),
* ``DB``  -- ``deadbeat-iv`` (the paper's deadbeat-observer route, IV),
* ``MOESP`` -- ``moesp`` (order 4, ``u`` as input) taken to physical
  coordinates (:func:`~maglevid.identify.physical.to_physical_coordinates`);
  no covariance, so no coverage;

and ML a second time started at the truth: the two must reach the same
optimum (records where they differ by more than 0.01 standard errors in any
v_i, or where either did not converge, are counted).

Per method and parameter: the bias (mean error), the standard deviation, the
coverage of the stated 95 % intervals and the ratio of the standard
deviation to the Cramér-Rao bound (:func:`design_information`: the linear
model at the truth with the sensor noise levels unknown, the model ML fits).

ML's bias, antithetic: ML is fitted also on the record's twin with the sensor
noise negated (same seed, same excitation; :func:`_mirror`, simulated in the
record's batch by :func:`records`), and the bias is
the mean of the pair means ``(e(+n) + e(-n)) / 2``, in which the error's part
odd in the noise (its first-order, zero-mean part) cancels. ``-n`` has the law
of ``n``, so the pair mean is unbiased on either plant; on the linear one the
twin is exactly ``2 d(r, 0) - d(r, n)`` (tested). Its standard error is ~0.02
std with 100 pairs, against 0.1 std for the plain mean of 100 records -- which
cannot tell a bias of 0.2 std from none (docs/gosiewski.md, section 10: the
nonlinear 1e4 point's plain-mean "bias" of 0.30 +- 0.10 std was that).

Record counts: a point is judged only with at least :data:`MIN_RECORDS`
records (the notes there); fewer are reported and listed as not measured.
Where a record's time goes is recorded per record (``stages``) and printed.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import platform
import time
import zlib
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from typing import Any

import numpy as np

from maglevid.experiments._parallel import one_blas_thread, start_method
from maglevid.identify.cramer_rao import (
    NoiseModel,
    amb_linear_gaussian_model,
    derived_parameters,
    predictor_statistics,
)
from maglevid.identify.ml import fit_ml
from maglevid.identify.physical import fit_physical, to_physical_coordinates
from maglevid.identify.planning import design_information, model_error_level
from maglevid.identify.registry import get_method
from maglevid.physics.amb import V_NAMES, AMBParameters, v_from_matrices
from maglevid.simulate.amb import (
    DEFAULT_NOISE_STD,
    DEFAULT_SUBSTEPS,
    simulate_amb_loop,
    simulate_amb_loops,
)

#: Parameters reported (v1..v9 and the physical parameters a diagnosis names).
REPORTED = (*V_NAMES, "R1", "R2", "L1", "L2", "ki1", "ki2", "kw1", "kw2", "x0")

#: Method labels, in table order.
METHODS = ("LS", "IV", "ML", "DB", "MOESP")

#: RK4 steps per sample of the nonlinear plant here (the simulator's default is
#: 4): the same record to 3e-6 of the sensor noise (measured: 2e4 samples, max
#: |y(1) - y(4)| / noise std <= 2.7e-6 per channel; ML's v_i differ by <= 2e-5
#: standard errors) at a quarter of the RK4 work: ~1.8x less simulation time
#: (the observer/controller part of the per-sample loop stays). Tested.
SUBSTEPS = 1

#: LS is fitted up to this N only: it refuses every noisy record (errors in
#: variables; 100 of 100 at every N = 1e4 point of the last runs), and each
#: refusal costs an IV-sized fit. Its column is "-" beyond.
LS_MAX_N = 10_000

NOISE_LEVELS = {"default": 1.0, "0.3x": 0.3, "3x": 3.0}
PLANTS = {"linear": {"R1": 1.2}, "nonlinear": {}}  # plant model -> fault
SIZES = (10_000, 100_000, 1_000_000)

#: The make-bench plan: (plant, noise level, N, records at most, time budget [s]).
#: The issue's whole grid, every point to 100 records. Per record on one worker
#: (one BLAS thread; at the section's load ~2 wall is about CPU): linear 1e4
#: ~0.7 s, nonlinear 1e4 ~1.0 s, linear 1e5 ~2.2 s, nonlinear 1e5 ~2-3 s (its
#: two simulations batched: was 3.4 s), linear 1e6 ~7 s (simulations 0.8, IV
#: 0.6, ML from IV 1.0, from the truth 1.2, the twin's ML 2.1, DB 0.8, MOESP
#: 0.4), nonlinear 1e6 ~10-13 s (was ~22 s: the record and its twin are now
#: simulated in batches of :func:`batch_size` records + twins, ~5-7 s a record
#: instead of 15; the fits ~5 s). Measured: a reduced nonlinear default 1e6 run
#: (docs/gosiewski.md, "The plan and its budget"). Expected wall on 2 workers:
#: 3 x 35 + 3 x 45 + 3 x 110 + 3 x 130 + 3 x 350 + 3 x ~600 s = ~3800 s, plus
#: the bounds and the 1e5 timing (~30 s): **~65 min** (~25 min before, without
#: the five 1e6 points linear 0.3x/3x and nonlinear default/0.3x/3x). The budgets
#: are caps for a loaded machine, not the estimate.
PLAN: tuple[tuple[str, str, int, int, float], ...] = (
    ("linear", "default", 10_000, 100, 100.0),
    ("linear", "0.3x", 10_000, 100, 100.0),
    ("linear", "3x", 10_000, 100, 100.0),
    ("nonlinear", "default", 10_000, 100, 150.0),
    ("nonlinear", "0.3x", 10_000, 100, 150.0),
    ("nonlinear", "3x", 10_000, 100, 150.0),
    ("linear", "default", 100_000, 100, 300.0),
    ("linear", "0.3x", 100_000, 100, 300.0),
    ("linear", "3x", 100_000, 100, 300.0),
    ("nonlinear", "default", 100_000, 100, 600.0),
    ("nonlinear", "0.3x", 100_000, 100, 600.0),
    ("nonlinear", "3x", 100_000, 100, 600.0),
    ("linear", "default", 1_000_000, 100, 900.0),
    ("linear", "0.3x", 1_000_000, 100, 900.0),
    ("linear", "3x", 1_000_000, 100, 900.0),
    ("nonlinear", "default", 1_000_000, 100, 1200.0),
    ("nonlinear", "0.3x", 1_000_000, 100, 1200.0),
    ("nonlinear", "3x", 1_000_000, 100, 1200.0),
)
QUICK_PLAN = (("linear", "default", 10_000, 20, 60.0),)

#: The time target's record length and repeats (one process, same data).
TIMING_N, TIMING_REPEATS = 100_000, 3


def point_label(plant: str, level: str, n: int) -> str:
    fault = "R1x1.2" if PLANTS[plant] else "healthy"
    return f"{plant} {fault}, noise {level}, N={int(n)}"


def _truth(data: Any) -> dict[str, float]:
    """True parameters: the linearisation at the (settled) operating point."""
    op = data.metadata.get("operating_point_true")
    v = np.asarray(op["v"] if op else data.metadata["truth_v"], dtype=float)
    return _with_derived(v, data)


def _with_derived(v: np.ndarray, data: Any) -> dict[str, float]:
    op = data.loop["operating_point"]
    names, vals = derived_parameters(v, m=op["m"], i0=op["i0"])
    return dict(zip((*V_NAMES, *names), np.concatenate([v, vals]).tolist()))


def _moesp_physical(data: Any) -> tuple[dict[str, float], None]:
    """MOESP (order 4) taken to physical coordinates; no covariance."""
    res = get_method("moesp")(data, order=4)
    _, cont = to_physical_coordinates(res.model)
    v, _ = v_from_matrices(cont.A, cont.B)
    return _with_derived(np.asarray(v, dtype=float), data), None


def _fit(
    name: str, data: Any, iv: Any = None
) -> tuple[dict[str, float], dict[str, float] | None, Any]:
    """(estimates, standard errors or None, result) of one method; ML starts from
    ``iv``, this record's IV result (the start ``fit_ml`` would compute again)."""
    if name == "MOESP":
        est, se = _moesp_physical(data)
        return est, se, None
    fit = {
        "LS": lambda d: fit_physical(d, estimator="ls"),
        "IV": fit_physical,
        "ML": lambda d: fit_ml(d, start="physical" if iv is None else iv),
        "DB": get_method("deadbeat-iv"),
    }[name]
    res = fit(data)
    return dict(res.parameters), res.std_errors(), res


def methods_at(n: int) -> tuple[str, ...]:
    """The methods fitted at record length ``n``: LS only up to :data:`LS_MAX_N`."""
    return tuple(m for m in METHODS if m != "LS" or n <= LS_MAX_N)


class _NegatedNoise(np.random.Generator):
    """A generator whose ``(n, 3)`` standard-normal draw (the sensor noise of
    :func:`simulate_amb_loop`, drawn after the excitation) comes out negated:
    the same record with the noise ``-n`` (same excitation, same force draw)."""

    def standard_normal(self, size: Any = None, dtype: Any = np.float64, out: Any = None) -> Any:
        x = super().standard_normal(size, dtype, out)
        return -x if isinstance(size, tuple) and len(size) == 2 and size[1] == 3 else x


def _twin_rng(rng: int) -> np.random.Generator:
    """The generator of a record's antithetic twin: same seed, sensor noise negated."""
    return _NegatedNoise(np.random.default_rng(rng).bit_generator)


def _mirror(data: Any, spec: dict[str, Any], rng: int) -> Any:
    """The record with its sensor noise negated, d(r, -n), simulated again.

    On the linear plant this is ``2 d(r, 0) - d(r, n)`` (tested); on the
    nonlinear one it is the only way to it, and ``-n`` has the law of ``n``, so
    the pair mean is an unbiased estimate of the error's mean whatever the
    plant (the variance reduction is that of the error's part odd in ``n``).
    :func:`records` simulates the twins in the records' batch instead (the same
    arrays, bit for bit)."""
    return _check_twin(data, _simulate(spec, _twin_rng(rng)))


def _check_twin(data: Any, twin: Any) -> Any:
    if not np.array_equal(np.asarray(twin.r), np.asarray(data.r)):
        raise RuntimeError("the twin's excitation differs: the simulator's draw order changed")
    return twin


def _sim_options(spec: dict[str, Any], noise: Any = None) -> dict[str, Any]:
    """simulate_amb_loop's arguments for one point (``noise`` overrides the spec's)."""
    nominal = AMBParameters.nominal()
    opts: dict[str, Any] = {
        "nominal": nominal,
        "n_samples": spec["n"],
        "noise_std": spec["noise"] if noise is None else noise,
        "plant_model": spec["plant"],
        # No force disturbance: the bound here is the sensor-noise model's; the
        # realistic bearing with its 0.1 N force is bench_ml_realistic.py.
        "force_std": 0.0,
        "substeps": SUBSTEPS if spec["plant"] == "nonlinear" else DEFAULT_SUBSTEPS,
    }
    opts["excitation_std"] = spec.get("excitation_std", BENCH_EXCITATION_STD)
    return opts


def _simulate(spec: dict[str, Any], rng: Any, noise: Any = None) -> Any:
    nominal = AMBParameters.nominal()
    plant = nominal.with_fault(**PLANTS[spec["plant"]])
    return simulate_amb_loop(plant, rng=rng, **_sim_options(spec, noise))


def _record_seed(spec: dict[str, Any]) -> int:
    label = zlib.crc32(spec["label"].encode())
    return int(np.random.SeedSequence([spec["seed"], label, spec["run"]]).generate_state(1)[0])


def records(specs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Simulate the records of ``specs`` (one point) and their twins in one batch
    (:func:`~maglevid.simulate.amb.simulate_amb_loops`, each record bit for bit
    :func:`_simulate` of its seed), then fit them one by one (module-level: pickled).

    Each record's ``stages["simulate"]`` is its share of the batch (the batch's
    time over its records: the record and its twin)."""
    seeds = [_record_seed(sp) for sp in specs]
    nominal = AMBParameters.nominal()
    plant = nominal.with_fault(**PLANTS[specs[0]["plant"]])
    t0 = time.perf_counter()
    sims = simulate_amb_loops(
        plant, rngs=[*seeds, *(_twin_rng(r) for r in seeds)], **_sim_options(specs[0])
    )
    share = (time.perf_counter() - t0) / len(specs)
    k = len(specs)
    out = []
    for i, spec in enumerate(specs):
        d, twin = sims[i], sims[k + i]
        sims[i] = sims[k + i] = None  # the record's memory goes with its fits
        out.append(_fit_record(spec, d, twin, share))
    return out


def one_record(spec: dict[str, Any]) -> dict[str, Any]:
    """One record (and its twin) simulated and fitted by every method: :func:`records`."""
    return records([spec])[0]


def _fit_record(spec: dict[str, Any], d: Any, twin: Any, sim_s: float) -> dict[str, Any]:
    """Fit one record by every method, ML also from the truth and on its twin.

    ``out["stages"]`` holds where the record's time went [s]: the simulation
    (its share of the batch, twin included), each method, ML from the truth and
    the twin's ML."""
    stages = {"simulate": sim_s}
    truth = _truth(d)
    out: dict[str, Any] = {"truth": truth, "stages": stages}
    iv = None
    for name in methods_at(spec["n"]):
        t0 = time.perf_counter()
        try:
            est, se, res = _fit(name, d, iv)
        except Exception as exc:  # a failure is a result of the benchmark, recorded
            out[name] = {"error": str(exc)[:200]}
            stages[name] = time.perf_counter() - t0
            continue
        dt_fit = time.perf_counter() - t0
        if name == "IV":
            iv = res
        elif name == "ML" and iv is not None:
            dt_fit += out["IV"]["time"]  # ML's time includes its start, as a user's call
        out[name] = {
            "est": {k: est[k] for k in REPORTED if k in est},
            "se": None if se is None else {k: se[k] for k in REPORTED if k in se},
            "time": dt_fit,
        }
        stages[name] = time.perf_counter() - t0
        if name == "ML":
            out[name].update(_ml_extras(d, res, out[name], truth, twin, stages))
    return out


def whitened_error(res: Any, v_true: np.ndarray) -> float:
    """``e^T C^-1 e`` of ML's v1..v9 error ``e`` under its stated covariance ``C``.

    Chi-square with 9 degrees of freedom where the intervals are honest, so its
    mean over a point's records / 9 is 1 within ``sqrt(2 / (9 records))``: a
    check of the intervals that uses the parameters' correlations. The pooled
    coverage the bench judges is much noisier than its binomial error suggests,
    because the 9 parameters' errors move together (at linear 3x 1e6 its
    Monte Carlo sd is ~0.01 at 100 records; docs/gosiewski.md, "ML's coverage
    at linear 3x noise")."""
    e = np.array([res.parameters[k] for k in V_NAMES]) - v_true
    return float(e @ np.linalg.solve(np.asarray(res.covariance)[:9, :9], e))


def _ml_extras(
    d: Any,
    res: Any,
    row: dict[str, Any],
    truth: dict[str, float],
    twin: Any,
    stages: dict[str, float],
) -> dict[str, Any]:
    """ML from the truth (same optimum?), restarts, and the antithetic twin's estimate."""
    x: dict[str, Any] = {
        "converged": bool(res.extras["converged"]),
        "iterations": int(res.extras["iterations"]),
        "restarted": any("nominal bearing" in n or "from the nominal" in n for n in res.notes),
    }
    vi = np.array([row["est"][k] for k in V_NAMES])
    se = np.array([row["se"][k] for k in V_NAMES])
    x["chi2"] = whitened_error(res, np.array([truth[k] for k in V_NAMES]))
    t0 = time.perf_counter()
    try:
        rt = fit_ml(d, start=np.array([truth[k] for k in V_NAMES]))
        vt = np.array([rt.parameters[k] for k in V_NAMES])
        gap = float(np.max(np.abs(vi - vt) / se))
        x["gap_to_truth_start_se"] = gap
        x["same_optimum"] = bool(gap < 0.01 and rt.extras["converged"] and x["converged"])
    except Exception as exc:  # recorded as a convergence failure
        x["same_optimum"] = False
        x["truth_start_error"] = str(exc)[:200]
    stages["ML from the truth"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    try:
        tw = fit_ml(_check_twin(d, twin))
        if tw.extras["converged"]:
            x["twin_est"] = {k: tw.parameters[k] for k in REPORTED}
        else:  # a twin that did not converge is left out of the bias, counted
            x["twin_error"] = "did not converge"
    except Exception as exc:  # the pair is left out of the antithetic bias
        x["twin_error"] = str(exc)[:200]
    stages["twin ML"] = time.perf_counter() - t0
    return x


#: Records simulated together on the nonlinear plant (each with its twin, so the
#: batch is twice this): the vectorised loop's per-sample overhead (~45 us) is
#: paid once per batch, ~0.8 us a sample per record on top (docs/control-and-
#: simulation.md). At most :data:`BATCH_SAMPLES` samples of records a batch:
#: ~170 bytes a record-sample while it is simulated (measured peak RSS: 2.4 GB
#: for 8 records of 1e6 + twins, fits included), so 10 records of 1e6 ~3 GB,
#: inside run_all's 8 GB address-space limit per worker; and at most
#: :data:`BATCH_MAX` records (4 batches of a 100-record point). The linear
#: plant, vectorised in time already, runs a record and its twin per batch.
BATCH_SAMPLES, BATCH_MAX = 10_000_000, 25


def batch_size(plant: str, n: int) -> int:
    """Records per batch (:data:`BATCH_SAMPLES`)."""
    if plant != "nonlinear":
        return 1
    return max(1, min(BATCH_MAX, BATCH_SAMPLES // int(n)))


def _map_until(specs: list[dict[str, Any]], workers: int, budget_s: float) -> list[Any]:
    """:func:`records` over batches of ``specs`` on ``workers`` processes within ``budget_s``.

    ``workers`` batches (:func:`batch_size` records each) are kept in flight; a
    new one is started only while the time spent plus the slowest batch so far
    fits the budget, and made smaller when only a few records' time (at the
    slowest record rate seen) is left, so a point ends near its budget instead
    of overrunning it by the records in flight (measured: a 240 s budget at N =
    1e6 took 492 s when all records were queued at once, load 12-20). A batch's
    cost is all its records', its simulation included."""
    results: list[Any] = [None] * len(specs)
    size = batch_size(specs[0]["plant"], specs[0]["n"]) if specs else 1
    t0 = time.perf_counter()
    per_record = 0.0  # the slowest seconds per record of a finished batch
    with one_blas_thread():
        ctx = multiprocessing.get_context(start_method())
        with ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
            running: dict[Any, tuple[int, int, float]] = {}
            nxt = 0
            while nxt < len(specs) or running:
                while nxt < len(specs) and len(running) < workers:
                    left = budget_s - (time.perf_counter() - t0)
                    k = min(size, len(specs) - nxt)
                    if per_record > 0:
                        k = min(k, int(left // per_record))
                    if k < 1 or left <= 0:
                        break
                    f = pool.submit(records, specs[nxt : nxt + k])
                    running[f] = (nxt, k, time.perf_counter())
                    nxt += k
                if not running:
                    break
                done, _ = wait(running, return_when=FIRST_COMPLETED)
                for f in done:
                    i, k, started = running.pop(f)
                    per_record = max(per_record, (time.perf_counter() - started) / k)
                    results[i : i + k] = f.result()
    return [r for r in results if r is not None]


#: The bench's amplifier limit [V rms]: the simulator's default excitation,
#: the level every point used before the model-error rule.
BENCH_EXCITATION_STD = 1.0


def point_excitation_std(plant: str, level: str, n: int) -> float:
    """The excitation [V rms] of a point (its spec's ``"excitation_std"``).

    Linear plant: 1 V (no model error). Nonlinear plant: the planner's level
    (:func:`~maglevid.identify.planning.model_error_level`) for this N and
    noise, within 1 V: the largest at which the linearisation's predicted
    model-error bias is at most 0.1 standard errors of every v_i and
    physical parameter reported, so that ML's estimand (the best linear model
    at the excitation) stays within the target of the settled-point truth. The
    bound of the point is evaluated at the same level.
    """
    if plant == "linear":
        return BENCH_EXCITATION_STD
    design = _point_design(plant, level)
    names = design.bound(n_samples=1, excitation_std=1.0).names
    return model_error_level(
        design,
        n_samples=int(n),
        parameters=[k for k in REPORTED if k in names],
        max_excitation_std=BENCH_EXCITATION_STD,
    )


def _point_design(plant: str, level: str) -> Any:
    """The bound's design of a point: its bearing, the sensor noise, no force."""
    nominal = AMBParameters.nominal()
    noise = tuple(float(s) * NOISE_LEVELS[level] for s in DEFAULT_NOISE_STD)
    return design_information(
        nominal.with_fault(**PLANTS[plant]), nominal=nominal, noise=NoiseModel(noise)
    )


def run_point(
    *,
    plant: str,
    level: str,
    n: int,
    runs: int,
    budget_s: float,
    seed: int = 2026,
    workers: int | None = None,
) -> dict[str, Any]:
    """One point of the plan: at most ``runs`` records within ``budget_s``."""
    label = point_label(plant, level, n)
    noise = tuple(float(s) * NOISE_LEVELS[level] for s in DEFAULT_NOISE_STD)
    exc = point_excitation_std(plant, level, n)
    specs = [
        {"label": label, "plant": plant, "n": int(n), "noise": noise, "seed": seed, "run": i}
        | {"excitation_std": exc}
        for i in range(runs)
    ]
    workers = max(1, int(workers or os.cpu_count() or 1))
    t0 = time.perf_counter()
    records = _map_until(specs, workers, budget_s)
    wall = time.perf_counter() - t0
    design = _point_design(plant, level)
    crb = design.bound(n_samples=int(n), excitation_std=exc).std()
    return {
        "label": label,
        "plant": plant,
        "level": level,
        "n": int(n),
        "excitation_std": exc,
        "planned": runs,
        "summary": summarise(records, crb),
        "timing": {"wall_s": wall, "workers": workers, "budget_s": budget_s},
        "load": os.getloadavg()[0],
    }


def _param_stats(ok: list[dict[str, Any]], name: str, k: str, crb: float | None) -> dict[str, Any]:
    t = np.array([r["truth"][k] for r in ok])
    e = np.array([r[name]["est"][k] for r in ok]) - t
    sd = float(np.std(e, ddof=1))
    st: dict[str, Any] = {
        "bias_rel": float(np.mean(e / np.abs(t))),
        "std_rel": float(np.std(e / np.abs(t), ddof=1)),
        "std": sd,
        "bias_over_std": float(np.mean(e) / sd) if sd > 0 else float("nan"),
        "bias_se_over_std": 1.0 / np.sqrt(len(e)),
        "bias_kind": "plain",
        "std_over_crb": sd / crb if crb else float("nan"),
    }
    if all(r[name].get("se") and k in r[name]["se"] for r in ok):
        se = np.array([r[name]["se"][k] for r in ok])
        st["coverage"] = float(np.mean(np.abs(e) <= 1.959964 * se))
        st["covered"] = int(np.sum(np.abs(e) <= 1.959964 * se))
    pairs = [r for r in ok if name == "ML" and "twin_est" in r["ML"]]
    if len(pairs) >= 3 and sd > 0:
        # Antithetic: the mean of (e(+n) + e(-n)) / 2 over the pairs (module notes).
        pm = np.array([(r["ML"]["est"][k] + r["ML"]["twin_est"][k]) / 2 for r in pairs])
        pm = pm - np.array([r["truth"][k] for r in pairs])
        st["bias_over_std"] = float(np.mean(pm) / sd)
        st["bias_se_over_std"] = float(np.std(pm, ddof=1) / np.sqrt(len(pm)) / sd)
        st["bias_kind"] = f"antithetic, {len(pm)} pairs"
    return st


def _covered_fraction(ok: list[dict[str, Any]]) -> np.ndarray | None:
    """Per record, the share of v1..v9 whose stated 95 % interval covers the truth."""
    if not all(r["ML"].get("se") and all(k in r["ML"]["se"] for k in V_NAMES) for r in ok):
        return None
    e = np.array([[r["ML"]["est"][k] - r["truth"][k] for k in V_NAMES] for r in ok])
    se = np.array([[r["ML"]["se"][k] for k in V_NAMES] for r in ok])
    return np.mean(np.abs(e) <= 1.959964 * se, axis=1)


def summarise(records: list[dict[str, Any]], crb: dict[str, float]) -> dict[str, Any]:
    """Per method: failures, per-parameter statistics, median time; ML's convergence."""
    summ: dict[str, Any] = {"records": len(records)}
    stages = [r["stages"] for r in records if "stages" in r]
    if stages:
        names = dict.fromkeys(k for st in stages for k in st)
        summ["stages_median_s"] = {
            k: float(np.median([st.get(k, 0.0) for st in stages])) for k in names
        }
    for name in METHODS:
        if records and not any(name in r for r in records):
            summ[name] = {"not_run": True, "failures": 0}
            continue
        ok = [r for r in records if "est" in r.get(name, {})]
        ok = [r for r in ok if all(k in r[name]["est"] for k in REPORTED)]
        row: dict[str, Any] = {"failures": len(records) - len(ok)}
        if len(ok) >= 2:
            row["parameters"] = {k: _param_stats(ok, name, k, crb.get(k)) for k in REPORTED}
            row["time_median_s"] = float(np.median([r[name]["time"] for r in ok]))
        if name == "ML" and ok:
            row["not_same_optimum"] = int(sum(not r["ML"].get("same_optimum", False) for r in ok))
            row["gap_max_se"] = float(
                max((r["ML"].get("gap_to_truth_start_se", np.inf) for r in ok), default=np.nan)
            )
            row["iterations_median"] = float(np.median([r["ML"]["iterations"] for r in ok]))
            row["restarted_from_nominal"] = int(sum(r["ML"].get("restarted", False) for r in ok))
            row["twin_failures"] = int(sum("twin_error" in r["ML"] for r in ok))
            frac = _covered_fraction(ok)
            if frac is not None and len(frac) >= 2:  # judged (_coverage_check)
                row["pooled_coverage"] = float(np.mean(frac))
                row["pooled_coverage_sd"] = float(np.std(frac, ddof=1) / np.sqrt(len(frac)))
            q = [r["ML"]["chi2"] for r in ok if "chi2" in r["ML"]]
            if q:  # reported, not judged (whitened_error)
                row["chi2_over_dof"] = float(np.mean(q) / 9)
                row["chi2_over_dof_se"] = float(np.sqrt(2.0 / 9.0 / len(q)))
        summ[name] = row
    both = [r for r in records if "time" in r.get("ML", {}) and "time" in r.get("IV", {})]
    if both:
        summ["ml_over_iv_time_median"] = float(
            np.median([r["ML"]["time"] / r["IV"]["time"] for r in both])
        )
    return summ


def time_ratio(
    *, n: int = TIMING_N, repeats: int = TIMING_REPEATS, seed: int = 7
) -> dict[str, Any]:
    """ML's and IV's time on the same record in one process, best of ``repeats``
    (interleaved), and the load average before and after."""
    spec = {"plant": "linear", "n": int(n), "noise": DEFAULT_NOISE_STD}
    d = _simulate(spec, seed)
    load0 = os.getloadavg()[0]
    t_iv, t_ml = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fit_physical(d)
        t_iv.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        fit_ml(d)
        t_ml.append(time.perf_counter() - t0)
    return {
        "n": int(n),
        "repeats": repeats,
        "iv_s": min(t_iv),
        "ml_s": min(t_ml),
        "ratio": min(t_ml) / min(t_iv),
        "load": [load0, os.getloadavg()[0]],
    }


def run(
    plan: tuple[tuple[str, str, int, int, float], ...] = PLAN,
    *,
    workers: int | None = None,
    seed: int = 2026,
    timing: bool = True,
) -> dict[str, Any]:
    """Every point of ``plan`` and the time ratio, in this process (``main``)."""
    out: dict[str, Any] = {"machine": platform.platform(), "points": {}}
    for plant, level, n, runs, budget in plan:
        pt = run_point(
            plant=plant, level=level, n=n, runs=runs, budget_s=budget, seed=seed, workers=workers
        )
        out["points"][pt["label"]] = pt
        print(
            f"done {pt['label']}: {pt['summary']['records']} records in "
            f"{pt['timing']['wall_s']:.0f} s",
            flush=True,
        )
    if timing:
        out["timing"] = time_ratio()
    return out


# ---------------------------------------------------------------------------
# make bench: the section, its report and its verdicts
# ---------------------------------------------------------------------------
def measure(run_: Any, plan: dict[str, Any], args: Any) -> dict[str, Any]:
    """Each point in its own worker process with its own budget (plus one record's slack)."""
    out: dict[str, Any] = {"machine": platform.platform(), "points": {}}
    for plant, level, n, runs, budget in QUICK_PLAN if plan.get("quick") else PLAN:
        res = run_.call(
            "benchmarks.bench_ml_crb:run_point",
            timeout=budget + 120.0 + n / 1e6 * 120.0,
            plant=plant,
            level=level,
            n=n,
            runs=runs,
            budget_s=budget,
        )
        out["points"][point_label(plant, level, n)] = res
    if not plan.get("quick"):
        out["timing"] = run_.call("benchmarks.bench_ml_crb:time_ratio", timeout=300.0)
    return out


def _cell(p: dict[str, Any] | None) -> str:
    if p is None:
        return "-"
    cov = f"{p['coverage']:.2f}" if "coverage" in p else "n/a"
    return (
        f"{100 * p['bias_rel']:.2g} / {100 * p['std_rel']:.2g} / {cov} / {p['std_over_crb']:.3g}"
    )


def markdown_section(results: dict[str, Any]) -> list[str]:
    """The BENCHMARKS.md section."""
    L = [
        "## Physical parameters against the Cramér-Rao bound (LS, IV, ML, deadbeat, MOESP)",
        "",
        f"`python -m benchmarks.bench_ml_crb` ({results.get('machine', '?')}); points and "
        "their record counts below (a point that ran out of its time budget used fewer "
        "records than planned: the count is the one it used). Each cell: bias % / std % "
        "(relative to the true value) / coverage of the stated 95 % intervals / std over "
        "the Cramér-Rao bound. ML's |bias|/std: antithetic (mean of the pair means of "
        "each record and its noise-negated twin, on both plants); ± its "
        "standard error. A point with fewer than "
        f"{MIN_RECORDS} records is shown but not judged. LS refuses noisy records (errors in "
        "variables); MOESP has no covariance (coverage n/a).",
        "",
    ]
    tm = results.get("timing")
    if tm and "ratio" in tm:
        L += [
            f"Time, one process, same record, best of {tm['repeats']}: N = {tm['n']:.0e}: "
            f"ML {tm['ml_s']:.2f} s, IV {tm['iv_s']:.3f} s, ratio {tm['ratio']:.1f}x "
            f"(load average {tm['load'][0]:.1f} -> {tm['load'][1]:.1f} on 2 shared cores).",
            "",
        ]
    for key, pt in results.get("points", {}).items():
        L.append(f"### {key}")
        L.append("")
        if "summary" not in pt:
            L += [f"not measured: {pt.get('error', 'no result')}", ""]
            continue
        s, ml = pt["summary"], pt["summary"].get("ML", {})
        L.append(
            f"Excitation {pt.get('excitation_std', BENCH_EXCITATION_STD):.3g} V rms per input"
            + (
                " (the planner's level for this N and noise: model-error bias <= 0.1 std, "
                "`point_excitation_std`; the bound at the same level). "
                if pt.get("plant") == "nonlinear"
                else ". "
            )
            + f"{s['records']} of {pt['planned']} planned records (budget "
            f"{pt['timing']['budget_s']:.0f} s, wall {pt['timing']['wall_s']:.0f} s on "
            f"{pt['timing']['workers']} workers, load {pt['load']:.1f}). "
            "ML/IV time (median per record) "
            f"{s.get('ml_over_iv_time_median', float('nan')):.1f}x; "
            f"ML median iterations {ml.get('iterations_median', float('nan')):.0f}; "
            f"ML from IV != ML from the truth: {ml.get('not_same_optimum', 'n/a')} records "
            f"(largest gap {ml.get('gap_max_se', float('nan')):.1e} se; started or restarted "
            f"from the nominal bearing on {ml.get('restarted_from_nominal', 'n/a')}); "
            "failures "
            + ", ".join(
                f"{m} not run" if s[m].get("not_run") else f"{m} {s[m]['failures']}"
                for m in METHODS
            )
            + "; "
            f"antithetic twins left out (failed or not converged): {ml.get('twin_failures', 0)}."
            + (
                " ML's intervals, whitened (reported, not judged): mean e^T C^-1 e / 9 = "
                f"{ml['chi2_over_dof']:.3f} ± {ml['chi2_over_dof_se']:.3f} (1 if honest)."
                if "chi2_over_dof" in ml
                else ""
            )
        )
        if "stages_median_s" in s:
            L += [
                "",
                "Where a record's time goes (median per record, one worker): "
                + ", ".join(f"{k} {v:.2g} s" for k, v in s["stages_median_s"].items())
                + ".",
            ]
        L += ["", "| parameter | " + " | ".join(METHODS) + " | ML \\|bias\\|/std |"]
        L.append("|---" * (len(METHODS) + 2) + "|")
        for k in REPORTED:
            cells = [_cell(s[m].get("parameters", {}).get(k)) for m in METHODS]
            pm = ml.get("parameters", {}).get(k)
            cells.append(
                "-"
                if pm is None
                else f"{abs(pm['bias_over_std']):.2f} ± {pm['bias_se_over_std']:.2f}"
            )
            L.append(f"| {k} | " + " | ".join(cells) + " |")
        L.append("")
    return L


def _short(plant: str, level: str, n: int) -> str:
    return f"{plant} {level} {n:.0e}"


def targets(results: dict[str, Any], judge: Any) -> None:
    """Verdicts on the issue's grid (plant x noise level x N), one row per target
    over the points measured, one "not measured" row naming the points not run."""
    pts = results.get("points", {})
    checks: dict[str, list[tuple[str, bool]]] = {}
    missing: dict[str, list[str]] = {}
    for plant in PLANTS:
        for level in NOISE_LEVELS:
            for n in SIZES:
                pt = pts.get(point_label(plant, level, n))
                for kind, text, ok in _point_checks(plant, level, pt):
                    if ok is None:
                        why = f" ({text})" if text else ""
                        missing.setdefault(kind, []).append(_short(plant, level, n) + why)
                    else:
                        checks.setdefault(kind, []).append(
                            (f"{_short(plant, level, n)}: {text}", ok)
                        )
    for kind in _KINDS:
        if kind in checks:
            judge.add(
                f"{kind} (points measured)",
                "; ".join(t for t, _ in checks[kind]),
                all(ok for _, ok in checks[kind]),
            )
        if kind in missing:
            judge.not_measured(
                f"{kind} (points not measured: not in the plan, failed, or fewer than "
                f"{MIN_RECORDS} records)",
                ", ".join(missing[kind]),
            )
    tm = results.get("timing")
    target = "ML at N = 1e5 within 20x IV's time (one process, same record, best of 3)"
    if not tm or "ratio" not in tm:
        judge.not_measured(target, (tm or {}).get("error", "timing not run"))
    else:
        judge.add(
            target,
            f"ML {tm['ml_s']:.2f} s / IV {tm['iv_s']:.3f} s = {tm['ratio']:.1f}x "
            f"(load {tm['load'][0]:.1f})",
            tm["ratio"] <= 20.0,
        )


#: Records a point needs before its figures are judged (the issue's ">= 100
#: recordings per point"). Below it a point is reported with its count and
#: listed as not measured: at 13 records the pooled v1..v9 coverage has a
#: binomial sd of 0.020 (the 0.93-0.97 band is +-1 sd), std/CRB a sampling sd
#: of ~20 % (1.15 cannot be told from 1.3) and the bias a standard error of
#: ~0.28 std without the twin (0.2 std cannot be told from 0). At 100: 0.007,
#: 7 % and 0.02-0.1 std. One exception: a record where ML from IV and ML from
#: the truth differ fails that target at any count.
MIN_RECORDS = 100

_KINDS = (
    "ML std/CRB <= 1.3, every parameter",
    "ML coverage 0.93-0.97 (v1..v9 pooled, within 2 Monte Carlo sd)",
    "ML |bias| < 0.2 std, every parameter",
    "ML from IV = ML from the truth on every record",
    "ML std >= 5x below IV at the default noise (bound-capped)",
)


def _point_checks(plant: str, level: str, pt: dict[str, Any] | None) -> list[tuple[str, str, Any]]:
    """(target kind, measured text, met or None) of one grid point."""
    kinds = list(_KINDS) if level == "default" else list(_KINDS[:4])
    if pt is None or "summary" not in pt or "parameters" not in pt["summary"].get("ML", {}):
        return [(k, "", None) for k in kinds]
    s = pt["summary"]
    ml, par = s["ML"], s["ML"]["parameters"]
    rec = f"{s['records']} rec"
    if s["records"] < MIN_RECORDS:
        # Too few records to support a verdict (MIN_RECORDS); a record on which
        # ML from IV missed ML from the truth is a failure at any count.
        few = f"{rec} < {MIN_RECORDS}"
        out_few: list[tuple[str, str, Any]] = [(k, few, None) for k in kinds]
        if ml.get("not_same_optimum", 0) > 0:
            out_few[3] = (kinds[3], f"{ml['not_same_optimum']} differ, {rec}", False)
        return out_few
    worst = max(REPORTED, key=lambda k: par[k]["std_over_crb"])
    out = [
        (
            kinds[0],
            f"max {par[worst]['std_over_crb']:.2f} ({worst}), {rec}",
            par[worst]["std_over_crb"] <= 1.3,
        )
    ]
    out.append((kinds[1], *_coverage_check(ml, par, rec)))
    wb = max(REPORTED, key=lambda k: abs(par[k]["bias_over_std"]))
    b = par[wb]
    out.append(
        (
            kinds[2],
            f"max {abs(b['bias_over_std']):.3f} ± {b['bias_se_over_std']:.3f} "
            f"({wb}; {b['bias_kind']}), {rec}",
            abs(b["bias_over_std"]) < 0.2,
        )
    )
    out.append(
        (
            kinds[3],
            f"{ml['not_same_optimum']} differ (largest gap {ml['gap_max_se']:.1e} se), {rec}",
            ml["not_same_optimum"] == 0,
        )
    )
    if level == "default":
        out.append((kinds[4], *_gain_over_iv(s, rec)))
    return out


#: The coverage band of the issue (0.93-0.97) and how many Monte Carlo standard
#: deviations of the measured pooled coverage may separate it from the band.
COVERAGE_BAND, COVERAGE_SDS = (0.93, 0.97), 2.0


def _coverage_check(ml: dict[str, Any], par: dict[str, Any], rec: str) -> tuple[str, bool]:
    """Pooled v1..v9 coverage judged against the band within its Monte Carlo error.

    The target is on the intervals' true coverage; 100 records measure it with a
    Monte Carlo sd of ~0.01 (the sd over records of each record's covered share
    / sqrt(records): the 9 parameters' errors move together, so this is larger
    than the binomial 0.007). Judged on the measured value alone, exact
    intervals would leave the band at one of the 18 points in about one run of
    three (docs/gosiewski.md, "ML's coverage at linear 3x noise": 20,000
    simulated runs). So a point fails only when the band lies more than
    COVERAGE_SDS of its own sd away: the data then show the coverage outside it.
    The measured value and its sd are printed; the whitened statistic
    (``chi2_over_dof``) is reported beside it, not judged."""
    cov = [par[k]["coverage"] for k in REPORTED]
    if "pooled_coverage" not in ml:
        return f"no stated intervals, {rec}", None
    p, sd = ml["pooled_coverage"], ml["pooled_coverage_sd"]
    lo, hi = COVERAGE_BAND
    met = lo - COVERAGE_SDS * sd <= p <= hi + COVERAGE_SDS * sd
    return f"{p:.3f} ± {sd:.3f} (each {min(cov):.2f}-{max(cov):.2f}), {rec}", met


#: Where IV is already near the bound no estimator can be 5x better: the
#: precision target per parameter is min(5, IV std / (1.3 CRB)) -- it binds on
#: v8, v9 only, where IV's std is 4.5-5x the bound (docs/gosiewski.md, section 10).
_IV_RATIO, _EFFICIENT = 5.0, 1.3


def _gain_over_iv(s: dict[str, Any], rec: str) -> tuple[str, Any]:
    iv, par = s["IV"].get("parameters"), s["ML"]["parameters"]
    if not iv:
        return "no IV result", None
    gains = []
    for k in REPORTED:
        need = min(_IV_RATIO, iv[k]["std_over_crb"] / _EFFICIENT)
        gains.append((iv[k]["std"] / par[k]["std"], need, k))
    g, need, k = min(gains, key=lambda x: x[0] / x[1])
    text = (
        f"smallest IV/ML std {g:.1f}x ({k}; required {need:.1f}x = min(5, IV std/CRB "
        f"{s['IV']['parameters'][k]['std_over_crb']:.1f} / 1.3)), {rec}"
    )
    return text, all(gg >= nn for gg, nn, _ in gains)


def score_statistic(data: Any, noise: tuple[float, ...]) -> float:
    """Rao's score statistic of v1..v9 at the truth of a linear-plant record.

    The gradient and Fisher matrix of eq. (1) at the true v and sensor noise
    levels, force variance 0 (:func:`~maglevid.identify.cramer_rao.predictor_statistics`:
    the time-domain recursion, independent of ML's frequency-domain code), the
    nuisance parameters (log s, offsets, initial state) eliminated:
    ``g_eff^T I_eff^-1 g_eff``. Chi-square(9) iff the scores' variance is the
    Fisher matrix (the information-matrix equality, which makes the inverse
    Fisher matrix the estimator's covariance); no fit is involved."""
    model = amb_linear_gaussian_model(
        np.asarray(data.metadata["truth_v"], dtype=float),
        data.dt,
        NoiseModel(noise),
        m=data.loop["operating_point"]["m"],
        estimate_noise=True,
        estimate_force=False,
    )
    st = predictor_statistics(model, np.asarray(data.y, float), np.asarray(data.u, float))
    g, info = st.gradient, st.fisher
    v, nu = slice(0, 9), slice(9, None)
    g_eff = g[v] - info[v, nu] @ np.linalg.solve(info[nu, nu], g[nu])
    i_eff = info[v, v] - info[v, nu] @ np.linalg.solve(info[nu, nu], info[nu, v])
    return float(g_eff @ np.linalg.solve(i_eff, g_eff))


def ml_calibration(
    *,
    plant: str,
    level: str,
    n: int,
    runs: range,
    seed: int = 2026,
    score: bool = False,
    **fit_options: Any,
) -> dict[str, Any]:
    """ML alone on a point's records, against its whole stated covariance (a diagnostic).

    The records are the bench's own (:func:`_record_seed` of ``seed`` and the
    run numbers ``runs``: ``range(100)`` at seed 2026 is the plan's draw,
    ``range(100, 300)`` fresh ones), simulated one at a time without twins and
    fitted by ``fit_ml(record, **fit_options)`` only (``force_std=0.0`` or
    ``noise_std="metadata"`` isolate the nuisance parameters' part). Per record:
    ``z = (v - v_true) / se`` and the whitened error ``q = e^T C^-1 e``, ``C``
    ML's stated covariance of v1..v9 (chi-square with 9 degrees of freedom if
    the intervals are honest). Returned with ``chi2_over_dof`` (mean q / 9,
    standard error ``sqrt(2 / (9 runs))``): a calibration statistic that uses
    the parameters' correlations, far less noisy than the pooled coverage,
    whose 9 parameters move together (docs/gosiewski.md, "ML's coverage at
    linear 3x noise"). ``score``: also :func:`score_statistic` at the truth
    (``score_q``, ``score_over_dof``; linear plant only), no fit involved."""
    label = point_label(plant, level, n)
    noise = tuple(float(s) * NOISE_LEVELS[level] for s in DEFAULT_NOISE_STD)
    exc = point_excitation_std(plant, level, n)
    z, q, sq = [], [], []
    for i in runs:
        spec = {"label": label, "plant": plant, "n": int(n), "noise": noise, "seed": seed}
        spec |= {"run": i, "excitation_std": exc}
        d = _simulate(spec, _record_seed(spec))
        res = fit_ml(d, **fit_options)
        truth = np.array([_truth(d)[k] for k in V_NAMES])
        se = res.std_errors()
        z.append([(res.parameters[k] - t) / se[k] for k, t in zip(V_NAMES, truth)])
        q.append(whitened_error(res, truth))
        if score:
            sq.append(score_statistic(d, noise))
    za, qa = np.array(z), np.array(q)
    extra = {"score_q": sq, "score_over_dof": float(np.mean(sq) / 9)} if score else {}
    return extra | {
        "label": label,
        "runs": [runs.start, runs.stop],
        "z": za.tolist(),
        "q": qa.tolist(),
        "rms_z": np.sqrt(np.mean(za**2, axis=0)).tolist(),
        "coverage": float(np.mean(np.abs(za) <= 1.959964)),
        "chi2_over_dof": float(np.mean(qa) / 9),
        "chi2_over_dof_se": float(np.sqrt(2.0 / 9.0 / len(qa))),
    }


try:  # run_all's section registry (benchmarks/sections.py)
    from benchmarks.sections import Section
except ImportError:  # pragma: no cover - run as a script without the package
    pass
else:
    #: The ``make bench`` section (``run_all.PLUGINS`` names this module).
    SECTION = Section("ml_crb", measure, markdown_section, targets)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--quick", action="store_true", help="20 records at N = 1e4 only")
    ap.add_argument("--n", type=int, default=None, help="only the plan's points at this N")
    ap.add_argument("--no-timing", action="store_true", help="leave out the 1e5 time ratio")
    ap.add_argument("--json", default=None, help="write the results here")
    ap.add_argument("--markdown", default=None, help="write the markdown section here")
    a = ap.parse_args(argv)
    res = run(
        QUICK_PLAN if a.quick else tuple(p for p in PLAN if a.n in (None, p[2])),
        workers=a.workers,
        seed=a.seed,
        timing=not (a.quick or a.no_timing),
    )
    md = "\n".join(markdown_section(res))
    print(md)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(res, f, indent=1)
    if a.markdown:
        with open(a.markdown, "w") as f:
            f.write(md + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
