"""``with_physical_parameters``: v1..v9 results extended by eq. (4)'s physical parameters."""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.identify.result import IdentificationResult
from maglevid.identify.uncertainty import PHYSICAL_NAMES, with_physical_parameters
from maglevid.physics.amb import V_NAMES, AMBParameters, parameters_from_v


def _v_result(cov_scale=1e-6):
    nom = AMBParameters.nominal()
    v = nom.v()
    cov = np.diag((cov_scale * v) ** 2)
    return nom, IdentificationResult(
        method="pbsid", model=None, parameters=dict(zip(V_NAMES, map(float, v))), covariance=cov
    )


def test_physical_parameters_and_their_delta_method_covariance():
    nom, res = _v_result()
    out = with_physical_parameters(res, nom.m, nom.i0)
    truth = parameters_from_v(nom.v(), m=nom.m, i0=nom.i0)
    for k in PHYSICAL_NAMES:
        assert out.parameters[k] == pytest.approx(truth[k], rel=1e-12)
    assert out.parameters["R1"] == pytest.approx(nom.R1, rel=1e-9)  # reference: the design
    # R1 = m v5 v2 / v4 ... depends on v2, v4, v5 (eq. (4)): its relative variance is the
    # sum of theirs at 1e-6 each (delta method, uncorrelated v)
    se = out.std_errors()
    assert se["R1"] / out.parameters["R1"] == pytest.approx(np.sqrt(3) * 1e-6, rel=1e-3)
    lam = np.linalg.eigvalsh(out.covariance)  # rank 9 of 27: PSD to rounding
    assert lam.min() > -1e-12 * lam.max()
    assert out.covariance.shape == (9 + len(PHYSICAL_NAMES),) * 2


def test_unchanged_without_the_operating_point():
    nom, res = _v_result()
    assert with_physical_parameters(res, None, nom.i0) is res
    assert with_physical_parameters(res, nom.m, None) is res
