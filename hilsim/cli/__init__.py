"""The ``hilsim`` command line.

Each subcommand lives in its own module that defines::

    HELP: str                                   # one line for ``hilsim --help``
    def add_arguments(parser: argparse.ArgumentParser) -> None
    def run(args: argparse.Namespace) -> int     # the process exit code

and is listed in ``SUBCOMMANDS``. Modules are imported only when the parser is
built, and must not import matplotlib or dynamixel_sdk at module level (do it
inside ``run``), so ``hilsim --help`` stays fast. ``hilsim NAME ...`` builds the parser of
NAME alone (:func:`main`): ``hilsim run`` never imports the emulator's pty server, the
bench or the integrator study just to list them.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import logging
import sys
from collections.abc import Iterator, Sequence

from hilsim.exit_codes import ExitCode

#: subcommand name -> module implementing it
SUBCOMMANDS: dict[str, str] = {
    "run": "hilsim.cli.run",
    "scan": "hilsim.cli.scan",
    "setup": "hilsim.cli.setup",
    "plot": "hilsim.cli.plot",
    "bench": "hilsim.cli.bench",
    "emulate": "hilsim.cli.emulate",
    "compare": "hilsim.cli.compare",
    "tracks": "hilsim.cli.tracks",
    "service": "hilsim.cli.service",
    "sounds": "hilsim.cli.sounds",
    "panel": "hilsim.cli.panel",
}


class _Version(argparse.Action):
    """``--version``: the installed version, looked up only when asked for (reading the
    package metadata would cost every command's start-up)."""

    def __call__(self, parser: argparse.ArgumentParser, *_: object) -> None:
        from hilsim import __version__

        print(f"hilsim {__version__}")  # on stdout, as argparse's own version action
        parser.exit()


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The ``hilsim`` parser with every subcommand, or with ``only`` that one."""
    parser = argparse.ArgumentParser(
        prog="hilsim",
        description="Drive animatronic joints as damped springs on Dynamixel servos "
        "(or on the built-in emulated bus).",
    )
    parser.add_argument(
        "--version", action=_Version, nargs=0, help="show program's version number and exit"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, module_name in SUBCOMMANDS.items():
        if only is not None and name != only:
            continue
        module = importlib.import_module(module_name)
        p = sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


@contextlib.contextmanager
def _library_log(command: str) -> Iterator[None]:
    """The library logs (``hilsim`` loggers); the command prints its warnings on stderr, in
    its own words: ``hilsim run: ...``."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter(f"hilsim {command}: %(message)s"))
    handler.setLevel(logging.WARNING)
    root = logging.getLogger("hilsim")
    root.addHandler(handler)
    try:
        yield
    finally:
        root.removeHandler(handler)


def main(argv: Sequence[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        # ``hilsim run ...``: that subcommand's module alone (start-up time); anything else
        # (--help, --version, a typo) gets the whole parser and its list of commands
        parser = build_parser(argv[0] if argv and argv[0] in SUBCOMMANDS else None)
        args = parser.parse_args(argv)
        if getattr(args, "_run", None) is None:
            parser.print_help()
            return int(ExitCode.USAGE)
        with _library_log(args.command):
            return int(args._run(args))
    except KeyboardInterrupt:  # Ctrl-C before a command took over SIGINT: nothing had moved
        print("hilsim: interrupted", file=sys.stderr)
        return int(ExitCode.SIGINT)


if __name__ == "__main__":
    sys.exit(main())
