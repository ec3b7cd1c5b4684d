"""Missions for tests: a QGroundControl .plan made from local NED waypoints about mavsim's origin."""

from __future__ import annotations

import json

import numpy as np

from companion.loop.goal_frames import GeoPoint, to_geodetic

#: mavsim's default home, which is also its local origin.
MAVSIM_ORIGIN = GeoPoint(47.397742, 8.545594, 488.0)


def plan_dict(waypoints_ned, *, origin: GeoPoint = MAVSIM_ORIGIN, takeoff_alt_m: float | None = 5.0,
              final: int | None = 20, acceptance_m: float = 1.0, extra_items=()) -> dict:
    """A .plan (as a dict) flying ``waypoints_ned`` (altitudes relative to home = origin)."""
    items = []
    if takeoff_alt_m is not None:
        items.append({"type": "SimpleItem", "command": 22, "frame": 3, "autoContinue": True, "doJumpId": 1,
                      "params": [0, 0, 0, None, origin.lat_deg, origin.lon_deg, takeoff_alt_m]})
    for n, e, d in waypoints_ned:
        p = to_geodetic(np.array([n, e, d], dtype=float), origin)
        items.append({"type": "SimpleItem", "command": 16, "frame": 3, "autoContinue": True,
                      "doJumpId": len(items) + 1, "params": [0, acceptance_m, 0, None, p.lat_deg, p.lon_deg, -d]})
    items.extend(extra_items)
    if final is not None:
        items.append({"type": "SimpleItem", "command": final, "frame": 2, "autoContinue": True,
                      "doJumpId": len(items) + 1, "params": [0, 0, 0, 0, 0, 0, 0]})
    return {"fileType": "Plan", "version": 1, "groundStation": "QGroundControl",
            "mission": {"version": 2, "firmwareType": 12, "vehicleType": 2, "cruiseSpeed": 15, "hoverSpeed": 5,
                        "items": items, "plannedHomePosition": [origin.lat_deg, origin.lon_deg, origin.alt_m]},
            "geoFence": {"version": 2, "polygons": [], "circles": []},
            "rallyPoints": {"version": 2, "points": []}}


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
