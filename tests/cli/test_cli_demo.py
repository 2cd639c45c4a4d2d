"""``maglevid demo --out DIR`` (interim): recording + plot of a faulty bearing."""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.cli.main import main


def test_demo_writes_recording_and_png(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    out = tmp_path / "demo"
    code = main(["demo", "--out", str(out), "--n-samples", "1500", "--fault", "K1=0.9", "-q"])
    assert code == 0
    png = out / "signals.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rec = out / "recording.npz"
    assert rec.exists() and rec.stat().st_size > 0
    with np.load(rec, allow_pickle=False) as z:
        assert len(z.files) > 0
    text = capsys.readouterr().out
    assert "signals.png" in text and "K1" in text
