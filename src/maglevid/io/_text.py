"""Delimited text: maglevid's CSV + JSON side-car, and users' own logs through a mapping."""

from __future__ import annotations

import codecs
import csv
import io
import json
import logging
import re
from collections.abc import Iterator, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from maglevid.data import ClosedLoopData
from maglevid.exceptions import FileFormatError
from maglevid.io import _native
from maglevid.io._engine import Key, Table, assemble
from maglevid.io._files import (
    SNIFF_BYTES,
    check_input_file,
    dumps_json,
    known_binary,
    read_as,
    read_head,
    sidecar_path,
)
from maglevid.io.mapping import ColumnMapping, TextOptions

log = logging.getLogger(__name__)

#: Encodings in which a delimiter or newline byte is always that character.
_ASCII_SAFE = {"utf-8", "utf-8-sig", "ascii", "iso8859-1", "cp1252"}
#: Bytes read at a time by the check of every row's field count.
_BLOCK_BYTES = 1 << 23

_UNIT_IN_HEADER = re.compile(r"^(?P<name>.*?)\s*[\[(](?P<unit>[^\])]*)[\])]\s*$")


def _split(line: str, opts: TextOptions) -> list[str]:
    if opts.delimiter is None:
        return line.split()
    row = next(csv.reader([line], delimiter=opts.delimiter, quotechar=opts.quote or '"'))
    return [f.strip() for f in row]


def _is_number(field: str, opts: TextOptions) -> bool:
    if opts.quote:
        field = field.strip(opts.quote)
    if opts.decimal == ",":
        field = field.replace(",", ".")
    try:
        float(field)
    except ValueError:
        return False
    return True


def check_text_file(path: Path, encoding: str = "utf-8") -> None:
    """Refuse a binary file before reading it as text, naming its format when known.

    A file is binary when it starts with a known signature (zip/NPZ, MATLAB,
    HDF5, Parquet, ...) or has NUL bytes in its first :data:`SNIFF_BYTES` bytes
    (which no 8-bit or UTF-8 text has; UTF-16/32 text, declared by the
    mapping's ``text.encoding``, is exempt).
    """
    head = read_head(path)
    known = known_binary(head)
    if known is not None:
        what, fmt = known
        hint = "" if fmt is None else f": {read_as(fmt)}"
        raise FileFormatError(
            f"is a binary file, not text: it looks like {what}{hint}", path=str(path)
        )
    wide = codecs.lookup(encoding).name.startswith(("utf-16", "utf-32"))
    if head.startswith((b"\xff\xfe", b"\xfe\xff")) and not wide:
        raise FileFormatError(
            'is UTF-16 text: set the mapping\'s text.encoding to "utf-16"', path=str(path)
        )
    if b"\x00" in head and not wide:
        raise FileFormatError(
            f"is a binary file, not text (it has NUL bytes in its first {SNIFF_BYTES} bytes) "
            "and of no format maglevid knows; a recording is .csv (+ .json side-car), .npz, "
            ".mat or .parquet",
            path=str(path),
        )


def _k_per_line(marks: np.ndarray, starts: np.ndarray, ends: np.ndarray, k: int) -> bool:
    """Whether each line ``[starts[i], ends[i])`` holds exactly ``k`` of the sorted ``marks``.

    With ``k * n_lines`` marks in all, line ``i`` holds exactly ``k`` when its
    share ``marks[i*k : (i+1)*k]`` starts and ends inside it: O(lines), no counting.
    """
    if marks.size != k * starts.size:
        return False
    if k == 0:
        return True
    return bool(np.all(marks[::k] >= starts) and np.all(marks[k - 1 :: k] < ends))


def _layout_hint(text: str) -> str:
    """What a header that does not split as expected says about the file's layout: a
    spreadsheet's export with ';' and decimal commas, or comment lines above the header
    (such files were told only "header column 0 is 't;y:x;...'" or "the header has 1
    fields"; found from outside, seventeenth session)."""
    if text.lstrip().startswith("#"):
        return (
            "the file starts with comment lines: remove them, or read it through a column "
            'mapping with "text": {"comment": "#"}'
        )
    for sep, name in ((";", "semicolon"), ("\t", "tab")):
        if sep in text:
            return (
                f"the file looks separated by {name}s (a spreadsheet's export?), not commas: "
                "re-export it with commas and decimal points, or read it through a column "
                f'mapping with "text": {{"delimiter": "{name}"'
                + (', "decimal": ","}' if sep == ";" else "}")
            )
    return ""


