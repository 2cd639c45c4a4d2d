"""Files of named arrays: NPZ, MATLAB v5 (scipy.io) and MATLAB v7.3 (HDF5, h5py).

Native layout (what :func:`write_npz` and :func:`write_mat` produce and what a
MATLAB user can write by hand):

==========  ==============  ======================================================
variable    shape           meaning
==========  ==============  ======================================================
``y``       (N*p, ny)       outputs, time along the rows
``u``       (N, nu)         plant input (also ``r``, ``u_f``), optional
``dt``      scalar          control period in seconds (required)
``p``       scalar          output samples per control period (default 1)
``t0``      scalar          time of the first sample (default 0)
``metadata``  string        JSON description (names, units, loop, metadata)
``extra_*``   vector        extra channels named in ``metadata``
==========  ==============  ======================================================

Without ``metadata`` the channels are named ``y1, y2, ...`` and have no units;
the variable names are then compared without case (``Y``, ``U``, ``DT``) and
MATLAB's ``Ts`` is accepted for ``dt``.
Row and column vectors are one channel; a matrix with fewer rows than columns
(channels x samples) is an error unless the mapping sets ``layout``.
"""

from __future__ import annotations

import json
import logging
import time
import zipfile
from collections.abc import Callable, Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from maglevid.data import SIGNALS, ClosedLoopData
from maglevid.exceptions import FileFormatError
from maglevid.io import _native
from maglevid.io._engine import ArrayTable, assemble, oriented_width
from maglevid.io._files import describe_content, not_readable, read_head
from maglevid.io.mapping import ColumnMapping, presets_for_variables

log = logging.getLogger(__name__)

_SCALARS = ("dt", "p", "t0")


# =================================================================== reading
def _scalar(path: Path, name: str, value: Any, *, integer: bool = False) -> float:
    a = np.asarray(value)
    if a.dtype.kind not in "biuf" or a.size != 1:
        raise FileFormatError(
            f"must be a number (a 1x1 scalar); got {a.dtype} of shape {a.shape}",
            path=str(path),
            column=name,
        )
    v = float(a.reshape(-1)[0])
    if not np.isfinite(v) or (integer and (v != round(v) or v < 1)):
        raise FileFormatError(
            f"is {v!r}; expected {'an integer >= 1' if integer else 'a finite number'}",
            path=str(path),
            column=name,
        )
    return v


def _text(path: Path, name: str, value: Any) -> str:
    a = np.asarray(value)
    if isinstance(value, str):
        return value
    if a.dtype.kind == "U":
        return "".join(a.reshape(-1).tolist())
    if a.dtype.kind == "S":
        try:
            return b"".join(a.reshape(-1).tolist()).decode("utf-8")
        except UnicodeDecodeError as exc:
            raise FileFormatError(
                f"is not UTF-8 text (byte {exc.start}: {exc.reason}); maglevid metadata is "
                "UTF-8 JSON",
                path=str(path),
                column=name,
            ) from None
    raise FileFormatError(
        f"must be a JSON text string; got {a.dtype} of shape {a.shape}",
        path=str(path),
        column=name,
    )


def read_variables(
    path: Path,
    fmt: str,
    arrays: Mapping[str, Any],
    shapes: Mapping[str, tuple[int, ...]],
    mapping: ColumnMapping | None,
    *,
    matlab: bool,
) -> ClosedLoopData:
    """Shared reader of NPZ/MAT variables (native, plain, or through a mapping)."""
    if "metadata" not in arrays and not (mapping is not None and mapping.has_signals):
        arrays, shapes = _plain_names(path, arrays, shapes)
    table = ArrayTable(path, arrays, kind=fmt, matlab=matlab)
    if mapping is not None and mapping.has_signals:
        md = _native.source_metadata({}, path, fmt) | {"mapping": mapping.origin}
        return assemble(table, mapping, extra_metadata=md)

    layout_given = mapping is not None and mapping.layout != "auto"
    layout = mapping.layout if mapping is not None else "auto"
    if "metadata" in arrays:
        raw_json = _text(path, "metadata", table.load(["metadata"])["metadata"])
        try:
            raw = json.loads(raw_json)
        except json.JSONDecodeError as exc:
            raise FileFormatError(
                f"malformed maglevid metadata: not valid JSON ({exc.msg} at character {exc.pos})",
                path=str(path),
                column="metadata",
            ) from None
        desc = _native.parse_description(raw, path=str(path))
        # Scalars stored beside the JSON (for MATLAB users) must agree with it.
        for name in _SCALARS:
            if name in arrays:
                v = _scalar(path, name, table.load([name])[name], integer=name == "p")
                want = float(getattr(desc, name))
                if v != want:
                    raise FileFormatError(
                        f"is {v!r} but the metadata says {want!r}", path=str(path), column=name
                    )
        if not layout_given:
            layout = _native_layout(table, shapes, desc)
        _check_widths(table, shapes, desc, layout)
    else:
        desc = _plain_description(path, table, arrays, shapes, layout, matlab=matlab, fmt=fmt)
    native = _native.variable_mapping(desc, origin=f"{fmt} variables", present=set(arrays))
    if mapping is not None:
        native = native.with_options(mapping)
    native = replace(native, layout=layout)
    return assemble(
        table, native, extra_metadata=_native.source_metadata(desc.metadata, path, fmt)
    )


