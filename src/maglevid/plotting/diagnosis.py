"""Figures of a diagnosis: parameter changes, poles, impulse and frequency responses, trends.

Every ``plot_*`` function builds and returns a :class:`matplotlib.figure.Figure`
without touching ``pyplot`` (no global state, no window, safe in threads and in
a headless server); :func:`figure_to_png` and :func:`figure_to_svg` turn a
figure into bytes/text for embedding in the HTML report. In a notebook the
returned figure displays itself.

Colours are fixed across the figures so that a reader learns them once:
baseline = grey (hollow markers, dashed lines), identified = blue, a changed
parameter = red, the closed loop = green/purple.
"""

from __future__ import annotations

import io
import math
from collections.abc import Mapping, Sequence
from datetime import datetime, timezone
from typing import Any

import matplotlib
import numpy as np
import scipy.linalg as sla
from matplotlib.figure import Figure
from scipy import special  # not scipy.stats: 0.6 s to import for one quantile

from maglevid.diagnose.compare import DEFAULT_TOLERANCE, ParameterChange
from maglevid.exceptions import DataError
from maglevid.lti import StateSpace, discretize

__all__ = [
    "COLORS",
    "TIME_UNITS",
    "drift_crossing",
    "drift_line",
    "figure_to_png",
    "figure_to_svg",
    "impulse_horizon",
    "plot_frequency_responses",
    "plot_impulse_responses",
    "plot_parameter_changes",
    "plot_pole_maps",
    "plot_trends",
]

#: The report's palette (hex), shared with the HTML.
COLORS = {
    "baseline": "#6b7280",
    "identified": "#1d4ed8",
    "changed": "#c0262d",
    "within_tolerance": "#0e7490",
    "not_resolved": "#b45309",
    "unchanged": "#374151",
    "band": "#d1fae5",
    "closed_baseline": "#7c3aed",
    "closed_identified": "#15803d",
    "grid": "#e5e7eb",
}

_STATUS_COLOR = {
    "changed": COLORS["changed"],
    "within tolerance": COLORS["within_tolerance"],
    "not resolved": COLORS["not_resolved"],
    "unchanged": COLORS["unchanged"],
}

_RC = {
    "font.size": 9.5,
    "axes.titlesize": 10.5,
    "axes.titleweight": "bold",
    "axes.labelsize": 9.5,
    "axes.edgecolor": "#9ca3af",
    "axes.linewidth": 0.8,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "axes.grid": True,
    "grid.color": COLORS["grid"],
    "grid.linewidth": 0.7,
    "xtick.color": "#374151",
    "ytick.color": "#374151",
    "legend.frameon": False,
    "legend.fontsize": 8.5,
    "savefig.facecolor": "white",
}


def _figure(width: float, height: float) -> Figure:
    with matplotlib.rc_context(_RC):
        fig = Figure(figsize=(width, height), layout="constrained")
    fig.set_facecolor("white")
    return fig


def _styled(fn):
    """Run a plot function under the report's rc settings (axes read them at creation)."""

    def wrapper(*args: Any, **kwargs: Any) -> Figure:
        with matplotlib.rc_context(_RC):
            return fn(*args, **kwargs)

    wrapper.__name__ = fn.__name__
    wrapper.__qualname__ = fn.__qualname__
    wrapper.__doc__ = fn.__doc__
    wrapper.__module__ = fn.__module__
    return wrapper


def figure_to_png(fig: Figure, *, dpi: float = 130) -> bytes:
    """PNG bytes of ``fig`` (Agg renderer; no display needed)."""
    buf = io.BytesIO()
    with matplotlib.rc_context(_RC):
        fig.savefig(buf, format="png", dpi=dpi, metadata={"Software": None})
    return buf.getvalue()


def figure_to_svg(fig: Figure) -> str:
    """SVG text of ``fig``, to inline in HTML (text as paths: no font needed to view it)."""
    buf = io.StringIO()
    with matplotlib.rc_context({**_RC, "svg.fonttype": "path", "svg.hashsalt": "maglevid"}):
        fig.savefig(buf, format="svg", metadata={"Date": None, "Creator": None})
    return buf.getvalue()


# --------------------------------------------------------------------------- changes
def _change_ci_percent(c: ParameterChange) -> tuple[float, float]:
    if c.baseline == 0:
        return (math.nan, math.nan)
    lo, hi = (100.0 * c.change_ci[0] / c.baseline, 100.0 * c.change_ci[1] / c.baseline)
    return (min(lo, hi), max(lo, hi))


