"""Fault isolation of one-coil levitators (diagnose/levitator.py).

References: the physics of the steel-ball levitator (physics/levitator.py, eqs. (LIN1),
(Q1), (L1)-(LIN2)); exact observations of a faulty rig are predicted by that physics,
so a single injected cause must come back exactly (1e-6, the least-squares tolerance);
on the nonlinear simulated twin (experiments/rigs.py, quantised sensors, force
disturbance) the cause must be named and its size recovered within a few standard errors.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from benchmarks.bench_levitator_isolation import diagnose_twin, faulty_twin

from maglevid.diagnose.levitator import (
    LEVITATOR_HYPOTHESES,
    isolate_levitator_fault,
    observations_of,
    predict_observations,
)
from maglevid.diagnose.pipeline import diagnose
from maglevid.experiments.rigs import UAQ_TWIN
from maglevid.physics.levitator import LevitatorParameters

P = LevitatorParameters.uaq()
#: The UAQ rig with its driver as the twin states it (ku, and the offset v0 = 1.36 V).
PD = P.with_changes(R=5.05, ku=0.515, v0=1.36)
FAULTS = {
    "gap_offset": -2.9e-3, "gap_gain": 1.1, "a": 0.6, "k": 0.85, "m": 1.2,
    "current_gain": 1.05, "R": 1.3, "ku": 0.8, "v0": 1.2,
}  # fmt: skip


def _observed(changes, gaps=(0.004, 0.005, 0.006), electrical=True, command=False, base=P):
    """Exact observations of the UAQ rig with ``changes`` (0.3 % noise assumed)."""
    o = observations_of(
        base, y_ref=0.005, gaps=gaps, electrical=electrical, command=command, rel_se=3e-3
    )
    z = predict_observations(base, o, changes)
    n, n_el = len(gaps), 2 if electrical else 0
    return replace(
        o, pole=float(np.exp(z[0])), currents=tuple(np.exp(z[1 : 1 + n])),
        electrical=tuple(np.exp(z[1 + n : 1 + n + n_el])) if electrical else None,
        commands=tuple(np.exp(z[1 + n + n_el :])) if command else (),
    )  # fmt: skip


@pytest.mark.parametrize(
    ("name", "command"),
    # v0 moves only the command's level (without it: test_the_drivers_offset_is_judged...)
    [(n, c) for n in FAULTS for c in (False, True) if c or n != "v0"],
)
def test_each_hypothesis_is_recovered_from_its_exact_signature(name, command):
    iso = isolate_levitator_fault(_observed({name: FAULTS[name]}, command=command, base=PD), PD)
    assert iso.explained and iso.best.parameters
    named = [iso.best, *iso.indistinguishable]
    hit = next(h for h in named if h.parameters == (name,))
    assert hit.values[0] == pytest.approx(FAULTS[name], rel=1e-6)
    # Ties only between collinear signatures: k, m and the current-sensor gain all
    # scale the equilibrium currents alone (the coil circuit's floors need not split them).
    force_per_ampere = {"k", "m", "current_gain"}
    for h in named:
        assert h.parameters == (name,) or {name, *h.parameters} <= force_per_ampere


def test_healthy_rig_is_not_flagged():
    iso = isolate_levitator_fault(_observed({}), P)
    assert iso.best.parameters == () and iso.no_change.p_value > 0.5


def test_sensor_zero_and_gain_cannot_be_told_apart_at_one_gap():
    # One gap: a shifted zero and a gap-sensor gain both move only the true gap behind
    # the one reading (y_true = y/gs + d): identical signatures. The tool must say so,
    # and say what would resolve it. (A changed a differs: it also scales the currents
    # through sqrt(1/a), eq. (Q1).)
    iso = isolate_levitator_fault(_observed({"gap_offset": -2.9e-3}, gaps=(0.005,)), P)
    assert ("gap_offset", "gap_gain") in iso.collinear
    assert any(h.parameters == ("gap_gain",) for h in iso.indistinguishable)
    assert any("known gap reference" in h for h in iso.resolve_hints())
    d = iso.best.to_dict()  # the offset's change is in mm, and the JSON says so
    assert d["change_units"] == {"gap_offset": "mm"}
    assert d["changes_percent"]["gap_offset"] == pytest.approx(-2.9, abs=0.3)


def test_without_the_driver_R_and_ku_are_not_judged():
    iso = isolate_levitator_fault(_observed({"R": 1.3}, electrical=False), P)
    assert {n for n, _ in iso.not_tested} == {"R", "ku", "v0"}
    assert iso.best.parameters == ()  # the pole and currents see no change


def test_the_drivers_offset_is_judged_by_the_commands_level():
    # eq. (E1) at rest: ku u = R i + v0. v0 moves the command's level alone; the coil
    # circuit's R/L, ku/L and the currents do not see it (a twin with v0 x1.5 read "No
    # significant change": found from outside, twenty-seventh session).
    iso = isolate_levitator_fault(_observed({"v0": 1.2}, command=True, base=PD), PD)
    assert iso.best.parameters == ("v0",)
    assert iso.best.values[0] == pytest.approx(1.2, rel=1e-6)
    assert not iso.indistinguishable
    assert iso.observations.names[-3:] == ("u_eq@4mm", "u_eq@5mm", "u_eq@6mm")
    # the same change unseen without the command's level, and said why
    blind = isolate_levitator_fault(_observed({"v0": 1.2}, base=PD), PD)
    assert blind.best.parameters == ()
    why = dict(blind.not_tested)["v0"]
    assert "command's level" in why and "states no driver offset" in why
    # an ideal driver (v0 = 0) has nothing for a factor to move: not judged either
    ideal = isolate_levitator_fault(_observed({}, command=True), P)
    assert "v0" in dict(ideal.not_tested)


def test_unknown_hypothesis_is_refused():
    with pytest.raises(ValueError, match="unknown hypotheses"):
        isolate_levitator_fault(_observed({}), P, hypotheses=["Ls1"])
    assert set(LEVITATOR_HYPOTHESES) == set(FAULTS)


# ----------------------------------------------------------------- simulated rigs


def _twin(params, offset=0.0, seed=3):
    return faulty_twin(params, offset, seed=seed)


def _diagnose(data):
    return diagnose_twin(data)


@pytest.mark.parametrize(
    ("name", "params", "offset", "value"),
    [
        ("R", replace(UAQ_TWIN, R=1.3 * UAQ_TWIN.R), 0.0, 1.3),
        ("ku", replace(UAQ_TWIN, ku=0.8 * UAQ_TWIN.ku), 0.0, 0.8),
        ("k", replace(UAQ_TWIN, k=0.85 * UAQ_TWIN.k), 0.0, 0.85),
        ("gap_offset", UAQ_TWIN, 0.5e-3, 0.5e-3),
        ("v0", replace(UAQ_TWIN, v0=1.2 * UAQ_TWIN.v0), 0.0, 1.2),
    ],
)
def test_simulated_fault_is_isolated(name, params, offset, value):
    d = _diagnose(_twin(params, offset))
    iso = d.isolation
    assert d.verdict_code in ("fault", "inconclusive"), d.verdict
    named = [iso.best, *iso.indistinguishable]
    hit = next(h for h in named if h.parameters == (name,))
    # within 4 standard errors (noise + model-error floors) or 3 % of the injected size
    tol = max(4 * hit.std_errors[0], 0.03 * abs(value))
    assert abs(hit.values[0] - value) < tol, (hit, d.verdict)


def test_simulated_healthy_rig_is_not_flagged():
    d = _diagnose(_twin(UAQ_TWIN))
    assert d.verdict_code in ("no_change", "within_tolerance"), d.verdict
    assert d.isolation.best.parameters == ()
    # the twin states its driver's offset: the command's level is compared
    assert len(d.isolation.observations.commands) == 2
    assert not any("v0: not judged" in r for r in d.reasons)
    # what the observations cannot see is said (v0 x1.3 read a bare "No significant
    # change"; found from outside, seventeenth session): a baseline without v0
    data = _twin(UAQ_TWIN)
    plant = {k: v for k, v in data.metadata["plant"].items() if k != "v0_V"}
    d = _diagnose(replace(data, metadata={**data.metadata, "plant": plant}))
    assert d.verdict_code in ("no_change", "within_tolerance"), d.verdict
    assert any(r.startswith("the driver's voltage offset v0: not judged") for r in d.reasons)


# ----------------------------------------------------------------- real UAQ sessions
# One command-frame grey box per session (~8 s each) instead of the levitator consensus
# (80 s on escalon under load): the isolation reads the pole, the segments' equilibrium
# currents and the coil circuit, which every command-frame fit states.
# Reference (docs/real-rigs.md): the equilibrium line of multiescalon gives a = 2.3 +-
# 0.4 mm against the published 5.2 mm, i.e. a + y about 2.9 mm smaller than published.


@pytest.mark.parametrize(("session", "offset_mm"), [("escalon", -2.4), ("multiescalon", -2.9)])
def test_real_session_names_a_shifted_gap_zero_and_says_what_cannot_be_told_apart(
    shared_data, session, offset_mm
):
    path = next((shared_data / "maglev-uaq-levitador").glob(f"dataset_{session}_*.txt"))
    d = diagnose(
        path, mapping="uaq-levitador", method="greybox-levitator",
        method_options={"model": "electromechanical"},
    )  # fmt: skip
    iso = d.isolation
    # a change beyond tolerance whose cause is ambiguous is a fault, as the bearing's ties
    assert d.verdict_code == "fault" and "cannot be told apart" in d.verdict
    assert iso.best.parameters[0] == "gap_offset"
    # the zero moved by the equilibrium line's a - 5.2 mm (+-0.4 mm, its standard error)
    assert 1e3 * iso.best.values[0] == pytest.approx(offset_mm, abs=0.6)
    # the published physics state no driver: R, the driver gain and its offset not judged
    assert {n for n, _ in iso.not_tested} == {"R", "ku", "v0"}
    assert "R and the driver gain: not judged" in d.verdict
    assert any("known gap reference" in r for r in d.reasons)


def test_levitator_report_shows_the_levitator_panels_only():
    from maglevid.report.html import render_report

    d = _diagnose(_twin(replace(UAQ_TWIN, R=1.3 * UAQ_TWIN.R)))
    assert d.plant_kind == "levitator"
    page = render_report(d)
    # plants/levitator.py: no percentage index (an AMB panel over the v1..v9 matrices)
    assert 'id="percentage"' not in page and 'href="#percentage"' not in page
    assert 'id="poles"' in page and "equilibrium currents" in page


def test_history_baseline_compares_the_coil_circuit_and_names_a_driver_fault(tmp_path):
    # Against an earlier identification of the same rig (history), the baseline holds R,
    # ku, k0, a, k, so the coil circuit R/L, ku/L is compared: a driver gain down 20 %
    # (nothing else) must be named, R must not.
    import sqlite3

    from maglevid.diagnose.history import open_history

    store = open_history(tmp_path / "h.sqlite")
    kw = {"method": "greybox-levitator", "method_options": {"model": "electromechanical"},
          "baseline": "history", "machine": "lev1"}  # fmt: skip
    diagnose(_twin(UAQ_TWIN), recorded_at="2026-01-01T00:00:00+00:00", history=store, **kw)
    # a copy of the history as written before the driver's offset was stored
    old = tmp_path / "old.sqlite"
    src, dst = sqlite3.connect(tmp_path / "h.sqlite"), sqlite3.connect(old)
    try:
        src.backup(dst)  # (the store's write-ahead log included)
        dst.execute("DELETE FROM estimates WHERE parameter = 'v0'")
        dst.commit()
    finally:
        src.close()
        dst.close()
    faulty = _twin(replace(UAQ_TWIN, ku=0.8 * UAQ_TWIN.ku), seed=4)
    for path, blind in (("h.sqlite", set()), ("old.sqlite", {"v0"})):
        d = diagnose(faulty, recorded_at="2026-02-01T00:00:00+00:00",
                     history=open_history(tmp_path / path), **kw)  # fmt: skip
        assert d.baseline["source"].startswith("earlier identification")
        iso = d.isolation
        # the grey box stores v0 = ku u - R i: the command level is compared; a history
        # without it leaves v0 alone unjudged, and says so
        assert iso.observations.electrical is not None and set(dict(iso.not_tested)) == blind
        assert len(iso.observations.commands) == (0 if blind else 2)
        assert iso.best.parameters == ("ku",), d.verdict
        assert d.verdict_code == "fault" and "driver" in d.verdict
        tol = max(4 * iso.best.std_errors[0], 0.03)
        assert iso.best.values[0] == pytest.approx(0.8, abs=tol)
    assert any(r.startswith("the driver's voltage offset v0: not judged") for r in d.reasons)


def test_history_with_the_driver_offset_judges_the_command_level(tmp_path):
    # The levitator consensus (the default method) stores the driver's offset v0 = ku u
    # - R i with its command-frame fit (recomputed after the consensus widens R's and
    # ku's intervals), so a later record's command level is compared
    # with the history's: a v0 x1.2 twin is named against its healthy predecessor (it
    # read "not judged" against any history until the twenty-eighth session). One
    # candidate grey box keeps it fast; the consensus' other candidates change nothing
    # here (the command level is static).
    from maglevid.diagnose.history import open_history

    store = open_history(tmp_path / "h.sqlite")
    opts = {"flux_lag": [False], "command_delay": [False], "disturbance": ["white"]}
    kw = {"method": "levitator", "method_options": opts, "baseline": "history",
          "machine": "lev1", "history": store}  # fmt: skip
    first = diagnose(_twin(UAQ_TWIN), recorded_at="2026-01-01T00:00:00+00:00", **kw)
    v0 = first.identification.parameters["v0"]
    ku = first.identification.parameters["ku"]
    # v0 / ku (what the command level compares) within 5 % of the twin's
    assert v0 / ku == pytest.approx(UAQ_TWIN.v0 / UAQ_TWIN.ku, rel=0.05)
    # stored with their units (the history's levitator rows had none but i0's: found
    # from outside, twenty-eighth session)
    stored = store.latest_estimates("lev1")
    assert {k: stored[k].unit for k in ("R", "ku", "k0", "v0", "i0")} == {
        "R": "Ω", "ku": "V·V⁻¹", "k0": "H", "v0": "V", "i0": "A"
    }  # fmt: skip
    # a healthy record against it: the command level agrees
    d = diagnose(_twin(UAQ_TWIN, seed=5), recorded_at="2026-02-01T00:00:00+00:00", **kw)
    assert d.verdict_code in ("no_change", "within_tolerance"), d.verdict
    assert len(d.isolation.observations.commands) == 2
    # the driver's offset up 20 % against the latest (healthy) record
    d = diagnose(
        _twin(replace(UAQ_TWIN, v0=1.2 * UAQ_TWIN.v0), seed=4),
        recorded_at="2026-03-01T00:00:00+00:00", **kw,
    )  # fmt: skip
    iso = d.isolation
    assert d.baseline["source"].startswith("earlier identification")
    assert len(iso.observations.commands) == 2 and not dict(iso.not_tested)
    assert iso.best.parameters == ("v0",), d.verdict
    assert iso.best.values[0] == pytest.approx(1.2, abs=max(4 * iso.best.std_errors[0], 0.036))


def test_every_pair_that_can_tie_has_advice():
    """A tie names what would separate it, whichever two causes tie: a k x0.85 twin tied
    k with "gap_offset +0.82 mm" and the advice covered only k, m and the current sensor
    (found from outside, issue 16, sixteenth session)."""
    from itertools import combinations

    from maglevid.diagnose.levitator import RESOLVE_HINTS

    missing = [
        (x, y) for x, y in combinations(LEVITATOR_HYPOTHESES, 2)
        if frozenset({x, y}) not in RESOLVE_HINTS
    ]  # fmt: skip
    assert missing == []
    assert "known gap reference" in RESOLVE_HINTS[frozenset({"gap_offset", "k"})]


def test_tied_explanations_say_each_action_once():
    """Escalon ties gap_offset + k with gap_offset + m, gap_offset + a and a + k: the
    advice comes from what differs, each action once (with the pairs' hints completed it
    said "a known gap reference" and "records at gaps further apart" twice each)."""
    from types import SimpleNamespace

    from maglevid.diagnose.levitator import LevitatorIsolation

    tied = [("gap_offset", "m"), ("gap_offset", "a"), ("a", "k")]
    iso = SimpleNamespace(
        best=SimpleNamespace(parameters=("gap_offset", "k")),
        indistinguishable=[SimpleNamespace(parameters=p) for p in tied],
    )
    hints = LevitatorIsolation.resolve_hints(iso)
    assert len(hints) == len(set(hints)) == 3, hints
    assert sum("known gap reference" in h for h in hints) == 1
    assert sum("gaps further apart" in h for h in hints) == 1
    assert any(h.startswith("weighing the levitated body") for h in hints)


def test_the_coil_circuit_ratios_come_from_the_fit_not_the_widened_constants():
    # The consensus widens each constant's standard error to its hull by its own factor
    # (1e4x where a candidate cannot determine R, ku, k0): correlations kept, but the
    # near-exact cancellation in R/L and ku/L lost - UAQ twin R x1.3 (seed 504, default
    # path) read "R/L +30 % (interval -100 ... +3.5e94 %)", inconclusive, where R/L was
    # 75.2 against 57.7 (found from outside, seventeenth session).
    from types import SimpleNamespace

    from maglevid.diagnose.levitator import _electrical

    names = ["R", "ku", "k0", "a", "k"]
    th = np.array([5.05, 0.515, 0.0704, 0.0052, 0.0327])
    # R, ku and L (k0, k) known only together (their ratios): one common direction
    common = np.r_[th[:3], 0.0, th[4]]
    own = 0.04 * np.outer(common, common) + np.diag((1e-4 * th) ** 2)
    f = np.array([1e4, 1.01e4, 0.99e4, 1.0, 1.0])
    fit = SimpleNamespace(parameters=dict(zip(names, th)), covariance=own, extras={})
    widened = SimpleNamespace(parameters=fit.parameters, covariance=own * np.outer(f, f),
                              extras={"covariance_fit": own.tolist()})  # fmt: skip
    (rl, kl), cov = _electrical(fit, 0.005)
    (rl_w, kl_w), cov_w = _electrical(widened, 0.005)
    assert (rl_w, kl_w) == (rl, kl) and np.allclose(cov_w, cov)
    assert np.sqrt(cov[0][0]) / rl < 1e-3  # the ratio is fixed where R and L are not
    no_fit = SimpleNamespace(parameters=fit.parameters, covariance=widened.covariance, extras={})
    assert np.sqrt(_electrical(no_fit, 0.005)[1][0][0]) / rl > 10  # what it was


def _with_twin_noise(obs):
    """``obs`` with the standard errors of a 20 s twin record (Monte Carlo of the UAQ
    twin, nineteenth session: pole 1.1 %, currents 0.1 %, R/L 1.15 % and ku/L 1.05 %
    correlated 0.9)."""
    s = np.array([0.0115, 0.0105]) * np.asarray(obs.electrical)
    cov = np.array([[s[0] ** 2, 0.9 * s[0] * s[1]], [0.9 * s[0] * s[1], s[1] ** 2]])
    return replace(
        obs, pole_se=0.011 * obs.pole, current_se=tuple(1e-3 * c for c in obs.currents),
        electrical_cov=tuple(map(tuple, cov)),
    )  # fmt: skip


def test_the_driver_gain_down_15_percent_is_named_with_a_twin_records_noise(monkeypatch):
    # ku/L's model-error floor is 3 % (the twin's bias +0.7 %, the UAQ sessions' ku/L
    # within 1 % of each other); at the former 5 % the change was a 3-sigma move and the
    # joint test did not reject "no change" (7 of 10 twins "inconclusive", 1 named).
    import maglevid.diagnose.levitator as lev

    obs = _with_twin_noise(_observed({"ku": 0.85}, gaps=(0.005, 0.0045)))
    iso = isolate_levitator_fault(obs, P)
    assert iso.best.parameters == ("ku",) and not iso.indistinguishable
    assert iso.best.values[0] == pytest.approx(0.85, abs=0.01)
    monkeypatch.setattr(lev, "ELECTRICAL_FLOORS", (0.05, 0.05))
    assert isolate_levitator_fault(obs, P).best.parameters == ()  # what it was


def test_a_healthy_twin_records_coil_circuit_bias_is_no_change():
    # The twin's mean bias of R/L and ku/L (+1.2 %, +0.7 %) with its noise is not a change.
    obs = _with_twin_noise(_observed({}, gaps=(0.005, 0.0045)))
    obs = replace(obs, electrical=(1.012 * obs.electrical[0], 1.007 * obs.electrical[1]))
    iso = isolate_levitator_fault(obs, P)
    assert iso.best.parameters == () and iso.no_change.p_value > 0.5


def test_fits_the_data_do_not_reject_are_said_beside_the_named_cause():
    # The tie rule names fits within a chi-square of 1 of the best; the others that the
    # data do not reject (p >= alpha) are said in the reasons (UAQ multiescalon against
    # chirp's history: "m -16 %" with k and the current sensor at p 0.66 and 0.62 unsaid).
    from maglevid.plants.levitator import isolation_reasons

    iso = isolate_levitator_fault(
        _with_twin_noise(_observed({"m": 0.84}, gaps=(0.005, 0.0045))), P
    )
    (also,) = [r for r in isolation_reasons(iso, P) if r.startswith("also not rejected")]
    assert "gap-sensor zero -0.81 mm" in also and "(p = 0.43)" in also
    for h in (iso.best, *iso.indistinguishable):
        assert h.describe() not in also
    iso = isolate_levitator_fault(
        _with_twin_noise(_observed({"ku": 0.85}, gaps=(0.005, 0.0045))), P
    )
    assert not [r for r in isolation_reasons(iso, P) if r.startswith("also not rejected")]


@pytest.mark.parametrize(
    ("ku", "code"), [(0.88, "fault"), (0.9, "inconclusive"), (0.95, "no_change")]
)
def test_a_move_beyond_noise_and_model_error_is_not_no_change(ku, code):
    # ku/L -10 % (interval -15 ... -4 %: apart from 0, across -5 % by its 3 % floor alone)
    # while the joint test over five observations does not reject "no change" (p = 0.05):
    # it read "No significant change" (a twin with the driver's gain -10 %, nineteenth
    # session); -12 % is named, -5 % is no change.
    from maglevid.plants.levitator import _verdict

    iso = isolate_levitator_fault(_with_twin_noise(_observed({"ku": ku}, gaps=(0.005, 0.0045))), P)
    verdict, got = _verdict([], iso, P, 0.05)
    assert got == code, verdict
    if code == "inconclusive":
        assert "ku/L -10 % (interval -15 … -4.2 %)" in verdict
        assert "moved beyond noise and model error" in verdict