#: Names a plain file may use for a variable, compared without case: MATLAB's
#: ``Ts`` is the sample time (System Identification Toolbox, ``iddata``).
_ALIASES = {"ts": "dt"}
_PLAIN = (*SIGNALS, *_SCALARS)


def _plain_names(
    path: Path, arrays: Mapping[str, Any], shapes: Mapping[str, tuple[int, ...]]
) -> tuple[dict[str, Any], dict[str, tuple[int, ...]]]:
    """A plain file's variables under maglevid's names: ``Y``, ``U`` and ``Ts`` too.

    Two variables that mean the same (``y`` and ``Y``; ``dt`` and ``Ts``) are an
    error naming both, never a silent choice.
    """
    renamed: dict[str, str] = {}
    for name in arrays:
        key = name.lower()
        key = _ALIASES.get(key, key)
        if key in _PLAIN:
            if key in renamed:
                raise FileFormatError(
                    f"holds both {renamed[key]!r} and {name!r}, which both mean {key!r}; keep one",
                    path=str(path),
                    column=name,
                )
            renamed[key] = name
    back = {orig: key for key, orig in renamed.items()}
    return (
        {back.get(n, n): v for n, v in arrays.items()},
        {back.get(n, n): v for n, v in shapes.items()},
    )


def _native_layout(
    table: ArrayTable, shapes: Mapping[str, tuple[int, ...]], desc: _native.Description
) -> str:
    """maglevid writes time first; say so clearly if a variable is stored transposed."""
    for sig in desc.signals:
        if sig not in shapes:
            raise table.error("missing: the metadata describes it", column=sig)
        shape = shapes[sig]
        width = desc.width(sig)
        if len(shape) == 2 and shape[1] != width and shape[0] == width:
            raise table.error(
                f"has shape {shape}, but the metadata describes {width} channel(s): it is "
                "stored channels x samples. It is not transposed silently: store the "
                'transpose, or read it with a mapping {"layout": "channels_first"} (mapping= '
                "in Python, --mapping FILE.json on the command line)",
                column=sig,
            )
    return "time_first"


def _check_widths(
    table: ArrayTable,
    shapes: Mapping[str, tuple[int, ...]],
    desc: _native.Description,
    layout: str,
) -> None:
    """Each signal's variable has as many channels as the metadata names: none is dropped."""
    for sig in desc.signals:
        width = desc.width(sig)
        got = oriented_width(table, sig, shapes[sig], layout)
        if got != width:
            names = ", ".join(desc.signals[sig][0])
            dropped = " (extra channels are never dropped silently)" if got > width else ""
            raise table.error(
                f"has {got} channel(s) (shape {tuple(shapes[sig])}), but the metadata "
                f"describes {width} ({names}): the arrays and the metadata do not belong "
                f"together; was the file edited?{dropped} Store matching arrays and metadata",
                column=sig,
            )


