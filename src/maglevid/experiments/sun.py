"""Reproduction of Sun, Miyake, Ohmori & Sano: Tables 1-2 and Figs. 6-9.

``maglevid reproduce sun [--out DIR] [--runs R] [--duration S] [--p-values 1,...,6]
[--controller lead-lag|pid] [--plant linear|nonlinear] [--workers W] [--seed S]``
prints, beside the values the paper prints,

1. the nominal T-model (eq. (28)) of our physical parameter set and the
   controller actually used (the printed PID does not stabilise eq. (28));
2. Table 1: mean and standard deviation of ``a1..a3, b1..b3`` over ``--runs``
   records of ``--duration`` seconds for every ``p`` (``p = 1``: the
   conventional direct method; ``p >= 2``: :func:`fit_intersample`), their bias
   against the simulation's true model, the mean reported standard error, and
   in how many runs the unstable pole was found;
3. the same for the paper's pure Step 1 (subspace only), eq. (15) with the
   subspace ``B_j`` and the IV numerator of Step 2 (the variants the paper
   describes, computed on the same records);
4. Table 2: ``p = --table2-p`` at the sensor readings ``Y = 3, 4, 6 mm``;
5. Fig. 6 (singular values of the data matrix for ``p = 1, 2, 3``) and pole
   maps like Figs. 7-9, as PNG under ``--out``;
6. the pass/fail checks of the reproduction's aim (see ``docs/sun.md``).

The paper's data were measured; ours are simulated, so agreement is judged
against the true model of the simulation, not against the paper's means.
Every run has its own seed derived from ``--seed`` and its position, so the
result does not depend on ``--workers``.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Any

import numpy as np

from maglevid.control.pid import loop_margins, noise_gain
from maglevid.exceptions import MaglevidError
from maglevid.experiments._parallel import Progress, run_parallel
from maglevid.identify.intersample import (
    data_matrix_singular_values,
    fit_conventional_direct,
    fit_intersample,
)
from maglevid.physics.suspension import (
    PRINTED_POLES_28,
    PRINTED_T_MODEL_28,
    PRINTED_TABLE2_NOMINAL,
    SuspensionParameters,
    suspension_t_model,
)
from maglevid.simulate.suspension import CONTROLLERS, simulate_suspension

__all__ = [
    "PAPER",
    "PAPER_HELP",
    "PAPER_TABLE1",
    "PAPER_TABLE2",
    "add_paper_arguments",
    "format_text",
    "run_reproduction",
]

log = logging.getLogger(__name__)

PAPER = "sun"
PAPER_HELP = (
    "Sun, Miyake, Ohmori & Sano: Tables 1-2 (10 runs per inter-sampling rate p = 1..6 and "
    "per operating point), Fig. 6 and pole maps (Figs. 7-9) as PNG; all cores"
)

PARAMS = ("a1", "a2", "a3", "b1", "b2", "b3")
#: Display factor of the parameters (b in units of 1e-6, as printed).
SCALE = np.array([1.0, 1.0, 1.0, 1e6, 1e6, 1e6])

#: Table 1 as printed: mean and standard deviation over 10 experiments (b x 1e-6).
PAPER_TABLE1: dict[int, dict[str, tuple[float, ...]]] = {
    1: {
        "mean": (-2.9130, 2.8310, -0.9179, 0.1660, -0.2165, 0.1126),
        "std": (0.0461, 0.0888, 0.0429, 0.4858, 0.8399, 0.3276),
    },
    2: {
        "mean": (-2.9714, 2.9310, -0.9599, -0.0532, -0.2104, -0.0519),
        "std": (0.0250, 0.0521, 0.0274, 0.0215, 0.0840, 0.0201),
    },
    3: {
        "mean": (-2.9630, 2.9184, -0.9556, -0.0418, -0.1655, -0.0409),
        "std": (0.0205, 0.0385, 0.0181, 0.0116, 0.0461, 0.0115),
    },
    4: {
        "mean": (-2.9520, 2.8991, -0.9473, -0.0325, -0.1282, -0.0316),
        "std": (0.0127, 0.0240, 0.0113, 0.0052, 0.0207, 0.0051),
    },
    5: {
        "mean": (-2.9568, 2.9077, -0.9511, -0.0356, -0.1408, -0.0347),
        "std": (0.0131, 0.0254, 0.0124, 0.0064, 0.0252, 0.0063),
    },
    6: {
        "mean": (-2.9672, 2.9274, -0.9605, -0.0391, -0.1547, -0.0383),
        "std": (0.0082, 0.0160, 0.0080, 0.0067, 0.0264, 0.0065),
    },
}
#: Table 1's "nominal" column (eq. (28)), b x 1e-6.
PAPER_TABLE1_NOMINAL = (-2.9793, 2.9488, -0.9698, -0.0411, -0.1631, -0.0404)

#: Table 2 as printed (p = 3): estimates by sensor reading Y [mm], b x 1e-6.
PAPER_TABLE2: dict[float, dict[str, tuple[float, ...]]] = {
    3.0: {
        "mean": (-2.9674, 2.9229, -0.9559, -0.0516, -0.2042, -0.0505),
        "std": (0.0160, 0.0304, 0.0145, 0.0079, 0.0315, 0.0079),
    },
    4.0: {
        "mean": (-2.9712, 2.9298, -0.9590, -0.0587, -0.2325, -0.0575),
        "std": (0.0180, 0.0354, 0.0354, 0.0090, 0.0355, 0.0088),
    },
    6.0: {
        "mean": (-2.9630, 2.9184, -0.9556, -0.0418, -0.1655, -0.0409),
        "std": (0.0205, 0.0385, 0.0181, 0.0116, 0.0461, 0.0115),
    },
}

#: A run "finds" the unstable pole when a real estimated pole lies this close to it.
POLE_FOUND_TOL = 0.02


def _seed(base: int, *path: int) -> int:
    """A per-run seed from the base seed and the run's position (worker-independent)."""
    return int(np.random.SeedSequence([int(base), *map(int, path)]).generate_state(1)[0])


