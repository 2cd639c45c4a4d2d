"""The nonlinear plant (eq. (1) under ZOH, RK4): equilibrium, linearisation, agreement."""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.lti import StateSpace, discretize
from maglevid.physics.amb import C_AMB, AMBParameters, amb_matrices, amb_nonlinear_rhs
from maglevid.simulate.amb import (
    DEFAULT_DT,
    _rk4_stepper,
    default_amb_controller,
    default_amb_observer,
    linearized_v,
    nonlinear_equilibrium,
    simulate_amb_loop,
)
from maglevid.simulate.loop import simulate_linear_loop

NOM = AMBParameters.nominal()
FAULTY = NOM.with_fault(R1=1.2, kw1=1.2, K1=0.9)


def test_rk4_stepper_matches_physics_rhs():
    p = FAULTY
    h = 2.5e-5
    s = np.array([3e-6, 1e-3, 0.49, 0.51])
    u = np.array([8.9, 8.6])
    f = lambda z: amb_nonlinear_rhs(p, z, u)  # noqa: E731
    k1 = f(s)
    k2 = f(s + h / 2 * k1)
    k3 = f(s + h / 2 * k2)
    k4 = f(s + h * k3)
    ref = s + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    got = _rk4_stepper(p, h)(*s, *u)
    # Same arithmetic in another order: round-off only.
    np.testing.assert_allclose(got, ref, rtol=1e-13, atol=0)


def test_linearized_v_at_nominal_is_eq4():
    np.testing.assert_allclose(linearized_v(NOM, x=0.0, I1=NOM.i0, I2=NOM.i0), NOM.v(), rtol=1e-13)


def test_linearized_v_is_the_jacobian_of_eq1():
    p, x, I1, I2 = FAULTY, 2e-6, 0.47, 0.52
    # an operating point needs kw_j u_j = R_j I_j (no current drift)
    u = np.array([p.R1 * I1 / p.kw1, p.R2 * I2 / p.kw2])
    s0 = np.array([x, 0.0, I1, I2])
    J = np.empty((4, 4))
    for j, step in enumerate([1e-9, 1e-5, 1e-6, 1e-6]):  # central differences
        d = np.zeros(4)
        d[j] = step
        J[:, j] = (amb_nonlinear_rhs(p, s0 + d, u) - amb_nonlinear_rhs(p, s0 - d, u)) / (2 * step)
    Ac, _ = amb_matrices(linearized_v(p, x=x, I1=I1, I2=I2))
    # A nonzero x also gives a force offset, but the Jacobian is what eq. (4) describes.
    mask = Ac != 0
    # central differences: ~1e-7 relative truncation/round-off
    np.testing.assert_allclose(J[mask], Ac[mask], rtol=1e-6)
    np.testing.assert_allclose(J[~mask], 0, atol=1e-6 * np.abs(Ac).max())


def test_equilibrium_with_fault_is_held_by_the_integral():
    obs, ctrl = default_amb_observer(NOM, DEFAULT_DT), default_amb_controller(NOM, DEFAULT_DT)
    eq = nonlinear_equilibrium(FAULTY, NOM, obs, ctrl)
    assert abs(eq["x"]) < 1e-15  # integral action on x: centred (to round-off)
    # force balance at x = 0: K1 I1^2 = K2 I2^2
    assert FAULTY.K1 * eq["I1"] ** 2 == pytest.approx(FAULTY.K2 * eq["I2"] ** 2, rel=1e-10)
    ub = np.array([NOM.R1 * NOM.i0 / NOM.kw1, NOM.R2 * NOM.i0 / NOM.kw2])
    cur = np.array([FAULTY.kw1, FAULTY.kw2]) * (ub + eq["u_f"])
    np.testing.assert_allclose(cur, [FAULTY.R1 * eq["I1"], FAULTY.R2 * eq["I2"]], rtol=1e-10)
    # nominal plant: the operating point is the nominal one
    eq0 = nonlinear_equilibrium(NOM, NOM, obs, ctrl)
    assert eq0["I1"] == pytest.approx(NOM.i0, rel=1e-12)
    np.testing.assert_allclose(eq0["u_f"], 0, atol=1e-12)


def test_nonlinear_record_starts_at_rest():
    d = simulate_amb_loop(
        FAULTY, nominal=NOM, n_samples=300, rng=1, plant_model="nonlinear",
        excitation_std=0.0, noise_std=(0, 0, 0), force_std=0.0,
    )  # fmt: skip
    op = d.metadata["operating_point_true"]
    # no excitation, no noise: the loop stays at its rest point (round-off drift only)
    np.testing.assert_allclose(d.y, np.tile(op["y"], (300, 1)), rtol=0, atol=1e-12)
    np.testing.assert_allclose(d.u_f, np.tile(op["u_f"], (300, 1)), rtol=0, atol=1e-9)


def _difference(plant, a, n=4000):
    kw = dict(
        nominal=NOM, n_samples=n, rng=3, excitation_std=a, noise_std=(0, 0, 0), force_std=0.0
    )
    dn = simulate_amb_loop(plant, plant_model="nonlinear", **kw)
    op = dn.metadata["operating_point_true"]
    # The linear loop around the nonlinear rest point: eq. (4) with v at that point.
    Ac, Bc = amb_matrices(np.asarray(op["v"]))
    lin = discretize(StateSpace(Ac, Bc, C_AMB), DEFAULT_DT)
    obs, ctrl = default_amb_observer(NOM, DEFAULT_DT), default_amb_controller(NOM, DEFAULT_DT)
    sig = simulate_linear_loop(lin, obs, ctrl, r=dn.r)
    dy = np.asarray(dn.y) - np.asarray(op["y"]) - sig.y
    return np.abs(dy).max(axis=0), np.abs(sig.y).max(axis=0)


@pytest.mark.parametrize("plant", [NOM, FAULTY], ids=["nominal", "faulty"])
def test_nonlinear_agrees_with_linear_to_first_order(plant):
    # With excitation amplitude a, the signals are O(a) and the nonlinear-minus-linear
    # difference O(a^2): halving a quarters the difference and halves the relative one.
    # Observed ratios 3.97-3.99 at a = 1 -> 0.5 V; accepted [3.5, 4.5].
    d1, s1 = _difference(plant, 1.0)
    d2, s2 = _difference(plant, 0.5)
    assert np.all((d1 / d2 > 3.5) & (d1 / d2 < 4.5)), d1 / d2
    rel1, rel2 = d1 / s1, d2 / s2
    assert np.all((rel1 / rel2 > 1.75) & (rel1 / rel2 < 2.25)), rel1 / rel2
    # At the default 1 V excitation the linear model is good to ~1 % (observed 0.9-1.1 %).
    assert np.all(rel1 < 0.02)
