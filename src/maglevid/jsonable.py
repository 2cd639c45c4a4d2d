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

And one writer, :func:`to_json_text`: the command line's ``--json``. It converts
as :func:`to_jsonable` (objects with a ``to_dict`` through it, anything else as
its text) and then refuses NaN and Infinity, so that what it writes is always
JSON (RFC 8259 has no NaN or Infinity; ``JSON.parse`` and strict parsers reject
them).

Examples
--------
>>> import numpy as np
>>> to_jsonable({"a": np.float64(1.5), "b": float("nan"), "c": np.array([1j])})
{'a': 1.5, 'b': None, 'c': {'re': [0.0], 'im': [1.0]}}
>>> to_json_text({"se": np.array([0.5, np.inf]), "fit": np.nan})
'{"se": [0.5, "inf"], "fit": null}'
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from datetime import datetime
from typing import Any

import numpy as np

from maglevid.exceptions import DataError
from maglevid.lti import StateSpace

__all__ = ["thaw", "to_json_checked", "to_json_nulls", "to_json_text", "to_jsonable"]


def to_jsonable(v: Any) -> Any:
    """JSON-safe copy of a result's values (unknown types pass through unchanged).

    Arrays and NumPy scalars are converted element by element, so a NaN or inf
    inside an array is ``None`` or ``"inf"``/``"-inf"`` like a lone one.
    """
    if isinstance(v, StateSpace):
        return v.to_dict()
    if isinstance(v, np.ndarray):
        if np.iscomplexobj(v):
            return {"re": to_jsonable(v.real.tolist()), "im": to_jsonable(v.imag.tolist())}
        return to_jsonable(v.tolist())
    if isinstance(v, (np.generic,)):
        return to_jsonable(v.item())
    if isinstance(v, complex):
        return {"re": to_jsonable(v.real), "im": to_jsonable(v.imag)}
    if isinstance(v, Mapping):
        return {str(k): to_jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [to_jsonable(x) for x in v]
    if isinstance(v, float) and not np.isfinite(v):
        return None if np.isnan(v) else ("inf" if v > 0 else "-inf")
    return v


def to_json_text(v: Any, *, indent: int | None = None) -> str:
    """``v`` as JSON text that every strict parser reads: no NaN, no Infinity.

    Values are converted by :func:`to_jsonable` (NaN to ``null``, +-inf to
    ``"inf"``/``"-inf"``, complex to ``{"re", "im"}``); an object with a
    ``to_dict`` is written as its dictionary, converted the same way, and any
    other object as its text.

    Raises
    ------
    ValueError
        Never for the values above: the conversion leaves no NaN or inf, and
        ``allow_nan=False`` makes a regression an error rather than invalid JSON.
    """
    return json.dumps(to_jsonable(v), default=_jsonable_default, indent=indent, allow_nan=False)


def _jsonable_default(o: Any) -> Any:
    """What :func:`json.dumps` cannot write by itself: a ``to_dict``, else the text."""
    if hasattr(o, "to_dict"):
        return to_jsonable(o.to_dict())
    return str(o)


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
