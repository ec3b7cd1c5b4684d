"""The PX4 personality: HEARTBEAT identity, modes, commander, parameters, streams.

:data:`PX4` is what mavsim's generic core asks (:class:`mavsim.personalities.base.Personality`);
its :class:`Commander` is PX4's commander behaviour: flight modes, arming, the offboard
contract, failsafe. Pure and clock-free: every call takes the simulated time ``now_s`` and the true
vehicle state. Messages to the ground station (STATUSTEXT) are queued in
:attr:`Commander.texts` for the caller to send.

Imitated (see ``docs/PX4_FACTS.md``, sections 2, 3, 5 and 6):

- custom_mode = (main << 16) | (sub << 24); base_mode 1 + 128 armed + mode flags
  (AUTO 4|8|16, POSCTL 64|16, OFFBOARD 16); system_status 3 standby, 4 active,
  5 critical while a failsafe is active.
- OFFBOARD needs a setpoint stream (a setpoint younger than COM_OF_LOSS_T) unless the
  vehicle is disarmed; refused in flight with ACK ``offboard_reject_ack`` (0 as PX4
  main), the mode unchanged and "Switching to Offboard is currently not available".
- Arming in OFFBOARD needs the stream. No disarm in the air (except force, 21196).
  Auto-disarm COM_DISARM_PRFLT after arming without takeoff, COM_DISARM_LAND after landing.
- Setpoint loss in OFFBOARD while armed: after COM_OF_LOSS_T the vehicle leaves for the
  COM_OBL_RC_ACT fallback (0-2 Position hold, 3 Return, 4 Land, 5 Hold, 6-7 Land) and
  never re-enters OFFBOARD by itself. No failsafe while disarmed.
- Takeoff climbs at MPC_TKO_SPEED to the target, then AUTO.LOITER.
- AUTO.MISSION (MAV_CMD_MISSION_START, or the mode) flies the stored mission item by item
  (:mod:`mavsim.personalities.px4_mission`), MISSION_CURRENT streamed at 1 Hz,
  MISSION_ITEM_REACHED sent at once and again with each of the next ten MISSION_CURRENT (as
  measured); no mission: "Mission start denied! No valid mission".
- Dead reckoning (no GPS) for EKF2_NOAID_TOUT: the local position is invalid. Armed and
  airborne, PX4 says "Failsafe: blind land" and "Failsafe activated" and leaves any mode that
  needs a position for ALTCTL, descending at MPC_LAND_SPEED without horizontal position control
  (mavsim commands zero horizontal velocity); modes that need a position are refused until it
  is valid again, and then the vehicle returns (AUTO.RTL), as measured on PX4 SITL
  (docs/PX4_FACTS.md).

Deviations: POSCTL behaves as position hold with centred sticks (real PX4 without RC
refuses it); RTL flies home at the current altitude (no climb to RTL_RETURN_ALT), then
descends in AUTO.RTL.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from mavsim.missions import MissionItem
from mavsim.params import PARAM_TYPE_INT32, PARAM_TYPE_REAL32, ParamStore, ParamTable
from mavsim.personalities.base import SEV_CRITICAL, SEV_INFO, SEV_WARNING, OffboardSetpoint
from mavsim.personalities.px4_mission import ACTIVE, COMPLETE, NO_MISSION, MissionFlight
from mavsim.personalities.px4_geofence import FenceZones, GeofenceWatch
from mavsim.personalities.px4_response import Px4Response
from mavsim.vehicle import VehicleCommand, VehicleState

logger = logging.getLogger(__name__)

__all__ = ["PX4", "Px4Personality", "Commander", "MODES", "START_MODES", "PARAMS", "STREAM_RATES_HZ",
           "mode_from_custom", "heartbeat_mode", "heartbeat_mode_name", "engaged"]

#: PX4 mode name -> (main mode, sub mode).
MODES: dict[str, tuple[int, int]] = {
    "ALTCTL": (2, 0),
    "POSCTL": (3, 0),
    "AUTO.TAKEOFF": (4, 2),
    "AUTO.LOITER": (4, 3),
    "AUTO.RTL": (4, 5),
    "AUTO.LAND": (4, 6),
    "AUTO.MISSION": (4, 4),
    "OFFBOARD": (6, 0),
}
_MODE_BY_NUMBER = {v: k for k, v in MODES.items()}
#: The modes ``[sim] start_mode`` accepts, in the order its error message lists them.
START_MODES = ("POSCTL", "AUTO.LOITER", "AUTO.TAKEOFF", "AUTO.LAND", "AUTO.RTL", "OFFBOARD")
#: Names PX4 uses in its messages.
DISPLAY = {"ALTCTL": "Altitude", "POSCTL": "Position", "AUTO.TAKEOFF": "Takeoff", "AUTO.LOITER": "Hold",
           "AUTO.RTL": "Return", "AUTO.LAND": "Land", "AUTO.MISSION": "Mission", "OFFBOARD": "Offboard"}
_MAIN_DISPLAY = {1: "Manual", 2: "Altitude", 3: "Position", 4: "Auto", 5: "Acro", 6: "Offboard",
                 7: "Stabilized", 8: "Rattitude"}
_AUTO_SUB_DISPLAY = {0: "Mission", 1: "Ready", 4: "Mission", 7: "Follow target", 8: "Precision land"}

POS_GAIN_PER_S = 1.0  # position-error to velocity gain (PX4 MPC_XY_P 0.95, MPC_Z_P 1.0)
#: MISSION_ITEM_REACHED is sent again with the next ten MISSION_CURRENT (1 Hz): eleven in all, measured.
REACHED_REPEATS = 10
_FALLBACK = {0: "POSCTL", 1: "POSCTL", 2: "POSCTL", 3: "AUTO.RTL", 4: "AUTO.LAND", 5: "AUTO.LOITER",
             6: "AUTO.LAND", 7: "AUTO.LAND"}


#: PX4's HEARTBEAT: type MAV_TYPE_QUADROTOR, autopilot MAV_AUTOPILOT_PX4, the main mode
#: OFFBOARD, base_mode's armed flag.
MAV_TYPE_QUADROTOR = 2
MAV_AUTOPILOT_PX4 = 12
OFFBOARD_MAIN_MODE = 6
ARMED_FLAG = 128

#: name -> (default, type, min, max). Defaults as in PX4 main.
PARAMS: ParamTable = {
    "COM_OF_LOSS_T": (1.0, PARAM_TYPE_REAL32, 0.0, 60.0),
    "COM_OBL_RC_ACT": (0, PARAM_TYPE_INT32, 0, 7),
    "COM_DISARM_LAND": (2.0, PARAM_TYPE_REAL32, -1.0, 20.0),
    "COM_DISARM_PRFLT": (10.0, PARAM_TYPE_REAL32, -1.0, 20.0),
    "COM_RCL_EXCEPT": (0, PARAM_TYPE_INT32, 0, 31),
    "COM_RC_IN_MODE": (3, PARAM_TYPE_INT32, 0, 4),
    "MIS_TAKEOFF_ALT": (2.5, PARAM_TYPE_REAL32, 0.0, 100.0),
    "MPC_XY_VEL_MAX": (12.0, PARAM_TYPE_REAL32, 0.0, 20.0),
    "MPC_XY_CRUISE": (5.0, PARAM_TYPE_REAL32, 3.0, 20.0),
    "MPC_Z_VEL_MAX_UP": (3.0, PARAM_TYPE_REAL32, 0.5, 8.0),
    "MPC_Z_VEL_MAX_DN": (1.5, PARAM_TYPE_REAL32, 0.5, 4.0),
    "MPC_TKO_SPEED": (1.5, PARAM_TYPE_REAL32, 1.0, 5.0),
    "MPC_LAND_SPEED": (0.7, PARAM_TYPE_REAL32, 0.6, 2.0),
    "MAV_SYS_ID": (1, PARAM_TYPE_INT32, 1, 250),
    "NAV_DLL_ACT": (0, PARAM_TYPE_INT32, 0, 6),
    "EKF2_NOAID_TOUT": (5000000, PARAM_TYPE_INT32, 500000, 10000000),   # us of dead reckoning allowed
    "NAV_ACC_RAD": (2.0, PARAM_TYPE_REAL32, 0.05, 200.0),     # a waypoint's default acceptance radius, m
    "NAV_MC_ALT_RAD": (0.8, PARAM_TYPE_REAL32, 0.05, 200.0),  # a mission altitude's acceptance, m
    # the failsafe geofence about home (docs/PX4_FACTS.md, "Geofence"): its action, and its largest
    # horizontal distance and height from home (m; 0 off)
    "GF_ACTION": (2, PARAM_TYPE_INT32, 0, 5),
    "GF_MAX_HOR_DIST": (0.0, PARAM_TYPE_REAL32, 0.0, 10000.0),
    "GF_MAX_VER_DIST": (0.0, PARAM_TYPE_REAL32, 0.0, 10000.0),
}

#: Stream name -> default rate (Hz): PX4's on the offboard link.
STREAM_RATES_HZ: dict[str, float] = {
    "HEARTBEAT": 1.0,
    "SYS_STATUS": 5.0,
    "EXTENDED_SYS_STATE": 5.0,
    "LOCAL_POSITION_NED": 30.0,
    "ODOMETRY": 30.0,
    "ATTITUDE": 30.0,
    "GLOBAL_POSITION_INT": 50.0,
    "HOME_POSITION": 0.5,
    "GPS_RAW_INT": 0.0,  # off unless set or requested (MAV_CMD_REQUEST_MESSAGE 24)
    "TIMESYNC": 10.0,  # requests (tc1 0, ts1 the boot clock in ns), as PX4 sends them on its links
    "MISSION_CURRENT": 1.0,
}


def heartbeat_mode(custom_mode: int) -> tuple[int, int]:
    """PX4's (main, sub) mode from a HEARTBEAT's custom_mode ((main << 16) | (sub << 24))."""
    return (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF


def heartbeat_mode_name(custom_mode: int) -> str:
    """A PX4 HEARTBEAT's mode as PX4 names it (``OFFBOARD``, ``AUTO.LOITER``; else ``main.sub``)."""
    main, sub = heartbeat_mode(custom_mode)
    return mode_from_custom(main, sub) or f"{main}.{sub}"


