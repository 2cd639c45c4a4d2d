"""Non-finite numbers on the command line: text that prints them, JSON that stays JSON.

Each case is one a user met (each failed before the fix):

* a UAQ levitator log whose current column is constant gives PEM infinite standard
  errors; the text table raised ``ValueError: Unknown format code 'g' for object of
  type 'str'`` on the ``"inf"`` that the JSON-safe result holds;
* ``--json`` wrote the tokens ``NaN`` and ``Infinity`` (``inspect`` of a record with a
  1e300 sample: ``"std": Infinity``), which RFC 8259 does not allow and strict parsers
  (``JSON.parse``, ``jq``, Go, Rust) reject;
* ``identify --method list`` needed a recording it does not read;
* records too short or too large for the arithmetic leaked NumPy's RuntimeWarnings
  ("Mean of empty slice", "overflow encountered in square") above the one-line error.

The convention is the project's (:mod:`maglevid.jsonable`, docs/report.md): NaN
(unknown) is ``null``, +-inf is ``"inf"``/``"-inf"``, in every command's JSON.
"""

from __future__ import annotations

import json
import logging
import math

import numpy as np
import pytest

from maglevid.cli.identify import format_text
from maglevid.cli.main import main
from maglevid.io import write_recording
from maglevid.jsonable import to_json_text
from maglevid.physics.amb import AMBParameters
from maglevid.simulate.amb import simulate_amb_loop


def _strict_loads(text: str):
    """``json.loads`` that refuses NaN, Infinity and -Infinity, as RFC 8259 does."""

    def refuse(token: str):
        raise ValueError(f"not JSON (RFC 8259): {token}")

    return json.loads(text, parse_constant=refuse)


def _stderr_lines(capsys) -> list[str]:
    return [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]


@pytest.fixture(scope="module")
def amb_record():
    """A healthy bearing, 2000 control periods (the quality gate's minimum)."""
    return simulate_amb_loop(AMBParameters.nominal(), n_samples=2000, rng=17)


@pytest.fixture
def flat_current_log(shared_data, tmp_path):
    """The UAQ step log with its current column ``i`` set to 0.4000 A in every row
    (format kept: tab-separated, four decimals), as a user's edited copy."""
    src = shared_data / "maglev-uaq-levitador" / "dataset_escalon_20251217_205858.txt"
    lines = src.read_bytes().split(b"\n")
    header = next(ln for ln in lines if ln.startswith(b"# Columnas:"))
    col = header.split(b":", 1)[1].split().index(b"i")
    out = []
    for ln in lines:
        if ln and not ln.startswith(b"#"):
            fields = ln.split(b"\t")
            fields[col] = b"0.4000"
            ln = b"\t".join(fields)
        out.append(ln)
    path = tmp_path / "flat_i.txt"
    path.write_bytes(b"\n".join(out))
    return path


# -- defect 1: the text table prints "inf", never a traceback ------------------------------
def test_identify_text_prints_infinite_std_errors_of_a_flat_current(flat_current_log, capsys):
    # With i constant the input regressors b1, b2 are not identifiable: their variance
    # is infinite (cov = inv(Phi'Phi) of a singular Phi), a correct answer to print.
    # The quality gate names the dead channel first; --force identifies anyway.
    argv = ["identify", str(flat_current_log), "--mapping", "uaq-levitador",
            "--method", "pem", "--option", "input=y:1", "-q"]  # fmt: skip
    assert main(argv) == 1
    assert "constant channel(s): i = 0.4 throughout" in capsys.readouterr().err
    argv.append("--force")
    assert main(argv) == 0
    out = capsys.readouterr()
    assert "Traceback" not in out.err
    rows = {ln.split()[0]: ln.split() for ln in out.out.splitlines() if ln.startswith(" ")}
    assert rows["b1"][2] == "inf" and rows["b1"][3:] == ["[-inf,", "inf]"]
    assert math.isfinite(float(rows["a1"][2]))  # the identifiable ones keep their numbers
    # The same run as JSON: std errors "inf", the interval ["-inf", "inf"], strict JSON.
    assert main([*argv, "--json"]) == 0
    d = _strict_loads(capsys.readouterr().out)
    assert d["std_errors"]["b1"] == "inf" and d["ci95"]["b1"] == ["-inf", "inf"]


def test_identify_text_of_non_finite_values_of_every_kind():
    # What a JSON-safe result can hold where a number is expected: a float (also NaN
    # or inf), None (a NaN: unknown), "inf"/"-inf" (infinite). Every place prints.
    result = {
        "recording": "r.npz", "method": "pem", "n_samples": 10,
        "parameters": {"a": 1.5, "b": float("nan"), "c": float("inf")},
        "std_errors": {"a": "inf", "b": None, "c": float("nan")},
        "ci95": {"a": ["-inf", "inf"], "b": [None, None], "c": [1.0, "inf"]},
        "poles": {"re": [0.5, None, "inf"], "im": [0.0, "-inf", None]},
        "fit": {"one_step_fit_percent": None, "residual_rms": "inf"},
        "intersample_numerators": {"j": [1], "B": [[1.0, None]], "std_error": [["inf", None]]},
        "notes": [],
    }  # fmt: skip
    lines = format_text(result).splitlines()
    assert lines[4].split() == ["a", "1.5", "inf", "[-inf,", "inf]"]
    assert lines[5].split() == ["b", "nan", "nan"]  # unknown: no interval
    assert lines[6].split() == ["c", "inf", "nan", "[1,", "inf]"]
    assert lines[7] == "discrete poles: 0.5+0j, nan-infj, inf+nanj"
    assert lines[8:10] == ["fit one_step_fit_percent: nan", "fit residual_rms: inf"]
    assert lines[10] == "B_1 (z^0..z^-1): 1 ± inf, nan"