class TextTable(Table):
    """A delimited text file: optional skipped lines, comments, a header, numeric rows."""

    kind = "text"

    def __init__(
        self,
        path: Path,
        opts: TextOptions,
        columns: Sequence[str] | None = None,
        *,
        native: bool = False,
    ):
        if codecs.lookup(opts.encoding).name == "utf-8":
            # Excel and Notepad put a byte-order mark before UTF-8 text; it is not data.
            opts = replace(opts, encoding="utf-8-sig")
        check_text_file(path, opts.encoding)
        self.opts = opts
        self._comment = opts.comment
        comments: list[str] = []
        header: list[str] | None = None
        first: list[str] | None = None
        skip = 0  # lines before the first data row
        try:
            with open(path, encoding=opts.encoding) as fh:
                for _ in range(opts.skip_lines):
                    if not fh.readline():
                        break
                    skip += 1
                for line in fh:
                    s = line.strip()
                    if not s or (self._comment and s.startswith(self._comment)):
                        text = s[len(self._comment or "") :].strip()
                        if text:
                            comments.append(text)
                        skip += 1
                        continue
                    fields = _split(line, opts)
                    if header is None and (
                        opts.header is True
                        or (
                            opts.header == "auto"
                            and not all(_is_number(f, opts) for f in fields if f)
                        )
                    ):
                        header = fields
                        skip += 1
                        continue
                    first = fields
                    break
        except UnicodeDecodeError as exc:
            raise FileFormatError(
                f"cannot be decoded as {opts.encoding} text ({exc.reason} at byte "
                f'{exc.start}); set the mapping\'s text.encoding (e.g. "latin-1")',
                path=str(path),
            ) from None
        except OSError as exc:
            raise FileFormatError(f"cannot be read: {exc}", path=str(path)) from None
        n_columns = len(first) if first is not None else (len(header) if header else 0)
        names: list[str] | None = None
        units: dict[Key, Any] = {}
        aliases: dict[str, str] = {}
        if columns is not None:
            if first is not None and len(columns) != n_columns:
                raise FileFormatError(
                    f"the mapping names {len(columns)} columns ({list(columns)}); the file "
                    f"has {n_columns}",
                    path=str(path),
                )
            names = list(columns)
        elif header is not None:
            names = header
            if first is not None and len(header) != n_columns:
                hint = _layout_hint(" ".join(map(str, header)))
                raise FileFormatError(
                    f"the header has {len(header)} fields but the first data row has {n_columns}"
                    + (f": {hint}" if hint else ""),
                    path=str(path),
                )
        if names is not None and not native:
            for i, name in enumerate(names):
                m = _UNIT_IN_HEADER.match(name)
                if m and m.group("name"):
                    units[i] = m.group("unit").strip()
                    aliases.setdefault(m.group("name"), name)
        super().__init__(path, names, n_columns)
        self.units.update(units)
        self.aliases = {a: f for a, f in aliases.items() if a not in (names or ())}
        self.header = header
        self.skiprows = skip
        self.has_data = first is not None
        #: maglevid's own CSV: may be parsed by pyarrow (4-7x faster than numpy.loadtxt).
        self.fast = native and opts.delimiter == "," and opts.quote is None
        if comments:
            self.metadata["header_comments"] = comments

    # ---------------------------------------------------------- addressing
    # Keys are 0-based column indices (names may repeat in a native file's header).
    def resolve(self, ref: Key) -> Key:
        if isinstance(ref, str) and self.names is not None and self.names.count(ref) > 1:
            raise self.error(
                f"the name appears {self.names.count(ref)} times in the header; refer to the "
                'column by 0-based index or rename the columns with "columns"',
                column=ref,
            )
        key = super().resolve(ref)
        if isinstance(ref, int):
            return ref
        return key if isinstance(key, int) else self.names.index(key)  # type: ignore[union-attr]

    def label(self, key: Key, index: int | None = None) -> str:
        if isinstance(key, int) and self.names is not None:
            return self.names[key]
        return f"#{key}" if isinstance(key, int) else key

    def default_name(self, key: Key) -> str | None:
        if not isinstance(key, int) or self.names is None:
            return None
        full = self.names[key]
        m = _UNIT_IN_HEADER.match(full)
        return m.group("name") if (m and m.group("name") and key in self.units) else full

    # -------------------------------------------------------------- loading
    def _index(self, key: Key) -> int:
        return key if isinstance(key, int) else self.names.index(key)  # type: ignore[union-attr]

    def _load_arrow(self, idx: list[int]) -> np.ndarray | None:
        """Fast path for maglevid's own CSV (plain commas, one header line, UTF-8)."""
        try:
            import pyarrow as pa
            import pyarrow.csv as pacsv
        except ModuleNotFoundError:  # pragma: no cover - optional extra
            return None
        names = [f"c{i}" for i in range(self.n_columns)]
        try:
            table = pacsv.read_csv(
                self.path,
                read_options=pacsv.ReadOptions(skip_rows=self.skiprows, column_names=names),
                convert_options=pacsv.ConvertOptions(
                    column_types={n: pa.float64() for n in names},
                    include_columns=[names[i] for i in idx],
                    null_values=[],
                    strings_can_be_null=False,
                ),
            )
        except (pa.ArrowInvalid, pa.ArrowIOError):
            return None  # the slow path finds and names the bad row
        return np.column_stack([table.column(names[i]).to_numpy() for i in idx])

    def load(self, keys: Sequence[Key]) -> dict[Key, np.ndarray]:
        if not self.has_data:
            return {k: np.empty(0) for k in keys}
        idx = sorted({self._index(k) for k in keys})
        if self.fast:
            arr = self._load_arrow(idx)
            if arr is not None:
                return {k: arr[:, idx.index(self._index(k))] for k in keys}
        opts = self.opts
        src: Any = self.path
        if opts.decimal == ",":
            src = io.StringIO(self.path.read_text(encoding=opts.encoding).replace(",", "."))
        try:
            arr = np.loadtxt(
                src,
                delimiter=opts.delimiter,
                comments=self._comment,
                skiprows=self.skiprows,
                usecols=idx,
                encoding=opts.encoding,
                quotechar=opts.quote,
                ndmin=2,
                dtype=float,
            )
        except UnicodeDecodeError as exc:
            raise FileFormatError(
                f"cannot be decoded as {opts.encoding} text ({exc.reason}); set the mapping's "
                'text.encoding (e.g. "latin-1")',
                path=str(self.path),
            ) from None
        except ValueError as exc:
            raise self._diagnose(idx, str(exc)) from None
        self._check_row_widths()  # loadtxt with usecols ignores extra fields: refuse them
        return {k: arr[:, idx.index(self._index(k))] for k in keys}

    def _data_lines(self) -> Iterator[tuple[int, str]]:
        """(line number, text) of each data row, skipping what loadtxt skips."""
        with open(self.path, encoding=self.opts.encoding) as fh:
            for no, line in enumerate(fh, start=1):
                if no <= self.skiprows:
                    continue
                s = line
                if self._comment and self._comment in s:
                    s = s.split(self._comment, 1)[0]
                if s.strip():
                    yield no, s

    def _n_fields(self, line: str) -> int:
        """Number of fields of one data line (its comment already cut off)."""
        opts = self.opts
        if opts.delimiter is not None and opts.quote is None:
            return line.count(opts.delimiter) + 1
        return len(_split(line.rstrip("\r\n"), opts))

    def _width_error(self, row: int, no: int, n: int) -> FileFormatError:
        """A data row with another number of fields than the header (or first row)."""
        message = f"data row {row} (line {no}) has {n} field(s); expected {self.n_columns}"
        if n > self.n_columns:
            why = "two rows joined on one line" if n >= 2 * self.n_columns - 1 else "extra values"
            message += (
                f" ({why}?); extra fields are never dropped silently: fix or remove that line"
            )
        return self.error(message)

    def _widths_look_right(self) -> bool:
        """Fast pass: does every data line have ``n_columns`` fields? ``False``: look closely.

        Counts delimiters (or white-space separated tokens) per line on the raw
        bytes with numpy, a block at a time; only lines whose count is off
        (comments, blank lines, bad rows) are decoded and looked at. Anything
        unusual (quoted fields, an encoding that is not ASCII-compatible, a
        lone carriage return) leaves the decision to the exact pass.
        """
        opts = self.opts
        if (
            opts.quote is not None
            or codecs.lookup(opts.encoding).name not in _ASCII_SAFE
            or not (opts.delimiter or "").isascii()
        ):
            return False
        d = None if opts.delimiter is None else ord(opts.delimiter)
        with open(self.path, "rb") as fh:
            for _ in range(self.skiprows):
                if b"\r" in fh.readline().rstrip(b"\r\n"):
                    return False
            rest = b""
            while True:  # whole lines at a time; the last one may lack its newline
                block = fh.read(_BLOCK_BYTES)
                data = rest + block
                cut = len(data) if not block else data.rfind(b"\n") + 1
                rest = data[cut:]
                if cut and not self._block_widths_right(data[:cut], d):
                    return False
                if not block:
                    return True

    def _block_widths_right(self, raw: bytes, d: int | None) -> bool:
        """Whether every line of ``raw`` (whole lines) has ``n_columns`` fields."""
        buf = np.frombuffer(raw if raw.endswith(b"\n") else raw + b"\n", dtype=np.uint8)
        cr = np.flatnonzero(buf == 13)
        if cr.size and np.any(buf[np.minimum(cr + 1, buf.size - 1)] != 10):
            return False  # a lone \r is a line break to Python: let the exact pass count
        ends = np.flatnonzero(buf == 10)
        starts = np.concatenate(([0], ends[:-1] + 1))
        if d is not None:
            marks, k = np.flatnonzero(buf == d), self.n_columns - 1  # delimiters
        else:
            if buf.max() >= 128 or buf.min() < 9 or np.any((buf > 13) & (buf < 28)):
                return False  # non-ASCII white space (NBSP...) or odd control bytes
            ws = buf <= 32  # now exactly the ASCII white space str.split() splits on
            token = ~ws
            token[1:] &= ws[:-1]  # a field starts where white space ends
            marks, k = np.flatnonzero(token), self.n_columns  # field starts
        if _k_per_line(marks, starts, ends, k):
            return True
        counts = np.bincount(np.searchsorted(ends, marks), minlength=ends.size)
        for j in np.flatnonzero(counts != k):
            line = bytes(buf[starts[j] : ends[j]]).decode(self.opts.encoding, "replace")
            if self._comment and self._comment in line:
                line = line.split(self._comment, 1)[0]
            if line.strip() and self._n_fields(line) != self.n_columns:
                return False
        return True

    def _check_row_widths(self) -> None:
        """Every data row has exactly ``n_columns`` fields; else name the first that has not."""
        if self._widths_look_right():
            return
        for row, (no, line) in enumerate(self._data_lines()):
            n = self._n_fields(line)
            if n != self.n_columns:
                raise self._width_error(row, no, n)

    def _diagnose(self, idx: list[int], numpy_message: str) -> FileFormatError:
        """Find the first row that does not parse (slow path, only after an error)."""
        for row, (no, line) in enumerate(self._data_lines()):
            fields = _split(line.rstrip("\r\n"), self.opts)
            if len(fields) != self.n_columns:
                return self._width_error(row, no, len(fields))
            for i in idx:
                if not _is_number(fields[i], self.opts):
                    return self.error(
                        f"data row {row} (line {no}): {fields[i]!r} is not a number",
                        column=self.label(self.names[i] if self.names else i),
                    )
        return self.error(f"cannot be parsed as numbers: {numpy_message}")

    def where(self, row: int) -> str:
        for k, (no, _) in enumerate(self._data_lines()):
            if k == row:
                return f"data row {row} (line {no})"
        return f"data row {row}"  # pragma: no cover - rows come from this file


