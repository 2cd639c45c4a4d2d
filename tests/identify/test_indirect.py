"""Indirect method (closed-loop output error with the known controller)."""

from __future__ import annotations

import numpy as np
import pytest
from _loopsim import arx_plant, mech_polynomials, position_pid, random_steps, simulate_linear_loop

from maglevid.control.cascade_pid import cascade_state_space
from maglevid.exceptions import DataError, IdentificationError
from maglevid.experiments.rigs import UAQ_TWIN
from maglevid.identify.indirect import fit_indirect
from maglevid.physics.levitator import linearize

A_TRUE, B_TRUE = mech_polynomials()
Z_TRUE = float(np.max(np.abs(np.roots(A_TRUE))))


def _siso(rng, n=1500, **noise):
    P, _ = arx_plant(A_TRUE, B_TRUE)
    r = random_steps(n, hold=50, levels=(-2e-4, 0.0, 2e-4), rng=rng)
    return simulate_linear_loop(P, position_pid(), [-1, 0], r, rng=rng, **noise)


def test_noise_free_closed_loop_gives_the_plant(rng):
    d = _siso(rng)
    res = fit_indirect(
        d, controller=position_pid(), controller_inputs=["r:0", "y:0"], n=2,
        segments=[(0, 700), (750, 1500)],
    )  # fmt: skip
    # noise-free: the closed loop is fitted exactly (optimiser tolerance ~1e-8)
    assert res.parameters["a1"] == pytest.approx(A_TRUE[1], rel=1e-7)
    assert res.parameters["a2"] == pytest.approx(A_TRUE[2], rel=1e-7)
    assert res.parameters["pole_z"] == pytest.approx(Z_TRUE, rel=1e-7)
    assert not res.model.is_stable()


def test_uaq_cascade_simo_plant_and_mechanical_pole(rng):
    plant = linearize(UAQ_TWIN, 0.005, dt=0.01)
    den = np.poly(plant.A)
    num_i = np.poly(plant.A - plant.B @ plant.C[1:2]) - den
    z_mech = float(np.max(np.roots(num_i[1:]).real))  # zero of B_i: the i -> y pole
    z_volt = float(np.max(np.abs(plant.poles())))
    r = random_steps(2000, hold=60, levels=(-3e-4, 0.0, 3e-4), rng=rng)
    d = simulate_linear_loop(
        plant, cascade_state_space(), [-1, 0, 1], r, input_noise=0.05,
        output_noise=[2e-5, 2e-3], rng=rng, names={"y": ("y", "i")},
    )  # fmt: skip
    res = fit_indirect(d, controller="uaq-cascade", intermediate="y:i", initial=plant)
    se = res.std_errors()
    assert abs(res.parameters["intermediate_pole_z"] - z_mech) < 3 * se["intermediate_pole_z"]
    assert abs(res.parameters["pole_z"] - z_volt) < 3 * se["pole_z"]
    assert res.parameters["intermediate_pole_z"] > 1.0
    assert res.fit["closed_loop_fit_percent_y"] > 50


def test_controller_is_required_and_checked(rng):
    d = _siso(rng, n=300)
    with pytest.raises(DataError, match="needs the controller"):
        fit_indirect(d)
    with pytest.raises(DataError, match="preset"):
        fit_indirect(d, controller="pid-of-my-dreams")
    with pytest.raises(DataError, match="controller_inputs"):
        fit_indirect(d, controller=position_pid(), controller_inputs=["r:0"])
    with pytest.raises(DataError, match="no exogenous"):
        fit_indirect(d, controller=position_pid(), controller_inputs=["y:0", "y:0"])


def test_unstable_closed_loop_start_is_refused(rng):
    d = _siso(rng, n=400)
    bad = np.r_[A_TRUE[1:], -B_TRUE[1:]]  # wrong sign of the gain: positive feedback
    with pytest.raises(IdentificationError, match="stable closed loop"):
        fit_indirect(d, controller=position_pid(), controller_inputs=["r:0", "y:0"], n=2,
                     initial=bad)  # fmt: skip


def test_a_bearing_record_gets_the_methods_that_fit_it():
    # The simulated two-coil bearing's controller is a state feedback with integral
    # action and an observer, not one state-space model: the error said only "missing
    # ['A', 'B', 'C']" (found from outside, issue 16, thirteenth session).
    from maglevid.physics.amb import AMBParameters
    from maglevid.simulate.amb import simulate_amb_loop

    nom = AMBParameters.nominal()
    d = simulate_amb_loop(nom, nominal=nom, n_samples=2000, rng=1, plant_model="linear")
    with pytest.raises(DataError, match="For a two-coil bearing use method ml, physical"):
        fit_indirect(d)
