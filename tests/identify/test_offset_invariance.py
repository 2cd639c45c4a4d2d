"""Every AMB fit is invariant to constant offsets in y, u, u_f and r (issue 12).

A real recording carries the operating point it settled at (a faulty bearing
with the nominal bias settles away from the nominal one) and possibly absolute
levels (coil currents, bias voltages). The identified dynamics must not depend
on those constants. Reference: the same recording without the shift; the
estimates agree to rounding (rtol 1e-7: the shifted columns lose
``log10(offset / signal)`` ~ 3-4 digits in the QR against the constant column).
"""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.identify.arx import solve_linear_regression
from maglevid.identify.physical import to_physical_coordinates
from maglevid.identify.registry import get_method
from maglevid.identify.streaming import fit_physical_streamed, fit_subspace_streamed
from maglevid.physics.amb import AMBParameters, v_from_matrices
from maglevid.simulate.amb import simulate_amb_loop

NOM = AMBParameters.nominal()
# y: absolute position 3 um off, absolute currents (+ i0); u, u_f: the bias
# voltages on top; r: an excitation with a DC level.
DY = np.array([3e-6, 0.5, 0.5])
DUF = np.array([8.75, 8.75])
DR = np.array([0.2, -0.1])


@pytest.fixture(scope="module")
def records():
    d = simulate_amb_loop(
        NOM.with_fault(R2=1.05), nominal=NOM, plant_model="nonlinear", n_samples=6000,
        noise_std=(1e-9, 1e-6, 1e-6), rng=11,
    )  # fmt: skip
    shifted = d.replace(
        y=np.asarray(d.y) + DY,
        u_f=np.asarray(d.u_f) + DUF,
        r=np.asarray(d.r) + DR,
        u=np.asarray(d.u) + DUF + DR,
    )
    return d, shifted


def _v(res):
    return np.array([res.parameters[f"v{i}"] for i in range(1, 10)])


def _se(res):
    se = res.std_errors()
    return np.array([se[f"v{i}"] for i in range(1, 10)])


CASES = [
    ("physical", {"estimator": "ls"}),
    ("physical", {"estimator": "iv", "instruments": "loop"}),
    ("physical", {"estimator": "iv", "instruments": "lags"}),
    ("deadbeat-arx", {}),
    ("deadbeat-iv", {}),
    ("okid-era", {}),
]


@pytest.mark.parametrize("method, options", CASES, ids=lambda c: str(c))
def test_regression_fits_ignore_offsets(records, method, options):
    d, s = records
    a, b = get_method(method)(d, **options), get_method(method)(s, **options)
    np.testing.assert_allclose(_v(b), _v(a), rtol=1e-7)
    # Standard errors: delta method by finite differences whose steps follow the
    # coefficients; through ERA's SVD a 1e-9 change of the coefficients moves them
    # by up to 4e-4 (the noise floor of the delta method, cf. test_streaming.py).
    np.testing.assert_allclose(_se(b), _se(a), rtol=1e-3 if method == "okid-era" else 1e-5)


@pytest.mark.parametrize("method", ["moesp", "n4sid"])
def test_subspace_in_physical_coordinates_ignores_offsets(records, method):
    d, s = records
    a = get_method(method)(d, order=4, horizon=10)
    b = get_method(method)(s, order=4, horizon=10)
    va, _ = v_from_matrices(*_ab(a))
    vb, _ = v_from_matrices(*_ab(b))
    np.testing.assert_allclose(vb, va, rtol=1e-7)
    # and streamed (two passes: means, then statistics) equals in memory
    c = fit_subspace_streamed(s, algorithm=method, chunk_size=1500, order=4, horizon=10)
    vc, _ = v_from_matrices(*_ab(c))
    np.testing.assert_allclose(vc, vb, rtol=1e-7)
    np.testing.assert_allclose(c.extras["operating_point_means"]["y"], np.mean(s.y, axis=0))


def _ab(res):
    _, cont = to_physical_coordinates(res.model)
    return cont.A, cont.B


@pytest.mark.parametrize("instruments", ["loop", "lags"])
def test_streamed_physical_ignores_offsets_and_equals_in_memory(records, instruments):
    d, s = records
    ref = get_method("physical")(d, instruments=instruments)
    got = fit_physical_streamed(s, chunk_size=1700, instruments=instruments)
    np.testing.assert_allclose(_v(got), _v(ref), rtol=1e-7)
    np.testing.assert_allclose(_se(got), _se(ref), rtol=1e-5)


def test_intercept_equals_an_explicit_constant_regressor():
    # Frisch-Waugh-Lovell: the intercept option gives the slopes, the constant and
    # the slopes' covariance of the regression with a column of ones (also an
    # instrument for IV).
    rng = np.random.default_rng(0)
    N = 3000
    Z = rng.standard_normal((N, 3))
    Phi = Z @ rng.standard_normal((3, 3)) + 0.3 * rng.standard_normal((N, 3))
    Y = (
        Phi @ np.array([[1.0, 2], [3, -1], [0.5, 0.2]])
        + [5.0, -2]
        + 0.1 * rng.standard_normal((N, 2))
    )
    ones = np.ones((N, 1))
    for inst in (None, Z):
        f = solve_linear_regression(Y, Phi, instruments=inst, intercept=True, hac_lags=1)
        z1 = None if inst is None else np.hstack([inst, ones])
        g = solve_linear_regression(Y, np.hstack([Phi, ones]), instruments=z1, hac_lags=1)
        np.testing.assert_allclose(f.coefficients, g.coefficients[:, :3], rtol=1e-12)
        np.testing.assert_allclose(f.intercept, g.coefficients[:, 3], rtol=1e-12)
        keep = np.r_[0:3, 4:7]
        np.testing.assert_allclose(f.covariance, g.covariance[np.ix_(keep, keep)], rtol=1e-10)
        np.testing.assert_allclose(f.residuals, g.residuals, atol=1e-12)
