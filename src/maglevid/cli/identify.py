"""``maglevid identify RECORDING``: identify a plant from a closed-loop recording."""

from __future__ import annotations

import argparse
import json
from typing import Any

from maglevid.exceptions import DataError
from maglevid.identify.options import parse_cli_options
from maglevid.identify.registry import (
    describe_method_options,
    describe_methods,
    get_method,
    method_options,
)

COMMAND = "identify"
HELP = "identify the plant (and its physical parameters) from a recording"
DESCRIPTION = """\
Identify the open-loop plant from a closed-loop recording and print the
discrete and continuous models, the physical parameters with standard errors
and the fit diagnostics (one-step prediction, never an open-loop simulation of
an unstable model).

  maglevid identify rec.npz --method deadbeat-arx --json

Without --method the method follows from the plant kind (two-coil AMB,
inter-sampled suspension, one-coil levitator, generic MIMO; stated in the
recording or inferred), and the choice and its reason are printed. Several
recordings of one rig are identified together and one by one:

  maglevid identify A.txt B.txt C.txt --mapping uaq-levitador

On a two-coil bearing's record, pbsid and ssarx report its physical parameters
(coordinates=physical, as in `maglevid diagnose`; a note says so):
--option coordinates=identified gives their black-box model instead.

Records larger than memory are streamed: a Parquet recording above 256 MB (or
any recording with --stream) is read in chunks of --chunk-size control periods
and identified with memory independent of its length (methods physical, moesp,
n4sid, pbsid, ssarx; physical reads the file twice). Without --method such a
file gets its kind's method as in memory (from its first chunk); a bearing
record without its loop's controller and observer, whose method in memory (ml)
has no streamed form, gets pbsid in physical coordinates. --no-stream always
reads the whole file.

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
    parser.add_argument(
        "recording",
        nargs="*",
        help="recording file (.npz, .csv + .json, .mat, .parquet); several sessions of one "
        "one-coil levitator rig give one answer and the per-session ones (other plants: "
        "one recording at a time; none with `--method list`)",
    )
    # `--method list` needs no recording, every other use at least one: checked in run(),
    # as argparse would (usage on stderr, exit code 2).
    parser.set_defaults(_identify_parser=parser)
    parser.add_argument(
        "--recover-excitation",
        action="store_true",
        help="the recording has no excitation r: recover the dither from the controller law "
        "(stated in loop['controller_law'] or fitted); automatic for two-stage and indirect",
    )
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
        help="method option, typed by the method's declaration (`--method list` shows each "
        "method's options, kinds, defaults and ranges); repeatable",
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


def _check_option_syntax(items: list[str]) -> None:
    """Every ``--option`` is ``KEY=VALUE`` (checked before the recording is read)."""
    for item in items:
        if "=" not in item:
            raise DataError(f"--option {item!r}: expected KEY=VALUE")


def _typed_options(method: str, items: list[str]) -> dict[str, Any]:
    """``--option`` items as ``method``'s keyword options, typed and validated by its
    declaration (:mod:`maglevid.identify.options`); one DataError otherwise."""
    declared = method_options(method)
    if declared is not None:
        return parse_cli_options(method, declared, items)
    out: dict[str, Any] = {}  # a method without a declaration: JSON when possible
    for item in items:
        k, v = item.split("=", 1)
        try:
            out[k] = json.loads(v)
        except json.JSONDecodeError:
            out[k] = v
    return out


#: Methods that need an excitation r (recovered from the controller when not logged).
NEEDS_EXCITATION = ("two-stage", "indirect")


def _should_stream(args: argparse.Namespace) -> bool:
    if args.stream is not None:
        return bool(args.stream)
    from pathlib import Path

    path = Path(args.recording[0])
    return path.suffix.lower() == ".parquet" and (
        path.is_file() and path.stat().st_size > STREAM_THRESHOLD_BYTES
    )


def _run_streamed(args: argparse.Namespace) -> dict[str, Any]:
    from maglevid.cli._progress import progress
    from maglevid.identify.streaming import STREAMED_METHODS, identify_streamed
    from maglevid.io import iter_recording_chunks

    if len(args.recording) > 1:
        from maglevid.exceptions import DataError

        raise DataError("several recordings cannot be streamed; use --no-stream")
    args.recording = args.recording[0]
    # The quality gate on the record's first MIN_SAMPLES control periods at least (the
    # whole record when shorter): a first chunk of 10 was refused as "too short".
    from maglevid.diagnose.checks import MIN_SAMPLES

    head = max(args.chunk_size, MIN_SAMPLES)
    first = next(iter_recording_chunks(args.recording, head, mapping=args.mapping))
    if args.method is None:
        method, reason, defaults = _streamed_default(first)
    else:
        method, reason, defaults = args.method, "chosen by the user", {}
    if method not in STREAMED_METHODS:
        from maglevid.exceptions import DataError

        raise DataError(
            f"method {method!r} cannot be streamed (streamed: "
            f"{', '.join(sorted(STREAMED_METHODS))}); use --no-stream to read the whole file"
        )
    from maglevid.plants import infer_kind
    from maglevid.plants.amb import identify_options

    notes: list[str] = []
    options = identify_options(
        infer_kind(first)[0], method, {**defaults, **_typed_options(method, args.option)}, notes
    )
    warnings = quality_gate(first, force=args.force)
    passes = {"n": 0}

    def chunks() -> Any:
        passes["n"] += 1
        return iter_recording_chunks(args.recording, args.chunk_size, mapping=args.mapping)

    def bar(it: Any) -> Any:
        return progress(it, desc=f"{method}: pass {passes['n']}", args=args)

    result = identify_streamed(chunks, method, progress=bar, **options)
    if method in ("pbsid", "ssarx"):  # R, L, ki, kw from v1..v9 where m and i0 are stated
        from maglevid.identify.uncertainty import operating_point, with_physical_parameters

        result = with_physical_parameters(result, *operating_point(first.loop or {}))
    out = result.to_dict()
    out["recording"] = args.recording
    out["method_reason"] = reason
    out["streamed"] = {"chunk_size": args.chunk_size, "passes": passes["n"]}
    out["notes"] = notes + out["notes"]
    # the gate saw the first chunk only: what the whole record's numbers say (a record
    # in mA from its middle on printed R1 = -2.1e-5 ohm without a word; found from
    # outside, seventeenth session)
    return _with_warnings(out, warnings + _result_warnings(result, infer_kind(first)[0]))


def _streamed_default(first: Any) -> tuple[str, str, dict[str, Any]]:
    """``(method, why, default options)`` of a streamed record, from its first chunk: the
    plant kind's method where it has a streamed form; on a bearing whose loop is not
    recorded (``ml``, which has none) PBSID-opt in physical coordinates, consistent
    under feedback without the loop (its instruments would be lags of ``r`` in
    ``physical``: biased on the bearing, issue 16, fourteenth session)."""
    from maglevid.identify.streaming import STREAMED_METHODS
    from maglevid.plants import choose_method, infer_kind

    method, reason = choose_method(first)
    if method in STREAMED_METHODS:
        return method, reason, {}
    if infer_kind(first)[0] == "amb-two-coil":
        return (
            "pbsid",
            (
                f"{method} (the choice for this record in memory) has no streamed form, so "
                "PBSID-opt in physical coordinates: consistent under feedback without the "
                "loop's controller and observer, which this record does not carry"
            ),
            {"coordinates": "physical"},
        )
    from maglevid.exceptions import DataError

    raise DataError(
        f"this record's method {method!r} cannot be streamed (streamed: "
        f"{', '.join(sorted(STREAMED_METHODS))}); pass --method, or --no-stream"
    )


def run(args: argparse.Namespace) -> dict[str, Any]:
    if args.method == "list":
        described = describe_methods()
        return {
            "methods": list(described),
            "descriptions": described,
            "options": describe_method_options(),
        }
    if not args.recording:
        args._identify_parser.error(
            "the following arguments are required: recording (only `--method list` needs none)"
        )
    _check_option_syntax(args.option)
    if _should_stream(args):
        return _run_streamed(args)
    if len(args.recording) > 1:
        return _run_sessions(args)
    return _run_one(args.recording[0], args)


def _run_one(path: str, args: argparse.Namespace) -> dict[str, Any]:
    from maglevid.cli._progress import stages
    from maglevid.io import read_recording
    from maglevid.plants import choose_method, infer_kind
    from maglevid.plants.amb import identify_options

    steps = stages(("reading", "identifying"), desc="identify", args=args)
    next(steps)
    data = read_recording(path, mapping=args.mapping)
    kind, kind_reason = infer_kind(data)
    method, reason = choose_method(data)
    if args.method is not None and args.method != method:
        method, reason = args.method, "chosen by the user"
    options = _typed_options(method, args.option)  # an unknown method is refused here
    notes: list[str] = []
    options = identify_options(kind, method, options, notes)
    if data.r is None and (args.recover_excitation or method in NEEDS_EXCITATION):
        data, recovered = _recover(data, method, options)
        notes += recovered
    if kind == "levitator" and "segments" not in options and method != "levitator":
        data, note = _levitating(data, method, options)
        notes += [note] if note else []
    fit = get_method(method)
    try:
        warnings = quality_gate(data, force=args.force)
    except DataError as exc:
        why = _unidentifiable(data) if kind == "mimo" else None
        if why is None:
            raise
        msg = f"{exc}; and even with --force: the record cannot give the plant: {why}"
        raise DataError(msg) from exc
    next(steps)
    result = fit(data, **options)
    steps.close()
    out = result.to_dict()
    if result.extras.get("B_intersample") is not None:
        out["intersample_numerators"] = _intersample_numerators(result.extras)
    out.update(recording=path, plant_kind=kind, plant_kind_reason=kind_reason,
               method_reason=reason, units=_units(kind, result))  # fmt: skip
    if kind == "mimo":
        why = _unidentifiable(data)
        if why is not None:
            out["plant_identifiable"] = False
            notes.append("the poles above are of a model of the closed-loop data, not the "
                         f"plant's: {why}")  # fmt: skip
    out["notes"] = notes + out["notes"]
    if "consensus" in result.extras:
        _add_consensus(out, result)
    from maglevid.identify.registry import UNSUPPORTED_POLE_NOTE

    warnings += [n for n in result.notes if n.startswith(UNSUPPORTED_POLE_NOTE)]
    return _with_warnings(out, warnings + _result_warnings(result, kind))


def _units(kind: str, result: Any) -> dict[str, str]:
    """SI unit of each parameter of ``result`` that has one
    (:func:`maglevid.plants.base.parameter_units`; the text table had no unit column:
    found from outside, issue 16, fourteenth session)."""
    from maglevid.plants.base import parameter_units

    return parameter_units(kind, result)


def _result_warnings(result: Any, kind: str) -> list[str]:
    """What the result's numbers say about the record, as warnings (printed beside the
    table, not only as notes): a fit that did not converge, and a bearing's parameters
    no magnetic bearing has, or with a sign eq. (4) does not allow
    (:func:`maglevid.plants.amb.implausible_parameters`)."""
    from maglevid.plants.amb import KIND, implausible_parameters

    out = []
    if (result.extras or {}).get("converged") is False:
        out.append(
            f"the {result.method} fit did not converge: its estimates are not an optimum and "
            "their intervals mean nothing"
        )
    if kind == KIND.name:
        out += implausible_parameters(result.parameters)
    return out


def _unidentifiable(data: Any) -> str | None:
    from maglevid.plants import unidentifiable_reason

    return unidentifiable_reason(data)


def _add_consensus(out: dict[str, Any], result: Any) -> None:
    """The levitator's consensus, its candidates and excluded pieces, JSON-safe as the
    rest of the result (NaN -> None, +-inf -> "inf"/"-inf": :mod:`maglevid.jsonable`)."""
    from maglevid.jsonable import to_jsonable

    for key in ("consensus", "candidates", "segments_excluded"):
        out[key] = to_jsonable(result.extras[key])
    out["ci95"]["pole_rad_s"] = to_jsonable(list(result.extras["consensus"]["ci95"]))


def _recover(data: Any, method: str, options: dict[str, Any]) -> tuple[Any, list[str]]:
    """The dither recovered from the controller law (no r logged)."""
    from maglevid.identify.excitation import recover_excitation

    data, rep = recover_excitation(data)
    if method == "indirect":
        options.setdefault("controller", data.loop["controller"])
        options.setdefault("controller_inputs", list(data.loop["controller_inputs"]))
    note = (
        f"no excitation r logged: recovered from the controller law ({rep['source']}"
        + (f", R^2 = {rep['r_squared']:.4f}" if "r_squared" in rep else "")
        + f"; dither rms {rep['r_rms']:.3g})"
    )
    return data, [note]


def _levitator_segments(data: Any, method: str) -> list[tuple[int, int]]:
    """Learned levitating segments (operating points for the grey box)."""
    from maglevid.identify.levitator import find_levitator_segments

    rep, segs, _ = find_levitator_segments(data)
    return segs if method == "greybox-levitator" else rep.bounds()


def _levitating(data: Any, method: str, options: dict[str, Any]) -> tuple[Any, str | None]:
    """A levitator record for ``method``: its levitating segments as the method's
    ``segments`` option where it takes one; else (one model of the whole record: the
    subspace, ML and PEM methods) the longest segment alone, said in a note -- the
    pieces where the ball rests or is caught are not the loop the model describes."""
    from maglevid.identify.registry import method_options

    segs = _levitator_segments(data, method)
    if any(o.name == "segments" for o in method_options(method) or ()):
        options["segments"] = segs
        return data, None
    a, b = max(segs, key=lambda ab: ab[1] - ab[0])
    if (a, b) == (0, data.n_samples):
        return data, None
    note = (
        f"{method} fits one model to one record: fitted on samples {a}..{b} (the longest "
        f"of {len(segs)} levitating segment(s) found); `--method indirect`, "
        "`greybox-levitator` or `levitator` use every segment"
    )
    return data.segment(a, b), note


def _run_sessions(args: argparse.Namespace) -> dict[str, Any]:
    """Several sessions of one rig: each on its own, then all together."""
    from maglevid.exceptions import DataError
    from maglevid.identify.levitator import fit_levitator_sessions
    from maglevid.io import read_recording
    from maglevid.plants import infer_kind

    sessions = [read_recording(p, mapping=args.mapping) for p in args.recording]
    kinds = {infer_kind(d)[0] for d in sessions}
    if kinds != {"levitator"} or args.method not in (None, "levitator"):
        raise DataError(
            "several recordings are identified together for one-coil levitators (method "
            f"levitator); these are {sorted(kinds)}"
            + (f", method {args.method}" if args.method else "")
        )
    per = [_run_one(p, args) for p in args.recording]
    joint = fit_levitator_sessions(sessions, **_typed_options("levitator", args.option))
    out = joint.to_dict()
    out.update(
        recording=list(args.recording),
        plant_kind="levitator",
        plant_kind_reason="every recording is a one-coil levitator",
        method_reason="several sessions: the model validated across sessions, one pooled fit",
        sessions=per,
        units=_units("levitator", joint),
    )
    _add_consensus(out, joint)
    return out


def _intersample_numerators(extras: Any) -> dict[str, Any]:
    """The B_j (j = 1..p-1, coefficients of z^0..z^-n) with standard errors (Sun et al.)."""
    import numpy as np

    B = np.asarray(extras["B_intersample"], dtype=float)
    se = extras.get("B_intersample_std_error")
    return {
        "j": list(range(1, B.shape[0] + 1)),
        "powers_of_z": [-k for k in range(B.shape[1])],
        "B": B.tolist(),
        "std_error": None if se is None else np.asarray(se, dtype=float).tolist(),
    }


def _with_warnings(out: dict[str, Any], warnings: list[str]) -> dict[str, Any]:
    """The result with ``warnings`` (printed as such) also first among its notes."""
    if warnings:
        out["warnings"] = warnings
        out["notes"] = list(dict.fromkeys([*warnings, *out.get("notes", [])]))
    return out


def quality_gate(data: Any, *, force: bool) -> list[str]:
    """The checks of ``maglevid diagnose`` before an identification; the failures as text.

    A failed blocking check refuses (:class:`~maglevid.exceptions.DataError`
    naming every reason) unless ``force``; then the reasons are returned as
    warnings. One exception to diagnose's gate: a record without any logged
    excitation r is not refused here, because the methods made for such
    records (the inter-sampled suspension of Sun et al., driven by noise)
    need none, and the methods that do need r refuse it themselves.
    """
    from maglevid.diagnose.checks import (
        check_channels_move,
        check_sample_time,
        check_units,
        run_checks,
    )
    from maglevid.diagnose.levitator import is_levitator, levitator_checks
    from maglevid.exceptions import DataError

    if is_levitator(data):
        checks = (
            check_channels_move(data),
            *levitator_checks(data)[0],
            check_sample_time(data),
            check_units(data),
        )
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
        return _method_list_text(result)
    rec = result["recording"]
    lines = [f"recording: {', '.join(rec) if isinstance(rec, list) else rec}"]
    if result.get("plant_kind"):
        lines.append(f"plant kind: {result['plant_kind']} ({result['plant_kind_reason']})")
    lines.append(f"method: {result['method']}")
    if result.get("method_reason"):
        lines.append(f"why: {result['method_reason']}")
    if result.get("streamed"):
        st = result["streamed"]
        lines.append(f"streamed: chunks of {st['chunk_size']}, {st['passes']} pass(es)")
    lines.append(f"samples: {result['n_samples']}")
    se = result.get("std_errors") or {}
    ci = result.get("ci95") or {}
    units = result.get("units") or {}
    head = f"{'parameter':>14} {'estimate':>14} {'std. error':>12}   95 % interval"
    lines.append(f"{head:<74} unit" if units else head)
    for k, v in result["parameters"].items():
        lo, hi = ci.get(k) or (None, None)
        band = "" if lo is None or hi is None else f"[{_num(lo, '.6g')}, {_num(hi, '.6g')}]"
        row = f"{k:>14} {_num(v, '.6g'):>14} {_num(se.get(k), '.3g'):>12}   {band}"
        lines.append(f"{row:<74} {units[k]}" if k in units else row)
    if result.get("poles") is not None:
        p = result["poles"]
        re, im = (p["re"], p["im"]) if isinstance(p, dict) else (p, [0.0] * len(p))
        poles = (f"{_num(a, '.6g')}{_num(b, '+.3g')}j" for a, b in zip(re, im))
        lines.append("discrete poles: " + ", ".join(poles))
    for k, v in (result.get("fit") or {}).items():
        lines.append(f"fit {k}: {_num(v, '.6g')}")
    num = result.get("intersample_numerators")
    if num:
        ses = num["std_error"] or [[None] * len(b) for b in num["B"]]
        for j, b, e in zip(num["j"], num["B"], ses):
            terms = ", ".join(
                _num(c, ".4g") + (f" ± {_num(s, '.2g')}" if s is not None else "")
                for c, s in zip(b, e)
            )
            lines.append(f"B_{j} (z^0..z^-{len(b) - 1}): {terms}")
    warned = set(result.get("warnings", []))
    lines.extend(f"warning: {n}" for n in result.get("warnings", []))
    lines.extend(f"note: {n}" for n in result.get("notes", []) if n not in warned)
    lines.extend(_consensus_lines(result))
    return "\n".join(lines)


def _num(v: Any, spec: str, missing: str = "nan") -> str:
    """``v`` formatted by ``spec`` when it is a number; else as text: ``missing`` for
    None (a NaN in the JSON-safe result), the string itself for "inf"/"-inf" (signed
    when ``spec`` asks for a sign)."""
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        return format(v, spec)
    text = missing if v is None else str(v)
    return "+" + text if spec.startswith("+") and not text.startswith("-") else text


def _method_list_text(result: dict[str, Any]) -> str:
    """One line per method, then one indented line per declared option:
    ``name  kind = default  [range | choices] unit  doc``."""
    width = max(map(len, result["methods"]))
    lines = []
    for name in result["methods"]:
        lines.append(f"{name:<{width}}  {result['descriptions'][name]}")
        for o in result.get("options", {}).get(name, []):
            allowed = ""
            if "choices" in o:
                allowed = "{" + ", ".join(map(str, o["choices"])) + "}"
            elif "range" in o:
                lo, hi = o["range"]
                left = "-inf" if lo is None else f"{lo:g}"
                allowed = ("(" if o.get("low_open") else "[") + left + ", "
                allowed += "inf)" if hi is None else f"{hi:g}]"
            unit = f" [{o['unit']}]" if o.get("unit") else ""
            head = f"{o['name']}: {o['kind']} = {json.dumps(o['default'])}"
            lines.append(f"    {head:<36} {allowed}{unit}  {o['doc']}".rstrip())
    return "\n".join(lines)


def _consensus_lines(result: dict[str, Any]) -> list[str]:
    """The per-model table, the excluded pieces and the per-session answers."""
    if "consensus" not in result:
        return []
    c = result["consensus"]
    lo, hi = c["ci95"]
    lines = [
        f"consensus unstable pole: {_num(c['pole_rad_s'], '.4g')} rad/s, 95 % interval "
        f"[{_num(lo, '.4g')}, {_num(hi, '.4g')}] (model: {c['chosen_model']})",
        f"{'model':>28} {'held-out fit %':>15} {'supported':>9} {'pole':>8}   95 % interval",
    ]
    for row in result["candidates"]:
        ci = row["ci95"]
        band = f"[{_num(ci[0], '.4g')}, {_num(ci[1], '.4g')}]" if ci else row["note"] or "-"
        pole = _num(row["pole_rad_s"], ".4g", missing="-")
        hof = row["held_out_fit_percent"]
        hof_s = _num(hof, ".1f", missing="-") if hof == hof else "-"
        lines.append(f"{row['model']:>28} {hof_s:>15} {row['supported']!s:>9} {pole:>8}   {band}")
    for ex in result.get("segments_excluded", []):
        lines.append(f"segments: {ex['range']}")
        for piece in ex["excluded"]:
            lines.append(
                f"  excluded {piece['start_s']:.2f}-{piece['stop_s']:.2f} s: {piece['reason']}"
            )
    for s in result.get("sessions", []):
        sc = s.get("consensus") or {}
        if sc:
            lo, hi = sc["ci95"]
            lines.append(
                f"session {s['recording']}: {_num(sc['pole_rad_s'], '.4g')} rad/s "
                f"[{_num(lo, '.4g')}, {_num(hi, '.4g')}] ({sc['chosen_model']})"
            )
    return lines
