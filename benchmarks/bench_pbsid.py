"""Closed-loop subspace (PBSID-opt, SSARX) beside MOESP, N4SID, physical IV and the peers.

Run from the repository root::

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python -m benchmarks.bench_pbsid
    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python -m benchmarks.bench_pbsid --sizes 1e4 1e5
    OPENBLAS_NUM_THREADS=1 PYTHONPATH=src python -m benchmarks.bench_pbsid --parsim-k-scaling 2e5

(the last: PARSIM-K's time and peak memory alone, one process per N; the
stored ``PARSIM_K_MEASURED`` say why it is not run above ``PEER_MAX_N``).

Three plants, so that the method is not tied to one:

1. **The closed-loop unstable bearing** (``bench_amb_speed.bearing_case``): the
   simulator's defaults (noise 1e-7 m, 1e-4 A; BENCHMARKS.md's bearing section,
   where MOESP/N4SID's v5 and v7 are ~50 % off) and the paper-like record
   (R1, kw1 +20 %, noise 1e-10 m, 3e-6 A). Unstable-pole error (relative, in z),
   largest v_i error (relative) and the fit's time, for PBSID-opt and SSARX in
   physical coordinates (automatic past up to 80, and PBSID-opt up to 40;
   order 4; v1..v9 by the structured weighted least-squares fit, the default,
   over a window chosen from the data (docs/subspace.md (P16)), and by the
   transform, ``physical_fit="transform"``, whose v errors are informative; the
   time targets judge both paths),
   MOESP/N4SID + physical coordinates at horizon 40, physical IV,
   SIPPY's PARSIM-K and maglevid's maximum-likelihood method where they are
   installed (else "not measured").
2. **A generic MIMO closed loop** (``simulate.feedback.example_unstable_mimo``:
   3 states, 2 x 2, pole 1.07, a controller with direct feedthrough, white r and
   innovations of 0.3 rms): largest error of the first 10 Markov parameters and
   of the poles.
3. **The suspension of Sun et al. at the control rate with r != 0**: the
   linearised plant (``physics.suspension``) ZOH-sampled at the lead-lag
   controller's period, white r (10 V rms; the controller's own output is
   ~30 V rms) added to the controller's output, white sensor noise 0.1 mm fed
   back (``simulate_suspension`` has r = 0; this loop is built here from the
   same plant and controller): the unstable continuous pole, relative error.

Times are medians of three runs (one above 5 s; PARSIM-K warmed up first by an
untimed fit of a short record, as its first fit in a process carries ~2 s of
one-time cost), one BLAS thread; progress
goes to stderr, the Markdown to stdout (``--out`` writes it to a file too).
4. **A Monte Carlo on both bearing records** (``MONTE_CARLO``: 100 records at
   N = 1e4, 30 at 1e5) and on the realistic bearing's short records
   (``REALISTIC_MONTE_CARLO``: 100 at N = 4000, 50 at 1e4, judged on their own):
   PBSID-opt, SSARX and ML on the same records; the v_i
   target's errors as RMS over the records (one record's ratio of two errors is
   a coin toss), the structured fit's intervals (P15): RMS of the normalised
   errors and the 95 % intervals' coverage, and each fit's time over MOESP's on
   the same record (the time target's verdict: the median over the records, as
   the Gauss-Newton path's length varies from record to record) (about 2.5 min
   on one idle core).

``SECTION`` (where ``benchmarks/sections.py`` exists) plugs this into
``make bench``: :func:`run` measures, :func:`markdown_section` reports,
:func:`targets` judges the issue's four targets for PBSID-opt and SSARX.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import scipy.signal

from benchmarks.bench_amb_speed import BEARING_HORIZON, bearing_case, unstable_pole
from maglevid.exceptions import IdentificationError
from maglevid.identify.pbsid import fit_pbsid, fit_ssarx
from maglevid.identify.physical import fit_physical, to_physical_coordinates
from maglevid.identify.registry import available_methods
from maglevid.identify.subspace import fit_moesp, fit_n4sid
from maglevid.lti import StateSpace
from maglevid.physics.amb import v_from_matrices
from maglevid.physics.suspension import SuspensionParameters, suspension_state_space
from maglevid.simulate.feedback import example_unstable_mimo, simulate_innovation_loop
from maglevid.simulate.suspension import CONTROLLERS

SIZES = (10_000, 100_000, 1_000_000)
#: The structured-fit rows (``physical_fit="structured"``, the default in physical
#: coordinates): the v_i and pole targets judge these.
STRUCTURED = {
    "pbsid": "maglevid pbsid, structured fit (default)",
    "ssarx": "maglevid ssarx, structured fit (default)",
}
#: The transform rows (``physical_fit="transform"``): the time targets judge these
#: and the structured rows alike; their v errors are informative.
TRANSFORM = {
    "pbsid": "maglevid pbsid, transform path",
    "ssarx": "maglevid ssarx, transform path",
}
#: PARSIM-K takes ~6 s at 1e4 and ~45 s at 1e5 (BENCHMARKS.md): not run above this.
PEER_MAX_N = 100_000
#: SIPPY PARSIM-K (sippy_unipi 1.0.1, horizon 40, order 4) on the issue record,
#: measured by ``python -m benchmarks.bench_pbsid --parsim-k-scaling 1e4 1e5 2e5 3e5``
#: (one process per N, one BLAS thread, 2-core machine with 24 GiB shared by five
#: users): ``(N, seconds, peak resident GB, load average)``. Issue 16, fifth session.
PARSIM_K_MEASURED = (
    (10_000, 5.5, 0.30, 0.6),
    (100_000, 50.0, 1.32, 1.7),
    (200_000, 86.8, 2.46, 1.9),
    (300_000, 237.8, 3.59, 4.4),
)
#: Memory one peer run may take on this machine (of 24 GiB shared by five users).
PEER_MEMORY_GB = 8.0


#: A call taking longer than this is timed once, shorter ones three times (median). 5 s
#: since the thirtieth session (was 2 s): PARSIM-K at 1e4 takes 2.0-2.8 s, so one record's
#: PARSIM-K was timed once and the other's three times in the same run, and its single
#: times moved by a third from run to run (its ratio to MOESP carries the 50x target).
SINGLE_RUN_S = 5.0


def _median_time(fn: Callable[..., Any], *args: Any, **kw: Any) -> tuple[float, Any]:
    t0 = time.perf_counter()
    out = fn(*args, **kw)
    times = [time.perf_counter() - t0]
    if times[0] < SINGLE_RUN_S:
        for _ in range(2):
            t0 = time.perf_counter()
            out = fn(*args, **kw)
            times.append(time.perf_counter() - t0)
    return statistics.median(times), out


# ------------------------------------------------------- PARSIM-K at large N
def parsim_k_projection(n: int) -> tuple[float, float]:
    """``(peak GB, seconds)`` of PARSIM-K at ``n`` samples, extrapolated linearly.

    Peak memory: a least-squares line through :data:`PARSIM_K_MEASURED` (it is
    linear in N: 1.13-1.16 GB per 1e5 samples between the points). Time: the
    least per-sample cost measured (the quietest runs) times ``n``, a lower bound.
    """
    N = np.array([r[0] for r in PARSIM_K_MEASURED], dtype=float)
    gb = np.array([r[2] for r in PARSIM_K_MEASURED])
    slope, icpt = np.polyfit(N, gb, 1)
    per_sample = min(r[1] / r[0] for r in PARSIM_K_MEASURED[1:])  # 1e4 is fixed cost
    return float(slope * n + icpt), float(per_sample * n)


def parsim_k_verdict(n: int) -> str:
    """Why PARSIM-K is not run at ``n`` (> PEER_MAX_N): its measured footprint."""
    gb, sec = parsim_k_projection(n)
    big = PARSIM_K_MEASURED[-1]
    why = (
        f"over the {PEER_MEMORY_GB:.0f} GB a peer may take here"
        if gb > PEER_MEMORY_GB
        else "within memory; not run to keep the section's time"
    )
    return (
        f"not measured: PARSIM-K's peak memory grows linearly, {big[2]:.2f} GB and "
        f"{big[1]:.0f} s at N = {big[0]:.0e} (load {big[3]:.1f}); ~{gb:.1f} GB and "
        f">= {sec / 60:.0f} min projected at N = {n:.0e}, {why}"
    )


def measure_parsim_k(n: int, case: str = "issue") -> dict[str, Any]:
    """Time and peak resident memory of one PARSIM-K fit at ``n``, in a fresh process."""
    import subprocess

    code = (
        "import json, resource, time, numpy as np\n"
        "from benchmarks.bench_amb_speed import bearing_case\n"
        "from benchmarks.peers import sippy\n"
        f"d, _ = bearing_case({int(n)}, case={case!r})\n"
        "t0 = time.perf_counter()\n"
        "sippy.identify(np.asarray(d.y), np.asarray(d.u), 4, 40, method='PARSIM-K')\n"
        "t = time.perf_counter() - t0\n"
        "gb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6\n"  # kB (Linux)
        "print(json.dumps({'N': d.n_samples, 'time_s': t, 'peak_gb': gb}))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    return {**json.loads(out.splitlines()[-1]), "load": os.getloadavg()[0]}


# ------------------------------------------------------------------ bearing
def _v_of(model: StateSpace) -> np.ndarray:
    _, cont = to_physical_coordinates(model)
    return v_from_matrices(cont.A, cont.B)[0]


def _bearing_tools() -> dict[str, Callable[[Any], tuple[Any, Any] | str]]:
    def subspace(fit: Callable[..., Any]) -> Callable[[Any], tuple[Any, Any]]:
        def run(d: Any) -> tuple[Any, Any]:
            res = fit(d.y, d.u, order=4, horizon=BEARING_HORIZON, dt=d.dt)
            return res.model.poles(), _v_of(res.model)

        return run

    def predictor(fit: Callable[..., Any], **kw: Any) -> Callable[[Any], tuple[Any, Any]]:
        def run(d: Any) -> tuple[Any, Any]:
            res = fit(d.y, d.u, order=4, dt=d.dt, coordinates="physical", **kw)
            return res.model.poles(), np.array([res.parameters[f"v{i}"] for i in range(1, 10)])

        return run

    def physical_iv(d: Any) -> tuple[Any, Any]:
        res = fit_physical(d)
        return res.model.poles(), np.array([res.parameters[f"v{i}"] for i in range(1, 10)])

    def ml(d: Any) -> tuple[Any, Any] | str:
        method = available_methods().get("ml")
        if method is None:
            return "not measured: no `ml` method on this branch (issue 13)"
        res = method(d)
        return res.model.poles(), np.array([res.parameters[f"v{i}"] for i in range(1, 10)])

    def parsim_k(d: Any) -> tuple[Any, Any] | str:
        from benchmarks.peers import PeerMissing, sippy

        if d.n_samples > PEER_MAX_N:
            return parsim_k_verdict(d.n_samples)
        try:
            res = sippy.identify(np.asarray(d.y), np.asarray(d.u), 4, 40, method="PARSIM-K")
        except PeerMissing as exc:
            return f"not measured: {exc}"
        return res.poles, None

    return {
        TRANSFORM["pbsid"]: predictor(fit_pbsid, physical_fit="transform"),
        # The bearing's Kalman predictor has a pole at ~0.98: the VARX truncation
        # of a shorter past (AIC up to 40, not the default 80) shows at N >= 1e5.
        "maglevid pbsid, transform path, max_past=40": predictor(
            fit_pbsid, physical_fit="transform", max_past=40
        ),
        TRANSFORM["ssarx"]: predictor(fit_ssarx, physical_fit="transform"),
        # v1..v9 and K fitted to the window's Gram in the bearing's structure
        # (docs/subspace.md (P11)-(P16)), window from the data: no pass over the data, no ML.
        STRUCTURED["pbsid"]: predictor(fit_pbsid),
        STRUCTURED["ssarx"]: predictor(fit_ssarx),
        "maglevid moesp + physical coordinates": subspace(fit_moesp),
        "maglevid n4sid + physical coordinates": subspace(fit_n4sid),
        "maglevid physical (IV)": physical_iv,
        "maglevid ml": ml,
        PARSIM_K_TOOL: parsim_k,
    }


def bench_bearing(sizes: tuple[int, ...], cases: tuple[str, ...]) -> list[dict[str, Any]]:
    rows = []
    _warm_up_parsim_k()
    for case in cases:
        for n in sizes:
            data, truth = bearing_case(n, case=case)
            for tool, fn in _bearing_tools().items():
                row: dict[str, Any] = {"case": case, "N": n, "tool": tool}
                try:
                    t, out = _median_time(fn, data)
                except Exception as exc:  # a failure is a result here
                    rows.append({**row, "error": f"{type(exc).__name__}: {exc}"[:160]})
                    continue
                if isinstance(out, str):
                    rows.append({**row, "error": out})
                    continue
                poles, v = out
                pe = unstable_pole(poles, truth)
                v_err = None if v is None else float(np.max(np.abs(v / truth["v"] - 1.0)))
                rows.append(
                    {**row, "time_s": t, "pole_error": pe["pole_error"], "found": pe["found"]}
                    | {"v_error": v_err}
                )
                print(_row_text(rows[-1]), file=sys.stderr, flush=True)
            _interleaved_times([r for r in rows if r["case"] == case and r["N"] == n], data)
    return rows


MOESP_TOOL = "maglevid moesp + physical coordinates"
PARSIM_K_TOOL = "SIPPY PARSIM-K"
#: Samples of the untimed PARSIM-K fit that warms the peer up (:func:`_warm_up_parsim_k`).
PARSIM_K_WARM_UP_N = 2_000


def _warm_up_parsim_k() -> None:
    """One untimed PARSIM-K fit of a short record before any is timed.

    The first PARSIM-K fit of a process carries ~2 s of one-time cost (measured, thirtieth
    session: 4.1 s then 2.1 s on the issue record at 1e4, 2.2 then 2.1 s on the
    paper-like one): a peer timed once (``_median_time``, then calls above 2 s) was charged
    it on whichever record came first, which put PARSIM-K at 172x MOESP's time on the
    issue record against 82x on the paper-like one in the same run. Nothing when SIPPY
    is not installed (the rows then say so).
    """
    from benchmarks.peers import PeerMissing, sippy

    data, _ = bearing_case(PARSIM_K_WARM_UP_N, case="issue")
    try:
        sippy.identify(np.asarray(data.y), np.asarray(data.u), 4, 40, method="PARSIM-K")
    except PeerMissing:
        return


def _interleaved_times(rows: list[dict[str, Any]], data: Any) -> None:
    """Re-time the maglevid fits (and PARSIM-K where short) interleaved: rounds of one
    call each (module notes).

    A shared core's speed drifts by tens of percent within seconds, so each
    fit's ratio to MOESP is the median over rounds of its time over MOESP's in
    the same round (as ``bench_amb_speed`` times its regressions); ``time_s``
    becomes the median of the rounds.
    """
    tools = _bearing_tools()
    # The structured fits are timed here too since the seventh session (0.1-0.5 s;
    # they took 1-70 s before, and were timed by _median_time alone). PARSIM-K too
    # where a call is short enough to repeat (under SINGLE_RUN_S: 1e4, 2-2.8 s, ~12 s
    # more a record): its ratio to MOESP carries the 50x target, and had been two
    # medians of three calls a minute apart, 82-113x from run to run on the paper-like
    # record (thirtieth session), the machine's speed drifting by tens of percent.
    timed = [
        r
        for r in rows
        if "error" not in r
        and (
            r["tool"].startswith("maglevid")
            or (r["tool"] == PARSIM_K_TOOL and r["time_s"] < SINGLE_RUN_S)
        )
    ]
    if not any(r["tool"] == MOESP_TOOL for r in timed):
        return
    rounds = 5 if data.n_samples <= 100_000 else 3
    times: dict[str, list[float]] = {r["tool"]: [] for r in timed}
    for _ in range(rounds):
        for tool in times:
            t0 = time.perf_counter()
            tools[tool](data)
            times[tool].append(time.perf_counter() - t0)
    ref = times[MOESP_TOOL]
    for r in timed:
        t = times[r["tool"]]
        r["time_s"] = statistics.median(t)
        r["moesp_ratio"] = statistics.median(a / b for a, b in zip(t, ref, strict=True))


# --------------------------------------------------------------- Monte Carlo
#: ``(N, records)`` of the Monte Carlo on both bench records: the v_i target's
#: errors as RMS over records (one record's ratio of two errors is a coin toss:
#: the bench's record at 1e4 gave 2.1x where 100 records give 1.33x, issue 16,
#: tenth session) and the intervals' coverage. ~2.5 min in all on one idle core.
MONTE_CARLO = ((10_000, 100), (100_000, 30))
#: ``(N, records)`` of the Monte Carlo on the realistic bearing (the hard case: the
#: nonlinear plant under the nominal bias voltages, 0.1 N white force, the command
#: line's sensor noise; ``simulate_amb_loop``'s defaults), short records where the
#: window's dropped term mattered (docs/subspace.md (P23): up to 2.9x ML's errors at
#: N = 4000 before it). Truth: the linearisation where the bearing settles. 100 records
#: at 4000: 30 read PBSID-opt's largest ratio 1.98x or 2.05x by seed, 100 1.86x. ~1.5 min.
REALISTIC_MONTE_CARLO = ((4_000, 100), (10_000, 50))
#: The methods each record is fitted by (the structured fit's default window; ML the
#: reference of the v_i target).
MC_METHODS = ("pbsid", "ssarx", "ml")


def bench_monte_carlo(n: int = 10_000, records: int = 100, case: str = "issue") -> dict[str, Any]:
    """PBSID-opt, SSARX (structured fit, default window) and ML on ``records`` seeds.

    Per method and parameter: the RMS of the relative error ``v / truth - 1`` and,
    where the method has intervals, of ``(v - truth) / se`` (1 when the covariance
    (P15) is right) and how often the 95 % interval holds the truth; pooled over
    v1..v9 too. ML is left out (``None``) where the branch has no ``ml`` method.
    """
    ml = available_methods().get("ml")
    fits: dict[str, Callable[[Any], Any] | None] = {
        "pbsid": lambda d: fit_pbsid(d.y, d.u, order=4, dt=d.dt, coordinates="physical"),
        "ssarx": lambda d: fit_ssarx(d.y, d.u, order=4, dt=d.dt, coordinates="physical"),
        "ml": ml,
    }
    rel: dict[str, list[list[float]]] = {k: [] for k in MC_METHODS}
    z: dict[str, list[list[float]]] = {k: [] for k in MC_METHODS}
    seconds = dict.fromkeys(MC_METHODS, 0.0)
    refused = dict.fromkeys(MC_METHODS, 0)
    moesp = _bearing_tools()[MOESP_TOOL] if case != "realistic" else None
    ratios: dict[str, list[float]] = {k: [] for k in MC_METHODS}  # time / MOESP's, per record
    t0 = time.perf_counter()
    for seed in range(1000, 1000 + records):
        d, truth = _monte_carlo_record(n, seed, case)
        t_moesp = _timed(moesp, d) if moesp is not None else None
        for name, fit in fits.items():
            if fit is None:
                continue
            t1 = time.perf_counter()
            try:
                res = fit(d)
            except IdentificationError:  # the method declined this record: counted
                refused[name] += 1
                continue
            finally:
                seconds[name] += time.perf_counter() - t1
                if t_moesp:  # a refusal's time is time spent too
                    ratios[name].append((time.perf_counter() - t1) / t_moesp)
            v = np.array([res.parameters[f"v{i}"] for i in range(1, 10)])
            rel[name].append((v / truth["v"] - 1.0).tolist())
            se = res.std_errors()
            if se:
                z[name].append([(v[i] - truth["v"][i]) / se[f"v{i + 1}"] for i in range(9)])
    out: dict[str, Any] = {"case": case, "N": n, "records": records, "methods": {}}
    for name in MC_METHODS:
        if not rel[name]:
            out["methods"][name] = None
            continue
        E, Z = np.asarray(rel[name]), np.asarray(z[name]) if z[name] else None
        out["methods"][name] = {
            "rms_rel": np.sqrt(np.mean(E**2, axis=0)).tolist(),
            "rms_z": None if Z is None else np.sqrt(np.mean(Z**2, axis=0)).tolist(),
            "cover95": None if Z is None else np.mean(np.abs(Z) <= 1.96, axis=0).tolist(),
            "rms_z_all": None if Z is None else float(np.sqrt(np.mean(Z**2))),
            "cover95_all": None if Z is None else float(np.mean(np.abs(Z) <= 1.96)),
            "time_s": seconds[name] / records,
            "refused": refused[name],
            "moesp_ratio": _spread(ratios[name]),
        }
    out["time_s"] = time.perf_counter() - t0
    print(f"monte carlo {case} {n:.0e}: {records} records, {out['time_s']:.0f} s", file=sys.stderr)
    return out


def _timed(fn: Callable[[Any], Any], d: Any) -> float:
    """Seconds one call of ``fn(d)`` took."""
    t0 = time.perf_counter()
    fn(d)
    return time.perf_counter() - t0


def _spread(ratios: list[float]) -> dict[str, float] | None:
    """Median, 90th percentile and largest of per-record time ratios (None without any)."""
    if not ratios:
        return None
    r = np.asarray(ratios)
    med, p90 = float(np.median(r)), float(np.quantile(r, 0.9))
    return {"median": med, "p90": p90, "max": float(r.max())}


def _monte_carlo_record(n: int, seed: int, case: str) -> tuple[Any, dict[str, Any]]:
    """One record and its truth (``truth["v"]``): a bench record (``bearing_case``) or,
    for ``case="realistic"``, the realistic bearing (``REALISTIC_MONTE_CARLO``)."""
    if case != "realistic":
        return bearing_case(n, seed=seed, case=case)
    from maglevid.physics.amb import AMBParameters
    from maglevid.simulate.amb import simulate_amb_loop

    nom = AMBParameters.nominal()
    d = simulate_amb_loop(nom, nominal=nom, n_samples=n, rng=seed)
    return d, {"v": np.asarray(d.metadata["operating_point_true"]["v"], dtype=float)}


def _ratio_to_ml(mc: dict[str, Any], method: str) -> np.ndarray | None:
    """Per-parameter RMS relative error of ``method`` over ML's, None without ML."""
    a, b = mc["methods"].get(method), mc["methods"].get("ml")
    if a is None or b is None:
        return None
    return np.asarray(a["rms_rel"]) / np.asarray(b["rms_rel"])


