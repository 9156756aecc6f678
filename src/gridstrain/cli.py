"""The ``gridstrain`` command line.

Each sub-command lives in a module ``gridstrain._cli_<name>`` exposing
``register(subparsers)``, which adds its parser and sets ``func`` to a callable
``func(args) -> int``. User errors (``ValueError``, ``TypeError``, ``OSError``)
become one line on stderr and exit code 2; the library itself never prints.

Only the module of the sub-command being run is imported: ``gridstrain --help``
lists the sub-commands from the one-line summaries below, without importing the
numerical core, h5py or matplotlib.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import sys

from . import __version__

# sub-command -> the one-line summary its module's parser declares (a test checks
# that they agree)
_COMMANDS = {
    "demo": "simulate a plate with a hole in tension and measure it",
    "measure": "displacement and strain maps from image series",
    "noise": "estimate the camera noise (and vibrations) from a static stack or a single "
             "image",
    "plot": "figures of a result file: maps of every state, strain history",
    "report": "a self-contained HTML report of a result file",
    "reproduce": "re-run the paper's synthetic experiments (RMSE vs T, methods A and B)",
}


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, no usage dump
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser(commands=None) -> argparse.ArgumentParser:
    """The top-level parser.

    ``commands``: the sub-commands whose parsers are built in full (their modules
    imported); the others are listed by their summary only. Default: all of them.
    """
    parser = _Parser(prog="gridstrain",
                     description="Displacement and strain maps with the grid method.")
    parser.add_argument("--version", action="version", version=f"gridstrain {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND",
                                parser_class=_Parser)
    for name, summary in _COMMANDS.items():
        module = f"gridstrain._cli_{name}"
        if commands is not None and name not in commands:
            if importlib.util.find_spec(module) is not None:
                sub.add_parser(name, help=summary, add_help=False)
            continue
        try:
            mod = importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name != module:
                raise
            continue
        mod.register(sub)
    return parser


def main(argv=None) -> int:
    """Entry point of the ``gridstrain`` console script."""
    if argv is None:
        argv = sys.argv[1:]
    # the top level has no option taking a value: the first word is the sub-command
    command = next((a for a in argv if not a.startswith("-")), None)
    parser = build_parser([command] if command in _COMMANDS else [])
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
