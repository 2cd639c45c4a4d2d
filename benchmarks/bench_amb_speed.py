"""The closed-loop unstable bearing: maglevid's AMB methods, their speed and accuracy.

Run from the repository root::

    python -m benchmarks.bench_amb_speed                  # N = 1e4, 1e5, 1e6
    python -m benchmarks.bench_amb_speed --sizes 1e6 --profile

Two things, on the bearing of Gosiewski & Paszowski in closed loop (controller
and deadbeat observer designed on the nominal bearing, white Gaussian
excitation of 1 V rms; the two records of ``CASES``):

1. **Regression speed** (the ``"diagnostic"`` record, on which least squares
   works too). The AMB methods are linear regressions. The
   regressor of the plant ARX (``phi(k) = [y(k), x_pos(k-1), u(k), u(k-1)]``,
   :func:`maglevid.identify.physical.plant_regression`) is built once and
   ``np.linalg.lstsq`` timed on it: the cost of one bare least-squares solve.
   Each maglevid fit is timed from the recording to the physical parameters
   with their covariance (it builds its own regressors, and for IV simulates
   its instruments). The ratio is the overhead of everything maglevid adds;
   the target is 3x at N = 10^6. ``--profile`` prints where the time goes.
2. **Accuracy** (used by ``run_all``): the unstable pole (about
   ``exp(460 dt)``) and v1..v9 of every maglevid method.
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from benchmarks.bench_amb_mc import PAPER_LIKE_NOISE
from maglevid.data import ClosedLoopData
from maglevid.identify.deadbeat import fit_deadbeat_arx, fit_deadbeat_iv
from maglevid.identify.physical import fit_physical, plant_regression, to_physical_coordinates
from maglevid.identify.subspace import fit_moesp, fit_n4sid
from maglevid.physics.amb import AMBParameters, amb_state_space, v_from_matrices
from maglevid.simulate import simulate_amb_loop

#: The fault of the diagnostic case (that of bench_amb_mc).
FAULT = {"R1": 1.2, "kw1": 1.2}
#: Horizon of the subspace methods on this plant (unstable, sampled fast: docs/subspace.md).
BEARING_HORIZON = 40
#: Rows skipped at the start by the AMB fits (their default).
SKIP = 10

#: The two bearing records. ``"issue"``: the healthy bearing as
#: :func:`~maglevid.simulate.simulate_amb_loop` makes it by default (its
#: measurement noise, 1e-7 m and 1e-4 A, is what makes the peers and the
#: least-squares methods fail); unstable pole ~455 rad/s. ``"diagnostic"``: R1
#: and kw1 +20 %, paper-like noise (1e-10 m, 3e-6 A), the observer running on
#: the real plant so that the paper's deadbeat method applies (bench_amb_mc).
CASES: dict[str, dict[str, Any]] = {
    "issue": {"fault": {}, "noise_std": None, "observer_model": "nominal"},
    "diagnostic": {"fault": FAULT, "noise_std": PAPER_LIKE_NOISE, "observer_model": "plant"},
}


def bearing_case(
    n: int, seed: int = 11, case: str = "diagnostic"
) -> tuple[ClosedLoopData, dict[str, Any]]:
    """The closed-loop record and its truth (unstable pole in z and in rad/s, v1..v9)."""
    spec = CASES[case]
    nom = AMBParameters.nominal()
    plant = nom.with_fault(**spec["fault"]) if spec["fault"] else nom
    kw = {} if spec["noise_std"] is None else {"noise_std": spec["noise_std"]}
    data = simulate_amb_loop(
        plant,
        nominal=nom,
        n_samples=int(n),
        rng=seed,
        observer_model=spec["observer_model"],
        **kw,
        plant_model="linear",
    )
    poles = amb_state_space(plant, data.dt).poles()
    z = float(np.max(poles[np.abs(poles.imag) < 1e-12].real))
    truth = {
        "z": z,
        "s": float(np.log(z) / data.dt),
        "v": np.asarray(data.metadata["truth_v"], dtype=float),
        "dt": data.dt,
        "noise_std": list(data.metadata["noise_std"]),
    }
    return data, truth


def unstable_pole(poles: Any, truth: dict[str, Any]) -> dict[str, Any]:
    """Error of the pole nearest the true unstable one; ``found`` when it is unstable,
    real to 1 % and within 10 % of the true rate in rad/s."""
    p = np.asarray(poles, dtype=complex).ravel()
    if p.size == 0 or not np.all(np.isfinite(p)):
        return {"pole_error": float("nan"), "found": False, "s_hat": float("nan")}
    k = int(np.argmin(np.abs(p - truth["z"])))
    z = p[k]
    s_hat = float(np.log(abs(z)) / truth["dt"]) if abs(z) > 0 else float("nan")
    found = bool(
        abs(z) > 1.0
        and abs(z.imag) < 0.01 * abs(z.real - 1.0) + 1e-12
        and abs(s_hat - truth["s"]) < 0.1 * truth["s"]
    )
    return {
        "pole_error": float(abs(z - truth["z"]) / abs(truth["z"])),
        "found": found,
        "s_hat": s_hat,
    }


def _subspace(fit: Callable[..., Any]) -> Callable[[ClosedLoopData], tuple[Any, Any]]:
    def run(d: ClosedLoopData) -> tuple[Any, Any]:
        res = fit(np.asarray(d.y), np.asarray(d.u), order=4, horizon=BEARING_HORIZON, dt=d.dt)
        _, cont = to_physical_coordinates(res.model)  # the physical parameters too
        v, _ = v_from_matrices(cont.A, cont.B)
        return res.model.poles(), v

    return run


def _amb(fit: Callable[..., Any], **options: Any) -> Callable[[ClosedLoopData], tuple[Any, Any]]:
    def run(d: ClosedLoopData) -> tuple[Any, Any]:
        res = fit(d, **options)
        return res.model.poles(), np.array([res.parameters[f"v{i}"] for i in range(1, 10)])

    return run


#: maglevid's methods on the bearing: ``data -> (discrete poles, v1..v9)``.
BEARING_METHODS: dict[str, Callable[[ClosedLoopData], tuple[Any, Any]]] = {
    "physical (IV)": _amb(fit_physical),
    "physical (LS)": _amb(fit_physical, estimator="ls"),
    "deadbeat-iv": _amb(fit_deadbeat_iv),
    "deadbeat-arx": _amb(fit_deadbeat_arx),
    "moesp + physical coordinates": _subspace(fit_moesp),
    "n4sid + physical coordinates": _subspace(fit_n4sid),
}

#: The regression fits timed against one lstsq.
REGRESSION_FITS: dict[str, Callable[[ClosedLoopData], Any]] = {
    "physical (LS)": lambda d: fit_physical(d, estimator="ls"),
    "physical (IV)": lambda d: fit_physical(d),
    "deadbeat-arx": lambda d: fit_deadbeat_arx(d),
    "deadbeat-iv": lambda d: fit_deadbeat_iv(d),
}


def median_time(fn: Callable[[], Any], repeat: int) -> tuple[float, Any]:
    """Median wall time of ``repeat`` calls and the last result."""
    times, out = [], None
    for _ in range(max(1, repeat)):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def profile_text(fn: Callable[[], Any], lines: int = 14) -> str:
    """cProfile of one call, the ``lines`` entries with the largest cumulative time."""
    prof = cProfile.Profile()
    prof.enable()
    fn()
    prof.disable()
    buf = io.StringIO()
    pstats.Stats(prof, stream=buf).strip_dirs().sort_stats("cumulative").print_stats(lines)
    text = buf.getvalue()
    start = text.find("   ncalls")
    return text[start:].rstrip() if start >= 0 else text.rstrip()


def regression_speed(
    n: int, *, repeat: int = 5, profile_above: float | None = 3.0
) -> dict[str, Any]:
    """Time lstsq on the plant-ARX regressor and every AMB fit on the same record.

    On a shared machine the speed of a core drifts by tens of percent within
    seconds, so the fits and ``lstsq`` are timed *interleaved*: ``repeat`` rounds,
    each timing ``lstsq`` and then every fit once. The ratio of a fit is the
    median over the rounds of (fit time / that round's ``lstsq`` time): both
    sides of each ratio were taken seconds apart. One untimed warm-up round first.
    """
    data, _ = bearing_case(n)
    y, u = np.asarray(data.y), np.asarray(data.u)
    lhs, phi = plant_regression(y, u, start=SKIP)

    def lstsq() -> Any:
        return np.linalg.lstsq(phi, lhs, rcond=None)

    def once(fn: Callable[[], Any]) -> float:
        t0 = time.perf_counter()
        fn()
        return time.perf_counter() - t0

    once(lstsq)
    for fit in REGRESSION_FITS.values():
        once(lambda fit=fit: fit(data))
    t_ls: list[float] = []
    times: dict[str, list[float]] = {name: [] for name in REGRESSION_FITS}
    for _ in range(repeat):
        t_ls.append(once(lstsq))
        for name, fit in REGRESSION_FITS.items():
            times[name].append(once(lambda fit=fit: fit(data)))
    lstsq_s = statistics.median(t_ls)
    out: dict[str, Any] = {
        "n": n,
        "lstsq_s": lstsq_s,
        "lstsq_spread": [min(t_ls), max(t_ls)],
        "rounds": repeat,
        "regressor_shape": list(phi.shape),
        "fits": {},
    }
    for name, fit in REGRESSION_FITS.items():
        ratios = [t / tl for t, tl in zip(times[name], t_ls, strict=True)]
        ratio = statistics.median(ratios)
        row: dict[str, Any] = {
            "time_s": statistics.median(times[name]),
            "ratio": ratio,
            "ratio_spread": [min(ratios), max(ratios)],
        }
        if profile_above is not None and ratio > profile_above:
            row["profile"] = profile_text(lambda fit=fit: fit(data))
        out["fits"][name] = row
    return out


def versus_ctrlsys(
    sizes: list[int], *, repeat: int = 7, parsim_at: int | None = None
) -> list[dict[str, Any]]:
    """``moesp + physical coordinates`` (horizon 40) against ctrlsys MOESP at horizon 40.

    The bearing's speed targets in one process, interleaved: each round times the
    maglevid fit and SLICOT's IB01AD + IB01BD (Cholesky, ``nobr = 40``, with the Kalman
    gain: ``jobck='K'``, as maglevid's default computes it) on the same
    record, ``repeat`` rounds after one warm-up; the best wall and CPU
    (``process_time``) time of each. At ``parsim_at`` samples SIPPY's PARSIM-K is
    timed too (2 rounds: it takes seconds). On a loaded machine compare the CPU
    ratios (docs/performance.md, 'Subspace against SLICOT').
    """
    import gc
    import os

    from benchmarks.peers import ctrlsys_slicot, sippy

    run = BEARING_METHODS["moesp + physical coordinates"]
    rows = []
    for n in sizes:
        data, _ = bearing_case(int(n), case="issue")
        y, u = np.asarray(data.y), np.asarray(data.u)
        fns: dict[str, Callable[[], Any]] = {
            "maglevid": lambda data=data: run(data),
            "ctrlsys": lambda y=y, u=u: ctrlsys_slicot.identify(y, u, 4, BEARING_HORIZON),
        }
        rounds = {k: repeat for k in fns}
        if parsim_at is not None and int(n) == parsim_at:
            fns["PARSIM-K"] = lambda y=y, u=u: sippy.identify(y, u, 4, None, "PARSIM-K")
            rounds["PARSIM-K"] = 2
        for fn in fns.values():
            fn()
        wall: dict[str, list[float]] = {k: [] for k in fns}
        cpu: dict[str, list[float]] = {k: [] for k in fns}
        for r in range(repeat):
            for k, fn in fns.items():
                if r >= rounds[k]:
                    continue
                gc.collect()
                c0, t0 = time.process_time(), time.perf_counter()
                fn()
                wall[k].append(time.perf_counter() - t0)
                cpu[k].append(time.process_time() - c0)
        row: dict[str, Any] = {"n": int(n), "load": os.getloadavg()[0]}
        row.update({k: min(v) for k, v in wall.items()})
        row.update({f"{k} cpu": min(v) for k, v in cpu.items()})
        rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", nargs="+", type=float, default=[1e4, 1e5, 1e6])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--profile", action="store_true", help="profile every fit")
    ap.add_argument(
        "--versus-ctrlsys",
        action="store_true",
        help="moesp + physical coordinates against ctrlsys (horizon 40) and, at 1e4, PARSIM-K",
    )
    args = ap.parse_args(argv)
    if args.versus_ctrlsys:
        sizes = [int(s) for s in args.sizes]
        print(f"{'N':>7} {'maglevid':>9} {'ctrlsys':>9} {'ratio':>6} {'cpu ratio':>9}  PARSIM-K")
        for r in versus_ctrlsys(sizes, repeat=args.repeat, parsim_at=10**4):
            pk = ""
            if "PARSIM-K" in r:
                pk = f"{r['PARSIM-K']:.3g} s: x{r['PARSIM-K cpu'] / r['maglevid cpu']:.0f} (cpu)"
            print(
                f"{r['n']:>7.0e} {1e3 * r['maglevid']:>7.2f}ms {1e3 * r['ctrlsys']:>7.2f}ms "
                f"{r['maglevid'] / r['ctrlsys']:>6.2f} "
                f"{r['maglevid cpu'] / r['ctrlsys cpu']:>9.2f}  {pk}  load {r['load']:.1f}"
            )
        return 0
    print(f"{'N':>9} {'fit':<16} {'time [s]':>9} {'lstsq [s]':>10} {'x lstsq':>8}")
    for size in args.sizes:
        r = regression_speed(
            int(size), repeat=args.repeat, profile_above=0.0 if args.profile else None
        )
        for name, row in r["fits"].items():
            print(
                f"{r['n']:>9} {name:<16} {row['time_s']:>9.3f} {r['lstsq_s']:>10.3f} "
                f"{row['ratio']:>8.2f}"
            )
            if "profile" in row:
                print(row["profile"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
