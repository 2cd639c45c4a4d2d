"""Progress reporting is a callback passed in, not an import of the CLI (issue 19).

``run_scenario`` (and the experiments' ``run_parallel``) take
``progress(iterable, *, desc, total=None)``; without one they report nothing.
"""

from __future__ import annotations

import argparse

from maglevid.experiments._parallel import run_parallel
from maglevid.simulate import amb


def _args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    amb.add_scenario_arguments(parser)
    return parser.parse_args(list(argv))


def test_scenario_reports_its_chunks_through_the_callback_it_is_given():
    seen: list[tuple[str, int | None, int]] = []

    def progress(items, *, desc, total=None):
        items = list(items)
        seen.append((desc, total, len(items)))
        return items

    args = _args("--n-samples", "2500", "--seed", "1")
    with_bar = amb.run_scenario(args, progress=progress)
    without = amb.run_scenario(args)
    # 2500 samples in chunks of 2000: two chunks, announced and iterated.
    assert seen == [("simulating", 2, 2)]
    assert (with_bar.y == without.y).all()  # reporting changes nothing


def test_parallel_runs_report_every_task():
    seen = []

    def progress(items, *, desc, total=None):
        seen.append((desc, total))
        return items

    results, _ = run_parallel(abs, [-1, -2, -3], argparse.Namespace(workers=1), progress=progress)
    assert results == [1, 2, 3]
    assert seen == [("Monte Carlo", 3)]
