"""Diagnosis: comparison with a baseline, fault isolation, history and drift.

The main job in Python is the function :func:`maglevid.diagnose` (defined in
:mod:`maglevid.diagnose.pipeline`); this package holds its stages, imported as
``from maglevid.diagnose.history import open_history`` and the like.
"""

from __future__ import annotations

__all__: list[str] = []
