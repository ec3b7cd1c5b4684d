"""Marks in the companion's own tlog: what a replay needs that the wire does not carry.

A tlog holds every packet the companion handled or sent, stamped with its link time.
Two things a replay needs are not in those packets:

- **Which link a message came in on.** The companion keys obstacle tracks by link and
  refuses other systems' positions on the autopilot link, so a message from an obstacle
  link must be replayed as from that link. Before the autopilot is known, for instance,
  no rule can tell an obstacle link's report from one on the autopilot link.
- **When the loop ticked without sending anything.** The loop's timers (its HEARTBEAT
  every second, the offboard sequence's retries) run on tick times; a tick that sent
  nothing leaves no packet behind, and a replay that guesses its time from the setpoint
  grid drifts from the real one by the real loop's jitter.

So :func:`companion.loop.realtime.run_realtime` writes two marks into its tlog, never
onto a link: :data:`TICK` (stamped with the tick's time, before the tick's packets) and
:data:`RX_LINK` (stamped with the message's receive time, just before an inbound record
that came on an obstacle link; its value is the link's 1-based index). Both are
NAMED_VALUE_INT packets from the companion's own (system, component), which other tools
read as ordinary telemetry. :mod:`companion.offline.replay` takes them out of the
stream and uses them instead of its inference.
"""

from __future__ import annotations

import logging

from pymavlink.dialects.v20 import common as mavlink2

from companion.loop.traffic_config import AUTOPILOT_LINK, OBSTACLE_LINK_PREFIX, obstacle_link_name
from companion.mavlink.tlog import TlogWriter

logger = logging.getLogger(__name__)

TICK = "tick"
RX_LINK = "rx_link"
_NAMES = (TICK, RX_LINK)


def link_index(link: str) -> int:
    """The 1-based index of an obstacle link from its name (``obstacles2`` -> 2); 0 for the autopilot link."""
    if link == AUTOPILOT_LINK:
        return 0
    if link.startswith(OBSTACLE_LINK_PREFIX) and link[len(OBSTACLE_LINK_PREFIX):].isdigit():
        return int(link[len(OBSTACLE_LINK_PREFIX):])
    raise ValueError(f"not a link name the companion gives: {link!r}")


def link_name(index: int) -> str:
    """The link name of an :data:`RX_LINK` mark's value (inverse of :func:`link_index`)."""
    return AUTOPILOT_LINK if index <= 0 else obstacle_link_name(int(index) - 1)


def mark_of(msg) -> tuple[str, int] | None:
    """``(name, value)`` when ``msg`` (from the companion's own key) is a mark, else None."""
    if msg.get_type() != "NAMED_VALUE_INT":
        return None
    name = str(msg.name).rstrip("\x00")
    return (name, int(msg.value)) if name in _NAMES else None


class TlogMarks:
    """Writes marks into ``tlog`` as the companion ``key`` (system, component); never sends them.

    Parameters
    ----------
    tlog : the companion's tlog writer.
    key : the companion's (system id, component id), the source of its own packets.
    """

    def __init__(self, tlog: TlogWriter, key: tuple[int, int]) -> None:
        self.tlog = tlog
        self._mav = mavlink2.MAVLink(None, int(key[0]), int(key[1]))

    def _write(self, t_s: float, name: str, value: int) -> None:
        msg = mavlink2.MAVLink_named_value_int_message(int(round(t_s * 1000.0)) % (1 << 32), name.encode(), int(value))
        self.tlog.write(t_s, bytes(msg.pack(self._mav)))

    def tick(self, t_s: float) -> None:
        """The loop ticks at link time ``t_s`` (s); write before the tick's packets."""
        self._write(t_s, TICK, 0)

    def received(self, t_s: float, link: str) -> None:
        """The next inbound record, received at ``t_s`` (s), came on ``link`` (written only for obstacle links)."""
        if link != AUTOPILOT_LINK:
            self._write(t_s, RX_LINK, link_index(link))
