"""Plant kinds as modules (issue 19, item 1): each kind satisfies the protocol, and a
new kind registered from outside runs through the pipeline's stages unchanged."""

from __future__ import annotations

from types import MappingProxyType, SimpleNamespace

import numpy as np
import pytest

import maglevid.identify.registry as registry
from maglevid.data import ClosedLoopData
from maglevid.diagnose.diagnosis import Diagnosis, QualityCheck
from maglevid.diagnose.pipeline import diagnose
from maglevid.exceptions import DataError
from maglevid.physics.amb import V_NAMES, AMBParameters
from maglevid.physics.levitator import LevitatorParameters
from maglevid.physics.units import UNIT_WORDS
from maglevid.plants import (
    KINDS,
    DiagnosisStages,
    PlantKind,
    amb,
    infer_kind,
    levitator,
    mimo,
    register_kind,
    suspension,
)
from maglevid.plants.base import GENERIC_KIND, BaseKind, kinds_in_order

MODULES = (amb, suspension, levitator, mimo)


@pytest.mark.parametrize("module", MODULES, ids=lambda m: m.__name__.rsplit(".", 1)[-1])
def test_each_kind_module_satisfies_the_protocol(module):
    kind = module.KIND
    assert isinstance(kind, PlantKind)
    assert KINDS[kind.name] is kind
    assert kind.default_method == kind.methods[0]
    # every method the kind offers is a registered identification method
    assert set(kind.methods) <= set(registry.available_methods()), kind.methods
    # each parameter has an SI unit maglevid can put in words (report tooltips)
    assert all(unit in UNIT_WORDS for unit in kind.parameters.values()), kind.parameters
    for method in kind.methods:
        stages = kind.stages(method)
        assert isinstance(stages, DiagnosisStages)
        # The shared v-space stages drift-test the AMB's parameters whatever the kind
        # (as before the kinds existed): a suspension or MIMO record has none of them.
        own = stages is not amb.STAGES or kind is amb.KIND
        assert not own or set(stages.drift_parameters) <= set(kind.parameters)


def test_the_report_shows_every_panel_a_kind_names():
    # The panels are section ids of report/html.py; a bare diagnosis renders them all
    # (as "not available" where there is nothing to show).
    from maglevid.report.html import render_report

    page = render_report(Diagnosis(verdict="No significant change", verdict_code="no_change"))
    for kind in KINDS.values():
        missing = [p for p in kind.report_panels if f'id="{p}"' not in page]
        assert not missing, (kind.name, missing)


def test_the_generic_kind_is_tried_last_and_the_amb_default_is_one_constant():
    assert kinds_in_order()[-1].name == GENERIC_KIND
    assert amb.KIND.default_method is amb.DEFAULT_METHOD


def test_amb_fault_signatures_follow_eq_4_at_the_design_point():
    # eq. (4): v5 = R1/L1, so R1 up 1 % moves v5 by exactly +1 % and no other v_i;
    # a displacement-sensor gain gx scales v2, v3 by gx and v4, v6 by 1/gx
    # (isolate.v_with_sensor_gains).
    p = AMBParameters.nominal()
    sig = amb.KIND.signature("R1", p)
    assert sig["v5"] == pytest.approx(0.01, rel=1e-9)
    assert all(abs(sig[k]) < 1e-12 for k in V_NAMES if k != "v5")
    gx = amb.KIND.signature("gx", p)
    assert gx["v2"] == pytest.approx(0.01) and gx["v4"] == pytest.approx(1 / 1.01 - 1)
    with pytest.raises(DataError, match="no fault hypothesis 'R9'"):
        amb.KIND.signature("R9", p)
    # The levitator has a fault model since issue 14 (diagnose/levitator.py): R moves
    # only R/L (eq. (LIN2)), a gap-sensor zero moves the pole and the currents.
    lp = LevitatorParameters.uaq()
    r = levitator.KIND.signature("R", lp)
    assert r["R/L"] == pytest.approx(0.01, rel=1e-9)
    assert all(abs(v) < 1e-12 for k, v in r.items() if k != "R/L")
    assert levitator.KIND.signature("gap_offset", lp)["pole"] < 0
    with pytest.raises(DataError, match="no fault hypothesis 'R9'"):
        levitator.KIND.signature("R9", lp)


def test_a_kind_that_is_not_a_plant_kind_is_refused():
    with pytest.raises(DataError, match="is not a plant kind"):
        register_kind(object())  # type: ignore[arg-type]
    with pytest.raises(DataError, match="already registered"):
        register_kind(amb.KIND)


