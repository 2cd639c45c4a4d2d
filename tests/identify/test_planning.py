"""Experiment planning: the excitation/noise split of the information, and the plan."""

from __future__ import annotations

import json

import numpy as np
import pytest

from maglevid.cli.main import main
from maglevid.exceptions import DataError
from maglevid.identify.cramer_rao import NoiseModel, cramer_rao_bound
from maglevid.identify.planning import (
    design_information,
    excitation_signal,
    plan_experiment,
    plan_for_recording,
)
from maglevid.physics.amb import AMBParameters
from maglevid.simulate.amb import (
    DEFAULT_FORCE_STD,
    DEFAULT_NOISE_STD,
    default_amb_controller,
    default_amb_observer,
    simulate_amb_loop,
)

NOMINAL = AMBParameters.nominal()
FAULTY = NOMINAL.with_fault(R1=1.2)

#: The plan is computed on the paper's linear model with sensor noise
#: (planning.py, module notes: the excitation/noise split is exact there), so
#: the records it is checked against are simulated on that model explicitly
#: (the simulator's default is the nonlinear bearing with a force disturbance).
LINEAR = {"plant_model": "linear", "force_std": 0.0}


#: The noise model of those linear records: sensor noise only (the planner's
#: default adds the realistic bearing's 0.1 N force disturbance).
SENSOR_ONLY = NoiseModel(DEFAULT_NOISE_STD)


@pytest.fixture(scope="module")
def design():
    return design_information(FAULTY, nominal=NOMINAL, noise=SENSOR_ONLY, spectra=("lowpass:100",))


@pytest.mark.parametrize("excitation", [0.5, 2.0])
def test_split_information_predicts_the_bound_of_a_record_at_another_excitation(
    design, excitation
):
    """``alpha^2 I_r + I_e`` (from runs at 1 V and at 0 V) against the bound computed
    directly on records simulated at ``excitation`` (independent seeds). Each
    is a sample average; x0's bound, set by the slowest dynamics, varies by
    ~8 % between 1e4-sample records (measured over seeds 5-7: 170-193 nm at
    2 V), so the direct bound is the rms over three records (~5 %) and the
    plan's over 2e4 samples (~5 %): 12 % accepted."""
    direct = {}
    for seed in (5, 6, 7):
        d = simulate_amb_loop(
            FAULTY,
            nominal=NOMINAL,
            n_samples=10_000,
            excitation_std=excitation,
            rng=seed,
            **LINEAR,
        )
        for k, s in cramer_rao_bound(d, estimate_noise=True).std().items():
            direct[k] = direct.get(k, 0.0) + s**2 / 3
    planned = design.bound(n_samples=10_000, excitation_std=excitation).std()
    for k in ("v1", "v5", "v8", "R1", "kw1", "L1", "x0"):
        assert planned[k] == pytest.approx(np.sqrt(direct[k]), rel=0.12), k


def test_plan_rows_are_consistent_with_the_bound(design):
    plan = plan_experiment(
        design, n_samples=20_000, excitation_std=1.0, parameters=("R1", "kw1"), tolerance=0.01
    )
    for row in plan.rows:
        n_needed = round(row.seconds_now / design.dt)
        at_n = design.bound(n_samples=n_needed, excitation_std=1.0).std()[row.name]
        assert at_n == pytest.approx(row.target_std, rel=1e-3)
        # More excitation can only help; the bound falls ~ 1/alpha^2 when the
        # excitation's information dominates (it does at 4 V).
        assert row.seconds_at_max < row.seconds_now
        assert row.seconds_at_max == pytest.approx(row.seconds_now / 16, rel=0.15)
        exc = row.excitation_for_length
        at_exc = design.bound(n_samples=20_000, excitation_std=exc).std()[row.name]
        assert at_exc == pytest.approx(row.target_std, rel=0.01)
    assert "at this excitation" in plan.sentence()
    # The displacement limit binds before a large amplifier limit.
    wide = plan_experiment(design, n_samples=20_000, excitation_std=1.0, max_excitation_std=100)
    assert wide.max_excitation_std < 100
    assert design.displacement_rms(wide.max_excitation_std) == pytest.approx(
        0.02 * FAULTY.x0, rel=1e-6
    )


def test_plan_for_a_recording_and_its_errors():
    d = simulate_amb_loop(FAULTY, nominal=NOMINAL, n_samples=4000, rng=2, **LINEAR)
    plan = plan_for_recording(d, parameters=("R1",), tolerance=0.02)
    assert plan.n_samples == 4000 and plan.rows[0].name == "R1"
    assert np.isfinite(plan.rows[0].seconds_now)
    with pytest.raises(DataError, match="unknown parameters"):
        plan_for_recording(d, parameters=("R9",))


