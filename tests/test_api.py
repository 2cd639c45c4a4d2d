"""The plain-function API of issue 18: real signatures, notebook views, frames, round trips."""

from __future__ import annotations

import inspect
import json

import numpy as np
import pytest

import maglevid
from maglevid.identify.result import IdentificationResult
from maglevid.physics.amb import AMBParameters

NOMINAL = AMBParameters.nominal()


@pytest.fixture(scope="module")
def faulty(amb_r1_fault):
    return amb_r1_fault  # tests/conftest.py: R1 +20 %, the README's bearing


@pytest.fixture(scope="module")
def diagnosis(faulty):
    return maglevid.diagnose(faulty, baseline="nominal")


def test_identify_and_diagnose_are_functions_with_real_signatures():
    for fn in (maglevid.identify, maglevid.diagnose):
        assert inspect.isfunction(fn)
        params = inspect.signature(fn).parameters
        assert not any(p.kind is p.VAR_POSITIONAL for p in params.values())
        assert "Parameters\n" in fn.__doc__ and "Returns\n" in fn.__doc__
    sig = inspect.signature(maglevid.diagnose)
    assert sig.parameters["baseline"].kind is inspect.Parameter.KEYWORD_ONLY
    assert list(inspect.signature(maglevid.identify).parameters)[:2] == ["data", "method"]


def test_the_subpackages_stay_importable():
    from maglevid.diagnose.history import open_history
    from maglevid.diagnose.pipeline import diagnose
    from maglevid.identify.arx import fit_arx

    assert callable(open_history) and callable(fit_arx)
    assert diagnose is maglevid.diagnose


def test_identify_chooses_the_plant_kinds_method_and_takes_options(faulty):
    # identify keeps the plant kind's default (`physical`, as `maglevid identify` does);
    # only a diagnosis uses `ml` by default (issue 13), at about 10x the time.
    r = maglevid.identify(faulty)
    assert r.method == "physical"
    # R1 is identified within 4 standard errors of the simulated 1.2 * 17.5 ohm.
    assert abs(r.parameters["R1"] - 1.2 * NOMINAL.R1) < 4 * r.std_errors()["R1"]
    r2 = maglevid.identify(faulty, "deadbeat-arx")
    assert r2.method == "deadbeat-arx"
    with pytest.raises(maglevid.DataError, match="unknown method"):
        maglevid.identify(faulty, "no-such-method")


def test_identify_by_pbsid_gives_a_bearings_physical_parameters(faulty):
    # As `maglevid identify --method pbsid` (twenty-third session): on a bearing's record
    # PBSID-opt reports v1..v9 and R, L, ki, kw, not the black box's a1..a4; a note says
    # so, and coordinates="identified" still gives the black box.
    r = maglevid.identify(faulty, "pbsid")
    assert r.options["coordinates"] == "physical"
    assert any("coordinates='physical'" in n for n in r.notes)
    assert abs(r.parameters["R1"] - 1.2 * NOMINAL.R1) < 4 * r.std_errors()["R1"]
    box = maglevid.identify(faulty, "pbsid", coordinates="identified")
    assert "v1" not in box.parameters and "a1" in box.parameters
    assert not any("coordinates='physical'" in n for n in box.notes)


def test_identify_reads_a_file(tmp_path, faulty):
    from maglevid.io import write_recording

    path = write_recording(faulty, tmp_path / "rec.npz")
    assert maglevid.identify(path).method == "physical"


def test_result_frame_has_units_and_95_percent_intervals(faulty):
    r = maglevid.identify(faulty)
    df = r.to_dataframe()
    assert list(df.columns) == ["estimate", "std_error", "ci_low", "ci_high", "unit"]
    assert df.loc["R1", "unit"] == "Ω" and df.loc["ki1", "unit"] == "N·A⁻¹"
    # 95 %: estimate +- 1.96 standard errors (normal quantile 1.959964).
    row = df.loc["R1"]
    assert row.ci_high - row.estimate == pytest.approx(1.959964 * row.std_error, rel=1e-6)
    page = r._repr_html_()
    assert "95 % interval" in page and "N·A⁻¹" in page and "<table>" in page
    assert len(repr(r)) < 200


