"""The ArduPilot (ArduCopter) personality: HEARTBEAT identity, modes, readiness, GUIDED, streams.

:data:`ARDUPILOT` is what mavsim's generic core asks (:class:`mavsim.personalities.base.Personality`);
its :class:`Commander` is ArduCopter's mode, arming and GUIDED behaviour. Pure and clock-free:
every call takes the simulated time ``now_s`` and the true vehicle state.

Imitated (measured on ArduCopter SITL 4.7.0-dev; ``docs/ARDUPILOT_SIM.md``):

- HEARTBEAT type 2, autopilot 3 (ARDUPILOTMEGA); ``custom_mode`` is the plain mode number
  (:data:`MODES`: STABILIZE 0, GUIDED 4, LOITER 5, RTL 6, LAND 9, BRAKE 17 ...); base_mode
  1 + 16 + 64 (81), + 8 in the navigating modes (GUIDED, LOITER, RTL, LAND, BRAKE, POSHOLD:
  89), + 128 armed (217); system_status 3 standby (disarmed or on the ground), 4 flying.
  It boots in STABILIZE.
- Readiness: the EKF has an absolute horizontal position ``ready_s`` after boot (``[sim]
  arming_delay_s``; unset: :data:`DEFAULT_READY_S` on the ground, 0 for an airborne spawn; SITL
  takes about 41 s). Before that EKF_STATUS_REPORT.flags is 167 (CONST_POS_MODE), then 831
  (POS_HORIZ_ABS); LOCAL_POSITION_NED is not sent at all; arming in a mode that needs a
  position fails (ACK 4, "Arm: Need Position Estimate"), and so does switching to such a
  mode while armed. The EKF origin and home are set at half ``ready_s`` (SITL: 20 s of 41 s):
  GPS_GLOBAL_ORIGIN and HOME_POSITION are then sent once on every link, unrequested, and
  are not sent before.
- Streams: none by default but HEARTBEAT at 1 Hz; a client asks for each message with
  MAV_CMD_SET_MESSAGE_INTERVAL (ODOMETRY and TIMESYNC are not streams: ACK 2).
  POSITION_TARGET_LOCAL_NED echoes the GUIDED target (GUIDED only).
- Modes: MAV_CMD_DO_SET_MODE (param1 1, param2 the number) or SET_MODE; a mode mavsim does
  not fly, or an unknown number, fails with ACK 4. Arming: MAV_CMD_COMPONENT_ARM_DISARM,
  refused ACK 4 with a STATUSTEXT; DISARM_DELAY s after arming on the ground without a
  takeoff it disarms. MAV_CMD_NAV_TAKEOFF (param7 metres above home) in GUIDED, armed, on
  the ground: climbs at up to WPNAV_SPEED_UP, staying in GUIDED, then holds.
- GUIDED: SET_POSITION_TARGET_LOCAL_NED is used in GUIDED only (silently ignored in other
  modes). A velocity (or acceleration) target is held GUID_TIMEOUT s after the last one,
  then zeroed: the vehicle stops and hovers, still in GUIDED (no failsafe). A position +
  velocity target moves on at that velocity until the timeout, then stops there. A
  position-only target has no timeout.
- Parameters travel as floats (ArduPilot's encoding, integers by value).

The velocity response is :mod:`mavsim.personalities.ardupilot_response` (``[sim] vehicle =
"ardupilot"``, fitted to SITL's step responses).

Deviations: STABILIZE, ALT_HOLD, POSHOLD, LOITER and BRAKE in the air all hold the stopping
point (no RC: sticks centred); RTL flies home at the current altitude, then lands; LAND
descends at LAND_SPEED all the way; STATUSTEXTs go to every link at once (ArduPilot waits until
a link has sent something); GLOBAL_POSITION_INT carries the position before readiness too;
SET_POSITION_TARGET_LOCAL_NED frames 7 and 9 (offsets) are refused as by the generic core.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as apm
from pymavlink.dialects.v20 import common as mavlink2

from mavsim.params import PARAM_TYPE_INT8, PARAM_TYPE_INT16, PARAM_TYPE_REAL32, ParamStore, ParamTable
from mavsim.personalities.ardupilot_response import ArduPilotResponse
from mavsim.personalities.base import SEV_CRITICAL, SEV_INFO, OffboardSetpoint
from mavsim.vehicle import VehicleCommand, VehicleState

logger = logging.getLogger(__name__)

__all__ = ["ARDUPILOT", "ArduPilotPersonality", "Commander", "MODES", "START_MODES", "PARAMS", "STREAM_RATES_HZ",
           "DEFAULT_READY_S", "EKF_FLAGS_NO_POSITION", "EKF_FLAGS_READY", "heartbeat_mode_name", "engaged"]

#: ArduCopter's mode numbers (``custom_mode``).
MODES: dict[str, int] = {
    "STABILIZE": 0, "ACRO": 1, "ALT_HOLD": 2, "AUTO": 3, "GUIDED": 4, "LOITER": 5, "RTL": 6, "CIRCLE": 7,
    "LAND": 9, "DRIFT": 11, "SPORT": 13, "FLIP": 14, "AUTOTUNE": 15, "POSHOLD": 16, "BRAKE": 17, "THROW": 18,
    "AVOID_ADSB": 19, "GUIDED_NOGPS": 20, "SMART_RTL": 21,
}
_NAME_BY_NUMBER = {v: k for k, v in MODES.items()}
#: The modes mavsim flies (and ``[sim] start_mode`` accepts).
START_MODES = ("STABILIZE", "ALT_HOLD", "GUIDED", "LOITER", "RTL", "LAND", "POSHOLD", "BRAKE")
#: Modes that need the EKF's position (ArduCopter's ``requires_GPS``).
_NEEDS_POSITION = frozenset({"GUIDED", "LOITER", "RTL", "POSHOLD", "BRAKE"})
#: Modes whose HEARTBEAT carries MAV_MODE_FLAG_GUIDED_ENABLED (8).
_GUIDED_FLAG = frozenset({"AUTO", "GUIDED", "LOITER", "RTL", "LAND", "CIRCLE", "POSHOLD", "BRAKE", "AVOID_ADSB",
                          "SMART_RTL"})

MAV_TYPE_QUADROTOR = 2
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
GUIDED_MODE = MODES["GUIDED"]
ARMED_FLAG = 128
#: EKF_STATUS_REPORT.flags before the EKF has an absolute position (attitude, velocities, vertical
#: position, CONST_POS_MODE) and after (+ POS_HORIZ_REL, POS_HORIZ_ABS, PRED_POS_HORIZ_*, no CONST_POS_MODE).
EKF_FLAGS_NO_POSITION = 167
EKF_FLAGS_READY = 831
#: Simulated seconds to readiness on the ground when the scenario sets no ``arming_delay_s``.
DEFAULT_READY_S = 5.0

POS_GAIN_PER_S = 1.0        # PSC_POSXY_P / PSC_POSZ_P
BRAKE_ACCEL_MPS2 = 2.5      # stopping distance of LOITER / BRAKE entry (WPNAV_ACCEL)
LAND_DISARM_S = 1.0         # on the ground in LAND this long: disarmed

#: name -> (default, type, min, max). Defaults as ArduCopter 4.7 (speeds in cm/s as ArduPilot has them).
PARAMS: ParamTable = {
    "GUID_TIMEOUT": (3.0, PARAM_TYPE_REAL32, 0.1, 5.0),
    "GUID_OPTIONS": (0, PARAM_TYPE_INT16, 0, 65535),
    "DISARM_DELAY": (10, PARAM_TYPE_INT8, 0, 127),
    "WPNAV_SPEED": (1000.0, PARAM_TYPE_REAL32, 10.0, 2000.0),
    "WPNAV_SPEED_UP": (250.0, PARAM_TYPE_REAL32, 10.0, 1000.0),
    "WPNAV_SPEED_DN": (150.0, PARAM_TYPE_REAL32, 10.0, 500.0),
    "LAND_SPEED": (50, PARAM_TYPE_INT16, 30, 200),
    "TKOFF_SLEW_TIME": (2.0, PARAM_TYPE_REAL32, 0.25, 5.0),
    "FS_GCS_ENABLE": (0, PARAM_TYPE_INT8, 0, 7),
    "AVD_ENABLE": (0, PARAM_TYPE_INT8, 0, 1),
    "MAV_SYSID": (1, PARAM_TYPE_INT16, 1, 255),
}

#: Stream name -> default rate (Hz): nothing but HEARTBEAT until asked (ArduCopter's MAVn_* are 0).
STREAM_RATES_HZ: dict[str, float] = {
    "HEARTBEAT": 1.0,
    "SYS_STATUS": 0.0,
    "EXTENDED_SYS_STATE": 0.0,
    "LOCAL_POSITION_NED": 0.0,
    "ATTITUDE": 0.0,
    "GLOBAL_POSITION_INT": 0.0,
    "HOME_POSITION": 0.0,
    "GPS_GLOBAL_ORIGIN": 0.0,
    "GPS_RAW_INT": 0.0,
    "POSITION_TARGET_LOCAL_NED": 0.0,
    "EKF_STATUS_REPORT": 0.0,
}
MSG_LOCAL_POSITION_NED, MSG_GPS_GLOBAL_ORIGIN, MSG_POSITION_TARGET, MSG_EKF_STATUS, MSG_HOME = 32, 49, 85, 193, 242


def heartbeat_mode_name(custom_mode: int) -> str:
    """An ArduCopter HEARTBEAT's mode name (``GUIDED``, ``LOITER``; else ``mode N``)."""
    return _NAME_BY_NUMBER.get(int(custom_mode), f"mode {int(custom_mode)}")


