"""``companion campaign``: Monte Carlo safety campaign over randomised encounters.

Draws ``--episodes`` encounters of a ``--family`` from ``--seed``, flies each one with
every method of ``--methods`` in lockstep (mavsim plus the companion over MAVLink
bytes), in parallel over ``--workers`` processes, and prints one table row per method:
collisions with a 95 % Clopper-Pearson interval, the per-step collision frequency
against the bound ``Phi(-r_min)``, the share of steps below ``c_min``, goal reached,
time to goal, planner failures, slack use and solve times. ``--episode I`` re-runs
episode ``I`` alone (same encounter, same simulator seed).
"""

from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

from companion.commands._argtypes import integer_at_least, open_unit_interval, output_file, positive_seconds, seed
from companion.offline.campaign import DEFAULT_DURATION_S, FAMILIES, METHODS, format_table, run_campaign

logger = logging.getLogger(__name__)

QUIET_LOGGERS = ("mavsim", "estimator", "companion.loop.app", "companion.core.planner", "companion.mavlink.offboard", "companion.mavlink.link")


def _methods(text: str) -> list[str]:
    names = [m.strip() for m in text.split(",") if m.strip()]
    unknown = [m for m in names if m not in METHODS]
    if not names or unknown:
        raise argparse.ArgumentTypeError(f"unknown method(s) {', '.join(unknown) or '(none)'}; choose from {', '.join(METHODS)}")
    if len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(f"method listed twice: {text}")
    return names


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the ``campaign`` subcommand."""
    p = subparsers.add_parser("campaign", help="Monte Carlo safety campaign: randomised encounters, per method",
                              description=__doc__.split("\n\n")[1], formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--family", choices=FAMILIES, default="antipodal", help="kind of encounter")
    p.add_argument("--episodes", type=integer_at_least(1), default=20, help="number of episodes (indices 0..N-1)")
    p.add_argument("--methods", type=_methods, default=list(METHODS), help="comma-separated planner formulations",
                   metavar=",".join(METHODS))
    p.add_argument("--seed", type=seed, default=0, help="campaign seed (episode i uses default_rng([seed, i]))")
    p.add_argument("--workers", type=integer_at_least(1), default=None, help="worker processes (default: CPU count)")
    p.add_argument("--episode", type=integer_at_least(0), default=None, metavar="I",
                   help="run only episode I of this campaign (reproduce one encounter)")
    p.add_argument("--c-min", type=open_unit_interval, default=0.90, help="contour of touch that may not be crossed")
    p.add_argument("--duration", type=positive_seconds, default=DEFAULT_DURATION_S, help="simulated seconds per episode")
    p.add_argument("--json", type=output_file, metavar="FILE", help="write the summary and per-episode rows as JSON")
    p.add_argument("--plot", metavar="DIR", help="draw the campaign figures (PNG) into DIR")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run the campaign, print the table, write JSON and figures if asked."""
    if not getattr(args, "verbose", 0):
        # Collisions and planner trouble are what a campaign counts: report them in the
        # table, not as hundreds of log lines from the worker processes.
        for name in QUIET_LOGGERS:
            logging.getLogger(name).setLevel(logging.ERROR)
    episodes = [args.episode] if args.episode is not None else range(args.episodes)
    result = run_campaign(args.family, episodes, args.methods, args.seed, workers=args.workers,
                          c_min=args.c_min, duration_s=args.duration)
    print(format_table(result))
    if args.episode is not None:
        for row in result.results:
            print(json.dumps({k: v for k, v in row.items() if k not in ("solve_times_s", "truth")}, default=float))
    if args.json:
        path = Path(args.json)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(result.to_json(), indent=1, default=float, allow_nan=False))
        print(f"wrote {path}")
    if args.plot:
        for path in result.plot(args.plot):
            print(f"wrote {path}")
    return 0