# ------------------------------------------------------------------ generic
def bench_generic(sizes: tuple[int, ...], seed: int = 3) -> list[dict[str, Any]]:
    plant, K, ctrl = example_unstable_mimo()
    h_true = plant.markov(10)
    p_true = np.sort_complex(plant.poles())
    tools = {
        "maglevid pbsid": lambda y, u: fit_pbsid(y, u, order=3),
        "maglevid ssarx": lambda y, u: fit_ssarx(y, u, order=3),
        "maglevid moesp": lambda y, u: fit_moesp(y, u, order=3),
        "maglevid n4sid": lambda y, u: fit_n4sid(y, u, order=3),
    }
    rows = []
    for n in sizes:
        y, u = simulate_innovation_loop(plant, K, ctrl, n, e_std=0.3, rng=seed)
        for tool, fn in tools.items():
            t, res = _median_time(fn, y, u)
            m = res.model
            rows.append(
                {
                    "case": "generic",
                    "N": n,
                    "tool": tool,
                    "time_s": t,
                    "markov_error": float(np.max(np.abs(m.markov(10) - h_true))),
                    "pole_error": float(np.max(np.abs(np.sort_complex(m.poles()) - p_true))),
                }
            )
            print(_row_text(rows[-1]), file=sys.stderr, flush=True)
    return rows


