"""Periodic disturbances (unbalance, mains hum): found in the prediction errors and
profiled out of the maximum-likelihood fit (maglevid.identify.periodic, identify/ml.py),
taken out of the record before PBSID-opt and SSARX (``fit_without_lines``).

References: the chi-square law of a white error's bin (detection's false alarms, on
synthetic white errors); a sinusoid's known frequency and amplitude (synthetic); the
simulator's truth (the linearisation of its nonlinear bearing) for the fits; the
information's bordered blocks against the sensitivities formed explicitly.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal as ss

from maglevid.exceptions import DataError
from maglevid.identify import ml
from maglevid.identify.cramer_rao import NoiseModel
from maglevid.identify.ml import fit_ml
from maglevid.identify.periodic import (
    amplitude_text,
    check_lines,
    find_lines,
    fit_without_lines,
    line_amplitudes,
    line_sequences,
    remove_lines,
)
from maglevid.physics.amb import V_NAMES, AMBParameters
from maglevid.simulate.amb import simulate_amb_loop

NOMINAL = AMBParameters.nominal()
DT = 1e-4


def _spectrum(e: np.ndarray) -> np.ndarray:
    return np.fft.rfft(e, axis=0)


def test_white_errors_show_no_line():
    """30 records of 3 x 20 000 white errors: the false-alarm rate is 1e-4 a record."""
    rng = np.random.default_rng(0)
    found = [find_lines(_spectrum(rng.standard_normal((20_000, 3))), np.eye(3), 20_000, DT)[0]
             for _ in range(30)]  # fmt: skip
    assert all(f == () for f in found)


def test_a_line_between_bins_is_found_at_its_frequency():
    """37.31 Hz (0.93 bins off a bin), amplitude 0.2 in unit white errors of one channel:
    its statistic ~160 (40 at 0.1), three times the threshold; frequency to 0.01 Hz."""
    rng = np.random.default_rng(1)
    n = 20_000
    e = rng.standard_normal((n, 3))
    e[:, 1] += 0.2 * np.cos(2 * np.pi * 37.31 * DT * np.arange(n) + 1.0)
    freqs, stats = find_lines(_spectrum(e), np.eye(3), n, DT)
    assert len(freqs) == 1
    assert freqs[0] == pytest.approx(37.31, abs=0.01)
    assert stats[0] > 60


def test_a_resonance_of_the_errors_is_not_a_line():
    """White errors plus white noise through a lightly damped resonance (Q 10 at 40 Hz):
    bins far above the local level, but as wide as the resonance, not a sinusoid's
    leakage."""
    rng = np.random.default_rng(2)
    n = 30_000
    b, a = ss.iirpeak(40.0, 10.0, fs=1 / DT)
    e = rng.standard_normal((n, 3))
    e[:, 0] += 300 * ss.lfilter(b, a, rng.standard_normal(n))
    assert find_lines(_spectrum(e), np.eye(3), n, DT)[0] == ()


def test_known_lines_are_not_found_again():
    rng = np.random.default_rng(3)
    n = 20_000
    e = rng.standard_normal((n, 3)) + np.cos(2 * np.pi * 50 * DT * np.arange(n))[:, None]
    assert find_lines(_spectrum(e), np.eye(3), n, DT)[0] == pytest.approx((50.0,), abs=1e-3)
    assert find_lines(_spectrum(e), np.eye(3), n, DT, known=(50.0,))[0] == ()


def test_line_amplitudes_and_their_text():
    n = 10_000
    y = np.stack([2e-6 * np.sin(2 * np.pi * 50 * DT * np.arange(n) + 0.4) + 1e-3,
                  np.zeros(n)], axis=1)  # fmt: skip
    amp = line_amplitudes(y, DT, (50.0,))
    np.testing.assert_allclose(amp, [[2e-6, 0.0]], atol=1e-12)
    assert amplitude_text(2e-6, "m") == "2 um"
    assert amplitude_text(8.2e-7, "m") == "820 nm"
    assert amplitude_text(0.0071, "A") == "7.1 mA"


def test_the_option_is_checked():
    assert check_lines("auto", DT) is None
    assert check_lines("none", DT) == ()
    assert check_lines([50, 100.0], DT) == (50.0, 100.0)
    assert check_lines(50, DT) == (50.0,)
    with pytest.raises(DataError, match="Nyquist"):
        check_lines([6000.0], DT)
    with pytest.raises(DataError, match="'auto', 'none'"):
        check_lines("often", DT)
    with pytest.raises(DataError, match="at most"):
        check_lines(np.arange(1, 12), DT)


def test_the_simulators_unbalance_is_checked():
    with pytest.raises(DataError, match="nonlinear plant"):
        simulate_amb_loop(NOMINAL, n_samples=300, plant_model="linear", unbalance=(1, 50))
    with pytest.raises(DataError, match="Nyquist"):
        simulate_amb_loop(NOMINAL, n_samples=300, unbalance=(1, 6000))
    with pytest.raises(DataError, match="amplitude"):
        simulate_amb_loop(NOMINAL, n_samples=300, unbalance=(-1, 50))


@pytest.fixture(scope="module")
def unbalanced():
    """The realistic bearing (nonlinear plant, nominal bias voltages, 0.1 N white force,
    default sensor noise) with a 1 N unbalance at 50 Hz: 3000 rpm, a 1.8 kg rotor
    ~5.6 um out of balance; the rotor moves 5 um, the currents 7-8 mA at 50 Hz."""
    return simulate_amb_loop(NOMINAL, n_samples=30_000, rng=31001, unbalance=(1.0, 50.0))


def _z(res, truth):
    v = np.array([res.parameters[k] for k in V_NAMES])
    se = np.sqrt(np.diag(res.covariance))[[list(res.parameters).index(k) for k in V_NAMES]]
    return (v - truth) / se, v / truth - 1


def test_ml_with_an_unbalance_finds_it_and_stays_at_the_truth(unbalanced):
    truth = np.array(unbalanced.metadata["truth_v"])
    res = fit_ml(unbalanced)
    z, _ = _z(res, truth)
    assert np.max(np.abs(z)) < 4.0  # 1.8 on this seed; healthy records: RMS z 1.1
    assert res.extras["periodic_hz"][0] == pytest.approx(50.0, abs=0.01)
    amp = res.extras["periodic_amplitude"][0]
    assert 3e-6 < amp[0] < 8e-6 and 4e-3 < amp[1] < 1.2e-2  # x [m], i1 [A]
    assert any(n.startswith("periodic lines found") and "50 Hz" in n for n in res.notes)
    assert "line0_cos_x" in res.extras["fisher_names"]
    given = fit_ml(unbalanced, periodic=np.array([50.0]))
    assert np.max(np.abs(_z(given, truth)[0])) < 4.0


def test_ml_without_the_lines_is_what_went_wrong(unbalanced):
    """The failure the profile removes: a white-noise likelihood reads the 50 Hz line as
    dynamics (v1..v3 -96 % on this record; the diagnosis then blamed units or signs)."""
    res = fit_ml(unbalanced, periodic="none")
    _, rel = _z(res, np.array(unbalanced.metadata["truth_v"]))
    assert np.max(np.abs(rel[:3])) > 0.5


def test_a_healthy_record_has_no_line():
    d = simulate_amb_loop(NOMINAL, n_samples=20_000, rng=31004)
    res = fit_ml(d)
    assert res.extras["periodic_hz"].size == 0
    assert not any("periodic" in n for n in res.notes)


def test_the_lines_information_equals_the_explicit_sensitivities(unbalanced):
    """The bordered information (identify/ml.py, _line_information: the lines' cross terms
    by the adjoint) against the sensitivities formed at every bin: ``-L^-1 C (zI - F)^-1
    W_i sw`` for the parameters and the transient, ``-Psi`` for the lines."""
    y, u = np.asarray(unbalanced.y), np.asarray(unbalanced.u)
    lay = ml._Layout(NoiseModel((1e-7, 1e-4, 1e-4), force_std=0.1), True, True)
    model = lay.model(lay.theta(np.array(unbalanced.metadata["truth_v"])), DT, 1.8)
    sp = ml._spectra(y, u, None, lines=(50.0, 100.0), dt=DT)
    st = ml._evaluate(model, sp, derivatives=True)
    info = st["fisher"]
    # explicit: the sensitivities of the whitened, weighted errors at every bin
    K, S = st["K"], st["S"]
    F = model.A - K @ model.C
    res = ml._Resolvent(F, sp.z)
    Li = np.linalg.inv(np.linalg.cholesky(S))
    LC, sw = Li @ model.C, np.sqrt(sp.w)
    tau = st["tau"]
    drive = sp.U @ model.B.T + sp.Y @ K.T + sp.z[:, None] * tau[None, :]
    Xh = res.apply(drive[:, None, :], np.eye(4))[:, 0, :]
    eps = sp.Y - Xh @ model.C.T
    dK = ml.predictor_derivatives(model, K, *ml.steady_state_predictor(
        model.A, model.C, model.Q, model.R)[1:])[0]  # fmt: skip
    W = (np.einsum("pij,fj->fpi", model.dA, Xh) + np.einsum("pij,fj->fpi", model.dB, sp.U)
         + np.einsum("pij,fj->fpi", dK, eps))  # fmt: skip
    Wt = sp.z[:, None, None] * np.eye(4)[None]  # the transient's sources
    psi = -res.apply(np.concatenate([W, Wt], axis=1), LC) * sw[:, None, None]  # (M, p+n, ny)
    Psi = np.einsum("fj,ic->fijc", sp.D * sw[:, None], Li).reshape(len(sp.z), 3, -1)
    cross = np.real(np.einsum("fpi,fiq->pq", psi.conj(), -Psi)) / sp.N
    own = np.real(np.einsum("fiq,fir->qr", Psi.conj(), Psi)) / sp.N
    k = psi.shape[1]
    scale = np.sqrt(np.outer(np.diag(info), np.diag(info)))
    np.testing.assert_allclose(info[:k, k:] / scale[:k, k:], cross / scale[:k, k:], atol=1e-9)
    np.testing.assert_allclose(info[k:, k:] / scale[k:, k:], own / scale[k:, k:], atol=1e-9)


def test_lag_path_with_lines_equals_the_dft_path(unbalanced, monkeypatch):
    """The lines' sinusoids enter the lag path's lagged products as inputs do: the fit on
    the lag path (forced below its size threshold) equals the DFT path's."""
    fits = []
    for ratio in (np.inf, 0.0):
        with monkeypatch.context() as mp:
            mp.setattr(ml, "_LAG_MIN_RATIO", ratio)
            fits.append(fit_ml(unbalanced, periodic=[50.0]))
    dft, lag = fits
    assert lag.notes != dft.notes  # the lag path did run
    v = np.array([[f.parameters[k] for k in V_NAMES] for f in fits])
    se = np.sqrt(np.diag(dft.covariance))[:9]
    np.testing.assert_array_less(np.abs(v[1] - v[0]) / se, 0.05)


