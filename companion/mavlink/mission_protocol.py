"""The MAVLink mission protocol (download and upload of mission items) as pure state machines.

Download (what a ground station does to read the vehicle's mission)::

    MISSION_REQUEST_LIST -> MISSION_COUNT(n) -> MISSION_REQUEST_INT(0) -> MISSION_ITEM_INT(0)
        -> ... MISSION_REQUEST_INT(n-1) -> MISSION_ITEM_INT(n-1) -> MISSION_ACK(ACCEPTED)

Upload (what it does to write one)::

    MISSION_COUNT(n) -> MISSION_REQUEST_INT(0) (or MISSION_REQUEST) -> MISSION_ITEM_INT(0)
        -> ... -> MISSION_ACK(result) from the vehicle

Each machine is driven by the vehicle's messages (:meth:`on_message`) and link time
(:meth:`step`); both return the messages to send, and nothing reads a clock or a socket
(like :mod:`companion.mavlink.offboard`). Timeouts and retries follow the protocol's
defaults (MAVLink's mission protocol page: 1500 ms for an item, a few retries): the last
message sent is repeated after ``timeout_s`` of silence, at most ``retries`` times, then
the transfer fails with a reason that says which step never got an answer. A
MISSION_ACK with an error ends a transfer at once, named (e.g. ``MAV_MISSION_UNSUPPORTED_FRAME``).

:class:`MissionItem` is one item as MISSION_ITEM_INT carries it (``x``/``y`` latitude and
longitude in degrees here, the wire's degE7 on encoding).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink2

logger = logging.getLogger(__name__)

#: The vehicle's messages in a download (what answers MISSION_REQUEST_LIST and each item request;
#: MISSION_ITEM for old autopilots).
DOWNLOAD_REPLIES = frozenset({"MISSION_COUNT", "MISSION_ITEM_INT", "MISSION_ITEM", "MISSION_ACK"})
#: The vehicle's messages in an upload (its item requests and the final ack).
UPLOAD_REQUESTS = frozenset({"MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"})
#: Every message of the protocol a vehicle sends to a client.
VEHICLE_MESSAGES = DOWNLOAD_REPLIES | UPLOAD_REQUESTS
#: The client's answers, each sent on receipt of a vehicle's message: an upload's items, a
#: download's item requests and its ack.
CLIENT_ANSWERS = frozenset({"MISSION_ITEM_INT", "MISSION_ITEM", "MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"})

#: MAV_MISSION_TYPE
MISSION = mavlink2.MAV_MISSION_TYPE_MISSION
FENCE = mavlink2.MAV_MISSION_TYPE_FENCE
RALLY = mavlink2.MAV_MISSION_TYPE_RALLY
#: The protocol's default timeout for one step, and its retries.
TIMEOUT_S = 1.5
RETRIES = 5
#: Largest mission accepted (PX4 stores up to a few thousand items; a bigger count is a bad message).
MAX_ITEMS = 2000

#: MAV_FRAMEs whose x/y are latitude/longitude.
GLOBAL_FRAMES = frozenset({
    mavlink2.MAV_FRAME_GLOBAL, mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink2.MAV_FRAME_GLOBAL_INT,
    mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
})
RELATIVE_FRAMES = frozenset({mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT})


@dataclass(frozen=True)
class MissionItem:
    """One mission item: MAV_CMD ``command`` in MAV_FRAME ``frame``, ``params`` 1..4, and x, y, z
    (latitude and longitude in degrees for a global frame, altitude in metres)."""

    seq: int
    frame: int
    command: int
    params: tuple[float, float, float, float] = (0.0, 0.0, 0.0, math.nan)
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0
    current: int = 0
    autocontinue: int = 1
    mission_type: int = MISSION

    def to_message(self, target_system: int, target_component: int) -> mavlink2.MAVLink_mission_item_int_message:
        """MISSION_ITEM_INT for this item (global x/y as degE7)."""
        if self.frame in GLOBAL_FRAMES:
            x, y = int(round(self.x * 1e7)), int(round(self.y * 1e7))
        else:
            x, y = int(round(self.x * 1e4)), int(round(self.y * 1e4))  # local: metres * 1e4
        p = [float(v) for v in self.params]
        return mavlink2.MAVLink_mission_item_int_message(
            target_system, target_component, self.seq, self.frame, self.command, self.current, self.autocontinue,
            p[0], p[1], p[2], p[3], x, y, float(self.z), self.mission_type)

    @classmethod
    def from_message(cls, msg) -> "MissionItem":
        """The item a MISSION_ITEM_INT carries."""
        frame = int(msg.frame)
        scale = 1e-7 if frame in GLOBAL_FRAMES else 1e-4
        return cls(seq=int(msg.seq), frame=frame, command=int(msg.command),
                   params=(float(msg.param1), float(msg.param2), float(msg.param3), float(msg.param4)),
                   x=int(msg.x) * scale, y=int(msg.y) * scale, z=float(msg.z), current=int(msg.current),
                   autocontinue=int(msg.autocontinue), mission_type=int(getattr(msg, "mission_type", MISSION)))


def result_name(result: int) -> str:
    """MAV_MISSION_RESULT's name (``MAV_MISSION_ACCEPTED``), or the number."""
    entry = mavlink2.enums["MAV_MISSION_RESULT"].get(int(result))
    return entry.name if entry is not None else f"MAV_MISSION_RESULT {result}"


