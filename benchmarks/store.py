"""Each section's latest measurement, kept on its own; BENCHMARKS.md is assembled from them.

``make bench`` measures every section in one run: about 130 minutes of the 2-core
development machine with ``--huge``. A run stopped before its end (a session that ends, a
machine that is needed for something else) lost everything it had measured, and
BENCHMARKS.md went five sessions without a complete run. So every section, the moment its
measurement ends, is written on its own to ``benchmarks/results/<name>.json`` with the
commit, date, command, machine, versions and load it was measured under
(:class:`SectionRun`; written atomically: a crash mid-write leaves the previous file), and
the repository's BENCHMARKS.md is assembled from the latest stored run of every section:

* ``python -m benchmarks.run_all --sections pbsid`` measures one section and rewrites the
  report with it and every other section's stored run;
* ``python -m benchmarks.run_all --assemble`` rewrites the report from the store alone.

What a verdict rests on does not change: each verdict is made from its own section's run,
in which maglevid and the peer it is compared with were measured side by side
(``benchmarks/judge.py``). Where the report mixes runs it says so: its provenance table
gives each section's commit, date and load and the measured code (:data:`MEASURED_CODE`)
changed since that commit, and every heading and verdict of a section measured at another
commit than the report's carries that commit (:func:`section_stamp`).
"""

from __future__ import annotations

import json
import os
import subprocess
import tempfile
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

__all__ = [
    "MEASURED_CODE",
    "RESULTS",
    "SectionRun",
    "changed_since",
    "load_runs",
    "provenance_table",
    "runs_from_json",
    "save_run",
    "section_stamp",
]

ROOT = Path(__file__).resolve().parents[1]
#: Where the repository's stored section runs live (committed with BENCHMARKS.md).
RESULTS = ROOT / "benchmarks" / "results"
#: The paths whose change can move a measurement (``git diff`` pathspecs): the library,
#: the benchmarks (their stored results and their prose excepted) and the dependencies.
MEASURED_CODE = (
    "src",
    "benchmarks",
    "pyproject.toml",
    ":(exclude)benchmarks/results",
    ":(exclude,glob)benchmarks/**/*.md",
)


@dataclass(frozen=True)
class SectionRun:
    """One section's measurement and what it was measured under.

    Attributes
    ----------
    name : str
        The section (``--sections`` name).
    result : dict
        What the section's ``measure`` returned (JSON-able; ``{"error": ...}`` when it
        raised: the latest run of a section that failed is stored too).
    meta : dict
        ``git`` (short commit), ``dirty`` (changed files, empty for a clean tree),
        ``stamp`` (the modified-tree mark, ``""`` when clean), ``command``, ``started``
        (when its ``run_all`` began), ``run_id`` (that invocation's), ``date`` (when the
        section ended), ``elapsed_s``, ``quick``, ``machine``, ``versions``,
        ``load_start``, ``load_end`` (1/5/15-minute load averages), ``blas_threads``,
        ``memory_limit_gb``.
    """

    name: str
    result: dict[str, Any]
    meta: dict[str, Any]

    @property
    def run_key(self) -> tuple[str, str]:
        """Which ``run_all`` invocation measured it: (commit, start time)."""
        when = self.meta.get("run_id") or self.meta.get("started", "?")
        return str(self.meta.get("git", "?")), str(when)


def _json_default(o: Any) -> Any:
    """numpy scalars and arrays, sets and tuples as JSON (the section results hold them)."""
    if hasattr(o, "tolist"):
        return o.tolist()
    if isinstance(o, (set, frozenset)):
        return sorted(o)
    raise TypeError(f"not JSON-serialisable: {type(o).__name__}")


def save_run(run: SectionRun, folder: Path = RESULTS) -> Path:
    """Write ``run`` to ``folder/<name>.json`` atomically; returns the path.

    The text is built and written to a temporary file in the same folder first and moved
    over the old file only once it is complete and on disk: a crash or a result that
    cannot be written leaves the previous run of the section as it was."""
    folder.mkdir(parents=True, exist_ok=True)
    text = json.dumps(
        {"name": run.name, "meta": run.meta, "result": run.result},
        indent=1,
        sort_keys=True,
        default=_json_default,
    )
    path = folder / f"{run.name}.json"
    fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{run.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(text + "\n")
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o644)  # mkstemp's 0600 would hide the results from other users
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def load_runs(
    names: Iterable[str], folder: Path = RESULTS
) -> tuple[dict[str, SectionRun], list[str]]:
    """The stored runs of ``names`` found in ``folder``, and one line per file that could
    not be read (named with its reason; its section counts as not stored)."""
    runs: dict[str, SectionRun] = {}
    problems: list[str] = []
    for name in names:
        path = folder / f"{name}.json"
        if not path.exists():
            continue
        try:
            raw = json.loads(path.read_text())
            runs[name] = SectionRun(name, dict(raw["result"]), dict(raw["meta"]))
        except (OSError, ValueError, KeyError, TypeError) as exc:
            problems.append(f"{path.name}: not readable ({type(exc).__name__}: {exc})"[:200])
    return runs, problems


