"""``companion identify LOG``: fit the vehicle's velocity response to a flight log (a tlog or a PX4 ULog).

Prints the fitted parameters (horizontal and vertical), the fit rms and the prediction
error one planner step ahead beside a first-order fit and the reference lag (0.3 s, the
planner's old model). ``--write-scenario FILE`` writes the ``[planner.vehicle_response]``
table, to append to a scenario that has none; with ``--into SCENARIO`` it writes a copy of
SCENARIO with its vehicle response replaced (or added) instead, checked to load. ``--plot DIR`` draws measured against modelled
velocity. Exit 2 with one line on a log that cannot be identified, e.g. one without a
velocity step of at least 0.5 m/s on each axis group.
"""

from __future__ import annotations

import argparse
import json
import logging
import re
from pathlib import Path

from companion.commands._argtypes import output_file, scenario_file, seconds_between
from companion.commands._defaults import IDENTIFY_HORIZON_RANGE_S, IDENTIFY_REFERENCE_LAG_RANGE_S
from companion.errors import CompanionError, ConfigError

logger = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "identify",
        help="fit the vehicle's velocity response (PI loop, drag, lag) to a tlog or PX4 ULog of OFFBOARD velocity steps",
        description=(
            "Read the velocity setpoints (SET_POSITION_TARGET_LOCAL_NED, velocity or position + velocity) and "
            "the vehicle's LOCAL_POSITION_NED (or ODOMETRY) of a tlog, keep the stretches in OFFBOARD, and fit "
            "the planner's vehicle response per axis. Fly `companion fly --identify --tlog steps.tlog` (or any "
            "OFFBOARD flight with velocity steps) to get such a log. A PX4 ULog (recognised by its magic; needs the "
            "view extra) gives the same from its vehicle_status, trajectory_setpoint and vehicle_local_position."
        ),
    )
    p.add_argument("log", metavar="LOG", help="a tlog, or a PX4 ULog (.ulg)")
    lo, hi = IDENTIFY_HORIZON_RANGE_S
    p.add_argument("--horizon", type=seconds_between(lo, hi), default=0.3, metavar="S",
                   help=f"prediction horizon of the fit and of the prediction error, seconds (the planner's step), "
                        f"{lo:g} to {hi:g} (default: %(default)s)")
    lo, hi = IDENTIFY_REFERENCE_LAG_RANGE_S
    p.add_argument("--reference-lag", type=seconds_between(lo, hi), default=0.3, metavar="S",
                   help=f"lag model to compare with, seconds, {lo:g} to {hi:g} (default: %(default)s)")
    p.add_argument("--write-scenario", type=output_file, default=None, metavar="FILE",
                   help="write the [planner.vehicle_response] table (TOML) to FILE, to append to a scenario without "
                        "one; with --into, a whole scenario")
    p.add_argument("--into", default=None, metavar="SCENARIO", type=scenario_file,
                   help="with --write-scenario: write a copy of SCENARIO (a .toml or a shipped scenario's name) with "
                        "its [planner] vehicle_response replaced by the identified one (comments and everything else kept)")
    p.add_argument("--plot", default=None, metavar="DIR", help="write the measured vs modelled velocity figure here")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=run)


def response_lines(result) -> list[str]:
    """The ``[planner]`` lines of an identification: ``vehicle_response.horizontal = {...}`` and ``.vertical``."""
    lines = []
    for name, axis in (("horizontal", result.horizontal), ("vertical", result.vertical)):
        body = ", ".join(f"{k} = {v:.4g}" for k, v in axis.as_dict().items())
        lines.append(f"vehicle_response.{name} = {{ {body} }}")
    return lines


def scenario_table(result) -> str:
    """What ``--write-scenario`` writes without ``--into``: the ``[planner.vehicle_response]`` table.

    It can be appended to a scenario that has no vehicle response; appended to one that has
    (``vehicle_response.horizontal = ...`` under ``[planner]``, as the shipped PX4 scenarios)
    it is a TOML error ("Cannot declare ('planner', 'vehicle_response') twice"): the comment
    says so and names ``--into``, which replaces it.
    """
    lines = ["# identified by `companion identify` "
             f"(one-step rms {result.figures['model']['one_step_rms_all']:.3f} m/s): append to a scenario without",
             "# a vehicle response; to replace one: companion identify LOG --into SCENARIO --write-scenario COPY",
             "[planner.vehicle_response]"]
    for name, axis in (("horizontal", result.horizontal), ("vertical", result.vertical)):
        body = ", ".join(f"{k} = {v:.4g}" for k, v in axis.as_dict().items())
        lines.append(f"{name} = {{ {body} }}")
    return "\n".join(lines) + "\n"


