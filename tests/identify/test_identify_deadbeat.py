"""The paper's method, eqs. (44)-(51): exactness, its two traps, and where it breaks."""

from __future__ import annotations

import numpy as np
import pytest
from _amb_cases import FAULTS, NOMINAL, make_loop, v_est, v_true

from maglevid.exceptions import DataError, IdentificationError
from maglevid.identify.arx import solve_linear_regression
from maglevid.identify.deadbeat import (
    deadbeat_regression,
    fit_deadbeat_arx,
    fit_deadbeat_iv,
    loop_matrices,
    loop_output_matrix,
    observer_controller_arx,
    plant_from_observer_controller,
)
from maglevid.physics.amb import C_AMB, amb_state_space

#: Noise-free identification: the issue asks for every v_i to better than 1e-6 %
#: (1e-8 relative); the method is exact, so only rounding remains.
EXACT = 1e-8


@pytest.fixture(scope="module")
def nominal_loop():
    return make_loop(NOMINAL, observer_model="plant", n_samples=1500)


@pytest.mark.parametrize("fit", [fit_deadbeat_arx, fit_deadbeat_iv])
def test_exact_without_noise_when_the_observer_runs_on_the_plant(nominal_loop, fit):
    res = fit(nominal_loop)
    np.testing.assert_allclose(v_est(res), v_true(nominal_loop), rtol=EXACT)
    # Physical parameters follow (m, i0 from the loop's operating point).
    assert res.parameters["R1"] == pytest.approx(NOMINAL.R1, rel=EXACT)
    assert res.parameters["ki2"] == pytest.approx(NOMINAL.ki2, rel=EXACT)
    assert res.parameters["Ls1"] == pytest.approx(NOMINAL.Ls1, rel=1e-7)
    assert res.fit["one_step_fit_percent_min"] > 99.99


@pytest.mark.parametrize("name", ["R1+20%", "kw1+20%"])
def test_exact_for_a_fault_when_the_observer_model_is_the_faulty_plant(name):
    # The paper's examples II-III ("the same observer gain"): its derivation needs the
    # observer's model to be the running plant; then the method is exact.
    data = make_loop(NOMINAL.with_fault(**FAULTS[name]), observer_model="plant", n_samples=1500)
    np.testing.assert_allclose(v_est(fit_deadbeat_arx(data)), v_true(data), rtol=EXACT)


def test_trap_a_printed_normal_matrix_is_singular_and_gd_is_arbitrary(nominal_loop):
    d = nominal_loop
    y, u, uf = np.asarray(d.y), np.asarray(d.u), np.asarray(d.u_f)
    mats = loop_matrices(d)
    P = loop_output_matrix(mats["C"], mats["F"], mats["Fe"])
    # Eq. (29) as printed: regressors [y_u(k); v(k)] = [y, u_f, u, y](k): y(k) twice.
    k = slice(10, y.shape[0] - 1)
    V = np.hstack([y[k], uf[k], u[k], y[k]])
    assert np.linalg.matrix_rank(V / np.sqrt(np.mean(V**2, axis=0))) == 10 - 3
    # With the distinct regressors the fit is exact and unique ...
    lhs, phi = deadbeat_regression(y, u, uf, E=mats["E"], Fe=mats["Fe"], start=10)
    Theta = solve_linear_regression(lhs, phi).coefficients
    # ... and every split Gd' of the y(k) coefficient gives the same A, B.
    A_true = amb_state_space(NOMINAL, d.dt).A
    B_true = amb_state_space(NOMINAL, d.dt).B
    rng = np.random.default_rng(1)
    for Gd in (mats["G"], np.zeros((4, 3)), rng.standard_normal((4, 3)) * 100):
        out = observer_controller_arx(Theta, P, Gd, C=C_AMB, nu=2)
        np.testing.assert_allclose(out["A"], A_true, rtol=1e-8, atol=1e-8 * np.abs(A_true).max())
        np.testing.assert_allclose(out["B"], B_true, rtol=1e-6, atol=1e-8 * np.abs(B_true).max())
        np.testing.assert_allclose(out["Gd"], Gd, atol=1e-9 * max(1.0, np.abs(Gd).max()))
        # The predictions a1 y_u(k) + b1 v(k) are identical for every split.
        pred = np.hstack([y[k], uf[k]]) @ out["a1"].T + np.hstack([u[k], y[k]]) @ out["b1"].T
        assert np.all(np.abs(pred - lhs).max(axis=0) < 1e-9 * np.abs(lhs).max(axis=0))
    # The split with the loop's own gain reproduces eq. (48) with the real observer.
    Gd = mats["G"]
    a1 = P @ np.block([[A_true + Gd @ C_AMB, np.zeros((4, 1))], [np.zeros((1, 4)), np.eye(1)]])
    a1 = np.linalg.solve(P.T, a1.T).T
    got = observer_controller_arx(Theta, P, Gd, C=C_AMB, nu=2)["a1"]
    np.testing.assert_allclose(got, a1, atol=1e-7 * np.abs(a1).max())


