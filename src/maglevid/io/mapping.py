"""Column mappings: how a user's own log becomes a :class:`~maglevid.data.ClosedLoopData`.

A mapping says which column (or MATLAB/NPZ variable) holds which channel of
``y``, ``u``, ``r`` and ``u_f``, with scale factors and units, where the time
is (or what the sample time is when the file has none), and how to parse a
text file (delimiter, comment prefix, header lines, encoding). It is a plain
dict, a JSON or TOML file, or the name of a preset shipped with maglevid
(:func:`available_presets`). The full schema, with examples, is in
``docs/recording-format.md``; :func:`load_mapping` checks it and names the key
at fault.

Mappings are also how the native readers work: a maglevid file's own metadata
is turned into a mapping, so every file goes through the same checks.
"""

from __future__ import annotations

import json
import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any

from maglevid.data import SIGNALS
from maglevid.exceptions import FileFormatError
from maglevid.io._files import check_input_file

__all__ = [
    "ChannelSpec",
    "ColumnMapping",
    "TextOptions",
    "TimeSpec",
    "available_presets",
    "load_mapping",
]

#: Formats a mapping may force (``"text"``: any delimited text file).
MAPPING_FORMATS = ("text", "csv", "npz", "mat", "parquet")

#: Layouts of 2-D variables in NPZ/MAT files.
LAYOUTS = ("auto", "time_first", "channels_first")

#: Seconds per unit of a time column.
TIME_UNITS = {
    "s": 1.0,
    "ms": 1e-3,
    "us": 1e-6,
    "µs": 1e-6,
    "μs": 1e-6,
    "ns": 1e-9,
    "min": 60.0,
}

#: Words accepted for a text delimiter (TOML and JSON users rarely like escapes).
DELIMITER_WORDS = {
    "tab": "\t",
    "comma": ",",
    "semicolon": ";",
    "space": " ",
    "whitespace": None,
}

#: Default relative tolerance on each step of a time column (1 %: catches a dropped
#: sample, which doubles one step, and tolerates time stamps printed with few digits).
DEFAULT_TIME_TOLERANCE = 0.01
#: Default relative tolerance on the mean step of a time column against ``dt``.
DEFAULT_RATE_TOLERANCE = 1e-3

_TOP_KEYS = {
    "description",
    "extends",
    "any_of",
    "format",
    "text",
    "columns",
    "n_columns",
    "layout",
    "time",
    "dt",
    "sample_rate",
    "p",
    "t0",
    "n_samples",
    "y",
    "u",
    "r",
    "u_f",
    "extra",
    "expect_units",
    "loop",
    "metadata",
}
_TEXT_KEYS = {"delimiter", "comment", "skip_lines", "header", "encoding", "decimal", "quote"}
_TIME_KEYS = {"column", "unit", "scale", "tolerance", "rate_tolerance"}
_CHANNEL_KEYS = {"column", "index", "name", "unit", "file_unit", "scale", "offset"}
_EXTRA_KEYS = {*_CHANNEL_KEYS, "rate"}
_OUTPUT_KEYS = {*_CHANNEL_KEYS, "intersamples"}
#: Rates an extra channel may have: ``"output"`` (one value per output sample) or
#: ``"control"`` (one per control period; held over the period in row-per-output files).
RATES = ("output", "control")


@dataclass(frozen=True)
class TextOptions:
    """How to parse a delimited text file.

    ``delimiter="auto"`` follows the extension (``,`` for .csv, tab for .tsv,
    white space otherwise); ``delimiter=None`` splits on runs of white space;
    ``header`` is ``True``, ``False`` or ``"auto"`` (a first line that does
    not parse as numbers is a header); ``skip_lines`` lines are dropped before anything else;
    ``decimal=","`` reads decimal commas (the delimiter must then not be a comma).
    """

    delimiter: str | None = "auto"
    comment: str | None = "#"
    skip_lines: int = 0
    header: bool | str = "auto"
    encoding: str = "utf-8"
    decimal: str = "."
    quote: str | None = None


@dataclass(frozen=True)
class TimeSpec:
    """A time column: where it is, its unit and the uniformity tolerances.

    ``scale`` converts the file's numbers to seconds (from ``unit`` unless
    given). ``tolerance`` bounds each step relative to the output sample
    interval ``dt/p``; ``rate_tolerance`` bounds the mean step against ``dt/p``
    when the mapping also gives ``dt``.
    """

    column: str | int
    unit: str = "s"
    scale: float = 1.0
    tolerance: float = DEFAULT_TIME_TOLERANCE
    rate_tolerance: float = DEFAULT_RATE_TOLERANCE


