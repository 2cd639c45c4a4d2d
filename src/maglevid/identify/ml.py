"""Maximum likelihood (prediction error) in the AMB's physical parameterisation.

Why: instrumental variables (:mod:`maglevid.identify.physical`) are consistent
but not efficient. Their instruments come from the excitation ``r`` alone and
their equation error is a moving average of the sensor noise, weighted as if
all channels were alike; on the default bearing the position noise (0.1 um) is
large against the ~1 um motion the 1 V excitation causes, and IV's scatter is
30-40 % of R1 and kw1 on a 2 s record while the Cramér-Rao bound is ~0.3 %
(``docs/gosiewski.md``, "Maximum likelihood").

What: the exact (stationary) Gaussian likelihood of the logged ``y`` given
``u`` -- eq. (1) of :mod:`maglevid.identify.cramer_rao` -- maximised over

* ``v1..v9`` (eq. (4)), through the ZOH model (eq. (7));
* the three sensor noise levels (``log s``), unless given;
* the variance ``s_F^2`` of a white force disturbance on the rotor, held over
  each sample (process noise through ``b_F``, the ZOH of
  ``B_F = [0, 1/m, 0, 0]^T``), unless given: the realistic bearing of the
  simulator (and a real one) has it, and a likelihood without it is not the
  likelihood of the data -- its intervals then cover far less than they say;
  ``s_F^2 >= 0`` is kept by an active-set step (``s_F = 0`` on a record
  without disturbance is on the boundary);
* output offsets ``c`` (a constant offset of ``u`` is the same as one of
  ``y`` for this plant, which has no pole at ``z = 1``: both are absorbed);
* the initial predictor state (the plant is unstable; the steady-state
  Kalman predictor ``A - K C`` is stable, and ``x0`` removes its start-up).

Valid under feedback: ``u`` is logged, and the likelihood of ``y`` given its
past and ``u`` is the product of the innovation densities whatever the
controller (Ljung 1999, sec. 13.4).

How: Fisher scoring (Gauss-Newton on eq. (1) with the expected Hessian, eq.
(2)) with Levenberg-Marquardt damping, from the ``physical`` IV estimate (from the
loop's nominal bearing where the IV estimate has no physical counterpart: a record
too noisy or too little excited for the plant ARX).
Sensitivities come from the linear recursions (3)-(4) of the predictor,
evaluated in the frequency domain (the record's DFT bins; above ~74k
samples the same sums from the record's lagged products on a fixed grid,
:func:`_lag_spectra`, so an iteration costs the same at 1e6 as at 1e5:
``docs/gosiewski.md``, "The ml method"). The covariance
is the inverse Fisher matrix at the optimum (all nuisance parameters
included), propagated to R, L, ki, kw, x0, ... by the delta method.
"""

from __future__ import annotations

import logging
import warnings
import weakref
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import scipy.linalg as sla

from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError, IdentificationError
from maglevid.identify.cramer_rao import (
    NoiseModel,
    amb_linear_gaussian_model,
    derived_parameters,
    eliminate_nuisance,
    invert_information,
    pinv_information,
    predictor_derivatives,
    steady_state_predictor,
)
from maglevid.identify.options import AMB_OPTIONS, Option
from maglevid.identify.pbsid import fit_pbsid
from maglevid.identify.periodic import (
    ENVELOPE,
    MAX_LINES,
    START_STAT,
    amplitude_text,
    check_lines,
    excursion_note,
    find_lines,
    line_amplitudes,
    line_coefficients,
    line_sequences,
    unsettled_lines,
)
from maglevid.identify.physical import fit_physical, loop_recorded
from maglevid.identify.result import IdentificationResult, propagate_covariance
from maglevid.identify.uncertainty import one_step_fit_percent, operating_point
from maglevid.physics.amb import (
    C_AMB,
    V_NAMES,
    AMBParameters,
    amb_state_space,
)

__all__ = ["METHODS", "fit_ml"]

logger = logging.getLogger(__name__)

#: Range of an estimated sensor noise level, relative to its channel's standard
#: deviation (:meth:`_Layout.bounds`).
_SENSOR_RANGE = (1e-6, 10.0)

#: Converged when the Fisher-scoring step would lower eq. (1) by less than this
#: (g^T I^-1 g, the remaining step's length in standard errors, squared: 1e-6
#: per parameter is a thousandth of a standard error).
_TOL = 1e-6

#: Frequencies the information of a scoring step is computed from (every
#: k-th; the gradient always uses all of them, so the optimum is exact).
_FISHER_FREQUENCIES = 16384


def fit_ml(
    data: ClosedLoopData,
    *,
    start: Any = "physical",
    noise_std: Any = "estimate",
    force_std: Any = "estimate",
    amplifier_std: Any = (0.0, 0.0),
    max_iter: int = 60,
    m: float | None = None,
    i0: float | None = None,
    periodic: Any = "auto",
) -> IdentificationResult:
    """Maximum-likelihood v1..v9 and physical parameters of the two-coil AMB (module notes).

    Parameters
    ----------
    data : ClosedLoopData
        ``y = [x, i1, i2]`` at the control rate and the logged ``u`` (or
        ``u_f`` and ``r``).
    start : "physical", IdentificationResult or (9,) array_like
        Starting point: the ``physical`` IV estimate (default; or that fit of
        this record already made, passed as its result: the same start without
        fitting IV a second time) or given v1..v9.
    noise_std : "estimate", "metadata" or (3,) sequence
        Sensor noise standard deviations of ``[x, i1, i2]``: estimated with the
        parameters (default), taken from ``metadata["noise_std"]`` of a
        simulated record, or given [m, A, A].
    force_std : "estimate", "metadata" or float
        Standard deviation of the white force disturbance on the rotor [N, held
        over each sample]: estimated (default; started at 0), taken from
        ``metadata["force_std"]`` of a simulated record, or given (0: none, the
        paper's linear model). Without the mass ``m`` it is an acceleration
        [m/s^2].
    amplifier_std : (2,) sequence
        Amplifier input noise [V per sample, held], assumed known.
    max_iter : int
        Fisher-scoring iterations at most.
    m, i0 : float, optional
        Mass and bias current; default ``data.loop["operating_point"]``.
    periodic : "auto", "none" or frequencies [Hz]
        Periodic disturbances (unbalance at the running speed and its harmonics,
        mains hum): a sinusoid of free amplitude and phase in each channel's
        prediction error at each line, profiled out
        (:mod:`maglevid.identify.periodic`). ``"auto"`` (default): the lines
        found in the prediction errors at the start and at the optimum;
        ``"none"``: no line; or the frequencies, e.g. the rotor's running speed.

    Returns
    -------
    IdentificationResult
        ``method="ml"``; v1..v9 then the physical parameters (or ratios) with
        their covariance; innovations as residuals; noise levels, offsets,
        Kalman gain, iterations and the periodic lines (``periodic_hz``, their
        amplitudes in ``y`` per channel, ``periodic_amplitude``) in ``extras``.

    Raises
    ------
    DataError
        Wrong signals or options, or a degenerate record (saturated, constant:
        the predictor or its information cannot be computed).
    IdentificationError
        The predictor does not exist at the start, or no descent is found.
    """
    try:
        return _fit_ml(data, start, noise_std, force_std, amplifier_std, max_iter, m, i0, periodic)
    except (np.linalg.LinAlgError, FloatingPointError, ValueError, sla.LinAlgWarning) as exc:
        # A saturated or constant record makes the DARE, the Lyapunov equation or
        # an inverse fail inside numpy/scipy (LinAlgError, or a ValueError on
        # LAPACK errors / non-finite arrays): the record's fault, said once.
        # Our own DataErrors pass; any other ValueError is a bug and propagates.
        if isinstance(exc, DataError) or not (
            isinstance(exc, (np.linalg.LinAlgError, FloatingPointError, sla.LinAlgWarning))
            or _raised_in_numerics(exc)
        ):
            raise
        raise DataError(
            f"ml: the record is degenerate for the Kalman predictor ({exc}); a saturated, "
            "constant or non-bearing record cannot be fitted by maximum likelihood"
        ) from exc


def _raised_in_numerics(exc: BaseException) -> bool:
    """Whether ``exc`` was raised inside numpy or scipy (its innermost frame)."""
    tb = exc.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    name = "" if tb is None else tb.tb_frame.f_code.co_filename
    return any(f"{sep}{pkg}{sep}" in name for pkg in ("numpy", "scipy") for sep in "/\\")


