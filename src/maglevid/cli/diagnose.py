"""``maglevid diagnose RECORDING``: what changed in the bearing, and where."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from maglevid.cli.plan import _limits
from maglevid.exceptions import DataError

COMMAND = "diagnose"
HELP = "diagnose a bearing from a recording: what changed, in which coil, amplifier or sensor"
DESCRIPTION = """\
Identify the bearing's physical parameters from a closed-loop recording and
compare them with a baseline. A change is reported only when it is significant
twice over: outside the combined confidence interval AND larger than the
engineering tolerance. The cause is isolated (coil resistance, shorted turns,
amplifier gain, mass, operating point, sensor gain) and every verdict cites
its numbers. Bad data give "cannot diagnose, because ..." instead of a guess.

  maglevid diagnose rec.npz --baseline nominal --report rec.html
  maglevid diagnose rec.npz --machine B7 --store fleet.sqlite --baseline history
  maglevid diagnose rec.npz --tolerance R1=0.1 --tolerance kw1=0.02 --json
  maglevid diagnose rec.npz --baseline bearing-7.json

--baseline FILE.json is one JSON object of parameter values in SI units,
e.g. the bearing's acceptance test:

  {"m": 1.8, "i0": 0.5, "x0": 0.00035, "R1": 17.5, "R2": 17.5,
   "Ls1": 0.086, "Ls2": 0.086, "K1": 0.00024, "K2": 0.00024, "kw1": 1.0, "kw2": 1.0}

m [kg], i0 [A], x0 [m], R1 R2 [ohm], Ls1 Ls2 [H], K1 K2 = N^2 A mu0 [H*m],
kw1 kw2 [V/V]. With all eleven the fault is isolated (which coil, amplifier,
...); a partial set (e.g. {"R1": 17.5, "kw1": 1.0}) is compared parameter by
parameter without isolation. Values are taken as exact (no standard error).
For an inter-sampled suspension (Sun et al.) the names are pole_rad_s [1/s],
alpha [N/m], eta [N/A], L [H], R [ohm], gap [m], Q [H*m], L_inf [H], e.g.
{"alpha": 1011, "eta": 8.45, "L": 0.872}; compared jointly, without isolation.
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", help="recording file (.npz, .csv + .json, .mat, .parquet)")
    parser.add_argument(
        "--baseline",
        default="nominal",
        help="'nominal' (design values stored in the recording), 'history' (the machine's "
        "latest identification in --store) or a JSON file of AMB parameters in SI units, "
        "format below (default: nominal)",
    )
    parser.add_argument("--machine", default=None, help="machine name (for the history)")
    parser.add_argument(
        "--store",
        default=None,
        help="history store: SQLite file or postgresql:// URL; the diagnosis is recorded there",
    )
    parser.add_argument(
        "--method",
        default=None,
        help="identification method (default: ml for a two-coil bearing, unless the "
        "machine's stored history continues with physical; the plant kind's method "
        "otherwise)",
    )
    parser.add_argument(
        "--tolerance",
        action="append",
        default=[],
        metavar="[NAME=]FRACTION",
        help="engineering tolerance, relative (0.05 = 5 %%); per parameter with NAME=; repeatable",
    )
    parser.add_argument("--mapping", default=None, help="column mapping for a rig's own log")
    parser.add_argument(
        "--report",
        default=None,
        help="write a self-contained HTML report here (never over an input or its side-car)",
    )
    parser.add_argument(
        "--overwrite", action="store_true", help="replace --report if it exists (default: refuse)"
    )
    parser.add_argument(
        "--max-excitation-std",
        type=_limits,
        default=None,
        metavar="V or V1,V2",
        help="amplifier limit [V rms] that the advice of an inconclusive verdict keeps to, one "
        "for both inputs or one per input (e.g. 4,0.5 when coil 2's amplifier has less "
        "headroom) (default: the planner's, as in `maglevid plan`)",
    )
    parser.add_argument(
        "--fail-on-fault",
        action="store_true",
        help="exit code 3 when the verdict is a fault, an unexplained change or a drift, "
        "4 when the recording cannot be diagnosed (a dead sensor must not look healthy)",
    )
    parser.add_argument(
        "--option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="option of the identification method, typed by its declaration as in "
        "`maglevid identify --option` (`maglevid identify --method list` shows them); "
        "repeatable",
    )


def _tolerances(items: list[str]) -> float | dict[str, float] | None:
    if not items:
        return None
    per: dict[str, float] = {}
    default = None
    for item in items:
        name, _, val = item.rpartition("=")
        try:
            f = float(val)
        except ValueError:
            raise DataError(
                f"--tolerance {item!r}: expected [NAME=]FRACTION, e.g. R1=0.05"
            ) from None
        if name:
            per[name] = f
        else:
            default = f
    if default is not None and not per:
        return default
    if default is not None:
        from maglevid.diagnose.pipeline import DIAGNOSED_PARAMETERS

        per = {**dict.fromkeys(DIAGNOSED_PARAMETERS, default), **per}
    return per


