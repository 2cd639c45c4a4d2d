"""Data-quality tools, on synthetic signals with known answers and on the real records."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.io

from maglevid.control.cascade_pid import CascadeGains, cascade_state_space, replay_cascade
from maglevid.diagnose.quality import (
    compare_signals,
    controller_equation_error,
    estimate_quantisation_step,
    excitation_summary,
    find_levitation_segments,
    fit_cascade_gains,
    fit_controller_arx,
    fit_pid_gains,
    persistent_excitation_order,
    quantisation_snr,
    regressor_condition_number,
    scan_sample_time,
)
from maglevid.exceptions import DataError, IdentificationError

UAQ = "maglev-uaq-levitador"


def _dataset(shared_data, profile):
    # Private loader until maglevid.io.read_recording lands (columns t y y_obs dy_obs i u yd).
    path = next((shared_data / UAQ).glob(f"dataset_{profile}_*.txt"))
    _t, y, _, _, i, u, yd = np.loadtxt(path, comments="#", encoding="latin-1").T
    return y, i, u, yd


# ------------------------------------------------------------------ segments
def test_segments_synthetic_reasons_and_guards():
    y = np.full(1200, 5e-3)
    y[:200] = 1e-3  # held at the magnet: lift-off
    y[600:650] = 20e-3  # fallen
    u = np.full(1200, 7.0)
    u[900:903] = 9.86  # saturated
    rep = find_levitation_segments(
        y, dt=0.01, position_range=(2e-3, 10e-3), command=u, command_limits=(0, 9.86)
    )
    # lift-off 0-200 + settle 100; fall 600-650 +- guard 50; saturation 900-903 +- 50
    assert rep.bounds() == [(300, 550), (953, 1200)]
    reasons = {e.reason for e in rep.excluded}
    assert {"lift-off", "above-range", "command-high", "guard", "short"} <= reasons
    assert rep.mask().sum() == 250 + 247
    # the short piece between the fall and the saturation (700-850) is excluded as short
    assert any(e.reason == "short" and e.start == 700 for e in rep.excluded)


def test_segments_keep_saturation_when_asked():
    y = np.full(500, 5e-3)
    u = np.full(500, 7.0)
    u[250] = 0.0
    rep = find_levitation_segments(
        y, dt=0.01, position_range=(2e-3, 10e-3), command=u, command_limits=(0, 9.86),
        exclude_saturation=False,
    )  # fmt: skip
    assert rep.bounds() == [(0, 500)]


def test_segments_validate_arguments():
    with pytest.raises(DataError, match="position_range"):
        find_levitation_segments(np.ones(10), dt=0.01, position_range=(1.0, 0.0))
    with pytest.raises(DataError, match="reference"):
        find_levitation_segments(
            np.ones(10), dt=0.01, position_range=(0, 2), max_tracking_error=0.1
        )


def test_segments_on_real_step_session(shared_data):
    y, _i, u, yd = _dataset(shared_data, "escalon")
    rep = find_levitation_segments(
        y, dt=0.01, position_range=(2e-3, 10e-3), command=u, command_limits=(0, 9.86),
        reference=yd, max_tracking_error=2e-3,
    )  # fmt: skip
    # README: levitating 96.2 %, 2.7 % of u at a limit, lift-off of 2-4 s.
    assert rep.excluded[0].reason == "lift-off"
    assert 1.0 < rep.segments[0].start * 0.01 < 4.0
    assert 0.8 < rep.usable_fraction < 0.962


def test_segments_on_messy_legacy_session(shared_data):
    _t, yd, y, _idl, _i, u = np.loadtxt(shared_data / UAQ / "datos_levitador.txt").T
    rep = find_levitation_segments(
        y, dt=0.01, position_range=(2e-3, 10e-3), command=u, command_limits=(0, 9.86),
        reference=yd, max_tracking_error=2e-3,
    )  # fmt: skip
    by = rep.excluded_by_reason()
    # README: falls, sticking to the magnet (~48-50 s), resting on the bottom stop,
    # saturation; levitating ~50 % of the time (guards and min_duration remove more).
    assert {"lift-off", "below-range", "above-range", "command-high"} <= set(by)
    assert by["below-range"] > 10.0  # seconds stuck at the magnet
    assert 0.1 < rep.usable_fraction < 0.5
    stuck = [e for e in rep.excluded if e.reason == "below-range" and e.length > 500]
    assert any(e.start * 0.01 < 49.0 < e.stop * 0.01 for e in stuck)


# ------------------------------------------------------------------ controller checks
def test_equation_error_is_zero_for_the_stated_law_whatever_its_state(rng):
    n = 300
    yd = np.full(n, 0.005)
    y = 0.005 + 2e-5 * rng.standard_normal(n)
    i = 0.45 + 2e-3 * rng.standard_normal(n)
    rep = replay_cascade(yd, y, i, I0=-0.45, J0=7.0)
    r, valid = controller_equation_error(cascade_state_space(), np.column_stack([yd, y, i]), rep.u)
    # exact algebra (integrator states unknown to the check): round-off of u ~ 10 V
    assert np.max(np.abs(r[valid])) < 1e-11
    wrong = cascade_state_space(CascadeGains(kd=1.6))
    r2, _ = controller_equation_error(wrong, np.column_stack([yd, y, i]), rep.u)
    assert np.sqrt(np.mean(r2[valid] ** 2)) > 1e-3


def test_compare_signals():
    a = np.sin(np.linspace(0, 10, 100))
    chk = compare_signals(a, a + 0.01)
    assert chk.rms == pytest.approx(0.01) and chk.correlation == pytest.approx(1.0)
    with pytest.raises(DataError, match="mask"):
        compare_signals(a, a, mask=np.zeros(100, dtype=bool))


def test_fit_pid_gains_recovers_the_products(rng):
    kp, ki, kd, dt = 100.0, 50.0, 1.5, 0.01
    e = rng.standard_normal(300) * 1e-4
    v = np.empty_like(e)
    I, prev = 0.0, 0.0
    for k, ek in enumerate(e):
        I += ki * dt * ek
        v[k] = kp * ek + I + kd * (ek - prev) / dt
        prev = ek
    fit = fit_pid_gains(e, v, dt=dt)
    # noise-free: exact to round-off
    assert fit.kp == pytest.approx(kp, rel=1e-9)
    assert fit.ki == pytest.approx(ki, rel=1e-9)
    assert fit.kd == pytest.approx(kd, rel=1e-9)
    assert fit.implied_dt(ki=ki, kd=kd)["from_kd"] == pytest.approx(dt, rel=1e-9)
    with pytest.raises(IdentificationError):
        fit_pid_gains(e[:5], v[:5])


@pytest.mark.parametrize("profile", ["escalon", "multiescalon", "constante"])
def test_documented_cascade_reproduces_real_sessions(shared_data, profile):
    y, i, u, yd = _dataset(shared_data, profile)
    rep = replay_cascade(yd, y, i)
    lin = rep.linear & (u > 0) & (u < 9.86)
    ok = lin.copy()
    ok[2:] &= lin[1:-1] & lin[:-2]
    r, valid = controller_equation_error(cascade_state_space(), np.column_stack([yd, y, i]), u)
    # Equation error floor: u printed to 0.1 mV, i quantised to 2.2 mA (x (kpi + kii dt)
    # = 42 V/A -> 0.09 V per step, but rounding, not noise, is what is left): < 10 mV.
    assert np.sqrt(np.mean(r[ok & valid] ** 2)) < 0.01
    g, _se, _rms = fit_cascade_gains(yd, y, i, u, dt=0.01, mask=lin)
    doc = CascadeGains.uaq()
    for name in ("kp", "ki", "kd", "kpi", "kii"):
        # documented gains recovered to 1 % (the law is exact; the rounding of the logged
        # signals leaves standard errors of 0.03-0.8 %)
        assert getattr(g, name) == pytest.approx(getattr(doc, name), rel=0.01)
    scan = scan_sample_time(
        np.arange(0.006, 0.0141, 0.001),
        lambda dt: controller_equation_error(
            cascade_state_space(CascadeGains(dt=dt)), np.column_stack([yd, y, i]), u
        )[0][ok & valid],
    )
    assert scan.best == pytest.approx(0.01)
    assert scan.contrast() > 5.0


def test_maggy_controller_is_a_linear_filter_of_sensor_1(shared_data):
    mat = scipy.io.loadmat(shared_data / "maggy-ntnu" / "PD_data_with_input.mat")
    B = np.hstack([mat[f"rawMeasurements{j}"] for j in (1, 2, 3)])
    u = mat["u"].astype(float)
    n = u.shape[0]
    seg = slice(int(3.0 * 2700), int(6.8 * 2700))  # README: stable levitation 3-6.8 s
    ok = np.zeros(n, dtype=bool)
    ok[seg] = np.abs(u[seg, 0]) < 255
    fit = fit_controller_arx(B, u[:, 0], na=2, nb=2, nk=0, mask=ok)
    # A second-order difference equation explains u1 to ~0.01 PWM counts (R^2 > 0.9999),
    # where a static PD on the 9 channels explains 88 % (README).
    assert fit.r_squared > 0.9999
    assert fit.residual_rms < 0.05
    b = np.abs(fit.b)
    assert b[0].max() > 100 * np.delete(b, 0, axis=0).max()  # only s1x enters u1


# ------------------------------------------------------------------ excitation
def test_persistent_excitation_orders(rng):
    n = 2000
    assert persistent_excitation_order(rng.standard_normal(n), max_order=10)[0] == 10
    t = np.arange(n)
    two_sines = np.sin(0.3 * t) + np.sin(1.1 * t)
    assert persistent_excitation_order(two_sines, max_order=10)[0] == 4
    assert persistent_excitation_order(np.ones(n), max_order=5)[0] == 0


def test_excitation_summary_finds_a_sine():
    t = np.arange(4096) * 0.01
    out = excitation_summary({"r": np.sin(2 * np.pi * 2.0 * t)}, dt=0.01)
    assert out["r"]["peak_hz"] == pytest.approx(2.0, abs=0.2)
    assert out["r"]["f90_hz"] < 3.0


def test_condition_number_is_unit_free():
    X = np.column_stack([np.arange(10.0), np.ones(10)])
    assert regressor_condition_number(X * [1e-6, 1e3]) == pytest.approx(
        regressor_condition_number(X), rel=1e-12
    )


def test_quantisation_step_of_the_real_gap_and_current(shared_data):
    y, i, _u, _yd = _dataset(shared_data, "escalon")
    # README: 10-bit ADCs, 48.9 um and 2.2 mA steps (0.05/1023 m, 5/(2.2*1023) A).
    assert estimate_quantisation_step(y) == pytest.approx(0.05 / 1023, rel=2e-3)
    assert estimate_quantisation_step(i) == pytest.approx(5 / (2.2 * 1023), rel=5e-3)
    snr = quantisation_snr(y[1200:2900], 0.05 / 1023)
    # std ~100 um against a 49 um step: 10-20 dB (the motion is a few steps)
    assert 5.0 < snr < 25.0
