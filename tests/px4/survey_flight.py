"""PX4 SITL flies the survey mission an operator uploaded; the companion guards it, watches it, or flies it.

Usage (measurements for the notes; not part of ``.ci/run``)::

    python -m tests.px4.survey_flight WORK_DIR [--takeover guard|watch|always] [--alone] [--runs 5] [--json FILE]

Each run starts PX4 SIH in a fresh directory (``MPC_XY_CRUISE`` 3 m/s, the survey's leg speed),
waits for its HOME_POSITION and uploads, on its ground link as QGroundControl does
(:mod:`tests.px4.gcs`), ``configs/mission_survey.plan``'s mission with a landing at the last
waypoint added, and its fence (an inclusion rectangle and a building, an exclusion zone on the
third leg). Then mavsim's traffic player plays :data:`TRAFFIC` (one aircraft on the companion's
obstacle link across the first leg, one as ADS-B through PX4 across the last leg, SIH's truth)
and ``companion fly --mission vehicle --fence vehicle --takeover MODE --arm`` runs: it downloads
both, arms PX4, starts the mission and guards it (takes over on a predicted conflict, gives
back once clear), only watches it (PX4 flies alone: the baseline), or flies it all in OFFBOARD.
The traffic starts moving when SIH's truth has the vehicle 4.3 m up (the first leg about to
begin).

Reported per run: the companion's exit and report (conflicts, takeovers with their
decision-to-OFFBOARD time, items reached and by whom, the smallest realised contour), PX4's
modes, texts and failsafes, the flight's duration (PX4's arming to its disarming), PX4's own mode switches
from its log, the closest true approach to each aircraft and the smallest true distance of
the drone's body inside the fence. About 2 minutes a run.
"""

from __future__ import annotations

import argparse
import json
import sys
import tomllib
from pathlib import Path

import numpy as np

from companion.loop.fence_source import place_fence
from companion.loop.mission_file import parse_plan
from companion.offline.campaign.toml_writer import write_scenario
from mavsim.scenario import load_scenario
from mavsim.traffic import PlayerLinks, TrafficPlayer
from tests.px4.flight import OBSTACLE_PORT
from tests.px4.gcs import GroundStation, plan_items
from tests.px4.guard_flight import mode_switch_latency
from tests.px4.sitl import PARAMS, REPO, Sitl
from tests.px4.traffic_run import companion_report, fly_beside_traffic, px4_words, runs_main

PLAN = REPO / "configs" / "mission_survey.plan"
SCENARIO = REPO / "configs" / "mission_survey.toml"
PX4_SCENARIO = REPO / "configs" / "antipodal_px4.toml"
CRUISE_MPS = 3.0
COMPANION_TIMEOUT_S = 200.0
LANDING_WAIT_S = 60.0
DRONE_RADIUS_M = 0.5
LAND = 21

#: The traffic, as the scenario's [[world.obstacles]] (NED m about PX4's origin, times from the
#: moment the vehicle is 4.3 m up). Timed on PX4 flying alone (``--takeover watch``): it reached
#: N 20 on the first leg 10 s after that moment; each corner took it about 8 s (it turns to face
#: the next leg first), so the last leg's N 20 comes some 70 s after it, later with takeovers: the
#: second aircraft flies a long shallow diagonal against the last leg (10 degrees across it, at
#: 0.5 m/s) and is within 2 m of the leg's line for 48 s about its crossing.
LEG1_CROSSING = {"transport": "link", "message": "ODOMETRY", "name": "crossing-leg-1", "radius_m": 0.5,
                 "start_ned_m": [20.0, -12.0, -5.0], "waypoints_ned_m": [[20.0, 26.0, -5.0]], "speed_mps": 1.5,
                 "measurement_cov_m2": (0.02 * np.eye(3)).tolist(), "report_rate_hz": 10.0}
LEG5_CROSSING = {"transport": "adsb", "name": "crossing-leg-5", "radius_m": 0.5,
                 "start_ned_m": [44.0, 24.0, -5.0], "waypoints_ned_m": [[-4.0, 16.0, -5.0]], "speed_mps": 0.5,
                 "measurement_cov_m2": (0.5 * np.eye(3)).tolist(), "report_rate_hz": 2.0}