def engaged(base_mode: int, custom_mode: int) -> bool:
    """True when a PX4 HEARTBEAT shows the vehicle armed in OFFBOARD (a companion flies it)."""
    return bool(base_mode & ARMED_FLAG) and heartbeat_mode(custom_mode)[0] == OFFBOARD_MAIN_MODE


def mode_from_custom(main: int, sub: int) -> str | None:
    """Mode name for PX4 (main, sub); AUTO with sub 0 is not a mode mavsim flies."""
    if main != 4:
        sub = 0
    return _MODE_BY_NUMBER.get((main, sub))


def _display(main: int, sub: int) -> str:
    name = mode_from_custom(main, sub)
    if name:
        return DISPLAY[name]
    if main == 4:
        return _AUTO_SUB_DISPLAY.get(sub, "Auto")
    return _MAIN_DISPLAY.get(main, f"mode {main}")


class Commander:
    """Mode, arming and failsafe logic of the autopilot.

    Parameters
    ----------
    params : ParamStore
    mode : str
        Initial mode (a key of :data:`MODES`).
    armed : bool
        Initially armed.
    vehicle : VehicleState
        Initial true state (the hold point is taken from it).
    arming_delay_s : float
        Arming is denied before this simulated time.
    offboard_reject_ack : int
        ACK result when OFFBOARD is refused for lack of a stream.
    """

    def __init__(self, params: ParamStore, mode: str, armed: bool, vehicle: VehicleState,
                 arming_delay_s: float = 0.0, offboard_reject_ack: int = 0) -> None:
        self.params = params
        self.mode = mode
        self.armed = armed
        self.failsafe = False
        #: the estimator has a local position (False after EKF2_NOAID_TOUT without aiding)
        self.position_valid = True
        self.arming_delay_s = arming_delay_s
        self.offboard_reject_ack = offboard_reject_ack
        self.setpoint: OffboardSetpoint | None = None
        self._parts_of: OffboardSetpoint | None = None   # the setpoint self._parts was worked out for
        self._parts: tuple = ()
        self.last_setpoint_s = -math.inf
        self.hold_point = vehicle.position_ned_m.copy()
        self.takeoff_z = min(vehicle.position_ned_m[2], -params["MIS_TAKEOFF_ALT"])
        # An airborne spawn that is not armed is held in place, as on a stand, until armed.
        self.on_stand = not armed and not vehicle.on_ground
        self.arm_time_s = 0.0 if armed else -math.inf
        self.was_airborne = not vehicle.on_ground
        self.landed_since_s: float | None = None
        self.texts: list[tuple[int, str]] = []
        self.mode_changes: list[tuple[float, str]] = [(0.0, mode)]
        self.announce: list[int] = []
        self.mission_items: list[MissionItem] = []   # the stored mission, local NED (load_mission)
        self.mission_start = 0                        # the stored current item (MISSION_SET_CURRENT)
        self.mission: MissionFlight | None = None     # the mission being flown (AUTO.MISSION)
        self._reached: list[int] = []                 # items reached, to be sent (MISSION_ITEM_REACHED)
        self._reached_repeats = 0                     # times the last one is sent again, with MISSION_CURRENT
        self._last_reached = 0
        self._acc_integrator = np.zeros(3)
        #: the failsafe geofence (GF_*) and the stored fence zones (:mod:`mavsim.personalities.px4_geofence`)
        self.geofence = GeofenceWatch(params)
        self._enter(mode, vehicle, 0.0)

    # ------------------------------------------------------------------ encoding
    @property
    def custom_mode(self) -> int:
        main, sub = MODES[self.mode]
        return (main << 16) | (sub << 24)

    @property
    def base_mode(self) -> int:
        main, _ = MODES[self.mode]
        flags = {2: 64 | 16, 3: 64 | 16, 4: 4 | 8 | 16, 6: 16}[main]
        return 1 | flags | (128 if self.armed else 0)

    @property
    def system_status(self) -> int:
        if not self.armed:
            return 3
        return 5 if self.failsafe else 4

    @property
    def engaged(self) -> bool:
        """Armed in OFFBOARD."""
        return self.armed and self.mode == "OFFBOARD"

    def landed_state(self, vehicle: VehicleState) -> int:
        """MAV_LANDED_STATE: on ground 1, in air 2, taking off 3, landing 4 (RTL sinking > 0.3 m/s)."""
        if vehicle.on_ground:
            return 1
        if self.mode == "AUTO.TAKEOFF":
            return 3
        if self.mode == "AUTO.LAND" or (self.mode == "AUTO.RTL" and vehicle.velocity_ned_mps[2] > 0.3):
            return 4
        return 2

    def sends(self, msg_id: int) -> bool:
        """Every stream has something to send."""
        return True

    def message(self, msg_id: int, now_us: int, vehicle: VehicleState, est_pos: np.ndarray, est_vel: np.ndarray):
        """The mission's MISSION_CURRENT (42) and MISSION_ITEM_REACHED (46); None for the rest
        (PX4's other messages are the generic ones)."""
        if msg_id == 42:
            if self._reached_repeats > 0:             # PX4 sends the last item reached again with it
                self._reached_repeats -= 1
                self._reached.append(self._last_reached)
                self.announce.append(46)
            m = self.mission
            if m is None:     # PX4 said "no mission" (1) with a mission stored but not started (measured)
                return mavlink2.MAVLink_mission_current_message(self.mission_start, len(self.mission_items),
                                                                NO_MISSION, 0)
            return mavlink2.MAVLink_mission_current_message(m.current, m.total, m.state,
                                                            int(self.mode == "AUTO.MISSION"))
        if msg_id == 46 and self._reached:
            return mavlink2.MAVLink_mission_item_reached_message(self._reached.pop(0))
        return None

    def load_mission(self, items: list[MissionItem], current: int) -> None:
        """A new stored mission (local NED) and its current item, after an upload or a clear; a
        mission in flight flies on until AUTO.MISSION is entered again."""
        self.mission_items = list(items)
        self.mission_start = int(current)

    def load_fence(self, items: list[MissionItem]) -> None:
        """The stored fence (local NED), after an upload or a clear: kept from the next step."""
        self.geofence.load(FenceZones.from_items(items))

    def set_mission_current(self, seq: int) -> None:
        """MISSION_SET_CURRENT: the mission goes on from item ``seq``, at once if it is flying."""
        self.mission_start = int(seq)
        if self.mission is not None and self.mission.items is self.mission_items:
            self.mission.jump(int(seq))

    def request_mission_start(self, first: float, now_s: float, vehicle: VehicleState) -> int:
        """MAV_CMD_MISSION_START (param1: the first item; NaN or 0: the stored current one)."""
        if not self.mission_items:
            self._say(SEV_CRITICAL, "Mission start denied! No valid mission")
            return mavlink2.MAV_RESULT_DENIED
        if math.isfinite(first) and 0 < first < len(self.mission_items):
            self.mission_start = int(first)
        return self.request_mode(*MODES["AUTO.MISSION"], now_s, vehicle)

    def offboard_signal(self, now_s: float) -> bool:
        """True while the newest accepted setpoint is younger than COM_OF_LOSS_T."""
        return now_s - self.last_setpoint_s <= self.params["COM_OF_LOSS_T"]

    # ------------------------------------------------------------------ requests
    def _say(self, severity: int, text: str) -> None:
        logger.info("STATUSTEXT %d: %s", severity, text)
        self.texts.append((severity, text))

    def _enter(self, mode: str, vehicle: VehicleState, now_s: float) -> None:
        if mode != self.mode:
            self.mode_changes.append((now_s, mode))
            logger.info("t=%.2f mode %s -> %s", now_s, self.mode, mode)
        self.mode = mode
        p = vehicle.position_ned_m
        self.hold_point = p.copy()
        if mode == "OFFBOARD":
            self._acc_integrator = vehicle.velocity_ned_mps.copy()

    def request_mode(self, main: int, sub: int, now_s: float, vehicle: VehicleState) -> int:
        """A mode change asked by MAV_CMD_DO_SET_MODE (param2 main, param3 sub mode) or SET_MODE;
        returns the MAV_RESULT."""
        name = mode_from_custom(main, sub)
        if name is None:
            # Manual-input modes (no RC here) and missions (none loaded) are not available.
            self._say(SEV_CRITICAL, f"Switching to {_display(main, sub)} is currently not available")
            return mavlink2.MAV_RESULT_ACCEPTED
        if not self.position_valid and name != "ALTCTL":
            self._say(SEV_CRITICAL, f"Switching to {DISPLAY[name]} is currently not available")
            return self.offboard_reject_ack if name == "OFFBOARD" else mavlink2.MAV_RESULT_ACCEPTED
        if name == "OFFBOARD" and self.armed and not self.offboard_signal(now_s):
            self._say(SEV_CRITICAL, "Switching to Offboard is currently not available")
            return self.offboard_reject_ack
        if name == "AUTO.MISSION":
            if not self.mission_items:
                self._say(SEV_CRITICAL, "Mission start denied! No valid mission")
                return mavlink2.MAV_RESULT_DENIED
            m = self.mission
            if m is None or m.items is not self.mission_items or m.state != ACTIVE:
                self.mission = MissionFlight(self.mission_items, self.params, POS_GAIN_PER_S, self.mission_start)
            elif self.mode != "AUTO.MISSION":
                m.jump(m.current)          # back in the mission: on from the item it was at
        if name == "AUTO.TAKEOFF" and self.mode != "AUTO.TAKEOFF":
            self.takeoff_z = min(vehicle.position_ned_m[2], -self.params["MIS_TAKEOFF_ALT"])
        self.failsafe = False
        self._enter(name, vehicle, now_s)
        return mavlink2.MAV_RESULT_ACCEPTED

    def request_set_mode(self, custom_mode: int, now_s: float, vehicle: VehicleState) -> int:
        """SET_MODE: ``custom_mode`` packs (main << 16) | (sub << 24)."""
        return self.request_mode(*heartbeat_mode(custom_mode), now_s, vehicle)

    def request_land(self, now_s: float, vehicle: VehicleState) -> int:
        """MAV_CMD_NAV_LAND: AUTO.LAND."""
        return self.request_mode(*MODES["AUTO.LAND"], now_s, vehicle)

    def request_return(self, now_s: float, vehicle: VehicleState) -> int:
        """MAV_CMD_NAV_RETURN_TO_LAUNCH: AUTO.RTL."""
        return self.request_mode(*MODES["AUTO.RTL"], now_s, vehicle)

    def request_hold(self, now_s: float, vehicle: VehicleState) -> int:
        """MAV_CMD_NAV_LOITER_UNLIM: AUTO.LOITER."""
        return self.request_mode(*MODES["AUTO.LOITER"], now_s, vehicle)

    def request_takeoff(self, rel_alt_m: float, now_s: float, vehicle: VehicleState) -> int:
        """MAV_CMD_NAV_TAKEOFF to ``rel_alt_m`` above home (NaN: MIS_TAKEOFF_ALT)."""
        alt = self.params["MIS_TAKEOFF_ALT"] if not math.isfinite(rel_alt_m) else rel_alt_m
        if not 0.0 < alt <= 1000.0:
            self._say(SEV_CRITICAL, "Takeoff denied: altitude out of range")
            return mavlink2.MAV_RESULT_DENIED
        self.failsafe = False
        self._enter("AUTO.TAKEOFF", vehicle, now_s)
        self.takeoff_z = min(vehicle.position_ned_m[2], -alt)
        return mavlink2.MAV_RESULT_ACCEPTED

    def request_arm(self, arm: bool, force: bool, now_s: float, vehicle: VehicleState) -> int:
        """MAV_CMD_COMPONENT_ARM_DISARM; returns the MAV_RESULT."""
        if arm:
            if self.armed:
                return mavlink2.MAV_RESULT_ACCEPTED
            if now_s < self.arming_delay_s and not force:
                self._say(SEV_CRITICAL, "Arming denied: Resolve system health failures first")
                return mavlink2.MAV_RESULT_TEMPORARILY_REJECTED
            if self.mode == "OFFBOARD" and not self.offboard_signal(now_s):
                self._say(SEV_CRITICAL, "Arming denied: No offboard signal")
                return mavlink2.MAV_RESULT_TEMPORARILY_REJECTED
            self.armed = True
            self.on_stand = False
            self.arm_time_s = now_s
            self.was_airborne = not vehicle.on_ground
            self.landed_since_s = None
            self.hold_point = vehicle.position_ned_m.copy()
            self._say(SEV_INFO, "Armed by external command")
            return mavlink2.MAV_RESULT_ACCEPTED
        if not self.armed:
            return mavlink2.MAV_RESULT_ACCEPTED
        if not vehicle.on_ground and not force:
            self._say(SEV_CRITICAL, "Disarming denied: not landed")
            return mavlink2.MAV_RESULT_TEMPORARILY_REJECTED
        self._disarm("Disarmed by external command")
        return mavlink2.MAV_RESULT_ACCEPTED

    def _disarm(self, why: str) -> None:
        self.armed = False
        self.failsafe = False
        self._say(SEV_INFO, why)

    def accept_setpoint(self, sp: OffboardSetpoint, now_s: float) -> None:
        """Store a validated setpoint; it is proof of life and applies in OFFBOARD."""
        self.setpoint = sp
        self.last_setpoint_s = now_s

    def position_aiding(self, unaided_s: float | None, now_s: float, vehicle: VehicleState) -> None:
        """The estimator has dead-reckoned for ``unaided_s`` seconds (None: it is aided): past
        EKF2_NOAID_TOUT the local position is invalid and an armed vehicle in a mode that needs
        it fails safe to ALTCTL and lands blind; once aided again, a vehicle that failed safe so
        returns."""
        if self.position_valid and unaided_s is not None and unaided_s * 1e6 >= self.params["EKF2_NOAID_TOUT"]:
            self.position_valid = False
            if self.armed and self.mode != "ALTCTL":
                self._say(SEV_CRITICAL, "Failsafe: blind land")
                self._say(SEV_CRITICAL, "Failsafe activated")
                self._enter("ALTCTL", vehicle, now_s)
                self.failsafe = True
        elif not self.position_valid and unaided_s is None:
            self.position_valid = True
            if self.armed and self.failsafe and self.mode == "ALTCTL":
                self._enter("AUTO.RTL", vehicle, now_s)

    # ------------------------------------------------------------------ control
    def update(self, now_s: float, dt: float, vehicle: VehicleState) -> VehicleCommand:
        """Run failsafe and auto-disarm checks, then return this step's command."""
        p = vehicle.position_ned_m
        if self.armed:
            self._checks(now_s, vehicle)
        if not self.armed:
            # Disarmed: no thrust, except that an airborne spawn is held as on a stand.
            return VehicleCommand(np.zeros(3), motors_on=self.on_stand)
        yaw = yaw_rate = None
        if self.mode == "OFFBOARD" and self.setpoint is not None:
            v, yaw, yaw_rate = self._offboard(dt, vehicle)
        elif self.mode == "AUTO.TAKEOFF":
            v = POS_GAIN_PER_S * (self.hold_point - p)
            err = self.takeoff_z - p[2]
            # MPC_Z_P like the hold: with the vehicle's 0.3 s velocity lag this approach is
            # nearly critically damped (a gain of 2/s overshot the target altitude by ~0.15 m)
            v[2] = max(-self.params["MPC_TKO_SPEED"], min(0.0, POS_GAIN_PER_S * err))
            if err > -0.05:
                self._say(SEV_INFO, "Takeoff complete")
                self._enter("AUTO.LOITER", vehicle, now_s)
                self.hold_point[2] = self.takeoff_z
        elif self.mode == "AUTO.LAND":
            v = POS_GAIN_PER_S * (self.hold_point - p)
            v[2] = self.params["MPC_LAND_SPEED"]
        elif self.mode == "AUTO.RTL":
            d = -p[:2]
            dist = float(np.hypot(d[0], d[1]))
            v = np.zeros(3)
            if dist > 0.5:
                v[:2] = d / dist * min(self.params["MPC_XY_CRUISE"], POS_GAIN_PER_S * dist)
            else:
                v[:2] = POS_GAIN_PER_S * d
                v[2] = self.params["MPC_LAND_SPEED"]
        elif self.mode == "AUTO.MISSION" and self.mission is not None:
            v = self.mission.command(now_s, p)
            if self.mission.reached:
                self._reached += self.mission.reached
                self.announce += [46] * len(self.mission.reached)
                self._last_reached, self._reached_repeats = self.mission.reached[-1], REACHED_REPEATS
                self.mission.reached.clear()
            if self.mission.landing and vehicle.on_ground:
                self.mission.state = COMPLETE
            if self.mission.hand_over is not None:
                self._enter(self.mission.hand_over, vehicle, now_s)
                self.mission.hand_over = None
        elif self.mode == "ALTCTL":   # no horizontal position: level; a failsafe's blind land descends
            v = np.array([0.0, 0.0, self.params["MPC_LAND_SPEED"] if self.failsafe
                          else POS_GAIN_PER_S * (self.hold_point[2] - p[2])])
        else:  # POSCTL, AUTO.LOITER, OFFBOARD before any setpoint: hold
            v = POS_GAIN_PER_S * (self.hold_point - p)
        return VehicleCommand(self._limit(v), yaw, yaw_rate, True)

    def _limit(self, v: np.ndarray) -> np.ndarray:
        vmax = self.params["MPC_XY_VEL_MAX"]
        h = math.hypot(v[0], v[1])
        if h > vmax:
            v = v.copy()
            v[:2] *= vmax / h
        v[2] = min(max(v[2], -self.params["MPC_Z_VEL_MAX_UP"]), self.params["MPC_Z_VEL_MAX_DN"])
        return v

    def _setpoint_parts(self, sp: OffboardSetpoint) -> tuple:
        """Which fields of ``sp`` apply, their values with the ignored ones zeroed, and whether only its
        velocity applies, worked out once per setpoint (setpoints arrive at about 20 Hz, the physics
        steps at 100 Hz)."""
        if self._parts_of is not sp:
            pos_ok, vel_ok, acc_ok = (np.isfinite(sp.position_ned_m), np.isfinite(sp.velocity_ned_mps),
                                      np.isfinite(sp.accel_ned_mps2))
            velocity_only = bool(vel_ok.all() and not pos_ok.any() and not acc_ok.any())
            self._parts = (pos_ok, vel_ok, acc_ok, np.where(pos_ok, sp.position_ned_m, 0.0),
                           np.where(vel_ok, sp.velocity_ned_mps, 0.0), np.where(acc_ok, sp.accel_ned_mps2, 0.0),
                           velocity_only)
            self._parts_of = sp
        return self._parts

    def _offboard(self, dt: float, vehicle: VehicleState) -> tuple[np.ndarray, float | None, float | None]:
        sp = self.setpoint
        assert sp is not None
        p = vehicle.position_ned_m
        pos_ok, vel_ok, acc_ok, pos_sp, vel_ff, acc_sp, velocity_only = self._setpoint_parts(sp)
        if velocity_only:    # what the general case below gives for it (the companion's setpoints)
            self._acc_integrator = vehicle.velocity_ned_mps.copy()
            v = vel_ff.copy()
        else:
            self._acc_integrator = np.where(acc_ok, self._acc_integrator + acc_sp * dt, vehicle.velocity_ned_mps)
            v = np.where(pos_ok, POS_GAIN_PER_S * (pos_sp - p) + vel_ff,
                         np.where(vel_ok, vel_ff, np.where(acc_ok, self._acc_integrator, 0.0)))
        yaw = sp.yaw_rad if math.isfinite(sp.yaw_rad) else None
        rate = sp.yaw_rate_radps if math.isfinite(sp.yaw_rate_radps) else None
        return v, yaw, rate

    def _checks(self, now_s: float, vehicle: VehicleState) -> None:
        fence = self.geofence.step(now_s, vehicle.position_ned_m, self.mode)
        if fence is not None:
            for text in fence.texts:
                self._say(SEV_WARNING, text)
            if fence.mode is not None:
                self._enter(fence.mode, vehicle, now_s)
                self.failsafe = True
        if self.mode == "OFFBOARD" and not self.offboard_signal(now_s):
            fallback = _FALLBACK[int(self.params["COM_OBL_RC_ACT"])]
            self._say(SEV_CRITICAL, f"Failsafe: offboard lost, switching to {DISPLAY[fallback]}")
            self._enter(fallback, vehicle, now_s)
            self.failsafe = True
        if not vehicle.on_ground:
            self.was_airborne = True
            self.landed_since_s = None
            return
        if self.was_airborne:
            if self.landed_since_s is None:
                self.landed_since_s = now_s
                self._say(SEV_INFO, "Landing detected")
            t = self.params["COM_DISARM_LAND"]
            if t >= 0 and now_s - self.landed_since_s >= t:
                self._disarm("Disarmed by landing")
        else:
            t = self.params["COM_DISARM_PRFLT"]
            if t >= 0 and now_s - self.arm_time_s >= t:
                self._disarm("Disarmed by auto preflight disarming")


