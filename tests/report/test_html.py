"""The HTML report: self-contained, verdict first, escaped, machine-readable."""

from __future__ import annotations

import base64
import io
import json
import re
from datetime import datetime, timezone
from html import unescape
from html.parser import HTMLParser

import numpy as np
import pytest
from PIL import Image

from diagnosis_examples import DT, NOMINAL, example_controller
from maglevid import __version__
from maglevid.diagnose.compare import compare_parameters
from maglevid.diagnose.diagnosis import VERDICT_CODES, Diagnosis, QualityCheck
from maglevid.exceptions import DataError
from maglevid.physics.amb import amb_state_space
from maglevid.report import render_report, write_report
from maglevid.report.html import VERDICT_STYLE, _closed_loops, _json_safe

GENERATED = datetime(2026, 3, 14, 10, 0, 0, tzinfo=timezone.utc)

SECTION_IDS = (
    "verdict", "parameters", "percentage", "poles", "responses", "trends", "quality", "method",
)  # fmt: skip


class _Collect(HTMLParser):
    """Every start tag with its attributes, and the text of <script> elements."""

    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.tags: list[tuple[str, dict[str, str | None]]] = []
        self.scripts: list[tuple[dict[str, str | None], str]] = []
        self._in_script: dict[str, str | None] | None = None
        self.text: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))
        if tag == "script":
            self._in_script = dict(attrs)
            self.scripts.append((self._in_script, ""))

    def handle_endtag(self, tag):
        if tag == "script":
            self._in_script = None

    def handle_data(self, data):
        if self._in_script is not None:
            attrs, text = self.scripts[-1]
            self.scripts[-1] = (attrs, text + data)
        else:
            self.text.append(data)


def _parse(text: str) -> _Collect:
    p = _Collect()
    p.feed(text)
    p.close()
    return p


def _minimal(code: str, **kw) -> Diagnosis:
    return Diagnosis(verdict=f"verdict for {code}", verdict_code=code, **kw)


@pytest.fixture(scope="module")
def fault_html(fault_report):
    return fault_report.read_text(encoding="utf-8")


@pytest.fixture(scope="module")
def fault_parsed(fault_html):
    return _parse(fault_html)


def test_verdict_comes_first_and_sections_follow_in_the_issue_order(fault_html, fault_diagnosis):
    positions = [fault_html.index(f'id="{k}"') for k in SECTION_IDS]
    assert positions == sorted(positions)
    # The verdict text is the first heading of the page.
    first_h1 = re.search(r"<h1[^>]*>(.*?)</h1>", fault_html).group(1)
    assert unescape(first_h1) == fault_diagnosis.verdict
    assert f'style="background:{VERDICT_STYLE["fault"][0]}"' in fault_html


def test_self_contained_no_external_resource(fault_parsed, fault_html):
    for tag, attrs in fault_parsed.tags:
        for key in ("src", "href", "data", "poster"):
            v = attrs.get(key)
            if v is None:
                continue
            assert v.startswith(("data:", "#")), f"<{tag} {key}={v[:60]!r}> is not inline"
        assert tag not in ("link", "iframe", "object", "embed"), tag
    assert "@import" not in fault_html and "url(" not in fault_html
    assert len(fault_html.encode("utf-8")) < 2_000_000


def test_every_image_is_a_decodable_png(fault_parsed):
    imgs = [a for t, a in fault_parsed.tags if t == "img"]
    # forest plot, pole maps, impulse responses, Bode, trends
    assert len(imgs) == 5
    for a in imgs:
        assert a["alt"]
        prefix = "data:image/png;base64,"
        assert a["src"].startswith(prefix)
        im = Image.open(io.BytesIO(base64.b64decode(a["src"][len(prefix) :], validate=True)))
        im.load()
        assert im.format == "PNG" and im.size[0] >= 1000


