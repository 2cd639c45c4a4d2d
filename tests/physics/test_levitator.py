"""Single-magnet levitator physics: equilibrium, linearisation, inverse maps, integration."""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.exceptions import DataError
from maglevid.lti import discretize
from maglevid.physics.levitator import (
    LevitatorParameters,
    current_gain,
    equilibrium,
    integrate_zoh,
    levitator_rhs,
    linearize,
    mechanical_from_pole,
    mechanical_state_space,
    unstable_pole,
)

P = LevitatorParameters.uaq()


def test_published_equilibrium_current_and_pole():
    # README of maglev-uaq-levitador: i0 = 0.465 A at 5 mm, pole ~44 rad/s, z ~1.55 at 10 ms
    # (the README rounds; 3 decimals for i0, 0.5 rad/s and 0.01 for the pole).
    i0, _ = equilibrium(P, 0.005)
    assert i0 == pytest.approx(0.465, abs=5e-4)
    p = unstable_pole(P, 0.005)
    assert p == pytest.approx(44.0, abs=0.5)
    assert np.exp(p * 0.01) == pytest.approx(1.55, abs=0.01)


def test_force_balances_gravity_at_equilibrium():
    # Exact algebra: F(i0, y0) = m g.
    for y0 in (0.003, 0.005, 0.008):
        i0, _ = equilibrium(P, y0)
        assert float(P.force(i0, y0)) == pytest.approx(P.m * P.g, rel=1e-12)


def test_force_is_coenergy_gradient():
    # F = 1/2 i^2 |dL/dy| with dL/dy by central differences of L(y) (truncation ~h^2).
    y, i, h = 0.005, 0.4, 1e-7
    dL = (P.inductance(y + h) - P.inductance(y - h)) / (2 * h)
    assert float(P.inductance_gradient(y)) == pytest.approx(float(dL), rel=1e-7)
    assert float(P.force(i, y)) == pytest.approx(0.5 * i**2 * abs(float(dL)), rel=1e-7)


def test_linearisation_is_the_jacobian_of_the_nonlinear_model():
    p = P.with_changes(R=5.0, ku=0.5, v0=1.2)
    y0 = 0.005
    i0, u0 = equilibrium(p, y0)
    x0 = np.array([y0, 0.0, i0])
    assert np.allclose(levitator_rhs(p, x0, u0), 0.0, atol=1e-12)
    sys = linearize(p, y0)
    J = np.empty((3, 3))
    for j in range(3):
        dx = np.zeros(3)
        dx[j] = 1e-7 * max(abs(x0[j]), 1e-3)
        J[:, j] = (levitator_rhs(p, x0 + dx, u0) - levitator_rhs(p, x0 - dx, u0)) / (2 * dx[j])
    du = 1e-6
    Bn = (levitator_rhs(p, x0, u0 + du) - levitator_rhs(p, x0, u0 - du)) / (2 * du)
    # central differences: relative error ~1e-8 on entries of size 1..2000
    assert np.allclose(sys.A, J, rtol=1e-6, atol=1e-6)
    assert np.allclose(sys.B[:, 0], Bn, rtol=1e-6, atol=1e-9)


def test_mechanical_plant_poles_are_plus_minus_p():
    p = unstable_pole(P, 0.005)
    poles = np.sort(mechanical_state_space(P, 0.005).poles().real)
    assert np.allclose(poles, [-p, p], rtol=1e-12)
    z = np.sort(np.abs(mechanical_state_space(P, 0.005, dt=0.01).poles()))
    assert np.allclose(z, [np.exp(-p * 0.01), np.exp(p * 0.01)], rtol=1e-12)


def test_mechanical_inverse_map_round_trip():
    y0 = 0.0045
    out = mechanical_from_pole(unstable_pole(P, y0), current_gain(P, y0), y0, m=P.m, g=P.g)
    assert out["a"] == pytest.approx(P.a, rel=1e-12)
    assert out["k"] == pytest.approx(P.k, rel=1e-12)
    assert out["i0"] == pytest.approx(equilibrium(P, y0)[0], rel=1e-12)


def test_integrate_zoh_matches_the_sampled_linear_model_for_small_motion():
    p = P.with_changes(R=5.05, ku=0.515, v0=1.36)
    y0 = 0.005
    i0, u0 = equilibrium(p, y0)
    sysd = discretize(linearize(p, y0), 0.01)
    dx = np.array([1e-7, 0.0, 0.0])
    x1 = integrate_zoh(p, np.array([y0, 0.0, i0]) + dx, u0 + 1e-4, 0.01, substeps=50)
    lin = sysd.A @ dx + sysd.B[:, 0] * 1e-4
    # second-order terms of a 1e-7 m / 1e-4 V perturbation are ~1e-6 of the first-order ones
    assert np.allclose(x1 - [y0, 0.0, i0], lin, rtol=1e-4, atol=1e-12)


def test_integrate_zoh_respects_the_stops():
    x = integrate_zoh(P, [0.019, 0.5, 0.0], 0.0, 0.01, gap_limits=(0.0, 0.0197))
    assert x[0] == pytest.approx(0.0197) and x[1] == 0.0


def test_invalid_parameters_are_rejected():
    with pytest.raises(DataError, match="`R`"):
        LevitatorParameters(R=-1.0)
    with pytest.raises(DataError, match="y0"):
        equilibrium(P, -0.01)
    with pytest.raises(DataError, match="unknown parameter"):
        P.with_changes(Q=1.0)
