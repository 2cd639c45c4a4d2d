"""``maglevid history MACHINE``: parameter trends and drift tests from the history store."""

from __future__ import annotations

import argparse
import math
from typing import Any

from maglevid.diagnose.trend_summary import history_summary

COMMAND = "history"
HELP = "parameter trends of a machine, with a drift test per parameter"
DESCRIPTION = """\
Show how the physical parameters of a machine evolved over its stored
diagnoses: one line per parameter with its unit, the latest value +- standard
error, the change from the baseline, the trend (linear drift: weighted least
squares, t-test on the slope; or Mann-Kendall) or the step that describes the
series better, and a verdict (DRIFTING, STEP, stable). Changed parameters come
first; --points lists the series behind each line.

  maglevid history --list                          # machines in the store
  maglevid history pump-7                          # one line per parameter
  maglevid history pump-7 --parameter R1 --points  # and the values behind it
  maglevid history pump-7 --parameter R1 Ls1 --tolerance R1=0.2 --json

The store is --store PATH_OR_URL, else $MAGLEVID_HISTORY, else
maglevid-history.sqlite in the current folder. A PostgreSQL store is given as
postgresql://user:password@host:port/database.
"""

_TEXT_POINTS = 20  # most recent points per parameter in text output; --json has all


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("machine", nargs="?", help="machine name (see --list)")
    parser.add_argument(
        "--store",
        default=None,
        metavar="PATH_OR_URL",
        help="history store: SQLite file or postgresql:// URL "
        "(default: $MAGLEVID_HISTORY or ./maglevid-history.sqlite)",
    )
    parser.add_argument(
        "--schema", default=None, help="PostgreSQL schema of the store (default: maglevid)"
    )
    parser.add_argument("--list", action="store_true", help="list the machines and exit")
    parser.add_argument(
        "--parameter",
        nargs="+",
        action="extend",
        default=None,
        metavar="NAME",
        help="parameters to show (default: all)",
    )
    parser.add_argument("--method", default=None, help="only diagnoses made by this method")
    parser.add_argument(
        "--alpha", type=float, default=0.01, help="significance level of the drift test"
    )
    parser.add_argument(
        "--drift-method",
        choices=("wls", "mann-kendall"),
        default="wls",
        help="drift test: weighted least-squares t-test (default) or Mann-Kendall",
    )
    parser.add_argument(
        "--tolerance",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="band half-width of a parameter (its unit) around its stored baseline; "
        "projects when the trend leaves it; repeatable",
    )
    parser.add_argument(
        "--points",
        action="store_true",
        help=f"also list each parameter's series (the last {_TEXT_POINTS}; --json has all)",
    )
    parser.add_argument(
        "--fail-on-drift",
        action="store_true",
        help="exit with status 3 when any parameter drifts (for scheduled checks)",
    )


def _tolerances(items: list[str]) -> dict[str, float]:
    from maglevid.exceptions import DataError

    out: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            tol = float(value)
        except ValueError:
            tol = math.nan
        if not sep or not name or not (math.isfinite(tol) and tol > 0):
            raise DataError(f"--tolerance {item!r}: expected NAME=VALUE with VALUE > 0")
        out[name] = tol
    return out


def run(args: argparse.Namespace) -> dict[str, Any]:
    from maglevid.diagnose.history import default_store_location, open_history
    from maglevid.exceptions import DataError

    location = args.store or default_store_location()
    if not (0.0 < args.alpha < 1.0):
        raise DataError(f"--alpha {args.alpha}: expected 0 < alpha < 1")
    with open_history(location, create=False, schema=args.schema) as store:
        if args.list:
            return {"store": store.location, "machines": [m.to_dict() for m in store.machines()]}
        if not args.machine:
            raise DataError("give a MACHINE (or --list to see the machines)")
        result = history_summary(
            store,
            args.machine,
            parameters=args.parameter,
            method=args.method,
            alpha=args.alpha,
            drift_method=args.drift_method,
            tolerances=_tolerances(args.tolerance),
        )
    result["exit_code"] = 3 if (args.fail_on_drift and result["drifting"]) else 0
    result["points"] = bool(args.points)
    return result


def _fmt(x: float | None, digits: int = 6) -> str:
    return "n/a" if x is None else f"{x:.{digits}g}"


def _rank(name: str, p: dict[str, Any]) -> tuple[int, bool]:
    """Changed parameters first, then drifting ones, v1..v9 after the physical ones."""
    flagged = {"STEP": 0, "DRIFTING": 1}.get(p.get("verdict", ""), 2)
    return flagged, name[:1] == "v" and name[1:].isdigit()