def test_result_round_trips_through_json(faulty):
    r = maglevid.identify(faulty)
    d = json.loads(json.dumps(r.to_dict()))
    back = IdentificationResult.from_dict(d)
    assert back.to_dict() == r.to_dict()
    np.testing.assert_array_equal(back.model.A, r.model.A)
    with pytest.raises(maglevid.DataError, match="not a maglevid identification"):
        IdentificationResult.from_dict({"format": "something else"})
    with pytest.raises(maglevid.DataError, match="newer"):
        IdentificationResult.from_dict({**d, "version": 99})


def test_diagnosis_repr_is_short_and_html_shows_verdict_and_table(diagnosis):
    assert diagnosis.verdict_code == "fault"
    text = repr(diagnosis)
    assert len(text) < 300 and "R1" in text and "fault" in text
    page = diagnosis._repr_html_()
    assert diagnosis.verdict.split()[0] in page and "95 % interval" in page and "Ω" in page


def test_diagnosis_frame(diagnosis):
    df = diagnosis.to_dataframe()
    assert df.loc["R1", "status"] == "changed"
    assert df.loc["R1", "unit"] == "Ω"
    # R1 +20 % simulated: the change is within 3 of its standard errors (the 95 %
    # interval's half-width / 1.96). Not "inside the 95 % interval": one record misses
    # that 1 time in 20 when the interval is honest, and this one (seed 1) is a
    # 2.06-standard-error draw since the model-error term is the measured 2 e^2
    # (issue 13; it was e). Measured on seeds 1-30 of this fixture: rms z of R1 1.03,
    # 1 of 30 beyond 1.96 (the README's quiet sensors, nonlinear plant).
    lo, hi = df.loc["R1", "ci_low_percent"], df.loc["R1", "ci_high_percent"]
    assert abs((lo + hi) / 2 - 20) <= 3 * (hi - lo) / 2 / 1.959964
    assert set(df.index) == {c.name for c in diagnosis.changes}


def test_history_frame_has_units(tmp_path, faulty):
    from maglevid.diagnose.history import open_history

    path = tmp_path / "h.sqlite"
    maglevid.diagnose(faulty, baseline="nominal", machine="B-1", history=path)
    with open_history(path) as store:
        df = store.to_dataframe("B-1")
    r1 = df[df.parameter == "R1"].iloc[0]
    assert r1.unit == "Ω" and r1.baseline == NOMINAL.R1
    assert df[df.parameter == "ki1"].unit.iloc[0] == "N·A⁻¹"
    assert str(df.recorded_at.dtype).startswith("datetime64") and df.recorded_at.dt.tz is not None


@pytest.mark.parametrize(
    "first",
    [
        "import maglevid",
        "from maglevid.diagnose.history import open_history",
        "import maglevid.identify.arx",
        "from maglevid.diagnose import pipeline",
        "from maglevid import diagnose, identify",
    ],
)
def test_the_names_are_the_functions_whatever_is_imported_first(first):
    # The subpackages of the same names must never shadow the functions.
    import subprocess
    import sys

    code = (
        f"{first}\nimport inspect, maglevid\n"
        "assert inspect.isfunction(maglevid.diagnose), maglevid.diagnose\n"
        "assert inspect.isfunction(maglevid.identify), maglevid.identify\n"
        "print('ok')"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr


def test_import_maglevid_stays_light():
    # `import maglevid` (every CLI call) does not load the diagnosis: it is bound
    # on first use of maglevid.diagnose / maglevid.identify.
    import subprocess
    import sys

    code = "import sys, maglevid\nprint('maglevid.diagnose.pipeline' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_identify_refuses_a_mapping_for_data_in_memory(faulty):
    with pytest.raises(maglevid.DataError, match="mapping"):
        maglevid.identify(faulty, mapping={"layout": "time_first"})


def test_submodules_reached_through_the_functions_name():
    # `import maglevid.diagnose.pipeline as p` (and mock.patch's dotted paths) reach
    # `pipeline` as an attribute of `maglevid.diagnose`, the function.
    import maglevid.diagnose.pipeline as pipeline
    import maglevid.identify.arx as arx

    assert pipeline.diagnose is maglevid.diagnose
    assert callable(arx.fit_arx)