@dataclass(frozen=True)
class ChannelSpec:
    """One channel: ``value = file_value * scale + offset``, stored in ``unit``.

    ``column`` is a header name or a 0-based column index (text, Parquet) or
    a variable name (NPZ, MAT); ``index`` picks a column of a 2-D variable.
    ``file_unit`` is the unit the file uses; when the file states a unit (a
    side-car, a ``name [unit]`` header, Parquet field metadata) it must match
    ``file_unit`` (or ``unit`` when there is no scaling). ``rate`` (extra
    channels only) is ``"output"`` or ``"control"``; ``None`` takes it from the
    number of samples.
    """

    column: str | int
    index: int | None = None
    name: str | None = None
    unit: str = ""
    file_unit: str | None = None
    scale: float = 1.0
    offset: float = 0.0
    rate: str | None = None
    #: Wide inter-sampled layout (outputs only): the ``p`` columns holding the
    #: samples ``y(mT + j T/p)``, ``j = 0..p-1``, of one row per control period.
    intersamples: tuple[str | int, ...] = ()

    @property
    def expected_file_unit(self) -> str | None:
        """The unit the file should state for this column (``None``: cannot tell)."""
        if self.file_unit is not None:
            return self.file_unit
        if self.scale == 1.0 and self.offset == 0.0 and self.unit:
            return self.unit
        return None


@dataclass(frozen=True)
class ColumnMapping:
    """A checked mapping (see :func:`load_mapping` and ``docs/recording-format.md``).

    ``signals`` is empty for an *options-only* mapping (``layout``,
    ``expect_units``, ``dt``...), which refines how a native file is read
    instead of replacing its own description.
    """

    origin: str = "dict"
    description: str = ""
    format: str | None = None
    text: TextOptions | None = None
    columns: tuple[str, ...] | None = None
    n_columns: int | None = None
    layout: str = "auto"
    time: TimeSpec | None = None
    dt: float | None = None
    p: int | None = None
    t0: float | None = None
    n_samples: int | None = None
    signals: Mapping[str, tuple[ChannelSpec, ...]] = field(default_factory=dict)
    extra: tuple[ChannelSpec, ...] = ()
    expect_units: Mapping[str, tuple[str, ...]] = field(default_factory=dict)
    loop: Mapping[str, Any] = field(default_factory=dict)
    metadata: Mapping[str, Any] = field(default_factory=dict)
    alternatives: tuple[ColumnMapping, ...] = ()

    @property
    def has_signals(self) -> bool:
        """Whether the mapping says where the signals are (else: options only)."""
        return bool(self.signals)

    def with_options(self, options: ColumnMapping) -> ColumnMapping:
        """This mapping refined by an options-only mapping (its non-default fields win)."""
        changes: dict[str, Any] = {}
        for name in ("layout", "dt", "p", "t0", "text", "time", "n_columns"):
            value = getattr(options, name)
            default = getattr(ColumnMapping, name, None)
            if value is not None and value != default:
                changes[name] = value
        if options.expect_units:
            changes["expect_units"] = {**self.expect_units, **options.expect_units}
        if options.loop:
            changes["loop"] = {**self.loop, **options.loop}
        if options.metadata:
            changes["metadata"] = {**self.metadata, **options.metadata}
        return replace(self, **changes)


# ----------------------------------------------------------------- presets
def _preset_dir() -> Any:
    return resources.files("maglevid.io") / "presets"


def available_presets() -> dict[str, str]:
    """Names and one-line descriptions of the mapping presets shipped with maglevid.

    Examples
    --------
    >>> "uaq-levitador" in available_presets()
    True
    """
    out = {}
    for entry in sorted(_preset_dir().iterdir(), key=lambda e: e.name):
        if entry.name.endswith(".json"):
            raw = json.loads(entry.read_text(encoding="utf-8"))
            out[entry.name[:-5].replace("_", "-")] = str(raw.get("description", "")).split("\n")[0]
    return out


def _named_columns(m: ColumnMapping) -> set[Any]:
    """The columns (or variables) a mapping reads: channels, inter-samples, extras, time."""
    specs = [c for chans in m.signals.values() for c in chans] + list(m.extra)
    cols: set[Any] = {c.column for c in specs} | {i for c in specs for i in c.intersamples}
    if m.time is not None:
        cols.add(m.time.column)
    return cols


