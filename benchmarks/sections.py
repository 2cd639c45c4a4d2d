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

__all__ = ["Section", "load_plugin", "records_main"]


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
    """The ``SECTION`` of ``module``, or None when the module is not on this branch.

    A module without ``SECTION`` but with a ``main(argv)`` that prints Markdown
    (the older benchmark scripts) becomes a section that runs ``main`` in a
    worker process (``["--quick"]`` under ``--quick`` when it takes it) and
    prints what it printed; it has no targets until it defines its own.
    """
    try:
        if importlib.util.find_spec(module) is None:
            return None
    except ModuleNotFoundError:
        return None
    mod = importlib.import_module(module)
    sec = getattr(mod, "SECTION", None)
    if sec is None and callable(getattr(mod, "main", None)):
        return _main_section(module)
    if not isinstance(sec, Section):
        raise TypeError(f"{module}.SECTION must be a benchmarks.sections.Section")
    return sec


def run_main(module: str, quick: bool = False) -> dict[str, Any]:
    """Run ``module.main(argv)`` and return what it printed (a worker's job)."""
    import contextlib
    import io

    main = importlib.import_module(module).main
    for argv in [["--quick"], []] if quick else [[]]:
        buf = io.StringIO()
        try:
            with contextlib.redirect_stdout(buf):
                main(argv)
        except SystemExit as exc:
            if exc.code == 2 and argv:  # argparse: --quick not known; run it plain
                continue
            if exc.code not in (0, None):
                raise RuntimeError(f"{module}.main exited with {exc.code}") from None
        return {"markdown": buf.getvalue(), "argv": argv}
    return {"error": f"{module}.main did not run"}  # pragma: no cover


def _main_section(module: str) -> Section:
    name = module.rsplit(".", 1)[-1].removeprefix("bench_")

    # A module may state the time its whole run needs (``TIMEOUT_S``), when that is
    # more than run_all's per-task limit.
    timeout = getattr(importlib.import_module(module), "TIMEOUT_S", None)

    def measure(run: Any, plan: dict[str, Any], args: Any) -> dict[str, Any]:
        limit = None if timeout is None else max(timeout, args.timeout)
        return run.call("benchmarks.sections:run_main", limit, module=module, quick=plan["quick"])

    def report(res: dict[str, Any]) -> list[str]:
        head = f"## `{module}` (its own output, `main({res.get('argv', [])})`)"
        if "markdown" not in res:
            return [head, "", f"failed: {res.get('error')}"]
        return [head, "", res["markdown"].strip()]

    return Section(name, measure, report)


def records_main(
    argv: list[str] | None,
    *,
    doc: str,
    run: Callable[[int, int], dict[str, Any]],
    report: Callable[[dict[str, Any]], list[str]],
    records: int,
) -> int:
    """The command line of a Monte Carlo section (``--records``, ``--workers``,
    ``--json``): ``run(records, workers)``, its Markdown on stdout, the wall time on
    stderr."""
    import argparse
    import json
    import sys
    import time

    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--records", type=int, default=records)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", help="write the raw result here")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    result = run(args.records, args.workers)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(result, fh, indent=1)
    print("\n".join(report(result)))
    print(f"\n({time.perf_counter() - t0:.0f} s wall)", file=sys.stderr)
    return 0
