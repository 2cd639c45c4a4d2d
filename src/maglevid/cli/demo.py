"""``maglevid demo``: the main job on the bundled default (what ``make demo`` runs)."""

from __future__ import annotations

import argparse
from typing import Any

COMMAND = "demo"
HELP = "simulate a small fleet of bearings over weeks, diagnose every recording, report faults"
DESCRIPTION = """\
The main job on the bundled default: three simulated bearings recorded every
3 days for 8 weeks (AMB-1 healthy, AMB-2 with coil 1 slowly heating, AMB-3
losing 20 % of amplifier 1's gain at week 5). Every recording is diagnosed into
a SQLite history; a table of verdicts is printed, and an HTML report is
written for each bearing whose latest verdict is a fault or a drift.

  maglevid demo                   # into ./demo-out
  maglevid demo --out /tmp/demo --weeks 4
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="demo-out", help="output folder (default demo-out)")
    parser.add_argument("--weeks", type=int, default=8, help="length of the campaign")
    parser.add_argument("--every", type=int, default=3, help="days between recordings")
    parser.add_argument("--seed", type=int, default=0, help="base random seed")


def run(args: argparse.Namespace) -> dict[str, Any]:
    from maglevid.cli._progress import progress
    from maglevid.experiments.demo import run_demo

    def bar(jobs: Any) -> Any:
        return progress(jobs, desc="diagnosing", total=len(jobs), args=args)

    return run_demo(
        args.out, weeks=args.weeks, every_days=args.every, seed=args.seed, progress=bar
    )


def format_text(result: dict[str, Any]) -> str:
    lines = [f"{'machine':<7} {'day':>3}  {'truth':<16} verdict"]
    for r in result["rows"]:
        v = r["verdict"] if len(r["verdict"]) < 110 else r["verdict"][:107] + "..."
        lines.append(f"{r['machine']:<7} {r['day']:>3}  {r['truth']:<16} {v}")
    lines.append("")
    for m, desc in result["bearings"].items():
        day = result["first_alarm_day"].get(m)
        lines.append(f"{m}: {desc}; first alarm: {'none' if day is None else f'day {day}'}")
    lines.append(
        f"history: {result['store']}   (maglevid history AMB-2 --store {result['store']})"
    )
    for m, path in result["reports"].items():
        lines.append(f"report {m}: {path}")
    return "\n".join(lines)