def test_line_sequences():
    seq = line_sequences(4, 0.25, (1.0,))
    np.testing.assert_allclose(seq, [[1, 0], [0, 1], [-1, 0], [0, -1]], atol=1e-12)
    assert line_sequences(4, 0.25, ()).shape == (4, 0)


def test_a_sensor_line_is_profiled_out_too():
    """Mains hum on the logged current i1 (1 mA at 60 Hz, ten times the sensor noise):
    not a force, but it reaches the errors as a sinusoid all the same (module notes).
    Without the lines the same record reads v off by ~270 standard errors."""
    d = simulate_amb_loop(NOMINAL, n_samples=30_000, rng=35002)
    y = np.array(d.y)
    y[:, 1] += 1e-3 * np.sin(2 * np.pi * 60.0 * DT * np.arange(y.shape[0]) + 0.7)
    d = d.replace(y=y)
    res = fit_ml(d)
    z, _ = _z(res, np.asarray(d.metadata["operating_point_true"]["v"]))
    assert np.max(np.abs(z)) < 4.0
    assert res.extras["periodic_hz"] == pytest.approx([60.0], abs=0.01)


@pytest.mark.parametrize("method", ["pbsid", "ssarx"])
def test_pbsid_and_ssarx_take_the_lines_out(unbalanced, method):
    """With the 1 N unbalance, PBSID-opt and SSARX (structured fit, through the registry:
    periodic='auto') find the 50 Hz line in their first fit's residuals, take its
    least-squares sinusoid out of every channel and refit: v1..v9 within 4 of their
    standard errors of the truth (measured over 6 records: RMS z 1.02 / 1.09, healthy
    records 1.09 / 1.17)."""
    from maglevid.identify.registry import get_method

    res = get_method(method)(unbalanced, coordinates="physical")
    assert res.extras["periodic_hz"][0] == pytest.approx(50.0, abs=0.01)
    z, _ = _z(res, np.asarray(unbalanced.metadata["operating_point_true"]["v"]))
    assert np.max(np.abs(z)) < 4.0
    note = next(n for n in res.notes if n.startswith("periodic lines (found"))
    assert "taken out of every channel of y and u" in note
    assert not any(n.startswith("periodic lines in the residuals") for n in res.notes)