def _fit_ml(
    data: ClosedLoopData,
    start: Any,
    noise_std: Any,
    force_std: Any,
    amplifier_std: Any,
    max_iter: int,
    m: float | None,
    i0: float | None,
    periodic: Any = "auto",
) -> IdentificationResult:
    y, u = _signals(data)
    lines = check_lines(periodic, data.dt)
    auto = lines is None  # "auto": the lines are looked for
    op_m, op_i0 = operating_point(data.loop)
    m = op_m if m is None else m
    i0 = op_i0 if i0 is None else i0
    try:
        v0, noise0, start_kind, notes = _start(data, start, m=m, i0=i0)
    except (DataError, IdentificationError) as exc:
        # the IV start needs a usable ARX of the plant; on a record too noisy or too
        # little excited for it (20-40x the default sensor noise at 1e4 samples), the
        # nominal bearing the loop was designed on is the other natural start
        # (and without it, PBSID-opt's structured fit: a user's own healthy 0.25-1 s
        # records ended at "ml: physical: ... eq. (8)" there; found from outside,
        # fourteenth session of issue 16)
        if not (isinstance(start, str) and start == "physical"):
            raise
        v0, start_kind = _nominal_v(data), "nominal"
        if v0 is None:
            v0, start_kind = _subspace_v(y, u, data.dt), "subspace"
        if v0 is None:
            raise
        noise0 = None
        notes = [f"the physical (IV) start failed ({exc}); started from the "
                 f"{_START_WORDS[start_kind]}"]  # fmt: skip
    noise, estimate_noise = _noise(data, noise_std, amplifier_std, noise0)
    force0, est_force = _force(data, force_std)
    noise = NoiseModel(noise.sensor_std, force_std=force0, amplifier_std=noise.amplifier_std)
    lay = _Layout(noise, estimate_noise, est_force)
    rho = _predictor_radius(lay, v0, data.dt, m)
    if auto:  # the lines in the start's prediction errors first
        lines = _start_lines(data, y, u, lay, v0, m)
    sp = _spectra(y, u, rho, key=data, lines=lines, dt=data.dt)
    theta, final, it, converged = _fit_from_starts(
        data, sp, y, u, lay, (v0, start_kind), notes, m, max_iter, (noise, estimate_noise)
    )
    if auto:  # and those that show at the optimum
        for _ in range(_LINE_ROUNDS):
            new, _ = find_lines(final["eps"], final["S"], y.shape[0], data.dt, known=lines,
                                max_lines=MAX_LINES - len(lines))  # fmt: skip
            if not new:
                break
            lines = lines + new
            sp = _spectra(y, u, rho, key=data, lines=lines, dt=data.dt)
            theta, final, n_it, converged = _refit(sp, y, theta, lay, data.dt, m, max_iter)
            it += n_it
    envelope: tuple[int, ...] = ()
    if auto and lines:  # a line a fixed sinusoid leaves unsettled gets an envelope
        moving = unsettled_lines(final["eps"], final["S"], y.shape[0], data.dt, lines)
        if moving:
            envelope = tuple(ENVELOPE if f in moving else 0 for f in lines)
            sp = _spectra(y, u, rho, key=data, lines=lines, dt=data.dt, degrees=envelope)
            theta, final, n_it, converged = _refit(sp, y, theta, lay, data.dt, m, max_iter)
            it += n_it
    if sp.lags:
        notes.append(f"eq. (1) from the record's lagged products up to lag {sp.lags} "
                     "(large-N path; equal to the DFT path to rho^L)")  # fmt: skip
    moving: tuple[float, ...] = ()
    if lines:
        notes.append(_lines_note(y, data, lines, auto=auto))
        if any(envelope):
            drift = ", ".join(f"{f:.4g}" for f, d in zip(lines, envelope, strict=True) if d)
            notes.append(
                f"the line(s) at {drift} Hz change over the record (a fixed sinusoid left "
                "their neighbouring frequencies raised: a running speed or an amplitude that "
                f"varies): each was taken out with a degree-{ENVELOPE} envelope (Legendre "
                "polynomials in time)"
            )
        op = data.loop.get("operating_point") if isinstance(data.loop, Mapping) else None
        op = op if isinstance(op, Mapping) else {}
        x0, i0_ = op.get("x0"), i0
        warn = excursion_note(line_amplitudes(y, data.dt, lines), (x0, i0_, i0_),
                              data.channel_names("y"), lines)  # fmt: skip
        if warn:
            notes.append(warn)
        moving = unsettled_lines(final["eps"], final["S"], y.shape[0], data.dt, lines)
        if moving:
            notes.append(
                f"the line(s) at {', '.join(f'{f:.4g}' for f in moving)} Hz change over the "
                "record (their neighbouring frequencies stay raised after a fixed sinusoid is "
                "taken out: a running speed or an amplitude that varies): the estimates are "
                "biased by what is left (measured over 3 s: a 0.1 % speed drift, v1..v3 up to "
                "2.7 standard errors off; 0.5 %, 17); a record at steady speed, or a shorter "
                "one, resolves it"
            )
    if not converged:
        notes.append(f"Fisher scoring stopped after {it} iterations without converging")
    return _result(
        data,
        theta,
        final,
        lay,
        m=m,
        i0=i0,
        iterations=it,
        options={
            "start": start_kind,
            "noise_std": noise_std if isinstance(noise_std, str) else list(noise.sensor_std),
            "force_std": force_std if isinstance(force_std, str) else float(force_std),
            "amplifier_std": list(noise.amplifier_std),
            "max_iter": int(max_iter),
            "m": m,
            "i0": i0,
            "periodic": "auto" if auto else list(lines),
        },
        notes=notes,
        converged=converged,
        v_start=v0,
        lines=lines,
        unsettled=moving,
        envelope=envelope,
    )


#: Rounds of "find the lines at the optimum, refit from it" at most (periodic="auto").
_LINE_ROUNDS = 2


def _fit_from_starts(data, sp, y, u, lay, v0_kind, notes, m, max_iter, noise_est):  # type: ignore[no-untyped-def]
    """Fisher scoring from the ordered starts (:func:`_ordered_starts`), the force
    disturbance's restarts where the first does not converge, the better end kept;
    finished on the DFT bins (:func:`_finished`). Returns theta, the final evaluation
    (its ``eps`` on the DFT bins), the iterations and whether it converged."""
    (v0, start_kind), (noise, estimate_noise) = v0_kind, noise_est
    est_force = lay.est_force
    starts = _ordered_starts(data, sp, lay, v0, start_kind, m, notes, y, u)
    best = None
    for k, (vs, kind) in enumerate(starts):
        run = _optimise(sp, y, vs, lay, dt=data.dt, m=m, max_iter=max_iter)
        if (
            best is None
            or (run[3] and not best[0][3])
            or (run[3] == best[0][3] and run[4] < best[0][4])
        ):
            best = (run, vs, kind)
        if k > 0:
            notes.append(
                f"the first start did not converge; restarted from the {_START_WORDS[kind]} "
                f"({'converged' if run[3] else 'did not converge either'})"
            )
        if run[3]:
            break
        if k == 0 and est_force:  # first the force disturbance's start (the usual cause)
            best = _force_restarts(sp, y, best, noise, estimate_noise, data.dt, m, max_iter, notes)
            if best[0][3]:
                break
        if k == len(starts) - 1 and start_kind == "physical" and kind != "subspace":
            vs = _subspace_v(y, u, data.dt)  # the last resort: the closed-loop subspace fit
            if vs is not None and all(kd != "subspace" for _, kd in starts):
                starts.append((vs, "subspace"))
    assert best is not None
    return _finished(y, sp, best[0], lay, data.dt, m, max_iter)


def _refit(sp, y, theta, lay, dt, m, max_iter):  # type: ignore[no-untyped-def]
    """The scoring again from ``theta`` on new entries (lines added, or an envelope)."""
    run = _optimise(sp, y, theta[:9], lay, dt=dt, m=m, max_iter=max_iter, theta0=theta)
    return _finished(y, sp, run, lay, dt, m, max_iter)


def _finished(y, sp, run, lay, dt, m, max_iter):  # type: ignore[no-untyped-def]
    """A run's ``(theta, final, iterations, converged)`` with the innovations on the DFT
    bins (after the lag path, :func:`_exact_finish`)."""
    theta, final, it, converged, _ = run
    if sp.lags:
        theta, final, it, converged = _exact_finish(
            y, sp, theta, final, lay, it, converged, dt=dt, m=m, max_iter=max_iter
        )
    return theta, final, it, converged


def _start_lines(data, y, u, lay, v0, m) -> tuple[float, ...]:  # type: ignore[no-untyped-def]
    """The periodic lines in the prediction errors at the start (none where the
    start has no predictor)."""
    sp = _Spectra(y, u)
    st = _trial(lambda th, _: _evaluate(lay.model(th, data.dt, m), sp, derivatives=False),
                lay.theta(v0), False)  # fmt: skip
    if st is None:
        return ()
    eps = _bin_errors(lay.model(lay.theta(v0), data.dt, m), st, sp)
    return find_lines(eps, st["S"], y.shape[0], data.dt, min_stat=START_STAT, signals=y)[0]


def _lines_note(y: np.ndarray, data: ClosedLoopData, lines: tuple[float, ...], auto: bool) -> str:
    """What the fit did about the periodic lines, with their amplitudes in ``y``."""
    amp = line_amplitudes(y, data.dt, lines)
    names, units = data.channel_names("y"), data.channel_units("y")
    parts = []
    for f, a in zip(lines, amp, strict=True):
        each = ", ".join(
            f"{n} {amplitude_text(v, un)}" for n, v, un in zip(names, a, units, strict=True)
        )
        parts.append(f"{f:.4g} Hz ({each})")
    how = ("found in the prediction errors (far beyond white errors: a periodic "
           "disturbance such as unbalance at the running speed, its harmonics or mains "
           "hum)") if auto else "given"  # fmt: skip
    return (
        f"periodic lines {how}: {'; '.join(parts)} (amplitude in y); a sinusoid of free "
        "amplitude and phase in each channel's prediction error at each was profiled out, "
        "losing the information of those frequencies only"
    )