def presets_for_variables(names: Collection[str], fmt: str) -> list[str]:
    """The shipped presets for ``fmt`` files whose every named variable is in ``names``.

    A preset is suggested only when it names its variables (not column
    indices) and the file has them all, so a suggestion is never a guess.

    Examples
    --------
    >>> names = ["rawMeasurements1", "rawMeasurements2", "rawMeasurements3", "u"]
    >>> presets_for_variables(names, "mat")
    ['maggy-ntnu']
    >>> presets_for_variables(["y", "dt"], "mat")
    []
    """
    have = set(names)
    fmt = {"mat73": "mat"}.get(fmt, fmt)
    out = []
    for name in available_presets():
        try:
            m = load_mapping(name)
        except FileFormatError:  # pragma: no cover - shipped presets are checked by tests
            continue
        if m.alternatives or not m.has_signals or m.format not in (None, fmt):
            continue
        cols = _named_columns(m)
        if all(isinstance(c, str) for c in cols) and cols <= have:
            out.append(name)
    return out


def _read_preset(name: str) -> tuple[dict[str, Any], str]:
    key = name.strip().lower().replace("-", "_")
    entry = _preset_dir() / f"{key}.json"
    if not entry.is_file():
        raise FileFormatError(
            f"mapping {name!r} is neither an existing mapping file (.json/.toml) nor a preset; "
            f"presets: {', '.join(available_presets())}"
        )
    return json.loads(entry.read_text(encoding="utf-8")), f"preset {key.replace('_', '-')}"