@_styled
def plot_parameter_changes(
    changes: Sequence[ParameterChange],
    *,
    labels: Mapping[str, str] | None = None,
    level: float = 0.95,
) -> Figure:
    """Forest plot: % change of each parameter with its confidence interval.

    Each row is one :class:`~maglevid.diagnose.compare.ParameterChange`: a dot at
    ``change_percent`` with the interval ``change_ci`` (in % of the baseline),
    the tolerance band ``±tolerance`` shaded, coloured by status (changed: red;
    significant but within tolerance: teal; exceeds the tolerance but not
    resolved by the data: amber; unchanged: dark grey).

    Parameters
    ----------
    changes : sequence of ParameterChange
        In the order to show, top to bottom. Parameters with a zero baseline
        (no relative change) are listed with "n/a".
    labels : mapping, optional
        Longer row labels by parameter name.
    level : float
        Level of the intervals in ``changes`` (for the axis label only).
    """
    changes = list(changes)
    if not changes:
        raise DataError("`changes` is empty: nothing to plot")
    labels = dict(labels or {})
    n = len(changes)
    fig = _figure(9.6, 0.9 + 0.34 * n)
    ax = fig.add_subplot()
    y = np.arange(n)[::-1]
    xs = []
    for yi, c in zip(y, changes):
        tol = 100.0 * c.tolerance
        ax.fill_betweenx([yi - 0.42, yi + 0.42], -tol, tol, color=COLORS["band"], lw=0, zorder=0)
        color = _STATUS_COLOR.get(c.status, COLORS["unchanged"])
        lo, hi = _change_ci_percent(c)
        x = c.change_percent
        if math.isfinite(x):
            xs.extend([x, tol, -tol])
            if math.isfinite(lo) and math.isfinite(hi):
                xs.extend([lo, hi])
                ax.plot([lo, hi], [yi, yi], color=color, lw=2.2, solid_capstyle="butt", zorder=3)
                ax.plot([lo, lo], [yi - 0.17, yi + 0.17], color=color, lw=1.2, zorder=3)
                ax.plot([hi, hi], [yi - 0.17, yi + 0.17], color=color, lw=1.2, zorder=3)
            ax.plot(
                [x],
                [yi],
                "o",
                ms=6.5 if c.significant else 5,
                color=color,
                mec="white",
                mew=0.8,
                zorder=4,
            )
    ax.axvline(0.0, color="#111827", lw=0.9, zorder=1)
    finite = [v for v in xs if math.isfinite(v)] or [-1.0, 1.0]
    lo_x, hi_x = min(finite), max(finite)
    pad = 0.06 * max(hi_x - lo_x, 1.0)
    ax.set_xlim(lo_x - pad, hi_x + pad)
    # Value and interval printed at the right edge, outside the data.
    for yi, c in zip(y, changes):
        lo, hi = _change_ci_percent(c)
        if math.isfinite(c.change_percent):
            txt = f"{c.change_percent:+.2f} %"
            if math.isfinite(lo):
                txt += f"  [{lo:+.2f}, {hi:+.2f}]"
        else:
            txt = "n/a (baseline 0)"
        ax.annotate(
            txt,
            (1.0, yi),
            xycoords=("axes fraction", "data"),
            xytext=(6, 0),
            textcoords="offset points",
            va="center",
            ha="left",
            fontsize=8.5,
            color=_STATUS_COLOR.get(c.status, COLORS["unchanged"]),
            fontweight="bold" if c.significant else "normal",
        )
    ax.set_yticks(y)
    ax.set_yticklabels([labels.get(c.name, c.name) for c in changes])
    for tick, c in zip(ax.get_yticklabels(), changes):
        if c.significant:
            tick.set_color(COLORS["changed"])
            tick.set_fontweight("bold")
    ax.set_ylim(-0.6, n - 0.4)
    ax.grid(axis="y", visible=False)
    ax.set_xlabel(f"change from baseline [%]  (dot: estimate; bar: {100 * level:.0f} % CI)")
    ax.tick_params(axis="y", length=0)
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    present = {c.status for c in changes}
    handles = [Patch(color=COLORS["band"], label="tolerance band (±tolerance)")]
    handles += [
        Line2D([], [], color=color, marker="o", lw=2, label=status)
        for status, color in _STATUS_COLOR.items()
        if status in present
    ]
    ax.legend(
        handles=handles,
        loc="lower left",
        bbox_to_anchor=(0.0, 1.0),
        ncol=len(handles),
        borderaxespad=0.3,
        handlelength=1.6,
    )
    return fig


# ---------------------------------------------------------------------------- poles
def _discrete_poles(model: StateSpace, dt: float | None) -> np.ndarray | None:
    if model.is_discrete:
        return model.poles()
    if dt is None:
        return None
    return np.exp(model.poles() * dt)  # z = exp(s dt): ZOH maps every pole this way


def _continuous_poles(model: StateSpace) -> tuple[np.ndarray, int]:
    """s-plane poles; a discrete model's ``z`` map to ``ln(z)/dt`` (``z = 0`` left out)."""
    p = model.poles()
    if not model.is_discrete:
        return p, 0
    nz = np.abs(p) > 1e-12
    return np.log(p[nz].astype(complex)) / model.dt, int((~nz).sum())


def _scatter_poles(ax, p, *, kind: str, label: str) -> None:
    style = {
        "baseline": {"marker": "o", "mfc": "none", "mec": COLORS["baseline"], "ms": 9, "mew": 1.6},
        "identified": {"marker": "x", "color": COLORS["identified"], "ms": 8, "mew": 2.0},
        "closed_baseline": {
            "marker": "s",
            "mfc": "none",
            "mec": COLORS["closed_baseline"],
            "ms": 8,
            "mew": 1.4,
        },
        "closed_identified": {
            "marker": "+",
            "color": COLORS["closed_identified"],
            "ms": 10,
            "mew": 2.0,
        },
    }[kind]
    ax.plot(p.real, p.imag, ls="none", label=label, zorder=4, **style)


