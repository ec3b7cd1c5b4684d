"""The vehicle side of the MAVLink mission protocol: mission, fence and rally items stored and served.

As PX4 answers a ground station: MISSION_REQUEST_LIST -> MISSION_COUNT; MISSION_REQUEST_INT
(or MISSION_REQUEST) -> MISSION_ITEM_INT; an upload MISSION_COUNT(n) is answered with
MISSION_REQUEST_INT(0), each MISSION_ITEM_INT in order with the request for the next, and
the last with MISSION_ACK (ACCEPTED, the items then replace the stored ones); MISSION_COUNT 0
and MISSION_CLEAR_ALL clear; MISSION_SET_CURRENT is answered with MISSION_CURRENT. Refused
with a MISSION_ACK naming why: more than :data:`MAX_ITEMS` (NO_SPACE), an item in a frame
PX4 does not take for its type (UNSUPPORTED_FRAME), an item out of sequence during an
upload (INVALID_SEQUENCE, answered with the request again as PX4 does). Not yet: the
vehicle's own re-requests after a timeout. :func:`local_items` gives a personality the stored
mission in local NED to fly (PX4's AUTO.MISSION: :mod:`mavsim.personalities.px4_mission`).
Pure: no clock; messages in, messages out.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

logger = logging.getLogger(__name__)

MAX_ITEMS = 1000
#: Frames whose altitude is relative to home (GLOBAL_RELATIVE_ALT, its _INT twin); the others AMSL.
_RELATIVE_FRAMES = frozenset({3, 6})
#: Frames PX4 stores mission items in (global AMSL / relative, int or not, and MISSION for DO_ items).
_MISSION_FRAMES = frozenset({0, 2, 3, 5, 6})


class MissionStore:
    """Stored items per MAV_MISSION_TYPE and the upload in progress (see the module docstring)."""

    def __init__(self) -> None:
        self.items: dict[int, list] = {0: [], 1: [], 2: []}
        self.current = 0
        self._upload: dict[int, tuple[int, list]] = {}   # mission_type -> (count, items so far)

    def handle(self, msg) -> list:
        """Answers to one mission-protocol message (its sender is the target of each)."""
        t = msg.get_type()
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        kind = int(getattr(msg, "mission_type", 0))
        if kind not in self.items:
            return [mavlink2.MAVLink_mission_ack_message(*src, mavlink2.MAV_MISSION_UNSUPPORTED, kind)]
        if t == "MISSION_REQUEST_LIST":
            return [mavlink2.MAVLink_mission_count_message(*src, len(self.items[kind]), kind)]
        if t in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            stored = self.items[kind]
            if not 0 <= msg.seq < len(stored):
                return [mavlink2.MAVLink_mission_ack_message(*src, mavlink2.MAV_MISSION_INVALID_SEQUENCE, kind)]
            m = stored[msg.seq]
            return [mavlink2.MAVLink_mission_item_int_message(
                *src, m.seq, m.frame, m.command, int(m.seq == self.current and kind == 0), m.autocontinue,
                m.param1, m.param2, m.param3, m.param4, m.x, m.y, m.z, kind)]
        if t == "MISSION_COUNT":
            if msg.count == 0:
                self.items[kind] = []
                return [mavlink2.MAVLink_mission_ack_message(*src, mavlink2.MAV_MISSION_ACCEPTED, kind)]
            if msg.count > MAX_ITEMS:
                return [mavlink2.MAVLink_mission_ack_message(*src, mavlink2.MAV_MISSION_NO_SPACE, kind)]
            self._upload[kind] = (int(msg.count), [])
            return [mavlink2.MAVLink_mission_request_int_message(*src, 0, kind)]
        if t == "MISSION_ITEM_INT":
            if kind not in self._upload:
                return []
            count, got = self._upload[kind]
            if msg.seq != len(got):
                return [mavlink2.MAVLink_mission_request_int_message(*src, len(got), kind)]
            if kind == 0 and msg.frame not in _MISSION_FRAMES:
                del self._upload[kind]
                return [mavlink2.MAVLink_mission_ack_message(*src, mavlink2.MAV_MISSION_UNSUPPORTED_FRAME, kind)]
            got.append(msg)
            if len(got) < count:
                return [mavlink2.MAVLink_mission_request_int_message(*src, len(got), kind)]
            del self._upload[kind]
            self.items[kind] = got
            if kind == 0:
                self.current = 0
            logger.info("mission type %d: %d items stored", kind, count)
            return [mavlink2.MAVLink_mission_ack_message(*src, mavlink2.MAV_MISSION_ACCEPTED, kind)]
        if t == "MISSION_CLEAR_ALL":
            self.items[kind] = []
            self._upload.pop(kind, None)
            return [mavlink2.MAVLink_mission_ack_message(*src, mavlink2.MAV_MISSION_ACCEPTED, kind)]
        if t == "MISSION_SET_CURRENT":
            if 0 <= msg.seq < len(self.items[0]):
                self.current = int(msg.seq)
            return [mavlink2.MAVLink_mission_current_message(self.current, len(self.items[0]))]
        return []


@dataclass(frozen=True)
class MissionItem:
    """One stored mission item with its position in local NED (m)."""

    seq: int
    command: int
    params: tuple[float, float, float, float]
    position_ned_m: np.ndarray


def local_items(items: list, home: tuple[float, float, float], earth_radius_m: float) -> list[MissionItem]:
    """The stored MISSION_ITEM_INT messages as :class:`MissionItem` about ``home`` (lat deg, lon deg,
    alt m AMSL): the flat-earth map mavsim's telemetry uses, inverted. Positions are taken as
    they are (latitude and longitude 0 is a point off Africa, as for PX4)."""
    lat0, lon0, alt0 = home
    cos_lat = math.cos(math.radians(lat0))
    out = []
    for m in items:
        north = math.radians(m.x * 1e-7 - lat0) * earth_radius_m
        east = math.radians(m.y * 1e-7 - lon0) * earth_radius_m * cos_lat
        down = -float(m.z) if m.frame in _RELATIVE_FRAMES else alt0 - float(m.z)
        out.append(MissionItem(int(m.seq), int(m.command), (float(m.param1), float(m.param2), float(m.param3),
                                                             float(m.param4)), np.array([north, east, down])))
    return out
