"""A ground station on PX4 SITL's ground link, as QGroundControl talks to it: home, missions, fences.

For the PX4 SITL tests and measurements that prepare the vehicle as an operator would before the
companion starts: wait for HOME_POSITION (PX4 acknowledges a mission uploaded before home with 0,
then refuses MISSION_START, "No valid mission"), then upload a mission and a fence with the
mission protocol (MISSION_COUNT, MISSION_REQUEST_INT answered by MISSION_ITEM_INT, MISSION_ACK).

:func:`plan_items` turns a QGroundControl ``.plan`` (its JSON as a dict) into the items QGC
sends: mission items with the plan's frame, command and params (a ``null`` param sent as NaN,
latitude and longitude in 1e-7 degrees); fence polygons as one item per vertex (command 5001
inclusion, 5002 exclusion, param1 the vertex count, frame GLOBAL) and circles as one item each
(5003 inclusion, 5004 exclusion, param1 the radius in metres).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink2

GCS_URL = "udpin:127.0.0.1:14550"       # PX4's ground-station link (it sends from 18570)
REQUEST_MESSAGE = 512                   # MAV_CMD_REQUEST_MESSAGE
HOME_POSITION_ID = 242


@dataclass(frozen=True)
class Item:
    """One MISSION_ITEM_INT's fields (x, y: latitude and longitude in 1e-7 degrees)."""

    command: int
    frame: int
    params: tuple[float, float, float, float]
    x: int
    y: int
    z: float
    autocontinue: int = 1


def _param(value) -> float:
    return math.nan if value is None else float(value)


def plan_items(plan: dict) -> tuple[list[Item], list[Item]]:
    """The mission items and the fence items of a ``.plan`` dict, as QGroundControl uploads them."""
    mission = []
    for it in plan["mission"]["items"]:
        p = [_param(v) for v in it["params"]]
        lat, lon = (0.0 if math.isnan(v) else v for v in p[4:6])
        mission.append(Item(int(it["command"]), int(it["frame"]), tuple(p[:4]), round(lat * 1e7), round(lon * 1e7),
                            0.0 if math.isnan(p[6]) else p[6], int(bool(it.get("autoContinue", True)))))
    fence = []
    geo = plan.get("geoFence") or {}
    for zone in geo.get("polygons", []):
        cmd = (mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION if zone["inclusion"]
               else mavlink2.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION)
        ring = zone["polygon"]
        fence += [Item(cmd, mavlink2.MAV_FRAME_GLOBAL, (len(ring), 0.0, 0.0, 0.0), round(lat * 1e7), round(lon * 1e7), 0.0)
                  for lat, lon in ring]
    for zone in geo.get("circles", []):
        cmd = (mavlink2.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION if zone["inclusion"]
               else mavlink2.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION)
        (lat, lon), radius = zone["circle"]["center"], zone["circle"]["radius"]
        fence.append(Item(cmd, mavlink2.MAV_FRAME_GLOBAL, (float(radius), 0.0, 0.0, 0.0), round(lat * 1e7),
                          round(lon * 1e7), 0.0))
    return mission, fence


class GroundStation:
    """A pymavlink connection on PX4's ground link (system 255, component 190), closed on exit."""

    def __init__(self, url: str = GCS_URL, target: tuple[int, int] = (1, 1)) -> None:
        from pymavlink import mavutil

        self.target = target
        self.conn = mavutil.mavlink_connection(url, source_system=255, source_component=190)

    def __enter__(self) -> GroundStation:
        return self

    def __exit__(self, *exc) -> None:
        self.conn.close()

    def wait_heartbeat(self, timeout_s: float = 30.0) -> None:
        if self.conn.wait_heartbeat(timeout=timeout_s) is None:
            raise AssertionError(f"no HEARTBEAT on PX4's ground link within {timeout_s} s")

    def wait_home(self, timeout_s: float = 60.0) -> tuple[float, float, float]:
        """HOME_POSITION (requested every second): latitude, longitude (deg), altitude AMSL (m)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.conn.mav.command_long_send(*self.target, REQUEST_MESSAGE, 0, HOME_POSITION_ID, 0, 0, 0, 0, 0, 0)
            msg = self.conn.recv_match(type="HOME_POSITION", blocking=True, timeout=1)
            if msg is not None:
                return msg.latitude * 1e-7, msg.longitude * 1e-7, msg.altitude * 1e-3
        raise AssertionError(f"no HOME_POSITION within {timeout_s} s")

    def upload(self, items: list[Item], mission_type: int = mavlink2.MAV_MISSION_TYPE_MISSION,
               timeout_s: float = 20.0) -> int:
        """Upload ``items`` with the mission protocol; PX4's MISSION_ACK result (0: accepted)."""
        self.conn.mav.mission_count_send(*self.target, len(items), mission_type)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            msg = self.conn.recv_match(type=["MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"], blocking=True,
                                       timeout=1)
            if msg is None or getattr(msg, "mission_type", 0) != mission_type:
                continue
            if msg.get_type() == "MISSION_ACK":
                return int(msg.type)
            it = items[msg.seq]
            self.conn.mav.mission_item_int_send(*self.target, msg.seq, it.frame, it.command, 0, it.autocontinue,
                                                *it.params, it.x, it.y, it.z, mission_type)
        raise AssertionError(f"no MISSION_ACK (mission type {mission_type}) within {timeout_s} s")
