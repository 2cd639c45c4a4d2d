"""Matrix percentage index of Gosiewski & Paszowski (Example I, after eq. (51)).

To judge an identified model against a reference, the paper divides the two
matrices element by element ("array division")::

    A_p = (A_Ce - A_C) / A_C * 100 %,     B_p = (B_Ce - B_C) / B_C * 100 %

and prints ``×`` where the reference element is a structural zero, where the
ratio has no meaning. Here the ``×`` is ``NaN``. For the two-coil bearing the
defined elements of ``A_p`` are ``v1..v7`` and the structural 1 in row 0, those
of ``B_p`` are ``v8`` and ``v9`` (eq. (4)).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from maglevid._validation import as_matrix
from maglevid.exceptions import DataError

__all__ = ["percentage_index"]


def percentage_index(estimate: Any, reference: Any, *, zero_tol: float = 0.0) -> np.ndarray:
    """Element-wise percentage change of ``estimate`` against ``reference``.

    Implements the matrix percentage indexes ``A_p`` and ``B_p`` of
    Gosiewski & Paszowski (Example I): ``(M_est - M_ref) / M_ref * 100`` by
    array division.

    Parameters
    ----------
    estimate, reference : array_like, same 2-D shape
        Identified and reference matrices (e.g. ``A_Ce`` and ``A_C``).
    zero_tol : float
        Reference elements with ``|ref| <= zero_tol * max|ref|`` count as
        structural zeros. ``0`` (default): exactly zero, as in the paper. A
        reference that went through ``discretize``/``undiscretize`` carries
        round-off (~1e-12 of the largest element) where the physics has zeros;
        ``1e-10`` restores them.

    Returns
    -------
    ndarray
        Percentages, read-only, ``NaN`` where the reference element is exactly
        zero (the paper's ``×``). An identified element that is non-zero where
        the reference has a structural zero is *not* judged here: the index
        cannot express it; look at the identified matrix itself.

    Raises
    ------
    DataError
        If the shapes differ or an input holds NaN/inf.

    Examples
    --------
    >>> percentage_index([[0.0, 0.99], [2.2, -41.06]], [[0.0, 1.0], [2.0, -40.8]]).round(4)
    array([[    nan, -1.    ],
           [10.    ,  0.6373]])
    """
    est = as_matrix(estimate, "estimate")
    ref = as_matrix(reference, "reference")
    if est.shape != ref.shape:
        raise DataError(
            f"`estimate` has shape {est.shape}; expected the shape of `reference`, {ref.shape}"
        )
    if not (zero_tol >= 0 and np.isfinite(zero_tol)):
        raise DataError(f"`zero_tol` must be a finite number >= 0; got {zero_tol!r}")
    out = np.full(ref.shape, np.nan)
    nz = np.abs(ref) > zero_tol * float(np.max(np.abs(ref), initial=0.0))
    out[nz] = (est[nz] - ref[nz]) / ref[nz] * 100.0  # A_p = (A_Ce - A_C) / A_C * 100 %
    out.setflags(write=False)
    return out
