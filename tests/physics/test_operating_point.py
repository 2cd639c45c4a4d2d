"""The operating point a (faulty) bearing settles at under its loop (eq. (1) at rest)."""

from __future__ import annotations

from dataclasses import asdict

import numpy as np
import pytest

from maglevid.exceptions import DataError, ModelError
from maglevid.physics.amb import (
    AMBParameters,
    amb_matrices,
    bias_voltages,
    linearized_v,
    settled_operating_point,
)
from maglevid.simulate.amb import (
    DEFAULT_DT,
    _simulate_nonlinear,
    default_amb_controller,
    default_amb_observer,
)

NOM = AMBParameters.nominal()
OBS, CTRL = default_amb_observer(NOM, DEFAULT_DT), default_amb_controller(NOM, DEFAULT_DT)
LOOP = {"controller": CTRL.to_dict(), "observer": OBS.to_dict()}
FAULTS = [{"R1": 1.05}, {"R2": 1.05}, {"kw1": 0.8}, {"kw2": 0.95}, {"K1": 0.9}, {"K2": 0.92}]


def test_nominal_bearing_settles_at_the_nominal_point():
    op = settled_operating_point(NOM, NOM, LOOP)
    assert op.x == pytest.approx(0, abs=1e-15)
    assert op.I1 == pytest.approx(NOM.i0, rel=1e-12) and op.I2 == pytest.approx(NOM.i0, rel=1e-12)
    np.testing.assert_allclose(op.u_f, 0, atol=1e-12)
    np.testing.assert_allclose(op.u, bias_voltages(NOM), rtol=1e-12)
    np.testing.assert_allclose(op.v, NOM.v(), rtol=1e-10)  # eq. (4) at x = 0, i = i0
    Ac, Bc = amb_matrices(NOM)
    np.testing.assert_allclose(op.A_c, Ac, rtol=1e-10)
    np.testing.assert_allclose(op.B_c, Bc, rtol=1e-10)


@pytest.mark.parametrize("fault", FAULTS, ids=lambda f: next(iter(f)))
def test_settled_point_satisfies_eq1_at_rest(fault):
    plant = NOM.with_fault(**fault)
    op = settled_operating_point(plant, NOM, LOOP)
    # integral action on x: the rotor is centred
    assert abs(op.x) < 1e-12 * NOM.x0
    # force balance of eq. (1) at x = 0: K1 I1^2 = K2 I2^2 (unequal K -> unequal currents)
    assert plant.K1 * op.I1**2 == pytest.approx(plant.K2 * op.I2**2, rel=1e-10)
    # each coil at rest: kw_j (u_bias_j + u_fj) = R_j I_j, with the nominal bias
    np.testing.assert_allclose(
        [plant.kw1 * op.u[0], plant.kw2 * op.u[1]], [op.U1, op.U2], rtol=1e-10
    )
    np.testing.assert_allclose([op.U1, op.U2], [plant.R1 * op.I1, plant.R2 * op.I2], rtol=1e-12)
    np.testing.assert_allclose(op.u_bias, bias_voltages(NOM), rtol=0)
    np.testing.assert_allclose(op.y, [op.x, op.I1 - NOM.i0, op.I2 - NOM.i0], rtol=1e-12)
    np.testing.assert_allclose(op.v, linearized_v(plant, x=op.x, I1=op.I1, I2=op.I2), rtol=1e-14)
    # the fault moved the operating point, so eq. (4) at i0 (plant.v()) is not the
    # truth: ki1/m differs by 0.06 % (R2 +5 %, kw2 -5 %) to 3.5 % (K1 -10 %)
    assert abs(op.v[1] / plant.v()[1] - 1) > 5e-4


def test_weaker_coil_2_takes_more_current_than_coil_1():
    op = settled_operating_point(NOM.with_fault(K2=0.92), NOM, LOOP)
    # force balance: I2 / I1 = sqrt(K1 / K2) = 1 / sqrt(0.92)
    assert op.I2 / op.I1 == pytest.approx(1 / np.sqrt(0.92), rel=1e-10)
    # ki_j = K_j I_j / (2 x0^2) then changes for both coils (v2 and v3 both move)
    dv = op.v / NOM.v() - 1
    assert abs(dv[1]) > 1e-3 and abs(dv[2]) > 1e-3


def test_resistance_fault_with_nominal_bias_lowers_its_current():
    # R1 +5 % under the nominal bias: coil 1's current drops unless the loop
    # compensates entirely; at x = 0, K1 = K2, the force balance keeps I1 = I2.
    op = settled_operating_point(NOM.with_fault(R1=1.05), NOM, LOOP)
    assert op.I1 == pytest.approx(op.I2, rel=1e-10)
    assert op.I1 < NOM.i0


