"""`maglevid diagnose --option KEY=VALUE`: typed by the identification method the diagnosis
uses, exactly as `identify --option` (issue 14: `diagnose` on rig logs that need a
method option), with one clear error for a bad key or value."""

from __future__ import annotations

import numpy as np
import pytest

import maglevid.diagnose.pipeline as pipeline
from maglevid.cli.main import main
from maglevid.experiments.rigs import simulate_pd_dither_levitator
from maglevid.io import write_recording


@pytest.fixture(scope="module")
def rig_log(tmp_path_factory):
    # a one-coil levitator log (PD loop, dither, no r): diagnose chooses `levitator`
    log = simulate_pd_dither_levitator(600, rng=np.random.default_rng(3))
    return write_recording(log, tmp_path_factory.mktemp("rig") / "rig.npz")


@pytest.fixture
def captured(monkeypatch):
    """The pipeline's diagnose replaced by a recorder of its keyword arguments (the
    fit itself is tested elsewhere; here: what the command line passes on)."""
    seen: dict = {}

    class _Done:
        def to_dict(self):
            return {"verdict": "recorded"}

        def summary(self):
            return "recorded"

        verdict_code = "no_change"

    def fake(recording, **kwargs):
        seen.update(kwargs)
        return _Done()

    monkeypatch.setattr(pipeline, "diagnose", fake)
    return seen


def test_options_are_typed_by_the_chosen_method(rig_log, captured):
    args = ["diagnose", str(rig_log), "--option", "k_step=3", "--option", "disturbance=ar1"]
    assert main(["-q", *args]) == 0
    # `levitator` declares k_step an int and disturbance a list of texts
    assert captured["method_options"] == {"k_step": 3, "disturbance": ["ar1"]}


def test_no_option_passes_none(rig_log, captured):
    assert main(["-q", "diagnose", str(rig_log)]) == 0
    assert captured["method_options"] is None


@pytest.mark.parametrize(
    ("item", "words"),
    [
        ("bogus=1", "bogus"),  # unknown key: named, with the method
        ("k_step", "expected KEY=VALUE"),  # no '='
        ("disturbance=pink", "pink"),  # a value outside the declared choices
    ],
)
def test_a_bad_option_is_one_clear_error(rig_log, captured, capsys, item, words):
    assert main(["-q", "diagnose", str(rig_log), "--option", item]) == 1
    err = capsys.readouterr().err
    assert "Traceback" not in err and words in err
    assert not captured  # refused before any diagnosis


def test_the_stated_method_types_the_options(rig_log, captured):
    args = ["diagnose", str(rig_log), "--method", "greybox-levitator"]
    assert main(["-q", *args, "--option", "disturbance=ar1"]) == 0
    assert captured["method_options"] == {"disturbance": "ar1"}  # one text for the grey box


@pytest.mark.parametrize(
    ("given", "words"),
    [("nothere.json", "no such file"), ("nomnal", "is neither 'nominal' nor 'history'"),
     (".", "is a folder")],
)  # fmt: skip
def test_a_bad_baseline_says_what_is_wrong_with_it(tmp_path, capsys, given, words):
    # --baseline nothere.json said only "expected 'nominal', 'history' or a JSON file",
    # as if the option were misused (found from outside, seventeenth session).
    rec = tmp_path / "r.npz"
    rec.write_bytes(b"")  # never read: the baseline is checked first
    assert main(["-q", "diagnose", str(rec), "--baseline", given]) == 1
    err = capsys.readouterr().err
    assert words in err and "expected 'nominal', 'history' or a JSON file" in err
