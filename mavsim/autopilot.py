"""The autopilot's MAVLink face: incoming messages to commander calls and replies,
and per-link telemetry stream scheduling. The same for every autopilot: what a request
does is its personality's commander's (:class:`mavsim.personalities.base.Commander`).

Handled: COMMAND_LONG / COMMAND_INT (DO_SET_MODE 176, COMPONENT_ARM_DISARM 400,
NAV_TAKEOFF 22, NAV_LAND 21, NAV_RETURN_TO_LAUNCH 20, NAV_LOITER_UNLIM 17,
REQUEST_MESSAGE 512, REQUEST_AUTOPILOT_CAPABILITIES 520, SET_MESSAGE_INTERVAL 511,
GET_MESSAGE_INTERVAL 510; every other command is answered ACK 3 UNSUPPORTED),
SET_MODE, SET_POSITION_TARGET_LOCAL_NED, PARAM_REQUEST_LIST / PARAM_REQUEST_READ /
PARAM_SET, the mission protocol (upload and download of mission, fence and rally items,
MISSION_SET_CURRENT: :mod:`mavsim.missions`), PING, TIMESYNC (answered; answers to its own requests are counted in
``stats["timesync_answers"]``). Messages addressed to another system or component are
ignored; anything else is counted and ignored. Replies go to the link the request
came on; STATUSTEXT to every link.
"""

from __future__ import annotations

import logging
import math
from collections import Counter

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from mavsim.missions import MissionStore, local_items
from mavsim.params import ParamStore
from mavsim.personalities.base import SEV_WARNING, Commander, OffboardSetpoint
from mavsim.telemetry import EARTH_RADIUS_M, MSG_AUTOPILOT_VERSION, STREAM_IDS, TelemetryBuilder
from mavsim.vehicle import VehicleState

logger = logging.getLogger(__name__)


__all__ = ["Autopilot", "SYSID", "COMPID", "statustext"]

SYSID = 1
COMPID = 1
POS_LIMIT_M = 1.0e4
VEL_LIMIT_MPS = 100.0
ACC_LIMIT_MPS2 = 100.0
YAW_RATE_LIMIT_RADPS = 20.0
_NAN = float("nan")


def _finite_int(x: float) -> int | None:
    return int(x) if math.isfinite(x) and abs(x) < 2**31 else None


MSG_GPS_GLOBAL_ORIGIN = 49

