"""Two-stage (projection, 2SLS) method on simulated closed loops."""

from __future__ import annotations

import numpy as np
import pytest
from _loopsim import arx_plant, mech_polynomials, position_pid, random_steps, simulate_linear_loop

from maglevid.control.cascade_pid import cascade_state_space
from maglevid.exceptions import IdentificationError
from maglevid.experiments.rigs import UAQ_TWIN
from maglevid.identify.twostage import fit_two_stage, newey_west
from maglevid.physics.levitator import linearize

A_TRUE, B_TRUE = mech_polynomials()
Z_TRUE = float(np.max(np.abs(np.roots(A_TRUE))))


def _loop(rng, *, c=None, std=0.0, n=3000):
    P, K = arx_plant(A_TRUE, B_TRUE, c)
    r = random_steps(n, hold=30, levels=(-2e-4, 0.0, 2e-4), rng=rng)
    return simulate_linear_loop(P, position_pid(), [-1, 0], r,
                                innovations=(K, std) if std else None, rng=rng)  # fmt: skip


def test_noise_free_two_stage_is_exact(rng):
    d = _loop(rng, n=1500)
    res = fit_two_stage(d, input="u:0", n_fir=30)
    # exact algebra: 2SLS of a noise-free equation returns its coefficients (round-off)
    assert res.parameters["a1"] == pytest.approx(A_TRUE[1], rel=1e-8)
    assert res.parameters["b1"] == pytest.approx(B_TRUE[1], rel=1e-8)
    assert res.parameters["pole_z"] > 1.0


@pytest.mark.parametrize("seed", [11, 12])
def test_coloured_noise_two_stage_consistent(seed):
    # Coloured equation error (C = 1 - 0.9 q^-1): 2SLS needs no noise model.
    d = _loop(np.random.default_rng(seed), c=np.array([1.0, -0.9]), std=3e-5)
    ts = fit_two_stage(d, input="u:0", n_fir=40)
    se = ts.std_errors()["pole_z"]
    assert abs(ts.parameters["pole_z"] - Z_TRUE) < 3 * se
    assert ts.confidence_intervals()["pole_rad_s"][0] > 0


def test_uaq_cascade_current_to_gap(rng):
    plant = linearize(UAQ_TWIN, 0.005, dt=0.01)
    den = np.poly(plant.A)
    num_i = np.poly(plant.A - plant.B @ plant.C[1:2]) - den
    z_mech = float(np.max(np.roots(num_i[1:]).real))
    r = random_steps(3000, hold=50, levels=(-3e-4, 0.0, 3e-4), rng=rng)
    d = simulate_linear_loop(plant, cascade_state_space(), [-1, 0, 1], r, input_noise=0.05,
                             output_noise=[2e-5, 2e-3], rng=rng)  # fmt: skip
    res = fit_two_stage(d, input="y:1", nb=3, nk=0)
    se = res.std_errors()["pole_z"]
    assert abs(res.parameters["pole_z"] - z_mech) < 3 * se
    assert res.fit["stage1_r2_input"] > 0.5


def test_constant_reference_is_refused(rng):
    d = _loop(rng, std=1e-5, n=800)
    flat = d.replace(r=np.zeros((800, 1)))
    with pytest.raises(IdentificationError, match="rank deficient"):
        fit_two_stage(flat, input="u:0", n_fir=20)


def test_newey_west_with_zero_lags_is_the_white_sandwich(rng):
    X = rng.standard_normal((50, 2))
    e = rng.standard_normal(50)
    assert np.allclose(newey_west(X, e, 0), (X * e[:, None]).T @ (X * e[:, None]), rtol=1e-12)
