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

For a design (the nominal bearing under the default loop, optionally with a
fault), or for an existing recording (at its parameters: the simulated truth,
or an estimate given with --from-fit of the ml method):

  maglevid plan
  maglevid plan --fault R1=1.2 --seconds 2 --excitation-std 1 --tolerance 0.02
  maglevid plan rec.npz --parameters R1,kw1 --max-excitation-std 3
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
        type=float,
        default=DEFAULT_MAX_EXCITATION_STD,
        help="amplifier limit [V rms per input] (default %(default)s)",
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
    }
    noise = _noise_model(args, NoiseModel)
    if args.recording is not None:
        if args.fault:
            raise DataError("--fault describes a design; with a recording, leave it out")
        plan = _plan_recording(args, noise, options, plan_for_recording)
        source = args.recording
    else:
        nominal = AMBParameters.nominal()
        plant = nominal.with_fault(**dict(args.fault)) if args.fault else nominal
        design = design_information(plant, nominal=nominal, dt=args.dt, noise=noise)
        n = DEFAULT_N_SAMPLES if args.seconds is None else max(1, round(args.seconds / args.dt))
        exc = DEFAULT_EXCITATION_STD if args.excitation_std is None else args.excitation_std
        plan = plan_experiment(design, n_samples=n, excitation_std=exc, **options)
        source = "design: nominal bearing" + (
            " with " + ", ".join(f"{k}x{v:g}" for k, v in args.fault) if args.fault else ""
        )
    out = plan.to_dict()
    out["source"] = source
    return out


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


def format_text(result: dict[str, Any]) -> str:
    r = result
    lines = [
        f"plan for {r['source']}: {r['seconds']:.3g} s at {r['excitation_std']:.3g} V rms; "
        f"largest allowed excitation {r['max_excitation_std']:.3g} V rms "
        f"(amplifier {r['amplifier_limit']:.3g} V, rms displacement "
        f"<= {100 * r['displacement_limit']:.3g} % of the gap)",
        f"target: 95 % half-width <= {r['fraction']:g} x tolerance",
        f"{'parameter':>10} {'value':>12} {'std now':>11} {'target':>11} {'s needed':>10} "
        f"{'s at max':>10} {'V rms for this length':>22}  best spectrum (s at its max V rms)",
    ]
    for p in r["parameters"]:
        exc = p["excitation_for_present_length"]
        lines.append(
            f"{p['name']:>10} {p['value']:>12.5g} {p['std_now']:>11.3g} {p['target_std']:>11.3g} "
            f"{p['seconds_now']:>10.3g} {p['seconds_at_max_excitation']:>10.3g} "
            f"{'not reachable' if exc is None else f'{exc:.3g}':>22}  "
            f"{_label(p['best_spectrum'])} ({p['seconds_with_best_spectrum']:.3g} s at "
            f"{p['excitation_with_best_spectrum']:.3g} V)"
        )
    lines.append(r["sentence"])
    return "\n".join(lines)


def _label(spectrum: str) -> str:
    from maglevid.identify.planning import spectrum_label

    return spectrum_label(spectrum)
