"""PBSID-opt and SSARX: exact without noise, consistent under feedback, streamed == in memory.

Reference values. The generic plant is ``example_unstable_mimo`` (its poles,
Markov parameters and noise gain are the truth); the bearing's v1..v9 and unstable pole come from
the simulator's physics (``bench_amb_speed.bearing_case``'s truth). The closed
loop uses a dynamic controller with direct feedthrough of ``y`` and a white
reference ``r``, so the plant input is correlated with the current innovation:
the case where open-loop subspace (MOESP) is biased.
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import scipy.linalg as sla

from maglevid.cli.main import main
from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError, IdentificationError
from maglevid.identify.pbsid import PredictorAccumulator, fit_pbsid, fit_ssarx
from maglevid.identify.physical import to_physical_coordinates
from maglevid.identify.registry import available_methods, get_method
from maglevid.identify.result import propagate_covariance
from maglevid.identify.streaming import fit_predictor_streamed, identify_streamed
from maglevid.identify.subspace import fit_moesp
from maglevid.lti import StateSpace
from maglevid.physics.amb import AMBParameters, v_from_matrices
from maglevid.simulate import simulate_amb_loop
from maglevid.simulate.feedback import example_unstable_mimo, simulate_innovation_loop

PLANT, K, CONTROLLER = example_unstable_mimo()
A, C = PLANT.A, PLANT.C


def generic_loop(n: int, noise: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``(y, u)`` of the closed loop, inputs ``[r, e]`` white (r unit, e ``noise`` rms)."""
    return simulate_innovation_loop(PLANT, K, CONTROLLER, n, e_std=noise, rng=seed)


def _markov_error(model: StateSpace) -> float:
    return float(np.max(np.abs(model.markov(10) - PLANT.markov(10))))


@pytest.fixture(scope="module")
def bearing() -> ClosedLoopData:
    # simulate_amb_loop's defaults (noise 1e-7 m, 1e-4 A): BENCHMARKS.md's closed-loop
    # bearing, where MOESP's v5/v7 are ~50 % off.
    return simulate_amb_loop(AMBParameters.nominal(), n_samples=20_000, rng=11)


@pytest.mark.parametrize("fit", [fit_pbsid, fit_ssarx])
def test_exact_on_noise_free_closed_loop_data(fit):
    y, u = generic_loop(3000, 0.0, seed=1)
    res = fit(y, u)  # automatic past (AIC: smallest exact VARX) and order (rank 3)
    assert res.options["order"] == 3 and res.options["order_rule"] == "auto"
    np.testing.assert_allclose(
        np.sort_complex(res.model.poles()), np.sort_complex(PLANT.poles()), atol=1e-10
    )
    assert _markov_error(res.model) < 1e-10
    assert res.model.D.shape == (2, 2) and not res.model.D.any()
    assert res.extras["kalman_gain"].shape == (3, 2)
    # No noise, no innovations: K is not determined (0 from the minimum-norm least
    # squares), A - K C = A is unstable, and no predictor residuals are claimed.
    assert res.residuals is None
    assert any("predictor A - K C is not stable" in n for n in res.notes)


def test_consistent_under_feedback_where_moesp_is_biased():
    # Markov-parameter error, RMS over 3 records: falls like 1/sqrt(N) (x3.2 per
    # decade; measured 0.027 -> 0.0093 -> 0.0015 at 1e4, 1e5, 1e6 over 5 seeds),
    # while PO-MOESP's stays at ~0.7 (the feedback bias, independent of N).
    err: dict[str, list[float]] = {}
    for n in (10_000, 100_000):
        for seed in range(3):
            y, u = generic_loop(n, 0.3, seed=20 + seed)
            for fit in (fit_pbsid, fit_ssarx, fit_moesp):
                kw = {"past": 20} if fit is not fit_moesp else {"horizon": 20}
                err.setdefault(f"{fit.__name__}{n}", []).append(
                    _markov_error(fit(y, u, order=3, **kw).model)
                )
    rms = {k: float(np.sqrt(np.mean(np.square(v)))) for k, v in err.items()}
    for name in ("fit_pbsid", "fit_ssarx"):
        assert rms[f"{name}100000"] < rms[f"{name}10000"] / 2.0, rms  # sqrt(10) = 3.2
        assert rms[f"{name}100000"] < 0.02, rms
    assert rms["fit_moesp100000"] > 0.3 and rms["fit_moesp10000"] > 0.3, rms


def test_kalman_gain_is_consistent():
    # Noise model C A^k K (basis invariant) against the truth at N = 2e5.
    y, u = generic_loop(200_000, 0.3, seed=5)
    res = fit_pbsid(y, u, order=3, past=20)
    m, Kh = res.model, res.extras["kalman_gain"]
    for k in range(4):
        want = C @ np.linalg.matrix_power(A, k) @ K
        got = m.C @ np.linalg.matrix_power(m.A, k) @ Kh
        np.testing.assert_allclose(got, want, atol=0.03)
    assert res.extras["predictor_spectral_radius"] < 1.0
    # Innovation covariance: e has unit variance 0.3^2 per channel.
    np.testing.assert_allclose(np.diag(res.extras["innovation_covariance"]), 0.09, rtol=0.05)