def test_trap_b_the_known_b0_term_belongs_on_the_left(nominal_loop):
    d = nominal_loop
    y, u, uf = np.asarray(d.y), np.asarray(d.u), np.asarray(d.u_f)
    mats = loop_matrices(d)
    P = loop_output_matrix(mats["C"], mats["F"], mats["Fe"])
    A_true = amb_state_space(NOMINAL, d.dt).A
    lhs, phi = deadbeat_regression(y, u, uf, E=mats["E"], Fe=mats["Fe"], start=10)
    A, _ = plant_from_observer_controller(
        solve_linear_regression(lhs, phi).coefficients, P, nx=4, ny=3, nu=2
    )
    np.testing.assert_allclose(A, A_true, rtol=1e-8, atol=1e-10 * np.abs(A_true).max())
    # Estimating b0 as unknown puts v(k+1) = [u, y](k+1) among the regressors; y(k+1)
    # is then on both sides and, being a function of [y, u_f, u](k), collinear.
    with pytest.raises(IdentificationError, match="rank deficient"):
        solve_linear_regression(lhs, np.hstack([phi, u[11:], y[11:]]))
    # Dropping it (u_f(k+1) alone on the left) still fits exactly -- y(k+1) is a
    # function of the regressors -- with rows (I - [0; Fe E][I, 0]) Theta. Eqs. (49)-(51)
    # then still give A and B (P^-1 [0; Fe E][I, 0] P = [0, 0; E C, 0] only touches the
    # integrator row), but L = P^-1 a1 P loses its structure diag(., I): L21 = -E C L11.
    dropped = solve_linear_regression(np.hstack([y[11:], uf[11:]]), phi)
    A2, _ = plant_from_observer_controller(dropped.coefficients, P, nx=4, ny=3, nu=2)
    np.testing.assert_allclose(A2, A_true, rtol=1e-8, atol=1e-10 * np.abs(A_true).max())
    a1 = dropped.coefficients[:, :5]
    L = np.linalg.solve(P, a1 @ P)
    np.testing.assert_allclose(L[4:, :4], -mats["E"] @ C_AMB @ A_true, atol=1e-8)


def test_mirror_symmetric_controller_makes_the_method_impossible():
    data = make_loop(NOMINAL, observer_model="plant", symmetric=True, n_samples=500)
    with pytest.raises(IdentificationError, match=r"singular.*symmetric"):
        fit_deadbeat_arx(data)


@pytest.mark.parametrize("name", list(FAULTS))
def test_biased_without_noise_when_the_observer_runs_on_the_nominal_plant(name):
    # The diagnostic case: the observer's model is the nominal bearing.
    data = make_loop(NOMINAL.with_fault(**FAULTS[name]), observer_model="nominal", n_samples=1500)
    res = fit_deadbeat_arx(data)
    err = np.max(np.abs(v_est(res) / v_true(data) - 1))
    assert err > 1e-4  # orders of magnitude above rounding
    assert any("not exact" in n for n in res.notes)


def test_plant_from_observer_controller_inverts_eq_48():
    dt = 1e-4
    sys = amb_state_space(NOMINAL, dt)
    rng = np.random.default_rng(3)
    F, Fe = rng.standard_normal((2, 4)), rng.standard_normal((2, 1))
    E = np.array([[1.0, 0, 0]])
    P = loop_output_matrix(C_AMB, F, Fe)
    Ae = np.block([[sys.A, np.zeros((4, 1))], [np.zeros((1, 4)), np.eye(1)]])
    a1 = np.linalg.solve(P.T, (P @ Ae).T).T  # P diag(A, I) P^-1 (split Gd' = 0)
    Theta = np.hstack([a1, P @ np.vstack([sys.B, np.zeros((1, 2))])])
    A, B = plant_from_observer_controller(Theta, P, nx=4, ny=3, nu=2)
    np.testing.assert_allclose(A, sys.A, rtol=1e-10, atol=1e-12 * np.abs(sys.A).max())
    np.testing.assert_allclose(B, sys.B, rtol=1e-8, atol=1e-12 * np.abs(sys.B).max())
    assert E.shape == (1, 3)


def test_missing_controller_and_wrong_rate_are_clear_errors(nominal_loop):
    bare = nominal_loop.replace(loop={})
    with pytest.raises(IdentificationError, match="controller gains"):
        fit_deadbeat_arx(bare)
    with pytest.raises(DataError, match="least-squares"):
        fit_deadbeat_arx(nominal_loop, estimator="iv")
    with pytest.raises(DataError, match="samples"):
        fit_deadbeat_arx(nominal_loop.segment(0, 30))


def test_result_records_options_and_the_papers_matrices(nominal_loop):
    res = fit_deadbeat_iv(nominal_loop, skip=12)
    assert res.method == "deadbeat-iv"
    assert res.options["skip"] == 12 and res.options["instruments"] == "loop"
    for key in ("a1", "b0", "b1", "L", "M", "P"):
        assert key in res.extras
    # b0 v(k+1) = [0; -Fe E y(k+1)]
    b0 = res.extras["b0"]
    assert np.all(b0[:3] == 0) and np.all(b0[:, :2] == 0)
    assert res.to_dict()["method"] == "deadbeat-iv"