def test_embedded_json_is_the_diagnosis_to_dict(fault_parsed, fault_diagnosis):
    blocks = [s for a, s in fault_parsed.scripts if a.get("id") == "diagnosis-data"]
    assert len(blocks) == 1
    data = json.loads(blocks[0])
    expect = json.loads(json.dumps(_json_safe(fault_diagnosis.to_dict())))
    assert data == expect
    assert data["verdict_code"] == "fault"
    assert data["format"] == "maglevid-diagnosis"


def test_parameter_table_and_percentage_index(fault_html, fault_diagnosis):
    r1 = next(c for c in fault_diagnosis.changes if c.name == "R1")
    assert f"{r1.change_percent:+.2f} %".replace("-", "−") in fault_html
    # Paper's layout: 4x4 and 4x2 with x at the baseline's 8 + 6 structural zeros.
    assert fault_html.count('<td class="x"') == 14
    v5 = fault_diagnosis.percentage_index["A_p"][2, 2]
    assert f'<span class="vtag">v5</span>{v5:+.4f}' in fault_html
    assert 'class="status st-changed">changed<' in fault_html


def test_closed_loop_is_shown_with_the_controller(fault_html):
    assert "Closed loop with the identified plant is stable" in fault_html


def test_footer_has_version_and_creation_time(fault_html):
    assert f"Generated by maglevid {__version__} on 2026-03-14 10:00:00 UTC" in fault_html


def test_text_is_escaped(blocked_report):
    html = blocked_report.read_text(encoding="utf-8")
    assert "amplifiers saturate &lt;often&gt;" in html
    assert "<often>" not in html  # in the JSON block too: "<" is written \\u003c


def test_hostile_text_cannot_break_out():
    evil = '</script><script>alert("x")</script><img src=http://evil/>'
    d = Diagnosis(
        verdict=evil,
        verdict_code="unexplained_change",
        reasons=(evil,),
        machine=evil,
        quality=(QualityCheck(evil, False, 1.0, 2.0, evil, blocking=False),),
        notes=(evil,),
    )
    html = render_report(d, title=evil, generated_at=GENERATED)
    parsed = _parse(html)
    assert [t for t, _ in parsed.tags].count("script") == 2
    assert not any(t == "img" for t, _ in parsed.tags)
    data = json.loads(next(s for a, s in parsed.scripts if a.get("id") == "diagnosis-data"))
    assert data["verdict"] == evil


@pytest.mark.parametrize("code", VERDICT_CODES)
def test_each_verdict_code_has_its_colour_and_label(code):
    html = render_report(_minimal(code), generated_at=GENERATED)
    color, label = VERDICT_STYLE[code]
    assert f'style="background:{color}" data-verdict-code="{code}"' in html
    assert f'<div class="pill">{label}</div>' in html
    assert f"verdict for {code}" in html


def test_verdict_colours_are_distinct():
    assert len({c for c, _ in VERDICT_STYLE.values()}) == len(VERDICT_CODES)
    assert set(VERDICT_STYLE) == set(VERDICT_CODES)


def test_cannot_diagnose_report_is_clear(blocked_report):
    html = blocked_report.read_text(encoding="utf-8")
    parsed = _parse(html)
    assert not any(t == "img" for t, _ in parsed.tags)
    assert VERDICT_STYLE["cannot_diagnose"][0] in html
    assert "The data-quality checks stopped the diagnosis" in html
    assert "2 blocking check(s) failed (excitation SNR [dB], saturation [%])" in html
    assert html.count('class="status st-changed">fail<') == 2
    assert html.count('class="status st-pass">pass<') == 1
    assert "amplifiers saturate &lt;often&gt;" in html
    # Every section anchor still exists (the table of contents links to it).
    for k in SECTION_IDS:
        assert f'id="{k}"' in html


def test_without_controller_open_loop_only_and_it_says_so(fault_diagnosis):
    loops, note = _closed_loops(fault_diagnosis, None)
    assert loops is None and "only the open loop is shown" in note


