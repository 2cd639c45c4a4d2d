"""Matrix percentage index: the paper's Example I reproduced from its printed matrices."""

from __future__ import annotations

import numpy as np
import pytest

from maglevid.diagnose.percentage import percentage_index
from maglevid.exceptions import DataError
from maglevid.physics.amb import AMBParameters, amb_matrices

# Gosiewski & Paszowski, Example I: printed A_C, B_C (row 4 with -40.80 on the
# diagonal, our decision from eq. (4); see docs/papers.md), identified A_Ce, B_Ce
# and the printed percentage indexes A_p, B_p (NaN for the printed "x").
A_C = np.array(
    [[0, 1, 0, 0], [777547.06, 0, 272.14, -272.14], [0, -1142.12, -40.80, 0],
     [0, 1142.12, 0, -40.80]]
)  # fmt: skip
A_CE = np.array(
    [[-0.20, 0.99, -0.00, 0.00], [777360.39, -0.21, 272.11, -272.12],
     [593.28, -1141.43, -40.70, -0.05], [2821.75, 1145.41, 0.44, -41.06]]
)  # fmt: skip
A_P = np.array(
    [[np.nan, -0.0241, np.nan, np.nan], [-0.0240, np.nan, -0.0110, -0.0063],
     [np.nan, -0.0607, -0.2315, np.nan], [np.nan, 0.2886, np.nan, 0.6343]]
)  # fmt: skip
B_C = np.array([[0, 0], [0, 0], [2.3316, 0], [0, 2.3316]])
B_CE = np.array([[-0.0000, 0.0000], [-0.0000, 0.0000], [2.3316, -0.0000], [0.0001, 2.3314]])
B_P = np.array([[np.nan, np.nan], [np.nan, np.nan], [0.0005, np.nan], [np.nan, -0.0076]])


def _printing_tolerance(reference: np.ndarray, last_digit: float) -> np.ndarray:
    # The printed identified matrix is cut after its last digit (A_Ce[0, 1] = 0.99
    # for an A_p of -0.0241 % means 0.99976 was truncated, not rounded), so an
    # element may be off by one unit of that digit: 100 * unit / |reference|, plus
    # half a unit of the printed A_p's own 4th decimal.
    with np.errstate(divide="ignore"):
        return 100.0 * last_digit / np.abs(reference) + 5e-5


def test_reproduces_example_I_A_p_from_the_printed_matrices():
    got = percentage_index(A_CE, A_C)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(A_P))
    ok = ~np.isnan(A_P)
    tol = _printing_tolerance(A_C, 0.01)
    assert np.all(np.abs(got[ok] - A_P[ok]) <= tol[ok])


def test_reproduces_example_I_B_p_from_the_printed_matrices():
    got = percentage_index(B_CE, B_C)
    np.testing.assert_array_equal(np.isnan(got), np.isnan(B_P))
    ok = ~np.isnan(B_P)
    tol = _printing_tolerance(B_C, 1e-4)
    assert np.all(np.abs(got[ok] - B_P[ok]) <= tol[ok])


def test_printed_positive_row_4_diagonal_would_contradict_the_printed_index():
    # With +40.80 (as printed in A_C) the index of A_Ce[3, 3] = -41.06 would be
    # about -200 %, not the printed +0.6343 %: the printed sign is a typo.
    A_plus = A_C.copy()
    A_plus[3, 3] = +40.80
    assert percentage_index(A_CE, A_plus)[3, 3] == pytest.approx(-200.637, abs=1e-3)


def test_example_II_R1_fault_moves_only_v5():
    # Exact algebra: R1 x 1.2 changes v5 = R1/L1 by exactly +20 % and nothing else.
    p = AMBParameters.nominal()
    A0, B0 = amb_matrices(p)
    A1, B1 = amb_matrices(p.with_fault(R1=1.2))
    Ap, Bp = percentage_index(A1, A0), percentage_index(B1, B0)
    assert Ap[2, 2] == pytest.approx(20.0, rel=1e-12)
    others = np.isfinite(Ap) & ~np.eye(4, dtype=bool)
    others[2, 2] = False
    np.testing.assert_array_equal(Ap[others], 0.0)
    np.testing.assert_array_equal(Bp[np.isfinite(Bp)], 0.0)


def test_structural_zeros_are_nan_even_when_the_estimate_is_not_zero():
    got = percentage_index([[0.3, 2.0]], [[0.0, 1.0]])
    assert np.isnan(got[0, 0])
    assert got[0, 1] == 100.0
    assert not got.flags.writeable


@pytest.mark.parametrize(
    ("est", "ref", "match"),
    [
        (np.zeros((2, 2)), np.ones((2, 3)), "shape"),
        (np.zeros(3), np.ones(3), "2-D"),
        ([[np.nan]], [[1.0]], "non-finite"),
    ],
)
def test_bad_input_is_a_clear_error(est, ref, match):
    with pytest.raises(DataError, match=match):
        percentage_index(est, ref)


def test_zero_tolerance_restores_structural_zeros_after_a_round_trip():
    # undiscretize(discretize(.)) leaves ~1e-12 round-off at the zeros of eq. (4).
    from maglevid.lti import discretize, undiscretize
    from maglevid.physics.amb import amb_state_space

    base = amb_state_space(AMBParameters.nominal())
    back = undiscretize(discretize(base, 1e-4))
    exact = np.isnan(percentage_index(base.A, base.A))
    assert not np.array_equal(np.isnan(percentage_index(back.A, back.A)), exact)
    got = percentage_index(back.A, back.A, zero_tol=1e-10)
    np.testing.assert_array_equal(np.isnan(got), exact)
    with pytest.raises(DataError, match="zero_tol"):
        percentage_index(back.A, back.A, zero_tol=-1.0)
