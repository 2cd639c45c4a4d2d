"""One-coil levitators: segments, model family and one consensus answer (``levitator``).

What a real levitator log needs before any fit, and how the answer is chosen:

1. **Segments from the data** (:func:`find_levitator_segments`). The levitating
   range is learned, not fixed (:func:`levitation_range`): the reference span
   widened by ``SPREAD_WIDTH`` quiet-levitation standard deviations and twice the
   largest reference step. The tracking-error limit is ``TRACKING_SHARE`` of the
   range. Every excluded piece keeps its reason (lift-off, below/above the range,
   command at a limit, tracking, guard, short). The pieces are then split at
   reference steps, one operating point each.
2. **Candidates**: in the command frame the electromechanical grey box without and
   with a flux lag and a command delay; in the current frame the force laws of
   :data:`~maglevid.identify.greybox.FORCE_LAWS`, each without and with a flux lag;
   every one with a white and with an AR(1) force disturbance in its noise model.
   Each is fitted on one half of the segments (at one operating point alternate
   segments, halves of one segment if there is only one; at several gaps the first
   and second halves of every segment, so each fold keeps the static information)
   and validated by ``k``-step prediction of the gap on the other half, and the
   other way round: the *held-out* ``k``-step fit (mean of the two folds) ranks them.
3. **Consensus**: the best-validated candidate, refitted on every segment, gives
   the point; every candidate whose held-out fit is within ``SUPPORT_MARGIN``
   percentage points of the best counts as equally supported, and the interval is
   the hull of the 95 % intervals of the supported candidates' fits on all
   segments and on each half - it covers the spread between segments and models
   (model uncertainty), not only noise. A fit with a parameter at a bound or not
   identifiable claims no pole and enters neither the point nor the interval. The
   model's constants (``a``, ``k``, ``k0``, ``R``, ``ku``, ...) get the same hull over
   the supported candidates of the chosen force law (:func:`_constants_hull`), and the
   folds that disagree beyond their own intervals are named.
   With no logged excitation (noise only) the pole rests on the noise model: each
   noise model is ranked on its own, the hull covers both, and when one of them
   identifies no pole the answer is "inconclusive: no excitation" (no pole, no interval).

Several recordings of one rig (:func:`fit_levitator_sessions`) are validated and
pooled across sessions: the folds are the sessions.
"""

from __future__ import annotations

import inspect
import logging
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from maglevid.data import ClosedLoopData
from maglevid.diagnose.quality import SegmentReport, find_levitation_segments, split_segments
from maglevid.exceptions import DataError, IdentificationError, MaglevidError
from maglevid.identify.greybox import (
    DISTURBANCES,
    FORCE_LAWS,
    VOLTAGE_NOISE_CEILING,
    fit_greybox_levitator,
    validate_greybox,
    voltage_noise_share,
    with_driver_offset,
)
from maglevid.identify.options import Option
from maglevid.identify.result import IdentificationResult
from maglevid.parallel import map_in_processes

__all__ = [
    "METHODS",
    "dwell_share",
    "find_levitator_segments",
    "fit_levitator",
    "fit_levitator_sessions",
    "gap_reference",
    "levitation_range",
]

log = logging.getLogger(__name__)

#: The range reaches this many quiet-levitation standard deviations beyond the reference.
SPREAD_WIDTH = 10.0
#: Quantile of the 1 s windows' spread read as quiet levitation (robust to a body lost
#: for up to three quarters of the record).
QUIET_QUANTILE = 0.25
#: Tracking-error limit as a share of the levitating range.
TRACKING_SHARE = 0.25
#: Candidates within this many percentage points of the best held-out k-step fit
#: count as equally supported by the data.
SUPPORT_MARGIN = 2.0
#: Force-disturbance noise models of the candidates (greybox.DISTURBANCES).
DEFAULT_DISTURBANCES = ("white", "ar1")
#: Shortest operating-point segment [s] for the grey box.
MIN_SEGMENT_SECONDS = 2.0


def gap_reference(data: ClosedLoopData) -> np.ndarray | None:
    """The logged gap reference [m] (``r``, or the extra signal ``yd``), or ``None``."""
    if data.r is not None and data.r.shape[1] == 1:
        return np.asarray(data.r[:, 0], dtype=float)
    extras = data.metadata.get("extra_signals") if hasattr(data.metadata, "get") else None
    if extras and "yd" in extras:
        return np.asarray(extras["yd"]["values"], dtype=float)
    return None


def _command_limits(data: ClosedLoopData) -> tuple[float, float] | None:
    stated = data.metadata.get("u_range_V") if hasattr(data.metadata, "get") else None
    if stated is not None:
        lo, hi = (float(v) for v in np.asarray(stated).ravel()[:2])
        return lo, hi
    if data.u is None:
        return None
    u = data.u[:, 0]
    lo, hi = float(u.min()), float(u.max())  # a limit is where the command dwells
    return (lo, hi) if min(dwell_share(u, lo), dwell_share(u, hi)) > 0.01 else None


def dwell_share(u: np.ndarray, value: float) -> float:
    """Share of the samples of ``u`` at ``value`` (to 1e-9 of it): a command's dwell at a
    limit."""
    return float(np.mean(np.isclose(u, value, rtol=0, atol=1e-9 * max(1.0, abs(value)))))


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(int), 0]))
    return list(zip(edges[::2], edges[1::2]))


def _window_scale(x: np.ndarray, n: int, keep: np.ndarray | None = None) -> float:
    """``QUIET_QUANTILE`` of the standard deviations over windows of ``n`` samples: the
    spread of quiet levitation, robust to falls and lift-offs. Windows not in ``keep``
    (one flag per window) count as not quiet at all (infinite spread), as a falling
    body's would; with none kept, every window counts as it reads.

    Where the quantile falls between the noisiest kept window and an infinite one (as
    few windows kept as the quantile needs: 5 of 20), it is that kept window's spread:
    the interpolation with an infinite value is NaN, and the range learned from it was
    (nan, nan) (found from outside: the twin with the driver's gain -20 % that lost its
    ball at 5 s, `benchmarks.bench_levitator_isolation`, seed 104, stopped `diagnose` with
    "`position_range` must be (low, high) with low < high; got (nan, nan)").
    """
    m = x.size // n
    if m < 1:
        return float(np.std(x))
    sd = np.std(x[: m * n].reshape(m, n), axis=1)
    if keep is not None and np.count_nonzero(keep) >= QUIET_QUANTILE * m:
        sd = np.where(keep, sd, np.inf)
    with np.errstate(invalid="ignore"):
        q = float(np.quantile(sd, QUIET_QUANTILE))
    return q if np.isfinite(q) else float(np.max(sd[np.isfinite(sd)]))


