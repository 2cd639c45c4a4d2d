"""The block-recursion kernel equals the plain loop."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from maglevid.exceptions import DataError, ModelError
from maglevid.lti import StateSpace
from maglevid.simulate import kernel as kmod
from maglevid.simulate.kernel import simulate_lti


def _random_stable(rng, n=9, m=5, p=5, radius=0.998):
    M = rng.standard_normal((n, n))
    A = M * (radius / np.max(np.abs(np.linalg.eigvals(M))))
    return StateSpace(
        A,
        rng.standard_normal((n, m)),
        rng.standard_normal((p, n)),
        rng.standard_normal((p, m)),
        1.0,
    )


@pytest.mark.parametrize("N", [65, 1000, 5003, 20000])
@pytest.mark.parametrize("L", [2, 7, 16, 32])
def test_block_equals_loop(rng, N, L):
    sys = _random_stable(rng)
    w = rng.standard_normal((N, sys.nu))
    x0 = rng.standard_normal(sys.nx)
    y_loop, xf_loop = simulate_lti(sys, w, x0=x0, kernel="loop")
    y_blk, xf_blk = simulate_lti(sys, w, x0=x0, kernel="block", block_size=L)
    # Same sums, grouped differently: round-off only. 1e-10 relative to the signal scale
    # (we see ~1e-14); the stated target of the fast kernel.
    scale = np.abs(y_loop).max()
    np.testing.assert_allclose(y_blk, y_loop, rtol=0, atol=1e-10 * scale)
    np.testing.assert_allclose(xf_blk, xf_loop, rtol=0, atol=1e-10 * np.abs(xf_loop).max())


def test_block_on_the_amb_loop(rng):
    # The real use: the AMB closed loop (states of very different scales).
    from maglevid.physics.amb import AMBParameters, amb_state_space
    from maglevid.simulate.amb import default_amb_controller, default_amb_observer
    from maglevid.simulate.loop import closed_loop_system

    nom = AMBParameters.nominal()
    sys = closed_loop_system(
        amb_state_space(nom.with_fault(R1=1.2, K1=0.9), 1e-4),
        default_amb_observer(nom, 1e-4),
        default_amb_controller(nom, 1e-4),
    )
    w = rng.standard_normal((30000, 5)) * np.array([1.0, 1.0, 1e-7, 1e-4, 1e-4])
    y_loop, _ = simulate_lti(sys, w, kernel="loop")
    y_blk, _ = simulate_lti(sys, w, kernel="auto")
    for j in range(sys.ny):  # per channel: x in um, currents in mA, volts
        scale = np.abs(y_loop[:, j]).max()
        np.testing.assert_allclose(y_blk[:, j], y_loop[:, j], rtol=0, atol=1e-10 * scale)


def test_short_and_doc_example():
    sys = StateSpace([[0.5]], [[1.0]], [[1.0]], dt=1.0)
    y, xf = simulate_lti(sys, np.ones(4))
    np.testing.assert_allclose(y.ravel(), [0.0, 1.0, 1.5, 1.75], rtol=1e-15)
    assert xf[0] == pytest.approx(1.875, rel=1e-15)


def test_fallback_to_loop_when_spot_check_fails(rng, monkeypatch, caplog):
    sys = _random_stable(rng, n=3, m=1, p=1)
    w = rng.standard_normal((500, 1))
    ref, _ = simulate_lti(sys, w, kernel="loop")
    real_block = kmod._block

    def broken(*args, **kw):
        out, zf, Zb = real_block(*args, **kw)
        return out * (1 + 1e-6), zf, Zb  # a wrong answer the spot check must catch

    monkeypatch.setattr(kmod, "_block", broken)
    with caplog.at_level(logging.WARNING, logger="maglevid.simulate.kernel"):
        y, _ = simulate_lti(sys, w, kernel="block")
    np.testing.assert_array_equal(y, ref)
    assert "spot check" in caplog.text


def test_validation():
    sys = StateSpace([[0.5]], [[1.0]], [[1.0]], dt=1.0)
    with pytest.raises(DataError, match="kernel"):
        simulate_lti(sys, np.ones(3), kernel="fast")
    with pytest.raises(DataError, match="shape"):
        simulate_lti(sys, np.ones((3, 2)))
    with pytest.raises(ModelError, match="discrete"):
        simulate_lti(StateSpace([[0.5]], [[1.0]], [[1.0]]), np.ones(3))
    with pytest.raises(DataError, match="x0"):
        simulate_lti(sys, np.ones(3), x0=[1.0, 2.0])
