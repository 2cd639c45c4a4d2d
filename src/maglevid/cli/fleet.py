"""``maglevid fleet SOURCE...``: diagnose every recording of a fleet on a Dask cluster."""

from __future__ import annotations

import argparse
import logging
from typing import Any

COMMAND = "fleet"
HELP = "diagnose every recording of many machines on a Dask cluster, with a fleet summary"
DESCRIPTION = """\
Diagnose every recording of a folder, glob or manifest, record each diagnosis
in the history store, and summarise the fleet: which machines changed (and
why), which drift, which recordings could not be diagnosed.

  maglevid fleet recordings/                        # recordings/<machine>/.../<file>
  maglevid fleet fleet.csv --store postgresql://user@db/plant --summary fleet.html
  maglevid fleet 'recordings/*/*.npz' --baseline history --reports reports/
  maglevid fleet recordings/ --scheduler tcp://scheduler:8786   # an existing cluster

Machines: the manifest's 'machine' column; else --machine; else, for a folder
DIR, the first folder below it (DIR/<machine>/.../<recording>; files lying in
DIR itself belong to the machine named like DIR); for a glob or a file, the
folder holding the recording.

Manifest: CSV with a header (or JSON list of objects) with the columns
machine, recording (required), baseline (nominal | history | FILE.json),
method, tolerances ("0.05" or "R1=0.1 Ls1=0.05"), recorded_at (ISO 8601 with
offset), method_options (JSON). Relative paths are relative to the manifest.

Runs on a local Dask cluster with one single-threaded worker process per core
unless --scheduler names a running one. Running the same command again adds
nothing to the store: a recording already diagnosed (same machine, content,
method and options) is skipped. The store is --store PATH_OR_URL, else
$MAGLEVID_HISTORY, else maglevid-history.sqlite in the current folder; workers
on other hosts need a PostgreSQL store.
"""

_STATE_ORDER = {"changed": 0, "drifting": 1, "inconclusive": 2, "undiagnosed": 3, "ok": 4}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "sources",
        nargs="+",
        metavar="SOURCE",
        help="folder, glob, manifest (.csv/.json) or recording file; several allowed",
    )
    parser.add_argument(
        "--store",
        default=None,
        metavar="PATH_OR_URL",
        help="history store: SQLite file (created if missing) or postgresql:// URL "
        "(default: $MAGLEVID_HISTORY or ./maglevid-history.sqlite)",
    )
    parser.add_argument(
        "--schema", default=None, help="PostgreSQL schema of the store (default: maglevid)"
    )
    parser.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="address of a running Dask scheduler, e.g. tcp://host:8786 "
        "(default: a local cluster on this machine)",
    )
    parser.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help="worker processes of the local cluster (default: the cores available)",
    )
    parser.add_argument(
        "--machine", default=None, help="machine of every recording of folders, globs and files"
    )
    parser.add_argument(
        "--baseline",
        default="nominal",
        help="'nominal' (design values stored in each recording), 'history' (each machine's "
        "previous diagnosis) or a JSON file of AMB parameters; manifests may say per row",
    )
    parser.add_argument("--method", default=None, help="identification method (default: chosen)")
    parser.add_argument(
        "--tolerance",
        action="append",
        default=[],
        metavar="[NAME=]FRACTION",
        help="engineering tolerance, relative (0.05 = 5 %%); per parameter with NAME=; repeatable",
    )
    parser.add_argument(
        "--batch-size",
        type=int,
        default=None,
        metavar="N",
        help="recordings per Dask task (default: chosen from the fleet size, at most 8)",
    )
    parser.add_argument(
        "--retries", type=int, default=2, help="Dask retries of a task that raises (default 2)"
    )
    parser.add_argument(
        "--summary",
        default=None,
        metavar="HTML",
        help="write the fleet overview page (self-contained HTML) here",
    )
    parser.add_argument(
        "--overwrite", action="store_true", help="replace --summary if it exists (default: refuse)"
    )
    parser.add_argument(
        "--reports",
        default=None,
        metavar="DIR",
        help="write the report of each machine whose latest recording is a fault or an "
        "unexplained change into DIR",
    )
    parser.add_argument(
        "--alpha",
        type=float,
        default=0.01,
        help="drift false-alarm probability per machine (split over its parameters)",
    )
    parser.add_argument(
        "--fail-on-change",
        action="store_true",
        help="exit with status 3 when a machine changed or drifts (for scheduled checks)",
    )


