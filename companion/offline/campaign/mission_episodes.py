"""Randomised missions for guard-mode campaigns (family ``mission``): episode ``index`` of seed ``S``.

Episode ``i`` draws from ``np.random.default_rng([S, i, MISSION_STREAM])`` and its simulator
seed is :func:`~companion.offline.campaign.generate.episode_sim_seed`, so any episode is
re-run by its index alone. An episode is what an operator uploads and what crosses it:

- **the mission**: the drone hovers 5 m up at the origin (armed, in Hold); 3 to 5 waypoints
  5 m up, legs of 15 to 30 m turning 60 to 150 degrees either way, each reached within 1 m;
  a DO_CHANGE_SPEED first, 2 to 3 m/s (the autopilot's cruise, which the guard reads from
  the mission: ``[mission] autopilot_speed_mps`` is left at its default);
- **the geofence**: an inclusion rectangle 5 to 8 m round the route and, in
  :data:`BUILDING_SHARE` of episodes, a building (an exclusion square of 4 to 6 m, at least
  :data:`BUILDING_CLEARANCE_M` from the start and every waypoint) across
  one leg, 35 to 65 % along it and up to 1 m off its line: the autopilot alone flies into it;
- **the traffic**: 1 to 3 aircraft, each across a random leg 25 to 75 % along it at 45 to 135
  degrees, 0.5 to 2 m/s, timed to be there when the autopilot is predicted there (its
  cruise along the legs from :data:`START_S`, :data:`CORNER_S` a waypoint) give or take
  :data:`TIMING_SPREAD_S`: some meet it, some pass ahead or behind; none before
  :data:`MIN_CROSSING_S`, none parked near a waypoint or beside another leg (:func:`_crossing`). One in three reports by
  ADS-B through the autopilot, the others on the obstacle link (ODOMETRY).

Planner, estimator and companion settings are the shipped survey's (``configs/mission_survey.toml``:
N = 28, tau = 0.3 s, speed 3 m/s, sensing 10 m). NED metres, seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from companion.core.fence import Fence, PolygonZone
from companion.loop.goal_frames import GeoPoint
from companion.offline.campaign.generate import random_covariance
from companion.offline.plan_document import plan_document

#: the generator's stream tag: the mission family draws apart from the encounter families' (S, i)
MISSION_STREAM = 35
ALTITUDE_M = -5.0
LEGS = (3, 5)
LEG_M = (15.0, 30.0)
TURN_DEG = (60.0, 150.0)
CRUISE_MPS = (2.0, 3.0)
ACCEPTANCE_M = 1.0
END_CLEARANCE_M = 6.0
GOAL_TOLERANCE_M = 1.5
FENCE_MARGIN_M = (5.0, 8.0)
BUILDING_SHARE = 0.6
BUILDING_SIDE_M = (4.0, 6.0)
#: no building nearer the start or a waypoint than this (m): a waypoint beside a wall is not
#: reached within its acceptance radius with the drone's body and c_min contour kept off the wall,
#: and a mission starting beside one has the autopilot at the wall before OFFBOARD is in
BUILDING_CLEARANCE_M = 4.0
TRAFFIC = (1, 3)
TRAFFIC_SPEED_MPS = (0.5, 2.0)
ADSB_SHARE = 1.0 / 3.0
#: When the autopilot is at a point of its mission, as the generator times the traffic (s): the
#: mission starts START_S after the run does, and each waypoint costs CORNER_S over the legs at cruise.
#: Fitted on mavsim's PX4 mission flown alone (episodes 0-9 of seed 1: each waypoint reached within
#: 1.1 s of this; mavsim reaches a 1 m waypoint without slowing much, where PX4 SITL turns to face
#: the next leg first, some 8 s a corner: docs/MISSIONS.md).
START_S = 0.5
CORNER_S = 0.0
TIMING_SPREAD_S = 2.0
#: how long before its crossing an aircraft starts moving (s; it flies as far on past it)
LEAD_S = (4.0, 8.0)
#: no crossing earlier in the run than this (s), no aircraft parked nearer the route's points than this (m)
MIN_CROSSING_S = 10.0
SPAWN_CLEARANCE_M = 6.0
RADIUS_RANGE_M = (0.3, 0.6)
DRONE_RADIUS_M = (0.3, 0.5)
MEAS_VAR_RANGE_M2 = (0.005, 0.06)
#: mavsim's home, the missions' origin (the .plan's positions are geodetic about it)
ORIGIN = GeoPoint(47.397742, 8.545594, 488.0)


@dataclass(frozen=True)
class MissionEpisode:
    """One drawn episode: the scenario (TOML tables; ``[mission] plan_file`` still to be set to
    where :attr:`plan` is written), the .plan, and what was drawn (NED m, s)."""

    scenario: dict
    plan: dict
    waypoints: np.ndarray                        #: (K, 3)
    cruise_mps: float
    fence: list[tuple[np.ndarray, bool]]         #: (ring (M, 2) N/E, inclusion?)
    crossings: list[dict] = field(default_factory=list)   #: per aircraft: leg, point, predicted time, offset


def _unit(angle: float) -> np.ndarray:
    return np.array([math.cos(angle), math.sin(angle), 0.0])


def predicted_times(start: np.ndarray, waypoints: np.ndarray, cruise_mps: float) -> np.ndarray:
    """When the autopilot reaches each waypoint (s after the run starts), as the generator predicts it."""
    points = np.vstack([start, waypoints])
    legs = np.linalg.norm(np.diff(points, axis=0), axis=1)
    return START_S + np.cumsum(legs / cruise_mps) + CORNER_S * np.arange(len(legs))


def _square(centre: np.ndarray, along: np.ndarray, side: float) -> np.ndarray:
    """A square (4, 2) N/E of ``side`` metres about ``centre``, its sides along and across ``along``."""
    u = along[:2] / np.linalg.norm(along[:2])
    v = np.array([-u[1], u[0]])
    h = 0.5 * side
    return np.array([centre[:2] + h * (a * u + b * v) for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])


def _segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    ab = b - a
    f = float(np.clip(np.dot(p - a, ab) / max(float(np.dot(ab, ab)), 1e-12), 0.0, 1.0))
    return float(np.linalg.norm(p - (a + f * ab)))


def _parked_clearance(route: np.ndarray, leg: int, p: np.ndarray) -> float:
    """How far (m, horizontally) an aircraft crossing leg ``leg`` of ``route`` parks at ``p`` from
    the route's points and from every other leg."""
    flat = route[:, :2]
    near = float(np.min(np.linalg.norm(flat - p[:2], axis=1)))
    others = [_segment_distance(p[:2], flat[k], flat[k + 1]) for k in range(len(flat) - 1) if k != leg]
    return min([near, *others])


