"""The plain-function API for notebooks and scripts: ``maglevid.identify``, ``maglevid.diagnose``.

Both are ordinary functions with real signatures (``inspect.signature`` and
``help()`` show their parameters), exported at the top of the package::

    import maglevid
    result = maglevid.identify("rec.npz")                 # IdentificationResult
    diagnosis = maglevid.diagnose("rec.npz", baseline="nominal")

The subpackages of the same names stay importable as before
(``from maglevid.diagnose.history import open_history``,
``from maglevid.identify.arx import fit_arx``); only the attribute
``maglevid.diagnose`` is the function.
"""

from __future__ import annotations

import os
from dataclasses import replace
from typing import Any

from maglevid.data import ClosedLoopData
from maglevid.diagnose.pipeline import diagnose
from maglevid.identify.registry import get_method
from maglevid.identify.result import IdentificationResult
from maglevid.plants import choose_method, infer_kind
from maglevid.plants.amb import identify_options

__all__ = ["diagnose", "identify"]


def identify(
    data: ClosedLoopData | str | os.PathLike[str],
    method: str | None = None,
    *,
    mapping: Any = None,
    **options: Any,
) -> IdentificationResult:
    """Identify the open-loop plant of one closed-loop recording.

    Parameters
    ----------
    data : ClosedLoopData or path
        The recording, or a file :func:`maglevid.io.read_recording` reads
        (``.npz``, ``.csv`` + ``.json``, ``.mat``, ``.parquet``).
    method : str, optional
        A registered method (``maglevid identify --method list`` shows them
        with one line each). Default: the plant kind's method, as
        ``maglevid identify`` chooses it (:func:`maglevid.plants.choose_method`):
        ``"physical"`` for a two-coil bearing, ``"intersample-ml"`` for an
        inter-sampled suspension whose mass and coil resistance the recording
        states (``"intersample"`` without them), ``"levitator"`` for a levitator. (A
        diagnosis of a two-coil bearing uses ``"ml"`` by default, more
        precise at about 10x the time: :func:`maglevid.diagnose`.)
    mapping : dict, str or path-like, optional
        Column mapping for a rig's own log (only with a path).
    **options
        Options of the method (see its docstring), e.g. ``n_lags=30``. On a two-coil
        bearing's record ``"pbsid"`` and ``"ssarx"`` take ``coordinates="physical"``
        unless given (v1..v9 and R, L, ki, kw with covariance, as in a diagnosis; a
        note says so); ``coordinates="identified"`` gives their black-box model.

    Returns
    -------
    IdentificationResult
        Model, parameters with covariance, fit, residuals and notes.

    Raises
    ------
    DataError
        Unknown method or option, or data the method cannot use.
    FileFormatError
        A file that cannot be read.

    Examples
    --------
    >>> import maglevid
    >>> from maglevid.simulate.amb import simulate_amb_recording  # doctest: +SKIP
    >>> result = maglevid.identify(simulate_amb_recording(n_samples=4000))  # doctest: +SKIP
    >>> result.to_dataframe()  # doctest: +SKIP
    """
    if not isinstance(data, ClosedLoopData):
        from maglevid.io import read_recording

        data = read_recording(data, mapping=mapping)
    elif mapping is not None:
        from maglevid.exceptions import DataError

        raise DataError("`mapping` applies to a file path, not to a ClosedLoopData")
    if method is None:
        method = choose_method(data)[0]
    # a bearing's physical parameters from pbsid/ssarx, as `maglevid identify` gives them
    notes: list[str] = []
    options = identify_options(infer_kind(data)[0], method, options, notes)
    result = get_method(method)(data, **options)
    return replace(result, notes=(*notes, *result.notes)) if notes else result
