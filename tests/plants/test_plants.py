"""Plant kinds: what a recording is decides the method (maglevid.plants)."""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError
from maglevid.physics.amb import AMBParameters
from maglevid.plants import KINDS, choose_method, infer_kind, unidentifiable_reason
from maglevid.simulate.amb import simulate_amb_loop
from maglevid.simulate.suspension import simulate_suspension


def _record(ny, nu, **kw):
    return ClosedLoopData(y=np.zeros((60, ny)), u=np.zeros((60, nu)), dt=0.01, **kw)


def test_each_kind_is_recognised_from_the_recordings_shape():
    amb = simulate_amb_loop(AMBParameters.nominal(), n_samples=200, rng=1)
    assert infer_kind(amb)[0] == "amb-two-coil"
    assert choose_method(amb)[0] == "physical"
    sus = simulate_suspension(p=3, duration=1.0, rng=1)
    assert infer_kind(sus)[0] == "intersampled-suspension"
    # M and R stated: maximum likelihood; without them, Sun et al.'s method
    assert choose_method(sus)[0] == "intersample-ml"
    bare = ClosedLoopData(y=sus.y, u=sus.u, dt=sus.dt, p=sus.p)
    method, why = choose_method(bare)
    assert method == "intersample" and "no ball mass and coil resistance" in why
    assert infer_kind(_record(2, 1))[0] == "levitator"  # [gap, current], one coil
    assert infer_kind(_record(9, 2))[0] == "mimo"  # Maggy's shape


def test_a_one_input_levitator_never_gets_the_amb_method():
    method, why = choose_method(_record(2, 1))
    assert method == "levitator" and "plant kind levitator" in why
    assert choose_method(_record(1, 1))[0] == "pem"  # no current logged: no grey box
    assert all(k.default_method != "physical" for n, k in KINDS.items() if n != "amb-two-coil")


def test_a_stated_kind_takes_precedence_over_the_inference():
    d = _record(2, 1, loop={"plant_kind": "mimo"})
    assert infer_kind(d) == ("mimo", "the recording states plant_kind = 'mimo'")
    with pytest.raises(DataError, match="plant_kind 'rotor'"):
        infer_kind(_record(2, 1, metadata={"plant_kind": "rotor"}))


def test_noise_driven_exact_feedback_is_flagged_and_a_dither_is_not(rng):
    # u = -2 y1 + 0.5 y2 exactly: nothing but the outputs' noise drives the loop.
    y = rng.standard_normal((400, 2))
    exact = ClosedLoopData(y=y, u=(-2 * y[:, 0] + 0.5 * y[:, 1])[:, None], dt=0.01)
    assert "cannot be told from the controller's inverse" in unidentifiable_reason(exact)
    # a dither of 10 % of the command's rms makes R^2 ~ 0.99 < 0.9999: not flagged
    u = -2 * y[:, 0] + 0.5 * y[:, 1] + 0.2 * rng.standard_normal(400)
    assert unidentifiable_reason(ClosedLoopData(y=y, u=u[:, None], dt=0.01)) is None


def test_a_generic_mimo_record_is_refused_a_nominal_diagnosis_in_its_own_words():
    # Found from outside (twenty-seventh session): Maggy's log (9 fields, 2 inputs) given to
    # `diagnose` was told "baseline='nominal' needs the design parameters in the recording
    # (loop['nominal'])", the bearing's wording, with no such physics to give.
    from maglevid.diagnose.pipeline import diagnose

    rng = np.random.default_rng(0)
    d = ClosedLoopData(y=rng.standard_normal((400, 9)), u=rng.standard_normal((400, 2)), dt=0.01)
    assert infer_kind(d)[0] == "mimo"
    with pytest.raises(DataError, match="no nominal baseline") as err:
        diagnose(d)
    assert "no physical model of a generic multi-input multi-output plant" in str(err.value)
    assert "maglevid identify" in str(err.value) and "loop['nominal']" not in str(err.value)