def _route(rng: np.random.Generator, start: np.ndarray, tries: int = 200) -> np.ndarray:
    """The start and the waypoints (K + 1, 3), redrawn until the last waypoint is at least
    :data:`END_CLEARANCE_M` from every earlier leg: the referee's goal is the last waypoint, which
    the vehicle must not pass on the way."""
    for _ in range(tries):
        heading = rng.uniform(0.0, 2.0 * math.pi)
        points = [start]
        for k in range(int(rng.integers(LEGS[0], LEGS[1] + 1))):
            if k:
                heading += math.radians(rng.uniform(*TURN_DEG)) * rng.choice((-1.0, 1.0))
            points.append(points[-1] + rng.uniform(*LEG_M) * _unit(heading))
        if all(_segment_distance(points[-1], points[k], points[k + 1]) >= END_CLEARANCE_M for k in range(len(points) - 2)):
            return np.array(points)
    raise RuntimeError(f"could not draw a mission after {tries} draws")


def _crossing(rng: np.random.Generator, route: np.ndarray, leg_start_s: np.ndarray, cruise: float, tries: int = 200):
    """One aircraft's crossing: (leg, point, predicted time there, timing offset, direction, speed,
    run-up m), or None after ``tries`` draws.

    Redrawn until the autopilot is predicted there at least :data:`MIN_CROSSING_S` into the run
    (the guard has a horizon to see it come) and the aircraft waits for its start, and parks at
    its end, at least :data:`SPAWN_CLEARANCE_M` from the drone's start, from every waypoint and
    from every other leg: a parked aircraft must not sit on a waypoint, nor launch from beside a
    leg as the drone flies it (the tracker's model of traffic that hardly manoeuvres cannot
    foresee a start from rest, and no guard could avoid it)."""
    for _ in range(tries):
        leg = int(rng.integers(len(route) - 1))
        a, b = route[leg], route[leg + 1]
        f = float(rng.uniform(0.25, 0.75))
        point = a + f * (b - a)
        there = float(leg_start_s[leg] + f * np.linalg.norm(b - a) / cruise)
        offset = float(rng.uniform(-TIMING_SPREAD_S, TIMING_SPREAD_S))
        heading = math.atan2((b - a)[1], (b - a)[0])
        direction = _unit(heading + math.radians(rng.uniform(45.0, 135.0)) * rng.choice((-1.0, 1.0)))
        speed = float(rng.uniform(*TRAFFIC_SPEED_MPS))
        run_up = speed * float(rng.uniform(*LEAD_S))
        if there < MIN_CROSSING_S or any(_parked_clearance(route, leg, end) < SPAWN_CLEARANCE_M
                                         for end in (point - run_up * direction, point + run_up * direction)):
            continue
        return leg, point, there, offset, direction, speed, run_up
    return None   # the mission's geometry leaves no room: the caller draws another


