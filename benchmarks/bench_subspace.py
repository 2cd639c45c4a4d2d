"""Speed, memory and accuracy of maglevid's MOESP / N4SID against peers.

Run from the repository root::

    python -m benchmarks.bench_subspace                       # N = 1e4, 1e5, 1e6
    python -m benchmarks.bench_subspace --sizes 1e4 1e5 --noise 0.1 --json out.json
    python -m benchmarks.bench_subspace --versus-ctrlsys --sizes 1e3 1e4 1e5 1e6 \
        --noise 0.1 --repeat 5                                # against SLICOT, interleaved

Data: a fixed random 4th-order system with 2 inputs and 3 outputs (poles
0.9 e^{+-0.3j}, 0.5, -0.3; basis scrambled), white-noise inputs, optional white
output noise (``--noise``, relative to the output RMS). Every peer receives the
same ``(y, u, order, horizon)`` and returns the poles; the table gives the
best-of-``--repeat`` wall time and CPU time (``process_time``: steadier on a
shared machine; it sums the threads of a multi-threaded BLAS), the ratio of the
wall time to the bare-numpy reference, the peak traced memory (``tracemalloc``, a
separate run, so tracing does not slow the timing) and the largest relative
pole error.

Adding a peer (SIPPY, Octave, SLICOT, ...) is one function and one line::

    def sippy_n4sid(y, u, order, horizon):
        ...
        return np.linalg.eigvals(A)

    register(Peer("sippy-n4sid", sippy_n4sid, max_samples=10**6, note="SIPPY 0.x"))

A peer that needs a missing package should raise ``ImportError``; it is then
listed as skipped. ``max_samples`` skips sizes a peer cannot handle in memory.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import platform
import sys
import tempfile
import time
import tracemalloc
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
from numpy.lib.stride_tricks import sliding_window_view
from scipy.optimize import linear_sum_assignment

from maglevid.identify._recursion import linear_recursion
from maglevid.identify.subspace import SubspaceAccumulator, fit_moesp, fit_n4sid

PoleFunction = Callable[[np.ndarray, np.ndarray, int, int], np.ndarray]


@dataclass(frozen=True)
class Peer:
    """One contender: ``fn(y, u, order, horizon) -> poles``."""

    name: str
    fn: PoleFunction
    max_samples: int | None = None
    note: str = ""


PEERS: dict[str, Peer] = {}


def register(peer: Peer) -> None:
    """Add (or replace) a peer by name."""
    PEERS[peer.name] = peer


# ------------------------------------------------------------------ maglevid
def _maglevid_moesp(y, u, order, horizon):
    return fit_moesp(y, u, order=order, horizon=horizon).model.poles()


def _maglevid_n4sid(y, u, order, horizon):
    return fit_n4sid(y, u, order=order, horizon=horizon).model.poles()


def _maglevid_moesp_qr(y, u, order, horizon):
    return fit_moesp(y, u, order=order, horizon=horizon, factorization="qr").model.poles()


def _maglevid_stream(y, u, order, horizon):
    acc = SubspaceAccumulator(ny=y.shape[1], nu=u.shape[1], horizon=horizon)
    for k in range(0, y.shape[0], 100_000):
        acc.update(y[k : k + 100_000], u[k : k + 100_000])
    return acc.fit(algorithm="moesp", order=order).model.poles()


# ------------------------------------------------------ where the time goes
def stage_profile(y, u, order, horizon, repeat=3):
    """Median seconds of each stage of ``fit_moesp`` (the in-memory Gram route).

    ``read``: one pass over the data (``y.sum() + u.sum()``), the floor of any
    method; ``data pass``: the chunked lagged products (``_LagGram``, what
    ``fit_moesp`` runs over the record); ``model``: everything after it that
    does not look at the record again (Gram, Cholesky, subspace step, B and D,
    noise model and Kalman gain, result); ``residuals``: the one-step
    predictor over the record (``fit - model``); ``fit``: ``fit_moesp`` itself.
    Uses the module's internals: a profiler, not an API.
    """
    import statistics

    from maglevid.identify import subspace as ss
    from maglevid.identify._hankel import _LagGram

    m = y.shape[1] + u.shape[1]

    def data_pass():  # what fit_moesp runs over the record (subspace._feed)
        acc = _LagGram(m, 2 * horizon - 1)
        ss._feed(acc, u, y)
        return acc

    acc = data_pass()
    opt = ss._options(
        "moesp",
        order=order,
        horizon=horizon,
        dt=1.0,
        feedthrough=False,
        weighting="po",
        rank_tol=None,
        factorization="gram",
        bd_method="subspace",
        max_horizon=None,
    )
    stages = {
        "read": lambda: (y.sum(), u.sum()),
        "data pass": data_pass,
        "model": lambda: ss._fit(acc, u.shape[1], y.shape[1], opt, horizon, None),
        "fit": lambda: fit_moesp(y, u, order=order, horizon=horizon),
    }
    times: dict[str, list[float]] = {k: [] for k in stages}
    for _ in range(repeat):  # interleaved: a core's speed drifts within seconds
        for k, fn in stages.items():
            t0 = time.perf_counter()
            fn()
            times[k].append(time.perf_counter() - t0)
    out = {k: statistics.median(v) for k, v in times.items()}
    out["residuals"] = max(out["fit"] - out["data pass"] - out["model"], 0.0)
    return out


def versus_ctrlsys(sizes, order=4, horizon=10, noise=0.1, repeat=5, stages=True):
    """maglevid MOESP / N4SID against SLICOT (``ctrlsys``) in this process, interleaved.

    For each ``N`` of ``sizes``: the fits (maglevid MOESP, ctrlsys IB01AD/BD
    MOESP with Cholesky and ``jobck='K'``, maglevid N4SID, ctrlsys N4SID with
    Cholesky; the model with the noise covariances and the Kalman gain on both
    sides; ``lean``: maglevid's ``noise_model=False`` against ctrlsys's
    ``jobck='N'``, the model alone on both sides) and two
    reads of the data (``read``: ``y.sum() + u.sum()`` in memory; ``np.load``: the
    same data from a ``.npy`` file in the page cache) run in turn, ``repeat``
    rounds after one warm-up; the best (minimum) wall time of each is reported
    (``... median`` and ``... cpu``, the best ``process_time``, beside it) with the
    ratios maglevid / ctrlsys and maglevid / read: on a shared machine a core's
    speed drifts within seconds, so only interleaved ratios compare. ``stages``
    adds ``stage_profile``. The load average before and after is recorded (ratios
    stay meaningful, times do not). Raises ``ImportError`` when ctrlsys is missing.
    """
    import statistics

    from benchmarks.peers import ctrlsys_slicot

    ok, why = ctrlsys_slicot.available()
    if not ok:
        raise ImportError(why)
    rows = []
    for size in sizes:
        N = int(size)
        y, u, _ = make_data(N, noise)
        load0 = os.getloadavg()[0]
        fns = _contenders(y, u, order, horizon, ctrlsys_slicot.identify)
        with tempfile.TemporaryDirectory() as tmp:
            path = os.path.join(tmp, "z.npy")
            np.save(path, np.concatenate([u, y], axis=1))
            fns["read"] = lambda y=y, u=u: (y.sum(), u.sum())  # one pass, in memory
            fns["np.load"] = lambda path=path: np.load(path)  # one read from a file
            for fn in fns.values():  # warm-up: imports, caches, the file in the page cache
                fn()
            times: dict[str, list[float]] = {k: [] for k in fns}
            cpu: dict[str, list[float]] = {k: [] for k in fns}
            for _ in range(repeat):
                for k, fn in fns.items():
                    gc.collect()
                    c0, t0 = time.process_time(), time.perf_counter()
                    fn()
                    times[k].append(time.perf_counter() - t0)
                    cpu[k].append(time.process_time() - c0)
        row = {"n_samples": N, "repeat": repeat, "statistic": "best"}
        row.update({k: min(v) for k, v in times.items()})
        row.update({f"{k} median": statistics.median(v) for k, v in times.items()})
        row.update({f"{k} cpu": min(v) for k, v in cpu.items()})
        row["MOESP ratio"] = row["maglevid MOESP"] / row["ctrlsys MOESP"]
        row["N4SID ratio"] = row["maglevid N4SID"] / row["ctrlsys N4SID"]
        row["MOESP lean ratio"] = row["maglevid MOESP lean"] / row["ctrlsys MOESP lean"]
        row["N4SID lean ratio"] = row["maglevid N4SID lean"] / row["ctrlsys N4SID lean"]
        for a, b in (("MOESP", "MOESP"), ("N4SID", "N4SID"), ("MOESP lean", "MOESP lean")):
            row[f"{a} cpu ratio"] = row[f"maglevid {a} cpu"] / row[f"ctrlsys {b} cpu"]
        for k in ("maglevid MOESP", "maglevid MOESP lean"):
            row[f"{k} / read"] = row[k] / row["read"]
            row[f"{k} / np.load"] = row[k] / row["np.load"]
        if stages:
            row["stages"] = stage_profile(y, u, order, horizon, repeat=repeat)
        row["load"] = (load0, os.getloadavg()[0])
        rows.append(row)
    return rows


def _contenders(y, u, order, horizon, slicot):
    """The four timed calls of ``versus_ctrlsys`` on one record."""
    return {
        "maglevid MOESP": lambda: fit_moesp(y, u, order=order, horizon=horizon),
        "ctrlsys MOESP": lambda: slicot(y, u, order, horizon),
        "maglevid N4SID": lambda: fit_n4sid(y, u, order=order, horizon=horizon),
        "ctrlsys N4SID": lambda: slicot(y, u, order, horizon, "N4SID Cholesky"),
        # The model alone (A, B, C, D; no noise model) against SLICOT's jobck='N':
        "maglevid MOESP lean": lambda: fit_moesp(
            y, u, order=order, horizon=horizon, noise_model=False
        ),
        "ctrlsys MOESP lean": lambda: slicot(y, u, order, horizon, jobck="N"),
        "maglevid N4SID lean": lambda: fit_n4sid(
            y, u, order=order, horizon=horizon, noise_model=False
        ),
        "ctrlsys N4SID lean": lambda: slicot(y, u, order, horizon, "N4SID Cholesky", "N"),
    }


def print_versus(rows) -> None:
    """The table of ``versus_ctrlsys`` (milliseconds, best of the rounds)."""
    print(
        f"{'N':>9} {'MOESP':>9} {'ctrlsys':>9} {'ratio':>6} {'N4SID':>9} {'ctrlsys':>9} "
        f"{'ratio':>6} {'lean M':>7} {'lean N':>7} {'read':>7} {'np.load':>8} "
        f"{'M/load':>7} {'lean/load':>9} {'pass':>8} {'model':>7} {'resid':>7} "
        f"{'cpu: M':>6} {'N':>5} {'lean M':>6}  load"
    )
    for r in rows:
        st = r.get("stages", {})
        ms = [1e3 * r[k] for k in ("maglevid MOESP", "ctrlsys MOESP")]
        mn = [1e3 * r[k] for k in ("maglevid N4SID", "ctrlsys N4SID")]
        sp = [1e3 * st.get(k, float("nan")) for k in ("data pass", "model", "residuals")]
        print(
            f"{r['n_samples']:>9.0e} {ms[0]:>9.2f} {ms[1]:>9.2f} {r['MOESP ratio']:>6.2f} "
            f"{mn[0]:>9.2f} {mn[1]:>9.2f} {r['N4SID ratio']:>6.2f} {r['MOESP lean ratio']:>7.2f} "
            f"{r['N4SID lean ratio']:>7.2f} {1e3 * r['read']:>7.2f} {1e3 * r['np.load']:>8.2f} "
            f"{r['maglevid MOESP / np.load']:>7.1f} {r['maglevid MOESP lean / np.load']:>9.1f} "
            f"{sp[0]:>8.2f} {sp[1]:>7.2f} {sp[2]:>7.2f} {r['MOESP cpu ratio']:>6.2f} "
            f"{r['N4SID cpu ratio']:>5.2f} {r['MOESP lean cpu ratio']:>6.2f}  "
            f"{r['load'][0]:.1f}-{r['load'][1]:.1f}"
        )
        sys.stdout.flush()


# --------------------------------------------------- the bare numpy baseline
def numpy_gram_cholesky(y, u, order, horizon):
    """Textbook PO-MOESP with numpy alone: Gram of the block-Hankel rows + Cholesky.

    The Hankel rows are built chunk by chunk (a full 10^6 x 100 matrix would be
    800 MB) and the Gram accumulated with ``H.T @ H`` (BLAS syrk/gemm); the
    variables are ordered ``[U_f, U_p, Y_p, Y_f]`` so the Cholesky factor is the
    LQ factor ``L`` of the textbook; ``L32`` gives ``Gamma_i`` and the poles. The
    Cholesky gets a tiny ridge ``1e-12 max(diag)`` because the Gram of
    noise-free data is singular. This is the reference cost: maglevid aims to
    stay within 1.5x of it.
    """
    i = horizon
    z = np.concatenate([u, y], axis=1)
    N, m = z.shape
    nu, ny = u.shape[1], y.shape[1]
    w = 2 * i
    k = w * m
    G = np.zeros((k, k))
    chunk = 16384
    for s0 in range(0, N - w + 1, chunk):
        s1 = min(N - w + 1, s0 + chunk)
        H = sliding_window_view(z[s0 : s1 + w - 1], (w, m)).reshape(s1 - s0, k)
        G += H.T @ H
    # Reorder the variables: time-major [u(t), y(t)] blocks -> [U_f, U_p, Y_p, Y_f].
    idx_u = [t * m + c for t in range(w) for c in range(nu)]
    idx_y = [t * m + nu + c for t in range(w) for c in range(ny)]
    perm = idx_u[i * nu :] + idx_u[: i * nu] + idx_y[: i * ny] + idx_y[i * ny :]
    Gp = G[np.ix_(perm, perm)]
    L = np.linalg.cholesky(Gp + 1e-12 * np.max(np.diag(Gp)) * np.eye(k))
    r2, r3 = 2 * i * nu + i * ny, k
    L32 = L[r2:r3, i * nu : r2]
    U = np.linalg.svd(L32, full_matrices=False)[0][:, :order]
    A = np.linalg.lstsq(U[:-ny], U[ny:], rcond=None)[0]
    return np.linalg.eigvals(A)


# ------------------------------------------------------------- python-control
def control_era(y, u, order, horizon):
    """python-control: Markov parameters by least squares, then ERA."""
    import control

    m = 60  # FIR length: 0.9^60 ~ 2e-3 truncation for these poles
    H = control.markov(y, u, m, transpose=True)
    sys_, _ = control.eigensys_realization(H, order, m=horizon, n=horizon, transpose=True)
    return np.linalg.eigvals(np.asarray(sys_.A))


def slicot_ctrlsys(y, u, order, horizon):
    """SLICOT IB01AD (Cholesky) + IB01BD (MOESP) natively (PyPI ``ctrlsys``)."""
    from benchmarks.peers import PeerMissing, ctrlsys_slicot

    try:
        return ctrlsys_slicot.identify(y, u, order, horizon).poles
    except PeerMissing as exc:
        raise ImportError(str(exc)) from None


register(Peer("maglevid-moesp", _maglevid_moesp, note="PO-MOESP, Gram route (default)"))
register(Peer("maglevid-n4sid", _maglevid_n4sid, note="robust N4SID, Gram route (default)"))
register(Peer("maglevid-moesp-qr", _maglevid_moesp_qr, note="PO-MOESP, TSQR route"))
register(Peer("maglevid-stream", _maglevid_stream, note="accumulator, 1e5-sample chunks"))
register(Peer("numpy-gram-cholesky", numpy_gram_cholesky, note="the reference cost"))
register(Peer("control-era", control_era, max_samples=10**5, note="markov (m=60) + ERA"))
register(Peer("slicot-ctrlsys", slicot_ctrlsys, note="SLICOT IB01AD/BD, Cholesky, MOESP"))


# --------------------------------------------------------------------- data
TRUE_POLES = (0.9 * np.exp(0.3j), 0.9 * np.exp(-0.3j), 0.5, -0.3)


def make_system(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A, B, C) of the benchmark system (2 inputs, 3 outputs, 4 states)."""
    rng = np.random.default_rng(seed)
    p = TRUE_POLES[0]
    A0 = sla.block_diag([[p.real, p.imag], [-p.imag, p.real]], [[0.5]], [[-0.3]])
    T = rng.standard_normal((4, 4)) + 2 * np.eye(4)
    A = T @ A0 @ np.linalg.inv(T)
    return A, rng.standard_normal((4, 2)), rng.standard_normal((3, 4))


