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

Pure: no I/O. Only PX4 is recognised as an autopilot (autopilot id 12); this
companion relies on PX4's offboard contract, which ArduPilot does not share.
"""

from __future__ import annotations

import enum
import logging

from companion.errors import InputError

logger = logging.getLogger(__name__)

MAV_AUTOPILOT_PX4 = 12
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_MODE_FLAG_SAFETY_ARMED = 128

#: MAV_TYPE values that never denote a flying vehicle's autopilot: GCS 6,
#: ONBOARD_CONTROLLER 18, GIMBAL 26, ADSB 27, CAMERA 30, CHARGING_STATION 31,
#: FLARM 32, SERVO 33, ODID 34, BATTERY 36, PARACHUTE 37, LOG 38, OSD 39, IMU 40,
#: GPS 41, WINCH 42.
NON_VEHICLE_TYPES = frozenset({6, 18, 26, 27, 30, 31, 32, 33, 34, 36, 37, 38, 39, 40, 41, 42})


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


def is_armed(base_mode: int) -> bool:
    """Armed flag of a HEARTBEAT: ``base_mode & 128`` (MAV_MODE_FLAG_SAFETY_ARMED)."""
    return bool(int(base_mode) & MAV_MODE_FLAG_SAFETY_ARMED)


def is_autopilot_heartbeat(sysid: int, compid: int, autopilot: int, mav_type: int) -> bool:
    """Whether a HEARTBEAT comes from a PX4 autopilot.

    As MAVSDK decides it: the sender is component 1 (MAV_COMP_ID_AUTOPILOT1),
    announces autopilot 12 (MAV_AUTOPILOT_PX4), and its type is a vehicle, not a
    ground station, onboard controller, camera, gimbal or other peripheral.
    Any system id 1..255 is accepted (PX4's MAV_SYS_ID is configurable).
    Obstacle systems in ``mavsim`` send autopilot INVALID (8) and are refused.
    """
    return (
        1 <= int(sysid) <= 255
        and int(compid) == 1
        and int(autopilot) == MAV_AUTOPILOT_PX4
        and int(mav_type) not in NON_VEHICLE_TYPES
    )


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