def test_a_method_told_not_to_model_lines_says_they_are_there(unbalanced):
    """periodic='none': PBSID-opt's structured fit takes its errors as white and reads
    v1..v3 ~93 % off (tens of standard errors); its result says the lines are in its
    residuals (the contract of every method, identify/registry.py). A healthy record
    gets no note and no line."""
    from maglevid.identify.registry import get_method

    pbsid = get_method("pbsid")
    res = pbsid(unbalanced, coordinates="physical", periodic="none")
    z, _ = _z(res, np.asarray(unbalanced.metadata["operating_point_true"]["v"]))
    assert np.max(np.abs(z)) > 20.0
    note = next(n for n in res.notes if n.startswith("periodic lines in the residuals"))
    assert "residuals at 50, " in note and "pbsid does not model them" in note
    healthy = pbsid(simulate_amb_loop(NOMINAL, n_samples=30_000, rng=37001),
                    coordinates="physical")  # fmt: skip
    assert healthy.extras["periodic_hz"] == ()
    assert not any("periodic" in n for n in healthy.notes)


def test_remove_lines_takes_the_sinusoid_out_and_leaves_the_input():
    rng = np.random.default_rng(5)
    n = 4000
    t = DT * np.arange(n)
    x = rng.standard_normal((n, 2)) + 3.0
    x[:, 0] += 2.0 * np.cos(2 * np.pi * 123.4 * t + 0.3)
    before = x.copy()
    out = remove_lines(x, DT, (123.4,))
    np.testing.assert_array_equal(x, before)  # the caller's array is not modified
    assert line_amplitudes(out, DT, (123.4,))[0, 0] < 1e-12
    removed = (x - out)[:, 0]  # the sinusoid alone (the constant fitted beside it stays)
    assert np.max(np.abs(removed - 2.0 * np.cos(2 * np.pi * 123.4 * t + 0.3))) < 0.1