#: How a start is named in the notes.
_START_WORDS = {
    "physical": "physical (IV) estimate",
    "nominal": "nominal bearing",
    "subspace": "PBSID-opt structured fit",
    "given": "given v1..v9",
}


def _ordered_starts(data, sp, lay, v0, start_kind, m, notes, y, u):  # type: ignore[no-untyped-def]
    """The starts to try, the one of higher likelihood (eq. (1)) first.

    A poor IV start (short or very noisy record; a record without its loop, where the
    instruments are lags of ``r``) can leave the scoring in a wrong basin. The other
    natural starts: the nominal bearing the loop was designed on, where the record
    carries it; else PBSID-opt's structured fit, consistent under feedback without
    knowing the controller (a user's own .mat file: the IV estimate from lags of ``r``
    was 4x off in R1 on the nonlinear bearing there and the scoring stopped in 2
    iterations; docs/gosiewski.md, "The `ml` method"). The first is tried first, the
    others when it does not converge (``_fit_ml``), and the better end is kept.
    """
    starts = [(v0, start_kind)]
    if start_kind != "physical":
        return starts
    v_nom = _nominal_v(data)
    alt = (v_nom, "nominal") if v_nom is not None else (_subspace_v(y, u, data.dt), "subspace")
    if alt[0] is None:
        return starts
    if _start_likelihood(sp, alt[0], lay, data.dt, m) < _start_likelihood(sp, v0, lay, data.dt, m):
        note = f"started from the {_START_WORDS[alt[1]]} (higher likelihood than the IV estimate)"
        notes[:] = [note if n.startswith("started from the physical") else n for n in notes]
        return [alt, starts[0]]
    return [starts[0], alt]


#: Force disturbance levels [share of the rotor's weight] the scoring restarts from
#: when no start converged with it at 0 (:func:`_force_restarts`).
_FORCE_RESTARTS = (0.005, 0.05)


def _force_restarts(sp, y, best, noise, est_noise, dt, m, max_iter, notes):  # type: ignore[no-untyped-def]
    """The scoring again from the best start's v1..v9 with the force disturbance started
    at 0.5 % and then 5 % of the rotor's weight (an acceleration of that share of g
    without the mass), where the first start did not converge from 0 (tried before the
    other starts: a 2 N force stalled all three of them).

    From 0, stage 1 fits the dynamics with no disturbance at all; on a record a 2 N
    force drives (20x the simulator's default, rotor 2.3 um rms) the dynamics absorb
    the force there (R1 +42 % on a healthy bearing), and from that point a small force
    is not downhill: every start stopped after 60 iterations at -2 log L = -6.2e5,
    where the disturbance started at 0.09 N converges in 15 to 2.0 N and -9.8e5
    (found from outside, issue 16, thirteenth session; docs/gosiewski.md)."""
    vs, kind = best[1], best[2]
    weight = (m if m else 1.0) * 9.81
    for share in _FORCE_RESTARTS:
        f0 = share * weight
        lay_f = _Layout(
            NoiseModel(noise.sensor_std, force_std=f0, amplifier_std=noise.amplifier_std),
            est_noise,
            True,
        )
        run = _optimise(sp, y, vs, lay_f, dt=dt, m=m, max_iter=max_iter)
        notes.append(
            f"the start did not converge with the force disturbance from 0; restarted with it at "
            f"{f0:.2g} {'N' if m else 'm/s^2'} "
            f"({'converged' if run[3] else 'did not converge either'})"
        )
        if run[3] or run[4] < best[0][4]:
            best = (run, vs, kind)
        if run[3]:
            break
    return best


def _subspace_v(y: np.ndarray, u: np.ndarray, dt: float) -> np.ndarray | None:
    """v1..v9 of PBSID-opt's structured fit (None where it refuses the record)."""
    try:
        res = fit_pbsid(y, u, order=4, dt=dt, coordinates="physical")
    except (DataError, IdentificationError):
        return None
    return np.array([res.parameters[k] for k in V_NAMES])


# ---------------------------------------------------------------------------
# Steps
# ---------------------------------------------------------------------------
def _start_likelihood(
    sp: _Spectra, v: np.ndarray, lay: _Layout, dt: float, m: float | None
) -> float:
    """Eq. (1) at a starting point (inf where the predictor does not exist or its
    equations are ill-conditioned: a bad start, not a warning for the user)."""
    st = _trial(lambda th, _: _evaluate(lay.model(th, dt, m), sp, derivatives=False),
                lay.theta(v), False)  # fmt: skip
    return float("inf") if st is None else float(st["nll"])


def _predictor_radius(lay: _Layout, v: np.ndarray, dt: float, m: float | None) -> float | None:
    """Spectral radius of the Kalman predictor ``A - K C`` at ``v`` (None if none)."""

    def radius() -> float:
        model = lay.model(lay.theta(v), dt, m)
        K = steady_state_predictor(model.A, model.C, model.Q, model.R)[0]
        return float(np.max(np.abs(np.linalg.eigvals(model.A - K @ model.C))))

    return _guarded(radius)


def _exact_finish(
    y: np.ndarray,
    sp: _Spectra,
    theta: np.ndarray,
    final: dict[str, Any],
    lay: _Layout,
    it: int,
    converged: bool,
    *,
    dt: float,
    m: float | None,
    max_iter: int,
) -> tuple[np.ndarray, dict[str, Any], int, bool]:
    """After the lag path: the innovations' spectrum on the DFT bins.

    ``Xh = (zI - F)^-1 (B U + K Y + z tau)`` with the lag path's ``K`` and
    ``tau`` (equal to the DFT path's to rho^L), one pass over the bins. Where
    the predictor at the optimum decays slower than the lag count assumed
    (rho^L above 100 :data:`_LAG_TOL`) the fit is finished on the DFT path."""
    exact = sp.dft
    model = lay.model(theta, dt, m)
    if not _lags_hold(model.A - final["K"] @ model.C, sp.lags):
        runs = [_optimise(exact, y, theta[:9], lay, dt=dt, m=m, max_iter=max_iter,
                          theta0=theta)]  # fmt: skip
        restart = lay.theta(theta[:9])
        if not runs[0][3] and restart.size == theta.size and np.any(restart != theta):
            # The lag path's noise levels may be a corner its truncation made look good:
            # at 1e-3 of the default sensor noise (115 dB) it put the currents' noise on
            # its floor and x's on its ceiling (eq. (1) there -3e11 against -3e6), the
            # exact path then wandered 2.5 % in v2..v6 and stopped unconverged
            # (seventeenth session, on one machine's rounding). Again from the lag
            # optimum's v with the start's noise levels; the better exact fit is kept.
            lo, hi = lay.bounds(y)
            runs.append(_optimise(exact, y, theta[:9], lay, dt=dt, m=m, max_iter=max_iter,
                                  theta0=np.clip(restart, lo, hi)))  # fmt: skip
        theta, final, n_it, converged, _ = min(runs, key=lambda r: (not r[3], r[4]))
        return theta, final, it + n_it, converged
    return theta, {**final, "eps": _bin_errors(model, final, exact)}, it, converged


def _bin_errors(model: Any, st: dict[str, Any], exact: _Spectra) -> np.ndarray:
    """The innovations on the DFT bins, ``Y - C Xh - D s``, from an evaluation's ``K``,
    ``tau`` and lines ``s`` (``Xh = (zI - F)^-1 (B U + K Y + z tau)``)."""
    K, tau = st["K"], st["tau"]
    F = model.A - K @ model.C
    drive = exact.U @ model.B.T + exact.Y @ K.T + exact.z[:, None] * tau[None, :]
    Xh = _Resolvent(F, exact.z).apply(drive[:, None, :], np.eye(F.shape[0]))[:, 0, :]
    eps = exact.Y - Xh @ model.C.T
    return eps if st.get("lines") is None else eps - exact.D @ st["lines"]


def _nominal_v(data: ClosedLoopData) -> np.ndarray | None:
    """v1..v9 of the bearing the loop was designed on (``loop["nominal"]``), if recorded."""
    nom = data.loop.get("nominal") if isinstance(data.loop, Mapping) else None
    if not isinstance(nom, Mapping):
        return None
    try:
        return AMBParameters(**nom).v()
    except (TypeError, DataError):
        return None


def _signals(data: ClosedLoopData) -> tuple[np.ndarray, np.ndarray]:
    if not isinstance(data, ClosedLoopData):
        raise DataError(f"`data` must be a ClosedLoopData; got {type(data).__name__}")
    if data.p != 1:
        raise DataError(
            f"the ml method needs one output sample per control period; got p={data.p}"
        )
    if data.u is None and data.u_f is not None and data.r is not None:
        data = data.with_plant_input()
    if data.u is None or data.ny != 3 or data.nu != 2:
        raise DataError(
            "the ml method needs a two-coil AMB recording: y = [x, i1, i2] and the logged "
            f"u = [u1, u2]; got {data.ny} outputs and {0 if data.u is None else data.nu} inputs"
        )
    C = data.loop.get("C") if isinstance(data.loop, Mapping) else None
    if C is not None and not np.allclose(np.asarray(C, dtype=float), C_AMB):
        raise DataError("the ml method expects y = [x, i1, i2] (C of eq. (3))")
    if data.n_samples < 200:
        raise DataError(f"the recording has {data.n_samples} samples; the ml method needs >= 200")
    return np.asarray(data.y, dtype=float), np.asarray(data.u, dtype=float)