def _window_means(x: np.ndarray, n: int) -> np.ndarray:
    m = x.size // n
    return x[: m * n].reshape(m, n).mean(axis=1) if m else np.array([np.mean(x)])


def levitation_range(data: ClosedLoopData) -> tuple[tuple[float, float], str]:
    """The gap range [m] counted as levitating, learned from the record, and how.

    ``sigma`` is the lower quartile over 1 s windows of the gap's (with a reference: the
    tracking error's) standard deviation, i.e. the spread of quiet levitation; the
    range is the reference span (without one: the median gap) widened by
    ``SPREAD_WIDTH sigma`` and by twice the largest reference step (a step of ``h``
    may swing the body by up to ``2 h`` in a lightly damped loop).

    A body resting on a stop or stuck at the magnet reads nearly constant, so its
    windows would pass for the quietest levitation (on the UAQ twin with its bottom
    stop, a ball lost late: 7 rest windows of 20 made the quartile 9 um, where the
    same record falling freely gave 147 um). So the range is learned twice: windows
    whose mean gap lies outside the first range are not levitation and count in the
    second as a falling body's do (not quiet), so the quartile does not depend on
    whether a lost body rests or falls.
    """
    y = data.y_control[:, 0]
    ref = gap_reference(data)
    n = max(2, round(1.0 / data.dt))
    err = y if ref is None else y - ref
    if ref is None:
        lo = hi = float(np.median(y))
        step = 0.0
    else:
        lo, hi = float(ref.min()), float(ref.max())
        step = float(np.max(np.abs(np.diff(ref)), initial=0.0))

    def widened(sigma: float) -> tuple[float, float]:
        w = SPREAD_WIDTH * sigma + 2.0 * step
        return (max(lo - w, 1e-12) if lo > 0 else lo - w, hi + w)

    first = widened(_window_scale(err, n))
    means = _window_means(y, n)
    inside = (means >= first[0]) & (means <= first[1])
    sigma = _window_scale(err, n, inside)
    rng = widened(sigma)
    left = int(np.size(inside) - np.count_nonzero(inside)) if inside.any() else 0
    how = (
        f"range {_mm(rng[0])}-{_mm(rng[1])} mm learned from the data: "
        + ("reference span" if ref is not None else "median gap")
        + f" +- ({SPREAD_WIDTH:g} x {1e6 * sigma:.0f} um quiet spread"
        + (f" + 2 x {_mm(step)} mm largest reference step)" if step else ")")
        + (f", {left} of {inside.size} 1 s windows outside the range left out" if left else "")
    )
    return rng, how


def _mm(v: float | None) -> str:
    return "-" if v is None else f"{1e3 * v:.2f}"


def find_levitator_segments(
    data: ClosedLoopData, *, min_seconds: float = MIN_SEGMENT_SECONDS
) -> tuple[SegmentReport, list[tuple[int, int]], str]:
    """Levitating pieces with every exclusion's reason, and the operating-point segments.

    Returns
    -------
    report : SegmentReport
        What :func:`~maglevid.diagnose.quality.find_levitation_segments` found with the
        learned range (``report.excluded``: each piece and its reason).
    segments : list of (start, stop)
        The levitating pieces split at reference steps (one operating point each),
        at least ``min_seconds`` long.
    how : str
        The learned range and thresholds, in words.
    """
    rng, how = levitation_range(data)
    ref = gap_reference(data)
    limits = _command_limits(data)
    track = TRACKING_SHARE * (rng[1] - rng[0])
    rep = find_levitation_segments(
        data.y_control[:, 0],
        dt=data.dt,
        position_range=rng,
        command=None if data.u is None else data.u[:, 0],
        command_limits=limits,
        reference=ref,
        max_tracking_error=track if ref is not None else None,
        exclude_saturation=False,
    )
    n_min = round(min_seconds / data.dt)
    segs = rep.bounds()
    if ref is not None:
        steps = np.r_[False, np.diff(ref) != 0]
        # a continuously moving reference (sine, chirp) is not split: one linearisation
        # at the segment's mean gap
        if steps.mean() < 0.05:
            segs = split_segments(segs, steps, min_length=n_min)
    segs = [s for s in segs if s[1] - s[0] >= n_min]
    how += f"; tracking limit {_mm(track) if ref is not None else '-'} mm"
    return rep, segs, how


#: Segments whose mean gaps differ by more than this [m] are different operating points.
OPERATING_POINT_SPREAD = 3e-4


