"""The command line on bad input and hostile surroundings: one line, never a traceback,
never a user's file replaced (issue 17; each case failed on main e62a9f8)."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from maglevid.cli.main import main
from maglevid.io import write_recording
from maglevid.physics.amb import AMBParameters
from maglevid.simulate.amb import simulate_amb_loop

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def amb_record():
    """A healthy bearing, long enough for a diagnosis (2000 control periods)."""
    return simulate_amb_loop(AMBParameters.nominal(), n_samples=2000, rng=17)


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1, err
    return lines[0]


# -- writers never replace what they did not create -------------------------------------
def test_report_never_over_the_recording(tmp_path, capsys, amb_record):
    rec = write_recording(amb_record, tmp_path / "x.npz")
    before = _digest(rec)
    assert main(["-q", "diagnose", str(rec), "--report", str(rec)]) == 1
    assert "is an input" in _one_error_line(capsys)
    # Not even with --overwrite: an output never destroys its input.
    assert main(["-q", "diagnose", str(rec), "--report", str(rec), "--overwrite"]) == 1
    assert _digest(rec) == before


def test_report_never_over_the_sidecar_of_a_csv(tmp_path, capsys, amb_record):
    rec = write_recording(amb_record, tmp_path / "small.csv")
    side = tmp_path / "small.json"
    before = _digest(side)
    assert main(["-q", "diagnose", str(rec), "--report", str(side), "--overwrite"]) == 1
    assert "small.json" in _one_error_line(capsys)
    assert _digest(side) == before


def test_existing_report_needs_overwrite(tmp_path, capsys, amb_record):
    rec = write_recording(amb_record, tmp_path / "x.npz")
    page = tmp_path / "x.html"
    page.write_text("my notes", encoding="utf-8")
    assert main(["-q", "diagnose", str(rec), "--report", str(page)]) == 1
    assert "--overwrite" in _one_error_line(capsys)
    assert page.read_text(encoding="utf-8") == "my notes"
    assert main(["-q", "diagnose", str(rec), "--report", str(page), "--overwrite"]) == 0
    assert "<!DOCTYPE html>" in page.read_text(encoding="utf-8")


def test_report_refused_before_anything_is_stored(tmp_path, capsys, amb_record):
    rec = write_recording(amb_record, tmp_path / "x.npz")
    store = tmp_path / "s.sqlite"
    args = ["-q", "diagnose", str(rec), "--store", str(store), "--machine", "M"]
    assert main([*args, "--report", str(rec)]) == 1
    _one_error_line(capsys)
    assert not store.exists()


def test_fleet_summary_page_needs_overwrite(tmp_path, capsys):
    from maglevid.report.fleet import write_fleet_summary

    page = tmp_path / "fleet.html"
    page.write_text("keep", encoding="utf-8")
    summary = {"format": "maglevid-fleet-summary", "store": str(tmp_path / "s.sqlite")}
    with pytest.raises(Exception, match="exists; refusing"):
        write_fleet_summary(summary, page)
    assert page.read_text(encoding="utf-8") == "keep"


def test_convert_and_simulate_never_over_their_input(tmp_path, capsys, amb_record):
    rec = write_recording(amb_record, tmp_path / "x.csv")
    before = _digest(tmp_path / "x.json")
    assert main(["-q", "convert", str(rec), str(tmp_path / "x.json"), "--overwrite"]) == 1
    _one_error_line(capsys)
    assert _digest(tmp_path / "x.json") == before
    assert main(["-q", "simulate", "amb", "--out", str(rec), "--n-samples", "300"]) == 1
    assert "exists" in _one_error_line(capsys)


# -- output to a closed pipe ------------------------------------------------------------
@pytest.mark.parametrize("argv", [["inspect", "{rec}"], ["--json", "inspect", "{rec}"]])
def test_closed_pipe_exits_quietly(tmp_path, amb_record, argv):
    rec = write_recording(amb_record, tmp_path / "x.npz")
    # `maglevid ... | head` where head has already gone: the read end is closed
    # before the command starts, so its first write fails with EPIPE every time.
    read_end, write_end = os.pipe()
    os.close(read_end)
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    try:
        res = subprocess.run(
            [sys.executable, "-m", "maglevid.cli.main", *(a.format(rec=rec) for a in argv)],
            stdout=write_end, stderr=subprocess.PIPE, text=True, env=env, timeout=120,
        )  # fmt: skip
    finally:
        os.close(write_end)
    assert "Traceback" not in res.stderr and "BrokenPipe" not in res.stderr, res.stderr
    assert res.stderr == ""
    assert res.returncode == 141  # 128 + SIGPIPE, as a Unix tool killed by the signal


def test_closed_pipe_with_head(tmp_path, amb_record):
    rec = write_recording(amb_record, tmp_path / "x.npz")
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    cmd = f"{sys.executable} -m maglevid.cli.main --json identify {rec} | head -c 10 >/dev/null"
    res = subprocess.run(
        ["/bin/bash", "-o", "pipefail", "-c", cmd],
        capture_output=True, text=True, env=env, timeout=120,
    )  # fmt: skip
    assert "Traceback" not in res.stderr and "BrokenPipe" not in res.stderr, res.stderr
    assert res.returncode in (0, 141)


# -- a failed write ---------------------------------------------------------------------
def test_disk_full_report_is_one_line(tmp_path, capsys, amb_record, monkeypatch):
    import errno

    rec = write_recording(amb_record, tmp_path / "x.npz")
    real = Path.write_text

    def full(self, *a, **kw):
        real(self, "<!DOCT", encoding="utf-8")
        raise OSError(errno.EFBIG, "File too large")

    monkeypatch.setattr(Path, "write_text", full)
    assert main(["-q", "diagnose", str(rec), "--report", str(tmp_path / "r.html")]) == 1
    assert "file too large" in _one_error_line(capsys)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.npz"]


def test_json_error_is_one_object(tmp_path, capsys):
    fifo = tmp_path / "x.npz"
    os.mkfifo(fifo)
    assert main(["--json", "inspect", str(fifo)]) == 1
    out = json.loads(capsys.readouterr().out)
    assert out["error"] == "FileFormatError" and "FIFO" in out["message"]
