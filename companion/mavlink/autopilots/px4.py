"""PX4 flight modes and autopilot identity as they appear in MAVLink HEARTBEAT.

PX4 packs its flight mode into ``HEARTBEAT.custom_mode`` as
``(main << 16) | (sub << 24)`` (``src/modules/commander/px4_custom_mode.h``);
the low 16 bits are zero. Main modes: MANUAL 1, ALTCTL 2, POSCTL 3, AUTO 4,
ACRO 5, OFFBOARD 6, STABILIZED 7 (RATTITUDE 8 is legacy). AUTO sub modes:
READY 1, TAKEOFF 2, LOITER 3, MISSION 4, RTL 5, LAND 6, FOLLOW_TARGET 8,
PRECLAND 9. Reference values: POSCTL 196608, OFFBOARD 393216,
AUTO.TAKEOFF 33816576, AUTO.LOITER 50593792, AUTO.LAND 100925440.

Mode names follow PX4's own console and QGroundControl's short names
(``'POSCTL'``, ``'OFFBOARD'``, ``'AUTO.LOITER'``). pymavlink's
``mavutil.mode_string_v10`` prints the same names for non-AUTO modes and drops
the ``AUTO.`` prefix for AUTO sub modes (``'LOITER'``).

:data:`PX4` is PX4's :class:`~companion.mavlink.autopilots.base.Autopilot`: OFFBOARD is the
companion's role, AUTO.LOITER (Hold) where it hands back, AUTO.TAKEOFF PX4's take-off,
POSCTL the pilot's position mode. Pure: no I/O.
"""

from __future__ import annotations

import enum
import logging
import math

from companion.errors import InputError
from companion.mavlink.autopilots.base import (
    MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
    MAV_MODE_FLAG_SAFETY_ARMED,
    EngagementPlan,
    FenceLimits,
    ModeRole,
    is_vehicle_autopilot,
)

logger = logging.getLogger(__name__)

MAV_AUTOPILOT_PX4 = 12


class MainMode(enum.IntEnum):
    """PX4 custom main mode (``px4_custom_main_mode``)."""

    MANUAL = 1
    ALTCTL = 2
    POSCTL = 3
    AUTO = 4
    ACRO = 5
    OFFBOARD = 6
    STABILIZED = 7
    RATTITUDE = 8


class AutoSubMode(enum.IntEnum):
    """PX4 custom sub mode of main mode AUTO (``px4_custom_sub_mode_auto``)."""

    READY = 1
    TAKEOFF = 2
    LOITER = 3
    MISSION = 4
    RTL = 5
    LAND = 6
    FOLLOW_TARGET = 8
    PRECLAND = 9


def encode_custom_mode(main: int, sub: int = 0) -> int:
    """Pack a PX4 main and sub mode into ``HEARTBEAT.custom_mode``.

    Parameters
    ----------
    main, sub : int
        Main mode (1..255) and sub mode (0..255; only AUTO uses sub modes).

    Returns
    -------
    int
        ``(main << 16) | (sub << 24)``.
    """
    if not (0 <= int(main) <= 255 and 0 <= int(sub) <= 255):
        raise InputError(f"PX4 main/sub mode must be in 0..255, got main={main!r} sub={sub!r}")
    return (int(main) << 16) | (int(sub) << 24)


