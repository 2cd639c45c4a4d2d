"""Column mappings: dict, JSON and TOML files, presets, and the text options they carry."""

from __future__ import annotations

import json

import numpy as np
import pytest
from _io_helpers import user_columns

from maglevid.exceptions import FileFormatError
from maglevid.io import available_presets, load_mapping, read_recording
from maglevid.io.mapping import ColumnMapping

TOML_MAPPING = """
description = "bench B"
dt = 0.01

[text]
delimiter = "semicolon"
decimal = ","
skip_lines = 1
encoding = "latin-1"

[time]
column = "time [ms]"
unit = "ms"

[[y]]
column = "gap"
file_unit = "mm"
scale = 0.001
unit = "m"

[[u]]
column = 2
name = "v"
unit = "V"

[[extra]]
column = "ref"
unit = "m"

[metadata]
machine = "bench B"
"""

# What the TOML mapping reads: a European export with a title line, a units header,
# semicolons and decimal commas, in Latin-1.
EUROPEAN_LOG = (
    "Prüfstand B - Achse X\n"
    "time [ms];gap [mm];v;ref\n"
    "0;1,5;0,25;0,0015\n"
    "10;1,25;0,5;0,0015\n"
    "20;1;0,75;0,0015\n"
)


def test_toml_and_json_files_read_the_same(tmp_path):
    log = tmp_path / "log.txt"
    log.write_bytes(EUROPEAN_LOG.encode("latin-1"))
    toml = tmp_path / "map.toml"
    toml.write_text(TOML_MAPPING, encoding="utf-8")
    data = read_recording(log, mapping=toml)
    # Exact: 1.5 mm * 0.001 is the double nearest 0.0015 either way round? Not in general,
    # so compare with the same arithmetic the reader documents (value * scale).
    assert np.array_equal(data.y[:, 0], np.array([1.5, 1.25, 1.0]) * 0.001)
    assert np.array_equal(data.u[:, 0], [0.25, 0.5, 0.75])
    assert data.dt == 0.01 and data.t0 == 0.0
    assert data.names == {"y": ("gap",), "u": ("v",)}
    assert data.units == {"y": ("m",), "u": ("V",)}
    assert data.metadata["extra_signals"]["ref"]["unit"] == "m"
    assert data.metadata["machine"] == "bench B"
    assert data.metadata["mapping"] == f"file {toml}"

    import tomllib

    as_json = tmp_path / "map.json"
    as_json.write_text(json.dumps(tomllib.loads(TOML_MAPPING)))
    again = read_recording(log, mapping=as_json)
    assert np.array_equal(again.y, data.y) and np.array_equal(again.u, data.u)


def test_time_units_and_scale(tmp_path):
    cols = user_columns(10)
    log = tmp_path / "log.csv"
    rows = np.column_stack([cols["t"] * 1e6, cols["gap"]])
    log.write_text("t_us,gap\n" + "\n".join(f"{a!r},{b!r}" for a, b in rows.tolist()) + "\n")
    data = read_recording(log, mapping={"time": {"column": "t_us", "unit": "us"}, "y": ["gap"]})
    assert data.dt == pytest.approx(0.01, rel=1e-12)  # mean step, from rounded products
    data = read_recording(log, mapping={"time": {"column": 0, "scale": 1e-6}, "y": [1]})
    assert data.dt == pytest.approx(0.01, rel=1e-12)
    with pytest.raises(FileFormatError, match="unknown time unit 'hours'"):
        load_mapping({"time": {"column": "t", "unit": "hours"}, "y": ["x"]})