class _Transfer:
    """What download and upload share: the target, the retry clock, the end."""

    kind = "transfer"

    def __init__(self, target: tuple[int, int], mission_type: int, timeout_s: float, retries: int) -> None:
        self.target = target
        self.mission_type = mission_type
        self.timeout_s = float(timeout_s)
        self.retries = int(retries)
        self.done = False
        #: why the transfer failed (None while running or once done)
        self.failed: str | None = None
        self.resent = 0          #: messages repeated after a timeout, in all
        self._last: mavlink2.MAVLink_message | None = None
        self._last_t = -math.inf
        self._tries = 0
        self._waiting_for = ""

    @property
    def over(self) -> bool:
        return self.done or self.failed is not None

    def _send(self, t_s: float, msg, waiting_for: str) -> list:
        self._last, self._last_t, self._tries, self._waiting_for = msg, t_s, 0, waiting_for
        return [msg]

    def _fail(self, why: str) -> list:
        self.failed = f"mission {self.kind} failed: {why}"
        logger.warning("%s", self.failed)
        return []

    def step(self, t_s: float) -> list:
        """Messages to send at link time ``t_s``: a repeat after a timeout, or nothing."""
        if self.over or self._last is None or t_s - self._last_t < self.timeout_s - 1e-9:
            return []
        if self._tries >= self.retries:
            return self._fail(f"no {self._waiting_for} after {self.retries + 1} tries of {self.timeout_s:g} s")
        self._tries += 1
        self.resent += 1
        self._last_t = t_s
        logger.info("mission %s: no %s in %.1f s, repeating (%d/%d)", self.kind, self._waiting_for,
                    self.timeout_s, self._tries, self.retries)
        return [self._last]

    def _ours(self, msg) -> bool:
        """Whether ``msg`` is from the target and of this transfer's mission type."""
        return ((msg.get_srcSystem(), msg.get_srcComponent()) == self.target
                and int(getattr(msg, "mission_type", MISSION)) == self.mission_type)


