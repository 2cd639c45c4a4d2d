"""``--fault NAME=FACTOR``: parsed and checked alike for every scenario of ``maglevid
simulate`` (and ``maglevid plan``)."""

from __future__ import annotations

import argparse
import difflib
import math
from collections.abc import Iterable, Sequence

from maglevid.exceptions import DataError


def parse_fault(text: str) -> tuple[str, float]:
    """``"R1=1.2"`` -> ``("R1", 1.2)`` (the ``--fault`` option of the command line)."""
    if "=" not in text:
        raise argparse.ArgumentTypeError(f"--fault {text!r}: expected NAME=FACTOR, e.g. R1=1.2")
    name, value = text.split("=", 1)
    try:
        return name.strip(), float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--fault {text!r}: FACTOR must be a number") from None


def check_faults(faults: Iterable[tuple[str, float]], names: Sequence[str]) -> None:
    """Each ``(name, factor)`` names one of ``names`` and is a positive factor, judged as
    the factor the user wrote (found from outside, issue 16, fourteenth session: ``R1=-1``
    was refused as "got -17.5", the resistance it would have made)."""
    for k, f in faults:
        if k not in names:
            close = difflib.get_close_matches(k, names, n=1, cutoff=0.5)
            hint = f" (did you mean {close[0]}?)" if close else ""
            raise DataError(f"--fault {k}={f:g}: unknown name{hint}; one of {', '.join(names)}")
        if not (math.isfinite(f) and f > 0):
            raise DataError(
                f"--fault {k}={f:g}: the factor must be a positive number (1.2 for +20 %)"
            )
