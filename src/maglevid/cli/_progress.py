"""Progress bars for long work (tqdm on stderr; silent under --quiet/--json or no tty)."""

from __future__ import annotations

import sys
from collections.abc import Iterable, Iterator
from typing import Any, TypeVar

T = TypeVar("T")


def progress(
    iterable: Iterable[T], *, desc: str, total: int | None = None, args: Any = None
) -> Iterator[T]:
    """Wrap ``iterable`` in a progress bar unless the user asked for quiet output."""
    quiet = bool(
        args is not None and (getattr(args, "quiet", False) or getattr(args, "json", False))
    )
    if quiet:
        yield from iterable
        return
    from tqdm import tqdm

    yield from tqdm(
        iterable, desc=desc, total=total, file=sys.stderr, leave=False, mininterval=0.5
    )


def stages(names: Iterable[str], *, desc: str, args: Any = None) -> Iterator[str]:
    """A bar over the named stages of one command, the current one shown beside it.

    For commands whose work is a few long steps (read, identify, report): the
    bar appears once a step takes longer than a moment, with its name.
    """
    quiet = bool(
        args is not None and (getattr(args, "quiet", False) or getattr(args, "json", False))
    )
    names = list(names)
    if quiet:
        yield from names
        return
    from tqdm import tqdm

    bar = tqdm(total=len(names), desc=desc, file=sys.stderr, leave=False, mininterval=0.5)
    try:
        for name in names:
            bar.set_postfix_str(name, refresh=True)
            yield name
            bar.update(1)
    finally:
        bar.close()