def test_dt_given_with_a_time_column_is_checked(tmp_path):
    cols = user_columns(10)
    log = tmp_path / "log.csv"
    log.write_text(
        "t,gap\n"
        + "\n".join(f"{a!r},{b!r}" for a, b in zip(cols["t"].tolist(), cols["gap"].tolist()))
        + "\n"
    )
    assert read_recording(log, mapping={"time": "t", "dt": 0.01, "y": ["gap"]}).dt == 0.01
    # every step alike, half the dt: a dt (or a unit), not a gap (thirteenth session)
    with pytest.raises(FileFormatError, match=r"uniform at 0.01 s, 0.5 times the expected"):
        read_recording(log, mapping={"time": "t", "dt": 0.02, "y": ["gap"]})
    # 0.05 % off: every step within 1 %, but the mean step says dt is wrong.
    with pytest.raises(FileFormatError, match="is the mapping's dt right"):
        read_recording(log, mapping={"time": "t", "dt": 0.01005, "y": ["gap"]})
    assert read_recording(log, mapping={"sample_rate": 250, "y": ["gap"]}).dt == 1 / 250


def test_header_detection_and_units_in_the_header(tmp_path):
    log = tmp_path / "log.dat"
    log.write_text("# rig 3\n\ntime[s]  gap(m)  v\n0 1 2\n0.5 3 4\n# pause\n1.0 5 6\n")
    data = read_recording(log, mapping={"time": "time", "y": ["gap"], "u": ["v"]})
    assert np.array_equal(data.y[:, 0], [1, 3, 5]) and data.dt == 0.5
    assert data.names == {"y": ("gap",), "u": ("v",)}
    assert data.metadata["header_comments"] == ("rig 3",)  # the leading ones
    with pytest.raises(FileFormatError, match="unit mismatch: the file says 'm'"):
        read_recording(log, mapping={"time": "time", "y": [{"column": "gap", "unit": "mm"}]})
    # header = false: the header line is then data, and not a number.
    with pytest.raises(
        FileFormatError, match=r"column '#0': data row 0 \(line 3\): 'time\[s\]' is not a number"
    ):
        read_recording(log, mapping={"time": 0, "y": [1], "text": {"header": False}})


def test_headerless_file_by_index_or_named_columns(tmp_path):
    log = tmp_path / "log.txt"
    log.write_text("0\t1\t2\n0.1\t3\t4\n0.2\t5\t6\n")
    data = read_recording(log, mapping={"time": 0, "y": [2], "u": [1]})
    assert data.channel_names("y") == ("y1",) and np.array_equal(data.u[:, 0], [1, 3, 5])
    with pytest.raises(FileFormatError, match="no column names"):
        read_recording(log, mapping={"time": 0, "y": ["gap"]})
    data = read_recording(log, mapping={"columns": ["t", "a", "b"], "time": "t", "y": ["b"]})
    assert data.channel_names("y") == ("b",)
    with pytest.raises(FileFormatError, match="names 2 columns"):
        read_recording(log, mapping={"columns": ["t", "a"], "time": "t", "y": ["a"]})
    with pytest.raises(FileFormatError, match="index 3 is out of range"):
        read_recording(log, mapping={"time": 0, "y": [3]})
    with pytest.raises(FileFormatError, match="expects 4"):
        read_recording(log, mapping={"time": 0, "y": [1], "n_columns": 4})


def test_duplicate_header_names(tmp_path):
    log = tmp_path / "log.csv"
    log.write_text("t,x,x\n0,1,2\n1,3,4\n")
    assert np.array_equal(read_recording(log, mapping={"dt": 1, "y": [2]}).y[:, 0], [2, 4])
    with pytest.raises(FileFormatError, match="appears 2 times"):
        read_recording(log, mapping={"dt": 1, "y": ["x"]})


def test_quotes_comments_and_skip_lines(tmp_path):
    log = tmp_path / "log.csv"
    log.write_text('garbage line\n"t","gap"\n"0","1"\n"1","2" # note\n')
    m = {"dt": 1.0, "y": ["gap"], "text": {"skip_lines": 1, "quote": '"'}}
    assert np.array_equal(read_recording(log, mapping=m).y[:, 0], [1, 2])