def _plain_description(
    path: Path,
    table: ArrayTable,
    arrays: Mapping[str, Any],
    shapes: Mapping[str, tuple[int, ...]],
    layout: str,
    *,
    matlab: bool,
    fmt: str,
) -> _native.Description:
    """A file of plain variables (``y``, ``dt``, ...) without maglevid metadata."""
    missing = [k for k in ("y", "dt") if k not in arrays]
    if missing:
        shown = ", ".join(sorted(arrays)[:20])
        presets = presets_for_variables(arrays, fmt)
        hint = "".join(
            f" The preset {name!r} shipped with maglevid reads these variables: "
            f"--mapping {name} on the command line, mapping={name!r} in Python."
            for name in presets
        )
        raise FileFormatError(
            f"not a maglevid recording: no variable(s) {missing} (it has: {shown}).{hint} A "
            "recording holds y (samples x channels), dt and optionally u, r, u_f, p, t0; "
            "to import other variables, read the file through a column mapping (--mapping "
            "FILE.json or a preset name on the command line, mapping= in Python; see "
            "docs/recording-format.md)",
            path=str(path),
            column=missing[0],
        )
    loaded = table.load([k for k in _SCALARS if k in arrays])
    dt = _scalar(path, "dt", loaded["dt"])
    if dt <= 0:
        raise FileFormatError(
            f"is {dt!r}; expected a positive number", path=str(path), column="dt"
        )
    p = int(_scalar(path, "p", loaded["p"], integer=True)) if "p" in loaded else 1
    t0 = _scalar(path, "t0", loaded["t0"]) if "t0" in loaded else 0.0
    signals = {}
    for sig in SIGNALS:
        if sig in arrays:
            w = oriented_width(table, sig, shapes[sig], layout)
            signals[sig] = (tuple(f"{sig}{j + 1}" for j in range(w)), ("",) * w)
    return _native.Description(
        dt=dt,
        p=p,
        t0=t0,
        n_samples=None,
        signals=signals,
        loop={},
        metadata={},
        extras=(),
    )


# ---------------------------------------------------------------- NPZ
def _npy_shape(npz: Any, name: str) -> tuple[int, ...]:
    """Shape of an NPZ member from its header, without loading the data."""
    with npz.zip.open(f"{name}.npy") as fh:
        version = np.lib.format.read_magic(fh)
        if version == (1, 0):
            shape, _, _ = np.lib.format.read_array_header_1_0(fh)
        else:
            shape, _, _ = np.lib.format.read_array_header_2_0(fh)
    return tuple(shape)


def _check_zip(path: Path) -> None:
    """An NPZ file is a zip archive; anything else is named, never handed to ``np.load``.

    ``np.load`` takes any other file for pickled data and advises loading it
    unsafely; that advice must never reach a user.
    """
    head = read_head(path)
    if head.startswith(b"\x93NUMPY"):
        raise FileFormatError(
            "is a single .npy array, not an NPZ archive of named arrays (y, dt, ...); save "
            "it with numpy.savez(file, y=..., dt=...)",
            path=str(path),
        )
    if not head.startswith((b"PK\x03\x04", b"PK\x05\x06")):
        raise FileFormatError(
            "is not an NPZ archive (NPZ files are zip archives of .npy arrays): it looks like "
            f"{describe_content(head)}",
            path=str(path),
        )


def read_npz(path: Path, mapping: ColumnMapping | None) -> ClosedLoopData:
    _check_zip(path)
    try:
        npz = np.load(path, allow_pickle=False)
    except (zipfile.BadZipFile, ValueError, OSError, EOFError) as exc:
        why = "" if "pickle" in str(exc) else f": {exc}"
        raise FileFormatError(
            f"is a damaged NPZ archive (truncated or corrupted zip){why}", path=str(path)
        ) from None
    with npz:
        cache: dict[str, np.ndarray] = {}

        def loader(name: str) -> Callable[[], np.ndarray]:
            def load() -> np.ndarray:
                if name not in cache:
                    try:
                        cache[name] = npz[name]
                    except ValueError:  # object arrays need pickle: refused
                        raise FileFormatError(
                            "holds Python objects (a pickled object array), not numbers; "
                            "maglevid never loads pickled data (loading it can run code): "
                            "save plain numeric arrays",
                            path=str(path),
                            column=name,
                        ) from None
                return cache[name]

            return load

        arrays = {name: loader(name) for name in npz.files}
        try:
            shapes = {name: _npy_shape(npz, name) for name in npz.files}
        except (KeyError, ValueError, OSError, zipfile.BadZipFile) as exc:
            raise FileFormatError(
                f"is a damaged NPZ archive (a member is not a readable .npy array: {exc})",
                path=str(path),
            ) from None
        return read_variables(path, "npz", arrays, shapes, mapping, matlab=False)


