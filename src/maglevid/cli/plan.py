"""``maglevid plan``: how long a record and how much excitation resolve each parameter."""

from __future__ import annotations

import argparse
from typing import Any

COMMAND = "plan"
HELP = "experiment planning from the Cramér-Rao bound: record length and excitation needed"
DESCRIPTION = """\
From the Cramér-Rao bound of the physical parameters (the best any unbiased
estimator can do; the `ml` method attains it), say how long a record, and at
which excitation level within the amplifier and displacement limits, resolves
each parameter to a fraction of its tolerance (95 % half-width <= fraction x
tolerance x value).

It also compares candidate spectra (white, low-pass) and splits of the
excitation between the two coils (the amplifier limit is per coil, the
displacement limit shared) and names the one that needs the shortest record
("white, coil 1 only 2.1 V"). A diagnosis judges the difference from its
baseline: when the baseline is itself an estimate, --baseline-std gives its
relative std; it does not fall with a longer record, and where it alone exceeds
the target the plan says to re-record the baseline.

For a design (the nominal bearing under the default loop, optionally with a
fault), or for an existing recording (at its parameters: the simulated truth,
or an estimate given with --from-fit of the ml method):

  maglevid plan
  maglevid plan --fault R1=1.2 --seconds 2 --excitation-std 1 --tolerance 0.02
  maglevid plan rec.npz --parameters R1,kw1 --max-excitation-std 3
  maglevid plan --parameters R1,kw1 --baseline-std R1=0.01 --max-displacement 0.005
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from maglevid.identify.planning import (
        DEFAULT_FRACTION,
        DEFAULT_MAX_DISPLACEMENT,
        DEFAULT_MAX_EXCITATION_STD,
        DEFAULT_PARAMETERS,
    )
    from maglevid.simulate.amb import (
        DEFAULT_DT,
        DEFAULT_EXCITATION_STD,
        DEFAULT_FORCE_STD,
        DEFAULT_N_SAMPLES,
        DEFAULT_NOISE_STD,
        parse_fault,
        parse_floats,
    )

    parser.add_argument("recording", nargs="?", default=None, help="plan for this recording")
    parser.add_argument("--mapping", default=None, help="column mapping of the recording")
    parser.add_argument(
        "--from-fit",
        action="store_true",
        help="recording: evaluate the bound at the ml estimate (default: the simulated truth, "
        "else the ml estimate)",
    )
    parser.add_argument(
        "--fault",
        action="append",
        type=parse_fault,
        default=[],
        metavar="NAME=FACTOR",
        help="design: a fault of the bearing (controller stays on the nominal one); repeatable",
    )
    parser.add_argument(
        "--noise",
        type=parse_floats,
        default=None,
        metavar="SX,SI1,SI2",
        help=f"sensor noise std of x [m], i1 [A], i2 [A] (default {list(DEFAULT_NOISE_STD)} "
        "or the recording's)",
    )
    parser.add_argument(
        "--force-std",
        type=float,
        default=None,
        metavar="N",
        help=f"force disturbance on the rotor [N rms per sample] (default {DEFAULT_FORCE_STD} "
        "as the simulator's realistic bearing, or the recording's / its ml estimate)",
    )
    parser.add_argument(
        "--excitation-std",
        type=float,
        default=None,
        help=f"present excitation [V rms per input] (default {DEFAULT_EXCITATION_STD} or the "
        "recording's)",
    )
    parser.add_argument(
        "--seconds",
        type=float,
        default=None,
        help=f"present record length [s] (default {DEFAULT_N_SAMPLES * DEFAULT_DT:g} or the "
        "recording's)",
    )
    parser.add_argument("--dt", type=float, default=DEFAULT_DT, help="control period [s]")
    parser.add_argument(
        "--parameters",
        default=",".join(DEFAULT_PARAMETERS),
        help="comma-separated parameter names (default %(default)s)",
    )
    parser.add_argument(
        "--tolerance", type=float, default=0.05, help="relative tolerance (default %(default)s)"
    )
    parser.add_argument(
        "--fraction",
        type=float,
        default=DEFAULT_FRACTION,
        help="95 %% half-width as a fraction of the tolerance (default %(default)s)",
    )
    parser.add_argument(
        "--max-excitation-std",
        type=_limits,
        default=DEFAULT_MAX_EXCITATION_STD,
        metavar="V or V1,V2",
        help="amplifier limit [V rms], one for both inputs or one per input (e.g. 4,0.5 when "
        "coil 2's amplifier has less headroom) (default %(default)s)",
    )
    parser.add_argument(
        "--baseline-std",
        action="append",
        type=_baseline_std,
        default=[],
        metavar="[NAME=]REL",
        help="the baseline's own relative std (0.02 = 2 %%) when it is an estimate (a stored "
        "history, an earlier fit): a diagnosis judges the difference, so its variance adds and "
        "does not fall with the record; one value for every parameter or NAME=REL, repeatable",
    )
    parser.add_argument(
        "--max-displacement",
        type=float,
        default=DEFAULT_MAX_DISPLACEMENT,
        help="largest rms rotor displacement as a fraction of the air gap (default %(default)s)",
    )


def run(args: argparse.Namespace) -> dict[str, Any]:
    from maglevid.exceptions import DataError
    from maglevid.identify.cramer_rao import NoiseModel
    from maglevid.identify.planning import (
        design_information,
        plan_experiment,
        plan_for_recording,
    )
    from maglevid.physics.amb import AMBParameters
    from maglevid.simulate.amb import DEFAULT_EXCITATION_STD, DEFAULT_N_SAMPLES

    params = [p.strip() for p in args.parameters.split(",") if p.strip()]
    options = {
        "parameters": params,
        "tolerance": args.tolerance,
        "fraction": args.fraction,
        "max_excitation_std": args.max_excitation_std,
        "max_displacement": args.max_displacement,
        "baseline_std": _baseline_stds(args.baseline_std),
    }
    noise = _noise_model(args, NoiseModel)
    if args.recording is not None:
        if args.fault:
            raise DataError("--fault describes a design; with a recording, leave it out")
        plan = _plan_recording(args, noise, options, plan_for_recording)
        source = args.recording
    else:
        nominal = AMBParameters.nominal()
        plant = _faulty_plant(nominal, dict(args.fault))
        design = design_information(plant, nominal=nominal, dt=args.dt, noise=noise)
        n = DEFAULT_N_SAMPLES if args.seconds is None else max(1, round(args.seconds / args.dt))
        exc = DEFAULT_EXCITATION_STD if args.excitation_std is None else args.excitation_std
        plan = plan_experiment(design, n_samples=n, excitation_std=exc, **options)
        source = "design: nominal bearing" + (
            " with " + ", ".join(f"{k}x{v:g}" for k, v in args.fault) if args.fault else ""
        )
    out = plan.to_dict()
    out["source"] = source
    from maglevid.diagnose.isolate import SENSOR_GAINS

    if args.recording is None and any(k in SENSOR_GAINS for k, _ in args.fault):
        out["note"] = SENSOR_GAIN_NOTE
    return out


#: What the values of a sensor-gain plan are. Derivation (docs/gosiewski.md,
#: "Experiment planning"): the loop sees z = diag(gx, gx, gi1, gi2) x, so v2 ->
#: v2 gx/gi1, v4 -> v4 gi1/gx, v8 -> v8 gi1 (coil 2 alike) and eq. (4) inverted
#: with the true m and i0 gives ki_j' = m v2' = ki_j gx/gi_j, L_j' = ki_j'/v4' =
#: L_j (gx/gi_j)^2, R_j' = v5 L_j', kw_j' = v8' L_j' = kw_j gx^2/gi_j and
#: x0' = (ki1' + ki2') i0 / (m v1).
SENSOR_GAIN_NOTE = (
    "values are the bearing as the loop and the identification see it through the "
    "sensor gains (gi_j: coil j's current-sensor gain, not the amplifier's kw_j): "
    "ki_j gx/gi_j, L_j and R_j x (gx/gi_j)^2, kw_j gx^2/gi_j, "
    "x0 gx (ki1/gi1 + ki2/gi2)/(ki1 + ki2)"
)


def _faulty_plant(nominal: Any, faults: dict[str, float]) -> Any:
    """The bearing of ``--fault``: parameter factors and sensor gains (gx, gi1, gi2).

    A sensor gain is planned as the bearing the loop and the identification
    see through it (:func:`~maglevid.diagnose.isolate.v_with_sensor_gains`: a
    change of state scale, the same loop), as ``maglevid simulate amb`` takes it.
    """
    from maglevid.diagnose.isolate import SENSOR_GAINS, v_with_sensor_gains
    from maglevid.identify.cramer_rao import plant_from_v

    gains = {k: faults.pop(k) for k in SENSOR_GAINS if k in faults}
    plant = nominal.with_fault(**faults) if faults else nominal
    if not gains:
        return plant
    return plant_from_v(v_with_sensor_gains(plant, **gains), m=plant.m, i0=plant.i0)


def _limits(text: str) -> float | tuple[float, ...]:
    """``"4"`` -> 4.0; ``"4,0.5"`` -> (4.0, 0.5)."""
    try:
        values = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected V or V1,V2; got {text!r}") from None
    if len(values) not in (1, 2) or not all(v > 0 for v in values):
        raise argparse.ArgumentTypeError(f"expected one or two positive volts; got {text!r}")
    return values[0] if len(values) == 1 else values


def _baseline_std(text: str) -> tuple[str | None, float]:
    """``"R1=0.02"`` -> ``("R1", 0.02)``; ``"0.02"`` -> ``(None, 0.02)``."""
    name, _, value = text.rpartition("=")
    try:
        rel = float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected [NAME=]REL, e.g. R1=0.02; got {text!r}"
        ) from None
    if not rel >= 0:
        raise argparse.ArgumentTypeError(f"a relative std must be >= 0; got {text!r}")
    return (name.strip() or None), rel


def _baseline_stds(items: list[tuple[str | None, float]]) -> Any:
    """``--baseline-std`` values: one float for all, a mapping per name, or None."""
    if not items:
        return None
    everyone = [rel for name, rel in items if name is None]
    if everyone and len(items) == len(everyone):
        return everyone[-1]
    from maglevid.identify.planning import DEFAULT_PARAMETERS

    default = dict.fromkeys(DEFAULT_PARAMETERS, everyone[-1]) if everyone else {}
    return {**default, **{name: rel for name, rel in items if name is not None}}


def _noise_model(args: argparse.Namespace, noise_model: Any) -> Any:
    """The noise model the options state (``None``: the default or the recording's)."""
    from maglevid.simulate.amb import DEFAULT_FORCE_STD, DEFAULT_NOISE_STD

    if args.noise is None and args.force_std is None:
        return None
    sensor = DEFAULT_NOISE_STD if args.noise is None else args.noise
    force = DEFAULT_FORCE_STD if args.force_std is None else args.force_std
    return noise_model(tuple(sensor), force_std=force)


def _plan_recording(args: argparse.Namespace, noise: Any, options: dict, plan_fn: Any) -> Any:
    from maglevid.identify.cramer_rao import NoiseModel
    from maglevid.identify.ml import fit_ml
    from maglevid.identify.planning import noise_of_result
    from maglevid.io import read_recording

    data = read_recording(args.recording, mapping=args.mapping)
    _two_coil_bearing(data)
    has_truth = "truth_v" in data.metadata or "operating_point_true" in data.metadata
    v = None
    if args.from_fit or not has_truth or (noise is None and NoiseModel.from_data(data) is None):
        fit = fit_ml(data)
        if args.from_fit or not has_truth:
            v = [fit.parameters[f"v{i}"] for i in range(1, 10)]
        if noise is None and NoiseModel.from_data(data) is None:
            noise = noise_of_result(fit)  # the ml fit's sensor noise and force
    if args.excitation_std is not None or args.seconds is not None:
        from maglevid.exceptions import DataError

        raise DataError("--excitation-std/--seconds describe a design; a recording's own are used")
    return plan_fn(data, v=v, noise=noise, **options)


def _two_coil_bearing(data: Any) -> None:
    """The plan is the two-coil bearing's Cramér-Rao bound; another kind is told where its
    own answer is (an inter-sampled suspension: "ml ... got p=3" said nothing of that)."""
    from maglevid.exceptions import DataError
    from maglevid.plants import infer_kind

    kind, why = infer_kind(data)
    if kind == "amb-two-coil":
        return
    where = (
        "`maglevid diagnose` states the record length an inconclusive question needs"
        if kind == "intersampled-suspension"
        else "`maglevid identify` gives its estimates with their intervals"
    )
    raise DataError(
        f"maglevid plan designs experiments for the two-coil bearing (the Cramér-Rao bound "
        f"of its ml method); this recording is of kind {kind} ({why}): {where}"
    )


def format_text(result: dict[str, Any]) -> str:
    r = result
    rows = r["parameters"]
    with_base = any(p["baseline_std"] > 0 for p in rows)
    lines = [
        f"plan for {r['source']}: {r['seconds']:.3g} s at {r['excitation_std']:.3g} V rms; "
        f"largest allowed excitation {r['max_excitation_std']:.3g} V rms "
        f"(amplifier {_volts(r['amplifier_limit'])}, rms displacement "
        f"<= {100 * r['displacement_limit']:.3g} % of the gap)",
        f"target: 95 % half-width <= {r['fraction']:g} x tolerance"
        + ("; std now includes the baseline's own std" if with_base else ""),
        f"{'parameter':>10} {'value':>11} {'std now':>10} {'target':>10}"
        + (f" {'baseline':>10}" if with_base else "")
        + f" {'s needed':>9} {'s at max':>9} {'V for length':>12}  shortest: spectrum, excitation",
    ]
    for p in rows:
        exc = p["excitation_for_present_length"]
        lines.append(
            f"{p['name']:>10} {p['value']:>11.5g} {p['std_now']:>10.3g} {p['target_std']:>10.3g}"
            + (f" {p['baseline_std']:>10.3g}" if with_base else "")
            + f" {_s(p['seconds_now']):>9} {_s(p['seconds_at_max_excitation']):>9} "
            f"{'unreachable' if exc is None else f'{exc:.3g}':>12}  {_best(p)}"
        )
    lines.append(
        f"model error of the linearisation: largest level with bias <= "
        f"{r['model_error_ratio']:g} std at this length {_v(r['excitation_model_error'])}; "
        + ", ".join(f"{p['name']} {_s(p['model_error_in_std'])} std" for p in rows)
        + " at the present excitation"
    )
    lines.append(r["sentence"])
    if r.get("note"):
        lines.append("note: " + r["note"])
    return "\n".join(lines)


def _v(volts: float | None) -> str:
    return "none" if volts is None else f"{volts:.3g} V rms"


def _volts(limit: Any) -> str:
    if isinstance(limit, (list, tuple)):
        return f"{limit[0]:.3g} V on coil 1, {limit[1]:.3g} V on coil 2"
    return f"{limit:.3g} V"


def _s(seconds: float | None, unit: str = "") -> str:
    return "never" if seconds is None else f"{seconds:.3g}{unit}"


def _best(p: dict[str, Any]) -> str:
    """The row's shortest candidate: "low-pass 100 Hz, coil 1 only 2.1 V: 0.145 s"."""
    from maglevid.identify.planning import spectrum_label

    a1, a2 = p["best_input_levels"]
    how = f"both {a1:.2g} V" if abs(a1 - a2) <= 1e-9 * max(a1, a2, 1e-300) else (
        f"coil {1 if a2 == 0 else 2} only {max(a1, a2):.2g} V" if min(a1, a2) == 0
        else f"coil 1 {a1:.2g} V, coil 2 {a2:.2g} V"
    )  # fmt: skip
    return (
        f"{spectrum_label(p['best_spectrum'])}, {how}: {_s(p['seconds_with_best_spectrum'], ' s')}"
    )