def _padded_limits(values: np.ndarray, *, pad: float = 0.12, floor: float = 1e-9):
    lo, hi = float(np.min(values)), float(np.max(values))
    w = max(hi - lo, floor, 1e-3 * max(abs(lo), abs(hi)))
    return lo - pad * w, hi + pad * w


def _square_limits(values: np.ndarray, *, pad: float = 0.15) -> tuple[float, float, float]:
    """Centre and half-width of a square window (equal aspect) around complex ``values``."""
    xlo, xhi = _padded_limits(values.real, pad=pad)
    ylo, yhi = _padded_limits(np.concatenate([values.imag, -values.imag]), pad=pad)
    half = max(xhi - xlo, yhi - ylo) / 2
    return (xlo + xhi) / 2, (ylo + yhi) / 2, half


def _s_plane(ax, pairs, *, focus: np.ndarray, title: str, n_zero: int = 0) -> None:
    """Draw s-plane poles; the view covers ``focus`` (others off scale are counted)."""
    for p, kind, label in pairs:
        _scatter_poles(ax, p, kind=kind, label=label)
    xlo, xhi = _padded_limits(np.concatenate([focus.real, [0.0]]))
    ylo, yhi = _padded_limits(np.concatenate([focus.imag, -focus.imag]))
    yspan = max(yhi - ylo, 0.25 * (xhi - xlo))
    yc = (ylo + yhi) / 2
    ax.set_xlim(xlo, xhi)
    ax.set_ylim(yc - yspan / 2, yc + yspan / 2)
    allp = np.concatenate([p for p, _, _ in pairs])
    off = int(np.sum((allp.real < xlo) | (allp.real > xhi)))
    ax.axvline(0.0, color="#111827", lw=0.8, zorder=1)
    ax.axhline(0.0, color="#9ca3af", lw=0.6, zorder=1)
    ax.set_xlabel("Re s [rad/s]")
    ax.set_ylabel("Im s [rad/s]")
    notes = []
    if off:
        notes.append(f"{off} fast pole(s) left of the view")
    if n_zero:
        notes.append(f"{n_zero} at z = 0 (deadbeat) not shown")
    ax.set_title(title + ("\n" + "; ".join(notes) if notes else ""))
    ax.ticklabel_format(style="sci", scilimits=(-3, 4), axis="both")


def _z_plane(ax, pairs, *, focus: np.ndarray | None, title: str) -> None:
    """Draw z-plane poles with the unit circle; ``focus`` zooms on those poles."""
    for p, kind, label in pairs:
        _scatter_poles(ax, p, kind=kind, label=label)
    allp = np.concatenate([p for p, _, _ in pairs])
    if focus is None:
        # A loop with a deadbeat observer has poles at z = 0 and slow ones near
        # z = 1: on the whole circle both are blobs. Zoom on the slow ones and
        # count the others in the title.
        slow = allp[np.abs(allp) > 0.5]
        if 0 < slow.size < allp.size:
            focus = slow
            title += f"\n{allp.size - slow.size} pole(s) with |z| ≤ 0.5 not shown"
    if focus is None:
        th = np.linspace(0, 2 * np.pi, 400)
        r = max(1.12, float(np.max(np.abs(allp))) * 1.08)
        xc, yc, half = 0.0, 0.0, r
    else:
        xc, yc, half = _square_limits(focus)
        ang = float(np.angle(xc + 1j * yc))
        th = np.linspace(ang - 3 * half, ang + 3 * half, 400)
    ax.plot(np.cos(th), np.sin(th), color="#111827", lw=0.9, zorder=1, label="|z| = 1")
    ax.axhline(0.0, color="#9ca3af", lw=0.6, zorder=1)
    ax.set_xlim(xc - half, xc + half)
    ax.set_ylim(yc - half, yc + half)
    ax.set_aspect("equal")
    ax.set_xlabel("Re z")
    ax.set_ylabel("Im z")
    ax.set_title(title)
    ax.ticklabel_format(useOffset=False)


def _label_expected_unstable(ax, baseline_poles: np.ndarray) -> None:
    """Name the baseline's unstable pole: a magnetic bearing is open-loop unstable by physics."""
    unstable = baseline_poles[baseline_poles.real > 0]
    if not unstable.size:
        return
    p = unstable[np.argmax(unstable.real)]
    ax.annotate(
        "unstable pole: expected\nfor a magnetic bearing",
        xy=(p.real, p.imag),
        xytext=(-12, 28),
        textcoords="offset points",
        ha="right",
        fontsize=8,
        color="#374151",
        arrowprops={"arrowstyle": "->", "color": "#6b7280", "lw": 0.8},
    )