def _unstable_found(poles: np.ndarray, z_true: float) -> bool:
    z = np.asarray(poles, dtype=complex)
    real = z[np.abs(z.imag) <= 1e-9 * np.maximum(1.0, np.abs(z))].real
    return bool(np.any(np.abs(real - z_true) < POLE_FOUND_TOL))


def _task(spec: dict[str, Any]) -> dict[str, Any]:
    """One record and its identification (runs in a worker process)."""
    out: dict[str, Any] = {k: spec[k] for k in ("p", "Y", "run", "seed")}
    try:
        rec = simulate_suspension(
            p=spec["p"],
            duration=spec["duration"],
            params=SuspensionParameters.nominal(Y=spec["Y"] * 1e-3),
            controller=spec["controller"],
            noise_std=spec["noise_std"],
            plant=spec["plant"],
            rng=spec["seed"],
        )
        if spec["p"] == 1:
            res = fit_conventional_direct(rec, order=3)
            out["se"] = None
            out["variants"] = None
        else:
            res = fit_intersample(rec)
            se = res.std_errors()
            out["se"] = [se[k] for k in PARAMS]
            v = res.extras["numerator_variants"]
            out["variants"] = {
                "step1_subspace_a": [float(x) for x in res.extras["step1"]["a"]],
                "eq15_subspace_gain_b": [float(x) for x in v["physical-subspace"]["b"]],
                "iv_b": [float(x) for x in v["iv"]["b"]] if "iv" in v else None,
            }
        out["theta"] = [float(res.parameters[k]) for k in PARAMS]
        z = np.asarray(res.extras["poles"], dtype=complex)
        out["poles"] = [[float(x.real), float(x.imag)] for x in z]
        out["truth"] = [*rec.metadata["truth"]["a"], *rec.metadata["truth"]["b"]]
        out["true_unstable_pole"] = float(max(rec.metadata["truth"]["poles"]))
    except MaglevidError as exc:
        out["error"] = f"{type(exc).__name__}: {exc}"
    return out


