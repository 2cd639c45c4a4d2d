"""The model error the verdict counts is the one the inconclusive verdict's advice counts.

Issue 13 (h13diag). One function, :func:`maglevid.diagnose.isolate.model_error_term`,
sets the isolation's relative model error of each v_i from the loop's excursion
(the planner's measured law ``2 e^2``, floored at 0.1 %);
the verdict (plants/amb.py ``estimate_model_error``) and the Cramér-Rao advice
(resolve.py, at the excursion a planned record would have) both call it, so the
advice promises the interval the diagnosis of the advised record states
(tests/diagnose/test_resolve_plan.py follows such an advice). Where no record
resolves a cause, the advice says why (the model error at its smallest) and which
tolerance would be decided. References: the definitions (std of each channel over
x0, i0), and interval_side for the tolerance that an interval of the stated
half-width decides.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from maglevid.diagnose.isolate import MODEL_ERROR_FLOOR, model_error_term, relative_excursion
from maglevid.diagnose.pipeline import diagnose
from maglevid.diagnose.resolve import Unresolved, interval_side
from maglevid.exceptions import DataError
from maglevid.physics.amb import AMBParameters
from maglevid.plants.amb import estimate_model_error
from maglevid.simulate import simulate_amb_loop
from maglevid.simulate.amb import DEFAULT_FORCE_STD, DEFAULT_NOISE_STD

NOMINAL = AMBParameters.nominal()


def test_model_error_term_is_the_measured_law_floored():
    """max(0.1 %, 2 e^2): planning.MODEL_ERROR_GAIN = 2 (the measured law)."""
    assert model_error_term(0.0) == MODEL_ERROR_FLOOR
    assert model_error_term(4e-3) == MODEL_ERROR_FLOOR  # 2 x 0.004^2 = 3.2e-5 < floor
    assert model_error_term(0.03) == pytest.approx(2 * 0.03**2, rel=1e-12)
    with pytest.raises(DataError):
        model_error_term(float("nan"))
    with pytest.raises(DataError):
        model_error_term(-1.0)


def test_relative_excursion_is_the_largest_channel_std_over_its_scale():
    rng = np.random.default_rng(0)
    y = rng.standard_normal((5000, 3)) * np.array([1e-6, 2e-3, 5e-3])
    want = max(np.std(y[:, 0]) / 3.5e-4, np.std(y[:, 1]) / 0.8, np.std(y[:, 2]) / 0.8)
    assert relative_excursion(y, 3.5e-4, 0.8) == pytest.approx(want, rel=1e-12)
    with pytest.raises(DataError, match="n_samples, 3"):
        relative_excursion(y[:, :2], 3.5e-4, 0.8)


@pytest.fixture(scope="module")
def boundary():
    """Ls1 +5 % on the nonlinear bearing (nominal bias voltages, force, CLI noise, 2 s):
    the estimate sits on the 5 % tolerance, closer to it than the model error allows."""
    rec = simulate_amb_loop(
        NOMINAL.with_fault(Ls1=1.05), rng=501, nominal=NOMINAL, plant_model="nonlinear",
        noise_std=DEFAULT_NOISE_STD, force_std=DEFAULT_FORCE_STD, n_samples=20_000,
    )  # fmt: skip
    return rec, diagnose(rec, baseline="nominal")


def test_the_verdict_counts_the_shared_term(boundary):
    rec, d = boundary
    e = relative_excursion(rec.y, NOMINAL.x0, NOMINAL.i0)
    assert estimate_model_error(rec, NOMINAL) == model_error_term(e)
    assert d.isolation.model_error == pytest.approx(model_error_term(e), rel=1e-12)


def test_no_record_resolves_it_says_why_and_which_tolerance_would_be_decided(boundary):
    _, d = boundary
    assert d.verdict_code == "inconclusive", d.verdict
    u = next(x for x in d.resolution if x["parameter"] == "Ls1")
    w, c = u["model_error_percent"], abs(u["estimate_percent"])
    # The smallest model error over the levels is the term's floor or above it.
    assert u["model_error_min"] >= MODEL_ERROR_FLOOR
    # Why: the model error alone leaves more than the half-width that decides it.
    assert w > u["needed_percent"]
    assert "the model error alone leaves" in u["advice"] and "no record resolves it" in u["advice"]
    # The tolerances it names are decided by an interval of half-width w (rounded
    # outward in the text: 3 significant digits).
    wide, narrow = (float(s) for s in _numbers_after(u["advice"], ("at least ±", "at most ±")))
    assert wide >= c + w - 0.01
    assert interval_side(c / 100, w / 100, (wide + 0.01) / 100) == "inside"
    assert narrow <= c - w + 0.01
    assert interval_side(c / 100, w / 100, (narrow - 0.01) / 100) == "beyond"


def _numbers_after(text: str, keys: tuple[str, ...]) -> list[str]:
    out = []
    for k in keys:
        tail = text.split(k, 1)[1]
        out.append(tail.split(" ", 1)[0])
    return out


def test_a_plan_shorter_than_the_record_proposes_no_more_seconds():
    """The plan's present-level length below the record's (k < 1) is no "record more"."""
    u = Unresolved(
        parameter="R1", tolerance_percent=5.0, half_width_percent=6.0, length_factor=0.5,
        more_seconds=-1.0, excitation_factor=math.sqrt(0.5), excitation_rms=0.7,
        plan_seconds=1.0, plan_excitation=1.0, estimate_percent=4.0, needed_percent=1.0,
    )  # fmt: skip
    assert "more of the same excitation" not in u.advice()
    assert "1 s in all at 1 V rms" in u.advice()


def test_a_plan_at_the_recordings_length_is_one_clause():
    """The shortest plan is never below the recording's length; when it is that
    length its level is the refined "raise it to" level and is said once."""
    u = Unresolved(
        parameter="x0", tolerance_percent=5.0, half_width_percent=0.17, length_factor=3.9,
        more_seconds=5.8, excitation_factor=2.03, excitation_rms=2.03,
        plan_seconds=2.0, plan_excitation=2.03, estimate_percent=4.9, needed_percent=0.11,
    )  # fmt: skip
    text = u.advice()
    assert "raise it to 2.03 V rms at this length" in text and " in all at " not in text
