"""What the companion says and keeps up on the autopilot link besides its setpoints.

:class:`Supervisor` sends the companion's HEARTBEAT (1 Hz) and its TIMESYNC requests,
announces events as STATUSTEXT (and keeps them for the run report), and says once what
the links and clocks found wrong (packets dropped for their signature, an autopilot whose
TIMESYNC clock is not the one that stamps its poses). Every repeated announcement goes
through one :class:`RateLimiter`. Pure: link time (s) comes in as an argument.
"""

from __future__ import annotations

import logging
import math

from pymavlink.dialects.v20 import common as mavlink2

from companion.loop.records import EventLog
from companion.mavlink import messages

logger = logging.getLogger(__name__)

SEV_WARNING = mavlink2.MAV_SEVERITY_WARNING
SEV_NOTICE = mavlink2.MAV_SEVERITY_NOTICE
SEV_INFO = mavlink2.MAV_SEVERITY_INFO

HEARTBEAT_PERIOD_S = 1.0
SIGNATURE_WARN_PERIOD_S = 5.0  # as mavsim's

#: Start of the STATUSTEXT announcing packets dropped for a bad or missing MAVLink 2
#: signature; the text ends with the links' running total: ``"... (12 rejected)"``.
SIGNATURE_TEXT = "companion: bad or no signature ("
#: STATUSTEXT when the autopilot's TIMESYNC answers disagree with its pose stamps (<= 50 characters).
CLOCK_DISAGREES_TEXT = "companion: TIMESYNC off pose clock, using arrivals"

Outbox = list[mavlink2.MAVLink_message]


class RateLimiter:
    """At most one event every ``period_s`` of link time (the first is always allowed).

    ``tolerance_s`` lets an event through that many seconds early, for timers that run on
    a tick grid whose sums of floats land a hair short of the period.
    """

    def __init__(self, period_s: float, tolerance_s: float = 0.0) -> None:
        self.period_s = float(period_s)
        self.tolerance_s = float(tolerance_s)
        self.last_t = -math.inf

    def ready(self, t_s: float) -> bool:
        """Whether an event at link time ``t_s`` (s) is allowed (does not take it)."""
        return t_s - self.last_t >= self.period_s - self.tolerance_s

    def take(self, t_s: float) -> bool:
        """Allow and record an event at ``t_s`` if :meth:`ready`; returns whether it was."""
        if not self.ready(t_s):
            return False
        self.last_t = t_s
        return True


class Supervisor:
    """HEARTBEAT, TIMESYNC requests and announcements of one companion.

    Parameters
    ----------
    timesync_hz : float
        Rate of TIMESYNC requests to the autopilot once it is known (0: none).
    events : EventLog, optional
        Where every STATUSTEXT said goes, as (link time s, text), for the run report (a list will do).
    """

    def __init__(self, timesync_hz: float, events: EventLog | list | None = None) -> None:
        self.events: EventLog = EventLog() if events is None else events
        self._heartbeat = RateLimiter(HEARTBEAT_PERIOD_S, tolerance_s=1e-9)
        self._timesync = RateLimiter(1.0 / timesync_hz, tolerance_s=1e-9) if timesync_hz > 0.0 else None
        self._signature = RateLimiter(SIGNATURE_WARN_PERIOD_S)
        self._signatures_rejected = 0
        self._signatures_announced = 0
        self._clock_warned = False  # CLOCK_DISAGREES_TEXT said (once a run)

    def say(self, t_s: float, severity: int, text: str) -> mavlink2.MAVLink_statustext_message:
        """The STATUSTEXT announcing ``text`` at link time ``t_s``; logged and kept in :attr:`events`."""
        self.events.append((t_s, text))
        logger.info("%s", text)
        return messages.statustext(severity, text)

    def signatures_rejected(self, total: int) -> None:
        """The links' running count of packets dropped for a bad or missing signature."""
        self._signatures_rejected = max(self._signatures_rejected, int(total))

    def heartbeat(self, t_s: float) -> Outbox:
        """The companion's HEARTBEAT when one is due (1 Hz, from the first tick)."""
        return [messages.companion_heartbeat()] if self._heartbeat.take(t_s) else []

    def link_warnings(self, t_s: float) -> Outbox:
        """New signature rejections, at most one STATUSTEXT every 5 s (the count in the text)."""
        if self._signatures_rejected > self._signatures_announced and self._signature.take(t_s):
            self._signatures_announced = self._signatures_rejected
            return [self.say(t_s, SEV_WARNING, f"{SIGNATURE_TEXT}{self._signatures_rejected} rejected)")]
        return []

    def clock_warning(self, t_s: float, disagrees: bool) -> Outbox:
        """:data:`CLOCK_DISAGREES_TEXT`, once a run, when the vehicle clock found the disagreement."""
        if disagrees and not self._clock_warned:
            self._clock_warned = True
            return [self.say(t_s, SEV_WARNING, CLOCK_DISAGREES_TEXT)]
        return []

    def timesync_due(self, t_s: float, autopilot_known: bool) -> bool:
        """Whether this tick sends a TIMESYNC request (every ``1 / timesync_hz`` s once the autopilot is known)."""
        return self._timesync is not None and autopilot_known and self._timesync.take(t_s)
