"""numpy-alone references: the bare costs maglevid is measured against."""

from __future__ import annotations

import numpy as np

from benchmarks.bench_subspace import numpy_gram_cholesky
from benchmarks.peers import PeerResult

__all__ = ["available", "gram_cholesky", "lstsq"]


def available() -> tuple[bool, str]:
    return True, f"numpy {np.__version__}"


def gram_cholesky(y: np.ndarray, u: np.ndarray, order: int, horizon: int | None) -> PeerResult:
    """Textbook PO-MOESP: Gram of the block-Hankel rows + Cholesky (``bench_subspace``)."""
    return PeerResult(numpy_gram_cholesky(y, u, order, horizon or 10))


def lstsq(lhs: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """One ``np.linalg.lstsq`` on a regressor built beforehand (the reference of the AMB fits)."""
    return np.linalg.lstsq(phi, lhs, rcond=None)[0]
