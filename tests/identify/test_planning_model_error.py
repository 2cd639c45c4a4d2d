"""The linearisation's model error in experiment planning (issue 13).

On the nonlinear bearing ML's estimand is the best linear model at the
excitation; it departs from the settled point's tangent linearisation by a
bias ~ e^2 (``e`` the loop's largest relative excursion), while the standard
error falls as 1 / (a sqrt(N)), so a longer record must be taken at a lower
level (a^3 sqrt(N) fixed).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from maglevid.cli.main import main
from maglevid.diagnose.isolate import v_with_sensor_gains
from maglevid.identify.cramer_rao import NoiseModel
from maglevid.identify.ml import fit_ml
from maglevid.identify.planning import (
    MODEL_ERROR_GAIN,
    MODEL_ERROR_RATIO,
    design_information,
    model_error_bias,
    model_error_level,
    plan_experiment,
)
from maglevid.physics.amb import AMBParameters
from maglevid.simulate.amb import DEFAULT_NOISE_STD, simulate_amb_loop

NOMINAL = AMBParameters.nominal()
SENSOR_ONLY = NoiseModel(DEFAULT_NOISE_STD)
#: Limits wide enough that the model-error rule, not the amplifier, sets the level.
WIDE = {"max_excitation_std": 100.0, "max_displacement": 1.0}


@pytest.fixture(scope="module")
def design():
    return design_information(NOMINAL, noise=SENSOR_ONLY, spectra=())


#: 1e-3 of the CLI's sensor noise: ML's own scatter ~1e-6 of v_i, far below the law.
QUIET = tuple(1e-3 * s for s in DEFAULT_NOISE_STD)


def _ml_error(plant_model: str, level: float) -> np.ndarray:
    """Relative error of ML's v_i against the settled-point linearisation.

    One RK4 step per sample on the nonlinear plant (the bench's SUBSTEPS: the
    same record to ~3e-6 of the sensor noise, tested in tests/benchmarks)."""
    d = simulate_amb_loop(
        NOMINAL, n_samples=100_000, noise_std=QUIET, plant_model=plant_model, force_std=0.0,
        excitation_std=level, substeps=1, rng=20,
    )  # fmt: skip
    op = d.metadata.get("operating_point_true")
    v0 = np.asarray(op["v"] if op else d.metadata["truth_v"], float)
    fit = fit_ml(d, start=v0)
    v = np.array([fit.parameters[f"v{i}"] for i in range(1, 10)])
    return (v - v0) / np.abs(v0)


def test_the_law_has_the_size_of_the_nonlinear_records_error_and_vanishes_on_the_linear_one():
    # Reference: the measurement of benchmarks/measure_model_error.py (docs/
    # gosiewski.md): ML on a nonlinear record with 1e-3 of the sensor noise and
    # no force differs from the settled-point truth by ~1-2 e^2 of v_i (mean)
    # plus a record's own scatter of ~1.4 e^2 at N = 1e5 and 2 V (so a band of
    # 0.3-3x the law for the largest v_i error); on the linear plant the same
    # record has no model error and ML is within its sensor-noise scatter at
    # 1e-3 of the noise (~1e-6 relative), far below the law (1.3e-4).
    err_nl = _ml_error("nonlinear", 2.0)
    quiet = design_information(NOMINAL, noise=NoiseModel(QUIET), spectra=(), n_simulate=5000)
    e = quiet.excursion(2.0)
    law = MODEL_ERROR_GAIN * e * e
    assert 5e-3 < e < 1.2e-2  # 2 V moves the loop by ~0.8 % (the measurement's 0.81 %)
    assert 0.3 * law < np.max(np.abs(err_nl)) < 3 * law
    err_lin = _ml_error("linear", 2.0)
    assert np.max(np.abs(err_lin)) < 0.1 * law


def test_model_error_bias_is_second_order_in_the_excursion_and_propagates_to_physics(design):
    b1, b2 = model_error_bias(design, 1.0), model_error_bias(design, 2.0)
    e1, e2 = design.excursion(1.0), design.excursion(2.0)
    # v_i: exactly GAIN e^2 |v_i| (the law's definition).
    assert b1[:9] == pytest.approx(MODEL_ERROR_GAIN * e1**2 * np.abs(design.v), rel=1e-12)
    assert b2[:9] / b1[:9] == pytest.approx(np.full(9, (e2 / e1) ** 2), rel=1e-12)
    # Physical parameters: |J| |b_v| of eq. (4) inverted; positive and finite.
    assert np.all(np.isfinite(b1[9:])) and np.all(b1[9:] > 0)


def test_the_planners_level_falls_with_the_record_length_as_n_to_the_minus_sixth(design):
    # bias ~ a^2 and std ~ 1 / (a sqrt(N)): the level that holds bias / std fixed
    # goes as N^(-1/6) (a factor 10^(-1/6) = 0.68 a decade) while the noise's own
    # excursion and information are small next to the excitation's.
    names = ("v1", "v2", "v4", "v6", "R1", "kw1")
    levels = [model_error_level(design, n_samples=n, parameters=names, **WIDE)
              for n in (10**5, 10**6, 10**7)]  # fmt: skip
    ratios = np.array(levels[1:]) / np.array(levels[:-1])
    assert ratios == pytest.approx(np.full(2, 10 ** (-1 / 6)), rel=0.1)
    # At the level the worst parameter's bias is the stated fraction of its std.
    n, a = 10**6, levels[1]
    names_all = list(design.bound(n_samples=1, excitation_std=1.0).names)
    idx = [names_all.index(p) for p in names]
    std = np.sqrt(np.diag(design.bound(n_samples=n, excitation_std=a).covariance)[idx])
    worst = np.max(model_error_bias(design, a)[idx] / std)
    assert worst == pytest.approx(MODEL_ERROR_RATIO, rel=0.02)


def test_the_amplifier_limit_caps_the_model_error_level(design):
    assert model_error_level(design, n_samples=10**4, max_excitation_std=0.3) == pytest.approx(
        0.3, rel=1e-12
    )


def test_a_tolerance_request_gets_the_level_and_length_that_resolve_it_with_the_bias(design):
    plan = plan_experiment(design, n_samples=10**6, excitation_std=1.0,
                           parameters=("R1", "x0"), tolerance=0.002, **WIDE)  # fmt: skip
    for r in plan.rows:
        a, s = r.excitation_with_model_error, r.seconds_with_model_error
        assert a is not None and 0 < a < 100 and math.isfinite(s)
        i = list(design.bound(n_samples=1, excitation_std=1.0).names).index(r.name)
        n = s / design.dt
        std = math.sqrt(design.bound(n_samples=1, excitation_std=a).covariance[i, i] / n)
        assert std == pytest.approx(r.target_std, rel=1e-9)  # resolved at that length
        assert model_error_bias(design, a)[i] <= MODEL_ERROR_RATIO * r.target_std * 1.001
    # A tolerance so tight that the noise's own excursion biases beyond it: no
    # level and no length (the honest "no record" answer).
    tight = plan_experiment(design, n_samples=10**6, excitation_std=1.0,
                            parameters=("x0",), tolerance=1e-9, **WIDE)  # fmt: skip
    assert tight.rows[0].excitation_with_model_error is None
    assert tight.rows[0].to_dict()["seconds_with_model_error"] is None


def test_the_plan_says_when_the_present_excitation_is_too_strong_for_the_length(design):
    plan = plan_experiment(design, n_samples=10**7, excitation_std=2.0, parameters=("x0",), **WIDE)
    assert plan.rows[0].model_error > MODEL_ERROR_RATIO * plan.rows[0].std_now
    assert plan.excitation_model_error is not None and plan.excitation_model_error < 2.0
    assert f"excite at most {plan.excitation_model_error:.3g} V rms" in plan.sentence()
    short = plan_experiment(design, n_samples=1000, excitation_std=0.5, parameters=("x0",))
    assert "model error" not in short.sentence()


def test_plan_command_accepts_sensor_gain_faults(capsys):
    assert main(["--json", "plan", "--parameters", "R1,kw1", "--fault", "gx=1.1"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert "gxx1.1" in out["source"]
    assert out["parameters"][0]["model_error_bias"] > 0
    # The bearing planned is the one seen through the gains: its v2 is that of
    # isolate.v_with_sensor_gains (v2 x gx / gi1, the change of state scale).
    assert main(["--json", "plan", "--parameters", "v2", "--fault", "gx=1.1",
                 "--fault", "gi1=0.9"]) == 0  # fmt: skip
    v2 = json.loads(capsys.readouterr().out)["parameters"][0]["value"]
    assert v2 == pytest.approx(v_with_sensor_gains(NOMINAL, gx=1.1, gi1=0.9)[1], rel=1e-9)
    assert main(["plan", "--fault", "gq=1.1"]) == 1
    assert "unknown parameter 'gq'" in capsys.readouterr().err


def test_the_bench_points_take_the_planners_level_on_the_nonlinear_plant():
    from benchmarks.bench_ml_crb import point_excitation_std

    # The linear plant has no model error: 1 V as before. The nonlinear points
    # take the planner's level, within the bench's 1 V, falling with N.
    assert point_excitation_std("linear", "0.3x", 10**6) == 1.0
    levels = [point_excitation_std("nonlinear", "0.3x", n) for n in (10**5, 10**6)]
    assert 0 < levels[1] < levels[0] < 1.0
    assert levels[1] / levels[0] == pytest.approx(10 ** (-1 / 6), rel=0.1)


def test_plan_command_prints_the_model_error_and_the_level_for_a_long_record(capsys):
    # 100 s at 1 V on the realistic default bearing: x0's predicted bias is above
    # 0.1 std, so the table's note and the sentence name the lower level.
    assert main(["plan", "--parameters", "R1,kw1,x0", "--seconds", "100"]) == 0
    out = capsys.readouterr().out
    assert "model error of the linearisation: largest level with bias <= 0.1 std" in out
    assert "excite at most" in out and "for a record of 100 s" in out
