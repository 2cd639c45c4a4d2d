"""Identification methods. Every ``fit_*`` returns an :class:`IdentificationResult`."""

from maglevid.identify.result import IdentificationResult

__all__ = ["IdentificationResult"]
