"""Faulty nonlinear bearings identified at the operating point they settle at (issue 12).

The realistic bearing: eq. (1) under the *nominal* bias voltages, so a fault
moves the equilibrium. The reference for every estimate is eq. (4) linearised
at that settled point (:func:`maglevid.physics.amb.settled_operating_point`,
recorded by the simulator in ``metadata["operating_point_true"]``), not
``plant.v()`` at the nominal point.

Tolerances: noise-free records are exact up to the nonlinearity of eq. (1)
under the 1 V excitation (the linear model is good to ~1 % in the signals,
``test_simulate_nonlinear.py``; the estimates of v1..v9 came out within
0.04 %), so 1 % is the issue's bar with a wide margin.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from maglevid.cli.main import main
from maglevid.identify.physical import fit_physical
from maglevid.physics.amb import AMBParameters
from maglevid.simulate.amb import simulate_amb_loop

NOM = AMBParameters.nominal()
# K2 -8 % is unstable at its settled point with the default design (both currents
# rise, and the negative stiffness with them): K2 -5 % is the largest tested.
FAULTS = [{"R1": 1.05}, {"R2": 1.05}, {"kw1": 0.8}, {"kw2": 0.95}, {"K1": 0.9}, {"K2": 0.95}, {}]


def _v(res):
    return np.array([res.parameters[f"v{i}"] for i in range(1, 10)])


def _se(res):
    se = res.std_errors()
    return np.array([se[f"v{i}"] for i in range(1, 10)])


@pytest.mark.parametrize("fault", FAULTS, ids=lambda f: ",".join(f) or "healthy")
@pytest.mark.parametrize("estimator", ["ls", "iv"])
def test_noise_free_faulty_bearing_is_identified_at_its_settled_point(fault, estimator):
    plant = NOM.with_fault(**fault)
    d = simulate_amb_loop(
        plant, nominal=NOM, n_samples=12_000, noise_std=(0, 0, 0), force_std=0.0, rng=5
    )
    v_true = np.asarray(d.metadata["operating_point_true"]["v"])
    res = fit_physical(d, estimator=estimator)
    np.testing.assert_allclose(_v(res), v_true, rtol=1e-2)
    # the physical parameters that the operating point does not move
    for name in ("R1", "R2", "kw1", "kw2"):
        assert res.parameters[name] == pytest.approx(getattr(plant, name), rel=1e-2), name


def test_cli_r2_fault_on_the_nonlinear_bearing(tmp_path, capsys):
    # Issue 12's case, exactly: on e62a9f8 this printed R2 = -17.07 ohm (truth 18.375):
    # the constant offsets of the settled point were read as dynamics. The command
    # now also applies the default 0.1 N force disturbance; 1 % still holds.
    out = tmp_path / "t.npz"
    args = ["simulate", "amb", "--fault", "R2=1.05", "--plant", "nonlinear", "--noise", "0,0,0"]
    assert main(["-q", *args, "--seed", "7", "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["-q", "--json", "identify", str(out)]) == 0
    res = json.loads(capsys.readouterr().out)
    p = res["parameters"]
    assert p["R2"] == pytest.approx(17.5 * 1.05, rel=1e-2)
    assert p["R1"] == pytest.approx(17.5, rel=1e-2)


def test_noisy_intervals_cover_the_settled_point():
    # One realistic record (default noise and force disturbance): every v_i within
    # 3.5 standard errors of the linearisation at the settled point (a 9-parameter
    # check at ~0.4 % false-failure rate per record if the intervals are right;
    # coverage itself is measured by the slow Monte Carlo below).
    d = simulate_amb_loop(NOM.with_fault(K2=0.95), nominal=NOM, n_samples=20_000, rng=21)
    v_true = np.asarray(d.metadata["operating_point_true"]["v"])
    res = fit_physical(d)
    z = (_v(res) - v_true) / _se(res)
    assert np.all(np.abs(z) < 3.5), z


@pytest.mark.slow
def test_coverage_of_the_95_percent_intervals_monte_carlo():
    # 24 realistic records (4 fault kinds x 6 seeds), 9 intervals each: 216 intervals.
    # Nominal 95 %: the binomial 99 % band for 216 Bernoulli(0.95) is [0.91, 0.98];
    # records share nothing, but the 9 v_i of one record are correlated, so the
    # band is a little wider in truth; we accept >= 0.90 (and report the number).
    hits = []
    for fault in ({"R1": 1.05}, {"kw2": 0.95}, {"K1": 0.9}, {}):
        for seed in range(6):
            d = simulate_amb_loop(
                NOM.with_fault(**fault), nominal=NOM, n_samples=20_000, rng=100 + seed
            )
            v_true = np.asarray(d.metadata["operating_point_true"]["v"])
            res = fit_physical(d)
            hits.append(np.abs(_v(res) - v_true) <= 1.96 * _se(res))
    cov = float(np.mean(hits))
    assert cov >= 0.90, cov


def test_dc_levels_give_settled_currents_and_static_coil_estimates():
    # kw2 -10 % and R1 +20 % with the nominal bias. The coil equation averaged over
    # the record gives R_j / kw_j = mean(u_j) / mean(I_j) exactly up to a flux
    # term / T, so the static R_j (nominal kw_j taken as known) is R_j kw_j,nom / kw_j.
    plant = NOM.with_fault(R1=1.2, kw2=0.9)
    d = simulate_amb_loop(plant, nominal=NOM, n_samples=20_000, rng=4)
    op = d.metadata["operating_point_true"]
    res = fit_physical(d)
    ev = res.extras["dc_levels"]
    for name, truth in [
        ("I1", op["I1"]), ("I2", op["I2"]), ("R1_static", plant.R1),
        ("R2_static", plant.R2 / plant.kw2), ("g1", plant.kw1 / plant.R1),
        ("u1", op["u"][0]), ("u2", op["u"][1]), ("U2", op["u"][1]),
    ]:  # fmt: skip
        lo, hi = ev[name]["ci95"]
        assert lo <= truth <= hi, (name, truth, ev[name])
        assert ev[name]["std_error"] < 1e-3 * abs(truth), name  # the DC levels are precise
    # kw_j = R_j g_j with the dynamic R_j: its interval carries R_j's
    lo, hi = ev["kw2_static"]["ci95"]
    assert lo <= plant.kw2 <= hi
    assert any(n.startswith("DC levels") for n in res.notes)
    # streamed: the same batches, the same evidence
    from maglevid.identify.streaming import fit_physical_streamed

    got = fit_physical_streamed(d, chunk_size=3_333).extras["dc_levels"]
    for name in ("I1", "R1_static", "g2"):
        assert got[name]["value"] == pytest.approx(ev[name]["value"], rel=1e-12)
        assert got[name]["std_error"] == pytest.approx(ev[name]["std_error"], rel=1e-9)
    # without the loop's operating point only the mean displacement is reported
    bare = fit_physical(
        d.replace(loop={k: v for k, v in d.loop.items() if k != "operating_point"})
    )
    assert set(bare.extras["dc_levels"]) == {"x"}
