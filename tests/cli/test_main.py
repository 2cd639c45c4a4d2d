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


def test_bad_method_option_is_one_clear_line(capsys):
    # Unknown --method is a DataError -> exit 1 with a single message, no traceback.
    code = main(["identify", "missing.npz", "--option", "novalue"])
    err = capsys.readouterr().err
    assert code == 1
    assert "error" in err and "Traceback" not in err
