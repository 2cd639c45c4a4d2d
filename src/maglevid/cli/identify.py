"""``maglevid identify RECORDING``: identify a plant from a closed-loop recording."""

from __future__ import annotations

import argparse
import json
from typing import Any

from maglevid.identify.registry import available_methods, get_method

COMMAND = "identify"
HELP = "identify the plant (and its physical parameters) from a recording"
DESCRIPTION = """\
Identify the open-loop plant from a closed-loop recording and print the
discrete and continuous models, the physical parameters with standard errors
and the fit diagnostics (one-step prediction, never an open-loop simulation of
an unstable model).

  maglevid identify rec.npz --method deadbeat-arx --json

Records larger than memory are streamed: a Parquet recording above 256 MB (or
any recording with --stream) is read in chunks of --chunk-size control periods
and identified with memory independent of its length (methods physical, moesp,
n4sid; physical reads the file twice). Without --method such a file gets
method physical. --no-stream always reads the whole file.

  maglevid identify hour.parquet --stream --method physical --option estimator=ls

Before identifying, the recording (a streamed one: its first chunk) goes
through the same quality gate as
`maglevid diagnose` (record length, u = u_f + r, outputs that respond,
excitation, saturation, levitation, the stated controller): a failed check
refuses with the reason; --force identifies anyway and prints the failed
checks as warnings (also in the result's notes).
"""

#: Parquet recordings larger than this are streamed unless --no-stream (about
#: 3e6 samples of a bearing; in memory the physical method needs ~300 B/sample).
STREAM_THRESHOLD_BYTES = 256 * 2**20


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", help="recording file (.npz, .csv + .json, .mat, .parquet)")
    parser.add_argument(
        "--method",
        default=None,
        help="identification method (default: chosen from the recording); "
        "`--method list` shows them",
    )
    parser.add_argument(
        "--mapping",
        default=None,
        help="column mapping for a rig's own log: a preset name (`maglevid convert --presets`) "
        "or a JSON/TOML mapping file",
    )
    parser.add_argument(
        "--option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="method option (VALUE parsed as JSON when possible); repeatable",
    )
    parser.add_argument(
        "--force",
        action="store_true",
        help="identify even when the quality gate fails (its reasons become warnings)",
    )
    parser.add_argument(
        "--stream",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="read the recording in chunks, memory independent of its length (default: "
        f"for Parquet files above {STREAM_THRESHOLD_BYTES // 2**20} MB)",
    )
    parser.add_argument(
        "--chunk-size",
        type=int,
        default=1_000_000,
        metavar="N",
        help="control periods per chunk when streaming (default 1000000)",
    )


def _parse_options(items: list[str]) -> dict[str, Any]:
    from maglevid.exceptions import DataError

    out: dict[str, Any] = {}
    for item in items:
        if "=" not in item:
            raise DataError(f"--option {item!r}: expected KEY=VALUE")
        k, v = item.split("=", 1)
        try:
            out[k] = json.loads(v)
        except json.JSONDecodeError:
            out[k] = v
    return out


def _default_method(data: Any) -> str:
    from maglevid.diagnose.pipeline import choose_method

    return choose_method(data)[0]  # "physical" for AMB recordings (observer-independent)


def _should_stream(args: argparse.Namespace) -> bool:
    if args.stream is not None:
        return bool(args.stream)
    from pathlib import Path

    path = Path(args.recording)
    return path.suffix.lower() == ".parquet" and (
        path.is_file() and path.stat().st_size > STREAM_THRESHOLD_BYTES
    )


def _run_streamed(args: argparse.Namespace, options: dict[str, Any]) -> dict[str, Any]:
    from maglevid.cli._progress import progress
    from maglevid.identify.streaming import STREAMED_METHODS, identify_streamed
    from maglevid.io import iter_recording_chunks

    method = args.method or "physical"
    if method not in STREAMED_METHODS:
        from maglevid.exceptions import DataError

        raise DataError(
            f"method {method!r} cannot be streamed (streamed: "
            f"{', '.join(sorted(STREAMED_METHODS))}); use --no-stream to read the whole file"
        )
    # The quality gate on the first chunk (the whole record when it fits in one).
    first = next(iter_recording_chunks(args.recording, args.chunk_size, mapping=args.mapping))
    warnings = quality_gate(first, force=args.force)
    passes = {"n": 0}

    def chunks() -> Any:
        passes["n"] += 1
        return iter_recording_chunks(args.recording, args.chunk_size, mapping=args.mapping)

    def bar(it: Any) -> Any:
        return progress(it, desc=f"{method}: pass {passes['n']}", args=args)

    result = identify_streamed(chunks, method, progress=bar, **options)
    out = result.to_dict()
    out["recording"] = args.recording
    out["streamed"] = {"chunk_size": args.chunk_size, "passes": passes["n"]}
    return _with_warnings(out, warnings)


