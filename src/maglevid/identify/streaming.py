"""Identification of records larger than memory: the data streamed in chunks.

A magnetic bearing controlled at 10-20 kHz records 10^7-10^8 samples an hour;
held in memory with its regressors and instruments that is tens of GB. The
methods here read such a record chunk by chunk and keep only statistics whose
size does not depend on its length, so the peak memory is that of one chunk
(plus small fixed arrays) whatever the record length.

Subspace (``moesp``, ``n4sid``): two passes
    Pass 1 the means of ``y`` and ``u`` (the recording's operating point), pass 2
    the block-Hankel statistics of
    :class:`~maglevid.identify.subspace.SubspaceAccumulator` (lagged products
    of the deviations ``z = [u, y] - mean`` and the first and last samples;
    ``docs/subspace.md``), as the in-memory registry methods do.

Closed-loop subspace (``pbsid``, ``ssarx``): one pass
    The lagged products of
    :class:`~maglevid.identify.pbsid.PredictorAccumulator`, whose VARX
    carries its own constant (``remove_mean``), so one pass suffices.

The physical AMB method (``physical``, least squares or IV): two passes
    The plant ARX of :mod:`maglevid.identify.physical` is a linear regression
    ``y(k+1) = Theta phi(k) + eps(k)`` with instruments ``Z`` (section 4 there).
    Pass 1 accumulates the triangular factor ``R`` of ``[Z, Phi, Y]`` by a
    running QR (``R <- qr([R; rows of the chunk])``, the kernel of
    :class:`~maglevid.identify.arx.RegressionAccumulator`, which
    :func:`~maglevid.identify.arx.solve_linear_regression` also uses in memory);
    ``Theta`` follows from ``R`` alone. The covariance needs the residuals
    ``eps = Y - Phi Theta^T``, which are only known after pass 1, so pass 2
    reads the record again and accumulates their lagged products (and those of
    the effective instruments). The ``"loop"`` instruments are the nominal
    closed loop's response to the recorded ``r``
    (:func:`~maglevid.identify.iv.loop_instrument_system`), simulated chunk by
    chunk with the state carried across chunk boundaries; the regressors of the
    rows that straddle a boundary use the last samples of the previous chunk.

Every row of the regression, every instrument and every product is the same as
in the in-memory fit; only the order of summation differs. So the result equals
:func:`~maglevid.identify.physical.fit_physical` and
:func:`~maglevid.identify.subspace.fit_moesp` / ``fit_n4sid`` to rounding
(``tests/identify/test_streaming.py``), except that the time series of
residuals is not kept (``residuals`` is ``None``; the one-step fit is computed
from running sums).

A source is either a zero-argument callable returning a fresh iterable of
:class:`~maglevid.data.ClosedLoopData` chunks (two passes call it twice), e.g.
``lambda: maglevid.io.iter_recording_chunks(path, 10**6)``, or a
``ClosedLoopData`` already in memory, which is cut into ``chunk_size`` pieces.
This module does not read files itself (``identify`` does not import ``io``);
``maglevid identify --stream`` does that.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError
from maglevid.identify.arx import RegressionAccumulator
from maglevid.identify.iv import loop_instrument_system
from maglevid.identify.pbsid import (
    DEFAULT_MAX_PAST,
    DEFAULT_STRUCTURE_PAST,
    PredictorAccumulator,
)
from maglevid.identify.periodic import excitation_lines, record_lines
from maglevid.identify.physical import (
    _plant_signals,
    physical_labels,
    physical_noise_ma,
    physical_result,
    plan_physical,
    plant_regression_blocks,
    realization_scales,
)
from maglevid.identify.result import IdentificationResult
from maglevid.identify.subspace import DEFAULT_MAX_HORIZON, SubspaceAccumulator, centred_result
from maglevid.identify.uncertainty import DCLevels, one_step_fit_percent, with_dc_levels
from maglevid.lti import StateSpace
from maglevid.simulate.kernel import simulate_lti

__all__ = [
    "DEFAULT_CHUNK",
    "STREAMED_METHODS",
    "fit_physical_streamed",
    "fit_predictor_streamed",
    "fit_subspace_streamed",
    "identify_streamed",
]

logger = logging.getLogger(__name__)

#: Control periods per chunk when a source is cut here (10^6 x 7 channels: 56 MB).
DEFAULT_CHUNK = 1_000_000

ChunkSource = Callable[[], Iterable[ClosedLoopData]] | ClosedLoopData
Progress = Callable[[Iterable[ClosedLoopData]], Iterable[ClosedLoopData]]


def _slices(data: ClosedLoopData, chunk_size: int) -> Iterator[ClosedLoopData]:
    n, p = data.n_samples, data.p
    bounds = [*range(0, n, chunk_size), n]
    if len(bounds) > 2 and bounds[-1] - bounds[-2] < 2:
        del bounds[-2]
    for a, b in itertools.pairwise(bounds):
        yield ClosedLoopData(
            y=data.y[a * p : b * p],
            u=None if data.u is None else data.u[a:b],
            r=None if data.r is None else data.r[a:b],
            u_f=None if data.u_f is None else data.u_f[a:b],
            dt=data.dt,
            p=p,
            names=data.names,
            units=data.units,
            loop=data.loop,
        )


def _opener(source: ChunkSource, chunk_size: int) -> Callable[[], Iterable[ClosedLoopData]]:
    if isinstance(chunk_size, bool) or int(chunk_size) != chunk_size or chunk_size < 2:
        raise DataError(f"`chunk_size` must be an integer >= 2; got {chunk_size!r}")
    if isinstance(source, ClosedLoopData):
        return lambda: _slices(source, int(chunk_size))
    if callable(source):
        return source
    raise DataError(
        "`source` must be a ClosedLoopData or a callable returning an iterable of "
        f"ClosedLoopData chunks; got {type(source).__name__}"
    )


def _chunks(
    opener: Callable[[], Iterable[ClosedLoopData]], progress: Progress | None
) -> Iterator[ClosedLoopData]:
    it = opener()
    if progress is not None:
        it = progress(it)
    for chunk in it:
        if not isinstance(chunk, ClosedLoopData):
            raise DataError(
                f"a chunk of the source is a {type(chunk).__name__}, not ClosedLoopData"
            )
        yield chunk


class _Moments:
    """Count, mean and centred sum of squares per column, merged chunk by chunk (Chan et al.)."""

    def __init__(self, width: int) -> None:
        self.n = 0
        self.mean = np.zeros(width)
        self.m2 = np.zeros(width)

    def update(self, x: np.ndarray) -> None:
        nb = x.shape[0]
        if nb == 0:
            return
        mb = x.mean(axis=0)
        xc = x - mb
        m2b = np.einsum("ij,ij->j", xc, xc)
        n = self.n + nb
        delta = mb - self.mean
        self.mean = self.mean + delta * (nb / n)
        self.m2 = self.m2 + m2b + delta**2 * (self.n * nb / n)
        self.n = n


class _PhysicalRows:
    """Rows ``(Y, Phi, Z)`` of the plant ARX for consecutive chunks (module notes).

    Row ``k`` (``y(k+1) = Theta phi(k)``) needs samples ``k-1 .. k+1`` and, for
    lagged instruments, ``r(k - L)``; the last ``1 + max(1, L)`` samples of each
    chunk are carried into the next, and the loop simulation of the ``"loop"``
    instruments carries its state.
    """

    def __init__(self, plan: Mapping[str, Any], lags: int, system: StateSpace | None) -> None:
        self.start = int(plan["start"])
        self.kind = plan["instruments"]
        self.L = int(lags) if self.kind == "lags" else 0
        self.keep = 1 + max(1, self.L)
        self.system = system
        self.state = None if system is None else np.zeros(system.nx)
        self.g = 0  # index of the first sample of the next chunk
        self.next_k = self.start
        self.carry: dict[str, np.ndarray] = {}
        self.r0: np.ndarray | None = None

    def rows(
        self, y: np.ndarray, u: np.ndarray, r: np.ndarray | None
    ) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray] | None] | None:
        nc = y.shape[0]
        sig = {"y": y, "u": u}
        if self.kind == "lags":
            sig["r"] = r
        elif self.kind == "loop":
            assert self.system is not None and r is not None
            ny = y.shape[1]
            if self.r0 is None:
                self.r0 = np.array(r[0])  # the loop starts at rest at r(0), as fit_physical's
            rd = r - self.r0
            w = np.hstack([rd, np.zeros((nc, ny))])
            out, self.state = simulate_lti(self.system, w, x0=self.state)
            sig["sy"] = out[:, :ny]
            sig["su"] = out[:, ny:] + rd  # u = u_f + r
        ext = {k: np.concatenate([self.carry[k], v]) if self.carry else v for k, v in sig.items()}
        offset = self.g - (ext["y"].shape[0] - nc)  # sample index of ext[0]
        k0, k1 = self.next_k, self.g + nc - 1  # rows k0 .. k1 - 1
        out_rows = None
        if k1 > k0:
            a, b = k0 - offset, k1 - offset
            lhs, phi = plant_regression_blocks(ext["y"], ext["u"], start=a)
            Z = None
            if self.kind == "loop":
                _, Z = plant_regression_blocks(ext["sy"], ext["su"], start=a)
            elif self.kind == "lags":
                Z = [ext["r"][a - j : b - j] for j in range(self.L + 1)]  # lagged_excitation
            out_rows = (lhs, phi, Z)
            self.next_k = k1
        n_keep = min(self.keep, ext["y"].shape[0])
        self.carry = {k: np.array(v[-n_keep:]) for k, v in ext.items()}
        self.g += nc
        return out_rows


def fit_physical_streamed(
    source: ChunkSource,
    *,
    chunk_size: int = DEFAULT_CHUNK,
    estimator: str = "iv",
    instruments: str = "auto",
    skip: int = 10,
    instrument_lags: int = 30,
    covariance: str = "white-noise",
    hac_lags: int = 4,
    m: float | None = None,
    i0: float | None = None,
    progress: Progress | None = None,
) -> IdentificationResult:
    """:func:`~maglevid.identify.physical.fit_physical` on a record streamed in chunks.

    Two passes over the source (module notes); memory independent of the
    record length. Same options and same result, to rounding, as the in-memory
    method, except ``residuals`` (``None``).

    Parameters
    ----------
    source : ClosedLoopData or callable
        The record: a zero-argument callable returning a fresh iterable of
        consecutive chunks (called once per pass), or a ``ClosedLoopData`` cut
        into ``chunk_size`` pieces.
    chunk_size : int
        Control periods per chunk when ``source`` is a ``ClosedLoopData``.
    estimator, instruments, skip, instrument_lags, covariance, hac_lags, m, i0
        As in :func:`~maglevid.identify.physical.fit_physical`.
    progress : callable, optional
        Wraps each pass's iterable of chunks (e.g. a progress bar).

    Returns
    -------
    IdentificationResult
        As :func:`~maglevid.identify.physical.fit_physical`, with a note on the
        streaming and ``residuals=None``.

    Raises
    ------
    DataError
        Wrong signals, chunks that disagree (sample time, channels), a source
        that gives different data on the second pass, or too short a record.
    IdentificationError
        As :func:`~maglevid.identify.physical.fit_physical`.

    Examples
    --------
    >>> from maglevid.physics.amb import AMBParameters
    >>> from maglevid.simulate import simulate_amb_loop
    >>> from maglevid.identify.physical import fit_physical
    >>> nom = AMBParameters.nominal()
    >>> d = simulate_amb_loop(nom.with_fault(R1=1.2), nominal=nom, n_samples=20_000, rng=1,
    ...                       noise_std=(1e-10, 3e-6, 3e-6))
    >>> a = fit_physical_streamed(d, chunk_size=3_000)
    >>> b = fit_physical(d)
    >>> abs(a.parameters["R1"] / b.parameters["R1"] - 1) < 1e-9
    True
    """
    opener = _opener(source, chunk_size)
    options = {
        "estimator": estimator,
        "instruments": instruments,
        "skip": skip,
        "instrument_lags": instrument_lags,
        "covariance": covariance,
    }
    # Pass 1: the regression's normal equations (eq. (47) form of physical.py), the
    # moments of y, u and the left-hand side, the DC levels.
    first = _PhysicalFirstPass(options)
    for chunk in _chunks(opener, progress):
        first.feed(chunk)
    if first.acc is None or first.rows is None:
        raise DataError("the source gave no chunks")
    acc, plan, N = first.acc, first.plan, first.rows.g
    plan_physical(**options, has_r=True, loop=first.loop, n_samples=N)  # the length check
    acc.solve(
        hac_lags=hac_lags, noise_ma=physical_noise_ma(3) if covariance == "white-noise" else None
    )
    # Pass 2: the residuals, for the covariance.
    rows2 = _PhysicalRows(plan, instrument_lags, first.system)
    for chunk in _chunks(opener, progress):
        y, u = _plant_signals(chunk)
        got = rows2.rows(y, u, None if chunk.r is None else np.asarray(chunk.r))
        if got is not None:
            acc.update_residuals(*got)
    if rows2.g != N:
        raise DataError(
            f"the source gave {rows2.g} samples on the second pass and {N} on the first; a "
            "streamed fit reads the record twice and needs the same data both times"
        )
    fit = acc.finish()
    y_scale, h_scale = realization_scales(first.moments_y.m2, first.moments_u.m2, N)
    assert fit.residual_sum_of_squares is not None
    logger.info("physical: %d samples streamed in %d chunks, two passes", N, first.n_chunks)
    res = physical_result(
        fit,
        Y=None,
        y_scale=y_scale,
        h_scale=h_scale,
        dt=first.dt,
        loop=first.loop,
        names=first.names,
        plan=plan,
        hac_lags=hac_lags,
        m=m,
        i0=i0,
        one_step_fit=one_step_fit_percent(fit.residual_sum_of_squares, first.moments.m2),
        extra_notes=(
            f"streamed: {N} samples in {first.n_chunks} chunk(s), two passes; residuals not kept",
        ),
    )
    assert first.dc is not None
    return with_dc_levels(res, first.dc, first.loop)


class _PhysicalFirstPass:
    """First pass of :func:`fit_physical_streamed`, fed chunk by chunk.

    The first chunk fixes ``dt``, the loop and the channel names, and with them
    the plan of :func:`~maglevid.identify.physical.plan_physical` (instruments,
    rows) and the accumulator of the normal equations.
    """

    def __init__(self, options: Mapping[str, Any]) -> None:
        self.options = dict(options)
        self.plan: dict[str, Any] = {}
        self.acc: RegressionAccumulator | None = None
        self.rows: _PhysicalRows | None = None
        self.system: StateSpace | None = None
        self.dt = 0.0
        self.loop: Mapping[str, Any] = {}
        self.names: tuple[str, ...] = ()
        self.n_chunks = 0
        self.moments_y, self.moments_u = _Moments(3), _Moments(2)
        self.dc: DCLevels | None = None
        self.moments = _Moments(3)  # of the regression's left-hand side

    def _start(self, chunk: ClosedLoopData) -> None:
        self.dt, self.loop, self.names = chunk.dt, chunk.loop, chunk.channel_names("y")
        lags = self.options["instrument_lags"]
        self.plan = plan_physical(
            **self.options, has_r=chunk.r is not None, loop=self.loop, n_samples=None
        )
        if self.plan["instruments"] == "loop":
            self.system = loop_instrument_system(self.loop, dt=self.dt)
        self.rows = _PhysicalRows(self.plan, lags, self.system)
        nz = {None: None, "loop": 8, "lags": 2 * (int(lags) + 1)}
        self.acc = RegressionAccumulator(
            8,
            3,
            nz=nz[self.plan["instruments"]],
            labels=physical_labels(self.names, chunk.channel_names("u")),
            intercept=True,
        )

    def feed(self, chunk: ClosedLoopData) -> None:
        y, u = _plant_signals(chunk)
        if self.acc is None:
            self._start(chunk)
        elif abs(chunk.dt - self.dt) > 1e-12 * self.dt:
            raise DataError(
                f"chunk {self.n_chunks} has dt={chunk.dt:g} s; the first had {self.dt:g} s"
            )
        if self.plan["instruments"] is not None and chunk.r is None:
            raise DataError(
                f"chunk {self.n_chunks} lacks the excitation r that the instruments need"
            )
        assert self.rows is not None and self.acc is not None
        self.moments_y.update(y)
        self.moments_u.update(u)
        if self.dc is None:
            self.dc = DCLevels(self.dt, 3, 2)
        self.dc.update(y, u)
        got = self.rows.rows(y, u, None if chunk.r is None else np.asarray(chunk.r))
        if got is not None:
            lhs, phi, Z = got
            self.acc.update(lhs, phi, Z, check=False)  # chunks are ClosedLoopData: finite
            self.moments.update(lhs)
        self.n_chunks += 1


def _feed_plant_io(
    opener: Callable[[], Iterable[ClosedLoopData]],
    progress: Progress | None,
    method: str,
    make: Callable[[int, int], Any],
    first: Callable[[ClosedLoopData], None] | None = None,
) -> tuple[Any, float, int]:
    """One pass: ``make(ny, nu)`` builds the accumulator, fed ``(y_control, u)`` per chunk
    (``first``, if given, also sees the first chunk).

    Returns the accumulator, ``dt`` and the number of chunks.
    """
    acc = None
    dt = 0.0
    n_chunks = 0
    for chunk in _chunks(opener, progress):
        data = chunk.with_plant_input() if chunk.u is None else chunk
        if data.u is None:
            raise DataError(
                f"method {method!r} needs the plant input `u` (or `u_f` and `r`); chunk "
                f"{n_chunks} has neither"
            )
        if acc is None:
            dt = data.dt
            acc = make(data.ny, data.nu)
            if first is not None:
                first(data)
        elif abs(data.dt - dt) > 1e-12 * dt:
            raise DataError(f"chunk {n_chunks} has dt={data.dt:g} s; the first had {dt:g} s")
        acc.update(data.y_control, data.u)
        n_chunks += 1
    if acc is None:
        raise DataError("the source gave no chunks")
    return acc, dt, n_chunks


def fit_subspace_streamed(
    source: ChunkSource,
    *,
    algorithm: str = "moesp",
    chunk_size: int = DEFAULT_CHUNK,
    order: int | None = None,
    horizon: int | None = None,
    max_horizon: int = DEFAULT_MAX_HORIZON,
    feedthrough: bool = False,
    weighting: str | None = None,
    variant: str = "robust",
    rank_tol: float | None = None,
    factorization: str = "gram",
    progress: Progress | None = None,
) -> IdentificationResult:
    """MOESP or N4SID of a record streamed in chunks (two passes: means, then statistics).

    The plant input ``u`` (or ``u_f + r``) and the outputs at the control
    instants, as the in-memory registry methods ``moesp``/``n4sid`` use them;
    ``dt`` from the data. Equals :func:`~maglevid.identify.subspace.fit_moesp`
    / ``fit_n4sid`` on the whole record to rounding, without ``residuals``.

    Parameters
    ----------
    source : ClosedLoopData or callable
        As in :func:`fit_physical_streamed`.
    algorithm : {"moesp", "n4sid"}
    chunk_size : int
        As in :func:`fit_physical_streamed`.
    order, horizon, max_horizon, feedthrough, weighting, variant, rank_tol, factorization
        As in :func:`~maglevid.identify.subspace.fit_moesp` and
        :class:`~maglevid.identify.subspace.SubspaceAccumulator`.
    progress : callable, optional
        Wraps the iterable of chunks.

    Returns
    -------
    IdentificationResult
    """
    opener = _opener(source, chunk_size)
    acc: SubspaceAccumulator | None = None
    dt = 0.0
    n_chunks = 0
    # Pass 1: the means (the recording's operating point), removed in pass 2 as
    # the in-memory registry methods remove them.
    mom_y: _Moments | None = None
    mom_u: _Moments | None = None
    for chunk in _chunks(opener, progress):
        data = _subspace_chunk(chunk, algorithm, n_chunks)
        if mom_y is None:
            mom_y, mom_u = _Moments(data.ny), _Moments(data.nu)
        assert mom_u is not None
        mom_y.update(np.asarray(data.y_control))
        mom_u.update(np.asarray(data.u))
        n_chunks += 1
    if mom_y is None or mom_u is None:
        raise DataError("the source gave no chunks")
    n_chunks = 0
    for chunk in _chunks(opener, progress):
        data = _subspace_chunk(chunk, algorithm, n_chunks)
        if acc is None:
            dt = data.dt
            acc = SubspaceAccumulator(
                ny=data.ny,
                nu=data.nu,
                horizon=horizon,
                max_horizon=max_horizon,
                factorization=factorization,
            )
        elif abs(data.dt - dt) > 1e-12 * dt:
            raise DataError(f"chunk {n_chunks} has dt={data.dt:g} s; the first had {dt:g} s")
        acc.update(np.asarray(data.y_control) - mom_y.mean, np.asarray(data.u) - mom_u.mean)
        n_chunks += 1
    if acc is None or acc.n_samples != mom_y.n:
        raise DataError(
            "the source gave different data on its two passes; a streamed subspace fit reads "
            "the record twice (means, then statistics) and needs the same data both times"
        )
    res = acc.fit(
        algorithm=algorithm,
        order=order,
        dt=dt,
        feedthrough=feedthrough,
        weighting=weighting,
        variant=variant,
        rank_tol=rank_tol,
    )
    note = f"streamed: {acc.n_samples} samples in {n_chunks} chunk(s), two passes"
    logger.info("%s: %s", algorithm, note)
    res = centred_result(res, mom_y.mean, mom_u.mean)
    return replace(res, notes=(*res.notes, note))


def _subspace_chunk(chunk: ClosedLoopData, algorithm: str, index: int) -> ClosedLoopData:
    data = chunk.with_plant_input() if chunk.u is None else chunk
    if data.u is None:
        raise DataError(
            f"method {algorithm!r} needs the plant input `u` (or `u_f` and `r`); chunk "
            f"{index} has neither"
        )
    return data


def fit_predictor_streamed(
    source: ChunkSource,
    *,
    algorithm: str = "pbsid",
    chunk_size: int = DEFAULT_CHUNK,
    past: int | None = None,
    future: int | None = None,
    max_past: int = DEFAULT_MAX_PAST,
    remove_mean: bool = True,
    structure_past: int | None = None,
    progress: Progress | None = None,
    **fit_options: Any,
) -> IdentificationResult:
    """PBSID-opt or SSARX of a record streamed in chunks (one pass).

    The lagged products of :class:`~maglevid.identify.pbsid.PredictorAccumulator`;
    equals :func:`~maglevid.identify.pbsid.fit_pbsid` / ``fit_ssarx`` on the whole
    record to rounding, without ``residuals`` (and without ``periodic`` lines taken
    out: that needs the record in memory, refused). ``fit_options`` (order,
    feedthrough, weighting, rank_tol, coordinates, physical_fit) go to its
    ``fit``; ``structure_past`` is the window of ``physical_fit="structured"``
    (default: chosen from the data, up to ``DEFAULT_STRUCTURE_PAST`` lags kept).
    """
    periodic = fit_options.pop("periodic", "none")
    if not (isinstance(periodic, str) and periodic == "none"):
        raise DataError(
            f"`periodic`={periodic!r}: the lines are taken out of every channel before the "
            "lagged products, which needs the whole record in memory; a streamed fit is one "
            "pass over it: identify without streaming (--no-stream), or with periodic='none'"
        )
    fit = fit_options.get("physical_fit") or (
        "structured" if fit_options.get("coordinates") == "physical" else "transform"
    )  # pbsid's default
    keep = DEFAULT_STRUCTURE_PAST if fit == "structured" else None
    lines: list[Any] = []  # (samples searched, frequencies) of the first chunk
    acc, dt, n_chunks = _feed_plant_io(
        _opener(source, chunk_size),
        progress,
        algorithm,
        lambda ny, nu: PredictorAccumulator(
            ny=ny,
            nu=nu,
            algorithm=algorithm,
            past=past,
            future=future,
            max_past=max_past,
            remove_mean=remove_mean,
            structure_past=structure_past,
            structure_lags=keep,
        ),
        first=lambda data: lines.append(_first_chunk_lines(data)),
    )
    fit_options.setdefault("dt", dt)
    res = acc.fit(**fit_options)
    notes = [f"streamed: {acc.n_samples} samples in {n_chunks} chunk(s), one pass"]
    searched, found = lines[0]
    if found:
        notes.append(
            f"the record's first {searched} samples carry periodic lines at "
            f"{', '.join(f'{f:.4g}' for f in found)} Hz (unbalance, hum): "
            "a streamed fit cannot take them out and its estimate is biased by them (1 N "
            "of unbalance at 50 Hz put the bearing's v1..v3 93 % off); identify the record "
            "in memory (--no-stream), where PBSID-opt and SSARX take them out"
        )
    return replace(res, notes=(*res.notes, *notes))


#: Samples of the first chunk a streamed predictor fit searches for strong periodic lines
#: (``periodic.record_lines``: 0.1-0.2 s; 13 s of record at 10 kHz, bins of 0.08 Hz).
_LINE_CHECK_SAMPLES = 1 << 17


def _first_chunk_lines(data: ClosedLoopData) -> tuple[int, tuple[float, ...]]:
    """``(samples searched, lines)``: strong lines in the first samples of a streamed
    record, less those the recorded excitation carries (the experiment's own)."""
    k = _LINE_CHECK_SAMPLES
    y, u = np.asarray(data.y_control)[:k], np.asarray(data.u)[:k]
    found = record_lines(y, u, data.dt)
    r = getattr(data, "r", None)
    own = excitation_lines(None if r is None else np.asarray(r)[:k], data.dt, found)
    return y.shape[0], tuple(f for f in found if f not in own)


def _moesp(source: ChunkSource, **options: Any) -> IdentificationResult:
    return fit_subspace_streamed(source, algorithm="moesp", **options)


def _n4sid(source: ChunkSource, **options: Any) -> IdentificationResult:
    return fit_subspace_streamed(source, algorithm="n4sid", **options)


#: Methods that can be streamed, by the names of ``maglevid identify --method``.
STREAMED_METHODS: Mapping[str, Callable[..., IdentificationResult]] = {
    "physical": fit_physical_streamed,
    "moesp": _moesp,
    "n4sid": _n4sid,
    "pbsid": lambda source, **o: fit_predictor_streamed(source, algorithm="pbsid", **o),
    "ssarx": lambda source, **o: fit_predictor_streamed(source, algorithm="ssarx", **o),
}


def identify_streamed(source: ChunkSource, method: str, **options: Any) -> IdentificationResult:
    """Run the streamed form of a registered method (``physical``, ``moesp``, ``n4sid``, ...).

    Raises
    ------
    DataError
        ``method`` has no streamed form.
    """
    if method not in STREAMED_METHODS:
        raise DataError(
            f"method {method!r} cannot be streamed; streamed methods: "
            + ", ".join(sorted(STREAMED_METHODS))
        )
    return STREAMED_METHODS[method](source, **options)