def _summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    ok = [r for r in rows if "error" not in r]
    out: dict[str, Any] = {"runs": len(rows), "successful": len(ok)}
    if not ok:
        return out
    T = np.array([r["theta"] for r in ok])
    truth = np.array(ok[0]["truth"])
    out["truth"] = truth.tolist()
    out["mean"] = T.mean(axis=0).tolist()
    out["std"] = T.std(axis=0, ddof=1).tolist() if len(ok) > 1 else None
    out["bias"] = (T.mean(axis=0) - truth).tolist()
    se = [r["se"] for r in ok if r.get("se") is not None]
    out["mean_se"] = np.mean(se, axis=0).tolist() if se else None
    out["unstable_found"] = int(
        sum(
            _unstable_found(np.array([complex(*z) for z in r["poles"]]), r["true_unstable_pole"])
            for r in ok
        )
    )
    out["any_unstable"] = int(
        sum(any(np.hypot(*z) > 1 and abs(z[1]) < 1e-9 for z in r["poles"]) for r in ok)
    )
    variants: dict[str, Any] = {}
    vs = [r["variants"] for r in ok if r.get("variants")]
    if vs:
        for key in ("step1_subspace_a", "eq15_subspace_gain_b", "iv_b"):
            V = np.array([v[key] for v in vs if v[key] is not None])
            if V.size:
                variants[key] = {
                    "mean": V.mean(axis=0).tolist(),
                    "std": V.std(axis=0, ddof=1).tolist() if len(V) > 1 else None,
                }
    out["variants"] = variants
    return out


def add_paper_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--runs", type=int, default=10, help="records per case (paper: 10)")
    parser.add_argument("--duration", type=float, default=18.0, help="record length [s]")
    parser.add_argument(
        "--p-values", default="1,2,3,4,5,6", help="inter-sampling rates of Table 1"
    )
    parser.add_argument("--table2-p", type=int, default=3, help="p of Table 2 (paper: 3)")
    parser.add_argument(
        "--table2-Y", default="3,4,6", help="sensor readings of Table 2 [mm] (empty: skip)"
    )
    parser.add_argument("--controller", choices=sorted(CONTROLLERS), default="lead-lag")
    parser.add_argument("--plant", choices=("linear", "nonlinear"), default="linear")
    parser.add_argument("--noise-std-mm", type=float, default=0.1, help="output noise [mm]")
    parser.add_argument(
        "--workers", type=int, default=None, help="processes for the Monte Carlo (default: all)"
    )
    parser.add_argument("--seed", type=int, default=2000, help="base seed of every run")
    parser.add_argument("--no-figures", action="store_true", help="do not write the PNGs")