def _read_mapping_file(path: Path) -> dict[str, Any]:
    check_input_file(path, what="mapping")
    try:
        raw_bytes = path.read_bytes()
    except OSError as exc:
        raise FileFormatError(f"cannot read the mapping file: {exc}", path=str(path)) from None
    suffix = path.suffix.lower()
    if suffix == ".toml":
        try:
            import tomllib  # Python >= 3.11
        except ModuleNotFoundError:  # pragma: no cover - Python 3.10 only
            try:
                import tomli as tomllib  # type: ignore[no-redef]
            except ModuleNotFoundError:
                raise FileFormatError(
                    "TOML mapping files need Python >= 3.11 (tomllib) or the package tomli; "
                    "write the mapping as JSON instead (same keys)",
                    path=str(path),
                ) from None
        try:
            return tomllib.loads(raw_bytes.decode("utf-8"))
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise FileFormatError(f"not a valid TOML mapping: {exc}", path=str(path)) from None
    if suffix == ".json":
        try:
            return json.loads(raw_bytes.decode("utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise FileFormatError(f"not a valid JSON mapping: {exc}", path=str(path)) from None
    raise FileFormatError(
        f"mapping files are .json or .toml; got {suffix or 'no extension'!r}", path=str(path)
    )


def load_mapping(spec: Any) -> ColumnMapping:
    """Check a column mapping and return it as a :class:`ColumnMapping`.

    Parameters
    ----------
    spec : dict, str, os.PathLike or ColumnMapping
        A mapping dict, the path of a ``.json`` or ``.toml`` mapping file, or
        the name of a preset (:func:`available_presets`), e.g.
        ``"uaq-levitador"``.

    Returns
    -------
    ColumnMapping

    Raises
    ------
    FileFormatError
        Unknown key (typos are not ignored), wrong type or value, unreadable
        file, unknown preset; the message names the key.

    Examples
    --------
    >>> m = load_mapping({"time": "t", "y": ["gap"], "u": [{"column": "v", "unit": "V"}]})
    >>> m.signals["u"][0].unit, m.time.column
    ('V', 't')
    """
    if isinstance(spec, ColumnMapping):
        return spec
    if isinstance(spec, Mapping):
        return _parse(dict(spec), origin="dict", path=None, depth=0)
    if isinstance(spec, (str, Path)):
        raw, origin, path = _resolve_named(spec)
        return _parse(raw, origin=origin, path=path, depth=0)
    raise FileFormatError(
        f"`mapping` must be a dict, a mapping file or a preset name; got {type(spec).__name__}"
    )


def _resolve_named(spec: str | Path) -> tuple[dict[str, Any], str, str | None]:
    path = Path(spec)
    looks_like_file = isinstance(spec, Path) or path.suffix.lower() in (".json", ".toml")
    if path.is_file() or looks_like_file:
        if not path.is_file():
            raise FileFormatError("mapping file not found", path=str(path))
        return _read_mapping_file(path), f"file {path}", str(path)
    raw, origin = _read_preset(str(spec))
    return raw, origin, None


# ------------------------------------------------------------------ parser
class _Err:
    """Raise mapping errors that name the mapping and the key."""

    def __init__(self, origin: str, path: str | None):
        self.origin = origin
        self.path = path

    def __call__(self, key: str, message: str) -> FileFormatError:
        where = "" if self.path else f"mapping ({self.origin}): "
        return FileFormatError(f"{where}key {key!r}: {message}", path=self.path)


def _number(err: _Err, key: str, value: Any, *, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise err(key, f"expected a number; got {value!r}")
    v = float(value)
    if not math.isfinite(v) or (positive and v <= 0):
        raise err(key, f"expected a {'positive ' if positive else ''}finite number; got {value!r}")
    return v


def _integer(err: _Err, key: str, value: Any, *, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise err(key, f"expected an integer >= {minimum}; got {value!r}")
    return int(value)


def _string(err: _Err, key: str, value: Any) -> str:
    if not isinstance(value, str):
        raise err(key, f"expected a string; got {value!r}")
    return value


def _column_ref(err: _Err, key: str, value: Any) -> str | int:
    if isinstance(value, bool) or not isinstance(value, (str, int)):
        raise err(key, f"expected a column name or a 0-based column index; got {value!r}")
    if isinstance(value, int) and value < 0:
        raise err(key, f"column indices are 0-based and non-negative; got {value}")
    return value


def _check_keys(err: _Err, key: str, raw: Mapping[str, Any], allowed: set[str]) -> None:
    unknown = sorted(set(raw) - allowed)
    if unknown:
        raise err(
            key if key else unknown[0],
            f"unknown key(s) {unknown}; allowed: {sorted(allowed)}",
        )


def _parse_text(err: _Err, raw: Any) -> TextOptions:
    if not isinstance(raw, Mapping):
        raise err("text", f"expected a table of text options; got {raw!r}")
    _check_keys(err, "text", raw, _TEXT_KEYS)
    kw: dict[str, Any] = {}
    if "delimiter" in raw:
        d = raw["delimiter"]
        if d is not None:
            d = _string(err, "text.delimiter", d)
            d = DELIMITER_WORDS.get(d.lower(), d) if len(d) > 1 and d != "auto" else d
            if d is not None and d != "auto" and (len(d) != 1 or d in "\r\n"):
                raise err("text.delimiter", f"expected one character or a word; got {d!r}")
        kw["delimiter"] = d
    if "comment" in raw:
        c = raw["comment"]
        kw["comment"] = None if c in (None, "") else _string(err, "text.comment", c)
    if "skip_lines" in raw:
        kw["skip_lines"] = _integer(err, "text.skip_lines", raw["skip_lines"], minimum=0)
    if "header" in raw:
        h = raw["header"]
        if h not in (True, False, "auto"):
            raise err("text.header", f'expected true, false or "auto"; got {h!r}')
        kw["header"] = h
    if "encoding" in raw:
        enc = _string(err, "text.encoding", raw["encoding"])
        import codecs

        try:
            codecs.lookup(enc)
        except LookupError:
            raise err("text.encoding", f"unknown text encoding {enc!r}") from None
        kw["encoding"] = enc
    if "decimal" in raw:
        dec = raw["decimal"]
        if dec not in (".", ","):
            raise err("text.decimal", f'expected "." or ","; got {dec!r}')
        kw["decimal"] = dec
    if "quote" in raw:
        q = raw["quote"]
        if q is not None and (not isinstance(q, str) or len(q) != 1):
            raise err("text.quote", f"expected one character or null; got {q!r}")
        kw["quote"] = q
    opts = TextOptions(**kw)
    if opts.decimal == "," and opts.delimiter in (",", "auto"):
        raise err("text.decimal", 'a decimal comma needs another delimiter (e.g. ";")')
    return opts


def _parse_time(err: _Err, raw: Any) -> TimeSpec | None:
    if raw is None:
        return None
    if not isinstance(raw, Mapping):
        return TimeSpec(column=_column_ref(err, "time", raw))
    _check_keys(err, "time", raw, _TIME_KEYS)
    if "column" not in raw:
        raise err("time", "needs 'column' (name or 0-based index)")
    unit = _string(err, "time.unit", raw.get("unit", "s"))
    if "scale" in raw:
        scale = _number(err, "time.scale", raw["scale"], positive=True)
    elif unit in TIME_UNITS:
        scale = TIME_UNITS[unit]
    else:
        raise err(
            "time.unit",
            f"unknown time unit {unit!r}; use one of {sorted(TIME_UNITS)} or give 'scale' "
            "(seconds per file unit)",
        )
    return TimeSpec(
        column=_column_ref(err, "time.column", raw["column"]),
        unit=unit,
        scale=scale,
        tolerance=_number(
            err, "time.tolerance", raw.get("tolerance", DEFAULT_TIME_TOLERANCE), positive=True
        ),
        rate_tolerance=_number(
            err,
            "time.rate_tolerance",
            raw.get("rate_tolerance", DEFAULT_RATE_TOLERANCE),
            positive=True,
        ),
    )


def _parse_channel(err: _Err, key: str, raw: Any) -> ChannelSpec:
    if not isinstance(raw, Mapping):
        return ChannelSpec(column=_column_ref(err, key, raw))
    is_extra = key.startswith("extra")
    allowed = _EXTRA_KEYS if is_extra else _OUTPUT_KEYS if key.startswith("y") else _CHANNEL_KEYS
    _check_keys(err, key, raw, allowed)
    rate = raw.get("rate")
    if rate is not None and rate not in RATES:
        raise err(f"{key}.rate", f"expected one of {RATES}; got {rate!r}")
    inter = raw.get("intersamples")
    if inter is not None:
        if not isinstance(inter, list) or len(inter) < 2 or "column" in raw:
            raise err(
                f"{key}.intersamples",
                "expected a list of the p >= 2 columns y(mT + jT/p), j = 0..p-1, of one row "
                f"per control period (instead of 'column'); got {inter!r}",
            )
        inter = tuple(_column_ref(err, f"{key}.intersamples[{i}]", c) for i, c in enumerate(inter))
    elif "column" not in raw:
        raise err(key, "needs 'column' (header name, 0-based index or variable name)")
    index = raw.get("index")
    return ChannelSpec(
        column=inter[0] if inter else _column_ref(err, f"{key}.column", raw["column"]),
        intersamples=inter or (),
        index=None if index is None else _integer(err, f"{key}.index", index, minimum=0),
        name=None if raw.get("name") is None else _string(err, f"{key}.name", raw["name"]),
        unit=_string(err, f"{key}.unit", raw.get("unit", "")),
        file_unit=(
            None
            if raw.get("file_unit") is None
            else _string(err, f"{key}.file_unit", raw["file_unit"])
        ),
        scale=_number(err, f"{key}.scale", raw.get("scale", 1.0)),
        offset=_number(err, f"{key}.offset", raw.get("offset", 0.0)),
        rate=rate,
    )


def _parse_channels(err: _Err, key: str, raw: Any) -> tuple[ChannelSpec, ...]:
    if isinstance(raw, (str, int, Mapping)) and not isinstance(raw, bool):
        raw = [raw]
    if not isinstance(raw, list) or not raw:
        raise err(key, f"expected a non-empty list of channels; got {raw!r}")
    return tuple(_parse_channel(err, f"{key}[{i}]", c) for i, c in enumerate(raw))


def _merge_extends(raw: dict[str, Any], err: _Err, depth: int) -> dict[str, Any]:
    base_spec = raw.pop("extends")
    if depth > 4:
        raise err("extends", "too deeply nested (a cycle?)")
    if not isinstance(base_spec, str):
        raise err("extends", f"expected a preset name or mapping file; got {base_spec!r}")
    base_raw, _, _ = _resolve_named(base_spec)
    if "extends" in base_raw:
        base_raw = _merge_extends(dict(base_raw), err, depth + 1)
    merged = dict(base_raw)
    merged.update(raw)  # top-level keys of the extending mapping win
    return merged


def _parse(raw: dict[str, Any], *, origin: str, path: str | None, depth: int) -> ColumnMapping:
    err = _Err(origin, path)
    if not isinstance(raw, dict):
        raise err("<top>", f"a mapping is a table of keys; got {type(raw).__name__}")
    if "extends" in raw:
        raw = _merge_extends(dict(raw), err, depth)
    _check_keys(err, "", raw, _TOP_KEYS)
    if "any_of" in raw:
        alts = raw["any_of"]
        if not isinstance(alts, list) or not alts:
            raise err("any_of", "expected a non-empty list of mappings or preset names")
        parsed = []
        for i, alt in enumerate(alts):
            if isinstance(alt, str):
                alt_raw, alt_origin, alt_path = _resolve_named(alt)
                parsed.append(_parse(alt_raw, origin=alt_origin, path=alt_path, depth=depth + 1))
            elif isinstance(alt, Mapping):
                parsed.append(
                    _parse(dict(alt), origin=f"{origin} any_of[{i}]", path=path, depth=depth + 1)
                )
            else:
                raise err(f"any_of[{i}]", f"expected a mapping or preset name; got {alt!r}")
            if parsed[-1].n_columns is None:
                raise err(f"any_of[{i}]", "each alternative needs 'n_columns' to be chosen by")
        return ColumnMapping(
            origin=origin,
            description=str(raw.get("description", "")),
            alternatives=tuple(parsed),
        )

    kw: dict[str, Any] = {"origin": origin, "description": str(raw.get("description", ""))}
    if "format" in raw:
        fmt = raw["format"]
        if fmt not in MAPPING_FORMATS:
            raise err("format", f"expected one of {MAPPING_FORMATS}; got {fmt!r}")
        kw["format"] = fmt
    if "text" in raw:
        kw["text"] = _parse_text(err, raw["text"])
    if "columns" in raw:
        cols = raw["columns"]
        if not isinstance(cols, list) or not all(isinstance(c, str) for c in cols) or not cols:
            raise err("columns", f"expected a list of column names; got {cols!r}")
        if len(set(cols)) != len(cols):
            raise err("columns", f"names must be unique; got {cols}")
        kw["columns"] = tuple(cols)
    if "n_columns" in raw:
        kw["n_columns"] = _integer(err, "n_columns", raw["n_columns"], minimum=1)
    if kw.get("columns") and kw.get("n_columns") and len(kw["columns"]) != kw["n_columns"]:
        raise err("columns", f"names {len(kw['columns'])} columns but n_columns={kw['n_columns']}")
    if "layout" in raw:
        if raw["layout"] not in LAYOUTS:
            raise err("layout", f"expected one of {LAYOUTS}; got {raw['layout']!r}")
        kw["layout"] = raw["layout"]
    if "time" in raw:
        kw["time"] = _parse_time(err, raw["time"])
    if "dt" in raw and "sample_rate" in raw:
        raise err("sample_rate", "give either 'dt' (s) or 'sample_rate' (Hz), not both")
    if "dt" in raw:
        kw["dt"] = _number(err, "dt", raw["dt"], positive=True)
    if "sample_rate" in raw:
        kw["dt"] = 1.0 / _number(err, "sample_rate", raw["sample_rate"], positive=True)
    if "p" in raw:
        kw["p"] = _integer(err, "p", raw["p"], minimum=1)
    if "t0" in raw:
        kw["t0"] = _number(err, "t0", raw["t0"])
    if "n_samples" in raw:
        kw["n_samples"] = _integer(err, "n_samples", raw["n_samples"], minimum=1)
    signals = {s: _parse_channels(err, s, raw[s]) for s in SIGNALS if s in raw}
    if signals and "y" not in signals:
        raise err("y", "a mapping that places signals must place 'y' (the outputs)")
    widths = {len(c.intersamples) for c in signals.get("y", ())}
    if widths - {0}:
        if len(widths) > 1:
            raise err("y", "give 'intersamples' for every output channel, with p columns each")
        p_wide = widths.pop()
        if kw.get("p", p_wide) != p_wide:
            raise err("p", f"p={kw['p']}, but 'intersamples' lists {p_wide} columns per output")
        kw["p"] = p_wide
    kw["signals"] = signals
    if "extra" in raw:
        extra = _parse_channels(err, "extra", raw["extra"])
        names = [c.name if c.name is not None else str(c.column) for c in extra]
        if len(set(names)) != len(names):
            raise err("extra", f"extra channel names must be unique; got {names}")
        kw["extra"] = extra
    if "expect_units" in raw:
        eu = raw["expect_units"]
        if not isinstance(eu, Mapping):
            raise err("expect_units", f"expected a table signal -> list of units; got {eu!r}")
        out = {}
        for sig, units in eu.items():
            if sig not in SIGNALS:
                raise err(f"expect_units.{sig}", f"unknown signal; expected one of {SIGNALS}")
            if isinstance(units, str):
                units = [units]
            if not isinstance(units, list) or not all(isinstance(u, str) for u in units):
                raise err(f"expect_units.{sig}", f"expected a list of unit strings; got {units!r}")
            out[sig] = tuple(units)
        kw["expect_units"] = out
    for key in ("loop", "metadata"):
        if key in raw:
            if not isinstance(raw[key], Mapping):
                raise err(key, f"expected a table; got {raw[key]!r}")
            kw[key] = dict(raw[key])
    return ColumnMapping(**kw)
