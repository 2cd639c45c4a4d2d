"""``maglevid identify --json`` on an inter-sampled record gives B_j with standard errors
(from either inter-sample method)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from maglevid.cli.main import main
from maglevid.identify.multirate import intersample_numerators
from maglevid.io import write_recording
from maglevid.lti import discretize
from maglevid.physics.suspension import SuspensionParameters, suspension_state_space
from maglevid.simulate.suspension import simulate_suspension


@pytest.mark.parametrize("method", ["intersample-ml", "intersample"])
def test_intersample_numerators_with_standard_errors(tmp_path, capsys, method):
    rec = simulate_suspension(p=3, duration=6.0, rng=5)  # linear plant of Sun et al., eq. (27)
    path = write_recording(rec, tmp_path / "s.npz")
    assert main(["identify", str(path), "--json", "--method", method]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["method"] == method
    num = out["intersample_numerators"]
    B, se = np.array(num["B"]), np.array(num["std_error"])
    assert num["j"] == [1, 2] and B.shape == se.shape == (2, 4)
    assert np.all(se > 0)
    # Truth: Theorem 2 of Sun et al. (identify.multirate) on the simulated plant;
    # every coefficient within 4 of its standard errors.
    plant = discretize(suspension_state_space(SuspensionParameters.nominal()), rec.dt / 3)
    _, B_true = intersample_numerators(plant, 3)
    assert np.all(np.abs(B - B_true[1:]) < 4 * se)
    # The text output lists them too.
    assert main(["identify", str(path), "--method", method]) == 0
    assert "B_1 (z^0..z^-3):" in capsys.readouterr().out
