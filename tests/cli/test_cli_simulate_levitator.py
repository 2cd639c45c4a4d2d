"""``maglevid simulate levitator``: the UAQ twin with faults, written as a rig's log.

Reference: the twin's own physics (``simulate.levitator.UAQ_TWIN``, eqs. (L1), (LIN1))
with the injected factor; the diagnosis must name the injected cause and its size.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from maglevid.cli.main import build_parser, main
from maglevid.diagnose.pipeline import diagnose
from maglevid.exceptions import DataError
from maglevid.io import read_recording
from maglevid.simulate import levitator as scenario


def _args(*extra: str):
    return build_parser().parse_args(["-q", "simulate", "levitator", "--out", "x.npz", *extra])


def test_scenario_contract_and_the_faults_it_injects():
    assert scenario.SCENARIO == "levitator" and scenario.SCENARIO_HELP
    args = _args("--fault", "R=1.3", "--gap-offset", "0.5", "--gaps", "5", "4.5",
                 "--seconds-per-gap", "3", "--seed", "4")  # fmt: skip
    data = args._scenario(args)
    truth = data.metadata["truth"]
    assert truth["R"] == pytest.approx(1.3 * scenario.UAQ_TWIN.R, rel=1e-15)
    assert truth["gap_offset_m"] == pytest.approx(5e-4) and truth["ku"] == scenario.UAQ_TWIN.ku
    # the recording states the healthy twin's physics with its driver
    assert (
        data.metadata["plant"]["R_ohm"] == scenario.UAQ_TWIN.R and "ku" in data.metadata["plant"]
    )
    # the gap reference is an extra channel in metres (r would be an excitation in V)
    assert data.r is None and data.n_samples == 600
    yd = np.asarray(data.metadata["extra_signals"]["yd"]["values"])
    np.testing.assert_allclose(yd, np.r_[np.full(300, 5e-3), np.full(300, 4.5e-3)], rtol=1e-12)
    # the reading is the true gap less the offset: the ball levitates 0.5 mm further out
    assert np.mean(data.y[200:300, 0]) == pytest.approx(5e-3, abs=1e-4)
    np.testing.assert_array_equal(args._scenario(args).y, data.y)  # same seed, same record


@pytest.mark.parametrize(
    ("fault", "message"),
    [("Rx=1.2", "unknown name (did you mean R?)"), ("R=-1", "positive number"),
     ("g=1.1", "unknown name")],
)  # fmt: skip
def test_bad_faults_say_what_is_wrong(fault, message):
    args = _args("--fault", fault)
    with pytest.raises(DataError, match=re.escape(message)):
        args._scenario(args)


def test_written_twin_is_diagnosed_with_the_injected_cause(tmp_path):
    out = tmp_path / "twin.npz"
    code = main(["-q", "simulate", "levitator", "--fault", "R=1.3", "--seed", "3",
                 "--out", str(out)])  # fmt: skip
    assert code == 0
    # one command-frame grey box (the default consensus is ~100 s): R +30 % named
    d = diagnose(read_recording(out), method="greybox-levitator",
                 method_options={"model": "electromechanical"})  # fmt: skip
    assert d.verdict_code == "fault" and d.isolation.best.parameters == ("R",)
    value, se = d.isolation.best.values[0], d.isolation.best.std_errors[0]
    assert abs(value - 1.3) < 2.5 * se, d.verdict
    # the written file is not touched by reading it, and refuses to be overwritten
    before = out.read_bytes()
    assert main(["-q", "simulate", "levitator", "--seed", "3", "--out", str(out)]) != 0
    assert out.read_bytes() == before


def test_simulate_levitator_json(tmp_path, capsys):
    out = tmp_path / "h.npz"
    main(["--json", "simulate", "levitator", "--seconds-per-gap", "2", "--seed", "1",
          "--out", str(out)])  # fmt: skip
    got = json.loads(capsys.readouterr().out)
    assert got["n_samples"] == 400 and got["written"] == str(out)
