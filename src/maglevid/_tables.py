"""Small HTML tables for the notebook representations of results and diagnoses."""

from __future__ import annotations

import html
import math
from collections.abc import Sequence
from typing import Any

__all__ = ["html_table", "number"]


def number(x: Any, digits: int = 5) -> str:
    """``x`` to ``digits`` significant digits; an em dash for None/NaN."""
    if x is None:
        return "—"
    try:
        v = float(x)
    except (TypeError, ValueError):
        return str(x)
    return "—" if math.isnan(v) else f"{v:.{digits}g}"


def html_table(header: Sequence[str], rows: Sequence[Sequence[Any]], *, titles: Any = None) -> str:
    """An escaped HTML table; ``titles[i]`` (optional) is the hover text of row ``i``."""
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in header)
    body = []
    for i, row in enumerate(rows):
        title = titles[i] if titles is not None and titles[i] else ""
        attr = f' title="{html.escape(title, quote=True)}"' if title else ""
        cells = "".join(f"<td>{html.escape(str(c))}</td>" for c in row)
        body.append(f"<tr{attr}>{cells}</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"