@_styled
def plot_pole_maps(
    baseline: StateSpace,
    identified: StateSpace,
    *,
    dt: float | None = None,
    closed_loop: tuple[StateSpace, StateSpace] | None = None,
) -> Figure:
    """Pole maps in the s-plane and the z-plane, open loop and closed loop.

    Row 1, open loop (the plant): s-plane; z-plane detail near ``z = 1``
    (at fast sampling every plant pole crowds there) with the unit-circle arc.
    Row 2, when ``closed_loop`` is given: the same controller closing the loop
    around the baseline and around the identified plant, in the s-plane
    (``s = ln(z)/dt``; a view on the slower poles, faster ones counted, poles at
    ``z = 0`` left out and counted) and on the whole unit circle.

    Parameters
    ----------
    baseline, identified : StateSpace
        Open-loop plant models (continuous or discrete).
    dt : float, optional
        Control period: continuous models are mapped to ``z = exp(s dt)`` (the
        poles of their ZOH sampling, eq. (7)). Without it (and for continuous
        models) only the s-plane is drawn.
    closed_loop : (StateSpace, StateSpace), optional
        Discrete closed loops (baseline plant, identified plant) with the same
        controller, e.g. from :func:`maglevid.report.loop.close_loop`.
    """
    zb, zi = _discrete_poles(baseline, dt), _discrete_poles(identified, dt)
    has_z = zb is not None and zi is not None
    nrows = 2 if (closed_loop is not None and has_z) else 1
    ncols = 2 if has_z else 1
    fig = _figure(11.5 if has_z else 5.5, 4.0 * nrows + 0.5)
    axes = fig.subplots(nrows, ncols, squeeze=False)
    sb, _ = _continuous_poles(baseline)
    si, _ = _continuous_poles(identified)
    open_pairs = [(sb, "baseline", "baseline plant"), (si, "identified", "identified plant")]
    _s_plane(axes[0, 0], open_pairs, focus=np.concatenate([sb, si]), title="open loop: s-plane")
    _label_expected_unstable(axes[0, 0], sb)
    if has_z:
        _z_plane(
            axes[0, 1],
            [(zb, "baseline", "baseline plant"), (zi, "identified", "identified plant")],
            focus=np.concatenate([zb, zi]),
            title=f"open loop: z-plane (dt = {1e3 * dt:g} ms), detail near z = 1"
            if dt
            else "open loop: z-plane, detail",
        )
    if nrows == 2:
        zcb, zci = closed_loop[0].poles(), closed_loop[1].poles()
        cb, n0b = _continuous_poles(closed_loop[0])
        ci, n0i = _continuous_poles(closed_loop[1])
        # The s-plane view covers the closed-loop poles no faster than 3x the
        # fastest open-loop pole: observer poles far to the left would squash the rest.
        lim = 3.0 * float(np.max(np.abs(np.concatenate([sb, si]))))
        slow = np.concatenate([cb[np.abs(cb) <= lim], ci[np.abs(ci) <= lim]])
        _s_plane(
            axes[1, 0],
            [
                (cb, "closed_baseline", "closed loop, baseline plant"),
                (ci, "closed_identified", "closed loop, identified plant"),
            ],
            focus=slow if slow.size else np.concatenate([cb, ci]),
            title="closed loop: s-plane",
            n_zero=max(n0b, n0i),
        )
        _z_plane(
            axes[1, 1],
            [
                (zcb, "closed_baseline", "closed loop, baseline plant"),
                (zci, "closed_identified", "closed loop, identified plant"),
            ],
            focus=None,
            title="closed loop: z-plane",
        )
    handles, labels = [], []
    for ax in axes[:, -1]:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    fig.legend(handles, labels, loc="outside lower center", ncol=min(len(labels), 5))
    return fig


# ------------------------------------------------------------------------ impulses
def impulse_horizon(model: StateSpace, *, growth: float = 4.0, decay: float = 6.0) -> float:
    """A time span that shows a model's impulse response without hiding it.

    For an unstable model: until the fastest growing mode has grown by
    ``exp(growth)`` (the response would otherwise fill the plot with one
    exponential). For a stable one: ``decay`` time constants of its slowest mode.
    """
    p, _ = _continuous_poles(model)
    sigma = p.real
    if np.any(sigma > 0):
        return growth / float(np.max(sigma))
    slow = float(np.max(sigma)) if sigma.size else -1.0
    return decay / max(-slow, 1e-12)


def _impulse(model: StateSpace, t_end: float, dt: float | None) -> tuple[np.ndarray, np.ndarray]:
    """Times and impulse response ``(n, ny, nu)``.

    Discrete (or with ``dt``): Markov parameters ``C A^(k-1) B`` of the sampled
    model, i.e. the response to a unit pulse held for one period (eq. (9)).
    Continuous without ``dt``: ``C exp(A t) B`` on a fine grid.
    """
    if model.is_discrete or dt is not None:
        md = model if model.is_discrete else discretize(model, dt)
        n = max(math.ceil(t_end / md.dt) + 1, 3)
        return np.arange(n) * md.dt, md.markov(n + 1)[1:]
    t = np.linspace(0.0, t_end, 400)
    E = sla.expm(model.A * (t[1] - t[0]))
    out = np.empty((t.size, model.ny, model.nu))
    X = model.B.copy()
    for k in range(t.size):
        out[k] = model.C @ X
        X = E @ X
    return t, out


