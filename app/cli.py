"""The ``cogmap`` command line: thin shells over library functions, one error handler.

Each command lives in its own module ``app/cmd_<name>.py`` exposing ``add_parser(subparsers)``;
the parser's ``func`` takes the parsed arguments and returns the exit code. Every expected
failure is a :class:`cogmap_core.errors.CogmapError`, printed here as one line (no traceback)
with its exit code (2). Ctrl-C prints "interrupted" (exit 130); SIGTERM unwinds the same way,
so partial outputs are removed, and prints "terminated" (exit 143).
"""

from __future__ import annotations

import argparse
import importlib
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from types import FrameType
from typing import NoReturn

from cogmap_core import __version__
from cogmap_core.errors import CogmapError


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised like Ctrl-C so that every command cleans up its partial outputs."""


def _terminate(signum: int, frame: FrameType | None) -> None:
    raise Terminated


def _install_sigterm() -> Callable[[], None]:
    """Turn SIGTERM into :class:`Terminated` while a command runs; returns the undo."""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    previous = signal.getsignal(signal.SIGTERM)
    if previous not in (signal.SIG_DFL, None):  # someone else handles it: leave it alone
        return lambda: None
    signal.signal(signal.SIGTERM, _terminate)
    return lambda: signal.signal(signal.SIGTERM, previous or signal.SIG_DFL)


# Modules app/cmd_<name>.py, in the order they appear in --help.
COMMAND_MODULES: tuple[str, ...] = (
    "app.cmd_serve",
    "app.cmd_run",
    "app.cmd_optimize",
    "app.cmd_route",
    "app.cmd_make_maze",
    "app.cmd_make_log",
    "app.cmd_dataset",
    "app.cmd_sweep",
)


class CommandLineParser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line: the command, the problem, the help.

    argparse prints the usage block and then the error; this prints only
    ``cogmap run: error: the following arguments are required: --out; see cogmap run --help``
    (exit code 2). Sub-command parsers are of this class too (argparse makes them of the class of
    their parent).
    """

    #: The sub-commands' parsers, by name (set by :func:`build_parser` on the top-level one).
    commands: dict[str, argparse.ArgumentParser] = {}

    def error(self, message: str) -> NoReturn:
        """Print the one-line usage error and exit with code 2."""
        self.exit(2, f"{self.prog}: error: {message}; see {self.prog} --help\n")

    def parse_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> argparse.Namespace:
        """Parse like argparse; unrecognized arguments are reported by the parser they follow.

        argparse reports them from the top-level parser (``cogmap: error: ...``) even when they
        were given to a sub-command; here ``cogmap run ... --bogus`` is ``cogmap run``'s error.
        """
        parsed, unknown = self.parse_known_args(args, namespace)
        if unknown:
            tokens = list(sys.argv[1:] if args is None else args)
            command = getattr(parsed, "command", None)
            owner: argparse.ArgumentParser = self
            if command in self.commands and command in tokens:
                if tokens.index(unknown[0]) > tokens.index(command):
                    owner = self.commands[command]
            owner.error(f"unrecognized arguments: {' '.join(unknown)}")
        return parsed


def build_parser() -> argparse.ArgumentParser:
    """The full argument parser with every available sub-command."""
    parser = CommandLineParser(
        prog="cogmap",
        description="Brain-inspired compact cognitive maps: SLAM on iRat-layout bags, "
        "pose-graph optimisation, synthetic rat mazes and a live web app.",
    )
    parser.add_argument("--version", action="version", version=f"cogmap {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module_name in COMMAND_MODULES:
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name == module_name:  # command not built yet
                continue
            raise
        module.add_parser(subparsers)
    parser.commands = dict(subparsers.choices)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``cogmap`` command line; return the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    restore = _install_sigterm()
    try:
        return int(args.func(args) or 0)
    except CogmapError as exc:
        print(f"cogmap {args.command}: error: {exc}", file=sys.stderr)
        return exc.exit_code
    except Terminated:
        print(f"cogmap {args.command}: terminated", file=sys.stderr)
        return 128 + signal.SIGTERM
    except KeyboardInterrupt:
        print(f"cogmap {args.command}: interrupted", file=sys.stderr)
        return 130
    finally:
        restore()


if __name__ == "__main__":
    sys.exit(main())