_HEADER = re.compile(r"^\s*\[\[?\s*([^\]]*?)\s*\]\]?\s*(#.*)?$")
_RESPONSE_KEY = re.compile(r"^\s*vehicle_response\s*[.=]")


def merge_into_scenario(text: str, lines: list[str], source: str = "<scenario>") -> str:
    """``text`` (a scenario file) with its ``[planner]`` vehicle response replaced by ``lines``.

    Removes the ``vehicle_response`` keys of ``[planner]`` (dotted or inline) and any
    ``[planner.vehicle_response...]`` tables, and puts ``lines`` where the first removed
    key was (else at the end of ``[planner]``, else in a new ``[planner]`` at the end).
    The result is checked: it parses, its vehicle response is ``lines``', and every other
    value is the original's.

    Raises
    ------
    ConfigError
        ``text`` is not TOML, or the edit did not give that result (names ``source``).
    """
    import tomllib

    try:
        before = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: not valid TOML: {exc}") from None
    out: list[str] = []
    section, dropping, insert_at, planner_end = None, False, None, None
    for line in text.splitlines():
        header = _HEADER.match(line)
        if header:
            if section == "planner" and planner_end is None:
                planner_end = len(out)
            section = header.group(1).replace(" ", "").replace('"', "")
            dropping = section == "planner.vehicle_response" or section.startswith("planner.vehicle_response.")
            if dropping:
                continue
        elif dropping:
            continue
        elif section == "planner" and _RESPONSE_KEY.match(line):
            if insert_at is None:
                insert_at = len(out)
            continue
        out.append(line)
    if section == "planner" and planner_end is None:
        planner_end = len(out)
    if insert_at is None and planner_end is not None:
        insert_at = planner_end
        while insert_at > 0 and not out[insert_at - 1].strip():
            insert_at -= 1                                 # before the blank lines that end [planner]
    if insert_at is None:
        out += ["", "[planner]"]
        insert_at = len(out)
    merged = "\n".join(out[:insert_at] + lines + out[insert_at:]) + "\n"
    try:
        after = tomllib.loads(merged)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: cannot put the vehicle response into it ({exc}); paste the lines by hand") from None
    wanted = tomllib.loads("\n".join(lines))["vehicle_response"]
    rest_before = {**before, "planner": {k: v for k, v in before.get("planner", {}).items() if k != "vehicle_response"}}
    rest_after = {**after, "planner": {k: v for k, v in after.get("planner", {}).items() if k != "vehicle_response"}}
    if after.get("planner", {}).get("vehicle_response") != wanted or rest_after != rest_before:
        raise ConfigError(f"{source}: cannot put the vehicle response into it (its layout is unusual); "
                          f"paste the lines by hand")
    return merged


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
    if args.into and not args.write_scenario:
        raise ConfigError("--into SCENARIO needs --write-scenario FILE (where to write the copy)")
    into_text = None
    if args.into:
        from companion.loop.config import read_scenario_toml

        read_scenario_toml(args.into)                      # one line naming it if missing, too large, not TOML
        into_text = Path(args.into).read_text(encoding="utf-8")
    from companion.offline.identify import GRID_S, IdentifyError, identify, load_response_log

    log = load_response_log(args.log)
    try:
        result = identify(log, reference_lag_s=args.reference_lag, horizon_s=args.horizon)
    except IdentifyError as exc:
        raise IdentifyError(f"{args.log}: {exc}") from None
    summary = {"log": args.log, "duration_s": result.duration_s, "setpoints": result.kinds,
               "horizontal": result.horizontal.as_dict(), "vertical": result.vertical.as_dict(),
               "figures": result.figures}
    if args.write_scenario:
        if into_text is not None:
            import tomllib

            from companion.loop.config import scenario_from_dict

            merged = merge_into_scenario(into_text, response_lines(result), args.into)
            try:
                scenario_from_dict(tomllib.loads(merged), args.into)
            except CompanionError as exc:
                raise ConfigError(f"the copy of {args.into} with the identified response does not load: {exc}") from None
            Path(args.write_scenario).write_text(merged)
        else:
            Path(args.write_scenario).write_text(scenario_table(result))
        summary["scenario_table"] = str(args.write_scenario)
    if args.plot:
        from companion.plots.identify_figure import plot_identification

        summary["figure"] = str(plot_identification(log, result, args.plot, reference_lag_s=args.reference_lag, dt=GRID_S))
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(_format(result, args))
        if args.write_scenario:
            print(f"scenario: {args.write_scenario} (a copy of {args.into} with this response)" if args.into
                  else f"scenario table: {args.write_scenario}")
        if args.plot:
            print(f"figure: {summary['figure']}")
    return 0
