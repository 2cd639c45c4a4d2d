"""The dither of a rig that did not log it, recovered from the controller law."""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.exceptions import DataError
from maglevid.experiments.rigs import simulate_pd_dither_levitator
from maglevid.identify.excitation import controller_state_space, recover_excitation
from maglevid.lti import StateSpace


@pytest.fixture(scope="module")
def log():
    return simulate_pd_dither_levitator(3000, rng=np.random.default_rng(5))


def test_recovered_dither_is_the_true_one(log):
    data, rep = recover_excitation(log)
    d = np.asarray(log.metadata["truth_dither"])
    r = data.r[:, 0]
    # The law u = (kc + R) (i0 + kp y + kd dy/dt + d) - kc i is exactly a PD on [y, i]
    # (na = 0, nb = 2), so the equation error is (kc + R) d plus the fitted gains' error
    # times the regressors. The white dither is uncorrelated with y_k, i_k (one sample
    # of plant delay), so the gains are unbiased with a relative error ~ 1/sqrt(N) of
    # the dither's share of u: a correlation above 0.99 and the scale within 2 %.
    kc_r = 30.0 + 2.72
    assert np.corrcoef(r[2:], d[2:])[0, 1] > 0.99
    assert np.std(r[2:]) == pytest.approx(kc_r * np.std(d[2:]), rel=0.02)
    assert rep["r_squared"] > 0.5 and data.loop["controller_inputs"][0] == "r:0"
    np.testing.assert_allclose(data.u_f[:, 0] + r, log.u[:, 0], rtol=1e-12)


def test_a_stated_law_is_used_as_it_is(log):
    law = {"a": [], "b": [[kc := 32.72 * 131.0 + 32.72 * 2.0 / 0.002, -32.72 * 2.0 / 0.002],
                          [-30.0, 0.0]], "intercept": 0.0}  # fmt: skip
    assert kc > 0
    data, rep = recover_excitation(log.replace(loop={"controller_law": law}))
    assert rep["source"].startswith("stated")
    # the true law (kc + R)(kp y + kd dy/dt) - kc i with noise-free gains: the equation
    # error is (kc + R) d plus the measurement noise through the law (y noise 10 um x kd/dt)
    assert np.corrcoef(data.r[2:, 0], np.asarray(log.metadata["truth_dither"])[2:])[0, 1] > 0.99


def test_controller_state_space_is_the_difference_equation(rng):
    a, b = np.array([-0.5, 0.1]), np.array([[1.0, 0.3, -0.2], [0.0, 2.0, 0.0]])
    K = controller_state_space(a, b, 0.01)
    assert isinstance(K, StateSpace) and K.nu == 2
    w = rng.standard_normal((200, 2))
    x = np.zeros(K.nx)
    u = np.empty(200)
    for t in range(200):
        u[t] = (K.C @ x + K.D @ w[t])[0]
        x = K.A @ x + K.B @ w[t]
    # u_k = 0.5 u_{k-1} - 0.1 u_{k-2} + b0 w_k + b1 w_{k-1} + b2 w_{k-2}  (exact algebra)
    k = np.arange(2, 200)
    rhs = -a[0] * u[k - 1] - a[1] * u[k - 2]
    rhs += sum(b[j, l] * w[k - l, j] for j in range(2) for l in range(3))
    np.testing.assert_allclose(u[k], rhs, rtol=1e-10, atol=1e-12)


def test_a_record_with_r_is_refused(log):
    data, _ = recover_excitation(log)
    with pytest.raises(DataError, match="already has an excitation"):
        recover_excitation(data)


def test_two_stage_and_indirect_run_from_the_command_line_without_r(log, tmp_path, capsys):
    import json

    from maglevid.cli.main import main
    from maglevid.io import write_recording

    path = tmp_path / "rig.npz"
    write_recording(log.replace(metadata={"source": "rig log"}), path)
    for method, opts in (("two-stage", ["input=y:1", "nb=3", "nk=0"]),
                         ("indirect", ["intermediate=y:1"])):  # fmt: skip
        args = ["--json", "identify", str(path), "--method", method]
        args += [a for o in opts for a in ("--option", o)]
        assert main(args) == 0
        res = json.loads(capsys.readouterr().out)
        assert res["notes"][0].startswith("no excitation r logged: recovered")
        assert res["plant_kind"] == "levitator" and res["method_reason"] == "chosen by the user"
