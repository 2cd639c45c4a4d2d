"""``maglevid demo``: the main job from the command line (a short campaign)."""

from __future__ import annotations

import json

from maglevid.cli.main import main


def test_demo_command_prints_table_and_writes_outputs(tmp_path, capsys):
    out = tmp_path / "demo"
    code = main(["demo", "--out", str(out), "--weeks", "1", "--every", "7", "-q"])
    assert code == 0
    text = capsys.readouterr().out
    assert "AMB-1" in text and "first alarm" in text and "history:" in text
    assert (out / "history.sqlite").exists()
    assert (out / "signals.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert len(list((out / "recordings").glob("*/day-*.npz"))) == 6


def test_demo_json(tmp_path, capsys):
    code = main(["--json", "demo", "--out", str(tmp_path / "d"), "--weeks", "1", "--every", "7"])
    assert code == 0
    res = json.loads(capsys.readouterr().out)
    assert {r["machine"] for r in res["rows"]} == {"AMB-1", "AMB-2", "AMB-3"}
    assert all(r["verdict_code"] == "no_change" for r in res["rows"] if r["machine"] == "AMB-1")
