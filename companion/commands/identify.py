"""``companion identify LOG.tlog``: fit the vehicle's velocity response to a flight log.

Prints the fitted parameters (horizontal and vertical), the fit rms and the prediction
error one planner step ahead beside a first-order fit and the reference lag (0.3 s, the
planner's old model). ``--write-scenario FILE`` writes the ``[planner.vehicle_response]``
table to paste into (or merge with) a scenario; ``--plot DIR`` draws measured against
modelled velocity. Exit 2 with one line on a log that cannot be identified.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from companion.offline.identify import GRID_S, identify, load_response_log

logger = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "identify",
        help="fit the vehicle's velocity response (PI loop, drag, lag) to a tlog of OFFBOARD velocity steps",
        description=(
            "Read the velocity setpoints (SET_POSITION_TARGET_LOCAL_NED, velocity or position + velocity) and "
            "the vehicle's LOCAL_POSITION_NED (or ODOMETRY) of a tlog, keep the stretches in OFFBOARD, and fit "
            "the planner's vehicle response per axis. Fly `companion fly --identify --tlog steps.tlog` (or any "
            "OFFBOARD flight with velocity steps) to get such a log."
        ),
    )
    p.add_argument("log", metavar="LOG.tlog")
    p.add_argument("--horizon", type=float, default=0.3, metavar="S",
                   help="prediction horizon of the fit and of the prediction error, seconds (the planner's step)")
    p.add_argument("--reference-lag", type=float, default=0.3, metavar="S", help="lag model to compare with, seconds")
    p.add_argument("--write-scenario", default=None, metavar="FILE",
                   help="write the [planner.vehicle_response] table (TOML) to FILE")
    p.add_argument("--plot", default=None, metavar="DIR", help="write the measured vs modelled velocity figure here")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=run)


def scenario_table(result) -> str:
    """The ``[planner.vehicle_response]`` TOML table of an identification."""
    lines = ["# identified by `companion identify` "
             f"(one-step rms {result.figures['model']['one_step_rms_all']:.3f} m/s)",
             "[planner.vehicle_response]"]
    for name, axis in (("horizontal", result.horizontal), ("vertical", result.vertical)):
        body = ", ".join(f"{k} = {v:.4g}" for k, v in axis.as_dict().items())
        lines.append(f"{name} = {{ {body} }}")
    return "\n".join(lines) + "\n"


def _format(result, args) -> str:
    out = [f"log {args.log}: {result.duration_s:.1f} s in OFFBOARD; setpoints "
           + ", ".join(f"{k} {v}" for k, v in result.kinds.items())]
    for name, axis in (("horizontal", result.horizontal), ("vertical", result.vertical)):
        out.append(f"{name:10s}  " + "  ".join(f"{k} {v:.3f}" for k, v in axis.as_dict().items()))
    out.append("")
    head = f"{'model':18s} {'fit rms h/v/all [m/s]':>24s}   {f'{args.horizon:g} s-ahead rms h/v/all [m/s]':>30s}"
    out.append(head)
    for label, row in result.figures.items():
        fit = "/".join(f"{row[f'fit_rms_{g}']:.3f}" for g in ("horizontal", "vertical", "all"))
        one = "/".join(f"{row[f'one_step_rms_{g}']:.3f}" for g in ("horizontal", "vertical", "all"))
        out.append(f"{label:18s} {fit:>24s}   {one:>30s}")
    ref = result.figures[f"lag {args.reference_lag:g} s"]
    mod = result.figures["model"]
    out.append("prediction error of the lag / of the model: " + ", ".join(
        f"{g} {ref[f'one_step_rms_{g}'] / mod[f'one_step_rms_{g}']:.1f}x" for g in ("horizontal", "vertical", "all")))
    return "\n".join(out)


def run(args: argparse.Namespace) -> int:
    log = load_response_log(args.log)
    result = identify(log, reference_lag_s=args.reference_lag, horizon_s=args.horizon)
    summary = {"log": args.log, "duration_s": result.duration_s, "setpoints": result.kinds,
               "horizontal": result.horizontal.as_dict(), "vertical": result.vertical.as_dict(),
               "figures": result.figures}
    if args.write_scenario:
        Path(args.write_scenario).write_text(scenario_table(result))
        summary["scenario_table"] = args.write_scenario
    if args.plot:
        from companion.plots.identify_figure import plot_identification

        summary["figure"] = str(plot_identification(log, result, args.plot, reference_lag_s=args.reference_lag, dt=GRID_S))
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(_format(result, args))
        if args.write_scenario:
            print(f"scenario table: {args.write_scenario}")
        if args.plot:
            print(f"figure: {summary['figure']}")
    return 0