def _ints(text: str, name: str) -> list[int]:
    try:
        return [int(x) for x in str(text).split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{name}: expected integers like 1,2,3") from None


def _floats(text: str, name: str) -> list[float]:
    try:
        return [float(x) for x in str(text).split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{name}: expected numbers like 3,4,6") from None


def run_reproduction(
    args: argparse.Namespace, *, progress: Progress | None = None
) -> dict[str, Any]:
    """Run the reproduction; returns a JSON-safe dict (and writes the figures).

    ``progress`` (see :data:`~maglevid.experiments._parallel.Progress`, default
    none) reports the Monte Carlo runs done.
    """
    p_values = _ints(args.p_values, "--p-values")
    Y_values = _floats(args.table2_Y, "--table2-Y")
    runs = int(args.runs)
    if runs < 1 or not p_values or any(p < 1 for p in p_values):
        raise argparse.ArgumentTypeError("--runs must be >= 1 and --p-values >= 1")
    ctl = CONTROLLERS[args.controller]
    nominal = SuspensionParameters.nominal()
    a, b = suspension_t_model(nominal, ctl.dt)
    margins = loop_margins(ctl, a, b)
    base = {
        "duration": float(args.duration),
        "controller": args.controller,
        "noise_std": float(args.noise_std_mm) * 1e-3,
        "plant": args.plant,
    }
    specs = [
        {**base, "p": p, "Y": 6.0, "run": r, "seed": _seed(args.seed, 6000, p, r)}
        for p in p_values
        for r in range(runs)
    ]
    t2p = int(args.table2_p)
    for Y in Y_values:
        if Y == 6.0 and t2p in p_values:
            continue  # the same records as Table 1 at p = table2_p (as in the paper)
        specs += [
            {**base, "p": t2p, "Y": Y, "run": r, "seed": _seed(args.seed, round(Y * 1000), t2p, r)}
            for r in range(runs)
        ]
    results, timing = run_parallel(_task, specs, args, progress=progress)
    workers = timing["workers"]

    table1 = {}
    for p in p_values:
        s = _summary([r for r in results if r["p"] == p and r["Y"] == 6.0])
        if p in PAPER_TABLE1:
            s["paper_mean"] = list(PAPER_TABLE1[p]["mean"])
            s["paper_std"] = list(PAPER_TABLE1[p]["std"])
        table1[str(p)] = s
    table2 = {}
    for Y in Y_values:
        s = _summary([r for r in results if r["p"] == t2p and r["Y"] == Y])
        model_a, model_b = suspension_t_model(nominal.at(Y * 1e-3), ctl.dt)
        s["model_nominal"] = [*model_a[1:], *model_b[1:]]
        if Y * 1e-3 in PRINTED_TABLE2_NOMINAL:
            pr = PRINTED_TABLE2_NOMINAL[Y * 1e-3]
            s["paper_nominal"] = [*pr["a"], *pr["b"]]
        if Y in PAPER_TABLE2 and t2p == 3:
            s["paper_mean"] = list(PAPER_TABLE2[Y]["mean"])
            s["paper_std"] = list(PAPER_TABLE2[Y]["std"])
        table2[f"{Y:g}"] = s

    checks = _checks(table1)
    result: dict[str, Any] = {
        "paper": PAPER,
        "settings": {
            **base,
            "runs": runs,
            "p_values": p_values,
            "table2_p": t2p,
            "table2_Y_mm": Y_values,
            "seed": int(args.seed),
            "workers": workers,
            "monte_carlo_timing": timing,
            "T": ctl.dt,
            "identification": "p = 1: fit_conventional_direct(order=3); p >= 2: "
            "fit_intersample() defaults (MOESP step 1, output-error refinement, eq. (15))",
        },
        "controller": {
            **ctl.to_dict(),
            "margins": margins.to_dict(),
            "noise_gain_V_per_m": noise_gain(ctl, a, b),
        },
        "nominal_model": {
            "a": a[1:].tolist(),
            "b": b[1:].tolist(),
            "poles": np.sort(np.roots(a).real)[::-1].tolist(),
            "printed_a": list(PRINTED_T_MODEL_28["a"]),
            "printed_b": list(PRINTED_T_MODEL_28["b"]),
            "printed_poles": list(PRINTED_POLES_28),
            "operating_point": nominal.operating_point(),
        },
        "table1": table1,
        "table2": table2,
        "checks": checks,
        "seeds": {f"p{r['p']}-Y{r['Y']:g}-run{r['run']}": r["seed"] for r in results},
        "failed_fits": [
            {"p": r["p"], "Y": r["Y"], "seed": r["seed"], "error": r["error"]}
            for r in results
            if "error" in r
        ],
    }
    result["poles"] = {
        str(p): [r["poles"] for r in results if r["p"] == p and r["Y"] == 6.0 and "poles" in r]
        for p in p_values
    }
    fig6 = {}
    for p in (1, 2, 3):
        rec = simulate_suspension(
            p=p,
            duration=max(float(args.duration), 2600 * ctl.dt),
            controller=args.controller,
            noise_std=base["noise_std"],
            plant="linear",
            rng=_seed(args.seed, 6, p),
        )
        fig6[str(p)] = data_matrix_singular_values(rec, L=20, M=2500).tolist()
    result["fig6"] = fig6
    result["figures"] = (
        []
        if args.no_figures
        else _figures(result, Path(args.out), overwrite=getattr(args, "overwrite", False))
    )
    return result


def _checks(table1: dict[str, Any]) -> dict[str, Any]:
    """The reproduction's aims (docs/sun.md), as booleans with their numbers."""
    out: dict[str, Any] = {}
    t1 = table1.get("1")
    if t1 and t1.get("successful"):
        out["p1_unstable_pole_not_found"] = t1["unstable_found"] == 0
    for p, s in table1.items():
        if p == "1" or not s.get("successful"):
            continue
        out[f"p{p}_unstable_pole_in_every_run"] = s["unstable_found"] == s["runs"]
    for p in ("3", "6"):
        s = table1.get(p)
        if not s or s.get("std") is None:
            continue
        std = np.array(s["std"])
        out[f"p{p}_std_at_most_paper"] = bool(np.all(std <= np.array(s["paper_std"]) / SCALE))
        out[f"p{p}_bias_below_std"] = bool(np.all(np.abs(s["bias"]) < std))
    return out


def _figures(result: dict[str, Any], out: Path, *, overwrite: bool = False) -> list[str]:
    try:
        from maglevid.plotting.sun import plot_pole_map, plot_singular_values
    except ImportError as exc:  # pragma: no cover - depends on the environment
        log.warning("no figures: %s", exc)
        return []
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    path = out / "sun_fig6_singular_values.png"
    fig6 = {f"p = {p}": s for p, s in result["fig6"].items()}
    plot_singular_values(fig6, path=path, overwrite=overwrite)
    paths.append(str(path))
    nominal = result["nominal_model"]["poles"]
    for p, poles in result["poles"].items():
        fig = {"1": "7", "2": "8", "3": "9"}.get(p, "")
        path = out / f"sun_poles_p{p}.png"
        plot_pole_map(
            [[complex(*z) for z in run] for run in poles],
            nominal,
            title=f"Estimated poles, p = {p}" + (f" (cf. Fig. {fig})" if fig else ""),
            path=path,
            overwrite=overwrite,
        )
        paths.append(str(path))
    return paths


def _cell(mean: float, std: float | None, scale: float) -> str:
    if std is None:
        return f"{mean * scale:9.4f}"
    return f"{mean * scale:9.4f}±{std * scale:.4f}"


def _block(title: str, s: dict[str, Any], paper_scale_b: bool = True) -> list[str]:
    lines = [title]
    if not s.get("successful"):
        lines.append("  (no successful fit)")
        return lines
    lines.append(
        f"  {'':4}{'truth':>10} {'paper':>17} {'ours':>17} {'bias/std':>9} "
        f"{'mean SE':>9} {'std<=paper':>10}"
    )
    for i, k in enumerate(PARAMS):
        sc = SCALE[i]
        truth = s["truth"][i] * sc
        paper = (
            _cell(s["paper_mean"][i] / sc, s["paper_std"][i] / sc, sc) if "paper_mean" in s else ""
        )
        std = s["std"][i] if s.get("std") else None
        ours = _cell(s["mean"][i], std, sc)
        ratio = f"{s['bias'][i] / std:9.2f}" if std else ""
        mse = f"{s['mean_se'][i] * sc:9.4f}" if s.get("mean_se") else ""
        ok = ""
        if std is not None and "paper_std" in s:
            ok = "yes" if std * sc <= s["paper_std"][i] else "NO"
        lines.append(f"  {k:4}{truth:10.4f} {paper:>17} {ours:>17} {ratio:>9} {mse:>9} {ok:>10}")
    return lines


def format_text(result: dict[str, Any]) -> str:
    """The tables of the reproduction, the paper's printed values beside ours."""
    st = result["settings"]
    c = result["controller"]
    m = c["margins"]
    nm = result["nominal_model"]
    out = [
        "Sun, Miyake, Ohmori & Sano -- reproduction (simulated; judged against the true model)",
        f"T = {st['T']} s, {st['runs']} runs of {st['duration']} s per case, noise "
        f"{st['noise_std'] * 1e3:g} mm, {st['plant']} plant, seed {st['seed']}, "
        f"{st['workers']} workers",
        f"identification: {st['identification']}",
        f"controller ({c['type']}): D = {np.round(c['num'], 1).tolist()}, C = "
        f"{np.round(c['den'], 6).tolist()}; peak sensitivity {m['peak_sensitivity']:.2f}, "
        f"phase margin {m['phase_margin_deg']:.1f} deg, gain margins x{m['gain_margin_lower']:.2f}"
        f" .. x{m['gain_margin_upper']:.2f} (the printed PID does not stabilise eq. (28))",
        "",
        "Nominal T-model at Y = 6 mm (b x 1e-6):",
        "  printed (28): a = "
        + ", ".join(f"{x:.4f}" for x in nm["printed_a"])
        + "; b = "
        + ", ".join(f"{x * 1e6:.4f}" for x in nm["printed_b"])
        + "; poles "
        + ", ".join(f"{x:.4f}" for x in nm["printed_poles"]),
        "  ours:         a = "
        + ", ".join(f"{x:.4f}" for x in nm["a"])
        + "; b = "
        + ", ".join(f"{x * 1e6:.4f}" for x in nm["b"])
        + "; poles "
        + ", ".join(f"{x:.4f}" for x in nm["poles"]),
        f"  operating point: gap {nm['operating_point']['gap'] * 1e3:.3f} mm "
        f"(sensor Y 6 mm + offset {nm['operating_point']['Y_offset'] * 1e3:.3f} mm), "
        f"I = {nm['operating_point']['I']:.4f} A, U = {nm['operating_point']['U']:.3f} V",
        "",
        "Table 1 (b x 1e-6): mean±std over the runs",
    ]
    for p, s in result["table1"].items():
        found = (
            f"unstable pole found in {s.get('unstable_found', 0)}/{s['runs']} runs"
            if s.get("successful")
            else ""
        )
        method = "conventional direct" if p == "1" else "inter-sampling"
        out += _block(f"p = {p} ({method}; {found})", s)
        var = s.get("variants") or {}
        for key, label, sc in (
            ("step1_subspace_a", "paper's Step 1 alone (subspace): a", 1.0),
            ("eq15_subspace_gain_b", "eq. (15) with the subspace B_j: b", 1e6),
            ("iv_b", "Step 2 IV (non-causal instrument): b", 1e6),
        ):
            v = var.get(key)
            if v:
                sds = v["std"] or [None] * len(v["mean"])
                out.append(
                    f"    {label} = "
                    + ", ".join(_cell(mu, sd, sc) for mu, sd in zip(v["mean"], sds))
                )
    if result["table2"]:
        out += ["", f"Table 2 (p = {st['table2_p']}, b x 1e-6):"]
        for Y, s in result["table2"].items():
            if "paper_nominal" in s:
                out.append(
                    f"  Y = {Y} mm nominal, paper: "
                    + ", ".join(f"{v * sc:.4f}" for v, sc in zip(s["paper_nominal"], SCALE))
                )
            out.append(
                f"  Y = {Y} mm nominal, ours:  "
                + ", ".join(f"{v * sc:.4f}" for v, sc in zip(s["model_nominal"], SCALE))
            )
            out += _block(f"  Y = {Y} mm", s)
    out += ["", "Checks:"]
    out += [f"  {k}: {'PASS' if v else 'FAIL'}" for k, v in result["checks"].items()]
    if result["failed_fits"]:
        out.append(f"failed fits: {len(result['failed_fits'])}")
    f6 = result["fig6"]
    out.append("")
    out.append("Fig. 6: singular values above 1e-8 sigma_1 (of 40): " + ", ".join(
        f"p = {p}: {int(np.sum(np.array(s) / s[0] > 1e-8))}" for p, s in f6.items()
    ))  # fmt: skip
    if result.get("figures"):
        out += [f"figure: {p}" for p in result["figures"]]
    return "\n".join(out)
