"""``maglevid demo --out DIR``: simulate a faulty bearing, write its recording and a plot.

Interim command (to be replaced by the full demonstration once identification
and diagnosis exist): the controller and deadbeat observer are designed on the
nominal bearing of Gosiewski & Paszowski; the simulated bearing has a fault.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np

COMMAND = "demo"
HELP = "simulate a bearing with a coil fault; write its recording and a plot of the signals"
DESCRIPTION = """\
Simulate the voltage-controlled magnetic bearing of Gosiewski & Paszowski with a
fault (default: coil 1 resistance +20 %) under the controller and deadbeat
observer designed on the nominal bearing, and write into DIR:

  recording.npz   the closed-loop recording (y, u, r, u_f, loop, metadata)
  signals.png     displacement, coil currents, feedback and excitation

  maglevid demo --out demo-out
  maglevid demo --out demo-out --fault K1=0.9 --plant nonlinear
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from maglevid.simulate.amb import parse_fault

    parser.add_argument("--out", required=True, help="output folder (created if missing)")
    parser.add_argument(
        "--fault",
        action="append",
        type=parse_fault,
        default=None,
        metavar="NAME=FACTOR",
        help="fault of the simulated bearing (default R1=1.2); repeatable",
    )
    parser.add_argument("--n-samples", type=int, default=20_000, help="control periods")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument(
        "--plant", choices=("linear", "nonlinear"), default="linear", help="plant model"
    )


def _write(data: Any, path: Path) -> Path:
    try:
        from maglevid.io import write_recording
    except ImportError:
        # maglevid.io not available yet: plain NPZ with the JSON description.
        np.savez(
            path,
            **{s: np.asarray(getattr(data, s)) for s in data.signals()},
            meta=np.array(json.dumps(data.to_dict())),
        )
        return path
    return write_recording(data, path, overwrite=True)


def run(args: argparse.Namespace) -> dict[str, Any]:
    from functools import partial

    from maglevid.cli._progress import progress
    from maglevid.physics.amb import AMBParameters
    from maglevid.plotting.signals import plot_signals
    from maglevid.simulate.amb import simulate_amb_loop

    faults = dict(args.fault) if args.fault else {"R1": 1.2}
    nominal = AMBParameters.nominal()
    plant = nominal.with_fault(**faults)
    data = simulate_amb_loop(
        plant,
        nominal=nominal,
        n_samples=args.n_samples,
        plant_model=args.plant,
        rng=args.seed,
        progress=partial(progress, desc="simulating", args=args),
    )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rec = _write(data, out / "recording.npz")
    fault_text = ", ".join(f"{k} x{v:g}" for k, v in faults.items())
    png = out / "signals.png"
    plot_signals(data, path=png, title=f"AMB with fault {fault_text} ({args.plant} plant)")
    return {
        "recording": str(rec),
        "plot": str(png),
        "fault": faults,
        "n_samples": data.n_samples,
        "loop_matrix_condition": data.loop["loop_matrix_condition"],
    }