def engaged(base_mode: int, custom_mode: int) -> bool:
    """True when an ArduCopter HEARTBEAT shows it armed in GUIDED (a companion flies it)."""
    return bool(base_mode & ARMED_FLAG) and int(custom_mode) == GUIDED_MODE


class Commander:
    """ArduCopter's modes, arming, readiness and GUIDED targets (see the module docstring).

    Parameters
    ----------
    params : ParamStore
    mode : str
        Initial mode (one of :data:`START_MODES`).
    armed : bool
    vehicle : VehicleState
        Initial true state.
    ready_s : float
        Simulated time the EKF has an absolute position (origin and home at half of it).
    """

    def __init__(self, params: ParamStore, mode: str, armed: bool, vehicle: VehicleState, ready_s: float) -> None:
        self.params = params
        self.mode = mode
        self.armed = armed
        self.ready_s = float(ready_s)
        self.origin_s = self.ready_s / 2.0
        self.ready = self.ready_s <= 0.0
        self.origin_set = self.origin_s <= 0.0
        #: Message ids to send once on every link (GPS_GLOBAL_ORIGIN, HOME_POSITION when set).
        self.announce: list[int] = []
        self.texts: list[tuple[int, str]] = []
        self.mode_changes: list[tuple[float, str]] = [(0.0, mode)]
        self.on_stand = not armed and not vehicle.on_ground
        self.arm_time_s = 0.0 if armed else -math.inf
        self.was_airborne = not vehicle.on_ground
        self.landed_since_s: float | None = None
        self.hold_point = vehicle.position_ned_m.copy()
        self.setpoint: OffboardSetpoint | None = None
        self.setpoint_s = -math.inf
        self.takeoff_z: float | None = None
        self._takeoff_start_s = 0.0
        self._acc_velocity = np.zeros(3)

    # ------------------------------------------------------------------ encoding
    @property
    def custom_mode(self) -> int:
        return MODES[self.mode]

    @property
    def base_mode(self) -> int:
        return 1 | 16 | 64 | (8 if self.mode in _GUIDED_FLAG else 0) | (ARMED_FLAG if self.armed else 0)

    @property
    def system_status(self) -> int:
        return 4 if self.armed and self.was_airborne else 3

    @property
    def engaged(self) -> bool:
        """Armed in GUIDED."""
        return self.armed and self.mode == "GUIDED"

    def landed_state(self, vehicle: VehicleState) -> int:
        """MAV_LANDED_STATE: on ground 1, in air 2, taking off 3, landing 4."""
        if vehicle.on_ground:
            return 1
        if self.takeoff_z is not None:
            return 3
        return 4 if self.mode == "LAND" else 2

    # ------------------------------------------------------------------ telemetry hooks
    def sends(self, msg_id: int) -> bool:
        """Whether a due stream ``msg_id`` has something to send now."""
        if msg_id == MSG_LOCAL_POSITION_NED:
            return self.ready
        if msg_id == MSG_POSITION_TARGET:
            return self.mode == "GUIDED"
        if msg_id in (MSG_GPS_GLOBAL_ORIGIN, MSG_HOME):
            return self.origin_set
        return True

    def message(self, msg_id: int, now_us: int, vehicle: VehicleState, est_pos: np.ndarray, est_vel: np.ndarray):
        """EKF_STATUS_REPORT and POSITION_TARGET_LOCAL_NED (ArduCopter's own); None for the rest."""
        if msg_id == MSG_EKF_STATUS:
            flags = EKF_FLAGS_READY if self.ready else EKF_FLAGS_NO_POSITION
            return apm.MAVLink_ekf_status_report_message(flags, 0.02, 0.01 if self.ready else 0.0, 0.01, 0.03, 0.0)
        if msg_id == MSG_POSITION_TARGET:
            return self._target_message(now_us * 1e-6, vehicle)
        return None

    def _target_message(self, now_s: float, vehicle: VehicleState):
        sp = self.setpoint if self.mode == "GUIDED" else None
        nan3 = np.full(3, math.nan)
        if sp is None or self.takeoff_z is not None:
            pos, vel, acc = self.hold_point if self.takeoff_z is None else \
                np.array([self.hold_point[0], self.hold_point[1], self.takeoff_z]), np.zeros(3), nan3
            mask = 0b110111000000 | 0b111000
        else:
            pos, vel, acc = self._target(now_s)
            mask = 0b110000000000
            for i, arr in enumerate((pos, vel, acc)):
                if not np.isfinite(arr).all():
                    mask |= 7 << (3 * i)
        f = [0.0 if not math.isfinite(x) else float(x) for x in (*pos, *vel, *acc)]
        return mavlink2.MAVLink_position_target_local_ned_message(round(now_s * 1e3), 1, mask, *f, 0.0, 0.0)

    # ------------------------------------------------------------------ requests
    def _say(self, severity: int, text: str) -> None:
        logger.info("STATUSTEXT %d: %s", severity, text)
        self.texts.append((severity, text))

    def _stopping_point(self, vehicle: VehicleState) -> np.ndarray:
        v = vehicle.velocity_ned_mps
        return vehicle.position_ned_m + v * (float(np.linalg.norm(v)) / (2.0 * BRAKE_ACCEL_MPS2))

    def _enter(self, mode: str, vehicle: VehicleState, now_s: float) -> None:
        if mode != self.mode:
            self.mode_changes.append((now_s, mode))
            logger.info("t=%.2f mode %s -> %s", now_s, self.mode, mode)
        self.mode = mode
        self.hold_point = self._stopping_point(vehicle) if not vehicle.on_ground else vehicle.position_ned_m.copy()
        self.setpoint = None
        self.takeoff_z = None

    def request_mode(self, custom_mode: int, custom_sub_mode: int, now_s: float, vehicle: VehicleState) -> int:
        """DO_SET_MODE param2 = the mode number (param3 unused)."""
        name = _NAME_BY_NUMBER.get(custom_mode)
        if name is None or name not in START_MODES:
            self._say(SEV_CRITICAL, f"Mode change to {name or custom_mode} failed: unavailable")
            return mavlink2.MAV_RESULT_FAILED
        if name == self.mode:
            return mavlink2.MAV_RESULT_ACCEPTED
        if self.armed and name in _NEEDS_POSITION and not self.ready:
            self._say(SEV_CRITICAL, f"Mode change to {name} failed: requires position")
            return mavlink2.MAV_RESULT_FAILED
        self._enter(name, vehicle, now_s)
        return mavlink2.MAV_RESULT_ACCEPTED

    def request_set_mode(self, custom_mode: int, now_s: float, vehicle: VehicleState) -> int:
        return self.request_mode(custom_mode, 0, now_s, vehicle)

    def request_land(self, now_s: float, vehicle: VehicleState) -> int:
        return self.request_mode(MODES["LAND"], 0, now_s, vehicle)

    def request_return(self, now_s: float, vehicle: VehicleState) -> int:
        return self.request_mode(MODES["RTL"], 0, now_s, vehicle)

    def request_hold(self, now_s: float, vehicle: VehicleState) -> int:
        return self.request_mode(MODES["LOITER"], 0, now_s, vehicle)

    def request_takeoff(self, rel_alt_m: float, now_s: float, vehicle: VehicleState) -> int:
        """NAV_TAKEOFF to ``rel_alt_m`` above home: GUIDED, armed and on the ground only."""
        if not (self.armed and self.mode == "GUIDED" and vehicle.on_ground and math.isfinite(rel_alt_m)
                and 0.0 < rel_alt_m <= 1000.0):
            return mavlink2.MAV_RESULT_FAILED
        self.takeoff_z = -rel_alt_m
        self._takeoff_start_s = now_s
        self.setpoint = None
        self.hold_point = vehicle.position_ned_m.copy()
        return mavlink2.MAV_RESULT_ACCEPTED

    def request_arm(self, arm: bool, force: bool, now_s: float, vehicle: VehicleState) -> int:
        if arm:
            if self.armed:
                return mavlink2.MAV_RESULT_ACCEPTED
            if not force and not self.ready and (self.mode in _NEEDS_POSITION or not self.origin_set):
                self._say(SEV_CRITICAL, "Arm: Need Position Estimate")
                return mavlink2.MAV_RESULT_FAILED
            self.armed = True
            self.on_stand = False
            self.arm_time_s = now_s
            self.was_airborne = not vehicle.on_ground
            self.landed_since_s = None
            self.hold_point = vehicle.position_ned_m.copy()
            self._say(SEV_INFO, "Arming motors")
            return mavlink2.MAV_RESULT_ACCEPTED
        if not self.armed:
            return mavlink2.MAV_RESULT_ACCEPTED
        if not vehicle.on_ground and not force:
            self._say(SEV_CRITICAL, "Disarm: not landed")
            return mavlink2.MAV_RESULT_FAILED
        self._disarm()
        return mavlink2.MAV_RESULT_ACCEPTED

    def _disarm(self) -> None:
        self.armed = False
        self.takeoff_z = None
        self._say(SEV_INFO, "Disarming motors")

    def accept_setpoint(self, sp: OffboardSetpoint, now_s: float) -> None:
        """A target: used in GUIDED only (silently ignored in other modes); it ends a takeoff."""
        if self.mode != "GUIDED":
            return
        self.setpoint = sp
        self.setpoint_s = now_s
        self.takeoff_z = None

    # ------------------------------------------------------------------ control
    def _target(self, now_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The GUIDED target now (position, velocity, acceleration; NaN where unused), the timeout applied."""
        sp = self.setpoint
        assert sp is not None
        pos, vel, acc = sp.position_ned_m, sp.velocity_ned_mps, sp.accel_ned_mps2
        has_vel = bool(np.isfinite(vel).any() or np.isfinite(acc).any())
        if not has_vel:
            return pos, vel, acc
        age = now_s - self.setpoint_s
        timeout = self.params["GUID_TIMEOUT"]
        v = np.where(np.isfinite(vel), vel, 0.0)
        if np.isfinite(pos).any():
            moved = pos + v * min(age, timeout)
            if age > timeout:
                return moved, np.zeros(3), np.full(3, math.nan)
            return moved, vel, acc
        if age > timeout:
            return np.full(3, math.nan), np.zeros(3), np.full(3, math.nan)
        return pos, vel, acc

    def _guided(self, now_s: float, dt: float, vehicle: VehicleState) -> np.ndarray:
        p = vehicle.position_ned_m
        if self.takeoff_z is not None:
            v = POS_GAIN_PER_S * (self.hold_point - p)
            err = self.takeoff_z - p[2]
            ramp = min(1.0, (now_s - self._takeoff_start_s) / self.params["TKOFF_SLEW_TIME"])
            v[2] = max(-self.params["WPNAV_SPEED_UP"] / 100.0 * ramp, min(0.0, POS_GAIN_PER_S * err))
            if err > -0.05 and not vehicle.on_ground:
                self.hold_point = np.array([self.hold_point[0], self.hold_point[1], self.takeoff_z])
                self.takeoff_z = None
            return v
        if self.setpoint is None:
            return POS_GAIN_PER_S * (self.hold_point - p)
        pos, vel, acc = self._target(now_s)
        acc_ok = np.isfinite(acc)
        if acc_ok.any() and not np.isfinite(vel).any():
            self._acc_velocity = np.where(acc_ok, self._acc_velocity + np.where(acc_ok, acc, 0.0) * dt, 0.0)
            vel = self._acc_velocity
        else:
            self._acc_velocity = vehicle.velocity_ned_mps.copy()
        v = np.where(np.isfinite(vel), vel, 0.0)
        pos_ok = np.isfinite(pos)
        if pos_ok.any():
            v = v + np.where(pos_ok, POS_GAIN_PER_S * (np.where(pos_ok, pos, 0.0) - p), 0.0)
            h = math.hypot(v[0], v[1])
            vmax = self.params["WPNAV_SPEED"] / 100.0
            if h > vmax:
                v[:2] *= vmax / h
        return v

    def request_mission_start(self, first: float, now_s: float, vehicle: VehicleState) -> int:
        """Not modelled: ArduPilot's AUTO mode is not flown by mavsim."""
        return mavlink2.MAV_RESULT_UNSUPPORTED

    def load_mission(self, items: list, current: int) -> None:
        """Nothing: the stored mission is served (mission protocol), not flown."""

    def set_mission_current(self, seq: int) -> None:
        """Nothing (the mission is not flown)."""

    def load_fence(self, items: list) -> None:
        """Nothing: ArduCopter's fence is served (mission protocol), not kept (no breach action)."""

    def position_aiding(self, unaided_s: float | None, now_s: float, vehicle: VehicleState) -> None:
        """Nothing: ArduPilot's EKF failsafe is not modelled (its personality refuses outages of
        ``gps_outage_max_s`` or more)."""

    def update(self, now_s: float, dt: float, vehicle: VehicleState) -> VehicleCommand:
        """Readiness, auto-disarm, then this step's velocity command."""
        if not self.origin_set and now_s >= self.origin_s:
            self.origin_set = True
            self.announce += [MSG_GPS_GLOBAL_ORIGIN, MSG_HOME]
            self._say(SEV_INFO, "EKF3 IMU0 origin set")
        if not self.ready and now_s >= self.ready_s:
            self.ready = True
            self._say(SEV_INFO, "EKF3 IMU0 is using GPS")
        if self.armed:
            self._checks(now_s, vehicle)
        if not self.armed:
            return VehicleCommand(np.zeros(3), motors_on=self.on_stand)
        p = vehicle.position_ned_m
        yaw = rate = None
        if self.mode == "GUIDED":
            v = self._guided(now_s, dt, vehicle)
            sp = self.setpoint
            if sp is not None:
                yaw = sp.yaw_rad if math.isfinite(sp.yaw_rad) else None
                rate = sp.yaw_rate_radps if math.isfinite(sp.yaw_rate_radps) and yaw is None else None
        elif self.mode == "LAND":
            v = POS_GAIN_PER_S * (self.hold_point - p)
            v[2] = self.params["LAND_SPEED"] / 100.0
        elif self.mode == "RTL":
            d = -p[:2]
            dist = float(np.hypot(d[0], d[1]))
            v = np.zeros(3)
            if dist > 0.5:
                v[:2] = d / dist * min(self.params["WPNAV_SPEED"] / 100.0, POS_GAIN_PER_S * dist)
            else:
                v[:2] = POS_GAIN_PER_S * d
                v[2] = self.params["LAND_SPEED"] / 100.0
        elif vehicle.on_ground:
            v = np.zeros(3)       # STABILIZE/ALT_HOLD/... with the throttle low: stays down
        else:
            v = POS_GAIN_PER_S * (self.hold_point - p)
        if self.mode != "LAND" and not (self.mode == "GUIDED" and self.setpoint is not None):
            # the autopilot's own climbs and descents (a client's GUIDED targets are not bounded by these)
            v[2] = min(max(v[2], -self.params["WPNAV_SPEED_UP"] / 100.0), self.params["WPNAV_SPEED_DN"] / 100.0)
        return VehicleCommand(v, yaw, rate, True)

    def _checks(self, now_s: float, vehicle: VehicleState) -> None:
        if not vehicle.on_ground:
            self.was_airborne = True
            self.landed_since_s = None
            return
        if self.was_airborne:
            if self.landed_since_s is None:
                self.landed_since_s = now_s
            if self.mode in ("LAND", "RTL") and now_s - self.landed_since_s >= LAND_DISARM_S:
                self._disarm()
        elif self.takeoff_z is None:
            t = self.params["DISARM_DELAY"]
            if t > 0 and now_s - self.arm_time_s >= t:
                self._disarm()


class ArduPilotPersonality:
    """ArduCopter 4.7 as mavsim imitates it, with its GUIDED velocity response as the
    ``"ardupilot"`` vehicle profile."""

    name = "ardupilot"
    mav_type = MAV_TYPE_QUADROTOR
    mav_autopilot = MAV_AUTOPILOT_ARDUPILOTMEGA
    flight_sw_version = (4 << 24) | (7 << 16) | (0 << 8) | 0x00   # 4.7.0, FIRMWARE_VERSION_TYPE_DEV
    vendor_id = 0
    product_id = 0
    mode_names = START_MODES
    params = PARAMS
    stream_rates_hz = STREAM_RATES_HZ
    response_models = {"ardupilot": ArduPilotResponse(
        accel_xy_max_mps2=2.34, jerk_xy_mps3=4.14, pos_xy_p_per_s=1.02, vel_xy_p_per_s=2.97, accel_xy_lag_s=0.137,
        accel_up_max_mps2=1.05, accel_down_max_mps2=1.28, jerk_z_mps3=3.12, pos_z_p_per_s=0.85, vel_z_p_per_s=6.87,
        accel_z_lag_s=0.138)}
    #: Integer parameters travel as float values, not PX4's bytewise int32.
    param_ints_bytewise = False
    #: MAV_CMD_NAV_TAKEOFF param7 is metres above home.
    takeoff_alt_amsl = False
    gps_outage_max_s = 5.0          # its EKF failsafe on a lost position is not modelled

    def default_start_mode(self, airborne: bool) -> str:
        """LOITER when airborne, STABILIZE (as ArduCopter boots) on the ground."""
        return "LOITER" if airborne else "STABILIZE"

    def default_arming_delay_s(self, airborne: bool) -> float:
        """Readiness (the EKF's absolute position): :data:`DEFAULT_READY_S` on the ground, at once airborne."""
        return 0.0 if airborne else DEFAULT_READY_S

    def commander(self, params: ParamStore, start_mode: str, armed: bool, vehicle: VehicleState,
                  arming_delay_s: float, offboard_reject_ack: int) -> Commander:
        return Commander(params, start_mode, armed, vehicle, arming_delay_s)

    def heartbeat_mode_name(self, custom_mode: int) -> str:
        return heartbeat_mode_name(custom_mode)

    def engaged(self, base_mode: int, custom_mode: int) -> bool:
        return engaged(base_mode, custom_mode)


#: The ArduPilot personality (registered as ``"ardupilot"`` in :mod:`mavsim.personalities`).
ARDUPILOT = ArduPilotPersonality()