def write_npz(data: ClosedLoopData, tmp: Path) -> None:
    out = _variables_of(data)
    with open(tmp, "wb") as fh:
        np.savez(fh, **out)


def _variables_of(data: ClosedLoopData) -> dict[str, Any]:
    desc = _native.describe(data)
    out: dict[str, Any] = {s: np.asarray(getattr(data, s)) for s in data.signals()}
    out["dt"] = np.float64(data.dt)
    out["p"] = np.float64(data.p)  # MATLAB's default class; read back as an integer
    out["t0"] = np.float64(data.t0)
    out["metadata"] = np.str_(json.dumps(desc, allow_nan=True))
    values = {e[0]: e[3] for e in _native.extra_signals(data)}
    for e in desc["extra_signals"]:
        out[e["key"]] = np.asarray(values[e["name"]], dtype=float)
    return out


# ---------------------------------------------------------------- MAT
def _is_hdf5(path: Path) -> bool:
    try:
        with open(path, "rb") as fh:
            head = fh.read(128)
            fh.seek(512)
            sig = fh.read(8)
    except OSError as exc:
        raise FileFormatError(f"cannot be read: {exc}", path=str(path)) from None
    return head.startswith(b"MATLAB 7.3") or sig == b"\x89HDF\r\n\x1a\n"


def read_mat(path: Path, mapping: ColumnMapping | None) -> ClosedLoopData:
    if _is_hdf5(path):
        return _read_mat73(path, mapping)
    import scipy.io as sio

    try:
        info = sio.whosmat(str(path))
    except Exception as exc:  # scipy raises several types for a broken file
        raise not_readable(path, "MATLAB .mat file (v4/v5/v7 or v7.3)", "mat", exc) from None
    shapes = {name: tuple(shape) for name, shape, _ in info}
    classes = {name: cls for name, _, cls in info}
    cache: dict[str, Any] = {}

    def loader(name: str) -> Callable[[], Any]:
        def load() -> Any:
            if name not in cache:
                if classes[name] in ("struct", "cell", "object", "sparse"):
                    raise FileFormatError(
                        f"is a MATLAB {classes[name]}, not a numeric array; store plain "
                        "matrices (or name the fields in a mapping)",
                        path=str(path),
                        column=name,
                    )
                try:
                    m = sio.loadmat(str(path), variable_names=[name], chars_as_strings=True)
                except Exception as exc:
                    raise FileFormatError(
                        f"cannot be read: {exc}", path=str(path), column=name
                    ) from None
                cache[name] = m[name]
            return cache[name]

        return load

    arrays = {name: loader(name) for name in shapes}
    return read_variables(path, "mat", arrays, shapes, mapping, matlab=True)


def _read_mat73(path: Path, mapping: ColumnMapping | None) -> ClosedLoopData:
    try:
        import h5py
    except ModuleNotFoundError:  # pragma: no cover - h5py is an optional extra
        raise FileFormatError(
            "is a MATLAB v7.3 (HDF5) file; reading it needs h5py (pip install 'maglevid[mat73]')",
            path=str(path),
        ) from None
    try:
        fh = h5py.File(path, "r")
    except OSError as exc:
        raise FileFormatError(
            f"not a readable MATLAB v7.3 (HDF5) file: {exc}", path=str(path)
        ) from None
    with fh:
        shapes: dict[str, tuple[int, ...]] = {}
        arrays: dict[str, Callable[[], Any]] = {}
        for name, obj in fh.items():
            if name.startswith("#"):
                continue  # MATLAB's #refs# / #subsystem# groups
            if isinstance(obj, h5py.Dataset):
                # MATLAB is column-major: an (N x 3) variable is stored as HDF5 shape (3, N).
                shapes[name] = tuple(obj.shape[::-1])
            else:
                shapes[name] = ()
            arrays[name] = _mat73_loader(path, name, obj, h5py)
        return read_variables(path, "mat73", arrays, shapes, mapping, matlab=True)


def _attr_text(value: Any) -> str:
    if isinstance(value, bytes):
        return value.decode("ascii", "replace")
    if isinstance(value, np.ndarray):
        return _attr_text(value.reshape(-1)[0]) if value.size else ""
    return str(value)


