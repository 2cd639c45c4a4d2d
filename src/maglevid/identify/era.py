"""Eigensystem Realization Algorithm (Juang & Pappa 1985), as used by OKID.

From Markov parameters ``Y_0 = D, Y_k = C A^(k-1) B`` (Gosiewski & Paszowski
eqs. (9), (19)) build the block Hankel matrices

    H(0) = [Y_{i+j+1}],  H(1) = [Y_{i+j+2}],   i < rows, j < cols,

factor ``H(0) = U S V^T`` and keep ``order`` singular values; then

    A = S^-1/2 U^T H(1) V S^-1/2,   B = S^1/2 V^T[:, :nu],   C = U[:ny] S^1/2,

a balanced realization (Juang, *Applied System Identification*, 1994, sec. 5.4).
The realization is in arbitrary ("ERA") coordinates; physical coordinates need
a transformation (eqs. (13)-(15), (22)-(26)). Nothing is stabilised: an
unstable system has growing Markov parameters and is realized as unstable.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from maglevid.exceptions import DataError, IdentificationError
from maglevid.lti import StateSpace

__all__ = ["block_hankel", "realize_era"]


def block_hankel(markov: np.ndarray, *, rows: int, cols: int, shift: int = 0) -> np.ndarray:
    """``[Y_{i+j+1+shift}]`` for ``i < rows, j < cols``, shape ``(rows*ny, cols*nu)``."""
    n, ny, nu = markov.shape
    need = rows + cols - 1 + shift + 1
    if n < need:
        raise DataError(
            f"a {rows}x{cols} block Hankel matrix with shift {shift} needs {need} Markov "
            f"parameters; got {n}"
        )
    H = np.empty((rows * ny, cols * nu))
    for i in range(rows):
        for j in range(cols):
            H[i * ny : (i + 1) * ny, j * nu : (j + 1) * nu] = markov[i + j + 1 + shift]
    return H


def realize_era(
    markov: Any,
    *,
    order: int,
    rows: int | None = None,
    cols: int | None = None,
    dt: float | None = None,
    output_scale: Any = None,
    input_scale: Any = None,
) -> tuple[StateSpace, np.ndarray]:
    """State-space realization of Markov parameters by ERA.

    Parameters
    ----------
    markov : array_like, shape (n, ny, nu)
        ``Y_0 = D``, ``Y_k = C A^(k-1) B`` (the convention of
        :meth:`maglevid.lti.StateSpace.markov`).
    order : int
        Number of states kept.
    rows, cols : int, optional
        Block rows and columns of the Hankel matrix; by default the fewest with
        ``rows*ny >= order`` and ``cols*nu >= order``, plus one.
    dt : float, optional
        Sample time of the returned model (``None`` gives ``dt = 1``).
    output_scale, input_scale : array_like, optional
        Typical sizes of the output and input channels (e.g. their RMS). The
        Hankel matrix is built from ``diag(1/output_scale) Y_k
        diag(input_scale)`` so that the singular values (and the order
        decision) do not depend on the units; the realization is scaled back.

    Returns
    -------
    model : StateSpace
        Discrete realization ``(A, B, C, D)``.
    singular_values : ndarray
        All singular values of ``H(0)`` (for the order choice).

    Raises
    ------
    IdentificationError
        ``H(0)`` has fewer than ``order`` nonzero singular values.

    Examples
    --------
    >>> import numpy as np
    >>> from maglevid.lti import StateSpace
    >>> true = StateSpace([[0.5, 1.0], [0.0, -0.3]], [[0.0], [1.0]], [[1.0, 0.0]], dt=1.0)
    >>> est, s = realize_era(true.markov(10), order=2)
    >>> np.allclose(np.sort(est.poles().real), [-0.3, 0.5])
    True
    """
    Y = np.asarray(markov, dtype=float)
    if Y.ndim != 3:
        raise DataError(f"`markov` must have shape (n, ny, nu); got {Y.shape}")
    _, ny, nu = Y.shape
    if order < 1:
        raise DataError(f"`order` must be >= 1; got {order}")
    rows = -(-order // ny) + 1 if rows is None else int(rows)
    cols = -(-order // nu) + 1 if cols is None else int(cols)
    if rows * ny < order or cols * nu < order:
        raise DataError(
            f"a {rows}x{cols} block Hankel matrix of {ny}x{nu} blocks has rank at most "
            f"{min(rows * ny, cols * nu)} < order {order}"
        )
    so = np.ones(ny) if output_scale is None else np.asarray(output_scale, dtype=float)
    si = np.ones(nu) if input_scale is None else np.asarray(input_scale, dtype=float)
    if so.shape != (ny,) or si.shape != (nu,) or np.any(so <= 0) or np.any(si <= 0):
        raise DataError(
            f"`output_scale` and `input_scale` must be positive with {ny} and {nu} entries"
        )
    Ys = Y / so[None, :, None] * si[None, None, :]
    H0 = block_hankel(Ys, rows=rows, cols=cols)
    H1 = block_hankel(Ys, rows=rows, cols=cols, shift=1)
    U, s, Vt = np.linalg.svd(H0, full_matrices=False)
    tol = s[0] * max(H0.shape) * np.finfo(float).eps
    if s[order - 1] <= tol:
        raise IdentificationError(
            f"the Hankel matrix has numerical rank {int(np.sum(s > tol))} < order {order}"
        )
    Un, sn, Vn = U[:, :order], s[:order], Vt[:order].T
    rs = np.sqrt(sn)
    A = (Un.T @ H1 @ Vn) / rs[:, None] / rs[None, :]
    B = (rs[:, None] * Vn.T)[:, :nu] / si[None, :]
    C = (Un * rs[None, :])[:ny] * so[:, None]
    return StateSpace(A, B, C, Y[0], dt=1.0 if dt is None else dt), s
