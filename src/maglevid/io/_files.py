"""File-level helpers: format from the extension, safe atomic writes, source protection."""

from __future__ import annotations

import contextlib
import json
import logging
import os
import tempfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from maglevid.exceptions import DataError, FileFormatError

log = logging.getLogger(__name__)

#: Formats that can be read (``text``: a user's delimited log, read through a mapping).
READ_FORMATS = ("csv", "text", "npz", "mat", "parquet")
#: Formats that can be written (``mat``: MATLAB v5; ``mat73``: MATLAB v7.3 / HDF5).
WRITE_FORMATS = ("csv", "npz", "mat", "mat73", "parquet")

_EXTENSIONS = {
    ".csv": "csv",
    ".txt": "text",
    ".dat": "text",
    ".tsv": "text",
    ".log": "text",
    ".npz": "npz",
    ".mat": "mat",
    ".parquet": "parquet",
    ".pq": "parquet",
}


def format_from_path(path: Path, fmt: str | None, *, writing: bool) -> str:
    """The format named by ``fmt`` or, when ``None``, by the file's extension."""
    allowed = WRITE_FORMATS if writing else (*READ_FORMATS, "mat73")
    if fmt is not None:
        key = str(fmt).lower().lstrip(".")
        key = {"pq": "parquet", "txt": "text", "mat5": "mat", "mat7.3": "mat73"}.get(key, key)
        if key not in allowed:
            raise FileFormatError(
                f"unknown format {fmt!r}; expected one of {allowed}", path=str(path)
            )
        if writing and key == "text":  # pragma: no cover - excluded above
            raise FileFormatError("text logs are read-only; write 'csv'", path=str(path))
        return "mat" if (key == "mat73" and not writing) else key
    suffix = path.suffix.lower()
    if suffix == ".json":
        raise FileFormatError(
            "this looks like a metadata side-car or a mapping file, not a recording; "
            "read the .csv beside it",
            path=str(path),
        )
    if suffix not in _EXTENSIONS:
        raise FileFormatError(
            f"cannot tell the format from the extension {suffix or '(none)'!r}; known: "
            f"{sorted(_EXTENSIONS)}; pass format= (one of {allowed})",
            path=str(path),
        )
    key = _EXTENSIONS[suffix]
    if writing and key == "text":
        raise FileFormatError(
            f"{suffix} files are read through a mapping only; write .csv (with a JSON side-car), "
            ".npz, .mat or .parquet",
            path=str(path),
        )
    return key


def sidecar_path(csv_path: Path) -> Path:
    """The JSON side-car of a CSV recording: ``rec.csv`` -> ``rec.json``."""
    return csv_path.with_suffix(".json")


def _same_file(a: Path, b: Path) -> bool:
    try:
        if a.resolve() == b.resolve():
            return True
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:  # pragma: no cover - unreadable paths
        return False


def check_targets(targets: Sequence[Path], *, overwrite: bool, metadata: Any) -> None:
    """Refuse to write over an existing file (unless ``overwrite``) or over the data's source.

    The source (``metadata["source"]``, set by every reader) is protected even
    with ``overwrite=True``: a conversion must never destroy its input.
    """
    protected: list[Path] = []
    source = metadata.get("source") if hasattr(metadata, "get") else None
    if isinstance(source, str) and source:
        src = Path(source)
        protected = [src, sidecar_path(src)] if src.suffix.lower() == ".csv" else [src]
    for target in targets:
        for src in protected:
            if _same_file(target, src):
                raise FileFormatError(
                    f"refusing to write over {src}, the file this recording was read from; "
                    "choose another output path",
                    path=str(target),
                )
        if target.exists() and not overwrite:
            raise FileFormatError(
                "exists; refusing to overwrite it (pass overwrite=True, or --overwrite)",
                path=str(target),
            )
        if target.exists() and target.is_dir():
            raise FileFormatError("is a folder, not a file", path=str(target))
        if not target.parent.is_dir():
            raise FileFormatError(f"folder {target.parent} does not exist", path=str(target))


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(target: Path, *, overwrite: bool) -> Iterator[Path]:
    """Yield a temporary path in ``target``'s folder; on success move it onto ``target``.

    The temporary file is in the same folder, so the final move is an atomic
    rename (``os.replace``) on one file system: a reader never sees half a file,
    and an error leaves ``target`` untouched. Without ``overwrite`` the move is
    ``os.link`` + unlink, which fails instead of replacing a file created
    meanwhile.
    """
    fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        # mkstemp makes the file private (0600); give it the mode a plain open() would.
        os.chmod(tmp, 0o666 & ~_umask())
        if overwrite:
            os.replace(tmp, target)
        else:
            try:
                os.link(tmp, target)
            except FileExistsError:
                raise FileFormatError(
                    "appeared while writing; refusing to overwrite it", path=str(target)
                ) from None
            except OSError:  # file systems without hard links
                if target.exists():
                    raise FileFormatError(
                        "appeared while writing; refusing to overwrite it", path=str(target)
                    ) from None
                os.replace(tmp, target)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()


def write_files(
    writers: Sequence[tuple[Path, Callable[[Path], None]]], *, overwrite: bool, metadata: Any
) -> None:
    """Run each ``writer(tmp_path)`` and move the results into place, all checks first."""
    check_targets([t for t, _ in writers], overwrite=overwrite, metadata=metadata)
    for target, writer in writers:
        with atomic_path(target, overwrite=overwrite) as tmp:
            writer(tmp)
        log.info("wrote %s", target)


def check_input_units(data: Any) -> None:
    """``u = u_f + r``: channel j of u, r and u_f must share a unit (empty = unknown)."""
    sigs = [s for s in ("u", "r", "u_f") if getattr(data, s) is not None]
    for j in range(data.nu):
        seen: dict[str, str] = {}
        for s in sigs:
            unit = data.channel_units(s)[j]
            if unit:
                seen[s] = unit
        if len(set(seen.values())) > 1:
            raise DataError(
                f"input channel {j} has inconsistent units {seen}; u = u_f + r needs one unit "
                "per channel"
            )


def dumps_json(value: Any, indent: int = 2) -> str:
    """JSON with objects indented and lists of numbers or strings kept on one line.

    A matrix prints one row per line, so a side-car stays readable; the values
    are exactly those of :func:`json.dumps` (floats by ``repr``, exact).
    """

    def flat(v: Any) -> bool:
        return isinstance(v, list) and all(not isinstance(x, (list, dict)) for x in v)

    def enc(v: Any, level: int) -> str:
        pad, inner = " " * (indent * level), " " * (indent * (level + 1))
        if isinstance(v, dict):
            if not v:
                return "{}"
            items = [f"{inner}{json.dumps(str(k))}: {enc(x, level + 1)}" for k, x in v.items()]
            return "{\n" + ",\n".join(items) + "\n" + pad + "}"
        if isinstance(v, list):
            if flat(v):
                return json.dumps(v, allow_nan=True)
            rows = [inner + enc(x, level + 1) for x in v]
            return "[\n" + ",\n".join(rows) + "\n" + pad + "]"
        return json.dumps(v, allow_nan=True)

    return enc(value, 0)