#: MATLAB classes stored as plain HDF5 datasets of numbers (char: UTF-16 code units).
_MAT73_CLASSES = {
    "double",
    "single",
    "logical",
    "char",
    *(f"{s}int{b}" for s in ("", "u") for b in (8, 16, 32, 64)),
}


def _mat73_loader(path: Path, name: str, obj: Any, h5py: Any) -> Callable[[], Any]:
    def load() -> Any:
        cls = _attr_text(obj.attrs.get("MATLAB_class", b""))
        if not isinstance(obj, h5py.Dataset) or (cls and cls not in _MAT73_CLASSES):
            # struct, cell, string, sparse, objects: stored as groups or references.
            raise FileFormatError(
                f"is a MATLAB {cls or 'group'}, not a numeric array", path=str(path), column=name
            )
        if obj.attrs.get("MATLAB_empty", 0):
            # MATLAB stores an empty matrix's dimensions as its data (e.g. [0, 3]).
            dims = tuple(int(d) for d in np.asarray(obj[()]).reshape(-1))
            return np.zeros(dims if len(dims) == 2 and 0 in dims else (0,))
        data = obj[()]
        if data.dtype.names:  # compound: complex numbers
            raise FileFormatError(
                "holds complex numbers; a recording's signals must be real. Store the real "
                "part (real(x) in MATLAB) or whichever real quantity was measured",
                path=str(path),
                column=name,
            )
        if cls == "char":
            return "".join(map(chr, np.asarray(data).T.reshape(-1).tolist()))
        return np.asarray(data).T

    return load


def write_mat(data: ClosedLoopData, tmp: Path) -> None:
    """MATLAB v5 (``save -v7`` without compression readable by every MATLAB and Octave)."""
    import scipy.io as sio

    out = _variables_of(data)
    out["metadata"] = str(out["metadata"])
    for key, value in out.items():
        if isinstance(value, np.ndarray) and value.nbytes >= 2**31:
            raise FileFormatError(
                f"variable {key!r} is {value.nbytes / 2**30:.1f} GiB, over the 2 GiB limit of "
                "MAT v5; write MATLAB v7.3 (HDF5) instead: format='mat73' in Python, "
                "--to mat73 with maglevid convert",
                path=str(tmp),
            )
    with open(tmp, "wb") as fh:
        sio.savemat(fh, out, oned_as="column", do_compression=False)


def write_mat73(data: ClosedLoopData, tmp: Path) -> None:
    """MATLAB v7.3: an HDF5 file with MATLAB's 512-byte header and class attributes.

    Layout as MATLAB writes it (and hdf5storage documents): a 512-byte user
    block whose first 128 bytes are the text header (116 bytes, space padded),
    8 bytes of subsystem offset (zero), the version 0x0200 and the endian
    indicator ``IM``; every variable is a dataset with a ``MATLAB_class``
    attribute, stored transposed (MATLAB is column-major); text is ``char``:
    UTF-16 code units with ``MATLAB_int_decode = 2``.
    """
    try:
        import h5py
    except ModuleNotFoundError:  # pragma: no cover - optional extra
        raise FileFormatError(
            "writing MATLAB v7.3 needs h5py (pip install 'maglevid[mat73]')", path=str(tmp)
        ) from None
    out = _variables_of(data)
    with h5py.File(tmp, "w", userblock_size=512) as fh:
        for key, value in out.items():
            if key == "metadata":
                codes = np.frombuffer(str(value).encode("utf-16-le"), dtype="<u2")
                ds = fh.create_dataset(key, data=codes.reshape(-1, 1))
                ds.attrs["MATLAB_class"] = np.bytes_(b"char")
                ds.attrs["MATLAB_int_decode"] = np.int32(2)
                continue
            a = np.asarray(value, dtype=float)
            a = a.reshape(1, 1) if a.ndim == 0 else (a[:, None] if a.ndim == 1 else a)
            ds = fh.create_dataset(key, data=np.ascontiguousarray(a.T))
            ds.attrs["MATLAB_class"] = np.bytes_(b"double")
    stamp = time.strftime("%a %b %d %H:%M:%S %Y", time.gmtime())
    head = f"MATLAB 7.3 MAT-file, Platform: maglevid, Created on: {stamp} HDF5 schema 1.00 ."
    block = head.encode("ascii").ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02IM"
    with open(tmp, "r+b") as fh:
        fh.write(block)