def _start(
    data: ClosedLoopData, start: Any, *, m: float | None, i0: float | None
) -> tuple[np.ndarray, np.ndarray | None, str, list[str]]:
    """v1..v9 to start from, sensor noise levels if known, and how they were obtained."""
    if isinstance(start, IdentificationResult):
        if start.method != "physical" or not all(k in start.parameters for k in V_NAMES):
            raise DataError(
                "`start` as a result must be the `physical` fit of this record; got "
                f"method {start.method!r}"
            )
        iv = start
    elif isinstance(start, str):
        if start != "physical":
            raise DataError(f"`start` must be 'physical' or 9 numbers; got {start!r}")
        # without the loop's controller and observer, the IV start takes lags of r (a
        # start only: the other starts of _ordered_starts compete with it)
        lags = not loop_recorded(data.loop)
        iv = fit_physical(data, m=m, i0=i0, instruments="lags" if lags else "auto")
    if isinstance(start, (str, IdentificationResult)):
        v0 = np.array([iv.parameters[k] for k in V_NAMES])
        cov_w = iv.extras.get("noise_covariance")
        s0 = None if cov_w is None else np.sqrt(np.clip(np.diag(np.asarray(cov_w)), 0, None))
        note = f"started from the physical ({iv.options['estimator']}) estimate"
        return v0, s0, "physical", [note]
    v0 = np.asarray(start, dtype=float).reshape(-1)
    if v0.size != 9 or not np.all(np.isfinite(v0)):
        raise DataError(f"`start` must be 'physical' or 9 finite numbers; got {start!r}")
    return v0, None, "given", ["started from the given v1..v9"]


def _noise(
    data: ClosedLoopData,
    noise_std: Any,
    amplifier_std: Any,
    s0: np.ndarray | None,
) -> tuple[NoiseModel, bool]:
    """The noise model to start from and whether its sensor levels are estimated."""
    if isinstance(noise_std, str):
        if noise_std == "metadata":
            nm = NoiseModel.from_data(data)
            if nm is None:
                raise DataError("noise_std='metadata': the recording has no positive noise_std")
            s, est = nm.sensor_std, False
        elif noise_std == "estimate":
            # Start: the IV fit's white-noise estimate, else the sample-to-sample
            # variation of each channel (the log of each level is a parameter).
            dy = np.diff(np.asarray(data.y, dtype=float), axis=0)
            fallback = np.maximum(np.std(dy, axis=0) / np.sqrt(2.0), 1e-300)
            ok = s0 is not None and np.all(np.isfinite(s0)) and np.all(s0 > 0)
            s = tuple((s0 if ok else fallback).tolist())  # type: ignore[union-attr]
            est = True
        else:
            raise DataError(
                f"`noise_std` must be 'estimate', 'metadata' or 3 numbers; got {noise_std!r}"
            )
    else:
        s, est = tuple(np.asarray(noise_std, dtype=float).reshape(-1).tolist()), False
    return NoiseModel(s, amplifier_std=amplifier_std), est  # type: ignore[arg-type]


def _force(data: ClosedLoopData, force_std: Any) -> tuple[float, bool]:
    """The force disturbance's level to start from [N] and whether it is estimated."""
    if isinstance(force_std, str):
        if force_std == "estimate":
            return 0.0, True
        if force_std == "metadata":
            f = data.metadata.get("force_std") if isinstance(data.metadata, Mapping) else None
            if f is None:
                raise DataError("force_std='metadata': the recording has no force_std")
            return float(f), False
        raise DataError(
            f"`force_std` must be 'estimate', 'metadata' or a number >= 0; got {force_std!r}"
        )
    try:
        f = float(force_std)
    except (TypeError, ValueError):
        raise DataError(f"`force_std` must be a number >= 0; got {force_std!r}") from None
    if not np.isfinite(f) or f < 0:
        raise DataError(f"`force_std` must be a number >= 0; got {force_std!r}")
    return f, False


