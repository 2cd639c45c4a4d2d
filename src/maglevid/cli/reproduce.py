"""``maglevid reproduce PAPER``: the papers' tables and figures beside ours.

Reproductions are modules of :mod:`maglevid.experiments` that define ``PAPER``
(name), ``PAPER_HELP``, ``add_paper_arguments(parser)`` and
``run_reproduction(args, *, progress=None) -> dict`` (which also writes figures
under ``--out``; ``progress``: the CLI's progress bar, a callable wrapping an
iterable).
"""

from __future__ import annotations

import argparse
from typing import Any

from maglevid._plugins import modules_with

COMMAND = "reproduce"
HELP = "reproduce a paper's tables and figures (gosiewski, sun, rigs)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="paper", metavar="PAPER", required=True)
    for mod in modules_with("maglevid.experiments", "PAPER"):
        p = sub.add_parser(mod.PAPER, help=mod.PAPER_HELP, description=mod.PAPER_HELP)
        p.add_argument("--out", default="reproduce-out", help="folder for figures (PNG)")
        p.add_argument(
            "--overwrite",
            action="store_true",
            help="replace figures already in --out (default: refuse)",
        )
        mod.add_paper_arguments(p)
        p.set_defaults(_reproduce=mod.run_reproduction, _format=getattr(mod, "format_text", None))


def run(args: argparse.Namespace) -> dict[str, Any]:
    from functools import partial

    from maglevid.cli._progress import progress

    return args._reproduce(args, progress=partial(progress, args=args))
