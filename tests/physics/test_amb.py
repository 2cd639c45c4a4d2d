"""AMB physics (Gosiewski & Paszowski eqs. (1)-(4)) and the decisions on the printed paper."""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.exceptions import DataError
from maglevid.physics.amb import (
    C_AMB,
    AMBParameters,
    amb_matrices,
    amb_nonlinear_rhs,
    open_loop_poles,
    parameters_from_v,
    ratios_from_v,
    v_from_matrices,
)

# Printed nominal matrices, "Computer simulation" section of the paper, with row 4's
# diagonal sign taken from eq. (4) (-v7; printed +40.80, see docs/papers.md).
A_PRINTED = np.array(
    [
        [0, 1, 0, 0],
        [777547.06, 0, 272.14, -272.14],
        [0, -1142.12, -40.80, 0],
        [0, 1142.12, 0, -40.80],
    ]
)
A_DIGITS = np.array([[0, 0, 0, 0], [2, 0, 2, 2], [0, 2, 2, 0], [0, 2, 0, 2]])
B_PRINTED = np.array([[0, 0], [0, 0], [2.3316, 0], [0, 2.3316]])


def test_nominal_reproduces_every_printed_element():
    A, B = amb_matrices(AMBParameters.nominal())
    # Each element equals the printed number when rounded to the printed digits.
    for (r, c), printed in np.ndenumerate(A_PRINTED):
        assert round(A[r, c], int(A_DIGITS[r, c])) == pytest.approx(printed, abs=1e-9), (r, c)
    for (r, c), printed in np.ndenumerate(B_PRINTED):
        assert round(B[r, c], 4) == pytest.approx(printed, abs=1e-12), (r, c)


def test_printed_parameter_values_are_the_rounded_derived_ones():
    # Paper: ks = 7e5 N/m, ki = 4.9e2 (N/A), Lo = 0.343 (H), Ls = 0.086 (H).
    p = AMBParameters.nominal()
    assert f"{p.ks1:.1e}" == "7.0e+05"
    assert f"{p.ki1:.1e}" == "4.9e+02"
    assert round(p.Lo1, 3) == 0.343
    # The rounded values themselves do NOT give the printed v1 (777777.8 vs 777547.06).
    assert 2 * 7e5 / 1.8 == pytest.approx(777777.78, abs=0.01)


def test_millihenry_reading_does_not_reproduce_the_paper():
    p = AMBParameters.nominal()
    mh = AMBParameters(
        m=p.m, i0=p.i0, x0=p.x0, R1=p.R1, R2=p.R2, Ls1=0.086e-3, Ls2=0.086e-3,
        K1=p.K1 * 1e-3, K2=p.K2 * 1e-3,
    )  # fmt: skip
    _, B = amb_matrices(mh)
    assert abs(B[2, 0] - 2.3316) > 1000


def test_unstable_pole_is_not_sqrt_v1():
    p = AMBParameters.nominal()
    poles = open_loop_poles(p)
    unstable = poles[poles.real > 0]
    assert unstable.size == 1 and abs(unstable[0].imag) < 1e-9
    assert unstable[0].real == pytest.approx(455.04, abs=0.01)
    assert np.sqrt(p.v()[0]) == pytest.approx(881.79, abs=0.01)
    # Characteristic polynomial check: det(sI - A_c) = 0 at the pole (independent of eig).
    A, _ = amb_matrices(p)
    s = unstable[0].real
    assert abs(np.linalg.det(s * np.eye(4) - A)) < 1e-6 * s**4


def test_inverse_map_recovers_parameters():
    p = AMBParameters.nominal().with_fault(R1=1.2, K2=0.9, kw1=1.1)
    est = parameters_from_v(p.v(), m=p.m, i0=p.i0)
    for name in ("R1", "R2", "kw1", "kw2", "x0", "K1", "K2", "Ls1", "Ls2"):
        assert est[name] == pytest.approx(getattr(p, name), rel=1e-12), name
    for name in ("ki1", "ki2", "ks1", "ks2", "L1", "L2", "Lo1", "Lo2"):
        assert est[name] == pytest.approx(getattr(p, name), rel=1e-12), name


def test_ratios_need_no_mass_or_bias_current():
    p = AMBParameters.nominal().with_fault(R1=1.3, K1=0.8, kw2=0.7)
    r = ratios_from_v(p.v())
    assert r["R1/R2"] == pytest.approx(p.R1 / p.R2, rel=1e-12)
    assert r["L1/L2"] == pytest.approx(p.L1 / p.L2, rel=1e-12)
    assert r["kw1/kw2"] == pytest.approx(p.kw1 / p.kw2, rel=1e-12)
    assert r["ki1/ki2"] == pytest.approx(p.ki1 / p.ki2, rel=1e-12)
    assert r["kw1/R1"] == pytest.approx(p.kw1 / p.R1, rel=1e-12)


def test_v_from_matrices_round_trip_and_structure_residual():
    v = AMBParameters.nominal().v()
    A, B = amb_matrices(v)
    v2, resid = v_from_matrices(A, B)
    np.testing.assert_array_equal(v2, v)
    assert resid == 0.0
    A_bad = A.copy()
    A_bad[2, 0] = 0.1 * A[2, 1]
    assert v_from_matrices(A_bad, B)[1] > 0.05


def test_output_matrix_has_no_duplicated_row():
    assert np.linalg.matrix_rank(C_AMB) == 3
    np.testing.assert_array_equal(C_AMB @ np.arange(4.0), [0.0, 2.0, 3.0])


def test_nonlinear_model_linearises_to_eq4():
    # Jacobian of eq. (1) at the operating point (central differences) equals A_c, B_c.
    p = AMBParameters.nominal().with_fault(R1=1.2, kw2=0.9)
    x_op = np.array([0.0, 0.0, p.i0, p.i0])
    u_op = np.array([p.R1 * p.i0 / p.kw1, p.R2 * p.i0 / p.kw2])
    np.testing.assert_allclose(amb_nonlinear_rhs(p, x_op, u_op), 0.0, atol=1e-9)
    A, B = amb_matrices(p)
    h = np.array([1e-9, 1e-6, 1e-6, 1e-6])
    J = np.column_stack(
        [
            (
                amb_nonlinear_rhs(p, x_op + h[i] * e, u_op)
                - amb_nonlinear_rhs(p, x_op - h[i] * e, u_op)
            )
            / (2 * h[i])
            for i, e in enumerate(np.eye(4))
        ]
    )
    np.testing.assert_allclose(J, A, rtol=1e-6, atol=1e-6 * np.abs(A).max())
    Ju = np.column_stack(
        [
            (
                amb_nonlinear_rhs(p, x_op, u_op + 1e-6 * e)
                - amb_nonlinear_rhs(p, x_op, u_op - 1e-6 * e)
            )
            / 2e-6
            for e in np.eye(2)
        ]
    )
    np.testing.assert_allclose(Ju, B, rtol=1e-6, atol=1e-9)


def test_parameters_are_validated():
    with pytest.raises(DataError, match="R1"):
        AMBParameters.nominal().with_fault(R1=-1.0)
    with pytest.raises(DataError, match="unknown parameter"):
        AMBParameters.nominal().with_fault(R3=1.0)