def _settled_time(t: np.ndarray, *responses: np.ndarray, rel: float = 0.01) -> float:
    """Time after which every response stays below ``rel`` of its peak (plus 30 %)."""
    last = 0
    for h in responses:
        a = np.abs(np.asarray(h)).reshape(len(t), -1).max(axis=1)
        above = np.nonzero(a > rel * max(float(a.max()), 1e-300))[0]
        if above.size:
            last = max(last, int(above[-1]))
    return float(t[min(len(t) - 1, max(int(1.3 * last), 10))])


def _time_scale(t_end: float) -> tuple[float, str]:
    if t_end < 2e-3:
        return 1e6, "µs"
    if t_end < 2.0:
        return 1e3, "ms"
    return 1.0, "s"


@_styled
def plot_impulse_responses(
    baseline: StateSpace,
    identified: StateSpace,
    *,
    dt: float | None = None,
    output: int = 0,
    output_label: str = "displacement x",
    output_unit: tuple[float, str] = (1e6, "µm"),
    horizon: float | None = None,
    closed_loop: tuple[StateSpace, StateSpace] | None = None,
) -> Figure:
    """Impulse responses of one output to every input, identified vs baseline.

    Gosiewski & Paszowski, Figs. 3 and 4: the displacement after a unit pulse on
    each input, open loop (unstable: the response grows; the horizon is cut
    where the fastest unstable mode has grown ``e^4``-fold, see
    :func:`impulse_horizon`) and, when ``closed_loop`` is given, closed loop
    (pulse on the excitation ``r``).

    Parameters
    ----------
    baseline, identified : StateSpace
        Open-loop plants.
    dt : float, optional
        Control period; continuous models are sampled with a ZOH and the response
        is to a one-period pulse (Markov parameters). Without it, the continuous
        impulse response ``C exp(A t) B``.
    output : int
        Output index (0 = displacement for the AMB).
    output_label, output_unit : str, (float, str)
        Label; scale factor and unit of the output on the plot.
    horizon : float, optional
        Open-loop horizon [s]; default :func:`impulse_horizon` of the baseline.
    closed_loop : (StateSpace, StateSpace), optional
        Discrete closed loops (baseline, identified), input ``r``.
    """
    nu = baseline.nu
    nrows = 2 if closed_loop is not None else 1
    fig = _figure(11.5, 3.3 * nrows + 0.4)
    axes = fig.subplots(nrows, nu, squeeze=False)
    scale, unit = output_unit
    t_end = horizon if horizon is not None else impulse_horizon(baseline)
    rows = [("open loop", baseline, identified, t_end)]
    if closed_loop is not None:
        rows.append(("closed loop", closed_loop[0], closed_loop[1], None))
    p_unst = float(np.max(_continuous_poles(baseline)[0].real))
    for r, (what, mb, mi, t_e) in enumerate(rows):
        if t_e is None:
            # Closed loop: long enough to decay, then cut where both responses
            # have stayed below 1 % of their peak.
            t_long = min(impulse_horizon(mb), 4000 * mb.dt)
            tb, hb = _impulse(mb, t_long, dt)
            ti, hi = _impulse(mi, t_long, dt)
            t_e = _settled_time(tb, hb[:, output, :], hi[:, output, :])
            keep = tb <= t_e
            tb, hb, ti, hi = tb[keep], hb[keep], ti[keep], hi[keep]
        else:
            tb, hb = _impulse(mb, t_e, dt)
            ti, hi = _impulse(mi, t_e, dt)
        ts, tu = _time_scale(t_e)
        pulse = "pulse" if (mb.is_discrete or dt is not None) else "impulse"
        for j in range(nu):
            ax = axes[r, j]
            names = mb.input_names or baseline.input_names
            inp_name = names[j] if names else f"u{j + 1}"
            yb, yi = hb[:, output, j] * scale, hi[:, output, j] * scale
            ax.plot(
                tb * ts, yb, color=COLORS["baseline"], lw=2.4, ls="--", label="baseline", zorder=3
            )
            ax.plot(ti * ts, yi, color=COLORS["identified"], lw=1.5, label="identified", zorder=4)
            ax.axhline(0.0, color="#9ca3af", lw=0.6)
            ax.set_title(f"{what}: {output_label}, unit {pulse} on {inp_name}")
            ax.set_xlabel(f"time [{tu}]")
            ax.set_ylabel(f"{output_label.split()[-1]} [{unit}]")
            ax.set_xlim(0, t_e * ts)
            # Annotations go to the corner away from the curve.
            up = yb[-1] >= 0 if r == 0 else abs(yb.max()) >= abs(yb.min())
            corner_y, va = (0.96, "top") if up else (0.04, "bottom")
            if r == 0 and p_unst > 0:
                ax.text(
                    0.02,
                    corner_y,
                    f"open loop is unstable: grows as $e^{{{p_unst:.0f}\\,t}}$\n"
                    f"(t in s); short horizon shown",
                    transform=ax.transAxes,
                    va=va,
                    ha="left",
                    fontsize=8.5,
                    color=COLORS["changed"],
                    bbox={"boxstyle": "round,pad=0.35", "fc": "white", "ec": "#fca5a5"},
                )
            ax.legend(loc=("lower right" if up else "upper right") if r == 0 else "best")
    return fig


