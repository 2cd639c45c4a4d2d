"""The inter-sampled suspension loop of Sun et al. (Figs. 1-3): linear and nonlinear plant."""

from __future__ import annotations

import argparse

import numpy as np
import pytest
from scipy import signal

from maglevid.control.pid import PAPER_PID, RETUNED_LEAD_LAG, RETUNED_PID
from maglevid.exceptions import DataError, DesignError
from maglevid.lti import discretize
from maglevid.physics.suspension import (
    SuspensionParameters,
    suspension_state_space,
    suspension_t_model,
)
from maglevid.simulate.suspension import (
    add_scenario_arguments,
    run_scenario,
    simulate_suspension,
)

NOMINAL = SuspensionParameters.nominal()


def _recursion(params, controller, W):
    """Independent reference: the loop run sample by sample at rate Delta (no lfilter)."""
    n, p = W.shape
    sd = discretize(suspension_state_space(params), controller.dt / p)
    d, c = controller.num, controller.den
    e = np.zeros(d.size)
    uh = np.zeros(c.size)
    x = np.zeros(3)
    y = np.empty((n, p))
    u = np.empty(n)
    for m in range(n):
        e = np.r_[-(sd.C @ x).item() - W[m, 0], e[:-1]]
        um = d @ e - c[1:] @ uh[:-1]
        uh = np.r_[um, uh[:-1]]
        u[m] = um
        for j in range(p):
            y[m, j] = (sd.C @ x).item() + W[m, j]
            x = sd.A @ x + sd.B[:, 0] * um
    return y, u


@pytest.mark.parametrize("controller", [RETUNED_LEAD_LAG, RETUNED_PID])
@pytest.mark.parametrize("p", [1, 3])
def test_linear_simulation_equals_the_sample_recursion(controller, p):
    rec = simulate_suspension(p=p, duration=0.6, controller=controller, warmup=0.0, rng=3)
    W = 1e-4 * np.random.default_rng(3).standard_normal((rec.n_samples, p))
    y, u = _recursion(NOMINAL, controller, W)
    # same loop, different arithmetic (lfilter of the closed-loop polynomials vs
    # the state recursion): rounding only, 1e-9 of the signal size
    np.testing.assert_allclose(rec.u[:, 0], u, rtol=0, atol=1e-9 * np.abs(u).max())
    np.testing.assert_allclose(rec.y[:, 0], y.ravel(), rtol=0, atol=1e-9 * np.abs(y).max())


def test_record_layout_loop_and_truth():
    rec = simulate_suspension(p=4, duration=1.2, rng=7)
    assert rec.p == 4 and rec.n_samples == 500 and rec.y.shape == (2000, 1)
    assert rec.u.shape == (500, 1) and np.array_equal(rec.u, rec.u_f)
    ctl = rec.loop["controller"]
    assert ctl["type"] == "lead-lag" and list(ctl["den"]) == list(RETUNED_LEAD_LAG.den)
    assert rec.loop["T"] == pytest.approx(2.4e-3) and rec.loop["reference"] == 0.0
    assert rec.loop["operating_point"]["Y"] == pytest.approx(6e-3)
    assert rec.loop["physical"]["M"] == pytest.approx(0.54)
    truth = rec.metadata["truth"]
    a, b = suspension_t_model(NOMINAL)
    np.testing.assert_allclose(truth["a"], a[1:], rtol=1e-12)
    np.testing.assert_allclose(truth["b"], b[1:], rtol=1e-10)
    assert np.asarray(truth["B"]).shape == (4, 4)
    assert max(truth["closed_loop_pole_moduli"]) < 1
    assert rec.metadata["seed"] == 7 and rec.metadata["plant"] == "linear"


def test_same_seed_same_record_other_seed_other_record():
    a = simulate_suspension(p=2, duration=0.5, rng=11)
    b = simulate_suspension(p=2, duration=0.5, rng=11)
    c = simulate_suspension(p=2, duration=0.5, rng=12)
    assert np.array_equal(a.y, b.y) and np.array_equal(a.u, b.u)
    assert not np.array_equal(a.y, c.y)


def test_noise_is_white_with_the_stated_std_on_every_intersample():
    # w_j = y_j - (B_j/A) u; short record from rest, so the open-loop filter is exact
    # enough (1.106^300 * 1e-16 ~ 1e-3 of 1e-4 m would be too much: use 250 samples).
    p, n = 3, 250
    rec = simulate_suspension(p=p, duration=n * 2.4e-3, warmup=0.0, noise_std=2e-4, rng=5)
    truth = rec.metadata["truth"]
    a = np.r_[1.0, truth["a"]]
    w = np.column_stack(
        [
            rec.y_intersample(j)[:, 0] - signal.lfilter(truth["B"][j], a, rec.u[:, 0])
            for j in range(p)
        ]
    )
    # sample std of 750 N(0, 2e-4^2) values: within 4 standard errors (2.6 %) of 2e-4
    assert abs(w.std() / 2e-4 - 1) < 4 / np.sqrt(2 * w.size)
    corr = np.corrcoef(w.T)
    assert np.max(np.abs(corr - np.eye(p))) < 4 / np.sqrt(n)


