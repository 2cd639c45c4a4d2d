"""Recordings of a closed loop: :class:`ClosedLoopData`.

What a bearing's controller logs, in one immutable container:

==========  ==================  ==================================================
signal      shape               meaning
==========  ==================  ==================================================
``y``       ``(N*p, ny)``       measured outputs; ``p`` samples per control period
``u``       ``(N, nu)``         plant input (held over each control period)
``r``       ``(N, nu)``         excitation added to the feedback, ``u = u_f + r``
``u_f``     ``(N, nu)``         feedback part of the input (controller output)
==========  ==================  ==================================================

``dt`` is the control period in seconds. With output inter-sampling
(Sun et al., Fig. 2) the outputs are sampled ``p`` times per control period:
``y[m*p + j] = y(m T + j T/p)``; ``y[m*p]`` is the sample the controller uses.
For ``p = 1`` the output and input rates are equal.

``loop`` holds what is known about the loop (controller matrices, operating
point, nominal plant), ``metadata`` anything else (machine id, time stamp,
source file). Both are JSON-safe mappings; arrays inside ``loop`` are read-only
numpy arrays.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np

from maglevid._validation import as_signal, check_positive, readonly
from maglevid.exceptions import DataError
from maglevid.jsonable import thaw

__all__ = ["SIGNALS", "ClosedLoopData", "unfreeze"]

#: Signals a recording may hold, in canonical order. ``y`` is always present.
SIGNALS: tuple[str, ...] = ("y", "u", "r", "u_f")

#: Fewest control periods a recording may have (identification methods ask for more).
MIN_SAMPLES = 2


def unfreeze(value: Any) -> Any:
    """Read-only mappings (at any depth) as plain dicts, everything else as it is: the
    inverse of the freeze for pickling (:func:`maglevid.jsonable.thaw` also turns arrays
    into lists, for JSON)."""
    if isinstance(value, Mapping):
        return {k: unfreeze(v) for k, v in value.items()}
    if isinstance(value, tuple):
        return tuple(unfreeze(v) for v in value)
    return value


def _freeze(value: Any) -> Any:
    """Deep-freeze a JSON-like value: dicts become read-only mappings, lists of numbers arrays."""
    if isinstance(value, Mapping):
        return MappingProxyType({str(k): _freeze(v) for k, v in value.items()})
    if isinstance(value, np.ndarray):
        return readonly(value) if value.dtype.kind in "biuf" else value
    if isinstance(value, (list, tuple)):
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            return tuple(_freeze(v) for v in value)
        return readonly(arr)
    return value


#: Sections of ``loop`` that hold physical numbers only (checked on construction).
NUMERIC_LOOP_SECTIONS = ("operating_point", "nominal")


def _check_loop_numbers(loop: Mapping[str, Any]) -> None:
    """``loop["operating_point"]`` and ``loop["nominal"]`` hold finite numbers (or lists of them).

    Checked when a recording is made or read, so that a malformed value
    (``"i0": "abc"``) is one clear error naming it, not a ValueError deep in
    an identification (issue 17).
    """
    if not hasattr(loop, "get"):
        raise DataError(f"`loop` must be a mapping; got {type(loop).__name__}")
    for section in NUMERIC_LOOP_SECTIONS:
        entries = loop.get(section)
        if entries is None:
            continue
        if not hasattr(entries, "items"):
            raise DataError(f"loop[{section!r}] must be a mapping of numbers; got {entries!r}")
        for key, value in entries.items():
            try:
                arr = np.asarray(value, dtype=float)
            except (TypeError, ValueError):
                arr = None
            if isinstance(value, (bool, str)) or arr is None or not np.all(np.isfinite(arr)):
                raise DataError(
                    f"loop[{section!r}][{key!r}] is {value!r}; expected a finite number (SI units)"
                )


@dataclass(frozen=True, eq=False)
class ClosedLoopData:
    """An immutable closed-loop recording.

    Parameters
    ----------
    y : array_like, shape (N*p, ny)
        Measured outputs, time first. A 1-D array is one channel.
    dt : float
        Control period (input sample time) in seconds.
    u, r, u_f : array_like, shape (N, nu), optional
        Plant input, excitation and feedback. When two of them are given the
        third is *not* derived silently; use :meth:`with_plant_input`.
    p : int
        Output samples per control period (1 = same rate).
    names, units : mapping of signal -> sequence of str, optional
        Channel names and units per signal, e.g. ``{"y": ("x", "i1", "i2")}``.
    t0 : float
        Time of the first sample in seconds.
    loop : mapping, optional
        Known loop: controller (``"controller"``), operating point, nominal plant.
    metadata : mapping, optional
        Free JSON-safe information (machine, source file, time stamp, ...).

    Raises
    ------
    DataError
        Wrong shapes, NaN/inf, too few samples, non-positive ``dt``, or a
        names/units list that does not match the number of channels.

    Examples
    --------
    >>> import numpy as np
    >>> d = ClosedLoopData(y=np.zeros((6, 1)), u=np.zeros((3, 1)), dt=0.01, p=2)
    >>> d.n_samples, d.y_control.shape
    (3, (3, 1))
    """

    y: np.ndarray
    dt: float
    u: np.ndarray | None = None
    r: np.ndarray | None = None
    u_f: np.ndarray | None = None
    p: int = 1
    names: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    units: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    t0: float = 0.0
    loop: Mapping[str, Any] = field(default_factory=dict)
    metadata: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        dt = check_positive(self.dt, "dt")
        p = self.p
        if isinstance(p, bool) or not isinstance(p, (int, np.integer)) or p < 1:
            raise DataError(
                f"`p` (output samples per control period) must be an integer >= 1; got {p!r}"
            )
        p = int(p)
        y = as_signal(self.y, "y", min_samples=MIN_SAMPLES * p)
        if y.shape[0] % p:
            raise DataError(
                f"`y` has {y.shape[0]} samples, not a multiple of p={p}: a multi-rate record "
                "must hold p output samples for every control period"
            )
        n = y.shape[0] // p
        nu = None
        for sig in ("u", "r", "u_f"):
            v = getattr(self, sig)
            if v is None:
                continue
            v = as_signal(v, sig, n_samples=n, n_channels=nu)
            nu = v.shape[1]
            object.__setattr__(self, sig, v)
        names = {str(k): tuple(str(s) for s in v) for k, v in dict(self.names).items()}
        units = {str(k): tuple(str(s) for s in v) for k, v in dict(self.units).items()}
        for label, table in (("names", names), ("units", units)):
            for sig, entries in table.items():
                if sig not in SIGNALS:
                    raise DataError(
                        f"`{label}` has unknown signal {sig!r}; expected one of {SIGNALS}"
                    )
                arr = y if sig == "y" else getattr(self, sig)
                if arr is None:
                    raise DataError(
                        f"`{label}` describes signal {sig!r}, which the recording lacks"
                    )
                if len(entries) != arr.shape[1]:
                    raise DataError(
                        f"`{label}[{sig!r}]` has {len(entries)} entries "
                        f"for {arr.shape[1]} channel(s)"
                    )
        object.__setattr__(self, "y", y)
        object.__setattr__(self, "dt", dt)
        object.__setattr__(self, "p", p)
        object.__setattr__(self, "t0", float(self.t0))
        object.__setattr__(self, "names", MappingProxyType(names))
        object.__setattr__(self, "units", MappingProxyType(units))
        _check_loop_numbers(self.loop)
        object.__setattr__(self, "loop", _freeze(dict(self.loop)))
        object.__setattr__(self, "metadata", _freeze(dict(self.metadata)))

    # ------------------------------------------------------------ properties
    @property
    def n_samples(self) -> int:
        """Number of control periods N."""
        return self.y.shape[0] // self.p

    @property
    def ny(self) -> int:
        return self.y.shape[1]

    @property
    def nu(self) -> int:
        for sig in ("u", "r", "u_f"):
            v = getattr(self, sig)
            if v is not None:
                return v.shape[1]
        return 0

    @property
    def dt_output(self) -> float:
        """Output sample interval ``Delta = dt / p``."""
        return self.dt / self.p

    @property
    def time(self) -> np.ndarray:
        """Control instants ``t0 + m dt``, shape (N,)."""
        return self.t0 + self.dt * np.arange(self.n_samples)

    @property
    def time_output(self) -> np.ndarray:
        """Output sampling instants ``t0 + k dt/p``, shape (N*p,)."""
        return self.t0 + self.dt_output * np.arange(self.y.shape[0])

    @property
    def y_control(self) -> np.ndarray:
        """Outputs at the control instants (what the controller sees), shape (N, ny)."""
        return self.y[:: self.p]

    def y_intersample(self, j: int) -> np.ndarray:
        """``y_j(m) = y(mT + j Delta)``, shape (N, ny) (Sun et al., eq. (7))."""
        if not 0 <= j < self.p:
            raise DataError(f"inter-sample index j={j} outside 0..{self.p - 1}")
        return self.y[j :: self.p]

    def channel_names(self, signal: str) -> tuple[str, ...]:
        """Names of a signal's channels (defaults ``y1, y2, ...``)."""
        arr = self.y if signal == "y" else getattr(self, signal)
        if arr is None:
            raise DataError(f"the recording has no {signal!r} signal")
        return self.names.get(signal) or tuple(f"{signal}{i + 1}" for i in range(arr.shape[1]))

    def channel_units(self, signal: str) -> tuple[str, ...]:
        """Units of a signal's channels (empty strings when unknown)."""
        arr = self.y if signal == "y" else getattr(self, signal)
        if arr is None:
            raise DataError(f"the recording has no {signal!r} signal")
        return self.units.get(signal) or ("",) * arr.shape[1]

    def signals(self) -> tuple[str, ...]:
        """The signals present, in canonical order."""
        return tuple(s for s in SIGNALS if s == "y" or getattr(self, s) is not None)

    # -------------------------------------------------------------- derived
    def replace(self, **changes: Any) -> ClosedLoopData:
        """Copy with some fields changed (validated again)."""
        kw = {
            "y": self.y,
            "dt": self.dt,
            "u": self.u,
            "r": self.r,
            "u_f": self.u_f,
            "p": self.p,
            "names": self.names,
            "units": self.units,
            "t0": self.t0,
            "loop": thaw(self.loop),
            "metadata": thaw(self.metadata),
        }
        kw.update(changes)
        # A signal removed by the change takes its names and units with it.
        for table in ("names", "units"):
            if table not in changes:
                kw[table] = {k: v for k, v in kw[table].items() if k == "y" or kw[k] is not None}
        return ClosedLoopData(**kw)

    def with_metadata(self, **items: Any) -> ClosedLoopData:
        """Copy with metadata entries added or replaced (e.g. ``machine=``)."""
        return self.replace(metadata={**thaw(self.metadata), **items})

    def segment(self, start: int, stop: int | None = None) -> ClosedLoopData:
        """Control periods ``start:stop`` as a new recording (time origin kept)."""
        n = self.n_samples
        stop = n if stop is None else stop
        if not (0 <= start < stop <= n):
            raise DataError(f"segment [{start}, {stop}) is outside the recording's 0..{n}")
        p = self.p
        kw: dict[str, Any] = {"y": self.y[start * p : stop * p], "t0": self.t0 + start * self.dt}
        for sig in ("u", "r", "u_f"):
            v = getattr(self, sig)
            kw[sig] = None if v is None else v[start:stop]
        extras = self.metadata.get("extra_signals")
        if extras:
            # Extra channels (e.g. a position reference) live in metadata with a rate:
            # "control" (N values) or "output" (N*p values); cut them with the signals.
            meta = thaw(self.metadata)
            for entry in meta["extra_signals"].values():
                vals = entry.get("values")
                if vals is None:
                    continue
                lo, hi = (start * p, stop * p) if len(vals) == self.y.shape[0] else (start, stop)
                entry["values"] = vals[lo:hi]
            kw["metadata"] = meta
        return self.replace(**kw)

    def with_plant_input(self) -> ClosedLoopData:
        """Fill ``u = u_f + r`` when ``u`` is missing and both parts are present."""
        if self.u is not None:
            return self
        if self.u_f is None or self.r is None:
            raise DataError("cannot form u = u_f + r: the recording lacks u_f or r")
        return self.replace(u=np.asarray(self.u_f) + np.asarray(self.r))

    def input_identity_mismatch(self) -> float | None:
        """Relative rms of ``u - (u_f + r)``, constant offset removed; ``None`` unless all logged.

        A digital loop logs ``u = u_f + r`` exactly (a bias voltage may add a
        constant). A large value means the excitation was not applied as
        logged, or the channels disagree (see
        :func:`maglevid.diagnose.checks.check_input_identity`).
        """
        if self.u is None or self.r is None or self.u_f is None:
            return None
        u = np.asarray(self.u, dtype=float)
        e = u - np.asarray(self.u_f, dtype=float) - np.asarray(self.r, dtype=float)
        scale = float(np.sqrt(np.mean(np.square(u - u.mean(axis=0)))))
        err = float(np.sqrt(np.mean(np.square(e - e.mean(axis=0)))))
        return err / max(scale, 1e-300)

    def to_dict(self) -> dict[str, Any]:
        """Everything but the signal arrays, JSON-safe (the metadata side-car content)."""
        return {
            "format": "maglevid-recording",
            "version": 1,
            "dt": self.dt,
            "p": self.p,
            "t0": self.t0,
            "n_samples": self.n_samples,
            "signals": {
                s: {"names": list(self.channel_names(s)), "units": list(self.channel_units(s))}
                for s in self.signals()
            },
            "loop": thaw(self.loop),
            "metadata": thaw(self.metadata),
        }

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickled as its fields, the read-only mappings as plain ones (a mappingproxy does
        not pickle): for worker processes (:mod:`maglevid.parallel`) and users' own pools.
        Unpickling validates and freezes them again."""
        return (
            ClosedLoopData,
            (self.y, self.dt, self.u, self.r, self.u_f, self.p, unfreeze(self.names),
             unfreeze(self.units), self.t0, unfreeze(self.loop), unfreeze(self.metadata)),
        )  # fmt: skip

    def __repr__(self) -> str:
        sig = ", ".join(
            f"{s}:{(self.y if s == 'y' else getattr(self, s)).shape[1]}" for s in self.signals()
        )
        return f"ClosedLoopData(N={self.n_samples}, dt={self.dt:g}, p={self.p}, {sig})"
