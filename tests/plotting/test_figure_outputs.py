"""Figures follow the rule of every maglevid output (issue 17): never over an
existing file without ``overwrite``, atomically, never over a folder."""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.data import ClosedLoopData
from maglevid.exceptions import FileFormatError
from maglevid.plotting.signals import plot_signals, save_figure


def test_figures_need_overwrite(tmp_path):
    import matplotlib.pyplot as plt

    data = ClosedLoopData(y=np.sin(np.arange(50.0)), u=np.cos(np.arange(50.0)), dt=0.01)
    png = tmp_path / "s.png"
    png.write_bytes(b"a user's picture")
    with pytest.raises(FileFormatError, match="exists; refusing"):
        plt.close(plot_signals(data, path=png))
    assert png.read_bytes() == b"a user's picture"
    plt.close(plot_signals(data, path=png, overwrite=True))
    assert png.read_bytes().startswith(b"\x89PNG")
    fig = plt.figure()
    try:
        with pytest.raises(FileFormatError, match="is a folder"):
            save_figure(fig, tmp_path, overwrite=True)
        out = save_figure(fig, tmp_path / "f.svg")
        assert out.read_text(encoding="utf-8").lstrip().startswith("<?xml")
    finally:
        plt.close(fig)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.svg", "s.png"]  # no temporaries