def test_scale_and_offset(tmp_path):
    log = tmp_path / "log.csv"
    log.write_text("counts\n0\n1023\n512\n")
    m = {"dt": 0.01, "y": [{"column": "counts", "scale": 0.05 / 1023, "offset": -0.01}]}
    y = read_recording(log, mapping=m).y[:, 0]
    assert np.array_equal(y, np.array([0.0, 1023.0, 512.0]) * (0.05 / 1023) + -0.01)


def test_mapping_keys_are_checked():
    cases = [
        ({"y": ["x"], "dtt": 1}, "unknown key"),
        ({"y": [{"column": "x", "unitt": "m"}]}, "unknown key"),
        ({"u": ["x"], "dt": 1}, "must place 'y'"),
        ({"y": ["x"], "dt": -1}, "positive"),
        ({"y": ["x"], "dt": True}, "expected a number"),
        ({"y": ["x"], "p": 0}, "integer >= 1"),
        ({"y": [-1]}, "0-based"),
        ({"y": []}, "non-empty list"),
        ({"y": ["x"], "dt": 1, "sample_rate": 2}, "not both"),
        ({"y": ["x"], "format": "xls"}, "expected one of"),
        ({"y": ["x"], "layout": "sideways"}, "expected one of"),
        ({"y": ["x"], "text": {"delimiter": "::"}}, "one character"),
        ({"y": ["x"], "text": {"encoding": "klingon"}}, "unknown text encoding"),
        ({"y": ["x"], "text": {"decimal": ","}}, "decimal comma needs another delimiter"),
        ({"y": ["x"], "text": {"header": "yes"}}, "true, false"),
        ({"y": ["x"], "columns": ["a", "a"]}, "unique"),
        ({"y": ["x"], "columns": ["a"], "n_columns": 2}, "n_columns=2"),
        ({"y": ["x"], "expect_units": {"q": ["m"]}}, "unknown signal"),
        ({"y": [{"column": "x", "rate": "control"}]}, "unknown key"),
        ({"y": ["x"], "extra": [{"column": "e", "rate": "fast"}]}, "expected one of"),
        ({"y": ["x"], "extra": ["e", "e"]}, "unique"),
        ({"any_of": [{"y": ["x"]}]}, "needs 'n_columns'"),
        ({"y": ["x"], "loop": [1, 2]}, "expected a table"),
    ]
    for raw, message in cases:
        with pytest.raises(FileFormatError, match=message) as err:
            load_mapping(raw)
        assert "mapping (dict)" in str(err.value)
    with pytest.raises(FileFormatError, match="must be a dict"):
        load_mapping(42)


def test_mapping_files_errors(tmp_path):
    bad = tmp_path / "m.json"
    bad.write_text("{oops")
    with pytest.raises(FileFormatError, match="not a valid JSON mapping") as err:
        load_mapping(bad)
    assert err.value.path == str(bad)
    bad = tmp_path / "m.toml"
    bad.write_text("y = [")
    with pytest.raises(FileFormatError, match="not a valid TOML mapping"):
        load_mapping(str(bad))
    with pytest.raises(FileFormatError, match="mapping file not found"):
        load_mapping(tmp_path / "missing.json")
    with pytest.raises(FileFormatError, match="neither an existing mapping file") as err:
        load_mapping("no-such-preset")
    assert "uaq-levitador" in str(err.value)
    wrong = tmp_path / "m.yaml"
    wrong.write_text("y: [x]")
    with pytest.raises(FileFormatError, match=r"\.json or \.toml"):
        load_mapping(wrong)
    keyed = tmp_path / "k.json"
    keyed.write_text('{"y": ["x"], "colour": 1}')
    with pytest.raises(FileFormatError, match="unknown key") as err:
        load_mapping(keyed)
    assert err.value.path == str(keyed)


