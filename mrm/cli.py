"""The ``mrm`` command: one console script whose subcommands cover the user's jobs.

Each subcommand lives in its own module under :mod:`mrm.commands` and exposes
``register(subparsers)``, which adds its parser and sets ``func`` to a callable taking the
parsed arguments and returning an exit code. Bad input anywhere ends in a one-line message
naming the field and exit code 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from mrm_cosim import __version__
from mrm_cosim.errors import InputError

# Subcommand modules, in the order they appear in ``mrm --help``.
COMMANDS = ("robot", "plan", "run", "hdl", "bench")

EXIT_USAGE = 2


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors are one line: ``mrm plan quintic: --tf: ...``."""

    def error(self, message):  # noqa: D102 - argparse API
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        raise SystemExit(EXIT_USAGE)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="mrm", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"mrm-cosim {__version__}")
    subparsers = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for name in COMMANDS:
        importlib.import_module(f"mrm_cosim.mrm.commands.{name}").register(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        code = args.func(args)
    except InputError as exc:
        sys.stderr.write(f"mrm {args.command}: error: {exc}\n")
        return EXIT_USAGE
    except BrokenPipeError:  # `mrm robot urdf mrm3 | head`
        return 0
    return int(code or 0)


if __name__ == "__main__":
    sys.exit(main())
