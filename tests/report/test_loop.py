"""Closed loop of plant and controller: separation principle and hand-solvable loops."""

from __future__ import annotations

import numpy as np
import pytest

from diagnosis_examples import DT, NOMINAL, example_controller
from maglevid.exceptions import DataError, ModelError
from maglevid.lti import StateSpace
from maglevid.physics.amb import amb_state_space
from maglevid.report.loop import close_loop, controller_state_space


def _sorted(p):
    return np.sort_complex(np.round(p, 12))


def test_observer_controller_on_its_own_model_separates():
    # Separation principle: plant = the observer's model gives the poles of
    # A - B F (state feedback) and A + G C (observer, eq. (17)), nothing else.
    plant = amb_state_space(NOMINAL, dt=DT)
    c = example_controller()
    loop = close_loop(plant, controller_state_space(c, plant=plant))
    A, B, C = plant.A, plant.B, plant.C
    expect = np.concatenate([np.linalg.eigvals(A - B @ c["F"]), np.linalg.eigvals(A + c["G"] @ C)])
    # Eigenvalues of an 8x8 non-normal matrix vs two 4x4 ones: agreement to ~1e-9.
    np.testing.assert_allclose(_sorted(loop.poles()), _sorted(expect), atol=1e-9)
    assert loop.is_stable()
    assert loop.input_names == ("r1", "r2")


def test_integral_part_adds_its_states():
    plant = amb_state_space(NOMINAL, dt=DT)
    c = example_controller()
    spec = {**c, "Fi": np.zeros((2, 1)), "Ci": [[1.0, 0.0, 0.0]]}
    K = controller_state_space(spec, plant=plant)
    assert K.nx == 5 and K.nu == 5 and K.ny == 2
    # A zero integral gain leaves the integrator decoupled: one extra pole at z = 1.
    poles = close_loop(plant, K).poles()
    assert np.min(np.abs(poles - 1.0)) < 1e-12


def test_scalar_loop_with_algebraic_feedthrough():
    # x+ = a x + b u, y = x; u_f = dy*y + du*u (static), u = u_f + r
    # => u = (dy x + r) / (1 - du), closed-loop pole a + b dy / (1 - du).
    a, b, dy, du = 1.2, 0.5, -1.0, 0.25
    plant = StateSpace([[a]], [[b]], [[1.0]], None, 0.01)
    K = StateSpace(np.zeros((1, 1)), np.zeros((1, 2)), [[0.0]], [[du, dy]], 0.01)
    loop = close_loop(plant, K)
    assert loop.A[0, 0] == pytest.approx(a + b * dy / (1 - du), rel=1e-14)
    assert loop.B[0, 0] == pytest.approx(b / (1 - du), rel=1e-14)


def test_controller_from_a_dict_with_y_input_only():
    plant = StateSpace([[1.1]], [[1.0]], [[1.0]], None, 0.01)
    K = {"A": [[0.0]], "B": [[0.0]], "C": [[0.0]], "D": [[-0.6]], "dt": 0.01}
    loop = close_loop(plant, controller_state_space(K))
    assert _sorted(loop.poles())[-1] == pytest.approx(0.5, abs=1e-14)


def test_model_inside_the_spec_wins_over_the_plant_argument():
    plant = amb_state_space(NOMINAL, dt=DT)
    c = example_controller()
    other = amb_state_space(NOMINAL.with_fault(R1=1.5), dt=DT)
    K = controller_state_space({**c, "model": other.to_dict()}, plant=plant)
    np.testing.assert_allclose(K.A[:4, :4], other.A + c["G"] @ other.C, rtol=1e-12)


def test_errors_name_the_problem():
    plant = amb_state_space(NOMINAL, dt=DT)
    c = example_controller()
    with pytest.raises(DataError, match="'F' and 'G'"):
        controller_state_space({"K": 1})
    with pytest.raises(DataError, match="no 'model'"):
        controller_state_space(c)
    with pytest.raises(DataError, match=r"controller\['F'\]"):
        controller_state_space({"F": np.zeros((3, 4)), "G": c["G"]}, plant=plant)
    with pytest.raises(ModelError, match="discrete"):
        controller_state_space(amb_state_space(NOMINAL))
    K = controller_state_space(c, plant=plant)
    with pytest.raises(ModelError, match="differ"):
        close_loop(amb_state_space(NOMINAL, dt=2 * DT), K)
    bad = StateSpace(np.eye(1), np.zeros((1, 4)), np.zeros((2, 1)), None, DT)
    with pytest.raises(DataError, match="4 inputs"):
        close_loop(plant, bad)