def files(work: Path, leg1_s: float = 10.0, leg5_s: float = 78.0, traffic: bool = True) -> tuple[Path, dict]:
    """The scenario and the .plan (with a landing added) of a run, the scenario written into ``work``.

    The scenario is mission_survey's [scenario], [vehicle], [mission] (without its plan file: the
    mission is the vehicle's) and [traffic], with antipodal_px4's planner, estimator, companion and
    offboard settings (PX4's identified response, its estimate taken as it is, its drift), and the
    two aircraft timed to reach the middle of their crossings at ``leg1_s`` and ``leg5_s`` (none
    without ``traffic``).
    """
    survey = tomllib.loads(SCENARIO.read_text())
    px4 = tomllib.loads(PX4_SCENARIO.read_text())
    data = {k: survey[k] for k in ("scenario", "vehicle", "mission", "traffic")}
    data["mission"] = {k: v for k, v in data["mission"].items() if k != "plan_file"}
    data.update({k: px4[k] for k in ("planner", "estimator", "companion", "offboard")})
    first = dict(LEG1_CROSSING, start_delay_s=round(leg1_s - 12.0 / LEG1_CROSSING["speed_mps"], 2))
    half = 0.5 * float(np.linalg.norm(np.subtract(LEG5_CROSSING["start_ned_m"], LEG5_CROSSING["waypoints_ned_m"][0])))
    last = dict(LEG5_CROSSING, start_delay_s=round(leg5_s - half / LEG5_CROSSING["speed_mps"], 2))
    # (the traffic player needs one aircraft: without traffic, one parked 140 m away, never started)
    parked = dict(LEG1_CROSSING, name="parked", start_ned_m=[-100.0, -100.0, -5.0], waypoints_ned_m=[[-100.0, -90.0, -5.0]])
    data["world"] = {"obstacles": [first, last] if traffic else [parked]}
    scenario = write_scenario(data, work / "survey_px4.toml")
    plan = json.loads(PLAN.read_text())
    items = plan["mission"]["items"]
    wp = items[-1]["params"]
    items.append({"type": "SimpleItem", "command": LAND, "frame": 3, "autoContinue": True, "doJumpId": len(items) + 1,
                  "params": [0, 0, 0, None, wp[4], wp[5], 0]})
    return scenario, plan


def prepare_vehicle(plan: dict) -> dict:
    """Home awaited, then the mission and the fence uploaded on PX4's ground link as QGroundControl does."""
    mission, fence = plan_items(plan)
    with GroundStation() as gcs:
        gcs.wait_heartbeat()
        home = gcs.wait_home()
        return {"home": home, "mission_ack": gcs.upload(mission), "fence_ack": gcs.upload(fence, mission_type=1),
                "mission_items": len(mission), "fence_items": len(fence)}


def fly_survey(work: Path, seed: int = 0, takeover: str = "guard", alone: bool = False) -> dict:
    """One run (see the module docstring); its figures. ``alone``: PX4 flies the mission by itself
    (watched), with no traffic and no building in its fence: the baseline of the flight's duration."""
    work.mkdir(parents=True, exist_ok=True)
    scenario, plan = files(work, traffic=not alone)
    if alone:
        takeover = "watch"
        plan["geoFence"]["polygons"] = [z for z in plan["geoFence"]["polygons"] if z["inclusion"]]
    tlog = work / "flight.tlog"
    result: dict = {"work": str(work), "takeover": takeover, "alone": alone}
    with Sitl(work / "sih", params={**PARAMS, "MPC_XY_CRUISE": CRUISE_MPS}):
        result["upload"] = prepare_vehicle(plan)
        player = TrafficPlayer(load_scenario(scenario), PlayerLinks(obstacle_port=OBSTACLE_PORT), seed=seed,
                               start="manual", keep_samples=True)
        with player:
            # the flight's end is PX4's (a landing handed to it): listen until it disarms
            proc = fly_beside_traffic(player, [
                "--connect", "udpin:127.0.0.1:14540", "--scenario", str(scenario), "--mission", "vehicle",
                "--fence", "vehicle", "--takeover", takeover, "--arm", "--obstacles",
                f"udpin:127.0.0.1:{OBSTACLE_PORT}", "--tlog", str(tlog), "--duration", str(COMPANION_TIMEOUT_S - 20),
                "--json"], timeout_s=COMPANION_TIMEOUT_S, move_traffic=not alone, until_disarmed_s=LANDING_WAIT_S)
    result.update(companion_report(proc, work, (
        "outcome", "phase", "mission_items_reached", "mission_items_reached_by", "autopilot_items_reached",
        "watch_conflicts", "takeovers", "min_realised_contour", "replans_with_slack", "failed_plans",
        "min_fence_clearance_m", "setpoint_gap_max_ms")))
    result.update(px4_words(player))
    truth_t = np.array([t for t, _ in player.samples["truth"]])
    truth_p = np.array([p for _, p in player.samples["truth"]]).reshape(-1, 3)
    np.savez(work / "truth.npz", t=truth_t, p=truth_p, engaged=result["engaged_at_s"] or np.nan)
    if player.origin is not None and truth_p.size:
        fence = place_fence(parse_plan(json.dumps(plan)), *player.origin[:2])
        airborne = truth_p[-(truth_p[:, 2] - truth_p[0, 2]) > 1.0]
        result["min_true_fence_clearance_m"] = round(min(fence.clearance(p) for p in airborne) - DRONE_RADIUS_M, 3) \
            if len(airborne) else None
    # the flight's duration in PX4's words, whoever flew it: from its arming to its disarming
    armed = [t for t, text in player.texts if text.startswith("Armed")]
    disarmed = [t for t, text in player.texts if text.startswith("Disarmed")]
    result["flight_s"] = round(disarmed[-1] - armed[0], 2) if armed and disarmed else None
    result["mode_switch_after_s"] = mode_switch_latency(work / "sih", tlog)
    return result


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--takeover", choices=("guard", "watch", "always"), default="guard")
    p.add_argument("--alone", action="store_true",
                   help="PX4 flies the mission alone (watched): no traffic, no building in the fence")
    return runs_main(p, lambda work, k, args: fly_survey(work, seed=k, takeover=args.takeover, alone=args.alone), argv)


if __name__ == "__main__":
    sys.exit(main())
