"""The diagnosis report: one self-contained HTML file, verdict first.

:func:`render_report` turns a :class:`~maglevid.diagnose.diagnosis.Diagnosis`
into an HTML page an engineer can open offline, attach to a ticket or print:
inline CSS, figures as base64 PNG data URIs, no external script, style sheet or
font. Sections, in the order of issue 5:

1. verdict (plain words, colour-coded by ``verdict_code``) with the reasons
   and the fault-isolation evidence;
2. identified vs baseline parameters: forest plot of the % change with
   confidence intervals and tolerance bands, and the table;
3. the matrix percentage indexes ``A_p``, ``B_p`` (Gosiewski & Paszowski,
   Example I) as coloured tables in the paper's layout;
4. pole maps (s- and z-plane), open loop and, when the controller is known,
   closed loop;
5. impulse responses (displacement, both inputs; Figs. 3-4 of the paper) and
   Bode plots, identified vs baseline;
6. parameter trends, when a history is given;
7. the data-quality checks;
8. method and notes; footer with the maglevid version and creation time.

The diagnosis' ``to_dict()`` is embedded as
``<script type="application/json" id="diagnosis-data">`` so that a program can
read the report too. All text is escaped.
"""

from __future__ import annotations

import base64
import dataclasses
import html
import json
import logging
import math
import os
from collections.abc import Callable, Mapping, Sequence
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import linear_sum_assignment

from maglevid.control.feedback import close_loop, controller_state_space
from maglevid.diagnose.compare import DEFAULT_TOLERANCE
from maglevid.diagnose.diagnosis import Diagnosis
from maglevid.diagnose.isolate import FaultHypothesis
from maglevid.diagnose.percentage import percentage_index
from maglevid.exceptions import DataError, MaglevidError
from maglevid.lti import StateSpace, discretize
from maglevid.physics.amb import amb_matrices
from maglevid.physics.units import PARAMETER_INFO, UNIT_WORDS

__all__ = ["VERDICT_STYLE", "is_maglevid_page", "render_report", "write_report"]

logger = logging.getLogger(__name__)

#: Banner colour and label per verdict code.
VERDICT_STYLE: dict[str, tuple[str, str]] = {
    "no_change": ("#15803d", "No change"),
    "within_tolerance": ("#0e7490", "Within tolerance"),
    "inconclusive": ("#b45309", "Inconclusive"),  # amber: never green
    "drift": ("#a16207", "Drift"),
    "fault": ("#b91c1c", "Fault"),
    "unexplained_change": ("#c2410c", "Unexplained change"),
    "cannot_diagnose": ("#475569", "Cannot diagnose"),
}

#: Relative size below which a baseline element is a structural zero of A_p, B_p.
ZERO_TOL = 1e-10

_STATUS_CLASS = {
    "changed": "st-changed",
    "within tolerance": "st-within",
    "not resolved": "st-unresolved",
    "unchanged": "st-unchanged",
}

_SECTIONS = (
    ("verdict", "Verdict"),
    ("parameters", "Parameters"),
    ("percentage", "Percentage index"),
    ("poles", "Poles"),
    ("responses", "Responses"),
    ("trends", "Trends"),
    ("quality", "Data quality"),
    ("method", "Method & notes"),
)


# ------------------------------------------------------------------- small helpers
def _e(text: Any) -> str:
    return html.escape(str(text), quote=True)


def _num(x: Any, digits: int = 5) -> str:
    if x is None:
        return "—"
    try:
        v = float(x)
    except (TypeError, ValueError):
        return _e(x)
    if math.isnan(v):
        return "—"
    if math.isinf(v):
        return "∞" if v > 0 else "−∞"
    return f"{v:.{digits}g}".replace("-", "−")


def _pct(x: float, digits: int = 2, sign: bool = True) -> str:
    if x is None or not math.isfinite(x):
        return "—"
    return (f"{x:+.{digits}f}" if sign else f"{x:.{digits}f}").replace("-", "−") + " %"


def _pval(p: float) -> str:
    if p is None or not math.isfinite(p):
        return "—"
    if p < 1e-4:
        return "&lt; 0.0001"
    return f"{p:.2g}"


