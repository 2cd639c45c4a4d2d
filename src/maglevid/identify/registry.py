"""Names of the identification methods, for ``maglevid identify --method NAME``.

A module of :mod:`maglevid.identify` registers methods by defining
``METHODS = {"name": fit_function}``; each function takes a
:class:`~maglevid.data.ClosedLoopData` and keyword options and returns an
:class:`~maglevid.identify.result.IdentificationResult`.

:func:`get_method` returns the method under one contract, the same for every
method (tests/identify/test_method_contract.py runs it on every registered
method and every kind of recording): it either returns a result whose notes
say what is doubtful, or raises one :class:`~maglevid.exceptions.DataError`
naming the reason. A numerical breakdown inside a method (a singular matrix,
an overflow, a model with no continuous counterpart) is such a reason: it
means the data cannot carry the estimate. And an unstable pole is reported
only with a validation that supports it: when the method's own multi-step
predictor fit is worse than the record's mean, the result says so in a note
that starts with :data:`UNSUPPORTED_POLE_NOTE` (the CLI prints it as a warning).

A method's one-line description (``--method list``) is ``DESCRIPTIONS[name]``
where its module defines it, else the first line of the function's docstring.

Every method declares its options once (:mod:`maglevid.identify.options`):
``fit.options`` (the ``@declared`` decorator) or ``OPTIONS[name]`` beside its
module's ``METHODS``. :func:`method_options` returns that declaration, with
the defaults taken from the fit function's signature; :func:`get_method`
validates the keyword options against it (one DataError: unknown option with
the closest name, wrong kind, out of range) before anything else.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Callable, Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from maglevid._plugins import modules_with
from maglevid.exceptions import DataError, MaglevidError
from maglevid.identify.options import Option, bind_defaults, check_options, describe_option
from maglevid.identify.periodic import unmodelled_lines_note

__all__ = [
    "UNSUPPORTED_POLE_NOTE",
    "available_methods",
    "check_unstable_poles",
    "describe_method_options",
    "describe_methods",
    "get_method",
    "method_options",
]

#: How a note on an unstable pole that the validation does not support begins.
UNSUPPORTED_POLE_NOTE = "unsupported unstable pole"

#: Fit keys that measure a multi-step (k > 1) prediction, e.g. "5_step_fit_percent_x".
_MULTI_STEP = re.compile(r"^(?:(\d+)_step|horizon_predictor)_fit_percent")


def available_methods() -> dict[str, Callable[..., Any]]:
    """All registered methods, by name."""
    out: dict[str, Callable[..., Any]] = {}
    for mod in modules_with("maglevid.identify", "METHODS"):
        for name, fn in mod.METHODS.items():
            if name in out:
                raise RuntimeError(f"identification method {name!r} is registered twice")
            out[name] = fn
    return out


def _declarations() -> dict[str, tuple[Option, ...] | None]:
    """Each registered method's declared options (``None``: the method declares none)."""
    out: dict[str, tuple[Option, ...] | None] = {}
    for mod in modules_with("maglevid.identify", "METHODS"):
        declared = getattr(mod, "OPTIONS", {})
        for name, fn in mod.METHODS.items():
            opts = getattr(fn, "options", None)
            if opts is None and name in declared:
                opts = bind_defaults(declared[name], fn)
            out[name] = None if opts is None else tuple(opts)
    return out


def method_options(name: str) -> tuple[Option, ...] | None:
    """The declared options of method ``name`` (defaults filled in), or ``None``.

    ``None`` only for a method that declares none (tests/identify/
    test_method_contract.py refuses such a registration).
    """
    declarations = _declarations()
    if name not in declarations:
        raise DataError(f"unknown method {name!r}; available: {', '.join(sorted(declarations))}")
    return declarations[name]


def describe_method_options() -> dict[str, list[dict[str, Any]]]:
    """Each method's declared options as plain data (``--method list``), by name."""
    return {
        name: [describe_option(o) for o in opts or ()]
        for name, opts in sorted(_declarations().items())
    }


def get_method(name: str) -> Callable[..., Any]:
    """The fit function registered as ``name``, under the contract of this module.

    A clear error lists the valid names. The returned function has the
    method's signature; its keyword options are validated against the
    method's declaration (one DataError naming the option).
    """
    methods = available_methods()
    if name not in methods:
        raise DataError(f"unknown method {name!r}; available: {', '.join(sorted(methods))}")
    return _under_contract(name, methods[name], method_options(name))


def _under_contract(
    name: str, fit: Callable[..., Any], declared: tuple[Option, ...] | None
) -> Callable[..., Any]:
    @functools.wraps(fit)
    def run(data: Any, *args: Any, **options: Any) -> Any:
        if declared is not None:
            check_options(name, declared, options)
        _refuse_constant(name, data)
        _refuse_other_kind(name, data)
        try:
            result = fit(data, *args, **options)
        except DataError:
            raise
        except (MaglevidError, np.linalg.LinAlgError, ArithmeticError) as exc:
            # IdentificationError, ModelError, singular or overflowing numerics:
            # the recording cannot carry this method's estimate.
            text = str(exc)
            prefix = "" if text.startswith(f"{name}:") else f"{name}: "
            raise DataError(f"{prefix}{text or type(exc).__name__}") from exc
        return _note_unmodelled_lines(name, check_unstable_poles(result), data)

    return run


