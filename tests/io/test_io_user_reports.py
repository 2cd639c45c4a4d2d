"""Messages for the wrong files users hand to ``maglevid inspect``/``read_recording``.

Reference: the defects found by running the CLI as a user (random bytes or a
text file named ``.npz``; an NPZ renamed ``.csv``; a folder; Python-only
wording; an empty or complex MATLAB matrix; extra data dropped silently; the
Maggy record without its preset). Each test reproduces one user's file and
asserts what the one error line says: what is wrong with the file and what to
do, in words that serve both the Python API and the command line (the CLI
prints ``str(exc)``). The expected texts are the specification of each fix.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from _io_helpers import RECORDINGS, _write_mat73, full_recording, write_user_file

from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError, FileFormatError
from maglevid.io import check_output, read_recording, write_recording


def read_bad(path: Path, **kw) -> str:
    """Read ``path`` expecting one FileFormatError naming it; return the message."""
    with pytest.raises(FileFormatError) as err:
        read_recording(path, **kw)
    exc = err.value
    assert isinstance(exc, DataError) and Path(str(exc.path)).name == Path(path).name
    message = str(exc)
    # Never numpy's advice to load pickled data, never Python-only wording alone.
    assert "allow_pickle" not in message and "unsafely" not in message
    assert "pass mapping=" not in message and "pass format=" not in message
    return message


@pytest.fixture
def native_npz(tmp_path, rng) -> Path:
    data = ClosedLoopData(y=rng.standard_normal((50, 3)), u=rng.standard_normal((50, 2)), dt=0.01)
    return write_recording(data, tmp_path / "rec.npz")


# ------------------------------------------------- 1. not an NPZ archive
def test_random_bytes_named_npz(tmp_path, rng):
    path = tmp_path / "random.npz"
    path.write_bytes(rng.bytes(5000))
    message = read_bad(path)
    assert "is not an NPZ archive (NPZ files are zip archives of .npy arrays)" in message
    assert "it looks like binary data of an unknown kind" in message


def test_text_file_named_npz_and_csv_read_as_npz(tmp_path, rng):
    path = tmp_path / "text.npz"
    path.write_text("t,y\n0,1\n0.1,2\n")
    message = read_bad(path)
    assert "is not an NPZ archive" in message and "it looks like text" in message
    csv = write_recording(RECORDINGS["full_p1"](rng), tmp_path / "rec.csv")
    message = read_bad(csv, format="npz")
    assert "is not an NPZ archive" in message and "it looks like text" in message


def test_npy_named_npz_and_object_arrays(tmp_path):
    path = tmp_path / "single.npz"
    with open(path, "wb") as fh:
        np.save(fh, np.arange(10.0))
    assert "is a single .npy array, not an NPZ archive" in read_bad(path)
    # An object array needs pickle to load: refused without numpy's advice to unpickle it.
    path = tmp_path / "objects.npz"
    np.savez(path, y=np.array([{"a": 1}, None], dtype=object), dt=np.float64(0.1))
    message = read_bad(path)
    assert "column 'y': holds Python objects (a pickled object array), not numbers" in message


# ------------------------------------------------- 2. binary file read as text
def test_npz_renamed_csv_with_and_without_sidecar(tmp_path, native_npz):
    path = tmp_path / "binary.csv"
    path.write_bytes(native_npz.read_bytes())
    for _ in range(2):  # without, then with a side-car
        message = read_bad(path)
        assert "is a binary file, not text: it looks like an NPZ/zip archive" in message
        assert "format='npz' in Python" in message
        # identify/diagnose have no --format: the hint names the command that has it
        assert "`maglevid convert FILE OUT.npz --format npz`" in message
        assert "decoded" not in message and "latin-1" not in message
        (tmp_path / "binary.json").write_text("{}")
    # ... and through a user's mapping (the encoding hint would mislead here too).
    message = read_bad(path, mapping={"dt": 0.01, "y": [0]})
    assert "is a binary file, not text" in message and "NPZ/zip archive" in message


def test_mat_files_and_unknown_binary_read_as_text(tmp_path, rng):
    import scipy.io as sio

    v5 = tmp_path / "v5.csv"
    sio.savemat(v5, {"y": np.arange(5.0), "dt": 0.1})
    assert "it looks like a MATLAB .mat file: read it as mat" in read_bad(v5)
    v73 = tmp_path / "v73.txt"
    _write_mat73(v73, {"y": np.arange(5.0)})
    message = read_bad(v73, mapping={"dt": 0.1, "y": [0]})
    assert "it looks like a MATLAB v7.3 .mat file: read it as mat" in message
    blob = tmp_path / "blob.csv"
    blob.write_bytes(rng.bytes(3000) + b"\x00")
    message = read_bad(blob)
    assert "is a binary file, not text (it has NUL bytes in its first 8192 bytes)" in message


def test_utf16_text_is_not_called_binary(tmp_path):
    # UTF-16 text has NUL bytes; with its encoding declared it reads as text.
    path = tmp_path / "log.txt"
    path.write_bytes("t y\n0 1\n0.1 2\n0.2 4\n".encode("utf-16"))
    assert 'set the mapping\'s text.encoding to "utf-16"' in read_bad(
        path, mapping={"time": "t", "y": ["y"]}
    )
    m = {"time": "t", "y": ["y"], "text": {"encoding": "utf-16"}}
    assert read_recording(path, mapping=m).y[:, 0].tolist() == [1.0, 2.0, 4.0]


def test_text_starting_like_a_signature_is_text(tmp_path):
    # "PAR1" is Parquet's signature, and a fine name for a log's first column.
    path = tmp_path / "log.csv"
    path.write_text("PAR1,gap\n0,1\n0.1,2\n0.2,3\n")
    assert read_recording(path, mapping={"time": "PAR1", "y": ["gap"]}).n_samples == 3


def test_files_read_as_the_wrong_binary_format_name_the_right_one(tmp_path, native_npz):
    message = read_bad(native_npz, format="mat")
    assert "not a readable MATLAB .mat file" in message and "looks like an NPZ/zip" in message
    message = read_bad(native_npz, format="parquet")
    assert "not a readable Parquet file" in message and "--format npz" in message


# ------------------------------------------------- 3. a folder
@pytest.mark.parametrize("name", ["recordings", "dir.npz", "run.json"])
def test_folder_is_named_before_the_extension(tmp_path, name):
    folder = tmp_path / name
    folder.mkdir()
    message = read_bad(folder)
    assert "is a folder, not a recording" in message and "extension" not in message
    with pytest.raises(FileFormatError, match="is a folder, not a file"):
        write_recording(RECORDINGS["full_p1"](np.random.default_rng(0)), folder)


# ------------------------------------------------- 4. words for both APIs
def test_messages_name_the_python_and_the_command_line_way(tmp_path, rng):
    path = tmp_path / "rec.xyz"
    path.write_text("1,2\n")
    message = read_bad(path)
    assert "format= in Python, --format with maglevid inspect and convert" in message
    rec = write_recording(RECORDINGS["full_p1"](rng), tmp_path / "rec.npz")
    with pytest.raises(FileFormatError) as err:
        check_output(rec)
    assert "overwrite=True in Python, --overwrite on the command line" in str(err.value)
    log = tmp_path / "log.csv"
    log.write_text("t,y\n0,1\n1,2\n")
    assert "--mapping FILE.json or a preset name on the command line" in read_bad(log)
    txt = tmp_path / "log.txt"
    txt.write_text("0 1\n1 2\n")
    assert "--mapping on the command line" in read_bad(txt)
    path, _ = write_user_file(tmp_path, "mat", {"y": np.arange(30.0).reshape(3, 10), "dt": [0.1]})
    message = read_bad(path)
    assert '{"layout": "channels_first"} (mapping= in Python, --mapping FILE.json' in message


# ------------------------------------------------- 5, 6. empty and complex MATLAB data
@pytest.mark.parametrize("fmt", ["mat", "npz"])
def test_empty_matrix_is_called_empty(tmp_path, fmt):
    path, _ = write_user_file(tmp_path, fmt, {"y": np.zeros((0, 3)), "dt": np.array([0.01])})
    message = read_bad(path)
    assert "column 'y': is an empty variable (0x3: 0 samples)" in message
    assert "channels x samples" not in message


def test_empty_matrix_in_mat73(tmp_path):
    import h5py

    path = tmp_path / "e.mat"
    _write_mat73(path, {"dt": np.array([0.01])})
    with h5py.File(path, "a") as fh:  # as MATLAB stores zeros(0, 3)
        ds = fh.create_dataset("y", data=np.array([0, 3], dtype=np.uint64))
        ds.attrs["MATLAB_class"] = np.bytes_(b"double")
        ds.attrs["MATLAB_empty"] = np.uint8(1)
    assert "is an empty variable (0x3: 0 samples)" in read_bad(path)


def test_complex_matrix_is_called_complex(tmp_path, rng):
    import scipy.io as sio

    path = tmp_path / "cplx.mat"
    sio.savemat(path, {"y": rng.standard_normal((100, 2)) + 1j, "dt": 0.01})
    message = read_bad(path)
    assert "column 'y': holds complex numbers (complex128)" in message
    assert "signals must be real" in message and "cell/struct" not in message


def test_complex_matrix_in_mat73(tmp_path):
    import h5py

    path = tmp_path / "c73.mat"
    _write_mat73(path, {"dt": np.array([0.01])})
    with h5py.File(path, "a") as fh:  # MATLAB's compound (real, imag) type
        z = np.zeros((2, 10), dtype=[("real", "<f8"), ("imag", "<f8")])
        fh.create_dataset("y", data=z).attrs["MATLAB_class"] = np.bytes_(b"double")
    message = read_bad(path)
    assert "holds complex numbers" in message and "signals must be real" in message


# ------------------------------------------------- 7. extra data is never dropped
def test_npz_with_more_columns_than_its_metadata(tmp_path, native_npz):
    arrays = dict(np.load(native_npz))
    arrays["y"] = np.column_stack([arrays["y"], arrays["y"][:, 0]])
    np.savez(tmp_path / "y4.npz", **arrays)
    message = read_bad(tmp_path / "y4.npz")
    assert "column 'y': has 4 channel(s) (shape (50, 4)), but the metadata describes 3" in message
    assert "never dropped silently" in message


@pytest.fixture
def native_csv_lines(tmp_path, rng) -> tuple[Path, list[str]]:
    data = ClosedLoopData(
        y=rng.standard_normal((400, 3)), u=rng.standard_normal((400, 2)), dt=0.01
    )
    path = write_recording(data, tmp_path / "rec.csv")
    return path, path.read_text().splitlines()


def test_native_csv_row_with_an_extra_field(native_csv_lines):
    path, lines = native_csv_lines
    lines[301] += ",1.5"  # data row 300 is line 302 (the header is line 1)
    path.write_text("\n".join(lines) + "\n")
    message = read_bad(path)
    assert "data row 300 (line 302) has 7 field(s); expected 6 (extra values?)" in message


def test_native_csv_rows_joined_on_one_line(native_csv_lines):
    path, lines = native_csv_lines
    lines[301] += lines.pop(302)  # the newline between two rows is lost
    path.write_text("\n".join(lines) + "\n")
    message = read_bad(path)
    assert "data row 300 (line 302) has 11 field(s); expected 6" in message
    assert "two rows joined on one line" in message and "truncated" not in message


def test_user_log_rows_with_more_or_fewer_fields(tmp_path):
    path = tmp_path / "log.csv"
    m = {"time": "t", "y": ["gap"]}  # uses columns 0 and 1 of 3
    path.write_text("t,gap,v\n0,1,2\n0.01,1,2,7\n0.02,1,2\n")
    assert "data row 1 (line 3) has 4 field(s); expected 3" in read_bad(path, mapping=m)
    path.write_text("t,gap,v\n0,1,2\n0.01,1\n0.02,1,2\n")
    assert "data row 1 (line 3) has 2 field(s); expected 3" in read_bad(path, mapping=m)
    # Comment and blank lines are not rows; a good file still reads.
    path.write_text("t,gap,v\n0,1,2\n# note, with, commas\n\n0.01,1,2\n0.02,1,2\n")
    assert read_recording(path, mapping=m).n_samples == 3


# ------------------------------------------------- 8. shipped presets are suggested
def test_variables_of_a_preset_suggest_it(tmp_path, rng):
    import scipy.io as sio

    names = {f"rawMeasurements{k}": rng.standard_normal((20, 3)) for k in (1, 2, 3)}
    path = tmp_path / "maggy.mat"
    sio.savemat(path, {**names, "u": rng.standard_normal((20, 2))})
    message = read_bad(path)
    assert "The preset 'maggy-ntnu' shipped with maglevid reads these variables" in message
    assert "--mapping maggy-ntnu on the command line, mapping='maggy-ntnu' in Python" in message
    sio.savemat(path, names)  # no u: the preset does not fit, and is not suggested
    assert "preset 'maggy-ntnu'" not in read_bad(path)


def test_maggy_record_suggests_its_preset(shared_data):
    path = shared_data / "maggy-ntnu" / "PD_data_with_input.mat"
    message = read_bad(path)
    assert "not a maglevid recording" in message and "--mapping maggy-ntnu" in message


def test_good_files_still_read(tmp_path, rng):
    data = full_recording(rng, p=2, n=10)
    for name in ("rec.csv", "rec.npz", "rec.mat", "rec.parquet"):
        back = read_recording(write_recording(data, tmp_path / name))
        assert np.array_equal(back.y, data.y) and np.array_equal(back.u, data.u)
        assert back.channel_names("y") == data.channel_names("y")


@pytest.mark.parametrize("block", [None, 7])  # 7 bytes: rows cut across reads
@pytest.mark.parametrize(
    "sep,extra_text",
    [
        (",", {"text": {"delimiter": ","}}),
        ("\t", {"text": {"delimiter": "tab"}}),
        (" ", {"text": {"delimiter": None}}),
        (",", {"text": {"delimiter": ",", "quote": '"'}}),
    ],
    ids=["comma", "tab", "whitespace", "quoted"],
)
def test_row_width_check_on_every_kind_of_text(tmp_path, monkeypatch, block, sep, extra_text):
    # The exact rule (every data row has as many fields as the header) holds for
    # the fast byte-level pass and the exact line-by-line one alike.
    import maglevid.io._text as text_module

    if block is not None:
        monkeypatch.setattr(text_module, "_BLOCK_BYTES", block)
    m = {"time": "t", "y": ["gap"], **extra_text}
    rows = [sep.join(r) for r in (["t", "gap", "v"], ["0", "1", "2"], ["0.01", "1", "2"])]
    good = [*rows, "# a comment, with, commas\t and  spaces", "", "0.02  " + sep + "1" + sep + "2"]
    path = tmp_path / "log.txt"
    path.write_text("\r\n".join(good))  # Windows line ends, no final newline
    assert read_recording(path, mapping=m).n_samples == 3
    bad = [*rows, sep.join(["0.02", "1", "2", "9"]), sep.join(["0.03", "1", "2"])]
    path.write_text("\n".join(bad) + "\n")
    message = read_bad(path, mapping=m)
    assert "data row 2 (line 4) has 4 field(s); expected 3 (extra values?)" in message


# ------------------------------------------------- a spreadsheet's export of a recording
def test_semicolons_and_comment_lines_are_named(tmp_path, rng):
    # A maglevid CSV re-saved by a spreadsheet with ';' and decimal commas, or with comment
    # lines above its header, was told only "header column 0 is 't;y:x;...'" or "the
    # header has 1 fields" (found from outside, seventeenth session).
    csv = write_recording(RECORDINGS["full_p1"](rng), tmp_path / "rec.csv")
    text = csv.read_text()
    csv.write_text(text.replace(",", ";"))
    message = read_bad(csv)
    assert "separated by semicolons" in message and '"delimiter": "semicolon"' in message
    csv.write_text("# exported by scope v1.2\n" + text)
    message = read_bad(csv)
    assert "starts with comment lines" in message and '"comment": "#"' in message
    own = tmp_path / "own.csv"  # through a mapping that expects commas
    own.write_text("t;x\n0,0;1,5\n0,1;1,6\n")
    message = read_bad(own, mapping={"time": "t", "y": ["x"]})
    assert "the header has 1 fields" in message and '"decimal": ","' in message
