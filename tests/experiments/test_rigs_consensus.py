"""`maglevid identify` with no method on the real rigs (../shared/data): plant kind,
consensus pole with its interval, several sessions at once, and Maggy's refusal.

Physics reference: the published UAQ law, sqrt(2 g/(a + y0)) with a = 5.2 mm
(docs/real-rigs.md); it is a reference, not a target - the sessions that disagree are
reported in docs/real-rigs.md, not tuned away.
"""

from __future__ import annotations

import json
import math

import pytest

from maglevid.cli.main import main
from maglevid.experiments.rigs import PUBLISHED
from maglevid.physics.levitator import unstable_pole

UAQ = "maglev-uaq-levitador"


def _identify(capsys, *args):
    assert main(["--json", "identify", *map(str, args)]) == 0
    return json.loads(capsys.readouterr().out)


def test_maggy_states_why_it_gives_no_plant_pole(shared_data, capsys):
    path = str(shared_data / "maggy-ntnu" / "PD_data_with_input.mat")
    # The quality gate refuses it (the amplifier saturates), and says why even --force
    # would not give the plant.
    assert main(["identify", path, "--mapping", "maggy-ntnu"]) == 1
    err = capsys.readouterr().err
    assert "saturates" in err and "cannot give the plant" in err
    res = _identify(capsys, path, "--mapping", "maggy-ntnu", "--force")
    assert res["plant_kind"] == "mimo" and res["method"] == "n4sid"
    # the README's PD law is exact on the levitating part (docs: R^2 = 1.000000) and
    # nothing else drives the loop: the record cannot give the open-loop pole
    assert res["plant_identifiable"] is False
    assert any("exact linear function of the outputs" in n for n in res["notes"])


def test_sessions_one_by_one_and_together(shared_data, capsys):
    # two of the five sessions, one by one and pooled; docs/real-rigs.md has all five and
    # the slow test below checks each. With the default candidates (the command delay and
    # both noise models, white and AR(1), included): escalon 52.9 [52.4, 53.4],
    # multiescalon 53.3 [50.5, 55.9]. Senoidal (52.6 [42.5, 57.3]) was a third session
    # here until the suite's time asked for it (nineteenth session: the test took 229-286 s
    # with it in a full run on two cores, 97 s alone without it): it is in the slow test.
    paths = [next((shared_data / UAQ).glob(f"dataset_{n}_*.txt"))
             for n in ("escalon", "multiescalon")]  # fmt: skip
    res = _identify(capsys, *paths, "--mapping", "uaq-levitador")
    assert len(res["sessions"]) == 2 and res["consensus"]["n_sessions"] == 2
    lo, hi = res["consensus"]["ci95"]
    assert 0 < lo <= res["parameters"]["pole_rad_s"] <= hi  # unstable, point inside
    for s in res["sessions"]:
        slo, shi = s["consensus"]["ci95"]
        assert 0 < slo <= s["parameters"]["pole_rad_s"] <= shi
    _meets_the_interval_condition(res["sessions"])
    # The pooled fit's constants: their noise-only intervals excluded every session's own
    # estimate (R 1.459 +- 0.008 ohm against escalon's 2.60 and multiescalon's 1.39; found
    # from outside, issue 16, fifteenth session); the hull over the sessions holds them.
    assert any(n.startswith("intervals of the model's constants") for n in res["notes"])
    for name in ("a", "k", "R", "ku"):
        lo, hi = res["ci95"][name]
        for s in res["sessions"]:  # escalon and multiescalon: both halves identify them
            assert lo <= s["parameters"][name] <= hi, (name, s["recording"], lo, hi)
    assert res["units"]["R"] == "Ω" and res["units"]["ku"] == "V·V⁻¹"


#: Sessions exempt from issue 14's +-15 % width: senoidal met it only through a fit whose
#: noise model had collapsed (flux lag + command delay, the current read as exact: its
#: measurement noise 9.5e-8 of what the record's changes allow; greybox
#: CURRENT_NOISE_FLOOR, fifteenth session of issue 16), as did every other flux-lag
#: candidate there. The one sound candidate (command delay) gives 52.6 [42.5, 57.3] rad/s
#: (-19 / +9 %), which holds the published physics at its gap (43.8): a wider honest answer.
_WIDER = ("senoidal",)


def _meets_the_interval_condition(sessions):
    """Issue 14's condition: each 95 % interval holds the published physics at its gap or
    overlaps every other session's interval, and none is wider than +-15 % (but
    :data:`_WIDER`)."""
    ivs = [s["consensus"]["ci95"] for s in sessions]
    for s, (lo, hi) in zip(sessions, ivs):
        physics = unstable_pole(PUBLISHED, s["options"]["y_ref"])
        p = s["parameters"]["pole_rad_s"]
        if not any(w in str(s["recording"]) for w in _WIDER):
            assert hi - p <= 0.15 * p and p - lo <= 0.15 * p, s["recording"]
        holds = lo <= physics <= hi
        overlaps = all(lo <= h and l <= hi for l, h in ivs)
        assert holds or overlaps, (s["recording"], lo, hi, ivs)


@pytest.mark.slow
def test_every_uaq_session_meets_the_interval_condition(shared_data, capsys):
    # the five sessions one by one, as `identify SESSION --mapping uaq-levitador` (the
    # table in docs/real-rigs.md); several minutes on one core. Constante has no
    # excitation (no r, one reference value): its pole rests on the noise model, and with
    # the AR(1) force disturbance no candidate identifies it (k0 at its bound or not
    # identifiable), so it is answered "inconclusive: no excitation" with no interval
    # (docs/real-rigs.md, 'Noise-only records'); every session that gives an interval
    # meets issue 14's condition.
    sessions = []
    for path in sorted((shared_data / UAQ).glob("dataset_*_*.txt")):
        res = _identify(capsys, path, "--mapping", "uaq-levitador")
        assert res["method"] == "levitator"
        sessions.append({**res, "recording": str(path)})
    assert len(sessions) == 5
    quiet = [s for s in sessions if "constante" in s["recording"]]
    (c,) = quiet
    assert c["consensus"]["inconclusive"].startswith("inconclusive: no excitation")
    pole = c["parameters"]["pole_rad_s"]
    assert (pole is None or math.isnan(pole)) and c["consensus"]["ci95"] == [None, None]
    answered = [s for s in sessions if s is not c]
    assert all(s["consensus"]["ci95"][0] is not None for s in answered)
    _meets_the_interval_condition(answered)