class _FiveAxisStages:
    """Stages of a fake kind that log each call, to check the pipeline's order."""

    drift_parameters = ("omega",)

    def __init__(self, calls: list[str]) -> None:
        self.calls = calls

    def quality(self, run):
        self.calls.append("quality")
        run.identify_options = {"order": 2}
        return (QualityCheck("five-axis", True, 1.0, 1.0, "all five axes logged"),)

    def baseline(self, run):
        self.calls.append("baseline")
        run.base = {"omega": (100.0, 0.0)}

    def compare(self, run):
        self.calls.append("compare")
        run.compared = run.result.parameters["omega"] / run.base["omega"][0] - 1

    def isolate(self, run):
        self.calls.append("isolate")
        return Diagnosis(
            verdict=f"omega {100 * run.compared:+.0f} %",
            verdict_code="no_change",
            quality=run.quality,
            notes=tuple(run.notes),
            **run.common,
        )


class _FiveAxisRotor(BaseKind):
    name = "five-axis-rotor"
    description = "a test's five-axis rotor (ten outputs, five inputs)"
    default_method = "n4sid"
    method_reason = "the test's stub"
    methods = ("n4sid",)
    parameters = MappingProxyType({"omega": "s⁻¹"})
    hypotheses = MappingProxyType({})
    report_panels = ("verdict", "quality", "method")

    def __init__(self, calls: list[str]) -> None:
        self._stages = _FiveAxisStages(calls)

    def recognise(self, data):
        return "ten outputs, five inputs" if (data.ny, data.nu) == (10, 5) else None

    def stages(self, method):
        return self._stages


@pytest.fixture
def five_axis(monkeypatch):
    calls: list[str] = []
    before = dict(KINDS)
    register_kind(_FiveAxisRotor(calls))
    fits = []

    def stub_fit(data, **options):
        fits.append(options)
        return SimpleNamespace(notes=("stub fit",), parameters={"omega": 110.0})

    monkeypatch.setattr(registry, "get_method", lambda name: stub_fit)
    yield calls, fits
    KINDS.clear()
    KINDS.update(before)


def test_a_new_kind_goes_through_the_pipelines_stages(five_axis, tmp_path):
    calls, fits = five_axis
    data = ClosedLoopData(y=np.zeros((50, 10)), u=np.zeros((50, 5)), dt=1e-3)
    assert infer_kind(data) == ("five-axis-rotor", "ten outputs, five inputs")
    diag = diagnose(data, machine="rotor-1", history=tmp_path / "h.sqlite")
    # the baseline first: a bad one is the caller's error, not hidden by a failed check
    assert calls == ["baseline", "quality", "compare", "isolate"]
    assert fits == [{"order": 2}]  # what the kind's quality stage asked the method for
    assert diag.verdict == "omega +10 %" and diag.method == "n4sid"
    assert "plant kind five-axis-rotor" in diag.method_reason
    assert diag.notes == ("stub fit",)
    # the record stage stored it (a second run is recognised as the same diagnosis)
    again = diagnose(data, machine="rotor-1", history=tmp_path / "h.sqlite")
    assert any(n.startswith("already stored") for n in again.notes)
    # the existing kinds are untouched by the new one
    assert infer_kind(ClosedLoopData(y=np.zeros((50, 9)), u=np.zeros((50, 2)), dt=0.01))[0] == (
        "mimo"
    )


def test_a_bearing_without_its_loop_is_identified_by_ml():
    # README's own-.mat recipe (no controller recorded): `identify` chose physical, whose
    # instruments were then lags of r: R1 3.7 against 17.5 ohm (found from outside, issue
    # 16, thirteenth session). Reference: the plants' own choice on both records.
    import dataclasses

    from maglevid.physics.amb import AMBParameters
    from maglevid.plants import choose_method
    from maglevid.simulate.amb import simulate_amb_loop

    nom = AMBParameters.nominal()
    d = simulate_amb_loop(nom, nominal=nom, n_samples=500, rng=1, plant_model="linear")
    assert choose_method(d)[0] == "physical"
    user = dataclasses.replace(
        d, loop={"operating_point": {"m": nom.m, "i0": nom.i0, "x0": nom.x0}}
    )
    method, why = choose_method(user)
    assert method == "ml" and "instruments would be lags of r" in why
