"""The loop matrix [[C, 0], [-F, Fe]] of eq. (46): singularity of symmetric controllers."""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.control import (
    check_loop_matrix,
    design_lqr,
    loop_matrix,
    loop_matrix_condition,
    restricted_loop_matrix,
)
from maglevid.exceptions import DesignError
from maglevid.physics.amb import C_AMB, AMBParameters, amb_state_space
from maglevid.simulate.amb import default_amb_controller

DT = 1e-4


def _mirror_symmetric_lqr():
    # Mirror-symmetric weights on the (symmetric) nominal bearing.
    sys = amb_state_space(AMBParameters.nominal(), DT)
    Q = np.diag([1e10, 0.0, 1e2, 1e2, 1e3]) * DT
    return design_lqr(sys, Q=Q, R=np.eye(2))


def test_mirror_symmetric_lqr_is_detected():
    ctrl = _mirror_symmetric_lqr()
    # The design is mirror-symmetric to round-off...
    np.testing.assert_allclose(ctrl.F[1, :2], -ctrl.F[0, :2], rtol=1e-9)
    np.testing.assert_allclose(ctrl.Fe[1], -ctrl.Fe[0], rtol=1e-9)
    # ...so the loop matrix is singular to round-off (condition ~1/eps).
    assert loop_matrix_condition(C_AMB, ctrl.F, ctrl.Fe) > 1e10
    with pytest.raises(DesignError, match="mirror-symmetric") as exc:
        check_loop_matrix(C_AMB, ctrl.F, ctrl.Fe)
    assert "eq. (46)" in str(exc.value) and "u_f1" in str(exc.value)


def test_exact_symmetry_reports_combination():
    F = np.array([[1e6, 700.0, 300.0, -300.0], [-1e6, -700.0, -300.0, 300.0]])
    Fe = np.array([[500.0], [-500.0]])
    with pytest.raises(DesignError, match=r"\(1\) u_f1 \+ \(1\) u_f2"):
        check_loop_matrix(C_AMB, F, Fe)


def test_default_design_is_well_conditioned():
    ctrl = default_amb_controller(AMBParameters.nominal(), DT)
    cond = loop_matrix_condition(C_AMB, ctrl.F, ctrl.Fe)
    # Documented value ~4.8 (docs/control-and-simulation.md); 20 leaves room for
    # place_poles differences between scipy versions, 1e8 is the hard limit.
    assert cond < 20
    assert check_loop_matrix(C_AMB, ctrl.F, ctrl.Fe) == cond
    assert ctrl.info["loop_matrix_condition"] == pytest.approx(cond, rel=1e-12)
    assert np.linalg.matrix_rank(loop_matrix(C_AMB, ctrl.F, ctrl.Fe)) == 5


@pytest.mark.parametrize("fault", [{"R1": 1.2}, {"K1": 0.9}, {"m": 1.2}])
def test_default_design_well_conditioned_on_other_nominals(fault):
    # The identification engineer may design on a non-nominal (e.g. identified) bearing.
    ctrl = default_amb_controller(AMBParameters.nominal().with_fault(**fault), DT)
    assert loop_matrix_condition(C_AMB, ctrl.F, ctrl.Fe) < 50


def test_restricted_matrix_carries_the_determinant(rng):
    # For C selecting x, i1, i2, det M = +-det S (S = [-F N, Fe], N = +-e_velocity).
    F, Fe = rng.standard_normal((2, 4)), rng.standard_normal((2, 1))
    M = loop_matrix(C_AMB, F, Fe)
    S = restricted_loop_matrix(C_AMB, F, Fe)
    assert M.shape == (5, 5) and S.shape == (2, 2)
    assert abs(np.linalg.det(M)) == pytest.approx(abs(np.linalg.det(S)), rel=1e-12)


def test_non_square_loop_matrix_is_explained():
    F, Fe = np.ones((2, 4)), np.ones((2, 2))  # two integrals: 5 x 6
    with pytest.raises(DesignError, match="not square"):
        loop_matrix_condition(C_AMB, F, Fe)


def test_rank_deficient_C():
    C = np.array([[1.0, 0, 0, 0], [1.0, 0, 0, 0], [0, 0, 0, 1.0]])
    with pytest.raises(DesignError, match="full row rank"):
        loop_matrix_condition(C, np.ones((2, 4)), np.ones((2, 1)))
