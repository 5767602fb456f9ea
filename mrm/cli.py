"""The ``mrm`` command: one console script whose subcommands cover the user's jobs.

Each subcommand lives in its own module under :mod:`mrm.commands` and exposes
``register(subparsers)``, which adds its parser and sets ``func`` to a callable taking the
parsed arguments and returning an exit code. The conventions every command keeps:

- exit codes: 0 done (a clean run), 1 failed (the output could not be written, a tool
  failed), 2 bad input (one line naming the flag or field; nothing written), 3 a run that is
  not clean (its results are written and the reasons printed), 130 / 143 interrupted by
  SIGINT (Ctrl-C) / SIGTERM (worker processes stopped, temporary folders removed, earlier
  results left as they were);
- a flag given twice is bad input (exit 2), as is anything argparse refuses;
- ``-v`` / ``-q`` on every command set the :mod:`logging` level (progress lines are INFO on
  stderr; ``-q`` leaves only errors and silences the closing summary);
- a standard output that is full or closed (``> /dev/full``, ``| head``) ends with one line;
- every ``--help`` page shows the defaults and an example.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import importlib
import logging
import os
import signal
import sys

from mrm_cosim import __version__
from mrm_cosim.errors import InputError

# Subcommand modules, in the order they appear in ``mrm --help``.
COMMANDS = ("robot", "plan", "dmp", "run", "hdl", "bench", "sweep", "tune", "cache")

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_USAGE = 2
EXIT_NOT_CLEAN = 3
EXIT_SIGINT = 128 + signal.SIGINT       # 130
EXIT_SIGTERM = 128 + signal.SIGTERM     # 143

LOGGER = "mrm_cosim"


class Formatter(argparse.RawDescriptionHelpFormatter):
    """Help with every option's default (``(default: 1.5)``; none shown for flags, unset
    options and lists) and the epilog's example kept as written."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        if ("%(default)" in text or default is None or isinstance(default, bool)
                or default == argparse.SUPPRESS or default == [] or not action.option_strings
                or isinstance(action, argparse._CountAction)):
            return text
        return f"{text} (default: %(default)s)" if text else "(default: %(default)s)"


class _Once:
    """Mixin of an argparse action given at most once: ``--duration 1 --duration 2`` is an
    error naming the flag (it used to keep the last value silently)."""

    def __call__(self, parser, namespace, values, option_string=None):
        seen = namespace.__dict__.setdefault("_flags_given", set())
        if self.dest in seen:
            raise argparse.ArgumentError(self, "given more than once")
        seen.add(self.dest)
        super().__call__(parser, namespace, values, option_string)


class _StoreOnce(_Once, argparse._StoreAction):
    pass


class _StoreTrueOnce(_Once, argparse._StoreTrueAction):
    pass


class _StoreConstOnce(_Once, argparse._StoreConstAction):
    pass


class Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors are one line (``mrm plan quintic: error: …``, exit 2),
    whose help shows defaults (:class:`Formatter`) and whose flags are given at most once."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("formatter_class", Formatter)
        super().__init__(*args, **kwargs)
        self.register("action", None, _StoreOnce)
        self.register("action", "store", _StoreOnce)
        self.register("action", "store_true", _StoreTrueOnce)
        self.register("action", "store_const", _StoreConstOnce)

    def error(self, message):  # noqa: D102 - argparse API
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        raise SystemExit(EXIT_USAGE)


_Parser = Parser          # the name tests and older code use


