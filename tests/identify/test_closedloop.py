"""Shared machinery of the same-rate closed-loop methods."""

from __future__ import annotations

import numpy as np
import pytest
from _loopsim import MECH, arx_plant, mech_polynomials, position_pid, simulate_linear_loop
from scipy import signal

from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError
from maglevid.identify.closedloop import (
    close_loop,
    extend_covariance,
    innovations_from_polynomials,
    pole_statistics,
    resolve_channel,
    resolve_segments,
    simo_polynomials_to_state_space,
    stabilise_noise_polynomial,
)


def test_armax_predictor_equals_the_filter_form(rng):
    a = np.array([1.0, -2.2, 1.0])
    b = np.array([0.0, 0.3, 0.1])
    c = np.array([1.0, 0.5])
    n = 200
    u = rng.standard_normal(n)
    y = rng.standard_normal(n)
    inn = innovations_from_polynomials(a, [b], c)
    yhat = inn.predict(y[:, None], u[:, None], k=1)[:, 0]
    # one-step predictor of A y = B u + C e: e = (A y - B u)/C, yhat = y - e
    e = signal.lfilter([1.0], c, signal.lfilter(a, [1.0], y) - signal.lfilter(b, [1.0], u))
    assert np.allclose(yhat, y - e, rtol=1e-10, atol=1e-10)
    assert np.allclose(np.sort(np.abs(inn.predictor_poles())), [0.0, 0.5], atol=1e-12)


def test_k_step_prediction_against_brute_force(rng):
    a = np.array([1.0, -1.5, 0.6])
    b = np.array([0.0, 1.0, 0.5])
    inn = innovations_from_polynomials(a, [b])
    n, k = 60, 4
    u = rng.standard_normal(n)
    y = rng.standard_normal(n)
    pk = inn.predict(y[:, None], u[:, None], k=k)[:, 0]
    x1 = np.zeros(2)
    X = []
    for t in range(n):  # one-step predicted states
        X.append(x1.copy())
        AK, BK = inn.A - inn.K @ inn.C, (inn.B - inn.K @ inn.D)[:, 0]
        x1 = AK @ x1 + BK * u[t] + inn.K[:, 0] * y[t]
    for t in range(k, n):
        x = X[t - k + 1].copy()
        for s in range(t - k + 1, t):
            x = inn.A @ x + inn.B[:, 0] * u[s]
        assert pk[t] == pytest.approx(float((inn.C @ x)[0] + inn.D[0, 0] * u[t]), abs=1e-12)


def test_close_loop_matches_a_step_by_step_simulation(rng):
    P, _ = arx_plant(*mech_polynomials())
    K = position_pid()
    r = rng.standard_normal(100) * 1e-4
    d = simulate_linear_loop(P, K, [-1, 0], r)
    cl = close_loop(P, K, [-1, 0])
    z, _ = cl.simulate(r)
    assert np.allclose(z[:, 0], d.y[:, 0], rtol=1e-10, atol=1e-15)
    assert np.allclose(z[:, 1], d.u[:, 0], rtol=1e-10, atol=1e-12)
    assert cl.is_stable() and not MECH.is_stable()


def test_simo_polynomials_to_state_space_transfer_functions():
    a = np.array([1.0, -2.0, 0.9])
    bs = [np.array([0.0, 1.0, 0.2]), np.array([0.5, 0.0, -0.1])]
    sys = simo_polynomials_to_state_space(a, bs, 0.1)
    w = np.array([0.3, 2.0])
    H = sys.frequency_response(w)
    z = np.exp(1j * w * 0.1)
    for j, b in enumerate(bs):
        ref = np.polyval(b, z) / np.polyval(a, z)
        assert np.allclose(H[:, j, 0], ref, rtol=1e-12)


def test_noise_polynomial_reflection_keeps_the_spectrum():
    c = np.array([1.0, -2.5])  # root 2.5
    cs, flipped = stabilise_noise_polynomial(c)
    assert flipped and np.all(np.abs(np.roots(cs)) < 1)
    w = np.linspace(0.1, 3, 7)
    ratio = np.abs(np.polyval(c, np.exp(1j * w))) / np.abs(np.polyval(cs, np.exp(1j * w)))
    assert np.allclose(ratio, ratio[0], rtol=1e-9)  # same shape: a constant factor


def test_pole_statistics_never_reflects_and_gives_a_delta_method_interval():
    theta = np.array([-2.19545608, 1.0])  # roots 1.5505, 0.645
    cov = np.diag([1e-4, 1e-4])
    vals, J, _notes = pole_statistics(lambda t: np.r_[1.0, t], theta, 0.01)
    assert vals["pole_z"] == pytest.approx(1.5505, abs=1e-4)
    assert vals["pole_rad_s"] == pytest.approx(np.log(vals["pole_z"]) / 0.01, rel=1e-12)
    ext = extend_covariance(cov, [J])
    # implicit-function derivative dz/da_j = -z^(n-j) / A'(z)
    z = vals["pole_z"]
    dA = 2 * z + theta[0]
    Jz = -np.array([z, 1.0]) / dA
    assert ext[2, 2] == pytest.approx(Jz @ cov @ Jz, rel=1e-5)
    stable, _, notes2 = pole_statistics(lambda t: np.r_[1.0, t], np.array([-0.5, 0.06]), 0.01)
    assert stable["pole_z"] < 1 and any("no unstable" in n for n in notes2)


def test_channel_and_segment_validation():
    d = ClosedLoopData(y=np.zeros((50, 2)), u=np.zeros(50), dt=0.01,
                       names={"y": ("gap", "i")})  # fmt: skip
    assert resolve_channel(d, "y:i").index == 1
    assert resolve_channel(d, "u").name == "u1"
    for bad, msg in (("y", "name one"), ("y:5", "outside"), ("r:0", "no 'r'"), ("q", "unknown")):
        with pytest.raises(DataError, match=msg):
            resolve_channel(d, bad)
    with pytest.raises(DataError, match="outside"):
        resolve_segments(d, [(0, 60)], min_length=5)
    with pytest.raises(DataError, match="disjoint"):
        resolve_segments(d, [(10, 30), (20, 40)], min_length=5)
    with pytest.raises(DataError, match="needs >="):
        resolve_segments(d, [(0, 4)], min_length=5)
    multi = ClosedLoopData(y=np.zeros((100, 1)), u=np.zeros(50), dt=0.01, p=2)
    with pytest.raises(DataError, match="p = 1"):
        resolve_channel(multi, "y:0")