def test_fit_without_lines_given_auto_and_none():
    """The wrapper alone, around a stand-in fit whose residuals are its ``y``: given
    frequencies are taken out of both signals; 'auto' takes a line strong in the record
    out before the first fit, and a weak one (below START_STAT there) from the first
    fit's residuals with a refit; 'none' passes the signals through untouched; a line the
    recorded excitation carries is left in."""
    from dataclasses import dataclass, field

    @dataclass(frozen=True)
    class Fit:
        residuals: np.ndarray
        extras: dict = field(default_factory=dict)
        notes: tuple = ()

    calls = []

    def fit(y, u):
        calls.append((y, u))
        return Fit(np.asarray(y))

    rng = np.random.default_rng(6)
    n = 20_000
    unit = np.sin(2 * np.pi * 50.0 * DT * np.arange(n))
    noise_y, noise_u = rng.standard_normal((n, 3)), rng.standard_normal((n, 2))
    y, u = noise_y + 0.5 * unit[:, None], noise_u + 0.5 * unit[:, None]
    assert fit_without_lines(fit, y, u, DT, "none", method="x").residuals is y
    calls.clear()
    res = fit_without_lines(fit, y, u, DT, [50.0], method="x")
    assert len(calls) == 1 and res.extras["periodic_hz"] == (50.0,)
    assert line_amplitudes(calls[0][1], DT, (50.0,)).max() < 1e-12
    calls.clear()  # strong (statistic ~5000 in the record): out before the only fit
    res = fit_without_lines(fit, y, u, DT, "auto", method="x")
    assert len(calls) == 1 and res.extras["periodic_hz"][0] == pytest.approx(50.0, abs=0.01)
    assert res.extras["periodic_amplitude"][0] == pytest.approx([0.5] * 3, rel=0.05)
    assert "as given" not in res.notes[-1] and "found in the record" in res.notes[-1]
    calls.clear()  # weak (~300 in y: under START_STAT in the record, a line in the errors)
    weak = noise_y + 0.1 * unit[:, None]
    res = fit_without_lines(fit, weak, noise_u, DT, "auto", method="x")
    assert len(calls) == 2 and res.extras["periodic_hz"][0] == pytest.approx(50.0, abs=0.02)
    calls.clear()  # the same strong line in the recorded excitation r: the experiment's own
    r = rng.standard_normal((n, 2)) + unit[:, None]
    res = fit_without_lines(fit, y, u, DT, "auto", method="x", excitation=r)
    assert len(calls) == 1 and res.extras["periodic_hz"] == ()
    assert "are in the excitation r too" in res.notes[-1]
    white = rng.standard_normal((n, 2))  # a white excitation does not hide it
    assert fit_without_lines(fit, y, u, DT, "auto", method="x", excitation=white).extras[
        "periodic_hz"
    ][0] == pytest.approx(50.0, abs=0.01)


