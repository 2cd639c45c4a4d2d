"""The augmented closed loop equals eqs. (6), (16), (39), (42), (43) run sample by sample."""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.control import design_deadbeat_observer, design_kalman_observer
from maglevid.exceptions import DataError, DesignError
from maglevid.physics.amb import AMBParameters, amb_state_space
from maglevid.simulate.amb import default_amb_controller
from maglevid.simulate.loop import closed_loop_system, replay_feedback, simulate_linear_loop

DT = 1e-4


def literal_loop(plant, obs, ctrl, r, v, x_hat0, e0):
    """The paper's equations, one sample at a time (reference)."""
    x, xh, e = np.zeros(plant.nx), np.array(x_hat0, float), np.array(e0, float)
    Y, UF = [], []
    for k in range(r.shape[0]):
        y = plant.C @ x + v[k]
        if k > 0:
            e = e - ctrl.E @ y  # eq. (39): e(k) = e(k-1) - E y(k)
        uf = -ctrl.F @ xh + ctrl.Fe @ e  # eq. (42)
        u = uf + r[k]  # eq. (16)
        x = plant.A @ x + plant.B @ u  # eq. (6)
        xh = (obs.A + obs.G @ obs.C) @ xh + obs.B @ u - obs.G @ y  # eq. (43)
        Y.append(y)
        UF.append(uf)
    return np.array(Y), np.array(UF)


@pytest.fixture
def setup():
    nom = AMBParameters.nominal()
    plant = amb_state_space(nom.with_fault(R1=1.2, kw1=1.2, K1=0.9), DT)
    nominal = amb_state_space(nom, DT)
    return plant, design_deadbeat_observer(nominal), default_amb_controller(nom, DT)


@pytest.mark.parametrize("kernel", ["loop", "block"])
def test_loop_equals_literal_equations(setup, rng, kernel):
    plant, obs, ctrl = setup
    N = 3000
    r = rng.standard_normal((N, 2))
    v = rng.standard_normal((N, 3)) * [1e-7, 1e-4, 1e-4]
    xh0, e0 = rng.standard_normal(4) * 1e-4, np.array([2e-4])
    sig = simulate_linear_loop(plant, obs, ctrl, r=r, noise=v, x_hat0=xh0, e0=e0, kernel=kernel)
    Y, UF = literal_loop(plant, obs, ctrl, r, v, xh0, e0)
    # Exact algebra regrouped: 1e-12 of each channel's scale.
    for j in range(3):
        np.testing.assert_allclose(
            sig.y[:, j], Y[:, j], rtol=0, atol=1e-12 * np.abs(Y[:, j]).max()
        )
    np.testing.assert_allclose(sig.u_f, UF, rtol=0, atol=1e-12 * np.abs(UF).max())
    np.testing.assert_array_equal(sig.u, sig.u_f + sig.r)


def test_replay_feedback_reproduces_u_f(setup, rng):
    plant, obs, ctrl = setup
    N = 2000
    r = rng.standard_normal((N, 2))
    v = rng.standard_normal((N, 3)) * [1e-7, 1e-4, 1e-4]
    e0, xh0 = np.array([1e-4]), rng.standard_normal(4) * 1e-5
    sig = simulate_linear_loop(plant, obs, ctrl, r=r, noise=v, e0=e0, x_hat0=xh0)
    tol = 1e-12 * np.abs(sig.u_f).max()
    for kw in ({"r": sig.r}, {"u": sig.u}):
        uf = replay_feedback(obs, ctrl, y=sig.y, e0=e0, x_hat0=xh0, **kw)
        np.testing.assert_allclose(uf, sig.u_f, rtol=0, atol=tol)
    # Fed the recorded u, without initial states: a deadbeat observer agrees after its
    # nilpotency index (2), up to the constant Fe e(0) of the missing initial integral.
    uf0 = replay_feedback(obs, ctrl, y=sig.y, u=sig.u)
    np.testing.assert_allclose(uf0[2:] + ctrl.Fe @ e0, sig.u_f[2:], rtol=0, atol=tol)
    assert np.abs(uf0[:2] + ctrl.Fe @ e0 - sig.u_f[:2]).max() > 1e-6  # not before
    with pytest.raises(DataError, match="exactly one"):
        replay_feedback(obs, ctrl, y=sig.y)


def test_unstable_loop_is_refused(rng):
    nom = AMBParameters.nominal()
    plant = amb_state_space(nom.with_fault(x0=0.9), DT)  # 10 % smaller gap: too stiff
    obs = design_deadbeat_observer(amb_state_space(nom, DT))
    ctrl = default_amb_controller(nom, DT)
    with pytest.raises(DesignError, match="unstable"):
        simulate_linear_loop(plant, obs, ctrl, r=rng.standard_normal((100, 2)))
    sig = simulate_linear_loop(plant, obs, ctrl, r=np.zeros((10, 2)), allow_unstable=True)
    assert sig.y.shape == (10, 3)


def test_separation_principle_with_exact_model():
    # Plant = observer model: closed-loop poles = controller poles + observer poles.
    nom = AMBParameters.nominal()
    sys = amb_state_space(nom, DT)
    Q = np.diag([1e-6, 1e-2, 1e-4, 1e-4])
    obs = design_kalman_observer(sys, Q=Q, R=np.diag([1e-14, 1e-8, 1e-8]))
    ctrl = default_amb_controller(nom, DT)
    cl = np.sort_complex(closed_loop_system(sys, obs, ctrl).poles())
    want = np.sort_complex(
        np.concatenate([np.exp(np.array([-400, -600, -800, -100, -30]) * DT), obs.poles()])
    )
    np.testing.assert_allclose(cl, want, rtol=1e-8, atol=1e-10)


def test_kernel_name_is_checked(setup):
    plant, obs, ctrl = setup
    with pytest.raises(DataError, match="kernel"):
        simulate_linear_loop(plant, obs, ctrl, r=np.zeros((100, 2)), kernel="fast")


@pytest.mark.parametrize("kernel", ["loop", "block"])
def test_noise_free_loop_equals_literal_equations(setup, rng, kernel):
    # noise=None drives the loop by r alone (no input of zeros since the large-N work of
    # issue 15); the reference is the loop's literal equations with v = 0.
    plant, obs, ctrl = setup
    N = 3000
    r = rng.standard_normal((N, 2))
    xh0, e0 = rng.standard_normal(4) * 1e-4, np.array([2e-4])
    sig = simulate_linear_loop(plant, obs, ctrl, r=r, x_hat0=xh0, e0=e0, kernel=kernel)
    Y, UF = literal_loop(plant, obs, ctrl, r, np.zeros((N, 3)), xh0, e0)
    for j in range(3):
        np.testing.assert_allclose(
            sig.y[:, j], Y[:, j], rtol=0, atol=1e-12 * np.abs(Y[:, j]).max()
        )
    np.testing.assert_allclose(sig.u_f, UF, rtol=0, atol=1e-12 * np.abs(UF).max())
    zero = simulate_linear_loop(
        plant, obs, ctrl, r=r, noise=np.zeros((N, 3)), x_hat0=xh0, e0=e0, kernel=kernel
    )
    # the same sums without the zero terms: equal to rounding (GEMM may group differently)
    np.testing.assert_allclose(sig.y, zero.y, rtol=0, atol=1e-14 * np.abs(zero.y).max())
    np.testing.assert_allclose(sig.u_f, zero.u_f, rtol=0, atol=1e-14 * np.abs(zero.u_f).max())