@pytest.mark.parametrize("fit", [fit_pbsid, fit_ssarx])
def test_bearing_physical_parameters_unbiased_where_moesp_is_not(bearing, fit):
    truth = np.asarray(bearing.metadata["truth_v"])
    # the transform path (the default in physical coordinates is now the structured fit,
    # which has its own tests below): the same poles as the identified model
    res = fit(
        bearing.y,
        bearing.u,
        order=4,
        past=40,
        dt=bearing.dt,
        coordinates="physical",
        physical_fit="transform",
    )
    v = np.array([res.parameters[f"v{i}"] for i in range(1, 10)])
    # Measured 4-6 % at N = 2e4 (0.4-0.7 % at 1e5, bench_pbsid); MOESP's v5/v7 ~50 %.
    assert np.max(np.abs(v / truth - 1.0)) < 0.15
    np.testing.assert_allclose(res.model.C, [[1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], atol=1e-9)
    mo = fit_moesp(bearing.y, bearing.u, order=4, horizon=40, dt=bearing.dt)
    _, cont = to_physical_coordinates(mo.model)
    v_mo, _ = v_from_matrices(cont.A, cont.B)
    assert np.max(np.abs(v_mo / truth - 1.0)) > 0.3
    # The same poles and Kalman predictor whatever the coordinates.
    ref = fit(bearing.y, bearing.u, order=4, past=40, dt=bearing.dt)
    np.testing.assert_allclose(
        np.sort_complex(res.model.poles()), np.sort_complex(ref.model.poles()), rtol=1e-9
    )
    np.testing.assert_allclose(res.residuals, ref.residuals, atol=1e-9 * np.std(bearing.y))


@pytest.mark.parametrize("algorithm", ["pbsid", "ssarx"])
def test_streamed_equals_in_memory(bearing, algorithm):
    fit = fit_pbsid if algorithm == "pbsid" else fit_ssarx
    ref = fit(bearing.y, bearing.u, order=4, past=12, dt=bearing.dt)
    got = fit_predictor_streamed(bearing, algorithm=algorithm, chunk_size=3001, order=4, past=12)
    # Same lagged products summed in another order, and another reference shift
    # (the first chunk's mean): rounding (rtol 1e-8).
    np.testing.assert_allclose(
        np.sort_complex(got.model.poles()), np.sort_complex(ref.model.poles()), rtol=1e-8
    )
    h = ref.model.markov(10)
    np.testing.assert_allclose(got.model.markov(10), h, atol=1e-8 * np.max(np.abs(h)))
    assert got.residuals is None and "one pass" in got.notes[-1]
    assert got.model.dt == bearing.dt
    auto = identify_streamed(bearing, algorithm, chunk_size=7000, order=4)
    assert auto.options["past_rule"] == "auto"


@pytest.mark.parametrize("fit", [fit_pbsid, fit_ssarx])
def test_offsets_change_nothing(fit):
    # Constant offsets of 1e3 x the signal rms (an operating point): the centred
    # Gram makes the fit offset invariant (rounding after the reference shift).
    y, u = generic_loop(20_000, 0.3, seed=7)
    cy, cu = np.array([300.0, -500.0]), np.array([1e3, 2.0])
    ref = fit(y, u, order=3, past=10)
    got = fit(y + cy, u + cu, order=3, past=10)
    h = ref.model.markov(10)
    np.testing.assert_allclose(got.model.markov(10), h, atol=1e-7 * np.max(np.abs(h)))
    np.testing.assert_allclose(got.extras["mean"]["y"], np.mean(y, axis=0) + cy)
    # Without centring the offsets bias the model.
    raw = fit(y + cy, u + cu, order=3, past=10, remove_mean=False)
    assert np.max(np.abs(raw.model.markov(10) - h)) > 1e-3


def test_accumulator_chunks_and_registry(bearing):
    acc = PredictorAccumulator(ny=3, nu=2, algorithm="ssarx", past=8)
    for k in range(0, bearing.n_samples, 4000):
        acc.update(bearing.y[k : k + 4000], bearing.u[k : k + 4000])
    got = acc.fit(order=4, dt=bearing.dt)
    ref = get_method("ssarx")(bearing, order=4, past=8)
    np.testing.assert_allclose(
        np.sort_complex(got.model.poles()), np.sort_complex(ref.model.poles()), rtol=1e-8
    )
    methods = available_methods()
    for name in ("pbsid", "ssarx"):
        assert name in methods and "closed-loop" in methods[name].__doc__.splitlines()[0]


def test_method_list_names_them(capsys):
    assert main(["--json", "identify", "x.npz", "--method", "list"]) == 0
    names = json.loads(capsys.readouterr().out)["methods"]
    assert "pbsid" in names and "ssarx" in names


def test_cli_stream_from_parquet_equals_whole_file(bearing, tmp_path, capsys):
    pytest.importorskip("pyarrow")
    from maglevid.io import write_recording

    path = tmp_path / "rec.parquet"
    write_recording(bearing, path)
    opts = ["--option", "order=4", "--option", "past=10"]
    outs = []
    for how in (["--no-stream"], ["--stream", "--chunk-size", "2500"]):
        assert main(["--json", "identify", str(path), "--method", "pbsid", *how, *opts]) == 0
        outs.append(json.loads(capsys.readouterr().out))
    whole, streamed = outs
    assert streamed["streamed"]["passes"] == 1
    for name, value in whole["parameters"].items():
        assert streamed["parameters"][name] == pytest.approx(value, rel=1e-7, abs=1e-12), name


def test_bad_input_gives_one_clear_error():
    y, u = generic_loop(2000, 0.1, seed=2)
    with pytest.raises(DataError, match="future"):
        fit_pbsid(y, u, past=4, future=6)
    with pytest.raises(DataError, match="order"):
        fit_ssarx(y, u, past=2, order=5)
    with pytest.raises(DataError, match="constant"):
        fit_pbsid(np.column_stack([y[:, 0], np.ones(2000)]), u)
    with pytest.raises(DataError, match="two-coil"):
        fit_pbsid(y, u, order=3, past=5, coordinates="physical")
    with pytest.raises(DataError, match="weighting"):
        fit_ssarx(y, u, weighting="n4sid")
    with pytest.raises(DataError, match="samples"):
        fit_pbsid(y[:50], u[:50], past=20)


def test_nonlinear_faulted_bearing_reads_the_fault():
    # The hard case: nonlinear plant at its bias point, R1 +20 % (v5 moves by +20 %,
    # the nominal bearing is 16.7 % off the faulted truth), the simulator's default
    # sensor noise, observer and controller on the nominal bearing. Truth: the
    # simulator's linearisation (metadata["truth_v"]). Measured at N = 4e4:
    # PBSID-opt within 3.6 %, v5 within 1.5 % (the physical IV: v5 +155 %).
    nom = AMBParameters.nominal()
    d = simulate_amb_loop(
        nom.with_fault(R1=1.2), nominal=nom, n_samples=40_000, rng=4, plant_model="nonlinear"
    )
    truth = np.asarray(d.metadata["truth_v"])
    res = get_method("pbsid")(d, order=4, coordinates="physical")
    v = np.array([res.parameters[f"v{i}"] for i in range(1, 10)])
    assert np.max(np.abs(v / truth - 1.0)) < 0.08
    assert abs(v[4] / truth[4] - 1.0) < 0.05 < abs(nom.v()[4] / truth[4] - 1.0)


# ---------------------------------------------------------- structured fit (P11)-(P13)
def _v_error(res, truth) -> float:
    v = np.array([res.parameters[f"v{i}"] for i in range(1, 10)])
    return float(np.max(np.abs(v / truth - 1.0)))


def test_structured_fit_is_closer_to_the_truth_than_the_transform(bearing):
    # Truth: the simulator's v1..v9. On this record (20 000 samples, default noise)
    # the transform leaves the largest v error at 2.7 % (PBSID-opt) / 1.6 % (SSARX,
    # past 40); the structured weighted least squares over 100 lags (a short window
    # to keep the test fast; 1.0 % with the default 240) brings both to 1.3 %
    # (measured; asserted under 1.5 % and under the transform's), in an innovation
    # model with the bearing's own structure.
    truth = np.asarray(bearing.metadata["truth_v"])
    kw = dict(order=4, past=40, dt=bearing.dt, coordinates="physical")
    got = {}
    for fit in (fit_pbsid, fit_ssarx):
        ref = fit(bearing.y, bearing.u, physical_fit="transform", **kw)
        res = fit(bearing.y, bearing.u, structure_past=100, **kw)  # structured: the default
        assert _v_error(res, truth) < min(0.015, _v_error(ref, truth))
        assert res.options["physical_fit"] == "structured"
        assert res.options["structure_past"] == res.extras["structure_lags"] == 100
        assert any("structured" in n for n in res.notes)
        np.testing.assert_array_equal(res.model.C, [[1, 0, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
        assert res.extras["predictor_spectral_radius"] < 1.0
        assert res.residuals is not None and res.residuals.shape == bearing.y.shape
        got[fit.__name__] = np.array([res.parameters[f"v{i}"] for i in range(1, 10)])
    # The criterion (P11) depends on the Gram only: from the two methods' different
    # starts the Gauss-Newton steps reach the same optimum, to their stopping rule
    # (measured 6e-4 relative, v5; far inside the 1.3 % error).
    np.testing.assert_allclose(got["fit_pbsid"], got["fit_ssarx"], rtol=1e-3)


def test_structured_fit_streamed_equals_in_memory(bearing):
    kw = dict(order=4, dt=bearing.dt, coordinates="physical", physical_fit="structured")
    ref = fit_pbsid(bearing.y, bearing.u, past=20, structure_past=60, **kw)
    acc = PredictorAccumulator(ny=3, nu=2, past=20, structure_past=60)
    for k in range(0, bearing.n_samples, 4999):
        acc.update(bearing.y[k : k + 4999], bearing.u[k : k + 4999])
    got = acc.fit(**kw)
    # the same Gram up to summation order; the Gauss-Newton steps keep it (rtol 1e-6).
    for name in [f"v{i}" for i in range(1, 10)]:
        assert got.parameters[name] == pytest.approx(ref.parameters[name], rel=1e-6)
    # the streamed method keeps the lags the structured fit asks for
    st = identify_streamed(bearing, "pbsid", chunk_size=7000, past=20, structure_past=60, **kw)
    assert st.options["structure_past"] == 60
    assert st.parameters["v5"] == pytest.approx(ref.parameters["v5"], rel=1e-6)


def test_structured_fit_options_are_checked(bearing):
    with pytest.raises(DataError, match="coordinates='physical'"):
        fit_pbsid(bearing.y, bearing.u, order=4, physical_fit="structured")
    with pytest.raises(DataError, match="physical_fit"):
        fit_pbsid(bearing.y, bearing.u, order=4, coordinates="physical", physical_fit="ml")


# ------------------------------------ refusals where the data cannot give v1..v9 (twelfth session)
@pytest.mark.parametrize("fit", [fit_pbsid, fit_ssarx])
def test_high_sensor_noise_is_refused_with_what_to_do(fit):
    # 20x the simulator's sensor noise (2e-6 m, 2e-3 A): the closed-loop predictor is
    # slower than a VARX of 80 lags can hold, and the order-4 black-box model has a pole
    # on the negative real axis (measured), so it has no physical coordinates. Before:
    # the transform's error without a way out; on a 30000-sample nonlinear record with
    # this noise (docs/subspace.md, "twelfth session") SSARX's structured fit ran 40 steps
    # to an unstable predictor and a diagnosis read it as a change in all 13 parameters.
    # Reference: the record does hold v1..v9 -- maximum likelihood through the Kalman
    # predictor (method ml, the way out the message names) finds them within 1.7
    # standard errors of the truth on this very record (measured).
    nom = AMBParameters.nominal()
    d = simulate_amb_loop(
        nom.with_fault(Ls1=1.1),
        nominal=nom,
        n_samples=20_000,
        rng=11,
        noise_std=(2e-6, 2e-3, 2e-3),
        plant_model="linear",
    )
    with pytest.raises(IdentificationError, match=r"physical coordinates.*method 'ml'"):
        fit(d.y, d.u, order=4, dt=d.dt, coordinates="physical")


def test_structured_fit_stopped_far_from_its_optimum_is_refused(bearing, monkeypatch):
    # One Gauss-Newton step (the bench's fits take 5-11): the step limit ends the
    # fit with a gain of hundreds of units of N log det still predicted. Such an
    # estimate's intervals mean nothing: refused, saying why. Below _STRUCTURE_LEFT (1
    # unit, about a standard error; one of 400 Monte Carlo fits at 1e4 stops there with
    # 0.044) it is kept with a note.
    from maglevid.identify import pbsid as P

    full = P.fit_bearing_structure
    monkeypatch.setattr(P, "fit_bearing_structure", lambda G, **kw: full(G, **kw, max_iter=1))
    kw = dict(order=4, dt=bearing.dt, coordinates="physical")
    with pytest.raises(
        IdentificationError, match=r"stopped after 1 Gauss-Newton step with a gain"
    ):
        fit_ssarx(bearing.y, bearing.u, **kw)
    monkeypatch.setattr(P, "_STRUCTURE_LEFT", np.inf)
    res = fit_ssarx(bearing.y, bearing.u, **kw)
    assert any("stopped at its step limit (1 Gauss-Newton step)" in n for n in res.notes)
    # an estimate whose predictor is unstable is refused whatever its convergence
    monkeypatch.setattr(
        P,
        "fit_bearing_structure",
        lambda G, **kw: dataclasses.replace(full(G, **kw), K=np.zeros((4, 3))),
    )
    with pytest.raises(IdentificationError, match="ends on an unstable predictor"):
        fit_pbsid(bearing.y, bearing.u, **kw)


def test_start_state_is_exact_on_noise_free_plant_data():
    # (P14): x(t) = Gamma_k^+ (Y_k - T_k U_k) is exact when y = C x and x follows
    # the plant (reference: the simulated state itself), in scaled units too.
    from maglevid.identify._structured import _plant, _state_map
    from maglevid.physics.amb import C_AMB

    v = AMBParameters.nominal().v()
    Ad, Bd = _plant(v, 1e-4)
    rng = np.random.default_rng(0)
    sy, su = np.array([1e-6, 1e-3, 1e-3]), np.array([0.5, 2.0])
    x = rng.standard_normal(4) * [1e-6, 1e-4, 1e-3, 1e-3]
    x0, z = x.copy(), []
    for _ in range(8):
        u = rng.standard_normal(2)
        z.append(np.concatenate([u / su, C_AMB @ x / sy]))
        x = Ad @ x + Bd @ u
    M = _state_map(Ad, Bd * su[None, :], C_AMB / sy[:, None], 8)
    np.testing.assert_allclose(M @ np.concatenate(z), x0, rtol=1e-8, atol=1e-20)


def test_structured_window_is_chosen_from_the_data(bearing):
    # (P16): P = ln N / (-2 ln rho), so that the truncation rho^P = N^{-1/2} falls like
    # the standard error; analytic values: ln(1e6) / (-2 ln 0.9826) = 393.9 -> 394.
    from maglevid.identify.pbsid import _structure_window

    assert _structure_window(1000, 1_000_000, 0.9826) == 394
    assert _structure_window(1000, 10_000, 0.9826) == 263
    assert _structure_window(300, 1_000_000, 0.9826) == 300  # capped by the lags kept
    assert _structure_window(300, 1_000_000, 1.01) == 300  # unstable predictor: the cap
    # (P23): where the start state stays at 0 (rho^P snr <= 1), at least
    # ln(snr / 0.05) / (-ln rho): ln(18.36 / 0.05) / 0.03190 = 185.1 -> 186 at N = 1e4
    # (P16 alone: 144.3 -> 145), up to the lags kept in memory there (305)
    assert _structure_window(1000, 10_000, 0.9686, 18.36) == 186
    assert _structure_window(1000, 10_000, 0.98, 20.0) == 297  # 296.6; P16: 228
    assert _structure_window(1000, 10_000, 0.9686, 1e4) == 145  # rebuilt (P17): P16's
    assert _structure_window(1000, 1_000_000, 0.9826, 20.0) == 394  # P16 longer (341.3)
    assert _structure_window(1000, 10_000, 0.984, 20.0) == 305  # 371: the lags kept
    kw = dict(order=4, dt=bearing.dt, coordinates="physical", physical_fit="structured")
    res = fit_pbsid(bearing.y, bearing.u, **kw)
    rho, P = res.extras["structure_predictor_radius"], res.extras["structure_lags"]
    assert res.options["structure_past_rule"] == "auto"
    assert res.options["structure_past"] == P >= _structure_window(10**9, bearing.n_samples, rho)
    assert res.extras["structure_dropped"] <= 0.05  # (P23) lengthened P16's window
    # (P17): this record's noise (1e-7 m, 1e-4 A) leaves the truncated start state below
    # the innovations, so it is left at 0; a high-SNR record rebuilds it (P14)
    assert res.extras["structure_start_samples"] == 0
    from maglevid.identify.pbsid import _options, _start_samples

    auto = _options(
        "pbsid",
        order=4,
        past=None,
        future=None,
        max_past=None,
        dt=1e-4,
        feedthrough=False,
        weighting="cca",
        rank_tol=None,
        remove_mean=True,
        coordinates="physical",
    )
    auto = dataclasses.replace(auto, structure_auto=True)
    y_rms = np.ones(3)
    assert _start_samples(auto, 0.98, 300, y_rms, np.eye(3) * 1e-2) == 0  # 2.3e-3 x 10 < 1
    assert _start_samples(auto, 0.98, 300, y_rms, np.eye(3) * 1e-8) == 8  # 2.3e-3 x 1e4 > 1
    # streamed with the default lags kept: the same window and fit (rtol: summation order)
    st = identify_streamed(bearing, "pbsid", chunk_size=7000, **kw)
    assert st.extras["structure_lags"] == P
    for name in [f"v{i}" for i in range(1, 10)]:
        assert st.parameters[name] == pytest.approx(res.parameters[name], rel=1e-6)
    # intervals like the other AMB methods: cov(v) (P15), v1..v9 and a1..a4
    assert res.covariance is not None and res.covariance.shape == (13, 13)
    se = res.std_errors()
    assert all(np.isfinite(se[f"v{i}"]) and se[f"v{i}"] > 0 for i in range(1, 10))


def test_structured_covariance_matches_the_scatter():
    # (P15) against the truth over a few records (the >= 30-record Monte Carlo is in
    # benchmarks/bench_pbsid.py): the normalised errors (v - truth) / se of 4 records
    # x 9 parameters have mean square 1 when the covariance is right; a 2x error in
    # the standard errors gives 0.25 or 4. Window 60 lags given (fast).
    z = []
    for seed in range(4):
        d = simulate_amb_loop(AMBParameters.nominal(), n_samples=6000, rng=100 + seed)
        truth = np.asarray(d.metadata["truth_v"])
        res = fit_pbsid(
            d.y,
            d.u,
            order=4,
            dt=d.dt,
            coordinates="physical",
            physical_fit="structured",
            structure_past=60,
        )
        se = res.std_errors()
        z += [(res.parameters[f"v{i}"] - truth[i - 1]) / se[f"v{i}"] for i in range(1, 10)]
    assert 0.4 < float(np.mean(np.square(z))) < 2.5


def test_in_place_factor_is_the_lower_cholesky_factor_or_rebuilds_the_gram():
    # _factor with a rebuild takes the Cholesky factor in the Gram's own memory (the
    # upper factor of its Fortran-ordered transpose, read back in C order).
    # Reference: LAPACK dpotrf's lower factor of a copy (measured equal to 1e-16 of
    # the unit diagonal; asserted 1e-13). A rank-deficient Gram (a noise-free record's)
    # is overwritten by the failed attempt: the pivoted factor is taken of the Gram
    # built again, exact to rounding (F F^T = G).
    from scipy.linalg import lapack

    from maglevid.identify import pbsid as P

    rng = np.random.default_rng(3)
    X = rng.standard_normal((60, 400))
    G = X @ X.T / 400
    ref = lapack.dpotrf(G, lower=1, clean=1)[0]
    calls = []
    F, rank = P._factor(G.copy(), lambda: calls.append(1) or G.copy())
    assert rank == 60 and not calls and not np.any(np.triu(F, 1))
    np.testing.assert_allclose(F, ref, atol=1e-13)
    Y = np.concatenate([X[:25], X[:5] + X[5:10]])  # 30 rows of rank 25
    G0 = Y @ Y.T / 400
    G0 /= np.sqrt(np.outer(np.diag(G0), np.diag(G0)))  # unit diagonal
    F, rank = P._factor(G0.copy(), lambda: calls.append(1) or G0.copy())
    assert calls == [1] and rank == 25
    np.testing.assert_allclose(F @ F.T, G0, atol=1e-12)


def test_unpivoted_factor_equals_the_pivoted_one(bearing, monkeypatch):
    # Reference: the pivoted-Cholesky data stage of 72d103a (factor_gram, all columns
    # kept). The plain Cholesky factor (_factor, on this noisy record) and the leading
    # columns of its rows (_leading) differ from it by an orthogonal F -> F Q and
    # zero columns: every estimate equal to rounding (measured 1e-10 relative on
    # the bench records; asserted 1e-8).
    from maglevid.identify import pbsid as P
    from maglevid.identify._hankel import factor_gram

    st = P._window_stats  # the new path is taken here: the factor is triangular
    acc = P._LagGram(5, 40)
    acc.update(np.concatenate([bearing.u, bearing.y], axis=1)[:5000])
    F = st(acc, 2, 3, 41, np.zeros(5), True).F
    assert F.shape[0] == F.shape[1] and not np.any(np.triu(F, 1))
    kw = dict(order=4, dt=bearing.dt, coordinates="physical", physical_fit="transform")
    new = [fit(bearing.y, bearing.u, **kw) for fit in (fit_pbsid, fit_ssarx)]
    # (_factor takes the rows to extend since the sixth session; the pivoted one never does)
    monkeypatch.setattr(P, "_factor", lambda G, prefix=None: factor_gram(G))
    monkeypatch.setattr(P, "_leading", lambda F, rows: F[:rows])
    old = [fit(bearing.y, bearing.u, **kw) for fit in (fit_pbsid, fit_ssarx)]
    for a, b in zip(new, old, strict=True):
        for name in [f"v{i}" for i in range(1, 10)]:
            assert a.parameters[name] == pytest.approx(b.parameters[name], rel=1e-8)
        np.testing.assert_allclose(a.extras["kalman_gain"], b.extras["kalman_gain"], rtol=1e-6)


@pytest.mark.parametrize("feedthrough", [False, True])
def test_varx_aic_from_the_triangular_factor_equals_the_reordered_one(bearing, feedthrough):
    # Reference: _arx_horizon's general route (QR of the rows reordered [y, u] per
    # time), taken for the same factor rotated by an orthogonal Q (F -> F Q changes
    # no Gram, so no AIC). The Cholesky factor's diagonal blocks give the same
    # residual covariances without the QR: equal to rounding (rtol 1e-10).
    from maglevid.identify import pbsid as P
    from maglevid.identify.subspace import _arx_horizon

    acc = P._LagGram(5, 30)
    acc.update(np.concatenate([bearing.u, bearing.y], axis=1)[:8000])
    st = P._window_stats(acc, 2, 3, 31, np.zeros(5), True)
    assert not np.any(np.triu(st.F, 1))  # the fast route is the one taken
    Q = np.linalg.qr(np.random.default_rng(0).standard_normal(st.F.shape))[0]
    p_fast, aic_fast = _arx_horizon(st, 30, feedthrough)
    p_ref, aic_ref = _arx_horizon(dataclasses.replace(st, F=st.F @ Q), 30, feedthrough)
    assert p_fast == p_ref
    np.testing.assert_allclose(aic_fast[1:], aic_ref[1:], rtol=1e-10)


def test_split_lag_pass_equals_the_interleaved_one(bearing, monkeypatch):
    # Records above _SPLIT_MIN feed u and y apart (update_split); the same lagged
    # products summed in another order: every estimate equal to rounding (rtol 1e-9,
    # measured 1e-12). Forced here on the 2e4-sample record.
    from maglevid.identify import pbsid as P

    kw = dict(order=4, dt=bearing.dt, coordinates="physical", physical_fit="transform")
    ref = [fit(bearing.y, bearing.u, **kw) for fit in (fit_pbsid, fit_ssarx)]
    monkeypatch.setattr(P, "_SPLIT_MIN", 0)
    monkeypatch.setattr(P, "_PASS_CHUNK", 3000)  # several chunks and junctions
    y, u = np.array(bearing.y), np.array(bearing.u)  # writable: the fit reads them in place
    got = [fit(y, u, **kw) for fit in (fit_pbsid, fit_ssarx)]
    np.testing.assert_array_equal(y, bearing.y)  # the user's arrays are not modified
    np.testing.assert_array_equal(u, bearing.u)
    for a, b in zip(got, ref, strict=True):
        for name in [f"v{i}" for i in range(1, 10)]:
            assert a.parameters[name] == pytest.approx(b.parameters[name], rel=1e-9)
        np.testing.assert_allclose(a.residuals, b.residuals, atol=1e-9 * np.abs(b.residuals).max())
        assert a.fit["one_step_fit_percent"] == pytest.approx(b.fit["one_step_fit_percent"])


def _paper_like_record() -> ClosedLoopData:
    """The bench's paper-like record at N = 1e4 (noise 1e-10 m, 3e-6 A; R1, kw1 +20 %):
    the truncated start state dominates the residual and (P17) rebuilds it (P14)."""
    nom = AMBParameters.nominal()
    return simulate_amb_loop(
        nom.with_fault(R1=1.2, kw1=1.2),
        nominal=nom,
        n_samples=10_000,
        rng=11,
        observer_model="plant",
        noise_std=(1e-10, 3e-6, 3e-6),
        plant_model="linear",
    )


def test_structured_jacobian_equals_central_differences(monkeypatch):
    # The Gauss-Newton Jacobian of (P11) with the start-state term (P14) is analytic:
    # d(Abar^P) by the block-triangular power, d(Gamma_k^+) by the pseudo-inverse's
    # derivative, the ZOH's by Van Loan's block exponential. The whitened residual is
    # linear in the predictor's blocks V (J = -W^{1/2} dV Fz), so dV is what is
    # checked. Reference: central differences of V, steps scaled to each column
    # (truncation ~h^2, measured 1e-7-6e-7 relative on this record). The forward
    # differences of 6769610 (step 1e-7 on K entries of ~1e-7) were 0.7 % - 3000x off
    # in the K columns here (measured), and Gauss-Newton crawled (40 steps at N = 1e5).
    from maglevid.identify import _structured as S

    seen = {}

    def spy(crit, p, W, j, max_iter, tol, final=False):
        dV = crit.blocks(p.theta)[1].transpose(3, 0, 1, 2).reshape(p.theta.size, -1)
        d = np.linalg.norm(dV, axis=1)
        err = np.empty(p.theta.size)
        for i in range(p.theta.size):
            e = np.zeros_like(p.theta)
            e[i] = 1e-5 * np.linalg.norm(p.V) / d[i]
            dc = (crit.markov(p.theta + e) - crit.markov(p.theta - e)).ravel() / (2 * e[i])
            err[i] = np.linalg.norm(dV[i] - dc) / np.linalg.norm(dc)
        seen.setdefault("err", err)
        return p, 0, (p.theta, p.Re), 0.0

    monkeypatch.setattr(S, "_gauss_newton", spy)
    d = _paper_like_record()
    kw = dict(order=4, dt=d.dt, coordinates="physical")
    res = fit_pbsid(d.y, d.u, **kw)
    assert res.extras["structure_start_samples"] == S.START_SAMPLES
    assert seen["err"].shape == (21,) and np.all(seen["err"] < 1e-5), seen["err"]


# --------------------------------------------- the structured fit's time (sixth session)
def _assert_same_optimum(new, old, se_tol: float, steps: str) -> None:
    """v1..v9 within ``se_tol`` standard errors of ``old``'s, the standard errors to
    ``se_tol`` relative; Gauss-Newton steps ``"equal"``, ``"no more"`` or ``"any"``."""
    se = np.sqrt(np.diag(old.extras["structure_covariance"]))
    v = [np.array([r.parameters[f"v{i}"] for i in range(1, 10)]) for r in (new, old)]
    assert np.max(np.abs(v[0] - v[1]) / se) < se_tol
    se_new = np.sqrt(np.diag(new.extras["structure_covariance"]))
    np.testing.assert_allclose(se_new, se, rtol=se_tol)
    it_new, it_old = new.extras["structure_iterations"], old.extras["structure_iterations"]
    if steps != "any":
        assert it_new == it_old if steps == "equal" else it_new <= it_old


@pytest.mark.parametrize("fit", [fit_pbsid, fit_ssarx])
def test_structured_fit_through_the_gram_operator_equals_the_dense_gram(bearing, fit, monkeypatch):
    # Reference: the data stage's own factor F of the window's Gram (its Cholesky, as
    # the sixth session's fit read it; since the ninth, the Hankel rows of the structured
    # window itself, N - P rows), products X (F F^T) Y^T formed densely. The seventh
    # session reads the Gram only through FFT products (P18), equal to rounding
    # (test_gram_operator.py), and evaluates cost differences instead of costs: the
    # same optimum (measured <= 1e-6 of a standard error on the bench records at 1e4;
    # asserted 1e-4), the same number of Gauss-Newton steps.
    from maglevid.identify import pbsid as P

    kw = dict(order=4, dt=bearing.dt, coordinates="physical")
    new = fit(bearing.y, bearing.u, **kw)

    class Dense:
        def __init__(self, wg, k):
            st = P._window_stats(wg.acc, 2, 3, k, np.zeros(5), wg.center, k)
            self.G, self.k, self.j = st.F @ st.F.T, k, st.j
            self.n = k  # the FFT's length the criterion pads its rows to: none here

        def encode_blocks(self, Xb):  # (k, r, m) block-major -> rows (r, k m)
            return Xb.transpose(1, 0, 2).reshape(Xb.shape[1], -1)

        def inner(self, A, C):
            return A @ self.G @ C.T

    monkeypatch.setattr(P._WindowGram, "__call__", lambda wg, k: Dense(wg, k))
    _assert_same_optimum(new, fit(bearing.y, bearing.u, **kw), 1e-4, "equal")


def test_a_step_to_an_unstable_predictor_fails_without_its_cost(bearing, monkeypatch):
    # From a stable predictor, a trial step whose Abar has a pole on or outside the
    # unit circle is failed at once (cost change inf, the point's Re kept): its cost
    # rises for certain through Abar^P and the fit would be refused there. Reference:
    # the bearing's open-loop A_d (K = 0) is unstable (its pole e^{p dt} > 1, eq. (4));
    # a step of 1e-6 in v1 from the start keeps the predictor stable and is costed.
    from maglevid.identify import _structured as S

    seen = {}

    def spy(crit, p, W, j, max_iter, tol, final=False):
        unstable = np.concatenate([p.theta[:9], np.zeros(12)])
        seen["bad"] = crit.trial(p, unstable, W)
        seen["ok"] = crit.trial(p, p.theta + 1e-6 * np.eye(p.theta.size)[0], W)
        with np.errstate(all="ignore"):  # a step far past it: Abar not even finite
            seen["far"] = crit.trial(p, p.theta * 1e300 * 1e300, W)
        seen["rho"] = p.rho
        return p, 0, (p.theta, p.Re), 0.0

    monkeypatch.setattr(S, "_gauss_newton", spy)
    fit_pbsid(bearing.y, bearing.u, order=4, dt=bearing.dt, coordinates="physical")
    assert seen["rho"] < 1.0
    assert seen["bad"][0] == np.inf and seen["far"][0] == np.inf
    assert np.isfinite(seen["ok"][0]) and abs(seen["ok"][0]) < 1e-3


@pytest.mark.parametrize("record", ["default", "paper-like"])
def test_sequence_basis_products_equal_the_encoded_rows(bearing, record, monkeypatch):
    # (P22): the 63 derivative rows are sequences of one 4-state predictor and its
    # derivative, in a space of at most 2 n = 8 sequences; their Gram products go
    # through an orthonormal basis of it (and, with the start term (P14), the unit
    # rows of its k0 blocks). Reference: the 66 rows encoded as they are (the route of
    # the seventh to twelfth sessions, equal to the dense Gram: test above), at the
    # structured fit's start. Measured 8e-12 (default record) and 1.3e-7 (paper-like:
    # there the products of rows written out against the dense Gram differ from both
    # routes by 7e-8 - 2e-7 too, rounding) of the products' diagonal scale; the normal
    # equations 3e-12 / 4e-9 (J^T J) and 4e-14 / 3e-10 (J^T r) of their largest entries.
    from maglevid.identify import _structured as S

    seen = {}

    def spy(crit, p, W, j, max_iter, tol, final=False):
        dv = crit._sequence_rows(crit.blocks(p.theta)[1])
        monkeypatch.setattr(crit, "_sequences", False)
        q = crit.point(p.theta)
        seen.update(k0=crit.k0, rank=dv.coef.shape[1] // 5, new=p, old=q, W=W)
        return p, 0, (p.theta, p.Re), 0.0

    monkeypatch.setattr(S, "_gauss_newton", spy)
    d = bearing if record == "default" else _paper_like_record()
    fit_pbsid(d.y, d.u, order=4, dt=d.dt, coordinates="physical")
    assert seen["k0"] == (0 if record == "default" else S.START_SAMPLES)
    assert seen["rank"] == 8  # 2 n: the four modes of Abar, each with its derivative's
    new, old = seen["new"], seen["old"]
    assert isinstance(new.dV, S._SequenceRows) and isinstance(old.dV, S._EncodedRows)
    sc = np.sqrt(np.diag(old.M))
    tol = 1e-10 if record == "default" else 1e-6
    assert np.max(np.abs(new.M - old.M) / np.outer(sc, sc)) < tol
    (H1, g1), (H0, g0) = S._normal(new, seen["W"]), S._normal(old, seen["W"])
    assert np.max(np.abs(H1 - H0)) < tol * np.max(np.abs(H0))
    assert np.max(np.abs(g1 - g0)) < tol * np.max(np.abs(g0))


@pytest.mark.parametrize("fit", [fit_pbsid, fit_ssarx])
def test_structured_fit_through_the_sequence_basis_reaches_the_same_optimum(
    bearing, fit, monkeypatch
):
    # Reference: the fit with every point's rows encoded as they are (what a point
    # falls back to when its basis misses a row by more than _BASIS_TOL, forced here
    # by a negative tolerance): the same steps and the same optimum to rounding
    # (measured 7e-12 standard errors on the bench's default record at 1e4, 1e-6 on
    # the paper-like one; asserted 1e-4, as the dense Gram's test).
    from maglevid.identify import _structured as S

    kw = dict(order=4, dt=bearing.dt, coordinates="physical")
    new = fit(bearing.y, bearing.u, **kw)
    monkeypatch.setattr(S, "_BASIS_TOL", -1.0)
    _assert_same_optimum(new, fit(bearing.y, bearing.u, **kw), 1e-4, "equal")


@pytest.mark.parametrize("fit", [fit_pbsid, fit_ssarx])
def test_gauss_newton_halving_reaches_the_same_optimum(bearing, fit, monkeypatch):
    # Reference: the Levenberg-Marquardt loop without halvings (ab22305's). Both stop
    # when a step gains less than 1e-3 in j J (twice the log-likelihood), i.e. a
    # few hundredths of a standard error from the optimum; measured 1e-6 - 5.4e-4
    # standard errors apart on the bench records (but for SSARX on the paper-like
    # record at 1e6, where halving reaches a better local minimum: docs/subspace.md,
    # "sixth session"). Asserted 0.02 (the stop rule's reach), standard errors to
    # 2 %, and never more Jacobians.
    from maglevid.identify import _structured as S

    kw = dict(order=4, dt=bearing.dt, coordinates="physical")
    new = fit(bearing.y, bearing.u, **kw)
    monkeypatch.setattr(S, "_HALVINGS", 0)
    _assert_same_optimum(new, fit(bearing.y, bearing.u, **kw), 0.02, "no more")


@pytest.mark.parametrize("fit", [fit_pbsid, fit_ssarx])
def test_structured_fit_with_fft_lag_products_equals_the_direct_sums(bearing, fit, monkeypatch):
    # Reference: the direct lagged sums (the stream's route), forced by raising the
    # FFT's threshold. The FFT's products equal them to ~1e-15 of the channels'
    # energies (test_hankel_fft.py): v1..v9 and their standard errors equal to a
    # small fraction of a standard error (measured ~1e-6 on the bench records at 1e4;
    # asserted 1e-4), the same number of Gauss-Newton steps.
    from maglevid.identify import pbsid as P

    kw = dict(order=4, dt=bearing.dt, coordinates="physical")
    new = fit(bearing.y, bearing.u, **kw)
    assert new.options["structure_past"] >= P._FFT_MIN_LAGS  # the FFT route is taken
    monkeypatch.setattr(P, "_FFT_MIN_LAGS", 10**9)
    _assert_same_optimum(new, fit(bearing.y, bearing.u, **kw), 1e-4, "equal")


def test_secant_update_meets_the_secant_equation():
    # Reference: Dennis, Gay & Welsch (1981), NL2SOL: the updated S is symmetric and
    # maps the step to y# = (J1 - J0)^T r1 exactly (the secant equation; algebra).
    # The fit passes the products g = J^T R of both points and J0^T R1.
    from maglevid.identify._structured import _dgw

    rng = np.random.default_rng(3)
    J0, R0 = rng.standard_normal((40, 6)), rng.standard_normal((4, 10))
    J1, R1 = J0 + 0.1 * rng.standard_normal((40, 6)), R0 + 0.1 * rng.standard_normal((4, 10))
    r0, r1 = R0.ravel(), R1.ravel()
    s = np.linalg.lstsq(J0, -r0, rcond=None)[0]
    S = None
    for _ in range(2):  # from 0, then from the first update (sized)
        S = _dgw(S, s, J0.T @ r0, J1.T @ r1, J0.T @ r1)
        np.testing.assert_allclose(S, S.T, atol=1e-12)
        np.testing.assert_allclose(S @ s, (J1 - J0).T @ r1, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("fit", [fit_pbsid, fit_ssarx])
def test_secant_second_order_term_reaches_the_same_optimum(bearing, fit, monkeypatch):
    # Reference: the steps without S (Gauss-Newton with halvings). The same stop rule,
    # so the same optimum to its reach: measured 8e-5 - 1.7e-3 standard errors apart
    # on the bench records (1e4-1e6), the criterion never higher; asserted 0.02 and
    # standard errors to 2 %.
    from maglevid.identify import _structured as S

    kw = dict(order=4, dt=bearing.dt, coordinates="physical")
    new = fit(bearing.y, bearing.u, **kw)
    monkeypatch.setattr(S, "_dgw", lambda *a: None)
    old = fit(bearing.y, bearing.u, **kw)
    _assert_same_optimum(new, old, 0.02, "any")
    ld = [np.linalg.slogdet(r.extras["innovation_covariance"])[1] for r in (new, old)]
    assert (ld[0] - ld[1]) * bearing.n_samples < 1e-2  # not a worse fit (a gain of 1e-3: stop)


def test_varx_by_triangular_solve_equals_the_pivoted_qr(bearing, monkeypatch):
    # Reference: PBSID-opt's VARX before the seventh session (b7871a3), the pivoted-QR
    # least squares (LAPACK dgelsy, subspace._regress) on the same factor rows. On
    # the Cholesky factor's square triangular rows the triangular solve is the same
    # solution: measured 8e-15 of V's largest entry here; asserted 1e-12. The default
    # fit on top of it: measured 4e-15 relative in v1..v9 and 4e-14 in the residuals
    # here (<= 2.1e-14 and 1.7e-12 on both bench records against b7871a3); asserted
    # 1e-10, the rounding bound of the task (issue 16, seventh session).
    from maglevid.identify import pbsid as P
    from maglevid.identify.subspace import _regress

    acc = P._LagGram(5, 40)
    acc.update(np.concatenate([bearing.u, bearing.y], axis=1)[:8000])
    st = P._window_stats(acc, 2, 3, 41, np.zeros(5), True)
    p = 40
    V, D = P._varx(st, p, False)
    assert P._cholesky_solver(P._leading(st.F, p * 5)) is not None  # the route taken
    ref = _regress(st.F[st.y_rows(p, p + 1)], st.F[P._z_rows(st, 0, p)], P._RCOND)
    np.testing.assert_allclose(V, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    assert not np.any(D)
    kw = dict(order=4, dt=bearing.dt, coordinates="physical")
    new = fit_pbsid(bearing.y, bearing.u, **kw)
    monkeypatch.setattr(P, "_cholesky_solver", lambda Zp: None)  # the pivoted QR
    old = fit_pbsid(bearing.y, bearing.u, **kw)
    for name in [f"v{i}" for i in range(1, 10)]:
        assert new.parameters[name] == pytest.approx(old.parameters[name], rel=1e-10, abs=0)
    scale = np.abs(old.residuals).max()
    np.testing.assert_allclose(new.residuals, old.residuals, rtol=0, atol=1e-10 * scale)
    assert new.options == old.options and new.notes == old.notes


@pytest.mark.parametrize("weighting", ["cca", "none"])
def test_ssarx_state_map_left_unformed_equals_the_formed_one(bearing, weighting, monkeypatch):
    # Since the thirtieth session SSARX's beta = ytil_f,k Z_p^{-1} is not formed on the
    # Cholesky factor's triangular rows: (P8) factors ytil_f,k itself (= beta Z_p) and
    # the states solve n rows. Reference: the formed route (beta by the triangular solve
    # of all f ny rows, then beta Z_p), taken by making the rows look non-triangular to
    # the new branch only. Measured on this record: singular values equal to 1.7e-13 of
    # s_1 and L to 1.3e-12 of its largest entry (the formed route's solve and product
    # with Z_p, condition ~1e3, carry that rounding), the fit's v1..v9 to 3e-14
    # relative; asserted 1e-11, 1e-10 and 1e-10.
    from maglevid.identify import pbsid as P

    acc = P._LagGram(5, 60)
    acc.update(np.concatenate([bearing.u, bearing.y], axis=1)[:8000])
    st = P._window_stats(acc, 2, 3, 60, np.zeros(5), True)
    p, f = 40, 20
    svd, GK = P._state_map_ssarx(st, p, f, False, weighting, [])
    assert isinstance(GK, P._RightSolved)  # the route taken
    kw = dict(order=4, dt=bearing.dt, coordinates="physical", weighting=weighting)
    new = fit_ssarx(bearing.y, bearing.u, **kw)
    monkeypatch.setattr(P, "_is_triangular", lambda Zp: False)
    svd0, GK0 = P._state_map_ssarx(st, p, f, False, weighting, [])
    assert isinstance(GK0, np.ndarray)
    np.testing.assert_allclose(svd.s, svd0.s, rtol=0, atol=1e-11 * svd0.s[0])
    L, L0 = P._state_matrix(svd, GK, 4), P._state_matrix(svd0, GK0, 4)
    np.testing.assert_allclose(L, L0, rtol=0, atol=1e-10 * np.abs(L0).max())
    old = fit_ssarx(bearing.y, bearing.u, **kw)
    for name in [f"v{i}" for i in range(1, 10)]:
        assert new.parameters[name] == pytest.approx(old.parameters[name], rel=1e-10, abs=0)


@pytest.mark.parametrize("gap", [1e3, 1.28])
def test_left_svd_values_and_leading_vectors_equal_the_full_svd(gap):
    # The transform's SVD: values by gesdd without vectors, the n leading left vectors
    # as eigenvectors of R^T R (eighth session). Reference: numpy's full SVD of P.
    # A clear gap (1e3) and the UAQ rig's marginal one (s_4 / s_5 = 1.28), s_1 / s_4
    # = 1e3: values to 1e-12 relative, the vectors' projector to 1e-9 (bound
    # ~eps s_1^2 / (s_4^2 - s_5^2) ~ 3e-10 at the marginal gap).
    from maglevid.identify.pbsid import _LeftSVD

    rng = np.random.default_rng(5)
    r, c = 60, 200
    s_true = np.concatenate([[1.0, 0.3, 0.05, 1e-3], 1e-3 / gap * np.logspace(0, -3, r - 4)])
    Ul = np.linalg.qr(rng.standard_normal((r, r)))[0]
    Vr = np.linalg.qr(rng.standard_normal((c, r)))[0]
    P = (Ul * s_true) @ Vr.T
    U, s, _ = np.linalg.svd(P, full_matrices=False)
    svd = _LeftSVD(P)
    np.testing.assert_allclose(svd.s, s, rtol=1e-12, atol=1e-15 * s[0])
    V = svd.vectors(4)
    assert V.shape == (r, 4)
    assert np.max(np.abs(V @ V.T - U[:, :4] @ U[:, :4].T)) < 1e-9
    tall = _LeftSVD(P[:, :40].T @ P[:, :40])  # rows >= columns: the SVD itself
    np.testing.assert_allclose(
        np.abs(tall.vectors(2)), np.abs(np.linalg.svd(P[:, :40].T @ P[:, :40])[0][:, :2])
    )


def test_bounded_values_from_the_gram_equal_the_svd():
    # SSARX's CCA-weighted state map: values that whitening bounds (canonical
    # correlations) from the eigenvalues of P P^T (thirty-first session). Reference:
    # numpy's SVD. Values spanning 1 to 0.09 (the bench records'): values to 1e-13
    # relative, the leading vectors' projector to 1e-13. Values spanning 1e-6 (past
    # _GRAM_SVD_SPAN): the QR route, values to 1e-12 relative or 1e-15 of s_1, as before.
    from maglevid.identify.pbsid import _LeftSVD

    rng = np.random.default_rng(7)
    r, c = 40, 150

    def wide(s_true):
        Ul = np.linalg.qr(rng.standard_normal((r, r)))[0]
        return (Ul * s_true) @ np.linalg.qr(rng.standard_normal((c, r)))[0].T

    for low, via_gram in ((0.09, True), (1e-6, False)):
        s_true = np.concatenate([[1.0, 0.99, 0.97, 0.95], np.geomspace(0.3, low, r - 4)])
        P = wide(s_true)
        U, s, _ = np.linalg.svd(P, full_matrices=False)
        svd = _LeftSVD(P, bounded=True)
        assert (svd._R is None) == via_gram
        np.testing.assert_allclose(svd.s, s, rtol=1e-13 if via_gram else 1e-12, atol=1e-15)
        V = svd.vectors(4)
        assert np.max(np.abs(V @ V.T - U[:, :4] @ U[:, :4].T)) < 1e-13


def test_leading_eigenvectors_by_subspace_iteration_equal_syevr():
    # The transform's leading vectors by subspace iteration where the values' gap makes
    # it a few steps (thirty-first session). Reference: LAPACK's syevr (scipy's eigh) on
    # R^T R. A clear gap (s_5 / s_4 = 1e-3): the same projector to 1e-13, each vector's
    # largest entry positive; the UAQ rig's marginal gap (1.28) and a block as wide as R:
    # None (syevr then). A rank-4 R (s_5 = 0): exact in one step.
    from maglevid.identify.pbsid import _leading_eigenvectors

    rng = np.random.default_rng(11)
    r = 60

    def case(s_true):
        R = np.linalg.qr(
            (np.linalg.qr(rng.standard_normal((r, r)))[0] * s_true) @ rng.standard_normal((r, r))
        )[1]
        return R, np.linalg.svd(R, compute_uv=False)

    for tail in (1e-3, 0.0):
        R, s = case(
            np.concatenate([[1.0, 0.3, 0.05, 1e-2], tail * 1e-2 * np.logspace(0, -3, r - 4)])
        )
        U = _leading_eigenvectors(R, s, 4)
        V = sla.eigh(R.T @ R, subset_by_index=[r - 4, r - 1])[1][:, ::-1]
        assert np.max(np.abs(U @ U.T - V @ V.T)) < 1e-13
        np.testing.assert_allclose(np.abs(U), np.abs(V), atol=1e-13)
        assert np.all(U[np.argmax(np.abs(U), axis=0), np.arange(4)] > 0)
    R, s = case(np.concatenate([[1.0, 0.3, 0.05, 1e-2], 1e-2 / 1.28 * np.logspace(0, -3, r - 4)]))
    assert _leading_eigenvectors(R, s, 4) is None
    assert _leading_eigenvectors(R[:6, :6], s[:6], 4) is None


def test_characteristic_polynomial_covariance_equals_central_differences(bearing):
    # Reference: the delta method with central differences of a = char. poly(A_d(v))
    # (result.propagate_covariance, relative steps 1e-6: its own error ~1e-6). The fit
    # takes the Jacobian analytically (Faddeev-LeVerrier adjugate and the ZOH's Frechet
    # derivatives): measured 7e-7 apart on the bench records; asserted 1e-5.
    from maglevid.identify import pbsid as P
    from maglevid.identify._structured import _plant
    from maglevid.identify.subspace import _char_poly

    res = fit_pbsid(bearing.y, bearing.u, order=4, dt=bearing.dt, coordinates="physical")
    cov_v = res.extras["structure_covariance"]
    got = P._parameter_covariance(res.parameters, cov_v, bearing.dt)
    v = np.array([res.parameters[f"v{i}"] for i in range(1, 10)])
    _, ref = propagate_covariance(
        lambda x: np.concatenate([x, _char_poly(_plant(x, bearing.dt)[0])]), v, cov_v
    )
    sd = np.sqrt(np.diag(ref))
    assert got.shape == (13, 13)
    np.testing.assert_allclose(got / np.outer(sd, sd), ref / np.outer(sd, sd), atol=1e-5)
    np.testing.assert_allclose(res.covariance, got)  # what the result carries


@pytest.mark.parametrize("fit", [fit_pbsid, fit_ssarx])
def test_final_step_lands_within_the_stop_rules_reach(bearing, fit, monkeypatch):
    # Reference: the same fit converged to a predicted gain of 1e-5 (no final step).
    # The default ends on a step predicted to gain < 0.1 of j J (at most ~0.3 standard
    # errors long) without a point after it, its covariance from the point one step
    # back: measured 5e-4 - 9.3e-3 standard errors from the reference on the bench
    # records and <= 0.033 on 16 more fits (docs/subspace.md, "ninth session");
    # asserted 0.05 and standard errors to 1 %.
    from maglevid.identify import _structured as S

    kw = dict(order=4, dt=bearing.dt, coordinates="physical")
    new = fit(bearing.y, bearing.u, **kw)
    monkeypatch.setattr(S, "_GAIN_TOL", 1e-5)
    monkeypatch.setattr(S, "_FINAL_GAIN", 0.0)
    ref = fit(bearing.y, bearing.u, **kw)
    _assert_same_optimum(new, ref, 0.05, "no more")
    se = np.sqrt(np.diag(ref.extras["structure_covariance"]))
    se_new = np.sqrt(np.diag(new.extras["structure_covariance"]))
    np.testing.assert_allclose(se_new, se, rtol=0.01)


# ------------------------------------------------- the automatic order without a clear gap
def test_bic_order_without_a_clear_gap_is_the_simulators(bearing):
    # Reference: the simulator's state dimension (4: x, dx/dt, i1, i2). SSARX's
    # singular values on this record have no clear gap (s_4/s_5 = 4.3 < 10); the
    # BIC of each candidate model's own one-step prediction errors picks 4, the
    # runner-up (5) 75 units of N log det above it (measured).
    res = fit_ssarx(bearing.y, bearing.u, dt=bearing.dt)
    assert res.options["order"] == 4 and res.options["order_rule"] == "auto-bic"
    bic = res.extras["order_bic"]
    assert int(np.argmin(bic)) == 3 and np.sort(bic)[1] - bic[3] > 20.0
    assert any("no clear gap" in n for n in res.notes)
    assert not any("marginal" in n for n in res.notes)
    # a clear gap still decides (PBSID-opt here: s_4/s_5 = 31), and physical
    # coordinates take the bearing's 4 states whatever the values say
    clear = fit_pbsid(bearing.y, bearing.u, dt=bearing.dt)
    assert clear.options["order_rule"] == "auto" and "order_bic" not in clear.extras
    phys = fit_ssarx(bearing.y, bearing.u, dt=bearing.dt, coordinates="physical",
                     physical_fit="transform")  # fmt: skip
    assert phys.options["order"] == 4 and phys.options["order_rule"] == "structure"


@pytest.mark.parametrize(
    ("method", "session", "old"),
    [
        ("ssarx", "escalon_20251217_205858", "order 44 by a gap of 1.38, one-step fit -54 %"),
        ("pbsid", "chirp_20251217_210058", "order 1 by a gap of 9.7, predictor unstable"),
        ("pbsid", "multiescalon_20251217_210203", "order 128 by a gap of 8.8"),
    ],
)
def test_real_levitator_gets_an_order_that_predicts(shared_data, capsys, method, session, old):
    # The UAQ levitator (real, nonlinear; ../shared/data/maglev-uaq-levitador): its
    # singular values decay without a clear gap and the largest ratio landed anywhere
    # (`old`, measured on 5ab7623). Reference: the record itself - the chosen model's
    # own one-step predictor must be stable and predict (fits measured with the new
    # rule: 51.6, 92.9, 94.6 %; orders 4, 11, 10; physically the levitator is 3).
    path = shared_data / "maglev-uaq-levitador" / f"dataset_{session}.txt"
    assert main(["identify", str(path), "--mapping", "uaq-levitador", "--method", method,
                 "--json"]) == 0  # fmt: skip
    out = json.loads(capsys.readouterr().out)
    assert out["options"]["order_rule"] == "auto-bic", old
    assert out["options"]["order"] <= 20
    assert out["fit"]["one_step_fit_percent"] > 45.0, old
    assert not any("predictor A - K C is not stable" in n for n in out["notes"])