def test_plan_command(capsys):
    assert main(["--json", "plan", "--parameters", "R1,kw1", "--fault", "R1=1.2"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [p["name"] for p in out["parameters"]] == ["R1", "kw1"]
    assert out["seconds"] == pytest.approx(2.0)
    assert main(["plan", "--parameters", "nope"]) == 1
    assert "unknown parameters" in capsys.readouterr().err


def test_plan_from_an_iv_result_cites_seconds_and_volts():
    """The resolver for an inconclusive verdict, from the default method's result."""
    from maglevid.identify.physical import fit_physical
    from maglevid.identify.planning import plan_from_result

    d = simulate_amb_loop(FAULTY, nominal=NOMINAL, n_samples=3000, rng=4, **LINEAR)
    plan = plan_from_result(d, fit_physical(d), parameters=("R1", "kw1"), tolerance=0.01)
    text = plan.sentence()
    assert "needs" in text and "V rms" in text and "R1" in text


def test_force_disturbance_in_the_plan_predicts_the_bound_of_a_realistic_record():
    """The planner's default noise model is the realistic bearing's (sensor noise and a
    0.1 N force on the rotor). Checked against the bound computed directly on a
    record of the nonlinear simulator with that force (nominal bearing, so it
    settles at the nominal point the plan linearises at; force variance a
    nuisance, as in the ``ml`` fit). Sample averages over 1e4 samples plus the
    nonlinearity's second-order effect: 15 % accepted. Leaving the force out (the
    plan before) would promise too much on the coil parameters: measured 1.8x
    smaller std for R1 and kw1 (the force also excites the rotor, so not every
    v_i loses: v5 1.1x)."""
    d = simulate_amb_loop(NOMINAL, n_samples=10_000, excitation_std=1.0, rng=9)
    assert d.metadata["force_std"] == DEFAULT_FORCE_STD
    direct = cramer_rao_bound(d, estimate_noise=True, estimate_force=True).std()
    with_force = design_information(NOMINAL, spectra=())
    assert with_force.noise.force_std == DEFAULT_FORCE_STD
    planned = with_force.bound(n_samples=10_000, excitation_std=1.0).std()
    quiet = design_information(NOMINAL, noise=SENSOR_ONLY, spectra=())
    sensor_only = quiet.bound(n_samples=10_000, excitation_std=1.0).std()
    for k in ("v1", "v5", "v8", "R1", "kw1", "L1"):
        assert planned[k] == pytest.approx(direct[k], rel=0.15), k
    for k in ("R1", "kw1"):
        assert planned[k] > 1.5 * sensor_only[k], k


def test_a_candidate_spectrum_predicts_the_bound_of_a_record_with_that_spectrum(design):
    """The low-pass candidate's information against the bound computed directly on a
    linear-loop record excited by an independent draw of that spectrum (the
    simulator's own loop, :func:`simulate_linear_loop`): 12 % as above. On this
    bearing the low-pass excitation carries more information per volt than
    white noise (its power sits where the coils' and rotor's dynamics are)."""
    from maglevid.data import ClosedLoopData
    from maglevid.physics.amb import amb_state_space
    from maglevid.simulate.loop import simulate_linear_loop

    n, dt = 10_000, design.dt
    r = excitation_signal("lowpass:100", n, dt, rng=21)
    gen = np.random.default_rng(22)
    sig = simulate_linear_loop(
        amb_state_space(FAULTY, dt),
        default_amb_observer(NOMINAL, dt),
        default_amb_controller(NOMINAL, dt),
        r=r,
        noise=gen.standard_normal((n, 3)) * np.asarray(DEFAULT_NOISE_STD),
    )
    d = ClosedLoopData(y=sig.y, u=sig.u, r=r, dt=dt, metadata={"noise_std": DEFAULT_NOISE_STD})
    direct = cramer_rao_bound(d, v=FAULTY.v(), estimate_noise=True, m=FAULTY.m, i0=FAULTY.i0).std()
    planned = design.bound(n_samples=n, excitation_std=1.0, spectrum="lowpass:100").std()
    white = design.bound(n_samples=n, excitation_std=1.0).std()
    for k in ("v1", "v5", "v8", "R1", "kw1", "L1"):
        assert planned[k] == pytest.approx(direct[k], rel=0.12), k
        assert planned[k] < white[k], k
    # The same rms moves the rotor more at low frequency (the displacement limit).
    assert design.displacement_rms(1.0, "lowpass:100") > design.displacement_rms(1.0)


def test_the_plan_proposes_the_spectrum_that_needs_the_shortest_record(design):
    plan = plan_experiment(
        design, n_samples=2000, excitation_std=0.2, parameters=("R1", "kw1"), tolerance=0.01
    )
    assert plan.spectrum == "white"
    for row in plan.rows:
        per_spectrum = {}
        for sp in ("white", "lowpass:100"):
            a = design.max_excitation(4.0, 0.02, sp)
            var = design.bound(n_samples=1, excitation_std=a, spectrum=sp).std()[row.name] ** 2
            per_spectrum[sp] = var / row.target_std**2 * design.dt
        assert row.best_spectrum == min(per_spectrum, key=per_spectrum.get)
        assert row.seconds_best == pytest.approx(min(per_spectrum.values()), rel=1e-9)
    out = plan.to_dict()
    assert out["best_spectrum"] in ("white", "lowpass:100")
    if plan.best_spectrum != "white":
        assert "low-pass 100 Hz excitation" in plan.sentence()


def test_a_recordings_own_excitation_is_the_present_spectrum():
    d = simulate_amb_loop(FAULTY, nominal=NOMINAL, n_samples=4000, rng=2, **LINEAR)
    plan = plan_for_recording(d, parameters=("R1",), tolerance=0.02)
    assert plan.spectrum == "recorded"
    with pytest.raises(DataError, match="spectrum"):
        excitation_signal("pink", 10, 1e-4, rng=0)
    with pytest.raises(DataError, match="Nyquist"):
        excitation_signal("lowpass:6000", 10, 1e-4, rng=0)
