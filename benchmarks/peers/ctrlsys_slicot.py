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
) -> PeerResult:
    """``IB01AD`` + ``IB01BD`` of order ``order`` with ``horizon`` block rows."""
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
    A, *_rest, info_b = ctrlsys.ib01bd(meth_b, "A", "N", nobr, order, nu, ny, n_samples, R, 0.0)
    if info_b != 0:
        raise RuntimeError(f"IB01BD info={info_b}")
    poles = np.linalg.eigvals(np.asarray(A))
    t = time.perf_counter() - t0
    return PeerResult(poles, inner_time_s=t, info={"nobr": nobr, "order_estimate": int(n_est)})