# --------------------------------------------------------------- suspension
def suspension_loop(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, float, float]:
    """``(y, u, dt, s_true)``: Sun et al.'s plant and lead-lag at the control rate, r != 0."""
    ctl = CONTROLLERS["lead-lag"]
    plant = suspension_state_space(SuspensionParameters.nominal(), ctl.dt)
    s_true = float(
        np.max(np.linalg.eigvals(suspension_state_space(SuspensionParameters.nominal()).A).real)
    )
    # Controller u = D(q^-1)/C(q^-1) (-y): a state-space form acting on y.
    num = np.concatenate([ctl.num, np.zeros(max(0, ctl.den.size - ctl.num.size))])
    den = np.concatenate([ctl.den, np.zeros(max(0, ctl.num.size - ctl.den.size))])
    Ac, Bc, Cc, Dc = scipy.signal.tf2ss(-num, den)
    ctrl = StateSpace(Ac, Bc, Cc, Dc, dt=ctl.dt)
    # Output noise 0.1 mm (innovations through K = 0: white measurement noise).
    K = np.zeros((plant.nx, 1))
    y, u = simulate_innovation_loop(plant, K, ctrl, n, r_std=10.0, e_std=1e-4, rng=seed)
    return y, u, ctl.dt, s_true


def bench_suspension(sizes: tuple[int, ...], seed: int = 5) -> list[dict[str, Any]]:
    # The Kalman predictor of this loop has a pole at 0.907 (the unstable pole's
    # mirror): the VARX truncation 0.907^p is 2e-4 at the default max_past 80.
    tools: dict[str, Callable[..., Any]] = {
        "maglevid pbsid": fit_pbsid,
        "maglevid ssarx": fit_ssarx,
        "maglevid pbsid, max_past=100": lambda *a, **k: fit_pbsid(*a, max_past=100, **k),
        "maglevid ssarx, max_past=100": lambda *a, **k: fit_ssarx(*a, max_past=100, **k),
        "maglevid moesp": fit_moesp,
        "maglevid n4sid": fit_n4sid,
    }
    rows = []
    for n in sizes:
        y, u, dt, s_true = suspension_loop(n, seed)
        for tool, fit in tools.items():
            t, res = _median_time(fit, y, u, order=3, dt=dt)
            s = np.log(res.model.poles().astype(complex)) / dt
            s_hat = float(np.max(s.real))
            rows.append(
                {
                    "case": "suspension",
                    "N": n,
                    "tool": tool,
                    "time_s": t,
                    "pole_error": abs(s_hat - s_true) / s_true,
                    "s_hat": s_hat,
                    "s_true": s_true,
                }
            )
            print(_row_text(rows[-1]), file=sys.stderr, flush=True)
    return rows