def test_controller_is_found_in_the_baseline(fault_diagnosis):
    base = dict(fault_diagnosis.baseline, loop=example_controller())
    d = Diagnosis(
        verdict="x", verdict_code="fault", baseline=base,
        baseline_model=fault_diagnosis.baseline_model,
        identified_model=fault_diagnosis.identified_model, dt=DT,
    )  # fmt: skip
    loops, note = _closed_loops(d, None)
    assert note == "" and loops[1].is_stable()


def test_bad_controller_is_reported_not_raised(fault_diagnosis):
    bad = {"controller": {"F": np.zeros((3, 3))}, "observer": {"G": np.zeros((4, 3))}}
    loops, note = _closed_loops(fault_diagnosis, bad)
    assert loops is None and note.startswith("Closed loop not shown") and "'F'" in note


def test_trends_table_and_crossing_date():
    trends = {
        "R1": {
            "time": ["2026-01-01T00:00:00+00:00", "2026-01-31T00:00:00+00:00"],
            "value": [17.5, 18.0],
            "std_error": [0.05, 0.05],
            "drift": {
                "drifting": True, "p_value": 1e-6, "slope": 0.5 / (30 * 86400),
                "t_ref": 1767225600.0, "value_at_ref": 17.5,  # 2026-01-01 UTC
                "projected_crossing_time": 1777593600.0,  # 2026-05-01 UTC
            },
        }
    }  # fmt: skip
    changes = compare_parameters({"R1": (18.0, 0.05)}, {"R1": 17.5})
    html = render_report(_minimal("fault", changes=changes), trends=trends)
    assert "leaves the tolerance band around 2026-05-01" in html
    assert "+2.86 % of baseline per 30 days" in html.replace("−", "-")
    assert "18 ± 0.05" in html


def test_a_figure_that_fails_leaves_a_visible_note(caplog):
    bad = {"R1": {"time": [0, 1, 2], "value": [1.0, 2.0]}}
    html = render_report(_minimal("no_change"), trends=bad)
    assert "could not be drawn" in html and "3 times but 2 values" in html
    assert any("failed" in r.getMessage() for r in caplog.records)
    assert "</html>" in html


def test_write_report_checks_its_arguments(tmp_path):
    with pytest.raises(DataError, match="does not exist"):
        write_report(_minimal("no_change"), tmp_path / "missing" / "r.html")
    with pytest.raises(DataError, match="must be a Diagnosis"):
        render_report({"verdict": "x"})
    with pytest.raises(DataError, match="`trends` must be a mapping"):
        render_report(_minimal("no_change"), trends=[1, 2])
    out = write_report(_minimal("no_change"), tmp_path / "r.html")
    assert out == tmp_path / "r.html" and out.read_text(encoding="utf-8").startswith("<!DOCTYPE")


def test_percentage_index_is_computed_when_the_diagnosis_has_none():
    base, ident = amb_state_space(NOMINAL), amb_state_space(NOMINAL.with_fault(kw1=1.2))
    d = Diagnosis(
        verdict="x", verdict_code="fault", baseline_model=base, identified_model=ident, dt=DT
    )
    from maglevid.report.html import _percentage_section

    html = _percentage_section(d)
    # Example III of the paper: kw1 +20 % moves v8 by exactly +20 %.
    assert '<span class="vtag">v8</span>+20.0000' in html


def test_discrete_models_give_the_same_evidence(fault_diagnosis):
    # A diagnosis may carry the sampled models: A_p, B_p come from their
    # continuous equivalents (eq. (8)), equal to the continuous ones to ~1e-9.
    from maglevid.lti import discretize
    from maglevid.report.html import _percentage, _poles_section

    d = Diagnosis(
        verdict="x", verdict_code="fault", dt=DT,
        baseline_model=discretize(fault_diagnosis.baseline_model, DT),
        identified_model=discretize(fault_diagnosis.identified_model, DT),
    )  # fmt: skip
    Ap, Bp = _percentage(d)
    ref = fault_diagnosis.percentage_index
    np.testing.assert_allclose(Ap, ref["A_p"], atol=1e-6, equal_nan=True)
    np.testing.assert_allclose(Bp, ref["B_p"], atol=1e-6, equal_nan=True)
    html = _poles_section(d, None, "")
    assert "<img" in html and "could not be drawn" not in html
    assert "455.041" in html  # the unstable pole, read back through ln(z)/dt