def _trend_text(p: dict[str, Any]) -> str:
    step = p.get("step")
    if step:
        pct = f" ({step['percent']:+.1f} %)" if step.get("percent") is not None else ""
        return f"step at {(step['at'] or '?')[:10]}{pct}, {_p_text(step['p_value'])}"
    latest = p.get("latest") or {}
    d = p["drift"].get(latest.get("method"), {})
    if not d or "skipped" in d:
        return "not tested (too few points)" if d else "-"
    unit = p["unit"] or ""
    text = f"{_fmt(d['slope'], 3)} {unit}/day, {_p_text(d['p_value'])}"
    if d.get("projected_crossing_at"):
        text += f", limit ~{d['projected_crossing_at'][:10]}"
    return text


def _p_text(p: float | None) -> str:
    """A p-value as text; below 1e-16 (double precision) as a bound, never "p = 0"."""
    if p is None:
        return "p n/a"
    return "p < 1e-16" if p < 1e-16 else f"p = {p:.2g}"


def _line(name: str, p: dict[str, Any]) -> str:
    latest = p.get("latest")
    if latest is None:
        return f"{name:<10} {(p['unit'] or ''):<12} {'-':>22}"
    se = latest["std_error"]
    value = f"{latest['value']:.5g}" + (f" ± {se:.2g}" if se is not None else "")
    change = "-" if p["change_percent"] is None else f"{p['change_percent']:+.1f} %"
    return (
        f"{name:<10} {(p['unit'] or ''):<12} {value:>22} {change:>9}  "
        f"{_trend_text(p):<46} {p['verdict']}"
    )


def _series(name: str, p: dict[str, Any]) -> list[str]:
    unit = p["unit"] or ""
    lines = ["", f"{name} [{unit}]" if unit else name]
    pts = p["points"]
    if len(pts) > _TEXT_POINTS:
        lines.append(f"  ... {len(pts) - _TEXT_POINTS} earlier points (all in --json)")
    for q in pts[-_TEXT_POINTS:]:
        se = q["std_error"]
        pm = f" ± {se:.3g}" if se is not None else " (no s.e.)"
        when = q["recorded_at"][:16].replace("T", " ")
        lines.append(f"  {when}  {q['value']:.6g}{pm}  {q['method']}")
    for method, d in p["drift"].items():
        if "skipped" in d:
            lines.append(f"  drift ({method}): not tested: {d['skipped']}")
            continue
        verdict = "DRIFTING" if d["drifting"] else "no significant drift"
        lines.append(
            f"  drift ({d['method']}, {method}): slope {_fmt(d['slope'], 3)} {unit}/day "
            f"± {_fmt(d['slope_se'], 2)}, p = {_fmt(d['p_value'], 2)}: {verdict}"
        )
        if d.get("projected_crossing_at"):
            ci = d.get("crossing_ci_at") or [None, None]
            lines.append(
                f"    limit {_fmt(d['limit'])} {unit} (baseline {_fmt(d['baseline'])} ± "
                f"{_fmt(d['tolerance'])}) reached about {d['projected_crossing_at'][:10]} "
                f"({d['confidence']:.0%} CI {(ci[0] or '-inf')[:10]} .. "
                f"{(ci[1] or '+inf')[:10]})"
            )
        lines.extend(f"    note: {n}" for n in d["notes"])
    return lines


def format_text(result: dict[str, Any]) -> str:
    if "machines" in result:
        if not result["machines"]:
            return f"store {result['store']}: no machines"
        lines = [f"store {result['store']}:"]
        lines.append(
            f"  {'machine':<24} {'diagnoses':>9}  {'first recording':<19}  last recording"
        )
        for m in result["machines"]:
            first = (m["first_recorded_at"] or "-")[:19]
            last = (m["last_recorded_at"] or "-")[:19]
            lines.append(f"  {m['name']:<24} {m['n_diagnoses']:>9}  {first:<19}  {last}")
        return "\n".join(lines)
    lines = [
        f"machine {result['machine']}  ({result['n_diagnoses']} "
        f"{'diagnosis' if result['n_diagnoses'] == 1 else 'diagnoses'}; store "
        f"{result['store']})",
        "",
        f"{'parameter':<10} {'unit':<12} {'latest':>22} {'change':>9}  "
        f"{'trend or step':<46} verdict",
    ]
    order = sorted(result["parameters"].items(), key=lambda kv: _rank(*kv))
    for name, p in order:
        lines.append(_line(name, p))
    if result.get("points"):
        for name, p in order:
            lines.extend(_series(name, p))
    if result["drifting"]:
        lines.append("")
        lines.append("drifting: " + ", ".join(result["drifting"]))
    return "\n".join(lines)
