"""nfoursid (PyPI ``nfoursid``): PO-MOESP by a QR of the full block-Hankel data."""

from __future__ import annotations

import numpy as np

from benchmarks.peers import PeerMissing, PeerResult

__all__ = ["available", "po_moesp"]


def available() -> tuple[bool, str]:
    try:
        import importlib.metadata as md

        import nfoursid  # noqa: F401
    except ImportError as exc:
        return False, f"nfoursid not installed ({exc})"
    return True, f"nfoursid {md.version('nfoursid')}"


def po_moesp(y: np.ndarray, u: np.ndarray, order: int, horizon: int | None) -> PeerResult:
    try:
        import pandas as pd
        from nfoursid.nfoursid import NFourSID
    except ImportError as exc:
        raise PeerMissing(f"nfoursid not installed ({exc})") from None
    ucols = [f"u{i}" for i in range(u.shape[1])]
    ycols = [f"y{i}" for i in range(y.shape[1])]
    df = pd.DataFrame(np.hstack([u, y]), columns=ucols + ycols)
    nfs = NFourSID(df, output_columns=ycols, input_columns=ucols, num_block_rows=horizon or 10)
    nfs.subspace_identification()
    ss, _ = nfs.system_identification(rank=order)
    return PeerResult(np.linalg.eigvals(np.asarray(ss.a)))
