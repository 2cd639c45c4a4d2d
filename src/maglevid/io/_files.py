"""File-level helpers: format from the extension, safe atomic writes, source protection."""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import stat
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


#: How users choose a format, in the Python API and on the command line.
_FORMAT_HOW = {
    False: "rename it, or format= in Python, --format with maglevid inspect and convert",
    True: "format= in Python, --to with maglevid convert",
}


def format_from_path(path: Path, fmt: str | None, *, writing: bool) -> str:
    """The format named by ``fmt`` or, when ``None``, by the file's extension.

    A folder is refused first, whatever its name: it is not a recording.
    """
    allowed = WRITE_FORMATS if writing else (*READ_FORMATS, "mat73")
    if path.is_dir():
        raise FileFormatError(
            "is a folder, not a file; give the path of the file to write"
            if writing
            else "is a folder, not a recording; give the path of a recording file in it",
            path=str(path),
        )
    if fmt is not None:
        key = str(fmt).lower().lstrip(".")
        key = {"pq": "parquet", "txt": "text", "mat5": "mat", "mat7.3": "mat73"}.get(key, key)
        if key not in allowed:
            raise FileFormatError(
                f"unknown format {fmt!r}; expected one of {', '.join(allowed)}", path=str(path)
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
            f"{', '.join(sorted(_EXTENSIONS))}. Name the format, one of "
            f"{', '.join(allowed)} ({_FORMAT_HOW[writing]})",
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


#: Signatures of binary files a user may hand over by mistake: (offset, bytes,
#: what it is, the format that reads it or ``None``). HDF5 sits at byte 512 in a
#: MATLAB v7.3 file (after MATLAB's text header).
_MAGIC: tuple[tuple[int, bytes, str, str | None], ...] = (
    (0, b"PK\x03\x04", "an NPZ/zip archive", "npz"),
    (0, b"PK\x05\x06", "an empty zip archive", None),
    (0, b"\x93NUMPY", "a single NumPy .npy array (not an NPZ archive of named arrays)", None),
    (0, b"MATLAB 7.3 MAT-file", "a MATLAB v7.3 .mat file", "mat"),
    (0, b"MATLAB 5.0 MAT-file", "a MATLAB .mat file", "mat"),
    (0, b"\x89HDF\r\n\x1a\n", "an HDF5 file (a MATLAB v7.3 .mat?)", "mat"),
    (512, b"\x89HDF\r\n\x1a\n", "a MATLAB v7.3 .mat (HDF5) file", "mat"),
    (0, b"PAR1", "a Parquet file", "parquet"),
    (0, b"\x1f\x8b", "a gzip-compressed file (decompress it first)", None),
    (0, b"\xfd7zXZ\x00", "an xz-compressed file (decompress it first)", None),
    (0, b"%PDF", "a PDF document", None),
)

#: Bytes read to tell what a file holds.
SNIFF_BYTES = 8192


def read_head(path: Path, n: int = SNIFF_BYTES) -> bytes:
    """The first ``n`` bytes of ``path`` (an unreadable file is a :class:`FileFormatError`)."""
    try:
        with open(path, "rb") as fh:
            return fh.read(n)
    except OSError as exc:
        raise FileFormatError(f"cannot be read: {exc.strerror or exc}", path=str(path)) from None


def known_binary(head: bytes) -> tuple[str, str | None] | None:
    """``(what it is, format that reads it)`` when ``head`` starts a known binary file.

    A signature that is plain text (``PAR1``, ``MATLAB 5.0 MAT-file``) counts
    only with a NUL byte in ``head`` too: a text log may well begin "PAR1,PAR2".
    """
    for offset, magic, what, fmt in _MAGIC:
        if head[offset : offset + len(magic)] == magic:
            if magic.isascii() and magic.decode().isprintable() and b"\x00" not in head:
                continue
            return what, fmt
    return None


def read_as(fmt: str) -> str:
    """How to read a file as ``fmt``, in the Python API and on the command line."""
    # identify, diagnose and plan take no --format (found from outside, seventeenth
    # session: the hint named an option they refuse); inspect and convert do
    return (
        f"read it as {fmt} (rename it to .{fmt}, or name the format: format={fmt!r} in "
        f"Python; on the command line `maglevid convert FILE OUT.{fmt} --format {fmt}` "
        "writes a copy the other commands read)"
    )


def describe_content(head: bytes) -> str:
    """What the first bytes of a file look like, for messages: a known format, text or binary.

    Examples
    --------
    >>> describe_content(b"t,y\n0,1\n")
    'text (a CSV or text log?)'
    >>> describe_content(bytes(range(256)))
    'binary data of an unknown kind'
    """
    known = known_binary(head)
    if known is not None:
        what, fmt = known
        return what if fmt is None else f"{what}: {read_as(fmt)}"
    if not head:
        return "an empty file (0 bytes)"
    if head.startswith((b"\xff\xfe", b"\xfe\xff")):
        return "UTF-16 text"
    if b"\x00" in head:
        return "binary data of an unknown kind"
    controls = sum(b < 32 and b not in b"\t\n\r\f\x1a" for b in head)
    if controls > len(head) // 100:
        return "binary data of an unknown kind"
    return "text (a CSV or text log?)"


def not_readable(path: Path, what: str, fmt: str, exc: Exception) -> FileFormatError:
    """A file the reader of ``fmt`` failed on: damaged, or another kind of file (which)."""
    head = read_head(path)
    known = known_binary(head)
    if known is not None and known[1] == fmt:
        return FileFormatError(
            f"not a readable {what}: it starts like one but is damaged or truncated ({exc})",
            path=str(path),
        )
    looks = describe_content(head)
    detail = f" ({exc})" if looks.startswith("binary") else ""
    return FileFormatError(f"not a readable {what}{detail}: it looks like {looks}", path=str(path))


def sidecar_path(csv_path: Path) -> Path:
    """The JSON side-car of a CSV recording: ``rec.csv`` -> ``rec.json``."""
    return csv_path.with_suffix(".json")


def check_input_file(path: str | os.PathLike[str], *, what: str = "recording") -> Path:
    """Refuse, before opening it, anything but a regular file: a read must never block.

    A FIFO, a character or block device or a socket would make a read wait
    forever (or read without end); a folder is not a recording either.

    Raises
    ------
    FileNotFoundError
        No such file.
    FileFormatError
        A folder or a special file; the message says which.
    """
    p = Path(path)
    try:
        mode = os.stat(p).st_mode
    except FileNotFoundError:
        raise FileNotFoundError(f"{p}: no such file") from None
    except OSError as exc:
        raise FileFormatError(f"cannot be read: {exc.strerror or exc}", path=str(p)) from None
    if stat.S_ISREG(mode):
        return p
    if stat.S_ISDIR(mode):
        raise FileFormatError(f"is a folder, not a {what}", path=str(p))
    kind = (
        "a FIFO (named pipe)"
        if stat.S_ISFIFO(mode)
        else "a socket"
        if stat.S_ISSOCK(mode)
        else "a device"
        if stat.S_ISCHR(mode) or stat.S_ISBLK(mode)
        else "not a regular file"
    )
    raise FileFormatError(
        f"is {kind}, not a {what} file; refusing to read it (a read could block forever). "
        "Copy the data to a regular file first",
        path=str(p),
    )


def _same_file(a: Path, b: Path) -> bool:
    try:
        if a.resolve() == b.resolve():
            return True
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:  # pragma: no cover - unreadable paths
        return False


def protected_paths(sources: Sequence[str | os.PathLike[str] | None]) -> list[Path]:
    """The files a writer must never replace: each input and, for a CSV, its JSON side-car."""
    out: list[Path] = []
    for source in sources:
        if source is None or not str(source) or "://" in str(source):
            continue  # nothing, or a database URL
        src = Path(source)
        out.append(src)
        if src.suffix.lower() == ".csv":
            out.append(sidecar_path(src))
    return out


def check_output(
    target: str | os.PathLike[str],
    *,
    overwrite: bool = False,
    inputs: Sequence[str | os.PathLike[str] | None] = (),
) -> Path:
    """Check that ``target`` may be written; the rule every writer of maglevid follows.

    A target is refused when it is one of ``inputs`` or the side-car of one
    (even with ``overwrite``: an output never destroys what it was made
    from), when it exists and ``overwrite`` is false, when it is a folder or
    a special file, or when its folder does not exist.

    Returns
    -------
    Path
        ``target`` as a :class:`~pathlib.Path`.

    Raises
    ------
    FileFormatError
        One of the cases above; the message names the file and the way out.
    """
    target = Path(target)
    for src in protected_paths(inputs):
        if _same_file(target, src):
            raise FileFormatError(
                f"refusing to write over {src}: it is an input (the file this recording was "
                "read from, its side-car, or another file this command reads); choose another "
                "output path",
                path=str(target),
            )
    if target.exists() and not target.is_file():
        kind = "a folder" if target.is_dir() else "a special file (FIFO, device or socket)"
        raise FileFormatError(f"is {kind}, not a file", path=str(target))
    if target.exists() and not overwrite:
        raise FileFormatError(
            "exists; refusing to overwrite it (overwrite=True in Python, --overwrite on the "
            "command line)",
            path=str(target),
        )
    if not target.parent.is_dir():
        raise FileFormatError(f"folder {target.parent} does not exist", path=str(target))
    return target


def check_targets(targets: Sequence[Path], *, overwrite: bool, metadata: Any) -> None:
    """:func:`check_output` for each target, the data's source (``metadata["source"]``) protected.

    The source, set by every reader, is protected even with ``overwrite=True``:
    a conversion must never destroy its input.
    """
    source = metadata.get("source") if hasattr(metadata, "get") else None
    inputs = [source] if isinstance(source, str) and source else []
    for target in targets:
        check_output(target, overwrite=overwrite, inputs=inputs)


def write_output(
    target: str | os.PathLike[str],
    content: str | bytes | Callable[[Path], None],
    *,
    overwrite: bool = False,
    inputs: Sequence[str | os.PathLike[str] | None] = (),
) -> Path:
    """Write ``content`` to ``target`` by the recording writers' rules.

    :func:`check_output` first, then an atomic write (:func:`atomic_path`): a
    reader never sees half a file, and a failed write (disk full, file too
    large) leaves ``target`` as it was and no temporary file behind.
    ``content`` is text (UTF-8), bytes, or a function that writes the file
    at the path it is given.

    Returns
    -------
    Path
        The path written.

    Examples
    --------
    >>> import pathlib, tempfile
    >>> out = write_output(pathlib.Path(tempfile.mkdtemp()) / "a.txt", "hello")
    >>> try:
    ...     write_output(out, "again")
    ... except FileFormatError as exc:
    ...     print(str(exc).split(": ", 1)[1])
    exists; refusing to overwrite it (overwrite=True in Python, --overwrite on the command line)
    """
    target = check_output(target, overwrite=overwrite, inputs=inputs)
    with atomic_path(target, overwrite=overwrite) as tmp:
        if isinstance(content, str):
            tmp.write_text(content, encoding="utf-8")
        elif isinstance(content, bytes):
            tmp.write_bytes(content)
        else:
            content(tmp)
    log.info("wrote %s", target)
    return target


#: errno values of a write that ran out of room: the message says so.
_NO_ROOM = {errno.ENOSPC: "no space left on the device", errno.EFBIG: "file too large"}
if hasattr(errno, "EDQUOT"):
    _NO_ROOM[errno.EDQUOT] = "disk quota exceeded"


def _write_error(target: Path, exc: OSError) -> FileFormatError:
    """One clear line for a failed write; nothing was written to ``target``."""
    why = _NO_ROOM.get(exc.errno or -1, exc.strerror or str(exc))
    return FileFormatError(
        f"could not be written ({why}); nothing was written and the file, if it existed, "
        "is unchanged",
        path=str(target),
    )


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
    try:
        fd, tmp_name = tempfile.mkstemp(
            prefix=f".{target.name}.", suffix=".tmp", dir=target.parent
        )
    except OSError as exc:
        raise _write_error(target, exc) from None
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        try:
            yield tmp
        except OSError as exc:
            raise _write_error(target, exc) from None
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
