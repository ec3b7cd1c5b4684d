"""The autopilots the companion flies with, one module each, registered here.

To add an autopilot: write a module beside :mod:`.px4` whose object implements
:class:`~companion.mavlink.autopilots.base.Autopilot`, and add it to :data:`REGISTERED`.
Nothing else in the companion reads a mode number or an autopilot id.
"""

from __future__ import annotations

from companion.mavlink.autopilots.base import Autopilot, ModeRole, is_armed, is_vehicle_autopilot
from companion.mavlink.autopilots.px4 import PX4

#: Every autopilot the companion recognises, by its HEARTBEAT ``autopilot`` id.
REGISTERED: dict[int, Autopilot] = {ap.mav_autopilot: ap for ap in (PX4,)}


def of_heartbeat(sysid: int, compid: int, autopilot: int, mav_type: int) -> Autopilot | None:
    """The registered autopilot a HEARTBEAT comes from, or None (not an autopilot, or one the
    companion cannot fly with: mavsim's obstacle systems send autopilot INVALID, 8)."""
    if not is_vehicle_autopilot(sysid, compid, mav_type):
        return None
    return REGISTERED.get(int(autopilot))


def by_mav_autopilot(autopilot: int) -> Autopilot | None:
    """The registered autopilot announcing HEARTBEAT ``autopilot`` id, whatever the sender."""
    return REGISTERED.get(int(autopilot))


__all__ = ["Autopilot", "ModeRole", "REGISTERED", "by_mav_autopilot", "is_armed", "of_heartbeat"]
