"""What a flight's flags make of its scenario: one reading shared by ``fly`` and ``replay``.

``fly`` flies with these flags; ``replay`` must be given the same ones to reproduce what
the companion commanded (a tlog holds the wire traffic, not the flags), so both commands
build the offboard settings, planner overrides and goal from them here, the same way.
"""

from __future__ import annotations

import argparse
import dataclasses

from companion.commands._argtypes import fence_file, goal_spec, integer_at_least, mission_source
from companion.errors import ConfigError
from companion.commands._defaults import TAKEOVER_CHOICES


def add_recorded_flight_flags(p: argparse.ArgumentParser) -> None:
    """``replay``'s copies of ``fly``'s flags that change what the companion commands
    (``--arm``, ``--takeoff-alt``, ``--exit-after-goal`` and ``--formulation`` are registered by ``replay`` itself)."""
    p.add_argument("--goal", type=goal_spec, default=None, metavar="FRAME:A,B,C",
                   help="the recorded run's --goal (fly --goal)")
    p.add_argument("--mission", type=mission_source, default=None, metavar="FILE|vehicle",
                   help="the recorded run's --mission (fly --mission; 'vehicle': the download is in the log)")
    p.add_argument("--fence", type=fence_file, default=None, metavar="FILE|vehicle",
                   help="the recorded run's --fence (fly --fence)")
    p.add_argument("--target-system", type=integer_at_least(1), default=None, metavar="N",
                   help="the recorded run named its vehicle (fly --target-system N)")
    p.add_argument("--autopilot", choices=("auto", "px4", "ardupilot"), default=None,
                   help="the recorded run's --autopilot")
    p.add_argument("--reengage", action="store_true", help="the recorded run re-requested OFFBOARD (fly --reengage)")
    p.add_argument("--no-c-max", action="store_true", help="the recorded run dropped c_max (fly --no-c-max)")
    p.add_argument("--takeover", choices=TAKEOVER_CHOICES, default=None, help="the recorded run's --takeover")


def planner_overrides(args: argparse.Namespace) -> dict:
    """Scenario overrides from ``--formulation`` and ``--no-c-max``."""
    overrides: dict = {"formulation": args.formulation} if args.formulation else {}
    if args.no_c_max:
        overrides["c_max"] = None
    return overrides


def goal_given(args: argparse.Namespace) -> bool:
    """Whether the flags say where to fly (``--goal`` or ``--mission``): the scenario then needs no goal."""
    return args.goal is not None or args.mission is not None


def offboard_settings(scenario_offboard, args: argparse.Namespace, mission=None):
    """The scenario's ``[offboard]`` with the flags applied (a flag wins over the file); with the
    scenario's ``[mission]`` (``mission``), a takeover that needs a mission is refused without one."""
    if args.goal is not None and args.mission is not None:
        raise ConfigError("--goal and --mission: give one of them")
    takeover = scenario_offboard.takeover if getattr(args, "takeover", None) is None else args.takeover
    if takeover != "always" and mission is not None and args.mission is None and mission.plan_file is None:
        raise ConfigError(f"--takeover {takeover} needs a mission to watch: --mission FILE|vehicle, or [mission] plan_file")
    if takeover != "always":
        for flag, value in (("--exit-after-goal", args.exit_after_goal), ("--takeoff-alt", args.takeoff_alt)):
            if value is not None:
                raise ConfigError(f"{flag} does not go with --takeover {takeover}: the autopilot's mission takes off "
                                  "and ends the flight")
    return dataclasses.replace(
        scenario_offboard,
        arm=args.arm or scenario_offboard.arm,
        takeoff_alt_m=scenario_offboard.takeoff_alt_m if args.takeoff_alt is None else args.takeoff_alt,
        reengage=args.reengage or scenario_offboard.reengage,
        hold_after_goal_s=args.exit_after_goal,
        target_system=scenario_offboard.target_system if args.target_system is None else args.target_system,
        autopilot=scenario_offboard.autopilot if args.autopilot is None else args.autopilot,
        takeover=takeover,
    )


def goal_keywords(args: argparse.Namespace, scenario) -> dict:
    """``Companion`` keywords for ``--goal``, ``--mission`` and ``--fence`` (none: the scenario's ``[mission]``)."""
    fence = getattr(args, "fence", None)
    if args.goal is None and args.mission is None and fence is None:
        return {}
    from companion.loop.fence_source import FenceSource
    from companion.loop.goal import PlacedGoal
    from companion.loop.mission_goal import MissionGoal
    from companion.loop.vehicle_reference import VehicleReference

    reference = VehicleReference()
    out: dict = {"reference": reference}
    if fence == "vehicle":
        out["fence"] = FenceSource.from_vehicle(reference, scenario.mission.goal_wait_s)
    elif fence is not None:
        out["fence"] = FenceSource(fence, reference, scenario.mission.goal_wait_s, fence.source)
    if args.goal is not None:
        out["goal"] = PlacedGoal(scenario.mission, reference, args.goal)
    elif args.mission is not None:
        plan = None if args.mission == "vehicle" else args.mission
        out["goal"] = MissionGoal(scenario.mission, reference, plan)
        if fence is None and plan is not None and (plan.polygons or plan.circles):
            out["fence"] = FenceSource(plan, reference, scenario.mission.goal_wait_s, plan.source)
    return out
