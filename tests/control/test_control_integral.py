"""State feedback with integral action: extended model (eq. (41)), LQR, pole placement."""

from __future__ import annotations

import json

import numpy as np
import pytest

from maglevid.control import (
    IntegralStateFeedback,
    closed_loop_poles,
    design_lqr,
    design_pole_placement,
    extended_model,
    integral_selector,
)
from maglevid.exceptions import DataError, DesignError
from maglevid.physics.amb import AMBParameters, amb_state_space

DT = 1e-4


@pytest.fixture
def sys():
    return amb_state_space(AMBParameters.nominal(), DT)


def test_extended_model_is_eq41_and_integrates_y_next(sys, rng):
    E = integral_selector([0], 3)
    ext = extended_model(sys, E)
    assert ext.nx == 5 and ext.nu == 2 and ext.ny == 3
    x, e, u = rng.standard_normal(4), rng.standard_normal(1), rng.standard_normal(2)
    z_next = ext.A @ np.concatenate([x, e]) + ext.B @ u
    x_next = sys.A @ x + sys.B @ u
    # eq. (39): e(k+1) = e(k) - E y(k+1) with y(k+1) = C x(k+1). Exact algebra: rtol 1e-12.
    np.testing.assert_allclose(z_next[:4], x_next, rtol=1e-12)
    np.testing.assert_allclose(z_next[4:], e - E @ sys.C @ x_next, rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(ext.C, np.hstack([sys.C, np.zeros((3, 1))]))
    assert ext.state_names[-1] == "e1"


def test_integral_selector_and_validation():
    np.testing.assert_array_equal(integral_selector([0, 2], 3), [[1, 0, 0], [0, 0, 1]])
    with pytest.raises(DataError, match="distinct output indices"):
        integral_selector([0, 0], 3)
    with pytest.raises(DataError, match="identity"):
        IntegralStateFeedback(np.zeros((2, 4)), np.zeros((2, 1)), [[0.5, 0.5, 0]])


def test_extended_model_refuses_continuous():
    with pytest.raises(DesignError, match="continuous"):
        extended_model(amb_state_space(AMBParameters.nominal()))


def test_pole_placement_reaches_requested_poles(sys):
    s = np.array([-400.0, -600.0, -800.0, -100.0, -30.0])
    ctrl = design_pole_placement(sys, poles=np.exp(s * DT))
    got = np.sort(closed_loop_poles(sys, ctrl).real)
    # place_poles is exact to ~1e-12 here; 1e-9 leaves room for its iterations.
    np.testing.assert_allclose(got, np.sort(np.exp(s * DT)), rtol=1e-9)
    assert ctrl.F.shape == (2, 4) and ctrl.Fe.shape == (2, 1)
    # u = -F x + Fe e  <=>  u = -K z with K = [F, -Fe] (eq. (42))
    np.testing.assert_array_equal(ctrl.gain, np.hstack([ctrl.F, -ctrl.Fe]))


def test_pole_placement_rejects_unstable_request(sys):
    with pytest.raises(DesignError, match="unit circle"):
        design_pole_placement(sys, poles=[0.9, 0.9, 0.9, 0.9, 1.1])
    with pytest.raises(DataError, match="5 poles"):
        design_pole_placement(sys, poles=[0.9, 0.8])


def test_lqr_closed_loop_is_stable_and_matches_python_control(sys):
    Q = np.diag([1e10, 0.0, 1e2, 1e2, 1e3])
    R = np.diag([1.0, 2.0])
    ctrl = design_lqr(sys, Q=Q, R=R)
    assert np.max(np.abs(closed_loop_poles(sys, ctrl))) < 1.0
    control = pytest.importorskip("control")
    ext = extended_model(sys)
    K, _, _ = control.dlqr(ext.A, ext.B, Q, R)
    # Independent gain formula (python-control 0.10); same Riccati solver underneath.
    np.testing.assert_allclose(ctrl.gain, K, rtol=1e-9)


def test_lqr_reports_unsolvable_riccati(sys):
    with pytest.raises(DesignError, match="Riccati"):
        design_lqr(sys, Q=np.eye(5), R=-np.eye(2))


def test_feedback_and_json_round_trip(sys, rng):
    ctrl = design_pole_placement(sys, poles=np.exp(np.array([-400, -600, -800, -100, -30]) * DT))
    x, e = rng.standard_normal((7, 4)), rng.standard_normal((7, 1))
    np.testing.assert_allclose(ctrl.feedback(x, e), -x @ ctrl.F.T + e @ ctrl.Fe.T, rtol=1e-12)
    d = json.loads(json.dumps(ctrl.to_dict()))
    assert d["type"] == "state_feedback_integral"
    back = IntegralStateFeedback.from_dict(d)
    np.testing.assert_array_equal(back.F, ctrl.F)
    np.testing.assert_array_equal(back.Fe, ctrl.Fe)
    np.testing.assert_array_equal(back.E, ctrl.E)
    assert not ctrl.F.flags.writeable
    with pytest.raises(AttributeError):
        ctrl.F = np.zeros((2, 4))  # frozen
