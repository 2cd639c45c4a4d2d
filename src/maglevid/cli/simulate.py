"""``maglevid simulate SCENARIO``: write a simulated closed-loop recording.

Scenarios are modules of :mod:`maglevid.simulate` that define ``SCENARIO``
(name), ``SCENARIO_HELP``, ``add_scenario_arguments(parser)`` and
``run_scenario(args, *, progress=None) -> ClosedLoopData`` (``progress``: the
CLI's progress bar, a callable wrapping an iterable).
"""

from __future__ import annotations

import argparse
from typing import Any

from maglevid._plugins import modules_with

COMMAND = "simulate"
HELP = "simulate a closed loop and write the recording to a file"
DESCRIPTION = """\
Simulate a magnetic suspension under feedback and write what its controller
would log (excitation, plant input, feedback, outputs) as a recording.

  maglevid simulate amb --fault R1=1.2 --n-samples 20000 --out faulty.npz
  maglevid simulate SCENARIO --help     # the options of one scenario
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="scenario", metavar="SCENARIO", required=True)
    for mod in modules_with("maglevid.simulate", "SCENARIO"):
        p = sub.add_parser(mod.SCENARIO, help=mod.SCENARIO_HELP, description=mod.SCENARIO_HELP)
        p.add_argument(
            "--out", required=True, help="recording to write (.npz, .csv, .mat, .parquet)"
        )
        p.add_argument(
            "--overwrite", action="store_true", help="replace --out if it exists (default: refuse)"
        )
        mod.add_scenario_arguments(p)
        p.set_defaults(_scenario=mod.run_scenario)


def run(args: argparse.Namespace) -> dict[str, Any]:
    from functools import partial

    from maglevid.cli._progress import progress, stages
    from maglevid.io import write_recording

    steps = stages(("simulating", "writing"), desc=f"simulate {args.scenario}", args=args)
    next(steps)
    data = args._scenario(args, progress=partial(progress, args=args))
    next(steps)
    path = write_recording(data, args.out, overwrite=args.overwrite)
    steps.close()
    return {"written": str(path), "recording": repr(data), "n_samples": data.n_samples}