class MissionDownload(_Transfer):
    """Read the vehicle's items of one mission type (see the module docstring); :attr:`items` when done."""

    kind = "download"

    def __init__(self, target: tuple[int, int], mission_type: int = MISSION, *, timeout_s: float = TIMEOUT_S,
                 retries: int = RETRIES) -> None:
        super().__init__(target, mission_type, timeout_s, retries)
        self.count: int | None = None
        self.items: list[MissionItem] = []

    def start(self, t_s: float) -> list:
        """MISSION_REQUEST_LIST, at link time ``t_s``."""
        return self._send(t_s, mavlink2.MAVLink_mission_request_list_message(*self.target, self.mission_type),
                          "MISSION_COUNT")

    def on_message(self, t_s: float, msg) -> list:
        """Take one inbound message (others' and other kinds are ignored); what to send in answer."""
        if self.over or not self._ours(msg):
            return []
        mtype = msg.get_type()
        if mtype == "MISSION_ACK":
            return self._fail(f"the vehicle answered {result_name(msg.type)}")
        if mtype == "MISSION_COUNT" and self.count is None:
            if not 0 <= int(msg.count) <= MAX_ITEMS:
                return self._fail(f"MISSION_COUNT {msg.count} (at most {MAX_ITEMS})")
            self.count = int(msg.count)
            return self._next(t_s)
        if mtype == "MISSION_ITEM_INT" and self.count is not None and int(msg.seq) == len(self.items):
            self.items.append(MissionItem.from_message(msg))
            return self._next(t_s)
        return []  # a duplicate, or an item we did not ask for: the retry asks again

    def _next(self, t_s: float) -> list:
        assert self.count is not None
        if len(self.items) < self.count:
            seq = len(self.items)
            return self._send(t_s, mavlink2.MAVLink_mission_request_int_message(*self.target, seq, self.mission_type),
                              f"MISSION_ITEM_INT {seq}")
        self.done, self._last = True, None
        logger.info("mission download: %d items", self.count)
        return [mavlink2.MAVLink_mission_ack_message(*self.target, mavlink2.MAV_MISSION_ACCEPTED, self.mission_type)]


class MissionUpload(_Transfer):
    """Write ``items`` to the vehicle (see the module docstring); :attr:`done` once it acknowledged them."""

    kind = "upload"

    def __init__(self, target: tuple[int, int], items: list[MissionItem], mission_type: int = MISSION, *,
                 timeout_s: float = TIMEOUT_S, retries: int = RETRIES) -> None:
        super().__init__(target, mission_type, timeout_s, retries)
        self.items = [MissionItem(**{**vars(item), "seq": i, "mission_type": mission_type}) for i, item in enumerate(items)]
        self.requested: set[int] = set()

    def start(self, t_s: float) -> list:
        """MISSION_COUNT, at link time ``t_s``."""
        return self._send(t_s, mavlink2.MAVLink_mission_count_message(*self.target, len(self.items), self.mission_type),
                          "MISSION_REQUEST_INT 0" if self.items else "MISSION_ACK")

    def on_message(self, t_s: float, msg) -> list:
        """Take one inbound message; the item asked for, or nothing."""
        if self.over or not self._ours(msg):
            return []
        mtype = msg.get_type()
        if mtype == "MISSION_ACK":
            if int(msg.type) != mavlink2.MAV_MISSION_ACCEPTED:
                return self._fail(f"the vehicle answered {result_name(msg.type)}")
            if len(self.requested) < len(self.items):
                return self._fail(f"acknowledged after {len(self.requested)} of {len(self.items)} items")
            self.done, self._last = True, None
            logger.info("mission upload: %d items accepted", len(self.items))
            return []
        if mtype in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            seq = int(msg.seq)
            if not 0 <= seq < len(self.items):
                return self._fail(f"the vehicle asked for item {seq} of {len(self.items)}")
            self.requested.add(seq)
            following = "MISSION_ACK" if seq == len(self.items) - 1 else f"MISSION_REQUEST_INT {seq + 1}"
            return self._send(t_s, self.items[seq].to_message(*self.target), following)
        return []


def set_current(seq: int, target: tuple[int, int]) -> mavlink2.MAVLink_mission_set_current_message:
    """MISSION_SET_CURRENT: make item ``seq`` the vehicle's current one."""
    return mavlink2.MAVLink_mission_set_current_message(target[0], target[1], int(seq))