# ------------------------------------------------------------------- report
def _e(x: Any) -> str:
    return "-" if x is None else f"{x:.1e}"


def _row_text(r: dict[str, Any]) -> str:
    if "error" in r:
        return f"{r['case']:10s} {r['N']:.0e} {r['tool']:40s} {r['error']}"
    extra = " ".join(
        f"{k}={_e(r.get(k))}" for k in ("pole_error", "v_error", "markov_error") if k in r
    )
    return f"{r['case']:10s} {r['N']:.0e} {r['tool']:40s} {r['time_s']:.3g} s {extra}"


def run(sizes: tuple[int, ...] = SIZES, monte_carlo: bool = True) -> dict[str, Any]:
    """All four benchmarks; the results :func:`markdown_section` formats."""
    return {
        "bearing": bench_bearing(sizes, ("issue", "diagnostic")),
        "generic": bench_generic(sizes),
        "suspension": bench_suspension(sizes),
        "monte_carlo": [
            bench_monte_carlo(n, k, case)
            for n, k in MONTE_CARLO
            if n in sizes
            for case in ("issue", "diagnostic")
        ]
        + [bench_monte_carlo(n, k, "realistic") for n, k in REALISTIC_MONTE_CARLO]
        if monte_carlo
        else [],
        "load": os.getloadavg(),
    }


