"""Error against time of every tool at every N: the picture of docs/performance.md.

From the raw results of a ``make bench`` run::

    python -m benchmarks.run_all --json /tmp/bench.json ...
    python -m benchmarks.plot_speed_accuracy /tmp/bench.json docs/images/speed_accuracy.png

Two panels (the open-loop MIMO case and the closed-loop unstable bearing):
one marker per tool and record length, x = time, y = relative pole error (the
largest over the poles, or that of the unstable pole), a line joining one
tool's sizes; maglevid's methods drawn solid, the peers dashed. A tool that was
not measured at a size has no marker there.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

from benchmarks.judge import measured

__all__ = ["plot"]

_PANELS = (
    ("subspace", "open-loop MIMO (2 in, 3 out, order 4)"),
    ("bearing", "closed-loop unstable bearing"),
)


def _series(rows: list[dict[str, Any]]) -> dict[str, list[tuple[int, float, float]]]:
    out: dict[str, list[tuple[int, float, float]]] = {}
    for r in rows:
        e = r.get("pole_error")
        if measured(r) and e is not None and math.isfinite(e) and e > 0:
            out.setdefault(r["tool"], []).append((r["n"], r["time_s"], e))
    return {k: sorted(v) for k, v in out.items()}


def plot(results: dict[str, Any], path: Path, stamp: str = "") -> None:
    """Draw the two panels into ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [(k, t) for k, t in _PANELS if results.get(k, {}).get("rows")]
    fig, axes = plt.subplots(1, max(1, len(panels)), figsize=(7.5 * max(1, len(panels)), 6))
    axes = [axes] if len(panels) <= 1 else list(axes)
    for ax, (key, title) in zip(axes, panels):
        series = _series(results[key]["rows"])
        for k, (tool, pts) in enumerate(series.items()):
            ours = tool.startswith("maglevid")
            ax.plot(
                [p[1] for p in pts],
                [p[2] for p in pts],
                marker="os^vD<>ph*"[k % 10],
                color=plt.cm.tab20(k % 20),
                linestyle="-" if ours else "--",
                linewidth=2 if ours else 1,
                label=tool,
            )
            for n, t, e in pts:
                ax.annotate(f"{n:.0e}", (t, e), fontsize=6, alpha=0.6)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("time [s] (one BLAS thread)")
        ax.set_ylabel("relative pole error")
        ax.set_title(title + stamp, fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6, loc="best")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("json", help="raw results of run_all --json")
    ap.add_argument("png", help="where to write the picture")
    args = ap.parse_args(argv)
    raw = json.loads(Path(args.json).read_text())
    plot(raw["results"], Path(args.png), stamp=raw.get("meta", {}).get("stamp", ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
