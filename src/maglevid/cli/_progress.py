"""Progress bars for long work (tqdm on stderr; silent under --quiet/--json or no tty)."""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator
from typing import Any, TypeVar

T = TypeVar("T")


def _quiet(args: Any) -> bool:
    """No bar under --quiet or --json, nor when stderr is not a terminal (logs, pipes, CI):
    a bar's carriage returns would only clutter a log, and an error line printed after
    it must stay one line."""
    if args is not None and (getattr(args, "quiet", False) or getattr(args, "json", False)):
        return True
    isatty = getattr(sys.stderr, "isatty", None)
    return not (callable(isatty) and isatty())


def _tqdm() -> Any:
    """tqdm's bar without its monitor thread: a bar left a thread running for the rest of
    the process, and with a second thread alive the levitator's candidate fits no longer
    fork onto the other cores (maglevid.parallel; found in the test suite, eighteenth
    session). The monitor only shortens a stalled bar's refresh; these bars update at
    each step."""
    from tqdm import tqdm

    tqdm.monitor_interval = 0
    return tqdm


def progress(
    iterable: Iterable[T], *, desc: str, total: int | None = None, args: Any = None
) -> Iterator[T]:
    """Wrap ``iterable`` in a progress bar unless the user asked for quiet output."""
    if _quiet(args):
        yield from iterable
        return
    tqdm = _tqdm()
    yield from tqdm(
        iterable, desc=desc, total=total, file=sys.stderr, leave=False, mininterval=0.5
    )


def stages(names: Iterable[str], *, desc: str, args: Any = None) -> Iterator[str]:
    """A bar over the named stages of one command, the current one shown beside it.

    For commands whose work is a few long steps (read, identify, report): the
    bar appears once a step takes longer than a moment, with its name.
    """
    names = list(names)
    if _quiet(args):
        yield from names
        return
    tqdm = _tqdm()
    bar = tqdm(total=len(names), desc=desc, file=sys.stderr, leave=False, mininterval=0.5)
    try:
        for name in names:
            bar.set_postfix_str(name, refresh=True)
            yield name
            bar.update(1)
    finally:
        bar.close()
