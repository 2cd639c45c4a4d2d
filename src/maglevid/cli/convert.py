"""``maglevid convert IN OUT``: convert a recording between formats, or import a log."""

from __future__ import annotations

import argparse
from typing import Any

COMMAND = "convert"
HELP = "convert a recording between formats, or import your own log through a mapping"
DESCRIPTION = """\
Read a recording (or your own log, through a column mapping) and write it in
another format. The format follows each file's extension: .csv (+ .json
side-car), .npz, .mat (MATLAB v5; --to mat73 for v7.3), .parquet. The input
is never written over; an existing OUT is refused without --overwrite.

  maglevid convert rec.npz rec.csv
  maglevid convert datos_levitador.txt uaq.parquet --mapping uaq-levitador
  maglevid convert mylog.txt rec.npz --mapping mymap.toml
  maglevid convert --presets          # the mapping presets shipped with maglevid
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("input", nargs="?", help="recording or log to read")
    parser.add_argument("output", nargs="?", help="file to write")
    parser.add_argument(
        "--mapping",
        default=None,
        help="column mapping: a .json/.toml file or a preset name (see --presets)",
    )
    parser.add_argument(
        "--format", default=None, help="format of INPUT when its extension does not say"
    )
    parser.add_argument(
        "--to", default=None, help="format of OUTPUT (csv, npz, mat, mat73, parquet)"
    )
    parser.add_argument(
        "--overwrite", action="store_true", help="replace OUTPUT if it exists (never INPUT)"
    )
    parser.add_argument("--presets", action="store_true", help="list the mapping presets and exit")


def run(args: argparse.Namespace) -> dict[str, Any]:
    from maglevid.exceptions import DataError
    from maglevid.io import available_presets, read_recording, write_recording

    if args.presets:
        return {"presets": available_presets()}
    if args.input is None or args.output is None:
        raise DataError("convert needs INPUT and OUTPUT (or --presets)")
    from pathlib import Path

    from maglevid.io import check_output

    # The mapping file is an input too (the recording and its side-car are
    # protected by write_recording itself); checked before the read.
    mapping_file = args.mapping if args.mapping and Path(args.mapping).is_file() else None
    check_output(args.output, overwrite=args.overwrite, inputs=[args.input, mapping_file])
    from maglevid.cli._progress import stages

    steps = stages(("reading", "writing"), desc="convert", args=args)
    next(steps)
    data = read_recording(args.input, format=args.format, mapping=args.mapping)
    next(steps)
    path = write_recording(data, args.output, format=args.to, overwrite=args.overwrite)
    steps.close()
    out: dict[str, Any] = {
        "read": args.input,
        "written": str(path),
        "recording": repr(data),
        "n_samples": data.n_samples,
        "dt": data.dt,
        "p": data.p,
        "signals": {s: list(data.channel_names(s)) for s in data.signals()},
    }
    if str(path).lower().endswith(".csv"):
        out["sidecar"] = str(path.with_suffix(".json"))
    return out


def format_text(result: dict[str, Any]) -> str:
    if "presets" in result:
        lines = ["mapping presets (use with --mapping NAME):"]
        for name, desc in result["presets"].items():
            lines.append(f"  {name:<24} {desc[:100]}{'...' if len(desc) > 100 else ''}")
        return "\n".join(lines)
    lines = [f"read    {result['read']}: {result['recording']}", f"wrote   {result['written']}"]
    if "sidecar" in result:
        lines.append(f"        {result['sidecar']} (metadata side-car)")
    return "\n".join(lines)
