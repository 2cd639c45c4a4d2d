"""Fixtures of the file tests (helpers are in ``_io_helpers.py``)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from _io_helpers import write_user_file


@pytest.fixture
def user_file(tmp_path: Path) -> Callable[..., tuple[Path, dict[str, Any]]]:
    """Write a user's own file: ``user_file(fmt, columns, units=..., name=...)``."""

    def make(fmt: str, columns: Any, **kw: Any) -> tuple[Path, dict[str, Any]]:
        return write_user_file(tmp_path, fmt, columns, **kw)

    return make
