"""The options of an identification method, declared once (issue 19, the method contract).

A registered method declares each keyword option as an :class:`Option`: its
name, kind, default, allowed values or range, unit and a one-line doc. From
that one declaration come

* the validation of keyword options (:func:`check_options`): an unknown name
  (with the closest known name suggested), a value of the wrong kind, outside
  its range or not among its choices gives ONE :class:`~maglevid.exceptions.DataError`
  naming the method, the option and what it takes;
* the ``--method list`` descriptions (:func:`describe_option`);
* the command line's ``--option name=value`` (:func:`parse_cli_options`), typed
  by the declared kind (``na=3`` is the integer 3, ``intercept=false`` the
  boolean, ``output=y:0`` the channel text).

A method declares its options in one of two ways, both read by
:mod:`maglevid.identify.registry`:

* ``@declared(Option(...), ...)`` on the fit function: every call, direct or
  through the registry, is validated, and the declaration is ``fit.options``;
* ``OPTIONS = {"name": (Option(...), ...)}`` beside the module's ``METHODS``
  (validated when the method is called through the registry and the CLI).

A default left out of an :class:`Option` is the fit function's own keyword
default (so it is written once, in the signature); a function that takes
``**options`` states its defaults in the declaration.
"""

from __future__ import annotations

import difflib
import functools
import inspect
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from maglevid.exceptions import DataError

__all__ = [
    "AMB_OPTIONS",
    "KINDS",
    "SIGNATURE_DEFAULT",
    "Option",
    "UnknownOptionError",
    "bind_defaults",
    "check_options",
    "declared",
    "describe_option",
    "options_doc",
    "parse_cli_options",
]


class UnknownOptionError(DataError, TypeError):
    """A keyword option the method does not declare: a :class:`DataError` (one line at
    the command line) and, as Python says of an unexpected keyword, a ``TypeError``."""


class _SignatureDefault:
    def __repr__(self) -> str:
        return "<the fit function's default>"


#: Marker: the default is the fit function's keyword default.
SIGNATURE_DEFAULT: Any = _SignatureDefault()

#: The kinds an option may have, with what a value of that kind is (for messages).
KINDS: Mapping[str, str] = {
    "int": "an integer",
    "float": "a number",
    "bool": "true or false",
    "str": "a text",
    "channel": "a channel such as 'y:0'",
    "channels": "a list of channels such as ['y:0', 'y:1']",
    "segments": "a list of [start, stop] sample ranges",
    "strs": "a list of texts",
    "bools": "a list of true/false",
    "floats": "a list of numbers (or null)",
    "object": "a value (see the option's doc)",
}

_LISTS = {"channels": "channel", "strs": "str", "bools": "bool", "floats": "float"}


