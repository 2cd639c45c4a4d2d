"""Data-quality checks that come before any diagnosis of a bearing recording.

Each check returns a :class:`~maglevid.diagnose.diagnosis.QualityCheck`; a failed
blocking check turns the verdict into "cannot diagnose, because ...", which is a
better answer than a wrong one. Thresholds are module constants, documented with
the reason for their value.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from maglevid.data import ClosedLoopData
from maglevid.diagnose.diagnosis import QualityCheck

__all__ = [
    "MIN_SAMPLES",
    "check_channels_move",
    "check_excitation",
    "check_feedback_consistency",
    "check_input_identity",
    "check_length",
    "check_levitation",
    "check_output_response",
    "check_sample_time",
    "check_saturation",
    "check_units",
    "run_checks",
]

#: Fewest control periods for a diagnosis. The ARX regression of the AMB methods
#: has up to ~40 regressors; 50 samples per regressor keep the relative standard
#: errors of v_i near 1/sqrt(2000) ~ 2 % even at unit signal-to-noise ratio.
MIN_SAMPLES = 2000

#: Excitation: rms of r relative to rms of u must exceed this (1 %). Below it the
#: loop runs on noise alone and the estimates are dominated by it.
MIN_EXCITATION_RATIO = 0.01

#: Saturation: fraction of samples pinned at the extreme value of an input.
MAX_SATURATED_FRACTION = 0.005

#: Lost levitation: |x| beyond this fraction of the nominal air gap x0 means the
#: rotor touched down (retainer bearings are typically at half the gap).
MAX_DISPLACEMENT_FRACTION = 0.5

#: Logged feedback versus the stated controller: relative rms mismatch allowed
#: (digital controllers replay exactly; 1e-3 leaves room for logging quantisation).
MAX_FEEDBACK_MISMATCH = 1e-3


def check_length(data: ClosedLoopData, *, min_samples: int = MIN_SAMPLES) -> QualityCheck:
    n = data.n_samples
    return QualityCheck(
        name="record length",
        passed=n >= min_samples,
        value=float(n),
        threshold=float(min_samples),
        message=(
            f"{n} control periods ({n * data.dt:.3g} s)"
            + ("" if n >= min_samples else f": too short, at least {min_samples} are needed")
        ),
    )


def check_excitation(
    data: ClosedLoopData, *, min_ratio: float = MIN_EXCITATION_RATIO
) -> QualityCheck:
    """Persistent excitation: the known signal r must be a visible part of u."""
    if data.r is None:
        return QualityCheck(
            name="excitation",
            passed=False,
            value=0.0,
            threshold=min_ratio,
            message="no excitation r in the recording: the closed-loop methods need a known r",
        )
    u = data.u if data.u is not None else data.with_plant_input().u
    r_rms = float(np.sqrt(np.mean(np.square(data.r - data.r.mean(axis=0)))))
    u_rms = float(np.sqrt(np.mean(np.square(u - u.mean(axis=0)))))
    ratio = r_rms / u_rms if u_rms > 0 else 0.0
    ok = ratio >= min_ratio
    return QualityCheck(
        name="excitation",
        passed=ok,
        value=ratio,
        threshold=min_ratio,
        message=(
            f"excitation is {100 * ratio:.2g} % of the plant input (rms)"
            + ("" if ok else ": too little excitation to identify the plant")
        ),
    )


def check_saturation(
    data: ClosedLoopData,
    *,
    limits: Any = None,
    max_fraction: float = MAX_SATURATED_FRACTION,
) -> QualityCheck:
    """Inputs pinned at a limit (given, or the observed extreme repeated many times)."""
    u = data.u if data.u is not None else data.with_plant_input().u
    if limits is None:
        limits = data.loop.get("u_limits") if hasattr(data.loop, "get") else None
    worst = 0.0
    for j in range(u.shape[1]):
        col = u[:, j]
        if limits is not None:
            lo, hi = np.asarray(limits, dtype=float).reshape(-1, 2)[min(j, len(limits) - 1)]
            frac = float(np.mean((col <= lo) | (col >= hi)))
        else:
            # Without stated limits, a clipped signal shows its extreme value many times.
            span = float(np.ptp(col)) or 1.0
            top = np.mean(col >= col.max() - 1e-9 * span)
            bot = np.mean(col <= col.min() + 1e-9 * span)
            frac = float(max(top, bot)) if max(top, bot) > 2.0 / col.size else 0.0
        worst = max(worst, frac)
    ok = worst <= max_fraction
    return QualityCheck(
        name="saturation",
        passed=ok,
        value=worst,
        threshold=max_fraction,
        message=(
            f"{100 * worst:.2g} % of samples at an input limit"
            + ("" if ok else ": the amplifier saturates, so the loop is not linear")
        ),
    )


#: A sensor clipped at its range piles its samples up on the extreme value; a free
#: (even coarsely quantised) signal thins out towards its extremes. An output is called
#: clipped when this fraction of its samples sits on one extreme and that extreme holds
#: :data:`CLIP_PILE_UP` times the samples of the next level in. (A Gaussian tail thins
#: outwards and a sine's arcsine density gives its top level ~1.4x the next; a clip on a
#: coarse ADC whose clipped level holds fewer than 5x its neighbour is not caught.)
MAX_CLIPPED_FRACTION = 0.01
CLIP_PILE_UP = 5.0


def _pile_up(col: np.ndarray) -> float:
    """The larger share of samples on the minimum or on the maximum, where it piles up
    (:data:`CLIP_PILE_UP` times the next distinct level's count); 0 otherwise."""
    levels, counts = np.unique(col, return_counts=True)
    if levels.size < 3:
        return 0.0  # a constant or two-level channel: check_channels_move's business
    worst = 0.0
    for edge, inner in ((counts[0], counts[1]), (counts[-1], counts[-2])):
        if edge >= CLIP_PILE_UP * inner:
            worst = max(worst, edge / col.size)
    return float(worst)


def check_output_clipping(
    data: ClosedLoopData, *, max_fraction: float = MAX_CLIPPED_FRACTION
) -> QualityCheck:
    """Outputs clipped at a sensor's range: a displacement clipped on 60 % of its samples
    passed every check of a user's own .mat, identified R1 = 3.07 ohm (17.5 true) and
    was then diagnosed as a unit error (found from outside, seventeenth session)."""
    y = np.asarray(data.y, dtype=float)
    names = data.channel_names("y")
    shares = [_pile_up(y[:, j]) for j in range(y.shape[1])]
    bad = [
        f"{names[j] if names else f'y{j}'!r} ({100 * f:.2g} % of its samples)"
        for j, f in enumerate(shares)
        if f > max_fraction
    ]
    worst = max(shares, default=0.0)
    return QualityCheck(
        name="output clipping",
        passed=not bad,
        value=worst,
        threshold=max_fraction,
        message=(
            "no output piles up at an extreme value"
            if not bad
            else "output(s) "
            + ", ".join(bad)
            + " sit on one extreme value: the sensor (or its ADC) is clipped at its range, "
            "so the loop the record shows is not the linear one; record within the sensor's "
            "range (a smaller excitation) or leave the clipped stretches out"
        ),
    )


#: Largest displacement, in air gaps, a rotor can physically show (the backup bearing
#: stops it at about one gap); beyond it the units or the stated gap are wrong.
MAX_PHYSICAL_FRACTION = 2.0


def _swings(y: np.ndarray) -> np.ndarray:
    """Each channel's largest departure from its median (the size the unit checks read)."""
    return np.max(np.abs(y - np.median(y, axis=0)), axis=0)


def _displacement_elsewhere(data: ClosedLoopData, x0: float) -> str:
    """A hint when another output channel moves like a displacement (within a tenth
    of the gap) while the first does not: the channels' order, not the
    units (a user's .mat with y = [i1, i2, x] was blamed on units: found from outside,
    issue 16, fourteenth session)."""
    y = np.asarray(data.y, dtype=float)
    swing = _swings(y)
    names = data.channel_names("y") or tuple(f"y{j + 1}" for j in range(y.shape[1]))
    like_x = [names[j] for j in range(1, y.shape[1]) if 0 < swing[j] < 0.1 * x0]
    if not like_x:
        return ""
    return (
        f"; or the channels are in another order: {', '.join(like_x)} moves like a "
        "displacement in metres (the first output must be the displacement: y = [x, i1, i2])"
    )


def check_levitation(
    data: ClosedLoopData,
    *,
    x0: float | None = None,
    max_fraction: float = MAX_DISPLACEMENT_FRACTION,
) -> QualityCheck:
    """The rotor stayed levitated: displacement (output 0) within a fraction of the gap."""
    if x0 is None:
        op = data.loop.get("operating_point", {}) if hasattr(data.loop, "get") else {}
        x0 = op.get("x0") if hasattr(op, "get") else None
    x = data.y[:, 0]
    if x0 is None:
        return QualityCheck(
            name="levitation",
            passed=True,
            value=float(np.max(np.abs(x))),
            threshold=float("nan"),
            message="air gap unknown: levitation not checked",
            blocking=False,
        )
    frac = float(np.max(np.abs(x)) / float(x0))
    stuck = bool(np.ptp(x) == 0.0)
    ok = frac <= max_fraction and not stuck
    msg = (
        f"largest displacement {100 * frac:.3g} % of the air gap"
        if frac <= 100.0
        else f"largest displacement {frac:.2g} air gaps (no rotor moves that far)"
    )
    if stuck:
        msg += ": the displacement does not move at all (rotor resting or sensor dead)"
    elif frac > MAX_PHYSICAL_FRACTION:
        # beyond the gap the rotor sits on its backup bearing: a displacement in mm read
        # as m (8.5 air gaps) was called a touch-down (found from outside, issue 16,
        # thirteenth session)
        msg += (
            ": no rotor moves that far beyond its air gap (the backup bearing stops it); "
            "the displacement is probably not in metres (mm?), or the air gap x0 is wrong"
        )
        msg += _displacement_elsewhere(data, float(x0))
    elif not ok and abs(float(np.mean(x)) - float(x0)) < 0.2 * float(x0):
        # a log of the gap x0 + x read as "touch-down" (found from outside, seventeenth
        # session): it averages x0 where the displacement averages ~0
        msg += (
            f": it averages {float(np.mean(x)):.3g} m, the air gap x0 = {float(x0):.3g} m - it "
            "looks like the absolute gap x0 + x; maglevid reads the displacement from the "
            f'centre: subtract x0 (a mapping with "offset": {-float(x0):.6g} on it)'
        )
    elif not ok:
        msg += ": levitation was lost (touch-down)"
    return QualityCheck(
        name="levitation", passed=ok, value=frac, threshold=max_fraction, message=msg
    )


def check_feedback_consistency(
    data: ClosedLoopData, *, max_mismatch: float = MAX_FEEDBACK_MISMATCH, skip: int = 50
) -> QualityCheck:
    """The logged feedback u_f equals what the stated controller computes from the logged y.

    The observer and controller of eqs. (42)-(43) are re-run on the logged ``y``
    and ``u`` (:func:`maglevid.simulate.loop.replay_feedback`). A mismatch means
    the stated controller matrices (or the channel order, units, time alignment)
    are wrong, and then every method that uses them is wrong too. The first
    ``skip`` samples (observer start-up) and a constant offset (the unknown
    initial integrator state ``F_e e(0)``) are not compared.
    """
    loop = data.loop
    if data.u_f is None or "controller" not in loop or "observer" not in loop:
        return QualityCheck(
            name="feedback consistency",
            passed=True,
            value=float("nan"),
            threshold=max_mismatch,
            message="no logged feedback or no stated controller: consistency not checked",
            blocking=False,
        )
    if data.n_samples <= 2 * skip:  # (the record length check says what is needed)
        return QualityCheck(
            name="feedback consistency", passed=True, value=float("nan"),
            threshold=max_mismatch, blocking=False,
            message=f"{data.n_samples} samples: too few to check the feedback against the "
            f"stated controller (its first {skip} are the observer's start-up)",
        )  # fmt: skip
    from maglevid.control import IntegralStateFeedback, Observer
    from maglevid.simulate.loop import replay_feedback

    try:
        replay = replay_feedback(
            Observer.from_dict(loop["observer"]),
            IntegralStateFeedback.from_dict(loop["controller"]),
            y=data.y_control,
            u=data.u if data.u is not None else data.with_plant_input().u,
        )
    except (KeyError, ValueError) as exc:
        return QualityCheck(
            name="feedback consistency",
            passed=False,
            value=float("inf"),
            threshold=max_mismatch,
            message=f"the stated controller cannot be replayed on this recording: {exc}",
        )
    d = (np.asarray(data.u_f) - replay)[skip:]
    ref = np.asarray(data.u_f)[skip:]
    mismatch = _rms(d) / max(_rms(ref), 1e-300)
    if not np.isfinite(mismatch):
        return QualityCheck(
            name="feedback consistency", passed=False, value=float("inf"),
            threshold=max_mismatch,
            message="the stated controller's replay on the logged y overflows: the logged "
            "signals are far outside the loop's range (units, or a corrupt sample)",
        )  # fmt: skip
    ok = mismatch <= max_mismatch
    return QualityCheck(
        name="feedback consistency",
        passed=ok,
        value=mismatch,
        threshold=max_mismatch,
        message=(
            f"logged feedback differs from the stated controller by {100 * mismatch:.2g} % rms"
            + (
                ""
                if ok
                else ": the recording is inconsistent with the stated controller "
                "(wrong gains, channel order, units or time alignment)"
            )
        ),
    )


#: u = u_f + r: relative rms of u - (u_f + r) (a constant offset, e.g. a bias
#: voltage, removed) allowed. Digital loops log the identity exactly; 1e-3
#: leaves room for logging quantisation (as MAX_FEEDBACK_MISMATCH).
MAX_INPUT_IDENTITY_MISMATCH = 1e-3

#: Outputs respond: the one-step ARX prediction of the outputs from their past
#: and the inputs' must be significant at this level (F-test of the regression
#: against "no relation", in the best channel). Pure noise passes it with this
#: probability; any plant record of a few hundred samples passes with p ~ 0,
#: even the noise-driven suspension of Sun et al., whose outputs are mostly
#: sensor noise (about 10 % of their variance predictable).
OUTPUT_RESPONSE_ALPHA = 1e-4


def _rms(x: np.ndarray) -> float:
    """RMS about each column's mean, scaled by the largest entry before squaring (no
    overflow for values up to the largest float; inf where ``x`` is not finite)."""
    x = x - x.mean(axis=0)
    top = float(np.max(np.abs(x))) if x.size else 0.0
    if not np.isfinite(top):
        return float("inf")
    return top * float(np.sqrt(np.mean(np.square(x / top)))) if top > 0 else 0.0


def check_input_identity(
    data: ClosedLoopData, *, max_mismatch: float = MAX_INPUT_IDENTITY_MISMATCH
) -> QualityCheck:
    """The logged plant input is the feedback plus the excitation: u = u_f + r.

    Checked wherever all three are logged. A record where u equals u_f was
    taken with the excitation not applied (or logged but not added): every
    closed-loop method would read r as a regressor or instrument that the
    plant never saw, and return confident nonsense (issue 17: R1 = -1.3e7 ohm,
    "no significant change"). A constant offset (bias voltage) is allowed.
    """
    name = "u = u_f + r"
    if data.u is None or data.r is None or data.u_f is None:
        return QualityCheck(
            name=name, passed=True, value=float("nan"), threshold=max_mismatch,
            message="u, u_f and r are not all logged: the identity is not checked",
            blocking=False,
        )  # fmt: skip
    u, uf, r = (np.asarray(x, dtype=float) for x in (data.u, data.u_f, data.r))
    scale = max(_rms(u), 1e-300)
    mismatch = float(data.input_identity_mismatch() or 0.0)
    ok = bool(mismatch <= max_mismatch)
    msg = f"u differs from u_f + r by {100 * mismatch:.2g} % rms"
    if not ok:
        if _rms(u - uf) / scale <= max_mismatch and _rms(r) / scale > max_mismatch:
            msg = (
                "u equals u_f: the excitation r was not applied to the plant (or not logged as "
                "applied), so u != u_f + r; identifying with r would be wrong"
            )
        elif _rms(u - r) / scale <= max_mismatch and _rms(uf) / scale > max_mismatch:
            msg = "u equals r: the feedback u_f is not in the logged plant input, so u != u_f + r"
        else:
            msg += (
                ": the logged u, u_f and r disagree (channel order, units, signs or time "
                "alignment)"
            )
    return QualityCheck(name=name, passed=ok, value=mismatch, threshold=max_mismatch, message=msg)


def check_output_response(
    data: ClosedLoopData, *, alpha: float = OUTPUT_RESPONSE_ALPHA, lags: int = 2
) -> QualityCheck:
    """The outputs respond: their past and the inputs' predict them, significantly.

    Each output channel (at the control rate) is regressed on ``lags`` past
    samples of every output and input, by least squares, and the fraction of
    its variance predicted (R^2) is F-tested against "no relation" (under
    which R^2 ~ regressors / samples). If no channel is significant at
    ``alpha`` the record is noise (or signals that do not belong together):
    any model identified from it is meaningless (issue 17: pure noise gave an
    OverflowError in the fault isolation, or "no significant change").
    """
    from scipy import stats

    name = "outputs respond"
    y = np.asarray(data.y_control, dtype=float)
    u = data.u if data.u is not None else data.with_plant_input().u
    u = np.zeros((y.shape[0], 0)) if u is None else np.asarray(u, dtype=float)
    n = y.shape[0]
    k = lags * (y.shape[1] + u.shape[1])
    if n <= 4 * k + 1:
        return QualityCheck(
            name=name, passed=True, value=float("nan"), threshold=alpha,
            message="too few samples to test whether the outputs respond", blocking=False,
        )  # fmt: skip
    cols = [np.ones(n - lags)]
    for j in range(1, lags + 1):
        cols.extend((y[lags - j : n - j]).T)
        cols.extend((u[lags - j : n - j]).T)
    phi = np.column_stack(cols)
    target = y[lags:]
    # each column scaled to its largest value: R^2 does not change, and a sample of
    # 1e300 no longer overflows the variances ("predicts nan %" before)
    top = np.max(np.abs(phi), axis=0)
    phi = phi / np.where(top > 0, top, 1.0)
    ttop = np.max(np.abs(target), axis=0)
    target = target / np.where(ttop > 0, ttop, 1.0)
    if not (np.all(np.isfinite(phi)) and np.all(np.isfinite(target))):
        return QualityCheck(
            name=name, passed=False, value=float("nan"), threshold=alpha,
            message="the outputs or inputs hold values beyond the float range",
        )  # fmt: skip
    coef, *_ = np.linalg.lstsq(phi, target, rcond=None)
    var = np.var(target, axis=0)
    safe = np.where(var > 0, var, 1.0)
    r2 = np.clip(np.where(var > 0, 1.0 - np.var(target - phi @ coef, axis=0) / safe, 0.0), 0, 1)
    dof = n - lags - k - 1
    f_stat = (r2 / k) / np.maximum((1.0 - r2) / dof, 1e-300)
    p_value = float(np.min(stats.f.sf(f_stat, k, dof)))
    best = float(np.max(r2))
    ok = p_value < alpha
    return QualityCheck(
        name=name,
        passed=ok,
        value=p_value,
        threshold=alpha,
        message=(
            f"one step of an ARX({lags}) predicts {100 * best:.3g} % of the output variance "
            f"(p = {p_value:.2g} against no relation)"
            + (
                ""
                if ok
                else ": the outputs look like noise, not a plant responding to its inputs "
                "(pure noise, or y and u from different records)"
            )
        ),
    )


#: Length units a position channel may come in, in metres (maglevid computes in SI).
LENGTH_UNITS = {"m": 1.0, "mm": 1e-3, "um": 1e-6, "µm": 1e-6, "μm": 1e-6, "cm": 1e-2}

#: Sample time against the plant: a digital loop stabilises an unstable pole p
#: only when it samples faster than the pole grows, p dt < 1 (every rig of the
#: papers: bearing 455 rad/s at 1e-4 s, 0.05; levitator 44 rad/s at 1e-2 s, 0.44;
#: Sun's suspension ~40 rad/s at 2.4 ms, 0.1). A time column in ms read as s
#: gives p dt ~ 50-450.
MAX_POLE_DT = 1.0

#: Relative disagreement allowed between the recording's dt and the dt the loop
#: states for its controller (they are the same clock).
MAX_DT_MISMATCH = 1e-3


def _stated_dt(loop: Any) -> tuple[float | None, str]:
    for key in ("dt_design", "T", "dt"):
        v = loop.get(key) if hasattr(loop, "get") else None
        if isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0:
            return float(v), f"loop[{key!r}]"
    ctrl = loop.get("controller") if hasattr(loop, "get") else None
    v = ctrl.get("dt") if hasattr(ctrl, "get") else None
    if isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0:
        return float(v), "the stated controller's dt"
    return None, ""


def _nominal_unstable_pole(data: ClosedLoopData) -> float | None:
    """The plant's unstable pole (rad/s) from the design values the recording carries."""
    from maglevid.diagnose.levitator import is_levitator, levitator_baseline

    if is_levitator(data):
        from maglevid.physics.levitator import unstable_pole

        try:
            gap = float(np.median(np.asarray(data.y_control)[:, 0]))
            return float(unstable_pole(levitator_baseline(data), gap))
        except (TypeError, ValueError, KeyError):
            return None
    loop = data.loop
    nominal = loop.get("nominal") if hasattr(loop, "get") else None
    if not hasattr(nominal, "items"):
        return None
    try:
        from maglevid.physics.amb import AMBParameters, open_loop_poles

        poles = open_loop_poles(AMBParameters(**{k: float(v) for k, v in nominal.items()}))
    except (TypeError, ValueError):
        return None
    real = np.real(poles)
    return float(real.max()) if real.max() > 0 else None


def check_sample_time(data: ClosedLoopData) -> QualityCheck:
    """``dt`` is plausible: the loop's stated controller period, and fast enough for the plant.

    A log whose time column is in ms while the mapping says s has a dt 1000
    times too long; every continuous-time parameter is then wrong by that
    factor, silently (issue 17). The recording's dt must equal the controller
    period the loop states (``loop["dt_design"]``, ``loop["T"]``, the
    controller's ``dt``), and, where the nominal plant is known, sample faster
    than its unstable pole grows (``p dt <`` :data:`MAX_POLE_DT`).
    """
    name = "sample time"
    stated, where = _stated_dt(data.loop)
    if stated is not None:
        ratio = data.dt / stated
        ok = abs(ratio - 1.0) <= MAX_DT_MISMATCH
        msg = f"dt = {data.dt:.4g} s; {where} = {stated:.4g} s"
        if not ok:
            msg += (
                f": {ratio:.4g} times the controller's period; the time column's unit is "
                "probably wrong (e.g. ms read as s) or the record was resampled"
            )
        return QualityCheck(name=name, passed=ok, value=ratio, threshold=MAX_DT_MISMATCH,
                            message=msg)  # fmt: skip
    pole = _nominal_unstable_pole(data)
    if pole is None:
        return QualityCheck(
            name=name, passed=True, value=float("nan"), threshold=MAX_POLE_DT,
            message=f"dt = {data.dt:.4g} s (no stated controller period or plant to check it "
            "against)", blocking=False,
        )  # fmt: skip
    x = pole * data.dt
    ok = x < MAX_POLE_DT
    msg = f"dt = {data.dt:.4g} s against the nominal unstable pole {pole:.4g} rad/s"
    msg += f" (p dt = {x:.3g})"
    if not ok:
        msg += (
            ": no digital loop stabilises the plant sampled this slowly; the time column's "
            "unit is probably wrong (e.g. ms read as s)"
        )
    return QualityCheck(name=name, passed=ok, value=x, threshold=MAX_POLE_DT, message=msg)


def check_units(data: ClosedLoopData) -> QualityCheck:
    """Position channels are in metres, and their size fits the air gap of the loop.

    maglevid computes in SI: a gap channel whose unit says mm is either in
    mm (then every parameter is off by 1000) or in m with a wrong label (issue
    17: accepted silently). Refused, with the likely cause read from the
    magnitudes against the nominal air gap ``x0`` (``loop["operating_point"]``).
    """
    name = "units"
    units = data.channel_units("y")
    swings = _swings(np.asarray(data.y_control, dtype=float))
    op = data.loop.get("operating_point") if hasattr(data.loop, "get") else None
    x0 = op.get("x0") if hasattr(op, "get") else None
    x0 = float(x0) if isinstance(x0, (int, float)) and x0 > 0 else None
    problems = []
    for j, unit in enumerate(units):
        if unit not in LENGTH_UNITS:
            continue
        size = float(swings[j])
        label = data.channel_names("y")[j] if data.channel_names("y") else f"y{j}"
        if unit != "m":
            cause = ""
            if x0 is not None:
                as_labelled = size * LENGTH_UNITS[unit]
                if as_labelled < 1e-4 * x0 and size < x0:
                    cause = (
                        f"; its values (up to {size:.3g}) look like metres: read as {unit} they "
                        f"would be {as_labelled:.3g} m, under 1e-4 of the air gap {x0:.3g} m"
                    )
            problems.append(
                f"y channel {label!r} is in {unit!r}; maglevid computes in SI (m): convert it "
                f"(a mapping with file_unit={unit!r}, unit='m'), or correct the label{cause}"
            )
        elif x0 is not None and size > 100 * x0:
            problems.append(
                f"y channel {label!r} (m) moves by up to {size:.3g} m, {size / x0:.3g} times "
                f"the air gap {x0:.3g} m: it is probably logged in mm (or um) while the unit "
                "says m"
            )
    problems += _current_unit_problems(data, swings, op)
    ok = not problems
    return QualityCheck(
        name=name, passed=ok, value=float(len(problems)), threshold=0.0,
        message="position and current channels of a size that fits the air gap and the "
        "bias current" if ok else "; ".join(problems),
    )  # fmt: skip


#: Largest swing of a bearing's coil current, in bias currents, a record may show:
#: the coil current ``i0 + di`` of a bias-controlled bearing stays within about
#: ``[0, 2 i0]``; 10 bias currents is no bearing in A (a log in mA read as A shows
#: ~1000 x its swing: found from outside, issue 16, fourteenth session, where such a
#: record passed and identified R1 = 1.7e-5 ohm +- 0.4 %).
MAX_CURRENT_SWING = 10.0


#: Largest mean level of a logged coil-current deviation ``i - i0``, in bias currents. A
#: bearing's faults move its settled currents by milliamperes (``kw2`` x1.1: 0.5 mA of
#: i0 = 0.5 A); a log of the absolute current ``i0 + di`` averages ``i0`` and was read as
#: the operating point "+500 mA from the design bias": "Fault: bias current i0 -100 %",
#: data quality passed (found from outside, seventeenth session).
MAX_CURRENT_LEVEL = 0.5


def _current_unit_problems(data: ClosedLoopData, swings: np.ndarray, op: Any) -> list[str]:
    """The coil-current channels of a two-coil bearing record (``y = [x, i1, i2]``, the
    operating point stating ``i0``) whose swing (:func:`_swings`) exceeds
    :data:`MAX_CURRENT_SWING` bias currents, or whose mean level (a deviation from the
    bias) exceeds :data:`MAX_CURRENT_LEVEL` bias currents."""
    i0 = op.get("i0") if hasattr(op, "get") else None
    if not isinstance(i0, (int, float)) or not i0 > 0 or swings.shape[0] != 3:
        return []
    units, names = data.channel_units("y"), data.channel_names("y")
    amps = [j for j in (1, 2) if units[j] in ("A", "")]
    levels = {j: float(np.mean(np.asarray(data.y_control, dtype=float)[:, j])) for j in amps}
    off = [  # a log in mA is the swing's problem below, not an offset
        j for j in amps
        if abs(levels[j]) > MAX_CURRENT_LEVEL * i0 and swings[j] <= MAX_CURRENT_SWING * i0
    ]  # fmt: skip
    out = []
    if off:
        labels = " and ".join(repr(names[j] if names else f"y{j}") for j in off)
        means = " and ".join(f"{levels[j]:+.4g} A" for j in off)
        absolute = all(abs(levels[j] - i0) < 0.2 * i0 for j in off)
        out.append(
            f"y channel(s) {labels} average {means} ({max(abs(levels[j]) for j in off) / i0:.2g}"
            f" x the bias current i0 = {i0:.3g} A): maglevid reads the coil currents as "
            "deviations i - i0 from the bias, whose mean a fault moves by milliamperes"
            + (
                "; these look like the absolute current i0 + di: subtract i0 (a mapping with "
                f'"offset": {-i0:.6g} on each current channel)'
                if absolute
                else "; they are logged with an offset, or i0 is wrong"
            )
        )
    for j in amps:
        size = float(swings[j])
        if size > MAX_CURRENT_SWING * i0:
            label = names[j] if names else f"y{j}"
            out.append(
                f"y channel {label!r} moves by up to {size:.3g} A, {size / i0:.3g} times the "
                f"bias current i0 = {i0:.3g} A: no coil current swings that far; it is "
                "probably logged in mA (maglevid reads A), or i0 is wrong"
            )
    return out


def check_channels_move(data: ClosedLoopData) -> QualityCheck:
    """Every output and input channel varies: a constant one is a dead sensor, an
    unplugged amplifier or a column that was not logged.

    A constant coil current on a levitator log gave "levitator: Singular matrix", and an
    all-zero i1 on a bearing "logged feedback differs from the stated controller by
    47 %" (found from outside, issue 16, thirteenth session): neither named the channel.
    """
    dead = []
    for group, arr in (("y", data.y), ("u", data.u)):
        if arr is None:
            continue
        a = np.asarray(arr, dtype=float)
        names = data.channel_names(group)
        for j in range(a.shape[1]):
            col = a[:, j]
            if col.size and np.all(col == col[0]):
                dead.append(f"{names[j]} = {col[0]:.6g} throughout")
    ok = not dead
    return QualityCheck(
        name="channels move",
        passed=ok,
        value=float(len(dead)),
        threshold=0.0,
        message=(
            "every output and input channel varies"
            if ok
            else "constant channel(s): " + "; ".join(dead) + " (a dead sensor, an unplugged "
            "amplifier, or a column that was not logged)"
        ),
    )


def run_checks(data: ClosedLoopData, **options: Any) -> tuple[QualityCheck, ...]:
    """All checks, in the order a person would want to read them."""
    return (
        check_length(data, **{k: v for k, v in options.items() if k == "min_samples"}),
        check_channels_move(data),
        check_sample_time(data),
        check_units(data),
        check_input_identity(data),
        check_output_response(data),
        check_excitation(data),
        check_saturation(data),
        check_output_clipping(data),
        check_levitation(data),
        check_feedback_consistency(data),
    )