def leaf_parsers(parser: argparse.ArgumentParser):
    """Every parser below ``parser`` that runs a command (has no subcommands), with its
    ``prog``; ``parser`` itself if it has none."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield parser
        return
    for action in subs:
        for child in dict.fromkeys(action.choices.values()):
            yield from leaf_parsers(child)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(prog="mrm", description=__doc__.split("\n\n")[0],
                    epilog="exit codes: 0 done, 1 failed, 2 bad input, 3 run not clean, "
                    "130/143 interrupted (SIGINT/SIGTERM)\nexample:\n  mrm run table2 "
                    "--duration 0.05 --out results/t2")
    parser.add_argument("--version", action="version", version=f"mrm-cosim {__version__}")
    subparsers = parser.add_subparsers(dest="command", required=True, parser_class=Parser)
    for name in COMMANDS:
        importlib.import_module(f"mrm_cosim.mrm.commands.{name}").register(subparsers)
    for leaf in leaf_parsers(parser):
        group = leaf.add_argument_group("output")
        group.add_argument("-v", "--verbose", action="count", default=0,
                           help="debug log lines on stderr too (the resolved experiment, …)")
        group.add_argument("-q", "--quiet", action="store_true",
                           help="print nothing but errors")
    return parser


# --- logging -------------------------------------------------------------------------------
class _StderrHandler(logging.Handler):
    """Log records as bare lines on the current ``sys.stderr`` (looked up at each record, so
    a replaced stderr, as in tests, receives them)."""

    def emit(self, record):
        try:
            sys.stderr.write(self.format(record) + "\n")
            sys.stderr.flush()
        except Exception:       # noqa: BLE001 - logging's own policy
            self.handleError(record)


def configure_logging(verbose: int = 0, quiet: bool = False) -> None:
    """The ``mrm_cosim`` logger: INFO (progress) by default, ERROR with ``-q``, DEBUG with
    ``-v``; one handler writing bare lines to stderr."""
    logger = logging.getLogger(LOGGER)
    for handler in [h for h in logger.handlers if isinstance(h, _StderrHandler)]:
        logger.removeHandler(handler)
    handler = _StderrHandler()
    handler.setFormatter(logging.Formatter("%(message)s"))
    logger.addHandler(handler)
    logger.propagate = False
    logger.setLevel(logging.ERROR if quiet else logging.DEBUG if verbose else logging.INFO)


# --- signals and standard output ----------------------------------------------------------
class Terminated(BaseException):
    """SIGTERM, raised where the program runs so that every ``finally`` (worker processes,
    temporary folders) runs as for Ctrl-C."""


class _StdoutError(Exception):
    def __init__(self, exc: OSError):
        super().__init__(exc)
        self.exc = exc


class _GuardedStdout:
    """``sys.stdout`` whose write errors (ENOSPC, EPIPE, …) surface as :class:`_StdoutError`,
    told apart from the errors of writing result files."""

    def __init__(self, stream):
        self._stream = stream

    def write(self, text):
        try:
            return self._stream.write(text)
        except OSError as exc:
            raise _StdoutError(exc) from None

    def flush(self):
        try:
            return self._stream.flush()
        except OSError as exc:
            raise _StdoutError(exc) from None

    def __getattr__(self, name):
        return getattr(self._stream, name)


@contextlib.contextmanager
def _signals_raise():
    """SIGINT raises KeyboardInterrupt and SIGTERM :class:`Terminated`; once one came, both
    are ignored while the program cleans up. Restored on exit (only in the main thread)."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        raise KeyboardInterrupt if signum == signal.SIGINT else Terminated

    saved = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, h in saved.items():
            signal.signal(s, h)


def _silence_stdout() -> None:
    """Point file descriptor 1 at /dev/null so that the interpreter's last flush of what
    could not be written does not print a second error at exit."""
    with contextlib.suppress(OSError, ValueError, AttributeError):
        fd = os.open(os.devnull, os.O_WRONLY)
        os.dup2(fd, sys.__stdout__.fileno())
        os.close(fd)


@contextlib.contextmanager
def _compiled_threads(args):
    """A command's ``--threads`` as ``$MRM_COMPILED_THREADS`` while it runs (the processes it
    starts inherit it; restored after), the variable checked first where the command takes
    ``--threads`` (an :class:`InputError` naming it: exit code 2 before anything runs)."""
    if not hasattr(args, "threads"):
        yield
        return
    from mrm_cosim.cosim.track import compiled_threads, compiled_threads_env

    with compiled_threads_env(args.threads):
        compiled_threads()
        yield


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    configure_logging(args.verbose, args.quiet)
    name = f"{parser.prog} {args.command}"
    logging.getLogger(LOGGER).debug("mrm-cosim %s, Python %s, pid %d", __version__,
                                    sys.version.split()[0], os.getpid())
    stdout = sys.stdout
    sys.stdout = _GuardedStdout(stdout)
    try:
        with _signals_raise():
            try:
                with _compiled_threads(args):
                    code = args.func(args)
                sys.stdout.flush()
            except InputError as exc:
                sys.stderr.write(f"{name}: error: {exc}\n")
                return EXIT_USAGE
            except KeyboardInterrupt:
                sys.stderr.write(f"{name}: interrupted (SIGINT): workers stopped, no "
                                 "partial results left, earlier results kept\n")
                return EXIT_SIGINT
            except Terminated:
                sys.stderr.write(f"{name}: terminated (SIGTERM): workers stopped, no "
                                 "partial results left, earlier results kept\n")
                return EXIT_SIGTERM
            except _StdoutError as exc:
                what = ("closed (broken pipe)" if exc.exc.errno == errno.EPIPE
                        else f"not writable ({exc.exc.strerror or exc.exc})")
                sys.stderr.write(f"{name}: error: standard output {what}\n")
                if stdout is sys.__stdout__:
                    _silence_stdout()
                return EXIT_FAILED
    finally:
        sys.stdout = stdout
    return int(code or 0)


if __name__ == "__main__":
    sys.exit(main())