# -- defect 2: --json is always JSON -------------------------------------------------------
def test_json_writer_round_trips_nan_and_inf_through_a_strict_parser():
    value = {
        "nan": float("nan"), "inf": float("inf"), "-inf": -math.inf,
        "np": np.float64(np.nan), "array": np.array([1.0, np.nan, np.inf, -np.inf]),
        "complex": complex(np.nan, np.inf), "c_array": np.array([np.nan + 1j]),
        "nested": [{"x": (np.float32(np.inf), 2)}], "ok": 1.25,
    }  # fmt: skip
    got = _strict_loads(to_json_text(value, indent=2))
    assert got == {
        "nan": None, "inf": "inf", "-inf": "-inf", "np": None,
        "array": [1.0, None, "inf", "-inf"], "complex": {"re": None, "im": "inf"},
        "c_array": {"re": [None], "im": [1.0]}, "nested": [{"x": ["inf", 2]}], "ok": 1.25,
    }  # fmt: skip


def test_every_command_json_is_strict_even_with_nan_and_inf(monkeypatch, capsys):
    # The writer of main(), whatever a command returns: arrays, NumPy scalars, objects
    # with to_dict, all converted; a float token NaN/Infinity is never written.
    from maglevid.cli import inspect_cmd

    class Result:
        def to_dict(self):
            return {"fit": float("nan"), "se": np.array([np.inf])}

    def run(args):
        return {"std": float("inf"), "mean": np.float64("nan"), "r": Result(), "n": np.int64(3)}

    monkeypatch.setattr(inspect_cmd, "run", run)
    assert main(["inspect", "any.npz", "--json"]) == 0
    d = _strict_loads(capsys.readouterr().out)
    assert d == {"std": "inf", "mean": None, "r": {"fit": None, "se": ["inf"]}, "n": 3}


def test_inspect_json_of_a_record_with_a_1e300_sample(tmp_path, capsys, amb_record):
    # std of a channel holding 1e300 overflows to inf (1e600 > float max): "inf".
    y = np.array(amb_record.y)
    y[100, 0] = 1e300
    rec = write_recording(amb_record.replace(y=y), tmp_path / "big.npz")
    assert main(["inspect", str(rec), "--json"]) == 0
    out = capsys.readouterr()
    d = _strict_loads(out.out)
    x = d["signals"]["y"][0]
    assert x["max"] == 1e300 and x["std"] == "inf"
    assert "RuntimeWarning" not in out.err


# -- defect 3: --method list needs no recording --------------------------------------------
def test_method_list_without_a_recording(capsys):
    assert main(["identify", "--method", "list"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("deadbeat-arx ") and "\npem " in out
    assert main(["identify", "--method", "list", "--json"]) == 0
    assert "pem" in _strict_loads(capsys.readouterr().out)["methods"]
    assert main(["identify", "x.npz", "--method", "list", "-q"]) == 0  # as before
    assert capsys.readouterr().out.startswith("deadbeat-arx ")


def test_identify_without_a_recording_is_still_a_usage_error(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["identify", "--method", "pem"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "usage: maglevid identify" in err
    assert "the following arguments are required: recording" in err


# -- defect 4: no raw RuntimeWarning above the one clear line ------------------------------
# (pytest turns warnings into errors here, so a leaked RuntimeWarning fails these tests.)
def test_identify_a_50_sample_record_is_one_line(tmp_path, capsys, amb_record):
    rec = write_recording(amb_record.segment(0, 50), tmp_path / "short50.npz")
    assert main(["identify", str(rec), "-q"]) == 1
    lines = _stderr_lines(capsys)
    assert len(lines) == 1, lines
    assert lines[0].startswith("maglevid identify: error: cannot identify")
    assert "too short" in lines[0]


def test_identify_a_record_with_a_1e300_sample_is_one_line(tmp_path, capsys, amb_record):
    y = np.array(amb_record.y)
    y[100, 0] = 1e300
    rec = write_recording(amb_record.replace(y=y), tmp_path / "big.npz")
    assert main(["identify", str(rec), "-q"]) == 1
    lines = _stderr_lines(capsys)
    assert len(lines) == 1, lines
    assert "times the air gap" in lines[0]  # the unit check names the 1e300 sample


def test_numerical_warnings_are_in_the_verbose_log(
    tmp_path, capsys, caplog, amb_record, monkeypatch
):
    # Not lost: -v (log level INFO) shows each, one log line, from logger maglevid.cli.
    # (The short record's own "Mean of empty slice" is gone since the feedback check
    # stops short of an empty slice; one is raised here where that check ran.)
    import maglevid.diagnose.checks as checks

    real = checks.check_feedback_consistency

    def empty_mean(data, **kw):
        np.mean(np.array([]))  # RuntimeWarning: Mean of empty slice
        return real(data, **kw)

    monkeypatch.setattr(checks, "check_feedback_consistency", empty_mean)
    rec = write_recording(amb_record.segment(0, 50), tmp_path / "short50.npz")
    caplog.set_level(logging.INFO, logger="maglevid.cli")
    assert main(["-v", "identify", str(rec), "-q"]) == 1
    logged = [r.getMessage() for r in caplog.records if r.name == "maglevid.cli"]
    assert any(m.startswith("numerical warning") and "Mean of empty slice" in m for m in logged)
    assert "RuntimeWarning" not in capsys.readouterr().err


def test_a_short_record_message_has_no_nan_percent(tmp_path, capsys, amb_record):
    rec = write_recording(amb_record.segment(0, 50), tmp_path / "short50.npz")
    assert main(["identify", str(rec), "-q"]) == 1
    assert "nan %" not in capsys.readouterr().err