# ------------------------------------------------------------------- read
def read_text(path: Path, mapping: ColumnMapping, *, csv_default: bool) -> ClosedLoopData:
    """A user's delimited log through ``mapping``."""
    opts = resolve_text_options(mapping.text, path, csv_default=csv_default)
    table = TextTable(path, opts, mapping.columns)
    if csv_default and sidecar_path(path).is_file():
        # A maglevid CSV read through a user's mapping: its side-car states the units.
        side = _read_sidecar(sidecar_path(path))
        cols = side.get("file", {}).get("columns") or []
        cunits = side.get("file", {}).get("column_units") or []
        for i, (_, unit) in enumerate(zip(cols, cunits)):
            if unit:
                table.units[i] = unit
    md = _native.source_metadata({}, path, "csv" if csv_default else "text")
    md["mapping"] = mapping.origin
    return assemble(table, mapping, extra_metadata=md)


def resolve_text_options(
    opts: TextOptions | None, path: Path, *, csv_default: bool
) -> TextOptions:
    """The mapping's text options, with ``delimiter="auto"`` resolved from the extension."""
    opts = opts or TextOptions()
    if opts.delimiter != "auto":
        return opts
    suffix = path.suffix.lower()
    if csv_default or suffix == ".csv":
        delimiter: str | None = ","
    elif suffix == ".tsv":
        delimiter = "\t"
    else:
        delimiter = None
    return replace(opts, delimiter=delimiter)