def test_nonlinear_simulator_converges_to_the_settled_point():
    # Start the faulty bearing at the *nominal* rest point (rotor centred, i = i0,
    # the nominal loop state) without excitation or noise: it must settle at the
    # computed point. The slowest closed-loop pole of this faulty loop is near
    # -15 rad/s (observed decay of the error: 4e-4 at 0.6 s, 1e-6 at 1 s, 5e-10 at
    # 1.5 s, round-off 2e-13 from 2 s on); after 1.6 s it is below 1e-9 relative.
    plant = NOM.with_fault(R2=1.05, K1=0.95)
    start = asdict(settled_operating_point(NOM, NOM, LOOP))
    op = settled_operating_point(plant, NOM, LOOP)
    n = 16000
    y, uf = _simulate_nonlinear(
        plant, NOM, OBS, CTRL, dt=DEFAULT_DT, r=np.zeros((n, 2)), v=np.zeros((n, 3)),
        substeps=2, eq=start, progress=None,
    )  # fmt: skip
    moved = np.abs(op.y - start["y"])
    assert np.all(moved[1:] > 1e-3)  # the start is far from the end
    np.testing.assert_allclose(y[-1], op.y, rtol=0, atol=1e-9 * np.abs(op.y).max())
    np.testing.assert_allclose(uf[-1], op.u_f, rtol=0, atol=1e-9 * np.abs(op.u_f).max())


def test_static_force_and_open_loop():
    # No loop: currents under the bias alone (i = i0), x from the force balance
    # (K1 (i0/(x0-x))^2 = K2 (i0/(x0+x))^2 -> x = x0 (s - 1)/(s + 1), s = sqrt(K2/K1)).
    op = settled_operating_point(NOM.with_fault(K2=0.92), NOM)
    s = np.sqrt(0.92)
    assert op.x == pytest.approx(NOM.x0 * (s - 1) / (s + 1), rel=1e-10)
    assert op.I1 == pytest.approx(NOM.i0, rel=1e-12)
    # a static load towards coil 2 under the loop: coil 1 carries it, x stays 0
    load = 5.0  # N
    opf = settled_operating_point(NOM, NOM, LOOP, force=-load)
    assert abs(opf.x) < 1e-12 * NOM.x0
    f = NOM.K1 / 4 * (opf.I1 / NOM.x0) ** 2 - NOM.K2 / 4 * (opf.I2 / NOM.x0) ** 2
    assert f == pytest.approx(load, rel=1e-9)


def test_bad_loop_and_unreachable_fault():
    with pytest.raises(DataError, match="controller"):
        settled_operating_point(NOM, NOM, {"controller": {}})
    with pytest.raises(ModelError, match="no rest point"):
        # 1 kN towards coil 2 (the rotor weighs 18 N): the loop's rest point
        # would need a negative current
        settled_operating_point(NOM, NOM, LOOP, force=-1e3)


def test_simulator_refuses_a_bearing_unstable_at_its_settled_point():
    # K2 -8 %: the default controller raises both currents (I2/I1 = sqrt(K1/K2)),
    # the negative stiffness grows and the loop around the settled point has a
    # pole at |z| = 1.0007; the simulation would run into the pole face.
    from maglevid.exceptions import DesignError
    from maglevid.simulate.amb import simulate_amb_loop

    with pytest.raises(DesignError, match="settles at"):
        simulate_amb_loop(NOM.with_fault(K2=0.92), nominal=NOM, n_samples=100, rng=1)


def test_a_recordings_loop_predicts_its_settled_point():
    # What the diagnosis uses: the hypothesis' parameters + the logged loop (its
    # controller, observer and bias inputs) give the point the recording settled at.
    from maglevid.simulate.amb import simulate_amb_loop

    plant = NOM.with_fault(R1=1.1, K2=0.97)
    d = simulate_amb_loop(plant, nominal=NOM, n_samples=200, rng=2)
    op = settled_operating_point(plant, NOM, d.loop)
    truth = d.metadata["operating_point_true"]
    np.testing.assert_allclose(op.v, truth["v"], rtol=1e-12)
    np.testing.assert_allclose(op.u_bias, d.loop["operating_point"]["u_bias"], rtol=0)
    assert op.to_dict()["I1"] == pytest.approx(truth["I1"], rel=1e-12)
