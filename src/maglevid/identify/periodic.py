"""Periodic disturbances: narrow lines in the prediction errors, found and profiled out.

Why: a rotor on magnetic bearings carries a force at its running speed (unbalance),
often at its harmonics, and a rig picks up mains hum. The likelihood of
:mod:`maglevid.identify.ml` models the disturbances as white; a sinusoid is not, and
its one frequency outweighs the rest of the record. Measured on the simulator's
nonlinear bearing (30 000 samples, default noise and 0.1 N white force): a 50 Hz
force of 0.1 N amplitude (a 1.8 kg rotor 0.6 um out of balance) moved v1..v3 by
-8 % (9 standard errors), 1 N by -96 %, and the diagnosis then blamed a sign
convention or a unit error (docs/gosiewski.md, "Periodic disturbances").

What: at each line's frequency ``f_h`` a sinusoid of free amplitude and phase is
subtracted from every channel's prediction error (6 real numbers per line for
three outputs) and profiled out with the predictor's start-up transient ``tau``,
which enters the same way (affinely). A sinusoid entering a stable linear loop
anywhere -- a force on the rotor, an amplifier's voltage, a sensor -- reaches the
stationary predictor's errors as a sinusoid of its frequency plus a transient of
the predictor's own modes (which ``tau`` absorbs), so the free sinusoid covers
every entry point; it costs the information of one frequency per line.

Found: where the whitened prediction errors ``w_f = L^-1 eps_f`` of a fit (DFT
bins, ``S = L L^T``) carry far more than white errors do. Each channel's
``2 |w_f,c|^2 / sigma_f,c^2`` is chi-square(2) for white errors (``sigma`` its local
level: the median of 501 neighbouring bins, mirrored at the ends), so their sum is
chi-square with ``2 ny`` degrees of freedom; a bin beyond the quantile of false-alarm
probability ``FALSE_ALARM / M`` (``M`` bins; the medians' own scatter in it, an F law)
is a candidate. It is a line when one sinusoid at its refined frequency leaves the
six bins on each side white (a resonance of the errors, or a start's colouring, is
wider). The frequency is refined between the neighbouring bins to the maximum of a
periodogram (no window: the sinusoid is fitted to the unwindowed record). Measured:
no line in 300 records of 3 x 30 000 white errors; none on six healthy records of the
nonlinear bearing; a 0.03 N line at 50 Hz found on each of four.

A line whose frequency or amplitude changes over the record (a running speed that
drifts) leaves its neighbouring bins raised after a fixed sinusoid
(:func:`unsettled_lines`); it is then taken out as its sinusoid times Legendre
polynomials of time (:data:`ENVELOPE`, :func:`line_sequences`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import numpy as np
import scipy.optimize as sopt
import scipy.stats as sstats

from maglevid.exceptions import DataError, IdentificationError

__all__ = [
    "ENVELOPE",
    "EXCURSION",
    "MAX_LINES",
    "START_STAT",
    "amplitude_text",
    "check_lines",
    "excitation_lines",
    "find_lines",
    "fit_without_lines",
    "line_amplitudes",
    "line_coefficients",
    "line_sequences",
    "record_lines",
    "refined_frequency",
    "remove_lines",
    "residual_lines",
    "unmodelled_lines_note",
    "unsettled_lines",
]

#: Lines modelled at most (the strongest); each costs ``2 ny`` nuisance parameters.
MAX_LINES = 8
#: Degree of the Legendre envelope a line gets when a fixed sinusoid leaves it unsettled
#: (:func:`unsettled_lines`): ``2 ny (ENVELOPE + 1)`` nuisance parameters for it.
ENVELOPE = 4
#: Probability that a record of white prediction errors shows one line or more.
FALSE_ALARM = 1e-4
#: The statistic a line needs in the prediction errors of a fit's start. They are not
#: white there (the start is not the optimum): on six healthy records of the simulator's
#: nonlinear bearing the chi-square quantile alone (47 at 15 000 bins) called 1-7 "lines"
#: per record at 2-190 Hz, statistics 53-115 with their neighbours raised too; at the
#: optimum the statistic followed chi-square (99.9 % quantile 23-25 against 22.5) and
#: none was called. A line this strong (a 50 Hz force of 0.1 N on the default bearing
#: reads ~1e4) pulls the first fit away; weaker ones are found at its optimum.
START_STAT = 1e3
#: A line's amplitude, relative to the air gap (in the position) or to the bias current
#: (in a coil current), above which the fit's note warns that the linearised model is
#: stretched: on the simulator's nonlinear bearing (30 000 samples, 4 records each) a
#: 50 Hz force of 1 N (position 1.4 % of the gap, currents 1.6 % of i0) left the
#: standard errors' RMS z at 1.3 (1.1 without it), 3 N (4 %, 5 %) at 1.65, and 10 N
#: (14 %, 16 %) at 14.5 (v9 48 standard errors off): the harmonics and the
#: intermodulation of the excitation with the line are dynamics eq. (4) does not have.
EXCURSION = 0.03
#: Bins on each side of a bin whose median is its local level (the median's own scatter,
#: ~3 % here, is in the threshold: :func:`_threshold`; with 50 bins and the plain
#: chi-square quantile, 3 of 30 records of white errors showed a "line").
_LOCAL = 250
#: Fewer bins on each side (a record of fewer than ~400 samples) and no line is looked for.
_LOCAL_MIN = 25
#: Bins at the low end never called a line (the offsets' bin and its neighbours:
#: a drift, not a period).
_LOW_BINS = 3
#: Bins on each side of a line that belong to it (the leakage of a sinusoid whose
#: frequency falls between bins decays as the distance).
_WIDTH = 2


def line_sequences(
    n: int, dt: float, freqs_hz: Sequence[float], degrees: Sequence[int] = ()
) -> np.ndarray:
    """``(n, sum 2 (d_h + 1))``: ``cos, sin`` of ``2 pi f_h t`` at ``t = k dt`` for each
    line, each times the Legendre polynomials ``P_0 .. P_d`` of ``t`` over the record
    (``degrees``, default 0: a fixed sinusoid; a degree ``d`` holds a line whose
    frequency or amplitude changes over the record, :data:`ENVELOPE`)."""
    t = np.arange(n) * dt
    s = 2.0 * np.arange(n) / max(n - 1, 1) - 1.0
    degs = list(degrees) + [0] * (len(freqs_hz) - len(degrees))
    cols = []
    for f, d in zip(freqs_hz, degs, strict=True):
        w = 2.0 * np.pi * float(f) * t
        c, si = np.cos(w), np.sin(w)
        for j in range(int(d) + 1):
            pj = np.polynomial.legendre.legval(s, [0] * j + [1]) if j else 1.0
            cols += [pj * c, pj * si]
    return np.column_stack(cols) if cols else np.zeros((n, 0))


def check_lines(value: Any, dt: float) -> tuple[float, ...] | None:
    """The ``periodic`` option: None for ``"auto"``, else the frequencies [Hz] given.

    ``"none"`` or an empty list: no line; a number or a list of numbers: those
    frequencies, each above 0 and below the Nyquist frequency ``1 / (2 dt)``.
    """
    if isinstance(value, str):
        if value == "auto":
            return None
        if value == "none":
            return ()
        raise DataError(f"`periodic` must be 'auto', 'none' or frequencies [Hz]; got {value!r}")
    vals = np.atleast_1d(np.asarray(value, dtype=float)).reshape(-1)
    nyq = 0.5 / dt
    bad = [f for f in vals if not (np.isfinite(f) and 0.0 < f < nyq)]
    if bad:
        raise DataError(
            f"`periodic`: each frequency must lie in (0, {nyq:g}) Hz, the Nyquist "
            f"frequency of dt = {dt:g} s; got {float(bad[0])!r}"
        )
    if vals.size > MAX_LINES:
        raise DataError(f"`periodic`: at most {MAX_LINES} frequencies; got {vals.size}")
    return tuple(float(f) for f in vals)


def find_lines(
    E: np.ndarray,
    S: np.ndarray,
    n: int,
    dt: float,
    *,
    known: Sequence[float] = (),
    false_alarm: float = FALSE_ALARM,
    max_lines: int = MAX_LINES,
    min_stat: float = 0.0,
    signals: np.ndarray | None = None,
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Lines in a fit's prediction errors: ``(frequencies [Hz], statistics)``, strongest first.

    ``E``: the errors' real DFT (``(n // 2 + 1, ny)``, bin 0 ignored), ``S`` their
    covariance, ``n`` samples of period ``dt``; ``known``: lines already modelled
    (their bins are not found again). The statistic is ``2 |w_f|^2 / sigma_f^2``
    (chi-square with ``2 ny`` degrees of freedom for white errors, module notes); a
    line needs it above the quantile and above ``min_stat`` (the errors of a fit's
    start are not white: :data:`START_STAT`). ``signals``: the record's own channels
    (time first), whose periodogram refines each line's frequency (default: the whitened
    errors'). The record's is the cleaner: a fit's errors at a point that partly
    predicts a line (a model with a resonance near it) have a notch there, and their
    periodogram's peak wandered 0.1-0.17 Hz off a 50 Hz line, where the record's was a
    clean main lobe at 50.00 Hz. The lines strong enough to be found at the start are
    refined on the record, those found at the optimum (weak: 16 nm at 100 Hz there, lost
    in the record's excitation) on its white errors; the weak ones land 0.16-0.19 Hz off
    either way, where a residual of their small amplitude is left.
    """
    M, ny = E.shape
    local = min(_LOCAL, M // 8)
    if local < _LOCAL_MIN or max_lines <= 0:
        return (), ()
    W, level, stat = _statistic(E, S, local)
    dof = 2 * ny
    thresh = max(_threshold(false_alarm / M, ny, 2 * local + 1), min_stat)
    taken = np.zeros(M, dtype=bool)
    taken[:_LOW_BINS] = True
    taken[-1] = True  # Nyquist: a real sinusoid there has no phase
    df = 1.0 / (n * dt)
    for f in known:
        k = round(f / df)
        taken[max(k - _WIDTH, 0) : k + _WIDTH + 1] = True
    w_time = w_err = None
    found: list[tuple[float, float]] = []
    for k in np.argsort(stat)[::-1]:
        if stat[k] <= thresh or len(found) >= max_lines:
            break
        if taken[k]:
            continue
        if w_time is None:
            w_err = np.fft.irfft(W, n=n, axis=0)
            w_time = w_err if signals is None else _refining_signals(signals, n)
        f = refined_frequency(w_time, k / (n * dt), n, dt)
        share = _START_SHARE if min_stat > 0 else 0.0
        if not _white_after(W, w_err, f, k, level, dof, dt, share * stat[k]):
            continue
        found.append((f, float(stat[k])))
        taken[max(k - _WIDTH, 0) : k + _WIDTH + 1] = True
    return tuple(f for f, _ in found), tuple(s for _, s in found)


#: Bins on each side of a line whose errors, once its sinusoid is taken out, must look
#: white (their mean statistic within three standard errors of a white bin's).
_NEIGHBOURS = 6


#: At a fit's start (errors not white) the bins around a line may stay raised after its
#: sinusoid is taken out, by this share of the line's statistic: a start's colouring
#: is broad and weak beside a line strong enough to be looked for there
#: (:data:`START_STAT`), a start's resonance is as strong as its neighbours.
_START_SHARE = 0.01


def _white_after(W, w_err, f_hz, k, level, dof, dt, extra=0.0) -> bool:  # type: ignore[no-untyped-def]
    """Whether one sinusoid at ``f_hz`` leaves the bins around ``k`` white (``extra``
    allowed above a white bin's mean statistic: :data:`_START_SHARE`): a line is a
    sinusoid; a resonance of the errors (or a start's colouring) is wider, and one
    sinusoid taken out of it leaves its neighbours raised. (White errors through a Q 10
    resonance at 40 Hz: a bin at 63 with neighbours at ~11.5 against white's 6; the
    start's errors of noisy records: 53-115 with neighbours ~35; a noise-free record's
    5 % mismatch: six "lines" at 9-74 Hz without this test.)"""
    n = w_err.shape[0]
    X = line_sequences(n, dt, (f_hz,))
    coef = np.linalg.lstsq(X, w_err, rcond=None)[0]
    lo, hi = max(k - _NEIGHBOURS, 1), min(k + _NEIGHBOURS + 1, W.shape[0])
    D = np.fft.rfft(X, axis=0)[lo:hi]
    rest = np.sum(np.abs(W[lo:hi] - D @ coef) ** 2 / level[lo:hi], axis=1)
    return float(rest.mean()) <= dof + 3.0 * np.sqrt(2.0 * dof / rest.size) + extra


def _statistic(E: np.ndarray, S: np.ndarray, local: int) -> tuple[np.ndarray, ...]:
    """``(W, level, stat)``: the errors whitened by ``S`` per bin, each channel's local
    level (chi-square(2) units) and the bins' statistic, chi-square(``2 ny``) for white
    errors. Each channel is judged against its own level: a band where one channel's
    errors are louder does not give the sum a heavier tail than chi-square's."""
    L = np.linalg.cholesky(0.5 * (S + S.T))
    W = np.linalg.solve(L, E.T).T
    level = np.maximum(_local_median(np.abs(W) ** 2, local), 1e-300) / sstats.chi2.median(2)
    return W, level, np.sum(np.abs(W) ** 2 / level, axis=1)


def _local_median(P: np.ndarray, local: int) -> np.ndarray:
    """The median of each column of ``P`` over ``2 local + 1`` bins around each bin,
    mirrored at the ends (a window padded with the end bin's value made the last bins'
    level that one exponential draw: 11 false lines near Nyquist in 300 white records),
    taken every ``local // 10`` bins and interpolated (the level varies slowly)."""
    M = P.shape[0]
    step = max(local // 10, 1)
    padded = np.pad(P, ((local, local), (0, 0)), mode="reflect")
    centres = np.arange(0, M, step)
    if centres[-1] != M - 1:
        centres = np.append(centres, M - 1)
    win = np.lib.stride_tricks.sliding_window_view(padded, 2 * local + 1, axis=0)[centres]
    med = np.median(win, axis=-1)  # (len(centres), ny)
    return np.stack([np.interp(np.arange(M), centres, med[:, c]) for c in range(P.shape[1])],
                    axis=1)  # fmt: skip


def _threshold(p: float, ny: int, n: int) -> float:
    """The statistic a white bin exceeds with probability ``p``: ``2 ny F(2 ny, d)``, each
    channel's local level being a median of ``n`` bins, as precise as a chi-square
    estimate with ``d = 2 ny / rel^2`` degrees of freedom (``rel`` the relative standard
    error of one channel's median, ``1 / (2 f(m) sqrt(n)) / m`` for the median ``m`` of
    chi-square(2) and its density ``f``; the ``ny`` levels' errors average)."""
    med = sstats.chi2.median(2)
    rel = 1.0 / (2.0 * sstats.chi2.pdf(med, 2) * np.sqrt(n)) / med
    return float(2 * ny * sstats.f.isf(p, 2 * ny, 2.0 * ny / rel**2))


def _refining_signals(signals: np.ndarray, n: int) -> np.ndarray:
    """The record's channels a line's frequency is refined on, each centred and scaled
    to unit variance (so that no channel's units dominate)."""
    x = np.asarray(signals, dtype=float).reshape(n, -1)
    x = x - x.mean(axis=0)
    sd = x.std(axis=0)
    return x / np.where(sd > 0, sd, 1.0)


def refined_frequency(w: np.ndarray, f_hz: float, n: int, dt: float, width: float = 1.0) -> float:
    """The frequency [Hz] within ``width`` bins of ``f_hz`` where the periodogram of
    ``w`` (time first, channels summed) peaks: the least-squares frequency of one
    sinusoid in white errors (no window)."""
    t = np.arange(n)
    k0 = f_hz * n * dt

    def neg_power(x: float) -> float:
        ph = np.exp(-2j * np.pi * x * t / n)
        return -float(np.sum(np.abs(ph @ w) ** 2))

    r = sopt.minimize_scalar(neg_power, bounds=(k0 - width, k0 + width), method="bounded",
                             options={"xatol": 1e-4})  # fmt: skip
    return float(r.x) / (n * dt)


def line_amplitudes(y: np.ndarray, dt: float, freqs_hz: Sequence[float]) -> np.ndarray:
    """``(H, ny)``: each line's amplitude in each channel of ``y`` (least squares of the
    lines' sinusoids and a constant; what the record shows, whatever drives it)."""
    y = np.asarray(y, dtype=float)
    c = line_coefficients(y, line_sequences(y.shape[0], dt, freqs_hz))
    return np.hypot(c[0::2], c[1::2])


def line_coefficients(x: np.ndarray, seq: np.ndarray) -> np.ndarray:
    """Least-squares coefficients of the columns of ``seq`` (a constant fitted beside
    them and left out) in each column of ``x``: ``x`` less ``seq @`` them has no line."""
    X = np.column_stack([seq, np.ones(x.shape[0])])
    return np.linalg.lstsq(X, x, rcond=None)[0][:-1]


_PREFIXES = ((1e-9, "n"), (1e-6, "u"), (1e-3, "m"), (1.0, ""), (1e3, "k"))


def amplitude_text(value: float, unit: str) -> str:
    """``3.7e-6, "m"`` -> ``"3.7 um"``: two significant digits and an SI prefix."""
    if not unit or not np.isfinite(value) or value == 0.0:
        return f"{value:.2g} {unit}".strip()
    scale, prefix = _PREFIXES[0]
    for s, p in _PREFIXES:
        if abs(value) >= s:
            scale, prefix = s, p
    return f"{float(f'{value / scale:.2g}'):g} {prefix}{unit}"


def excursion_note(amplitudes: np.ndarray, scale: Sequence[float | None], names: Sequence[str],
                   freqs_hz: Sequence[float]) -> str | None:  # fmt: skip
    """A warning where a line moves a channel by more than :data:`EXCURSION` of its
    operating point (``scale``: the air gap, the bias currents; None where unknown)."""
    worst = []
    for h, f in enumerate(freqs_hz):
        for c, s in enumerate(scale):
            if s and amplitudes[h, c] / s > EXCURSION:
                worst.append(f"{names[c]} {100 * amplitudes[h, c] / s:.0f} % at {f:.4g} Hz")
    if not worst:
        return None
    return (
        "the periodic lines move the bearing far from its operating point ("
        + ", ".join(worst)
        + " of the air gap or bias current): the linearised model (eq. (4)) does not "
        f"have the harmonics and the mixing with the excitation that brings, and beyond "
        f"{100 * EXCURSION:.0f} % the estimates drift from the truth by more than their "
        "standard errors (measured on the simulated bearing); a record with the unbalance "
        "compensated, or at a lower speed, is closer to the model"
    )


def residual_lines(
    residuals: Any,
    n_samples: int,
    dt: float,
    *,
    known: Sequence[float] = (),
    signals: np.ndarray | None = None,
    max_lines: int = MAX_LINES,
) -> tuple[float, ...]:
    """Lines in a fit's residuals (control rate, time first) beyond what white errors
    allow, strongest first (:func:`find_lines`; ``signals``: the record's channels the
    frequencies are refined on). ``()`` where the residuals cannot be judged: None, with
    gaps (not finite), far shorter than the record (segments) or of singular covariance."""
    spec = _residual_spectrum(residuals, n_samples)
    if spec is None:
        return ()
    E, S, n = spec
    if signals is not None and np.shape(signals)[0] != n:
        signals = None
    return find_lines(E, S, n, dt, known=known, signals=signals, max_lines=max_lines)[0]


def _residual_spectrum(residuals: Any, n_samples: int) -> tuple[np.ndarray, ...] | None:
    """``(E, S, n)``: the residuals' real DFT, covariance and length, or None (see
    :func:`residual_lines`)."""
    if residuals is None:
        return None
    e = np.asarray(residuals, dtype=float)
    if e.ndim != 2 or e.shape[0] < n_samples // 2 or not np.all(np.isfinite(e)):
        return None
    e = e - e.mean(axis=0)
    S = np.atleast_2d(np.cov(e.T))
    try:
        np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        return None
    return np.fft.rfft(e, axis=0), S, e.shape[0]


def unmodelled_lines_note(method: str, residuals: Any, n_samples: int, dt: float) -> str | None:
    """A note when a fit's residuals (control rate, time first) carry periodic lines that
    its method does not model, else None.

    Found from outside: with a 1 N unbalance at 50 Hz on the simulated bearing, PBSID-opt
    and SSARX (structured fit) read v1..v3 93 % off (108 standard errors) and said
    nothing; their residuals carry the line (they now take such lines out themselves
    through the registry: :func:`fit_without_lines`). Residuals with gaps (not finite)
    or far shorter than the record (segments) are not judged.
    """
    freqs = residual_lines(residuals, n_samples, dt)
    if not freqs:
        return None
    where = ", ".join(f"{f:.4g}" for f in sorted(freqs))
    return (
        f"periodic lines in the residuals at {where} Hz, beyond what white errors allow (a "
        "periodic disturbance: unbalance at the running speed, its harmonics, mains hum); "
        f"{method} does not model them. A fit that takes its errors as white is biased by "
        "them (with a 1 N unbalance at 50 Hz on the simulated bearing PBSID-opt and SSARX "
        "read v1..v3 93 % off unless the lines are taken out, their option periodic; "
        "instrumental variables stay consistent); the bearing's ml profiles them out"
    )


def remove_lines(
    x: np.ndarray, dt: float, freqs_hz: Sequence[float], degrees: Sequence[int] = ()
) -> np.ndarray:
    """``x`` (time first) less its least-squares sinusoids at ``freqs_hz`` (each times
    Legendre polynomials up to its entry of ``degrees``: :func:`line_sequences`); a
    constant is fitted beside them and kept. A new array; ``x`` is not modified."""
    x = np.asarray(x, dtype=float)
    flat = x.reshape(x.shape[0], -1)
    seq = line_sequences(flat.shape[0], dt, freqs_hz, degrees)
    return (flat - seq @ line_coefficients(flat, seq)).reshape(x.shape)


#: Searches of a fit's residuals after the first fit (a weaker line shows once the
#: stronger ones are out); each new line costs a refit.
_RESIDUAL_ROUNDS = 2


def fit_without_lines(
    fit: Callable[[np.ndarray, np.ndarray], Any],
    y: Any,
    u: Any,
    dt: float,
    periodic: Any,
    *,
    method: str,
    excitation: Any = None,
    probe: Callable[[np.ndarray, np.ndarray], Any] | None = None,
) -> Any:
    """``fit(y, u)`` on the record with its periodic lines taken out of every channel.

    For a method that takes its errors as white and reads only the record's second
    moments (PBSID-opt, SSARX): a fixed line entering a stable linear loop anywhere
    shows in every channel of ``y`` and ``u`` as a sinusoid of its frequency in steady
    state; its least-squares sinusoid is removed from each channel before the fit (two
    numbers per channel and line, no other change to the data). Measured on the
    simulator's nonlinear bearing with a 1 N unbalance at 50 Hz (30 000 samples, 6
    records): PBSID-opt's RMS z of v1..v9 49 -> 1.02 (healthy records: 1.09), SSARX's
    49 -> 1.09 (1.17); docs/gosiewski.md, "Periodic disturbances".

    ``periodic`` (:func:`check_lines`): ``"none"`` fits the record as it is; frequencies
    take those lines out; ``"auto"`` takes out the lines strong in the record itself
    (:func:`record_lines`), fits, searches the fit's residuals for weaker ones
    (:func:`residual_lines`, frequencies refined on ``y``) and refits without them (up
    to :data:`_RESIDUAL_ROUNDS` searches); a line a fixed sinusoid leaves unsettled
    (:func:`unsettled_lines`) is taken out with a degree-:data:`ENVELOPE` envelope.
    ``fit(y, u)`` returns a result with ``residuals`` (control rate), ``extras`` and
    ``notes`` (a dataclass); except with ``"none"`` the result's ``extras`` gain
    ``periodic_hz`` (the lines taken out; empty when none was found),
    ``periodic_amplitude`` (``(H, ny)``, in ``y``) and ``periodic_envelope_degree``.

    ``excitation``: the recorded excitation ``r`` (time first), if any. A line found
    where ``r`` itself has a line (:func:`_excitation_lines`) is the experiment's own
    excitation -- in the record by design, in the residuals a model error at its
    frequency, not a disturbance -- and is left in (taking it out would take the
    information out): noted. A periodic excitation not logged as ``r`` cannot be told
    from a disturbance and would be taken out (use ``"none"`` for a sine test).
    ``probe``: a sturdier fit whose residuals are searched
    when ``fit`` fails (IdentificationError) on the record the first search leaves --
    a line can be what breaks it; with no line found there, that failure is raised.
    """
    lines = check_lines(periodic, dt)
    if lines == ():
        return fit(y, u)
    y = np.asarray(y, dtype=float)
    u = np.asarray(u, dtype=float)
    if not (np.all(np.isfinite(y)) and np.all(np.isfinite(u))) or y.ndim > 2 or u.ndim > 2:
        return fit(y, u)  # its own error names the bad sample (a line fit would smear it)
    y, u = (x.reshape(x.shape[0], -1) if x.ndim == 1 else x for x in (y, u))
    auto = lines is None
    degrees: tuple[int, ...] = ()
    kept: tuple[float, ...] = ()
    if auto:
        strong = record_lines(y, u, dt)
        kept = excitation_lines(excitation, dt, strong)
        lines = tuple(f for f in strong if f not in kept)
        res, failed = _first_fit(fit, probe, *_without(y, u, dt, lines))
        for _ in range(_RESIDUAL_ROUNDS):
            new = residual_lines(res.residuals, y.shape[0], dt, known=lines + kept,
                                 signals=y, max_lines=MAX_LINES - len(lines))  # fmt: skip
            ours = excitation_lines(excitation, dt, new)
            kept += ours
            new = tuple(f for f in new if f not in ours)
            if not new:
                break
            lines, failed = lines + new, None
            res = fit(*_without(y, u, dt, lines))
        if failed is not None:
            raise failed
        spec = _residual_spectrum(res.residuals, y.shape[0]) if lines else None
        moving = unsettled_lines(*spec, dt, lines) if spec is not None else ()
        if moving:
            degrees = tuple(ENVELOPE if f in moving else 0 for f in lines)
            res = fit(*_without(y, u, dt, lines, degrees))
    else:
        res = fit(*_without(y, u, dt, lines))
    amp = line_amplitudes(y, dt, lines) if lines else np.zeros((0, y.shape[1]))
    extras = {**res.extras, "periodic_hz": tuple(lines), "periodic_amplitude": amp,
              "periodic_envelope_degree": degrees or (0,) * len(lines)}  # fmt: skip
    notes = tuple(res.notes)
    if lines:
        notes += (_removed_note(method, lines, amp, degrees, auto),)
    if kept:
        notes += (
            f"lines at {', '.join(f'{f:.4g}' for f in kept)} Hz are in the excitation r "
            "too: the experiment's own excitation (not a disturbance), left in the record",
        )
    return replace(res, extras=extras, notes=notes)


def _without(y, u, dt, lines, degrees=()):  # type: ignore[no-untyped-def]
    """``(y, u)`` with ``lines`` taken out (as they are when there is none)."""
    if not lines:
        return y, u
    return remove_lines(y, dt, lines, degrees), remove_lines(u, dt, lines, degrees)


def record_lines(y: np.ndarray, u: np.ndarray, dt: float) -> tuple[float, ...]:
    """Lines strong in the record itself: :func:`find_lines` on ``[y, u]`` (each channel
    scaled to unit variance) with a statistic above :data:`START_STAT`.

    Why not only the residuals: a line on a logged channel alone (sensor runout, hum)
    can be absorbed by the fit -- a sinusoid is predictable from its past, and the
    structured fit bent the bearing's model to predict a 1 um runout at 50 Hz on the
    position (v1..v9 ~350 standard errors off) and left the residuals' bin at ~20x its
    neighbours, below any threshold. In the record such a line reads 2300-3900 (6
    records; a 1 N unbalance 20 000-23 000), the rest of the bearing's closed-loop
    spectrum at most 81 (its colouring: the chi-square quantile alone would call it).
    """
    z = np.concatenate([np.asarray(y, float), np.asarray(u, float)], axis=1)
    z = z - z.mean(axis=0)
    sd = z.std(axis=0)
    z = z / np.where(sd > 0, sd, 1.0)
    S = np.atleast_2d(np.cov(z.T))
    try:
        np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        return ()
    E = np.fft.rfft(z, axis=0)
    return find_lines(E, S, z.shape[0], dt, min_stat=START_STAT, signals=y)[0]


def _first_fit(fit, probe, y, u):  # type: ignore[no-untyped-def]
    """``(result, None)`` of ``fit``; where it fails and there is a ``probe``, the
    probe's result and the failure (the failure raised if the probe fails too)."""
    try:
        return fit(y, u), None
    except IdentificationError as exc:
        if probe is None:
            raise
        try:
            return probe(y, u), exc
        except IdentificationError:
            raise exc from None


#: A line of the residuals is the excitation's own where ``r``'s periodogram at it (the
#: largest of the bins within ``_WIDTH``) exceeds this many times its local median (a
#: white ``r``'s bins reach ~20x at 1e-4 per record of 1e4 bins).
_EXCITATION_RATIO = 100.0


def excitation_lines(r: Any, dt: float, freqs_hz: Sequence[float]) -> tuple[float, ...]:
    """The frequencies of ``freqs_hz`` where the excitation ``r`` has a line."""
    if r is None or not freqs_hz:
        return ()
    x = np.asarray(r, dtype=float)
    x = x.reshape(x.shape[0], -1)
    if x.shape[0] < 2 * _LOCAL_MIN or not np.all(np.isfinite(x)):
        return ()
    P = np.sum(np.abs(np.fft.rfft(x - x.mean(axis=0), axis=0)) ** 2, axis=1)
    n = x.shape[0]
    out = []
    for f in freqs_hz:
        k = round(f * n * dt)
        near = P[max(k - _WIDTH, 1) : k + _WIDTH + 1]
        level = np.median(P[max(k - _LOCAL, 1) : k + _LOCAL + 1])
        if near.size and level > 0 and float(near.max()) > _EXCITATION_RATIO * level:
            out.append(f)
        elif near.size and level == 0 and float(near.max()) > 0:
            out.append(f)
    return tuple(out)


def _removed_note(method: str, lines: Sequence[float], amp: np.ndarray,
                  degrees: Sequence[int], auto: bool) -> str:  # fmt: skip
    where = "; ".join(
        f"{f:.4g} Hz (y amplitudes " + ", ".join(f"{a:.2g}" for a in amp[h]) + ")"
        for h, f in enumerate(lines)
    )
    how = "found in the record and the first fit's residuals" if auto else "as given"
    drift = [f"{f:.4g}" for f, d in zip(lines, degrees, strict=False) if d]
    env = (
        f"; the line(s) at {', '.join(drift)} Hz change over the record and were taken out "
        f"with a degree-{ENVELOPE} envelope (Legendre polynomials in time)"
        if drift
        else ""
    )
    return (
        f"periodic lines ({how}) at {where} were taken out of every channel of y and u "
        f"before the {method} fit (a least-squares sinusoid each: the steady response of a "
        f"fixed line in a linear loop){env}"
    )


#: A line is unsettled when the 13 bins around it average more than this many times a
#: white bin's statistic after it is taken out. Measured (1 N at 50 Hz, 3 s records):
#: steady lines 5.5-17.8 (white: 6; the nonlinear plant's sidebands), a 0.1 % drift
#: 67-70 (v1..v3 up to 2.7 standard errors off), a 0.5 % drift 117 (17 off).
_UNSETTLED = 5.0


def unsettled_lines(E: np.ndarray, S: np.ndarray, n: int, dt: float,
                    lines: Sequence[float]) -> tuple[float, ...]:  # fmt: skip
    """The modelled lines whose neighbouring bins stay raised in a fit's errors ``E``
    (taken out as fixed sinusoids): a frequency or an amplitude that changes over the
    record, which one sinusoid does not hold.

    Measured: a 1 N line whose frequency rose 50 -> 50.25 Hz over a 3 s record left its
    neighbours at 16-500 (white: 6) after the best single sinusoid, and v1..v3 17
    standard errors off. Sinusoids at the neighbouring bins did not whiten it (the
    chirp's leakage reaches ~8 bins); a polynomial envelope does (:data:`ENVELOPE`).
    """
    M, ny = E.shape
    local = min(_LOCAL, M // 8)
    if local < _LOCAL_MIN or not lines:
        return ()
    stat = _statistic(E, S, local)[2]
    dof = 2 * ny
    out = []
    for f in lines:
        k = round(f * n * dt)
        near = stat[max(k - _NEIGHBOURS, 1) : k + _NEIGHBOURS + 1]
        if near.size and float(near.mean()) > _UNSETTLED * dof:
            out.append(float(f))
    return tuple(out)
