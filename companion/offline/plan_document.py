"""A QGroundControl ``.plan`` written from local NED waypoints and fence rings about a geodetic origin.

What the campaigns and the tests upload or hand to ``companion fly --mission``: the document
QGroundControl saves (``fileType`` Plan, mission version 2, geofence version 2), its items in
``MAV_FRAME_GLOBAL_RELATIVE_ALT`` (3) with altitudes above home = the origin, read back by
:func:`companion.loop.mission_file.parse_plan`. Positions go through the inverse of PX4's own
map (:func:`companion.loop.goal_frames.to_geodetic`), so a waypoint placed again about the same
origin comes back where it was given.

Pure: no clock, no I/O.
"""

from __future__ import annotations

from typing import Iterable, Sequence

import numpy as np

from companion.loop.goal_frames import GeoPoint, to_geodetic

NAV_WAYPOINT, NAV_TAKEOFF, DO_CHANGE_SPEED = 16, 22, 178
#: MAV_FRAME_GLOBAL_RELATIVE_ALT (positions) and MAV_FRAME_MISSION (items without one)
FRAME_RELATIVE_ALT, FRAME_MISSION = 3, 2


def speed_item(speed_mps: float) -> dict:
    """DO_CHANGE_SPEED to ``speed_mps`` (m/s, ground speed) as a .plan item."""
    return {"type": "SimpleItem", "command": DO_CHANGE_SPEED, "frame": FRAME_MISSION, "autoContinue": True,
            "params": [1, float(speed_mps), -1, 0, 0, 0, 0]}


def plan_document(waypoints_ned: Iterable[Sequence[float]], *, origin: GeoPoint, takeoff_alt_m: float | None = 5.0,
                  final: int | None = 20, acceptance_m: float = 1.0, extra_items: Iterable[dict] = (),
                  speed_mps: float | None = None,
                  fence: Iterable[tuple[np.ndarray, bool]] = ()) -> dict:
    """A .plan (as a dict) flying ``waypoints_ned`` (N, E, D metres about ``origin``; altitudes
    relative to home = ``origin``).

    Items in order: a NAV_TAKEOFF to ``takeoff_alt_m`` above home (None: none), a DO_CHANGE_SPEED to
    ``speed_mps`` (None: none), the waypoints (acceptance radius ``acceptance_m``), ``extra_items``
    (their ``doJumpId`` as given), then ``final`` (a MAV_CMD such as 20 return or 21 land; None: nothing). ``fence``: polygons as
    (ring of (N, E) vertices in metres, inclusion?).
    """
    items: list[dict] = []
    if takeoff_alt_m is not None:
        items.append({"type": "SimpleItem", "command": NAV_TAKEOFF, "frame": FRAME_RELATIVE_ALT, "autoContinue": True,
                      "params": [0, 0, 0, None, origin.lat_deg, origin.lon_deg, float(takeoff_alt_m)]})
    if speed_mps is not None:
        items.append(speed_item(speed_mps))
    for n, e, d in waypoints_ned:
        p = to_geodetic(np.array([n, e, d], dtype=float), origin)
        items.append({"type": "SimpleItem", "command": NAV_WAYPOINT, "frame": FRAME_RELATIVE_ALT, "autoContinue": True,
                      "params": [0, float(acceptance_m), 0, None, p.lat_deg, p.lon_deg, -float(d)]})
    for k, item in enumerate(items):
        item["doJumpId"] = k + 1
    items.extend(dict(item) for item in extra_items)      # numbered as given
    if final is not None:
        items.append({"type": "SimpleItem", "command": int(final), "frame": FRAME_MISSION, "autoContinue": True,
                      "doJumpId": len(items) + 1, "params": [0, 0, 0, 0, 0, 0, 0]})
    polygons = []
    for ring, inclusion in fence:
        points = [to_geodetic(np.array([n, e, 0.0], dtype=float), origin) for n, e in np.asarray(ring, dtype=float)]
        polygons.append({"inclusion": bool(inclusion), "version": 1, "polygon": [[p.lat_deg, p.lon_deg] for p in points]})
    return {"fileType": "Plan", "version": 1, "groundStation": "QGroundControl",
            "mission": {"version": 2, "firmwareType": 12, "vehicleType": 2, "cruiseSpeed": 15, "hoverSpeed": 5,
                        "items": items, "plannedHomePosition": [origin.lat_deg, origin.lon_deg, origin.alt_m]},
            "geoFence": {"version": 2, "polygons": polygons, "circles": []},
            "rallyPoints": {"version": 2, "points": []}}