class Px4Personality:
    """PX4 as mavsim imitates it: the :class:`~mavsim.personalities.base.Personality` of PX4 main
    (1.15) on a quadrotor, with PX4's velocity loop on SIH as the ``"px4"`` vehicle profile."""

    name = "px4"
    mav_type = MAV_TYPE_QUADROTOR
    mav_autopilot = MAV_AUTOPILOT_PX4
    flight_sw_version = (1 << 24) | (15 << 16) | (0 << 8) | 0xFF   # 1.15.0 official (0xFF type byte)
    vendor_id = 0x26AC
    product_id = 0x0011
    mode_names = START_MODES
    params = PARAMS
    stream_rates_hz = STREAM_RATES_HZ
    response_models = {"px4": Px4Response()}
    param_ints_bytewise = True      # MAV_PARAM_TYPE_INT32 bits in the float field
    takeoff_alt_amsl = True         # NAV_TAKEOFF param7 is AMSL
    gps_outage_max_s = None         # past EKF2_NOAID_TOUT its failsafe (Commander.position_aiding)

    def default_arming_delay_s(self, airborne: bool) -> float:
        """No delay unless the scenario sets one."""
        return 0.0

    def default_start_mode(self, airborne: bool) -> str:
        """Hovering in AUTO.LOITER when airborne, POSCTL on the ground (as PX4 SITL boots)."""
        return "AUTO.LOITER" if airborne else "POSCTL"

    def commander(self, params: ParamStore, start_mode: str, armed: bool, vehicle: VehicleState,
                  arming_delay_s: float, offboard_reject_ack: int) -> Commander:
        return Commander(params, start_mode, armed, vehicle, arming_delay_s, offboard_reject_ack)

    def heartbeat_mode_name(self, custom_mode: int) -> str:
        return heartbeat_mode_name(custom_mode)

    def engaged(self, base_mode: int, custom_mode: int) -> bool:
        return engaged(base_mode, custom_mode)


#: The PX4 personality (registered as ``"px4"`` in :mod:`mavsim.personalities`).
PX4 = Px4Personality()
