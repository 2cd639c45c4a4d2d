"""Adapters of the tools people use today, for the side-by-side benchmark (``run_all``).

Every subspace adapter has the signature ``fn(y, u, order, horizon) -> Peer result``:
``y`` (N, ny) and ``u`` (N, nu) time first, the model order and the horizon
(block rows ``i``; ``None`` = the tool's own default), and returns the poles of
the identified ``A`` and, where the tool times itself (Octave's ``tic``/``toc``),
the time it reports. A tool that is not installed raises :class:`PeerMissing`
with the message the benchmark prints; ``available()`` of each module says so
without running anything.

===============  ==============================================  ==============================
adapter          tool                                            install
===============  ==============================================  ==============================
``octave``       SLICOT IB01AD/BD/CD via GNU Octave ``control``  apt: octave octave-control
``sippy``        SIPPY (N4SID, MOESP, CVA, PARSIM-K)             pip: sippy_unipi
``control_era``  python-control markov + eigensys_realization    pip: control
``nfoursid``     nfoursid (PO-MOESP by QR)                       pip: nfoursid
``numpy_ref``    numpy alone: Hankel Gram + Cholesky; lstsq      (numpy)
===============  ==============================================  ==============================
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["PeerMissing", "PeerResult"]


class PeerMissing(RuntimeError):
    """The tool is not installed (or cannot run here); the message says why."""


@dataclass
class PeerResult:
    """Poles of the identified ``A`` and the tool's own timing, if it has one."""

    poles: np.ndarray
    inner_time_s: float | None = None
    info: dict = field(default_factory=dict)
