"""The SLICOT adapter of the benchmarks (benchmarks/peers/ctrlsys_slicot.py).

Reference: the true poles of ``bench_subspace.make_system`` (0.9 e^{+-0.3j}, 0.5,
-0.3, set by construction); on noise-free data any consistent subspace method
recovers them to rounding.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
from benchmarks.bench_subspace import make_data, pole_error
from benchmarks.peers import PeerMissing, ctrlsys_slicot

# ctrlsys is in the dev extra (make test installs it): in CI this must run, not skip.
pytestmark = pytest.mark.skipif(
    not ctrlsys_slicot.available()[0] and os.environ.get("CI") != "true",
    reason="ctrlsys (SLICOT) not installed",
)


@pytest.mark.parametrize("method", sorted(ctrlsys_slicot.METHODS))
@pytest.mark.parametrize("horizon", [10, None])
def test_slicot_recovers_the_true_poles_on_noise_free_data(method, horizon):
    y, u, true = make_data(3000, 0.0)
    res = ctrlsys_slicot.identify(y, u, 4, horizon, method=method)
    assert pole_error(res.poles, true) < 1e-6
    assert res.inner_time_s > 0
    assert res.info["nobr"] == (horizon or ctrlsys_slicot.default_nobr(4)) == (horizon or 8)


def test_missing_ctrlsys_is_a_peer_missing(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "ctrlsys", None)  # import fails
    y, u, _ = make_data(500, 0.0)
    with pytest.raises(PeerMissing, match="pip install ctrlsys"):
        ctrlsys_slicot.identify(y, u, 4, 10)
    assert np.isfinite(y).all()


def test_kalman_gain_call_returns_the_same_model():
    """jobck='K' (what the benchmarks time: maglevid's default fit also returns the
    noise model) identifies the same A as jobck='N'; only K and Q, Ry, S are added."""
    y, u, true = make_data(3000, 0.1)
    with_k = ctrlsys_slicot.identify(y, u, 4, 10)
    alone = ctrlsys_slicot.identify(y, u, 4, 10, jobck="N")
    assert with_k.info["jobck"] == "K" and with_k.info["kalman_gain"] == "computed"
    assert alone.info["jobck"] == "N" and "kalman_gain" not in alone.info
    np.testing.assert_allclose(np.sort_complex(with_k.poles), np.sort_complex(alone.poles))
    assert pole_error(with_k.poles, true) < 0.05
    with pytest.raises(ValueError, match="jobck"):
        ctrlsys_slicot.identify(y, u, 4, 10, jobck="C")
