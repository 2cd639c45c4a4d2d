"""Entry point of the ``maglevid`` command: discovery, errors, ``--json`` output."""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import sys
import warnings
from collections.abc import Iterator, Sequence
from typing import Any

import maglevid
from maglevid._plugins import modules_with
from maglevid.exceptions import MaglevidError
from maglevid.jsonable import to_json_text
from maglevid.parallel import one_blas_thread_here

__all__ = ["build_parser", "main"]

DESCRIPTION = """\
maglevid identifies the physical parameters of magnetic bearings and maglev
plants (coil resistance and inductance, force factors, amplifier gains, mass)
from data recorded while the feedback loop is closed, and says what changed.

Typical use:
  maglevid simulate amb --fault R1=1.2 --out rec.npz   # make a recording
  maglevid identify rec.npz --json                      # physical parameters
  maglevid COMMAND --help                               # options of a command
"""


def _commands() -> list[Any]:
    return modules_with("maglevid.cli", "COMMAND")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="maglevid",
        description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"maglevid {maglevid.__version__}")
    parser.add_argument(
        "--json", action="store_true", help="print the result as JSON (for scripts and machines)"
    )
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    parser.add_argument("-v", "--verbose", action="store_true", help="log what is done")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for mod in _commands():
        p = sub.add_parser(
            mod.COMMAND,
            help=mod.HELP,
            description=getattr(mod, "DESCRIPTION", mod.HELP),
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run, _format=getattr(mod, "format_text", None))
        _add_common_options(p)
    return parser


def _add_common_options(parser: argparse.ArgumentParser) -> None:
    """--json and --quiet on every command and sub-command, before or after its arguments."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    for action in subs:
        for child in set(action.choices.values()):
            _add_common_options(child)
    have = parser._option_string_actions
    if "--json" not in have:
        parser.add_argument(
            "--json", action="store_true", default=argparse.SUPPRESS, help="print JSON"
        )
    if "--quiet" not in have:
        parser.add_argument(
            "-q",
            "--quiet",
            action="store_true",
            default=argparse.SUPPRESS,
            help="no progress bars",
        )


def _default_text(result: dict[str, Any]) -> str:
    lines = []
    for k, v in result.items():
        if isinstance(v, (dict, list)):
            v = to_json_text(v)
        lines.append(f"{k}: {v}")
    return "\n".join(lines)


def _error(args: argparse.Namespace, exc: BaseException) -> int:
    """One line (or one JSON object) for an error, exit code 1."""
    if args.json:
        print(to_json_text({"error": type(exc).__name__, "message": str(exc)}))
    else:
        print(f"maglevid {args.command}: error: {exc}", file=sys.stderr)
    return 1


def _print(args: argparse.Namespace, result: Any) -> None:
    if args.json:
        # Always JSON (RFC 8259): NaN -> null, +-inf -> "inf"/"-inf" (maglevid.jsonable).
        print(to_json_text(result, indent=2))
    else:
        fmt = args._format or _default_text
        print(fmt(result))
    sys.stdout.flush()


@contextlib.contextmanager
def _numerical_warnings_logged() -> Iterator[None]:
    """NumPy's RuntimeWarnings (overflow, "Mean of empty slice") go to the log, not stderr.

    The commands turn what such a warning announces (a record too short, a value
    that overflows) into one clear message or a note; the raw warning with its
    source line would only bury that message. ``-v`` shows them, one log line
    each. Other warnings (maglevid's own, for marginal problems) are unchanged.
    """
    log = logging.getLogger("maglevid.cli")
    shown = warnings.showwarning

    def show(message: Any, category: Any, filename: str, lineno: int, *rest: Any) -> None:
        if issubclass(category, RuntimeWarning):
            log.info("numerical warning (%s:%d): %s", filename, lineno, message)
        else:
            shown(message, category, filename, lineno, *rest)

    with warnings.catch_warnings():
        warnings.simplefilter("default", RuntimeWarning)
        warnings.showwarning = show
        yield


def _reader_went_away() -> int:
    """``maglevid ... | head``: the reader closed the pipe; stop quietly, as Unix tools do.

    Python's documented recipe (the ``signal`` module's notes on SIGPIPE):
    point stdout at /dev/null so that the interpreter's final flush does not
    raise again, and exit with 128 + SIGPIPE like a program the signal ended.
    """
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)
    return 128 + 13  # SIGPIPE


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code (0 ok, 1 error, 2 usage, 141 pipe closed)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    if args.command is None:
        parser.print_help()
        return 2
    try:
        with _numerical_warnings_logged(), one_blas_thread_here():
            result = args._run(args)
        if result is not None:
            _print(args, result)
    except BrokenPipeError:
        return _reader_went_away()
    except MaglevidError as exc:
        return _error(args, exc)
    except OSError as exc:  # missing file, permission, disk full: one line, no traceback
        return _error(args, exc)
    if result is None:
        return 0
    return int(result.get("exit_code", 0)) if isinstance(result, dict) else 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
