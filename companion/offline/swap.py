"""The swap: N drones on a circle fly to the antipodal points, with moving traffic across.

After the circle scenario of the multi-MAV chance-constrained MPC literature: drone i
starts at angle ``2 pi i / N`` on a circle of ``radius_m`` about the centre (NED north,
east at ``altitude``) and flies to the opposite point, so every pair meets near the
centre. ``traffic`` adds two aircraft that cross the circle at 1.5 m/s on chords, as the
antipodal encounter's obstacles do (on their own obstacle link, ODOMETRY). Each drone's
scenario is the base file's (planner, estimator, loop, simulator) with its own start and
goal; the world (the traffic) is the same for all.

Pure: builds parsed-TOML dicts (:func:`companion.offline.harness.run_lockstep` and
:func:`companion.offline.fleet_harness.run_fleet_lockstep` take them).
"""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np

from companion.loop.config import read_scenario_toml

__all__ = ["swap_scenarios", "rotated_fleet", "DEFAULT_BASE", "SWAP_BASE", "DEFAULT_TRAFFIC"]

def _shipped(name: str) -> Path:
    """A shipped scenario file: the source tree's ``configs/`` when run from it, else the installed
    package's (``companion.scenarios``)."""
    here = Path(__file__).resolve().parents[2] / "configs" / name
    if here.is_file():
        return here
    from importlib import resources

    return Path(str(resources.files("companion.scenarios") / name))


#: The base scenario: the antipodal encounter's planner, estimator, loop and simulator settings.
DEFAULT_BASE = _shipped("antipodal.toml")
#: The swap's own scenario (``configs/swap.toml``: [fleet] settings, the traffic's template).
SWAP_BASE = _shipped("swap.toml")
_TRAFFIC_SPEED_MPS = 1.5


#: The crossing aircraft reach the circle this long after the start (s): the drones take off and
#: engage first (a few seconds in real time), so the traffic meets them on their way, not
#: hovering at their starts.
TRAFFIC_ENTERS_AFTER_S = 8.0


def _traffic(radius_m: float, altitude: float, template: dict, specs) -> list[dict]:
    """Aircraft crossing the circle on chords: each spec (bearing rad, offset in radii, speed m/s), reaching
    the circle :data:`TRAFFIC_ENTERS_AFTER_S` after the start and flying as far beyond it."""
    out = []
    for k, (bearing, offset, speed) in enumerate(specs):
        direction = np.array([math.cos(bearing), math.sin(bearing)])
        normal = np.array([-direction[1], direction[0]])
        inside = math.sqrt(max(radius_m ** 2 - (offset * radius_m) ** 2, 0.0))   # half the chord
        half = inside + speed * TRAFFIC_ENTERS_AFTER_S
        start = -half * direction + offset * radius_m * normal
        end = half * direction + offset * radius_m * normal
        ob = copy.deepcopy(template)
        ob.update(name=f"traffic-{k + 1}", start_ned_m=[float(start[0]), float(start[1]), altitude],
                  waypoints_ned_m=[[float(end[0]), float(end[1]), altitude]], speed_mps=float(speed))
        out.append(ob)
    return out


#: The default traffic: two aircraft on chords 0.35 radius off the centre, opposite ways, 1.5 m/s.
DEFAULT_TRAFFIC = ((math.radians(30.0), 0.35, _TRAFFIC_SPEED_MPS), (math.radians(210.0), 0.35, _TRAFFIC_SPEED_MPS))


def swap_scenarios(n: int, *, radius_m: float = 6.0, altitude: float = -5.0, traffic: bool = True,
                   base: str | Path | dict = DEFAULT_BASE, duration_s: float | None = None,
                   rotation_rad: float = 0.0, traffic_specs=None) -> list[dict]:
    """The N drones' scenarios (parsed-TOML dicts), drone i's at index i.

    Parameters
    ----------
    n : drones, 2 to 16.
    radius_m : the circle's radius, m (> 1).
    altitude : NED down of the circle, m (negative: above the origin).
    traffic : aircraft crossing the circle (else no obstacles but the drones themselves).
    base : scenario file or parsed dict the settings come from (its obstacles are replaced;
        the first is the template of the traffic's message and noise).
    duration_s : the run's length (default: the base's).
    rotation_rad : drone i starts at angle ``rotation_rad + 2 pi i / n`` (from north, towards east).
    traffic_specs : the crossing aircraft as (bearing rad, offset in radii, speed m/s) each
        (default :data:`DEFAULT_TRAFFIC`).
    """
    if not 2 <= int(n) <= 16:
        raise ValueError(f"a swap needs 2 to 16 drones, got {n}")
    if not radius_m > 1.0:
        raise ValueError(f"the swap's radius must be > 1 m, got {radius_m}")
    data = copy.deepcopy(base) if isinstance(base, dict) else read_scenario_toml(base)
    template = (data.get("world", {}).get("obstacles") or [{}])[0]
    world = dict(data.get("world", {}))
    specs = DEFAULT_TRAFFIC if traffic_specs is None else tuple(traffic_specs)
    world["obstacles"] = _traffic(radius_m, altitude, template, specs) if traffic else []
    out = []
    for i in range(int(n)):
        angle = rotation_rad + 2.0 * math.pi * i / n
        start = [radius_m * math.cos(angle), radius_m * math.sin(angle), altitude]
        goal = [-start[0], -start[1], altitude]
        d = copy.deepcopy(data)
        d["scenario"] = {**d.get("scenario", {}), "name": f"swap{n}-drone{i + 1}",
                         "description": f"drone {i + 1} of {n} swapping across a {2 * radius_m:g} m circle"}
        if duration_s is not None:
            d["scenario"]["duration_s"] = float(duration_s)
        d["vehicle"] = {**d.get("vehicle", {}), "start_ned_m": [round(x, 6) for x in start]}
        d["mission"] = {**d.get("mission", {}), "goal_ned_m": [round(x, 6) for x in goal]}
        d["world"] = copy.deepcopy(world)
        out.append(d)
    return out


def rotated_fleet(data: dict, n: int) -> list[dict]:
    """N copies of one drone's scenario (parsed TOML), drone i's start and goal rotated by
    ``2 pi i / N`` about the vertical through the midpoint of the scenario's start and goal
    (:func:`mavsim.fleet.rotated`, as ``mavsim --vehicles N`` places its vehicles).

    With the start and goal on opposite sides of a circle (``configs/swap.toml``) this is the
    swap; the world (obstacles, walls) is the same for all. Drone i is named ``NAME-i+1``.
    """
    if not 1 <= int(n) <= 16:
        raise ValueError(f"a fleet of 1 to 16 drones, got {n}")
    from mavsim.fleet import rotated   # the same rotation as mavsim --vehicles N

    start0 = data.get("vehicle", {}).get("start_ned_m", [0.0, 0.0, 0.0])
    out = []
    for i in range(int(n)):
        start, goal = rotated(start0, data["mission"]["goal_ned_m"], i, int(n))
        d = copy.deepcopy(data)
        name = d.get("scenario", {}).get("name", "fleet")
        d["scenario"] = {**d.get("scenario", {}), "name": f"{name}-{i + 1}"}
        d["vehicle"] = {**d.get("vehicle", {}), "start_ned_m": [round(float(x), 6) for x in start]}
        d["mission"] = {**d["mission"], "goal_ned_m": [round(float(x), 6) for x in goal]}
        out.append(d)
    return out
