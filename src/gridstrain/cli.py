"""The ``gridstrain`` command line.

Each sub-command lives in a module ``gridstrain._cli_<name>`` exposing
``register(subparsers)``, which adds its parser and sets ``func`` to a callable
``func(args) -> int``. User errors (``ValueError``, ``TypeError``, ``OSError``)
become one line on stderr and exit code 2; the library itself never prints.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from . import __version__

_COMMANDS = ("demo", "measure", "noise", "plot", "report", "reproduce")


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, no usage dump
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every available sub-command."""
    parser = _Parser(prog="gridstrain",
                     description="Displacement and strain maps with the grid method.")
    parser.add_argument("--version", action="version", version=f"gridstrain {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND",
                                parser_class=_Parser)
    for name in _COMMANDS:
        try:
            mod = importlib.import_module(f"gridstrain._cli_{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"gridstrain._cli_{name}":
                raise
            continue
        mod.register(sub)
    return parser


def main(argv=None) -> int:
    """Entry point of the ``gridstrain`` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ValueError, TypeError, OSError) as exc:
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        print(f"gridstrain {args.command}: error: {msg}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"gridstrain {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