def _draw(rng: np.random.Generator, start: np.ndarray):
    """One draw of the mission, its fence and its traffic: (route, cruise, fence, predicted times at
    the waypoints, obstacles, crossings), or None when an aircraft found no crossing on it."""
    route = _route(rng, start)
    waypoints = route[1:]
    cruise = float(rng.uniform(*CRUISE_MPS))
    margin = float(rng.uniform(*FENCE_MARGIN_M))
    lo, hi = route[:, :2].min(axis=0) - margin, route[:, :2].max(axis=0) + margin
    fence: list[tuple[np.ndarray, bool]] = [(np.array([lo, [lo[0], hi[1]], hi, [hi[0], lo[1]]]), True)]
    if rng.random() < BUILDING_SHARE:
        leg = int(rng.integers(len(waypoints)))
        a, b = route[leg], route[leg + 1]
        across = np.array([-(b - a)[1], (b - a)[0], 0.0]) / np.linalg.norm((b - a)[:2])
        centre = a + rng.uniform(0.35, 0.65) * (b - a) + rng.uniform(-1.0, 1.0) * across
        square = _square(centre, b - a, float(rng.uniform(*BUILDING_SIDE_M)))
        building = Fence(polygons=(PolygonZone(square, False),))
        if min(building.clearance(q) for q in route) < BUILDING_CLEARANCE_M:
            return None
        fence.append((square, False))

    at = predicted_times(start, waypoints, cruise)
    before = np.concatenate([[START_S], at[:-1] + CORNER_S])      # when each leg starts
    obstacles, crossings = [], []
    for k in range(int(rng.integers(TRAFFIC[0], TRAFFIC[1] + 1))):
        found = _crossing(rng, route, before, cruise)
        if found is None:
            return None
        leg, point, there, offset, direction, speed, run_up = found
        adsb = bool(rng.random() < ADSB_SHARE)
        ob = {"name": f"crossing-{k + 1}", "radius_m": float(rng.uniform(*RADIUS_RANGE_M)),
              "start_ned_m": (point - run_up * direction).tolist(),
              "waypoints_ned_m": [(point + run_up * direction).tolist()], "speed_mps": speed,
              "start_delay_s": round(max(0.0, there + offset - run_up / speed), 3)}
        if adsb:
            ob.update(transport="adsb", measurement_cov_m2=(0.5 * np.eye(3)).tolist(), report_rate_hz=2.0)
        else:
            ob.update(transport="link", message="ODOMETRY", report_rate_hz=10.0,
                      measurement_cov_m2=random_covariance(rng, *MEAS_VAR_RANGE_M2).tolist())
        obstacles.append(ob)
        crossings.append({"leg": leg, "point_ned_m": point.tolist(), "predicted_s": there, "offset_s": offset,
                          "transport": ob["transport"]})
    return route, cruise, fence, at, obstacles, crossings


