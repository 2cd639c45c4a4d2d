"""Diagnosis: comparison with a baseline, fault isolation, history and drift.

``maglevid.diagnose(recording, baseline=...)`` is the main job in Python: this
package is callable, and calling it runs :func:`maglevid.diagnose.pipeline.diagnose`
(the package keeps its submodules, e.g. ``maglevid.diagnose.history``).
"""

from __future__ import annotations

import sys
import types
from typing import Any

__all__ = ["diagnose"]


def diagnose(*args: Any, **kwargs: Any) -> Any:
    """Diagnose one recording; see :func:`maglevid.diagnose.pipeline.diagnose`."""
    from maglevid.diagnose.pipeline import diagnose as _diagnose

    return _diagnose(*args, **kwargs)


class _CallablePackage(types.ModuleType):
    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return diagnose(*args, **kwargs)


sys.modules[__name__].__class__ = _CallablePackage