def _read_sidecar(path: Path) -> dict[str, Any]:
    check_input_file(path, what="metadata side-car")
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise FileFormatError(
            f"cannot read the metadata side-car: {exc}", path=str(path)
        ) from None
    except UnicodeDecodeError:
        raise FileFormatError("the metadata side-car is not UTF-8 text", path=str(path)) from None
    try:
        side = json.loads(text)
    except json.JSONDecodeError as exc:
        raise FileFormatError(
            f"malformed metadata side-car: not valid JSON ({exc.msg} at line {exc.lineno}, "
            f"column {exc.colno})",
            path=str(path),
        ) from None
    if not isinstance(side, dict):
        raise FileFormatError(
            "malformed metadata side-car: expected a JSON object", path=str(path)
        )
    return side


def read_native_csv(path: Path, options: ColumnMapping | None) -> ClosedLoopData:
    """A maglevid CSV recording (``rec.csv`` + ``rec.json``)."""
    check_text_file(path)
    side_path = sidecar_path(path)
    if not side_path.is_file():
        raise FileFormatError(
            f"no metadata side-car {side_path.name} beside it: a maglevid CSV recording has "
            "one (see docs/recording-format.md). If this is your own log, read it through a "
            "column mapping (mapping= in Python, --mapping FILE.json or a preset name on the "
            "command line)",
            path=str(path),
        )
    side = _read_sidecar(side_path)
    desc = _native.parse_description(side, path=str(side_path))
    table = TextTable(path, TextOptions(delimiter=",", comment=None, header=True), native=True)
    expected, column_units = _native.column_labels(desc)
    table.units = {i: u for i, u in enumerate(column_units) if u}
    if table.header is None:
        raise FileFormatError("has no header row; expected " + ",".join(expected), path=str(path))
    if list(table.header) != expected:
        for i, (got, want) in enumerate(zip(table.header, expected)):
            if got != want:
                raise FileFormatError(
                    f"header column {i} is {got!r}, but the side-car {side_path.name} "
                    f"describes {want!r}: "
                    + (_layout_hint(got) or "the two files do not belong together"),
                    path=str(path),
                    column=got,
                )
        raise FileFormatError(
            f"the header has {len(table.header)} columns; the side-car {side_path.name} "
            f"describes {len(expected)}: {expected}",
            path=str(path),
        )
    mapping = _native.row_mapping(desc, origin=f"side-car {side_path.name}")
    if options is not None:
        mapping = mapping.with_options(options)
    md = _native.source_metadata(desc.metadata, path, "csv")
    return assemble(table, mapping, extra_metadata=md)


