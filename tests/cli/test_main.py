"""The command-line entry point: help, usage errors, error lines instead of tracebacks."""

from __future__ import annotations

import json

import pytest

from maglevid.cli.main import main


def test_help_lists_commands(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "identify" in out and "simulate" in out and "closed" in out


def test_no_command_prints_help_and_returns_2(capsys):
    assert main([]) == 2
    assert "COMMAND" in capsys.readouterr().out


def test_method_list_json(capsys):
    assert main(["--json", "identify", "x.npz", "--method", "list"]) == 0
    assert "methods" in json.loads(capsys.readouterr().out)


def test_unknown_method_is_one_clear_line(capsys, tmp_path):
    # The recording exists, so the error can only come from the unknown --method:
    # a DataError that names the method and lists the valid ones, exit 1.
    from maglevid.data import ClosedLoopData
    from maglevid.io import write_recording

    rec = write_recording(
        ClosedLoopData(y=[0.0, 1, 2, 3], u=[1.0, 0, 1, 0], dt=0.1), tmp_path / "r.npz"
    )
    code = main(["identify", str(rec), "--method", "no-such-method"])
    err = capsys.readouterr().err
    assert code == 1
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "unknown method 'no-such-method'" in err and "physical" in err


def test_option_without_value_is_one_clear_line(capsys, tmp_path):
    from maglevid.data import ClosedLoopData
    from maglevid.io import write_recording

    rec = write_recording(
        ClosedLoopData(y=[0.0, 1, 2, 3], u=[1.0, 0, 1, 0], dt=0.1), tmp_path / "r.npz"
    )
    code = main(["identify", str(rec), "--option", "novalue"])
    err = capsys.readouterr().err
    assert code == 1 and "Traceback" not in err
    assert "--option 'novalue': expected KEY=VALUE" in err
