"""python-control: Markov parameters by least squares, then the eigensystem realization."""

from __future__ import annotations

import numpy as np

from benchmarks.peers import PeerMissing, PeerResult

__all__ = ["available", "markov_era"]

#: FIR length of the Markov estimate (0.9^60 ~ 2e-3 truncation on the open-loop system).
FIR_LENGTH = 60


def available() -> tuple[bool, str]:
    try:
        import control
    except ImportError as exc:
        return False, f"python-control not installed ({exc})"
    return True, f"python-control {control.__version__}"


def markov_era(
    y: np.ndarray, u: np.ndarray, order: int, horizon: int | None, fir: int = FIR_LENGTH
) -> PeerResult:
    """``control.markov`` (FIR of ``max(fir, 2 horizon + 2)`` samples) + ERA of that horizon."""
    try:
        import control
    except ImportError as exc:
        raise PeerMissing(f"python-control not installed ({exc})") from None
    h = horizon or 10
    fir = max(fir, 2 * h + 2)  # ERA needs m + n + 1 Markov parameters
    H = control.markov(y, u, fir, transpose=True)
    sys_, _ = control.eigensys_realization(H, order, m=h, n=h, transpose=True)
    return PeerResult(np.linalg.eigvals(np.asarray(sys_.A)), info={"fir": fir})
