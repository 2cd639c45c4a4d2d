"""``maglevid convert`` and ``maglevid inspect`` through the real entry point."""

from __future__ import annotations

import json

import numpy as np
import pytest

from maglevid.cli.main import main
from maglevid.data import ClosedLoopData
from maglevid.io import read_recording, write_recording


@pytest.fixture
def recording(tmp_path):
    data = ClosedLoopData(
        y=np.column_stack([np.linspace(0.001, 0.002, 8), np.arange(8.0)]),
        u=np.arange(4.0),
        dt=0.01,
        p=2,
        names={"y": ["gap", "i"], "u": ["v"]},
        units={"y": ["m", "A"], "u": ["V"]},
        loop={"controller": {"K": [[1.0, 2.0]]}},
        metadata={"machine": "m7"},
    )
    return data, write_recording(data, tmp_path / "rec.npz")


def test_convert_between_formats(tmp_path, recording, capsys):
    data, src = recording
    for name in ("rec.csv", "rec.parquet", "rec73.mat"):
        args = ["convert", str(src), str(tmp_path / name)]
        if name == "rec73.mat":
            args += ["--to", "mat73"]
        assert main(args) == 0
        out = capsys.readouterr().out
        assert f"wrote   {tmp_path / name}" in out
        assert ("(metadata side-car)" in out) == name.endswith(".csv")
        back = read_recording(tmp_path / name)
        assert np.array_equal(back.y, data.y) and np.array_equal(back.u, data.u)
    assert (tmp_path / "rec.json").exists()


def test_convert_json_output(tmp_path, recording, capsys):
    _, src = recording
    assert main(["--json", "convert", str(src), str(tmp_path / "out.csv")]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["written"] == str(tmp_path / "out.csv")
    assert result["sidecar"] == str(tmp_path / "out.json")
    assert result["n_samples"] == 4 and result["p"] == 2
    assert result["signals"] == {"y": ["gap", "i"], "u": ["v"]}


def test_convert_refuses_to_overwrite(tmp_path, recording, capsys):
    _, src = recording
    target = tmp_path / "out.npz"
    target.write_bytes(b"keep")
    assert main(["convert", str(src), str(target)]) == 1
    err = capsys.readouterr().err
    assert "maglevid convert: error:" in err and "refusing to overwrite" in err
    assert target.read_bytes() == b"keep"
    assert main(["convert", str(src), str(target), "--overwrite"]) == 0
    capsys.readouterr()
    # The input itself is never written over, even with --overwrite.
    assert main(["convert", str(target), str(target), "--overwrite"]) == 1
    assert "read from" in capsys.readouterr().err


def test_convert_a_users_log_with_a_mapping_file(tmp_path, capsys):
    log = tmp_path / "log.txt"
    log.write_text("# bench\n0 1.0 5\n0.5 2.0 6\n1.0 3.0 7\n")
    mapping = tmp_path / "map.json"
    mapping.write_text(
        json.dumps(
            {
                "time": 0,
                "y": [{"column": 1, "name": "x", "unit": "m"}],
                "u": [{"column": 2, "unit": "V"}],
            }
        )
    )
    out = tmp_path / "rec.npz"
    assert main(["convert", str(log), str(out), "--mapping", str(mapping)]) == 0
    data = read_recording(out)
    assert data.dt == 0.5 and data.channel_names("y") == ("x",)
    assert data.metadata["mapping"] == f"file {mapping}"
    capsys.readouterr()
    assert main(["convert", str(log), str(tmp_path / "b.npz")]) == 1
    assert "column mapping" in capsys.readouterr().err


def test_convert_presets_and_usage(capsys):
    assert main(["convert", "--presets"]) == 0
    out = capsys.readouterr().out
    assert "uaq-levitador" in out and "maggy-ntnu" in out
    assert main(["--json", "convert", "--presets"]) == 0
    assert "uaq-levitador-legacy" in json.loads(capsys.readouterr().out)["presets"]
    assert main(["convert", "only-one-argument.npz"]) == 1
    assert "needs INPUT and OUTPUT" in capsys.readouterr().err


def test_convert_missing_input(tmp_path, capsys):
    assert main(["convert", str(tmp_path / "nope.npz"), str(tmp_path / "b.npz")]) == 1
    assert "no such file" in capsys.readouterr().err


def test_inspect_text(recording, capsys):
    _, src = recording
    assert main(["inspect", str(src)]) == 0
    out = capsys.readouterr().out
    assert "N = 4 control periods x p = 2 (8 output samples)" in out
    assert "dt = 0.01 s (100 Hz), t0 = 0 s, duration 0.04 s" in out
    lines = {line.split()[1]: line.split() for line in out.splitlines() if line.startswith("y ")}
    assert lines["gap"][2] == "m" and float(lines["gap"][3]) == 0.001
    assert lines["i"][2] == "A" and float(lines["i"][4]) == 7.0
    assert "loop: controller" in out and "machine" in out


def test_inspect_json(recording, capsys):
    _, src = recording
    assert main(["inspect", str(src), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert (r["n_samples"], r["p"], r["dt"], r["ny"], r["nu"]) == (4, 2, 0.01, 2, 1)
    assert r["duration_s"] == pytest.approx(0.04, rel=1e-15)
    u = r["signals"]["u"][0]
    assert (u["name"], u["unit"], u["min"], u["max"], u["mean"]) == ("v", "V", 0.0, 3.0, 1.5)
    assert u["std"] == pytest.approx(np.std([0.0, 1.0, 2.0, 3.0]), rel=1e-15)
    assert r["loop_keys"] == ["controller"] and r["source"] == str(src.resolve())


def test_inspect_a_real_record_with_a_preset(shared_data, capsys):
    path = shared_data / "maglev-uaq-levitador" / "datos_levitador.txt"
    assert main(["inspect", str(path), "--mapping", "uaq-levitador"]) == 0
    out = capsys.readouterr().out
    assert "N = 7673 control periods" in out and "(100 Hz)" in out
    assert "extra   yd" in out and "extra   id" in out and "loop: controller_law" in out


def test_inspect_bad_file(tmp_path, capsys):
    bad = tmp_path / "bad.parquet"
    bad.write_bytes(b"not parquet")
    assert main(["inspect", str(bad)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("maglevid inspect: error:") and "not a readable Parquet file" in err
    assert len(err.strip().splitlines()) == 1


def test_identify_a_real_levitator_record_with_a_whole_record_method(shared_data, capsys):
    # Reference: the record's own levitating segments (levitator.find_levitator_segments:
    # 230..956 and 1089..2989 on this step record). A method that fits one model to
    # one record (pbsid here; the subspace, ML and PEM methods alike) was handed the
    # segments anyway and refused an option the user never gave ("no option
    # 'segments'"); it now fits the longest segment and says so.
    path = shared_data / "maglev-uaq-levitador" / "dataset_escalon_20251217_205858.txt"
    assert main(["identify", str(path), "--mapping", "uaq-levitador", "--method", "pbsid",
                 "--json"]) == 0  # fmt: skip
    out = json.loads(capsys.readouterr().out)
    assert out["n_samples"] == 2989 - 1089
    assert any("samples 1089..2989" in n and "indirect" in n for n in out["notes"])