@dataclass(frozen=True)
class Option:
    """One keyword option of an identification method.

    Parameters
    ----------
    name : str
        The keyword.
    kind : str
        One of :data:`KINDS`; ``"object"`` for values only the method can check
        (a controller model, starting parameters).
    doc : str
        One line: what the option does.
    default : Any
        Default value; :data:`SIGNATURE_DEFAULT` takes the fit function's.
    choices : tuple, optional
        The allowed values (for a list kind: of each element).
    low, high : float, optional
        Inclusive range of a number (for ``"floats"``: of each element);
        ``low_open`` makes the lower bound exclusive (``> low``).
    unit : str
        SI unit of a physical value ("" when none).
    optional : bool, optional
        ``None`` is allowed (default: when the default is ``None``).
    """

    name: str
    kind: str
    doc: str
    default: Any = SIGNATURE_DEFAULT
    choices: tuple[Any, ...] | None = None
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    unit: str = ""
    optional: bool | None = None

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"option {self.name!r}: unknown kind {self.kind!r}")
        if not self.doc.strip() or "\n" in self.doc:
            raise ValueError(f"option {self.name!r}: the doc is one non-empty line")

    @property
    def allows_none(self) -> bool:
        return self.default is None if self.optional is None else self.optional

    def expectation(self) -> str:
        """What a value must be, in words ("an integer >= 1 or None")."""
        text = KINDS[self.kind]
        if self.choices is not None:
            text = "one of " + ", ".join(map(repr, self.choices))
            if self.kind in _LISTS:
                text = f"a list of {text}"
        bounds = []
        if self.low is not None:
            bounds.append(f"{'>' if self.low_open else '>='} {self.low:g}")
        if self.high is not None:
            bounds.append(f"<= {self.high:g}")
        if bounds:
            text += " " + " and ".join(bounds)
        return text + (" or None" if self.allows_none else "")

    def check(self, value: Any) -> None:
        """``None`` if ``value`` is valid, else ValueError with the expectation."""
        if value is None and self.allows_none:
            return
        if self.kind in _LISTS or self.kind == "segments":
            if isinstance(value, (str, bytes, Mapping)) or not isinstance(
                value, (Sequence, np.ndarray)
            ):
                raise ValueError
            if self.kind == "segments":
                for seg in value:
                    if len(seg) != 2 or not all(_is_int(v) for v in seg):
                        raise ValueError
                return
            one = replace(self, kind=_LISTS[self.kind], optional=self.kind == "floats")
            for v in value:
                one.check(v)
            return
        if not _KIND_CHECKS[self.kind](value):
            raise ValueError
        if self.choices is not None and value not in self.choices:
            raise ValueError
        if self.kind in ("int", "float"):
            low_bad = self.low is not None and (
                value <= self.low if self.low_open else value < self.low
            )
            if low_bad or (self.high is not None and value > self.high):
                raise ValueError

    def parse(self, text: str) -> Any:
        """The value of ``--option name=text``, typed by the kind (ValueError if not)."""
        if self.allows_none and text.strip().lower() in ("none", "null"):
            return None
        kind = self.kind
        if kind == "int":
            return int(text.strip())  # "3.5" and "three" are ValueErrors
        if kind == "float":
            return float(text.strip())
        if kind == "bool":
            low = text.strip().lower()
            if low in ("true", "1", "yes", "on"):
                return True
            if low in ("false", "0", "no", "off"):
                return False
            raise ValueError
        if kind in ("str", "channel"):
            return text
        if kind in ("bools", "floats"):  # false,true or 0.1,0.2 (or JSON)
            item = Option(self.name, _LISTS[kind], self.doc)
            parts = text.strip().strip("[]").split(",")
            return [item.parse(t) for t in parts if t.strip()]
        try:
            return json.loads(text)
        except json.JSONDecodeError:
            if kind in ("channels", "strs"):  # y:0,y:1
                return [t.strip() for t in text.split(",") if t.strip()]
            if kind == "object":
                return text
            raise ValueError from None


#: Options shared by the two-coil AMB methods (physical, deadbeat, okid-era, ml and
#: the streamed physical fit), declared once; each method's default is its own.
AMB_OPTIONS: Mapping[str, Option] = {
    o.name: o
    for o in (
        Option("estimator", "str", "'iv': instrumental variables from r (consistent under "
               "sensor noise); 'ls': least squares (biased by it)", choices=("ls", "iv")),
        Option("instruments", "str", "IV instruments: the nominal loop's noise-free response "
               "to r ('loop'), lags of r ('lags'); 'auto': 'loop' when the loop is recorded",
               choices=("auto", "loop", "lags")),
        Option("skip", "int", "samples dropped at the start (observer transient)", low=0),
        Option("instrument_lags", "int", "lags of r for instruments='lags'", low=1),
        Option("covariance", "str", "'white-noise': the equation error written exactly in "
               "the sensor noise; 'hac': a lag-window estimate",
               choices=("white-noise", "hac")),
        Option("hac_lags", "int", "lag window for covariance='hac'", low=0),
        Option("m", "float", "rotor mass (default: data.loop['operating_point'])",
               low=0, low_open=True, unit="kg"),
        Option("i0", "float", "bias current (default: data.loop['operating_point'])",
               low=0, low_open=True, unit="A"),
    )
}  # fmt: skip


def _is_int(v: Any) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


def _is_number(v: Any) -> bool:
    return (
        isinstance(v, (int, float, np.integer, np.floating))
        and not isinstance(v, (bool, np.bool_))
        and math.isfinite(float(v))
    )


_KIND_CHECKS: Mapping[str, Callable[[Any], bool]] = {
    "int": _is_int,
    "float": _is_number,
    "bool": lambda v: isinstance(v, (bool, np.bool_)),
    "str": lambda v: isinstance(v, str),
    "channel": lambda v: isinstance(v, str),
    "object": lambda v: True,
}