def test_nonlinear_plant_agrees_with_the_linear_one_for_small_signals():
    # 1 um of noise: the nonlinearity (relative size ~ amplitude / gap ~ 1e-4) and the
    # RK4 error (h = 0.2 ms, |h lambda| < 0.01) are both far below 1e-2 of the signal.
    kw = dict(p=2, duration=0.5, noise_std=1e-6, rng=2)
    lin = simulate_suspension(**kw)
    non = simulate_suspension(plant="nonlinear", **kw)
    scale = np.abs(lin.y).max()
    np.testing.assert_allclose(non.y, lin.y, rtol=0, atol=1e-2 * scale)
    assert non.metadata["plant"] == "nonlinear"


def test_nonlinear_plant_at_the_papers_noise_stays_near_the_linear_one():
    kw = dict(p=3, duration=1.0, rng=4)
    lin = simulate_suspension(**kw)
    non = simulate_suspension(plant="nonlinear", **kw)
    # documented (docs/sun.md): ~5 % RMS distortion of the noise-free part at 0.1 mm
    clean = np.sqrt(max(lin.y.var() - 1e-8, 0.0))
    assert (non.y - lin.y).std() < 0.15 * clean


def test_printed_pid_is_refused():
    with pytest.raises(DesignError, match="does not stabilise"):
        simulate_suspension(controller=PAPER_PID, duration=0.1)


@pytest.mark.parametrize(
    "kw,match",
    [
        ({"p": 0}, "`p`"),
        ({"plant": "quantum"}, "`plant`"),
        ({"controller": "bang-bang"}, "`controller`"),
        ({"noise_std": -1.0}, "`noise_std`"),
        ({"duration": 0.001}, "`duration`"),
        ({"substeps": 0}, "`substeps`"),
        ({"force_std": -0.1, "plant": "nonlinear"}, "`force_std`"),
        ({"force_std": 0.1}, "plant='nonlinear'"),  # the paper's linear loop: noise alone
    ],
)
def test_bad_options_are_clear_errors(kw, match):
    with pytest.raises(DataError, match=match):
        simulate_suspension(**{"duration": 0.1, **kw})


def test_scenario_contract():
    parser = argparse.ArgumentParser()
    add_scenario_arguments(parser)
    args = parser.parse_args(["--p", "2", "--duration", "0.2", "--seed", "9", "--Y-mm", "4"])
    rec = run_scenario(args)
    assert rec.p == 2 and rec.loop["operating_point"]["Y"] == pytest.approx(4e-3)
    again = simulate_suspension(p=2, duration=0.2, params=NOMINAL.at(4e-3), rng=9, noise_std=1e-4)
    assert np.array_equal(rec.y, again.y)


def test_cli_writes_a_readable_multirate_recording(tmp_path):
    from maglevid.cli.main import main
    from maglevid.io import read_recording

    out = tmp_path / "rec.npz"
    code = main(["simulate", "suspension", "--p", "3", "--duration", "0.3", "--out", str(out)])
    assert code == 0
    rec = read_recording(out)
    assert rec.p == 3 and rec.y.shape[0] == 3 * rec.n_samples
    assert rec.loop["controller"]["type"] == "lead-lag"
    assert "truth" in rec.metadata


def test_a_force_on_the_ball_moves_it_and_is_recorded(tmp_path):
    """The force draws come after the sensor noise: without one the record is the same
    as before the option existed; with one the ball moves more (eq. (25): F/M on the
    acceleration)."""
    from maglevid.cli.main import main
    from maglevid.io import read_recording

    kw = {"p": 3, "duration": 2.0, "plant": "nonlinear", "noise_std": 1e-5, "rng": 4}
    calm = simulate_suspension(**kw)
    same = simulate_suspension(**kw, force_std=0.0)
    pushed = simulate_suspension(**kw, force_std=0.2)
    assert np.array_equal(calm.y, same.y)
    assert np.std(pushed.y) > 2.0 * np.std(calm.y)
    assert pushed.metadata["force_std"] == 0.2 and calm.metadata["force_std"] == 0.0
    out = tmp_path / "f.npz"
    argv = ["simulate", "suspension", "--plant", "nonlinear", "--force-std", "0.05"]
    assert main([*argv, "--duration", "0.3", "--out", str(out)]) == 0
    assert read_recording(out).metadata["force_std"] == pytest.approx(0.05)