def make_data(n_samples: int, noise: float, seed: int = 1):
    A, B, C = make_system()
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((n_samples, 2))
    X, _ = linear_recursion(A, u @ B.T)
    y = X @ C.T
    if noise:
        y = y + noise * y.std(axis=0) * rng.standard_normal(y.shape)
    return y, u, np.linalg.eigvals(A)


def pole_error(est: np.ndarray, true: np.ndarray) -> float:
    est = np.asarray(est, dtype=complex).ravel()
    if est.shape != true.shape:
        return float("nan")
    cost = np.abs(est[:, None] - true[None, :])
    r, c = linear_sum_assignment(cost)
    return float(np.max(cost[r, c] / np.abs(true[c])))


# ------------------------------------------------------------------- runner
def run_peer(peer: Peer, y, u, true, order, horizon, repeat, memory):
    times, cpu = [], []
    poles = None
    for _ in range(repeat):
        gc.collect()
        t0, c0 = time.perf_counter(), time.process_time()
        poles = peer.fn(y, u, order, horizon)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    peak = float("nan")
    if memory:
        gc.collect()
        tracemalloc.start()
        peer.fn(y, u, order, horizon)
        peak = tracemalloc.get_traced_memory()[1] / 2**20
        tracemalloc.stop()
    return {
        "time_s": min(times),
        "cpu_s": min(cpu),
        "peak_mib": peak,
        "pole_error": pole_error(poles, true),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", nargs="+", type=float, default=[1e4, 1e5, 1e6])
    ap.add_argument("--order", type=int, default=4)
    ap.add_argument("--horizon", type=int, default=10)
    ap.add_argument("--noise", type=float, default=0.0, help="output noise / output RMS")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--peers", nargs="+", default=None, help=f"subset of {sorted(PEERS)}")
    ap.add_argument("--no-memory", action="store_true", help="skip the tracemalloc run")
    ap.add_argument("--json", default=None, help="also write the results to this file")
    ap.add_argument(
        "--versus-ctrlsys",
        action="store_true",
        help="only maglevid MOESP/N4SID against ctrlsys, interleaved, best of --repeat rounds",
    )
    args = ap.parse_args(argv)
    if args.versus_ctrlsys:
        rows = versus_ctrlsys(args.sizes, args.order, args.horizon, args.noise, args.repeat)
        print(f"# maglevid vs ctrlsys [ms], best of {args.repeat} interleaved rounds")
        print_versus(rows)
        if args.json:
            with open(args.json, "w") as fh:
                json.dump({"args": vars(args), "versus_ctrlsys": rows}, fh, indent=2)
        return 0
    names = args.peers or list(PEERS)
    unknown = set(names) - set(PEERS)
    if unknown:
        ap.error(f"unknown peers {sorted(unknown)}; known: {sorted(PEERS)}")

    results = []
    print(
        f"# subspace benchmark: order {args.order}, horizon {args.horizon}, noise {args.noise}, "
        f"numpy {np.__version__}, python {platform.python_version()}"
    )
    print(
        f"{'N':>9} {'peer':<22} {'time [s]':>10} {'cpu [s]':>9} {'x numpy':>8} {'peak [MiB]':>11} "
        f"{'pole err':>9}  note"
    )
    for size in args.sizes:
        N = int(size)
        y, u, true = make_data(N, args.noise)
        base = None
        rows = []
        for name in names:
            peer = PEERS[name]
            if peer.max_samples is not None and N > peer.max_samples:
                rows.append({"peer": name, "skipped": f"N > {peer.max_samples}"})
                continue
            try:
                r = run_peer(
                    peer, y, u, true, args.order, args.horizon, args.repeat, not args.no_memory
                )
            except ImportError as exc:
                rows.append({"peer": name, "skipped": f"not installed ({exc})"})
                continue
            r["peer"] = name
            rows.append(r)
            if name == "numpy-gram-cholesky":
                base = r["time_s"]
        for r in rows:
            r["n_samples"] = N
            if "skipped" in r:
                print(f"{N:>9} {r['peer']:<22} {'skipped: ' + r['skipped']}")
                continue
            ratio = r["time_s"] / base if base else float("nan")
            r["ratio_to_numpy"] = ratio
            print(
                f"{N:>9} {r['peer']:<22} {r['time_s']:>10.3f} {r['cpu_s']:>9.3f} {ratio:>8.2f} "
                f"{r['peak_mib']:>11.1f} {r['pole_error']:>9.1e}  {PEERS[r['peer']].note}"
            )
        results.extend(rows)
        sys.stdout.flush()
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"args": vars(args), "results": results}, fh, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