# ----------------------------------------------------------------------- frequency
def _default_omega(models: Sequence[StateSpace], dt: float | None) -> np.ndarray:
    mags = np.concatenate([np.abs(_continuous_poles(m)[0]) for m in models])
    mags = mags[mags > 0]
    lo = 0.1 * float(np.min(mags)) if mags.size else 1.0
    hi = (np.pi / dt) if dt else 30.0 * float(np.max(mags)) if mags.size else 1e4
    return np.logspace(np.log10(lo), np.log10(hi), 500)


@_styled
def plot_frequency_responses(
    baseline: StateSpace,
    identified: StateSpace,
    *,
    channels: Sequence[tuple[int, int]] | None = None,
    dt: float | None = None,
    omega: Any = None,
    output_units: Sequence[str] | None = None,
    input_units: Sequence[str] | None = None,
) -> Figure:
    """Bode magnitude and phase of selected channels, identified vs baseline.

    The continuous plant's ``C (j w I - A)^-1 B`` is evaluated on the ``j w``
    axis; for the unstable open-loop bearing this is the transfer function, not
    a measurable steady-state response (no sine test of an open unstable plant
    exists), which is why the report labels it "open-loop model".

    Parameters
    ----------
    baseline, identified : StateSpace
    channels : sequence of (output, input), optional
        Default: every input to output 0 and each input ``j`` to output ``j + 1``
        (for the AMB: ``x/u1, x/u2, i1/u1, i2/u2``).
    dt : float, optional
        Control period: the frequency axis ends at the Nyquist frequency.
    omega : array_like, optional
        Angular frequencies [rad/s].
    output_units, input_units : sequence of str, optional
        Units per output/input, shown with each channel (e.g. ``m/V``).
    """
    if channels is None:
        channels = [(0, j) for j in range(baseline.nu)]
        channels += [(j + 1, j) for j in range(baseline.nu) if j + 1 < baseline.ny]
    channels = list(channels)
    w = _default_omega([baseline, identified], dt) if omega is None else np.asarray(omega, float)
    f = w / (2 * np.pi)
    Hb = baseline.frequency_response(w)
    Hi = identified.frequency_response(w)
    fig = _figure(11.5, 5.2)
    axes = fig.subplots(2, len(channels), squeeze=False, sharex=True)
    outs = baseline.output_names or tuple(f"y{i + 1}" for i in range(baseline.ny))
    ins = baseline.input_names or tuple(f"u{i + 1}" for i in range(baseline.nu))
    for k, (o, i) in enumerate(channels):
        for H, style in (
            (Hb, {"color": COLORS["baseline"], "lw": 2.4, "ls": "--", "label": "baseline"}),
            (Hi, {"color": COLORS["identified"], "lw": 1.5, "label": "identified"}),
        ):
            h = H[:, o, i]
            axes[0, k].semilogx(f, 20 * np.log10(np.abs(h)), **style)
            axes[1, k].semilogx(f, np.degrees(np.unwrap(np.angle(h))), **style)
        unit = ""
        if output_units and input_units:
            unit = f"  [dB re 1 {output_units[o]}/{input_units[i]}]"
        axes[0, k].set_title(f"{outs[o]} / {ins[i]}{unit}", fontsize=9.5)
        axes[1, k].set_xlabel("frequency [Hz]")
    axes[0, 0].set_ylabel("magnitude [dB]")
    axes[1, 0].set_ylabel("phase [deg]")
    axes[0, -1].legend(loc="best")
    if dt:
        for ax in axes.ravel():
            ax.axvline(0.5 / dt, color="#9ca3af", lw=0.8, ls=":")
        axes[1, 0].annotate(
            "Nyquist",
            (0.5 / dt, 1.0),
            xycoords=("data", "axes fraction"),
            xytext=(-3, -3),
            textcoords="offset points",
            ha="right",
            va="top",
            fontsize=8,
            color="#6b7280",
        )
    return fig


# -------------------------------------------------------------------------- trends
def _as_times(values: Sequence[Any]) -> tuple[np.ndarray, bool]:
    """Times as floats; ISO strings become seconds since 1970 UTC (``True`` flag)."""
    vals = list(values)
    if vals and all(isinstance(v, str) for v in vals):
        out = []
        for v in vals:
            try:
                t = datetime.fromisoformat(v.replace("Z", "+00:00") if v.endswith("Z") else v)
            except ValueError as exc:
                raise DataError(f"trend time {v!r} is not an ISO 8601 time") from exc
            if t.tzinfo is None:
                t = t.replace(tzinfo=timezone.utc)
            out.append(t.timestamp())
        return np.asarray(out), True
    if vals and all(isinstance(v, datetime) for v in vals):
        return np.asarray(
            [(v if v.tzinfo else v.replace(tzinfo=timezone.utc)).timestamp() for v in vals]
        ), True
    try:
        return np.asarray(vals, dtype=float), False
    except (TypeError, ValueError):
        raise DataError(
            "trend times must all be ISO 8601 strings, datetimes, or all numbers"
        ) from None


