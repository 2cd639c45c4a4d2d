"""Helpers of the file tests: recordings to round-trip and users' files in every format."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from maglevid.data import ClosedLoopData

#: Formats a user's own file may come in (each read through a mapping).
USER_FORMATS = ("csv", "tsv", "npz", "mat", "mat73", "parquet")
#: Formats with a row per output sample (inputs held over each control period).
ROW_FORMATS = ("csv", "tsv", "parquet")


def full_recording(rng: np.random.Generator, *, p: int = 3, n: int = 40) -> ClosedLoopData:
    """Every signal, names, units, a nested loop with matrices, extras at both rates."""
    return ClosedLoopData(
        y=rng.standard_normal((n * p, 2)),
        u=rng.standard_normal((n, 2)),
        r=rng.standard_normal((n, 2)),
        u_f=rng.standard_normal((n, 2)),
        dt=1e-3 / 3,
        p=p,
        t0=12.25,
        names={"y": ["gap", "i, coil"], "u": ["v1", "v2"], "r": ["v1", "v2"], "u_f": ["v1", "v2"]},
        units={"y": ["m", "A"], "u": ["V", "V"], "r": ["V", ""], "u_f": ["V", "V"]},
        loop={
            "controller": {
                "K": rng.standard_normal((2, 4)).tolist(),
                "observer": {"L": [[0.1], [0.2], [1 / 3], [-0.0]], "kind": "deadbeat"},
                "name": "state feedback",
            },
            "x_op": [0.0005, 0.5],
            "order": 4,
        },
        metadata={
            "machine": 'rig "7", bay 2',
            "tags": ["axis-x", "ü-umlaut"],
            "nested": {"a": {"b": 1.5e-300}},
            "extra_signals": {
                "ref": {"unit": "m", "rate": "control", "values": rng.standard_normal(n)},
                "temp": {"unit": "degC", "rate": "output", "values": rng.standard_normal(n * p)},
            },
        },
    )


def tricky_values(rng: np.random.Generator) -> ClosedLoopData:
    """Values that expose lossy float printing: -0, subnormals, huge, 1/3, large t0."""
    y = np.array([-0.0, 5e-324, 1e300, 1 / 3, 2.5e-7, -1e-320, 123456789.123456789, 0.1])
    return ClosedLoopData(y=np.column_stack([y, y[::-1]]), u=y[::-1], dt=1 / 2700, t0=1.7e9)


RECORDINGS: dict[str, Callable[[np.random.Generator], ClosedLoopData]] = {
    "full_p3": full_recording,
    "full_p1": lambda rng: full_recording(rng, p=1),
    "y_only": lambda rng: ClosedLoopData(y=rng.standard_normal(5), dt=0.5),
    "y_u_p2_no_names": lambda rng: ClosedLoopData(
        y=rng.standard_normal((20, 3)), u=rng.standard_normal((10, 1)), dt=0.01, p=2
    ),
    "u_f_and_r_only": lambda rng: ClosedLoopData(
        y=rng.standard_normal((6, 1)),
        r=rng.standard_normal((6, 1)),
        u_f=rng.standard_normal((6, 1)),
        dt=2e-4,
    ),
    "tricky_values": tricky_values,
}


def assert_same_recording(back: ClosedLoopData, data: ClosedLoopData) -> None:
    """Exactly equal signals (bit for bit, sign of zero too), timing, labels, loop, metadata."""
    assert back.signals() == data.signals()
    for sig in data.signals():
        a, b = getattr(back, sig), getattr(data, sig)
        assert a.shape == b.shape
        assert np.array_equal(a, b), sig
        assert np.array_equal(np.signbit(a), np.signbit(b)), sig
    assert (back.dt, back.p, back.t0) == (data.dt, data.p, data.t0)
    for sig in data.signals():
        assert back.channel_names(sig) == data.channel_names(sig)
        assert back.channel_units(sig) == data.channel_units(sig)
    d_back, d_data = back.to_dict(), data.to_dict()
    assert d_back["loop"] == d_data["loop"]
    meta_back = {
        k: v
        for k, v in d_back["metadata"].items()
        if k not in ("source", "source_format", "converted_from")
    }
    assert meta_back == d_data["metadata"]


# ---------------------------------------------------------------- user files
def _write_mat73(path: Path, variables: Mapping[str, np.ndarray]) -> None:
    """A MATLAB v7.3 file written by hand with h5py, as MATLAB lays it out."""
    import h5py

    with h5py.File(path, "w", userblock_size=512) as fh:
        for name, value in variables.items():
            a = np.asarray(value, dtype=float)
            a = a[:, None] if a.ndim == 1 else a
            ds = fh.create_dataset(name, data=a.T)  # MATLAB is column-major
            ds.attrs["MATLAB_class"] = np.bytes_(b"double")
    head = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: test HDF5 schema 1.00 ."
    with open(path, "r+b") as fh:
        fh.write(head.ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02IM")


def write_user_file(
    folder: Path,
    fmt: str,
    columns: Mapping[str, np.ndarray],
    *,
    units: Mapping[str, str] | None = None,
    name: str = "log",
) -> tuple[Path, dict[str, Any]]:
    """Write ``columns`` as a user would in ``fmt``; return the path and the mapping keys
    a reader needs besides the channels (text options for header-less files)."""
    units = dict(units or {})
    names = list(columns)
    arrays = [np.asarray(columns[n], dtype=float) for n in names]
    if fmt in ("csv", "tsv"):
        rows = np.column_stack(arrays) if arrays[0].size else np.empty((0, len(arrays)))
        body = "\n".join(
            ("," if fmt == "csv" else "\t").join(repr(float(v)) for v in row) for row in rows
        )
        if fmt == "csv":
            header = ",".join(f"{n} [{units[n]}]" if n in units else n for n in names)
            path = folder / f"{name}.csv"
            path.write_text(header + "\n" + body + "\n", encoding="utf-8")
            return path, {}
        path = folder / f"{name}.tsv"
        path.write_text("# exported by the rig\n# Ts: see below\n" + body + "\n", encoding="utf-8")
        return path, {"columns": names, "text": {"delimiter": "tab", "header": False}}
    if fmt == "npz":
        path = folder / f"{name}.npz"
        np.savez(path, **dict(zip(names, arrays)))
        return path, {}
    if fmt == "mat":
        import scipy.io as sio

        path = folder / f"{name}.mat"
        sio.savemat(path, dict(zip(names, arrays)), oned_as="column")
        return path, {}
    if fmt == "mat73":
        path = folder / f"{name}.mat"
        _write_mat73(path, dict(zip(names, arrays)))
        return path, {}
    if fmt == "parquet":
        import pyarrow as pa
        import pyarrow.parquet as pq

        fields = [
            pa.field(n, pa.float64(), metadata={"unit": units[n]} if n in units else None)
            for n in names
        ]
        table = pa.Table.from_arrays([pa.array(a) for a in arrays], schema=pa.schema(fields))
        path = folder / f"{name}.parquet"
        pq.write_table(table, path, row_group_size=7)
        return path, {}
    raise AssertionError(fmt)


def user_columns(n: int = 12, *, dt: float = 0.01, p: int = 1) -> dict[str, np.ndarray]:
    """A plain log: time, a gap, a coil voltage held over each control period, a 2nd input."""
    k = np.arange(n * p)
    return {
        "t": k * (dt / p),
        "gap": 1e-3 + 1e-5 * np.sin(k),
        "v": np.repeat(np.cos(np.arange(n)), p),
        "w": np.repeat(np.linspace(0, 1, n), p),
    }
