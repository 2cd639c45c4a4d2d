"""ERA: a realization reproduces the Markov parameters, poles included (unstable too)."""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.exceptions import DataError, IdentificationError
from maglevid.identify.era import block_hankel, realize_era
from maglevid.lti import StateSpace
from maglevid.physics.amb import AMBParameters, amb_state_space


def test_era_realizes_the_unstable_bearing():
    true = amb_state_space(AMBParameters.nominal(), 1e-4)
    Y = true.markov(30)
    est, s = realize_era(
        Y, order=4, rows=8, cols=8, dt=1e-4, output_scale=[1e-6, 1e-3, 1e-3], input_scale=[1, 1]
    )
    # Basis-invariant comparisons: Markov parameters and poles (noise-free: ~1e-8).
    np.testing.assert_allclose(est.markov(30), Y, rtol=1e-7, atol=1e-9 * np.abs(Y).max())
    np.testing.assert_allclose(
        np.sort_complex(est.poles()), np.sort_complex(true.poles()), rtol=1e-9
    )
    assert s[4] < 1e-8 * s[0]  # four states
    assert max(abs(est.poles())) > 1  # unstable, not stabilised


def test_era_scaling_does_not_change_the_system(rng):
    A = np.diag([0.9, -0.5, 0.3])
    true = StateSpace(A, rng.standard_normal((3, 2)), rng.standard_normal((2, 3)), dt=1.0)
    Y = true.markov(12)
    a, _ = realize_era(Y, order=3)
    b, _ = realize_era(Y, order=3, output_scale=[10.0, 0.1], input_scale=[3.0, 0.5])
    np.testing.assert_allclose(a.markov(12), b.markov(12), atol=1e-10)


def test_era_refuses_an_order_the_data_do_not_have(rng):
    true = StateSpace([[0.5]], [[1.0]], [[1.0]], dt=1.0)
    with pytest.raises(IdentificationError, match="rank"):
        realize_era(true.markov(10), order=2, rows=3, cols=3)
    with pytest.raises(DataError, match="Markov parameters"):
        block_hankel(true.markov(3), rows=3, cols=3)