class _Layout:
    """The parameter vector ``[v1..v9, log s (if estimated), s_F^2 (if estimated)]``."""

    def __init__(self, noise: NoiseModel, est: bool, est_force: bool) -> None:
        self.noise, self.est, self.est_force = noise, est, est_force
        self.size = 9 + 3 * est + est_force
        self.i_force = self.size - 1 if est_force else None

    def theta(self, v: np.ndarray) -> np.ndarray:
        parts = [np.asarray(v, dtype=float)]
        if self.est:
            parts.append(np.log(self.noise.sensor_std))
        if self.est_force:
            parts.append([self.noise.force_std**2])
        return np.concatenate(parts)

    def bounds(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds: the force variance is >= 0, and each estimated
        sensor noise level lies within ``[1e-6, 10] x`` its channel's standard
        deviation (:data:`_SENSOR_RANGE`). Below the floor a record is noise-free to
        the parameters' precision and the likelihood of a noise level has no
        finite optimum (a noise-free record, or one quantised more finely than
        its model error, would drive it to zero); above the ceiling the level
        would exceed the signal itself."""
        lo = np.full(self.size, -np.inf)
        hi = np.full(self.size, np.inf)
        if self.i_force is not None:
            lo[self.i_force] = 0.0
        if self.est:
            sd = np.std(np.asarray(y, dtype=float), axis=0)
            sd = np.where(sd > 0, sd, 1.0)
            lo[9:12] = np.log(_SENSOR_RANGE[0] * sd)
            hi[9:12] = np.log(_SENSOR_RANGE[1] * sd)
        return lo, hi

    def sensor(self, theta: np.ndarray) -> np.ndarray:
        return np.exp(theta[9:12]) if self.est else np.asarray(self.noise.sensor_std)

    def force(self, theta: np.ndarray) -> float:
        if self.i_force is None:
            return self.noise.force_std
        return float(np.sqrt(max(theta[self.i_force], 0.0)))

    def model(self, theta: np.ndarray, dt: float, m: float | None) -> Any:
        noise = NoiseModel(
            tuple(self.sensor(theta).tolist()),  # type: ignore[arg-type]
            force_std=self.force(theta),
            amplifier_std=self.noise.amplifier_std,
        )
        return amb_linear_gaussian_model(
            theta[:9], dt, noise, m=m, estimate_noise=self.est, estimate_force=self.est_force
        )


# ---------------------------------------------------------------------------
# Eq. (1) in the frequency domain
# ---------------------------------------------------------------------------
# The predictor is a linear filter from (y, u) to eps. For a record of N
# samples the DFT turns its recursion xh(k+1) = F xh(k) + B u(k) + K y(k) into,
# at z = exp(2 pi j f / N), exactly (z^N = 1)
#
#     Xh(z) = (z I - F)^-1 (B U(z) + K Y(z) + z tau),  tau = xh(0) - xh(N),
#
# and Parseval gives sum_k eps_k^T S^-1 eps_k = (1/N) sum_f E(f)^H S^-1 E(f).
# With tau a free nuisance parameter and the f = 0 bin left out (a constant
# offset of y or u only moves that bin) eq. (1) is the time-domain criterion
# with free offsets and a free start-up transient -- 7 of the N degrees of
# freedom -- and costs one batched 4 x 4 inverse per frequency instead of a
# recursion over the samples per parameter.


class _Spectra:
    """Real FFT of the record, the frequencies ``z`` and the Parseval weights.

    Every quantity of eq. (1) is a weighted sum over the entries ``f`` of
    products of two vectors linear in ``zeta_f = [Y_f; U_f; kappa_f]``
    (``kappa`` multiplies the transient's source ``z tau``). Here the entries
    are the N/2 + 1 DFT bins, ``kappa = 1`` and the weights are positive
    (``sign is None``); :func:`_lag_spectra` builds a short, signed set of
    entries with the same sums (the large-N path).
    """

    def __init__(self, y: np.ndarray, u: np.ndarray, seq: np.ndarray | None = None) -> None:
        N = y.shape[0]
        self.N = N
        self.Y = np.fft.rfft(y, axis=0)
        self.U = np.fft.rfft(u, axis=0)
        # the periodic lines' unit sinusoids (maglevid.identify.periodic), or None
        self.seq = seq if seq is not None and seq.shape[1] else None
        self.D = None if self.seq is None else np.fft.rfft(self.seq, axis=0)
        M = self.Y.shape[0]
        self.z = np.exp(2j * np.pi * np.arange(M) / N)
        w = np.full(M, 2.0)
        w[0] = 0.0  # the offsets' bin
        if N % 2 == 0:
            w[-1] = 1.0  # Nyquist
        self.w = w
        self.kappa = np.ones(M)
        self.sign: np.ndarray | None = None
        self.first = 1  # the first entry the information uses (bin 0 has weight 0)
        self.lags = 0  # 0: the exact DFT path
        self.dft = self

    #: More lags for a slower predictor (set by :func:`_spectra`); else the DFT bins.
    _wider: Callable[[float], _Spectra] | None = None

    def widen(self, rho: float) -> _Spectra:
        """Entries that hold eq. (1) for a predictor of spectral radius ``rho`` (the
        lag path's, when :func:`_evaluate` finds it slower than its lags hold)."""
        return self.dft if self._wider is None else self._wider(rho)


#: The lag path (:func:`_lag_spectra`) is used when the DFT has this many times
#: more entries (measured at N = 1e5, 24.6k lag entries against 50k bins: one
#: evaluation 0.07 s against 0.12 s, the lagged products 0.07 s once).
_LAG_MIN_RATIO = 1.5

#: Truncation of the lag path: L lags with rho^L <= this (rho: spectral radius
#: of the predictor A - K C at the start; the grid is the power of two >= 2 L + 2
#: and L is then half of it). Measured at N = 1e5 on the default bearing
#: (rho = 0.9956, 4095 lags): the scoring step differs from the DFT path's by
#: 3e-5 standard errors, the information by 2e-12 relative; the error grows
#: as rho^L sqrt(N).
_LAG_TOL = 1e-7

#: The lag path is trusted while ``rho^L`` of the predictor evaluated stays below this
#: (:func:`_evaluate` widens the entries beyond it; :func:`_exact_finish`).
_LAG_VALID = 100.0 * _LAG_TOL


def _lags_hold(F: np.ndarray, lags: int) -> bool:
    """Whether ``lags`` lags hold eq. (1) for the predictor ``F`` (``rho^L`` within
    :data:`_LAG_VALID`)."""
    return float(np.max(np.abs(np.linalg.eigvals(F)))) ** lags <= _LAG_VALID


#: The lag path's entries of recent records (ClosedLoopData is immutable), so a
#: second fit of the same record (another start) does not recompute them.
_LAG_CACHE: weakref.WeakKeyDictionary[Any, dict[Any, _Spectra]] = weakref.WeakKeyDictionary()


def _spectra(
    y: np.ndarray,
    u: np.ndarray,
    rho: float | None,
    key: Any = None,
    *,
    lines: tuple[float, ...] = (),
    dt: float = 1.0,
    degrees: tuple[int, ...] = (),
) -> _Spectra:
    """The exact DFT entries, or the lag path's when they are much fewer (N large);
    ``lines``: the frequencies [Hz] of the periodic lines profiled out (period ``dt``).

    With lines, ``y`` and ``u`` first lose their least-squares sinusoids at those
    frequencies (each channel): the errors change by sinusoids of the lines' frequencies
    filtered by the predictor, i.e. a sinusoid and a transient of its modes, which the
    profiled lines and ``tau`` absorb exactly, so eq. (1), its gradient and the
    information with the nuisance eliminated are unchanged; but the entries no longer
    carry the lines' energy (a 1 N unbalance: ~1e6 times a bin's noise), whose rounding
    and the lag path's truncation (``rho^L`` times it) otherwise swamped the information
    (found at N = 1e5: the scoring's information not positive definite).
    """
    seq = line_sequences(y.shape[0], dt, lines, degrees) if lines else None
    if seq is not None:
        y = y - seq @ line_coefficients(y, seq)
        u = u - seq @ line_coefficients(u, seq)
    if rho is None or not 0.0 < rho < 1.0:
        return _Spectra(y, u, seq)
    cache = _LAG_CACHE.setdefault(key, {}) if key is not None else {}

    def entries(rho: float, dft: _Spectra | None = None) -> _Spectra:
        """The lag path's entries for a predictor decaying as ``rho``, or the DFT bins
        (``dft``, computed here where not given)."""
        lags = int(np.ceil(np.log(_LAG_TOL) / np.log(rho)))  # a stable predictor: rho < 1
        grid = 1 << int(np.ceil(np.log2(2 * lags + 2)))
        if (6 + 2 * len(lines)) * (grid // 2 + 1) * _LAG_MIN_RATIO > y.shape[0] // 2 + 1:
            return _Spectra(y, u, seq) if dft is None else dft
        if (grid, lines, degrees) not in cache:
            out = _lag_spectra(_Spectra(y, u, seq) if dft is None else dft, y, u, grid)
            # a predictor slower than these lags hold (:func:`_evaluate`): entries with
            # room for it, halfway from its radius to 1 (or the DFT bins)
            out._wider = lambda rho_seen, d=out.dft: entries(0.5 * (1.0 + rho_seen), d)
            cache[grid, lines, degrees] = out
        return cache[grid, lines, degrees]

    return entries(rho)


def _lag_spectra(sp: _Spectra, y: np.ndarray, u: np.ndarray, grid: int) -> _Spectra:
    """Entries on a grid of ``grid`` frequencies with the sums of the DFT path.

    Every term of eq. (1), its gradient and eq. (2) is a sum over the N DFT bins
    ``f != 0`` of ``a(z_f)^H zeta_f zeta_f^H b(z_f)`` with ``zeta = [Z; 1]``,
    ``Z = [Y; U]``, and ``a``, ``b`` rational in ``z`` with the predictor's poles:
    their products' Fourier coefficients decay as ``k rho^|k|``. With the
    record's circular lagged products ``N R_k = sum_t z_(t+k) z_t^T`` (exact, by
    FFT; the mean removed: bin 0 carries only the offsets) and ``L`` lags
    (``M >= 2 L + 2``; ``z_m = exp(2 pi j m / M)``):

        sum_f F(z_f) Z_f Z_f^H = (N/M) sum_m F(z_m) P_m,  P_m = sum_|k|<=L N R_k z_m^-k
        sum_f G(z_f) Z_f       = (N/M) sum_m G(z_m) E_m,  E_m = sum_|t|<=L z_t z_m^-t
        sum_(f!=0) D(z_f)      = (N/M) sum_m D(z_m) - D(1)

    to the coefficients beyond ``L`` (``rho^L``) -- the linear terms are the
    transient's (``E`` holds the record's first and last ``L`` samples: the
    wrap-around the transient ``tau`` absorbs). So each grid frequency carries
    the 6 x 6 Hermitian ``A_m = [[P_m, E_m], [E_m^H, 1 - delta_m0 M/N]]``, and
    its eigenvectors ``v`` with the (signed) weights ``(N/M) w_m lambda`` are
    6 entries with exactly those sums. Cost per evaluation: ``3 M`` entries
    whatever ``N``; once per record: 15 inverse FFTs of length N.
    """
    N = sp.N
    lags = grid // 2 - 1
    seq = np.zeros((N, 0)) if sp.seq is None else sp.seq  # the lines' sinusoids: inputs too
    u = np.concatenate([u, seq], axis=1)
    parts = [sp.Y.T, sp.U.T] + ([] if sp.D is None else [sp.D.T])
    Zt = np.concatenate(parts)  # (5 + 2 H, M), rows contiguous
    Zt[:, 0] = 0.0  # the mean removed
    Zc = Zt.conj()
    c = Zt.shape[0]
    R = np.zeros((grid, c, c))  # N R_k at k (and -k at grid - k)
    for i in range(c):
        r = np.fft.irfft(Zt[i] * Zc[i:], n=N, axis=1)  # (c - i, N): pairs (i, j >= i)
        for j in range(i, c):
            rij = r[j - i]
            R[: lags + 1, i, j] = rij[: lags + 1]
            R[grid - lags :, i, j] = rij[N - lags :]
            R[: lags + 1, j, i] = np.r_[rij[0], rij[N - 1 : N - lags - 1 : -1]]
            R[grid - lags :, j, i] = rij[lags:0:-1]
    P = np.fft.fft(R, axis=0)[: grid // 2 + 1]
    mean = np.concatenate([y.mean(axis=0), u.mean(axis=0)])
    ez = np.zeros((grid, c))  # the record's first and last samples (t = -L..L)
    ez[: lags + 1] = np.concatenate([y[: lags + 1], u[: lags + 1]], axis=1) - mean
    ez[grid - lags :] = np.concatenate([y[N - lags :], u[N - lags :]], axis=1) - mean
    E = np.fft.fft(ez, axis=0)[: grid // 2 + 1]
    Mh = grid // 2 + 1
    A = np.zeros((Mh, c + 1, c + 1), dtype=complex)
    A[:, :c, :c] = 0.5 * (P + P.conj().transpose(0, 2, 1))
    A[:, :c, c] = E
    A[:, c, :c] = E.conj()
    A[:, c, c] = 1.0
    A[0, c, c] = 1.0 - grid / N
    lam, V = np.linalg.eigh(A)
    wm = np.full(Mh, 2.0)
    wm[0] = wm[-1] = 1.0
    w = (N / grid) * (wm[:, None] * lam).reshape(-1)
    ent = V.transpose(0, 2, 1).reshape(-1, c + 1)  # entry (m, eigenvector)
    out = object.__new__(_Spectra)
    out.N = N
    out.Y, out.U, out.kappa = ent[:, :3], ent[:, 3:5], ent[:, c]
    out.seq = sp.seq
    out.D = None if sp.seq is None else ent[:, 5:c]
    out.z = np.repeat(np.exp(2j * np.pi * np.arange(Mh) / grid), c + 1)
    out.w = np.abs(w)
    out.sign = np.sign(w)
    out.first = 0
    out.lags = lags
    out.dft = sp  # for the innovations at the end
    return out


#: The eigenbasis is used while ``cond(V)`` is below this (else batched inverses).
_EIG_COND = 1e6


class _Resolvent:
    """``(z I - F)^-1`` at every frequency, applied to rows (layout ``(M, c, n)``).

    By the eigendecomposition ``F = V diag(lam) V^-1`` (one BLAS product per
    application instead of a 4 x 4 solve per frequency); a batched inverse
    when ``V`` is ill-conditioned (``F`` close to defective).
    """

    def __init__(self, F: np.ndarray, z: np.ndarray) -> None:
        lam, V = np.linalg.eig(F)
        self.eig = bool(np.linalg.cond(V) < _EIG_COND)
        if self.eig:
            self.V, self.Vi, self.T = V, np.linalg.inv(V), 1.0 / (z[:, None] - lam[None, :])
        else:
            self.G = np.linalg.inv(z[:, None, None] * np.eye(F.shape[0]) - F)

    def apply(self, X: np.ndarray, left: np.ndarray) -> np.ndarray:
        """``left (zI - F)^-1 x`` for every row ``x`` of ``X`` (M, c, n) -> (M, c, k)."""
        if self.eig:
            M, c, n = X.shape
            Z = (X.reshape(-1, n) @ self.Vi.T).reshape(M, c, n) * self.T[:, None, :]
            return (Z.reshape(-1, n) @ (left @ self.V).T).reshape(M, c, -1)
        return np.einsum("fcj,fij,ki->fck", X, self.G, left, optimize=True)

    def select(self, idx: np.ndarray) -> _Resolvent:
        """The same resolvent at the frequencies ``idx`` only."""
        sub = object.__new__(_Resolvent)
        sub.eig = self.eig
        if self.eig:
            sub.V, sub.Vi, sub.T = self.V, self.Vi, self.T[idx]
        else:
            sub.G = self.G[idx]
        return sub

    def rows_times(self, Q: np.ndarray) -> np.ndarray:
        """``q_f (zI - F)^-1`` for every row ``q_f`` of ``Q`` (M, n)."""
        if self.eig:
            return ((Q @ self.V) * self.T) @ self.Vi
        return np.einsum("fi,fij->fj", Q, self.G)

    def matrix(self, left: np.ndarray) -> np.ndarray:
        """``left (zI - F)^-1`` per frequency, (M, k, n)."""
        if self.eig:
            Z = (left @ self.V)[None, :, :] * self.T[:, None, :]
            return (Z.reshape(-1, Z.shape[2]) @ self.Vi).reshape(Z.shape)
        return left @ self.G


def _gram(X: np.ndarray, sign: np.ndarray | None = None) -> np.ndarray:
    """``Re sum_f sign_f X_f^H X_f`` for ``X`` (M, c, k) as one real product, (c, c)."""
    Xt = X.transpose(0, 2, 1).reshape(-1, X.shape[1])
    R = np.concatenate([Xt.real, Xt.imag])
    if sign is None:
        return R.T @ R
    sg = np.tile(np.repeat(sign, X.shape[2]), 2)
    return R.T @ (R * sg[:, None])


#: Frequencies per block of :func:`_sensitivity_gram` (bounds its memory).
_GRAM_BLOCK = 32768


def _sensitivity_gram(
    res: _Resolvent,
    LC: np.ndarray,
    G: np.ndarray,
    s: np.ndarray,
    scale: np.ndarray,
    sign: np.ndarray | None = None,
) -> np.ndarray:
    """``Re sum_f Psi_f^H Psi_f`` with ``Psi_f[j] = scale_f LC (z_f I - F)^-1 G_j s_f``.

    The whitened sensitivity of the innovations to parameter ``j`` (eq. (3)) is
    ``LC (zI - F)^-1 W_j`` with ``W_j = dA_j Xh + dB_j U + dK_j eps`` (and
    ``z e_m`` for the transient ``tau_m``): ``W_j = G_j s_f`` with the sources
    ``s_f = [Xh, U, eps, z]`` (10 numbers per frequency). In the eigenbasis
    ``(zI - F)^-1 = V D_f V^-1`` and, with ``Q_j = V^-1 G_j`` and
    ``H = (LC V)^H (LC V)``,

        info_ij = Re sum_{a,b,k,l} H_ab conj(Q_j'[a,k]) Q_j[b,l] Gm[(a,k),(b,l)],
        Gm = sum_f conj(Z_f) Z_f^T,   Z_f[(a,k)] = scale_f D_f[a] s_f[k]:

    one (4 x 10)-column Gram over the frequencies for all parameters at once,
    instead of the (M, p, 3) sensitivities and their Gram (same numbers; tested).
    """
    n = res.V.shape[0]
    c = n * s.shape[1]
    Gm = np.zeros((c, c), dtype=complex)
    for lo in range(0, s.shape[0], _GRAM_BLOCK):
        sl = slice(lo, lo + _GRAM_BLOCK)
        Z = ((res.T[sl] * scale[sl, None])[:, :, None] * s[sl, None, :]).reshape(-1, c)
        Gm += Z.conj().T @ (Z if sign is None else Z * sign[sl, None])
    LV = LC @ res.V
    Hm = LV.conj().T @ LV
    Q = np.einsum("ab,pbk->pak", res.Vi, G).reshape(G.shape[0], c)
    kernel = Gm * np.repeat(np.repeat(Hm, s.shape[1], axis=0), s.shape[1], axis=1)
    return np.real(Q.conj() @ kernel @ Q.T)


def _profile_transient(
    res: _Resolvent,
    LC: np.ndarray,
    zw: np.ndarray,
    e0w: np.ndarray,
    sign: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares ``tau`` of ``e0w - Phi tau`` with ``Phi_f = zw_f LC (z_f I - F)^-1``.

    Returns ``tau`` and ``Phi tau``. In the eigenbasis ``Phi_f = zw_f LC V D_f V^-1``
    and the normal equations are n x n sums over the frequencies (one product
    each, never the (M, ny, n) array): ``Re V^-H (H o sum_f conj(d_f) d_f^T) V^-1``
    with ``H = (LC V)^H (LC V)``, ``d_f = zw_f diag(D_f)``. ``sign``: the
    entries' weight signs (lag path), else all positive.
    """
    sg = np.ones(zw.shape[0]) if sign is None else sign
    if not res.eig:
        Phi = res.matrix(LC) * zw[:, None, None]
        P = _gram(Phi.transpose(0, 2, 1), sign)
        b = np.real(np.einsum("fik,fi->k", Phi.conj(), e0w * sg[:, None]))
        tau = np.linalg.lstsq(P, b, rcond=None)[0]
        return tau, Phi @ tau
    LV = LC @ res.V
    d = res.T * zw[:, None]
    Hm = LV.conj().T @ LV
    ds = d if sign is None else d * sign[:, None]
    P = np.real(res.Vi.conj().T @ (Hm * (d.conj().T @ ds)) @ res.Vi)
    q = e0w @ LV.conj()  # rows (LC V)^H e0w_f
    b = np.real(res.Vi.conj().T @ np.einsum("fk,fk->k", ds.conj(), q))
    tau = np.linalg.lstsq(P, b, rcond=None)[0]
    return tau, ((res.Vi @ tau)[None, :] * d) @ LV.T


def _evaluate(model: Any, sp: _Spectra, *, derivatives: bool, stride: int = 1) -> dict[str, Any]:
    """Eq. (1) with ``tau`` profiled; with ``derivatives``, gradient and eq. (2)
    (the latter from every ``stride``-th frequency)."""
    A, B, C = model.A, model.B, model.C
    n = A.shape[0]
    K, P, S = steady_state_predictor(A, C, model.Q, model.R)
    F = A - K @ C
    if sp.lags:
        # The lag path holds eq. (1) to rho^L: a slower predictor gets wider entries
        # (its truncated sums otherwise made a slow, wrong predictor look better: at
        # 10x the default sensor noise the scoring walked from eq. (1) = -5.2e5 to a
        # lag-path -8.5e5 that is -4.7e5 on the DFT bins, uphill, then to -4e10; found
        # from outside, twenty-fifth session)
        if not _lags_hold(F, sp.lags):
            rho = float(np.max(np.abs(np.linalg.eigvals(F))))
            return _evaluate(model, sp.widen(rho), derivatives=derivatives, stride=stride)
    N, z, sw, sg = sp.N, sp.z, np.sqrt(sp.w), sp.sign
    zk = z * sp.kappa  # the transient's source z tau (kappa = 1 on the DFT path)
    res = _Resolvent(F, z)
    Li = np.linalg.inv(np.linalg.cholesky(S))
    LC = Li @ C
    # Whitened innovations Li eps = Li Y - Li C (zI-F)^-1 (B U + K Y) - Li Phi tau
    drive = (sp.U @ B.T + sp.Y @ K.T)[:, None, :]
    e0w = ((sp.Y @ Li.T)[:, None, :] - res.apply(drive, LC))[:, 0, :] * sw[:, None]
    lines = None  # the periodic lines' sinusoids in the prediction errors, (2 H, ny)
    if sp.D is None:
        tau, fitted = _profile_transient(res, LC, zk * sw, e0w, sg)
    else:
        Psi = np.einsum("fj,ic->fijc", sp.D * sw[:, None], Li).reshape(len(z), Li.shape[0], -1)
        tau, lines, fitted = _profile_transient_lines(res, LC, zk * sw, Psi, e0w, sg)
    ew = e0w - fitted  # whitened, weighted innovations
    ews_ = ew if sg is None else ew * sg[:, None]
    sum_ww = np.vdot(ew, ews_).real / N  # sum_k eps^T S^-1 eps (Parseval)
    _, logdet = np.linalg.slogdet(S)
    out: dict[str, Any] = {
        "nll": 0.5 * sum_ww + 0.5 * N * logdet, "S": S, "K": K, "tau": tau, "lines": lines
    }  # fmt: skip
    if not derivatives:
        return out
    dK, dS = predictor_derivatives(model, K, P, S)
    p = model.n_params
    # Xh = (zI-F)^-1 (B U + K Y + z tau), eps = Y - C Xh (unweighted DFTs)
    Xh = res.apply(drive + (zk[:, None] * tau[None, :])[:, None, :], np.eye(n))[:, 0, :]
    eps = sp.Y - Xh @ C.T  # the predictor's errors; the innovations less the lines:
    innov = eps if lines is None else eps - sp.D @ lines
    ews = innov * sw[:, None]
    sum_ee = np.real((ews if sg is None else ews * sg[:, None]).T @ ews.conj()) / N
    # Gradient of eq. (1) by the adjoint of eq. (3): with psi_i = -Li C (zI-F)^-1 W_i,
    # W_i = A_i Xh + B_i U + K_i E, sum_f psi_i^H ew = sum_f W_i^H mu with
    # mu = -(Li C (zI-F)^-1)^H ew: three n x (n, nu, ny) sums for all parameters at
    # once, instead of one recursion per parameter (tau is at its optimum: no term).
    mu = -np.conj(res.rows_times(ews_.conj() @ LC)) * sw[:, None]
    grad = np.zeros(p + n)
    grad[:p] = (
        np.einsum("pjk,jk->p", model.dA, np.real(mu.T @ Xh.conj()))
        + np.einsum("pjk,jk->p", model.dB, np.real(mu.T @ sp.U.conj()))
        + np.einsum("pjk,jk->p", dK, np.real(mu.T @ eps.conj()))
    ) / N
    # eq. (2) from the sensitivities at every `stride`-th frequency (weights scaled):
    # the scoring step needs the information only approximately; the covariance
    # is computed with stride 1.
    idx = np.arange(sp.first, len(z), stride)
    scale = np.sqrt(stride) * sw[idx]
    sgi = None if sg is None else sg[idx]
    sources = np.concatenate([Xh[idx], sp.U[idx], eps[idx], zk[idx, None]], axis=1)
    G = np.concatenate(
        [
            np.concatenate([model.dA, model.dB, dK, np.zeros((p, n, 1))], axis=2),
            np.concatenate([np.zeros((n, n, sources.shape[1] - 1)), np.eye(n)[:, :, None]], 2),
        ]
    )
    if res.eig:
        info = _sensitivity_gram(res.select(idx), LC, G, sources, scale, sgi) / N
    else:
        Psw = -res.select(idx).apply(np.einsum("pik,fk->fpi", G, sources), LC)
        info = _gram(Psw * scale[:, None, None], sgi) / N
    Si = np.linalg.inv(S)
    SidS = np.einsum("ij,pjk->pik", Si, dS)
    info[:p, :p] += 0.5 * N * np.einsum("pij,qji->pq", SidS, SidS)  # eq. (2)
    grad[:p] += 0.5 * N * np.trace(SidS, axis1=1, axis2=2) - 0.5 * np.einsum(
        "pij,ji->p", SidS @ Si, sum_ee
    )
    if lines is not None:  # the lines' sinusoids: nuisance parameters after tau
        info = _line_information(res, LC, info, Psi, sg, sw, model, dK, Xh, sp.U, eps, zk, N)
        grad = np.concatenate([grad, np.zeros(Psi.shape[2])])
    out["fisher"] = 0.5 * (info + info.T)
    out["gradient"] = grad
    out["eps"] = innov
    return out


def _profile_transient_lines(  # type: ignore[no-untyped-def]
    res: _Resolvent, LC: np.ndarray, zw: np.ndarray, Psi: np.ndarray, e0w, sign
):
    """Least-squares ``tau`` and lines' sinusoids ``s`` of ``e0w - Phi tau - Psi s``.

    ``Psi`` (M, ny, 2 H ny): the whitened, weighted unit sinusoids per channel
    (column ``j ny + c``: ``sw_f L^-1[:, c] D_f[j]``, ``D`` the lines' DFT),
    :mod:`maglevid.identify.periodic`. Returns ``tau``, ``s`` (2 H, ny) and the fitted
    ``Phi tau + Psi s``. ``Phi`` is formed (M, ny, n): with lines the frequencies are
    the DFT's or the lag path's entries, and the columns few.
    """
    X = np.concatenate([res.matrix(LC) * zw[:, None, None], Psi], axis=2)
    P = _gram(X.transpose(0, 2, 1), sign)
    ws = e0w if sign is None else e0w * sign[:, None]
    b = np.real(np.einsum("fik,fi->k", X.conj(), ws))
    sol = np.linalg.lstsq(P, b, rcond=None)[0]
    n = LC.shape[1]
    return sol[:n], sol[n:].reshape(-1, LC.shape[0]), np.einsum("fik,k->fi", X, sol)


def _line_information(  # type: ignore[no-untyped-def]
    res, LC, info, Psi, sign, sw, model, dK, Xh, U, eps, zk, N
) -> np.ndarray:
    """Eq. (2) bordered by the lines' sinusoids (nuisance parameters after ``tau``).

    Their sensitivity is ``-Psi`` (not filtered: they enter the errors directly);
    the cross terms with a parameter's ``-Li C (zI - F)^-1 W_i sw`` come from the
    adjoint ``v = Psi^H Li C (zI - F)^-1`` per column, as the gradient's do (every
    frequency: a line's information sits at a few of them, which a stride would miss).
    """
    q = Psi.shape[2]
    Q = np.conj(Psi).transpose(0, 2, 1) @ LC  # (M, q, n) rows Psi_col^H Li C
    if res.eig:
        Vt = ((Q @ res.V) * res.T[:, None, :]) @ res.Vi
    else:
        Vt = np.einsum("fci,fij->fcj", Q, res.G)
    wgt = sw if sign is None else sw * sign
    Vw = Vt * wgt[:, None, None]  # (M, q, n)
    p = model.n_params

    def cross(src: np.ndarray) -> np.ndarray:  # Re sum_f Vw_f[c, k] src_f[l] -> (q, n, l)
        return np.real(np.einsum("fck,fl->ckl", Vw, src))

    ixs = (
        np.einsum("pkl,ckl->pc", model.dA, cross(Xh))
        + np.einsum("pkl,ckl->pc", model.dB, cross(U))
        + np.einsum("pkl,ckl->pc", dK, cross(eps))
    )
    its = np.real(np.einsum("fck,f->kc", Vw, zk))
    iss = _gram(Psi.transpose(0, 2, 1), sign)
    ixs, its, iss = ixs / N, its / N, iss / N  # Parseval, as eq. (2)'s
    k = info.shape[0]
    out = np.zeros((k + q, k + q))
    out[:k, :k] = info
    out[:p, k:] = ixs
    out[p:k, k:] = its
    out[k:, :p] = ixs.T
    out[k:, p:k] = its.T
    out[k:, k:] = iss
    return out


def _optimise(
    sp: _Spectra,
    y: np.ndarray,
    v0: np.ndarray,
    lay: _Layout,
    *,
    dt: float,
    m: float | None,
    max_iter: int,
    theta0: np.ndarray | None = None,
) -> tuple[np.ndarray, dict[str, Any], int, bool, float]:
    """Fisher scoring with Levenberg-Marquardt damping on eq. (1).

    The parameters are ``[v, log s, s_F^2 (if estimated)]``; the transient ``tau``
    is profiled out exactly at every point (it enters affinely), so the
    reduced gradient and information (Schur complement) drive the step.
    Returns the estimate, the final evaluation (information with ``tau``
    from every frequency, innovations' spectrum, ``K``, ``S``), the
    iterations, whether it converged and the final value of eq. (1).
    ``sp``: the DFT entries or the lag path's (:func:`_spectra`); ``theta0``:
    the full start (else ``v0`` with the layout's noise levels).
    """
    lower, upper = lay.bounds(y)
    theta = np.clip(lay.theta(v0) if theta0 is None else theta0, lower, upper)
    p = theta.size

    stride = 1 if sp.lags else max(1, len(sp.z) // _FISHER_FREQUENCIES)

    def evaluate(th: np.ndarray, derivatives: bool, full: bool = False) -> dict[str, Any]:
        model = lay.model(th, dt, m)
        return _evaluate(model, sp, derivatives=derivatives, stride=1 if full else stride)

    try:
        st = evaluate(theta, True)
    except IdentificationError as exc:
        raise IdentificationError(f"ml: no stable Kalman predictor at the start ({exc})") from exc
    it = 0
    converged = False
    # Stage 1 holds the noise levels at their start (the IV fit's estimate, no
    # force disturbance): the dynamics converge from a poor start without the
    # noise levels absorbing the misfit; stage 2 frees everything.
    stages = [np.arange(9), np.arange(p)] if p > 9 else [np.arange(p)]
    for free in stages:
        theta, st, n_it, converged = _scoring(
            evaluate, theta, st, free, max_iter - it, lower=lower, upper=upper
        )
        it += n_it
    st = evaluate(theta, True, full=True)  # the covariance from every frequency
    return theta, st, it, converged, float(st["nll"])


def _scoring(
    evaluate: Any,
    theta: np.ndarray,
    st: dict[str, Any],
    free_all: np.ndarray,
    max_iter: int,
    *,
    lower: np.ndarray | None = None,
    upper: np.ndarray | None = None,
) -> tuple[np.ndarray, dict[str, Any], int, bool]:
    """Levenberg-Marquardt-damped Fisher scoring on the ``free`` parameters.

    Active set for the ``lower`` and ``upper`` bounds: a parameter on its bound
    whose gradient points out of the feasible set is held there for the step (it
    is at its constrained optimum, and the convergence test leaves it out); a
    step across a bound is cut at the bound.
    """
    p = theta.size
    lower = np.full(p, -np.inf) if lower is None else lower
    upper = np.full(p, np.inf) if upper is None else upper
    lam = 1e-3
    it = 0
    while it < max_iter:
        it += 1
        g_all = st["gradient"][:p]
        pinned = ((theta <= lower) & (g_all > 0)) | ((theta >= upper) & (g_all < 0))
        free = free_all[~pinned[free_all]]
        k = free.size
        info_red = eliminate_nuisance(st["fisher"], p)[np.ix_(free, free)]
        g = g_all[free]
        d = np.sqrt(np.clip(np.diag(info_red), 1e-300, None))
        decrease = float(g @ pinv_information(info_red) @ g)
        if decrease < _TOL * k:
            return theta, st, it, True
        for _ in range(14):
            Ms = info_red / np.outer(d, d) + lam * np.eye(k)
            trial = theta.copy()
            trial[free] -= np.linalg.solve(Ms, g / d) / d
            trial = np.minimum(np.maximum(trial, lower), upper)
            # A lightly damped step is usually accepted: evaluate it with the
            # derivatives at once (one pass instead of two); a heavily damped one
            # is checked cheaply first.
            likely = lam < 1e-2
            st_t = _trial(evaluate, trial, likely)
            if st_t is not None and st_t["nll"] < st["nll"] and not likely:
                st_t = _trial(evaluate, trial, True)  # its derivatives, for the next step
            if st_t is not None and st_t["nll"] < st["nll"]:
                theta, st = trial, st_t
                lam = max(lam / 10.0, 1e-9)
                break
            lam *= 10.0
        else:
            # No descent at any damping: at the optimum to rounding (or stuck).
            # (the remaining step under a tenth of a standard error: rounding, converged)
            return theta, st, it, decrease < 1e-2 * k
    return theta, st, it, False


def _trial(evaluate: Any, theta: np.ndarray, derivatives: bool) -> dict[str, Any] | None:
    """Eq. (1) at a trial point, or ``None`` where the predictor cannot be computed.

    An ill-conditioned predictor (Lyapunov equation, DARE) at a trial point is
    a bad point: rejected like a failed one, not warned about.
    """
    return _guarded(lambda: evaluate(theta, derivatives))


def _guarded(compute: Any) -> Any:
    """``compute()``, or None where the predictor's equations fail or are ill-conditioned
    (scipy's LinAlgWarning taken as a failure: a bad point, not a warning for the user)."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", sla.LinAlgWarning)
            return compute()
    except (
        IdentificationError,
        ValueError,
        FloatingPointError,
        np.linalg.LinAlgError,
        sla.LinAlgWarning,
    ):
        return None


def _result(
    data: ClosedLoopData,
    theta: np.ndarray,
    final: dict[str, Any],
    lay: _Layout,
    *,
    m: float | None,
    i0: float | None,
    iterations: int,
    options: dict[str, Any],
    notes: list[str],
    converged: bool,
    v_start: np.ndarray,
    lines: tuple[float, ...] = (),
    unsettled: tuple[float, ...] = (),
    envelope: tuple[int, ...] = (),
) -> IdentificationResult:
    """Model, parameters with covariance (inverse Fisher, delta method) and diagnostics."""
    v = theta[:9]
    info = final["fisher"]
    keep = np.ones(info.shape[0], dtype=bool)
    if lay.i_force is not None and theta[lay.i_force] <= 0.0:
        # No force disturbance (its variance on the bound 0, the constrained
        # optimum): the parameter is known there, not a free nuisance.
        keep[lay.i_force] = False
    cov_v = invert_information(eliminate_nuisance(info[np.ix_(keep, keep)], 9))
    dnames, _ = derived_parameters(v, m=m, i0=i0)

    def chain(vv: np.ndarray) -> np.ndarray:
        return np.concatenate([vv, derived_parameters(vv, m=m, i0=i0)[1]])

    values, cov = propagate_covariance(chain, v, cov_v)
    if m is None or i0 is None:
        notes.append(
            "mass m or bias current i0 unknown (loop['operating_point']): physical "
            "parameters need them; reporting v1..v9 and scale-free ratios only"
        )
    # Innovations: the inverse DFT of the final spectrum (zero-frequency bin, the
    # offsets, removed) -- the time-domain innovations of the predictor started
    # from the state that the profiled transient tau implies.
    y = np.asarray(data.y, float)
    E = np.array(final["eps"])
    # Output offsets: the zero-frequency bin, E(1) = N (I - C (I - F)^-1 K) c.
    model = lay.model(theta, data.dt, m)
    K = final["K"]
    Fm = model.A - K @ model.C
    Hc = np.eye(3) - model.C @ np.linalg.solve(np.eye(4) - Fm, K)
    c = np.linalg.solve(Hc, np.real(E[0]) / y.shape[0])
    E[0] = 0.0
    eps = np.fft.irfft(E, n=y.shape[0], axis=0)
    Yc = y - y.mean(axis=0)
    osf = one_step_fit_percent(np.einsum("ij,ij->j", eps, eps), np.einsum("ij,ij->j", Yc, Yc))
    fitd = {f"one_step_fit_percent_{n}": float(f) for n, f in zip(data.channel_names("y"), osf)}
    fitd["one_step_fit_percent_min"] = float(np.nanmin(osf))
    fitd["neg_log_likelihood"] = float(final["nll"])
    fitd["structure_residual"] = 0.0  # the model is parameterised in eq. (4) itself
    sensor = lay.sensor(theta)
    degrees = list(envelope) + [0] * (len(lines) - len(envelope))
    line_names = [f"line{h}_{q}{j or ''}_{n}" for h in range(len(lines))
                  for j in range(degrees[h] + 1) for q in ("cos", "sin")
                  for n in data.channel_names("y")]  # fmt: skip
    return IdentificationResult(
        method="ml",
        model=amb_state_space(v, data.dt),  # eq. (7): the ZOH model in physical coordinates
        continuous_model=amb_state_space(v),
        parameters=dict(zip(list(V_NAMES) + list(dnames), values.tolist())),
        covariance=0.5 * (cov + cov.T),
        n_samples=int(data.n_samples),
        options=options,
        residuals=eps,
        fit=fitd,
        notes=tuple(notes),
        extras={
            "sensor_noise_std": sensor,
            "sensor_noise_estimated": lay.est,
            "force_std": lay.force(theta),
            "force_std_estimated": lay.est_force,
            "output_offsets": c,
            "transient": final["tau"],
            "kalman_gain": final["K"],
            "innovation_covariance": final["S"],
            "iterations": iterations,
            "converged": converged,
            "v_start": v_start,
            "fisher": info,
            "fisher_names": (*model.names, "tau0", "tau1", "tau2", "tau3", *line_names),
            "periodic_hz": np.array(lines, dtype=float),
            "periodic_amplitude": line_amplitudes(y, data.dt, lines),
            "periodic_unsettled_hz": np.array(unsettled, dtype=float),
            "periodic_envelope_degree": np.array(degrees, dtype=int),
        },
    )


#: Registered with ``maglevid identify --method``.
METHODS: Mapping[str, Any] = {"ml": fit_ml}
#: Its options, declared once (maglevid.identify.options; defaults: fit_ml's).
OPTIONS = {
    "ml": (
        Option("start", "object", "starting point: 'physical' (the IV estimate) or v1..v9"),
        Option("noise_std", "object", "sensor noise std of [x, i1, i2]: 'estimate', "
               "'metadata' or three values [m, A, A]"),
        Option("force_std", "object", "force disturbance std: 'estimate', 'metadata' or a "
               "value [N] (0: none)"),
        Option("amplifier_std", "floats", "amplifier input noise per sample (known)", low=0,
               unit="V"),
        Option("max_iter", "int", "Fisher-scoring iterations at most", low=1),
        Option("periodic", "object", "periodic disturbances (unbalance, mains hum) profiled "
               "out: 'auto' (found in the prediction errors), 'none' or frequencies [Hz]"),
        AMB_OPTIONS["m"],
        AMB_OPTIONS["i0"],
    )
}  # fmt: skip
