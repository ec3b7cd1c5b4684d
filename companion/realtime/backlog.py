"""The stream's waiting room for obstacle traffic: the newest report of each source, bounded.

The setpoint stream (:func:`companion.realtime.stream.run_realtime`) handles the autopilot's
messages at once and obstacle traffic only within a per-tick budget. What cannot be handled
yet waits here, one entry per *source*: a newer report from a source that already waits
replaces the older one in its place in the line (counted as superseded), so an overloaded
companion fuses the freshest report of every obstacle, each obstacle's turn comes round in
arrival order, and the backlog never holds more than one report per source. Sources beyond
``max_sources`` push out the one that has waited longest (counted as dropped).

A source is the link, the sender's (system, component), the message type and, for the
kinds that carry one, the aircraft the report is about (ADSB ICAO address, UTM or Remote
ID UAS id): PX4 forwards every ADSB aircraft under its own system id, and those are not one
source.

What is replaced or dropped here is never handled, so it is not in the tlog either: a
replay feeds exactly the messages the companion handled, in its order.
"""

from __future__ import annotations

import logging
from collections import OrderedDict
from collections.abc import Hashable

from companion.mavlink.link import Received

logger = logging.getLogger(__name__)

DEFAULT_MAX_SOURCES = 2000


def source_of(rx: Received) -> Hashable:
    """The source ``rx`` is a report of (see the module docstring)."""
    msg = rx.msg
    mtype = msg.get_type()
    about: object = None
    if mtype == "ADSB_VEHICLE":
        about = int(msg.ICAO_address)
    elif mtype == "UTM_GLOBAL_POSITION":
        about = bytes(msg.uas_id) if not isinstance(msg.uas_id, str) else msg.uas_id
    elif mtype == "OPEN_DRONE_ID_LOCATION":
        about = bytes(msg.id_or_mac) if not isinstance(msg.id_or_mac, str) else msg.id_or_mac
    return (rx.link, msg.get_srcSystem(), msg.get_srcComponent(), mtype, about)


class ObstacleBacklog:
    """Newest waiting report per source, oldest source first; at most ``max_sources`` entries.

    Parameters
    ----------
    max_sources : int
        Sources that may wait at once; beyond, the longest-waiting is dropped.
    """

    def __init__(self, max_sources: int = DEFAULT_MAX_SOURCES) -> None:
        if max_sources < 1:
            raise ValueError(f"max_sources must be >= 1, got {max_sources}")
        self.max_sources = int(max_sources)
        self._waiting: OrderedDict[Hashable, Received] = OrderedDict()
        self.superseded = 0  #: reports replaced by a newer one of the same source before being handled
        self.dropped = 0     #: reports pushed out by more than ``max_sources`` sources

    def __len__(self) -> int:
        return len(self._waiting)

    def __bool__(self) -> bool:
        return bool(self._waiting)

    def put(self, rx: Received) -> None:
        """Queue ``rx``; it replaces a waiting report of its source, keeping that one's turn."""
        key = source_of(rx)
        if key in self._waiting:
            self.superseded += 1
        elif len(self._waiting) >= self.max_sources:
            self._waiting.popitem(last=False)
            self.dropped += 1
        self._waiting[key] = rx

    def take(self) -> Received:
        """The report whose source has waited longest (raises KeyError when empty)."""
        return self._waiting.popitem(last=False)[1]