def changed_since(rev: str, root: Path = ROOT) -> list[str] | None:
    """The measured code's files (:data:`MEASURED_CODE`) that differ between ``rev`` and
    the checked-out commit, or None when git cannot compare them (unknown commit)."""
    try:
        out = subprocess.run(
            ["git", "diff", "--name-only", rev, "HEAD", "--", *MEASURED_CODE],
            capture_output=True,
            text=True,
            cwd=root,
        )
    except OSError:
        return None
    if out.returncode != 0:
        return None
    return [line for line in out.stdout.splitlines() if line.strip()]


def section_stamp(run: SectionRun, head: str) -> str:
    """The mark of a section's heading and verdicts: the modified-tree mark of its run,
    else its commit where that is not the report's ``head``, else nothing."""
    if run.meta.get("stamp"):
        return str(run.meta["stamp"])
    git = str(run.meta.get("git", "?"))
    return "" if git == head else f" [git {git}]"


def _load_text(meta: Mapping[str, Any]) -> str:
    a, b = meta.get("load_start") or (float("nan"),), meta.get("load_end") or (float("nan"),)
    return f"{float(a[0]):.1f} / {float(b[0]):.1f}"


def _changed_text(changed: list[str] | None, git: str, head: str) -> str:
    if git == head:
        return "- (the report's commit)"
    if changed is None:
        return "unknown (commit not in this clone)"
    if not changed:
        return "none"
    shown = ", ".join(f"`{f}`" for f in changed[:4])
    return f"{len(changed)} file(s): {shown}" + (", ..." if len(changed) > 4 else "")


def provenance_table(runs: Mapping[str, SectionRun], head: str, root: Path = ROOT) -> list[str]:
    """Markdown rows: each section's commit, when it was measured, how long, the load at
    its start and end, the CPU, and the measured code changed since its commit."""
    L = [
        "| section | git | measured | min | load start / end | CPU "
        "| measured code changed since |",
        "|---|---|---|---|---|---|---|",
    ]
    cache: dict[str, list[str] | None] = {}
    for name, run in runs.items():
        git = str(run.meta.get("git", "?"))
        if git not in cache:
            cache[git] = None if git == head else changed_since(git, root)
        cpu = (run.meta.get("machine") or {}).get("Model name", "?")
        el = run.meta.get("elapsed_s")
        minutes = "?" if el is None else f"{float(el) / 60:.1f}"
        L.append(
            f"| {name} | {git}{' (modified tree)' if run.meta.get('stamp') else ''}"
            f"{' (--quick)' if run.meta.get('quick') else ''} | "
            f"{run.meta.get('date', '?')} | {minutes}"
            f" | {_load_text(run.meta)} | {cpu} | {_changed_text(cache[git], git, head)} |"
        )
    return L


def runs_from_json(raw: Mapping[str, Any]) -> list[SectionRun]:
    """The section runs of a ``run_all --json`` file.

    This version writes each section's own metadata (``section_meta``); an older file has
    one ``meta`` for the whole run: each of its sections gets that, with its own time
    unknown (``elapsed_s`` None; the run's in ``run_elapsed_s``) and the run's load."""
    meta = dict(raw["meta"])
    own = raw.get("section_meta") or {}
    out = []
    for name, result in raw["results"].items():
        if name in own:
            out.append(SectionRun(name, dict(result), dict(own[name])))
            continue
        legacy = {k: v for k, v in meta.items() if k not in ("absent", "elapsed_s")}
        legacy |= {
            "started": meta.get("date"),
            "elapsed_s": None,
            "run_elapsed_s": meta.get("elapsed_s"),
        }
        out.append(SectionRun(name, dict(result), legacy))
    return out


def main(argv: list[str] | None = None) -> int:
    """``python -m benchmarks.store --import-json FILE``: store a ``run_all --json`` run's
    sections (e.g. one made before the store existed) in ``--store`` (default
    benchmarks/results/); ``run_all --assemble`` then writes the report from them."""
    import argparse

    ap = argparse.ArgumentParser(description=main.__doc__.split(":")[0] if main.__doc__ else "")
    ap.add_argument("--import-json", required=True, help="a run_all --json file")
    ap.add_argument("--store", default=str(RESULTS))
    args = ap.parse_args(argv)
    try:
        raw = json.loads(Path(args.import_json).read_text())
        runs = runs_from_json(raw)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        print(f"benchmarks.store: {args.import_json} is not a run_all --json file ({exc})")
        return 2
    for run in runs:
        print(f"stored {run.name} (git {run.meta.get('git')}): {save_run(run, Path(args.store))}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