def decode_custom_mode(custom_mode: int) -> tuple[int, int]:
    """Split ``HEARTBEAT.custom_mode`` into ``(main, sub)``."""
    custom_mode = int(custom_mode)
    return (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF


def mode_name(custom_mode: int) -> str:
    """PX4 mode name of a packed ``custom_mode`` (``'OFFBOARD'``, ``'AUTO.LOITER'``, ...).

    Unknown combinations give ``'UNKNOWN(main.sub)'``; this never raises.
    """
    main, sub = decode_custom_mode(custom_mode)
    try:
        main_mode = MainMode(main)
    except ValueError:
        return f"UNKNOWN({main}.{sub})"
    if main_mode is MainMode.AUTO:
        try:
            return f"AUTO.{AutoSubMode(sub).name}"
        except ValueError:
            return f"UNKNOWN({main}.{sub})"
    return main_mode.name


def custom_mode_from_name(name: str) -> int:
    """Packed ``custom_mode`` of a PX4 mode name; inverse of :func:`mode_name`.

    Raises
    ------
    InputError
        If the name is not a PX4 mode this module knows.
    """
    head, _, tail = name.upper().partition(".")
    try:
        if head == "AUTO":
            return encode_custom_mode(MainMode.AUTO, AutoSubMode[tail])
        if tail:
            raise KeyError(name)
        return encode_custom_mode(MainMode[head])
    except KeyError:
        known = [m.name for m in MainMode if m is not MainMode.AUTO] + [f"AUTO.{s.name}" for s in AutoSubMode]
        raise InputError(f"unknown PX4 mode name {name!r}; known: {', '.join(known)}") from None


def is_offboard(custom_mode: int) -> bool:
    """True when ``custom_mode`` has main mode OFFBOARD (6)."""
    return decode_custom_mode(custom_mode)[0] == MainMode.OFFBOARD


def is_autopilot_heartbeat(sysid: int, compid: int, autopilot: int, mav_type: int) -> bool:
    """Whether a HEARTBEAT comes from a PX4 autopilot.

    As MAVSDK decides it: the sender is component 1 (MAV_COMP_ID_AUTOPILOT1),
    announces autopilot 12 (MAV_AUTOPILOT_PX4), and its type is a vehicle, not a
    ground station, onboard controller, camera, gimbal or other peripheral.
    Any system id 1..255 is accepted (PX4's MAV_SYS_ID is configurable).
    Obstacle systems in ``mavsim`` send autopilot INVALID (8) and are refused.
    """
    return int(autopilot) == MAV_AUTOPILOT_PX4 and is_vehicle_autopilot(sysid, compid, mav_type)


def set_mode_params(custom_mode: int, armed: bool) -> tuple[float, float, float]:
    """``(param1, param2, param3)`` of MAV_CMD_DO_SET_MODE (176) for a PX4 mode.

    param1 is the base mode: MAV_MODE_FLAG_CUSTOM_MODE_ENABLED (1), plus
    MAV_MODE_FLAG_SAFETY_ARMED (128) when the vehicle is armed, as MAVSDK sends
    it (older PX4 read the armed bit of DO_SET_MODE as an arming request, so
    the bit must match the vehicle's state; current PX4 ignores it).
    param2 is the main mode *unpacked* (6 for OFFBOARD, never 393216) and
    param3 the sub mode.
    """
    main, sub = decode_custom_mode(custom_mode)
    if main == 0:
        raise InputError(f"custom_mode {custom_mode!r} has no PX4 main mode")
    base = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
    return float(base), float(main), float(sub)


OFFBOARD = encode_custom_mode(MainMode.OFFBOARD)
POSCTL = encode_custom_mode(MainMode.POSCTL)
AUTO_TAKEOFF = encode_custom_mode(MainMode.AUTO, AutoSubMode.TAKEOFF)
AUTO_LOITER = encode_custom_mode(MainMode.AUTO, AutoSubMode.LOITER)
AUTO_LAND = encode_custom_mode(MainMode.AUTO, AutoSubMode.LAND)
AUTO_RTL = encode_custom_mode(MainMode.AUTO, AutoSubMode.RTL)
AUTO_MISSION = encode_custom_mode(MainMode.AUTO, AutoSubMode.MISSION)


_ROLES = {OFFBOARD: ModeRole.OFFBOARD, AUTO_LOITER: ModeRole.HOLD, AUTO_TAKEOFF: ModeRole.TAKEOFF, POSCTL: ModeRole.POSITION,
          AUTO_MISSION: ModeRole.MISSION}
#: PX4's Hold stops the vehicle and holds: it is also the hand-back for BRAKE.
_REQUESTS = {ModeRole.OFFBOARD: OFFBOARD, ModeRole.HOLD: AUTO_LOITER, ModeRole.BRAKE: AUTO_LOITER, ModeRole.POSITION: POSCTL,
             ModeRole.MISSION: AUTO_MISSION}


class Px4Autopilot:
    """PX4 as the companion sees it (:class:`~companion.mavlink.autopilots.base.Autopilot`)."""

    name = "PX4"
    mav_autopilot = MAV_AUTOPILOT_PX4
    #: PX4 streams LOCAL_POSITION_NED, ODOMETRY, HOME_POSITION and HEARTBEAT on its onboard link by itself.
    streams: tuple[tuple[int, float], ...] = ()
    #: Arm, AUTO.TAKEOFF (param7 AMSL) until it ends in Hold, then stream and request OFFBOARD.
    engagement = EngagementPlan()
    #: PX4 leaves OFFBOARD by itself when the stream stops; the companion brakes and streams on.
    brake_hand_back_s: float | None = None
    #: PX4's failsafe geofence about home: GF_MAX_HOR_DIST, GF_MAX_VER_DIST (m, 0 off; floats).
    fence_params: tuple[str, ...] = ("GF_MAX_HOR_DIST", "GF_MAX_VER_DIST")

    def fence_limits(self, values: dict[str, tuple[float, int]]) -> FenceLimits:
        """GF_MAX_HOR_DIST from home horizontally, GF_MAX_VER_DIST up from home (m); 0 or less: off."""
        hor, ver = (values.get(name, (0.0, 0))[0] for name in self.fence_params)
        return FenceLimits(hor if hor > 0.0 else None, ver if ver > 0.0 else None)

    def ready(self, estimator_flags: int) -> bool:
        """PX4 is commanded as soon as it is heard (it refuses to arm until it can fly)."""
        return True

    def mode_name(self, custom_mode: int) -> str:
        return mode_name(custom_mode)

    def mode_role(self, custom_mode: int) -> ModeRole:
        """By main mode for OFFBOARD and POSCTL (PX4 leaves the sub mode 0 there), by main and sub mode for AUTO."""
        main, sub = decode_custom_mode(custom_mode)
        return _ROLES.get(encode_custom_mode(main, sub if main == MainMode.AUTO else 0), ModeRole.OTHER)

    def custom_mode_of(self, role: ModeRole) -> int:
        try:
            return _REQUESTS[role]
        except KeyError:
            raise InputError(f"the companion never requests a PX4 mode for {role.value!r}") from None

    def set_mode_params(self, custom_mode: int, armed: bool) -> tuple[float, float, float]:
        return set_mode_params(custom_mode, armed)

    def takeoff_param7(self, height_m: float, home_alt_amsl_m: float | None) -> float:
        """Metres AMSL: home's altitude plus ``height_m`` (NaN without home: PX4 would climb to MIS_TAKEOFF_ALT)."""
        return math.nan if home_alt_amsl_m is None else home_alt_amsl_m + height_m


PX4 = Px4Autopilot()
