"""The vehicle's geodetic reference: its local origin (GPS_GLOBAL_ORIGIN) and home (HOME_POSITION).

One :class:`VehicleReference` per companion, shared by everything that turns latitude and
longitude into the local frame: the obstacle intake (ADS-B, UTM and Remote ID traffic)
and goals given relative to home or on the earth (:mod:`companion.loop.goal_frames`).
It keeps what the autopilot last said, and asks for each message (MAV_CMD_REQUEST_MESSAGE,
every ``period_s`` of link time) only while something waits for it, so a flight that needs
neither sends no request. Pure: link time (s) comes in as an argument.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from companion.loop.goal_frames import GeoPoint, Home
from companion.mavlink import messages, traffic

logger = logging.getLogger(__name__)

MSG_GPS_GLOBAL_ORIGIN = 49
MSG_HOME_POSITION = 242
#: Seconds between requests of a message that is waited for.
REQUEST_PERIOD_S = 2.0


class MessageRequest:
    """Asks the autopilot for one message (MAV_CMD_REQUEST_MESSAGE) every period while it is wanted.

    ``wanted`` is set by whoever waits for the message and cleared when it arrives; at most
    ``max_requests`` are sent in all (None: no limit).
    """

    def __init__(self, message_id: int, period_s: float, max_requests: int | None = None) -> None:
        self.message_id = message_id
        self.period_s = period_s
        self.max_requests = max_requests
        self.wanted = False
        self.sent = 0
        self._last_t = -math.inf

    def due(self, t_s: float, autopilot: tuple[int, int] | None):
        """The request to send at link time ``t_s`` (a COMMAND_LONG), or None."""
        if not self.wanted or autopilot is None or t_s - self._last_t < self.period_s:
            return None
        if self.max_requests is not None and self.sent >= self.max_requests:
            return None
        self._last_t = t_s
        self.sent += 1
        return messages.command_long(mavlink2.MAV_CMD_REQUEST_MESSAGE, (self.message_id,),
                                     target_system=autopilot[0], target_component=autopilot[1])

    @property
    def exhausted(self) -> bool:
        """True once the last allowed request has been sent."""
        return self.max_requests is not None and self.sent >= self.max_requests


class VehicleReference:
    """The autopilot's local origin and home, and the requests for them while they are waited for."""

    def __init__(self, period_s: float = REQUEST_PERIOD_S) -> None:
        #: the local frame's origin (GPS_GLOBAL_ORIGIN; with the geoid separation the intake knows)
        self.origin: traffic.GlobalOrigin | None = None
        #: the vehicle's home (HOME_POSITION with a position fix in it)
        self.home: Home | None = None
        self.origin_request = MessageRequest(MSG_GPS_GLOBAL_ORIGIN, period_s)
        self.home_request = MessageRequest(MSG_HOME_POSITION, period_s)

    @property
    def origin_point(self) -> GeoPoint | None:
        """The origin as a :class:`~companion.loop.goal_frames.GeoPoint` (None while unknown)."""
        o = self.origin
        return None if o is None else GeoPoint(o.lat_deg, o.lon_deg, o.alt_m)

    def on_origin(self, origin: traffic.GlobalOrigin) -> None:
        """The autopilot's GPS_GLOBAL_ORIGIN (decoded)."""
        if origin != self.origin:
            logger.info("GPS_GLOBAL_ORIGIN %.7f %.7f %.2f m", origin.lat_deg, origin.lon_deg, origin.alt_m)
        self.origin = origin
        self.origin_request.wanted = False

    def on_home(self, home: messages.HomePosition) -> None:
        """The autopilot's HOME_POSITION (ignored without a position in it: no fix yet)."""
        values = (home.lat_deg, home.lon_deg, home.altitude_amsl_m, *home.local_ned_m)
        if not all(math.isfinite(v) for v in values) or (home.lat_deg == 0.0 and home.lon_deg == 0.0):
            return
        new = Home(GeoPoint(home.lat_deg, home.lon_deg, home.altitude_amsl_m),
                   tuple(float(v) for v in home.local_ned_m))  # type: ignore[arg-type]
        if new != self.home:
            logger.info("HOME_POSITION %.7f %.7f %.2f m, local %s", home.lat_deg, home.lon_deg,
                        home.altitude_amsl_m, np.round(home.local_ned_m, 3).tolist())
        self.home = new
        self.home_request.wanted = False

    def outbound(self, t_s: float, autopilot: tuple[int, int] | None) -> list:
        """The requests due at link time ``t_s``: GPS_GLOBAL_ORIGIN, then HOME_POSITION, while wanted."""
        out = []
        for request in (self.origin_request, self.home_request):
            msg = request.due(t_s, autopilot)
            if msg is not None:
                out.append(msg)
        return out
