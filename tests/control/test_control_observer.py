"""Observers in the paper's sign convention (eq. (17)): deadbeat, Kalman, pole placement."""

from __future__ import annotations

import json

import numpy as np
import pytest

from maglevid.control import (
    Observer,
    design_deadbeat_observer,
    design_kalman_observer,
    design_observer_pole_placement,
    observability_indices,
)
from maglevid.exceptions import DesignError
from maglevid.lti import StateSpace, discretize
from maglevid.physics.amb import AMBParameters, amb_state_space


def _relative_power(obs: Observer, k: int) -> float:
    Abar = obs.A + obs.G @ obs.C
    return float(np.linalg.norm(np.linalg.matrix_power(Abar, k), 2) / np.linalg.norm(Abar, 2) ** k)


@pytest.mark.parametrize("dt", [5e-5, 1e-4, 2e-4])
@pytest.mark.parametrize("fault", [{}, {"R1": 1.2, "kw1": 1.2, "K1": 0.9}])
def test_deadbeat_is_nilpotent_in_two_steps(dt, fault):
    sys = amb_state_space(AMBParameters.nominal().with_fault(**fault), dt)
    obs = design_deadbeat_observer(sys)
    assert obs.kind == "deadbeat"
    assert obs.info["nilpotency_index"] == 2
    assert obs.info["observability_indices"] == [2, 1, 1]
    # (A+GC)^2 = 0 to ~1e-9 relative (the brief's bound; we see ~1e-16), while
    # (A+GC) itself is not zero: the index is exactly 2.
    assert _relative_power(obs, 2) < 1e-9
    assert _relative_power(obs, 1) == pytest.approx(1.0)
    assert np.max(np.abs(obs.poles())) < 1e-6


def test_deadbeat_estimate_is_exact_after_two_steps(rng):
    sys = amb_state_space(AMBParameters.nominal(), 1e-4)
    obs = design_deadbeat_observer(sys)
    x = rng.standard_normal(4) * np.array([1e-5, 1e-2, 1e-2, 1e-2])
    xh = np.zeros(4)
    for k in range(6):
        u = rng.standard_normal(2)
        y = sys.C @ x
        if k >= 2:
            # exact model, no noise: x̂(k) = x(k) to round-off (1e-9 of the state scale)
            np.testing.assert_allclose(xh, x, rtol=0, atol=1e-9 * np.abs(x).max())
        x, xh = sys.A @ x + sys.B @ u, obs.A_bar @ xh + obs.B @ u - obs.G @ y  # eq. (17)


def test_deadbeat_general_system(rng):
    # A random observable 6-state, 2-output system: index = max observability index.
    Ac = rng.standard_normal((6, 6))
    sys = discretize(StateSpace(Ac, rng.standard_normal((6, 1)), rng.standard_normal((2, 6))), 0.1)
    obs = design_deadbeat_observer(sys)
    mu = observability_indices(sys)
    assert sum(mu) == 6 and obs.info["nilpotency_index"] == max(mu) == 3
    assert _relative_power(obs, 3) < 1e-9


def test_deadbeat_refuses_unobservable():
    A = np.diag([0.5, 0.7, 0.9])
    sys = StateSpace(A, np.ones((3, 1)), [[1.0, 0.0, 0.0]], dt=1.0)
    with pytest.raises(DesignError, match="not observable"):
        design_deadbeat_observer(sys)


def test_deadbeat_refuses_singular_A():
    sys = StateSpace([[0.0, 1.0], [0.0, 0.0]], [[0.0], [1.0]], [[1.0, 0.0]], dt=1.0)
    with pytest.raises(DesignError, match="nonsingular A"):
        design_deadbeat_observer(sys)


def test_kalman_matches_python_control():
    sys = amb_state_space(AMBParameters.nominal(), 1e-4)
    Q = np.diag([1e-6, 1e-2, 1e-4, 1e-4])
    R = np.diag([1e-14, 1e-8, 1e-8])
    obs = design_kalman_observer(sys, Q=Q, R=R)
    assert obs.kind == "kalman" and np.max(np.abs(obs.poles())) < 1
    control = pytest.importorskip("control")
    L, _, _ = control.dlqe(sys.A, np.eye(4), sys.C, Q, R)
    # python-control 0.10 dlqe gives the predictor gain L of x̂+ = A x̂ + B u + L (y - C x̂);
    # eq. (17) uses G = -L.
    np.testing.assert_allclose(obs.G, -L, rtol=1e-9, atol=1e-12 * np.abs(L).max())


def test_observer_pole_placement():
    sys = amb_state_space(AMBParameters.nominal(), 1e-4)
    poles = np.array([0.5, 0.6, 0.7, 0.8])
    obs = design_observer_pole_placement(sys, poles=poles)
    np.testing.assert_allclose(np.sort(obs.poles().real), poles, rtol=1e-9)
    with pytest.raises(DesignError, match="failed"):
        design_observer_pole_placement(sys, poles=[0.0, 0.0, 0.0, 0.0])  # beyond rank(C)


def test_observer_json_round_trip_and_immutability():
    obs = design_deadbeat_observer(amb_state_space(AMBParameters.nominal(), 1e-4))
    d = json.loads(json.dumps(obs.to_dict()))
    assert d["type"] == "deadbeat" and d["info"]["nilpotency_index"] == 2
    back = Observer.from_dict(d)
    np.testing.assert_array_equal(back.G, obs.G)
    np.testing.assert_array_equal(back.A, obs.A)
    assert back.dt == obs.dt
    assert not obs.G.flags.writeable