def bind_defaults(options: Sequence[Option], fit: Callable[..., Any]) -> tuple[Option, ...]:
    """``options`` with each :data:`SIGNATURE_DEFAULT` replaced by ``fit``'s default.

    A default given in the declaration wins: a wrapper that supplies the
    value itself (``dt`` from the recording) declares what the user sees.

    Raises
    ------
    TypeError
        A declared option the signature lacks (unless ``fit`` takes
        ``**options``) or a keyword of the signature left undeclared: the
        declaration and the function name the same options (a programming
        error, found at import).
    """
    params = inspect.signature(fit).parameters
    var_kw = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values())
    keywords = {n: p for n, p in params.items() if p.kind is inspect.Parameter.KEYWORD_ONLY}
    names = [o.name for o in options]
    where = getattr(fit, "__qualname__", repr(fit))
    if len(set(names)) != len(names):
        raise TypeError(f"{where}: an option is declared twice: {names}")
    undeclared = sorted(set(keywords) - set(names))
    missing = sorted(set(names) - set(keywords)) if not var_kw else []
    if undeclared or missing:
        raise TypeError(f"{where}: undeclared keywords {undeclared}, unknown options {missing}")
    out = []
    for opt in options:
        param = keywords.get(opt.name)
        if opt.default is SIGNATURE_DEFAULT:
            if param is None or param.default is inspect.Parameter.empty:
                raise TypeError(f"{where}: option {opt.name!r} needs a declared default")
            opt = replace(opt, default=param.default)
        out.append(opt)
    return tuple(out)


def check_options(
    method: str, declared_options: Sequence[Option], options: Mapping[str, Any]
) -> None:
    """Validate keyword ``options`` of ``method`` against its declaration.

    Raises
    ------
    UnknownOptionError
        An option the method does not declare (with the closest known name).
    DataError
        One line: the option whose value is not what it takes.
    """
    by_name = {o.name: o for o in declared_options}
    for name, value in options.items():
        opt = by_name.get(name)
        if opt is None:
            close = difflib.get_close_matches(name, list(by_name), n=1, cutoff=0.6)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise UnknownOptionError(
                f"method {method!r} has no option {name!r}{hint}; its options: "
                f"{', '.join(by_name) or '(none)'}"
            )
        try:
            opt.check(value)
        except (ValueError, TypeError):
            raise DataError(
                f"{method}: `{name}` must be {opt.expectation()}; got {value!r}"
            ) from None


def parse_cli_options(
    method: str, declared_options: Sequence[Option], items: Sequence[str]
) -> dict[str, Any]:
    """``--option KEY=VALUE`` items as typed keyword options of ``method``, validated.

    Raises
    ------
    DataError
        An item without ``=``, an unknown option, or a value that is not of
        the option's kind (one line, naming what the option takes).
    """
    by_name = {o.name: o for o in declared_options}
    out: dict[str, Any] = {}
    for item in items:
        if "=" not in item:
            raise DataError(f"--option {item!r}: expected KEY=VALUE")
        key, text = item.split("=", 1)
        opt = by_name.get(key)
        if opt is None:
            check_options(method, declared_options, {key: text})  # the unknown-name error
            continue  # pragma: no cover - check_options raised
        try:
            out[key] = opt.parse(text)
        except ValueError:
            raise DataError(
                f"--option {item!r}: method {method!r} takes {opt.expectation()} for `{key}`"
            ) from None
    check_options(method, declared_options, out)
    return out


def describe_option(opt: Option) -> dict[str, Any]:
    """The declaration as plain data (``--method list --json``)."""
    out: dict[str, Any] = {"name": opt.name, "kind": opt.kind, "doc": opt.doc}
    default = opt.default
    out["default"] = list(default) if isinstance(default, tuple) else default
    if not isinstance(out["default"], (type(None), bool, int, float, str, list)):
        out["default"] = repr(default)
    if opt.choices is not None:
        out["choices"] = list(opt.choices)
    if opt.low is not None or opt.high is not None:
        out["range"] = [opt.low, opt.high]
        if opt.low_open:
            out["low_open"] = True
    if opt.unit:
        out["unit"] = opt.unit
    return out


def options_doc(options: Sequence[Option]) -> str:
    """The declaration as a numpydoc ``Options`` section (appended to the fit's docstring)."""
    lines = ["Options", "-------"]
    for o in options:
        head = f"{o.name} : {o.kind}, default {o.default!r}"
        if o.unit:
            head += f" [{o.unit}]"
        lines += [head, f"    {o.doc}; {o.expectation()}."]
    return "\n".join(lines)


def declared(*options: Option) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Decorator: ``fit`` takes the declared ``options``, validated on every call.

    The bound declaration (defaults from the signature) is ``fit.options``;
    the registry reads it. The method's name in messages is the function's.
    """

    def wrap(fit: Callable[..., Any]) -> Callable[..., Any]:
        bound = bind_defaults(options, fit)
        label = fit.__name__

        @functools.wraps(fit)
        def run(data: Any, *args: Any, **kwargs: Any) -> Any:
            check_options(label, bound, kwargs)
            return fit(data, *args, **kwargs)

        run.options = bound  # type: ignore[attr-defined]
        run.__doc__ = inspect.cleandoc(fit.__doc__ or "") + "\n\n" + options_doc(bound)
        return run

    return wrap
