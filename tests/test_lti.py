"""StateSpace, ZOH (eq. (7)) and its inverse (eq. (8)): analytic cases and invariants."""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.exceptions import DataError, ModelError
from maglevid.lti import StateSpace, discretize, undiscretize


def _random_stable(rng: np.random.Generator, nx: int, nu: int, ny: int) -> StateSpace:
    # Continuous model with real and complex poles in [-50, -1] and well-conditioned modes.
    Q, _ = np.linalg.qr(rng.standard_normal((nx, nx)))
    lam = -np.linspace(1.0, 50.0, nx)
    A = Q @ np.diag(lam) @ Q.T
    A[0, 1] += 5.0
    A[1, 0] -= 5.0  # a complex pair
    return StateSpace(A, rng.standard_normal((nx, nu)), rng.standard_normal((ny, nx)))


def test_zoh_first_order_analytic():
    # x' = a x + b u sampled with ZOH: A = e^{a dt}, B = b (e^{a dt} - 1)/a (exact).
    a, b, dt = -3.0, 2.0, 0.05
    d = discretize(StateSpace([[a]], [[b]], [[1.0]]), dt)
    np.testing.assert_allclose(d.A, [[np.exp(a * dt)]], rtol=1e-14)
    np.testing.assert_allclose(d.B, [[b * (np.exp(a * dt) - 1) / a]], rtol=1e-13)
    assert d.dt == dt


def test_zoh_double_integrator_analytic():
    # x'' = u: A = [[1, dt], [0, 1]], B = [[dt^2/2], [dt]].
    dt = 0.1
    d = discretize(StateSpace([[0.0, 1.0], [0.0, 0.0]], [[0.0], [1.0]], [[1.0, 0.0]]), dt)
    np.testing.assert_allclose(d.A, [[1, dt], [0, 1]], rtol=1e-14, atol=1e-16)
    np.testing.assert_allclose(d.B, [[dt**2 / 2], [dt]], rtol=1e-13)


def test_zoh_round_trip(rng):
    # Round trip to 1e-12 relative (issue 2 "Done means").
    sys = _random_stable(rng, 5, 2, 3)
    back = undiscretize(discretize(sys, 0.01))
    np.testing.assert_allclose(back.A, sys.A, rtol=0, atol=1e-12 * np.abs(sys.A).max())
    np.testing.assert_allclose(back.B, sys.B, rtol=0, atol=1e-12 * np.abs(sys.B).max())


def test_zoh_round_trip_handles_integrator():
    # eq. (8) as printed needs (A - I)^-1, singular for an integrator; the augmented log does not.
    sys = StateSpace([[0.0, 1.0], [0.0, -2.0]], [[0.0], [1.0]], [[1.0, 0.0]])
    back = undiscretize(discretize(sys, 0.02))
    np.testing.assert_allclose(back.A, sys.A, atol=1e-12)
    np.testing.assert_allclose(back.B, sys.B, atol=1e-12)


def test_zoh_step_invariance(rng):
    # ZOH is exact for piecewise-constant inputs: the discrete step response equals the
    # continuous one at the sample instants (continuous solved by scipy's expm-based lsim).
    from scipy import signal

    sys = _random_stable(rng, 4, 1, 2)
    dt = 0.02
    d = discretize(sys, dt)
    n = 60
    y_d, _ = d.simulate(np.ones((n, 1)))
    t = dt * np.arange(n)
    _, y_c, _ = signal.lsim((sys.A, sys.B, sys.C, sys.D), np.ones(n), t, interp=False)
    np.testing.assert_allclose(y_d, y_c, rtol=1e-9, atol=1e-12)


def test_markov_parameters_invariant_under_basis_change(rng):
    sys = discretize(_random_stable(rng, 4, 2, 3), 0.01)
    T = rng.standard_normal((4, 4)) + 4 * np.eye(4)
    np.testing.assert_allclose(sys.transform(T).markov(8), sys.markov(8), rtol=1e-10, atol=1e-13)
    np.testing.assert_allclose(
        np.sort_complex(sys.transform(T).poles()), np.sort_complex(sys.poles()), rtol=1e-12
    )


def test_frequency_response_matches_modal_form(rng):
    # Independent evaluation: H(jw) = C V diag(1/(jw - lambda)) V^-1 B (distinct poles).
    sys = _random_stable(rng, 3, 1, 2)
    w = np.logspace(-1, 2, 7)
    lam, V = np.linalg.eig(sys.A)
    Vi_B = np.linalg.solve(V, sys.B)
    ref = np.stack([(sys.C @ V) @ (Vi_B / (1j * wk - lam)[:, None]) for wk in w])
    np.testing.assert_allclose(sys.frequency_response(w), ref, rtol=1e-10)