def run(args: argparse.Namespace) -> dict[str, Any]:
    if args.method == "list":
        return {"methods": sorted(available_methods())}
    options = _parse_options(args.option)
    if _should_stream(args):
        return _run_streamed(args, options)
    from maglevid.io import read_recording

    data = read_recording(args.recording, mapping=args.mapping)
    method = args.method or _default_method(data)
    fit = get_method(method)  # an unknown method is refused before the gate
    check_options(method, fit, options)
    warnings = quality_gate(data, force=args.force)
    from maglevid.diagnose.levitator import is_levitator, levitator_checks

    if method == "greybox-levitator" and is_levitator(data) and "segments" not in options:
        # A rig log: identify on the segments where the ball levitates under control.
        options["segments"] = levitator_checks(data)[1]
    result = fit(data, **options)
    out = result.to_dict()
    out["recording"] = args.recording
    from maglevid.identify.registry import UNSUPPORTED_POLE_NOTE

    warnings += [n for n in result.notes if n.startswith(UNSUPPORTED_POLE_NOTE)]
    return _with_warnings(out, warnings)


def _with_warnings(out: dict[str, Any], warnings: list[str]) -> dict[str, Any]:
    """The result with ``warnings`` (printed as such) also first among its notes."""
    if warnings:
        out["warnings"] = warnings
        out["notes"] = list(dict.fromkeys([*warnings, *out.get("notes", [])]))
    return out


def check_options(method: str, fit: Any, options: dict[str, Any]) -> None:
    """Refuse an option the method does not take, naming the ones it does (one line).

    The fit function's keyword parameters are its options; calling it with
    another one would be a TypeError (a traceback at the command line).
    """
    import inspect

    from maglevid.exceptions import DataError

    params = inspect.signature(fit).parameters
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return
    known = [n for n, p in params.items() if p.kind is inspect.Parameter.KEYWORD_ONLY]
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise DataError(
            f"method {method!r} has no option {', '.join(map(repr, unknown))}; its options: "
            f"{', '.join(known) or '(none)'}"
        )


def quality_gate(data: Any, *, force: bool) -> list[str]:
    """The checks of ``maglevid diagnose`` before an identification; the failures as text.

    A failed blocking check refuses (:class:`~maglevid.exceptions.DataError`
    naming every reason) unless ``force``; then the reasons are returned as
    warnings. One exception to diagnose's gate: a record without any logged
    excitation r is not refused here, because the methods made for such
    records (the inter-sampled suspension of Sun et al., driven by noise)
    need none, and the methods that do need r refuse it themselves.
    """
    from maglevid.diagnose.checks import check_sample_time, check_units, run_checks
    from maglevid.diagnose.levitator import is_levitator, levitator_checks
    from maglevid.exceptions import DataError

    if is_levitator(data):
        checks = (*levitator_checks(data)[0], check_sample_time(data), check_units(data))
    else:
        checks = run_checks(data)
    failed = [
        q.message
        for q in checks
        if not q.passed and q.blocking and not (q.name == "excitation" and data.r is None)
    ]
    if failed and not force:
        raise DataError(
            "cannot identify from this recording: "
            + "; ".join(failed)
            + " (--force identifies anyway and reports these as warnings)"
        )
    return [f"quality gate failed (identified anyway with --force): {m}" for m in failed]


def format_text(result: dict[str, Any]) -> str:
    if "methods" in result:
        return "methods: " + ", ".join(result["methods"])
    lines = [f"recording: {result['recording']}", f"method: {result['method']}"]
    if result.get("streamed"):
        st = result["streamed"]
        lines.append(f"streamed: chunks of {st['chunk_size']}, {st['passes']} pass(es)")
    lines.append(f"samples: {result['n_samples']}")
    se = result.get("std_errors") or {}
    ci = result.get("ci95") or {}
    lines.append(f"{'parameter':>14} {'estimate':>14} {'std. error':>12}   95 % interval")
    for k, v in result["parameters"].items():
        e = se.get(k)
        lo, hi = ci.get(k) or (None, None)
        band = f"[{lo:.6g}, {hi:.6g}]" if isinstance(lo, float) and isinstance(hi, float) else ""
        lines.append(
            f"{k:>14} {v:>14.6g} {(e if e is not None else float('nan')):>12.3g}   {band}"
        )
    if result.get("poles") is not None:
        p = result["poles"]
        re, im = (p["re"], p["im"]) if isinstance(p, dict) else (p, [0.0] * len(p))
        lines.append("discrete poles: " + ", ".join(f"{a:.6g}{b:+.3g}j" for a, b in zip(re, im)))
    for k, v in (result.get("fit") or {}).items():
        lines.append(f"fit {k}: {v:.6g}")
    warned = set(result.get("warnings", []))
    lines.extend(f"warning: {n}" for n in result.get("warnings", []))
    lines.extend(f"note: {n}" for n in result.get("notes", []) if n not in warned)
    return "\n".join(lines)