def _note_unmodelled_lines(name: str, result: Any, data: Any) -> Any:
    """``result`` with a note when its residuals carry periodic lines its method does not
    model (:func:`maglevid.identify.periodic.unmodelled_lines_note`); a method that
    models them (``extras["periodic_hz"]``: ``ml``) or a record with inter-samples is
    left alone."""
    extras = getattr(result, "extras", None) or {}
    n, dt = getattr(data, "n_samples", None), getattr(data, "dt", None)
    if (
        "periodic_hz" in extras
        or getattr(data, "p", 1) != 1
        or n is None
        or dt is None
        or not hasattr(result, "notes")
    ):
        return result
    note = unmodelled_lines_note(name, getattr(result, "residuals", None), n, dt)
    return result if note is None else replace(result, notes=(*result.notes, note))


def describe_methods() -> dict[str, str]:
    """One line of description per registered method, by name (sorted)."""
    out: dict[str, str] = {}
    for mod in modules_with("maglevid.identify", "METHODS"):
        described = getattr(mod, "DESCRIPTIONS", {})
        for name, fn in mod.METHODS.items():
            doc = (getattr(fn, "__doc__", None) or "").strip().splitlines()
            out[name] = described.get(name) or (doc[0].replace("``", "") if doc else "")
    return dict(sorted(out.items()))


#: u = u_f + r: the relative rms mismatch beyond which no method is run (0.1 %, as
#: the quality gate's MAX_INPUT_IDENTITY_MISMATCH; logging quantisation fits under it).
MAX_INPUT_IDENTITY_MISMATCH = 1e-3


def _refuse_constant(name: str, data: Any) -> None:
    """Constant outputs or inputs, or u != u_f + r: no method can use such a record."""
    from maglevid.data import ClosedLoopData

    if not isinstance(data, ClosedLoopData):
        return  # the method names what it expects
    mismatch = data.input_identity_mismatch()
    if mismatch is not None and mismatch > MAX_INPUT_IDENTITY_MISMATCH:
        raise DataError(
            f"{name}: u differs from u_f + r by {100 * mismatch:.2g} % rms: the logged plant "
            "input is not the feedback plus the excitation (was r applied? are the channels, "
            "units, signs and time alignment of u, u_f and r the same?)"
        )
    u = data.u if data.u is not None else data.u_f
    for label, sig in (("outputs y", data.y), ("plant inputs u", u)):
        if sig is not None and not np.any(np.ptp(np.asarray(sig), axis=0) > 0):
            raise DataError(
                f"{name}: the {label} are constant over the whole record: there is nothing to "
                "identify (was the loop running, and the right channels logged?)"
            )


#: Methods made for one plant kind only (the others take any recording of their shape).
METHOD_KINDS = {"levitator": ("levitator",), "greybox-levitator": ("levitator",)}


def _refuse_other_kind(name: str, data: Any) -> None:
    """A method made for another plant kind than the recording's: refused, saying which.

    The levitator's grey box on a two-coil bearing record "identified" a 36 rad/s pole
    with the 18 g ball's mass (the bearing's is ~450 rad/s; found from outside, issue
    16, thirteenth session)."""
    from maglevid.data import ClosedLoopData
    from maglevid.plants.base import kind_of

    kinds = METHOD_KINDS.get(name)
    if kinds is None or not isinstance(data, ClosedLoopData):
        return
    kind, why = kind_of(data)
    if kind.name not in kinds:
        raise DataError(
            f"{name}: the method is made for a {' or '.join(kinds)} record; this one is "
            f"{kind.name} ({why}): choose one of the methods `maglevid identify` picks for "
            "it (--method list)"
        )


def check_unstable_poles(result: Any) -> Any:
    """``result``, with a note when its unstable poles are not supported by its validation.

    An unstable pole (|z| > 1) is a strong claim: a bearing is unstable by
    physics, and a method that returns an unstable pole from data that
    cannot carry it (issue 17: a suspension record without excitation, pem
    claiming z = 31.6 with a 5-step fit of -5.4e7 %) must not be read as the
    plant's. The support is the method's multi-step predictor fit: when every
    one it reports is below 0 % (worse than predicting the record's mean),
    the note says so. Methods that report no multi-step fit are unchanged.
    """
    model = getattr(result, "model", None)
    fits: Mapping[str, float] = getattr(result, "fit", None) or {}
    if model is None or not getattr(model, "is_discrete", False):
        return result
    try:
        mags = np.abs(np.linalg.eigvals(np.asarray(model.A, dtype=float)))
    except (np.linalg.LinAlgError, ValueError):
        return result
    unstable = mags[mags > 1.0]
    multi = {k: float(v) for k, v in fits.items() if _MULTI_STEP.match(str(k))}
    multi = {k: v for k, v in multi.items() if np.isfinite(v) or v < 0}
    if not unstable.size or not multi or max(multi.values()) >= 0.0:
        return result
    worst = ", ".join(f"{k} = {v:.3g} %" for k, v in sorted(multi.items()))
    note = (
        f"{UNSUPPORTED_POLE_NOTE}(s) |z| = {', '.join(f'{m:.4g}' for m in sorted(unstable))}: "
        f"the multi-step predictor does not support the model ({worst}, worse than the "
        "record's mean); the data cannot carry this pole, do not read it as the plant's"
    )
    return replace(result, notes=(*result.notes, note))
