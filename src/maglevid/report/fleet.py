"""The fleet overview page: one self-contained HTML file for a fleet run.

:func:`render_fleet_summary` turns the ``to_dict()`` of a
:class:`maglevid.fleet.FleetSummary` (also what ``maglevid fleet --json``
prints) into a page in the style of the diagnosis report (its CSS, colours and
helpers are imported from :mod:`maglevid.report.html`, not copied), verdict
first:

1. the fleet at a glance: machines, recordings, changed, drifting, not diagnosed;
2. machines that changed, with the cause and a link to their report;
3. machines whose parameters drift, with the slope and when the trend leaves
   its tolerance band;
4. recordings that could not be diagnosed, and why;
5. every machine; 6. every recording (folded).

It takes plain data so that a page can be rebuilt from stored JSON, and the
report package does not depend on the fleet package (imports flow
``cli -> fleet -> report``). The summary is embedded as
``<script type="application/json" id="fleet-data">``.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping, Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from maglevid.exceptions import DataError
from maglevid.report.html import _CSS, VERDICT_STYLE, _e, _num, _pct, _script_json

__all__ = ["render_fleet_summary", "write_fleet_summary"]

logger = logging.getLogger(__name__)

_STATE_STYLE = {
    "changed": ("#b91c1c", "Changed"),
    "drifting": ("#b45309", "Drifting"),
    "inconclusive": VERDICT_STYLE["inconclusive"],
    "undiagnosed": ("#475569", "No diagnosis"),
    "ok": ("#15803d", "OK"),
}
_STATE_ORDER = {"changed": 0, "drifting": 1, "inconclusive": 2, "undiagnosed": 3, "ok": 4}

_STATUS_LABEL = {
    "diagnosed": "diagnosed",
    "skipped": "already stored",
    "unreadable": "unreadable",
    "missing": "missing",
    "error": "error",
    "lost": "worker died",
    "duplicate": "duplicate",
}

_FLEET_CSS = """
.pillv{display:inline-block;border-radius:999px;padding:1px 9px;font-size:12px;font-weight:700;
 color:#fff;white-space:nowrap}
.fleet-banner{background:#111827}
td.wrap{max-width:520px;overflow-wrap:anywhere}
td.path{font-family:ui-monospace,SFMono-Regular,Menlo,monospace;font-size:12.5px;
 overflow-wrap:anywhere;max-width:360px}
"""


def _pill(code: str | None, *, status: str | None = None) -> str:
    if code in VERDICT_STYLE:
        color, label = VERDICT_STYLE[code]
    elif code == "drift":
        color, label = "#b45309", "Drift"
    else:
        color, label = "#6b7280", _STATUS_LABEL.get(status or "", status or "—")
    return (
        f'<span class="pillv" style="background:{color}" data-code="{_e(code or "")}">'
        f"{_e(label)}</span>"
    )


def _state_pill(state: str) -> str:
    color, label = _STATE_STYLE.get(state, ("#6b7280", state))
    return f'<span class="pillv" style="background:{color}">{_e(label)}</span>'


def _link(target: str | None, base: Path | None) -> str:
    if not target:
        return "—"
    href = target
    if base is not None:
        try:
            href = os.path.relpath(target, base)
        except ValueError:  # another drive (Windows): keep the absolute path
            href = Path(target).resolve().as_uri()
    return f'<a href="{_e(Path(href).as_posix())}">{_e(Path(target).name)}</a>'


def _date(text: str | None) -> str:
    return _e((text or "—")[:16].replace("T", " "))


def _table(head: Sequence[str], rows: Sequence[str], *, cls: str = "data") -> str:
    th = "".join(f"<th>{h}</th>" for h in head)
    return (
        f'<table class="{cls}"><thead><tr>{th}</tr></thead><tbody>{"".join(rows)}</tbody></table>'
    )


def _card(key: str, number: int, title: str, body: str, *, lead: str = "") -> str:
    lead_html = f'<p class="lead">{lead}</p>' if lead else ""
    return (
        f'<section id="{key}" class="card"><h2><span class="num">{number}</span>{_e(title)}'
        f"</h2>{lead_html}{body}</section>"
    )


def _facts(summary: Mapping[str, Any]) -> str:
    machines = summary["machines"]
    n_rec = sum(summary["counts"].values())
    run = summary.get("run", {})
    facts = [
        ("machines", str(len(machines)), f"{n_rec} recordings"),
        ("changed", str(len(summary["changed"])), "fault or unexplained change"),
        ("drifting", str(len(summary["drifting"])), "a parameter trends"),
        (
            "inconclusive",
            str(len(summary.get("inconclusive", ()))),
            "the data cannot resolve the tolerance",
        ),
        ("not diagnosed", str(summary["n_problems"]), "recordings without a usable diagnosis"),
        (
            "diagnosed now",
            str(summary["counts"].get("diagnosed", 0)),
            f"{summary['counts'].get('skipped', 0)} already in the store",
        ),
        (
            "run",
            f"{_num(run.get('seconds_total'), 3)} s",
            f"{run.get('n_workers', '?')} workers, "
            + ("local cluster" if run.get("local_cluster") else _e(run.get("scheduler", ""))),
        ),
    ]
    return (
        '<div class="facts">'
        + "".join(
            f'<div class="fact" data-fact="{_e(k)}"><div class="fact-k">{_e(k)}</div>'
            f'<div class="fact-v">{_e(v)}</div><div class="fact-s">{s}</div></div>'
            for k, v, s in facts
        )
        + "</div>"
    )


def _changed(summary: Mapping[str, Any], base: Path | None) -> str:
    rows = []
    for m in summary["machines"]:
        if m["state"] != "changed":
            continue
        latest = m["latest"]
        changes = ", ".join(
            f"{c['parameter']} {_num(c.get('change_percent'), 3)} %" for c in latest["changes"]
        )
        rows.append(
            f'<tr class="hl" data-machine="{_e(m["name"])}"><td><b>{_e(m["name"])}</b></td>'
            f"<td>{_pill(latest['verdict_code'])}</td>"
            f'<td class="wrap">{_e(latest.get("cause") or latest["verdict"])}'
            f'<div class="small">{_e(changes)}</div></td>'
            f'<td class="path">{_e(latest["recording"])}</td>'
            f"<td>{_date(latest['recorded_at'])}</td>"
            f"<td>{_link(m.get('report'), base)}</td></tr>"
        )
    if not rows:
        return (
            '<div class="callout good">No machine changed: every latest diagnosis is '
            '"no change", within tolerance or a drift.</div>'
        )
    return _table(
        ["machine", "verdict", "cause / changed parameters", "recording", "recorded", "report"],
        rows,
    )


def _drifting(summary: Mapping[str, Any]) -> str:
    rows = []
    for m in summary["machines"]:
        for d in m["drifts"]:
            if not d.get("drifting"):
                continue
            rows.append(
                f'<tr data-machine="{_e(m["name"])}"><td><b>{_e(m["name"])}</b></td>'
                f"<td>{_e(d['parameter'])}</td><td>{_e(d['method'])}</td>"
                f'<td class="r">{_pct(d.get("slope_percent_per_day"), 2)}/day</td>'
                f'<td class="r">{_num(d.get("p_value"), 2)}</td>'
                f'<td class="r">{d.get("n", "—")}</td>'
                f"<td>{_e((d.get('projected_crossing') or '—')[:10])}"
                f' <span class="small">(±{_num(d.get("tolerance_percent"), 3)} %)</span></td></tr>'
            )
    if not rows:
        return '<div class="callout good">No parameter drifts significantly.</div>'
    return _table(
        ["machine", "parameter", "method", "slope", "p", "points", "leaves its band"], rows
    )


def _problems(summary: Mapping[str, Any]) -> str:
    rows = []
    for m in summary["machines"]:
        for p in m["problems"]:
            rows.append(
                f'<tr data-machine="{_e(m["name"])}"><td>{_e(m["name"])}</td>'
                f'<td class="path">{_e(p["recording"])}</td>'
                f"<td>{_e(_STATUS_LABEL.get(p['status'], p['status']))}</td>"
                f'<td class="wrap">{_e(p["reason"])}</td></tr>'
            )
    if not rows:
        return '<div class="callout good">Every recording was diagnosed.</div>'
    return _table(["machine", "recording", "what happened", "why"], rows)


def _machines(summary: Mapping[str, Any], base: Path | None) -> str:
    rows = []
    for m in sorted(
        summary["machines"], key=lambda m: (_STATE_ORDER.get(m["state"], 9), m["name"])
    ):
        latest = m["latest"] or {}
        counts = ", ".join(f"{v} {_STATUS_LABEL.get(k, k)}" for k, v in m["counts"].items())
        rows.append(
            f'<tr data-machine="{_e(m["name"])}" data-state="{_e(m["state"])}">'
            f"<td><b>{_e(m['name'])}</b></td><td>{_state_pill(m['state'])}</td>"
            f'<td class="r">{m["n_recordings"]}</td><td class="small">{_e(counts)}</td>'
            f"<td>{_pill(latest.get('verdict_code'), status='none')}</td>"
            f'<td class="wrap">{_e(latest.get("verdict", "no usable diagnosis"))}</td>'
            f"<td>{_date(latest.get('recorded_at'))}</td>"
            f"<td>{_link(m.get('report'), base)}</td></tr>"
        )
    return _table(
        ["machine", "state", "recs", "this run", "latest", "verdict", "recorded", "report"], rows
    )


def _recordings(summary: Mapping[str, Any]) -> str:
    rows = []
    for o in summary["recordings"]:
        rows.append(
            f'<tr><td>{_e(o["machine"])}</td><td class="path">{_e(o["recording"])}</td>'
            f"<td>{_e(_STATUS_LABEL.get(o['status'], o['status']))}</td>"
            f"<td>{_pill(o.get('verdict_code'), status=o['status'])}</td>"
            f'<td class="wrap">{_e(o.get("verdict") or "")}</td>'
            f"<td>{_date(o.get('recorded_at'))}</td>"
            f'<td class="r">{_num(o.get("seconds"), 3)}</td></tr>'
        )
    table = _table(["machine", "recording", "status", "verdict", "", "recorded", "s"], rows)
    return f"<details><summary>{len(rows)} recordings</summary>{table}</details>"


def render_fleet_summary(
    summary: Mapping[str, Any],
    *,
    title: str | None = None,
    base: str | os.PathLike[str] | None = None,
    generated_at: datetime | None = None,
) -> str:
    """The fleet summary as one self-contained HTML page.

    Parameters
    ----------
    summary : mapping
        ``FleetSummary.to_dict()`` (``"format": "maglevid-fleet-summary"``).
    title : str, optional
        Page title (default "maglevid fleet summary").
    base : path, optional
        Folder the page will be saved in: links to reports are made relative
        to it (default: absolute paths).
    generated_at : datetime, optional
        Creation time in the footer (default now, UTC).

    Raises
    ------
    DataError
        ``summary`` is not a fleet summary.
    """
    if not isinstance(summary, Mapping) or summary.get("format") != "maglevid-fleet-summary":
        raise DataError(
            "`summary` must be FleetSummary.to_dict() (format 'maglevid-fleet-summary')"
        )
    from maglevid import __version__

    base_path = Path(base).resolve() if base is not None else None
    when = (generated_at or datetime.now(timezone.utc)).astimezone(timezone.utc)
    when_txt = when.strftime("%Y-%m-%d %H:%M:%S UTC")
    page_title = title or "maglevid fleet summary"
    n_changed, n_drift, n_prob = (
        len(summary["changed"]),
        len(summary["drifting"]),
        summary["n_problems"],
    )
    n_inc = len(summary.get("inconclusive", ()))
    headline = (
        f"{n_changed} of {len(summary['machines'])} machines changed, {n_drift} drifting, "
        + (f"{n_inc} inconclusive, " if n_inc else "")
        + f"{n_prob} recording{'' if n_prob == 1 else 's'} not diagnosed"
    )
    banner_color = (
        VERDICT_STYLE["fault"][0]
        if n_changed
        else ("#b45309" if n_drift or n_inc else VERDICT_STYLE["no_change"][0])
    )
    sections = [
        '<div class="verdict"><div id="fleet-banner" class="banner" '
        f'style="background:{banner_color}">'
        f'<div class="pill">Fleet</div><h1 id="fleet-headline">{_e(headline)}</h1></div>'
        '<div class="verdict-body"><div class="meta">'
        f"<span><b>store</b>{_e(summary['store'])}</span>"
        f"<span><b>started</b>{_e(summary.get('run', {}).get('started_at', '—'))}</span></div>"
        f"{_facts(summary)}</div></div>",
        _card(
            "changed",
            1,
            "Machines that changed",
            _changed(summary, base_path),
            lead="Each machine's latest diagnosis (by recording time, this run or earlier) "
            "is a fault or a change no single cause explains.",
        ),
        _card(
            "drifting",
            2,
            "Parameters that drift",
            _drifting(summary),
            lead="Weighted least-squares trend test over each machine's whole history, one "
            "test per parameter and method, at a per-machine false-alarm level split over "
            "its parameters (Bonferroni).",
        ),
        _card("problems", 3, "Recordings that could not be diagnosed", _problems(summary)),
        _card("machines", 4, "All machines", _machines(summary, base_path)),
        _card("recordings", 5, "All recordings of this run", _recordings(summary)),
    ]
    data = _script_json(summary)
    return (
        "<!DOCTYPE html>\n"
        '<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f'<meta name="generator" content="maglevid {_e(__version__)}">'
        f"<title>{_e(page_title)}</title><style>{_CSS}{_FLEET_CSS}</style></head>\n"
        f'<body data-changed="{n_changed}" data-drifting="{n_drift}" data-problems="{n_prob}">'
        '<div class="top"><div class="wrap"><span><b>maglevid</b> · fleet summary</span>'
        f"<span>{_e(summary['store'])}</span></div></div>"
        f'<main class="wrap">{"".join(sections)}</main>'
        f'<footer><div class="wrap"><span>Generated by maglevid {_e(__version__)} on '
        f"{_e(when_txt)}</span><span>{_e(page_title)}</span></div></footer>\n"
        f'<script type="application/json" id="fleet-data">{data}</script>\n'
        "</body></html>\n"
    )


def write_fleet_summary(
    summary: Mapping[str, Any],
    path: str | os.PathLike[str],
    *,
    title: str | None = None,
    generated_at: datetime | None = None,
    overwrite: bool = False,
) -> Path:
    """Write :func:`render_fleet_summary` to ``path`` (UTF-8); report links relative to it.

    Written by the rules of every maglevid output
    (:func:`maglevid.io.write_output`): atomically, never over a recording of
    the fleet (or its side-car) or the store, never over an existing file
    unless ``overwrite``.

    Raises
    ------
    DataError
        The folder of ``path`` does not exist, ``path`` exists (without
        ``overwrite``) or is one of the fleet's inputs, or ``summary`` is not
        a fleet summary.
    """
    from maglevid.io import check_output, write_output

    recordings = summary.get("recordings", ()) if isinstance(summary, Mapping) else ()
    inputs = [r.get("recording") for r in recordings if isinstance(r, Mapping)]
    inputs.append(summary.get("store") if isinstance(summary, Mapping) else None)
    path = check_output(path, overwrite=overwrite, inputs=inputs)
    text = render_fleet_summary(summary, title=title, base=path.parent, generated_at=generated_at)
    path = write_output(path, text, overwrite=overwrite, inputs=inputs)
    logger.info("wrote fleet summary %s (%d bytes)", path, len(text.encode("utf-8")))
    return path
