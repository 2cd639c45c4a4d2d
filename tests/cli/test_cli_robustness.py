"""The command line on bad input and hostile surroundings: one line, never a traceback,
never a user's file replaced (issue 17; each case failed on main e62a9f8)."""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
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


def test_a_failed_diagnosis_leaves_no_new_store_behind(tmp_path, capsys, amb_record):
    # A missing recording (or one that cannot be read) left an empty SQLite store with
    # the schema behind (found from outside, issue 16, thirteenth session). A store that
    # existed before is kept as it was, even when this diagnosis fails.
    store = tmp_path / "s.sqlite"
    args = ["-q", "diagnose", "--store", str(store), "--machine", "M"]
    assert main([*args, str(tmp_path / "nope.npz")]) == 1
    assert "no such file" in _one_error_line(capsys)
    assert not list(tmp_path.glob("s.sqlite*"))
    rec = write_recording(amb_record, tmp_path / "x.npz")
    assert main([*args, str(rec)]) == 0
    capsys.readouterr()
    before = store.stat().st_size
    assert main([*args, str(tmp_path / "nope.npz")]) == 1
    _one_error_line(capsys)
    assert store.exists() and store.stat().st_size == before


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


def test_json_error_is_one_object(no_hang, tmp_path, capsys):
    fifo = tmp_path / "x.npz"
    os.mkfifo(fifo)
    assert main(["--json", "inspect", str(fifo)]) == 1
    out = json.loads(capsys.readouterr().out)
    assert out["error"] == "FileFormatError" and "FIFO" in out["message"]


# -- one line instead of a traceback ----------------------------------------------------
def _noise_record(amb_record, rng_seed: int = 0):
    """Pure noise in the bearing's shapes and scales, the design values kept, no controller."""
    rng = np.random.default_rng(rng_seed)
    n = 4000
    loop = {k: v for k, v in amb_record.loop.items() if k in ("nominal", "operating_point")}
    from maglevid.data import ClosedLoopData

    return ClosedLoopData(
        y=rng.standard_normal((n, 3)) * [1e-5, 0.1, 0.1],
        u=rng.standard_normal((n, 2)),
        r=rng.standard_normal((n, 2)),
        dt=1e-4,
        loop=loop,
    )