class Autopilot:
    """Message handling and telemetry streams of system 1, component 1.

    Parameters
    ----------
    commander, params, telemetry
        The personality's commander, the parameter store and the message builder.
    links : sequence of str
        Link names (e.g. ``("api", "gcs")``); each has its own stream intervals.
    rates_hz : dict
        Stream rate overrides by name.
    home_alt_m : float
        Home altitude AMSL (m), to read NAV_TAKEOFF's param7.
    default_rates_hz : dict
        The streams sent by default, name -> rate (Hz, 0 off): the personality's.
    """

    def __init__(self, commander: Commander, params: ParamStore, telemetry: TelemetryBuilder,
                 links: tuple[str, ...], rates_hz: dict[str, float], home_alt_m: float,
                 default_rates_hz: dict[str, float], system_id: int = SYSID) -> None:
        self.cmdr, self.params, self.tm = commander, params, telemetry
        self.system_id = int(system_id)
        self.home_alt_m = home_alt_m
        rates = {**default_rates_hz, **rates_hz}
        self._default_us = {STREAM_IDS[n]: (round(1e6 / r) if r > 0 else None) for n, r in rates.items()}
        self.interval_us = {link: dict(self._default_us) for link in links}
        self.next_due = {link: {i: 0 for i in self._default_us} for link in links}
        self._earliest_due_us = 0    # no stream is due before this (us); lowered by SET_MESSAGE_INTERVAL
        self.stats: Counter[str] = Counter()
        self.missions = MissionStore()   # mission, fence and rally items uploaded by a client
        self._last_reject: dict[str, int] = {}

    # ------------------------------------------------------------------ streams
    def streams_due(self, now_us: int, veh: VehicleState, estimate) -> list[tuple[str, object]]:
        """Telemetry due at ``now_us`` as (link, message); ``estimate()`` gives (pos, vel)."""
        if now_us < self._earliest_due_us:     # most physics steps: nothing due
            return []
        out = []
        earliest = math.inf
        for msg_id in self._default_us:
            links = []
            for link, due in self.next_due.items():
                iv = self.interval_us[link][msg_id]
                if iv is not None and due[msg_id] <= now_us:
                    links.append(link)
                    due[msg_id] += iv
                    if due[msg_id] <= now_us:  # fell behind (e.g. a long step): no burst
                        due[msg_id] = now_us + iv
                if iv is not None:
                    earliest = min(earliest, due[msg_id])
            if links and self.cmdr.sends(msg_id):
                pos, vel = estimate()
                msg = self.tm.build(msg_id, now_us, self.cmdr, veh, pos, vel)
                out.extend((link, msg) for link in links)
        self._earliest_due_us = earliest
        return out

    # ------------------------------------------------------------------ incoming
    def handle(self, msg, link: str, now_us: int, veh: VehicleState, estimate) -> list[tuple[str, object]]:
        """Act on one decoded message; return replies as (link, message)."""
        mtype = msg.get_type()
        handler = getattr(self, "_on_" + mtype.lower(), None)
        if handler is None:
            self.stats["ignored_" + mtype] += 1
            return []
        ts = getattr(msg, "target_system", 0)
        tc = getattr(msg, "target_component", 0)
        if ts not in (0, self.system_id) or (mtype != "SET_MODE" and tc not in (0, COMPID)):
            self.stats["other_target"] += 1
            logger.debug("ignored %s for system %d component %d", mtype, ts, tc)
            return []
        self.stats[mtype] += 1
        self._current_link = link
        return [(link, m) for m in handler(msg, now_us, veh, estimate)]

    def _reject(self, key: str, text: str, now_us: int) -> list:
        """Log a rejection; STATUSTEXT at most once a second per kind."""
        self.stats["rejected_" + key] += 1
        logger.warning("rejected: %s", text)
        last = self._last_reject.get(key)
        if last is not None and now_us - last < 1_000_000:
            return []
        self._last_reject[key] = now_us
        self.cmdr.texts.append((SEV_WARNING, text[:50]))
        return []

    def _ack(self, msg, command: int, result: int):
        return mavlink2.MAVLink_command_ack_message(command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())

    def _on_command_long(self, msg, now_us, veh, estimate):
        p = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
        return self._command(msg, msg.command, p, now_us, veh, estimate)

    def _on_command_int(self, msg, now_us, veh, estimate):
        p = (msg.param1, msg.param2, msg.param3, msg.param4, float(msg.x), float(msg.y), msg.z)
        return self._command(msg, msg.command, p, now_us, veh, estimate)

    def _command(self, msg, command: int, p: tuple, now_us: int, veh, estimate) -> list:
        now_s = now_us * 1e-6
        c = self.cmdr
        extra: list = []
        if command == 176:  # MAV_CMD_DO_SET_MODE: base mode, custom mode, custom sub mode
            base, custom, sub = _finite_int(p[0]), _finite_int(p[1]), _finite_int(p[2])
            if base is None or custom is None or not base & 1:
                result = mavlink2.MAV_RESULT_DENIED
            else:
                result = c.request_mode(custom, sub or 0, now_s, veh)
        elif command == 400:  # MAV_CMD_COMPONENT_ARM_DISARM
            if p[0] not in (0.0, 1.0):
                result = mavlink2.MAV_RESULT_DENIED
            else:
                result = c.request_arm(p[0] == 1.0, p[1] == 21196.0, now_s, veh)
        elif command == 22:  # MAV_CMD_NAV_TAKEOFF, param7 altitude AMSL or above home (the personality's)
            rel = p[6] - self.home_alt_m if self.tm.personality.takeoff_alt_amsl else p[6]
            result = c.request_takeoff(rel, now_s, veh)
        elif command == 21:  # MAV_CMD_NAV_LAND
            result = c.request_land(now_s, veh)
        elif command == 20:  # MAV_CMD_NAV_RETURN_TO_LAUNCH
            result = c.request_return(now_s, veh)
        elif command == 17:  # MAV_CMD_NAV_LOITER_UNLIM
            result = c.request_hold(now_s, veh)
        elif command == 300:  # MAV_CMD_MISSION_START, param1 the first item
            result = c.request_mission_start(p[0], now_s, veh)
        elif command in (512, 520):  # REQUEST_MESSAGE, REQUEST_AUTOPILOT_CAPABILITIES
            msg_id = MSG_AUTOPILOT_VERSION if command == 520 else _finite_int(p[0])
            reply = None
            if msg_id == MSG_GPS_GLOBAL_ORIGIN:  # PX4 sends it once and on change: clients ask for it
                lat, lon, alt = self.tm.home
                reply = mavlink2.MAVLink_gps_global_origin_message(round(lat * 1e7), round(lon * 1e7), round(alt * 1000), now_us)
            elif msg_id is not None and (msg_id in self._default_us or msg_id == MSG_AUTOPILOT_VERSION):
                pos, vel = estimate()
                reply = self.tm.build(msg_id, now_us, c, veh, pos, vel)
            result = mavlink2.MAV_RESULT_ACCEPTED if reply is not None else mavlink2.MAV_RESULT_DENIED
            if reply is not None:
                extra.append(reply)
        elif command == 511:  # SET_MESSAGE_INTERVAL, param2 in us (-1 off, 0 default)
            msg_id, iv = _finite_int(p[0]), _finite_int(p[1])
            link = self._link_of(msg)
            if msg_id not in self._default_us or iv is None or iv < -1:
                result = mavlink2.MAV_RESULT_DENIED
            else:
                new = None if iv == -1 else (self._default_us[msg_id] if iv == 0 else max(iv, 1000))
                self.interval_us[link][msg_id] = new
                self.next_due[link][msg_id] = now_us
                self._earliest_due_us = min(self._earliest_due_us, now_us)
                result = mavlink2.MAV_RESULT_ACCEPTED
        elif command == 510:  # GET_MESSAGE_INTERVAL
            msg_id = _finite_int(p[0])
            if msg_id in self._default_us:
                iv = self.interval_us[self._link_of(msg)][msg_id]
                extra.append(mavlink2.MAVLink_message_interval_message(msg_id, -1 if iv is None else iv))
                result = mavlink2.MAV_RESULT_ACCEPTED
            else:
                result = mavlink2.MAV_RESULT_DENIED
        else:
            result = mavlink2.MAV_RESULT_UNSUPPORTED
        logger.info("t=%.2f command %d -> result %d", now_s, command, result)
        return [self._ack(msg, command, result)] + extra

    _current_link = "api"

    def _link_of(self, msg) -> str:
        return self._current_link

    def _on_set_mode(self, msg, now_us, veh, estimate):
        if not msg.base_mode & 1:
            return [self._ack(msg, 176, mavlink2.MAV_RESULT_DENIED)]
        return [self._ack(msg, 176, self.cmdr.request_set_mode(msg.custom_mode, now_us * 1e-6, veh))]

    def _on_set_position_target_local_ned(self, msg, now_us, veh, estimate):
        frame, mask = msg.coordinate_frame, msg.type_mask
        if frame not in (1, 8):
            return self._reject("frame", f"Offboard: frame {frame} not supported, use 1 or 8", now_us)
        pos = np.array([msg.x, msg.y, msg.z])
        vel = np.array([msg.vx, msg.vy, msg.vz])
        acc = np.array([msg.afx, msg.afy, msg.afz])
        pos_used = np.array([not mask & b for b in (1, 2, 4)])
        vel_used = np.array([not mask & b for b in (8, 16, 32)])
        acc_used = np.array([not mask & b for b in (64, 128, 256)])
        if not (pos_used.any() or vel_used.any() or acc_used.any()):
            return self._reject("mask", "Offboard: setpoint has no position, velocity or accel", now_us)
        yaw = msg.yaw if not mask & 1024 else _NAN
        rate = msg.yaw_rate if not mask & 2048 else _NAN
        ok = (np.all(np.abs(pos[pos_used]) <= POS_LIMIT_M) and np.all(np.abs(vel[vel_used]) <= VEL_LIMIT_MPS)
              and np.all(np.abs(acc[acc_used]) <= ACC_LIMIT_MPS2)
              and (mask & 1024 or abs(yaw) <= 4 * math.pi) and (mask & 2048 or abs(rate) <= YAW_RATE_LIMIT_RADPS))
        if not ok:  # NaN compares false, so NaN lands here too
            return self._reject("value", "Offboard: setpoint NaN or out of range, ignored", now_us)
        if frame == 8:  # BODY_NED: rotate by the current yaw only
            cy, sy = math.cos(veh.yaw_rad), math.sin(veh.yaw_rad)
            rot = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
            pos = veh.position_ned_m + rot @ np.where(pos_used, pos, 0.0)
            vel = rot @ np.where(vel_used, vel, 0.0)
            acc = rot @ np.where(acc_used, acc, 0.0)
        sp = OffboardSetpoint(np.where(pos_used, pos, _NAN), np.where(vel_used, vel, _NAN),
                              np.where(acc_used, acc, _NAN), float(yaw), float(rate))
        self.cmdr.accept_setpoint(sp, now_us * 1e-6)
        return []

    def _reject_unsupported_setpoint(self, msg, now_us, veh, estimate):
        return self._reject("sp_type", f"Offboard: {msg.get_type()} not supported", now_us)

    _on_set_position_target_global_int = _reject_unsupported_setpoint
    _on_set_attitude_target = _reject_unsupported_setpoint

    def _param_value(self, name: str):
        value, ptype = self.params.wire(name)
        return mavlink2.MAVLink_param_value_message(name.encode(), value, ptype, len(self.params),
                                                    self.params.index(name))

    def _on_param_request_list(self, msg, now_us, veh, estimate):
        return [self._param_value(n) for n in self.params.names]

    def _on_param_request_read(self, msg, now_us, veh, estimate):
        name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode(errors="replace")
        name = name.rstrip("\x00")
        if msg.param_index >= 0:
            if msg.param_index >= len(self.params):
                return []
            name = self.params.names[msg.param_index]
        if name not in self.params.names:
            self.stats["unknown_param"] += 1
            return []
        return [self._param_value(name)]

    def _on_param_set(self, msg, now_us, veh, estimate):
        name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode(errors="replace")
        name = name.rstrip("\x00")
        if name not in self.params.names:
            return self._reject("param", f"PARAM_SET: unknown parameter {name[:16]}", now_us)
        problem = self.params.set_from_wire(name, msg.param_value, msg.param_type)
        if problem:
            self._reject("param", f"PARAM_SET: {problem}", now_us)
        return [self._param_value(name)]

    def _on_mission(self, msg, now_us, veh, estimate):
        """The mission protocol: :class:`mavsim.missions.MissionStore` stores and serves the items;
        the commander is told the stored mission and fence (local NED) when they changed, and the
        current item when a client sets it."""
        before, fence_before = self.missions.items[0], self.missions.items[1]
        replies = self.missions.handle(msg)
        if self.missions.items[0] is not before:      # an upload completed, or a clear
            self.cmdr.load_mission(local_items(self.missions.items[0], self.tm.home, EARTH_RADIUS_M),
                                   self.missions.current)
        if self.missions.items[1] is not fence_before:
            self.cmdr.load_fence(local_items(self.missions.items[1], self.tm.home, EARTH_RADIUS_M))
        elif msg.get_type() == "MISSION_SET_CURRENT":
            self.cmdr.set_mission_current(self.missions.current)
        return replies

    _on_mission_request_list = _on_mission_count = _on_mission_clear_all = _on_mission
    _on_mission_request_int = _on_mission_request = _on_mission_item_int = _on_mission_set_current = _on_mission

    def _on_ping(self, msg, now_us, veh, estimate):
        if msg.target_system != 0:
            return []  # a reply to our ping, or not for us
        return [mavlink2.MAVLink_ping_message(msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent())]

    def _on_timesync(self, msg, now_us, veh, estimate):
        if msg.tc1 != 0:  # an answer to one of our 10 Hz requests (TIMESYNC stream): counted
            self.stats["timesync_answers"] += 1
            return []
        return [mavlink2.MAVLink_timesync_message(now_us * 1000, msg.ts1)]


def statustext(severity: int, text: str):
    """A STATUSTEXT (text at most 50 characters)."""
    return mavlink2.MAVLink_statustext_message(severity, text.encode()[:50])

