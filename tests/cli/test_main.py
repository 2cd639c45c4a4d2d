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


def _leaf_parsers(parser, path=()):
    import argparse

    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield path, parser
    for action in subs:
        for name, child in action.choices.items():
            yield from _leaf_parsers(child, (*path, name))


def test_every_leaf_command_takes_json_and_quiet():
    # Issue 18: `simulate amb ... --json` and `reproduce gosiewski ... --json` were rejected.
    from maglevid.cli.main import build_parser

    leaves = list(_leaf_parsers(build_parser()))
    assert len(leaves) >= 10
    for path, p in leaves:
        assert {"--json", "--quiet", "-q"} <= set(p._option_string_actions), path


def test_json_after_a_nested_subcommand(tmp_path, capsys):
    out = tmp_path / "a.npz"
    argv = ["simulate", "amb", "--n-samples", "2000", "--out", str(out), "--json", "-q"]
    assert main(argv) == 0
    assert json.loads(capsys.readouterr().out)["n_samples"] == 2000


def test_method_list_has_one_described_line_per_method(capsys):
    from maglevid.identify.registry import available_methods

    assert main(["identify", "x.npz", "--method", "list"]) == 0
    # Issue 19: each method's declared options follow its line, indented; the
    # method lines themselves are unchanged (one per method, described).
    lines = [ln for ln in capsys.readouterr().out.strip().splitlines() if not ln[:1].isspace()]
    assert len(lines) == len(available_methods())
    for line in lines:
        name, _, description = line.partition("  ")
        assert name in available_methods() and len(description.strip()) > 20, line


def test_stages_are_shown_unless_quiet(tmp_path, capsys, monkeypatch):
    # Issue 18: long single steps (simulate, read, identify, diagnose, write) were
    # silent; a bar names the stage in progress (on a terminal: stderr is made one).
    import sys

    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    out = tmp_path / "a.npz"
    assert main(["simulate", "amb", "--n-samples", "2000", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "simulate amb" in err and "simulating" in err and "writing" in err
    assert main(["identify", str(out), "-q"]) == 0
    assert capsys.readouterr().err == ""
    assert main(["identify", str(out)]) == 0
    assert "identifying" in capsys.readouterr().err


def test_a_bar_leaves_no_thread_behind(monkeypatch):
    # tqdm's monitor thread outlived its bar; with a second thread alive the levitator's
    # candidate fits no longer fork onto the other cores (maglevid.parallel.start_method)
    import sys
    import threading

    from maglevid.cli._progress import progress, stages

    monkeypatch.setattr(sys.stderr, "isatty", lambda: True, raising=False)
    before = {t.name for t in threading.enumerate()}
    assert list(progress(range(3), desc="x")) == [0, 1, 2]
    assert list(stages(["a", "b"], desc="y")) == ["a", "b"]
    assert {t.name for t in threading.enumerate()} <= before
