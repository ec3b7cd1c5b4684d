"""Run ``companion`` with this process's system clock stepped, as a time sync steps it.

    python -m tests.support.stepped_clock --step 5:+30 --step 9:-60 -- fly --connect ...

Each ``--step AT:BY`` adds BY seconds to what ``time.time()`` and ``time.time_ns()`` return,
from AT seconds (monotonic) after the start on. The machine's clock is not touched: only
this process, and the planning process it forks, see the steps (the test's mavsim does not).
"""

from __future__ import annotations

import argparse
import sys
import time


def stepped(steps: list[tuple[float, float]]):
    """(time, time_ns) replacements that add each step's seconds once its moment has passed."""
    real_time, real_time_ns, start = time.time, time.time_ns, time.monotonic()

    def offset_s() -> float:
        elapsed = time.monotonic() - start
        return sum(by for at, by in steps if elapsed >= at)

    return (lambda: real_time() + offset_s()), (lambda: real_time_ns() + round(offset_s() * 1e9))


def _step(text: str) -> tuple[float, float]:
    at, _, by = text.partition(":")
    return float(at), float(by)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.support.stepped_clock")
    parser.add_argument("--step", type=_step, action="append", default=[], metavar="AT:BY")
    parser.add_argument("command", nargs=argparse.REMAINDER)
    args = parser.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    time.time, time.time_ns = stepped(args.step)
    from companion.cli import main as companion

    return companion(command)


if __name__ == "__main__":
    sys.exit(main())
