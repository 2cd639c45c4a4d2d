"""The sections of ``make bench``: one registry, so a new benchmark plugs in with one line.

A section is three functions (:class:`Section`): ``measure`` runs the
measurements (in worker processes, through the ``Runner`` it receives) and
returns a JSON-able dict; ``report`` turns that dict into Markdown lines of
``BENCHMARKS.md``; ``targets`` (optional) makes the section's verdicts through
the :class:`benchmarks.judge.Judge` it receives: the only way a target enters
the table, so a target with no measurement shows as "not measured".

A benchmark module of its own (``benchmarks/bench_pbsid.py``, ...) defines a
module-level ``SECTION = Section(...)`` and is named once in
``run_all.PLUGINS``; a module that is not on the branch yet is listed in the
report as absent, and the run goes on. See ``benchmarks/README.md``.
"""

from __future__ import annotations

import importlib
import importlib.util
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

__all__ = ["Section", "load_plugin"]


@dataclass(frozen=True)
class Section:
    """One section of the benchmark report.

    Parameters
    ----------
    name : str
        The name ``--sections`` takes.
    measure : callable ``(run, plan, args) -> dict``
        ``run`` is ``run_all.Runner`` (``run.run(task)`` for a built-in worker,
        ``run.call("module:function", **kwargs)`` for any function, each in a
        fresh process); ``plan`` the sizes of this run (``plan["quick"]`` is
        True under ``--quick``); ``args`` the command-line options.
    report : callable ``(result) -> list[str]``
        Markdown lines, starting with the section's ``## `` heading.
    targets : callable ``(result, judge) -> None``, optional
        Verdicts through ``judge.add``/``faster``/``accurate``/``not_measured``.
    """

    name: str
    measure: Callable[..., dict[str, Any]]
    report: Callable[[dict[str, Any]], list[str]]
    targets: Callable[[dict[str, Any], Any], None] | None = None


def load_plugin(module: str) -> Section | None:
    """The ``SECTION`` of ``module``, or None when the module is not on this branch."""
    try:
        if importlib.util.find_spec(module) is None:
            return None
    except ModuleNotFoundError:
        return None
    sec = getattr(importlib.import_module(module), "SECTION", None)
    if not isinstance(sec, Section):
        raise TypeError(f"{module}.SECTION must be a benchmarks.sections.Section")
    return sec
