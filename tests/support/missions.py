"""Missions for tests: a QGroundControl .plan made from local NED waypoints about mavsim's origin."""

from __future__ import annotations

import json

from companion.loop.goal_frames import GeoPoint
from companion.offline.plan_document import plan_document

#: mavsim's default home, which is also its local origin.
MAVSIM_ORIGIN = GeoPoint(47.397742, 8.545594, 488.0)


def plan_dict(waypoints_ned, *, origin: GeoPoint = MAVSIM_ORIGIN, takeoff_alt_m: float | None = 5.0,
              final: int | None = 20, acceptance_m: float = 1.0, extra_items=()) -> dict:
    """A .plan (as a dict) flying ``waypoints_ned`` (altitudes relative to home = origin)."""
    return plan_document(waypoints_ned, origin=origin, takeoff_alt_m=takeoff_alt_m, final=final,
                         acceptance_m=acceptance_m, extra_items=extra_items)


def plan_text(waypoints_ned, **kw) -> str:
    return json.dumps(plan_dict(waypoints_ned, **kw), indent=2)


def crossing_plan_text(waypoints_ned, *, speed_mps: float = 1.5, final: int | None = 20) -> str:
    """A .plan: take-off to 5 m, DO_CHANGE_SPEED ``speed_mps``, the waypoints, then ``final`` (20
    return; 21 a landing where the last waypoint is: a LAND at latitude 0 would fly there; None:
    nothing, the mission ends at its last waypoint)."""
    data = plan_dict(waypoints_ned, final=final)
    items = data["mission"]["items"]
    items.insert(1, {"type": "SimpleItem", "command": 178, "frame": 2, "autoContinue": True,
                     "params": [1, speed_mps, -1, 0, 0, 0, 0]})
    if final == 21:
        items[-1]["params"][4:6] = items[-2]["params"][4:6]
        items[-1]["frame"] = 3
    for k, item in enumerate(items):
        item["doJumpId"] = k + 1
    return json.dumps(data, indent=1)