def _json_safe(v: Any) -> Any:
    """JSON with no NaN/inf (browsers' JSON.parse rejects them): NaN -> null, inf -> "inf"."""
    if isinstance(v, Mapping):
        return {str(k): _json_safe(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_json_safe(x) for x in v]
    if isinstance(v, np.ndarray):
        return _json_safe(v.tolist())
    if isinstance(v, np.generic):
        return _json_safe(v.item())
    if isinstance(v, float) and not math.isfinite(v):
        return None if math.isnan(v) else ("inf" if v > 0 else "-inf")
    return v


def _script_json(obj: Any) -> str:
    """JSON safe inside <script>: '<', '>' and '&' escaped as unicode escapes."""
    text = json.dumps(_json_safe(obj), ensure_ascii=False, allow_nan=False, indent=None)
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def _img(png: bytes, alt: str) -> str:
    data = base64.b64encode(png).decode("ascii")
    return f'<img src="data:image/png;base64,{data}" alt="{_e(alt)}" loading="eager">'


def _figure_html(
    make: Callable[[], Any], alt: str, caption: str, *, dpi: float = 130
) -> tuple[str, bool]:
    """Render a figure into an <figure>; on failure, a visible note (the report still renders)."""
    from maglevid.plotting.diagnosis import figure_to_png

    try:
        fig = make()
        png = figure_to_png(fig, dpi=dpi)
    except Exception as exc:  # a figure must never cost the whole report
        logger.exception("report figure %r failed", alt)
        return (
            f'<p class="note warn">The figure "{_e(alt)}" could not be drawn: '
            f"{_e(type(exc).__name__)}: {_e(exc)}</p>",
            False,
        )
    return (
        f"<figure>{_img(png, alt)}<figcaption>{caption}</figcaption></figure>",
        True,
    )


def _na(text: str) -> str:
    return f'<p class="note">{_e(text)}</p>'


def _unit_html(unit: str) -> str:
    """A unit with its words as a tooltip (N·A⁻¹: "newton per ampere")."""
    words = UNIT_WORDS.get(unit)
    return f'<abbr title="{_e(words)}">{_e(unit)}</abbr>' if words else _e(unit)


def _label(name: str) -> str:
    info = PARAMETER_INFO.get(name)
    return f"{name} · {info[0]}" if info else name


# ------------------------------------------------------------------------- models
def _as_continuous(model: StateSpace | None) -> StateSpace | None:
    if model is None or not model.is_discrete:
        return model
    from maglevid.lti import undiscretize

    return undiscretize(model)


def _as_discrete(model: StateSpace, dt: float) -> StateSpace:
    return model if model.is_discrete else discretize(model, dt)


def _find_controller(d: Diagnosis, controller: Any) -> Any:
    """The explicit controller, else a ``loop``/``controller`` kept with the diagnosis."""
    if controller is not None:
        return controller
    places = [d.baseline] + ([d.identification.extras] if d.identification is not None else [])
    for place in places:
        if isinstance(place, Mapping):
            for key in ("loop", "controller"):
                if place.get(key) is not None:
                    return place[key]
    return None


def _closed_loops(
    d: Diagnosis, controller: Any
) -> tuple[tuple[StateSpace, StateSpace] | None, str]:
    """Closed loops of (baseline, identified) plant with the same controller, or why not."""
    spec = _find_controller(d, controller)
    if spec is None:
        return None, (
            "The diagnosis carries no controller, so only the open loop is shown "
            "(pass the recording's loop to the report, or keep it with the baseline as "
            "baseline['loop'], to see the closed-loop poles and responses)."
        )
    if d.baseline_model is None or d.identified_model is None:
        return None, "Closed loop not shown: a plant model is missing."
    dt = d.dt
    if dt is None:
        for m in (d.identified_model, d.baseline_model):
            if m.is_discrete:
                dt = m.dt
    if dt is None:
        return None, "Closed loop not shown: the control period dt is unknown."
    try:
        base_d = _as_discrete(d.baseline_model, dt)
        id_d = _as_discrete(d.identified_model, dt)
        K = controller_state_space(spec, plant=base_d)
        return (close_loop(base_d, K), close_loop(id_d, K)), ""
    except (MaglevidError, ValueError, np.linalg.LinAlgError) as exc:
        logger.warning("closed loop not computed: %s", exc)
        return None, f"Closed loop not shown: {exc}"


def _percentage(d: Diagnosis) -> tuple[np.ndarray, np.ndarray] | None:
    pi = d.percentage_index
    if pi is not None and "A_p" in pi and "B_p" in pi:
        return np.asarray(pi["A_p"], dtype=float), np.asarray(pi["B_p"], dtype=float)
    base, ident = _as_continuous(d.baseline_model), _as_continuous(d.identified_model)
    if base is None or ident is None or base.A.shape != ident.A.shape:
        return None
    # Models that went through undiscretize() carry ~1e-12 round-off where the
    # physics has zeros: 1e-10 of the largest element still counts as a zero.
    return (
        percentage_index(ident.A, base.A, zero_tol=ZERO_TOL),
        percentage_index(ident.B, base.B, zero_tol=ZERO_TOL),
    )


# ----------------------------------------------------------------------- sections
def _section(key: str, number: int, title: str, body: str, *, lead: str = "") -> str:
    lead_html = f'<p class="lead">{lead}</p>' if lead else ""
    return (
        f'<section id="{key}" class="card"><h2><span class="num">{number}</span>{_e(title)}'
        f"</h2>{lead_html}{body}</section>"
    )


def _verdict_banner(d: Diagnosis) -> str:
    color, label = VERDICT_STYLE[d.verdict_code]
    return (
        f'<div id="verdict-banner" class="banner" style="background:{color}" '
        f'data-verdict-code="{_e(d.verdict_code)}">'
        f'<div class="pill">{_e(label)}</div>'
        f'<h1 id="verdict-text">{_e(d.verdict)}</h1>{_resolution_list(d)}</div>'
    )


def _resolution_list(d: Diagnosis) -> str:
    """What would resolve the tolerance (an inconclusive verdict's way forward)."""
    if not d.resolution:
        return ""
    items = "".join(f"<li>{_e(u.get('advice', ''))}</li>" for u in d.resolution)
    return (
        '<div id="verdict-resolution"><b>The data cannot resolve the tolerance of every '
        f"parameter. What would:</b><ul>{items}</ul></div>"
    )


def _key_facts(d: Diagnosis) -> str:
    facts: list[tuple[str, str, str]] = []
    sig = d.significant_changes
    if d.changes:
        biggest = max(
            (c for c in d.changes if math.isfinite(c.change_percent)),
            key=lambda c: abs(c.change_percent),
            default=None,
        )
        if biggest is not None:
            lo = 100 * biggest.change_ci[0] / biggest.baseline
            hi = 100 * biggest.change_ci[1] / biggest.baseline
            lo, hi = min(lo, hi), max(lo, hi)
            facts.append(
                (
                    "Largest change (free estimate)",
                    f"{_e(biggest.name)} {_pct(biggest.change_percent, 1)}",
                    f"95 % {_e(biggest.interval_label)} {_pct(lo, 1)} … {_pct(hi, 1)}; "
                    f"{_e(biggest.status)}",
                )
            )
        facts.append(
            (
                "Significant changes",
                f"{len(sig)} of {len(d.changes)}",
                "significant statistically <em>and</em> beyond tolerance",
            )
        )
    if d.isolation is not None:
        b = d.isolation.best
        name = (
            ", ".join(f"{k} {_pct(v, 1)}" for k, v in b.changes_percent.items())
            if b.parameters
            else "no change"
        )
        only = f"fit with only {' and '.join(b.parameters)} changed; " if b.parameters else ""
        facts.append(
            (
                "Best explanation" if d.isolation.explained else "Closest explanation",
                _e(name),
                f"{_e(only)}χ² = {b.chi2:.3g}, {b.dof} dof, p = {_pval(b.p_value)}",
            )
        )
    n_fail = sum(not q.passed for q in d.quality)
    n_block = sum((not q.passed) and q.blocking for q in d.quality)
    if d.quality:
        facts.append(
            (
                "Data quality",
                f"{len(d.quality) - n_fail} of {len(d.quality)} passed",
                "all checks passed"
                if not n_fail
                else f"{n_block} blocking, {n_fail - n_block} advisory failed",
            )
        )
    if d.identification is not None:
        dt_txt = f", dt = {d.dt * 1e3:g} ms" if d.dt else ""
        facts.append(
            (
                "Data used",
                f"{d.identification.n_samples:,} periods",
                f"method {_e(d.method or d.identification.method)}{dt_txt}",
            )
        )
    cells = "".join(
        f'<div class="fact"><div class="fact-k">{k}</div><div class="fact-v">{v}</div>'
        f'<div class="fact-s">{s}</div></div>'
        for k, v, s in facts
    )
    return f'<div class="facts">{cells}</div>' if cells else ""


def _isolation_table(d: Diagnosis) -> str:
    iso = d.isolation
    if iso is None:
        return ""
    rows: list[FaultHypothesis] = [iso.no_change, *iso.candidates[:4]]
    # A levitator's isolation reads the pole, equilibrium currents and coil circuit
    # (diagnose/levitator.py), the AMB's the v1..v9 of eq. (4).
    space = "observation" if getattr(iso, "observations", None) is not None else "v_i"
    obs = getattr(iso, "observations", None)
    seen_what = (
        "the identified v1..v9"
        if obs is None
        else "the pole and the equilibrium currents"
        + (" and the coil circuit" if obs.electrical is not None else "")
        + (" and the command's level" if getattr(obs, "commands", ()) else "")
    )
    seen: set[tuple[str, ...]] = set()
    body = []
    for h in rows:
        if h.parameters in seen:
            continue
        seen.add(h.parameters)
        fits = h.p_value >= iso.alpha
        best = h is iso.best or h.parameters == iso.best.parameters
        name = " + ".join(h.parameters) if h.parameters else "no change"
        what = h.describe() if h.parameters else f"every {space} as in the baseline"
        cls = ' class="best"' if best and iso.explained else ""
        body.append(
            f"<tr{cls}><td><b>{_e(name)}</b></td><td>{_e(what)}</td>"
            f'<td class="r">{h.chi2:.4g}</td><td class="r">{h.dof}</td>'
            f'<td class="r">{_pval(h.p_value)}</td>'
            f"<td>{'<span class=badge-ok>fits</span>' if fits else 'rejected'}</td></tr>"
        )
    tie = ""
    if iso.indistinguishable:
        names = ", ".join(" + ".join(h.parameters) for h in iso.indistinguishable)
        tie = (
            f'<p class="note warn">Indistinguishable from the best explanation with these data: '
            f"{_e(names)}.</p>"
        )
    return (
        f"<h3>Which physical cause explains {_e(seen_what)}</h3>"
        f'<p class="small">Each hypothesis "only this changed" is fitted by weighted least '
        f"squares ({_e(space)}s) and judged by its χ² (accepted when p ≥ α = {iso.alpha:g}), "
        + (
            f"with a model error of ±{100 * iso.model_error:.2g} % of each {space} "
            "beside the noise"
            if iso.model_error > 0
            else "with no model-error allowance beside the noise"
        )
        + (
            f", linearised at the recording's {_e(iso.operating_point.source)}"
            if iso.operating_point is not None
            else ""
        )
        + ". Its fitted change is the verdict's number; the parameter table holds the free "
        "estimates (every parameter fitted at once, the mass and bias current at the "
        "baseline's: a change of m scales every coil and amplifier parameter alike).</p>"
        '<table class="data"><thead><tr><th>hypothesis</th><th>fitted change</th>'
        '<th class="r">χ²</th><th class="r">dof</th><th class="r">p</th><th></th></tr>'
        f"</thead><tbody>{''.join(body)}</tbody></table>{tie}"
    )


def _verdict_section(d: Diagnosis) -> str:
    reasons = "".join(f"<li>{_e(r)}</li>" for r in d.reasons)
    reasons_html = f'<ul class="reasons">{reasons}</ul>' if reasons else ""
    failed = [q for q in d.quality if not q.passed and q.blocking]
    blocked = ""
    if not d.can_diagnose and failed:
        names = ", ".join(q.name for q in failed)
        blocked = (
            f'<div class="callout bad"><b>The data-quality checks stopped the diagnosis</b>: '
            f"{len(failed)} blocking check(s) failed ({_e(names)}). Nothing was identified; "
            'see <a href="#quality">section 7</a> for every check with its value and '
            "threshold.</div>"
        )
    meta = []
    for k, v in (
        ("machine", d.machine),
        ("recording", d.recording),
        ("diagnosed", d.created_at),
        ("baseline", d.baseline.get("source") if isinstance(d.baseline, Mapping) else None),
    ):
        if v:
            meta.append(f"<span><b>{k}</b> {_e(v)}</span>")
    return (
        f'<section id="verdict" class="verdict">{_verdict_banner(d)}'
        f'<div class="verdict-body"><div class="meta">{"".join(meta)}</div>'
        f"{_key_facts(d)}<h3>Why</h3>{reasons_html}{blocked}{_isolation_table(d)}</div>"
        "</section>"
    )


def _parameters_section(d: Diagnosis) -> str:
    if not d.changes:
        return _section(
            "parameters",
            2,
            "Identified vs baseline parameters",
            _na("No parameters were identified, so nothing is compared with the baseline."),
        )
    from maglevid.plotting.diagnosis import plot_parameter_changes

    joint = max(c.joint_over for c in d.changes)
    together = (
        f" The intervals hold for all {joint} parameters at once (Bonferroni), so a healthy "
        "machine shows none changed by chance."
        if joint > 1
        else ""
    )
    fig, _ = _figure_html(
        lambda: plot_parameter_changes(d.changes, labels={c.name: c.name for c in d.changes}),
        "Forest plot of the change of every parameter from its baseline",
        "Change of each parameter from the baseline, in % of the baseline, with the 95 % "
        "confidence interval of the change (identified and baseline uncertainty combined). "
        "The shaded band is the engineering tolerance. A parameter is <b>changed</b> only "
        "when its change is significant statistically <em>and</em> exceeds the tolerance."
        + together,
    )
    header = max(d.changes, key=lambda c: c.joint_over).interval_label
    rows = []
    for c in d.changes:
        desc, unit = PARAMETER_INFO.get(c.name, ("", ""))
        b = c.baseline
        if b != 0:
            lo, hi = sorted((100 * c.change_ci[0] / b, 100 * c.change_ci[1] / b))
            ci = f"{_pct(lo)} … {_pct(hi)}"
            if joint > 1 and c.joint_over == 1:  # the verdict's cause: its own interval
                ci += "<div class=small>on its own (the verdict's cause)</div>"
        else:
            ci = "—"
        base_se = f" ± {_num(c.baseline_std_error, 2)}" if c.baseline_std_error > 0 else ""
        cls = ' class="hl"' if c.significant else ""
        rows.append(
            f"<tr{cls}><td><b>{_e(c.name)}</b><div class=small>{_e(desc)}</div></td>"
            f"<td>{_unit_html(unit)}</td><td class=r>{_num(b)}{base_se}</td>"
            f"<td class=r>{_num(c.estimate)} ± {_num(c.std_error, 2)}</td>"
            f"<td class=r><b>{_pct(c.change_percent)}</b></td><td class=r>{ci}</td>"
            f"<td class=r>±{100 * c.tolerance:g} %</td>"
            f'<td><span class="status {_STATUS_CLASS.get(c.status, "")}">{_e(c.status)}'
            "</span></td></tr>"
        )
    table = (
        '<table class="data"><thead><tr><th>parameter</th><th>unit</th>'
        '<th class="r">baseline</th><th class="r">identified ± s.e.</th>'
        f'<th class="r">change</th><th class="r">95 % {_e(header)} of '
        'change</th><th class="r">tolerance</th><th>status</th></tr></thead>'
        f"<tbody>{''.join(rows)}</tbody></table>"
    )
    return _section("parameters", 2, "Identified vs baseline parameters", fig + table)


def _pi_color(value: float, scale: float) -> tuple[str, str]:
    """Diverging blue-white-red background for a percentage; text colour for contrast."""
    t = max(-1.0, min(1.0, value / scale))
    white = np.array([255.0, 255.0, 255.0])
    end = np.array([178.0, 24.0, 43.0]) if t > 0 else np.array([33.0, 102.0, 172.0])
    rgb = white + abs(t) * (end - white)
    r, g, b = (round(x) for x in rgb)
    return f"rgb({r},{g},{b})", ("#ffffff" if abs(t) > 0.55 else "#111827")


def _pi_labels(shape_a: tuple[int, ...], shape_b: tuple[int, ...]):
    """Which v_i sits in each cell (the AMB layout, eq. (4)); None for other models."""
    if shape_a != (4, 4) or shape_b != (4, 2):
        return None, None
    A, B = amb_matrices(np.arange(2.0, 11.0))  # v_i -> i + 1, the structural 1 stays 1

    def lab(M):
        out = np.full(M.shape, "", dtype=object)
        for idx, val in np.ndenumerate(np.abs(M)):
            if val >= 2:
                out[idx] = f"v{int(val) - 1}"
            elif val == 1:
                out[idx] = "1"
        return out

    return lab(A), lab(B)


def _pi_table(
    M: np.ndarray, name: str, rows: Sequence[str], cols: Sequence[str], labels, scale: float
) -> str:
    head = "".join(f"<th>{_e(c)}</th>" for c in cols)
    body = []
    for i in range(M.shape[0]):
        cells = []
        for j in range(M.shape[1]):
            v = M[i, j]
            lab = labels[i, j] if labels is not None else ""
            tag = f'<span class="vtag">{_e(lab)}</span>' if lab else ""
            if not math.isfinite(v):
                cells.append('<td class="x" title="structural zero in the baseline">×</td>')
            else:
                bg, fg = _pi_color(v, scale)
                text = f"{v:+.4f}".replace("-", "−")
                cells.append(
                    f'<td style="background:{bg};color:{fg}" title="{_e(lab)}">{tag}{text}</td>'
                )
        body.append(f"<tr><th>{_e(rows[i])}</th>{''.join(cells)}</tr>")
    return (
        f'<div class="pi"><div class="pi-name">{name}</div><table class="pi-table">'
        f"<thead><tr><th></th>{head}</tr></thead><tbody>{''.join(body)}</tbody></table></div>"
    )


def _percentage_section(d: Diagnosis) -> str:
    title = "Matrix percentage index A_p, B_p"
    pi = _percentage(d)
    if pi is None:
        return _section(
            "percentage",
            3,
            title,
            _na("Not available: the identified and baseline models are needed."),
        )
    Ap, Bp = pi
    tol = max((c.tolerance for c in d.changes), default=DEFAULT_TOLERANCE)
    scale = max(200.0 * tol, 1e-9)
    base = d.baseline_model
    states = (base.state_names if base is not None else ()) or tuple(
        f"x{i + 1}" for i in range(Ap.shape[0])
    )
    inputs = (base.input_names if base is not None else ()) or tuple(
        f"u{i + 1}" for i in range(Bp.shape[1])
    )
    la, lb = _pi_labels(Ap.shape, Bp.shape)
    nice = {"dx": "ẋ"}
    srows = [nice.get(s, s) for s in states]
    tables = _pi_table(Ap, "A<sub>p</sub> [%]", srows, srows, la, scale) + _pi_table(
        Bp, "B<sub>p</sub> [%]", srows, list(inputs), lb, scale
    )
    legend = (
        '<div class="pi-legend"><span>−' + f"{scale:g} %</span>"
        '<div class="grad"></div><span>+' + f"{scale:g} %</span>"
        f'<span class="small">colour saturates at twice the tolerance (±{scale:g} %); '
        "× = structural zero of the baseline (no ratio)</span></div>"
    )
    finite = np.concatenate([Ap[np.isfinite(Ap)], Bp[np.isfinite(Bp)]])
    summary = ""
    if finite.size:
        k = int(np.argmax(np.abs(finite)))
        summary = f"Largest element: <b>{_pct(float(finite[k]), 2)}</b>. "
    lead = (
        "Gosiewski &amp; Paszowski's matrix percentage indexes, "
        "A<sub>p</sub> = (A<sub>identified</sub> − A<sub>baseline</sub>) / "
        "A<sub>baseline</sub> · 100 % by array division (continuous-time A<sub>c</sub>, "
        "B<sub>c</sub> in physical coordinates), in the paper's 4×4 and 4×2 layout. " + summary
    )
    return _section(
        "percentage", 3, title, f'<div class="pi-wrap">{tables}</div>{legend}', lead=lead
    )


def _pole_table(base: StateSpace, ident: StateSpace, dt: float | None) -> str:
    pb = np.linalg.eigvals(base.A) if not base.is_discrete else np.log(base.poles()) / base.dt
    pi_ = np.linalg.eigvals(ident.A) if not ident.is_discrete else np.log(ident.poles()) / ident.dt
    cost = np.abs(pb[:, None] - pi_[None, :])
    r, c = linear_sum_assignment(cost)
    order = np.argsort(pb[r].real)
    rows = []
    for k in order:
        b, i = pb[r[k]], pi_[c[k]]
        if b.imag < -1e-9 * abs(b):
            continue  # one row per conjugate pair

        def s(z: complex) -> str:
            if abs(z.imag) <= 1e-9 * max(abs(z), 1.0):
                return _num(z.real, 6)
            return f"{_num(z.real, 6)} ± {_num(abs(z.imag), 5)}j"

        wn = abs(i) / (2 * np.pi)
        complex_pair = abs(i.imag) > 1e-9 * max(abs(i), 1.0)
        zeta = -i.real / abs(i) if complex_pair else float("nan")
        rel = 100 * abs(i - b) / abs(b) if abs(b) > 0 else float("nan")
        zi = f"{_num(abs(np.exp(i * dt)), 6)}" if dt else "—"
        if i.real > 0 and b.real > 0:
            stab = (
                '<span class="status st-unchanged" title="a magnetic bearing is open-loop '
                'unstable by physics (negative stiffness of the magnets)">unstable: expected '
                "for a magnetic bearing</span>"
            )
        elif i.real > 0:
            stab = '<span class="status st-changed">unstable (the baseline is not)</span>'
        else:
            stab = ""
        rows.append(
            f"<tr><td class=r>{s(b)}</td><td class=r>{s(i)}</td><td class=r>{_pct(rel, 2, False)}"
            f"</td><td class=r>{_num(wn, 4)}</td><td class=r>{_num(zeta, 3)}</td>"
            f"<td class=r>{zi}</td><td>{stab}</td></tr>"
        )
    return (
        '<table class="data"><thead><tr><th class="r">baseline s [rad/s]</th>'
        '<th class="r">identified s [rad/s]</th><th class="r">moved</th>'
        '<th class="r">|s|/2π [Hz]</th><th class="r">damping ζ</th>'
        '<th class="r">identified |z|</th><th></th></tr></thead>'
        f"<tbody>{''.join(rows)}</tbody></table>"
    )


def _poles_section(d: Diagnosis, loops, loop_note: str) -> str:
    title = "Pole maps"
    base, ident = d.baseline_model, d.identified_model
    if base is None or ident is None:
        return _section("poles", 4, title, _na("Not available: no identified model."))
    from maglevid.plotting.diagnosis import plot_pole_maps

    fig, _ = _figure_html(
        lambda: plot_pole_maps(base, ident, dt=d.dt, closed_loop=loops),
        "Pole maps in the s-plane and z-plane, open and closed loop",
        "Hollow grey circles: baseline plant; blue crosses: identified plant"
        + (
            "; purple squares / green pluses: the closed loop of the same controller around "
            "the baseline / identified plant"
            if loops is not None
            else ""
        )
        + ". Discrete poles are those of the zero-order-hold sampling, z = exp(s·dt).",
    )
    callout = ""
    if loops is not None:
        rb = float(np.max(np.abs(loops[0].poles())))
        ri = float(np.max(np.abs(loops[1].poles())))
        ok = ri < 1.0
        callout = (
            f'<div class="callout {"good" if ok else "bad"}"><b>Closed loop with the identified '
            f"plant is {'stable' if ok else 'UNSTABLE'}</b>: largest |z| = {ri:.5f} "
            f"(baseline plant: {rb:.5f}; 1 is the stability limit).</div>"
        )
    note = f'<p class="note">{_e(loop_note)}</p>' if loop_note else ""
    return _section(
        "poles",
        4,
        title,
        callout + note + fig + "<h3>Open-loop poles, paired</h3>" + _pole_table(base, ident, d.dt),
    )


def _responses_section(d: Diagnosis, loops) -> str:
    title = "Impulse and frequency responses"
    base, ident = _as_continuous(d.baseline_model), _as_continuous(d.identified_model)
    if base is None or ident is None:
        return _section("responses", 5, title, _na("Not available: no identified model."))
    from maglevid.plotting.diagnosis import (
        impulse_horizon,
        plot_frequency_responses,
        plot_impulse_responses,
    )

    amb = base.output_names[:1] == ("x",)
    unit = (1e6, "µm") if amb else (1.0, "")
    out_label = "displacement x" if amb else (base.output_names or ("y1",))[0]
    horizon = impulse_horizon(base)
    imp, _ = _figure_html(
        lambda: plot_impulse_responses(
            base,
            ident,
            dt=d.dt,
            output=0,
            output_label=out_label,
            output_unit=unit,
            closed_loop=loops,
        ),
        "Impulse responses of the displacement to each input, identified vs baseline",
        f"Response of the {_e(out_label)} to a unit pulse (1 V for one control period) on each "
        f"input, as in Gosiewski &amp; Paszowski Fig. 3"
        + (" (open loop) and Fig. 4 (closed loop, pulse on the excitation r)" if loops else "")
        + f". The open-loop bearing is unstable: its response grows without bound, so only "
        f"the first {horizon * 1e3:.1f} ms are shown (until the unstable mode has grown "
        "e<sup>4</sup> ≈ 55-fold).",
    )
    ou = ("m", "A", "A") if amb and base.ny == 3 else None
    iu = ("V",) * base.nu if amb else None
    bode, _ = _figure_html(
        lambda: plot_frequency_responses(base, ident, dt=d.dt, output_units=ou, input_units=iu),
        "Bode magnitude and phase, identified vs baseline",
        "Transfer functions C(jωI − A)<sup>−1</sup>B of the continuous open-loop models "
        "(an unstable plant has no measurable open-loop steady state; this is the model's "
        "frequency response) up to the Nyquist frequency of the control period.",
    )
    return _section(
        "responses",
        5,
        title,
        "<h3>Impulse responses</h3>" + imp + "<h3>Frequency responses</h3>" + bode,
    )


def _trend_rate(
    name: str, entry: Mapping[str, Any], drift: Mapping[str, Any], baseline: float | None
) -> str:
    """The fitted slope in words: per day (and % of baseline per 30 days) for dated series."""
    from maglevid.plotting.diagnosis import drift_crossing, drift_line

    unit = PARAMETER_INFO.get(name, ("", ""))[1] or str(entry.get("unit") or "")
    times = list(entry.get("time", ()))
    dated = bool(times) and all(isinstance(t, (str, datetime)) for t in times)
    fitted = drift_line(drift, dated=dated)
    if fitted is None:
        return "—"
    slope = fitted[0]
    if not dated:
        per = _e(entry.get("time_unit", "time unit"))
        return f"{_num(slope, 3)} {_e(unit)}/{per}"
    text = f"{_num(slope * 86400.0, 3)} {_e(unit)}/day"
    base = entry.get("baseline", baseline)
    if isinstance(base, (int, float)) and base:
        text += f" ({_pct(100.0 * slope * 30 * 86400.0 / base)} of baseline per 30 days)"
    cross = drift_crossing(drift)
    if cross is not None and math.isfinite(cross) and drift.get("drifting"):
        when = datetime.fromtimestamp(cross, tz=timezone.utc).strftime("%Y-%m-%d")
        text += f"; leaves the tolerance band around {when}"
    return text


def _trends_section(d: Diagnosis, trends: Mapping[str, Mapping[str, Any]] | None) -> str:
    title = "Parameter trends"
    if not trends:
        return _section("trends", 6, title, _na("No parameter history was given for this report."))
    from maglevid.plotting.diagnosis import plot_trends

    baselines = {c.name: c.baseline for c in d.changes}
    tolerances = {c.name: c.tolerance for c in d.changes}
    labels = {
        k: (f"{k} [{PARAMETER_INFO[k][1]}] · {PARAMETER_INFO[k][0]}" if k in PARAMETER_INFO else k)
        for k in trends
    }
    trends = _ordered_trends(d, trends)
    groups = [
        ("Physical parameters", {k: v for k, v in trends.items() if not _is_v(k)}),
        ("Model elements v1..v9 (Gosiewski & Paszowski eq. (4))", {
            k: v for k, v in trends.items() if _is_v(k)
        }),
    ]  # fmt: skip
    groups = [(head, group) for head, group in groups if group]
    figs = []
    for head, group in groups:
        fig, _ = _figure_html(
            lambda group=group: plot_trends(
                group, baselines=baselines, tolerances=tolerances, labels=labels
            ),
            f"Trend of each parameter over time: {head}",
            "Each recording's estimate with its 95 % confidence interval, the baseline "
            "(dashed), the tolerance band (shaded) and the drift test's fitted line and "
            "verdict. Changed and drifting parameters come first.",
        )
        figs.append((f"<h3>{_e(head)}</h3>" if len(groups) > 1 else "") + fig)
    rows = []
    for name, entry in trends.items():
        drift = entry.get("drift") or {}
        p = drift.get("p_value")
        verdict = drift.get("verdict") or (
            ("drifting" if drift.get("drifting") else "no significant drift")
            if "drifting" in drift
            else "—"
        )
        step = entry.get("step")
        if step:
            pct = step.get("percent")
            verdict = f"step at {str(step.get('at') or '?')[:10]}" + (
                f" ({_pct(pct, 1)})" if isinstance(pct, (int, float)) else ""
            )
            p = step.get("p_value")
        rate = (
            f"mean {_num(step['before'])} → {_num(step['after'])}"
            if step
            else _trend_rate(name, entry, drift, baselines.get(name))
        )
        values = list(entry.get("value", ()))
        ses = list(entry.get("std_error") or [])
        latest = _num(values[-1]) if values else "—"
        if values and len(ses) == len(values):
            latest += f" ± {_num(ses[-1], 2)}"
        rows.append(
            f"<tr><td><b>{_e(name)}</b></td><td class=r>{len(values)}</td>"
            f"<td class=r>{latest}</td><td>{_e(verdict)}</td>"
            f"<td class=r>{_pval(p) if isinstance(p, (int, float)) else '—'}</td>"
            f"<td>{rate}</td></tr>"
        )
    table = (
        '<table class="data"><thead><tr><th>parameter</th><th class="r">points</th>'
        '<th class="r">latest ± s.e.</th><th>drift test</th><th class="r">p</th>'
        "<th>trend</th></tr></thead>"
        f"<tbody>{''.join(rows)}</tbody></table>"
    )
    return _section("trends", 6, title, "".join(figs) + table)


def _is_v(name: str) -> bool:
    return name[:1] == "v" and name[1:].isdigit()


def _ordered_trends(
    d: Diagnosis, trends: Mapping[str, Mapping[str, Any]]
) -> dict[str, Mapping[str, Any]]:
    """Changed (this diagnosis) and drifting parameters first, then the others, in order."""
    changed = {c.name for c in d.significant_changes}

    def flagged(name: str) -> bool:
        entry = trends[name]
        return name in changed or bool(
            entry.get("step") or (entry.get("drift") or {}).get("drifting")
        )

    return {k: trends[k] for k in sorted(trends, key=lambda k: not flagged(k))}


def _quality_section(d: Diagnosis) -> str:
    if not d.quality:
        return _section("quality", 7, "Data quality", _na("No quality checks were recorded."))
    rows = []
    for q in d.quality:
        if q.passed:
            badge = '<span class="status st-pass">pass</span>'
        elif q.blocking:
            badge = '<span class="status st-changed">fail</span>'
        else:
            badge = '<span class="status st-unresolved">warning</span>'
        kind = "blocking" if q.blocking else "advisory"
        rows.append(
            f"<tr><td>{badge}</td><td><b>{_e(q.name)}</b></td><td class=r>{_num(q.value)}</td>"
            f"<td class=r>{_num(q.threshold)}</td><td>{_e(q.message)}</td>"
            f'<td class="small">{kind}</td></tr>'
        )
    n_fail = sum(not q.passed for q in d.quality)
    lead = (
        "Every check passed."
        if not n_fail
        else f"{n_fail} of {len(d.quality)} checks did not pass. A failed <em>blocking</em> "
        "check stops the diagnosis; an advisory one is reported and the diagnosis goes on."
    )
    table = (
        '<table class="data"><thead><tr><th></th><th>check</th><th class="r">value</th>'
        '<th class="r">threshold</th><th>what it means</th><th></th></tr></thead>'
        f"<tbody>{''.join(rows)}</tbody></table>"
    )
    return _section("quality", 7, "Data quality", table, lead=lead)


def _kv_table(items: Sequence[tuple[str, Any]]) -> str:
    rows = "".join(
        f"<tr><th>{_e(k)}</th><td>{_e(v) if not isinstance(v, float) else _num(v, 6)}</td></tr>"
        for k, v in items
    )
    return f'<table class="kv">{rows}</table>'


def _matrix_html(M: np.ndarray) -> str:
    rows = "".join("<tr>" + "".join(f"<td>{_num(x, 6)}</td>" for x in row) + "</tr>" for row in M)
    return f'<table class="matrix">{rows}</table>'


#: Words for the fit diagnostics of the identification methods.
_FIT_WORDS = {
    "one_step_fit_percent": "one-step prediction fit of {} [%]",
    "intersample_fit_percent": "inter-sample fit of {} [%]",
    "structure_residual": "departure from the structure of eq. (4) (relative)",
    "regression_condition": "condition number of the regression",
    "sigma_w": "noise standard deviation",
}


def _fit_label(key: str) -> str:
    """``one_step_fit_percent_x`` -> "one-step prediction fit of x [%]"."""
    for stem, words in _FIT_WORDS.items():
        if key == stem:
            return words.format("all outputs") if "{}" in words else words
        if key.startswith(stem + "_") and "{}" in words:
            channel = key[len(stem) + 1 :]
            return words.format("the worst output" if channel == "min" else channel)
    return key.replace("_", " ")


def _method_section(d: Diagnosis, loop_note: str) -> str:
    ident = d.identification
    parts = []
    if d.method or ident is not None:
        parts.append(
            f"<p><b>Method:</b> {_e(d.method or ident.method)}"
            + (f" — {_e(d.method_reason)}" if d.method_reason else "")
            + "</p>"
        )
    items: list[tuple[str, Any]] = []
    if ident is not None:
        items.append(("samples (control periods)", f"{ident.n_samples:,}"))
        items.extend(
            (f"option {k}", v)
            for k, v in ident.options.items()
            if v is not None and not isinstance(v, Mapping)
        )
        items.extend((_fit_label(k), float(v)) for k, v in ident.fit.items())
    if d.dt:
        items.append(("control period dt [s]", float(d.dt)))
    if d.isolation is not None:
        items.append(("isolation significance α", float(d.isolation.alpha)))
    if isinstance(d.baseline, Mapping) and d.baseline.get("source"):
        items.append(("baseline", d.baseline["source"]))
    if d.recording_hash:
        items.append(("recording hash", d.recording_hash))
    if items:
        parts.append(_kv_table(items))
    # Each note once (the diagnosis repeats some of the identification's); the
    # loop note is shown with the pole maps it explains.
    notes = list(dict.fromkeys([*d.notes, *(ident.notes if ident is not None else ())]))
    notes = [n for n in notes if n != loop_note]
    if notes:
        parts.append("<h3>Notes</h3><ul>" + "".join(f"<li>{_e(n)}</li>" for n in notes) + "</ul>")
    base, idm = _as_continuous(d.baseline_model), _as_continuous(d.identified_model)
    if base is not None and idm is not None:
        parts.append(
            "<details><summary>Continuous-time matrices A<sub>c</sub>, B<sub>c</sub> "
            "(identified and baseline)</summary><div class=mats>"
            f"<div><b>A<sub>c</sub> identified</b>{_matrix_html(idm.A)}</div>"
            f"<div><b>B<sub>c</sub> identified</b>{_matrix_html(idm.B)}</div>"
            f"<div><b>A<sub>c</sub> baseline</b>{_matrix_html(base.A)}</div>"
            f"<div><b>B<sub>c</sub> baseline</b>{_matrix_html(base.B)}</div></div></details>"
        )
    parts.append(
        '<p class="small">How to read this report: a parameter counts as <b>changed</b> when '
        "its change is significant twice over — outside the 95 % confidence interval "
        "<em>and</em> beyond the engineering tolerance. The fault isolation then asks which "
        "single physical cause (or pair) reproduces all nine identified elements v1..v9 "
        "(Gosiewski &amp; Paszowski eq. (4)) within their uncertainty. The machine-readable "
        'content of this report is embedded as JSON (<code>id="diagnosis-data"</code>).</p>'
    )
    return _section("method", 8, "Method and notes", "".join(parts))


# ---------------------------------------------------------------------------- CSS
_CSS = """
:root{--ink:#111827;--muted:#6b7280;--line:#e5e7eb;--bg:#f3f4f6;--card:#fff;}
*{box-sizing:border-box}
html{-webkit-text-size-adjust:100%}
body{margin:0;background:var(--bg);color:var(--ink);
 font:15px/1.5 system-ui,-apple-system,"Segoe UI",Roboto,"Helvetica Neue",Arial,
 "DejaVu Sans",sans-serif}
.top{background:#111827;color:#e5e7eb;padding:10px 0;font-size:13px}
.wrap{max-width:1160px;margin:0 auto;padding:0 20px}
.top .wrap{display:flex;justify-content:space-between;gap:16px;flex-wrap:wrap}
.top b{color:#fff;letter-spacing:.02em}
main.wrap{padding-top:20px;padding-bottom:24px}
.card,.verdict{background:var(--card);border:1px solid var(--line);border-radius:10px;
 margin:0 0 18px;box-shadow:0 1px 2px rgba(0,0,0,.04)}
.card{padding:18px 22px}
.verdict{overflow:hidden}
.banner{color:#fff;padding:22px 26px 20px}
.banner h1{margin:8px 0 0;font-size:27px;line-height:1.25;font-weight:700}
#verdict-resolution{margin-top:10px;font-size:14px}
#verdict-resolution ul{margin:4px 0 0 18px;padding:0}
.pill{display:inline-block;background:rgba(255,255,255,.2);border:1px solid
 rgba(255,255,255,.55);border-radius:999px;padding:2px 12px;font-size:12.5px;
 font-weight:700;letter-spacing:.08em;text-transform:uppercase}
.verdict-body{padding:14px 26px 20px}
.meta{display:flex;flex-wrap:wrap;gap:6px 22px;color:var(--muted);font-size:13px;
 margin-bottom:12px}
.meta b{color:var(--ink);font-weight:600;margin-right:4px}
.facts{display:grid;grid-template-columns:repeat(auto-fit,minmax(170px,1fr));gap:10px;
 margin:6px 0 8px}
.fact{border:1px solid var(--line);border-radius:8px;padding:9px 12px;background:#fafafa}
.fact-k{font-size:11.5px;text-transform:uppercase;letter-spacing:.06em;color:var(--muted)}
.fact-v{font-size:19px;font-weight:700;margin:2px 0}
.fact-s{font-size:12.5px;color:var(--muted)}
h2{font-size:19px;margin:0 0 10px;display:flex;align-items:center;gap:10px}
h2 .num{display:inline-flex;align-items:center;justify-content:center;min-width:26px;
 height:26px;border-radius:13px;padding:0 7px;background:#111827;color:#fff;font-size:13px}
h3{font-size:15px;margin:18px 0 6px}
.lead{color:#374151;margin:0 0 12px}
.reasons{margin:4px 0 8px;padding-left:20px}
.reasons li{margin:3px 0}
nav.toc{display:flex;flex-wrap:wrap;gap:6px;margin:0 0 18px}
nav.toc a{background:#fff;border:1px solid var(--line);border-radius:999px;padding:3px 12px;
 color:#1f2937;text-decoration:none;font-size:13px}
nav.toc a:hover{border-color:#9ca3af}
figure{margin:6px 0 10px}
figure img{display:block;width:100%;height:auto;border:1px solid var(--line);border-radius:6px}
figcaption{font-size:13px;color:#4b5563;margin-top:6px}
table{border-collapse:collapse}
table.data{width:100%;font-size:13.5px;margin:8px 0}
table.data th{text-align:left;font-weight:600;color:#374151;border-bottom:2px solid var(--line);
 padding:6px 8px;white-space:nowrap}
table.data td{border-bottom:1px solid var(--line);padding:5px 8px;vertical-align:top}
table.data tr.hl td{background:#fef2f2}
table.data tr.best td{background:#ecfdf5}
.r{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
table.data th.r{text-align:right}
.small{font-size:12.5px;color:var(--muted)}
.status{display:inline-block;border-radius:4px;padding:0 7px;font-size:12px;font-weight:600;
 white-space:nowrap}
.st-changed{background:#fee2e2;color:#991b1b}
.st-within{background:#cffafe;color:#155e75}
.st-unresolved{background:#ffedd5;color:#9a3412}
.st-unchanged{background:#f3f4f6;color:#374151}
.st-pass{background:#dcfce7;color:#166534}
.badge-ok{background:#dcfce7;color:#166534;border-radius:4px;padding:0 7px;font-size:12px;
 font-weight:600}
.note{background:#f9fafb;border-left:3px solid #9ca3af;padding:8px 12px;margin:8px 0;
 color:#374151;font-size:14px}
.note.warn{border-left-color:#d97706;background:#fffbeb}
.callout{border-radius:8px;padding:10px 14px;margin:8px 0 12px;font-size:14px}
.callout.good{background:#ecfdf5;border:1px solid #a7f3d0}
.callout.bad{background:#fef2f2;border:1px solid #fecaca}
.callout ul{margin:6px 0}
.pi-wrap{display:flex;flex-wrap:wrap;gap:28px;align-items:flex-start}
.pi-name{font-weight:700;margin-bottom:4px}
.pi-table{font-variant-numeric:tabular-nums;font-size:14px}
.pi-table th{padding:4px 8px;color:var(--muted);font-weight:600}
.pi-table td{width:104px;height:46px;text-align:center;border:1px solid #fff;
 position:relative;padding:14px 6px 4px}
.pi-table td.x{background:#f3f4f6;color:#9ca3af;font-size:18px;padding:4px}
.vtag{position:absolute;top:2px;left:5px;font-size:10.5px;opacity:.8}
.pi-legend{display:flex;align-items:center;gap:8px;margin-top:12px;font-size:13px;
 flex-wrap:wrap}
.pi-legend .grad{width:220px;height:12px;border-radius:3px;
 background:linear-gradient(90deg,rgb(33,102,172),#fff,rgb(178,24,43));border:1px solid #d1d5db}
table.kv{font-size:13.5px;margin:6px 0}
table.kv th{text-align:left;color:#374151;font-weight:600;padding:3px 16px 3px 0;
 vertical-align:top}
table.kv td{padding:3px 0;font-variant-numeric:tabular-nums}
details{margin:10px 0}
summary{cursor:pointer;font-weight:600}
.mats{display:flex;flex-wrap:wrap;gap:18px;margin-top:8px}
table.matrix td{padding:2px 8px;font-size:12.5px;text-align:right;
 font-variant-numeric:tabular-nums;border-left:1px solid var(--line)}
footer{color:var(--muted);font-size:12.5px;padding:6px 0 28px}
footer .wrap{display:flex;justify-content:space-between;flex-wrap:wrap;gap:10px}
@media print{body{background:#fff}.card,.verdict{box-shadow:none;break-inside:avoid}
 nav.toc{display:none}}
"""

# Marks the page once every image has decoded and the JSON parses; the browser
# test reads these attributes. Nothing else runs; the report works without it.
_SCRIPT = """
(function(){
  function check(){
    var imgs=document.images, ok=0;
    for(var i=0;i<imgs.length;i++){ if(imgs[i].complete&&imgs[i].naturalWidth>0){ok++;} }
    document.body.dataset.imagesTotal=String(imgs.length);
    document.body.dataset.imagesDecoded=String(ok);
    document.body.dataset.imagesOk=String(ok===imgs.length);
    var data=JSON.parse(document.getElementById('diagnosis-data').textContent);
    document.body.dataset.dataOk=String(data.format==='maglevid-diagnosis');
  }
  if(document.readyState==='complete'){check();}else{window.addEventListener('load',check);}
})();
"""


# --------------------------------------------------------------------------- public
def report_panels(d: Diagnosis) -> tuple[str, ...]:
    """The section ids to show: the diagnosis' plant kind's ``report_panels`` (every
    section when the kind is not stated or not registered, e.g. an older stored one)."""
    from maglevid.plants import KINDS

    kind = KINDS.get(d.plant_kind) if d.plant_kind else None
    panels = tuple(getattr(kind, "report_panels", ()) or ())
    return ("verdict", *panels) if panels else tuple(k for k, _ in _SECTIONS)


def render_report(
    diagnosis: Diagnosis,
    *,
    trends: Mapping[str, Mapping[str, Any]] | None = None,
    title: str | None = None,
    controller: Any = None,
    generated_at: datetime | None = None,
) -> str:
    """The diagnosis report as one self-contained HTML string.

    Parameters
    ----------
    diagnosis : Diagnosis
        What to report (any verdict, ``cannot_diagnose`` included).
    trends : mapping, optional
        Parameter histories as plain data,
        ``{name: {"time": [...], "value": [...], "std_error": [...], "drift": {...}}}``:
        times as ISO 8601 strings or numbers, ``std_error`` optional, ``drift``
        optional (the ``to_dict()`` of a drift test: ``drifting``/``verdict``,
        ``p_value``, and ``slope``, ``t_ref``, ``value_at_ref`` for the fitted
        line; times in seconds since 1970 UTC for dated histories). Optional
        ``baseline`` and relative ``tolerance`` per entry. See
        :func:`maglevid.plotting.diagnosis.plot_trends`.
    title : str, optional
        Page title (default from the machine and recording names).
    controller : mapping or StateSpace, optional
        The loop's controller, for the closed-loop poles and responses: normally
        the recording's ``loop`` (``ClosedLoopData.loop``); see
        :mod:`maglevid.report.loop` for the accepted forms. Default: the
        diagnosis' ``baseline["loop"]`` (or ``["controller"]``), then its
        identification's ``extras`` under the same keys; without one the report
        shows the open loop only and says so.
    generated_at : datetime, optional
        Creation time printed in the footer (default: now, UTC).

    Returns
    -------
    str
        The HTML document.

    Raises
    ------
    DataError
        If ``diagnosis`` is not a :class:`Diagnosis` or ``trends`` is malformed.
    """
    if not isinstance(diagnosis, Diagnosis):
        raise DataError(f"`diagnosis` must be a Diagnosis; got {type(diagnosis).__name__}")
    if trends is not None and not isinstance(trends, Mapping):
        raise DataError(
            "`trends` must be a mapping {parameter: {'time': [...], 'value': [...], ...}}; "
            f"got {type(trends).__name__}"
        )
    from maglevid import __version__

    d = diagnosis
    if d.identified_model is None and d.identification is not None:
        # The identification's own model stands in (continuous preferred: eq. (4) form).
        model = d.identification.continuous_model or d.identification.model
        if model is not None:
            d = dataclasses.replace(d, identified_model=model)
    when = (generated_at or datetime.now(timezone.utc)).astimezone(timezone.utc)
    when_txt = when.strftime("%Y-%m-%d %H:%M:%S UTC")
    name = d.machine or d.recording or "recording"
    page_title = title or f"maglevid diagnosis — {name}"
    loops, loop_note = (None, "")
    if d.identified_model is not None:
        loops, loop_note = _closed_loops(d, controller)
    shown = report_panels(d)
    toc = "".join(
        f'<a href="#{k}">{i + 1}. {_e(t)}</a>'
        for i, (k, t) in enumerate((k, t) for k, t in _SECTIONS if k in shown)
    )
    if d.identified_model is None and not d.changes:
        # Nothing identified: one card instead of four empty ones.
        why = (
            "the data-quality checks stopped the diagnosis"
            if not d.can_diagnose
            else "the diagnosis carries no identified model"
        )
        evidence = [
            '<section id="parameters" class="card"><h2><span class="num">2–5</span>'
            "Parameters, percentage index, poles, responses</h2>"
            f'<p class="note">Not available: {_e(why)}, so nothing was identified to compare '
            "with the baseline.</p>"
            '<span id="percentage"></span><span id="poles"></span><span id="responses"></span>'
            "</section>"
        ]
    else:
        evidence = [
            _parameters_section(d) if "parameters" in shown else "",
            _percentage_section(d) if "percentage" in shown else "",
            _poles_section(d, loops, loop_note) if "poles" in shown else "",
            _responses_section(d, loops) if "responses" in shown else "",
        ]
    sections = [
        _verdict_section(d),
        f'<nav class="toc">{toc}</nav>',
        *evidence,
        _trends_section(d, trends) if "trends" in shown else "",
        _quality_section(d) if "quality" in shown else "",
        _method_section(d, loop_note) if "method" in shown else "",
    ]
    header_right = " · ".join(_e(x) for x in (d.machine, d.recording, d.created_at) if x)
    data = _script_json(d.to_dict())
    return (
        "<!DOCTYPE html>\n"
        '<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f'<meta name="generator" content="maglevid {_e(__version__)}">'
        f'<meta name="maglevid-verdict-code" content="{_e(d.verdict_code)}">'
        f"<title>{_e(page_title)}</title><style>{_CSS}</style></head>\n"
        f'<body data-verdict-code="{_e(d.verdict_code)}">'
        f'<div class="top"><div class="wrap"><span><b>maglevid</b> · diagnosis report'
        f"</span><span>{header_right}</span></div></div>"
        f'<main class="wrap">{"".join(sections)}</main>'
        f'<footer><div class="wrap"><span>Generated by maglevid {_e(__version__)} on '
        f"{_e(when_txt)}</span><span>{_e(page_title)}</span></div></footer>\n"
        f'<script type="application/json" id="diagnosis-data">{data}</script>\n'
        f"<script>{_SCRIPT}</script>\n</body></html>\n"
    )


def write_report(
    diagnosis: Diagnosis,
    path: str | Path,
    *,
    trends: Mapping[str, Mapping[str, Any]] | None = None,
    title: str | None = None,
    controller: Any = None,
    generated_at: datetime | None = None,
    overwrite: bool = False,
    inputs: Sequence[str | os.PathLike[str] | None] | None = None,
) -> Path:
    """Write the self-contained HTML report of ``diagnosis`` to ``path``.

    See :func:`render_report` for the parameters. The file is written in UTF-8,
    atomically, by the rules of every maglevid output
    (:func:`maglevid.io.write_output`): never over one of ``inputs`` (default:
    the recording the diagnosis was made from) or its side-car, never over an
    existing file unless ``overwrite``; the parent directory must exist.

    Returns
    -------
    Path
        The path written.

    Raises
    ------
    FileFormatError
        ``path`` is an input or its side-car, exists (without ``overwrite``),
        is a folder, its folder does not exist, or the write failed (disk full).

    Examples
    --------
    >>> from maglevid.diagnose.diagnosis import Diagnosis
    >>> import tempfile, pathlib
    >>> d = Diagnosis(verdict="Cannot diagnose: no excitation", verdict_code="cannot_diagnose")
    >>> out = write_report(d, pathlib.Path(tempfile.mkdtemp()) / "r.html")
    >>> "Cannot diagnose: no excitation" in out.read_text(encoding="utf-8")
    True
    """
    from maglevid.io import write_output

    text = render_report(
        diagnosis, trends=trends, title=title, controller=controller, generated_at=generated_at
    )
    if inputs is None:
        inputs = [diagnosis.recording]
    path = write_output(path, text, overwrite=overwrite, inputs=inputs)
    logger.info("wrote diagnosis report %s (%d bytes)", path, len(text.encode("utf-8")))
    return path


def is_maglevid_page(path: str | os.PathLike[str]) -> bool:
    """True when ``path`` is a regular file written by maglevid's HTML writers.

    A writer that repeats (a fleet's per-machine reports) may replace its own
    earlier page, never another file: this looks for the ``generator`` meta
    tag in the file's first kilobytes.
    """
    p = Path(path)
    if not p.is_file():
        return False
    with open(p, "rb") as fh:
        head = fh.read(4096)
    return (
        head.startswith(b"<!DOCTYPE html>") and b'<meta name="generator" content="maglevid' in head
    )