def _plot_times(t: np.ndarray, dated: bool) -> np.ndarray:
    """Seconds since 1970 as ``datetime64`` (matplotlib converts it); plain numbers as is."""
    return (np.asarray(t) * 1e6).round().astype("datetime64[us]") if dated else t


#: Seconds per time unit a drift result may use (``DriftResult`` slopes are per
#: the unit of the times it was given; ``maglevid history`` tests in days).
TIME_UNITS = {"s": 1.0, "min": 60.0, "h": 3600.0, "day": 86400.0, "d": 86400.0,
              "week": 604800.0}  # fmt: skip


def _epoch_seconds(v: Any, scale: float) -> float | None:
    """A time from a drift result: ISO 8601 string, or a number in the drift's unit."""
    if isinstance(v, str):
        try:
            t = datetime.fromisoformat(v.replace("Z", "+00:00") if v.endswith("Z") else v)
        except ValueError:
            return None
        return (t if t.tzinfo else t.replace(tzinfo=timezone.utc)).timestamp()
    if isinstance(v, (int, float)) and math.isfinite(v):
        return float(v) * scale
    return None


def drift_line(
    drift: Mapping[str, Any], *, dated: bool = True
) -> tuple[float, float, float] | None:
    """The fitted drift line as ``(slope per second, t_ref, value at t_ref)``.

    Reads ``slope``, ``t_ref`` and ``value_at_ref`` of a drift result (the
    ``to_dict()`` of :class:`maglevid.diagnose.drift.DriftResult`, or an entry of
    ``maglevid history --json``), with ``time_unit`` (``"s"`` by default,
    ``"day"`` for the history command; see :data:`TIME_UNITS`). ``t_ref`` is an
    ISO 8601 time or a number in that unit since 1970 (dated histories). For an
    undated history (``dated=False``) times are used as they are. ``None`` when
    the line is not given or the unit is unknown.
    """
    unit = str(drift.get("time_unit", "s"))
    scale = TIME_UNITS.get(unit) if dated else 1.0
    slope, v_ref = drift.get("slope"), drift.get("value_at_ref")
    if scale is None or not isinstance(slope, (int, float)) or not isinstance(v_ref, (int, float)):
        return None
    t_ref = _epoch_seconds(drift.get("t_ref"), scale)
    if t_ref is None or not math.isfinite(slope):
        return None
    return float(slope) / scale, t_ref, float(v_ref)


def drift_crossing(drift: Mapping[str, Any]) -> float | None:
    """When the drift line leaves the tolerance band, seconds since 1970 (or ``None``)."""
    if isinstance(drift.get("projected_crossing_at"), str):
        return _epoch_seconds(drift["projected_crossing_at"], 1.0)
    scale = TIME_UNITS.get(str(drift.get("time_unit", "s")))
    if scale is None:
        return None
    return _epoch_seconds(drift.get("projected_crossing_time"), scale)


def _drift_text(drift: Mapping[str, Any]) -> tuple[str, bool]:
    drifting = drift.get("drifting")
    verdict = drift.get("verdict")
    if verdict is None and drifting is not None:
        verdict = "drifting" if drifting else "no significant drift"
    parts = [str(verdict) if verdict is not None else "drift test"]
    p = drift.get("p_value")
    if isinstance(p, (int, float)) and math.isfinite(p):
        parts.append("p < 0.0001" if p < 1e-4 else f"p = {p:.2g}")
    return ", ".join(parts), bool(drifting)


def _draw_step(ax, x: np.ndarray, step: Mapping[str, Any]) -> None:
    """The two means of a step (:func:`maglevid.diagnose.drift.detect_step`) over their points."""
    k = int(step["index"])
    for seg, level in ((x[:k], step["before"]), (x[k:], step["after"])):
        if len(seg):
            ax.plot([seg[0], seg[-1]], [level, level], color=COLORS["changed"], lw=1.4)


