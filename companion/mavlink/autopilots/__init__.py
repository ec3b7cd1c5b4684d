"""The autopilots the companion flies with, one module each, registered here.

To add an autopilot: write a module beside :mod:`.px4` whose object implements
:class:`~companion.mavlink.autopilots.base.Autopilot`, and add it to :data:`REGISTERED`.
Nothing else in the companion reads a mode number or an autopilot id.
"""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as _ardupilot_dialect

from companion.mavlink.autopilots.ardupilot import ARDUPILOT
from companion.mavlink.autopilots.base import Autopilot, EngagementPlan, ModeRole, is_armed, is_vehicle_autopilot
from companion.mavlink.autopilots.px4 import PX4

#: The MAVLink dialect every parser of the companion reads with (links, tlogs, replays): common
#: plus ArduPilot's messages (EKF_STATUS_REPORT, its readiness); the common messages are the
#: same, so a PX4 link parses as before. Outbound messages are built from ``common``.
DIALECT = _ardupilot_dialect

#: Every autopilot the companion recognises, by its HEARTBEAT ``autopilot`` id.
REGISTERED: dict[int, Autopilot] = {ap.mav_autopilot: ap for ap in (PX4, ARDUPILOT)}

#: ``companion fly --autopilot`` / ``[offboard] autopilot``: "auto" follows whichever registered
#: autopilot is heard first; a name follows only that kind.
AUTOPILOT_CHOICES = ("auto", *(ap.name.lower() for ap in REGISTERED.values()))


def by_choice(choice: str) -> Autopilot | None:
    """The registered autopilot named ``choice`` (``"px4"``, ``"ardupilot"``); None for ``"auto"``."""
    for ap in REGISTERED.values():
        if ap.name.lower() == choice:
            return ap
    return None


def of_heartbeat(sysid: int, compid: int, autopilot: int, mav_type: int) -> Autopilot | None:
    """The registered autopilot a HEARTBEAT comes from, or None (not an autopilot, or one the
    companion cannot fly with: mavsim's obstacle systems send autopilot INVALID, 8)."""
    if not is_vehicle_autopilot(sysid, compid, mav_type):
        return None
    return REGISTERED.get(int(autopilot))


def by_mav_autopilot(autopilot: int) -> Autopilot | None:
    """The registered autopilot announcing HEARTBEAT ``autopilot`` id, whatever the sender."""
    return REGISTERED.get(int(autopilot))


__all__ = ["AUTOPILOT_CHOICES", "DIALECT", "Autopilot", "EngagementPlan", "ModeRole", "REGISTERED", "by_choice", "by_mav_autopilot",
           "is_armed", "of_heartbeat"]
