"""SLICOT's IB01AD/IB01BD natively, through the Python bindings of PyPI's ``ctrlsys``.

``ctrlsys`` wraps the Fortran library SLICOT (compiled, with Python bindings:
no interpreter and no file transfer, unlike the GNU Octave route of
:mod:`benchmarks.peers.octave`). Two calls make a model:

``IB01AD`` (``ctrlsys.ib01ad``)
    the data stage: the upper triangular factor ``R`` of the block-Hankel matrix
    of ``[U; Y]`` with ``nobr`` block rows (``2 nobr`` in all, the same window
    as maglevid's ``horizon = nobr``), and the order's singular values.
    ``alg='C'``: Cholesky of the correlation matrix (built from its
    block-Toeplitz structure, the route maglevid's Gram takes); ``alg='Q'``:
    Householder QR of the Hankel matrix itself; ``alg='F'``: fast QR.
``IB01BD`` (``ctrlsys.ib01bd``)
    the system matrices ``A, C`` (and ``B, D``) from ``R``: MOESP
    (``meth='M'``), N4SID (``meth='N'``) or combined (``meth='C'``, MOESP for
    ``A, C`` and N4SID for ``B, D``: what Octave's ``moen4`` calls).
    ``jobck='K'`` (the default here) also gives the noise covariances ``Q, Ry, S``
    and the steady-state Kalman gain ``K``; ``jobck='N'`` the model alone.

Like for like: maglevid's default subspace fit returns ``A, B, C, D`` *and* the
noise covariances and the Kalman gain (and the one-step residuals, which SLICOT
does not compute), so the benchmarks ask IB01BD for ``jobck='K'``; until
2026-12-02 they asked for ``jobck='N'``, timing SLICOT's model alone against
maglevid's model plus noise model. ``jobck='N'`` is the like-for-like call for
maglevid's ``noise_model=False``. When SLICOT's Riccati solver fails
(``info = 3 + i``, SB02RD's ``i``) the model is still returned, as maglevid
returns its model with a note when no steady-state predictor exists; the
adapter records it in ``info["kalman_gain"]``.

The call is timed in Python around both routines, the data given to them in
the column-major layout Fortran reads (the conversion is counted; it is one
copy of the record). Without ``horizon`` the adapter uses the default of
SLICOT's Octave/MATLAB front ends, ``nobr = min(2 n, n + 10)`` (8 for
``n = 4``): SLICOT's routines themselves have none.
"""

from __future__ import annotations

import time

import numpy as np

from benchmarks.peers import PeerMissing, PeerResult

__all__ = ["METHODS", "available", "default_nobr", "identify"]

#: name -> (IB01AD meth, IB01AD alg, IB01AD jobd, IB01BD meth)
METHODS = {
    "MOESP Cholesky": ("M", "C", "N", "M"),
    "MOESP QR": ("M", "Q", "N", "M"),
    "N4SID Cholesky": ("N", "C", "N", "N"),
    "MOESP+N4SID Cholesky": ("M", "C", "M", "C"),
}


def available() -> tuple[bool, str]:
    try:
        import importlib.metadata as md

        import ctrlsys  # noqa: F401
    except ImportError as exc:
        return False, f"ctrlsys (SLICOT) not installed ({exc}); pip install ctrlsys"
    return True, f"ctrlsys {md.version('ctrlsys')} (SLICOT IB01AD/IB01BD)"


def default_nobr(order: int) -> int:
    """Block rows SLICOT's front ends choose without ``s``: ``min(2 n, n + 10)``."""
    return min(2 * order, order + 10)


def identify(
    y: np.ndarray,
    u: np.ndarray,
    order: int,
    horizon: int | None,
    method: str = "MOESP Cholesky",
    jobck: str = "K",
) -> PeerResult:
    """``IB01AD`` + ``IB01BD`` of order ``order`` with ``horizon`` block rows.

    ``jobck``: ``"K"`` (model, noise covariances and Kalman gain: what maglevid's
    default fit returns) or ``"N"`` (the model alone: maglevid's ``noise_model=False``).
    """
    if jobck not in ("K", "N"):
        raise ValueError(f"jobck must be 'K' or 'N', not {jobck!r}")
    try:
        import ctrlsys
    except ImportError as exc:
        raise PeerMissing(f"ctrlsys (SLICOT) not installed ({exc}); pip install ctrlsys") from None
    meth_a, alg, jobd, meth_b = METHODS[method]
    nobr = horizon or default_nobr(order)
    t0 = time.perf_counter()
    uf = np.asfortranarray(u, dtype=float)
    yf = np.asfortranarray(y, dtype=float)
    n_samples, nu = uf.shape
    ny = yf.shape[1]
    # ctrl='N': no interactive confirmation; tol < 0: SLICOT's own gap rule
    # (the order is given to IB01BD anyway).
    n_est, R, _sv, _warn, info = ctrlsys.ib01ad(
        meth_a, alg, jobd, "O", "N", "N", nobr, nu, ny, uf, yf, 0.0, -1.0
    )
    if info != 0:
        raise RuntimeError(f"IB01AD info={info}")
    A, *_rest, _warn_b, info_b = ctrlsys.ib01bd(
        meth_b, "A", jobck, nobr, order, nu, ny, n_samples, R, 0.0
    )
    # info 4..9 with jobck='K': the Riccati equation of K failed, A, B, C, D are valid.
    if info_b != 0 and not (jobck == "K" and 3 < info_b <= 9):
        raise RuntimeError(f"IB01BD info={info_b}")
    poles = np.linalg.eigvals(np.asarray(A))
    t = time.perf_counter() - t0
    info = {"nobr": nobr, "order_estimate": int(n_est), "jobck": jobck}
    if jobck == "K":
        info["kalman_gain"] = "computed" if info_b == 0 else f"failed (IB01BD info={info_b})"
    return PeerResult(poles, inner_time_s=t, info=info)