@pytest.mark.parametrize("seed", [0, 1, 3])
def test_pure_noise_is_refused_with_a_reason(tmp_path, capsys, amb_record, seed):
    # On main: OverflowError in the fault isolation (seed-dependent), or
    # "No significant change" with x0 off by -119 % (seed 0).
    rec = write_recording(_noise_record(amb_record, seed), tmp_path / "noise.npz")
    assert main(["--json", "diagnose", str(rec)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["verdict_code"] == "cannot_diagnose"
    assert "outputs look like noise" in out["verdict"]
    assert main(["identify", str(rec)]) == 1
    assert "outputs look like noise" in _one_error_line(capsys)


def test_operating_point_not_a_number_is_one_line(tmp_path, capsys, amb_record):
    loop = dict(amb_record.loop)
    loop["operating_point"] = {**loop["operating_point"], "i0": "abc"}
    from maglevid.data import ClosedLoopData
    from maglevid.exceptions import DataError

    with pytest.raises(DataError, match=r"\['i0'\] is 'abc'; expected a finite number"):
        amb_record.replace(loop=loop)
    # A file written by another tool: the same error at load, naming the file.
    fields = {s: getattr(amb_record, s) for s in ("y", "u", "r", "u_f")}
    desc = {
        "format": "maglevid-recording", "version": 1, "dt": amb_record.dt, "p": 1,
        "signals": {s: {"names": list(amb_record.channel_names(s)),
                        "units": list(amb_record.channel_units(s))} for s in fields},
        "loop": json.loads(json.dumps({"operating_point": {"i0": "abc", "m": 1.8}})),
    }  # fmt: skip
    path = tmp_path / "bad.npz"
    np.savez(path, metadata=np.array(json.dumps(desc)), **fields)
    for cmd in ("identify", "diagnose", "inspect"):
        assert main([cmd, str(path)]) == 1
        assert "'i0'] is 'abc'" in _one_error_line(capsys)
    assert ClosedLoopData  # the class the loop is checked in


def test_npz_metadata_not_utf8_is_one_line(tmp_path, capsys, amb_record):
    path = tmp_path / "latin1.npz"
    np.savez(path, metadata=np.array(b'{"format": "maglevid-recording", "note": "\xe9t\xe9"}'),
             y=amb_record.y, u=amb_record.u)  # fmt: skip
    assert main(["inspect", str(path)]) == 1
    assert "not UTF-8" in _one_error_line(capsys)


@pytest.fixture(scope="module")
def suspension_p1(tmp_path_factory):
    from maglevid.simulate.suspension import simulate_suspension

    data = simulate_suspension(p=1, duration=6.0, rng=1)
    return write_recording(data, tmp_path_factory.mktemp("susp") / "s1.npz")


def test_unknown_method_option_is_one_line(capsys, suspension_p1):
    # On main: TypeError: fit_pem() got an unexpected keyword argument 'order'.
    assert main(["identify", str(suspension_p1), "--method", "pem", "--option", "order=3"]) == 1
    line = _one_error_line(capsys)
    assert "method 'pem' has no option 'order'" in line and "na" in line


def test_indirect_on_a_transfer_function_controller_is_one_line(capsys, suspension_p1):
    # On main: KeyError 'A' (the suspension's controller is num/den, not A, B, C).
    # The record logs u and u_f with r = 0 (driven by noise alone): indirect has no
    # excitation to work with, and says so before the controller's form matters.
    assert main(["identify", str(suspension_p1), "--method", "indirect"]) == 1
    assert "no excitation in this record" in _one_error_line(capsys)


# -- silent wrong answers ---------------------------------------------------------------
def test_excitation_not_applied_is_refused(tmp_path, capsys, amb_record):
    # u logged as the feedback alone (u = u_f) while r is logged as if applied.
    # On main: "No significant change, all checks passed", R1 = -1.3e7 ohm.
    bad = amb_record.replace(u=amb_record.u_f)
    rec = write_recording(bad, tmp_path / "no_r.npz")
    assert main(["--json", "diagnose", str(rec)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["verdict_code"] == "cannot_diagnose"
    assert "u equals u_f: the excitation r was not applied" in out["verdict"]
    assert main(["identify", str(rec)]) == 1
    assert "u equals u_f" in _one_error_line(capsys)


def test_identify_runs_the_quality_gate(tmp_path, capsys, amb_record):
    short = write_recording(amb_record.segment(0, 500), tmp_path / "short.npz")
    assert main(["identify", str(short)]) == 1
    assert "too short" in _one_error_line(capsys)
    assert main(["identify", str(short), "--force"]) == 0
    out = capsys.readouterr().out
    assert "warning: quality gate failed" in out and "too short" in out


def test_falling_rotor_is_refused_by_identify(tmp_path, capsys, amb_record):
    # The rotor drifts to the retainer bearing: |x| beyond half the gap.
    x0 = amb_record.loop["operating_point"]["x0"]
    y = np.array(amb_record.y)
    y[:, 0] += np.linspace(0.0, 0.9 * x0, y.shape[0])
    rec = write_recording(amb_record.replace(y=y), tmp_path / "fall.npz")
    assert main(["identify", str(rec)]) == 1
    assert "levitation was lost" in _one_error_line(capsys)


def test_misaligned_record_is_refused_by_identify(tmp_path, capsys, amb_record):
    # y one control period late against u (a logging misalignment): the stated
    # controller no longer reproduces u_f. On main: R1 = -217 ohm, exit 0.
    d = amb_record
    y = np.roll(np.array(d.y), 1, axis=0)
    rec = write_recording(d.replace(y=y), tmp_path / "late.npz")
    assert main(["identify", str(rec)]) == 1
    assert "inconsistent with the stated controller" in _one_error_line(capsys)


def test_gap_in_m_labelled_mm_is_refused(tmp_path, capsys, amb_record):
    # A CSV whose side-car says the gap is in mm while the values are metres.
    # On main: accepted, diagnosed.
    rec = write_recording(amb_record, tmp_path / "g.csv")
    side = tmp_path / "g.json"
    desc = json.loads(side.read_text(encoding="utf-8"))
    desc["signals"]["y"]["units"][0] = "mm"
    side.write_text(json.dumps(desc), encoding="utf-8")
    assert main(["--json", "diagnose", str(rec)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["verdict_code"] == "cannot_diagnose"
    assert "is in 'mm'" in out["verdict"] and "look like metres" in out["verdict"]
    assert main(["identify", str(rec)]) == 1
    assert "look like metres" in _one_error_line(capsys)


def test_gap_in_mm_labelled_m_is_refused(tmp_path, capsys, amb_record):
    y = np.array(amb_record.y)
    y[:, 0] *= 1e3 * 300  # millimetres of a large motion, labelled m
    rec = write_recording(amb_record.replace(y=y), tmp_path / "mm.npz")
    assert main(["identify", str(rec)]) == 1
    assert "probably logged in mm" in _one_error_line(capsys)


def test_text_log_timed_in_ms_read_as_s_is_refused(tmp_path, capsys, amb_record):
    # A user's log whose time column is in ms while the mapping says s: dt comes out
    # 1000 times too long (0.1 s for the bearing's 0.1 ms). On main: accepted.
    d = amb_record
    t_ms = np.arange(d.n_samples) * d.dt * 1e3
    cols = np.column_stack([t_ms, d.y, d.u, d.r, d.u_f])
    log = tmp_path / "bearing.txt"
    header = "t,x,i1,i2,u1,u2,r1,r2,uf1,uf2"
    np.savetxt(log, cols, delimiter=",", header=header, comments="", fmt="%.17g")
    loop = {k: d.loop[k] for k in ("nominal", "operating_point")}
    mapping = {
        "format": "text",
        "text": {"delimiter": "comma", "header": True},
        "time": {"column": "t", "unit": "s"},
        "y": [{"column": c, "unit": u} for c, u in (("x", "m"), ("i1", "A"), ("i2", "A"))],
        "u": [{"column": "u1", "unit": "V"}, {"column": "u2", "unit": "V"}],
        "r": [{"column": "r1", "unit": "V"}, {"column": "r2", "unit": "V"}],
        "u_f": [{"column": "uf1", "unit": "V"}, {"column": "uf2", "unit": "V"}],
        "loop": json.loads(
            json.dumps(loop, default=lambda o: o.tolist() if hasattr(o, "tolist") else dict(o))
        ),
    }
    mfile = tmp_path / "map.json"
    mfile.write_text(json.dumps(mapping), encoding="utf-8")
    assert main(["identify", str(log), "--mapping", str(mfile)]) == 1
    line = _one_error_line(capsys)
    assert "dt = 0.1 s" in line and "ms read as s" in line
    # The same log with the right unit passes the check, at the bearing's 0.1 ms.
    from maglevid.diagnose.checks import check_sample_time
    from maglevid.io import read_recording

    mapping["time"]["unit"] = "ms"
    mfile.write_text(json.dumps(mapping), encoding="utf-8")
    data = read_recording(log, mapping=str(mfile))
    assert data.dt == pytest.approx(d.dt, rel=1e-9) and check_sample_time(data).passed


def test_convert_never_over_its_mapping(tmp_path, capsys, amb_record):
    rec = write_recording(amb_record, tmp_path / "x.npz")
    mapping = tmp_path / "map.csv"  # an odd name, but a file this command reads
    mapping.write_text("{}", encoding="utf-8")
    argv = ["-q", "convert", str(rec), str(mapping), "--mapping", str(mapping), "--overwrite"]
    assert main(argv) == 1
    assert "it is an input" in _one_error_line(capsys)
    assert mapping.read_text(encoding="utf-8") == "{}"


def test_streamed_identify_runs_the_quality_gate(tmp_path, capsys, amb_record):
    pytest.importorskip("pyarrow")
    short = write_recording(amb_record.segment(0, 500), tmp_path / "short.parquet")
    assert main(["identify", str(short), "--stream"]) == 1
    assert "too short" in _one_error_line(capsys)


def test_fail_on_fault_tells_a_dead_sensor_from_a_healthy_bearing(tmp_path, capsys, amb_record):
    # "Cannot diagnose" exited 0 with --fail-on-fault, as a healthy bearing does (found
    # from outside, issue 16, thirteenth session): now 4.
    y = np.array(amb_record.y, copy=True)
    y[:, 0] = 0.0  # the displacement sensor dead
    rec = write_recording(amb_record.replace(y=y), tmp_path / "dead.npz")
    assert main(["-q", "diagnose", str(rec), "--fail-on-fault"]) == 4
    assert "Cannot diagnose" in capsys.readouterr().out
    assert main(["-q", "diagnose", str(rec)]) == 0  # without the flag, as before


def test_identify_warns_on_coil_values_no_bearing_has(tmp_path, capsys, amb_record):
    # A user's own file timed in ms while read as s (no stated controller period or
    # nominal plant to check dt against): identify printed R1 = 1.75e-8 ohm +- 0.4 % as a
    # result (found from outside, issue 16, fourteenth session). It now warns.
    import dataclasses

    op = dict(amb_record.loop["operating_point"])
    rec = dataclasses.replace(amb_record, dt=amb_record.dt * 1000, loop={"operating_point": op})
    path = write_recording(rec, tmp_path / "ms.npz")
    assert main(["--json", "identify", str(path)]) == 0
    warnings = json.loads(capsys.readouterr().out)["warnings"]
    assert any("no magnetic bearing's coil or amplifier" in w and "seconds" in w for w in warnings)
    assert main(["--json", "identify", str(write_recording(amb_record, tmp_path / "ok.npz"))]) == 0
    ok = json.loads(capsys.readouterr().out).get("warnings", [])
    assert not any("coil or amplifier" in w or "not positive" in w for w in ok)


def test_identify_warns_on_signs_and_amplifier_gains_no_bearing_has(tmp_path, capsys, amb_record):
    # x logged with the other sign printed ki1 = -494, x0 = -3.5e-4 m, K1 < 0, and u in mV
    # kw1 = 0.001 V/V, without a word (found from outside, seventeenth session).
    y = np.array(amb_record.y, copy=True)
    y[:, 0] *= -1.0
    path = write_recording(amb_record.replace(y=y), tmp_path / "x_sign.npz")
    main(["--json", "identify", str(path), "--force"])
    warnings = json.loads(capsys.readouterr().out).get("warnings", [])
    assert any("not positive" in w and "x is probably logged with the opposite sign" in w
               for w in warnings), warnings  # fmt: skip
    from maglevid.plants.amb import implausible_parameters

    (w,) = implausible_parameters({"R1": 17.5, "kw1": 0.001, "kw2": 1.0})
    assert w.startswith("kw1 = 0.001: no magnetic bearing's coil or amplifier")
    (w,) = implausible_parameters({"R1": -2.1e-5, "kw1": 1.0})
    assert "R1 = -2.1e-05: not positive" in w and "other units than the rest" in w
    assert implausible_parameters({"R1": 17.5, "ki1": 490.0, "x0": 3.5e-4, "kw1": 48.0}) == []


def test_identify_warns_when_the_fit_did_not_converge(tmp_path, capsys, amb_record):
    # A fit stopped before its optimum was printed as a normal result table with 95 %
    # intervals, "did not converge" only in a note at the end (found from outside, issue
    # 16, fourteenth session). Forced here by one scoring iteration.
    path = write_recording(amb_record, tmp_path / "x.npz")
    argv = ["--json", "identify", str(path), "--method", "ml", "--option", "max_iter=1"]
    assert main(argv) == 0
    warnings = json.loads(capsys.readouterr().out).get("warnings", [])
    assert any("did not converge" in w and "intervals mean nothing" in w for w in warnings)


def test_identify_prints_the_units(tmp_path, capsys, amb_record):
    # The text table had no unit column for any method (the README promises tables with
    # units; found from outside, issue 16, fourteenth session): now a column and a
    # "units" field in the JSON, from the plant kind's table (PARAMETER_INFO).
    path = write_recording(amb_record, tmp_path / "x.npz")
    assert main(["identify", str(path), "-q"]) == 0
    text = capsys.readouterr().out
    assert next(ln for ln in text.splitlines() if ln.split()[:1] == ["parameter"]).endswith("unit")
    assert next(ln for ln in text.splitlines() if ln.split()[:1] == ["R1"]).endswith("Ω")
    assert main(["--json", "identify", str(path), "-q"]) == 0
    units = json.loads(capsys.readouterr().out)["units"]
    assert units["R1"] == "Ω" and units["x0"] == "m"
