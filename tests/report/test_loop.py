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


def test_observer_and_integral_feedback_on_its_own_model_separate():
    # Separation principle: plant = the observer's model gives the poles of the
    # integral state feedback on the extended model (eq. (41)), eig(Ae - Be K),
    # and those of the observer, eig(A + G C) (eq. (43)), and nothing else.
    plant = amb_state_space(NOMINAL, dt=DT)
    loop_spec = example_controller()
    loop = close_loop(plant, controller_state_space(loop_spec, plant=plant))
    ext, obs = loop_spec["extended"], loop_spec["observer"]
    expect = np.concatenate(
        [
            np.linalg.eigvals(ext["A"] - ext["B"] @ ext["K"]),
            np.linalg.eigvals(obs["A"] + obs["G"] @ obs["C"]),
        ]
    )
    # Eigenvalues of a 9x9 non-normal matrix vs a 5x5 and a 4x4: agreement to ~1e-9.
    np.testing.assert_allclose(_sorted(loop.poles()), _sorted(expect), atol=1e-9)
    assert loop.nx == 9 and loop.is_stable()
    assert loop.input_names == ("r1", "r2")


def test_integral_action_removes_the_static_error():
    # With eq. (39) integrating x, a constant excitation leaves no steady
    # displacement: the closed loop's DC gain from r to x is zero.
    plant = amb_state_space(NOMINAL, dt=DT)
    loop = close_loop(plant, controller_state_space(example_controller(), plant=plant))
    dc = loop.C @ np.linalg.solve(np.eye(loop.nx) - loop.A, loop.B)
    assert np.max(np.abs(dc[0])) < 1e-12 * np.max(np.abs(loop.markov(50)[:, 0, :]))


def test_plain_state_feedback_and_observer_without_model():
    # No Fe/E: 4 controller states; an observer without A, B, C runs on `plant`.
    plant = amb_state_space(NOMINAL, dt=DT)
    spec = example_controller()
    spec = {
        "controller": {"F": spec["controller"]["F"]},
        "observer": {"G": spec["observer"]["G"]},
    }
    K = controller_state_space(spec, plant=plant)
    assert K.nx == 4 and K.nu == 5 and K.ny == 2
    np.testing.assert_allclose(K.A, plant.A + spec["observer"]["G"] @ plant.C, rtol=1e-15)


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


def test_model_inside_the_loop_wins_over_the_plant_argument():
    # The observer runs on its stated model even when another plant is passed.
    spec = example_controller()
    other = amb_state_space(NOMINAL.with_fault(R1=1.5), dt=DT)
    K = controller_state_space(spec, plant=other)
    obs = spec["observer"]
    np.testing.assert_allclose(K.A[:4, :4], obs["A"] + obs["G"] @ obs["C"], rtol=1e-15)


def test_errors_name_the_problem():
    plant = amb_state_space(NOMINAL, dt=DT)
    spec = example_controller()
    with pytest.raises(DataError, match="recording's loop"):
        controller_state_space({"F": 1, "G": 2})
    with pytest.raises(DataError, match="states no model"):
        controller_state_space({"controller": spec["controller"], "observer": {"G": 0}})
    with pytest.raises(DataError, match="'kalman_filter' is not supported"):
        controller_state_space({**spec, "observer": {**spec["observer"], "type": "kalman_filter"}})
    with pytest.raises(DataError, match=r"loop\['controller'\]\['F'\]"):
        bad = {**spec, "controller": {"F": np.zeros((3, 4))}}
        controller_state_space(bad, plant=plant)
    with pytest.raises(ModelError, match="discrete"):
        controller_state_space(amb_state_space(NOMINAL))
    K = controller_state_space(spec, plant=plant)
    with pytest.raises(ModelError, match="differ"):
        close_loop(amb_state_space(NOMINAL, dt=2 * DT), K)
    bad_k = StateSpace(np.eye(1), np.zeros((1, 4)), np.zeros((2, 1)), None, DT)
    with pytest.raises(DataError, match="4 inputs"):
        close_loop(plant, bad_k)
