"""The levitator grey box's command delay, gap-sensor gain and second start (issue 14).

References: the delayed ZOH sampling against the exact continuous response of the
delayed pulse (matrix exponential, independent of the sampling code); the fits on
:func:`simulate_pd_dither_levitator` (published UAQ physics under a PD loop with an
unlogged dither; truth ``sqrt(2 g/(a + y0))`` at the mean gap).
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla

from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError
from maglevid.experiments.rigs import simulate_pd_dither_levitator
from maglevid.identify.greybox import fit_greybox_levitator, sample_zoh_delayed


@pytest.mark.parametrize("frac", [0.0, 0.3, 1.0, 1.4, 2.0])
def test_delayed_sampling_is_the_exact_delayed_pulse_response(frac):
    A = np.array([[0.0, 1.0], [2000.0, 0.0]])  # the levitator's unstable mechanics
    B = np.array([[0.0], [1.0]])
    C = np.array([[1.0, 0.0]])
    dt = 0.01
    Phi, G, Cd, _ = sample_zoh_delayed(A, B, C, dt, frac * dt)
    x, got = np.zeros(Phi.shape[0]), []
    for k in range(6):  # a unit pulse u_0 = 1 held over one period
        got.append(float((Cd @ x)[0]))
        x = Phi @ x + G[:, 0] * (k == 0)

    def step(t, t0):  # continuous response at t to a unit step starting at t0
        if t <= t0:
            return 0.0
        M = np.zeros((3, 3))
        M[:2, :2], M[:2, 2:] = A * (t - t0), B * (t - t0)
        return float((C @ sla.expm(M)[:2, 2])[0])

    want = [step(k * dt, frac * dt) - step(k * dt, (frac + 1) * dt) for k in range(6)]
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-15)


@pytest.fixture(scope="module")
def log():
    return simulate_pd_dither_levitator(3000, rng=np.random.default_rng(5))


def _delayed(log, n):
    """The same log with the command written ``n`` samples early (logged ``u'_k =
    u_{k+n}``): the plant sees the logged command ``n dt`` late."""
    return ClosedLoopData(
        y=log.y[:-n], u=log.u[n:], dt=log.dt, names=log.names, units=log.units,
        metadata=log.metadata,
    )  # fmt: skip


def test_a_one_sample_command_delay_is_estimated(log):
    d = _delayed(log, 1)
    segs = [(200, d.n_samples)]
    res = fit_greybox_levitator(
        d, model="electromechanical", command_delay=True, segments=segs, k_step=5
    )
    dl, se = res.parameters["delay"], res.std_errors()["delay"]
    # the simulated plant sees u_k one sample late (ZOH, no other delay)
    assert abs(dl - log.dt) < max(3 * se, 0.1 * log.dt)
    truth = log.metadata["truth_pole_rad_s"]  # measured: 39.4 +- 1.9 for 43.86
    assert abs(res.parameters["pole_rad_s"] - truth) < 3 * res.std_errors()["pole_rad_s"]
    plain = fit_greybox_levitator(d, model="electromechanical", segments=segs, k_step=5)
    assert res.fit["one_step_fit_percent_gap"] > plain.fit["one_step_fit_percent_gap"]


def test_sensor_gain_option_and_its_checks(log):
    segs = [(200, 3000)]
    res = fit_greybox_levitator(
        log, model="electromechanical", sensor_gain=True, segments=segs, k_step=5
    )
    gs, se = res.parameters["gs"], res.std_errors()["gs"]
    # true gain 1; whether the record separates it is in its standard error
    assert abs(gs - 1.0) < 3 * se + 0.05 or not res.extras["pole_identified"]
    with pytest.raises(DataError, match="electromechanical model only"):
        fit_greybox_levitator(log, command_delay=True, segments=segs)
    with pytest.raises(DataError, match="electromechanical model only"):
        fit_greybox_levitator(log, sensor_gain=True, segments=segs)
