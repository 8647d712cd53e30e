"""The one CLI entry point, ``vdp``; each subcommand is its own module.

A subcommand module provides ``add_parser(subparsers)`` and ``run(args) -> int``.
Errors derived from :class:`vdp.errors.VdpError` become a one-line message and
exit status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import difflib
import importlib
import logging
import sys

from .. import __version__
from ..errors import VdpError

SUBCOMMANDS = ("simulate", "replay", "serve", "export", "batch", "profile")


class Parser(argparse.ArgumentParser):
    """A parser that refuses the arguments it does not know itself, with its own usage and the
    option they most look like: argparse hands a subcommand's unknown ones up to ``vdp``, whose
    usage says nothing of the subcommand's options (``vdp replay --profle P``)."""

    def parse_known_args(self, args=None, namespace=None):
        ns, extras = super().parse_known_args(args, namespace)
        if extras and self._subparsers is None:  # a subcommand (the top level's are its own)
            hints = []
            for a in extras:
                flag = a.split("=", 1)[0]
                if flag.startswith("-"):
                    close = difflib.get_close_matches(flag, list(self._option_string_actions), n=1, cutoff=0.6)
                    if close:
                        hints.append(f"{flag} (did you mean {close[0]}?)")
                        continue
                hints.append(a)
            self.error(f"unrecognized arguments: {' '.join(hints)}")
        return ns, extras


def chosen(argv: list[str]) -> str | None:
    """The subcommand named in ``argv`` (the first word that is not an option), if it is one:
    only its module is then imported (``vdp replay`` does not load the simulator's)."""
    for a in argv:
        if not a.startswith("-"):
            return a if a in SUBCOMMANDS else None
    return None


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The parser; ``only``: with only that subcommand (its module alone imported), else all."""
    parser = Parser(prog="vdp", description="Vehicle dynamic parameter estimation from CAN data.")
    parser.add_argument("--version", action="version", version=f"vdp {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in (only,) if only else SUBCOMMANDS:
        try:
            module = importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"{__name__}.{name}":
                continue  # subcommand not built yet
            raise
        p = module.add_parser(sub)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser(chosen(argv))
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    try:
        return int(args._run(args) or 0)
    except VdpError as exc:
        print(f"vdp {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"vdp {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