def test_a_logged_line_the_fit_absorbs_is_found_in_the_record():
    """1 um of runout at 50 Hz on the logged position alone: the structured fit bends the
    model to predict it (v1..v9 ~350 standard errors off with periodic='none') and its
    residuals hide it; the record shows it (statistic ~2500), and with it taken out
    PBSID-opt is back at the truth (RMS z 0.94 over 4 records)."""
    from maglevid.identify.registry import get_method

    d = simulate_amb_loop(NOMINAL, n_samples=30_000, rng=35001)
    y = np.array(d.y)
    y[:, 0] += 1e-6 * np.sin(2 * np.pi * 50.0 * DT * np.arange(y.shape[0]) + 0.7)
    d = d.replace(y=y)
    res = get_method("pbsid")(d, coordinates="physical")
    assert res.extras["periodic_hz"][0] == pytest.approx(50.0, abs=0.02)
    truth = np.asarray(d.metadata["operating_point_true"]["v"])
    assert np.max(np.abs(_z(res, truth)[0])) < 4.0
    # periodic='none': biased, and a result (a trusted Gauss-Newton step there overflowed
    # the predictor's powers and ended in a ValueError before _structured._finite_point)
    biased = get_method("pbsid")(d, coordinates="physical", periodic="none")
    assert np.max(np.abs(_z(biased, truth)[0])) > 100.0


def test_a_streamed_fit_refuses_lines(tmp_path):
    """Taking lines out needs the record in memory: the one-pass streamed PBSID-opt says so."""
    from maglevid.identify.streaming import fit_predictor_streamed

    d = simulate_amb_loop(NOMINAL, n_samples=2_000, rng=5)
    with pytest.raises(DataError, match="needs the whole record in memory"):
        fit_predictor_streamed(d, periodic=[50.0])


def test_a_streamed_fit_says_when_the_record_carries_lines(unbalanced):
    """The streamed PBSID-opt cannot take the unbalance out; it finds it in the first
    chunk and says its estimate is biased and what to do. A healthy record: no note."""
    from maglevid.identify.streaming import fit_predictor_streamed

    res = fit_predictor_streamed(unbalanced, coordinates="physical", chunk_size=10_000)
    note = next(n for n in res.notes if "carry periodic lines" in n)
    assert "first 10000 samples" in note and "at 50 Hz" in note and "--no-stream" in note
    healthy = simulate_amb_loop(NOMINAL, n_samples=30_000, rng=37001)
    res = fit_predictor_streamed(healthy, coordinates="physical", chunk_size=10_000)
    assert not any("periodic" in n for n in res.notes)


def test_a_line_whose_frequency_drifts_is_said_to_be_unsettled():
    """A sinusoid taken out at the best fixed frequency leaves a drifting line's
    neighbours raised (50 -> 50.25 Hz over the record), a steady one's white."""
    from maglevid.identify.periodic import unsettled_lines

    rng = np.random.default_rng(4)
    n = 30_000
    t = DT * np.arange(n)
    chirp = np.sin(2 * np.pi * (50 * t + 0.5 * 0.25 / (n * DT) * t**2))
    f = 50.125
    X = line_sequences(n, DT, (f,))
    rest = chirp - X @ np.linalg.lstsq(X, chirp, rcond=None)[0]  # what a fit leaves
    e = rng.standard_normal((n, 3))
    e[:, 0] += 10 * rest
    assert unsettled_lines(_spectrum(e), np.eye(3), n, DT, (f,)) == (f,)
    white = rng.standard_normal((n, 3))
    assert unsettled_lines(_spectrum(white), np.eye(3), n, DT, (f,)) == ()