def run(args: argparse.Namespace) -> dict[str, Any]:
    from maglevid.cli._progress import progress
    from maglevid.cli.diagnose import _tolerances
    from maglevid.fleet import run_fleet
    from maglevid.fleet.jobs import parse_baseline

    if not getattr(args, "verbose", False):
        # The local cluster's scheduler runs in this process and logs at INFO
        # through distributed's own configuration, set when it is imported; -v shows it.
        try:
            import distributed  # noqa: F401
        except ImportError:  # run_fleet says what to install
            pass
        logging.getLogger("distributed").setLevel(logging.ERROR)

    def bar(items: Any, total: int) -> Any:
        return progress(items, desc="diagnosing", total=total, args=args)

    if args.summary:
        # Refused before the run, not after an hour of diagnoses.
        from maglevid.io import check_output

        check_output(args.summary, overwrite=args.overwrite, inputs=[args.store])
    summary = run_fleet(
        args.sources,
        store=args.store,
        schema=args.schema,
        scheduler=args.scheduler,
        n_workers=args.workers,
        machine=args.machine,
        baseline=parse_baseline(args.baseline),
        method=args.method,
        tolerances=_tolerances(args.tolerance),
        batch_size=args.batch_size,
        retries=args.retries,
        reports=args.reports,
        alpha=args.alpha,
        progress=bar,
    )
    out = summary.to_dict()
    if args.summary:
        from maglevid.report.fleet import write_fleet_summary

        page = write_fleet_summary(out, args.summary, overwrite=args.overwrite)
        out["summary_page"] = str(page)
    if args.fail_on_change and (out["changed"] or out["drifting"]):
        out["exit_code"] = 3
    return out


def _short(text: str | None, n: int) -> str:
    text = (text or "").replace("\n", " ")
    return text if len(text) <= n else text[: n - 1] + "…"


def _drift_words(d: dict[str, Any]) -> str:
    slope = d.get("slope_percent_per_day")
    words = f"{d['parameter']} ({d['method']})"
    if isinstance(slope, float):
        words += f" {slope:+.2g} %/day"
    words += f", p = {d['p_value']:.2g}" if isinstance(d.get("p_value"), float) else ""
    if d.get("projected_crossing"):
        words += (
            f", projected to leave ±{d['tolerance_percent']:.0f} % on "
            f"{d['projected_crossing'][:10]}"
        )
    return words


def format_text(result: dict[str, Any]) -> str:
    counts = result["counts"]
    machines = result["machines"]
    run = result["run"]
    n = sum(counts.values())
    parts = ", ".join(f"{v} {k}" for k, v in sorted(counts.items(), key=lambda kv: -kv[1]))
    where = "local cluster" if run.get("local_cluster") else run.get("scheduler", "")
    lines = [
        f"fleet: {n} recordings of {len(machines)} machines: {parts}",
        f"store {result['store']} · {run.get('n_workers')} workers ({where}) · "
        f"{run.get('seconds_total', 0.0):.1f} s",
        "",
    ]
    width = max([7, *(len(m["name"]) for m in machines)])
    lines.append(f"{'machine':<{width}}  {'recs':>4}  {'state':<11}  {'latest verdict'}")
    for m in sorted(machines, key=lambda m: (_STATE_ORDER[m["state"]], m["name"])):
        latest = m["latest"]
        verdict = "no usable diagnosis" if latest is None else latest["verdict"]
        extra = f"  [drift: {', '.join(m['drifting'])}]" if m["drifting"] else ""
        extra += f"  [{len(m['problems'])} not diagnosed]" if m["problems"] else ""
        lines.append(
            f"{m['name']:<{width}}  {m['n_recordings']:>4}  {m['state']:<11}  "
            f"{_short(verdict, 70)}{extra}"
        )
    changed = [m for m in machines if m["state"] == "changed"]
    if changed:
        lines += ["", f"changed ({len(changed)}):"]
        for m in changed:
            latest = m["latest"]
            lines.append(
                f"  {m['name']}: {latest['verdict']} (recording {latest['recording']}, "
                f"{(latest['recorded_at'] or '')[:10]})"
            )
            lines.extend(f"      {r}" for r in latest.get("reasons", [])[:3])
            if m.get("report"):
                lines.append(f"      report: {m['report']}")
    drifting = [m for m in machines if m["drifting"]]
    if drifting:
        lines += ["", f"drifting ({len(drifting)}):"]
        for m in drifting:
            for d in m["drifts"]:
                if d.get("drifting"):
                    lines.append(f"  {m['name']}: {_drift_words(d)}")
    problems = [(m["name"], p) for m in machines for p in m["problems"]]
    if problems:
        lines += ["", f"could not be diagnosed ({len(problems)}):"]
        for name, p in problems:
            lines.append(f"  {name}  {p['recording']}: {p['status']}: {_short(p['reason'], 160)}")
    if result.get("summary_page"):
        lines += ["", f"summary page: {result['summary_page']}"]
    return "\n".join(lines)