def generate_mission(seed: int, index: int, *, c_min: float = 0.90, tries: int = 50) -> MissionEpisode:
    """Draw episode ``index`` of a mission campaign with ``seed`` (see the module docstring): the
    mission, fence and traffic are drawn again, from the same stream, until every aircraft has a
    crossing (:func:`_crossing`)."""
    rng = np.random.default_rng([int(seed), int(index), MISSION_STREAM])
    start = np.array([0.0, 0.0, ALTITUDE_M])
    for _ in range(tries):
        drawn = _draw(rng, start)
        if drawn is not None:
            break
    else:
        raise RuntimeError(f"could not draw mission episode {index} of seed {seed} after {tries} draws")
    route, cruise, fence, at, obstacles, crossings = drawn
    waypoints = route[1:]

    duration = float(at[-1] * 1.5 + 30.0)
    plan = plan_document(waypoints, origin=ORIGIN, takeoff_alt_m=None, final=None, acceptance_m=ACCEPTANCE_M,
                         speed_mps=cruise, fence=fence)
    scenario = {
        "scenario": {"name": f"mission-{seed}-{index}", "duration_s": duration,
                     "description": f"campaign mission, seed {seed}, episode {index}: {len(waypoints)} waypoints, "
                                    f"{len(fence) - 1} building(s), {len(obstacles)} aircraft"},
        "vehicle": {"radius_m": float(rng.uniform(*DRONE_RADIUS_M)), "start_ned_m": start.tolist()},
        # the referee's goal is the last waypoint: the autopilot holds where it reached it, within 1 m
        "mission": {"goal_tolerance_m": GOAL_TOLERANCE_M, "waypoint_spacing_m": 12.0},
        "planner": {"formulation": "hyperplane", "horizon_steps": 28, "step_s": 0.3, "replan_period_s": 0.3,
                    "c_min": float(c_min), "velocity_max_mps": [3.0, 3.0, 1.0], "accel_max_mps2": [0.5, 0.5, 0.5],
                    "velocity_time_constant_s": 0.3, "sensing_range_m": 10.0, "weight_progress": 0.3},
        "estimator": {"drone": {"accel_noise_psd_m2ps3": 0.5}, "tracker": {"accel_noise_psd_m2ps3": 0.01}},
        "companion": {"setpoint_rate_hz": 20.0, "obstacle_radius_m": RADIUS_RANGE_M[1], "brake_accel_mps2": 2.0},
        "traffic": {"autopilot_link_kinds": ["ADSB_VEHICLE"], "position_std_m": 1.0, "vertical_std_m": 1.0,
                    "velocity_std_mps": 1.0},
        "sim": {"velocity_time_constant_s": 0.3, "accel_max_mps2": 4.0,
                "position_noise_cov_m2": (0.02 * np.eye(3)).tolist(),
                "velocity_noise_cov_m2ps2": (0.01 * np.eye(3)).tolist()},
        "world": {"obstacles": obstacles},
    }
    return MissionEpisode(scenario, plan, waypoints, cruise, fence, crossings)
