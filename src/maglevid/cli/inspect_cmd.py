"""``maglevid inspect RECORDING``: what a recording holds, in a few lines.

(The module is not called ``inspect.py`` so that it can never shadow the
standard library's :mod:`inspect`.)
"""

from __future__ import annotations

import argparse
from typing import Any

COMMAND = "inspect"
HELP = "describe a recording: size, timing, channels with units, statistics"
DESCRIPTION = """\
Print what a recording holds: number of control periods N, dt, p, duration,
every channel with its unit and min/max/mean/std, extra channels, and the keys
of the known loop and of the metadata.

  maglevid inspect rec.npz
  maglevid inspect dataset_chirp_20251217_210058.txt --mapping uaq-levitador
  maglevid inspect rec.parquet --json
"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", help="recording file (.csv + .json, .npz, .mat, .parquet)")
    parser.add_argument(
        "--mapping", default=None, help="column mapping (.json/.toml file or preset name)"
    )
    parser.add_argument("--format", default=None, help="format when the extension does not say")


def run(args: argparse.Namespace) -> dict[str, Any]:
    from maglevid.io import read_recording, summarize_recording

    data = read_recording(args.recording, format=args.format, mapping=args.mapping)
    out = {"recording": args.recording, "repr": repr(data)}
    out.update(summarize_recording(data))
    return out


def format_text(result: dict[str, Any]) -> str:
    r = result
    lines = [
        f"recording: {r['recording']}",
        f"N = {r['n_samples']} control periods x p = {r['p']} "
        f"({r['n_output_samples']} output samples)",
        f"dt = {r['dt']:.6g} s ({r['sample_rate_hz']:.6g} Hz), t0 = {r['t0']:.6g} s, "
        f"duration {r['duration_s']:.6g} s",
        f"{'signal':<7} {'channel':<12} {'unit':<8} {'min':>12} {'max':>12} {'mean':>12} "
        f"{'std':>12}",
    ]
    for sig, chans in r["signals"].items():
        for c in chans:
            lines.append(
                f"{sig:<7} {c['name']:<12} {c['unit'] or '-':<8} {c['min']:>12.5g} "
                f"{c['max']:>12.5g} {c['mean']:>12.5g} {c['std']:>12.5g}"
            )
    for name, e in r["extra_signals"].items():
        lines.append(
            f"{'extra':<7} {name:<12} {e['unit'] or '-':<8} {e['min']:>12.5g} {e['max']:>12.5g} "
            f"{e['mean']:>12.5g} ({e['rate']} rate)"
        )
    lines.append("loop: " + (", ".join(r["loop_keys"]) or "(nothing known)"))
    lines.append("metadata: " + (", ".join(r["metadata_keys"]) or "(none)"))
    return "\n".join(lines)
