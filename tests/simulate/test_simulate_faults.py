"""Every fault ``maglevid simulate amb`` accepts changes the record, on both plants."""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.exceptions import DataError
from maglevid.physics.amb import AMBParameters
from maglevid.simulate.amb import SENSOR_GAINS, simulate_amb_loop

NOM = AMBParameters.nominal()
PARAMS = ("R1", "R2", "Ls1", "Ls2", "K1", "K2", "kw1", "kw2", "m", "x0", "i0")


def _sim(plant_model: str, fault: dict[str, float], n: int = 300, **kw):
    gains = {k: v for k, v in fault.items() if k in SENSOR_GAINS}
    phys = {k: v for k, v in fault.items() if k not in SENSOR_GAINS}
    return simulate_amb_loop(
        NOM.with_fault(**phys),
        nominal=NOM,
        n_samples=n,
        plant_model=plant_model,
        rng=3,
        sensor_gains=gains,
        **kw,
    )


@pytest.mark.parametrize("plant_model", ["linear", "nonlinear"])
@pytest.mark.parametrize("name", PARAMS + SENSOR_GAINS)
def test_every_fault_changes_the_record_or_is_refused(plant_model, name):
    # i0 is the one no-op on the nonlinear plant (bias from the nominal voltages): refused
    factor = 1.02 if name in ("x0", "i0") else 1.05
    if plant_model == "nonlinear" and name == "i0":
        with pytest.raises(DataError, match="no effect on the nonlinear plant"):
            _sim(plant_model, {name: factor})
        return
    healthy = _sim(plant_model, {})
    faulty = _sim(plant_model, {name: factor})
    assert not np.array_equal(healthy.y, faulty.y)
    assert np.max(np.abs(healthy.y - faulty.y)) > 1e-3 * np.max(np.abs(healthy.y))


@pytest.mark.parametrize("plant_model", ["linear", "nonlinear"])
@pytest.mark.parametrize("j, name", [(0, "gx"), (1, "gi1"), (2, "gi2")])
def test_sensor_gain_logs_gain_times_loop_signal(plant_model, j, name):
    # Noise-free: the controller acts on g s, so the true signal (y_j / g) differs from
    # the healthy record under the same excitation. gi2 = 1.1 and gi1 = 1.2 destabilise
    # the default loop (DesignError), hence the smaller current-sensor gain.
    g = 1.2 if name == "gx" else 1.05
    kw = {"noise_std": (0.0, 0.0, 0.0), "force_std": 0.0} if plant_model == "nonlinear" else {}
    kw.setdefault("noise_std", (0.0, 0.0, 0.0))
    healthy = _sim(plant_model, {}, **kw)
    faulty = _sim(plant_model, {name: g}, **kw)
    assert faulty.metadata["sensor_gains"][name] == g
    # same excitation, different loop response
    np.testing.assert_array_equal(healthy.r, faulty.r)
    assert not np.allclose(faulty.y[:, j] / g, healthy.y[:, j], rtol=1e-3, atol=0)


def test_sensor_gain_measured_is_gain_times_true_linear():
    """Analytic: the logged x is gx times the plant's x, driven by the logged inputs."""
    from maglevid.physics.amb import amb_state_space

    g = 1.2
    d = _sim("linear", {"gx": g}, noise_std=(0.0, 0.0, 0.0))
    true = amb_state_space(NOM, 1e-4)
    A, B, C = np.asarray(true.A), np.asarray(true.B), np.asarray(true.C)
    s, y_true = np.zeros(A.shape[0]), []
    for u in d.u:  # y(k) = C s(k), then u(k) held over the period
        y_true.append(C @ s)
        s = A @ s + B @ u
    y_true = np.array(y_true)
    scale = np.max(np.abs(y_true), axis=0)
    np.testing.assert_allclose(d.y[:, 0], g * y_true[:, 0], rtol=0, atol=1e-9 * scale[0])
    np.testing.assert_allclose(d.y[:, 1:], y_true[:, 1:], rtol=0, atol=1e-9 * scale[1:].max())


def test_unknown_sensor_gain_and_bad_value_are_refused():
    with pytest.raises(DataError, match="unknown sensor gains"):
        simulate_amb_loop(NOM, n_samples=10, plant_model="linear", rng=1, sensor_gains={"gy": 1})
    with pytest.raises(DataError, match="positive"):
        simulate_amb_loop(NOM, n_samples=10, plant_model="linear", rng=1, sensor_gains={"gx": 0})


def test_current_gain_with_coil_fault_is_refused_on_nonlinear():
    with pytest.raises(DataError, match="current-sensor fault gi1"):
        _sim("nonlinear", {"gi1": 1.1, "R1": 1.1}, n=10)
