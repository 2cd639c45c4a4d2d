"""maglevid: physical-parameter identification and diagnosis of magnetic bearings.

Identify the open-loop physics of unstable magnetic suspensions from data recorded
with the loop closed (Gosiewski & Paszowski; Sun, Miyake, Ohmori & Sano), follow
the parameters over time, and say what changed and where.
"""

from __future__ import annotations

import logging

from maglevid import diagnose
from maglevid.data import ClosedLoopData
from maglevid.exceptions import (
    DataError,
    DesignError,
    FileFormatError,
    IdentificationError,
    MaglevidError,
    ModelError,
)
from maglevid.lti import StateSpace, discretize, undiscretize

__version__ = "0.1.0"

__all__ = [
    "ClosedLoopData",
    "DataError",
    "DesignError",
    "FileFormatError",
    "IdentificationError",
    "MaglevidError",
    "ModelError",
    "StateSpace",
    "__version__",
    "diagnose",
    "discretize",
    "undiscretize",
]

logging.getLogger(__name__).addHandler(logging.NullHandler())
