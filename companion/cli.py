"""``companion`` command line: the subcommands are the modules named in :data:`COMMANDS`.

Each module ``companion/commands/<name>.py`` listed there defines ``register(subparsers)``
which adds one (or more) subparsers and sets ``func`` on them; ``func(args) -> int`` is the
exit code. Only this entry point configures logging, and the BLAS thread pools (one thread).

Start-up is kept short: every ``companion`` run builds the whole parser, so registering a
command imports nothing heavy (no numpy, scipy, filterpy, osqp, numba, pymavlink,
matplotlib); a command imports what it needs in its ``func``, when it runs
(``tests/commands/test_startup.py``; ``python -m tests.benchmarks startup``).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
from importlib import metadata
import sys
from typing import NoReturn

from companion.commands._help import PlainHelpFormatter
from companion.errors import CompanionError
from companion.realtime.service import JournalPrefixFormatter, stderr_is_journal

logger = logging.getLogger(__name__)

#: Thread-pool sizes of the BLAS libraries numpy and scipy may load, set to one thread unless
#: the environment already says otherwise. Every matrix here is small (3x3 to 6x6 in the
#: filters and the response model; OSQP factors the QP itself), so extra BLAS threads only
#: wait, spinning: against PX4 SITL the process of ``fly`` used 55 to 61 % of a core with
#: OpenBLAS's default threads and 11 to 13 % with one (docs/REALTIME.md).
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")

#: The modules of ``companion.commands`` that register subcommands, in the order of ``--help``.
#: Listed, not discovered: discovering would import every module of the package, helpers
#: too (``fly_identify`` imports pymavlink). tests/commands/test_startup.py checks that every
#: module defining ``register`` is listed.
COMMANDS = ("campaign", "demo", "fly", "identify", "overlap", "plan", "reliability", "replay")


def _one_blas_thread() -> None:
    """Ask for one BLAS thread (:data:`BLAS_THREAD_VARIABLES`) before numpy is first imported.

    Read by the BLAS library when it loads, so it acts only in a process that has not
    imported numpy yet (``companion ...``, ``python -m companion.cli``), and in every
    process started from it (the planning process, mavsim).
    """
    for name in BLAS_THREAD_VARIABLES:
        os.environ.setdefault(name, "1")


def _version() -> str:
    """The installed distribution's version (the package's own when run from a source tree)."""
    try:
        return metadata.version("ogccmpc")
    except metadata.PackageNotFoundError:
        from companion import __version__

        return __version__


class OneLineErrorParser(argparse.ArgumentParser):
    """argparse with its errors on one line (``companion SUB: error: argument --x: ...``), exit 2,
    and its help in plain text (:class:`~companion.commands._help.PlainHelpFormatter` unless a
    parser names another formatter)."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("formatter_class", PlainHelpFormatter)
        super().__init__(*args, **kwargs)

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
    for name in COMMANDS:
        importlib.import_module(f"companion.commands.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    _one_blas_thread()   # before the commands import numpy
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    journal = stderr_is_journal()  # a systemd service: each line carries its priority for journald
    handler = logging.StreamHandler()
    log_format = "%(levelname)s %(name)s: %(message)s"
    handler.setFormatter(JournalPrefixFormatter(log_format) if journal else logging.Formatter(log_format))
    logging.basicConfig(level=level, handlers=[handler])
    error = "<3>" if journal else ""
    try:
        return int(args.func(args) or 0)
    except CompanionError as exc:
        print(f"{error}companion {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a file or directory that cannot be read or written, a port in use
        print(f"{error}companion {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
