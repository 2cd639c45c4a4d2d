"""Excitation signals r(k) (eq. (16))."""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.exceptions import DataError
from maglevid.simulate.excitation import make_excitation


def test_gaussian_statistics_and_determinism():
    r = make_excitation(200_000, 2, std=[1.0, 0.5], rng=np.random.default_rng(5))
    assert r.shape == (200_000, 2)
    # std estimate of N = 2e5 samples has relative sd 1/sqrt(2N) = 0.16 %; 1 % is > 6 sd.
    np.testing.assert_allclose(r.std(axis=0), [1.0, 0.5], rtol=0.01)
    # channels independent: correlation within 5 sd (sd = 1/sqrt(N) = 0.0022)
    assert abs(np.corrcoef(r.T)[0, 1]) < 0.011
    again = make_excitation(200_000, 2, std=[1.0, 0.5], rng=np.random.default_rng(5))
    np.testing.assert_array_equal(r, again)


def test_prbs_levels_and_hold():
    r = make_excitation(10, 2, std=0.3, kind="prbs", hold=3, rng=np.random.default_rng(1))
    np.testing.assert_array_equal(np.unique(np.abs(r)), [0.3])
    for start in (0, 3, 6):  # held for 3 samples
        assert np.all(r[start : start + 3] == r[start])


@pytest.mark.parametrize(
    "kw",
    [
        {"std": [1.0, 2.0, 3.0]},
        {"std": -1.0},
        {"std": 1.0, "kind": "sine"},
        {"std": 1.0, "hold": 0},
    ],
)
def test_validation(kw):
    with pytest.raises(DataError):
        make_excitation(10, 2, rng=np.random.default_rng(0), **kw)