@_styled
def plot_trends(
    trends: Mapping[str, Mapping[str, Any]],
    *,
    baselines: Mapping[str, float] | None = None,
    tolerances: Mapping[str, float] | None = None,
    labels: Mapping[str, str] | None = None,
    level: float = 0.95,
    ncols: int = 2,
) -> Figure:
    """Small multiples of each parameter's history: value ± CI, baseline, band, drift.

    Parameters
    ----------
    trends : mapping of name -> mapping
        ``{"time": [...], "value": [...], "std_error": [...], "drift": {...}}``
        per parameter. ``time``: ISO 8601 strings (or datetimes), shown as dates,
        or numbers (unit from an optional ``"time_unit"`` entry). ``std_error``
        optional. ``step`` optional (``index``, ``before``, ``after``, ``at``,
        ``percent``, as ``maglevid history --json`` gives it): drawn as the two
        means instead of the drift line. ``drift`` optional: the ``to_dict()`` of
        :class:`maglevid.diagnose.drift.DriftResult` or any mapping with
        ``drifting``/``verdict`` and ``p_value``; with ``slope``, ``t_ref`` and
        ``value_at_ref`` the fitted line is drawn (time in seconds since 1970 for
        dated histories, as the history store keeps it). Optional ``baseline``
        and relative ``tolerance`` override the arguments below.
    baselines, tolerances : mapping, optional
        Baseline value and relative tolerance (fraction) per parameter; default
        tolerance :data:`~maglevid.diagnose.compare.DEFAULT_TOLERANCE`.
    labels : mapping, optional
        Panel titles by parameter name.
    level : float
        Level of the error bars.
    ncols : int
        Panels per row.
    """
    if not trends:
        raise DataError("`trends` is empty: nothing to plot")
    baselines = dict(baselines or {})
    tolerances = dict(tolerances or {})
    labels = dict(labels or {})
    names = list(trends)
    ncols = max(1, min(ncols, len(names)))
    nrows = math.ceil(len(names) / ncols)
    fig = _figure(11.5, 2.9 * nrows + 0.3)
    axes = fig.subplots(nrows, ncols, squeeze=False)
    z = float(special.ndtri(0.5 + level / 2))
    for ax in axes.ravel()[len(names) :]:
        ax.set_visible(False)
    for ax, name in zip(axes.ravel(), names):
        entry = trends[name]
        for key in ("time", "value"):
            if key not in entry:
                raise DataError(f"trend {name!r} has no {key!r} list")
        t, dated = _as_times(entry["time"])
        v = np.asarray(entry["value"], dtype=float)
        if t.shape != v.shape:
            raise DataError(
                f"trend {name!r}: {t.size} times but {v.size} values; expected one per time"
            )
        se = entry.get("std_error")
        se = np.zeros_like(v) if se is None else np.asarray(se, dtype=float)
        if se.shape != v.shape:
            raise DataError(f"trend {name!r}: {se.size} standard errors for {v.size} values")
        x = _plot_times(t, dated)
        base = entry.get("baseline", baselines.get(name))
        tol = entry.get("tolerance", tolerances.get(name, DEFAULT_TOLERANCE))
        drift = entry.get("drift") or {}
        if base is not None and math.isfinite(float(base)):
            base = float(base)
            half = abs(float(tol) * base)
            ax.axhspan(
                base - half,
                base + half,
                color=COLORS["band"],
                lw=0,
                zorder=0,
                label=f"tolerance ±{100 * float(tol):g} %",
            )
            ax.axhline(base, color=COLORS["baseline"], ls="--", lw=1.3, label="baseline")
        ax.errorbar(
            x,
            v,
            yerr=z * se,
            fmt="o",
            ms=4.5,
            color=COLORS["identified"],
            ecolor="#93c5fd",
            elinewidth=1.6,
            capsize=2.5,
            label=f"estimate ± {100 * level:.0f} % CI",
            zorder=3,
        )
        step = entry.get("step")
        fitted = None if step else drift_line(drift, dated=dated)
        if step:
            _draw_step(ax, x, step)
        if fitted is not None and t.size >= 2:
            slope, t_ref, v_ref = fitted
            tt = np.linspace(float(t.min()), float(t.max()), 50)
            line = v_ref + slope * (tt - t_ref)
            xx = _plot_times(tt, dated)
            ax.plot(
                xx,
                line,
                color=COLORS["changed"] if drift.get("drifting") else "#6b7280",
                lw=1.4,
                label="fitted trend",
            )
        text, drifting = _drift_text(drift) if drift else ("", False)
        if step:
            pct = step.get("percent")
            size = f" ({pct:+.1f} %)" if isinstance(pct, (int, float)) else ""
            text, drifting = f"step at {str(step.get('at') or '?')[:10]}{size}", True
        title = labels.get(name, name)
        # The name above the drift verdict (right-aligned just over the axes): side
        # by side, a long name ran into the verdict in a narrow panel.
        ax.set_title(title, loc="left", pad=15 if text else 6)
        if text:
            ax.text(
                1.0,
                1.01,
                text,
                transform=ax.transAxes,
                ha="right",
                va="bottom",
                fontsize=9,
                fontweight="bold" if drifting else "normal",
                color=COLORS["changed"] if drifting else "#374151",
            )
        if dated:
            import matplotlib.dates as mdates

            loc = mdates.AutoDateLocator(minticks=3, maxticks=6)
            ax.xaxis.set_major_locator(loc)
            ax.xaxis.set_major_formatter(mdates.ConciseDateFormatter(loc))
        else:
            ax.set_xlabel(str(entry.get("time_unit", "time")))
        ax.ticklabel_format(axis="y", useOffset=False, style="sci", scilimits=(-3, 4))
    handles, lab = axes.ravel()[0].get_legend_handles_labels()
    fig.legend(handles, lab, loc="outside lower center", ncol=len(lab))
    return fig
