"""IdentificationResult: intervals, JSON safety, delta-method propagation."""

from __future__ import annotations

import json

import numpy as np
import pytest

from maglevid.identify.result import IdentificationResult, propagate_covariance
from maglevid.lti import StateSpace


def _result(**kw):
    return IdentificationResult(
        method="test",
        model=StateSpace([[1.1]], [[1.0]], [[1.0]], dt=0.1),
        parameters={"a": 2.0, "b": -1.0},
        covariance=np.diag([0.04, 0.01]),
        n_samples=100,
        notes=("assumed x",),
        **kw,
    )


def test_intervals_and_dict():
    res = _result()
    lo, hi = res.confidence_intervals(0.95)["a"]
    assert lo == pytest.approx(2.0 - 1.959964 * 0.2, rel=1e-6)
    assert hi == pytest.approx(2.0 + 1.959964 * 0.2, rel=1e-6)
    d = json.loads(json.dumps(res.to_dict()))
    assert d["version"] == 1 and d["std_errors"]["b"] == pytest.approx(0.1)
    assert "assumed x" in res.summary() and "<table>" in res._repr_html_()


def test_dict_is_strict_json_and_reads_back_nan_and_inf():
    # to_dict() said "JSON-safe" but wrote NaN and inf in parameters, covariance, fit and
    # singular values, which json.dumps writes as invalid JSON (the CLI's output was
    # strict; the API's was not: found from outside, issue 16, thirteenth session).
    nan, inf = float("nan"), float("inf")
    res = IdentificationResult(
        method="m",
        model=None,
        parameters={"a": nan, "b": 1.0, "c": inf},
        covariance=np.array([[nan, 1.0, 0.0], [1.0, inf, 0.0], [0.0, 0.0, 1.0]]),
        fit={"f": nan, "g": -inf},
        singular_values=np.array([1.0, nan]),
    )
    d = json.loads(json.dumps(res.to_dict(), allow_nan=False))
    assert d["parameters"] == {"a": None, "b": 1.0, "c": "inf"}
    back = IdentificationResult.from_dict(d)
    assert np.isnan(back.parameters["a"]) and back.parameters["c"] == inf
    assert np.isnan(back.covariance[0, 0]) and back.covariance[1, 1] == inf
    assert np.isnan(back.fit["f"]) and back.fit["g"] == -inf
    assert back.to_dict() == res.to_dict()


def test_no_covariance_means_nan_not_zero():
    res = IdentificationResult(method="m", model=None, parameters={"a": 1.0})
    assert np.isnan(res.std_errors()["a"])
    assert res.to_dict()["covariance"] is None


def test_covariance_shape_checked():
    with pytest.raises(ValueError, match="covariance"):
        IdentificationResult(method="m", model=None, parameters={"a": 1.0}, covariance=np.eye(2))


def test_delta_method_matches_analytic():
    # f(a, b) = (a b, a / b): J = [[b, a], [1/b, -a/b^2]] (analytic).
    theta = np.array([2.0, 4.0])
    cov = np.array([[0.01, 0.002], [0.002, 0.04]])
    val, c = propagate_covariance(lambda t: np.array([t[0] * t[1], t[0] / t[1]]), theta, cov)
    J = np.array([[4.0, 2.0], [0.25, -2.0 / 16.0]])
    np.testing.assert_allclose(val, [8.0, 0.5])
    # Central differences of a bilinear map are exact up to rounding (~1e-16 absolute).
    np.testing.assert_allclose(c, J @ cov @ J.T, rtol=1e-7, atol=1e-15)


def test_a_result_pickles_whole():
    # as recordings (tests/test_data.py): for worker processes and users' own pools
    import pickle

    res = _result(
        options={"order": 2}, fit={"rmse": 0.5}, extras={"consensus": {"ci95": [1.0, 3.0]}}
    )
    back = pickle.loads(pickle.dumps(res))
    assert back.to_dict() == res.to_dict()
    np.testing.assert_array_equal(back.covariance, res.covariance)
    assert back.extras["consensus"]["ci95"] == [1.0, 3.0]
    with pytest.raises(TypeError):
        back.parameters["a"] = 3.0