def test_presets_load_by_name():
    presets = available_presets()
    assert set(presets) == {
        "uaq-levitador",
        "uaq-levitador-session",
        "uaq-levitador-legacy",
        "maggy-ntnu",
    }
    assert all(presets.values())
    for name in presets:
        m = load_mapping(name)
        assert isinstance(m, ColumnMapping) and m.origin.startswith("preset")
    assert load_mapping("UAQ_Levitador_Legacy").n_columns == 6
    assert len(load_mapping("uaq-levitador").alternatives) == 2
    maggy = load_mapping("maggy-ntnu")
    assert maggy.dt == 1 / 2700 and len(maggy.signals["y"]) == 9


def test_extends_a_preset(tmp_path):
    m = load_mapping(
        {"extends": "uaq-levitador-legacy", "time": {"column": "t", "tolerance": 0.5}}
    )
    assert m.time.tolerance == 0.5 and m.n_columns == 6 and len(m.extra) == 2
    f = tmp_path / "mine.json"
    f.write_text(json.dumps({"extends": "uaq-levitador-session", "dt": 0.02}))
    m = load_mapping({"extends": str(f), "description": "twice removed"})
    assert m.dt == 0.02 and m.n_columns == 7 and m.description == "twice removed"


def test_any_of_chooses_by_column_count(tmp_path):
    m = {
        "any_of": [
            {"n_columns": 3, "dt": 1, "y": [1]},
            {"n_columns": 2, "dt": 1, "y": [0], "u": [1]},
        ]
    }
    log = tmp_path / "log.txt"
    log.write_text("1 2\n3 4\n")
    data = read_recording(log, mapping=m)
    assert data.nu == 1 and np.array_equal(data.y[:, 0], [1, 3])
    log.write_text("1 2 3 4\n5 6 7 8\n")
    with pytest.raises(FileFormatError, match="matches no alternative") as err:
        read_recording(log, mapping=m)
    assert "[4]" in str(err.value)
    with pytest.raises(FileFormatError, match="does not apply to a npz file"):
        np.savez(tmp_path / "x.npz", y=np.zeros(3))
        read_recording(tmp_path / "x.npz", mapping=m)


def test_options_only_mapping_refines_a_native_file(tmp_path, rng):
    from maglevid.data import ClosedLoopData
    from maglevid.io import write_recording

    data = ClosedLoopData(y=rng.standard_normal((6, 1)), dt=0.1, units={"y": ["m"]})
    path = write_recording(data, tmp_path / "rec.npz")
    m = load_mapping({"expect_units": {"y": ["m"]}, "metadata": {"operator": "kim"}})
    assert not m.has_signals
    back = read_recording(path, mapping=m)
    assert back.metadata["operator"] == "kim"


def test_byte_order_mark_is_not_part_of_the_first_name(tmp_path):
    log = tmp_path / "excel.csv"
    log.write_bytes("t;gap\n0;1\n1;2\n".encode("utf-8-sig"))
    m = {"time": "t", "y": ["gap"], "text": {"delimiter": ";"}}
    assert read_recording(log, mapping=m).dt == 1.0
    headerless = tmp_path / "excel.txt"
    headerless.write_bytes("0 1\n1 2\n".encode("utf-8-sig"))
    assert read_recording(headerless, mapping={"time": 0, "y": [1]}).y[0, 0] == 1.0


def test_a_maglevid_csv_read_through_a_mapping_keeps_its_units(tmp_path, rng):
    from maglevid.data import ClosedLoopData
    from maglevid.io import write_recording

    data = ClosedLoopData(
        y=rng.standard_normal(6), dt=0.1, names={"y": ["gap"]}, units={"y": ["m"]}
    )
    path = write_recording(data, tmp_path / "rec.csv")
    back = read_recording(path, mapping={"time": "t", "y": [{"column": "y:gap", "unit": "m"}]})
    assert np.array_equal(back.y, data.y) and back.metadata["source_format"] == "csv"
    with pytest.raises(FileFormatError, match="the file says 'm', the mapping expects 'mm'"):
        read_recording(path, mapping={"time": "t", "y": [{"column": "y:gap", "unit": "mm"}]})
