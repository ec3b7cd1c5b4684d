"""What the companion needs to know of an autopilot: the :class:`Autopilot` protocol.

An autopilot (PX4, and others as they are added) is recognised by its HEARTBEAT and packs
its flight mode into ``HEARTBEAT.custom_mode`` its own way. The rest of the companion never
reads a mode number: it asks the autopilot what *role* a mode plays (:class:`ModeRole`) and
asks it for the command that requests a role. One module per autopilot implements the
protocol; :mod:`companion.mavlink.autopilots` registers it.

Words used throughout: *offboard* is the role in which the companion's setpoints fly the
vehicle, whatever the autopilot calls that mode; *hold* is hovering in place under the
autopilot's own control (where the companion hands the vehicle back to).

Pure: no I/O. Nothing here imports :mod:`companion.mavlink.messages` (which imports this
package to decode HEARTBEATs).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Protocol

from pymavlink.dialects.v20 import common as mavlink2

MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_MODE_FLAG_SAFETY_ARMED = 128

#: MAV_TYPE values that never denote a flying vehicle's autopilot: GCS 6,
#: ONBOARD_CONTROLLER 18, GIMBAL 26, ADSB 27, CAMERA 30, CHARGING_STATION 31,
#: FLARM 32, SERVO 33, ODID 34, BATTERY 36, PARACHUTE 37, LOG 38, OSD 39, IMU 40,
#: GPS 41, WINCH 42.
NON_VEHICLE_TYPES = frozenset({6, 18, 26, 27, 30, 31, 32, 33, 34, 36, 37, 38, 39, 40, 41, 42})


class ModeRole(enum.Enum):
    """What a flight mode means to the companion."""

    OFFBOARD = "offboard"        # the companion's setpoints fly the vehicle
    HOLD = "hold"                # the autopilot hovers in place (where the companion hands back)
    BRAKE = "brake"              # the autopilot stops at once and then holds (a hand-back choice)
    TAKEOFF = "takeoff"          # the autopilot's own take-off
    POSITION = "position"        # a pilot flies with position assistance
    MISSION = "mission"          # the autopilot flies its stored mission (PX4 AUTO.MISSION, ArduCopter AUTO)
    OTHER = "other"              # anything else (manual, return, land, unknown)


@dataclass(frozen=True)
class EngagementPlan:
    """How an autopilot is engaged: the steps of the offboard sequence that differ between autopilots.

    Attributes
    ----------
    wait_ready : bool
        Command nothing (no arming, no mode) until :meth:`Autopilot.ready` says so from the
        autopilot's estimator status (EKF_STATUS_REPORT flags).
    mode_before_arming : bool
        Request the offboard mode before arming and taking off: the autopilot takes off in
        it (ArduCopter in GUIDED), and setpoints are streamed only after the takeoff.
    takeoff_above_home : bool
        MAV_CMD_NAV_TAKEOFF's param7 is metres above home (else metres AMSL, which needs
        HOME_POSITION's altitude first).
    takeoff_ends_by_height : bool
        The takeoff is complete when the vehicle's own estimate holds the requested height
        (else when the autopilot's takeoff mode ends in its hold mode).
    """

    wait_ready: bool = False
    mode_before_arming: bool = False
    takeoff_above_home: bool = False
    takeoff_ends_by_height: bool = False


@dataclass(frozen=True)
class FenceLimits:
    """An autopilot's failsafe fence about home, from its parameters: a cylinder.

    Attributes
    ----------
    max_horizontal_m : float or None
        The largest horizontal distance from home (m); None: no such limit.
    max_up_m : float or None
        The largest height above home (m); None: no such limit.
    """

    max_horizontal_m: float | None = None
    max_up_m: float | None = None

    @property
    def any(self) -> bool:
        return self.max_horizontal_m is not None or self.max_up_m is not None


class Autopilot(Protocol):
    """One autopilot's HEARTBEAT identity, modes and mode requests."""

    #: Short name for logs and reports (``"PX4"``).
    name: str
    #: The HEARTBEAT ``autopilot`` field it announces (MAV_AUTOPILOT).
    mav_autopilot: int
    #: (message id, rate in Hz) the companion must ask for (MAV_CMD_SET_MESSAGE_INTERVAL)
    #: because the autopilot does not stream them to a companion by itself; empty if none.
    streams: tuple[tuple[int, float], ...]
    #: The steps of its engagement that differ between autopilots.
    engagement: EngagementPlan
    #: Seconds of braking (stale estimate, no valid plan) after which the companion hands the
    #: vehicle back when the scenario does not say (``[offboard] brake_hand_back_s``); None never.
    brake_hand_back_s: float | None
    #: Parameters that hold its failsafe fence about home (read with the vehicle's fence,
    #: :meth:`fence_limits`); empty when none are read.
    fence_params: tuple[str, ...]

    def fence_limits(self, values: dict[str, tuple[float, int]]) -> FenceLimits:
        """Its fence about home from :attr:`fence_params`' values (name -> (PARAM_VALUE's value, type))."""

    def ready(self, estimator_flags: int) -> bool:
        """Whether the vehicle may be armed and commanded, from EKF_STATUS_REPORT ``flags``."""

    def mode_name(self, custom_mode: int) -> str:
        """The autopilot's own name of a ``custom_mode`` (never raises)."""

    def mode_role(self, custom_mode: int) -> ModeRole:
        """The role a ``custom_mode`` plays for the companion."""

    def custom_mode_of(self, role: ModeRole) -> int:
        """The ``custom_mode`` the companion requests for ``role`` (OFFBOARD, HOLD, BRAKE or POSITION)."""

    def set_mode_params(self, custom_mode: int, armed: bool) -> tuple[float, ...]:
        """The parameters (param1, param2, ...) of MAV_CMD_DO_SET_MODE for ``custom_mode``."""

    def takeoff_param7(self, height_m: float, home_alt_amsl_m: float | None) -> float:
        """MAV_CMD_NAV_TAKEOFF's param7 for ``height_m`` above home (NaN when it cannot be formed yet)."""


def is_armed(base_mode: int) -> bool:
    """Armed flag of a HEARTBEAT: ``base_mode & 128`` (MAV_MODE_FLAG_SAFETY_ARMED)."""
    return bool(int(base_mode) & MAV_MODE_FLAG_SAFETY_ARMED)


def is_vehicle_autopilot(sysid: int, compid: int, mav_type: int) -> bool:
    """Whether a HEARTBEAT's sender can be a vehicle's autopilot, whatever its kind.

    As MAVSDK decides it: component 1 (MAV_COMP_ID_AUTOPILOT1), any system id 1..255
    (configurable on every autopilot), and a vehicle type, not a ground station, onboard
    controller, camera, gimbal or other peripheral.
    """
    return 1 <= int(sysid) <= 255 and int(compid) == mavlink2.MAV_COMP_ID_AUTOPILOT1 \
        and int(mav_type) not in NON_VEHICLE_TYPES
