"""``maglevid simulate amb``: the scenario contract and the command."""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.cli.main import build_parser, main
from maglevid.exceptions import DataError
from maglevid.physics.amb import AMBParameters
from maglevid.simulate import amb as scenario


def _args(*extra: str):
    return build_parser().parse_args(["-q", "simulate", "amb", "--out", "rec.npz", *extra])


def _need_io():
    # A plain import: a broken maglevid.io must fail these tests, not skip them.
    import maglevid.io as io

    return io


def test_scenario_contract():
    assert scenario.SCENARIO == "amb" and scenario.SCENARIO_HELP
    args = _args(
        "--fault", "R1=1.2", "--fault", "kw1=1.2", "--noise", "1e-7,1e-4,1e-4",
        "--excitation-std", "0.5", "--n-samples", "600", "--dt", "1e-4", "--seed", "3",
    )  # fmt: skip
    data = args._scenario(args)
    truth = AMBParameters.nominal().with_fault(R1=1.2, kw1=1.2)
    assert dict(data.metadata["truth"]) == pytest.approx(truth.to_dict(), rel=1e-15)
    assert data.metadata["seed"] == 3 and data.n_samples == 600
    np.testing.assert_allclose(data.metadata["noise_std"], [1e-7, 1e-4, 1e-4])
    np.testing.assert_array_equal(data.metadata["excitation"]["std"], [0.5, 0.5])
    # same seed, same call: same record
    again = args._scenario(args)
    np.testing.assert_array_equal(again.y, data.y)


def test_scenario_nonlinear_and_two_excitation_levels():
    args = _args("--plant", "nonlinear", "--n-samples", "300", "--seed", "1",
                 "--excitation-std", "0.5,0.2")  # fmt: skip
    data = args._scenario(args)
    assert data.metadata["plant_model"] == "nonlinear"
    np.testing.assert_array_equal(data.metadata["excitation"]["std"], [0.5, 0.2])


def test_bad_fault_is_a_data_error():
    args = _args("--fault", "R9=1.2", "--n-samples", "100")
    # The accepted names include the sensor gains, and a factor is judged as a factor
    # (the list left out gx, gi1, gi2 and R1=-1 read "got -17.5": found from outside,
    # issue 16, fourteenth session).
    with pytest.raises(
        DataError, match=r"R9=1.2: unknown name \(did you mean R[12]\?\).*gi1, gi2, gx"
    ):
        args._scenario(args)
    bad = _args("--fault", "R1=-1", "--n-samples", "100")
    with pytest.raises(DataError, match="R1=-1: the factor must be a positive number"):
        bad._scenario(bad)
    with pytest.raises(SystemExit):
        _args("--fault", "R1")  # no factor: argparse usage error


def test_bad_fault_is_one_clear_line(capsys):
    _need_io()
    code = main(["simulate", "amb", "--out", "x.npz", "--fault", "R9=1.2", "--n-samples", "100"])
    assert code == 1
    err = capsys.readouterr().err
    assert "--fault R9=1.2: unknown name" in err and "Traceback" not in err


def test_command_writes_a_readable_recording(tmp_path):
    io = _need_io()
    out = tmp_path / "rec.npz"
    code = main(["--json", "simulate", "amb", "--out", str(out), "--fault", "R1=1.2",
                 "--n-samples", "500", "--seed", "4"])  # fmt: skip
    assert code == 0 and out.exists()
    back = io.read_recording(out)
    assert back.n_samples == 500
    assert back.loop["observer"]["type"] == "deadbeat"


def test_i0_fault_on_the_nonlinear_plant_is_refused(capsys):
    # the nonlinear plant's bias follows from the nominal voltages: i0 would be a silent no-op
    code = main(["simulate", "amb", "--out", "x.npz", "--fault", "i0=1.2", "--n-samples", "100"])
    assert code != 0
    err = capsys.readouterr().err
    assert "no effect on the nonlinear plant" in err and "--plant linear" in err


def test_sensor_gain_fault_is_diagnosed_end_to_end(tmp_path, capsys):
    out = tmp_path / "gx.npz"
    code = main(["-q", "simulate", "amb", "--plant", "nonlinear", "--fault", "gx=1.2",
                 "--n-samples", "5000", "--seed", "1", "--out", str(out)])  # fmt: skip
    assert code == 0
    capsys.readouterr()
    assert main(["diagnose", str(out), "--baseline", "nominal"]) == 0
    verdict = capsys.readouterr().out.splitlines()[0]
    assert "only gx changed" in verdict and "displacement sensor reads high" in verdict
    change = float(verdict.split("displacement-sensor gain")[1].split("%")[0])
    assert change == pytest.approx(20.0, abs=1.5)  # +19.5 % +- 0.39 % at seed 1