def test_identified_model_falls_back_to_the_identification(fault_diagnosis):
    import dataclasses

    d = dataclasses.replace(
        fault_diagnosis, identified_model=None, percentage_index=None, changes=()
    )
    html = render_report(d, generated_at=GENERATED)
    # Sections 3-5 are drawn from identification.continuous_model: the v5 cell,
    # the pole maps, impulse and Bode figures (no forest plot without changes).
    v5 = fault_diagnosis.percentage_index["A_p"][2, 2]
    assert f'<span class="vtag">v5</span>{v5:+.4f}' in html
    assert html.count("<img ") == 3


# ------------------------------------------------------------- issue 18: cosmetics
def test_units_are_unambiguous_with_words_on_hover(fault_html):
    # ki's unit was "N/A", which reads as "not applicable".
    assert '<abbr title="newton per ampere">N·A⁻¹</abbr>' in fault_html
    assert ">N/A<" not in fault_html


def test_no_internals_and_no_paper_sentence(fault_html, fault_diagnosis):
    text = unescape(re.sub(r"<[^>]+>", " ", fault_html))
    assert "Example II" not in text  # the paper's numbers belong to `reproduce gosiewski`
    assert "option: " not in text and "fit: " not in text
    assert "one_step_fit_percent" not in text.split("diagnosis-data")[0]
    assert "None" not in re.sub(
        r'<script type="application/json".*?</script>', "", fault_html, flags=re.S
    )
    assert "one-step prediction fit of" in text


def test_every_note_once(fault_html):
    notes = re.findall(r"<h3>Notes</h3><ul>(.*?)</ul>", fault_html, re.S)
    items = re.findall(r"<li>(.*?)</li>", notes[0]) if notes else []
    assert len(items) == len(set(items))
    # The loop note is shown once, with the pole maps.
    assert fault_html.count("The diagnosis carries no controller") <= 1


def test_expected_unstable_pole_is_labelled_as_expected(fault_html):
    # The bearing's open-loop pole at +455 rad/s is physics, not a fault.
    assert "unstable: expected for a magnetic bearing" in fault_html
    assert "unstable (the baseline is not)" not in fault_html


def test_trend_panels_changed_first_and_v_in_their_own_group(fault_diagnosis):
    from diagnosis_examples import example_trends
    from maglevid.report.html import _ordered_trends

    trends = example_trends()
    flat = trends["R2"]
    trends = {
        "K1": flat, "R2": flat, "v5": flat, "R1": trends["R1"], "v2": flat, "kw2": flat,
    }  # fmt: skip
    ordered = list(_ordered_trends(fault_diagnosis, trends))
    assert ordered[0] == "R1"  # the changed (and drifting) parameter leads
    assert ordered[1:] == ["K1", "R2", "v5", "v2", "kw2"]  # the rest keep their order
    html = render_report(fault_diagnosis, trends=trends, generated_at=GENERATED)
    section = html[html.index('id="trends"') :]
    assert section.index("<h3>Physical parameters</h3>") < section.index(
        "<h3>Model elements v1..v9"
    )


def test_inconclusive_banner_is_amber_and_says_what_would_resolve_it():
    # Issue 12: an interval wider than its tolerance is never shown green.
    advice = "R1 ±27 % (tolerance ±5 %): record about 58 s more of the same excitation"
    d = _minimal("inconclusive", resolution=({"parameter": "R1", "advice": advice},))
    html = render_report(d)
    banner = html.split('id="verdict-banner"')[1].split("</div></div>")[0]
    assert VERDICT_STYLE["inconclusive"][0] in banner and "Inconclusive" in banner
    assert VERDICT_STYLE["no_change"][0] not in banner
    assert "58 s more of the same excitation" in html
