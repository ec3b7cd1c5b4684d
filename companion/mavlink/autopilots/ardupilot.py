"""ArduPilot (ArduCopter) flight modes, readiness and engagement as they appear in MAVLink.

ArduCopter announces HEARTBEAT autopilot 3 (MAV_AUTOPILOT_ARDUPILOTMEGA) and puts its
mode number, unpacked, in ``custom_mode``: STABILIZE 0, ACRO 1, ALT_HOLD 2, AUTO 3,
GUIDED 4, LOITER 5, RTL 6, CIRCLE 7, LAND 9, DRIFT 11, SPORT 13, FLIP 14, AUTOTUNE 15,
POSHOLD 16, BRAKE 17, THROW 18, AVOID_ADSB 19, GUIDED_NOGPS 20, SMART_RTL 21. It boots in
STABILIZE. MAV_CMD_DO_SET_MODE takes param1 = 1 (custom mode enabled) and param2 = the mode
number.

What a companion must do (measured on ArduCopter 4.7.0-dev SITL; README "Flying ArduPilot"):

- Stream rates default to zero: every message the companion reads is requested with
  MAV_CMD_SET_MESSAGE_INTERVAL (:data:`STREAMS`); the request acts on the link it came from.
- It is ready only once EKF_STATUS_REPORT shows an absolute horizontal position
  (EKF_POS_HORIZ_ABS) and no constant-position mode (EKF_CONST_POS_MODE); LOCAL_POSITION_NED
  is not sent at all before that, and arming in GUIDED fails ("Need Position Estimate").
- GUIDED (the companion's offboard role) first, then arm, then MAV_CMD_NAV_TAKEOFF with param7
  in metres *above home*; the takeoff runs inside GUIDED and ends when the vehicle's estimate
  holds the height. SET_POSITION_TARGET_LOCAL_NED is used in GUIDED only.
- When the setpoint stream stops it does not fail safe: it holds the last velocity for
  GUID_TIMEOUT (3 s) and then hovers, still in GUIDED. So the companion hands the vehicle back
  itself after braking (:attr:`ArduPilotAutopilot.brake_hand_back_s`, 2 s), to LOITER (its hold) or
  BRAKE.

:data:`ARDUPILOT` is ArduPilot's :class:`~companion.mavlink.autopilots.base.Autopilot`. Pure: no I/O.
"""

from __future__ import annotations

import enum

from companion.errors import InputError
from companion.mavlink.autopilots.base import MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, EngagementPlan, FenceLimits, ModeRole

MAV_AUTOPILOT_ARDUPILOTMEGA = 3

#: EKF_STATUS_REPORT flags (EKF_STATUS_FLAGS).
EKF_POS_HORIZ_ABS = 16
EKF_CONST_POS_MODE = 128


class CopterMode(enum.IntEnum):
    """ArduCopter's flight modes (``custom_mode``)."""

    STABILIZE = 0
    ACRO = 1
    ALT_HOLD = 2
    AUTO = 3
    GUIDED = 4
    LOITER = 5
    RTL = 6
    CIRCLE = 7
    LAND = 9
    DRIFT = 11
    SPORT = 13
    FLIP = 14
    AUTOTUNE = 15
    POSHOLD = 16
    BRAKE = 17
    THROW = 18
    AVOID_ADSB = 19
    GUIDED_NOGPS = 20
    SMART_RTL = 21
    FLOWHOLD = 22
    FOLLOW = 23
    ZIGZAG = 24
    SYSTEMID = 25
    AUTOROTATE = 26
    AUTO_RTL = 27
    TURTLE = 28


#: (message id, Hz) the companion requests on its link: its pose (LOCAL_POSITION_NED, at the
#: rate PX4 streams it), the readiness (EKF_STATUS_REPORT), home and origin (the takeoff height,
#: the geodetic frame of traffic), ATTITUDE and GLOBAL_POSITION_INT for the log, and the target
#: the vehicle flies (POSITION_TARGET_LOCAL_NED, GUIDED only).
STREAMS: tuple[tuple[int, float], ...] = (
    (32, 50.0),    # LOCAL_POSITION_NED
    (193, 2.0),    # EKF_STATUS_REPORT
    (242, 1.0),    # HOME_POSITION
    (49, 1.0),     # GPS_GLOBAL_ORIGIN
    (30, 10.0),    # ATTITUDE
    (33, 10.0),    # GLOBAL_POSITION_INT
    (85, 10.0),    # POSITION_TARGET_LOCAL_NED
    (1, 1.0),      # SYS_STATUS
)

