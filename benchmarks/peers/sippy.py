"""SIPPY (PyPI ``sippy_unipi``): N4SID, MOESP, CVA (open loop) and PARSIM-K (closed loop)."""

from __future__ import annotations

import contextlib
import io

import numpy as np

from benchmarks.peers import PeerMissing, PeerResult

__all__ = ["METHODS", "available", "identify"]

#: SIPPY's method names.
METHODS = ("N4SID", "MOESP", "CVA", "PARSIM-K")


def available() -> tuple[bool, str]:
    try:
        import importlib.metadata as md

        import sippy_unipi  # noqa: F401
    except ImportError as exc:
        return False, f"SIPPY (sippy_unipi) not installed ({exc})"
    return True, f"sippy_unipi {md.version('sippy_unipi')}"


def identify(
    y: np.ndarray, u: np.ndarray, order: int, horizon: int | None, method: str = "N4SID"
) -> PeerResult:
    """``sippy_unipi.system_identification`` with a fixed order; ``horizon`` -> ``SS_f``
    (and ``SS_p`` for PARSIM-K); SIPPY's default is 20."""
    try:
        from sippy_unipi import system_identification
    except ImportError as exc:
        raise PeerMissing(f"SIPPY (sippy_unipi) not installed ({exc})") from None
    h = horizon or 20
    kw = {"SS_fixed_order": order, "SS_f": h}
    if method.startswith("PARSIM"):
        kw["SS_p"] = h
    with contextlib.redirect_stdout(io.StringIO()):  # SIPPY prints progress
        model = system_identification(y.T.copy(), u.T.copy(), method, **kw)
    return PeerResult(np.linalg.eigvals(np.asarray(model.A)), info={"SS_f": h})
