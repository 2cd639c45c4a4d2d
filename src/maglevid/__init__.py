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

import importlib
import logging
from typing import Any

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

# ``maglevid.identify`` and ``maglevid.diagnose`` are the functions of
# maglevid.api, and also the names of two subpackages. Importing a subpackage for
# the first time binds it as an attribute of this package; so both are imported
# here (cheap: their __init__ are small) and their attributes removed, and the
# functions are bound on first use by __getattr__ (maglevid.api imports the whole
# diagnosis, scipy.optimize included: too slow for every `import maglevid`).
# ``from maglevid.diagnose.history import open_history`` keeps working through
# sys.modules.
_FUNCTIONS = ("diagnose", "identify")
for _name in _FUNCTIONS:
    importlib.import_module(f"{__name__}.{_name}")
    globals().pop(_name, None)


def __getattr__(name: str) -> Any:
    if name in _FUNCTIONS:
        fn = getattr(importlib.import_module("maglevid.api"), name)
        _bind_submodules(fn, name)
        globals()[name] = fn
        return fn
    raise AttributeError(f"module 'maglevid' has no attribute {name!r}")


def _bind_submodules(fn: Any, package: str) -> None:
    """The subpackage's modules as attributes of the function of the same name.

    ``import maglevid.diagnose.pipeline as p`` and ``mock.patch("maglevid.diagnose.
    pipeline.x")`` reach ``pipeline`` as an attribute of ``maglevid.diagnose``,
    which is the function: so the function carries the modules too.
    """
    import pkgutil

    pkg = importlib.import_module(f"{__name__}.{package}")
    for info in pkgutil.iter_modules(pkg.__path__):
        if not hasattr(fn, info.name):
            setattr(fn, info.name, importlib.import_module(f"{pkg.__name__}.{info.name}"))


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_FUNCTIONS))
