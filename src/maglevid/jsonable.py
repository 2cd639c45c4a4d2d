"""JSON conversion, in one place: what every package writes into JSON goes through here.

Three conversions, each with its users:

- :func:`to_jsonable`: results and diagnoses (``IdentificationResult.to_dict``,
  ``Diagnosis.to_dict``). NumPy to Python, NaN to ``None``, +-inf to
  ``"inf"``/``"-inf"``, complex (and complex arrays) to ``{"re", "im"}``, a
  :class:`~maglevid.lti.StateSpace` to its ``to_dict``; anything else unchanged.
- :func:`to_json_checked`: what goes into the history store, where a value
  that is not JSON-like is one clear :class:`~maglevid.exceptions.DataError`
  naming where it sits, and datetimes become ISO text.
- :func:`to_json_nulls`: tables for people and the history's summaries, where
  every non-finite number (NaN and +-inf alike) is ``null``.
- :func:`thaw`: the inverse of the read-only freezing of a recording's
  ``loop`` and ``metadata`` (plain dicts, lists and floats).

Examples
--------
>>> import numpy as np
>>> to_jsonable({"a": np.float64(1.5), "b": float("nan"), "c": np.array([1j])})
{'a': 1.5, 'b': None, 'c': {'re': [0.0], 'im': [1.0]}}
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from datetime import datetime
from typing import Any

import numpy as np

from maglevid.exceptions import DataError
from maglevid.lti import StateSpace

__all__ = ["thaw", "to_json_checked", "to_json_nulls", "to_jsonable"]


def to_jsonable(v: Any) -> Any:
    """JSON-safe copy of a result's values (unknown types pass through unchanged)."""
    if isinstance(v, StateSpace):
        return v.to_dict()
    if isinstance(v, np.ndarray):
        if np.iscomplexobj(v):
            return {"re": v.real.tolist(), "im": v.imag.tolist()}
        return v.tolist()
    if isinstance(v, (np.generic,)):
        return v.item()
    if isinstance(v, complex):
        return {"re": v.real, "im": v.imag}
    if isinstance(v, Mapping):
        return {str(k): to_jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [to_jsonable(x) for x in v]
    if isinstance(v, float) and not np.isfinite(v):
        return None if np.isnan(v) else ("inf" if v > 0 else "-inf")
    return v


def to_json_checked(v: Any, where: str) -> Any:
    """JSON-safe copy: NumPy to Python, NaN to None, +-inf to "inf"/"-inf", complex to re/im.

    Raises
    ------
    DataError
        A value that is not JSON-like, naming ``where`` it sits.
    """
    if isinstance(v, np.ndarray):
        return to_json_checked(v.tolist(), where)
    if isinstance(v, np.generic):
        return to_json_checked(v.item(), where)
    if isinstance(v, float):
        if math.isnan(v):
            return None
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return v
    if v is None or isinstance(v, (bool, int, str)):
        return v
    if isinstance(v, complex):
        return {"re": to_json_checked(v.real, where), "im": to_json_checked(v.imag, where)}
    if isinstance(v, datetime):
        return v.isoformat()
    if isinstance(v, Mapping):
        return {str(k): to_json_checked(x, f"{where}[{k!r}]") for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [to_json_checked(x, f"{where}[{i}]") for i, x in enumerate(v)]
    if hasattr(v, "to_dict"):
        return to_json_checked(v.to_dict(), where)
    raise DataError(f"`{where}` is {type(v).__name__}; expected JSON-like data")


def to_json_nulls(v: Any) -> Any:
    """JSON-safe copy with every non-finite float as ``None``, complex as ``{"re", "im"}``."""
    if isinstance(v, Mapping):
        return {str(k): to_json_nulls(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [to_json_nulls(x) for x in v]
    if isinstance(v, complex):
        return {"re": v.real, "im": v.imag}
    if isinstance(v, np.generic):
        return to_json_nulls(v.item())
    if isinstance(v, float) and not np.isfinite(v):
        return None
    return v


def thaw(value: Any) -> Any:
    """Inverse of a recording's deep freeze, for serialisation: plain dicts, lists and floats."""
    if isinstance(value, Mapping):
        return {k: thaw(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, tuple):
        return [thaw(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value