_ROLES = {CopterMode.GUIDED: ModeRole.OFFBOARD, CopterMode.LOITER: ModeRole.HOLD, CopterMode.BRAKE: ModeRole.HOLD,
          CopterMode.POSHOLD: ModeRole.POSITION, CopterMode.AUTO: ModeRole.MISSION}
_REQUESTS = {ModeRole.OFFBOARD: CopterMode.GUIDED, ModeRole.HOLD: CopterMode.LOITER, ModeRole.BRAKE: CopterMode.BRAKE,
             ModeRole.POSITION: CopterMode.POSHOLD, ModeRole.MISSION: CopterMode.AUTO}


def mode_name(custom_mode: int) -> str:
    """ArduCopter's name of ``custom_mode`` (``'GUIDED'``, ``'LOITER'``); ``'UNKNOWN(n)'`` otherwise."""
    try:
        return CopterMode(int(custom_mode)).name
    except ValueError:
        return f"UNKNOWN({int(custom_mode)})"


def custom_mode_from_name(name: str) -> int:
    """``custom_mode`` of an ArduCopter mode name; inverse of :func:`mode_name`."""
    try:
        return int(CopterMode[name.upper()])
    except KeyError:
        raise InputError(f"unknown ArduCopter mode name {name!r}; known: {', '.join(m.name for m in CopterMode)}") from None


def ekf_ready(flags: int) -> bool:
    """EKF_STATUS_REPORT ``flags`` with an absolute horizontal position and no constant-position mode."""
    flags = int(flags)
    return bool(flags & EKF_POS_HORIZ_ABS) and not flags & EKF_CONST_POS_MODE


class ArduPilotAutopilot:
    """ArduCopter as the companion sees it (:class:`~companion.mavlink.autopilots.base.Autopilot`)."""

    name = "ArduPilot"
    mav_autopilot = MAV_AUTOPILOT_ARDUPILOTMEGA
    streams = STREAMS
    engagement = EngagementPlan(wait_ready=True, mode_before_arming=True, takeoff_above_home=True,
                                takeoff_ends_by_height=True)
    #: ArduCopter keeps GUIDED when the stream stops: after 2 s of braking, braked to a stop, the
    #: companion hands back (LOITER).
    brake_hand_back_s: float | None = 2.0
    #: ArduCopter's fence parameters (FENCE_ENABLE, FENCE_TYPE, FENCE_RADIUS, FENCE_ALT_MAX) are not
    #: read yet: its circle and ceiling about home are not flown by the planner (docs/MISSIONS.md, Limits).
    fence_params: tuple[str, ...] = ()

    def fence_limits(self, values: dict[str, tuple[float, int]]) -> FenceLimits:
        return FenceLimits()

    def ready(self, estimator_flags: int) -> bool:
        return ekf_ready(estimator_flags)

    def mode_name(self, custom_mode: int) -> str:
        return mode_name(custom_mode)

    def mode_role(self, custom_mode: int) -> ModeRole:
        try:
            return _ROLES.get(CopterMode(int(custom_mode)), ModeRole.OTHER)
        except ValueError:
            return ModeRole.OTHER

    def custom_mode_of(self, role: ModeRole) -> int:
        try:
            return int(_REQUESTS[role])
        except KeyError:
            raise InputError(f"the companion never requests an ArduCopter mode for {role.value!r}") from None

    def set_mode_params(self, custom_mode: int, armed: bool) -> tuple[float, float]:
        """``(param1, param2)`` of MAV_CMD_DO_SET_MODE: custom mode enabled (1) and the mode number
        (ArduPilot ignores param1's armed bit)."""
        if int(custom_mode) not in CopterMode._value2member_map_:
            raise InputError(f"custom_mode {custom_mode!r} is not an ArduCopter mode")
        return float(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(int(custom_mode))

    def takeoff_param7(self, height_m: float, home_alt_amsl_m: float | None) -> float:
        """Metres above home: ArduCopter reads param7 of MAV_CMD_NAV_TAKEOFF relative to home."""
        return float(height_m)


ARDUPILOT = ArduPilotAutopilot()
