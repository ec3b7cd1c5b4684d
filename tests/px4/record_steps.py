"""Fly velocity steps against a live PX4 (SITL or vehicle) in OFFBOARD and record a tlog for identification.

Usage::

    python -m tests.px4.record_steps OUT.tlog [--connect udpin:127.0.0.1:14540] [--takeoff-alt 5]

The same flight as ``companion fly --identify --arm --takeoff-alt 5 --tlog OUT.tlog``
(:mod:`companion.commands.fly_identify`), kept under this name for the PX4 SITL notes.
"""

from __future__ import annotations

import argparse
import logging
import sys

from companion.commands.fly_identify import fly_identification


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("tlog")
    ap.add_argument("--connect", default="udpin:127.0.0.1:14540")
    ap.add_argument("--takeoff-alt", type=float, default=5.0)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(relativeCreated)8.0f %(message)s")
    report = fly_identification(args.connect, args.tlog, arm=True, takeoff_alt_m=args.takeoff_alt)
    logging.info("done: %s", report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