def markdown_section(results: dict[str, Any]) -> list[str]:
    """Markdown lines of the closed-loop subspace section (for run_all)."""
    out = [
        "## Closed-loop subspace: PBSID-opt and SSARX",
        "",
        f"`python -m benchmarks.bench_pbsid`; one BLAS thread; load average at the end "
        f"{results['load'][0]:.1f} (2 shared cores). Errors relative. Bearing: maglevid "
        f"fits, and PARSIM-K where a call takes under {SINGLE_RUN_S:g} s, timed interleaved "
        "(3-5 rounds, one call of each per round; time / MOESP's is the median of the "
        f"per-round ratios), other peers median of 3 (1 above {SINGLE_RUN_S:g} s; "
        "PARSIM-K warmed up by an untimed short fit first); "
        "other tables median of 3.",
        "",
        "| record | N | tool | time [s] | time / MOESP's | unstable pole error | max v error |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in results["bearing"]:
        if "error" in r:
            out.append(f"| {r['case']} | {r['N']:.0e} | {r['tool']} | - | - | - | {r['error']} |")
        else:
            ratio = r.get("moesp_ratio")
            out.append(
                f"| {r['case']} | {r['N']:.0e} | {r['tool']} | {r['time_s']:.3g} | "
                f"{'-' if ratio is None else f'{ratio:.2f}'} | "
                f"{_e(r['pole_error'])} | {_e(r['v_error'])} |"
            )
    out += _parsim_k_lines()
    out += [
        "",
        "Generic MIMO closed loop (`example_unstable_mimo`, e 0.3 rms, r 1 rms, order 3):",
        "",
        "| N | tool | time [s] | max Markov error | max pole error |",
        "|---|---|---|---|---|",
    ]
    out += [
        f"| {r['N']:.0e} | {r['tool']} | {r['time_s']:.3g} | {_e(r['markov_error'])} | "
        f"{_e(r['pole_error'])} |"
        for r in results["generic"]
    ]
    out += [
        "",
        "Suspension (Sun et al.) at the control rate, r 10 V rms, sensor noise 0.1 mm, order 3:",
        "",
        "| N | tool | time [s] | unstable pole error (s-plane) |",
        "|---|---|---|---|",
    ]
    out += [
        f"| {r['N']:.0e} | {r['tool']} | {r['time_s']:.3g} | {_e(r['pole_error'])} |"
        for r in results["suspension"]
    ]
    out += _monte_carlo_lines(results.get("monte_carlo") or [])
    return out


def _monte_carlo_lines(points: list[dict[str, Any]]) -> list[str]:
    """The Monte Carlo table: errors against ML's, the intervals' calibration."""
    points = [p for p in points if isinstance(p, dict) and "error" not in p]
    if not points:
        return []
    out = [
        "",
        "Monte Carlo on the bench's bearing records and on the realistic bearing's short "
        "records (`realistic`: nonlinear plant, 0.1 N force, the command line's noise; "
        "truth where it settles) (seeds 1000+; the structured fit with its default "
        "window, (P16) and (P23); ML the maximum-likelihood method on the same "
        "records): per parameter the RMS of the relative error over that of ML (the "
        "largest of v1..v9, and which), the RMS of (v - truth) / se (1 when the "
        "covariance (P15) is right) and the 95 % intervals' coverage, pooled over "
        "v1..v9; mean time a fit; its time over MOESP's (+ physical coordinates) on the "
        "same record, median and 90th percentile over the records (what the time target "
        "judges where it ran); the records the method refused (an IdentificationError: "
        "no estimate, left out of the RMS).",
        "",
        "| record | N | records | method | RMS error / ML's (largest) | RMS z | coverage "
        "| s a fit | time / MOESP's (median, p90) | refused |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for p in points:
        for name in MC_METHODS:
            m = p["methods"].get(name)
            if m is None:
                continue
            ratio = _ratio_to_ml(p, name)
            worst = (
                "-"
                if ratio is None or name == "ml"
                else f"{ratio.max():.2f} (v{int(np.argmax(ratio)) + 1})"
            )
            rz = "-" if m["rms_z_all"] is None else f"{m['rms_z_all']:.2f}"
            cv = "-" if m["cover95_all"] is None else f"{m['cover95_all']:.3f}"
            sp = m.get("moesp_ratio")
            tr = "-" if sp is None else f"{sp['median']:.2f}, {sp['p90']:.2f}"
            out.append(
                f"| {p['case']} | {p['N']:.0e} | {p['records']} | {name} | {worst} | {rz} | "
                f"{cv} | {m['time_s']:.3f} | {tr} | {m.get('refused', 0)} |"
            )
    return out


def _parsim_k_lines() -> list[str]:
    """Why PARSIM-K has no row above PEER_MAX_N: its measured footprint (stored)."""
    gb, sec = parsim_k_projection(1_000_000)
    pts = "; ".join(
        f"{n:.0e}: {t:.0f} s, {m:.2f} GB (load {ld:.1f})" for n, t, m, ld in PARSIM_K_MEASURED
    )
    return [
        "",
        f"SIPPY PARSIM-K above N = {PEER_MAX_N:.0e} (`--parsim-k-scaling`, issue record, "
        f"one process per N, peak resident memory): {pts}. Memory is linear in N, so "
        f"N = 1e6 would need ~{gb:.1f} GB (and >= {sec / 60:.0f} min): over the "
        f"{PEER_MEMORY_GB:.0f} GB one peer may take on this 24 GiB, 2-core machine "
        "shared by five users. The 1e6 speed ratio to PARSIM-K stays not measured.",
    ]


def targets(results: dict[str, Any], judge: Any) -> None:
    """The issue-16 verdicts through ``judge.add(target, measured_text, met)`` (run_all).

    The v_i and pole targets judge the structured fit (the default in physical
    coordinates); the time targets judge both the structured fit (the default) and
    the transform path; the transform's v errors are informative rows of the table.
    """
    rows = [r for r in results["bearing"] if "error" not in r]

    def get(case: str, n: int, tool: str) -> dict[str, Any] | None:
        return next((r for r in rows if (r["case"], r["N"], r["tool"]) == (case, n, tool)), None)

    mc = [p for p in results.get("monte_carlo") or [] if isinstance(p, dict) and "error" not in p]
    for method in ("pbsid", "ssarx"):
        label = f"{method}, structured fit (default)"
        _v_checks(rows, get, STRUCTURED[method], label, judge, mc, method)
        _realistic_check(mc, method, label, judge)
        _coverage_check(mc, method, label, judge)
        # The time targets judge both paths: the default (structured) one is what a
        # user gets, the transform path is the original subspace fit.
        # The Monte Carlo times the structured fit only.
        for tool, label, timed in (
            (STRUCTURED[method], f"{method}, structured fit (default)", method),
            (TRANSFORM[method], f"{method}, transform path", None),
        ):
            _time_checks(rows, get, tool, label, judge, mc, timed)


def _time_checks(
    rows: list[dict[str, Any]],
    get: Any,
    tool: str,
    label: str,
    judge: Any,
    mc: list[dict[str, Any]] | None = None,
    method: str | None = None,
) -> None:
    """>= 50x faster than PARSIM-K and within 2x MOESP's time, for one row kind.

    Every maglevid row carries the interleaved ratio to MOESP (``moesp_ratio``); a
    row without one (its interleaved rounds did not run) is divided by MOESP's
    median time of the same record. Where the Monte Carlo timed ``method`` against
    MOESP record by record (``mc``), the MOESP target is judged on the median of those
    ratios: a structured fit's time follows its Gauss-Newton path, which varies from
    record to record (issue 16, twenty-eighth session: 6-15 points at 1e4), so one
    record judges its own luck, as its errors did (the v_i target's Monte Carlo). The
    PARSIM-K target then divides PARSIM-K's time over MOESP's on the timed record (a
    one-pass method: its time does not depend on the record's noise) by that median.
    """
    checks: dict[str, list[tuple[str, bool]]] = {"peer": [], "moesp": []}
    unmeasured: list[str] = []  # PARSIM-K not run (its footprint: parsim_k_verdict)
    for r in (r for r in rows if r["tool"] == tool):
        where = f"{r['case']} {r['N']:.0e}"
        pk, mo = get(r["case"], r["N"], PARSIM_K_TOOL), get(r["case"], r["N"], MOESP_TOOL)
        ratio = r.get("moesp_ratio")
        if ratio is None:
            ratio = r["time_s"] / mo["time_s"] if mo is not None else None
        spread = _mc_time_spread(mc, r["case"], r["N"], method)
        if pk is not None:
            speed = pk["time_s"] / r["time_s"]
            text = f"{where}: {speed:.0f}x"
            if spread is not None and mo is not None:  # PARSIM-K / MOESP over the median
                interleaved = pk.get("moesp_ratio")
                pk_mo = interleaved or pk["time_s"] / mo["time_s"]
                how = "interleaved" if interleaved else "medians of 3"
                one, speed = speed, pk_mo / spread[1]["median"]
                text = (
                    f"{where}: {speed:.0f}x (PARSIM-K {pk_mo:.0f}x MOESP's time ({how}) "
                    f"over the Monte Carlo's median; the timed record {one:.0f}x)"
                )
            checks["peer"].append((text, speed >= 50.0))
        elif r["N"] > PEER_MAX_N:
            unmeasured.append(where)
        if spread is not None:
            records, sp = spread
            also = "" if ratio is None else f"; the timed record {ratio:.2g}x"
            text = (
                f"{where}: median {sp['median']:.2g}x, 90th percentile {sp['p90']:.2g}x "
                f"over {records} records{also}"
            )
            checks["moesp"].append((text, sp["median"] <= 2.0))
        elif ratio is not None:
            checks["moesp"].append((f"{where}: {ratio:.2g}x", ratio <= 2.0))
    names = {"peer": ">= 50x faster than PARSIM-K", "moesp": "within 2x MOESP's time"}
    for key, what in names.items():
        target = f"{label} (bearing): {what}"
        if not checks[key]:
            judge.add(target, "no measurement on this run", None)
            continue
        text = "; ".join(t for t, _ in checks[key])
        if key == "peer" and unmeasured:
            gb, _ = parsim_k_projection(max(r["N"] for r in rows))
            text += (
                f"; not measured at {', '.join(unmeasured)} (PARSIM-K ~{gb:.0f} GB "
                f"projected, over the {PEER_MEMORY_GB:.0f} GB limit)"
            )
        judge.add(target, text, all(ok for _, ok in checks[key]))


def _mc_point(mc: list[dict[str, Any]] | None, case: str, n: int) -> dict[str, Any] | None:
    """The Monte Carlo point of ``(case, n)``, None where it did not run."""
    return next((p for p in mc or [] if (p["case"], p["N"]) == (case, n)), None)


def _mc_time_spread(
    mc: list[dict[str, Any]] | None, case: str, n: int, method: str | None
) -> tuple[int, dict[str, float]] | None:
    """``(records, spread)`` of ``method``'s per-record time over MOESP's in the Monte
    Carlo point ``(case, n)``, None where it did not time them."""
    point = _mc_point(mc, case, n)
    if point is None or method is None:
        return None
    sp = (point["methods"].get(method) or {}).get("moesp_ratio")
    return None if sp is None else (point["records"], sp)


def _v_checks(
    rows: list[dict[str, Any]],
    get: Any,
    tool: str,
    label: str,
    judge: Any,
    mc: list[dict[str, Any]] | None = None,
    method: str | None = None,
) -> None:
    """The v_i and pole targets for one more row kind (the structured fit), judged alike.

    The v_i errors are compared as RMS over the Monte Carlo's records where it ran
    (``mc``: the largest per-parameter ratio to ML's), else on the timed record alone
    (its largest error over the best consistent method's).
    """
    v_checks, pole_checks = [], []
    for r in (r for r in rows if r["tool"] == tool):
        where = f"{r['case']} {r['N']:.0e}"
        ml = get(r["case"], r["N"], "maglevid ml")
        best = ml or get(r["case"], r["N"], "maglevid physical (IV)")
        one = None
        if best is not None and best.get("v_error") is not None:
            one = r["v_error"] / best["v_error"]
        point = _mc_point(mc, r["case"], r["N"])
        ratio = None if point is None or method is None else _ratio_to_ml(point, method)
        if ratio is not None:
            also = "" if one is None else f"; the timed record {one:.2g}x"
            n_ref = (point["methods"].get(method) or {}).get("refused", 0)
            also += f"; {n_ref} of {point['records']} records refused" if n_ref else ""
            text = f"{where}: {ratio.max():.2g}x (RMS over {point['records']} records{also})"
            v_checks.append((text, bool(ratio.max() <= 2.0) and not n_ref))
        elif one is not None:
            v_checks.append((f"{where}: {one:.2g}x (one record)", one <= 2.0))
        pk = get(r["case"], r["N"], PARSIM_K_TOOL)
        if pk is not None:
            ok = r["pole_error"] <= pk["pole_error"]
            pole_checks.append((f"{where}: {r['pole_error']:.1e} vs {pk['pole_error']:.1e}", ok))
    for checks, what in (
        (v_checks, "v_i error within 2x of the best consistent method (ML, else IV)"),
        (pole_checks, "unstable pole as accurate as the best peer (PARSIM-K)"),
    ):
        target = f"{label} (bearing): {what}"
        if not checks:
            judge.add(target, "no measurement on this run", None)
        else:
            judge.add(target, "; ".join(t for t, _ in checks), all(ok for _, ok in checks))


def _realistic_check(mc: list[dict[str, Any]], method: str, label: str, judge: Any) -> None:
    """The v_i target on the realistic bearing (``REALISTIC_MONTE_CARLO``): the largest
    per-parameter RMS error over ML's, within 2x at every N, no record refused."""
    target = f"{label} (realistic bearing): v_i error within 2x of ML (Monte Carlo, short records)"
    checks = []
    for p in (p for p in mc if p["case"] == "realistic"):
        ratio = _ratio_to_ml(p, method)
        if ratio is None:
            continue
        n_ref = (p["methods"].get(method) or {}).get("refused", 0)
        text = f"{p['N']:.0e}: {ratio.max():.2g}x (v{int(np.argmax(ratio)) + 1}; RMS over "
        text += f"{p['records']} records" + (f", {n_ref} refused)" if n_ref else ")")
        checks.append((text, bool(ratio.max() <= 2.0) and not n_ref))
    if not checks:
        judge.add(target, "no measurement on this run", None)
        return
    judge.add(target, "; ".join(t for t, _ in checks), all(ok for _, ok in checks))


def _coverage_check(mc: list[dict[str, Any]], method: str, label: str, judge: Any) -> None:
    """The structured fit's 95 % intervals hold the truth 90-99 % of the time (Monte
    Carlo, v1..v9 pooled), at every point the Monte Carlo ran."""
    target = f"{label} (bearing): 95 % intervals cover the truth (90-99 %, Monte Carlo)"
    checks = [(p, p["methods"].get(method) or {}) for p in mc]
    checks = [(p, m) for p, m in checks if m.get("cover95_all") is not None]
    if not checks:
        judge.add(target, "no measurement on this run", None)
        return
    text = "; ".join(
        f"{p['case']} {p['N']:.0e}, {p['records']} records x 9: {m['cover95_all']:.3f} "
        f"(RMS z {m['rms_z_all']:.2f})"
        for p, m in checks
    )
    judge.add(target, text, all(0.90 <= m["cover95_all"] <= 0.99 for _, m in checks))


def _measure(run_: Any, plan: dict[str, Any], args: Any) -> dict[str, Any]:
    sizes = [10_000] if plan.get("quick") else list(SIZES)
    result: dict[str, Any] = run_.call(
        "benchmarks.bench_pbsid:run", sizes=sizes, monte_carlo=False
    )
    # each Monte Carlo point in its own worker (its own time limit): 100 records of
    # three fits at 1e4 take ~40 s on an idle core, 30 at 1e5 ~30 s
    points = [(n, k) for n, k in MONTE_CARLO if n in sizes]
    if plan.get("quick"):
        points = [(10_000, 30)]
    jobs = [(n, k, case) for n, k in points for case in ("issue", "diagnostic")]
    jobs += [(n, 10 if plan.get("quick") else k, "realistic") for n, k in REALISTIC_MONTE_CARLO]
    mc = []
    for n, k, case in jobs:
        p = run_.call("benchmarks.bench_pbsid:bench_monte_carlo", n=n, records=k, case=case)
        mc.append(p if isinstance(p, dict) else {"error": str(p)})
    if isinstance(result, dict) and "bearing" in result:
        result["monte_carlo"] = mc
    return result


try:  # run_all's section registry (benchmarks/sections.py, issue 15), where present
    from benchmarks.sections import Section
except ImportError:  # pragma: no cover - older branches: run_all uses main()
    pass
else:
    #: The ``make bench`` section (``run_all.PLUGINS`` names this module).
    SECTION = Section("pbsid", _measure, markdown_section, targets)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", nargs="+", type=float, default=list(SIZES))
    ap.add_argument("--quick", action="store_true", help="N = 1e4 only")
    ap.add_argument("--out", help="write the markdown section here")
    ap.add_argument(
        "--parsim-k-scaling",
        nargs="+",
        type=float,
        metavar="N",
        help="only measure PARSIM-K's time and peak memory at these N (PARSIM_K_MEASURED)",
    )
    args = ap.parse_args(argv)
    if args.parsim_k_scaling:
        for n in args.parsim_k_scaling:
            r = measure_parsim_k(int(n))
            print(
                f"({r['N']}, {r['time_s']:.1f}, {r['peak_gb']:.2f}, {r['load']:.1f}),", flush=True
            )
        return 0
    res = run(tuple(int(n) for n in ([1e4] if args.quick else args.sizes)))
    text = "\n".join(markdown_section(res)) + "\n"
    if args.out:
        with open(args.out, "w", encoding="utf-8") as fh:
            fh.write(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
