"""Theorems 1 and 2 of Sun et al. against direct zero-order-hold sampling."""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.exceptions import DataError, ModelError
from maglevid.identify.multirate import (
    intersample_numerators,
    lift_intersample,
    t_model_from_delta,
    t_polynomials_from_delta,
)
from maglevid.lti import StateSpace, discretize
from maglevid.physics.suspension import (
    T_PAPER,
    SuspensionParameters,
    polynomials_from_state_space,
    suspension_state_space,
)

PLANT = suspension_state_space(SuspensionParameters.nominal())


def _direct_intersample(sys_c: StateSpace, T: float, tau: float) -> tuple[np.ndarray, np.ndarray]:
    """Polynomials of u(m) -> y(mT + tau) by ZOH at T with an output delay tau (independent route).

    y(mT + tau) = C e^{A tau} x(mT) + C int_0^tau e^{A s} ds B u(m).
    """
    sysT = discretize(sys_c, T)
    if tau == 0:
        return polynomials_from_state_space(sysT)
    part = discretize(sys_c, tau)
    shifted = StateSpace(sysT.A, sysT.B, sys_c.C @ part.A, sys_c.C @ part.B, T)
    return polynomials_from_state_space(shifted)


@pytest.mark.parametrize("p", [1, 2, 3, 4, 6])
def test_theorem1_equals_direct_zoh_at_T(p):
    a, b = t_polynomials_from_delta(discretize(PLANT, T_PAPER / p), p)
    a_T, b_T = polynomials_from_state_space(discretize(PLANT, T_PAPER))
    # exact algebra: machine precision relative to each polynomial's size
    np.testing.assert_allclose(a, a_T, rtol=0, atol=1e-12 * np.abs(a_T).max())
    np.testing.assert_allclose(b, b_T, rtol=0, atol=1e-12 * np.abs(b_T).max())


@pytest.mark.parametrize("p", [2, 3, 5, 6])
def test_theorem2_equals_zoh_with_output_delay(p):
    a, B = intersample_numerators(discretize(PLANT, T_PAPER / p), p)
    for j in range(p):
        a_j, b_j = _direct_intersample(PLANT, T_PAPER, j * T_PAPER / p)
        np.testing.assert_allclose(a, a_j, rtol=0, atol=1e-12 * np.abs(a_j).max())
        np.testing.assert_allclose(B[j], b_j, rtol=0, atol=1e-12 * np.abs(b_j).max())


def test_printed_eq5b_sum_from_one_is_wrong():
    # (5b) as printed sums Lam^i phi for i = 1..p-1; that misses phi and disagrees
    # with the direct ZOH (and with (6a) at j = 0). The corrected sum starts at 0.
    p = 3
    sd = discretize(PLANT, T_PAPER / p)
    Lam, phi = sd.A, sd.B
    wrong = StateSpace(
        np.linalg.matrix_power(Lam, p),
        sum(np.linalg.matrix_power(Lam, i) @ phi for i in range(1, p)),
        sd.C,
        None,
        T_PAPER,
    )
    _, b_wrong = polynomials_from_state_space(wrong)
    _, b_T = polynomials_from_state_space(discretize(PLANT, T_PAPER))
    assert np.max(np.abs(b_wrong - b_T)) > 0.1 * np.abs(b_T).max()


def test_all_numerators_share_the_static_gain():
    # B_0(1) = ... = B_(p-1)(1): the basis of eq. (15).
    _, B = intersample_numerators(discretize(PLANT, T_PAPER / 4), 4)
    s = B.sum(axis=1)
    np.testing.assert_allclose(s, s[0], rtol=1e-10)


def test_lifted_model_reproduces_the_fast_simulation():
    p = 3
    sd = discretize(PLANT, T_PAPER / p)
    lifted = lift_intersample(sd, p)
    rng = np.random.default_rng(1)
    u = rng.standard_normal(40)
    y_fast, _ = sd.simulate(np.repeat(u, p))
    y_lift, _ = lifted.simulate(u)
    np.testing.assert_allclose(
        y_lift.reshape(-1), y_fast.reshape(-1), rtol=0, atol=1e-12 * np.abs(y_fast).max()
    )
    assert t_model_from_delta(sd, p).ny == 1


def test_delay_shifts_every_numerator():
    sd = discretize(PLANT, T_PAPER / 2)
    _, B0 = intersample_numerators(sd, 2)
    _, B1 = intersample_numerators(sd, 2, delay=1)
    np.testing.assert_array_equal(B1[:, 1:], B0)
    assert np.all(B1[:, 0] == 0)


def test_inputs_are_validated():
    sd = discretize(PLANT, T_PAPER / 2)
    with pytest.raises(DataError, match="`p`"):
        intersample_numerators(sd, 0)
    with pytest.raises(ModelError, match="discrete"):
        intersample_numerators(PLANT, 2)
    with pytest.raises(ModelError, match="strictly proper"):
        intersample_numerators(StateSpace(sd.A, sd.B, sd.C, [[1.0]], sd.dt), 2)
    with pytest.raises(DataError, match="`delay`"):
        intersample_numerators(sd, 2, delay=-1)
