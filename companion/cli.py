"""``companion`` command line: subcommands are discovered in ``companion.commands``.

Each module ``companion/commands/<name>.py`` defines ``register(subparsers)`` which adds
one (or more) subparsers and sets ``func`` on them; ``func(args) -> int`` is the exit
code. Only this entry point configures logging.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import pkgutil
from importlib import metadata
import sys
from typing import NoReturn

from companion import commands as _commands
from companion.errors import CompanionError

logger = logging.getLogger(__name__)


def _version() -> str:
    """The installed distribution's version (the package's own when run from a source tree)."""
    try:
        return metadata.version("ogccmpc")
    except metadata.PackageNotFoundError:
        from companion import __version__

        return __version__


class OneLineErrorParser(argparse.ArgumentParser):
    """argparse with its errors on one line (``companion SUB: error: argument --x: ...``), exit 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineErrorParser(
        prog="companion",
        description="PX4 companion: overlap-of-Gaussians chance-constrained MPC over MAVLink.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more logging (-v info, -vv debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for info in sorted(pkgutil.iter_modules(_commands.__path__), key=lambda m: m.name):
        module = importlib.import_module(f"{_commands.__name__}.{info.name}")
        register = getattr(module, "register", None)
        if register is not None:
            register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except CompanionError as exc:
        print(f"companion {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a file or directory that cannot be read or written, a port in use
        print(f"companion {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