def test_undiscretize_refuses_negative_real_eigenvalue():
    with pytest.raises(ModelError, match="negative real axis"):
        undiscretize(StateSpace([[-0.5]], [[1.0]], [[1.0]], dt=0.1))
    with pytest.raises(ModelError, match="at zero"):
        undiscretize(StateSpace([[0.0, 0.0], [0.0, 0.5]], np.eye(2), np.eye(2), dt=0.1))


def test_statespace_is_immutable_and_validated():
    sys = StateSpace([[1.0]], [[1.0]], [[1.0]], dt=0.1)
    with pytest.raises(ValueError):
        sys.A[0, 0] = 2.0
    with pytest.raises(DataError, match="shape"):
        StateSpace([[1.0, 0.0]], [[1.0]], [[1.0]])
    with pytest.raises(DataError, match="non-finite"):
        StateSpace([[np.nan]], [[1.0]], [[1.0]])
    with pytest.raises(DataError, match="positive"):
        StateSpace([[1.0]], [[1.0]], [[1.0]], dt=-1)


def test_dict_round_trip_and_python_control(rng):
    sys = discretize(_random_stable(rng, 3, 2, 2), 0.01)
    again = StateSpace.from_dict(sys.to_dict())
    np.testing.assert_array_equal(again.A, sys.A)
    assert again.dt == sys.dt
    pytest.importorskip("control")
    back = StateSpace.from_control(sys.to_control())
    np.testing.assert_array_equal(back.A, sys.A)
    np.testing.assert_array_equal(back.D, sys.D)
    assert back.dt == sys.dt
    cont = StateSpace.from_control(_random_stable(rng, 2, 1, 1).to_control())
    assert cont.dt is None


def test_channel_names_survive_python_control():
    # Issue 18: x, i1, i2 stayed y[0..2] in python-control.
    pytest.importorskip("control")
    from maglevid.physics.amb import AMBParameters, amb_state_space

    sys = amb_state_space(AMBParameters.nominal())
    ctl = sys.to_control()
    assert list(ctl.output_labels) == ["x", "i1", "i2"]
    assert list(ctl.input_labels) == ["u1", "u2"]
    back = StateSpace.from_control(ctl)
    assert back.output_names == ("x", "i1", "i2") and back.state_names == sys.state_names
    # python-control's own default labels are not taken for names.
    plain = StateSpace.from_control(StateSpace([[0.5]], [[1.0]], [[1.0]], dt=0.1).to_control())
    assert plain.output_names == () and plain.input_names == ()


def test_undiscretize_eigen_route_equals_schur_route(rng):
    # undiscretize takes ln([[A, B], [0, I]]) from A's eigen-decomposition when A is
    # well diagonalisable (a fixed cost of every subspace fit); reference: scipy's
    # Schur-Pade logm of the balanced block matrix, the route it falls back to.
    from maglevid import lti

    for _ in range(50):
        nx, nu = int(rng.integers(1, 7)), int(rng.integers(1, 4))
        Ac = rng.standard_normal((nx, nx))
        rate = max(float(np.max(np.abs(np.linalg.eigvals(Ac)))), 1e-3)
        dt = float(rng.uniform(0.01, 2.0)) / rate
        d = discretize(StateSpace(Ac, rng.standard_normal((nx, nu)), np.ones((1, nx))), dt)
        lam, V = np.linalg.eig(d.A)
        L_eig = lti._log_zoh_eig(d.A, d.B, lam, V)
        assert L_eig is not None
        L_ref = lti._log_zoh_schur(d.A, d.B)
        np.testing.assert_allclose(L_eig, L_ref, rtol=0, atol=1e-12 * np.abs(L_ref).max())


def test_undiscretize_defective_matrix_takes_the_schur_route():
    # x'' = u: A = [[1, dt], [0, 1]] is a Jordan block (no eigenvector basis); the
    # eigen route declines and the Schur route gives the exact continuous model.
    from maglevid import lti

    dt = 0.1
    d = discretize(StateSpace([[0.0, 1.0], [0.0, 0.0]], [[0.0], [1.0]], [[1.0, 0.0]]), dt)
    lam, V = np.linalg.eig(d.A)
    assert lti._log_zoh_eig(d.A, d.B, lam, V) is None
    back = undiscretize(d)
    np.testing.assert_allclose(back.A, [[0.0, 1.0], [0.0, 0.0]], atol=1e-12)
    np.testing.assert_allclose(back.B, [[0.0], [1.0]], atol=1e-12)
