"""Streamed identification equals the in-memory one (records larger than memory).

Tolerances. Every row, instrument and product of a streamed fit is the one the
in-memory fit uses; only the order of summation (QR block boundaries, chunk
joins of the loop simulation and of the lagged sums) differs. So:

* coefficients, v1..v9 and the physical parameters agree to rounding,
  ``rtol=1e-9`` (measured ~1e-11 on 5e4 samples);
* the coefficient covariance agrees to ``rtol=1e-8`` (white-noise covariance,
  measured 1e-14) and ``1e-4`` with the lag-window ("hac") covariance, whose
  truncated-kernel sum nearly cancels on this plant (moving the in-memory pass
  boundaries alone changes it by 1e-6);
* the standard errors of the *physical* parameters agree to ``rtol=1e-3``:
  they come from a finite-difference Jacobian (``identify/uncertainty.py``)
  whose steps follow the coefficients, and a 4e-12 change of the coefficients
  (in memory, by moving the QR block boundaries) moves ``se(Ls2)`` by 2.4e-5.
  That is the noise floor of the delta method, not of streaming.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator

import numpy as np
import pytest

from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError
from maglevid.identify.arx import RegressionAccumulator, solve_linear_regression
from maglevid.identify.physical import fit_physical
from maglevid.identify.streaming import (
    fit_physical_streamed,
    fit_subspace_streamed,
    identify_streamed,
)
from maglevid.identify.subspace import fit_moesp, fit_n4sid
from maglevid.physics.amb import AMBParameters
from maglevid.simulate import simulate_amb_loop

#: Paper-like measurement noise [m, A, A] (benchmarks/bench_amb_mc.py).
NOISE = (1e-10, 3e-6, 3e-6)


@pytest.fixture(scope="module")
def record() -> ClosedLoopData:
    nom = AMBParameters.nominal()
    return simulate_amb_loop(
        nom.with_fault(R1=1.2, kw1=1.2),
        nominal=nom,
        n_samples=30_000,
        rng=3,
        noise_std=NOISE,
        plant_model="linear",
    )


def _values(res, kind: str = "parameters") -> np.ndarray:
    d = res.parameters if kind == "parameters" else res.std_errors()
    return np.array([d[k] for k in res.parameter_names])


@pytest.mark.parametrize(
    "options",
    [
        {"estimator": "ls"},
        {"estimator": "iv"},  # loop instruments: simulated chunk by chunk
        {"estimator": "iv", "instruments": "lags", "instrument_lags": 12},
    ],
    ids=["ls", "iv-loop", "iv-lags"],
)
def test_physical_streamed_equals_in_memory(record, options):
    ref = fit_physical(record, **options)
    got = fit_physical_streamed(record, chunk_size=4_099, **options)
    np.testing.assert_allclose(_values(got), _values(ref), rtol=1e-9)
    np.testing.assert_allclose(
        got.extras["coefficients"], ref.extras["coefficients"], rtol=1e-9, atol=0
    )
    np.testing.assert_allclose(
        got.extras["coefficient_std_errors"], ref.extras["coefficient_std_errors"], rtol=1e-8
    )
    np.testing.assert_allclose(_values(got, "se"), _values(ref, "se"), rtol=1e-3)
    np.testing.assert_allclose(got.model.A, ref.model.A, rtol=1e-9, atol=1e-12)
    for key, value in ref.fit.items():
        # structure_residual is a ratio of near-cancelling elements of A_c: rounding x 1e3.
        rel = 1e-6 if key == "structure_residual" else 1e-9
        assert got.fit[key] == pytest.approx(value, rel=rel, abs=1e-12), key
    assert got.n_samples == ref.n_samples
    assert got.options == ref.options
    assert got.residuals is None and ref.residuals is not None
    assert any(n.startswith("streamed: 30000 samples in 8 chunk(s)") for n in got.notes)


def test_physical_streamed_hac_covariance(record):
    ref = fit_physical(record, estimator="iv", covariance="hac")
    got = fit_physical_streamed(record, chunk_size=10_007, estimator="iv", covariance="hac")
    np.testing.assert_allclose(_values(got), _values(ref), rtol=1e-9)
    np.testing.assert_allclose(
        got.extras["coefficient_std_errors"], ref.extras["coefficient_std_errors"], rtol=1e-4
    )


def test_chunks_shorter_than_the_lags_and_the_skip():
    # Chunks of 7 samples: shorter than skip=10 and than the 12 instrument lags, so
    # rows straddle several chunk joins and the first chunks give no rows at all.
    nom = AMBParameters.nominal()
    d = simulate_amb_loop(nom, n_samples=1_500, rng=5, noise_std=NOISE, plant_model="linear")
    for options in ({"estimator": "ls"}, {"instruments": "lags", "instrument_lags": 12}):
        ref = fit_physical(d, **options)
        got = fit_physical_streamed(d, chunk_size=7, **options)
        np.testing.assert_allclose(_values(got), _values(ref), rtol=1e-9)


def test_source_callable_is_read_twice_and_must_repeat(record):
    calls = []

    def chunks() -> Iterator[ClosedLoopData]:
        calls.append(1)
        n = 20_000 if len(calls) == 1 else 19_000
        for a in range(0, n, 5_000):
            yield ClosedLoopData(
                y=record.y[a : a + 5_000][: n - a],
                u=record.u[a : a + 5_000][: n - a],
                r=record.r[a : a + 5_000][: n - a],
                dt=record.dt,
                loop=record.loop,
            )

    with pytest.raises(DataError, match="same data both times"):
        fit_physical_streamed(chunks)
    assert len(calls) == 2


@pytest.mark.parametrize("fit, algorithm", [(fit_moesp, "moesp"), (fit_n4sid, "n4sid")])
def test_subspace_streamed_equals_in_memory(record, fit, algorithm):
    # Both work on deviations from the record's means (issue 12): the streamed
    # fit removes the means found by its first pass.
    y, u = np.asarray(record.y), np.asarray(record.u)
    ref = fit(y - y.mean(axis=0), u - u.mean(axis=0), order=4, horizon=20, dt=record.dt)
    got = fit_subspace_streamed(record, algorithm=algorithm, chunk_size=3_001, order=4, horizon=20)
    # Basis-invariant: Markov parameters and poles (rounding, rtol 1e-9).
    np.testing.assert_allclose(
        np.sort_complex(got.model.poles()), np.sort_complex(ref.model.poles()), rtol=1e-9
    )
    h_ref = ref.model.markov(10)
    np.testing.assert_allclose(got.model.markov(10), h_ref, atol=1e-9 * np.max(np.abs(h_ref)))
    assert got.model.dt == record.dt
    assert got.options["horizon"] == 20


def test_identify_streamed_dispatch_and_errors(record):
    res = identify_streamed(record, "physical", chunk_size=10_000, estimator="ls")
    assert res.method == "physical"
    with pytest.raises(DataError, match="cannot be streamed"):
        identify_streamed(record, "deadbeat-arx")
    with pytest.raises(DataError, match="source"):
        fit_physical_streamed(np.zeros((10, 3)))  # type: ignore[arg-type]
    with pytest.raises(DataError, match="no chunks"):
        fit_physical_streamed(lambda: iter(()))
    with pytest.raises(DataError, match="chunk_size"):
        fit_physical_streamed(record, chunk_size=1)
    with pytest.raises(DataError, match="samples"):
        fit_physical_streamed(
            ClosedLoopData(
                y=record.y[:30], u=record.u[:30], r=record.r[:30], dt=record.dt, loop=record.loop
            )
        )


def test_regression_accumulator_in_chunks_equals_one_shot(rng):
    N = 5_000
    Z = rng.standard_normal((N, 4))
    Phi = Z[:, :3] + 0.5 * rng.standard_normal((N, 3))
    Y = Phi @ rng.standard_normal((3, 2)) + 0.1 * rng.standard_normal((N, 2))
    ref = solve_linear_regression(Y, Phi, instruments=Z, hac_lags=2)
    acc = RegressionAccumulator(3, 2, nz=4)
    cuts = [0, 1, 700, 701, 2_999, N]
    for a, b in itertools.pairwise(cuts):
        acc.update(Y[a:b], Phi[a:b], Z[a:b])
    acc.solve(hac_lags=2)
    for a, b in itertools.pairwise(cuts):
        acc.update_residuals(Y[a:b], Phi[a:b], Z[a:b])
    got = acc.finish()
    np.testing.assert_allclose(got.coefficients, ref.coefficients, rtol=1e-12)
    # The lag-window sum cancels less here (white errors): rounding, rtol 1e-10.
    np.testing.assert_allclose(got.covariance, ref.covariance, rtol=1e-10)
    np.testing.assert_allclose(
        got.residual_sum_of_squares, np.sum(ref.residuals**2, axis=0), rtol=1e-12
    )
    assert got.residuals is None and got.n_rows == N and got.estimator == "2sls"


def test_regression_accumulator_order_of_calls(rng):
    acc = RegressionAccumulator(2, 1)
    X = rng.standard_normal((50, 2))
    acc.update(X[:, :1], X)
    with pytest.raises(DataError, match="solve"):
        acc.update_residuals(X[:, :1], X)
    acc.solve()
    with pytest.raises(DataError, match="first pass is over"):
        acc.update(X[:, :1], X)
    acc.update_residuals(X[:20, :1], X[:20])
    with pytest.raises(DataError, match="second pass saw 20"):
        acc.finish()
    with pytest.raises(DataError, match="shape"):
        acc.update_residuals(X[:, :1], X[:, :1])
    bad = X.copy()
    bad[3, 1] = np.inf
    acc2 = RegressionAccumulator(2, 1)
    with pytest.raises(DataError, match="non-finite"):
        acc2.update(X[:, :1], bad)
