"""``maglevid identify --stream``: a Parquet recording read in chunks equals the whole read."""

from __future__ import annotations

import json

import pytest

from maglevid.cli import identify as identify_cmd
from maglevid.cli.main import main
from maglevid.physics.amb import AMBParameters
from maglevid.simulate import simulate_amb_loop

pytest.importorskip("pyarrow")


@pytest.fixture(scope="module")
def parquet(tmp_path_factory):
    from maglevid.io import write_recording

    nom = AMBParameters.nominal()
    data = simulate_amb_loop(
        nom.with_fault(R1=1.2),
        nominal=nom,
        n_samples=12_000,
        rng=7,
        noise_std=(1e-10, 3e-6, 3e-6),
        plant_model="linear",
    )
    path = tmp_path_factory.mktemp("stream") / "rec.parquet"
    write_recording(data, path)
    return path


def _run(capsys, *argv: str) -> dict:
    assert main(["--json", "identify", *argv]) == 0
    return json.loads(capsys.readouterr().out)


@pytest.mark.parametrize("method", ["physical", "moesp"])
def test_streamed_identify_equals_whole_file(parquet, capsys, method):
    extra = ["--option", "order=4", "--option", "horizon=20"] if method == "moesp" else []
    whole = _run(capsys, str(parquet), "--method", method, "--no-stream", *extra)
    streamed = _run(
        capsys, str(parquet), "--method", method, "--stream", "--chunk-size", "2500", *extra
    )
    # two passes for both: physical (coefficients, then residuals) and subspace
    # (the means, the record's operating point, then the statistics; issue 12)
    assert streamed["streamed"] == {"chunk_size": 2500, "passes": 2}
    assert "streamed" not in whole
    for name, value in whole["parameters"].items():
        # Same rows, summed in another order (tests/identify/test_streaming.py): rounding.
        assert streamed["parameters"][name] == pytest.approx(value, rel=1e-8, abs=1e-12), name


def test_large_parquet_streams_by_default_with_method_physical(parquet, capsys, monkeypatch):
    monkeypatch.setattr(identify_cmd, "STREAM_THRESHOLD_BYTES", 1)
    out = _run(capsys, str(parquet), "--chunk-size", "5000")
    assert out["method"] == "physical" and out["streamed"]["passes"] == 2


def test_stream_refuses_a_method_without_a_streamed_form(parquet, capsys):
    assert main(["identify", str(parquet), "--stream", "--method", "deadbeat-arx"]) != 0
    assert "cannot be streamed" in capsys.readouterr().err


def test_a_small_chunk_is_not_judged_too_short(parquet, capsys):
    # The quality gate read only the first chunk: --chunk-size 10 was refused as "10
    # control periods: too short" on a 12000-sample record (found from outside, issue
    # 16, thirteenth session). It now reads the first 2000 periods at least; the fit
    # is the same as with large chunks (rounding).
    small = _run(capsys, str(parquet), "--method", "physical", "--stream", "--chunk-size", "500")
    large = _run(capsys, str(parquet), "--method", "physical", "--stream", "--chunk-size", "6000")
    assert small["streamed"]["chunk_size"] == 500
    for name, value in large["parameters"].items():
        assert small["parameters"][name] == pytest.approx(value, rel=1e-8, abs=1e-12), name


def test_a_bearing_without_its_loop_streams_by_pbsid_in_physical_coordinates(
    parquet, tmp_path, capsys
):
    # `--stream` defaulted to physical, whose instruments are then lags of r: biased on
    # the bearing (issue 16, fourteenth session). In memory such a record gets ml, which
    # has no streamed form; the stream takes PBSID-opt in physical coordinates and says
    # why. --method physical is refused there, naming what to use.
    from maglevid.io import read_recording, write_recording

    data = read_recording(parquet)
    bare = {k: v for k, v in dict(data.loop).items() if k not in ("controller", "observer")}
    path = write_recording(data.replace(loop=bare), tmp_path / "bare.parquet")
    out = _run(capsys, str(path), "--stream", "--chunk-size", "5000")
    assert out["method"] == "pbsid" and out["options"]["coordinates"] == "physical"
    assert "no streamed form" in out["method_reason"]
    assert {f"v{i}" for i in range(1, 10)} <= set(out["parameters"])
    # the record states m and i0: R, L, ki, kw from v1..v9 (printed v only before; found
    # from outside, issue 16, fifteenth session), equal to the whole-file fit's
    assert out["parameters"]["R1"] == pytest.approx(1.2 * 17.5, rel=0.02)  # the R1 fault
    whole = _run(
        capsys, str(path), "--no-stream", "--method", "pbsid", "--option", "coordinates=physical"
    )
    for name in ("R1", "L2", "ki1", "kw2", "x0"):
        assert out["parameters"][name] == pytest.approx(whole["parameters"][name], rel=1e-6)
        assert out["std_errors"][name] == pytest.approx(whole["std_errors"][name], rel=1e-4)
    assert main(["identify", str(path), "--stream", "--method", "physical"]) != 0
    assert "loop['controller']" in capsys.readouterr().err


def test_pbsid_on_a_bearing_gives_the_physical_parameters(parquet, capsys):
    # `identify --method pbsid` on a bearing's record printed the black box's a1..a4 (no
    # standard errors: "nan"), where `diagnose` and the streamed default ask for the physical
    # parameters (found from outside, issue 16, twenty-third session). Now in memory and
    # streamed alike, with a note; coordinates=identified still gives the black box.
    for stream in ("--no-stream", "--stream"):
        out = _run(capsys, str(parquet), "--method", "pbsid", stream, "--chunk-size", "5000")
        assert out["options"]["coordinates"] == "physical", stream
        assert any("coordinates='physical'" in n for n in out["notes"]), stream
        assert out["parameters"]["R1"] == pytest.approx(1.2 * 17.5, rel=0.02), stream
        assert out["std_errors"]["R1"] > 0, stream
    assert main(["identify", str(parquet), "--method", "ssarx", "--option",
                 "coordinates=identified", "-q"]) == 0  # fmt: skip
    text = capsys.readouterr().out
    rows = {ln.split()[0] for ln in text.splitlines() if ln.startswith(" ")}
    assert "a1" in rows and "v1" not in rows and "coordinates='physical'" not in text
