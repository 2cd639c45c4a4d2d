"""ClosedLoopData: validation, multi-rate layout, immutability."""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.data import ClosedLoopData
from maglevid.exceptions import DataError


def _rec(**kw):
    base = {
        "y": np.arange(12.0).reshape(6, 2),
        "u": np.ones((6, 1)),
        "dt": 0.01,
        "names": {"y": ("x", "i1")},
        "units": {"y": ("m", "A")},
    }
    base.update(kw)
    return ClosedLoopData(**base)


def test_multirate_layout():
    y = np.arange(9.0)[:, None]  # 3 periods, p = 3
    d = ClosedLoopData(y=y, u=np.zeros((3, 1)), dt=0.03, p=3)
    assert d.n_samples == 3
    np.testing.assert_array_equal(d.y_control[:, 0], [0.0, 3.0, 6.0])
    np.testing.assert_array_equal(d.y_intersample(2)[:, 0], [2.0, 5.0, 8.0])
    assert d.dt_output == pytest.approx(0.01)
    np.testing.assert_allclose(d.time_output, 0.01 * np.arange(9))


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"u": np.ones((5, 1))}, "expected \\(6, n\\)"),
        ({"y": np.array([[1.0, np.nan]] * 6)}, "non-finite"),
        ({"y": np.array([[1.0, np.inf]] * 6)}, "inf"),
        ({"dt": 0.0}, "dt"),
        ({"y": np.zeros((1, 2)), "u": None}, "at least 2"),
        ({"p": 4, "y": np.zeros((10, 2)), "u": np.zeros((2, 1))}, "multiple of p=4"),
        ({"p": 0}, "integer >= 1"),
        ({"names": {"y": ("x",)}}, "1 entries for 2"),
        ({"units": {"q": ("m",)}}, "unknown signal"),
        ({"names": {"r": ("r1",)}}, "lacks"),
        ({"y": np.zeros((2, 3, 1))}, "1-D or 2-D"),
    ],
)
def test_bad_recordings_are_rejected_clearly(changes, match):
    with pytest.raises(DataError, match=match):
        _rec(**changes)


def test_u_r_uf_must_agree_in_channels():
    with pytest.raises(DataError, match="u_f"):
        _rec(r=np.ones((6, 1)), u_f=np.ones((6, 2)))


def test_immutable_and_inputs_not_aliased():
    y = np.arange(12.0).reshape(6, 2)
    d = _rec(y=y, loop={"controller": {"F": [[1.0, 2.0]]}})
    y[0, 0] = 99.0
    assert d.y[0, 0] == 0.0
    with pytest.raises(ValueError):
        d.y[0, 0] = 1.0
    with pytest.raises(TypeError):
        d.loop["x"] = 1  # type: ignore[index]
    assert d.loop["controller"]["F"].shape == (1, 2)


def test_segment_and_plant_input():
    d = ClosedLoopData(
        y=np.arange(8.0)[:, None], r=np.ones((4, 1)), u_f=2 * np.ones((4, 1)), dt=0.5, p=2
    )
    s = d.segment(1, 3)
    assert s.n_samples == 2 and s.t0 == 0.5
    np.testing.assert_array_equal(s.y[:, 0], [2.0, 3.0, 4.0, 5.0])
    np.testing.assert_array_equal(d.with_plant_input().u, 3 * np.ones((4, 1)))
    with pytest.raises(DataError, match="outside"):
        d.segment(3, 9)


def test_to_dict_is_json_safe():
    import json

    d = _rec(loop={"controller": {"F": np.eye(2)}}, metadata={"machine": "B1"})
    text = json.dumps(d.to_dict())
    assert '"machine": "B1"' in text
    assert d.to_dict()["signals"]["y"]["units"] == ["m", "A"]


def test_segment_cuts_extra_signals_with_their_rate():
    meta = {
        "extra_signals": {
            "yd": {"unit": "m", "rate": "control", "values": [0.0, 1.0, 2.0, 3.0]},
            "fast": {"unit": "V", "rate": "output", "values": list(range(8))},
        }
    }
    d = ClosedLoopData(y=np.zeros((8, 1)), u=np.zeros((4, 1)), dt=1.0, p=2, metadata=meta)
    s = d.segment(1, 3)
    np.testing.assert_array_equal(s.metadata["extra_signals"]["yd"]["values"], [1.0, 2.0])
    np.testing.assert_array_equal(s.metadata["extra_signals"]["fast"]["values"], [2, 3, 4, 5])


def test_a_recording_pickles_whole_and_stays_frozen():
    # Worker processes (maglevid.parallel: the levitator's candidates) and users' own pools
    # pickle recordings; the read-only mappings did not ("cannot pickle 'mappingproxy'").
    import pickle

    d = _rec(
        r=np.zeros((6, 1)),
        loop={"controller": "pid", "gains": {"kp": 2.0}},
        metadata={"machine": "AMB-1", "truth": {"R": [1.0, 2.0]}, "tags": ("a", "b")},
    )
    back = pickle.loads(pickle.dumps(d))
    for sig in ("y", "u", "r"):
        np.testing.assert_array_equal(getattr(back, sig), getattr(d, sig))
    assert (back.dt, back.p, back.t0) == (d.dt, d.p, d.t0)
    assert dict(back.names) == dict(d.names) and dict(back.units) == dict(d.units)
    assert back.loop["gains"]["kp"] == 2.0 and back.metadata["tags"] == ("a", "b")
    np.testing.assert_array_equal(back.metadata["truth"]["R"], [1.0, 2.0])
    with pytest.raises(TypeError):
        back.metadata["machine"] = "AMB-2"  # frozen again
    assert not back.y.flags.writeable
