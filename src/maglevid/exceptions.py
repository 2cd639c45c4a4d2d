"""Error and warning classes of maglevid.

One small hierarchy: every error derives from :class:`MaglevidError` and from the
built-in exception it refines, so ``except ValueError`` keeps working for users
who do not know maglevid's classes.
"""

from __future__ import annotations

__all__ = [
    "DataError",
    "DesignError",
    "FileFormatError",
    "IdentificationError",
    "IllConditionedWarning",
    "MaglevidError",
    "MaglevidWarning",
    "ModelError",
]


class MaglevidError(Exception):
    """Base class of every error raised by maglevid."""


class DataError(MaglevidError, ValueError):
    """A signal or recording is unusable: wrong shape, NaN/inf, too short, ..."""


class FileFormatError(DataError):
    """A recording file cannot be read; the message names file, column and problem."""

    def __init__(self, message: str, *, path: str | None = None, column: str | None = None):
        self.path = path
        self.column = column
        prefix = ""
        if path is not None:
            prefix = f"{path}: "
        if column is not None:
            prefix += f"column {column!r}: "
        super().__init__(prefix + message)


class ModelError(MaglevidError, ValueError):
    """A model is ill-posed for the requested operation (e.g. no real matrix logarithm)."""


class DesignError(MaglevidError, ValueError):
    """A controller or observer cannot be designed as asked (e.g. singular loop matrix)."""


class IdentificationError(MaglevidError, RuntimeError):
    """An identification method cannot produce an estimate from the given data."""


class MaglevidWarning(UserWarning):
    """Base class of maglevid's warnings: marginal, not ill-posed, problems."""


class IllConditionedWarning(MaglevidWarning):
    """A computation is numerically marginal; the result is returned but less reliable."""
