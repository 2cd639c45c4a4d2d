"""maglevid: physical-parameter identification and diagnosis of magnetic bearings.

Identify the open-loop physics of unstable magnetic suspensions from data recorded
with the loop closed (Gosiewski & Paszowski; Sun, Miyake, Ohmori & Sano), follow
the parameters over time, and say what changed and where.

>>> import maglevid
>>> result = maglevid.identify("rec.npz")          # doctest: +SKIP
>>> diagnosis = maglevid.diagnose("rec.npz", baseline="nominal")  # doctest: +SKIP
>>> diagnosis                                     # verdict and table in Jupyter  # doctest: +SKIP
"""

from __future__ import annotations

import logging

# The subpackages ``maglevid.identify`` and ``maglevid.diagnose`` are imported
# (by maglevid.api) before the functions of the same names are bound here, so the
# attributes are the functions while ``from maglevid.diagnose.x import y`` still
# finds the subpackages in ``sys.modules``.
from maglevid.api import diagnose, identify
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
    "identify",
    "undiscretize",
]

logging.getLogger(__name__).addHandler(logging.NullHandler())