def test_a_diagnosis_off_an_unsettled_line_is_inconclusive():
    """The bearing's verdict (plants/amb.py): a fault or an unexplained change read off a
    record whose line drifts becomes inconclusive, the change kept in the reasons; no
    change stays no change."""
    from types import SimpleNamespace

    from maglevid.plants.amb import _unsettled_lines

    drifting = SimpleNamespace(extras={"periodic_unsettled_hz": np.array([50.13])})
    reasons: list[str] = []
    verdict, code = _unsettled_lines(drifting, "Unexplained change", "unexplained_change",
                                     reasons)  # fmt: skip
    assert code == "inconclusive" and "50.13 Hz" in verdict and "steady speed" in verdict
    assert reasons == ["read off this record: Unexplained change"]
    assert _unsettled_lines(drifting, "No significant change", "no_change", []) == (
        "No significant change", "no_change")  # fmt: skip
    steady = SimpleNamespace(extras={"periodic_unsettled_hz": np.array([])})
    assert _unsettled_lines(steady, "Fault", "fault", []) == ("Fault", "fault")


@pytest.fixture
def drifting(monkeypatch):
    """The realistic bearing with a 1 N line whose frequency rises 50 -> 50.25 Hz over the
    3 s record (a running speed drifting 0.5 %)."""
    import maglevid.simulate.amb as sim

    draw = sim._draw

    def chirped(s, rng):
        r, v, force, meta = draw(s, rng)
        t = np.arange(r.shape[0]) * s.bearing.dt
        rate = 0.25 / (r.shape[0] * s.bearing.dt)
        return r, v, force + np.sin(2 * np.pi * (50.0 * t + 0.5 * rate * t**2)), meta

    monkeypatch.setattr(sim, "_draw", chirped)
    return simulate_amb_loop(NOMINAL, n_samples=30_000, rng=38001)


def test_a_drifting_line_gets_an_envelope(drifting):
    """ml: a fixed sinusoid left v1..v3 ~17 standard errors off; the line, found unsettled,
    is taken out with a Legendre envelope and the fit holds the settled point."""
    res = fit_ml(drifting)
    assert res.extras["periodic_envelope_degree"][0] > 0
    assert res.extras["periodic_unsettled_hz"].size == 0
    z, _ = _z(res, np.asarray(drifting.metadata["operating_point_true"]["v"]))
    assert np.max(np.abs(z)) < 4.0
    assert any("change over the record" in n and "envelope" in n for n in res.notes)


def test_pbsid_takes_a_drifting_line_out_with_an_envelope(drifting):
    """PBSID-opt: the line is found unsettled after a fixed sinusoid and taken out with
    the Legendre envelope; v1..v9 hold the settled point (3 records: RMS z 0.96, max
    |z| 2.2)."""
    from maglevid.identify.registry import get_method

    res = get_method("pbsid")(drifting, coordinates="physical")
    assert res.extras["periodic_envelope_degree"][0] > 0
    assert res.extras["periodic_hz"][0] == pytest.approx(50.125, abs=0.01)
    z, _ = _z(res, np.asarray(drifting.metadata["operating_point_true"]["v"]))
    assert np.max(np.abs(z)) < 4.0
    assert any("change over the record" in n and "envelope" in n for n in res.notes)


def test_lines_and_bad_input_the_fit_names_the_bad_sample():
    """A NaN is refused by the fit's own check, naming its sample: the lines' least-squares
    fit must not run first (it smeared one NaN over the whole channel: '5000 non-finite
    values'). A 1-D record takes its lines out too."""
    from maglevid.identify.pbsid import fit_pbsid

    rng = np.random.default_rng(0)
    y, u = rng.standard_normal((5000, 3)), rng.standard_normal((5000, 2))
    y[100, 1] = np.nan
    for periodic in ("auto", [50.0]):
        with pytest.raises(
            DataError, match=r"1 non-finite value\(s\) \(NaN first at index \(100, 1\)"
        ):
            fit_pbsid(y, u, dt=1e-3, periodic=periodic)
    t = 1e-3 * np.arange(5000)
    res = fit_pbsid(u[:, 0] + np.sin(2 * np.pi * 50 * t), u[:, 1], dt=1e-3, periodic="auto")
    assert res.extras["periodic_hz"][0] == pytest.approx(50.0, abs=0.01)