def _method_options(args: argparse.Namespace, store: Any) -> dict[str, Any] | None:
    """``--option`` items typed by the method the diagnosis will use (the stated one, or
    the one :func:`~maglevid.diagnose.pipeline.choose_method` picks for this recording),
    exactly as ``identify --option``; an unknown key is one DataError."""
    if not args.option:
        return None
    from maglevid.cli.identify import _check_option_syntax, _typed_options

    _check_option_syntax(args.option)
    method = args.method
    if method is None:
        from maglevid.diagnose.pipeline import choose_method
        from maglevid.io import read_recording

        data = read_recording(args.recording, mapping=args.mapping)
        method = choose_method(data, history=store, machine=args.machine)[0]
    return _typed_options(method, args.option)


def _baseline(text: str) -> Any:
    if text in ("nominal", "history"):
        return text
    path = Path(text)
    if not path.is_file():
        # a misspelt path read as if the option were misused (found from outside,
        # seventeenth session): say which it is
        why = (
            "is a folder, not a file"
            if path.is_dir()
            else "no such file"
            if path.suffix.lower() == ".json" or "/" in text or "\\" in text
            else "is neither 'nominal' nor 'history', nor an existing file"
        )
        raise DataError(
            f"--baseline {text!r}: {why}; expected 'nominal', 'history' or a JSON file of "
            "parameters"
        )
    try:
        values = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise DataError(f"{path}: baseline is not valid JSON ({exc})") from None
    if not isinstance(values, dict):
        raise DataError(f"{path}: baseline must be a JSON object of parameter values")
    return values


def _inputs(args: argparse.Namespace) -> list[str | None]:
    """Every file this command reads: an output must never replace one of them."""
    extra = [args.mapping, args.baseline if args.baseline not in ("nominal", "history") else None]
    return [args.recording, args.store, *(e for e in extra if e and Path(e).is_file())]


def run(args: argparse.Namespace) -> dict[str, Any]:
    if args.report:
        # Refused before the (slow) diagnosis and before anything is stored.
        from maglevid.io import check_output

        check_output(args.report, overwrite=args.overwrite, inputs=_inputs(args))
    store, fresh = None, None
    if args.store is not None:
        from maglevid.diagnose.history import open_history

        fresh = _new_sqlite_file(args.store)
        store = open_history(args.store)
    try:
        return _diagnosed(args, store)
    except BaseException:
        _drop_if_unused(store, fresh)
        raise


def _new_sqlite_file(location: str) -> Path | None:
    """The SQLite file ``--store`` names, if it does not exist yet (else None)."""
    from maglevid.diagnose.history import parse_target

    dialect, target = parse_target(location)
    if dialect != "sqlite" or target == ":memory:":
        return None
    path = Path(target)
    return None if path.exists() else path


def _drop_if_unused(store: Any, fresh: Path | None) -> None:
    """A failed diagnosis leaves no store behind that it created and never wrote to (a
    missing recording left an empty SQLite file: found from outside, issue 16,
    thirteenth session); a store that existed, or holds a machine, is kept."""
    if store is None:
        return
    try:
        unused = fresh is not None and not store.machines()
    finally:
        store.close()
    if unused:
        for suffix in ("", "-wal", "-shm", "-journal"):
            Path(str(fresh) + suffix).unlink(missing_ok=True)


def _diagnosed(args: argparse.Namespace, store: Any) -> dict[str, Any]:
    """The diagnosis, its report, and the result the command prints."""
    from maglevid.cli._progress import stages
    from maglevid.diagnose.pipeline import diagnose

    method_options = _method_options(args, store)
    steps = stages(("diagnosing", "writing the report"), desc="diagnose", args=args)
    next(steps)
    diag = diagnose(
        args.recording,
        baseline=_baseline(args.baseline),
        machine=args.machine,
        method=args.method,
        tolerances=_tolerances(args.tolerance),
        history=store,
        mapping=args.mapping,
        max_excitation_std=args.max_excitation_std,
        method_options=method_options,
    )
    out = diag.to_dict()
    if args.report:
        next(steps)
        from maglevid.report import write_report

        trends = None
        if store is not None and diag.machine:
            from maglevid.diagnose.trend_summary import history_summary
            from maglevid.report import trends_from_history

            hist = history_summary(store, diag.machine, parameters=None, method=diag.method)
            trends = trends_from_history(hist, method=diag.method)
        path = write_report(
            diag, args.report, trends=trends, overwrite=args.overwrite, inputs=_inputs(args)
        )
        out["report"] = str(path)
    steps.close()
    if store is not None:
        store.close()
    if args.fail_on_fault and diag.verdict_code in ("fault", "unexplained_change", "drift"):
        out["exit_code"] = 3
    elif args.fail_on_fault and diag.verdict_code == "cannot_diagnose":
        # a monitoring script could not tell a dead sensor from a healthy bearing by the
        # exit code (0 for both; found from outside, issue 16, thirteenth session)
        out["exit_code"] = 4
    out["summary_text"] = diag.summary()
    return out


def format_text(result: dict[str, Any]) -> str:
    text = result.get("summary_text", result.get("verdict", ""))
    if result.get("report"):
        text += f"\nreport: {result['report']}"
    return text
