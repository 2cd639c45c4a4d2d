"""The observer-independent method: exact in the diagnostic case, symmetric controllers too."""

from __future__ import annotations

import numpy as np
import pytest
from _amb_cases import FAULTS, NOMINAL, make_loop, v_est, v_true

from maglevid.exceptions import DataError, IdentificationError
from maglevid.identify.arx import solve_linear_regression
from maglevid.identify.physical import (
    fit_physical,
    format_percentage_index,
    percentage_index,
    physical_transformation,
    plant_regression,
    realize_plant_arx,
)
from maglevid.lti import StateSpace, undiscretize
from maglevid.physics.amb import C_AMB, amb_matrices, amb_state_space

EXACT = 1e-8  # noise-free: every v_i to better than 1e-6 % (the requirement)


@pytest.mark.parametrize("name", list(FAULTS))
@pytest.mark.parametrize("estimator", ["ls", "iv"])
def test_exact_with_a_nominal_observer_and_a_fault(name, estimator):
    data = make_loop(NOMINAL.with_fault(**FAULTS[name]), observer_model="nominal", n_samples=1500)
    res = fit_physical(data, estimator=estimator)
    np.testing.assert_allclose(v_est(res), v_true(data), rtol=EXACT)
    assert res.fit["structure_residual"] < 1e-8


def test_exact_with_a_mirror_symmetric_controller():
    data = make_loop(NOMINAL.with_fault(R1=1.2), symmetric=True, n_samples=1500)
    res = fit_physical(data)
    np.testing.assert_allclose(v_est(res), v_true(data), rtol=EXACT)


def test_exact_with_lagged_excitation_instruments():
    data = make_loop(NOMINAL.with_fault(kw1=1.2), n_samples=1500)
    res = fit_physical(data, instruments="lags", instrument_lags=10)
    assert res.options["instruments"] == "lags"
    np.testing.assert_allclose(v_est(res), v_true(data), rtol=EXACT)


def test_without_the_loop_the_default_instruments_refuse_and_lags_must_be_asked_for():
    # Lags of r used to be taken silently: on noisy simulated bearings (linear and
    # nonlinear plant, 30 000 samples) x0 came out 20-35 standard errors from the truth
    # (issue 16, fourteenth session). Now the default refuses, naming what works;
    # lags asked for by name still run (exact without noise) and say they are weak.
    data = make_loop(NOMINAL, n_samples=1500)
    bare = data.replace(loop={"operating_point": dict(data.loop["operating_point"])})
    with pytest.raises(DataError, match=r"loop\['controller'\].*'ml'.*instruments='lags'"):
        fit_physical(bare)
    res = fit_physical(bare, instruments="lags")
    assert res.options["instruments"] == "lags"
    assert any("lags of r (asked for)" in n and "do not cover" in n for n in res.notes)
    np.testing.assert_allclose(v_est(res), v_true(data), rtol=EXACT)


def test_structured_realization_has_the_plants_markov_parameters():
    data = make_loop(NOMINAL.with_fault(K1=0.9), n_samples=800)
    y, u = np.asarray(data.y), np.asarray(data.u)
    lhs, phi = plant_regression(y, u, start=5)
    Theta = solve_linear_regression(lhs, phi).coefficients
    At, Bt, Ct, hs = realize_plant_arx(Theta, ny=3, nu=2)
    assert hs[1] < 1e-9 * hs[0]  # the lagged block is rank one
    true = amb_state_space(NOMINAL.with_fault(K1=0.9), data.dt)
    est = StateSpace(At, Bt, Ct, dt=data.dt)
    Yt, Ye = true.markov(20), est.markov(20)
    scale = np.abs(Yt).max(axis=0)
    assert np.all(np.abs(Ye - Yt).max(axis=0) <= 1e-9 * scale)


def test_physical_transformation_is_the_unique_one():
    Ac, Bc = amb_matrices(NOMINAL)
    S = np.array([[2.0, 1, 0, 0], [0.3, 3, 0, 1], [1, 0, 1, 0], [0, -2, 0, 1]])
    sys = StateSpace(Ac, Bc, C_AMB).transform(S)  # arbitrary coordinates
    T = physical_transformation(sys.A, sys.C)
    # Row 1 of T is Ctilde_0 Atilde: sums of products of entries up to 8e5, so the
    # rounding is ~1e-16 * 8e5 * |S| ~ 1e-10 absolute.
    np.testing.assert_allclose(T, S, rtol=1e-12, atol=1e-9)
    with pytest.raises(IdentificationError, match="singular"):
        physical_transformation(np.eye(4), sys.C)  # position derivative adds nothing


def test_transformation_applies_to_the_discrete_model_too():
    dt = 1e-4
    # The coordinates of realize_plant_arx: xi = [x, i1, i2, h], here h = (dx/dt + 0.2 x) / 2.
    S = np.array([[1.0, 0, 0, 0], [-0.2, 0, 0, 2], [0, 1, 0, 0], [0, 0, 1, 0]])
    disc = amb_state_space(NOMINAL, dt).transform(S)
    T = physical_transformation(undiscretize(disc).A, disc.C)
    np.testing.assert_allclose(
        T @ disc.A @ np.linalg.inv(T), amb_state_space(NOMINAL, dt).A, rtol=1e-9, atol=1e-12
    )


def test_percentage_index_marks_structural_zeros():
    Ac, Bc = amb_matrices(NOMINAL)
    Ap = percentage_index(Ac * 1.01, Ac)
    assert np.isnan(Ap[0, 0]) and Ap[1, 0] == pytest.approx(1.0)
    text = format_percentage_index(Ap)
    assert text.count("×") == int(np.sum(Ac == 0)) and "1.0000" in text
    with pytest.raises(DataError, match="shape"):
        percentage_index(Ac, Bc)


def test_wrong_recordings_are_clear_errors():
    data = make_loop(NOMINAL, n_samples=500)
    with pytest.raises(DataError, match="estimator"):
        fit_physical(data, estimator="ml")
    with pytest.raises(DataError, match="samples"):
        fit_physical(data.segment(0, 20))
    with pytest.raises(DataError, match="needs the excitation"):
        fit_physical(data.replace(r=None))


def test_subspace_model_in_physical_coordinates():
    # A subspace model of the plant (arbitrary coordinates) through the same T.
    from maglevid.identify.physical import to_physical_coordinates
    from maglevid.identify.subspace import fit_moesp
    from maglevid.physics.amb import v_from_matrices

    data = make_loop(NOMINAL.with_fault(kw1=1.2), n_samples=3000)
    res = fit_moesp(np.asarray(data.y), np.asarray(data.u), order=4, dt=data.dt, horizon=8)
    disc, cont = to_physical_coordinates(res.model)
    v, structure = v_from_matrices(cont.A, cont.B)
    np.testing.assert_allclose(v, v_true(data), rtol=EXACT)
    np.testing.assert_allclose(disc.C, C_AMB, atol=1e-12)
    assert structure < 1e-8
    with pytest.raises(DataError, match="4 states"):
        to_physical_coordinates(StateSpace(np.eye(2), np.ones((2, 2)), np.eye(2), dt=1e-4))