# ------------------------------------------------------------------ write
def _write_columns(fh: Any, columns: Sequence[np.ndarray]) -> None:
    """Rows of shortest round-trip float text, comma-separated, to a binary file."""
    try:
        import pyarrow as pa
        import pyarrow.csv as pacsv
    except ModuleNotFoundError:  # pragma: no cover - optional extra
        fh.write(_format_columns_repr(columns).encode("ascii"))
        return
    # Arrow prints doubles with the shortest text that reads back exactly
    # (double-conversion's ToShortest), as Python's repr does, several times faster.
    table = pa.table({f"c{i}": np.asarray(c, dtype=float) for i, c in enumerate(columns)})
    pacsv.write_csv(table, fh, write_options=pacsv.WriteOptions(include_header=False))


def _format_columns_repr(columns: Sequence[np.ndarray]) -> str:
    texts = [list(map(float.__repr__, np.asarray(c, dtype=float).tolist())) for c in columns]
    body = "\n".join(map(",".join, zip(*texts)))
    return body + "\n" if body else ""


def write_csv(data: ClosedLoopData, target: Path, tmp: Path, *, sidecar: bool) -> None:
    """Write the CSV (``sidecar=False``) or its JSON side-car (``sidecar=True``) to ``tmp``."""
    labels, units, columns = _native.row_columns(data)
    if sidecar:
        desc = _native.describe(data)
        desc["file"] = {
            "format": "csv",
            "data_file": target.with_suffix(".csv").name,
            "columns": labels,
            "column_units": units,
            "rows": int(data.y.shape[0]),
            "time_column": "t",
            "layout": "one row per output sample (N*p rows); inputs held over each control "
            "period (p equal rows)",
        }
        tmp.write_text(dumps_json(desc) + "\n", encoding="utf-8")
        return
    head = io.StringIO()
    csv.writer(head, lineterminator="\n").writerow(labels)
    with open(tmp, "wb") as fh:
        fh.write(head.getvalue().encode("utf-8"))
        fh.flush()
        _write_columns(fh, columns)
