"""Link faults for lockstep flights, and what the vehicle saw of them (tests and the fault campaign).

:class:`VehicleSide` is a ``drop`` filter for :func:`companion.offline.harness.run_lockstep`: it
cuts the autopilot link (both directions, or one) or the obstacle link during time windows, and
records from the vehicle's side of the cut what crossed it: every setpoint the vehicle received
(``SET_POSITION_TARGET_LOCAL_NED``), every mode request, and when the companion could first know
that the vehicle had left OFFBOARD (the first HEARTBEAT out of OFFBOARD that got through).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from pymavlink.dialects.v20 import common as mavlink2

AUTOPILOT_SYSID = 1
PX4_OFFBOARD_MAIN_MODE = 6
SETPOINT_ID = mavlink2.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED


def _msgid(packet: bytes) -> int:
    """The message id of one MAVLink 2 packet (bytes 7 to 9, little-endian); -1 if not MAVLink 2."""
    if len(packet) < 10 or packet[0] != 0xFD:
        return -1
    return packet[7] | (packet[8] << 8) | (packet[9] << 16)


@dataclass
class Cut:
    """Drop ``what`` (``"autopilot"``: the autopilot link both ways; ``"autopilot_up"``: only the
    companion's messages to it; ``"autopilot_down"``: only the autopilot's to the companion;
    ``"obstacles"``: every report of another system, or only system ``sysid``'s) from ``start_s``
    to ``end_s`` (sim time, s)."""

    start_s: float
    end_s: float
    what: str = "autopilot"
    sysid: int | None = None

    def drops(self, t_s: float, direction: str, packet: bytes) -> bool:
        if not (self.start_s <= t_s < self.end_s):
            return False
        sysid = packet[5] if len(packet) > 5 else -1
        if self.what == "obstacles":
            return (direction == "to_companion" and sysid != AUTOPILOT_SYSID
                    and (self.sysid is None or sysid == self.sysid))
        up = direction == "to_vehicle"
        down = direction == "to_companion" and sysid == AUTOPILOT_SYSID
        return {"autopilot": up or down, "autopilot_up": up, "autopilot_down": down}[self.what]


@dataclass
class VehicleSide:
    """A lockstep ``drop`` filter applying ``cuts`` and recording what the vehicle received and sent."""

    cuts: list[Cut] = field(default_factory=list)
    setpoints_t: list[float] = field(default_factory=list)         #: sim times the vehicle received a setpoint
    mode_requests_t: list[float] = field(default_factory=list)     #: ... a DO_SET_MODE or SET_MODE
    left_offboard_seen_t: float | None = None   #: first HEARTBEAT out of OFFBOARD that reached the companion
    _in_offboard: bool = False
    _parser: mavlink2.MAVLink = field(default_factory=lambda: mavlink2.MAVLink(None))

    def __call__(self, t_s: float, direction: str, packet: bytes) -> bool:
        if any(c.drops(t_s, direction, packet) for c in self.cuts):
            return True
        msgid = _msgid(packet)
        if direction == "to_vehicle":
            if msgid == SETPOINT_ID:
                self.setpoints_t.append(t_s)
            elif msgid == mavlink2.MAVLINK_MSG_ID_SET_MODE:
                self.mode_requests_t.append(t_s)
            elif msgid == mavlink2.MAVLINK_MSG_ID_COMMAND_LONG:
                msg = self._decode(packet)
                if msg is not None and msg.command == mavlink2.MAV_CMD_DO_SET_MODE:
                    self.mode_requests_t.append(t_s)
        elif msgid == mavlink2.MAVLINK_MSG_ID_HEARTBEAT and packet[5] == AUTOPILOT_SYSID:
            msg = self._decode(packet)
            if msg is not None:
                offboard = (msg.custom_mode >> 16) & 0xFF == PX4_OFFBOARD_MAIN_MODE
                if self._in_offboard and not offboard and self.left_offboard_seen_t is None:
                    self.left_offboard_seen_t = t_s
                self._in_offboard = offboard
        return False

    def _decode(self, packet: bytes):
        try:
            return self._parser.decode(bytearray(packet))
        except Exception:  # noqa: BLE001 - a corrupt packet is not what is counted
            return None

    def setpoints_after(self, t_s: float | None) -> int:
        """Setpoints the vehicle received at or after sim time ``t_s`` (0 if None)."""
        return 0 if t_s is None else sum(1 for t in self.setpoints_t if t >= t_s - 1e-9)

    def mode_requests_after(self, t_s: float | None) -> int:
        return 0 if t_s is None else sum(1 for t in self.mode_requests_t if t >= t_s - 1e-9)


def left_offboard_t(truth: dict) -> float | None:
    """Sim time the vehicle first left OFFBOARD (mavsim's truth), None if it never did."""
    was = False
    for change in truth["mode_changes"]:
        if change["mode"] == "OFFBOARD":
            was = True
        elif was:
            return float(change["t_s"])
    return None


def gcs_mode_switch(at_s: float, main: int, sub: int):
    """A ground station (system 255) asking the vehicle for a mode once, at ``at_s``."""
    gcs = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    sent: list[float] = []

    def inject(t_s: float) -> list[bytes]:
        if t_s < at_s - 1e-9 or sent:
            return []
        sent.append(t_s)
        return [mavlink2.MAVLink_command_long_message(1, 1, mavlink2.MAV_CMD_DO_SET_MODE, 0, 1, main, sub,
                                                      0, 0, 0, 0).pack(gcs)]
    return inject


class PlanOrigins:
    """``after_tick``: at each tick flying a plan, whether that plan was built from an estimate older
    than the autopilot's last estimator reset (the vehicle time its plan starts from, against the
    vehicle time of the first report after the reset)."""

    def __init__(self) -> None:
        self.ticks_after_reset = 0
        self.stale_frame_ticks: list[float] = []
        self.first_plan_after_reset: list[tuple[float, float]] = []   # (reset t_v, first plan t0 after it)

    def __call__(self, companion, t_s: float, _outbox) -> None:
        resets = companion.perception.resets
        executor = companion.executor
        if not resets or companion.state.mode.name != "TRACKING" or executor.plan is None:
            return
        t_reset = resets[-1][0]
        self.ticks_after_reset += 1
        if executor.plan_t0_v < t_reset - 1e-9:
            self.stale_frame_ticks.append(t_s)
        if not self.first_plan_after_reset or self.first_plan_after_reset[-1][0] != t_reset:
            self.first_plan_after_reset.append((t_reset, executor.plan_t0_v))
