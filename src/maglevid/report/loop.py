"""The closed loop seen by the report; the code lives in :mod:`maglevid.control.feedback`.

Kept so that ``from maglevid.report.loop import close_loop`` still works: the
identification's ``compare`` (below the report) needs the same loop.
"""

from __future__ import annotations

from maglevid.control.feedback import close_loop, controller_state_space

__all__ = ["close_loop", "controller_state_space"]