def _folds(segs: list[tuple[int, int]], y: np.ndarray) -> tuple[list, list]:
    """Two folds of the segments. At one operating point: alternate segments (halves of
    one segment if there is only one). At several gaps: the first and the second half
    of every segment, so that each fold holds every operating point - the static force
    balance across gaps fixes ``a`` in the full fit, and a fold at one gap alone would
    estimate the pole from the dynamics only (on UAQ 'escalon' 62 and 47 rad/s for the
    two gaps against 53 from both)."""
    gaps = [float(np.mean(y[a:b])) for a, b in segs]
    if len(segs) >= 2 and np.ptp(gaps) <= OPERATING_POINT_SPREAD:
        return segs[0::2], segs[1::2]
    halves = [((a, (a + b) // 2), ((a + b) // 2, b)) for a, b in segs]
    return [h[0] for h in halves], [h[1] for h in halves]


#: Why each frame (:func:`fit_levitator`'s ``frame``).
FRAME_NOTES = {
    "command": (
        "frame: command u -> [gap, current] (electromechanical grey box): the measured "
        "current is a noisy, quantised output of the loop, not an exogenous input - as the "
        "input of i -> gap it is an errors-in-variables model whose current gain, and with "
        "it the pole, is biased (Soderstrom 2007); the logged command is known exactly"
    ),
    "current": (
        "frame: measured current i -> gap (mechanical force-law family): no command logged, "
        "or chosen; the current's measurement noise biases the gain (errors in variables)"
    ),
}


def _frame(data: ClosedLoopData, frame: str, current: str) -> str:
    if frame not in ("auto", "command", "current"):
        raise DataError(f"`frame` must be 'auto', 'command' or 'current'; got {frame!r}")
    if frame == "auto":
        return "command" if data.u is not None and data.ny >= 2 else "current"
    if frame == "command" and (data.u is None or data.ny < 2):
        raise DataError("frame='command' needs the command u and the current as y:1")
    return frame


def _candidates(
    force_laws: Sequence[str], flux_lag: Sequence[bool], equilibrium: Sequence[bool]
) -> list[dict[str, Any]]:
    """The grid of grey boxes. Without the equilibrium tie only the dynamics speak:
    at one gap the exponential and inverse-power laws then coincide with the
    inverse-square one (same ``p``, ``b = 2 g/i``), so only the inverse-square and
    the permanent-magnet (current gain free through ``i_m``) laws are kept there."""
    for law in force_laws:
        if law not in FORCE_LAWS:
            raise DataError(f"`force_laws`: {law!r} is not one of {FORCE_LAWS}")
    out = []
    for tie in equilibrium:
        laws = [w for w in force_laws if tie or w in ("inverse-square", "permanent-magnet")]
        out += [
            {"force_law": w, "flux_lag": lag, "use_equilibrium": tie}
            for w in laws
            for lag in flux_lag
        ]
    return out


def _disturbances(disturbance: Sequence[str]) -> list[str]:
    out = list(dict.fromkeys(disturbance))
    bad = [w for w in out if w not in DISTURBANCES]
    if bad or not out:
        raise DataError(f"`disturbance`: {bad or 'none'} given; choose from {DISTURBANCES}")
    return out


def _label(c: dict[str, Any]) -> str:
    noise = " + AR(1) force noise" if c.get("disturbance") == "ar1" else ""
    if c.get("model") == "electromechanical":
        lag = " + flux lag" if c["flux_lag"] else ""
        lag += " + command delay" if c.get("command_delay") else ""
        return f"electromechanical u -> [gap, i] (inverse-square{lag}{noise})"
    tie = "" if c["use_equilibrium"] else ", dynamics only"
    return c["force_law"] + (" + flux lag" if c["flux_lag"] else "") + noise + tie


def _pole_ci(res: IdentificationResult) -> tuple[float, float, float] | None:
    if not res.extras.get("pole_identified", False):
        return None
    p = res.parameters["pole_rad_s"]
    lo, hi = res.confidence_intervals(0.95)["pole_rad_s"]
    if not all(np.isfinite([p, lo, hi])):
        return None
    return float(p), float(lo), float(hi)


#: Quantities each fit reports at a gap of its own (the pole at ``y_ref``; the current gain
#: and equilibrium current at its first segment's): not constants of the model, so their
#: folds' values are not pooled into :func:`_constants_hull`.
_AT_A_GAP = ("pole_rad_s", "pole_z", "current_gain", "i0")


def _constant_intervals(res: IdentificationResult) -> dict[str, tuple[float, float, float]]:
    """``{name: (estimate, lo, hi)}``: the fit's model constants with a finite 95 % interval."""
    ci = res.confidence_intervals(0.95)
    out = {}
    for k, v in res.parameters.items():
        if k in _AT_A_GAP or k not in ci:
            continue
        lo, hi = ci[k]
        if np.all(np.isfinite([v, lo, hi])):
            out[k] = (float(v), float(lo), float(hi))
    return out


def _law(cand: dict[str, Any]) -> str:
    """The force law a candidate's constants belong to (the command frame's is inverse-square)."""
    return str(cand.get("force_law", "inverse-square"))


def _fit(data: ClosedLoopData, segs: list, cand: dict[str, Any], common: dict[str, Any]) -> Any:
    try:
        return fit_greybox_levitator(data, segments=segs, **cand, **common)
    except MaglevidError as exc:
        return exc


def _fold_fit(spec: tuple[Any, ...]) -> tuple[float, Any, dict[str, Any]] | None:
    """Candidate ``cand`` fitted on fold ``j`` and validated on the others: ``(held-out
    k-step fit, fold pole, fold constants)``, ``None`` when the fit fails. One task of
    :func:`_evaluate_all` (module level, one argument: it may run in a worker)."""
    folds, j, cand, common, k_step = spec
    dj, sj = folds[j]
    res = _fit(dj, sj, cand, common)
    if isinstance(res, Exception):
        return None
    pole = _pole_ci(res)
    # a fold that claims no pole (a parameter at a bound or not identifiable) gives
    # no interval of its constants either (a = 2 +- 2036 m on UAQ 'senoidal')
    params = _constant_intervals(res) if pole is not None else {}
    held = [validate_greybox(res, dk, sk, k_step=k_step) for k, (dk, sk) in enumerate(folds)
            if k != j]  # fmt: skip
    return float(np.mean(held)), pole, params


def _richness(cand: dict[str, Any]) -> int:
    """How many optional parts (flux lag, command delay, AR(1) noise, no equilibrium tie)
    a candidate has: a proxy of its fit's time."""
    parts = (
        cand.get("flux_lag"),
        cand.get("command_delay"),
        cand.get("disturbance") == "ar1",
        cand.get("use_equilibrium") is False,
    )
    return sum(bool(p) for p in parts)


def _evaluate_all(
    folds: list[tuple[ClosedLoopData, list]],
    cands: list[dict[str, Any]],
    common: dict[str, Any],
    k_step: int,
    workers: int | None,
) -> list[dict[str, Any]]:
    """Each candidate fitted on each fold and validated on the others: its mean held-out
    k-step fit, fold poles and fold constants. The fold fits are nine tenths of a
    levitator identification and independent: they run on ``workers`` processes
    (:func:`maglevid.parallel.map_in_processes`), one task per candidate and fold."""
    specs = [(folds, j, cand, common, k_step) for cand in cands for j in range(len(folds))]
    # the richest candidates first: their fits take longest (command delay + AR(1) noise
    # 8.5 s of a 25 s twin record's evaluation), and a worker that starts one last keeps
    # every other waiting
    order = sorted(range(len(specs)), key=lambda t: -_richness(specs[t][2]))
    done, _, _ = map_in_processes(_fold_fit, [specs[t] for t in order], workers, spawn=False)
    outs: list[Any] = [None] * len(specs)
    for t, out in zip(order, done):
        outs[t] = out
    rows = []
    for c in range(len(cands)):
        got = outs[c * len(folds) : (c + 1) * len(folds)]
        scores = [float("nan") if o is None else o[0] for o in got]
        rows.append({"validation": float(np.mean(scores)) if scores else float("nan"),
                     "fold_poles": [o[1] for o in got if o is not None],
                     "fold_params": [o[2] for o in got if o is not None]})  # fmt: skip
    return rows


def fit_levitator(
    data: ClosedLoopData,
    *,
    segments: Sequence[Sequence[int]] | None = None,
    force_laws: Sequence[str] = FORCE_LAWS,
    flux_lag: Sequence[bool] = (False, True),
    equilibrium: Sequence[bool] = (True, False),
    command_delay: Sequence[bool] = (False, True),
    disturbance: Sequence[str] = DEFAULT_DISTURBANCES,
    y_ref: float | None = None,
    k_step: int = 5,
    m: float = 0.018,
    gap: str = "y:0",
    current: str = "y:1",
    command: str = "u:0",
    frame: str = "auto",
    covariance: str = "sandwich",
    workers: int | None = None,
) -> IdentificationResult:
    """The levitator's unstable pole: model chosen by held-out prediction, one consensus.

    Parameters
    ----------
    data : ClosedLoopData
        A one-coil levitator log with the gap and the coil current as outputs.
    segments : list of (start, stop), optional
        Operating-point segments (default: :func:`find_levitator_segments`).
    force_laws : sequence of str
        Candidate force laws (default: all of ``FORCE_LAWS``).
    flux_lag : sequence of bool
        Fit each law without and/or with a flux lag.
    equilibrium : sequence of bool
        Fit each law with and/or without the tie of the current level to the law's
        equilibrium (without: the dynamics alone, ``i0`` = the segment's mean current).
    command_delay : sequence of bool
        Command frame: fit each model without and/or with an estimated delay (within
        one sample) between the logged command and the coil.
    disturbance : sequence of {"white", "ar1"}
        Fit each model with a held white and/or an AR(1) force disturbance in its noise
        model (:func:`~maglevid.identify.greybox.fit_greybox_levitator`).
    y_ref : float, optional
        Gap at which the pole is reported (default: mean gap of the segments).
    k_step : int
        Horizon of the validation (samples ahead).
    m : float
        Mass [kg] (only ``K/m`` enters: the pole does not depend on it).
    gap, current, command : str
        Channels of the gap [m], the coil current [A] and the command [V].
    frame : {"auto", "command", "current"}
        Which signal is the model's input. ``"command"``: the logged command drives
        the electromechanical grey box ``u -> [gap, current]`` and the measured
        current is an output; ``"current"``: the measured current drives the
        mechanical force-law family ``i -> gap``. ``"auto"`` (default): the command
        when it is logged (see :data:`FRAME_NOTES` for why).
    covariance : {"sandwich", "fisher"}
        Covariance of every grey-box fit, and so of the intervals the consensus hull
        is made of (:func:`~maglevid.identify.greybox.fit_greybox_levitator`): the
        sandwich (default) holds under coloured residuals, Fisher assumes white ones.
    workers : int, optional
        Processes for the candidates' fits, nine tenths of the work (default: every
        available core; 1: in this process; :func:`maglevid.parallel.map_in_processes`).
        Used where workers can be forked - Linux, one BLAS thread
        (``OPENBLAS_NUM_THREADS=1``, as ``make test`` runs) and no other Python thread -
        else the fits run in this process. The result does not depend on it.

    Returns
    -------
    IdentificationResult
        The best-validated grey box refitted on every segment, with ``pole_rad_s``
        replaced by the consensus and its interval (``extras["consensus"]``) and the
        per-candidate table (``extras["candidates"]``).
    """
    options = {k: v for k, v in locals().items() if k not in ("data", "segments")}
    return _fit_sessions([data], None if segments is None else [segments], **options)


def fit_levitator_sessions(
    sessions: Sequence[ClosedLoopData],
    *,
    segments: Sequence[Sequence[Sequence[int]]] | None = None,
    **options: Any,
) -> IdentificationResult:
    """:func:`fit_levitator` on several recordings of one rig: validated across sessions.

    ``options`` are :func:`fit_levitator`'s. With one session the folds are
    alternate segments; with several, each session is a fold (a model must predict
    the sessions it was not fitted on). The final fit pools every session's segments.
    """
    known = {
        n: p.default
        for n, p in inspect.signature(fit_levitator).parameters.items()
        if p.kind is inspect.Parameter.KEYWORD_ONLY and n != "segments"
    }
    unknown = set(options) - set(known)
    if unknown:
        raise DataError(f"unknown option(s) {sorted(unknown)}; known: {sorted(known)}")
    return _fit_sessions(sessions, segments, **{**known, **options})


def _fit_sessions(
    sessions: Sequence[ClosedLoopData],
    segments: Sequence[Sequence[Sequence[int]]] | None,
    *,
    force_laws: Sequence[str],
    flux_lag: Sequence[bool],
    equilibrium: Sequence[bool],
    command_delay: Sequence[bool],
    disturbance: Sequence[str],
    y_ref: float | None,
    k_step: int,
    m: float,
    gap: str,
    current: str,
    command: str,
    frame: str,
    covariance: str,
    workers: int | None,
) -> IdentificationResult:
    if not sessions:
        raise DataError("no recordings given")
    dts = {float(d.dt) for d in sessions}
    if len(dts) > 1:
        raise DataError(f"the sessions have different sample times {sorted(dts)}")
    seg_lists, exclusions = [], []
    for j, d in enumerate(sessions):
        if segments is not None:
            seg_lists.append([(int(a), int(b)) for a, b in segments[j]])
            exclusions.append({"range": "given", "excluded": []})
            continue
        rep, segs, how = find_levitator_segments(d)
        seg_lists.append(segs)
        exclusions.append(_exclusion_summary(rep, how))
    if not any(seg_lists):
        raise IdentificationError(
            "no levitating segment of at least "
            f"{MIN_SEGMENT_SECONDS} s: " + "; ".join(e["range"] for e in exclusions)
        )
    pooled, pooled_segs = _pool(sessions, seg_lists)
    if len(sessions) > 1:
        folds = [(d, s) for d, s in zip(sessions, seg_lists) if s]
    else:
        folds = [(pooled, f) for f in _folds(pooled_segs, pooled.y_control[:, 0])]
    y = pooled.y_control[:, 0]
    y_ref = (
        float(np.mean(np.concatenate([y[a:b] for a, b in pooled_segs])))
        if y_ref is None
        else y_ref
    )
    common = {"y_ref": y_ref, "m": m, "gap": gap, "current": current, "covariance": covariance}
    frame = _frame(pooled, frame, current)
    cands = (
        [
            {
                "model": "electromechanical",
                "command": command,
                "flux_lag": lag,
                "command_delay": dl,
            }
            for dl in command_delay
            for lag in flux_lag
        ]
        if frame == "command"
        else _candidates(force_laws, flux_lag, equilibrium)
    )
    cands = [{**c, "disturbance": w} for w in _disturbances(disturbance) for c in cands]
    if len(folds) > 1:
        evs = _evaluate_all(folds, cands, common, k_step, workers)
    else:
        evs = [{"validation": float("nan"), "fold_poles": [], "fold_params": []}] * len(cands)
    rows = [{"candidate": cand, **ev} for cand, ev in zip(cands, evs)]
    quiet = [j for j, (d, sl) in enumerate(zip(sessions, seg_lists)) if sl and _noise_only(d, sl)]
    noise_only = len(quiet) == sum(bool(sl) for sl in seg_lists)
    res = _consensus(
        pooled,
        pooled_segs,
        rows,
        common,
        k_step,
        exclusions,
        len(sessions),
        noise_only,
        workers,
    )
    if frame == "command":
        # the consensus widened R's and ku's intervals (the hull): v0's again
        res = with_driver_offset(res, pooled, pooled_segs, command, current)
    notes = [FRAME_NOTES[frame]]
    if quiet:
        notes.append(
            "no logged excitation in session(s) "
            + ", ".join(str(j + 1) for j in quiet)
            + " (no r; one reference value, or none, over all segments): unless an "
            "unlogged dither drives the loop (identify.excitation.recover_excitation finds "
            "one), only noise does, and the estimate rests on the noise model - it can be "
            "biased beyond its interval (docs/real-rigs.md: UAQ 'constante')"
        )
    return replace(
        res, notes=(*notes, *res.notes), extras={**res.extras, "noise_only_sessions": quiet}
    )


def _noise_only(data: ClosedLoopData, segs: list[tuple[int, int]]) -> bool:
    """No excitation ``r`` and one reference value over all the segments (a step between
    two segments counts: it excites the loop at the second one's start)."""
    ref = gap_reference(data)
    if data.r is not None and (ref is None or data.r.shape[1] != 1):
        return False
    if ref is None:
        return True
    return float(np.ptp(np.concatenate([ref[a:b] for a, b in segs]))) == 0.0


def _exclusion_summary(rep: SegmentReport, how: str) -> dict[str, Any]:
    return {
        "range": how,
        "excluded": [
            {"start_s": iv.start * rep.dt, "stop_s": iv.stop * rep.dt, "reason": iv.reason}
            for iv in rep.excluded
        ],
        "excluded_seconds": rep.excluded_by_reason(),
    }


def _pool(
    sessions: Sequence[ClosedLoopData], seg_lists: list[list[tuple[int, int]]]
) -> tuple[ClosedLoopData, list[tuple[int, int]]]:
    """One record of the sessions end to end; segments never cross a session boundary."""
    if len(sessions) == 1:
        return sessions[0], seg_lists[0]
    ys, us, segs, off = [], [], [], 0
    for d, sl in zip(sessions, seg_lists):
        ys.append(d.y_control)
        us.append(d.u)
        segs += [(a + off, b + off) for a, b in sl]
        off += d.n_samples
    first = sessions[0]
    pooled = ClosedLoopData(
        y=np.vstack(ys),
        u=np.vstack(us),
        dt=first.dt,
        names={k: v for k, v in first.names.items() if k in ("y", "u")},
        units={k: v for k, v in first.units.items() if k in ("y", "u")},
    )
    return pooled, segs


def _consensus(
    data: ClosedLoopData,
    segs: list[tuple[int, int]],
    rows: list[dict[str, Any]],
    common: dict[str, Any],
    k_step: int,
    exclusions: list[dict[str, Any]],
    n_sessions: int,
    noise_only: bool = False,
    workers: int | None = None,
) -> IdentificationResult:
    """Refit every candidate on all segments; the best-validated one with a pole gives the
    point, the supported ones (within ``SUPPORT_MARGIN`` of it) the hull interval.

    With no logged excitation (``noise_only``) the pole rests on the noise model, so each
    noise model (``disturbance``) is ranked on its own and the hull covers every noise
    model's supported candidates; when one noise model identifies no pole the answer is
    inconclusive (:func:`_inconclusive`)."""
    scores = np.array([r["validation"] for r in rows])
    noise = [r["candidate"].get("disturbance", "white") for r in rows]
    groups = [list(range(len(rows)))]
    if noise_only and len(set(noise)) > 1:
        groups = [[j for j in groups[0] if noise[j] == w] for w in dict.fromkeys(noise)]
    fits: list[Any] = [None] * len(rows)
    for grp in groups:
        sub = _refit(data, segs, [rows[j] for j in grp], scores[grp], common, workers)
        for j, f in zip(grp, sub):
            fits[j] = f
    fulls = [None if isinstance(f, (Exception, str)) else _pole_ci(f) for f in fits]
    ok = np.array([f is not None for f in fulls])
    if not ok.any():
        raise IdentificationError(
            "no candidate model gives an identifiable pole on these segments: "
            + "; ".join(f"{_label(r['candidate'])}: {_why_not(f)}" for r, f in zip(rows, fits))
        )
    support = np.zeros(len(rows), dtype=bool)
    for grp in groups:
        g = np.array(grp)
        ranked = ok[g] & np.isfinite(scores[g])
        if ranked.any():
            best_score = float(np.max(scores[g][ranked]))
            support[g] = ranked & (scores[g] >= best_score - SUPPORT_MARGIN)
        else:  # nothing to validate on (one fold): every identified candidate counts
            support[g] = ok[g]
    silent = [noise[grp[0]] for grp in groups if not support[grp].any()] if len(groups) > 1 else []
    order = sorted(
        range(len(rows)),
        key=lambda j: (not support[j], not ok[j], -np.nan_to_num(scores[j], nan=-np.inf)),
    )
    table, pool = [], []
    for j in order:
        r, full = rows[j], fulls[j]
        table.append({
            "model": _label(r["candidate"]),
            "held_out_fit_percent": r["validation"],
            "supported": bool(support[j]),
            "pole_rad_s": None if full is None else full[0],
            "ci95": None if full is None else [full[1], full[2]],
            "fold_poles": [None if f is None else f[0] for f in r["fold_poles"]],
            "note": _why_not(fits[j]),
        })  # fmt: skip
        if support[j]:
            pool += [full] + [f for f in r["fold_poles"] if f is not None]
    best = fits[order[0]]
    point = float(best.parameters["pole_rad_s"])
    lo = min(p[1] for p in pool)
    hi = max(p[2] for p in pool)
    law = _law(rows[order[0]]["candidate"])
    same = [j for j in order if support[j] and _law(rows[j]["candidate"]) == law]
    hull = _constants_hull(
        best, [fits[j] for j in same], [rows[j].get("fold_params", []) for j in same]
    )
    coil = _coil_circuit(data, segs, rows, fits, order, common)
    best = _widened(best, hull, n_sessions)
    res = _with_consensus(best, point, lo, hi, table, exclusions, n_sessions, k_step, data.dt)
    if coil is not None:
        res = replace(
            res,
            notes=(*res.notes, *coil.pop("notes")),
            extras={**res.extras, "coil_circuit": coil},
        )
    return _inconclusive(res, silent) if silent else res


#: The constants the coil circuit's ratios R/L, ku/L at a gap are made of (eq. (L1)).
COIL_CONSTANTS = ("R", "ku", "k0", "a", "k")


def _coil_circuit(
    data: ClosedLoopData,
    segs: list[tuple[int, int]],
    rows: list[dict[str, Any]],
    fits: list[Any],
    order: list[int],
    common: dict[str, Any],
) -> dict[str, Any] | None:
    """Which fit the coil circuit's constants come from (``extras["coil_circuit"]``): the
    chosen one, unless its coil equation is left to noise
    (:func:`~maglevid.identify.greybox.voltage_noise_share`); then the best-ranked
    candidate whose fit identifies its pole with a sound noise model, refitted on all
    segments if it was not. Each with its own covariance (not the hull's widening, which
    wrecks the ratios' cancellation; diagnose.levitator adds the coil circuit's model
    error). ``None`` where the chosen model has no coil (the current frame)."""
    chosen = fits[order[0]]
    if not all(n in chosen.parameters for n in COIL_CONSTANTS):
        return None
    for j in order:
        if isinstance(fits[j], str):  # not refitted on all segments: its score was too low
            # (one at a time: a batch on the workers waits for fits that the first sound
            # one makes needless)
            fits[j] = _fit(data, segs, rows[j]["candidate"], common)
        f = fits[j]
        if isinstance(f, Exception) or _pole_ci(f) is None:
            continue
        share = voltage_noise_share(f)
        if share is not None and share > VOLTAGE_NOISE_CEILING:
            continue
        idx = [list(f.parameters).index(n) for n in COIL_CONSTANTS]
        cov = np.asarray(f.covariance, dtype=float)[np.ix_(idx, idx)]
        label = _label(rows[j]["candidate"])
        notes = []
        if j != order[0]:
            notes.append(
                f"coil circuit (R, ku, k0 and the ratios R/L, ku/L) from {label} (held-out fit "
                f"{rows[j]['validation']:.1f} %): the chosen model's coil equation is left to "
                f"noise (voltage disturbance {voltage_noise_share(chosen):.2g} x what the "
                "record's changes allow)"
            )
        return {"model": label, "chosen": j == order[0], "names": list(COIL_CONSTANTS),
                "values": [float(f.parameters[n]) for n in COIL_CONSTANTS],
                "covariance": cov.tolist(), "voltage_noise_share": share,
                "notes": notes}  # fmt: skip
    why = (
        "every candidate that identifies its pole leaves its coil equation to noise (voltage "
        f"disturbance above {VOLTAGE_NOISE_CEILING:g} x what the record's changes allow): "
        "the coil circuit is not determined by this record"
    )
    return {"model": None, "chosen": False, "why": why, "notes": [why]}


def _constants_hull(
    best: IdentificationResult, fits: list[Any], folds: list[list[dict[str, Any]]]
) -> dict[str, dict[str, Any]]:
    """The model constants' intervals as the pole's: the hull of the 95 % intervals of the
    supported candidates of the chosen force law, on all segments and on each fold.

    Each fit's own interval is its noise's (sandwich): on the UAQ sessions those of ``a``,
    ``k``, ``R``, ``ku`` excluded each other from session to session, and the three sessions'
    pooled fit excluded every session's own estimate (``R`` 1.459 +- 0.008 against 2.60, 1.39
    and 1.76 ohm). Fits that claim no pole enter neither hull (their intervals are those
    of parameters the fold cannot determine). ``folds[0]`` are the chosen model's folds;
    a constant whose folds' intervals do not overlap is marked ``"disagree"``.
    """
    out: dict[str, dict[str, Any]] = {}
    own = _constant_intervals(best)
    fits = [f for f in fits if _pole_ci(f) is not None]  # as the pole's hull
    for name, (_, lo, hi) in own.items():
        ivs = [(lo, hi)]
        for f in fits:
            c = _constant_intervals(f).get(name)
            ivs += [c[1:]] if c else []
        ivs += [fp[name][1:] for fl in folds for fp in fl if name in fp]
        chosen = [fp[name] for fp in (folds[0] if folds else []) if name in fp]
        out[name] = {
            "ci95": [min(a for a, _ in ivs), max(b for _, b in ivs)],
            "fit_ci95": [lo, hi],
            "folds": [list(c) for c in chosen],
            "disagree": len(chosen) > 1 and max(c[1] for c in chosen) > min(c[2] for c in chosen),
        }
    return out


def _widened(
    best: IdentificationResult, hull: dict[str, dict[str, Any]], n_sessions: int
) -> IdentificationResult:
    """``best`` with each constant's standard error read off its hull (the larger side /
    1.96, as the pole's), its correlations kept (the covariance scaled on both sides)."""
    if not hull or best.covariance is None:
        return best
    names = list(best.parameters)
    f = np.ones(len(names))
    se = best.std_errors()
    for name, h in hull.items():
        p, (lo, hi) = best.parameters[name], h["ci95"]
        # a few ulps over, so that p +- 1.96 se holds the hull after rounding
        wide = max(p - lo, hi - p) / 1.959963984540054 * (1.0 + 8.0 * np.finfo(float).eps)
        if se[name] > 0 and wide > se[name]:
            f[names.index(name)] = wide / se[name]
    cov = np.asarray(best.covariance, dtype=float) * np.outer(f, f)
    folds = "sessions" if n_sessions > 1 else "halves of the segments"
    names_ = ", ".join(hull)
    if any(h["folds"] for h in hull.values()):
        wider = f"; up to {float(np.max(f)):.3g}x the fit's own" if np.max(f) > 1 else ""
        notes = [
            f"intervals of the model's constants ({names_}): the hull of the supported "
            "models' 95 % intervals on all segments and on each fold, as the pole's - they "
            f"cover the spread between the {folds}, not only noise (std. error = the larger "
            f"side / 1.96{wider})"
        ]
    else:
        notes = [
            f"intervals of the model's constants ({names_}): no fold of the chosen model "
            f"identifies them on its own, so the spread between the {folds} is not known; "
            "the intervals are the fit's own (noise only) and need not hold another "
            "session's value"
        ]
    split = [n for n, h in hull.items() if h["disagree"]]
    values = ", ".join(f"{n} ({_fold_values(hull[n])})" for n in split)
    if split and n_sessions > 1:
        notes.append(
            f"the sessions disagree beyond their own 95 % intervals on {values}: the rig "
            "differs between them, or the model leaves out something each compensates for "
            "differently; the pooled value is not one session's"
        )
    elif split:  # 12 % of healthy simulated records (UAQ twin): no evidence of a change
        notes.append(
            f"the two halves of the record give {values}, further apart than their own "
            "(noise-only) 95 % intervals allow: those understate the spread, which the "
            "intervals above cover; it is not by itself a sign that the rig changed"
        )
    return replace(
        best,
        covariance=cov,
        notes=(*best.notes, *notes),
        extras={
            **best.extras,
            "constants_ci95": hull,
            "constants_disagree": split,
            # the fit's own covariance, for quantities the widening would wreck: each
            # constant is widened by its own factor (up to 1e4x where a candidate cannot
            # determine R, ku, k0), which keeps the correlations but not the near-exact
            # cancellation in R/L and ku/L that the data do fix (diagnose.levitator)
            "covariance_fit": None if best.covariance is None else best.covariance.tolist(),
        },
    )


def _fold_values(h: dict[str, Any]) -> str:
    return " / ".join(f"{c[0]:.4g}" for c in h["folds"])


_NOISE_WORDS = {"white": "white", "ar1": "AR(1)"}


def _inconclusive(res: IdentificationResult, silent: list[str]) -> IdentificationResult:
    """A record with no excitation whose pole one of the noise models cannot identify: no
    pole and no interval, the candidates' table kept, and what would resolve it."""
    names = list(res.parameters)
    cov = np.array(res.covariance, dtype=float, copy=True)
    params = dict(res.parameters)
    for key in ("pole_rad_s", "pole_z"):
        if key in names:
            j = names.index(key)
            cov[j, :] = cov[:, j] = np.nan
            params[key] = float("nan")
    c = res.extras["consensus"]
    why = (
        "inconclusive: no excitation - only noise drives the loop, so the pole rests on the "
        f"noise model, and with the {' and '.join(_NOISE_WORDS[w] for w in silent)} "
        "force-disturbance model no "
        f"candidate identifies it (the other gives {c['pole_rad_s']:.4g} rad/s "
        f"[{c['ci95'][0]:.4g}, {c['ci95'][1]:.4g}]; see the candidates' fold poles); no pole "
        "claimed. What would resolve it: a reference step or a dither in the command "
        "(logged, or recoverable from a stated controller law), or this session identified "
        "together with excited sessions of the rig"
    )
    consensus = {**c, "pole_rad_s": float("nan"), "ci95": [float("nan")] * 2,
                 "inconclusive": why, "noise_only_estimate": c["pole_rad_s"],
                 "noise_only_ci95": c["ci95"]}  # fmt: skip
    return replace(
        res,
        parameters=params,
        covariance=cov,
        notes=(why, res.notes[0], *res.notes[2:]),  # in place of the consensus line
        extras={**res.extras, "consensus": consensus, "pole_identified": False},
    )


def _refit(
    data: ClosedLoopData,
    segs: list[tuple[int, int]],
    rows: list[dict[str, Any]],
    scores: np.ndarray,
    common: dict[str, Any],
    workers: int | None = None,
) -> list[Any]:
    """Every candidate that can still be supported, refitted on all segments, best
    held-out score first. Once a candidate with an identifiable pole has set the best
    score, one more than ``SUPPORT_MARGIN`` points below it can neither give the point
    nor enter the interval: it is not refitted (a string says why). Without any
    finite score every candidate is refitted (each identified one counts).

    In waves on ``workers`` processes, the same fits as one by one: while no best is known,
    every unfitted candidate within the margin of the first unfitted one's score (one by
    one, each of them would be fitted: the best's score is at most that one's); once one
    is known, every unfitted candidate within the margin of it."""
    fits: list[Any] = [None] * len(rows)
    order = sorted(range(len(rows)), key=lambda j: -np.nan_to_num(scores[j], nan=-np.inf))
    best = None
    while True:
        todo = [j for j in order if fits[j] is None]
        if not todo:
            return fits
        if best is None:
            ref = scores[todo[0]]
            wave = [j for j in todo if j == todo[0] or scores[j] >= ref - SUPPORT_MARGIN]
        else:
            wave = [j for j in todo if scores[j] >= best - SUPPORT_MARGIN]
            for j in todo:
                if j not in wave:
                    fits[j] = (
                        f"not refitted on all segments: held-out fit more than {SUPPORT_MARGIN} "
                        "points below the best"
                    )
        for j, f in zip(wave, _fit_many(data, segs, [rows[j] for j in wave], common, workers)):
            fits[j] = f
        for j in order:  # the best: the first by score, fitted, with an identified pole
            f = fits[j]
            if best is None and np.isfinite(scores[j]) and isinstance(f, IdentificationResult):
                if _pole_ci(f) is not None:
                    best = float(scores[j])
            if f is None:
                break


def _fit_spec(spec: tuple[Any, ...]) -> Any:
    """:func:`_fit` of one candidate (a worker's task: module level, one argument)."""
    return _fit(*spec)


def _fit_many(
    data: ClosedLoopData,
    segs: list[tuple[int, int]],
    rows: list[dict[str, Any]],
    common: dict[str, Any],
    workers: int | None,
) -> list[Any]:
    """The candidates of ``rows`` fitted on all segments, on ``workers`` processes."""
    specs = [(data, segs, r["candidate"], common) for r in rows]
    return map_in_processes(_fit_spec, specs, workers, spawn=False)[0]


def _why_not(res: Any) -> str:
    if res is None:
        return ""
    if isinstance(res, (Exception, str)):
        return str(res)
    return "; ".join(n for n in res.notes if n.startswith("no pole"))


def _with_consensus(
    best: IdentificationResult,
    point: float,
    lo: float,
    hi: float,
    table: list[dict[str, Any]],
    exclusions: list[dict[str, Any]],
    n_sessions: int,
    k_step: int,
    dt: float,
) -> IdentificationResult:
    names = list(best.parameters)
    cov = np.array(best.covariance, dtype=float, copy=True)
    j = names.index("pole_rad_s")
    # conservative symmetric reading of the hull: point +- 1.96 se contains [lo, hi]
    se = max(point - lo, hi - point) / 1.959963984540054
    cov[j, :] = cov[:, j] = 0.0
    cov[j, j] = se**2
    if "pole_z" in names:  # z = exp(p dt): the same interval, by the delta method
        jz = names.index("pole_z")
        cov[jz, :] = cov[:, jz] = 0.0
        cov[jz, jz] = (best.parameters["pole_z"] * dt * se) ** 2
        cov[j, jz] = cov[jz, j] = best.parameters["pole_z"] * dt * se**2
    params = dict(best.parameters)
    n_sup = sum(t["supported"] for t in table)
    chosen = table[0]["model"]
    notes = [
        f"model chosen by {k_step}-step prediction on held-out "
        + ("sessions" if n_sessions > 1 else "segments")
        + f": {chosen} (held-out fit {table[0]['held_out_fit_percent']:.1f} %); "
        f"{n_sup} of {len(table)} candidates within {SUPPORT_MARGIN} points count as supported"
        + (
            " (the score ranks the candidates: below 0 % the 5-step errors exceed the "
            "signals' own variation about their means, as on a quiet, quantised record; "
            "not a failed fit)"
            if table[0]["held_out_fit_percent"] < 0
            else ""
        ),
        f"consensus pole {point:.4g} rad/s, 95 % interval [{lo:.4g}, {hi:.4g}]: the hull of the "
        "supported models' intervals on all segments and on each fold (model uncertainty); "
        "pole_rad_s std. error = the larger side of the hull / 1.96 (symmetric, conservative)",
        *best.notes,
    ]
    extras = dict(best.extras)
    extras.update(
        consensus={"pole_rad_s": point, "ci95": [lo, hi], "chosen_model": chosen,
                   "k_step": k_step, "n_sessions": n_sessions},
        candidates=table,
        segments_excluded=exclusions,
    )  # fmt: skip
    return replace(
        best,
        method="levitator",
        parameters=params,
        covariance=cov,
        notes=tuple(notes),
        extras=extras,
        options={**best.options, "candidates": [t["model"] for t in table]},
    )


METHODS = {"levitator": fit_levitator}
#: Its options, declared once (maglevid.identify.options; defaults: fit_levitator's).
OPTIONS = {
    "levitator": (
        Option("segments", "segments", "operating-point segments (default: found)"),
        Option("force_laws", "strs", "candidate force laws", choices=FORCE_LAWS),
        Option("flux_lag", "bools", "fit each law without and/or with a flux lag"),
        Option("equilibrium", "bools", "with and/or without the equilibrium-current tie"),
        Option("command_delay", "bools", "command-input candidates without and/or with an "
               "estimated command-to-coil delay"),
        Option("disturbance", "strs", "force-disturbance noise models of the candidates: "
               "white and/or ar1", choices=DISTURBANCES),
        Option("y_ref", "float", "gap at which the pole is reported (default: mean gap)",
               unit="m"),
        Option("k_step", "int", "horizon of the validation, samples ahead", low=1),
        Option("m", "float", "ball mass (the pole does not depend on it)", low=0,
               low_open=True, unit="kg"),
        Option("gap", "channel", "channel of the gap [m]"),
        Option("current", "channel", "channel of the coil current [A]"),
        Option("command", "channel", "channel of the command [V]"),
        Option("frame", "str", "model input: the command, the measured current, or auto",
               choices=("auto", "command", "current")),
        Option("covariance", "str", "per-fit covariance: sandwich (coloured residuals) or "
               "fisher (white)", choices=("sandwich", "fisher")),
        Option("workers", "int", "processes for the candidates' evaluation (default: every "
               "core; 1: this process); the result does not depend on it", low=1),
    )
}  # fmt: skip
